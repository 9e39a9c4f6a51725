"""Blender's handlers: thin loops over the setups that never raise into Blender.

* ``frame_change_post``: every setup of the scene runs the frame rules
  (:func:`rules.evaluate`); an error becomes the setup's status message. A setup
  whose hair is in the scene but that belongs to another scene shows its source there
  (:func:`scenes.evaluate`). Showing another scene in a window runs this handler too,
  so the outputs follow the scene shown.
* ``frame_change_pre``: the setups with children close their output's guides gate, so
  that Blender's first pass does not run the children stack on the last frame's guides
  (:func:`children.before_frame`).
  Both this and the depsgraph check first prune the registry (:func:`registry.prune`):
  a deleted source's runtime and memory cache go.
* ``depsgraph_update_post``: an edited source or collider of a setup of the scene drops
  its playback cache (:func:`invalidation.invalidate`), an update that changes nothing
  the current frame was evaluated from (the animation evaluated again) does not
  (:func:`invalidation.edit_seen`); the dependency modifiers follow the setups'
  inputs. It never writes hair data.
* ``load_post``: a new file forgets every runtime and completes the setups'
  dependency modifiers; ``save_pre`` / ``save_post`` keep relative bake paths
  pointing at the same files when the file is saved elsewhere.
* The playback cache is not saved with the file: ``save_pre`` records how many frames
  each setup had cached, and ``load_post`` has such a setup say that they are gone
  (:data:`..store.playback.NOT_SAVED`): at once, and on every frame that is not cached until
  the start frame is solved again.
* ``undo_pre`` / ``redo_pre``: a running modal bake stops first (its objects are about
  to be replaced: :func:`bake.stop_for_undo`). ``undo_post`` / ``redo_post``: the
  current frame is evaluated again soon (the outputs hold the undo step's data, the
  session's status and cache are from before it).
"""

from __future__ import annotations

import os

import bpy
from bpy.app.handlers import persistent

from ..blender import bridge
from ..blender.dependencies import dependencies_stale, update_dependencies
from ..ops import bake
from ..settings import keyed
from ..settings.fingerprints import structure, structure_change
from ..store import invalidation, playback, registry, report
from . import children, record, scenes
from .colliders import collider_objects
from .setup import Setup


@persistent
def on_frame_change_post(scene, depsgraph=None):
    """Evaluate every setup of ``scene``; never raises."""
    if registry.busy() or depsgraph is None:
        return
    with registry.handlers_held():
        try:
            registry.prune()  # a deleted source's runtime and cache go
            for ob in registry.setups(scene, owned=False):
                try:  # (another scene's setup shows its source here, never raising)
                    scenes.evaluate(ob, scene, depsgraph)
                except Exception as exc:  # noqa: BLE001 - the handler must never raise
                    report.record_error(ob, exc)
        except Exception as exc:  # noqa: BLE001 - not even while listing the setups
            print(f"FurCollide: frame handler failed: {report.describe(exc)}", flush=True)


@persistent
def on_frame_change_pre(scene, *_args):
    """The setups with children close their output's guides gate
    (:func:`children.before_frame`); never raises."""
    if registry.busy():
        return
    try:
        for ob in registry.setups(scene):
            if ob.furcollide.children.output is not None:
                children.before_frame(ob)
    except Exception as exc:  # noqa: BLE001 - the handler must never raise
        print(f"FurCollide: frame change handler failed: {report.describe(exc)}",
              flush=True)


@persistent
def on_depsgraph_update_post(scene, depsgraph=None):
    """Invalidate (never write) when colliders or the source were edited.

    In the Blender application this handler also reports the animated objects that
    the depsgraph evaluated again: when playback starts, and on a frame change before
    ``frame_change_post`` runs. Those are not edits: :func:`invalidation.edit_seen`
    compares the scene with the record of what the frame handler saw at this frame,
    and only a real change drops the playback cache.
    """
    if registry.busy() or depsgraph is None or bridge.is_render(depsgraph):
        return
    try:
        registry.prune()  # a source deleted in the UI: its runtime and cache go
        edited = set()
        for u in depsgraph.updates:
            if (u.is_updated_geometry or u.is_updated_transform) and isinstance(
                u.id, bpy.types.Object
            ):
                edited.add(u.id.original.name)
        setups = registry.setups(scene)  # (another scene's setup is never dropped here)
        if not edited and not setups:
            return
        for ob in setups:
            try:
                _check_edits(ob, scene, depsgraph, edited)
            except Exception as exc:  # noqa: BLE001 - one setup's failure stays its own
                # its status (and one console line), as a frame's error would be
                report.set_status(ob, "ERROR", "depsgraph update check failed: "
                                    f"{report.describe(exc)}")
    except Exception as exc:  # noqa: BLE001
        print(f"FurCollide: depsgraph update check failed: {exc}", flush=True)


