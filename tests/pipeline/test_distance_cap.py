"""Collider Distance with a cap (``max_distance``), exact search (``exact=True``): exactly
min(true distance, cap). The default node field: tests/pipeline/test_distance_field.py."""

from __future__ import annotations

import numpy as np
import pipe_oracle as po
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core import Collider
from core.errors import InputError
from core.pipeline import collider_distance, segment_mesh_distance, segment_triangle_distance

PROP = settings(max_examples=examples(12))
TOL = 1e-9


def _scene(rng, n_curves=10, n_cvs=5, spread=1.2):
    V, F = po.icosphere(rng.uniform(-0.3, 0.3, 3), rng.uniform(0.3, 0.7), sub=2)
    curves = []
    for _ in range(n_curves):
        root = rng.uniform(-spread, spread, 3)
        steps = rng.normal(0, 0.15, (n_cvs - 1, 3))
        curves.append(np.vstack([root, root + np.cumsum(steps, 0)]))
    pts, off = po.pack(curves)
    return V, F, pts, off


def _tricky_pairs(rng, k):
    """Segments and triangles in the configurations that break distance code: parallel
    to the plane above the interior or an edge, coplanar (crossing, outside, along an
    edge), through a vertex or an edge, touching with an end point, zero-length,
    parallel to an edge, and random ones."""
    t0, t1, t2 = (rng.normal(0, 1, (k, 3)) for _ in range(3))
    n = np.cross(t1 - t0, t2 - t0)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    bary = rng.dirichlet([1, 1, 1], k)
    inner = bary[:, :1] * t0 + bary[:, 1:2] * t1 + bary[:, 2:] * t2
    dirs = np.cross(n, rng.normal(0, 1, (k, 3)))  # in the plane
    h = rng.uniform(-1, 1, (k, 1))
    kind = np.arange(k) % 10
    a = rng.normal(0, 1, (k, 3))
    b = rng.normal(0, 1, (k, 3))
    sel = [kind == i for i in range(10)]
    a[sel[0]] = (inner + h * n - dirs)[sel[0]]  # parallel, above the interior
    b[sel[0]] = (inner + h * n + dirs)[sel[0]]
    a[sel[1]] = (inner - dirs * 3)[sel[1]]  # coplanar, through the triangle
    b[sel[1]] = (inner + dirs * 3)[sel[1]]
    far = inner + 5 * (inner - t0)
    a[sel[2]] = far[sel[2]]  # coplanar, outside
    b[sel[2]] = (far + dirs)[sel[2]]
    a[sel[3]] = (t0 + 0.2 * (t1 - t0))[sel[3]]  # along an edge
    b[sel[3]] = (t0 + 0.7 * (t1 - t0))[sel[3]]
    a[sel[4]] = (t2 - n)[sel[4]]  # through a vertex
    b[sel[4]] = (t2 + n)[sel[4]]
    mid = 0.5 * (t0 + t1)
    a[sel[5]] = (mid - n)[sel[5]]  # through an edge
    b[sel[5]] = (mid + n)[sel[5]]
    a[sel[6]] = inner[sel[6]]  # an end point on the triangle
    b[sel[6]] = (inner + h * n)[sel[6]]
    b[sel[7]] = a[sel[7]]  # zero length
    a[sel[8]] = (mid + h * n + 0.3 * (t1 - t0))[sel[8]]  # parallel to an edge, above it
    b[sel[8]] = (mid + h * n - 0.3 * (t1 - t0))[sel[8]]
    return a, b, t0, t1, t2


def test_the_oracles_segment_triangle_distance_against_sampling():
    """The oracle itself (pipe_oracle.segment_triangle_distance) against dense sampling
    of the segment: exact up to the sampling's own bound."""
    rng = np.random.default_rng(4)
    a, b, t0, t1, t2 = _tricky_pairs(rng, 400)
    d = po.segment_triangle_distance(a, b, t0, t1, t2)
    n = 2001
    for i in range(0, 400, 3):
        q = a[i] + np.linspace(0, 1, n)[:, None] * (b[i] - a[i])
        est = po.point_mesh_distance(q, np.array([t0[i], t1[i], t2[i]]),
                                     np.array([[0, 1, 2]])).min()
        slack = np.linalg.norm(b[i] - a[i]) / (2 * (n - 1))
        assert est - slack - 1e-12 <= d[i] <= est + 1e-12, (i, i % 10, d[i], est)


