"""The frame-inputs record: what a cached frame was solved from, and what changed since.

A cached frame (memory or bake) keeps a record of what it was solved from (part name ->
64-bit digest, :func:`frame_inputs`); it is shown only while the current inputs give the
same record (see README "Time"): :func:`solved_inputs` makes it for a solved frame,
:func:`current_inputs` afresh, and :func:`cached_frame_change` /
:func:`baked_frame_change` say what changed, in words (:func:`describe_change`).
:func:`fixed_change` checks the settings a cached frame was solved with (what every frame
shares and the keyable values at that frame) without going there.

The record of the frame the frame handler last evaluated is remembered
(:func:`seen_inputs`, :func:`saw`): the depsgraph check tells an edit from the
animation evaluated again by comparing the scene with it
(:func:`..store.invalidation.edit_seen`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core import framecache
from ..blender import bridge
from ..settings import keyed, maps
from ..settings.fingerprints import structure_change
from .colliders import collider_objects, read_collider_inputs, renders_otherwise


def uses_growth(settings) -> bool:
    """Does the solve read the growth surface? (core Settings or the setup's properties)"""
    return bool(settings.attract_to_growth_surface
                or settings.pinch_resolution.lower() == "growth_surface")


def frame_inputs(inp, sig, colliders, flags, surface, attached_as_source=False,
                 structure=None, values=None) -> dict:
    """The frame-inputs record of one frame: part name -> 64-bit digest.

    Parameters
    ----------
    inp : FrameInputs
        The frame's input: the source's own positions and world matrix (part ``source
        local``; ``source``, the world positions before motion, for an input given
        in world space), offsets and the per-curve enable mask. With Fur Attach, the
        part ``attached`` digests
        the world positions of the Surface vertices the binding reads and the
        offsets instead of the positions (``attach.AttachInput.digest``): the
        attached positions are a function of them and of the binding (its
        ``attach_id`` is in the settings), so checking a record never attaches.
    sig : str
        The settings: :func:`signature` without the objects' identities (their
        geometry is digested; renaming an object or a new session never counts).
    colliders : list of (int, int)
        :func:`collider_inputs` of each collider, in :func:`collider_objects` order.
    flags : list of (bool, float or None)
        Each collider's Double Sided and Collision Offset, in the same order.
    surface : (int, int) or None
        The growth surface's, when the solve reads it.
    attached_as_source : bool
        The part ``source`` (the digest of the world positions before motion; with Fur
        Attach, of the attached points) instead of ``source local`` (``attached``):
        the record of a bake made before that part existed.
    structure : str, optional
        :func:`..settings.fingerprints.structure` without identities: what every frame of the shot
        shares (part ``structure``).
    values : dict, optional
        :func:`keyed.values` at this frame: every setting that can be keyed or driven
        (part ``values``, the values themselves, so a change can be named and the
        record of another frame checked without going there: :func:`fixed_change`).

    Returns
    -------
    dict
        Ordered as :func:`describe_change` reports the first difference: what the
        shot's frames share, the keyable values, the colliders' number and options,
        the settings, the source (or ``attached``),
        the enable mask, each collider's matrix and shape, the surface's.
    """
    rec = {}
    if structure is not None:
        rec[STRUCTURE_PART] = structure
    if values is not None:
        rec[VALUES_PART] = values
    rec["colliders"] = framecache.text_digest(repr(list(flags)))
    rec["settings"] = framecache.text_digest(sig)
    if inp.attached is None:
        if inp.source_local is not None and not attached_as_source:
            # (what the world input is made of: a frame checked needs no transform)
            rec[SOURCE_LOCAL_PART] = inp.source_digest()
        else:
            rec["source"] = framecache.digest(inp.before_motion(), inp.offsets)
    elif attached_as_source:  # (as read_inputs makes the points: float32)
        rec["source"] = framecache.digest(np.asarray(inp.attached.points(), np.float32),
                                          inp.offsets)
    else:
        rec[ATTACHED_PART] = inp.attached.digest
    if inp.enabled is not None:
        rec["enabled"] = framecache.digest(inp.enabled)
    if inp.maps:
        rec[MAPS_PART] = maps.digest(inp.maps)
    for i, (matrix, shape) in enumerate(colliders):
        rec[f"collider {i} matrix"] = matrix
        rec[f"collider {i} shape"] = shape
    if surface is not None:
        rec["surface matrix"], rec["surface shape"] = surface
    return rec


def solved_inputs(setup, inp, read) -> dict:
    """The record of the frame just solved (``read``: its settings as read once,
    :class:`..settings.fingerprints.SettingsRead`), from the colliders as the solve
    read them."""
    rt = setup.rt
    growth = rt.colliders.growth
    growth = growth if growth is not None and uses_growth(rt.solve.solver.settings) else None
    entries = list(rt.colliders.entries.values())
    return _tagged(setup, frame_inputs(
        inp, read.signature_record, [e.inputs for e in entries],
        [(e.double_sided, e.offset) for e in entries],
        growth.inputs if growth is not None else None,
        structure=read.structure_record, values=read.values))


#: Part of a frame-inputs record made from a render's depsgraph (see :func:`first_change`).
RENDER_PART = "render"
#: Parts of a frame-inputs record with what the shot's frames share
#: (:func:`fingerprints.structure`) and the keyable values at the frame
#: (:func:`keyed.values`).
#: Records made before they existed have neither: ``settings`` and ``colliders`` hold
#: them there (compared as they are).
STRUCTURE_PART = "structure"
VALUES_PART = "values"
#: Part of a frame-inputs record with the parameter maps' values (:func:`maps.digest`).
MAPS_PART = "maps"
#: Part of a frame-inputs record standing for the source when Fur Attach is on
#: (:func:`frame_inputs`). Bakes made before it have ``source``, the digest of the
#: attached points: :func:`current_inputs` makes that part for them (``like``,
#: ``frame_inputs(attached_as_source=True)``).
ATTACHED_PART = "attached"
#: Part of a frame-inputs record standing for the source without Fur Attach: its own
#: positions, offsets and world matrix (:func:`frame_inputs`), what the world input is
#: a function of. Records made before it have ``source``, the digest of the world
#: positions: :func:`current_inputs` makes that part for them (``like``).
SOURCE_LOCAL_PART = "source local"
#: The parts that stand for the source hair's own geometry.
SOURCE_PARTS = ("source", SOURCE_LOCAL_PART)


def _tagged(setup, record) -> dict:
    if bridge.is_render(setup.depsgraph):
        record[RENDER_PART] = 1
    return record


def current_inputs(setup, inp, read, like=None) -> dict:
    """The record of the frame the setup's depsgraph shows now, read afresh (no solver
    needed; ``read``: the settings as read once): what a cached frame's record must
    equal to be shown.

    ``like``: the record it will be compared with. One of a bake made before the
    ``attached`` or ``source local`` part existed has ``source``, the digest of the
    attached or world points, instead: the record made then has it too (the curves
    attached, or taken to world space, once, here).
    """
    ob, depsgraph = setup.ob, setup.depsgraph
    refs = read.refs
    cols = [read_collider_inputs(r.object, depsgraph, r.matrix(depsgraph)) for r in refs]
    surf = ob.data.surface
    surface = None
    if uses_growth(ob.furcollide) and surf is not None and surf.type == "MESH":
        surface = read_collider_inputs(surf, depsgraph)
    return _tagged(setup, frame_inputs(inp, read.signature_record,
                                       cols, [(r.double_sided, r.offset) for r in refs],
                                       surface,
                                       attached_as_source=like is not None and "source" in like,
                                       structure=read.structure_record, values=read.values))


@dataclass(slots=True)
class Seen:
    """The part of a setup's runtime with what the frame handler saw last, changed
    only here: changes made since without an update callback drop cached frames
    (:func:`.rules.since_seen`), and the depsgraph check tells an edit from the
    animation evaluated again (:func:`..store.invalidation.edit_seen`)."""

    #: What every frame of the shot shares (``fingerprints.structure``: which objects
    #: collide, Mode, ...); a change drops the playback cache.
    structure: str | None = None
    #: ``keyed.fingerprint``: the depsgraph check looks for changed values only when it
    #: changed (keys edited, a setting changed without an update).
    values: int | None = None
    attach: tuple | None = None  # (use_fur_attach, attach_id)
    time: float | None = None  # fingerprints.time_key
    #: ((scene name, frame), frame-inputs record) of the frame last evaluated: an update
    #: that changes nothing the frame was solved or shown from is the animation
    #: evaluated again, not an edit.
    record: tuple | None = None


def saw(rt, scene, frame, record) -> None:
    """Remember ``record`` as the inputs the frame handler saw at ``frame`` of
    ``scene`` (the depsgraph check compares the scene with it)."""
    rt.seen.record = ((scene.name, frame), record)


def last_seen(rt, scene, frame) -> dict | None:
    """The record the frame handler saw at ``frame`` of ``scene``; None when it has not
    evaluated that frame last."""
    seen = rt.seen.record
    return seen[1] if seen is not None and seen[0] == (scene.name, frame) else None


def saw_settings(rt, s, read) -> None:
    """Remember Fur Attach (of the setup's properties ``s``) and the time key of the
    settings ``read`` once: a change of either drops every cached frame."""
    rt.seen.attach = (bool(s.use_fur_attach), s.attach_id if s.use_fur_attach else "")
    rt.seen.time = read.time_key


def saw_structure(rt, read) -> None:
    """Remember what every frame shares and the values' fingerprint of the settings
    ``read`` once."""
    rt.seen.structure = read.structure
    rt.seen.values = read.fingerprint


def saw_values(rt, fingerprint) -> None:
    """Remember the values' fingerprint (the depsgraph check looked at it; None: look
    at the values again next time)."""
    rt.seen.values = fingerprint


def forget_structure(rt) -> None:
    """Accept the next structure seen without dropping cached frames (they were just
    dropped)."""
    rt.seen.structure = None


def fixed_change(setup, old, read, frame=None) -> str:
    """What changed, in words, in the settings record ``old`` (of cached ``frame``) was
    made with: what every frame shares, and the keyable values at ``frame``
    (:func:`keyed.values` there, without going there); '' when nothing did (or ``old``
    is None). A step from a cached frame checks them: that frame cannot be evaluated
    again at this one. A record made before values were recorded compares the
    settings and the colliders' options of the current frame instead. ``read``: the
    settings as read once at the frame shown (:class:`..settings.fingerprints.SettingsRead`)."""
    if old is None:
        return ""
    ob = setup.ob
    if VALUES_PART in old and STRUCTURE_PART in old:
        now = read.structure_record
        if old[STRUCTURE_PART] != now:
            return structure_change(old[STRUCTURE_PART], now)
        animation = read.animation
        at = None if frame is None or frame == setup.frame else frame
        values = read.values if at is None else keyed.values(ob, at, animation)
        path = keyed.first_difference(old[VALUES_PART], values)
        if path is None:
            return ""
        return value_change(ob, path, frame if animation.animates(path) else None)
    refs = read.refs
    flags = framecache.text_digest(repr([(r.double_sided, r.offset) for r in refs]))
    if old.get("colliders") != flags:
        count = sum(k.startswith("collider ") and k.endswith(" matrix") for k in old)
        if count != len(refs):
            return f"a collider was {'added' if len(refs) > count else 'removed'}"
        return "a collider's Double Sided or Collision Offset changed"
    if old.get("settings") != framecache.text_digest(read.signature_record):
        return "the settings changed"
    return ""


def value_change(ob, path, frame) -> str:
    """"Recovery Rate changed at frame 12": the keyable setting at ``path`` changed its
    value at ``frame`` ("Recovery Rate changed" for None: one value for every frame)."""
    where = f" at frame {frame}" if frame is not None else ""
    return f"{keyed.label(ob, path)} changed{where}"


def first_changed_frame(setup, frames, read) -> tuple[int, str] | None:
    """(the first of the cached ``frames`` whose settings record no longer holds, why),
    or None: the frames before it stay valid, it and every later one must be solved
    again (:func:`fixed_change`; ``read`` as there)."""
    memory = setup.rt.cache.memory
    for f in sorted(frames):
        why = fixed_change(setup, memory.inputs(f), read, f)
        if why:
            return f, why
    return None


def changed_objects(setup, old, new, refs) -> set | None:
    """Names of the objects whose parts differ between the records ``old`` and ``new``
    (the source, a collider and its instancers, the growth surface); None when
    another part differs (settings, the colliders' number or options) or a record is
    missing. ``refs``: the setup's colliders (:func:`.colliders.collider_objects`)."""
    if old is None or new is None:
        return None
    old, new = _comparable(setup, old, new, refs)
    ob = setup.ob
    names = set()
    for part in set(old) | set(new):
        if old.get(part) == new.get(part):
            continue
        what = part.rpartition(" ")[0]
        if part in (*SOURCE_PARTS, "enabled"):
            names.add(ob.name)
        elif (part == ATTACHED_PART or what == "surface") and ob.data.surface is not None:
            names.add(ob.data.surface.name)
        elif what.startswith("collider ") and int(what.split()[-1]) < len(refs):
            names.update(o.name for o in refs[int(what.split()[-1])].objects)
        else:
            return None
    return names


def describe_change(ob, part, scene, old=None, new=None, refs=None) -> str:
    """The change :func:`framecache.first_change` found between the records ``old`` and
    ``new``, in words naming the object (``refs``: the setup's colliders, when listed
    already)."""
    if part == "colliders":
        count = [sum(k.endswith(" matrix") and k.startswith("collider ") for k in r or {})
                 for r in (old, new)]
        if count[1] != count[0]:
            return f"a collider was {'added' if count[1] > count[0] else 'removed'}"
        return "a collider's Double Sided or Collision Offset changed"
    if part == "settings":
        return "the settings changed"
    if part == STRUCTURE_PART:
        return structure_change((old or {}).get(part, ""), (new or {}).get(part, ""))
    if part == VALUES_PART:
        path = keyed.first_difference((old or {}).get(part), (new or {}).get(part) or {})
        if not path:
            return "the settings changed"
        at = scene.frame_current if keyed.Animation(ob).animates(path) else None
        return value_change(ob, path, at)
    if part in SOURCE_PARTS:
        return f"the source hair '{ob.name}' changed (groom, modifiers or placement)"
    if part == MAPS_PART:
        return f"a parameter map of '{ob.name}' changed (its values on the evaluated hair)"
    if part == "enabled":
        return f"the enable attribute '{ob.furcollide.enable_attribute}' of '{ob.name}' changed"
    if part == ATTACHED_PART:
        surf = ob.data.surface
        return (f"the Surface '{surf.name if surf is not None else '?'}' the curves are "
                "attached to (Fur Attach) moved or changed shape")
    what, _, kind = part.rpartition(" ")
    change = "moved" if kind == "matrix" else "changed shape"
    if what == "surface":
        surf = ob.data.surface
        return f"the growth surface '{surf.name if surf is not None else '?'}' {change}"
    refs = collider_objects(ob, scene) if refs is None else refs
    i = int(what.split()[-1]) if what.startswith("collider ") else len(refs)
    return f"'{refs[i].name}' {change}" if i < len(refs) else "the colliders changed"


def cached_frame_change(setup, inp, f, read) -> tuple[str, dict | None]:
    """(why memory-cached frame ``f`` no longer matches the current inputs, '' when it
    does; the current record, None when ``f`` was stored without a record)."""
    old = setup.rt.cache.memory.inputs(f)
    if old is None:
        return "", None
    new = current_inputs(setup, inp, read)
    return change(setup, old, new, read.refs), new


def baked_frame_change(setup, inp, old, read) -> str:
    """Why the baked frame whose inputs record is ``old`` (:func:`framecache.read_shown`)
    no longer matches the current inputs ('' when it does, or for files baked before
    FurCollide stored their inputs, ``old`` None: not checked)."""
    if old is None:
        return ""
    return change(setup, old, current_inputs(setup, inp, read, like=old), read.refs)


def change(setup, old, new, refs) -> str:
    """What differs between the records ``old`` and ``new`` (:func:`first_change`), in
    words (:func:`describe_change`); '' when nothing does."""
    part = first_change(setup, old, new, refs)
    return describe_change(setup.ob, part, setup.scene, old, new, refs) if part else ""


def first_change(setup, old, new, refs) -> str | None:
    """The first part that differs between frame-inputs records ``old`` and ``new``
    (:func:`framecache.first_change`), where one was made from a render's depsgraph
    and the other from the viewport's: a collider that Blender evaluates with other
    modifier settings in renders (:func:`colliders.renders_otherwise`, e.g. a
    Subdivision Surface at its defaults) has another shape in each, which is not an
    edit (its placement still counts). So F12 keeps the playback cache, a bake (made
    from the viewport) is not outdated in its renders, and frames solved in a render
    are shown in the viewport. ``refs``: the setup's colliders."""
    return framecache.first_change(*_comparable(setup, old, new, refs))


def _comparable(setup, old, new, refs) -> tuple[dict, dict]:
    """``old`` and ``new`` without what :func:`first_change` does not compare."""
    skip = {RENDER_PART}
    # (records made before the settings were recorded per frame: ``settings`` holds them)
    skip |= {p for p in (STRUCTURE_PART, VALUES_PART) if p not in old}
    if (RENDER_PART in old) != (RENDER_PART in new):
        skip |= {f"collider {i} shape" for i, r in enumerate(refs)
                 if renders_otherwise(r.object, setup.scene)}
    return ({k: v for k, v in old.items() if k not in skip},
            {k: v for k, v in new.items() if k not in skip})
