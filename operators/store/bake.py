"""Bake and resume: solve a frame range in order and write it to disk.

A bake writes ``frame_NNNNNN.npz`` files (see :mod:`..core.framecache`) into the
setup's folder under its Cache Directory (:func:`bake_directory`). Each frame runs
the frame's spine as playback does (:func:`bake_frame`: :func:`..frame.spine.evaluate`
into :class:`ToBake`, which writes the frame's file).
Finished frames survive a cancel or a crash and the next bake resumes after the last
one whose settings match (:func:`resume_frame`) and whose inputs still hold
(:func:`resume_inputs_match`). A baked setup only reads its files until Free Bake.
:class:`BakeJob` bakes several setups of a scene in one pass over the frames; the bake
operators (:mod:`..ops.bake`) and the command line (:mod:`..ops.cli`) drive it.
"""

from __future__ import annotations

import os
import re

import bpy
import numpy as np

from ...core import framecache
from ..blender import bridge
from ..frame import children, groom, rules, solve, spine, topology
from ..frame.clock import clock
from ..frame.colliders import collider_list, keep_placements
from ..frame.inputs import read_inputs
from ..frame.record import current_inputs, first_change, fixed_change
from ..frame.setup import Setup
from ..settings import keyed, motion
from ..settings.fingerprints import core_settings, read_settings, structure
from . import playback, registry, report


def bake_directory(ob) -> str:
    """Absolute bake directory of the setup (raises ValueError if unsaved).

    A finished bake is read where it was written (``bake_path``, kept valid by Save
    As). A partial one (a failed, cancelled or crashed bake) is resumed there only
    while the Cache Directory still names that folder: once the artist points the
    Directory elsewhere (a typo fixed, the farm's share), the next Bake goes there.
    """
    s = ob.furcollide
    kept = bpy.path.abspath(s.bake_path) if s.bake_path else ""
    if kept and s.is_baked:
        return kept
    wanted = directory_from_settings(ob)
    return kept if kept and _same_path(kept, wanted) else wanted


def _same_path(a, b) -> bool:
    """Do the absolute paths ``a`` and ``b`` name the same folder (case as the OS)?"""
    return os.path.normcase(os.path.abspath(a)) == os.path.normcase(os.path.abspath(b))


def directory_from_settings(ob) -> str:
    """The bake directory the setup's Cache Directory names (raises ValueError if a
    relative Directory needs an unsaved .blend)."""
    s = ob.furcollide
    if not bpy.data.filepath and s.cache_directory.startswith("//"):
        raise ValueError(
            "Save the .blend file first: the bake cache is written next to it "
            f"('{s.cache_directory}')"
        )
    root = bpy.path.abspath(s.cache_directory)
    blend = os.path.splitext(os.path.basename(bpy.data.filepath))[0] or "untitled"
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", ob.name)
    return os.path.join(root, blend, f"{name}_{registry.ensure_uid(ob)[:8]}")


def settings_fingerprint(ob) -> str:
    """What every frame of a bake shares (:func:`fingerprints.structure`, objects by
    name): with each frame's keyable values (its record), what a bake file must match
    to be resumed from."""
    return structure(ob, stable=True)


def bake_frame(setup, directory, trust_solver) -> dict:
    """Solve the current frame ``f`` of ``setup`` for a bake and write it to ``directory``:
    the frame's spine (:func:`..frame.spine.evaluate`) into the bake (:class:`ToBake`).

    Parameters
    ----------
    setup : setup.Setup
        The setup in the baked scene, at frame ``f`` (``frame_start`` resets the solver).
    directory : str
        Absolute bake directory.
    trust_solver : bool
        The solver's state is frame ``f - 1``'s (just solved by this bake);
        otherwise that state is read from ``f - 1``'s file.

    Returns
    -------
    dict
        The frame's stats (curve counts per status, ``solve_ms``).
    """
    sink = ToBake(directory, trust_solver)
    spine.evaluate(setup, sink)
    return sink.stats


