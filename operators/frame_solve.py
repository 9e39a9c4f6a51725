"""One frame's solve: :func:`solve_frame`, the single path of playback, bake and CLI.

``solve_frame(setup, inputs) -> FrameResult`` runs the core's frame sequence
(:func:`core.pipeline.frame.solve`: the setup's ``Solver`` on the frame's inputs, then the
stages after collision: wind and jiggle limited by the Region of Influence, the collider
distance attribute) with the setup's motion settings read into plain values. It writes
nothing: the frame rules (:mod:`.frame_rules`) and the bake (:mod:`.bake`) decide what
to solve and keep. Scripts run the same sequence without Blender objects
(:class:`core.pipeline.frame.Shot`, ``scripts/demo.py``).
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np

from ..core import splines
from ..core.pipeline import frame
from ..core.pipeline.frame import FrameResult, frame_stats  # noqa: F401 (the glue's names)
from . import motion
from .clock import clock


def solve_frame(setup, inputs) -> FrameResult:
    """Solve one frame: the core step on ``inputs``, then the stages after collision.

    Parameters
    ----------
    setup : setup.Setup
        Its ``solver`` holds the previous frame's state (or was reset for the start
        frame); its ``motion`` settings, ``fps`` and ``history`` drive the stages.
    inputs : frame_inputs.FrameInputs
        ``points``, ``offsets``, ``enabled``, ``colliders``, ``growth`` and ``frame``.

    Raises
    ------
    Exception
        Any error of the core or a stage (the solver's state is then unknown).
    """
    m = motion.values(setup.motion)
    with drawn_clearance(setup.solver, inputs):
        result = frame.solve(setup.solver, inputs.points, inputs.offsets, inputs.frame,
                             inputs.colliders, growth=inputs.growth, enabled=inputs.enabled,
                             motion=m, fps=setup.fps if m.active else 24.0,
                             history=setup.history, threads=setup.s.core_threads,
                             raw=inputs.raw)
    for stage, ms in result.timings.items():
        clock.add(stage, ms)
    return result


def drawn_margin(settings, inputs) -> np.ndarray:
    """(C,) how much farther than the solved polyline each curve must keep from the
    colliders so that the spline Blender draws through its points clears them too
    (``splines.clearance_margin`` of the source's curve types, rounded up by
    ``splines.quantized``; 0 for Poly curves). Without the source's splines (a
    script) the curves are Catmull-Rom, Blender's hair default."""
    if inputs.splines is None:
        sp = splines.Splines.catmull_rom(len(inputs.offsets) - 1)
    else:
        sp = inputs.splines.at(inputs.points, inputs.offsets)
    key = _margin_key(settings, inputs, sp)
    hit = _last_margin.get("key")
    if hit is not None and _same_key(hit, key):
        return _last_margin["margin"]
    margin = splines.quantized(splines.clearance_margin(sp, inputs.points, inputs.offsets,
                                                        settings, inputs.enabled))
    _last_margin.update(key=key, margin=margin)
    return margin


# The last margin computed and what it was computed from: a groom that does not move
# (a collider passing through still fur) gives the same margin every frame.
_last_margin: dict = {}


def _margin_key(settings, inputs, sp) -> tuple:
    """(the settings that bound the turns, copies of every array the margin reads)."""
    s = settings
    arrays = (inputs.points, inputs.offsets, inputs.enabled, sp.types, sp.cyclic,
              sp.handle_left, sp.handle_right, sp.handle_type_left, sp.handle_type_right,
              sp.nurbs_order, sp.knots_mode, sp.nurbs_weight)
    return ((s.mode, s.max_angle, s.shrink, s.scale_minimum, s.scale_angle),
            *(None if a is None else np.array(a) for a in arrays))


def _same_key(a, b) -> bool:
    if a[0] != b[0]:
        return False
    for x, y in zip(a[1:], b[1:], strict=True):
        if (x is None) != (y is None):
            return False
        if x is not None and not (x.shape == y.shape and np.array_equal(x, y)):
            return False
    return True


#: The largest collision offset ``core.Settings`` and ``core.Collider`` take.
MAX_OFFSET = 1e6


@contextmanager
def drawn_clearance(solver, inputs):
    """Widen the clearance of ``solver``'s step by :func:`drawn_margin` (its settings
    are restored afterwards).

    Every curve is widened by the largest margin of the frame, as the core's
    ``Settings.clearance_margin`` (added to whatever offset applies to each collider,
    its own or the setup's): one shell per collider. Per-curve margins (the core takes
    a ``(C,)`` array) would make each collider one shell per level of margin, and each
    level costs a ray query per search round (a BVH build per frame for a deforming
    collider); the frame's largest margin is a few thousandths of the hair's length.
    """
    settings = solver.settings
    margin = drawn_margin(settings, inputs)
    widen = float(margin.max()) if len(margin) else 0.0
    if widen <= 0.0:
        yield
        return
    solver.settings = settings.replace(clearance_margin=min(widen, MAX_OFFSET))
    try:
        yield
    finally:
        solver.settings = settings
