"""Keyed and driven settings: a setting's value at a frame is an input of that frame.

Every numeric, boolean and choice setting that changes a frame's result (the solver's,
each collider entry's Enabled, Double Sided and Collision Offset, the collider
collection's Double Sided, the wind, jiggle, Region of Influence and collider distance
settings, the render groom's Clearance Pass) can be keyed or driven. Like a frame's
geometry, its values are recorded with the frame (the ``values`` part of the
frame-inputs record, :mod:`..frame.inputs`): a cached or baked frame stays valid while
the values it was solved with hold at that frame.

:func:`values` gives the values at any frame without going there: a keyed setting's
F-curve is evaluated at that frame and converted as Blender converts it (clamped to
the property's range; integers, booleans and choices are the F-curve's whole values).
Angles are recorded in degrees and the Mode and Pinched Hair choices in the core's
spelling, as :class:`core.Settings` takes them (and as earlier versions recorded them:
their bakes stay valid). A driven setting, or one animated by NLA strips, is known only
at the frame the scene shows (:data:`UNKNOWN` elsewhere, and never compared there): its
value is checked when its frame is shown again.

What cannot change mid-shot is not animatable (Blender refuses the key, saying the
property is not animatable), each for a reason its tooltip gives: Mode (a curve's
state in one mode means nothing in another), the frame range, the cache, the Enable
Attribute's name, Fur Attach and the render groom's binding (they change every frame's
input at once: bind again instead).
"""

from __future__ import annotations

import numpy as np

from . import angles
from .core_values import CORE_CHOICES, core_value

#: A value not known at that frame (a driver or NLA strips, away from the current frame).
UNKNOWN = None

#: The setup's own settings whose value at a frame is an input of that frame
#: (``ob.furcollide.<name>``), in the order a change is reported.
SETUP_VALUES = (
    "enabled", "rotation_precision", "max_angle", "affected_connected_cvs", "cv_falloff",
    "attract_to_growth_surface", "follow_collider_motion", "shrink", "scale_minimum",
    "scale_angle", "recovery_rate", "plasticity", "pinch_resolution", "recover_pinched",
    "collision_offset", "collection_double_sided",
)
#: Each collider entry's (``ob.furcollide.colliders[i].<name>``).
COLLIDER_VALUES = ("enabled", "double_sided", "use_offset", "collision_offset")
#: The render groom's (``ob.furcollide.groom.<name>``).
GROOM_VALUES = ("use_clearance",)


def _motion_values():
    from .properties_pipeline import MOTION_FIELDS

    return MOTION_FIELDS


def _owners(ob):
    """(data path prefix, property group, names) of every group of values."""
    s = ob.furcollide
    yield "furcollide", s, SETUP_VALUES
    for i, c in enumerate(s.colliders):
        yield f"furcollide.colliders[{i}]", c, COLLIDER_VALUES
    yield "furcollide.motion", s.motion, _motion_values()
    yield "furcollide.groom", s.groom, GROOM_VALUES


def _as_value(owner, name, index=None):
    """The current value of ``owner.name`` (element ``index`` of an array) as recorded:
    a bool, int, float (the stored float32, exactly) or choice identifier; a setup's
    angle and choice as the core takes them (degrees exactly as stored, the core's
    spelling: :func:`.properties.core_value`), as every version recorded them."""
    if name in angles.ANGLES or name in CORE_CHOICES:
        return core_value(owner, name)
    v = getattr(owner, name)
    if index is not None:
        v = v[index]
    if isinstance(v, float):
        return float(np.float32(v))
    return v


def _from_fcurve(prop, v):
    """What Blender sets property ``prop`` (RNA) to from F-curve value ``v`` (the
    F-curve evaluates integers, booleans and choices to whole values already), as
    :func:`_as_value` records it (an angle: the degrees its setter stores for ``v``)."""
    kind = prop.type
    if kind == "BOOLEAN":
        return bool(v > 0.5)
    if kind == "INT":
        return int(min(max(int(round(v)), prop.hard_min), prop.hard_max))
    if kind == "ENUM":
        for item in prop.enum_items:
            if item.value == int(round(v)):
                ident = item.identifier
                return ident.lower() if prop.identifier in CORE_CHOICES else ident
        return UNKNOWN
    if prop.identifier in angles.ANGLES:
        return angles.to_degrees(prop.identifier, v)
    return float(np.float32(min(max(v, prop.hard_min), prop.hard_max)))


def _action_fcurves(ob):
    """The object's action's F-curves (its slot's channel bag on Blender 4.4+)."""
    ad = ob.animation_data
    act = ad.action if ad is not None else None
    if act is None:
        return []
    if hasattr(act, "fcurves") and not hasattr(act, "layers"):
        return list(act.fcurves)
    if hasattr(act, "layers") and getattr(ad, "action_slot", None) is not None:
        try:
            from bpy_extras.anim_utils import action_get_channelbag_for_slot
        except ImportError:  # (4.4.0 lacked it)
            action_get_channelbag_for_slot = None
        if action_get_channelbag_for_slot is not None:
            bag = action_get_channelbag_for_slot(act, ad.action_slot)
            return list(bag.fcurves) if bag is not None else []
    if hasattr(act, "fcurves"):
        return list(act.fcurves)
    return [fc for layer in act.layers for strip in layer.strips
            for bag in strip.channelbags for fc in bag.fcurves]


