"""What an edit drops: the cached frames after the current one, then a refresh.

Settings' update callbacks, the operators and the depsgraph check call
:func:`invalidate`; the frame rules drop frames themselves
(:meth:`registry.Runtime.drop_frames_after`). In the UI the current frame is then
evaluated again soon (:func:`schedule_refresh`: a timer, since Blender's data must not
be written from inside an update callback); timers never fire headless.
"""

from __future__ import annotations

import bpy

from . import baked, frame_rules, registry
from .dependencies import update_dependencies
from .setup import Setup


def invalidate(ob, scene, reason="", from_frame=None, colliders=False, refresh=True) -> None:
    """Drop the memory-cached frames after ``from_frame`` (default: the current frame of
    ``scene``, the scene the change was seen in).

    A baked setup's bake is not affected (it is read-only until freed); a change of
    its settings marks it outdated at once (:func:`baked.check`).
    ``colliders`` also forgets the core Colliders and updates the output's
    dependency modifier. ``refresh`` re-evaluates the current frame soon
    (interactive sessions only; never from inside the frame handler).
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
    f = scene.frame_current if from_frame is None else from_frame
    rt.drop_frames_after(f, s.frame_start)
    if colliders:
        rt.colliders.clear()
        rt.growth = None
        update_dependencies(ob)
    if refresh:
        schedule_refresh(ob.name)


def refresh_groom(ob) -> None:
    """The groom options changed: recompute the groom on the next evaluation."""
    ob = registry.source_of(ob)
    if ob is not None and ob.furcollide.is_baked:
        baked.check(ob)
    rt = registry.get_runtime(ob, create=False) if ob is not None else None
    if rt is not None:
        rt.groom_shown = None
        schedule_refresh(ob.name)


_pending_refresh: dict = {}  # object name -> timer function


def schedule_refresh(name: str) -> None:
    """Re-evaluate the current frame soon (UI only: timers need an event loop)."""
    if bpy.app.background or name in _pending_refresh:
        return

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
                    frame_rules.evaluate(Setup(ob, scene, bpy.context.evaluated_depsgraph_get()))
            except Exception as exc:  # noqa: BLE001 - a timer must never raise either
                registry.record_error(ob, exc)
        return None

    _pending_refresh[name] = refresh
    bpy.app.timers.register(refresh, first_interval=0.05)


def cancel_refreshes() -> None:
    """Unregister the pending refresh timers (the add-on is being disabled)."""
    for fn in _pending_refresh.values():
        if bpy.app.timers.is_registered(fn):
            bpy.app.timers.unregister(fn)
    _pending_refresh.clear()