def test_segment_triangle_distance_equals_the_oracle():
    """core.pipeline.segment_triangle_distance against the independent oracle, to
    1e-12, on random and degenerate configurations."""
    rng = np.random.default_rng(5)
    a, b, t0, t1, t2 = _tricky_pairs(rng, 4000)
    want = po.segment_triangle_distance(a, b, t0, t1, t2)
    got = segment_triangle_distance(a, b, t0, t1, t2)
    bad = np.flatnonzero(np.abs(got - want) > 1e-12)
    assert len(bad) == 0, [(int(i), int(i % 10), got[i], want[i]) for i in bad[:5]]
    assert (want[np.arange(4000) % 10 == 1] < 1e-12).all()  # coplanar through: they meet


def test_segment_segment_distance_equals_the_oracle():
    """core's segment-segment distance (Ericson's clamping) against the oracle's
    (the unconstrained minimum if inside the unit square, else the end points')."""
    from core.pipeline.distance import segment_segment_distance

    rng = np.random.default_rng(6)
    k = 3000
    p0, p1, q0, q1 = (rng.normal(0, 1, (k, 3)) for _ in range(4))
    kind = np.arange(k) % 5
    q1[kind == 1] = (q0 + (p1 - p0) * 0.7)[kind == 1]  # parallel
    q0[kind == 2] = (p0 + 0.5 * (p1 - p0))[kind == 2]  # touching
    p1[kind == 3] = p0[kind == 3]  # a point
    q1[kind == 4] = (q0 - (p1 - p0) * 2.0)[kind == 4]  # anti-parallel
    want = po.segment_segment_distance_rows(p0, p1, q0, q1)
    got = segment_segment_distance(p0, p1, q0, q1)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_segment_triangle_distance_against_sampling():
    rng = np.random.default_rng(0)
    k = 400
    a, b = rng.normal(0, 1, (k, 3)), rng.normal(0, 1, (k, 3))
    t0, t1, t2 = (rng.normal(0, 1, (k, 3)) for _ in range(3))
    d = segment_triangle_distance(a, b, t0, t1, t2)
    n = 201
    for i in range(0, k, 40):
        q = a[i] + np.linspace(0, 1, n)[:, None] * (b[i] - a[i])
        est = po.point_mesh_distance(q, np.array([t0[i], t1[i], t2[i]]), np.array([[0, 1, 2]]))
        est = est.min()
        slack = np.linalg.norm(b[i] - a[i]) / (2 * (n - 1))
        assert est - slack - 1e-12 <= d[i] <= est + 1e-12


@PROP
@given(seed=st.integers(0, 10_000), cap=st.floats(0.0, 1.5), spread=st.floats(0.6, 3.0))
def test_capped_is_min_of_brute_force_and_cap(seed, cap, spread):
    rng = np.random.default_rng(seed)
    V, F, pts, off = _scene(rng, spread=spread)
    truth = po.brute_cv(pts, off, [(V, F)])
    d, exact = collider_distance(pts, off, [(V, F)], max_distance=cap, return_exact=True,
                                 exact=True)
    assert (d <= truth + TOL).all(), "never above the truth"
    assert (d <= cap).all()
    want = np.minimum(truth, cap)
    np.testing.assert_allclose(d[exact], want[exact], rtol=0, atol=TOL)
    assert exact.all()  # small meshes: every search settles
    # the uncapped result, capped afterwards, is the same where it is exact
    du, eu = collider_distance(pts, off, [(V, F)], return_exact=True, exact=True)
    np.testing.assert_allclose(d[eu], np.minimum(du, cap)[eu], rtol=0, atol=TOL)


