"""Pinch detection (paper 3.1) and resolution (3.2.5): pinch_resolution,
recover_pinched; only closed single-sided colliders pinch."""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes
import strategies as strat
from geom import FAST
from hypothesis import given
from hypothesis import strategies as st

from core import Collider, Settings, Solver, Status


def _fur(n=5):
    """A row of straight-ish vertical curves on the plane z=0, x in [-0.4, 0.4]."""
    curves = [scenes.curly_curve([x, 0.01 * i, 0], [0.1, 0.05, 1], 1.0, 6, amplitude=0.05)
              for i, x in enumerate(np.linspace(-0.4, 0.4, n))]
    return scenes.pack(curves)


def _growth():
    V, F = scenes.grid(size=6.0, n=6, z=0.0)
    return V, F, Collider(V, F)


def _engulfing_sphere():
    """Closed sphere containing every root (radius 0.7 at the origin)."""
    return scenes.uv_sphere([0, 0, 0.1], 0.7, 24, 12)


def test_root_inside_closed_single_sided_is_pinched():
    pts, offs = _fur()
    V, F = _engulfing_sphere()
    col = Collider(V, F)
    assert col.closed
    res = Solver(offs, Settings(pinch_resolution="stop")).step(pts, [col])
    assert np.all(np.asarray(res.status) == Status.PINCHED)
    # stop + no prior state: the input, untouched
    assert np.array_equal(res.points, pts)


@pytest.mark.parametrize("make", [
    lambda V, F: Collider(V, F, double_sided=True),  # double-sided
    lambda V, F: Collider(V, F[:-3]),  # open (3 faces removed)
], ids=["double-sided", "open"])
def test_never_pinched(make):
    pts, offs = _fur()
    V, F = _engulfing_sphere()
    res = Solver(offs, Settings()).step(pts, [make(V, F)])
    assert not np.any(np.asarray(res.status) == Status.PINCHED)


def test_box_pinch_whatever_the_winding():
    """A closed mesh wound inward (flipped normals) is wound outward again
    (core.meshfix): its inside is still an inside, roots there are pinched."""
    V, F = scenes.box([-1, -1, -0.5], [1, 1, 0.3])
    pts, offs = _fur()
    for faces in (F, scenes.flip(F)):
        col = Collider(V, faces)
        assert col.closed
        r = Solver(offs, Settings()).step(pts, [col])
        assert np.all(np.asarray(r.status) == Status.PINCHED)
    assert Collider(V, scenes.flip(F)).repairs.flipped == len(F)


def test_only_roots_inside_are_pinched():
    pts, offs = _fur(9)
    V, F = scenes.uv_sphere([0.4, 0, 0], 0.25, 24, 12)  # around the last roots
    res = Solver(offs, Settings()).step(pts, [Collider(V, F)])
    status = np.asarray(res.status)
    inside = oracle.points_inside_closed_mesh(pts[offs[:-1]], V, F)
    assert inside.any() and not inside.all()
    assert np.array_equal(status == Status.PINCHED, inside)


def test_stop_keeps_prior_local_state():
    pts, offs = _fur()
    Vs, Fs = scenes.uv_sphere([0.0, 0.0, 0.0], 0.25, 24, 12)  # used as a moving ball
    ball = Collider(Vs, Fs, matrix=scenes.translation([0.05, 0.1, 0.95]))
    solver = Solver(offs, Settings(mode="bend", pinch_resolution="stop", recovery_rate=0.5))
    r1 = solver.step(pts, [ball])
    assert np.any(np.asarray(r1.status) == Status.COLLIDING)
    # the ball drops onto the roots and grows to engulf them all
    ball.matrix = scenes.affine(t=[0, 0, 0.1], s=3.0)
    r2 = solver.step(pts, [ball])
    assert np.all(np.asarray(r2.status) == Status.PINCHED)
    np.testing.assert_allclose(r2.points, r1.points, atol=1e-12)


