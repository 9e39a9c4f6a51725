"""collision_offset (settings) and the per-collider offset override."""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes
import strategies as strat
from geom import EXCLUDED, FAST
from hypothesis import given
from hypothesis import strategies as st

from core import Collider, Settings, Solver, Status


def _scene(data, n=25):
    """Drawn fur and a drawn sphere (centre, radius) over it; the unit sphere mesh is
    placed by the test."""
    pts, offs, _V, _F, c, r = data.draw(strat.sphere_scenes(
        max_curves=n, center=((-0.3, 0.3), (-0.3, 0.3), (0.8, 1.1)), radius=(0.2, 0.4)),
        label="scene")
    V, F = scenes.uv_sphere([0, 0, 0], 1.0, 32, 16)
    return pts, offs, V, F, c, r


def _fixed_scene(seed, n=25):
    rng = np.random.default_rng(seed)
    pts, offs = scenes.fur_on_plane(rng, n_curves=n, curly=0.2, extent=0.6, n_cvs=(3, 10))
    r = rng.uniform(0.2, 0.4)
    c = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(0.8, 1.1)])
    V, F = scenes.uv_sphere([0, 0, 0], 1.0, 32, 16)
    return pts, offs, V, F, c, r


def _min_dist(points, offs, c):
    return oracle.curve_distance_to_sphere_center(points, offs, c)


