"""One frame's solve: :func:`solve_frame`, the single path of playback, bake and CLI.

:func:`prepare` gives the setup's ``Solver`` the state the frame starts from (the
groomed shape, or frame ``f - 1``'s: kept by the solver, or restored from the playback
cache); :func:`ensure_solver` builds it for the frame's curves and settings.
``solve_frame(setup, inputs) -> FrameResult`` runs the core's frame sequence
(:func:`core.pipeline.frame.solve`: the setup's ``Solver`` on the frame's inputs, then the
stages after collision: wind and jiggle limited by the Region of Influence, the collider
distance attribute) with the setup's motion settings read into plain values. It writes
nothing: the frame rules (:mod:`.rules`) and the bake (:mod:`..store.bake`) decide what
to solve and keep. Scripts run the same sequence without Blender objects
(:class:`core.pipeline.frame.Shot`, ``scripts/demo.py``).
"""

from __future__ import annotations

from ... import core
from ...core import framecache, splines
from ...core.pipeline import frame
from ...core.pipeline.frame import FrameResult
from ..settings import motion as motion_settings
from ..settings.fingerprints import core_settings
from .clock import clock


def ensure_solver(setup, inputs):
    """The core Solver for the curves of ``inputs`` and the current settings (with the
    frame's parameter maps).

    Built for the runtime's topology (a new curve layout forgets the solver:
    :meth:`..store.registry.Runtime.adopt_topology`); a settings change is applied to
    it (a mode change resets it: its state is unknown then).
    """
    rt = setup.rt
    settings = core_settings(setup.ob, inputs.maps)
    if rt.solver is None:
        rt.solver = core.Solver(inputs.offsets, settings)
        rt.solver_frame = None
        rt.memory.sparse = framecache.SparseState(rt.solver.state)
    elif rt.solver.settings != settings:
        if rt.solver.settings.mode != settings.mode:
            rt.solver_frame = None  # the solver resets on a mode change
        rt.solver.settings = settings
    return rt.solver


def prepare(setup, read, start) -> str | None:
    """Give the solver the state frame ``f`` starts from: the groomed shape (``start``
    ``"reset"``) or frame ``f - 1``'s (kept by the solver, else restored from the
    playback cache). None when it is ready; else why not ('' when ``f - 1``'s state is
    not known): the frame is then held. ``read``: the frame as read once."""
    rt, f = setup.rt, setup.frame
    solver = ensure_solver(setup, read.inputs)  # a mode change resets it: state unknown
    if start == "reset":
        solver.reset()
    elif rt.solver_frame != f - 1:
        state = rt.memory.state(f - 1)
        if state is None:
            return ""
        try:
            solver.state = state
        except ValueError as exc:  # saved with another mode
            rt.solver_frame = None
            return str(exc)
    return None


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
        Any error of the core or a stage (the solver's state is then unknown).
    """
    m = motion_settings.values(setup.motion) if motion is None else motion
    if inputs.splines is None:  # (no source read: Blender's default hair type)
        sp = splines.Splines.catmull_rom(len(inputs.offsets) - 1)
    else:
        sp = inputs.splines.at(inputs.points, inputs.offsets)
    result = frame.solve(setup.solver, inputs.points, inputs.offsets, inputs.frame,
                         inputs.colliders, growth=inputs.growth, enabled=inputs.enabled,
                         motion=m, fps=setup.fps if m.active else 24.0,
                         history=setup.history, threads=setup.s.core_threads,
                         raw=inputs.raw, splines=sp, drawn=setup.rt.drawn)
    for stage, ms in result.timings.items():
        clock.add(stage, ms)
    return result