@pytest.mark.parametrize(("mode", "factor"), [("stiff", 0.1), ("soft", 0.1), ("bend", 0.5)])
def test_growth_surface_lays_pinched_curves_down(mode, factor):
    """Stiff/soft lay the whole curve along the surface; bend (a uniform bend
    from root to tip) can only bring it down as an arc, tip on the surface."""
    pts, offs = _fur()
    Vg, Fg, growth = _growth()
    V, F = _engulfing_sphere()
    s = Settings(mode=mode, pinch_resolution="growth_surface")
    res = Solver(offs, s).step(pts, [Collider(V, F)], growth=growth)
    status = np.asarray(res.status)
    assert np.all(status == Status.PINCHED)
    geom.assert_roots_exact(pts, res.points, offs)
    geom.assert_lengths_kept(pts, res.points, offs, rtol=1e-9)
    d_in = oracle.distance_to_plane(pts, [0, 0, 0], [0, 0, 1])
    d_out = oracle.distance_to_plane(res.points, [0, 0, 0], [0, 0, 1])
    assert d_out.mean() < factor * d_in.mean(), (d_out.mean(), d_in.mean())
    tips = res.points[offs[1:] - 1]
    assert np.all(np.abs(tips[:, 2]) < 0.05), tips
    # laid down onto the surface, not swung through it
    assert np.all(res.points[:, 2] >= -0.05)
    assert np.all(np.isfinite(res.points))


@pytest.mark.parametrize("resolution", ["stop", "growth_surface"])
def test_recover_pinched_true(resolution):
    pts, offs = _fur()
    _, _, growth = _growth()
    V, F = _engulfing_sphere()
    s = Settings(mode="bend", pinch_resolution=resolution, recover_pinched=True,
                 recovery_rate=1.0)
    solver = Solver(offs, s)
    solver.step(pts, [Collider(V, F)], growth=growth)
    r = solver.step(pts, [], growth=growth)
    assert np.array_equal(r.points, pts)
    assert np.all(np.asarray(r.status) == Status.FREE)


def test_recover_pinched_false_keeps_the_pinch_pose():
    pts, offs = _fur()
    _, _, growth = _growth()
    V, F = _engulfing_sphere()
    s = Settings(mode="bend", pinch_resolution="growth_surface", recover_pinched=False,
                 recovery_rate=1.0)
    solver = Solver(offs, s)
    r1 = solver.step(pts, [Collider(V, F)], growth=growth)
    assert not np.allclose(r1.points, pts)
    for _ in range(3):
        r = solver.step(pts, [], growth=growth)
        assert not np.any(np.asarray(r.status) == Status.PINCHED)
        np.testing.assert_allclose(r.points, r1.points, atol=1e-9)


def test_recover_pinched_false_still_resolves_new_collisions():
    """After coming out of a pinch, a kept pose must still not cut colliders."""
    pts, offs = _fur()
    _, _, growth = _growth()
    V, F = _engulfing_sphere()
    s = Settings(mode="bend", pinch_resolution="growth_surface", recover_pinched=False)
    solver = Solver(offs, s)
    solver.step(pts, [Collider(V, F)], growth=growth)
    Vb, Fb = scenes.uv_sphere([0.3, 0.0, 0.25], 0.2, 24, 12)
    r = solver.step(pts, [Collider(Vb, Fb)], growth=growth)
    geom.assert_no_intersection(r.points, offs, r.status, [(Vb, Fb)])


