"""Soft recovery where clearance is not monotone along the recovery arc.

Soft's blocked recovery takes the largest safe fraction ``k / 16`` of the recovery
step (``SoftSolve.recover``). A curve that stopped at level ``m`` last frame first
probes the full step, ``m`` and ``m + 1`` (a lasting contact in two probes). When
``m`` is blocked but ``m + 1`` is clear, a thin obstacle lies between two levels:
what was learnt about ``m`` says nothing about the levels above ``m + 1``, so the
search forgets it and looks above ``m + 1`` (and decides the full step again).

The scene: one straight segment, pushed aside by a ball, then recovering
(``recovery_rate=1``: the arc runs from its current direction back to its input)
between thin walls placed across chosen levels of that arc. Which levels are clear
comes from the independent oracle; the warm and the full search must both find the
largest clear level.
"""

from __future__ import annotations

import numpy as np
import oracle
import pytest
import scenes

from core import Collider, Settings, Solver, Status

LEVELS = 16
PTS = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
OFFS = np.array([0, 2])


def _angle(points):
    d = points[1] - points[0]
    return float(np.arctan2(d[0], d[2]))


def _wall(a, b, rho=0.6, h=0.3):
    """A thin wall (one quad) across the fan of directions between the angles
    ``a`` and ``b`` (radians from +z toward +x): the segment hits it exactly when
    its angle lies between them."""
    pa = rho * np.array([np.sin(a), 0.0, np.cos(a)])
    pb = rho * np.array([np.sin(b), 0.0, np.cos(b)])
    up = np.array([0.0, h, 0.0])
    V = np.array([pa - up, pb - up, pb + up, pa + up])
    return V, np.array([[0, 1, 2], [0, 2, 3]])


def _level_points(start, k):
    """The segment at level ``k`` of the arc from ``start`` back to the input
    (slerp of the directions: Soft turns a segment about an axis normal to it)."""
    d0 = PTS[1] - PTS[0]
    d1 = start[1] - start[0]
    omega = np.arccos(np.clip(np.dot(d0, d1) / np.linalg.norm(d0) / np.linalg.norm(d1), -1, 1))
    t = k / LEVELS
    d = (np.sin((1 - t) * omega) * d1 + np.sin(t * omega) * d0) / np.sin(omega)
    return np.array([start[0], start[0] + d])


def _clear_levels(start, walls):
    out = []
    for k in range(LEVELS + 1):
        p = _level_points(start, k)
        out.append(not any(oracle.segments_hit_mesh(p, OFFS, V, F)[0] for V, F in walls))
    return np.array(out)


@pytest.mark.parametrize("warm", [True, False])
def test_a_thin_obstacle_between_two_levels_recovers_to_the_largest_clear_level(warm):
    solver = Solver(OFFS, Settings(mode="soft", recovery_rate=1.0))
    solver.warm_start = warm
    ball = scenes.uv_sphere([-0.2, 0.0, 0.8], 0.5, 32, 16)
    r = solver.step(PTS, [Collider(*ball)])
    assert np.asarray(r.status)[0] == Status.COLLIDING
    a = _angle(r.points)
    assert np.degrees(a) > 15.0

    # Frame 2: one wall across every level from 5.5 on (monotone): the curve
    # stops at level m = 5 and remembers it.
    m = 5
    walls = [_wall(a * (1 - (m + 0.5) / LEVELS), -0.2 * a)]
    pushed = r.points.copy()
    clear = _clear_levels(pushed, walls)
    assert clear[: m + 1].all() and not clear[m + 1:].any()
    r = solver.step(PTS, [Collider(*w) for w in walls])
    assert np.asarray(r.status)[0] == Status.COLLIDING
    np.testing.assert_allclose(r.points, _level_points(pushed, m), atol=1e-6)
    assert solver.state["contact"][0] and solver.state["delta"][0] == m / LEVELS

    # Frame 3, from there: a thin wall across level m only, another across level
    # m + 3 and everything beyond. Clear: 0..m-1, m+1, m+2; blocked: m, m+3..16.
    start = r.points.copy()
    b = _angle(start)
    walls = [_wall(b * (1 - (m + 0.5) / LEVELS), b * (1 - (m - 0.5) / LEVELS)),
             _wall(b * (1 - (m + 2.5) / LEVELS), -0.2 * b)]
    clear = _clear_levels(start, walls)
    want = np.ones(LEVELS + 1, bool)
    want[m] = False
    want[m + 3:] = False
    np.testing.assert_array_equal(clear, want)
    r = solver.step(PTS, [Collider(*w) for w in walls])
    assert np.asarray(r.status)[0] == Status.COLLIDING
    # the largest safe fraction of the step: level m + 2, right below a blocked one
    best = int(np.flatnonzero(clear).max())
    assert best == m + 2
    np.testing.assert_allclose(r.points, _level_points(start, best), atol=1e-6)
    assert solver.state["delta"][0] == best / LEVELS
    for V, F in walls:
        assert not oracle.segments_hit_mesh(r.points, OFFS, V, F)[0]


