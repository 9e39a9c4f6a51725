"""The frame rules: what the frame handler does with a setup at a frame.

Frame rules (``frame_change_post``; see README "Using it in Blender"):

* subframes (motion blur) never step: the output keeps the whole frame (a bake
  blends its two neighbouring baked frames);
* ``f == frame_start``: reset the solver and solve;
* ``f`` cached (memory, or disk when baked) and its inputs still hold: show it, bit
  for bit; its inputs changed: solve it again at the start frame; solve it again from
  ``f - 1`` when only objects the depsgraph reported while an earlier frame held
  changed (a key moved ahead: :func:`_key_moved_ahead`); else mark the setup outdated
  and drop the playback cache;
* ``f - 1`` cached with today's settings and colliders: restore its solver state if
  needed and step (other settings: the playback cache is dropped, as any change does);
* otherwise (jump ahead, a dropped cache): hold the newest cached frame, mark outdated;
* ``f < frame_start``: the output follows the source; ``f > frame_end``:
  the end frame is held.

:func:`evaluate` reads one frame top to bottom: the output checks, the inputs
(:mod:`.inputs`), the rule that applies, the solve (:func:`solve.solve_frame`)
or the cached frame, the write (:mod:`.output`), then the render groom stage
(:mod:`.groom`) and the children stage (:mod:`.children`). It returns an
:class:`Outcome`. It raises on errors; the handler
(:mod:`.handlers`) turns them into the setup's status message plus one console line,
and the output keeps its last good result.
"""

from __future__ import annotations

import enum
import os

import bpy
import numpy as np

from ...core import framecache
from ...core.pipeline.frame import frame_stats
from ..blender import bridge
from ..settings import keyed
from ..settings.fingerprints import structure_change
from ..store import baked
from . import children, groom, output, solve, topology
from .clock import clock
from .colliders import collider_note, read_for_solve, surface_as_collider
from .inputs import FrameInputs, prepare_input, read_inputs, shown
from .record import (
    baked_frame_change,
    cached_frame_change,
    changed_objects,
    first_changed_frame,
    fixed_change,
    saw,
    seen_inputs,
    solved_inputs,
)


class Outcome(enum.Enum):
    """What :func:`evaluate` did with a setup's frame."""

    RESET = "reset"  #: the start frame, solved from the groomed shape
    STEP = "step"  #: solved one step from the previous frame's state
    CACHE = "cache"  #: a memory-cached frame shown
    BAKE = "bake"  #: a baked frame shown (or the newest one before it, when missing)
    HOLD = "hold"  #: after the end frame: the end frame held
    OUTDATED = "outdated"  #: not solvable (jump ahead, changed inputs): a frame held
    PASSTHROUGH = "passthrough"  #: disabled or before the start: the output follows
    SUBFRAME = "subframe"  #: a motion-blur subframe (never steps; a bake blends)
    TOPOLOGY = "topology"  #: the source's curves changed: nothing written
    BAKING = "baking"  #: this setup's bake is running (it writes the frames)
    HIDDEN = "hidden"  #: no output of the setup is in this depsgraph


def evaluate(setup) -> Outcome:
    """Run the frame rules (module docstring) for ``setup``, then the render groom and
    children stages.

    Raises
    ------
    Exception
        Any error; the frame handler turns it into the status message, the bake into
        a report. A render groom error only warns (the guides are written).
    """
    clock.start()
    try:
        outcome, written = _rules(setup)
    except Exception:
        groom.follow_last_guides(setup)  # (never raises)
        children.run(setup)  # (never raises: the children follow the output)
        raise
    if setup.s.groom.output is not None and (
        written is not None or outcome in (Outcome.TOPOLOGY, Outcome.OUTDATED)
    ):  # (None: the groom follows the last good guides)
        try:
            groom.run(setup, written)
        except Exception as exc:  # noqa: BLE001 - the guides are written: only warn
            setup.set_status("WARNING", groom.error_message(exc, setup))
    if outcome not in (Outcome.HIDDEN, Outcome.BAKING):
        children.run(setup)  # (never raises)
    setup.rt.stats = dict(setup.rt.stats, **clock.stats())
    return outcome


