"""A setup's settings as the core takes them, and their fingerprints, read once a frame.

* :func:`core_settings`: the setup's properties (and a frame's parameter maps) as a
  :class:`core.Settings`.
* :func:`signature`: everything that changes the result but the input; :func:`structure`:
  what every frame of a shot shares (the keyable values are inputs of each frame:
  :func:`.keyed.values`). A change of the structure drops the playback cache; a bake
  resumes only where its structure is the setup's (``stable``: objects by name).
* :func:`time_key`: the frame rate, when the result depends on it (wind, jiggle).
* :func:`read_settings`: all of it for one evaluation, once (:class:`SettingsRead`): the
  colliders listed, the keyable values at the frame, the fingerprints. Every step of a
  frame takes them from there instead of reading the properties again.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

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


@dataclass(frozen=True)
class SettingsRead:
    """A setup's settings as one evaluation reads them (:func:`read_settings`).

    Attributes
    ----------
    refs : list of colliders.ColliderRef
        The colliders (:func:`.colliders.collider_objects` in the scene evaluated).
    animation : keyed.Animation
        Which values are keyed or driven.
    values : dict
        :func:`keyed.values` at the frame shown: part ``values`` of its record.
    fingerprint : int
        :func:`keyed.fingerprint`: what decides the values at every frame.
    structure : str
        :func:`structure`, objects by session id: a change drops the playback cache.
    structure_record, signature_record : str
        :func:`structure` and :func:`signature` without the objects' identities: parts
        ``structure`` and ``settings`` of a frame-inputs record.
    time_key : float or None
        :func:`time_key`.
    """

    refs: list
    animation: keyed.Animation
    values: dict
    fingerprint: int
    structure: str
    structure_record: str
    signature_record: str
    time_key: float | None


def read_settings(ob, scene) -> SettingsRead:
    """The settings of the setup on ``ob`` as ``scene`` shows them now, read once."""
    refs = collider_objects(ob, scene)
    animation = keyed.Animation(ob)
    with_ids, without_ids = structures(ob, scene=scene, animation=animation)
    return SettingsRead(
        refs=refs, animation=animation, values=keyed.values(ob, None, animation),
        fingerprint=keyed.fingerprint(ob, animation), structure=with_ids,
        structure_record=without_ids,
        signature_record=signature(ob, scene=scene, identities=False, refs=refs),
        time_key=time_key(ob, scene))


def signature(ob, stable=False, scene=None, identities=True, refs=None) -> str:
    """Fingerprint of everything that changes the result except the input.

    ``stable=False`` identifies colliders by session id (renames do not
    count); ``stable=True`` by name, which survives saving and reloading
    (bake files, so a bake resumes in a new session). ``identities=False``
    leaves out which objects the colliders and the surface are (renames never
    count, nor sessions): the frame-inputs record, which digests their
    geometry instead. ``refs``: the colliders, when listed already.
    """
    s = ob.furcollide
    refs = collider_objects(ob, scene) if refs is None else refs
    cols = [
        ((r.name if stable else r.uid), r.double_sided, r.offset) if identities
        else (r.double_sided, r.offset)
        for r in refs
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


def structure(ob, stable=False, scene=None, identities=True, animation=None) -> str:
    """Fingerprint of what a setup's frames share, whatever frame they are: everything
    :func:`signature` holds but the values that can be keyed or driven (those are
    inputs of each frame: :func:`keyed.values`). Which objects collide (every entry of
    the list, enabled or not, and the collider collection's members), the Mode, the
    growth surface, the Enable Attribute, the frame the shot starts at, Fur Attach's
    binding and the frame rate. ``stable`` and ``identities`` as in :func:`signature`;
    ``animation``: the setup's :class:`keyed.Animation`, when made already.
    """
    return structures(ob, stable, scene, animation)[0 if identities else 1]


def structures(ob, stable=False, scene=None, animation=None) -> tuple[str, str]:
    """:func:`structure` with and without the objects' identities, read in one pass."""
    s = ob.furcollide
    entries = [c.object for c in s.colliders]
    if s.collider_collection is not None:
        entries.append(s.collider_collection)
    listed = [o for o in entries
              if o is not None and (not isinstance(o, bpy.types.Object) or in_scene(o, scene))]
    cols = [o.name if stable else o.session_uid for o in listed]
    if s.collider_collection is not None:
        cols.append(sorted(
            (o.name if stable else o.session_uid) for o in s.collider_collection.all_objects))
    surf = ob.data.surface
    surface = "" if surf is None else surf.name if stable else surf.session_uid
    # (wind and jiggle run on seconds: frame / fps; only then does the fps count)
    anim = keyed.Animation(ob) if animation is None else animation
    timed = s.motion.use_wind or s.motion.use_jiggle or any(
        anim.animates(f"furcollide.motion.{n}") for n in ("use_wind", "use_jiggle"))
    rest = [core_value(s, "mode"), s.enable_attribute, s.frame_start]
    tail = [["fur_attach", s.attach_id] if s.use_fur_attach else None,
            motion.fps(scene or bpy.context.scene) if timed else None]
    mapped = {k: getattr(s, f"{k}_map") for k in MAPPED if getattr(s, f"{k}_map")}
    if mapped:  # (only when in use: structures without maps are unchanged)
        tail.append(["maps", mapped])
    return (json.dumps([cols, *rest, surface, *tail]),
            json.dumps([[True] * len(listed), *rest, surf is not None or "", *tail]))


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
