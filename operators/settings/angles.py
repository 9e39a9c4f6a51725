"""Angle settings: Blender angles over a store in degrees.

Rotation Precision, Max Angle and Scale Angle are Blender angles: the ANGLE subtype,
shown in degrees or radians as the user's unit settings say, keyed, driven and set from
Python in radians like every angle in Blender (``s.max_angle = math.radians(120)``).
Each is stored in **degrees**, under its own name, in the setup's stored properties
(:func:`store`): the unit of :class:`core.Settings`, and how earlier versions stored
them. So:

* a file saved by an earlier version opens with the same values, and the core gets
  exactly the degrees it got then (:func:`degrees`): a bake made then is not outdated;
* the property is a view: its getter gives radians of the stored degrees, its setter
  stores the degrees of the radians it gets (:func:`to_degrees`, which picks the float
  of the shortest decimal that gives those radians back: 30 typed in the field is stored
  as 30.0, not 29.999998), clamped to the setting's range in degrees.

What is keyed or driven evaluates to radians (F-curves hold radians); files saved before
this version hold degrees there, converted once when they are opened
(:mod:`.versioning`). Presets written before hold degrees too: :mod:`.presets_compat`.
"""

from __future__ import annotations

import math

import numpy as np
from bpy.props import FloatProperty

#: The angle settings of ``ob.furcollide``: name -> (default, min, max) in degrees.
ANGLES = {
    "rotation_precision": (0.25, 0.001, 45.0),
    "max_angle": (180.0, 0.01, 360.0),
    "scale_angle": (90.0, 0.01, 360.0),
}


def store(pg, create=False):
    """The stored properties of property group ``pg`` (its ID properties): Blender 5.0
    keeps the data of ``bpy.props`` apart, as "system properties"; before, they were
    the group's own ID properties. None when ``pg`` has none yet (``create``: made)."""
    system = getattr(pg, "bl_system_properties_get", None)
    if system is not None:
        return system(do_create=create)
    return pg


def degrees(pg, name) -> float:
    """The stored value in degrees of angle setting ``name`` of ``pg`` (its default
    when never set), exactly as stored: what the core takes."""
    st = store(pg)
    value = st.get(name) if st is not None else None
    return float(ANGLES[name][0] if value is None else value)


def set_degrees(pg, name, value) -> None:
    """Store ``value`` degrees (clamped to the setting's range, as a float32 like every
    Blender float property) as angle setting ``name`` of ``pg``. Calls no update
    callback: set the property (radians) for that."""
    _, lo, hi = ANGLES[name]
    v = float(value)
    if not math.isnan(v):  # (NaN is kept: the core's check names it)
        v = min(max(v, lo), hi)
    store(pg, create=True)[name] = float(np.float32(v))


#: How far (float32 steps of the radians) the radians of the degrees :func:`to_degrees`
#: picks may be from the radians it was given: a key converted to radians and
#: interpolated lands a step or two from the radians of the degrees it stood for (55
#: degrees between keys at 45 and 60), and a step is 1e-7 of the angle, far below any
#: Rotation Precision.
STEPS = 2


def to_degrees(name, radians) -> float:
    """The degrees angle setting ``name`` stores for ``radians`` (as Blender passes it:
    a float32): of the float32 numbers whose radians are within :data:`STEPS` float32
    steps of ``radians``, the one with the shortest decimal form (the nearest to the
    exact degrees on a tie), clamped to the setting's range. 30 degrees typed in the
    field is stored as 30.0, not 29.999998. A pure function of ``radians``: the setter
    and a keyed value evaluated at another frame (:mod:`.keyed`) agree bit for bit."""
    _, lo, hi = ANGLES[name]
    r = np.float32(radians)
    if not np.isfinite(r):
        return float(r) if np.isnan(r) else (hi if r > 0 else lo)
    exact = math.degrees(float(r))
    near = np.float32(exact)
    cands = {near}
    up, down = near, near
    for _ in range(3):
        up, down = np.nextafter(up, np.float32(np.inf)), np.nextafter(down, np.float32(-np.inf))
        cands |= {up, down}
    cands |= {np.float32(round(exact, k)) for k in range(9)}
    step = float(np.spacing(abs(r))) * STEPS
    back = [c for c in cands if abs(float(np.float32(math.radians(float(c)))) - float(r)) <= step]
    best = min(back, key=lambda c: (len(str(c)), abs(float(c) - exact))) if back else near
    return min(max(float(best), lo), hi)


def angle(name, label, description, update, soft_min=None, soft_max=None, precision=None):
    """The angle property ``name`` (:data:`ANGLES`): radians shown in the user's unit,
    stored in degrees. ``update`` runs after a change, as for any setting."""
    default, lo, hi = ANGLES[name]

    def get(self):
        return math.radians(degrees(self, name))

    def set_(self, value):
        set_degrees(self, name, to_degrees(name, value))

    kw = {"soft_min": math.radians(soft_min)} if soft_min is not None else {}
    if soft_max is not None:
        kw["soft_max"] = math.radians(soft_max)
    if precision is not None:
        kw["precision"] = precision
    return FloatProperty(
        name=label, description=description, subtype="ANGLE", unit="ROTATION",
        default=math.radians(default), min=math.radians(lo), max=math.radians(hi),
        get=get, set=set_, update=update, **kw,
    )
