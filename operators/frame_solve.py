"""One frame's solve: :func:`solve_frame`, the single path of playback, bake, CLI and demo.

``solve_frame(setup, inputs) -> FrameResult`` steps the setup's core ``Solver`` on the
frame's inputs (world curves, enable mask, colliders, growth surface), then runs the
stages after collision (wind and jiggle limited by the Region of Influence, the collider
distance attribute; :func:`motion.output_stage`). It reads no Blender data and writes
nothing: the frame rules (:mod:`.frame_rules`) and the bake (:mod:`.bake`) decide what
to solve and keep, and ``scripts/demo.py`` calls it with :meth:`setup.Setup.for_script`.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from ..core import Status, framecache, splines
from . import motion
from .clock import clock


@dataclass
class FrameResult:
    """What :func:`solve_frame` returns.

    Attributes
    ----------
    points : (P, 3) float32 ndarray
        The frame's final curves (world), after the stages.
    status : (C,) int8 ndarray
        Core ``Status`` code per curve.
    attributes : dict
        Per-point attributes for the output (name -> (P,) array).
    changed : (P,) bool ndarray
        The points that differ from the input before motion (``inputs.raw``).
    stats : dict
        The panel's statistics (:func:`frame_stats`).
    problems : list of str
        What is wrong with the curves the core marked INVALID (``StepResult.problems``).
    """

    points: np.ndarray
    status: np.ndarray
    attributes: dict = field(default_factory=dict)
    changed: np.ndarray | None = None
    stats: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)


def solve_frame(setup, inputs) -> FrameResult:
    """Solve one frame: the core step on ``inputs``, then the stages after collision.

    Parameters
    ----------
    setup : setup.Setup
        Its ``solver`` holds the previous frame's state (or was reset for the start
        frame); its ``motion`` settings (None: no stage), ``fps`` and ``history`` drive
        the stages.
    inputs : frame_inputs.FrameInputs
        ``points``, ``offsets``, ``enabled``, ``colliders``, ``growth`` and ``frame``.

    Raises
    ------
    Exception
        Any error of the core or a stage (the solver's state is then unknown).
    """
    with drawn_clearance(setup.solver, inputs):
        res = setup.solver.step(inputs.points, inputs.colliders, growth=inputs.growth,
                                enabled=inputs.enabled)
    clock.add("collide", res.timings.get("total", 0.0))
    m = setup.motion
    if m is None or not m.active:
        points, attributes = res.points, {}
    else:
        points, attributes = motion.output_stage(m, res.points, inputs.offsets, inputs.frame,
                                                 setup.fps, setup.history, inputs.colliders,
                                                 setup.s.core_threads)
    stats = frame_stats(res.status, inputs.frame, res.timings.get("total", 0.0))
    return FrameResult(points, res.status, attributes,
                       framecache.rows_differ(points, inputs.raw), stats, list(res.problems))


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


def frame_stats(status, frame, solve_ms=0.0, source="solved") -> dict:
    """Panel statistics: the number of curves per core ``Status`` (named in lower case;
    free curves are not counted), the frame, the solve time and where it came from."""
    counts = np.bincount(status.astype(np.intp, copy=False), minlength=len(Status))
    stats = {s.name.lower(): int(counts[s]) for s in Status if s != Status.FREE}
    stats.update(frame=int(frame), solve_ms=float(solve_ms), source=source)
    return stats
