"""A setup's settings as the core takes them, and their fingerprints.

* :func:`core_settings`: the setup's properties (and a frame's parameter maps) as a
  :class:`core.Settings`.
* :func:`signature`: everything that changes the result but the input; :func:`structure`:
  what every frame of a shot shares (the keyable values are inputs of each frame:
  :func:`.keyed.values`). A change of the structure drops the playback cache; a bake
  resumes only where its structure is the setup's (``stable``: objects by name).
* :func:`time_key`: the frame rate, when the result depends on it (wind, jiggle).
"""

from __future__ import annotations

import json

import bpy

from ... import core
from ..frame.colliders import collider_objects, in_scene
from . import keyed, motion
from .core_values import core_value
from .maps import MAPPED


def core_settings(ob, maps=None):
    """core.Settings for the setup's properties (raises SettingsError), with parameter
    ``maps`` (:func:`maps.read_maps`) in."""
    kw = ob.furcollide.to_core_kwargs()
    return core.Settings(**dict(kw, **maps) if maps else kw)


def signature(ob, stable=False, scene=None, identities=True) -> str:
    """Fingerprint of everything that changes the result except the input.

    ``stable=False`` identifies colliders by session id (renames do not
    count); ``stable=True`` by name, which survives saving and reloading
    (bake files, so a bake resumes in a new session). ``identities=False``
    leaves out which objects the colliders and the surface are (renames never
    count, nor sessions): the frame-inputs record, which digests their
    geometry instead.
    """
    s = ob.furcollide
    cols = [
        ((r.name if stable else r.uid), r.double_sided, r.offset) if identities
        else (r.double_sided, r.offset)
        for r in collider_objects(ob, scene)
    ]
    kw = s.to_core_kwargs()
    kw.pop("threads", None)
    surf = ob.data.surface
    surface = "" if surf is None else (surf.name if stable else surf.session_uid) if (
        identities) else True
    parts = [cols, kw, s.enable_attribute, s.frame_start, surface, bool(s.enabled)]
    if s.use_fur_attach:  # only when on: signatures (and bakes) without it are unchanged
        parts.append(["fur_attach", s.attach_id])
    if s.motion.active:  # likewise
        parts.append(["motion", s.motion.fingerprint()])
        t = time_key(ob, scene or bpy.context.scene)
        if t is not None:  # wind and jiggle run on seconds: frame / fps
            parts.append(["fps", t])
    return json.dumps(parts)


def structure(ob, stable=False, scene=None, identities=True) -> str:
    """Fingerprint of what a setup's frames share, whatever frame they are: everything
    :func:`signature` holds but the values that can be keyed or driven (those are
    inputs of each frame: :func:`keyed.values`). Which objects collide (every entry of
    the list, enabled or not, and the collider collection's members), the Mode, the
    growth surface, the Enable Attribute, the frame the shot starts at, Fur Attach's
    binding and the frame rate. ``stable`` and ``identities`` as in :func:`signature`.
    """
    s = ob.furcollide
    entries = [c.object for c in s.colliders]
    if s.collider_collection is not None:
        entries.append(s.collider_collection)
    cols = [
        (o.name if stable else o.session_uid) if identities else True
        for o in entries
        if o is not None and (not isinstance(o, bpy.types.Object) or in_scene(o, scene))
    ]
    if identities and s.collider_collection is not None:
        cols.append(sorted(
            (o.name if stable else o.session_uid) for o in s.collider_collection.all_objects))
    surf = ob.data.surface
    surface = "" if surf is None else (surf.name if stable else surf.session_uid) if (
        identities) else True
    # (wind and jiggle run on seconds: frame / fps; only then does the fps count)
    anim = keyed.Animation(ob)
    timed = s.motion.use_wind or s.motion.use_jiggle or any(
        anim.animates(f"furcollide.motion.{n}") for n in ("use_wind", "use_jiggle"))
    parts = [cols, core_value(s, "mode"), s.enable_attribute, s.frame_start, surface,
             ["fur_attach", s.attach_id] if s.use_fur_attach else None,
             motion.fps(scene or bpy.context.scene) if timed else None]
    mapped = {k: getattr(s, f"{k}_map") for k in MAPPED if getattr(s, f"{k}_map")}
    if mapped:  # (only when in use: structures without maps are unchanged)
        parts.append(["maps", mapped])
    return json.dumps(parts)


def signature_change(old: str, new: str) -> str:
    """What differs between two :func:`signature` strings, in words."""
    try:
        a, b = json.loads(old), json.loads(new)
    except ValueError:
        return "the settings changed"
    if a[0] != b[0]:
        if len(a[0]) != len(b[0]):
            return f"a collider was {'added' if len(b[0]) > len(a[0]) else 'removed'}"
        return "the colliders changed"
    if a[4] != b[4]:
        return "the growth surface changed"
    return "the settings changed"


def structure_change(old: str, new: str) -> str:
    """What differs between two :func:`structure` strings, in words."""
    try:
        a, b = json.loads(old), json.loads(new)
    except ValueError:
        return "the settings changed"
    names = ("", "Mode", "Enable Attribute", "Frame Start", "", "Fur Attach",
             "the frame rate")
    if a[0] != b[0]:
        if len(a[0]) != len(b[0]):
            return f"a collider was {'added' if len(b[0]) > len(a[0]) else 'removed'}"
        return "the colliders changed"
    if a[4] != b[4]:
        return "the growth surface changed"
    for i, name in enumerate(names):
        if name and a[i] != b[i]:
            return f"{name} changed"
    if a[len(names):] != b[len(names):]:
        return "a parameter map was chosen or cleared"
    return "the settings changed"


def time_key(ob, scene):
    """The scene's frames per second when the setup's result depends on it (wind,
    jiggle), else None."""
    m = ob.furcollide.motion
    return motion.fps(scene) if (m.use_wind or m.use_jiggle) else None