@pytest.mark.parametrize("mode", ["stiff", "soft", "bend"])
def test_growth_surface_on_a_curved_growth_mesh(mode):
    """Fur on a sphere; a ball engulfs the roots near the north pole. Put to
    Growth Surface brings the pinched curves down toward the sphere."""
    rng = np.random.default_rng(3)
    pts, offs = scenes.fur_on_sphere(rng, [0, 0, 0], 1.0, n_curves=200, n_cvs=(4, 8),
                                     length=(0.3, 0.5), curly=0.05)
    Vg, Fg = scenes.icosphere([0, 0, 0], 1.0, 3)
    Vb, Fb = scenes.uv_sphere([0, 0, 1.0], 0.3, 24, 12)
    s = Settings(mode=mode, pinch_resolution="growth_surface")
    res = Solver(offs, s).step(pts, [Collider(Vb, Fb)], growth=Collider(Vg, Fg))
    status = np.asarray(res.status)
    pinched = status == Status.PINCHED
    assert pinched.sum() >= 3
    sel = np.concatenate([np.arange(offs[c], offs[c + 1]) for c in np.nonzero(pinched)[0]])
    h_in = np.abs(np.linalg.norm(pts[sel], axis=1) - 1.0).mean()
    h_out = np.abs(np.linalg.norm(res.points[sel], axis=1) - 1.0).mean()
    factor = 0.5 if mode == "bend" else 0.25
    assert h_out < factor * h_in, (h_out, h_in)
    geom.assert_roots_exact(pts, res.points, offs)
    geom.assert_no_intersection(res.points, offs, status, [(Vb, Fb)])


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_pinched_pose_is_stable_and_held_when_disabled(mode):
    pts, offs = _fur()
    _, _, growth = _growth()
    V, F = _engulfing_sphere()
    col = Collider(V, F)
    s = Solver(offs, Settings(mode=mode, pinch_resolution="growth_surface"))
    r1 = s.step(pts, [col], growth=growth)
    r2 = s.step(pts, [col], growth=growth, enabled=np.zeros(len(offs) - 1, bool))
    assert np.all(np.asarray(r2.status) == Status.DISABLED)
    np.testing.assert_allclose(r2.points, r1.points, atol=1e-12)
    r3 = s.step(pts, [col], growth=growth)
    assert np.all(np.asarray(r3.status) == Status.PINCHED)
    np.testing.assert_allclose(r3.points, r1.points, atol=1e-12)


@FAST
@given(anchor=strat.curves(), kind=st.sampled_from(["sphere", "box", "icosphere", "bumpy",
                                                    "torus"]),
       mode=st.sampled_from(["stiff", "bend", "soft"]), data=st.data(),
       cloud=st.integers(0, 2**31 - 1))
def test_pinched_exactly_when_root_inside(anchor, kind, mode, data, cloud):
    """PINCHED <=> the root is inside a closed single-sided collider (parity
    oracle), for convex, concave and genus-1 colliders under any matrix. The
    collider is drawn (kind, size, orientation, placement); the 40 roots around it are
    a sample (``cloud``)."""
    spec = data.draw(strat.collider_specs([anchor], (kind,)), label="collider")
    rng = np.random.default_rng(cloud)
    Vw = scenes.world_vertices(spec)
    lo, hi = Vw.min(0), Vw.max(0)
    roots = rng.uniform(lo - 0.1, hi + 0.1, (40, 3))
    curves = [scenes.straight_curve(r, rng.normal(size=3), 0.3, 3) for r in roots]
    pts, offs = scenes.pack(curves)
    inside = oracle.points_inside_closed_mesh(roots, Vw, spec["F"])
    # robust: the same answer 1e-3 of the size away in several directions
    step = 1e-3 * np.linalg.norm(hi - lo)
    robust = np.ones(len(roots), bool)
    for dvec in np.eye(3).tolist() + (-np.eye(3)).tolist():
        robust &= oracle.points_inside_closed_mesh(roots + step * np.array(dvec), Vw,
                                                   spec["F"]) == inside
    for ds in (False, True):
        col = Collider(spec["V"], spec["F"], double_sided=ds, matrix=spec["matrix"])
        assert col.closed
        res = Solver(offs, Settings(mode=mode)).step(pts, [col])
        pinched = np.asarray(res.status) == Status.PINCHED
        if ds:
            assert not pinched.any()
        else:
            assert np.array_equal(pinched[robust], inside[robust])


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_recover_pinched_false_lets_unpinched_curves_recover(mode):
    """Recover Pinched Fur off holds only the curves that come out of a pinch: a curve
    that was only ever pushed recovers as usual when the collider leaves."""
    curve = scenes.straight_curve([0, 0, 0], [0, 0, 1], 1.0, 5)
    pts, offs = scenes.pack([curve])
    V, F = scenes.uv_sphere([0.12, 0.0, 0.8], 0.3, 32, 16)
    solver = Solver(offs, Settings(mode=mode, recover_pinched=False, recovery_rate=1.0))
    r = solver.step(pts, [Collider(V, F)])
    assert r.status[0] == Status.COLLIDING
    r = solver.step(pts, [])
    np.testing.assert_array_equal(r.points, pts)
    assert r.status[0] == Status.FREE