@PROP
@given(seed=st.integers(0, 10_000), cap=st.floats(0.01, 1.0),
       uniform=st.booleans())
def test_capped_collider_with_matrix(seed, cap, uniform):
    """A Collider with a transform (similarity or not): same as its world mesh."""
    rng = np.random.default_rng(seed)
    V, F, pts, off = _scene(rng, n_curves=8, n_cvs=4)
    R = po.rotation(rng.normal(0, 1, 3), rng.uniform(0, 3))
    S = np.diag(np.full(3, 1.3) if uniform else rng.uniform(0.6, 1.6, 3))
    M = np.eye(4)
    M[:3, :3] = R @ S
    M[:3, 3] = rng.uniform(-0.3, 0.3, 3)
    col = Collider(V, F, matrix=M)
    Vw = V.astype(np.float32).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    truth = po.brute_cv(pts, off, [(Vw, F)])
    for _ in range(2):  # the second call may reuse cached structures
        d = collider_distance(pts, off, [col], max_distance=cap, exact=True)
        np.testing.assert_allclose(d, np.minimum(truth, cap), rtol=0, atol=TOL)
        assert (d <= truth + TOL).all()


def test_several_colliders_with_cap():
    rng = np.random.default_rng(7)
    pts, off = po.fur_on_plane(rng, 12, 5, 1.0)
    a = po.icosphere((0, 0, 1.2), 0.5, 2)
    b = po.icosphere((0.5, 0, 0.9), 0.3, 2)
    truth = po.brute_cv(pts, off, [a, b])
    for cap in (0.05, 0.2, 0.6):
        d = collider_distance(pts, off, [a, Collider(*b)], max_distance=cap, exact=True)
        Vb = b[0].astype(np.float32).astype(np.float64)
        truth = po.brute_cv(pts, off, [a, (Vb, b[1])])
        np.testing.assert_allclose(d, np.minimum(truth, cap), rtol=0, atol=TOL)


def test_moved_and_deformed_collider_is_not_stale():
    """Cached structures follow the collider's matrix and vertices."""
    rng = np.random.default_rng(8)
    pts, off = po.fur_on_plane(rng, 15, 5, 1.0)
    V, F = po.icosphere((0, 0, 0.8), 0.5, 2)
    col = Collider(V, F)
    cap = 0.5
    for step in range(3):
        M = np.eye(4)
        M[:3, 3] = [0.2 * step, 0, 0.1 * step]
        col.matrix = M
        if step == 2:
            col.vertices = V * [1.0, 1.2, 0.8]
        Vw = col.vertices.astype(np.float64) + M[:3, 3]
        truth = po.brute_cv(pts, off, [(Vw, F)])
        d = collider_distance(pts, off, [col], max_distance=cap, exact=True)
        np.testing.assert_allclose(d, np.minimum(truth, cap), rtol=0, atol=TOL)


def test_cap_zero_gives_zeros_and_no_collider_gives_the_cap():
    rng = np.random.default_rng(9)
    pts, off = po.fur_on_plane(rng, 10, 4, 1.0)
    sphere = po.icosphere((0, 0, 2), 0.5, 1)
    d, exact = collider_distance(pts, off, [sphere], max_distance=0.0, return_exact=True)
    assert (d == 0).all() and exact.all()
    np.testing.assert_array_equal(collider_distance(pts, off, [], max_distance=0.3),
                                  np.full(len(pts), 0.3))
    np.testing.assert_array_equal(collider_distance(pts, off, [sphere], max_distance=np.inf),
                                  collider_distance(pts, off, [sphere]))
    np.testing.assert_array_equal(collider_distance(pts, off, [sphere], max_distance=None),
                                  collider_distance(pts, off, [sphere]))


def test_segment_mesh_distance_cap():
    V, F = po.grid(4.0, 8, z=0.0)
    A = np.array([[0.1, 0.2, 0.3], [0.0, 0.0, 2.0], [0.3, 0.3, -0.05]])
    B = A + [0.1, 0.0, 0.0]
    d, exact = segment_mesh_distance(A, B, V, F, max_distance=0.5)
    np.testing.assert_allclose(d, [0.3, 0.5, 0.05], atol=1e-12)
    assert exact.all()


