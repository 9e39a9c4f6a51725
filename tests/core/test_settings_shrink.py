"""Shrink / scale_minimum / scale_angle (paper 3.2.2): exact linear ramp."""

from __future__ import annotations

import geom
import numpy as np
import oracle
import scenes
import strategies as strat
from geom import FAST
from hypothesis import given
from hypothesis import strategies as st

from core import Collider, Settings, Solver, Status


def _scene(data, n_curves=15):
    """Drawn fur under a drawn sphere, with a collision."""
    pts, offs, V, F, _c, _r = data.draw(strat.sphere_scenes(
        max_curves=n_curves, extent=0.5, n_cvs=(3, 9), curl_max=0.25,
        center=((-0.3, 0.3), (-0.3, 0.3), (0.7, 1.0)), radius=(0.25, 0.45)), label="scene")
    return pts, offs, V, F


def _fixed_scene(seed, n_curves=15):
    rng = np.random.default_rng(seed)
    pts, offs = scenes.fur_on_plane(rng, n_curves=n_curves, curly=0.25, n_cvs=(3, 9),
                                    extent=0.5)
    c = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(0.7, 1.0)])
    V, F = scenes.uv_sphere(c, rng.uniform(0.25, 0.45), 24, 12)
    return pts, offs, V, F


shrink_params = dict(data=st.data(),
                     smin=st.sampled_from([0.1, 0.5, 0.9, 1.0]),
                     sang=st.sampled_from([5.0, 30.0, 90.0, 200.0]))


@FAST
@given(**shrink_params)
def test_stiff_shrink_ratio_is_ramp_of_angle(data, smin, sang):
    pts, offs, V, F = _scene(data)
    s = Settings(mode="stiff", shrink=True, scale_minimum=smin, scale_angle=sang)
    res = Solver(offs, s).step(pts, [Collider(V, F)])
    status = np.asarray(res.status)
    seg_in = scenes.segment_vectors(pts, offs)
    seg_out = scenes.segment_vectors(res.points, offs)
    for c in np.nonzero(status == Status.COLLIDING)[0]:
        ratio = np.linalg.norm(seg_out[c], axis=1) / np.linalg.norm(seg_in[c], axis=1)
        # stiff: one scale for the whole curve
        np.testing.assert_allclose(ratio, ratio[0], rtol=1e-9)
        R, resid = geom.fit_rotation(seg_in[c], seg_out[c] / ratio[0])
        assert resid < 1e-9
        theta = np.degrees(geom.rigid_angle(seg_in[c], seg_out[c])[0])
        np.testing.assert_allclose(ratio[0], geom.ramp(theta, smin, sang), rtol=0, atol=1e-7)
        if smin < 1:
            assert ratio[0] < 1
    geom.assert_no_intersection(res.points, offs, status, [(V, F)])
    geom.assert_roots_exact(pts, res.points, offs)


@FAST
@given(**shrink_params)
def test_bend_shrink_ratio_per_segment(data, smin, sang):
    pts, offs, V, F = _scene(data)
    s = Settings(mode="bend", shrink=True, scale_minimum=smin, scale_angle=sang)
    res = Solver(offs, s).step(pts, [Collider(V, F)])
    status = np.asarray(res.status)
    seg_in = scenes.segment_vectors(pts, offs)
    seg_out = scenes.segment_vectors(res.points, offs)
    for c in np.nonzero(status == Status.COLLIDING)[0]:
        n = len(seg_in[c])
        ratio = np.linalg.norm(seg_out[c], axis=1) / np.linalg.norm(seg_in[c], axis=1)
        axis, ang, ok = geom.common_axis_angles(seg_in[c], seg_out[c])
        if not ok[-1]:
            continue
        theta = np.degrees(ang[-1])
        seg_angle = theta * np.arange(1, n + 1) / n  # bend: theta * (j + 1) / n
        np.testing.assert_allclose(ratio, geom.ramp(seg_angle, smin, sang), rtol=0, atol=1e-6,
                                   err_msg=f"curve {c}")
    geom.assert_no_intersection(res.points, offs, status, [(V, F)])


