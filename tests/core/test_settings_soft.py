"""Soft mode: affected_connected_cvs and cv_falloff (paper 3.2.1)."""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes

from core import Collider, Settings, Solver, Status

N_SEG = 10


def _setup():
    """Straight vertical curve of 10 segments (0.1 each); a small tilted
    square crosses segment 3 only (at z = 0.35)."""
    curve = scenes.straight_curve([0.007, 0.004, 0], [0, 0, 1], 1.0, N_SEG + 1)
    pts, offs = scenes.pack([curve])
    h = 0.03
    tilt = np.radians(20)
    u = np.array([np.cos(tilt), 0, -np.sin(tilt)]) * 2 * h
    v = np.array([0, 2 * h, 0])
    origin = np.array([0, 0, 0.35]) - u / 2 - v / 2
    V, F = scenes.quad(origin, u, v)
    assert oracle.first_hit_segment(pts, offs, V, F)[0] == 3
    return pts, offs, V, F


@pytest.mark.parametrize("A", [0, 1, 2, 4])
@pytest.mark.parametrize("falloff", [0.0, 0.5, 1.0])
def test_connected_cvs_follow_with_falloff(A, falloff):
    pts, offs, V, F = _setup()
    s = Settings(mode="soft", affected_connected_cvs=A, cv_falloff=falloff)
    res = Solver(offs, s).step(pts, [Collider(V, F)])
    assert np.asarray(res.status)[0] == Status.COLLIDING
    assert not oracle.segments_hit_mesh(res.points, offs, V, F)[0]
    a = geom.angle_between(np.diff(pts, axis=0), np.diff(res.points, axis=0))
    k = 3
    phi = a[k]
    assert phi > np.radians(1)
    expected = np.zeros(N_SEG)
    for i in range(0, A + 1):
        if k + i < N_SEG:
            expected[k + i] = phi * (1 - falloff) ** i
    np.testing.assert_allclose(a, expected, atol=1e-7,
                               err_msg=f"A={A}, falloff={falloff}: per-segment angles")
    # all rotated segments turn about the same axis (same direction)
    seg_in, seg_out = np.diff(pts, axis=0), np.diff(res.points, axis=0)
    turned = expected > 1e-6
    ax = np.cross(seg_in[turned], seg_out[turned])
    ax /= np.linalg.norm(ax, axis=1, keepdims=True)
    np.testing.assert_allclose(ax, np.broadcast_to(ax[0], ax.shape), atol=1e-6)
    geom.assert_lengths_kept(pts, res.points, offs, rtol=1e-9)


def test_more_connected_cvs_move_the_tip_further():
    pts, offs, V, F = _setup()
    tips = []
    for A in (0, 2, 9):
        s = Settings(mode="soft", affected_connected_cvs=A, cv_falloff=0.0)
        out = Solver(offs, s).step(pts, [Collider(V, F)]).points
        tips.append(np.linalg.norm(out[-1] - pts[-1]))
    assert tips[0] < tips[1] < tips[2]


def test_soft_ignores_shrink():
    pts, offs, V, F = _setup()
    s = Settings(mode="soft", shrink=True, scale_minimum=0.2, scale_angle=5.0)
    res = Solver(offs, s).step(pts, [Collider(V, F)])
    assert np.asarray(res.status)[0] == Status.COLLIDING
    geom.assert_lengths_kept(pts, res.points, offs, rtol=1e-9)


def test_stiff_and_bend_ignore_soft_parameters():
    pts, offs, V, F = _setup()
    for mode in ("stiff", "bend"):
        base = Solver(offs, Settings(mode=mode)).step(pts, [Collider(V, F)]).points
        for A, f in ((0, 1.0), (7, 0.0)):
            s = Settings(mode=mode, affected_connected_cvs=A, cv_falloff=f)
            assert np.array_equal(Solver(offs, s).step(pts, [Collider(V, F)]).points, base)


