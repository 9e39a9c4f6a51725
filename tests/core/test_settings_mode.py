"""Settings.mode: stiff keeps the shape, bend bends uniformly, soft is local."""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes
import strategies as strat
from geom import FAST
from hypothesis import assume, given
from hypothesis import strategies as st

from core import Collider, Settings, Solver, Status


def _scene(data, n_curves=20, curly=0.25, n_cvs=(3, 10)):
    """Drawn fur under a drawn sphere, with a collision."""
    pts, offs, V, F, _c, _r = data.draw(strat.sphere_scenes(
        max_curves=n_curves, n_cvs=n_cvs, curl_max=curly,
        center=((-0.4, 0.4), (-0.4, 0.4), (0.75, 1.1))), label="scene")
    return pts, offs, V, F


def _fixed_scene(seed, n_curves=20, curly=0.25, n_cvs=(3, 10)):
    rng = np.random.default_rng(seed)
    pts, offs = scenes.fur_on_plane(rng, n_curves=n_curves, curly=curly, n_cvs=n_cvs,
                                    extent=0.6)
    r = rng.uniform(0.25, 0.5)
    c = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), rng.uniform(0.75, 1.1)])
    V, F = scenes.uv_sphere(c, r, 24, 12)
    return pts, offs, V, F


@FAST
@given(data=st.data())
def test_stiff_is_a_rigid_rotation_about_the_root(data):
    pts, offs, V, F = _scene(data)
    res = Solver(offs, Settings(mode="stiff")).step(pts, [Collider(V, F)])
    status = np.asarray(res.status)
    seg_in = scenes.segment_vectors(pts, offs)
    seg_out = scenes.segment_vectors(res.points, offs)
    for c in np.nonzero(status == Status.COLLIDING)[0]:
        R, resid = geom.fit_rotation(seg_in[c], seg_out[c])
        L = np.linalg.norm(seg_in[c], axis=1).sum()
        assert resid <= 1e-9 * L + 1e-12, f"curve {c} changed shape (rms {resid})"
        assert geom.rotation_angle(R) > 0
        # one axis, one angle: every segment rotated by the same R
        np.testing.assert_allclose(seg_in[c] @ R.T, seg_out[c], atol=1e-9 * L)


@FAST
@given(data=st.data())
def test_bend_is_a_uniform_bend_about_one_axis(data):
    pts, offs, V, F = _scene(data)
    res = Solver(offs, Settings(mode="bend")).step(pts, [Collider(V, F)])
    status = np.asarray(res.status)
    seg_in = scenes.segment_vectors(pts, offs)
    seg_out = scenes.segment_vectors(res.points, offs)
    for c in np.nonzero(status == Status.COLLIDING)[0]:
        n = len(seg_in[c])
        axis, ang, ok = geom.common_axis_angles(seg_in[c], seg_out[c])
        assert axis is not None, f"curve {c} COLLIDING but unchanged"
        if not ok[-1]:
            continue  # tip segment (nearly) along the axis: angle ill-defined
        theta = ang[-1]
        # uniform bend theta * (j + 1) / n -- or, for curves that bending
        # cannot clear, the documented fallback: a rigid turn at the root
        bend = theta * np.arange(1, n + 1) / n
        stiff = np.full(n, theta)
        expected = bend if np.allclose(ang[ok], bend[ok], atol=1e-7) else stiff
        np.testing.assert_allclose(ang[ok], expected[ok], atol=1e-7,
                                   err_msg=f"curve {c}: neither a uniform bend nor rigid")
        # and the rotation really is about that one axis, for every segment
        for j in range(n):
            Rj = scenes.rotation_matrix(axis, expected[j])
            np.testing.assert_allclose(Rj @ seg_in[c][j], seg_out[c][j], atol=1e-7)


