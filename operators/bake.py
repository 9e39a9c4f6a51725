"""Bake operators: solve a frame range in order and write it to disk.

A bake writes ``frame_NNNNNN.npz`` files (see :mod:`..core.framecache`) into the
setup's folder under its Cache Directory. Finished frames survive a cancel
or a crash and the next bake resumes after the last one whose settings
match. A baked setup only reads its files until Free Bake.

Interactive runs are modal (one frame per timer tick, progress in the
cursor and status bar, Esc cancels); background runs and tests use the
synchronous ``execute`` and print one line per frame.
"""

from __future__ import annotations

import os

import bpy
from bpy.types import Operator

from ..core import framecache
from . import runtime
from .setup import (
    SetupOperator,
    active_setup,
    backend_message,
    refresh,
    refuse,
    reports_errors,
)

#: Running interactive bakes: scene name -> (frames done, total). Drawn by the panel.
PROGRESS: dict = {}


class BakeError(RuntimeError):
    """A bake could not start or a frame failed (message is user-facing)."""


class BakeJob:
    """Bake several setups of one scene in a single pass over the frames.

    Parameters
    ----------
    scene : bpy.types.Scene
    sources : list of bpy.types.Object
        Setup source objects (not baked yet).
    verbose : bool
        Print one line per frame (background runs).
    """

    def __init__(self, scene, sources, verbose=False):
        self.scene = scene
        self.verbose = verbose
        self.jobs = []  # [source, directory, next_frame, last_solved]
        self.orig_frame = (scene.frame_current, scene.frame_subframe)
        self.errors = []
        self.frames_done = 0
        self.skipped = []
        for ob in sources:
            s = ob.furcollide
            if s.output is None:
                raise BakeError(f"'{ob.name}': the output hair object is missing")
            try:
                runtime.core_settings(ob)
            except ValueError as exc:
                raise BakeError(f"'{ob.name}': {exc}") from None
            try:
                directory = runtime.bake_directory(ob)
            except ValueError as exc:
                raise BakeError(str(exc)) from None
            last = runtime.resume_frame(ob, directory)
            if last is not None and not runtime.resume_inputs_match(ob, directory, last, scene):
                if verbose:
                    print(
                        f"FurCollide bake '{ob.name}': the source or a collider changed since "
                        f"the partial bake (frame {last}): starting over",
                        flush=True,
                    )
                last = None
            nxt = s.frame_start if last is None else last + 1
            self.jobs.append([ob, directory, nxt, None])
        if not self.jobs:
            raise BakeError("Nothing to bake")
        self.first = min(j[2] for j in self.jobs)
        self.last = max(j[0].furcollide.frame_end for j in self.jobs)
        self.frame = self.first
        for ob, directory, nxt, _ in self.jobs:
            s = ob.furcollide
            try:
                s.bake_path = bpy.path.relpath(directory) if bpy.data.filepath else directory
            except ValueError:  # other drive on Windows
                s.bake_path = directory
            if nxt > s.frame_start and self.verbose:
                print(f"FurCollide bake '{ob.name}': resuming after frame {nxt - 1}", flush=True)
            runtime.get_runtime(ob).baking = True

    @property
    def total(self) -> int:
        return max(0, self.last - self.first + 1)

    @property
    def done(self) -> bool:
        return self.frame > self.last

    def step(self) -> None:
        """Bake the next frame of every setup that needs it (raises BakeError)."""
        f = self.frame
        self.scene.frame_set(f)
        depsgraph = runtime.scene_depsgraph(self.scene)
        for job in self.jobs:
            ob, directory, nxt, last = job
            s = ob.furcollide
            if f < nxt or f > s.frame_end:
                continue
            try:
                st = runtime.bake_frame(
                    self.scene, depsgraph, ob, f, directory, trust_solver=(last == f - 1)
                )
            except Exception as exc:  # noqa: BLE001 - becomes a report
                raise BakeError(
                    f"'{ob.name}' frame {f}: {runtime.describe(exc)} (frames before {f} "
                    f"are kept; bake again to resume)"
                ) from exc
            job[3] = f
            if self.verbose:
                print(
                    f"FurCollide bake '{ob.name}': frame {f} "
                    f"({f - self.first + 1}/{self.total}) colliding {st['colliding']}, "
                    f"pinched {st['pinched']}, unresolved {st['unresolved']}, "
                    f"{st['solve_ms']:.1f} ms",
                    flush=True,
                )
        self.frames_done += 1
        self.frame += 1

    def run(self) -> list:
        """Bake every frame now; returns the baked sources.

        A failed frame keeps every finished frame (the next bake resumes)
        and re-raises its :class:`BakeError`.
        """
        try:
            while not self.done:
                self.step()
        except BakeError:
            self.finish(cancelled=True)
            raise
        return self.finish()

    def finish(self, cancelled=False) -> list:
        """Mark finished setups baked, restore the frame; returns the baked sources."""
        baked = []
        for ob, directory, _nxt, _last in self.jobs:
            rt = runtime.get_runtime(ob)
            rt.baking = False
            s = ob.furcollide
            have = set(framecache.list_frames(directory))
            complete = all(f in have for f in range(s.frame_start, s.frame_end + 1))
            if complete and not cancelled:
                s.is_baked = True
                rt.memory.clear()
                rt.hold = None
                baked.append(ob)
        f, sub = self.orig_frame
        self.scene.frame_set(f, subframe=sub)
        return baked


