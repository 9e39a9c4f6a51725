"""Parameter maps: settings that vary from curve to curve, painted or generated on the hair.

Plasticity, Recovery Rate, Collision Offset, Max Angle and Scale Minimum each take an
optional map: the name of a float attribute on the *evaluated* source, on the curve
domain or on the point domain (read at each curve's root). The value a curve is solved
with is the setting times its map value, clamped to the setting's range (the core takes
a ``(C,)`` array for these :class:`core.Settings` fields). A map that cannot be used (a
missing attribute, another type or domain, a value that is not finite) is a warning
naming the attribute, and the setting then applies unmapped: never a stopped frame.

A map's values are inputs of their frame (the ``maps`` part of the frame-inputs record):
an attribute animated by Geometry Nodes, or painted again, makes the frames it changed
be solved again. Which attribute is a map is a setting like any other.

Recipe (user guide): weight-paint a vertex group on the growth surface, then a Geometry
Nodes modifier on the hair samples it at the roots (*Sample Nearest Surface* or *Sample
UV Surface*) and stores it with *Store Named Attribute* on the Curve domain.
"""

from __future__ import annotations

import numpy as np

from ...core import framecache
from .core_values import core_value

#: The settings that take a map, with the range their mapped values are clamped to
#: (None: the lower bound is the setup's Rotation Precision, as core.Settings asks).
MAPPED = {
    "plasticity": (0.0, 1.0),
    "recovery_rate": (0.0, 1.0),
    "collision_offset": (0.0, 1e6),
    "max_angle": (None, 360.0),
    "scale_minimum": (0.001, 1.0),
}


def map_property(name: str) -> str:
    """The property holding the map of setting ``name`` (``plasticity_map``)."""
    return f"{name}_map"


def read_maps(curves, s, offsets) -> tuple[dict, list[str]]:
    """The mapped settings of setup properties ``s`` on evaluated hair ``curves``.

    Returns
    -------
    values : dict
        Setting name -> ``(C,)`` float64 values (the setting times the map, clamped),
        for every setting with a usable map.
    warnings : list of str
        One line per map that cannot be used (named), each ending in what to do.
    """
    n = len(offsets) - 1
    values, warnings = {}, []
    for name, (lo, hi) in MAPPED.items():
        attr_name = getattr(s, map_property(name))
        if not attr_name:
            continue
        raw, why = _read(curves, attr_name, offsets, n)
        label = s.bl_rna.properties[name].name
        if why:
            warnings.append(f"{label} map '{attr_name}' {why}: {label} applies unmapped")
            continue
        lo = core_value(s, "rotation_precision") if lo is None else lo
        setting = float(core_value(s, name))  # (Max Angle in degrees, as the core takes it)
        values[name] = np.clip(setting * raw.astype(np.float64), lo, hi)
    return values, warnings


def _read(curves, name, offsets, n):
    """(per-curve float32 values, '') of attribute ``name``, or (None, why not)."""
    attr = curves.attributes.get(name)
    if attr is None:
        return None, "is not an attribute of the evaluated hair"
    if attr.data_type != "FLOAT":
        return None, f"has type {attr.data_type.title()}, not Float"
    if attr.domain not in ("CURVE", "POINT"):
        return None, f"is on the {attr.domain.title()} domain, not Curve or Point"
    buf = np.empty(len(attr.data), np.float32)
    if len(buf):
        attr.data.foreach_get("value", buf)
    if attr.domain == "POINT":
        if len(buf) != offsets[-1]:
            return None, f"has {len(buf)} values for {offsets[-1]} points"
        buf = buf[offsets[:-1]]  # (each curve's root)
    elif len(buf) != n:
        return None, f"has {len(buf)} values for {n} curves"
    bad = np.flatnonzero(~np.isfinite(buf))
    if len(bad):
        return None, f"is not finite on curve {bad[0]}"
    return buf, ""


def apply(kw: dict, values: dict) -> dict:
    """``core.Settings`` keyword arguments ``kw`` with the mapped ``values`` in."""
    return dict(kw, **values) if values else kw


def digest(values: dict) -> int | None:
    """The maps' part of the frame-inputs record (None: no map in use)."""
    if not values:
        return None
    return framecache.digest(*(np.ascontiguousarray(values[k]) for k in sorted(values)))


def suggestions(ob, context, edit_text):
    """The evaluated hair's float attributes on the Curve and Point domains, for the map
    fields' search (as Blender lists vertex groups)."""
    try:
        dg = context.evaluated_depsgraph_get()
        data = ob.evaluated_get(dg).data
        names = [a.name for a in data.attributes
                 if a.data_type == "FLOAT" and a.domain in ("CURVE", "POINT")
                 and not a.name.startswith((".", "furcollide_")) and a.name != "radius"]
    except (AttributeError, RuntimeError, ReferenceError):
        return []
    return [n for n in sorted(names) if edit_text.lower() in n.lower()]
