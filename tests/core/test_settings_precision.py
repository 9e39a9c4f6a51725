"""Settings.rotation_precision / max_angle: the result is the smallest clearing
rotation on the precision grid (checked by brute-force stepping + oracle)."""

from __future__ import annotations

import geom
import numpy as np
import oracle
import scenes
import strategies as strat
from geom import FAST
from hypothesis import assume, given
from hypothesis import strategies as st

from core import Collider, Settings, Solver, Status


def _brute_force_clearing_angle(curve, axis, step_deg, V, F, max_deg=180.0):
    """Smallest k*step (degrees) at which the rigidly rotated curve is clear."""
    offs = np.array([0, len(curve)])
    for k in range(int(np.ceil(max_deg / step_deg)) + 1):
        ang = min(k * step_deg, max_deg)
        c = geom.rotate_curve(curve, axis, np.radians(ang))
        if not oracle.segments_hit_mesh(c, offs, V, F, eps=0.0)[0]:
            return ang
    return None


lean = strat.floats(-0.5, 0.5)


@FAST
@given(lx=lean, ly=lean, n=st.integers(3, 8), amp=strat.floats(0.0, 0.15),
       phi=strat.floats(0.0, 2 * np.pi), r=strat.floats(0.15, 0.4), up=strat.floats(0.6, 1.0),
       out=strat.floats(0.2, 0.9), precision=st.sampled_from([0.25, 1.0, 2.5, 7.0]))
def test_stiff_angle_is_smallest_clearing_step(lx, ly, n, amp, phi, r, up, out, precision):
    curve = scenes.curly_curve([0, 0, 0], [lx, ly, 1], 1.0, n, amplitude=amp)
    pts, offs = scenes.pack([curve])
    # convex collider: a sphere touching the upper part of the curve
    d = np.array([np.cos(phi), np.sin(phi), 0.0])
    center = curve[-1] * up + d * r * out
    center[2] = max(center[2], r + 0.05)  # root stays outside
    V, F = scenes.icosphere(center, r, 3)
    assume(oracle.segments_hit_mesh(pts, offs, V, F, eps=oracle.SURE)[0])  # a collision
    res = Solver(offs, Settings(mode="stiff", rotation_precision=precision)).step(
        pts, [Collider(V, F)])
    assert np.asarray(res.status)[0] == Status.COLLIDING
    R, resid = geom.fit_rotation(np.diff(curve, axis=0), np.diff(res.points, axis=0))
    assert resid < 1e-9
    theta, axis = geom.rigid_angle(np.diff(curve, axis=0), np.diff(res.points, axis=0))
    theta = np.degrees(theta)
    # theta is on the precision grid
    assert abs(theta / precision - round(theta / precision)) < 1e-6, theta
    best = _brute_force_clearing_angle(curve, axis, precision, V, F)
    assert best is not None
    assert abs(theta - best) <= precision + 1e-6, (theta, best)
    # and it is not an overshoot: one step less still collides (robustly or not)
    back = geom.rotate_curve(curve, axis, np.radians(theta - precision))
    assert oracle.segments_hit_mesh(back, offs, V, F, eps=oracle.MAYBE)[0]


def test_finer_precision_gives_smaller_or_equal_rotation():
    curve = scenes.straight_curve([0, 0, 0], [0, 0, 1], 1.0, 6)
    pts, offs = scenes.pack([curve])
    V, F = scenes.uv_sphere([0.1, 0, 0.9], 0.3, 32, 16)
    angles = []
    for p in (10.0, 2.0, 0.5, 0.1):
        out = Solver(offs, Settings(mode="stiff", rotation_precision=p)).step(
            pts, [Collider(V, F)]).points
        a = np.degrees(geom.angle_between(curve[-1] - curve[0], out[-1] - out[0]))
        angles.append(a)
        assert not oracle.segments_hit_mesh(out, offs, V, F)[0]
    # each coarser result is at most one coarse step above the finest
    for p, a in zip((10.0, 2.0, 0.5, 0.1), angles, strict=True):
        assert angles[-1] - 0.1 - 1e-6 <= a <= angles[-1] + p + 1e-6