def _bakeable(context):
    return [
        ob
        for ob in runtime.setups(context.scene)
        if not ob.furcollide.is_baked and ob.furcollide.enabled
    ]


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
            self.report({"ERROR"}, runtime.describe(exc))
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
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        job = self._job
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
            self.report({"ERROR"}, runtime.describe(exc))
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
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        return self._job.finish(cancelled=cancelled)


class FURCOLLIDE_OT_bake(_BakeBase, SetupOperator, Operator):
    """Solve the setup's frame range in order and write it to the disk cache next to the
    saved .blend file. A cancelled or crashed bake resumes from its last finished frame"""

    bl_idname = "furcollide.bake"
    bl_label = "Bake"
    bl_options = {"REGISTER"}

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
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if context.scene is None or not _bakeable(context):
            return refuse(cls, "No unbaked FurCollide setup in this scene")
        msg = backend_message()
        return refuse(cls, msg) if msg else True

    def sources(self, context):
        return _bakeable(context)


def bake_sharers(ob) -> list:
    """Other setups whose bake is in ``ob``'s bake directory (a copy of a baked
    setup: Shift-D, a full copy of the scene) by name."""
    path = ob.furcollide.bake_path
    if not path:
        return []
    d = os.path.normcase(os.path.abspath(bpy.path.abspath(path)))
    return [
        o.name for o in bpy.data.objects
        if o != ob and getattr(o, "furcollide", None) is not None and o.furcollide.is_setup
        and o.furcollide.bake_path
        and os.path.normcase(os.path.abspath(bpy.path.abspath(o.furcollide.bake_path))) == d
    ]


def free_bake(ob) -> int:
    """Delete the bake files of the setup on ``ob``; returns how many. Files another
    setup also reads (:func:`bake_sharers`) are kept: only ``ob`` forgets them."""
    s = ob.furcollide
    n = 0
    if s.bake_path and not bake_sharers(ob):
        n = framecache.remove_frames(bpy.path.abspath(s.bake_path))
    s.is_baked = False
    s.bake_path = ""
    runtime.clear_runtime(ob)
    return n


def _has_bake(ob) -> bool:
    s = ob.furcollide
    return bool(s.is_baked or s.bake_path)


class FURCOLLIDE_OT_free_bake(SetupOperator, Operator):
    """Delete this setup's bake files (only the files FurCollide wrote) so it can be
    changed and simulated again"""

    bl_idname = "furcollide.free_bake"
    bl_label = "Free Bake"
    bl_options = {"REGISTER"}

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
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if context.scene is None or not any(_has_bake(o) for o in runtime.setups(context.scene)):
            return refuse(cls, "No baked FurCollide setup in this scene")
        return True

    @reports_errors
    def execute(self, context):
        n = 0
        names = []
        for ob in runtime.setups(context.scene):
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