# ------------------------------------------- the smallest clearing angle (an oracle)
def _soft_curve(pts, k, axis, phi, A, falloff):
    """The Soft deformation written from the README: segment ``k`` turns by ``phi``
    about ``axis``, the next ``A`` by ``phi (1 - falloff)^i``, the curve re-chained
    from its root (float64, scenes' Rodrigues, nothing from core)."""
    seg = np.diff(np.asarray(pts, float), axis=0)
    out = [np.asarray(pts[0], float)]
    for j, v in enumerate(seg):
        i = j - k
        ang = phi * (1 - falloff) ** i if 0 <= i <= A else 0.0
        out.append(out[-1] + scenes.rotation_matrix(axis, ang) @ v)
    return np.array(out)


def _clear(curve, V, F):
    return not oracle.segments_hit_mesh(curve, np.array([0, len(curve)]), V, F, eps=0.0)[0]


def _clearing_angle(pts, k, axis, A, falloff, V, F):
    """The exact (continuous) smallest clearing angle, radians: a fine scan, then
    bisection between the last colliding and the first clear angle."""
    fine = np.radians(np.arange(0.0, 90.0, 0.05))
    i = 1
    while not _clear(_soft_curve(pts, k, axis, fine[i], A, falloff), V, F):
        i += 1  # (an IndexError past 90 degrees: no clearing angle)
    a, b = fine[i - 1], fine[i]
    for _ in range(60):
        m = 0.5 * (a + b)
        if _clear(_soft_curve(pts, k, axis, m, A, falloff), V, F):
            b = m
        else:
            a = m
    return b


@pytest.mark.parametrize("precision", [0.25, 0.7, 1.3, 3.0])
@pytest.mark.parametrize(("A", "falloff"), [(0, 0.5), (2, 0.5), (4, 0.0)])
def test_soft_turns_by_the_smallest_clearing_angle_on_the_precision_grid(precision, A,
                                                                         falloff):
    """README "Precision": the smallest clearing angle on the Rotation Precision grid.
    The oracle rotates the colliding segment (and the ones after it) itself and finds
    the exact clearing angle by bisection on the brute-force segment/triangle test; the
    solver's angle must be the first grid step past it (and the step below must
    collide). Only the rotation axis is read from the solver's output."""
    pts, offs, V, F = _setup()
    s = Settings(mode="soft", rotation_precision=precision, affected_connected_cvs=A,
                 cv_falloff=falloff)
    res = Solver(offs, s).step(pts, [Collider(V, F)])
    assert np.asarray(res.status)[0] == Status.COLLIDING
    k = 3
    seg_in, seg_out = np.diff(pts, axis=0), np.diff(res.points.astype(float), axis=0)
    axis = np.cross(seg_in[k], seg_out[k])
    axis /= np.linalg.norm(axis)
    assert abs(axis @ seg_in[k]) < 1e-9 * np.linalg.norm(seg_in[k])  # about its own axis
    phi = geom.angle_between(seg_in[k], seg_out[k])
    exact = _clearing_angle(pts, k, axis, A, falloff, V, F)
    step = np.radians(precision)
    grid = np.ceil(exact / step) * step
    # the test is meaningful only away from a grid point (float32 rays, margin shell)
    assert min(grid - exact, exact - (grid - step)) > 0.02 * step, (exact, step)
    assert phi == pytest.approx(grid, abs=1e-6), (
        f"Soft turned by {np.degrees(phi):.4f} deg; the smallest clearing angle on the "
        f"{precision} deg grid is {np.degrees(grid):.4f} (exact {np.degrees(exact):.4f})")
    assert not _clear(_soft_curve(pts, k, axis, grid - step, A, falloff), V, F)
    assert _clear(_soft_curve(pts, k, axis, grid, A, falloff), V, F)
    # the solver's curve is the oracle's deformation at that angle
    np.testing.assert_allclose(res.points, _soft_curve(pts, k, axis, grid, A, falloff),
                               atol=1e-9)