class ToBake:
    """The sink of a frame baked (:func:`bake_frame`; the spine's other sink is
    :class:`..frame.spine.Playback`): every frame is solved, from the groomed shape at
    the start frame (or enabled again), else from frame ``f - 1``'s state (the solver's,
    just solved by this bake, or read from ``f - 1``'s file); the frame goes into its
    bake file with the render groom and the children made from it."""

    #: Not the frame handler's evaluation: nothing is remembered as seen.
    sees = False

    def __init__(self, directory, trust_solver):
        self.directory = directory
        self.trust_solver = trust_solver
        self.stats = None  # the frame's statistics, once written

    def skip(self, setup):
        return None  # (a bake evaluates its frames while the frame handler keeps off)

    def attaches(self, setup) -> bool:
        return True

    def changes(self, setup, read):
        rt, inp = setup.rt, read.inputs
        layout = rt.solve.topology
        if self.trust_solver and layout is not None and layout != inp.key:
            # (frames of other curves than the frame before: no playback could show them)
            raise ValueError(topology.topology_message(setup.ob, layout, inp.key,
                                                       "baking", setup.s.frame_start))
        return rules.Changes(adopt=inp.key)

    def decide(self, setup, read):
        start = "reset" if rules.starts_here(setup, read.settings.animation) else "step"
        first = setup.frame == setup.s.frame_start
        return rules.Decision(rules.Outcome.RESET if first else rules.Outcome.STEP,
                              show="solve", start=start)

    def prepare(self, setup, read, d):
        rt, f = setup.rt, setup.frame
        solver = solve.ensure_solver(setup, read.inputs)
        if d.start == "reset":  # (the start frame, or enabled again)
            solver.reset()
        elif not self.trust_solver:
            _p, _st, offsets, stored = framecache.read_frame(self.directory, f - 1)
            if not np.array_equal(offsets, read.inputs.offsets):
                raise ValueError(f"bake frame {f - 1} was made for other curves")
            solve.restore(setup, framecache.decode_state(stored, rt.cache.memory.sparse))
        return None

    def continuous(self, setup) -> bool:
        return self.trust_solver

    def keep(self, setup, read, result, record) -> None:
        pass  # (the bake file is written with the render groom and the children)

    def stages(self, setup, outcome, shown):
        """The render groom and the children made from the guides just written: their
        parts of the bake file and statistics (None each: none)."""
        return _bake_groom(setup, shown.written), children.bake_frame(setup)

    def publish(self, setup, outcome, shown, parts) -> None:
        """Write the frame's bake file (the solver's state with the settings'
        fingerprint, the frame-inputs record, the render groom's and the children's
        parts), its statistics, and the status of INVALID curves."""
        rt, f, result = setup.rt, setup.frame, shown.result
        stats = dict(result.stats, source="bake")
        extra = {}
        for name, part in zip((groom.BAKE_PART, children.BAKE_PART), parts, strict=True):
            if part is not None:
                extra[name] = part[0]
                stats.update(part[1])
        state = rt.solve.solver.state
        state["fingerprint"] = np.frombuffer(settings_fingerprint(setup.ob).encode(), np.uint8)
        framecache.write_frame(self.directory, f, result.points, result.status,
                               shown.read.inputs.offsets, state, rt.cache.memory.sparse,
                               result.attributes, inputs=shown.record, extra=extra)
        self.stats = dict(stats, **clock.stats())
        invalid = rt.report.invalid_note
        report.publish(setup.ob, rt, invalid, stats=self.stats)

    def failed(self, setup) -> None:
        pass  # (the frames baked before are kept; the bake reports the error)


def _bake_groom(setup, guides_world):
    """The render groom's arrays for the frame's bake file (None: no render groom, or
    it failed: then it is computed on every frame shown, and the console says why)."""
    try:
        return groom.bake_frame(setup, guides_world)
    except Exception as exc:  # noqa: BLE001 - the guides are baked all the same
        print(f"FurCollide bake '{setup.ob.name}': frame {setup.frame}: render groom not "
              f"baked: {report.describe(exc)}", flush=True)
        return None