def test_the_landing_step_is_probed_where_it_lands():
    """Within half a precision step of its target, a recovering curve lands on the
    target (not ``recovery_rate`` of the way): the full step probed for clearance is
    that landing. A thin wall across the target but short of the plain step's
    position: the curve stops before the wall instead of landing in it."""
    prec, rate = 2.0, 0.5
    solver = Solver(OFFS, Settings(mode="soft", recovery_rate=rate, rotation_precision=prec))
    ball = scenes.uv_sphere([-0.2, 0.0, 0.8], 0.5, 32, 16)
    r = solver.step(PTS, [Collider(*ball)])
    a = _angle(r.points)
    half = np.radians(0.5 * prec)
    for _ in range(20):  # recover freely until the next step lands on the input
        if a * (1 - rate) < half:
            break
        r = solver.step(PTS, [])
        assert np.asarray(r.status)[0] == Status.RECOVERING
        a = _angle(r.points)
    assert 0 < a * (1 - rate) < half
    V, F = _wall(-a, a * (1 - rate) / 2)  # the target (angle 0) blocked, a (1 - rate) clear
    start = r.points.copy()
    assert oracle.segments_hit_mesh(PTS, OFFS, V, F)[0]
    assert not oracle.segments_hit_mesh(_level_points(start, LEVELS * rate), OFFS, V, F)[0]
    r = solver.step(PTS, [Collider(V, F)])
    assert np.asarray(r.status)[0] == Status.COLLIDING
    assert not oracle.segments_hit_mesh(r.points, OFFS, V, F)[0]
    assert 0 < _angle(r.points) <= a


def _stopped_at(m):
    """A solver whose curve stopped at level ``m`` of its recovery last frame (a
    wall across every level from m + 1/2 on), and that curve's points."""
    solver = Solver(OFFS, Settings(mode="soft", recovery_rate=1.0))
    ball = scenes.uv_sphere([-0.2, 0.0, 0.8], 0.5, 32, 16)
    r = solver.step(PTS, [Collider(*ball)])
    a = _angle(r.points)
    r = solver.step(PTS, [Collider(*_wall(a * (1 - (m + 0.5) / LEVELS), -0.2 * a))])
    assert np.asarray(r.status)[0] == Status.COLLIDING
    assert solver.state["contact"][0] and solver.state["delta"][0] == m / LEVELS
    return solver, r.points.copy()


def test_from_a_clear_level_above_a_blocked_one_the_search_bisects_up_to_the_largest():
    """Remembered level 1 blocked, 2 clear, the full step blocked: the search
    bisects between the clear level 2 it knows and the blocked full step, with
    walls across levels 1, 4-9 and 11-16 (clear: 0, 2, 3, 10). It takes the
    largest clear level, 10, not 3 (right above what it knows) nor below 2."""
    m = 1
    solver, start = _stopped_at(m)
    b = _angle(start)

    def at(level):
        return b * (1 - level / LEVELS)

    walls = [_wall(at(0.5), at(1.5)), _wall(at(3.5), at(9.5)), _wall(at(10.5), -0.2 * b)]
    clear = _clear_levels(start, walls)
    want = np.zeros(LEVELS + 1, bool)
    want[[0, 2, 3, 10]] = True
    np.testing.assert_array_equal(clear, want)
    r = solver.step(PTS, [Collider(*w) for w in walls])
    assert np.asarray(r.status)[0] == Status.COLLIDING
    np.testing.assert_allclose(r.points, _level_points(start, 10), atol=1e-6)
    assert solver.state["delta"][0] == 10 / LEVELS
