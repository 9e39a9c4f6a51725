"""Ray backends (embree and the numpy reference) against the independent oracle."""

from __future__ import annotations

import numpy as np
import oracle
import pytest
import scenes
from geom import FAST, MEDIUM
from hypothesis import given
from hypothesis import strategies as st

from core import Collider, Settings, Solver, Status


def _random_matrix(rng):
    R = scenes.rotation_matrix(rng.normal(size=3), rng.uniform(0, np.pi))
    return scenes.affine(R, t=rng.uniform(-1, 1, 3), s=rng.uniform(0.5, 2.0))


def _soup(rng, n_tris):
    V = rng.uniform(-1, 1, (3 * n_tris, 3))
    F = np.arange(3 * n_tris).reshape(-1, 3)
    return V, F


@MEDIUM
@given(seed=st.integers(0, 2**31 - 1), n_tris=st.integers(1, 60),
       n_seg=st.integers(1, 300), use_matrix=st.booleans())
def test_segment_hits_match_oracle(seed, n_tris, n_seg, use_matrix):
    rng = np.random.default_rng(seed)
    V, F = _soup(rng, n_tris)
    M = _random_matrix(rng) if use_matrix else None
    Vw = oracle.transform(V, M)
    lo, hi = Vw.min(0), Vw.max(0)
    A = rng.uniform(lo - 0.2, hi + 0.2, (n_seg, 3))
    D = rng.normal(size=(n_seg, 3)) * rng.uniform(0.05, 1.5, (n_seg, 1)) * np.abs(hi - lo).max()
    sure = oracle.segment_hits(A, A + D, Vw, F, eps=oracle.SURE)
    maybe = oracle.segment_hits(A, A + D, Vw, F, eps=oracle.MAYBE)
    robust = sure == maybe
    results = {}
    for backend in ("embree", "numpy"):
        col = Collider(V, F, matrix=M, backend=backend)
        results[backend] = np.asarray(col.segment_hits(A, D))
        assert results[backend].shape == (n_seg,)
        assert np.array_equal(results[backend][robust], sure[robust]), backend
    assert np.array_equal(results["embree"][robust], results["numpy"][robust])


@FAST
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 200))
def test_contains_matches_parity_oracle(seed, n):
    rng = np.random.default_rng(seed)
    V, F = scenes.uv_sphere(radius=1.0, segments=16, rings=8)
    M = _random_matrix(rng)
    Vw = oracle.transform(V, M)
    lo, hi = Vw.min(0), Vw.max(0)
    P = rng.uniform(lo - 0.3, hi + 0.3, (n, 3))
    inside = oracle.points_inside_closed_mesh(P, Vw, F)
    # skip points too close to the surface to decide robustly
    center = M[:3, 3]
    s = np.cbrt(abs(np.linalg.det(M[:3, :3])))
    r = np.linalg.norm(P - center, axis=1) / s
    robust = (r < 0.9) | (r > 1.01)
    for backend in ("embree", "numpy"):
        col = Collider(V, F, matrix=M, backend=backend)
        got = np.asarray(col.contains(P))
        assert np.array_equal(got[robust], inside[robust]), backend


def _two_cv_curves(rng, n, lo, hi):
    A = rng.uniform(lo, hi, (n, 3))
    D = rng.normal(size=(n, 3))
    D *= rng.uniform(0.1, 1.0, (n, 1)) / np.linalg.norm(D, axis=1, keepdims=True)
    pts = np.empty((2 * n, 3))
    pts[0::2], pts[1::2] = A, A + D
    return pts, np.arange(0, 2 * n + 1, 2)


@FAST
@given(seed=st.integers(0, 2**31 - 1), n_curves=st.integers(1, 60),
       mode=st.sampled_from(["stiff", "bend", "soft"]))
