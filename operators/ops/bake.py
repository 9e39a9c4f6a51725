"""Bake operators: Bake, Bake All, Free Bake, Free All Bakes (the work is in :mod:`..store.bake`).

Interactive runs are modal (one frame per timer tick, progress in the
cursor and status bar, Esc cancels); background runs and tests use the
synchronous ``execute`` and print one line per frame.
"""

from __future__ import annotations

import bpy
from bpy.types import Operator

from ..store import registry, report
from ..store.bake import BakeError, BakeJob, bake_sharers, free_bake
from .common import SetupOperator, active_setup, backend_message, refresh, refuse, reports_errors

#: Running interactive bakes: scene name -> (frames done, total). Drawn by the panel.
PROGRESS: dict = {}
#: The jobs of the running interactive bakes (:func:`stop_for_undo` stops them).
RUNNING: set = set()
#: Why a bake stopped by an undo says so.
STOPPED_BY_UNDO = "Undo stopped the bake"


def stop_for_undo() -> None:
    """Undo or redo is about to replace Blender's data: stop every running modal bake
    now, while its objects are still valid, as Blender stops its own jobs (the finished
    frames are kept, as after Esc). The operator ends on its next event
    (:meth:`_BakeBase.modal`). Left running, its next step met the replaced objects
    (ReferenceError) and the setup stayed 'baking': never evaluated again."""
    for job in list(RUNNING):
        RUNNING.discard(job)
        job.stop(STOPPED_BY_UNDO)
        PROGRESS.pop(job.scene.name, None)  # (the panel drawn after the undo)


def _bakeable(context):
    return [
        ob
        for ob in registry.setups(context.scene)
        if not ob.furcollide.is_baked and ob.furcollide.enabled
    ]


def _elsewhere(scene) -> str:
    """' (Fur is set up in scene 'A')' for the setups whose hair is in ``scene`` but
    that belong to another scene (Bake All and Free All leave them), else ''."""
    own = set(registry.setups(scene))
    where = [f"'{ob.name}' is set up in scene '{registry.owner(ob, prefer=scene).name}'"
             for ob in registry.setups(scene, owned=False) if ob not in own]
    return f" ({'; '.join(where)})" if where else ""


class _BakeBase:
    """Shared modal/synchronous driver of the two bake operators."""

    _job = None
    _timer = None

    def sources(self, context):  # pragma: no cover - overridden
        raise NotImplementedError

    def _start(self, context, verbose):
        try:
            self._job = BakeJob(context.scene, self.sources(context), verbose=verbose)
        except Exception as exc:  # noqa: BLE001 - BakeError or unexpected: a report
            self.report({"ERROR"}, report.describe(exc))
            return False
        return True

    @reports_errors
    def execute(self, context):
        if not self._start(context, verbose=True):
            return {"CANCELLED"}
        job = self._job
        try:
            baked = job.run()
        except BakeError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        unfinished = [ob.name for ob, *_ in job.jobs if ob not in baked]
        if unfinished:  # (never expected: a frame file that cannot be found again)
            self.report({"ERROR"}, f"FurCollide: the bake of {', '.join(unfinished)} is "
                        "incomplete: frame files are missing after baking")
            return {"CANCELLED"}
        self.report(
            {"INFO"},
            f"FurCollide: baked {', '.join(o.name for o in baked)} "
            f"({job.frames_done} frames solved)",
        )
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        if not self._start(context, verbose=False):
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.0, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, max(1, self._job.total))
        RUNNING.add(self._job)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        job = self._job
        if job.stopped:  # by an undo: its objects may be gone, touch none of them
            self._end(context, cancelled=True)
            self.report({"WARNING"}, f"FurCollide: {job.stopped} at frame {job.frame}: "
                        "finished frames kept")
            return {"CANCELLED"}
        if event.type == "ESC":
            self._end(context, cancelled=True)
            self.report({"WARNING"}, f"Bake cancelled at frame {job.frame}: finished frames kept")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            job.step()
        except Exception as exc:  # noqa: BLE001 - BakeError or unexpected: a report
            self._end(context, cancelled=True)
            self.report({"ERROR"}, report.describe(exc))
            return {"CANCELLED"}
        context.window_manager.progress_update(job.frames_done)
        PROGRESS[context.scene.name] = (job.frames_done, max(1, job.total))
        for area in context.screen.areas if context.screen else ():
            if area.type == "VIEW_3D":
                area.tag_redraw()
        if context.workspace is not None:
            context.workspace.status_text_set(
                f"FurCollide: baking frame {job.frame - 1} of {job.last} (Esc to cancel)"
            )
        if job.done:
            baked = self._end(context, cancelled=False)
            self.report({"INFO"}, f"FurCollide: baked {', '.join(o.name for o in baked)}")
            return {"FINISHED"}
        return {"RUNNING_MODAL"}

    def _end(self, context, cancelled):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        PROGRESS.pop(context.scene.name, None)
        RUNNING.discard(self._job)
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        if self._job.stopped:  # finished already, before the undo
            return []
        return self._job.finish(cancelled=cancelled)