def test_max_angle_limits_rotation_and_reports_unresolved():
    """A curve whose clearing angle exceeds max_angle is UNRESOLVED and keeps
    its last collision-free state (here: none, so its input)."""
    curve = scenes.straight_curve([0, 0, 0], [0, 0, 1], 1.0, 5)
    pts, offs = scenes.pack([curve])
    V, F = scenes.uv_sphere([0.05, 0, 0.8], 0.35, 32, 16)
    full = Solver(offs, Settings(mode="stiff")).step(pts, [Collider(V, F)])
    a = np.degrees(geom.angle_between(curve[-1], full.points[-1]))
    assert np.asarray(full.status)[0] == Status.COLLIDING and a > 10
    capped = Solver(offs, Settings(mode="stiff", max_angle=a / 2)).step(pts, [Collider(V, F)])
    assert np.asarray(capped.status)[0] == Status.UNRESOLVED
    assert np.array_equal(capped.points, pts)


def test_unresolved_keeps_last_collision_free_state():
    """Frame 1 resolvable; frame 2 the curve is boxed in: it keeps frame 1."""
    curve = scenes.straight_curve([0, 0, 0], [0, 0, 1], 1.0, 5)
    pts, offs = scenes.pack([curve])
    V, F = scenes.uv_sphere([0.05, 0, 0.8], 0.3, 32, 16)
    solver = Solver(offs, Settings(mode="stiff", recovery_rate=0.0))
    r1 = solver.step(pts, [Collider(V, F)])
    assert np.asarray(r1.status)[0] == Status.COLLIDING
    # frame 2: a double-sided sphere around the root (double-sided: no pinch)
    # crosses the curve whatever its rotation
    Vs, Fs = scenes.uv_sphere([0, 0, 0], 0.5, 16, 8)
    r2 = solver.step(pts, [Collider(V, F), Collider(Vs, Fs, double_sided=True)])
    assert np.asarray(r2.status)[0] == Status.UNRESOLVED
    np.testing.assert_allclose(r2.points, r1.points, atol=1e-12)


def _bend(curve, axis, theta_rad):
    seg = np.diff(curve, axis=0)
    n = len(seg)
    out = [scenes.rotation_matrix(axis, theta_rad * (j + 1) / n) @ seg[j] for j in range(n)]
    return np.vstack([curve[:1], curve[0] + np.cumsum(out, axis=0)])


@FAST
@given(lx=lean, ly=lean, n=st.integers(3, 8), amp=strat.floats(0.05, 0.15),
       phi=strat.floats(0.0, 2 * np.pi), r=strat.floats(0.15, 0.35), up=strat.floats(0.7, 1.0),
       out=strat.floats(0.2, 0.9), precision=st.sampled_from([0.25, 1.0, 4.0]))
def test_bend_angle_is_smallest_clearing_step(lx, ly, n, amp, phi, r, up, out, precision):
    """Bend: the tip angle theta is the smallest clearing multiple of the
    precision along the curve's axis (brute force with the oracle)."""
    curve = scenes.curly_curve([0, 0, 0], [lx, ly, 1], 1.0, n, amplitude=amp)
    pts, offs = scenes.pack([curve])
    d = np.array([np.cos(phi), np.sin(phi), 0.0])
    center = curve[-1] * up + d * r * out
    center[2] = max(center[2], r + 0.3)
    V, F = scenes.icosphere(center, r, 3)
    assume(oracle.segments_hit_mesh(pts, offs, V, F, eps=oracle.SURE)[0])  # a collision
    res = Solver(offs, Settings(mode="bend", rotation_precision=precision)).step(
        pts, [Collider(V, F)])
    if np.asarray(res.status)[0] != Status.COLLIDING:
        return
    si, so = np.diff(curve, axis=0), np.diff(res.points, axis=0)
    axis, ang, ok = geom.common_axis_angles(si, so)
    n = len(si)
    if not ok[-1] or np.allclose(ang[ok], ang[ok][0], atol=1e-7) and n > 1 and ok.sum() > 1:
        return  # tip angle ill-defined, or the stiff fallback (tested elsewhere)
    theta = np.degrees(ang[-1])
    assert abs(theta / precision - round(theta / precision)) < 1e-6, theta
    for k in range(int(round(theta / precision))):
        c = _bend(curve, axis, np.radians(k * precision))
        if not oracle.segments_hit_mesh(c, offs, V, F, eps=-1e-6)[0]:
            # a clear grid angle below theta: allowed only within one step
            assert theta - k * precision <= precision + 1e-6, (theta, k * precision)
            break
    np.testing.assert_allclose(_bend(curve, axis, np.radians(theta)), res.points, atol=1e-9)