def test_straight_curve_shrink_known_values():
    """Straight vertical curve through a tilted plane, bend: the measured angle
    of every segment gives its scale through the ramp; the tip shrinks most."""
    n = 6
    pts, offs = scenes.pack([scenes.straight_curve([0, 0, 0], [0, 0, 1], 1.0, n + 1)])
    V, F = scenes.quad([-1, -1, 0.5], [2, 0, 0.3], [0, 2, 0])
    s = Settings(mode="bend", shrink=True, scale_minimum=0.3, scale_angle=40.0)
    res = Solver(offs, s).step(pts, [Collider(V, F)])
    assert np.asarray(res.status)[0] == Status.COLLIDING
    si, so = np.diff(pts, axis=0), np.diff(res.points, axis=0)
    a = np.degrees(geom.angle_between(si, so))
    ratio = np.linalg.norm(so, axis=1) / np.linalg.norm(si, axis=1)
    np.testing.assert_allclose(ratio, geom.ramp(a, 0.3, 40.0), atol=1e-7)
    assert np.all(np.diff(ratio) <= 1e-12)  # tip shrinks most
    assert not oracle.segments_hit_mesh(res.points, offs, V, F)[0]


def test_shrinking_needs_less_or_equal_rotation():
    """Shrinking can only help clearing: the stiff angle with shrink is never
    larger than without (same axis at the first hit)."""
    pts, offs = scenes.pack([scenes.straight_curve([0, 0, 0], [0.1, 0, 1], 1.0, 5)])
    V, F = scenes.uv_sphere([0.25, 0.0, 0.9], 0.3, 32, 16)
    angles = []
    for shrink in (False, True):
        s = Settings(mode="stiff", shrink=shrink, scale_minimum=0.3, scale_angle=30.0)
        out = Solver(offs, s).step(pts, [Collider(V, F)]).points
        angles.append(geom.angle_between(pts[1] - pts[0], out[1] - out[0]))
    assert angles[1] <= angles[0] + 1e-12


def test_scale_minimum_one_means_no_shrink():
    pts, offs, V, F = _fixed_scene(3, n_curves=25)
    for mode in ("stiff", "bend"):
        a = Solver(offs, Settings(mode=mode, shrink=True, scale_minimum=1.0)).step(
            pts, [Collider(V, F)])
        b = Solver(offs, Settings(mode=mode)).step(pts, [Collider(V, F)])
        np.testing.assert_allclose(a.points, b.points, atol=1e-12)
        geom.assert_lengths_kept(pts, a.points, offs, rtol=1e-9)


def test_shrink_recovers_length():
    """Recovery 'rotates and lengthens' back: with rate 1 the next frame is
    the exact input (lengths included)."""
    pts, offs, V, F = _fixed_scene(5, n_curves=25)
    solver = Solver(offs, Settings(mode="bend", shrink=True, recovery_rate=1.0))
    r1 = solver.step(pts, [Collider(V, F)])
    assert np.any(np.asarray(r1.status) == Status.COLLIDING)
    r2 = solver.step(pts, [])
    assert np.array_equal(r2.points, pts)


def test_shrink_follows_angle_during_recovery():
    """Recovery rotates and lengthens together: at every frame the scale is
    the ramp of the current angle."""
    curve = scenes.curly_curve([0, 0, 0], [0, 0, 1], 1.0, 7, amplitude=0.12, turns=0.8)
    pts, offs = scenes.pack([curve])
    V, F = scenes.uv_sphere([0.15, 0.0, 0.85], 0.3, 32, 16)
    s = Settings(mode="stiff", shrink=True, scale_minimum=0.4, scale_angle=60.0,
                 recovery_rate=0.3)
    solver = Solver(offs, s)
    r = solver.step(pts, [Collider(V, F)])
    si = np.diff(pts, axis=0)
    for _ in range(40):
        so = np.diff(r.points, axis=0)
        ratio = np.linalg.norm(so, axis=1) / np.linalg.norm(si, axis=1)
        theta = np.degrees(geom.rigid_angle(si, so)[0])
        np.testing.assert_allclose(ratio, geom.ramp(theta, 0.4, 60.0), atol=1e-7)
        if np.array_equal(r.points, pts):
            break
        r = solver.step(pts, [])
    assert np.array_equal(r.points, pts)