def test_bend_straight_curve_angles_ramp_root_to_tip():
    """A straight vertical curve through a tilted open plane: segment j's
    angle to its input is theta * (j + 1) / n."""
    n = 8
    pts, offs = scenes.pack([scenes.straight_curve([0, 0, 0], [0, 0, 1], 1.0, n + 1)])
    V, F = scenes.quad([-1, -1, 0.6], [2, 0, 0.4], [0, 2, 0])
    res = Solver(offs, Settings(mode="bend")).step(pts, [Collider(V, F)])
    assert np.asarray(res.status)[0] == Status.COLLIDING
    a = geom.angle_between(np.diff(pts, axis=0), np.diff(res.points, axis=0))
    assert a[-1] > np.radians(1)
    np.testing.assert_allclose(a, a[-1] * np.arange(1, n + 1) / n, rtol=1e-7, atol=1e-9)
    assert not oracle.segments_hit_mesh(res.points, offs, V, F)[0]


def test_rotation_direction_follows_hit_normal():
    """Paper 3.2.1: rotate along the hit normal, or its inverse when the
    segment cuts through a back face. Plane normal = cross(u, v) points up
    and toward -x (it rises toward +x)."""
    V, F = scenes.quad([-1, -1, 0.6], [2, 0, 0.4], [0, 2, 0])
    nrm = np.cross([2, 0, 0.4], [0, 2, 0])
    assert nrm[0] < 0 < nrm[2]
    for mode in ("stiff", "bend", "soft"):
        for double_sided in (False, True):
            col = Collider(V, F, double_sided=double_sided)
            # from below: back face -> inverse normal, toward +x
            up, offs = scenes.pack([scenes.straight_curve([0, 0, 0], [0, 0, 1], 1.0, 6)])
            r = Solver(offs, Settings(mode=mode)).step(up, [col])
            assert np.asarray(r.status)[0] == Status.COLLIDING
            assert r.points[-1, 0] > 0.05, (mode, double_sided, r.points[-1])
            # from above: front face -> normal, toward -x
            down, offs = scenes.pack([scenes.straight_curve([0, 0, 1.3], [0, 0, -1], 1.0, 6)])
            r = Solver(offs, Settings(mode=mode)).step(down, [col])
            assert np.asarray(r.status)[0] == Status.COLLIDING
            assert r.points[-1, 0] < -0.05, (mode, double_sided, r.points[-1])


def test_modes_differ_on_the_same_input():
    pts, offs = scenes.pack([scenes.curly_curve([0, 0, 0], [0, 0, 1], 1.0, 9, 0.1)])
    V, F = scenes.uv_sphere([0.15, 0.0, 0.85], 0.3, 24, 12)
    outs = {m: Solver(offs, Settings(mode=m)).step(pts, [Collider(V, F)]).points
            for m in ("stiff", "bend", "soft")}
    assert not np.allclose(outs["stiff"], outs["bend"])
    assert not np.allclose(outs["bend"], outs["soft"])
    assert not np.allclose(outs["stiff"], outs["soft"])


@FAST
@given(data=st.data())
def test_soft_keeps_segments_before_first_contact(data):
    pts, offs, V, F = _scene(data, curly=0.3, n_cvs=(4, 12))
    first = oracle.first_hit_segment(pts, offs, V, F, eps=oracle.MAYBE)
    first_sure = oracle.first_hit_segment(pts, offs, V, F, eps=oracle.SURE)
    res = Solver(offs, Settings(mode="soft")).step(pts, [Collider(V, F)])
    status = np.asarray(res.status)
    for c in np.nonzero(status == Status.COLLIDING)[0]:
        k = first[c]
        if k < 0 or k != first_sure[c]:
            continue  # borderline first contact
        s = offs[c]
        # CVs 0..k (the root of the first colliding segment) do not move
        np.testing.assert_allclose(res.points[s:s + k + 1], pts[s:s + k + 1], rtol=0,
                                   atol=1e-12, err_msg=f"curve {c}: moved before contact {k}")
        assert not np.allclose(res.points[s + k + 1], pts[s + k + 1]), (
            f"curve {c}: first colliding segment {k} not rotated")


def test_soft_lengths_kept():
    rng = np.random.default_rng(7)
    pts, offs = scenes.fur_on_plane(rng, n_curves=30, curly=0.3, n_cvs=(4, 12), extent=0.6)
    V, F = scenes.uv_sphere([0, 0, 0.9], 0.45, 24, 12)
    res = Solver(offs, Settings(mode="soft")).step(pts, [Collider(V, F)])
    assert np.count_nonzero(np.asarray(res.status) == Status.COLLIDING) >= 5
    geom.assert_lengths_kept(pts, res.points, offs, rtol=1e-9)


