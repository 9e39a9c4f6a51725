"""One frame's solve: :func:`solve_frame`, the single path of playback, bake and CLI.

``solve_frame(setup, inputs) -> FrameResult`` runs the core's frame sequence
(:func:`core.pipeline.frame.solve`: the setup's ``Solver`` on the frame's inputs, then the
stages after collision: wind and jiggle limited by the Region of Influence, the collider
distance attribute) with the setup's motion settings read into plain values. It writes
nothing: the frame rules (:mod:`.rules`) and the bake (:mod:`..store.bake`) decide what
to solve and keep. Scripts run the same sequence without Blender objects
(:class:`core.pipeline.frame.Shot`, ``scripts/demo.py``).
"""

from __future__ import annotations

from ...core import splines
from ...core.pipeline import frame
from ...core.pipeline.frame import FrameResult
from ..settings import motion
from .clock import clock


def solve_frame(setup, inputs) -> FrameResult:
    """Solve one frame: the core step on ``inputs``, then the stages after collision.

    Parameters
    ----------
    setup : setup.Setup
        Its ``solver`` holds the previous frame's state (or was reset for the start
        frame); its ``motion`` settings, ``fps`` and ``history`` drive the stages.
    inputs : inputs.FrameInputs
        ``points``, ``offsets``, ``enabled``, ``colliders``, ``growth`` and ``frame``.

    Raises
    ------
    Exception
        Any error of the core or a stage (the solver's state is then unknown).
    """
    m = motion.values(setup.motion)
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
