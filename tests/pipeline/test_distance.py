"""Fur Collider Distance, exact search (``exact=True``): exact near colliders, never above
the true distance. The default node field: tests/pipeline/test_distance_field.py."""

from __future__ import annotations

import numpy as np
import pipe_oracle as po
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core import Collider
from core.errors import InputError
from core.pipeline import collider_distance, segment_mesh_distance

PROP = settings(max_examples=examples(10))
N_SAMPLES = 201


def _oracle_cv(points, offsets, V, F, n=N_SAMPLES):
    """Per-CV (upper estimate, sampling slack) from sampled segment distances."""
    A, B, _ = po.segments(points, offsets)
    seg = po.segment_mesh_distance_sampled(A, B, V, F, n)
    slack = np.linalg.norm(B - A, axis=1) / (2 * (n - 1))
    P = len(points)
    up = np.full(P, np.inf)
    sl = np.zeros(P)
    k = 0
    for i in range(len(offsets) - 1):
        for j in range(offsets[i], offsets[i + 1] - 1):
            for end in (j, j + 1):
                if seg[k] < up[end]:
                    up[end] = seg[k]
                    sl[end] = slack[k]
            k += 1
    return up, sl


@PROP
@given(seed=st.integers(0, 10_000), n_cvs=st.integers(2, 6))
def test_matches_brute_force(seed, n_cvs):
    rng = np.random.default_rng(seed)
    V, F = po.icosphere(rng.uniform(-0.3, 0.3, 3) + [0, 0, 0.8], rng.uniform(0.3, 0.6), sub=1)
    # random wiggly curves near (and sometimes through) the sphere
    curves = []
    for _ in range(6):
        root = np.r_[rng.uniform(-1, 1, 2), 0.0]
        steps = rng.normal(0, 0.25, (n_cvs - 1, 3)) + [0, 0, 0.3]
        curves.append(np.vstack([root, root + np.cumsum(steps, 0)]))
    pts, off = po.pack(curves)
    d, exact = collider_distance(pts, off, [Collider(V, F)], return_exact=True, exact=True)
    V32 = V.astype(np.float32).astype(np.float64)  # what the Collider stores
    up, slack = _oracle_cv(pts, off, V32, F)
    assert (d <= up + 1e-9).all(), "must never overestimate"
    assert (d[exact] >= up[exact] - slack[exact] - 1e-9).all()
    assert exact.mean() > 0.5


def test_far_segments_are_lower_bounds():
    V, F = po.grid(4.0, 40, z=0.0)  # 3200 small triangles: many grid cells
    rng = np.random.default_rng(1)
    curves = [np.r_[rng.uniform(-1, 1, 2), 3.0] + np.linspace(0, 0.05, 4)[:, None]
              * po.rotation([1, 0, 0], 1.0)[:, 2] for _ in range(5)]
    pts, off = po.pack(curves)
    d, exact = segment_mesh_distance(pts[:-1], pts[1:], V, F)
    A, B = pts[:-1], pts[1:]
    ref = np.minimum(A[:, 2], B[:, 2])  # above a plane that spans the curves
    assert not exact.any()
    assert (d <= ref + 1e-12).all()
    # documented slack: ~3 cells of a 64-cell field over the collider (4 wide), plus
    # half a piece (1/8) of the segment
    slack = 3 * 4.0 / 64 + np.linalg.norm(B - A, axis=1) / 16
    assert (d >= ref - slack - 1e-9).all()


def test_crossing_segment_is_zero_and_adjacent_cvs_share_it():
    V, F = po.grid(2.0, 2, z=0.5)
    pts, off = po.pack([np.array([[0.1, 0.1, 0], [0.1, 0.1, 1.0], [0.1, 0.1, 2.0]])])
    d = collider_distance(pts, off, [(V, F)])
    np.testing.assert_allclose(d, [0, 0, 0.5], atol=1e-15)  # the tip only has its last segment


