"""One frame's solve: :func:`solve_frame`, the single path of playback, bake and CLI.

The setup's runtime holds one :class:`SolveState` (the core ``Solver``, the frame its
state holds, the curve layout it belongs to, the jiggle's root history, the spline
margin), changed only here. :func:`prepare` gives the ``Solver`` the state the frame
starts from (the groomed shape, or frame ``f - 1``'s: kept by the solver, or restored
from the playback cache); :func:`ensure_solver` builds it for the frame's curves and
settings; :func:`adopt_topology` and :func:`forget_after` forget what belongs to other
curves or to frames dropped.
``solve_frame(setup, inputs) -> FrameResult`` runs the core's frame sequence
(:func:`core.pipeline.frame.solve`: the setup's ``Solver`` on the frame's inputs, then the
stages after collision: wind and jiggle limited by the Region of Influence, the collider
distance attribute) with the setup's motion settings read into plain values. It writes
nothing: the frame rules (:mod:`.rules`) and the bake (:mod:`..store.bake`) decide what
to solve and keep. Scripts run the same sequence without Blender objects
(:class:`core.pipeline.frame.Shot`, ``scripts/demo.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ... import core
from ...core import splines
from ...core.pipeline import frame
from ...core.pipeline.frame import FrameResult, RootHistory
from ..settings import motion as motion_settings
from ..settings.fingerprints import core_settings
from ..store import playback
from . import colliders
from .clock import clock


@dataclass(slots=True)
class SolveState:
    """The part of a setup's runtime with its solver."""

    solver: object = None  # core.Solver, built for ``topology`` (its settings: solver.settings)
    frame: int | None = None  # frame whose result the solver state holds
    #: The source's curve layout (``framecache.topology_key``) the solver, the cached
    #: frames and the jiggle history belong to: :func:`adopt_topology` changes it.
    topology: tuple | None = None
    history: RootHistory = field(default_factory=RootHistory)  # the roots seen: jiggle
    #: The spline margin of the last frame solved and what it was computed from.
    drawn: splines.DrawnMargin = field(default_factory=splines.DrawnMargin)


def adopt_topology(rt, key) -> bool:
    """Take the source's curve layout ``key``; True when it changed (the solver, its
    colliders and the jiggle history, which belong to the old curves, are forgotten)."""
    part = rt.solve
    changed = part.topology is not None and part.topology != key
    if changed:
        part.solver = None
        part.frame = None
        colliders.forget(rt)
        part.history.clear()
    part.topology = key
    return changed


def forget_after(rt, f) -> None:
    """The cached frames after ``f`` are dropped: forget the solver's state and the
    roots of those frames."""
    part = rt.solve
    if part.frame is not None and part.frame > f:
        part.frame = None
    part.history.drop_after(f)


def forget_frame(rt) -> None:
    """The solver's state is no frame's any more (the playback cache was dropped)."""
    rt.solve.frame = None


def record_roots(rt, f, roots) -> None:
    """Frame ``f``'s roots (C, 3), for jiggle."""
    rt.solve.history.record(f, roots)


def ensure_solver(setup, inputs):
    """The core Solver for the curves of ``inputs`` and the current settings (with the
    frame's parameter maps).

    Built for the runtime's topology (a new curve layout forgets the solver:
    :func:`adopt_topology`); a settings change is applied to it (a mode change resets
    it: its state is unknown then).
    """
    part = setup.rt.solve
    settings = core_settings(setup.ob, inputs.maps)
    if part.solver is None:
        part.solver = core.Solver(inputs.offsets, settings)
        part.frame = None
        playback.sparse(setup.rt, part.solver.state)
    elif part.solver.settings != settings:
        if part.solver.settings.mode != settings.mode:
            part.frame = None  # the solver resets on a mode change
        part.solver.settings = settings
    return part.solver


def prepare(setup, read, start) -> str | None:
    """Give the solver the state frame ``f`` starts from: the groomed shape (``start``
    ``"reset"``) or frame ``f - 1``'s (kept by the solver, else restored from the
    playback cache). None when it is ready; else why not ('' when ``f - 1``'s state is
    not known): the frame is then held. ``read``: the frame as read once."""
    rt, f = setup.rt, setup.frame
    solver = ensure_solver(setup, read.inputs)  # a mode change resets it: state unknown
    if start == "reset":
        solver.reset()
    elif rt.solve.frame != f - 1:
        state = rt.cache.memory.state(f - 1)
        if state is None:
            return ""
        try:
            solver.state = state
        except ValueError as exc:  # saved with another mode
            rt.solve.frame = None
            return str(exc)
    return None


def restore(setup, state) -> None:
    """Give the solver frame ``f - 1``'s ``state`` read from elsewhere (a bake's file);
    raises ValueError when it is not a state of this solver's mode."""
    setup.rt.solve.solver.state = state


def solve_frame(setup, inputs, motion=None) -> FrameResult:
    """Solve one frame: the core step on ``inputs``, then the stages after collision.

    Parameters
    ----------
    setup : setup.Setup
        Its ``solver`` holds the previous frame's state (or was reset for the start
        frame); its ``motion`` settings, ``fps`` and ``history`` drive the stages.
    inputs : inputs.FrameInputs
        ``points``, ``offsets``, ``enabled``, ``colliders``, ``growth`` and ``frame``.
    motion : core.pipeline.frame.Motion, optional
        The motion settings as read once for the frame (default: read now).

    Raises
    ------
    Exception
        Any error of the core or a stage (the solver's state is then unknown: the
        solver holds no frame).
    """
    part = setup.rt.solve
    m = motion_settings.values(setup.motion) if motion is None else motion
    if inputs.splines is None:  # (no source read: Blender's default hair type)
        sp = splines.Splines.catmull_rom(len(inputs.offsets) - 1)
    else:
        sp = inputs.splines.at(inputs.world(), inputs.offsets)
    part.frame = None  # until the frame is solved: a failed stage leaves it unknown
    result = frame.solve(part.solver, inputs.world(), inputs.offsets, inputs.frame,
                         inputs.colliders, growth=inputs.growth, enabled=inputs.enabled,
                         motion=m, fps=setup.fps if m.active else 24.0,
                         history=part.history, threads=setup.s.core_threads,
                         raw=inputs.before_motion(), splines=sp, drawn=part.drawn)
    part.frame = inputs.frame
    for stage, ms in result.timings.items():
        clock.add(stage, ms)
    return result
