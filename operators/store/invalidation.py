"""What an edit drops: the playback cache (as Blender's point cache), then a refresh.

Settings' update callbacks, the operators and the depsgraph check call
:func:`invalidate`; the depsgraph check first asks :func:`edit_seen` whether an update
really changed an input (the animation evaluated again is not an edit). The frame rules
drop frames themselves (:meth:`registry.Runtime.drop_cache`). In the UI the current frame is then
evaluated again soon (:func:`schedule_refresh`: a timer, since Blender's data must not
be written from inside an update callback); timers never fire headless.
"""

from __future__ import annotations

import bpy

from ..blender.dependencies import update_dependencies
from ..frame import rules, scenes
from ..frame.colliders import forget as forget_colliders
from ..frame.inputs import read_inputs
from ..frame.record import (
    STRUCTURE_PART,
    VALUES_PART,
    change,
    current_inputs,
    first_changed_frame,
    last_seen,
    saw,
    saw_values,
)
from ..frame.setup import Setup
from ..settings.fingerprints import read_settings
from . import baked, playback, registry, report


def invalidate(ob, scene, reason="", from_frame=None, colliders=False, refresh=True,
               values=False) -> None:
    """Drop the setup's unbaked playback cache after a change, like Blender's point cache.

    Every cached frame goes (a change of a setting, of the colliders or of an input
    changes what every frame is solved from): the frames shown next are solved again
    from the start frame on and, until then, the setup is outdated and each frame that is
    not cached says ``reason`` (e.g. "the settings changed"). Only ``from_frame`` at or
    after the start frame keeps the frames up to it (a shorter frame range), and
    ``values`` (a setting that can be keyed changed) keeps the frames before the first
    one whose values changed (:func:`values_changed`: with a keyed setting, often all
    but the current frame and those after it).

    A baked setup's bake is not affected (it is read-only until freed; a baked frame
    whose inputs changed is marked outdated when shown); a change of its settings marks
    it outdated at once (:func:`baked.check`). ``colliders`` also forgets the
    core Colliders and updates the output's dependency modifier. ``refresh``
    re-evaluates the current frame soon (interactive sessions only; never from inside
    the frame handler).
    """
    ob = registry.source_of(ob)
    if ob is None:
        return
    if ob.furcollide.is_baked:
        baked.check(ob, scene)
    rt = registry.get_runtime(ob, create=False)
    if rt is None:  # nothing cached (a file just opened), but the inputs may have changed
        if colliders:
            update_dependencies(ob)
        return
    s = ob.furcollide
    if values and from_frame is None:
        values_changed(Setup(ob, scene, None, rt))
        saw_values(rt, None)
    elif from_frame is not None and from_frame >= s.frame_start:
        playback.drop_after(rt, from_frame, s.frame_start)
    elif playback.drop_cache(rt, reason, s.frame_start, scene.frame_current) and (
            not s.is_baked):
        f = scene.frame_current
        if s.enabled and s.frame_start <= f:  # the output shows a result solved before
            report.mark_outdated(rt)
            if f > s.frame_start:  # (the start frame is solved again when shown)
                report.set_status(ob, "WARNING",
                                  rules.dropped_message(f, reason, s.frame_start))
    if colliders:
        forget_colliders(rt)
        update_dependencies(ob)
    if refresh:
        schedule_refresh(ob.name)


def values_changed(setup) -> None:
    """The setup's keyable values may have changed (a key edited, a setting changed):
    drop the cached frames from the first one whose values changed
    (:func:`..frame.record.first_changed_frame`), keep the others, and say so when the
    frame shown is one of the dropped ones; refresh the current frame."""
    s, rt, f = setup.s, setup.rt, setup.frame
    memory = rt.cache.memory
    changed = first_changed_frame(setup, memory.frames, read_settings(setup.ob, setup.scene))
    if changed is None:
        return
    first, why = changed
    playback.drop_from(rt, first, why, s.frame_start, f)
    if s.is_baked:
        return
    if s.enabled and first <= f and f > s.frame_start:
        report.mark_outdated(rt)
        k = memory.newest_before(f)
        resume = k if first > s.frame_start and k is not None and (
            memory.frames[k].state is not None) else None
        report.set_status(setup.ob, "WARNING",
                          rules.dropped_message(f, why, s.frame_start, resume))
    schedule_refresh(setup.ob.name)