def test_parallel_segment_and_tips():
    V, F = po.grid(4.0, 3, z=0.0)
    pts, off = po.pack([np.array([[0, 0, 0.3], [1.0, 0, 0.3], [1.0, 0, 1.3]])])
    d = collider_distance(pts, off, [(V, F)])
    np.testing.assert_allclose(d, [0.3, 0.3, 0.3], atol=1e-12)


def test_collider_matrix_equals_world_mesh():
    V, F = po.icosphere((0, 0, 0), 0.5, sub=1)
    R = po.rotation([1, 2, 3], 0.7)
    M = np.eye(4)
    M[:3, :3] = R * 1.7
    M[:3, 3] = [0.2, -0.1, 1.0]
    rng = np.random.default_rng(3)
    pts, off = po.fur_on_plane(rng, 20, 5, 1.5)
    col = Collider(V, F, matrix=M)
    Vw = V.astype(np.float32).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    np.testing.assert_allclose(collider_distance(pts, off, [col], exact=True),
                               collider_distance(pts, off, [(Vw, F)], exact=True), atol=1e-9)


def test_several_colliders_take_the_minimum_and_none_is_inf():
    rng = np.random.default_rng(4)
    pts, off = po.fur_on_plane(rng, 10, 4, 1.0)
    a = po.icosphere((0, 0, 2), 0.5, 1)
    b = po.icosphere((0.5, 0, 1.5), 0.3, 1)
    for exact in (True, False):
        da = collider_distance(pts, off, [a], exact=exact)
        db = collider_distance(pts, off, [b], exact=exact)
        # (the field: b's search is capped by a's distances, another window)
        np.testing.assert_allclose(collider_distance(pts, off, [a, b], exact=exact),
                                   np.minimum(da, db), rtol=1e-12, atol=0)
    assert np.isinf(collider_distance(pts, off, [])).all()
    assert np.isinf(collider_distance(pts, off, [Collider(np.zeros((0, 3)), [])])).all()


def test_bad_input_names_the_curve():
    pts = np.zeros((4, 3))
    pts[2] = np.nan
    with pytest.raises(InputError, match="curve 1"):
        collider_distance(pts, [0, 2, 4], [])
    with pytest.raises(InputError, match="curve 1"):
        collider_distance(np.zeros((3, 3)), [0, 2, 3], [])


@PROP
@given(seed=st.integers(0, 10_000), spread=st.floats(0.5, 6.0))
def test_never_overestimates_near_or_far(seed, spread):
    """Curves scattered near and far from a finely triangulated collider."""
    rng = np.random.default_rng(seed)
    V, F = po.icosphere(rng.uniform(-0.5, 0.5, 3), rng.uniform(0.2, 0.8), sub=2)
    curves = []
    for _ in range(12):
        root = rng.uniform(-spread, spread, 3)
        steps = rng.normal(0, 0.1, (3, 3))
        curves.append(np.vstack([root, root + np.cumsum(steps, 0)]))
    pts, off = po.pack(curves)
    d, exact = collider_distance(pts, off, [(V, F)], return_exact=True, exact=True)
    up, slack = _oracle_cv(pts, off, V, F, 41)
    assert (d <= up + 1e-9).all()
    assert (d[exact] >= up[exact] - slack[exact] - 1e-9).all()
    assert (d >= 0).all()
    # far ones are still informative: positive where the curve is well clear
    clear = up > 0.5
    assert (d[clear] > 0.2 * up[clear]).all()


def test_huge_and_tiny_triangles_in_one_collider():
    """A ground plane of 2 huge triangles next to a fine sphere (the big-triangle list)."""
    pts, off, V, F = po.sphere_and_ground()
    d, exact = collider_distance(pts, off, [(V, F)], return_exact=True)  # (too big a field)
    up, slack = _oracle_cv(pts, off, V, F, 101)
    assert exact.all()
    assert (d <= up + 1e-9).all() and (d >= up - slack - 1e-9).all()
