"""Files saved by earlier versions: their keys and drivers of angle settings, converted once.

Up to settings version 0 the angle settings (:data:`.angles.ANGLES`) were plain floats in
degrees; they are Blender angles now, keyed and driven in radians. Their stored values
need nothing (they are still stored in degrees: :mod:`.angles`), nor do the choices
(a file stores a choice's number, which did not change). What needs converting is what
Blender itself evaluates into the property: an F-curve keyed on ``furcollide.max_angle``
holds degrees, a driver computes degrees. :func:`migrate` converts them to radians, as
Blender's own versioning converts old data when a file is read.

Which objects are old: each object says which version its settings were keyed with
(``furcollide.settings_version``, hidden). It is written whenever this version lets go of
the data (:func:`stamp`: before a save, when the add-on is disabled) and by Add FurCollide;
an object without it that has keys or drivers on angle settings was saved by an earlier
version. Files are converted when they are opened (``load_post``, before the frame
handlers read anything) and when the add-on is enabled with a file already open.
Objects appended or linked from an earlier version's file are not converted: open and
save that file once with this version first.
"""

from __future__ import annotations

import math

import bpy
from bpy.app.handlers import persistent

from . import angles
from .keyed import _action_fcurves
from .properties import CURRENT_VERSION

#: Degrees to radians.
K = math.pi / 180.0
#: The data paths of the angle settings (``furcollide.max_angle``...).
PATHS = {f"furcollide.{name}" for name in angles.ANGLES}


def _strip_fcurves(strip):
    """The F-curves an NLA strip's action animates (its slot's on Blender 4.4+)."""
    act = getattr(strip, "action", None)
    if act is None:
        return []
    if hasattr(act, "layers") and getattr(strip, "action_slot", None) is not None:
        try:
            from bpy_extras.anim_utils import action_get_channelbag_for_slot
        except ImportError:
            action_get_channelbag_for_slot = None
        if action_get_channelbag_for_slot is not None:
            bag = action_get_channelbag_for_slot(act, strip.action_slot)
            return list(bag.fcurves) if bag is not None else []
    return list(getattr(act, "fcurves", []))


def angle_fcurves(ob):
    """(keyed F-curves, driver F-curves) of ``ob`` on angle settings: its action's and
    its NLA strips' keys, its drivers."""
    ad = ob.animation_data
    if ad is None:
        return [], []
    keyed = [fc for fc in _action_fcurves(ob) if fc.data_path in PATHS]
    for track in ad.nla_tracks:
        for strip in track.strips:
            keyed += [fc for fc in _strip_fcurves(strip) if fc.data_path in PATHS]
    drivers = [fc for fc in ad.drivers if fc.data_path in PATHS]
    return keyed, drivers


def _scale_keys(fc, k) -> None:
    """Multiply the values F-curve ``fc`` gives by ``k``: its keys and handles, and the
    modifiers that add or replace values."""
    for kp in fc.keyframe_points:
        kp.co.y *= k
        kp.handle_left.y *= k
        kp.handle_right.y *= k
    _scale_modifiers(fc, k)
    fc.update()


def _scale_modifiers(fc, k) -> None:
    """Multiply what the modifiers of ``fc`` add to (or put in place of) its value by
    ``k`` (the ones that only move time, Cycles and Stepped, are left)."""
    for m in fc.modifiers:
        if m.type == "GENERATOR":
            m.coefficients = [c * k for c in m.coefficients]
        elif m.type == "FNGENERATOR":
            m.amplitude *= k
            m.value_offset *= k
        elif m.type == "NOISE" and m.blend_type != "MULTIPLY":
            m.strength *= k
        elif m.type == "ENVELOPE":
            m.reference_value *= k
            m.default_min *= k
            m.default_max *= k
            for p in m.control_points:
                p.min *= k
                p.max *= k
        elif m.type == "LIMITS":
            m.min_y *= k
            m.max_y *= k


def _gives_values(fc) -> bool:
    """Does driver F-curve ``fc`` map the driver's value (keys, or a replacing
    generator) rather than pass it on?"""
    return len(fc.keyframe_points) > 0 or any(
        m.type in ("GENERATOR", "FNGENERATOR") and not m.use_additive for m in fc.modifiers)


#: A driver that is no expression, as one (its variables' names joined).
_AS_EXPRESSION = {
    "SUM": lambda names: " + ".join(names),
    "AVERAGE": lambda names: f"({' + '.join(names)}) / {len(names)}",
    "MIN": lambda names: f"min({', '.join(names)})",
    "MAX": lambda names: f"max({', '.join(names)})",
}