def _rules(setup):
    """(Outcome, the world points written into the output or None), rule by rule."""
    skipped = _not_evaluated(setup)
    if skipped is not None:
        return skipped
    setup.rt.seen = None
    inp = _read_frame(setup)
    if inp is None:
        return Outcome.TOPOLOGY, None
    outcome, written = _frame_rules(setup, inp)
    if setup.rt.seen is None and outcome is not Outcome.BAKE:
        # What this frame was evaluated from (solved and cached frames made it already):
        # the depsgraph check tells an edit from the animation evaluated again with it.
        seen_inputs(setup, inp)
    return outcome, written


def _passes_through(setup) -> bool:
    """Does the frame show the source as it is (the setup disabled, or before its
    Frame Start)? The first of the frame rules: a bake is shown only after it."""
    s = setup.s
    return not s.enabled or setup.frame < s.frame_start


def _frame_rules(setup, inp):
    """The rules once the frame's inputs are read: (Outcome, the points written)."""
    note = _input_warning(setup, inp)
    s, rt, f = setup.s, setup.rt, setup.frame
    if _passes_through(setup):
        return _pass_through(setup, inp, note)
    if s.is_baked:
        return _show_baked(setup, inp, note)
    if f > s.frame_end:
        return _after_the_end(setup, inp, note)
    if f in rt.memory:
        shown = _show_cached_if_current(setup, inp, note)
        if shown is not None:
            return shown
    if not starts_here(setup):
        if (f - 1) not in rt.memory:
            return _hold(setup, inp)
        # Frame f - 1 cannot be evaluated again from here: at least its settings
        # (what every frame shares, and the keyable values at f - 1) must be what it
        # was solved with.
        if fixed_change(setup, rt.memory.inputs(f - 1), f - 1):
            drop_changed(setup)
            return _hold(setup, inp)
    held = _prepare_solver(setup, inp)
    if held is not None:
        return held
    return _solve(setup, inp, note)


def starts_here(setup) -> bool:
    """Does the frame solve from the groomed shape: the start frame, or the first frame
    after frames where the setup's Enabled (keyed) was off? (Disabled frames show the
    source; the fur starts again from its groom when it is turned on.)"""
    f, s = setup.frame, setup.s
    if f == s.frame_start:
        return True
    if f < s.frame_start:
        return False
    return keyed.setup_value(setup.ob, "enabled", f - 1) is False


def _not_evaluated(setup):
    """The outcome when the frame is not evaluated at all (a bake runs, the outputs
    are hidden from this depsgraph, a subframe), else None. Raises ValueError when the
    output must not be written (:func:`check_output`)."""
    s = setup.s
    check_output(setup.ob)
    if setup.rt.baking:
        return Outcome.BAKING, None
    if not shown(s.output, setup.depsgraph) and not shown(s.groom.output, setup.depsgraph):
        # Nothing of this setup is in this depsgraph (its outputs are hidden from
        # it, e.g. from the render): nothing to show, so nothing to compute or to
        # report (its source is usually hidden too).
        return Outcome.HIDDEN, None
    if setup.subframe != 0.0:
        # Never step on subframes (motion blur). A bake is blended between its
        # whole frames; otherwise the output keeps the whole frame.
        if s.is_baked and s.enabled:
            return Outcome.SUBFRAME, _baked_subframe(setup)
        return Outcome.SUBFRAME, None
    return None


def _read_frame(setup):
    """The frame's inputs (motion before collision applied), or None when the source's
    curves changed (the status says so). Drops the cached frames that changes made
    without an update callback invalidate."""
    s, rt = setup.s, setup.rt
    _changes_without_callbacks(setup)  # before the input is read: see there
    # Fur Attach's points are needed unless the frame shows the bake (baked, and not
    # passing the source through): that writes the bake, and the record it is checked
    # against digests the Surface instead (frame_inputs).
    inp = read_inputs(setup, attach=not s.is_baked or _passes_through(setup))
    if not _check_topology(setup, inp):
        return None
    if inp.points is not None:  # (the jiggle's history and the motion feed a solve)
        prepare_input(setup, inp)
    if not s.is_baked:  # a bake checks its own curve layout first
        output.sync_output(setup, inp)
    sig = setup.structure()
    if rt.signature is not None and sig != rt.signature and not s.is_baked:
        # What every frame shares changed without an update callback (a deleted
        # collider, undo): like any such change, it drops the playback cache. (The
        # keyable values are inputs of each frame: their records say when they hold.)
        rt.drop_cache(structure_change(rt.signature, sig), s.frame_start, setup.frame)
        rt.colliders.clear()
    rt.signature = sig
    rt.values_seen = keyed.fingerprint(setup.ob)  # (the depsgraph check compares it)
    return inp