def test_solver_backends_agree_with_oracle(seed, n_curves, mode):
    """Through the public solver: on the first frame a curve is FREE exactly
    when the oracle says its input does not cross the (open) collider, and the
    two backends give the same statuses and (to float tolerance) points."""
    rng = np.random.default_rng(seed)
    V, F = scenes.grid(size=2.0, n=3, z=0.0)
    # bumpy open surface
    V[:, 2] = 0.2 * np.sin(3 * V[:, 0]) * np.cos(2 * V[:, 1])
    M = _random_matrix(rng)
    Vw = oracle.transform(V, M)
    pts, offs = _two_cv_curves(rng, n_curves, Vw.min(0) - 0.2, Vw.max(0) + 0.2)
    sure = oracle.segments_hit_mesh(pts, offs, Vw, F, eps=oracle.SURE)
    maybe = oracle.segments_hit_mesh(pts, offs, Vw, F, eps=oracle.MAYBE)
    robust = sure == maybe
    out = {}
    for backend in ("embree", "numpy"):
        col = Collider(V, F, matrix=M, backend=backend)
        res = Solver(offs, Settings(mode=mode)).step(pts, [col])
        st_ = np.asarray(res.status)
        assert not np.any(st_ == Status.PINCHED), "open collider reported a pinch"
        free = st_ == Status.FREE
        assert np.array_equal(free[robust], ~sure[robust]), backend
        for c in np.nonzero(free)[0]:
            assert np.array_equal(res.points[offs[c]:offs[c + 1]], pts[offs[c]:offs[c + 1]])
        out[backend] = res
    agree = robust
    assert np.array_equal(np.asarray(out["embree"].status)[agree],
                          np.asarray(out["numpy"].status)[agree])
    for c in np.nonzero(agree)[0]:
        np.testing.assert_allclose(out["embree"].points[offs[c]:offs[c + 1]],
                                   out["numpy"].points[offs[c]:offs[c + 1]], atol=1e-5)


def test_backend_names():
    V, F = scenes.box()
    for b in (None, "embree", "numpy"):
        Collider(V, F, backend=b)
    with pytest.raises(ValueError, match="backend"):
        Collider(V, F, backend="octree-of-doom")


@FAST
@given(seed=st.integers(0, 2**31 - 1), mode=st.sampled_from(["stiff", "bend", "soft"]),
       kind=st.sampled_from(["sphere", "box", "icosphere"]))
def test_solver_backends_agree_on_closed_colliders(seed, mode, kind):
    """Closed colliders (pinch detection, inside tests): both backends give
    the same statuses; both outputs are collision free."""
    rng = np.random.default_rng(seed)
    pts, offs = scenes.fur_on_plane(rng, n_curves=30, extent=0.8, curly=0.2)
    spec = scenes.random_collider(rng, kind)
    Vw = scenes.world_vertices(spec)
    sure = oracle.segments_hit_mesh(pts, offs, Vw, spec["F"], eps=oracle.SURE)
    maybe = oracle.segments_hit_mesh(pts, offs, Vw, spec["F"], eps=oracle.MAYBE)
    robust = sure == maybe
    st_ = {}
    for backend in ("embree", "numpy"):
        col = Collider(spec["V"], spec["F"], double_sided=spec["double_sided"],
                       matrix=spec["matrix"], backend=backend)
        res = Solver(offs, Settings(mode=mode)).step(pts, [col])
        st_[backend] = np.asarray(res.status)
        keep = ~np.isin(st_[backend], [Status.PINCHED, Status.UNRESOLVED])
        hit = oracle.segments_hit_mesh(res.points, offs, Vw, spec["F"])
        assert not np.any(hit & keep), backend
    assert np.array_equal(st_["embree"][robust], st_["numpy"][robust])


def test_split_batches_on_pool_threads_run_inline():
    """Two pool tasks that each trace a batch big enough to split: on a pool
    thread a batch is traced inline (waiting for the pool's other threads from
    inside the pool could deadlock); the hits are those of the caller's split."""
    from core import rays

    V, F = scenes.uv_sphere([0, 0, 0], 1.0, 32, 16)
    be = rays.make_backend("embree", V, F)
    rng = np.random.default_rng(0)
    o = rng.uniform(-1.5, 1.5, (20000, 3))
    d = rng.normal(size=(20000, 3)) * 0.5
    expected = be.first_hit(o, d, 1.0, threads=2)
    waits = [rays.beside(lambda: be.first_hit(o, d, 1.0, threads=2), 2) for _ in range(2)]
    for w in waits:
        assert np.array_equal(w(timeout=60), expected)
