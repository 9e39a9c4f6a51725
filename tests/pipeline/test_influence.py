"""Region of Influence: extreme wind never pushes collision-free curves through a collider."""

from __future__ import annotations

import numpy as np
import pipe_oracle as po
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core import Collider
from core.errors import InputError
from core.pipeline import collider_distance, region_of_influence

PROP = settings(max_examples=examples(8))


def _scene(seed):
    rng = np.random.default_rng(seed)
    pts, off = po.fur_on_plane(rng, 40, 6, 0.8, extent=1.0, tilt=0.4)
    V, F = po.icosphere((rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), 1.25), 0.4, sub=2)
    A, B, _ = po.segments(pts, off)
    assert not po.segments_cross_mesh(A, B, V, F).any()
    return rng, pts, off, V, F


@PROP
@given(seed=st.integers(0, 10_000), strength=st.floats(1.0, 4.0))
def test_extreme_wind_stays_collision_free(seed, strength):
    rng, pts, off, V, F = _scene(seed)
    col = Collider(V, F)
    dist = collider_distance(pts, off, [col])
    # strong noisy "wind" blowing toward the sphere: the raw result penetrates
    toward = (V.mean(0) - pts) * strength + rng.normal(0, strength, pts.shape)
    s = np.linspace(0, 1, 6)
    w = np.concatenate([s] * 40)[:, None]
    displaced = pts + toward * w
    A, B, _ = po.segments(displaced, off)
    raw_hits = po.segments_cross_mesh(A, B, V, F).sum()
    out = region_of_influence(pts, off, displaced, dist)
    A, B, _ = po.segments(out, off)
    V32 = V.astype(np.float32).astype(np.float64)
    assert not po.segments_cross_mesh(A, B, V32, F, eps=1e-9).any()
    assert not po.segments_cross_mesh(A, B, V, F, eps=1e-9).any()
    np.testing.assert_array_equal(out[off[:-1]], pts[off[:-1]])
    u0 = displaced - pts
    u1 = out - pts
    moved = np.linalg.norm(u1, axis=1) > 0
    cos = (u0[moved] * u1[moved]).sum(1) / (
        np.linalg.norm(u0[moved], axis=1) * np.linalg.norm(u1[moved], axis=1))
    np.testing.assert_allclose(cos, 1.0, atol=1e-12)
    assert (np.linalg.norm(u1, axis=1) <= 0.99 * dist + 1e-12).all()
    # the moved curves also keep a gap: distance of the result > 0 everywhere
    assert (collider_distance(out, off, [col], exact=True) > 0).all()
    if strength >= 2:
        assert raw_hits > 0  # the test is meaningful


def test_small_motion_passes_unchanged():
    _, pts, off, V, F = _scene(1)
    dist = collider_distance(pts, off, [(V, F)])
    disp = pts + 1e-4 * np.array([1.0, 0, 0])
    disp[off[:-1]] = pts[off[:-1]]
    np.testing.assert_array_equal(region_of_influence(pts, off, disp, dist), disp)


def test_no_collider_is_free_motion():
    _, pts, off, _, _ = _scene(2)
    disp = pts + 5.0
    out = region_of_influence(pts, off, disp, np.full(len(pts), np.inf))
    np.testing.assert_array_equal(out[off[:-1]], pts[off[:-1]])
    mask = np.ones(len(pts), bool)
    mask[off[:-1]] = False
    np.testing.assert_array_equal(out[mask], disp[mask])


def test_bad_input():
    _, pts, off, _, _ = _scene(3)
    d = np.ones(len(pts))
    with pytest.raises(InputError, match="shape"):
        region_of_influence(pts, off, pts[:-1], d)
    d[7] = -1
    with pytest.raises(InputError, match="curve 1"):
        region_of_influence(pts, off, pts, d)
    with pytest.raises(InputError, match="margin"):
        region_of_influence(pts, off, pts, np.ones(len(pts)), margin=1.5)