def _input_warning(setup, inp) -> tuple[str, str]:
    """(level, message) the status shows when the frame is fine: a warning about the
    enable attribute or a Surface listed as a collider, else ("INFO", "")."""
    if inp.warning:
        return "WARNING", inp.warning
    if warn := surface_as_collider(setup.ob):
        return "WARNING", warn
    return "INFO", ""


def _pass_through(setup, inp, note):
    """Disabled, or before the start frame: the output follows the source."""
    output.sync_output(setup, inp)
    written = output.write(setup, inp, inp.points, np.zeros(len(inp.offsets) - 1, np.int8))
    setup.rt.outdated = False
    level, msg = note
    setup.set_status(level, msg or ("Disabled" if not setup.s.enabled
                                    else "Before the start frame"))
    return Outcome.PASSTHROUGH, written


def _after_the_end(setup, inp, note):
    """After the end frame: hold the end frame (or, not cached, the newest cached one)."""
    rt, end = setup.rt, setup.s.frame_end
    if rt.hold is not None and rt.hold[0] == end:
        written = output.write(setup, inp, rt.hold[1], rt.hold[2])
        level, msg = note
        setup.set_status(level, msg or f"After the end frame: holding frame {end}")
        return Outcome.HOLD, written
    return _hold(setup, inp, reason=f"after the end frame, and frame {end} is not")


def _show_cached_if_current(setup, inp, note):
    """A memory-cached frame: shown while its inputs still hold; else the setup is
    outdated (or, at the start frame, None: it is solved again, which drops every
    cached frame)."""
    rt, f, start = setup.rt, setup.frame, setup.s.frame_start
    why = cached_frame_change(setup, inp, f)
    if not why:
        written, status, stats = _show_cached(setup, inp, f)
        if rt.hold is None and f == max(rt.memory.frames):
            rt.hold = (f, written, status)
        rt.stats = dict(stats, source="cache")
        rt.outdated = False
        setup.set_status(*_note(setup, stats, note))
        return Outcome.CACHE, written
    if f == start:
        return None  # solved again (which drops every cached frame)
    changed = drop_changed(setup)
    if changed is not None and changed[0] <= f:
        # A setting's value changed at a cached frame (a key edited): the frames
        # before it hold; f is solved again from f - 1 when that is one of them.
        if changed[0] == f and (f - 1) in rt.memory:
            return None
        return _hold(setup, inp)
    if _key_moved_ahead(setup, f):
        # Only the frames from f on were solved from other inputs (a key moved after
        # f - 1): solve f again from f - 1.
        rt.drop_frames_after(f - 1, start)
        return None
    return _outdated(setup, why)


def _key_moved_ahead(setup, f) -> bool:
    """Did frame ``f``'s inputs change only in objects the depsgraph reported while the
    frame it was seen at still held (``Runtime.trusted``), and is ``f - 1`` a frame
    known to hold since (``Runtime.verified``), with its solver state and today's
    settings? Then f is solved again from f - 1 (an animator moved a key ahead of the
    frame shown); anything else drops the playback cache."""
    rt = setup.rt
    fr = rt.memory.frames.get(f - 1)
    if fr is None or (f - 1) not in rt.verified or not rt.trusted:
        return False
    if fr.state is None and rt.solver_frame != f - 1:
        return False
    if fixed_change(setup, fr.inputs, f - 1):
        return False
    objects = changed_objects(setup, rt.memory.inputs(f), rt.seen[1] if rt.seen else None)
    return objects is not None and objects <= rt.trusted


def _prepare_solver(setup, inp):
    """Reset the solver at the start frame, else give it frame ``f - 1``'s state; the
    hold outcome when that state is not known, else None."""
    s, rt, f = setup.s, setup.rt, setup.frame
    solver = setup.ensure_solver(inp)  # a mode change resets it: state unknown
    if f == s.frame_start:
        solver.reset()
        rt.memory.clear()
        rt.verified.clear()
        rt.trusted.clear()
        rt.dropped = ""
        rt.memory.start = f
        rt.memory.limit = int(s.memory_limit * 1024 * 1024)
    elif starts_here(setup):  # enabled again after disabled frames: from the groom
        solver.reset()
        rt.drop_frames_after(f - 1, s.frame_start)
    elif rt.solver_frame != f - 1:
        state = rt.memory.state(f - 1)
        if state is None:
            return _hold(setup, inp)
        try:
            solver.state = state
        except ValueError as exc:  # saved with another mode
            rt.solver_frame = None
            return _hold(setup, inp, reason=str(exc))
    return None