class Animation:
    """Which of a setup's values are keyed (their F-curves) or known only where shown.

    Built per call site from the object's animation data; cheap (a few dozen
    F-curves at most)."""

    __slots__ = ("keyed", "shown_only")

    def __init__(self, ob):
        ad = ob.animation_data
        self.keyed = {}
        self.shown_only = set()
        if ad is None:
            return
        nla = any(not t.mute and len(t.strips) for t in ad.nla_tracks)
        for fc in _action_fcurves(ob):
            if not fc.mute and fc.data_path.startswith("furcollide."):
                self.keyed[(fc.data_path, fc.array_index)] = fc
        for fc in ad.drivers:
            if not fc.mute and fc.data_path.startswith("furcollide."):
                self.shown_only.add((fc.data_path, fc.array_index))
        if nla:  # NLA strips blend other actions in: known where shown only
            self.shown_only.add("*")

    def __bool__(self):
        return bool(self.keyed or self.shown_only)

    def animates(self, path: str) -> bool:
        """Is the value at data path ``path`` (:func:`values`' keys) keyed or driven
        (other at other frames), rather than the same at every frame?"""
        head, _, index = path.partition("[")
        if head.startswith("furcollide.colliders"):  # (the entry's index is in the path)
            head, _, rest = path.rpartition(".")
            head = f"{head}.{rest.partition('[')[0]}"
            index = rest.partition("[")[2]
        key = (head, int(index.rstrip("]")) if index else 0)
        return "*" in self.shown_only or key in self.keyed or key in self.shown_only

    def value(self, owner, path, name, index, frame):
        """The value of ``owner.name`` at ``frame`` (None: the current frame)."""
        if frame is None:
            return _as_value(owner, name, index)
        key = (f"{path}.{name}", 0 if index is None else index)
        if key in self.shown_only or "*" in self.shown_only:
            return UNKNOWN
        fc = self.keyed.get(key)
        if fc is None:
            return _as_value(owner, name, index)
        return _from_fcurve(owner.bl_rna.properties[name], fc.evaluate(frame))


def values(ob, frame=None, animation=None) -> dict:
    """The setup's values at ``frame`` (None: as the scene shows them now): data path
    (``furcollide.recovery_rate``, ``furcollide.colliders[0].enabled``,
    ``furcollide.motion.wind_direction[1]``) -> value, :data:`UNKNOWN` where not
    known at that frame (see the module docstring)."""
    anim = Animation(ob) if animation is None else animation
    out = {}
    for path, owner, names in _owners(ob):
        for name in names:
            prop = owner.bl_rna.properties[name]
            if getattr(prop, "is_array", False):
                for i in range(prop.array_length):
                    out[f"{path}.{name}[{i}]"] = anim.value(owner, path, name, i, frame)
            else:
                out[f"{path}.{name}"] = anim.value(owner, path, name, None, frame)
    return out


def setup_value(ob, name, frame=None):
    """The value of the setup's own setting ``name`` (``ob.furcollide.<name>``) at
    ``frame`` (:func:`values` for one setting)."""
    return Animation(ob).value(ob.furcollide, "furcollide", name, None, frame)


def first_difference(old: dict | None, new: dict) -> str | None:
    """The first data path whose value differs between the recorded ``old`` and
    ``new`` (an :data:`UNKNOWN` value of ``new`` is not compared), or None."""
    if old is None:
        return None
    for path, v in new.items():
        if v is not UNKNOWN and old.get(path, v) != v:
            return path
    for path in old:
        if path not in new:
            return path
    return None


def label(ob, path: str) -> str:
    """The setting at data path ``path`` as the panel names it: "Recovery Rate",
    "'Ball' Enabled", "Wind Direction Y"."""
    head, _, tail = path.rpartition(".")
    name, _, index = tail.partition("[")
    try:
        owner = ob.path_resolve(head)
        text = owner.bl_rna.properties[name].name
    except (ValueError, KeyError, AttributeError):
        return path
    if head.startswith("furcollide.colliders["):
        obj = getattr(owner, "object", None)
        text = f"'{obj.name if obj is not None else '?'}' {text}"
    elif head == "furcollide.motion" and not name.startswith("use_"):
        group = {"wind": "Wind", "jiggle": "Jiggle", "roi": "Region of Influence"}.get(
            name.partition("_")[0])
        text = f"{group} {text}" if group else text
    if index:
        text += " " + "XYZW"[int(index.rstrip("]"))]
    return text


def fingerprint(ob, animation=None) -> int:
    """Digest of what decides the setup's values at every frame: each unanimated
    value, each keyed value's F-curve (its keys, handles, interpolation, extrapolation
    and modifiers), each driven one's driver. Equal fingerprints give equal values at
    every frame, so the depsgraph check looks for changed frames only when it changes
    (:func:`frame.rules.drop_changed`). ``animation``: the setup's :class:`Animation`,
    when made already."""
    anim = Animation(ob) if animation is None else animation
    parts = []
    for path, owner, names in _owners(ob):
        for name in names:
            full = f"{path}.{name}"
            prop = owner.bl_rna.properties[name]
            n = prop.array_length if getattr(prop, "is_array", False) else 0
            for i in range(max(n, 1)):
                key = (full, i)
                fc = anim.keyed.get(key)
                if key in anim.shown_only or "*" in anim.shown_only:
                    parts.append((full, i, "shown"))
                elif fc is not None:
                    co = np.empty(2 * len(fc.keyframe_points), np.float32)
                    fc.keyframe_points.foreach_get("co", co)
                    hl, hr = np.empty_like(co), np.empty_like(co)
                    fc.keyframe_points.foreach_get("handle_left", hl)
                    fc.keyframe_points.foreach_get("handle_right", hr)
                    parts.append((full, i, co.tobytes().hex(), hl.tobytes().hex(),
                                  hr.tobytes().hex(),
                                  [k.interpolation for k in fc.keyframe_points],
                                  fc.extrapolation, len(fc.modifiers)))
                else:
                    parts.append((full, i, _as_value(owner, name, i if n else None)))
    return hash(repr(parts))