def _inradius_factor(V, F):
    """Smallest distance from the centre to a face plane of the unit mesh:
    a curve resting on a flat face of the (inflated) tessellated sphere is
    that much closer than the sphere radius."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return float(np.abs(np.einsum("ij,ij->i", n, a)).min())


def _floor(V, F, r, d):
    """Lowest allowed centre distance with offset d: the inflated mesh's face
    planes (k * (r + d)) minus the 10% tolerance of the offset."""
    return _inradius_factor(V, F) * (r + d) - 0.1 * d


@FAST
@given(data=st.data(), mode=st.sampled_from(["stiff", "bend", "soft"]),
       d=st.sampled_from([0.02, 0.1, 0.2]), mirror=st.booleans())
def test_settings_offset_keeps_distance(data, mode, d, mirror):
    pts, offs, V, F, c, r = _scene(data)
    M = scenes.affine(t=c, s=r)
    if mirror:  # det < 0 (a mirrored object): the same sphere, faces wound the other way
        M[:3, 0] *= -1.0
    col = Collider(V, F, matrix=M)
    res = Solver(offs, Settings(mode=mode, collision_offset=d)).step(pts, [col])
    status = np.asarray(res.status)
    keep = ~np.isin(status, EXCLUDED)
    dist = _min_dist(res.points, offs, c)
    assert np.all(dist[keep] >= _floor(V, F, r, d)), (dist[keep].min(), r + d)
    geom.assert_roots_exact(pts, res.points, offs)
    # curves already farther than r + d are untouched (first frame)
    far = _min_dist(pts, offs, c) > r + 1.1 * d
    for k in np.nonzero(far)[0]:
        assert status[k] == Status.FREE
        assert np.array_equal(res.points[offs[k]:offs[k + 1]], pts[offs[k]:offs[k + 1]])


def test_offset_curves_stop_near_inflated_surface():
    """With the offset, resolved curves end just outside r + d (within a few
    precision steps), not far away."""
    pts, offs, V, F, _, _ = _fixed_scene(1, n=40)
    c, r, d = np.array([0.0, 0.0, 0.9]), 0.35, 0.1
    col = Collider(V, F, matrix=scenes.affine(t=c, s=r))
    res = Solver(offs, Settings(mode="stiff", collision_offset=d)).step(pts, [col])
    status = np.asarray(res.status)
    hit = status == Status.COLLIDING
    assert hit.sum() >= 3
    dist = _min_dist(res.points, offs, c)
    assert np.median(dist[hit]) < r + 1.5 * d


def test_collider_offset_overrides_settings():
    pts, offs, V, F, c, r = _fixed_scene(2, n=40)
    M = scenes.affine(t=c, s=r)
    # per-collider 0.2 beats settings 0
    res = Solver(offs, Settings(mode="bend")).step(pts, [Collider(V, F, matrix=M, offset=0.2)])
    keep = ~np.isin(np.asarray(res.status), EXCLUDED)
    dist = _min_dist(res.points, offs, c)
    assert np.all(dist[keep] >= _floor(V, F, r, 0.2))
    # per-collider 0 beats settings 0.2: curves come closer than 0.2
    res0 = Solver(offs, Settings(mode="bend", collision_offset=0.2)).step(
        pts, [Collider(V, F, matrix=M, offset=0.0)])
    st0 = np.asarray(res0.status)
    dist0 = _min_dist(res0.points, offs, c)
    hit = st0 == Status.COLLIDING
    assert hit.any()
    assert dist0[hit].min() < r + 0.1
    geom.assert_no_intersection(res0.points, offs, st0, [(oracle.transform(V, M), F)])


def test_offset_is_per_collider():
    """Two spheres, different offsets: each keeps its own distance."""
    rng = np.random.default_rng(4)
    pts, offs = scenes.fur_on_plane(rng, n_curves=60, curly=0.1, extent=1.0, n_cvs=(3, 8))
    V, F = scenes.uv_sphere([0, 0, 0], 1.0, 32, 16)
    c1, c2, r = np.array([-0.5, 0, 0.9]), np.array([0.5, 0, 0.9]), 0.3
    cols = [Collider(V, F, matrix=scenes.affine(t=c1, s=r), offset=0.05),
            Collider(V, F, matrix=scenes.affine(t=c2, s=r), offset=0.15)]
    res = Solver(offs, Settings(mode="stiff")).step(pts, cols)
    keep = ~np.isin(np.asarray(res.status), EXCLUDED)
    assert np.all(_min_dist(res.points, offs, c1)[keep] >= _floor(V, F, r, 0.05))
    assert np.all(_min_dist(res.points, offs, c2)[keep] >= _floor(V, F, r, 0.15))
    # and the two offsets really differ: curves pushed by ball 2 stay farther
    assert _floor(V, F, r, 0.15) > r + 0.05


@pytest.mark.parametrize("d", [0.05, 0.2])
def test_offset_near_and_far_roots(d):
    """A root farther than the offset from a closed collider is not pinched;
    a root closer than the offset cannot keep the distance, so its curve
    must be excluded (PINCHED or UNRESOLVED), never silently too close."""
    V, F = scenes.uv_sphere([0, 0, 0], 0.5, 32, 16)
    far = scenes.straight_curve([0.5 + 3 * d, 0, 0], [1, 0, 0], 0.5, 4)
    near = scenes.straight_curve([0, 0.5 + 0.4 * d, 0], [0, 1, 0], 0.5, 4)
    pts, offs = scenes.pack([far, near])
    res = Solver(offs, Settings(collision_offset=d)).step(pts, [Collider(V, F)])
    status = np.asarray(res.status)
    assert status[0] == Status.FREE
    assert np.array_equal(res.points[:4], pts[:4])
    assert status[1] in (Status.PINCHED, Status.UNRESOLVED), status[1]


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
@pytest.mark.parametrize("side", ["front", "double", "back"])
def test_offset_on_open_plane(mode, side):
    """Fur under a large open sheet at z = 0.5 with offset d: whichever way
    the sheet faces (an open sheet has no inside) or double-sided, curves stay
    >= ~d below it and never cross it."""
    rng = np.random.default_rng(1)
    pts, offs = scenes.fur_on_plane(rng, n_curves=60, extent=0.6, curly=0.2)
    V, F = scenes.grid(size=4.0, n=4, z=0.5)
    d = 0.1
    FF = scenes.flip(F) if side == "front" else F
    col = Collider(V, FF, double_sided=(side == "double"))
    res = Solver(offs, Settings(mode=mode, collision_offset=d)).step(pts, [col])
    status = np.asarray(res.status)
    keep = ~np.isin(status, EXCLUDED)
    assert np.count_nonzero(status == Status.COLLIDING) >= 30
    zmax = np.array([res.points[offs[c]:offs[c + 1], 2].max() for c in range(len(offs) - 1)])
    limit = 0.5 - 0.9 * d
    assert np.all(zmax[keep] <= limit + 1e-9), zmax[keep].max()
    geom.assert_no_intersection(res.points, offs, status, [(V, F)])


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
@pytest.mark.parametrize("double_sided", [False, True])
@pytest.mark.parametrize("d", [0.0, 0.1])
def test_offset_never_lets_a_curve_through_an_open_sheet(mode, double_sided, d):
    """Regression: a curve entering from beyond the rim crosses the sheet while
    staying between its two offset copies (+-d); it must still be caught."""
    V, F = scenes.grid(size=2.0, n=2, z=0.5)  # sheet z = 0.5, |x|, |y| <= 1
    pts = np.array([[1.5, 0.01, 0.0], [1.1, 0.01, 0.45], [0.7, 0.01, 0.55],
                    [0.3, 0.01, 0.58]])
    offs = np.array([0, 4])
    assert oracle.segments_hit_mesh(pts, offs, V, F)[0]
    col = Collider(V, F, double_sided=double_sided)
    res = Solver(offs, Settings(mode=mode, collision_offset=d)).step(pts, [col])
    assert np.asarray(res.status)[0] != Status.FREE
    geom.assert_no_intersection(res.points, offs, res.status, [(V, F)])


@pytest.mark.parametrize("flip", [False, True])
def test_offset_shell_of_a_box_is_the_offset_everywhere_on_a_face(flip):
    """Curves whose tips stop 1.1 offsets below a box's bottom face, across the
    whole face up to its corners, stay free, whatever the faces' triangulation
    (a corner split into two triangles once pushed its face out by twice the
    offset). 0.9 offsets below, every one of them is pushed."""
    h, off = 0.5, 0.3
    V = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    F = []
    for a, b, c, d in quads:  # each quad's diagonal either way
        F += [(a, b, d), (b, c, d)] if flip else [(a, b, c), (a, c, d)]
    xs = np.linspace(-h * 0.98, h * 0.98, 7)
    roots = np.array([[x, y, -2.0] for x in xs for y in xs])
    for gap, free in ((1.1, True), (0.9, False)):
        tip_z = -h - gap * off
        t = np.linspace(0.0, 1.0, 5)[:, None]
        pts = (roots[:, None, :] + t * np.array([0.0, 0.0, tip_z + 2.0])).reshape(-1, 3)
        offs = np.arange(0, len(pts) + 1, 5)
        col = Collider(V, np.array(F), offset=off)
        res = Solver(offs, Settings(mode="stiff")).step(pts, [col])
        if free:
            assert (res.status == Status.FREE).all(), np.flatnonzero(res.status)
            np.testing.assert_array_equal(res.points, pts)
        else:
            assert (res.status == Status.COLLIDING).all(), res.status