def check_output(ob) -> None:
    """Raise ValueError when FurCollide must not write into the setup's output."""
    s = ob.furcollide
    if s.output is None:
        raise ValueError("the output hair object is missing: remove the setup and add it again")
    if s.output == ob or not s.output.furcollide.is_output:
        raise ValueError(
            f"'{s.output.name}' is not a FurCollide output: FurCollide only writes into "
            "the output object it created (remove the setup and add it again)"
        )
    if s.output.furcollide.source != ob:
        raise ValueError(
            f"this object is a copy of the setup on '{_owner_name(s.output)}': "
            "use Add FurCollide to give it its own output"
        )
    if problem := bridge.write_refusal(s.output, "output"):
        raise ValueError(problem)


def _changes_without_callbacks(setup) -> None:
    """Drop every cached frame when Fur Attach or the fps changed without an update
    callback (undo, a driver). Runs before the input is read: its root history for
    this frame must survive."""
    s, rt = setup.s, setup.rt
    att = (bool(s.use_fur_attach), s.attach_id if s.use_fur_attach else "")
    if rt.attach_state is not None and att != rt.attach_state and not s.is_baked:
        # Fur Attach toggled or rebound: every frame's input changed, so no cached
        # frame is valid.
        rt.drop_cache("Fur Attach changed", s.frame_start, setup.frame)
    rt.attach_state = att
    tk = setup.time_key()
    if None not in (tk, rt.time_state) and tk != rt.time_state and not s.is_baked:
        # The fps changed: wind and jiggle of every cached frame ran on the old
        # seconds. (Turning them on or off goes through the signature.)
        rt.drop_cache("the frame rate changed", s.frame_start, setup.frame)
    rt.time_state = tk


def _check_topology(setup, inp) -> bool:
    """Adopt or verify the source topology; False (with an error) on change."""
    rt, s = setup.rt, setup.s
    if rt.topology is None or rt.topology == inp.key:
        rt.adopt_topology(inp.key)
        return True
    if len(rt.memory) == 0 and not s.is_baked:
        rt.adopt_topology(inp.key)
        rt.hold = None
        return True
    old, new = rt.topology, inp.key
    what = "bake" if s.is_baked else "cached frames"
    if bridge.is_render(setup.depsgraph):
        # The viewport still has the curves the frames were solved for: a modifier
        # evaluates the source otherwise for renders. Reset would change nothing.
        setup.set_status(
            "ERROR",
            f"'{setup.ob.name}' has other curves in this render ({new[0]} curves / "
            f"{new[1]} points) than in the viewport ({old[0]} / {old[1]}): a modifier "
            "evaluates it otherwise for renders (e.g. Interpolate Hair Curves' Viewport "
            "Amount, an Is Viewport switch). The render shows the viewport's curves: make "
            "the source the same in both, or collide the dense hair as a Render Groom.",
        )
        return False
    setup.set_status("ERROR", topology.topology_message(setup.ob, old, new, what,
                                                        s.frame_start))
    # Never left frozen while marked current: the output is outdated and, playing,
    # follows the source (its roots on the skin), not collided (a bake's frame stays).
    rt.outdated = True
    if not s.is_baked and inp.points is not None:
        output.sync_output(setup, inp)
        output.write(setup, inp, inp.points, np.zeros(len(inp.offsets) - 1, np.int8))
    return False


def _solve(setup, inp, note):
    """Solve frame ``f`` (the solver holds ``f - 1``, or was reset), cache it, show it."""
    rt, f = setup.rt, setup.frame
    read_for_solve(setup, inp, continuous=rt.solver_frame == f - 1, fresh=starts_here(setup))
    rt.solver_frame = None  # until the frame is solved: a failed stage leaves it unknown
    result = solve.solve_frame(setup, inp)
    rt.solver_frame = f
    record = solved_inputs(setup, inp)
    saw(setup, record)
    rt.verified.add(f)
    rt.verified &= rt.memory.frames.keys() | {f}  # (frames the budget dropped go)
    rt.memory.put(
        f, inp.raw, result.points, result.status, inp.offsets, rt.solver.state, result.stats,
        result.changed, result.attributes, record,
    )
    if rt.hold is None or f >= rt.hold[0]:
        rt.hold = (f, result.points, result.status)
    written = output.write(setup, inp, result.points, result.status, result.changed,
                           result.attributes)
    rt.stats = result.stats
    rt.error = ""
    rt.outdated = False
    rt.invalid_note = invalid_note(result.problems)
    setup.set_status(*_note(setup, result.stats, note))
    return (Outcome.RESET if f == setup.s.frame_start else Outcome.STEP), written