def test_two_cv_curves_bend_equals_stiff():
    """With one segment, bend's theta * (j + 1) / n is theta: same as stiff."""
    rng = np.random.default_rng(5)
    pts, offs = scenes.fur_on_plane(rng, n_curves=40, n_cvs=(2, 2), extent=0.6)
    V, F = scenes.uv_sphere([0, 0, 0.8], 0.4, 24, 12)
    a = Solver(offs, Settings(mode="stiff")).step(pts, [Collider(V, F)])
    b = Solver(offs, Settings(mode="bend")).step(pts, [Collider(V, F)])
    assert np.count_nonzero(np.asarray(a.status) == Status.COLLIDING) >= 5
    assert np.array_equal(np.asarray(a.status), np.asarray(b.status))
    np.testing.assert_allclose(a.points, b.points, rtol=0, atol=1e-14)


@FAST
@given(fur=st.lists(strat.curves(extent=0.5, n_cvs=(20, 40), length=(1.0, 2.0), curl_max=0.3),
                   min_size=1, max_size=10),
       mode=st.sampled_from(["stiff", "bend", "soft"]))
def test_long_curves_many_cvs(fur, mode):
    pts, offs = scenes.pack(fur)
    V, F = scenes.uv_sphere([0, 0, 1.2], 0.45, 24, 12)
    assume(oracle.segments_hit_mesh(pts, offs, V, F).any())  # a collision to resolve
    res = Solver(offs, Settings(mode=mode)).step(pts, [Collider(V, F)])
    geom.assert_no_intersection(res.points, offs, res.status, [(V, F)])
    geom.assert_roots_exact(pts, res.points, offs)
    geom.assert_lengths_kept(pts, res.points, offs, rtol=1e-9)


def test_bend_falls_back_to_stiff_when_bending_cannot_clear():
    """A wide obstacle just above the root: bending turns the root segment by
    only 1/n of the angle and cannot clear it; the curve turns at the root
    (rigidly) instead, and is collision free."""
    n = 4
    pts, offs = scenes.pack([scenes.straight_curve([0.013, 0.021, 0], [0, 0, 1], 1.0, n + 1)])
    V, F = scenes.quad([-0.5, -0.5, 0.08], [1.0, 0, 0.04], [0, 1.0, 0])
    res = Solver(offs, Settings(mode="bend")).step(pts, [Collider(V, F)])
    assert np.asarray(res.status)[0] == Status.COLLIDING
    assert not oracle.segments_hit_mesh(res.points, offs, V, F)[0]
    a = geom.angle_between(np.diff(pts, axis=0), np.diff(res.points, axis=0))
    np.testing.assert_allclose(a, a[0], atol=1e-9)  # rigid: same angle everywhere
    assert np.degrees(a[0]) > 180 / n  # more than bending could give the root segment
    # it stays rigid until recovered, then recovers exactly
    solver = Solver(offs, Settings(mode="bend", recovery_rate=0.5))
    solver.step(pts, [Collider(V, F)])
    state = solver.state
    assert state["stiff"][0] and state["contact"][0]
    # its angle is now counted on Stiff's grid: the search's memory of the last
    # change (a Bend angle's) does not carry over
    assert state["delta"][0] == 0.0
    for _ in range(100):
        r = solver.step(pts, [])
        a = geom.angle_between(np.diff(pts, axis=0), np.diff(r.points, axis=0))
        np.testing.assert_allclose(a, a[0], atol=1e-9)
        if np.array_equal(r.points, pts):
            break
    assert np.array_equal(r.points, pts)


