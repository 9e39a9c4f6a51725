"""The solver state's memory (issue 15): Stiff and Bend keep no per-segment
quaternions (a fresh state's are one read-only identity row, shared), Soft makes its
own on its first step; an invalid curve's state is put back either way, and a
snapshot restored into a fresh solver continues bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
import scenes

from core import Collider, Settings, Solver, Status
from core.state import SolverState


def _shared(a) -> bool:
    return a.strides[0] == 0 and not a.flags.writeable


def _scene():
    """A 6 x 6 grid of 5-CV curves, curve 4 with a zero-length segment (invalid), and
    a ball lowered into the tips over 4 frames."""
    curves = [scenes.straight_curve([x, y, 0.0], [0, 0, 1], 1.0, 5)
              for x in np.linspace(-0.5, 0.5, 6) for y in np.linspace(-0.5, 0.5, 6)]
    points, offsets = scenes.pack(curves)
    points[offsets[4] + 2] = points[offsets[4] + 1]
    V, F = scenes.uv_sphere(center=(0.0, 0.0, 1.6), radius=0.5, segments=16, rings=8)
    frames = [Collider(V, F, matrix=scenes.translation((0.0, 0.0, -0.15 * f)))
              for f in range(4)]
    return points, offsets, frames


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_quaternions_cost_nothing_outside_soft_and_the_state_is_kept(mode):
    points, offsets, frames = _scene()
    solver = Solver(offsets, Settings(mode=mode))
    fresh = solver._state
    assert _shared(fresh.quat) and _shared(fresh.quat_max)
    assert fresh.quat.shape == (solver.layout.n_segments, 4)
    assert np.array_equal(fresh.quat[:, 0], np.ones(solver.layout.n_segments))
    copy = fresh.copy()  # shares them (read-only), copies the rest
    assert copy.quat is fresh.quat and copy.quat_max is fresh.quat_max
    assert copy.angle is not fresh.angle and np.array_equal(copy.angle, fresh.angle)
    results = []
    for k, col in enumerate(frames):
        res = solver.step(points, [col])
        assert res.status[4] == Status.INVALID, res.status
        assert np.array_equal(res.points[offsets[4]:offsets[5]], points[offsets[4]:offsets[5]])
        results.append(res)
        if k == 1:
            snap = solver.state
    assert (results[-1].status == Status.COLLIDING).sum() >= 4
    st = solver._state
    if mode == "soft":
        assert st.quat.flags.writeable and not _shared(st.quat)
        seg4 = slice(solver.layout.soff[4], solver.layout.soff[5])
        assert np.array_equal(st.quat[seg4], np.tile([1.0, 0, 0, 0], (4, 1)))
    else:  # never touched: still the shared identity row
        assert _shared(st.quat) and _shared(st.quat_max)
        assert set(snap) == set(SolverState.SHAPES) - set(SolverState.SOFT) | {"meta"}
    # a snapshot restored into a fresh solver continues bit for bit
    again = Solver(offsets, Settings(mode=mode))
    again.state = snap
    for col, res in zip(frames[2:], results[2:], strict=True):
        r2 = again.step(points, [col])
        assert np.array_equal(r2.points, res.points) and np.array_equal(r2.status, res.status)