@pytest.mark.parametrize("bad", [-0.1, float("nan"), "far", True, [0.1, 0.2], -np.inf])
def test_invalid_cap_raises(bad):
    pts, off = po.pack([np.array([[0.0, 0, 0], [0, 0, 1]])])
    with pytest.raises(InputError, match="max_distance"):
        collider_distance(pts, off, [po.grid(2.0, 2)], max_distance=bad)
    with pytest.raises(InputError, match="max_distance"):
        segment_mesh_distance(pts[:1], pts[1:], *po.grid(2.0, 2), max_distance=bad)


def test_capped_huge_and_tiny_triangles():
    """A ground plane of 2 huge triangles next to a fine sphere (triangles in no cell)."""
    pts, off, V, F = po.sphere_and_ground()
    truth = po.brute_cv(pts, off, [(V, F)])
    for cap in (0.02, 0.1, 0.3):
        d, exact = collider_distance(pts, off, [(V, F)], max_distance=cap, return_exact=True)
        assert exact.all()
        np.testing.assert_allclose(d, np.minimum(truth, cap), rtol=0, atol=TOL)


def test_capped_fine_mesh_many_curves():
    """A finer mesh (5,120 triangles) and fur around it: every search path is taken
    (cleared by the field, by the coarse slabs, exact), the curves move between calls
    (cached structures reused) and the collider rotates and scales uniformly."""
    rng = np.random.default_rng(21)
    V, F = po.icosphere((0, 0, 0), 0.6, 4)
    V = V * (1 + 0.05 * np.sin(5 * V[:, :1]))  # bumpy, not a sphere
    pts, off = po.fur_on_mesh(rng, V, F, n_curves=40, n_cvs=5, length=0.3, noise=0.6)
    pts = pts + rng.normal(0, 0.05, pts.shape)  # some curves off the surface, some inside
    col = Collider(V, F)
    for step in range(2):
        M = np.eye(4)
        M[:3, :3] = po.rotation([1, 1, 0], 0.3 * step) * (1 + 0.1 * step)
        M[:3, 3] = [0.02 * step, 0, 0]
        col.matrix = M
        moved = pts + 0.01 * step
        Vw = V.astype(np.float32).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
        truth = po.brute_cv(moved, off, [(Vw, F)])
        for cap in (0.01, 0.06):
            d, exact = collider_distance(moved, off, [col], max_distance=cap,
                                         return_exact=True, exact=True)
            assert (d <= truth + TOL).all()
            np.testing.assert_allclose(d[exact], np.minimum(truth, cap)[exact], rtol=0,
                                       atol=TOL)
            assert exact.mean() > 0.99


def test_float32_rigid_matrix_keeps_the_cache_and_never_overestimates():
    """A Blender matrix is float32: a rotation up to rounding still moves the queries
    (the collider's index is built once), and the distance stays a lower bound."""
    from core.pipeline.distance import _collider_index

    rng = np.random.default_rng(31)
    V, F, pts, off = _scene(rng, n_curves=8, n_cvs=4)
    col = Collider(V, F)
    built = None
    for step in range(3):
        M = np.eye(4)
        M[:3, :3] = po.rotation([1, 2, 3], 0.4 + 0.3 * step) * 1.1
        M[:3, 3] = [0.1 * step, 0.0, -0.05 * step]
        M = M.astype(np.float32).astype(np.float64)
        col.matrix = M
        index = _collider_index(col)[0]
        assert built is None or index is built
        built = index
        Vw = V.astype(np.float32).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
        truth = po.brute_cv(pts, off, [(Vw, F)])
        d = collider_distance(pts, off, [col], max_distance=0.3, exact=True)
        want = np.minimum(truth, 0.3)
        assert (d <= truth + TOL).all()
        np.testing.assert_allclose(d, want, rtol=1e-6, atol=TOL)