def invalid_note(problems):
    """The status for curves the core left as they are (INVALID), or None."""
    if not problems:
        return None
    return ("WARNING", f"Source hair: {problems[0]}. They are shown in yellow; the other "
            "curves are solved. Fix the source curves (merge or delete the points)")


def _note(setup, stats, note):
    """``note``, unless the frame shown holds INVALID curves: then what the last solve
    said about them (or how many there are, for a frame solved in another session).
    Without either, what there is to say about the colliders (an open mesh detects no
    pinch; what was repaired in one just built, once): :func:`colliders.collider_note`."""
    n = stats.get("invalid", 0)
    if not n:
        if note[1]:
            return note
        about = collider_note(setup.rt, setup)
        return ("INFO", about) if about else note
    return setup.rt.invalid_note or (
        "WARNING", f"Source hair: {n} curves have a zero-length segment or a non-finite "
        "point. They are shown as they are, in yellow; the other curves are solved")


def _show_cached(setup, inp, f):
    """Write memory-cached frame ``f`` to the output; returns (points, status, stats)."""
    rt = setup.rt
    out, status, stats = rt.memory.get(f, inp.raw, inp.offsets)
    output.write(setup, inp, out, status, attributes=rt.memory.attributes(f))
    return out, status, stats


def _outdated(setup, why):
    """The cached frame (not the start frame) was solved from inputs that no longer
    hold: drop the playback cache (the frames stepped from it would not be what a
    bake gives either), keep the output as it is and mark the setup outdated."""
    rt, f, start = setup.rt, setup.frame, setup.s.frame_start
    rt.drop_cache(why, start, f)
    rt.dropped_why = f"{why} since it was cached"
    rt.outdated = True
    setup.set_status("WARNING", dropped_message(f, rt.dropped_why, start))
    return Outcome.OUTDATED, None


def _hold(setup, inp, reason=""):
    """Jump ahead past the cache: hold the newest cached frame, mark outdated."""
    rt, f = setup.rt, setup.frame
    rt.outdated = True
    here = not reason and rt.dropped and rt.dropped_at == f  # the change was seen here
    reason = reason or rt.dropped
    k = rt.memory.newest_before(f)
    written = None
    if rt.hold is not None and rt.hold[0] == k:
        written = output.write(setup, inp, rt.hold[1], rt.hold[2])
        held = f"holding frame {k}"
    elif k is not None and k in rt.memory:  # (whatever frame was shown before the jump)
        written, status, _stats = _show_cached(setup, inp, k)
        rt.hold = (k, written, status)
        held = f"holding frame {k}"
    else:
        held = "showing the last result"
    start = setup.s.frame_start
    if rt.error:
        setup.set_status("ERROR", f"{rt.error} (frame {f} not solved: fix it, then go back "
                         f"to frame {start})")
        return Outcome.OUTDATED, written
    if here:
        # Only the frames from the change on were dropped: playing on from the newest
        # one kept (its state known) solves the rest.
        resume = k if rt.dropped_from > start and k is not None and (
            rt.memory.frames[k].state is not None) else None
        setup.set_status("WARNING", dropped_message(f, rt.dropped_why, start, resume))
        return Outcome.OUTDATED, written
    why = f" ({reason})" if reason else ""
    setup.set_status(
        "WARNING",
        f"Frame {f} is not cached{why}: {held}. Play from frame {start} or bake.",
    )
    return Outcome.OUTDATED, written


def drop_changed(setup):
    """Drop the cached frames from the first one whose settings record no longer holds
    (:func:`record.first_changed_frame`: a key edited, a setting changed); that
    (frame, why), or None when every cached frame holds."""
    rt, s = setup.rt, setup.s
    changed = first_changed_frame(setup, rt.memory.frames)
    if changed is not None:
        first, why = changed
        rt.drop_from(first, why, s.frame_start, setup.frame)
    return changed