def varying_source(ob, scene) -> str:
    """The status of a source whose curves differ between Frame Start and the next
    frame (:func:`topology.topology_message`), '' when they do not. Looked at only
    when a modifier of the source scatters its curves without the Surface's rest
    position: Bake refuses such a source before writing a frame playback cannot show."""
    s = ob.furcollide
    f0 = s.frame_start
    if f0 >= s.frame_end or not topology.unrested(ob):
        return ""
    back = (scene.frame_current, scene.frame_subframe)
    keys = []
    with registry.handlers_held():  # (a look at two frames: nothing solved)
        for f in (f0, f0 + 1):
            scene.frame_set(f)
            oe = ob.evaluated_get(scene_depsgraph(scene))
            keys.append(framecache.topology_key(bridge.curve_offsets(oe.data)))
    if keys[0] == keys[1]:
        return ""
    scene.frame_set(back[0], subframe=back[1])  # (the frame shown again, as it was)
    return topology.topology_message(ob, keys[0], keys[1], "baking", f0)


def scene_depsgraph(scene):
    """The evaluated depsgraph of ``scene`` (the context's one when it is the
    context scene; else its first view layer's, brought up to date): the CLI's
    ``--scene`` may name a scene no window shows."""
    if scene == bpy.context.scene:
        return bpy.context.evaluated_depsgraph_get()
    depsgraph = scene.view_layers[0].depsgraph
    depsgraph.update()
    return depsgraph


def resume_inputs_match(ob, directory, f, scene) -> bool:
    """Are frame ``f``'s inputs (source, colliders, surface, settings) what the
    partial bake solved at ``f`` (its frame-inputs record)? An edited collider or
    source means starting over: the settings fingerprint does not see geometry."""
    with registry.handlers_held():  # no live solve while looking
        scene.frame_set(f)
        setup = Setup(ob, scene, scene_depsgraph(scene))
        old = framecache.read_inputs(directory, f)
        if old is None:  # baked before FurCollide stored the record: start over
            return False
        read = read_settings(ob, scene)
        now = current_inputs(setup, read_inputs(setup, attach=False), read, like=old)
        return first_change(setup, old, now, read.refs) is None


def resume_frame(ob, directory) -> int | None:
    """Last frame of a contiguous, matching partial bake (None: start over)."""
    s = ob.furcollide
    if motion.values(s.motion).needs_history:
        return None  # jiggle needs the roots of every frame since the start: start over
    have = set(framecache.list_frames(directory))
    fp = settings_fingerprint(ob)
    setup = Setup(ob, bpy.context.scene, None)
    read = read_settings(ob, setup.scene)
    last = None
    f = s.frame_start
    while f in have and f <= s.frame_end:
        try:
            with np.load(framecache.frame_path(directory, f), allow_pickle=False) as z:
                key = next((k for k in z.files if k.endswith("__fingerprint")), None)
                ok = key is not None and z[key].tobytes().decode() == fp
            # (the keyable values at f: a key edited since the bake changes them there)
            ok = ok and not fixed_change(setup, framecache.read_inputs(directory, f), read, f)
        except framecache.UNREADABLE:
            ok = False
        if not ok:
            break
        last = f
        f += 1
    return last