def edit_seen(setup) -> str | None:
    """What changed in the setup's inputs since the frame handler evaluated the scene's
    current frame, in words; '' when nothing did; None when the frame handler has not
    evaluated this frame (a frame change under way: it checks the frame itself).

    The depsgraph reports every object it evaluated again, and in the Blender
    application that includes the animation: when playback starts, and on a frame
    change before ``frame_change_post`` runs. Those are not edits: the frame's record
    of inputs (:func:`..frame.record.current_inputs`) is still the one the frame handler
    saw.
    """
    rt = setup.rt
    old = last_seen(rt, setup.scene, setup.frame)
    if old is None:
        return None
    read = read_settings(setup.ob, setup.scene)
    new = current_inputs(setup, read_inputs(setup, attach=False), read)  # (the record only)
    saw(rt, setup.scene, setup.frame, new)
    if VALUES_PART in old:
        # The settings (their values, and what derives from them) are checked by
        # values_changed, frame by frame: only the objects are compared here.
        skip = (STRUCTURE_PART, VALUES_PART, "settings", "colliders")
        old, new = ({k: v for k, v in r.items() if k not in skip} for r in (old, new))
    return change(setup, old, new, read.refs)


def refresh_groom(ob) -> None:
    """The groom options changed: recompute the groom on the next evaluation."""
    ob = registry.source_of(ob)
    if ob is not None and ob.furcollide.is_baked:
        baked.check(ob)
    rt = registry.get_runtime(ob, create=False) if ob is not None else None
    if rt is not None:
        schedule_refresh(ob.name)


_pending_refresh: dict = {}  # object name -> timer function


def schedule_refresh(name: str, status: tuple | None = None) -> None:
    """Re-evaluate the current frame of the setup on object ``name`` soon (UI only:
    timers need an event loop). Until then the frame shown is marked outdated (it is
    not known to be current: an edit or an undo happened since it was shown), with
    ``status`` ``(level, message)`` when given; the refresh sets the frame's own."""
    if bpy.app.background:
        return
    ob = bpy.data.objects.get(name)
    rt = registry.get_runtime(ob, create=False) if ob is not None else None
    if rt is not None:
        report.publish(ob, rt, status, outdated=True)
    pending = _pending_refresh.get(name)
    if pending is not None and bpy.app.timers.is_registered(pending):
        return
    # (Opening a file removes the timers registered before: one pending then never
    # runs, and must not keep this object from being refreshed for the session.)

    def refresh():
        if registry.busy():
            return 0.1  # the frame handler is running: try again soon
        _pending_refresh.pop(name, None)
        ob = None
        with registry.handlers_held():
            try:
                ob = bpy.data.objects.get(name)
                scene = bpy.context.scene
                if ob is not None and scene is not None and ob.furcollide.is_setup:
                    # (shown as groomed where the setup is not the scene's: scenes)
                    scenes.evaluate(ob, scene, bpy.context.evaluated_depsgraph_get())
            except Exception as exc:  # noqa: BLE001 - a timer must never raise either
                report.record_error(ob, exc)
        return None

    _pending_refresh[name] = refresh
    bpy.app.timers.register(refresh, first_interval=0.05)


def cancel_refreshes() -> None:
    """Unregister the pending refresh timers (the add-on is being disabled)."""
    for fn in _pending_refresh.values():
        if bpy.app.timers.is_registered(fn):
            bpy.app.timers.unregister(fn)
    _pending_refresh.clear()
