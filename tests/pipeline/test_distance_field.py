"""Fur Collider Distance, default node field: a lower bound within a stated tolerance.

``collider_distance`` (without ``exact=True``) is never above the true distance
(so the Region of Influence stays collision free) and at most
``tolerances.DISTANCE_FIELD_CELLS`` field cells below it; the cell is at most half
the curves' median segment length. Checked against the brute-force oracle.
"""

from __future__ import annotations

import numpy as np
import pipe_oracle as po
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core import Collider
from core import tolerances as tol
from core.pipeline import collider_distance, region_of_influence, wind
from core.pipeline.distance import _collider_index

PROP = settings(max_examples=examples(15))
TOL = 1e-9


def _scene(rng, n_curves, spread, sub):
    V, F = po.icosphere(rng.uniform(-0.3, 0.3, 3), rng.uniform(0.3, 0.7), sub=sub)
    V = V * (1 + 0.08 * np.sin(4 * V[:, :1] + 1))  # bumpy
    curves = []
    for _ in range(n_curves):
        root = rng.uniform(-spread, spread, 3)
        steps = rng.normal(0, 0.06, (int(rng.integers(2, 7)), 3))
        curves.append(np.vstack([root, root + np.cumsum(steps, 0)]))
    pts, off = po.pack(curves)
    return V, F, pts, off


def _cell_bound(pts, off):
    """The largest field cell: half the median segment length."""
    A, B, _ = po.segments(pts, off)
    return 0.5 * float(np.median(np.linalg.norm(B - A, axis=1)))


@PROP
@given(seed=st.integers(0, 10_000), spread=st.floats(0.4, 2.5), sub=st.integers(2, 3),
       cap=st.one_of(st.none(), st.floats(0.0, 0.6)), kind=st.sampled_from(
           ["identity", "similarity", "general"]))
def test_lower_bound_within_the_stated_cells(seed, spread, sub, cap, kind):
    rng = np.random.default_rng(seed)
    V, F, pts, off = _scene(rng, 14, spread, sub)
    M = np.eye(4)
    if kind != "identity":
        S = np.diag(np.full(3, 1.2) if kind == "similarity" else rng.uniform(0.7, 1.4, 3))
        M[:3, :3] = po.rotation(rng.normal(size=3), rng.uniform(0, 3)) @ S
        M[:3, 3] = rng.uniform(-0.2, 0.2, 3)
    col = Collider(V, F, matrix=M)
    Vw = V.astype(np.float32).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    truth = po.brute_cv(pts, off, [(Vw, F)])
    want = truth if cap is None else np.minimum(truth, cap)
    for _ in range(2):  # the second call reuses the field
        d, exact = collider_distance(pts, off, [col], max_distance=cap, return_exact=True)
        (h, w), = _collider_index(col)[0]._node_fields  # the node field was used
        assert h <= _cell_bound(pts, off) * (1 + 1e-12)
        assert (d <= truth + TOL).all(), "never above the truth"
        # within the field's window (the cap and 6 cells, at most 32 cells)
        near = want <= (w - 6) * h
        assert (d[near] >= want[near] - tol.DISTANCE_FIELD_CELLS * h - TOL).all()
        assert (d[~near] >= 0.5 * want[~near]).all()  # farther: a coarse bound
        if cap is not None:
            assert (d <= cap).all()
            np.testing.assert_array_equal(d[exact], cap)  # exact: the cap is proven
        assert (d >= 0).all()


def test_same_input_same_output_whatever_came_before():
    rng = np.random.default_rng(5)
    V, F, pts, off = _scene(rng, 20, 1.0, 2)
    col = Collider(V, F)
    first = collider_distance(pts, off, [col], max_distance=0.2)
    collider_distance(pts, off, [col], max_distance=0.5)  # another window
    collider_distance(pts * 0.5, off, [col])  # other curves, no cap
    np.testing.assert_array_equal(collider_distance(pts, off, [col], max_distance=0.2), first)
    # a curve's distances do not depend on the other curves of the call
    sub = np.arange(3, 11)
    rows = np.concatenate([np.arange(off[i], off[i + 1]) for i in sub])
    sub_off = np.concatenate([[0], np.cumsum(np.diff(off)[sub])])
    np.testing.assert_array_equal(collider_distance(pts[rows], sub_off, [col], max_distance=0.2),
                                  first[rows])
    fresh = Collider(V, F)
    np.testing.assert_array_equal(collider_distance(pts, off, [fresh], max_distance=0.2), first)
    np.testing.assert_array_equal(collider_distance(pts, off, [(V.astype(np.float32), F)],
                                                    max_distance=0.2), first)


def test_far_curves_are_capped_exactly_and_bounded_without_cap():
    rng = np.random.default_rng(6)
    V, F, pts, off = _scene(rng, 10, 0.5, 2)
    far = pts + [6.0, -4.0, 3.0]  # far outside the field's box
    col = Collider(V, F)
    d, exact = collider_distance(far, off, [col], max_distance=0.3, return_exact=True)
    assert exact.all() and (d == 0.3).all()
    truth = po.brute_cv(far, off, [(V.astype(np.float32).astype(np.float64), F)])
    d = collider_distance(far, off, [col])
    assert (d <= truth + TOL).all() and (d >= 0.5 * truth).all()


def test_region_of_influence_with_the_field_stays_collision_free():
    """Strong wind after collision, limited by the field's distances: no crossing."""
    rng = np.random.default_rng(8)
    V, F = po.icosphere((0.1, 0, 0.35), 0.22, 3)
    pts, off = po.fur_on_plane(rng, 120, 6, 0.6, extent=0.7, tilt=0.4)
    V32 = V.astype(np.float32).astype(np.float64)
    A, B, cid = po.segments(pts, off)
    clear = np.setdiff1d(np.arange(len(off) - 1), cid[po.segments_cross_mesh(A, B, V32, F, 1e-6)])
    pts, off = po.pack([pts[off[i]:off[i + 1]] for i in clear])  # collision free
    col = Collider(V, F)
    raw = 0
    for frame in range(4):
        dist = collider_distance(pts, off, [col])
        blown = wind(pts, off, frame, direction=(1.0, 0.2, 0.1), strength=0.8, turbulence=1.0)
        raw += po.segments_cross_mesh(*po.segments(blown, off)[:2], V32, F).sum()
        out = region_of_influence(pts, off, blown, dist)
        A, B, _ = po.segments(out, off)
        assert not po.segments_cross_mesh(A, B, V32, F, eps=1e-9).any()
    assert raw > 0  # the wind alone would cross: the test is meaningful