def _follows(ob) -> bool:
    """Does the setup use Follow Collider Motion at any frame (on, keyed or driven)?"""
    return bool(ob.furcollide.follow_collider_motion) or keyed.Animation(ob).animates(
        "furcollide.follow_collider_motion")


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
        #: Why the bake was stopped from outside (:meth:`stop`: an undo), '' while not.
        self.stopped = ""
        #: The setups' runtimes (session objects, valid when Blender's data is not:
        #: :meth:`finish` clears their ``baking`` flag through them).
        self.runtimes = []
        for ob in sources:
            s = ob.furcollide
            if not registry.belongs(ob, scene):  # (its hair is in this scene too)
                raise BakeError(registry.refusal_in(ob, scene)
                                or f"'{ob.name}' is not in scene '{scene.name}'")
            if s.output is None:
                raise BakeError(f"'{ob.name}': the output hair object is missing")
            try:
                core_settings(ob)
            except ValueError as exc:
                raise BakeError(f"'{ob.name}': {exc}") from None
            try:
                directory = bake_directory(ob)
            except ValueError as exc:
                raise BakeError(str(exc)) from None
            old = bpy.path.abspath(s.bake_path) if s.bake_path else ""
            if old and not _same_path(old, directory) and verbose:
                print(f"FurCollide bake '{ob.name}': the Cache Directory changed since the "
                      f"partial bake in '{old}': baking into '{directory}' (the old folder "
                      "is left as it is)", flush=True)
            why = varying_source(ob, scene)
            if why:
                raise BakeError(f"'{ob.name}': {why}")
            last = resume_frame(ob, directory)
            if last is not None and not resume_inputs_match(ob, directory, last, scene):
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
        self.first = min(j[2] - (j[2] > j[0].furcollide.frame_start and _follows(j[0]))
                         for j in self.jobs)
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
            registry.adopt(ob, scene)  # (a setup of an older file: baked here, it is ours)
            rt = registry.get_runtime(ob)
            rt.baking = True
            self.runtimes.append(rt)

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
        depsgraph = scene_depsgraph(self.scene)
        for job in self.jobs:
            ob, directory, nxt, last = job
            s = ob.furcollide
            if f == nxt - 1 and _follows(ob):
                # The frame before a resumed one: only where its colliders are (Follow
                # Collider Motion takes their motion since this frame, as playback does).
                setup = Setup(ob, self.scene, depsgraph)
                collider_list(setup)
                keep_placements(setup)
                continue
            if f < nxt or f > s.frame_end:
                continue
            try:
                st = bake_frame(Setup(ob, self.scene, depsgraph), directory,
                                trust_solver=(last == f - 1))
            except Exception as exc:  # noqa: BLE001 - becomes a report
                kept = (f"frames {s.frame_start}-{f - 1} are kept; bake again to resume"
                        if f > s.frame_start else "no frame was written")
                raise BakeError(f"'{ob.name}' frame {f}: {report.describe(exc)} ({kept})"
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

    def finish(self, cancelled=False, restore_frame=True) -> list:
        """Mark finished setups baked, restore the frame (``restore_frame``); returns the
        baked sources."""
        for rt in self.runtimes:  # first, and without Blender's data: never left baking
            rt.baking = False
        baked = []
        for ob, directory, _nxt, _last in self.jobs:
            rt = registry.get_runtime(ob)
            s = ob.furcollide
            have = set(framecache.list_frames(directory))
            complete = all(f in have for f in range(s.frame_start, s.frame_end + 1))
            if complete and not cancelled:
                s.is_baked = True
                playback.forget(rt)
                baked.append(ob)
        if restore_frame:
            f, sub = self.orig_frame
            self.scene.frame_set(f, subframe=sub)
        return baked

    def stop(self, why: str) -> None:
        """Stop the bake now, as Esc does (the finished frames are kept, nothing is
        marked baked), because of ``why``; the frame is left as it is. An undo calls it
        before it replaces Blender's data (:func:`ops.bake.stop_for_undo`): the frame
        it goes back to is the undo step's."""
        if not self.stopped:
            self.stopped = why
            self.finish(cancelled=True, restore_frame=False)


def bake_sharers(ob) -> list:
    """Other setups whose bake is in ``ob``'s bake directory (a copy of a baked
    setup: Shift-D, a full copy of the scene) by name."""
    path = ob.furcollide.bake_path
    if not path:
        return []
    d = bpy.path.abspath(path)
    return [
        o.name for o in bpy.data.objects
        if o != ob and getattr(o, "furcollide", None) is not None and o.furcollide.is_setup
        and o.furcollide.bake_path and _same_path(bpy.path.abspath(o.furcollide.bake_path), d)
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
    registry.clear_runtime(ob)
    return n