def _check_edits(ob, scene, depsgraph, edited) -> None:
    """Drop the playback cache of the setup on ``ob`` when an input really changed."""
    if not ob.evaluated_get(depsgraph).is_evaluated:
        return  # hidden from this depsgraph: nothing to compare (as the frame handler)
    rt = registry.get_runtime(ob, create=False)
    if (rt is None or not rt.baking) and dependencies_stale(ob):
        update_dependencies(ob)  # (a no-op next time: no update loop)
    if rt is None or rt.baking or ob.furcollide.is_baked:
        return
    seen = rt.seen
    now = structure(ob, scene=scene) if seen.structure is not None else None
    if now is not None and now != seen.structure:
        why = structure_change(seen.structure, now)
        invalidation.invalidate(ob, scene, reason=why, colliders=True)
        return
    values = keyed.fingerprint(ob)
    cached = len(rt.cache.memory)
    if seen.values is not None and values != seen.values and cached:
        # A key edited (or a setting changed without an update callback): the frames
        # from the first one whose values changed are dropped, the others hold.
        invalidation.values_changed(Setup(ob, scene, depsgraph, rt))
    record.saw_values(rt, values)
    inputs = {ob.name} | {o.name for r in collider_objects(ob, scene) for o in r.objects}
    if ob.data.surface is not None:
        inputs.add(ob.data.surface.name)
    if edited & inputs and len(rt.cache.memory):
        why = invalidation.edit_seen(Setup(ob, scene, depsgraph, rt))
        if why:  # this frame's inputs changed: an edit
            invalidation.invalidate(ob, scene, reason=why)
        elif why == "":
            # This frame still holds: the animation evaluated again, or a key moved on
            # another frame. Only this frame is known to hold now; a cached frame whose
            # inputs changed in these objects is solved again from a verified one.
            playback.trust(rt, edited & inputs, scene.frame_current)


@persistent
def on_load_post(*_args):
    """A new file: forget every runtime (caches belong to the old file), and
    complete the setups' dependency modifiers (render groom outputs of older
    files, inputs changed without an update callback): without them a render
    with those inputs hidden would not see them."""
    registry.forget_all()
    try:
        for ob in bpy.data.objects:
            s = getattr(ob, "furcollide", None)
            if s is None or not s.is_setup or s.output is None:
                continue
            if s.output.furcollide.source == ob and dependencies_stale(ob):
                update_dependencies(ob)
    except Exception as exc:  # noqa: BLE001 - a handler must never raise
        print(f"FurCollide: could not update the setups' inputs: {exc}", flush=True)
    try:
        for ob in bpy.data.objects:
            s = getattr(ob, "furcollide", None)
            if s is not None and s.is_setup and s.cached_at_save > 0 and s.enabled and (
                    not s.is_baked):
                _cache_not_saved(ob)
    except Exception as exc:  # noqa: BLE001
        print(f"FurCollide: could not check the setups' playback caches: {exc}", flush=True)


def _cache_not_saved(ob) -> None:
    """``ob``'s file was saved while its setup had a playback cache, and that cache is
    not in the file: say so now (the status, one console line), and have the frames
    that are not cached say it until the start frame is solved again (the reason
    ``rules`` gives when it holds a frame is ``PlaybackCache.dropped``)."""
    s = ob.furcollide
    rt = registry.get_runtime(ob)
    if rt is None:
        return
    playback.not_saved(rt)
    n = s.cached_at_save
    report.set_status(ob, "WARNING", (
        f"The playback cache ({n} frame{'s' if n != 1 else ''}) is not saved with the "
        f"file: bake to keep the frames, or play from frame {s.frame_start}"))


def _record_playback_caches() -> None:
    """Before a save: record in each setup how many frames its playback cache holds
    (0 when baked, or when only the start frame is cached: that one is solved again
    when shown). A setup with nothing cached that has not solved its start frame since
    the file was opened keeps what the file said: its output still shows a frame of
    the cache lost then."""
    for ob in bpy.data.objects:
        s = getattr(ob, "furcollide", None)
        if s is None or not s.is_setup or ob.library is not None:
            continue
        rt = registry.get_runtime(ob, create=False)
        if s.is_baked:
            n = 0
        elif rt is None or (not len(rt.cache.memory) and rt.cache.dropped == playback.NOT_SAVED):
            continue
        else:
            memory = rt.cache.memory
            n = len(memory) if any(f > s.frame_start for f in memory.frames) else 0
        if s.cached_at_save != n:
            s.cached_at_save = n


