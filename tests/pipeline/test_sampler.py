"""Fur Sampler: exact count, deterministic, well spaced, uniform per area."""

from __future__ import annotations

import numpy as np
import pipe_oracle as po
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core.errors import ColliderError, InputError
from core.pipeline import dart_throwing, neighbor_pairs, sample_guides

PROP = settings(max_examples=examples(10))

# a 2 x 1 plane made of triangles of very different sizes
_X = np.array([0.0, 0.1, 0.3, 1.2, 2.0])
_PV = np.array([[x, y, 0.0] for x in _X for y in (0.0, 1.0)])
_PF = np.array([[2 * i, 2 * i + 2, 2 * i + 3] for i in range(4)]
               + [[2 * i, 2 * i + 3, 2 * i + 1] for i in range(4)])


def _plane_roots(rng, n, left_density=1.0):
    """Roots on the plane; the left half ``left_density`` times denser."""
    nl = int(n * left_density / (1 + left_density))
    left = np.c_[rng.uniform(0, 1, nl), rng.uniform(0, 1, nl)]
    right = np.c_[rng.uniform(1, 2, n - nl), rng.uniform(0, 1, n - nl)]
    xy = np.vstack([left, right])
    return np.c_[xy, np.zeros(len(xy))]


def _min_dist(X):
    D = np.linalg.norm(X[:, None] - X[None], axis=-1)
    np.fill_diagonal(D, np.inf)
    return D.min()


@PROP
@given(seed=st.integers(0, 10_000), fraction=st.floats(0.05, 0.5))
def test_count_and_determinism(seed, fraction):
    rng = np.random.default_rng(seed)
    X = _plane_roots(rng, 3000)
    idx = sample_guides(X, _PV, _PF, fraction, seed=seed)
    assert len(idx) == round(fraction * 3000)
    assert len(np.unique(idx)) == len(idx) and (np.diff(idx) > 0).all()
    np.testing.assert_array_equal(idx, sample_guides(X, _PV, _PF, fraction, seed=seed))
    assert not np.array_equal(idx, sample_guides(X, _PV, _PF, fraction, seed=seed + 1))


def test_well_spaced_compared_to_random_subset():
    rng = np.random.default_rng(1)
    X = _plane_roots(rng, 4000)
    idx = sample_guides(X, _PV, _PF, 0.15, seed=3)
    ours = _min_dist(X[idx])
    rand = np.median([_min_dist(X[rng.choice(len(X), len(idx), replace=False)])
                      for _ in range(5)])
    assert ours > 10 * rand
    # no holes: every root is close to a guide (nearest-guide distance bounded)
    D = np.linalg.norm(X[:, None] - X[idx][None], axis=-1).min(1)
    r_ideal = np.sqrt(2.0 / len(idx))
    assert D.max() < 1.5 * r_ideal


@pytest.mark.parametrize("left_density", [1.0, 3.0])
def test_uniform_per_area(left_density):
    """Guide counts per region follow the area, even when the groom is denser on one side."""
    rng = np.random.default_rng(2)
    X = _plane_roots(rng, 12000, left_density)
    idx = sample_guides(X, _PV, _PF, 0.05, seed=0)
    G = X[idx]
    regions = [(0, 0.5), (0.5, 1.0), (1.0, 1.5), (1.5, 2.0)]  # equal areas
    counts = np.array([((G[:, 0] >= a) & (G[:, 0] < b)).sum() for a, b in regions])
    expected = len(idx) / 4
    assert np.abs(counts - expected).max() < 0.12 * expected, counts
    # and the left/right halves (area 1 each) get about the same number
    half = (G[:, 0] < 1).sum()
    assert abs(half - len(idx) / 2) < 0.06 * len(idx)


def test_mask_restricts_the_area():
    rng = np.random.default_rng(3)
    X = _plane_roots(rng, 3000)
    mask = X[:, 0] < 0.7
    idx = sample_guides(X, _PV, _PF, 0.2, seed=0, mask=mask)
    assert mask[idx].all()
    assert len(idx) == round(0.2 * mask.sum())


def test_on_a_sphere():
    rng = np.random.default_rng(4)
    V, F = po.icosphere((0, 0, 0), 1.0, 3)
    pts, off = po.fur_on_mesh(rng, V, F, 3000, 2)
    roots = pts[off[:-1]]
    idx = sample_guides(roots, V, F, 0.1, seed=1)
    assert len(idx) == 300
    # hemispheres get about half each
    assert abs((roots[idx, 2] > 0).sum() - 150) < 25


def test_dart_throwing_is_sequential_dart_throwing():
    rng = np.random.default_rng(5)
    X = rng.uniform(0, 1, (400, 3))
    prio = rng.permutation(400)
    r = 0.15
    keep = dart_throwing(X, r, prio)
    ref = np.zeros(400, bool)
    for p in np.argsort(prio):  # the sequential oracle
        if not ref.any() or np.linalg.norm(X[ref] - X[p], axis=1).min() >= r:
            ref[p] = True
    np.testing.assert_array_equal(keep, ref)
    i, j, d = neighbor_pairs(X, r)
    D = np.linalg.norm(X[:, None] - X[None], axis=-1)
    np.fill_diagonal(D, np.inf)
    assert len(i) == (D < r).sum()


def test_bad_input():
    X = _plane_roots(np.random.default_rng(6), 100)
    with pytest.raises(InputError, match="fraction"):
        sample_guides(X, _PV, _PF, 0.0)
    with pytest.raises(InputError, match="mask"):
        sample_guides(X, _PV, _PF, 0.1, mask=np.ones(3, bool))
    with pytest.raises(ColliderError, match="no triangle"):
        sample_guides(X, _PV, np.zeros((0, 3), int))
    Xn = X.copy()
    Xn[7, 1] = np.nan
    with pytest.raises(InputError, match="curve 7"):
        sample_guides(Xn, _PV, _PF)
    assert len(sample_guides(X, _PV, _PF, 1.0)) == 100
    assert len(sample_guides(X, _PV, _PF, 0.1, mask=np.zeros(100, bool))) == 0