def test_a_curve_back_at_its_input_shape_remembers_nothing():
    """A curve that recovered to exactly its input shape drops its local state
    (``rigid.release``), Bend's fall back to Stiff included: its next contact is solved
    bit for bit as a fresh solver solves it."""
    n = 4
    pts, offs = scenes.pack([scenes.straight_curve([0.013, 0.021, 0], [0, 0, 1], 1.0, n + 1)])
    wall = Collider(*scenes.quad([-0.5, -0.5, 0.08], [1.0, 0, 0.04], [0, 1.0, 0]))
    ball = Collider(*scenes.uv_sphere([0.1, 0, 0.9], 0.3, 32, 16))
    settings = Settings(mode="bend", recovery_rate=1.0)
    fresh = Solver(offs, settings).step(pts, [ball])
    assert np.asarray(fresh.status)[0] == Status.COLLIDING
    solver = Solver(offs, settings)
    for cols, stiff in (([ball], False), ([], False), ([wall], True), ([], False)):
        r = solver.step(pts, cols)
        assert solver.state["stiff"][0] == stiff, cols  # (bent, released, Stiff, released)
        assert np.array_equal(r.points, pts) == (not cols)
    again = solver.step(pts, [ball])
    assert np.array_equal(again.points, fresh.points)
    assert not solver.state["stiff"][0]


def test_an_unresolved_bend_curve_keeps_its_last_bent_shape():
    """Bend, then boxed in: neither bending nor the fall back to Stiff finds an angle.
    The curve is UNRESOLVED in its last collision-free shape, bent as it was (the fall
    back's Stiff flag is undone), and bends on from there when it can again."""
    curve = scenes.straight_curve([0, 0, 0], [0, 0, 1], 1.0, 5)
    pts, offs = scenes.pack([curve])
    ball = Collider(*scenes.uv_sphere([0.05, 0, 0.8], 0.3, 32, 16))
    solver = Solver(offs, Settings(mode="bend", recovery_rate=0.0))
    r1 = solver.step(pts, [ball])
    assert np.asarray(r1.status)[0] == Status.COLLIDING and not solver.state["stiff"][0]
    a = geom.angle_between(np.diff(pts, axis=0), np.diff(r1.points, axis=0))
    assert a[-1] > 2 * a[0] > 0  # bent, not turned rigidly
    # a double-sided sphere around the root (no pinch) crosses every shape of the curve
    box = Collider(*scenes.uv_sphere([0, 0, 0], 0.5, 16, 8), double_sided=True)
    r2 = solver.step(pts, [ball, box])
    assert np.asarray(r2.status)[0] == Status.UNRESOLVED
    np.testing.assert_allclose(r2.points, r1.points, atol=1e-12)
    assert not solver.state["stiff"][0]


@pytest.mark.parametrize("modes", [("stiff", "soft"), ("soft", "bend"), ("bend", "stiff")])
def test_switching_mode_mid_shot_keeps_the_invariants(modes):
    """Settings switched to another mode mid-shot (the solver resets): every frame after
    keeps no resolved crossing, roots exact, no NaN; the switched solver equals a fresh
    solver in the new mode started at the switch."""
    rng = np.random.default_rng(5)
    pts, offs = scenes.fur_on_plane(rng, n_curves=70, curly=0.2, extent=0.9, n_cvs=(3, 8))
    V, F = scenes.uv_sphere([0, 0, 0], 0.4, 24, 12)
    col = Collider(V, F)
    solver = Solver(offs, Settings(mode=modes[0]))
    fresh = Solver(offs, Settings(mode=modes[1]))
    for f in range(6):
        col.matrix = scenes.turning_sweep(f)
        if f == 3:
            solver.settings = Settings(mode=modes[1])
        res = solver.step(pts, [col])
        geom.assert_roots_exact(pts, res.points, offs)
        assert np.isfinite(res.points).all()
        geom.assert_no_intersection(res.points, offs, res.status,
                                    [(oracle.transform(V, col.matrix), F)],
                                    excluded=geom.EXCLUDED_OR_INVALID)
        if f >= 3:
            ref = fresh.step(pts, [col])
            np.testing.assert_array_equal(res.points, ref.points)
            np.testing.assert_array_equal(res.status, ref.status)
    snap = solver.state  # a snapshot of the new mode restores into a solver of that mode
    other = Solver(offs, Settings(mode=modes[1]))
    other.state = snap
    with pytest.raises(ValueError, match="another mode"):
        Solver(offs, Settings(mode=modes[0])).state = snap