def dropped_message(f, why, start, resume=None) -> str:
    """The status of frame ``f`` when ``why`` (a change seen there) dropped cached
    frames: every one, or those after ``resume``, the frame to play on from."""
    if resume is None or resume < start:
        return (f"Frame {f} is outdated: {why}. The playback cache is dropped: go to frame "
                f"{start} and play, or press Bake.")
    return (f"Frame {f} is outdated: {why}. The frames after {resume} are dropped: go to "
            f"frame {resume} and play, or press Bake.")


def _show_baked(setup, inp, note):
    """A baked setup: show the baked frame (the newest one before it when missing)."""
    s, rt, f = setup.s, setup.rt, setup.frame
    directory = bpy.path.abspath(s.bake_path)
    fe = min(f, s.frame_end)
    if not os.path.exists(framecache.frame_path(directory, fe)):
        frames = [k for k in framecache.list_frames(directory) if k < fe]
        rt.outdated = True
        if frames:
            fe = frames[-1]
        else:
            setup.set_status("ERROR", f"Bake files are missing in {directory} (undo does not "
                             "bring back files Free Bake deleted): press Free Bake, then Bake")
            return Outcome.OUTDATED, None
    try:
        shown = framecache.read_shown(directory, fe)
    except framecache.UNREADABLE as exc:  # damaged (or not readable) since the bake
        rt.outdated = True
        setup.set_status("ERROR", f"Frame {fe} of the bake cannot be read: "
                         f"{framecache.frame_path(directory, fe)} ({type(exc).__name__}: "
                         f"{exc}). The output keeps its last result. A damaged file: "
                         "press Free Bake, then Bake")
        return Outcome.OUTDATED, None
    if not np.array_equal(shown.offsets, inp.offsets):
        setup.set_status(
            "ERROR",
            "The bake was made for other curves (the source changed): output keeps its "
            "last result. Free Bake to simulate the new curves.",
        )
        return Outcome.TOPOLOGY, None
    setup.baked = shown  # (its render groom too: the groom stage reads it from here)
    output.sync_output(setup, inp)
    written = output.write(setup, inp, shown.points, shown.status,
                           attributes=shown.attributes)
    rt.stats = frame_stats(shown.status, fe, source="bake")
    why = baked_frame_change(setup, inp, shown.inputs) if fe == f else ""
    other = baked.settings_change(setup.ob, setup.scene, directory, fe, shown.inputs)
    if other:
        rt.outdated = True
        setup.set_status("WARNING", f"Frame {fe} was {baked.message(other)} (the baked "
                         "frame is still shown)")
    elif why:  # still shown (it is what renders), never as if current
        rt.outdated = True
        setup.set_status("WARNING", f"Frame {f} of the bake is outdated: {why} since it was "
                         "baked. The baked frame is still shown: press Free Bake, then Bake.")
    elif fe == min(f, s.frame_end):
        rt.outdated = False
        setup.set_status(*_note(setup, rt.stats, note))
    else:
        setup.set_status("WARNING", f"Frame {f} is missing from the bake: holding frame {fe}")
    return Outcome.BAKE, written


def _owner_name(out) -> str:
    src = out.furcollide.source
    return src.name if src is not None else "?"


def _baked_subframe(setup):
    """Blend the two baked frames around a subframe into the output; the written
    points, or None (nothing written) when they are not both baked. From Frame End
    on, Frame End itself (held after the end, as whole frames are): the second
    motion step of Frame End's motion blur."""
    s = setup.s
    directory = bpy.path.abspath(s.bake_path)
    pair = framecache.subframe_pair(setup.frame, s.frame_start, s.frame_end)
    if pair is None:
        return None
    a, b = pair
    if not (os.path.exists(framecache.frame_path(directory, a)) and os.path.exists(
        framecache.frame_path(directory, b)
    )):
        return None
    pa, status, offs, _ = framecache.read_frame(directory, a, state=False)
    pb = framecache.read_frame(directory, b, state=False)[0]
    data = s.output.data
    if pa.shape != pb.shape or len(data.points) != len(pa):
        return None
    points = framecache.subframe_blend(pa, pb, setup.subframe)
    m_out_inv = bridge.matrix(s.output.evaluated_get(setup.depsgraph), inverted=True)
    inp = FrameInputs(points, offs, m_out_inv=m_out_inv)
    return output.write(setup, inp, points, status)