def _scale_driver(fc) -> None:
    """Make driver F-curve ``fc`` set radians where it set degrees: its keys (a mapping
    curve), else its expression in ``radians()`` (a sum, average, minimum or maximum of
    variables written as that expression first)."""
    if _gives_values(fc):
        _scale_keys(fc, K)
        return
    d = fc.driver
    if d.type != "SCRIPTED":
        names = [v.name for v in d.variables]
        expression = _AS_EXPRESSION[d.type](names) if names else "0.0"
        d.type = "SCRIPTED"
        d.expression = expression
    d.expression = f"radians({d.expression})"
    _scale_modifiers(fc, K)


def migrate(ob, done=None) -> bool:
    """Convert ``ob``'s keys and drivers on angle settings from degrees to radians if
    its settings were keyed by an earlier version; stamp it. True when something was
    converted. ``done``: the F-curves already converted in this pass (an action shared
    by several objects is converted once)."""
    s = getattr(ob, "furcollide", None)
    if s is None or s.settings_version >= CURRENT_VERSION or ob.library is not None:
        return False
    keyed, drivers = angle_fcurves(ob)
    if not keyed and not drivers:
        if s.is_setup or s.is_output:
            s.settings_version = CURRENT_VERSION
        return False
    done = set() if done is None else done
    for fc in keyed:
        if fc.as_pointer() in done:
            continue
        done.add(fc.as_pointer())
        _scale_keys(fc, K)
    for fc in drivers:
        _scale_driver(fc)
    s.settings_version = CURRENT_VERSION
    names = sorted({fc.data_path.rpartition(".")[2] for fc in keyed + drivers})
    print(f"FurCollide: '{ob.name}': the keys and drivers of {', '.join(names)} were "
          "converted to radians (saved by an earlier version)", flush=True)
    return True


def migrate_all() -> int:
    """:func:`migrate` every object of the open file; the number converted."""
    done = set()
    n = 0
    for ob in bpy.data.objects:
        try:
            n += migrate(ob, done)
        except Exception as exc:  # noqa: BLE001 - a file must open whatever happens
            print(f"FurCollide: '{ob.name}': its angle keys could not be converted: {exc}",
                  flush=True)
    return n


def stamp(obs=None) -> None:
    """Record that the objects' settings are keyed as this version keys them (every
    object with FurCollide settings that are a setup, an output, or keyed or driven on
    an angle setting)."""
    for ob in bpy.data.objects if obs is None else obs:
        s = getattr(ob, "furcollide", None)
        if s is None or ob.library is not None or s.settings_version >= CURRENT_VERSION:
            continue
        if s.is_setup or s.is_output or any(angle_fcurves(ob)):
            s.settings_version = CURRENT_VERSION


@persistent
def convert_on_load(*_args):
    """A file was read: convert what an earlier version saved, before anything reads it."""
    try:
        migrate_all()
    except Exception as exc:  # noqa: BLE001 - a handler must never raise
        print(f"FurCollide: could not convert the file's settings: {exc}", flush=True)


@persistent
def stamp_before_save(*_args):
    try:
        stamp()
    except Exception as exc:  # noqa: BLE001
        print(f"FurCollide: could not record the settings' version: {exc}", flush=True)


def _data_ready() -> bool:
    """Is ``bpy.data`` readable (not while Blender starts and registers add-ons)?"""
    return isinstance(getattr(bpy, "data", None), bpy.types.BlendData)


def register():
    handlers = bpy.app.handlers
    for lst, fn in ((handlers.load_post, convert_on_load), (handlers.save_pre, stamp_before_save)):
        for h in list(lst):  # (survive "Reload Scripts")
            if getattr(h, "__name__", "") == fn.__name__ and __name__ == getattr(
                    h, "__module__", ""):
                lst.remove(h)
    # first: before the frame handlers' load_post reads the settings
    handlers.load_post.insert(0, convert_on_load)
    handlers.save_pre.append(stamp_before_save)
    if _data_ready():  # (enabled with a file open: it may be an earlier version's)
        convert_on_load()


def unregister():
    if _data_ready():  # what is keyed now is this version's
        stamp_before_save()
    handlers = bpy.app.handlers
    for lst, fn in ((handlers.load_post, convert_on_load), (handlers.save_pre, stamp_before_save)):
        if fn in lst:
            lst.remove(fn)
