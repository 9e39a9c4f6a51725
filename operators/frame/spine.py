"""The frame's spine: read once, decide, solve, write once, then the stages after.

Playback, a bake's frame, a resumed bake and the command line run one frame of one
setup through :func:`evaluate`, top to bottom; they differ only in their *sink*
(:class:`Playback`, or the bake's :class:`..store.bake.ToBake`): who decides, where a
solved frame is kept, what the stages after the output give back.

1. **not evaluated** (:func:`.rules.not_evaluated`): a bake of the setup runs, its
   outputs are hidden from this depsgraph, or a motion-blur subframe (a bake blends);
2. **read once** (:func:`.inputs.read_frame`): the evaluated source, the settings (the
   colliders listed, the keyable values, the fingerprints, the time key), the motion
   settings; what changed since the frame handler last saw the setup
   (:func:`.rules.since_seen`) drops cached frames; the motion before collision
   (:func:`.inputs.prepare_input`);
3. **decide** (:func:`.rules.decide`): what the output shows and why, what to drop; a
   decision writes nothing, the spine applies it (:func:`_drop`);
4. **solve** (:func:`_solve`): the solver starts from the groom or frame ``f - 1``
   (:func:`.solve.prepare`), the colliders are read (:func:`.colliders.read_for_solve`),
   :func:`.solve.solve_frame` runs the core's frame sequence, the sink keeps the frame;
5. **write once** (:func:`.output.show`): the output's layout follows the source, the
   frame shown is written;
6. **the stages after** (:func:`.groom.run`, :func:`.children.run`), then the frame's
   status, statistics and outdated mark, once (:func:`.output.publish`); a bake writes
   its file.

It raises on errors (in playback the render groom then follows the last good guides and
the children the output); the handler (:mod:`.handlers`) turns them into the setup's
status message plus one console line, and the output keeps its last good result.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..store import playback, report
from . import children, colliders, groom, output, record, rules, solve
from .clock import clock
from .inputs import prepare_input, read_frame
from .output import Shown
from .rules import NOTE, Outcome

#: How many times a frame's rules are asked again after their drops (one is enough:
#: a drop leaves the frame uncached, or frame f - 1 known; the bound is a guard).
_AGAIN = 3


class Playback:
    """The sink of a frame played, scrubbed or rendered: the frame rules decide
    (:func:`.rules.decide`), a solved frame goes into the playback cache, the stages
    follow what the output shows, the status says why."""

    #: The frame handler's own evaluation: what it saw is remembered (the depsgraph
    #: check compares the scene with it), and changes since are looked for.
    sees = True

    def skip(self, setup):
        return rules.not_evaluated(setup)

    def attaches(self, setup) -> bool:
        # Fur Attach's points are needed unless the frame shows the bake (baked, and
        # not passing the source through): that writes the bake, and the record it is
        # checked against digests the Surface instead.
        return not setup.s.is_baked or rules.passes_through(setup)

    def changes(self, setup, read):
        return rules.since_seen(setup, read)

    def decide(self, setup, read):
        d, seen = rules.decide(setup, read), None
        for _ in range(_AGAIN):
            seen = d.record if d.record is not None else seen
            if d.then is None:
                break
            _drop(setup, d.drops)
            d = rules.hold(setup) if d.then == "hold" else rules.decide(setup, read, seen)
        return replace(d, record=seen)

    def prepare(self, setup, read, d):
        return solve.prepare(setup, read, d.start)

    def continuous(self, setup) -> bool:
        return setup.rt.solve.frame == setup.frame - 1

    def keep(self, setup, read, result, inputs_record) -> None:
        """The frame solved goes into the playback cache (with its inputs record), and
        is held after the end and on a jump ahead when it is the newest."""
        playback.keep(setup.rt, setup.frame, read.inputs, result, inputs_record)

    def stages(self, setup, outcome, shown):
        """The render groom and the children follow what the output shows: (their
        :class:`.output.Stage` each or None, the groom's error or '')."""
        groom_stage = children_stage = None
        groom_error = ""
        if setup.s.groom.output is not None and (
            shown.written is not None or outcome in (Outcome.TOPOLOGY, Outcome.OUTDATED)
        ):  # (None: the groom follows the last good guides)
            try:
                groom_stage = groom.run(setup, shown.written, shown.baked)
            except Exception as exc:  # noqa: BLE001 - the guides are written: only warn
                groom_error = groom.error_message(exc, setup)
        if outcome not in (Outcome.HIDDEN, Outcome.BAKING):
            children_stage = children.run(setup, shown.baked)  # (never raises)
        return groom_stage, children_stage, groom_error

    def publish(self, setup, outcome, shown, stages):
        """The frame's status (the rules', then the notes of the stages), statistics
        and outdated mark, set once."""
        rt = setup.rt
        groom_stage, children_stage, groom_error = stages
        done = [st for st in (groom_stage, children_stage) if st is not None]
        stats = dict(shown.stats if shown.stats is not None else rt.report.stats)
        for st in done:
            stats.update(st.stats)
        stats.update(clock.stats())
        outdated = True if any(st.outdated for st in done) else shown.outdated
        status = shown.status
        if status == NOTE:
            fresh = shown.fresh + tuple(n for st in done for n in st.fresh)
            status = rules.frame_note(setup, shown.read, stats, fresh)
        base = status if status is not None else rt.report.status
        final = ("WARNING", groom_error) if groom_error else groom.with_note(
            base, groom_stage, setup.ob)
        final = children.with_note(final, children_stage)
        output.publish(setup, final if status is not None or final != base else None,
                       outdated, stats)

    def failed(self, setup) -> None:
        """The frame raised: the render groom follows the last good guides, the
        children the output (neither raises)."""
        groom.follow_last_guides(setup)
        children.run(setup)


#: The sink of the frame handler and of everything that evaluates the current frame.
PLAYBACK = Playback()


def evaluate(setup, sink=PLAYBACK) -> Outcome:
    """Run the frame of ``setup`` (module docstring) into ``sink``; returns what it did.

    Raises
    ------
    Exception
        Any error; the frame handler turns it into the status message, a bake into a
        report. A render groom error only warns (the guides are written).
    """
    clock.start()
    try:
        outcome, shown = _frame(setup, sink)
    except Exception:
        sink.failed(setup)
        raise
    sink.publish(setup, outcome, shown, sink.stages(setup, outcome, shown))
    return outcome


# ------------------------------------------------------------------ frame
class Frame:
    """What a frame shows so far, passed down the spine to the sink (never kept)."""

    __slots__ = ("written", "baked", "stats", "status", "outdated", "fresh", "read",
                 "result", "record")

    def __init__(self):
        self.written = None  # world points written into the output (None: not needed)
        self.baked = None  # (frame, framecache.ShownFrame) of the bake shown
        self.stats = None  # the frame's statistics (None: unchanged)
        self.status = None  # (level, message), rules.NOTE or None (unchanged)
        self.outdated = None
        self.fresh = ()  # what was said of colliders just built
        self.read = None  # inputs.FrameRead
        self.result = None  # core.pipeline.frame.FrameResult of a frame solved
        self.record = None  # its frame-inputs record


def _frame(setup, sink):
    """(Outcome, Frame): steps 1 to 5 of the module docstring."""
    shown = Frame()
    d = sink.skip(setup)
    if d is not None:
        if d.show is not None:  # (a baked subframe: its two frames blended)
            shown.written = output.show(setup, d.inputs, d.shown)
        return d.outcome, shown
    s, rt = setup.s, setup.rt
    read = shown.read = read_frame(setup, attach=sink.attaches(setup))
    changes = sink.changes(setup, read)
    _drop(setup, changes.before)
    if sink.sees:
        record.saw_settings(rt, s, read.settings)
    if changes.topology is not None:
        _show(setup, read, changes.topology, shown)
        return changes.topology.outcome, shown
    if solve.adopt_topology(rt, changes.adopt) and not len(rt.cache.memory):
        playback.forget_hold(rt)  # (other curves, nothing cached: the held frame is of the old)
    if read.inputs.has_points:  # (the jiggle's history and the motion feed a solve)
        read = shown.read = replace(read, inputs=prepare_input(setup, read.inputs, read.motion))
    _drop(setup, changes.after)
    if sink.sees:
        record.saw_structure(rt, read.settings)  # (the depsgraph check compares them)
    d = sink.decide(setup, read)
    if d.show == "solve":
        held = sink.prepare(setup, read, d)
        if held is not None:  # frame f - 1's state is not known (or not for this mode)
            d = rules.hold(setup, reason=held)
    _drop(setup, d.drops)  # (a frame solved from the groom: once its solver is ready)
    seen = d.record
    if d.show == "solve":
        seen = _solve(setup, read, d, shown, sink)
    else:
        _show(setup, read, d, shown)
    if sink.sees and d.outcome is not Outcome.BAKE:
        # What this frame was evaluated from (solved and checked cached frames made it
        # already): the depsgraph check tells an edit from the animation evaluated
        # again with it.
        if seen is None:
            seen = record.current_inputs(setup, read.inputs, read.settings)
        record.saw(rt, setup.scene, setup.frame, seen)
    return d.outcome, shown


def _drop(setup, drops) -> None:
    """Apply a decision's drops to the setup's playback cache (:mod:`..store.playback`)."""
    rt, s, f = setup.rt, setup.s, setup.frame
    for drop in drops:
        if drop.kind == "cache":
            playback.drop_cache(rt, drop.why, s.frame_start, f, drop.since)
        elif drop.kind == "from":
            playback.drop_from(rt, drop.frame, drop.why, s.frame_start, f)
        elif drop.kind == "after":
            playback.drop_after(rt, drop.frame, s.frame_start)
        elif drop.kind == "restart":
            playback.restart(rt, drop.frame, s.memory_limit)
        if drop.colliders:
            colliders.forget(rt)


def _show(setup, read, d, shown) -> None:
    """Write what decision ``d`` shows (once), and note what the frame says."""
    cache = setup.rt.cache
    inp = read.inputs
    what, stats = None, None
    world = True
    if d.show == "source":
        what = Shown(inp.world(), np.zeros(len(inp.offsets) - 1, np.int8))
    elif d.show == "hold":
        what = Shown(cache.hold[1], cache.hold[2])
    elif d.show == "memory":
        rows, points, status, stats = cache.memory.get_moved(d.frame, inp.offsets)
        what = Shown(points, status, attributes=cache.memory.attributes(d.frame), rows=rows)
        # (no render groom follows it, no frame is held: written without the world input)
        world = d.keep_hold or setup.s.groom.output is not None
    elif d.show == "baked":
        b = d.baked
        what = Shown(b.points, b.status, attributes=b.attributes)
        shown.baked = (d.frame, b)
    shown.written = output.show(setup, inp, what, sync=rules.syncs(setup, d.outcome),
                                world=world)
    if d.keep_hold:
        playback.hold(setup.rt, d.frame, shown.written, what.status)
    shown.stats = dict(stats, source="cache") if d.outcome is Outcome.CACHE else d.stats
    shown.status, shown.outdated = d.status, d.outdated


def _solve(setup, read, d, shown, sink) -> dict:
    """Solve the frame (its solver prepared: reset, or holding ``f - 1``), have the sink
    keep it, show it; returns its inputs record."""
    inp = read.inputs
    cols, growth, fresh = colliders.read_for_solve(setup, read.settings.refs,
                                                   continuous=sink.continuous(setup),
                                                   fresh=d.start == "reset")
    result = solve.solve_frame(setup, replace(inp, colliders=cols, growth=growth),
                               motion=read.motion)
    solved = record.solved_inputs(setup, inp, read.settings)
    sink.keep(setup, read, result, solved)
    what = Shown(result.points, result.status, result.changed, result.attributes)
    shown.written = output.show(setup, inp, what, sync=True)
    report.solved(setup.rt, rules.invalid_note(result.problems))
    shown.stats, shown.status, shown.outdated = result.stats, NOTE, False
    shown.fresh, shown.result, shown.record = tuple(fresh), result, solved
    return solved