_save_remap: dict = {}  # object name -> bake_path before save_pre rewrote it


def _relative_bake_paths():
    for ob in bpy.data.objects:
        s = getattr(ob, "furcollide", None)
        if s is not None and s.is_setup and s.bake_path.startswith("//") and ob.library is None:
            yield ob, s


@persistent
def on_save_pre(filepath="", *_args):
    """Record each setup's playback cache (:func:`_record_playback_caches`). Save As
    to another folder: keep each bake's relative path pointing at the same files
    (Blender remaps its own relative paths, not an add-on's)."""
    _save_remap.clear()
    try:
        _record_playback_caches()
    except Exception as exc:  # noqa: BLE001 - a handler must never raise
        print(f"FurCollide: could not record the playback caches: {exc}", flush=True)
    try:
        old = bpy.data.filepath
        if not old or not filepath or os.path.dirname(old) == os.path.dirname(filepath):
            return
        start = os.path.dirname(os.path.abspath(filepath))
        for ob, s in _relative_bake_paths():
            target = bpy.path.abspath(s.bake_path)
            try:
                new = "//" + os.path.relpath(target, start).replace(os.sep, "/")
            except ValueError:  # another drive (Windows): keep it absolute
                new = target
            _save_remap[ob.name] = s.bake_path
            s.bake_path = new
    except Exception as exc:  # noqa: BLE001 - a handler must never raise
        print(f"FurCollide: could not remap the bake paths: {exc}", flush=True)


@persistent
def on_save_post(filepath="", *_args):
    """A *copy* was saved (File > Save Copy: the open file keeps its path): put
    back the bake paths :func:`on_save_pre` rewrote for it."""
    try:
        if filepath and os.path.abspath(bpy.data.filepath) != os.path.abspath(filepath):
            for name, path in _save_remap.items():
                ob = bpy.data.objects.get(name)
                if ob is not None:
                    ob.furcollide.bake_path = path
    except Exception as exc:  # noqa: BLE001
        print(f"FurCollide: could not restore the bake paths: {exc}", flush=True)
    finally:
        _save_remap.clear()


@persistent
def on_undo_pre(*_args):
    """An undo or redo is about to replace Blender's data: stop the running modal
    bakes while their objects are valid (:func:`bake.stop_for_undo`)."""
    try:
        bake.stop_for_undo()
    except Exception as exc:  # noqa: BLE001 - a handler must never raise
        print(f"FurCollide: could not stop the bake before the undo: {exc}", flush=True)


@persistent
def on_undo_post(*_args):
    """After an undo or redo Blender's data is the undo step's: each output holds what
    it showed when the step was taken (at the step's frame, or a frame held then),
    while the session's status and playback cache are from before the undo. Evaluate
    the current frame of every setup again soon (:func:`invalidation.schedule_refresh`):
    a cached frame whose inputs hold is shown, anything else says why."""
    try:
        for ob in registry.setups(bpy.context.scene, owned=False):
            # (until it runs, the output holds the undo step's data: outdated)
            invalidation.schedule_refresh(ob.name, ("INFO", "Updating the frame after the undo"))
    except Exception as exc:  # noqa: BLE001 - a handler must never raise
        print(f"FurCollide: could not refresh the setups after the undo: {exc}", flush=True)


_HANDLERS = (
    ("frame_change_pre", on_frame_change_pre),
    ("frame_change_post", on_frame_change_post),
    ("depsgraph_update_post", on_depsgraph_update_post),
    ("load_post", on_load_post),
    ("save_pre", on_save_pre),
    ("save_post", on_save_post),
    ("undo_pre", on_undo_pre),
    ("redo_pre", on_undo_pre),
    ("undo_post", on_undo_post),
    ("redo_post", on_undo_post),
)


def register():
    for name, fn in _HANDLERS:
        lst = getattr(bpy.app.handlers, name)
        for h in list(lst):  # survive "Reload Scripts"
            if getattr(h, "__name__", "") == fn.__name__ and "furcollide" in getattr(
                h, "__module__", ""
            ):
                lst.remove(h)
        lst.append(fn)


def unregister():
    for name, fn in _HANDLERS:
        lst = getattr(bpy.app.handlers, name)
        if fn in lst:
            lst.remove(fn)
    invalidation.cancel_refreshes()
    registry.forget_all()
