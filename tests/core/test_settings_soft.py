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