class FURCOLLIDE_OT_bake(_BakeBase, SetupOperator, Operator):
    """Solve the setup's frame range in order and write it to the disk cache next to the
    saved .blend file. A cancelled or crashed bake resumes from its last finished frame"""

    bl_idname = "furcollide.bake"
    bl_label = "Bake"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        if src.furcollide.is_baked:
            return "Already baked: Free Bake first"
        if not src.furcollide.enabled:
            return "The setup is disabled: enable it to bake"
        return backend_message()

    def sources(self, context):
        return [active_setup(context)]


class FURCOLLIDE_OT_bake_all(_BakeBase, Operator):
    """Bake every FurCollide setup of the scene that is not baked yet"""

    bl_idname = "furcollide.bake_all"
    bl_label = "Bake All"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if context.scene is None:
            return refuse(cls, "No unbaked FurCollide setup in this scene")
        if not _bakeable(context):
            return refuse(cls, "No unbaked FurCollide setup in this scene"
                          + _elsewhere(context.scene))
        msg = backend_message()
        return refuse(cls, msg) if msg else True

    def sources(self, context):
        return _bakeable(context)


def _has_bake(ob) -> bool:
    s = ob.furcollide
    return bool(s.is_baked or s.bake_path)


class FURCOLLIDE_OT_free_bake(SetupOperator, Operator):
    """Delete this setup's bake files (only the files FurCollide wrote) so it can be
    changed and simulated again"""

    bl_idname = "furcollide.free_bake"
    bl_label = "Free Bake"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        return "" if _has_bake(src) else "Nothing baked"

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        sharers = bake_sharers(src)
        n = free_bake(src)
        refresh(context)
        kept = f"; its files are kept: {', '.join(sharers)} reads them too" if sharers else ""
        self.report({"INFO"}, f"FurCollide: freed the bake of '{src.name}' ({n} files){kept}")
        return {"FINISHED"}


class FURCOLLIDE_OT_free_bake_all(Operator):
    """Delete the bake files of every FurCollide setup in the scene"""

    bl_idname = "furcollide.free_bake_all"
    bl_label = "Free All Bakes"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if context.scene is None:
            return refuse(cls, "No baked FurCollide setup in this scene")
        if not any(_has_bake(o) for o in registry.setups(context.scene)):
            return refuse(cls, "No baked FurCollide setup in this scene"
                          + _elsewhere(context.scene))
        return True

    @reports_errors
    def execute(self, context):
        n = 0
        names = []
        for ob in registry.setups(context.scene):
            if _has_bake(ob):
                n += free_bake(ob)
                names.append(ob.name)
        refresh(context)
        self.report({"INFO"}, f"FurCollide: freed {', '.join(names)} ({n} files)")
        return {"FINISHED"}


classes = (
    FURCOLLIDE_OT_bake,
    FURCOLLIDE_OT_bake_all,
    FURCOLLIDE_OT_free_bake,
    FURCOLLIDE_OT_free_bake_all,
)
