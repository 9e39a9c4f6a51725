"""Render curves the solver cannot work with, and the clearance pass's second try.

The clearance pass sets aside curves with a non-finite point (``Status.INVALID``, as
the solver does; the output never holds NaN) instead of refusing the whole groom, and
``fallback`` settings free the curves the first settings leave unresolved; whatever
is still unresolved keeps that status (checked with the brute-force oracle).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pipe_oracle as po

from core import Collider, Settings, Status
from core.curves import as_given, invalid_curves
from core.pipeline import clearance_pass

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
import oracle  # noqa: E402  (the core tests' brute-force segment/triangle oracle)


def _scene(seed=3, n=150):
    rng = np.random.default_rng(seed)
    V, F = po.grid(3.0, 6)
    pts, off = po.fur_on_mesh(rng, V, F, n, 6, 0.8, noise=0.1)
    ball = po.icosphere((0.2, -0.1, 0.5), 0.5, 2)
    return pts, off, ball


def test_invalid_curves_names_the_first_one():
    pts, off, _ = _scene()
    assert not invalid_curves(pts, off)[0].any()
    p = pts.copy()
    p[off[7] + 3] = p[off[7] + 2]
    bad, why = invalid_curves(p, off)
    assert np.flatnonzero(bad).tolist() == [7]
    assert why == f"curve 7 has a zero-length segment between points {off[7] + 2} and {off[7] + 3}"
    p[off[4] + 1] = np.nan
    bad, why = invalid_curves(p, off)
    assert np.flatnonzero(bad).tolist() == [4, 7]
    assert why.startswith(f"curve 4: point {off[4] + 1} is not finite")
    one = np.array([0, 1, 3])
    bad, why = invalid_curves(np.zeros((3, 3)) + [[0, 0, 0], [0, 0, 0], [0, 0, 1]], one)
    assert bad.tolist() == [True, False] and why == "curve 0 has fewer than 2 points"


def test_as_given_replaces_non_finite_points_like_the_solver():
    pts = np.array([[np.nan, 0, 0], [1, 0, 0], [np.inf, 0, 0], [2, 0, 0], [5, 5, 5.0]])
    out = as_given(pts, np.array([0, 4, 5]), np.array([True, False]))
    np.testing.assert_array_equal(out, [[1, 0, 0], [1, 0, 0], [1, 0, 0], [2, 0, 0], [5, 5, 5]])


def test_clearance_pass_sets_a_nan_curve_aside():
    pts, off, ball = _scene()
    col = Collider(*ball)
    want_pts, want_st, _ = clearance_pass(pts, off, [col])
    assert (want_st == Status.COLLIDING).sum() > 3  # the ball crosses some curves
    bad = pts.copy()
    c = int(np.flatnonzero(want_st == Status.COLLIDING)[0])
    bad[off[c] + 2] = np.nan
    got, st, n_fixed = clearance_pass(bad, off, [col])
    assert np.isfinite(got).all()
    assert st[c] == Status.INVALID
    rows = np.arange(off[c], off[c + 1])
    np.testing.assert_array_equal(got[rows], as_given(bad, off, np.arange(len(off) - 1) == c)[rows])
    keep = np.ones(len(pts), bool)
    keep[rows] = False
    np.testing.assert_array_equal(got[keep], want_pts[keep])  # the others as without it
    others = np.arange(len(off) - 1) != c
    np.testing.assert_array_equal(st[others], want_st[others])
    assert n_fixed == int(np.count_nonzero(want_st[others] == Status.COLLIDING))


def test_clearance_fallback_frees_what_the_first_settings_cannot():
    """Stiff limited to a few degrees leaves curves crossing the ball UNRESOLVED; Bend
    (the fallback) frees them; the others are exactly the first settings' result, and
    no curve whose status says resolved crosses the ball (oracle)."""
    pts, off, ball = _scene(seed=5)
    col = Collider(*ball)
    stiff = Settings(mode="stiff", max_angle=4.0)
    first, st1, _ = clearance_pass(pts, off, [col], settings=stiff)
    unresolved = st1 == Status.UNRESOLVED
    assert unresolved.sum() >= 3
    got, st, _ = clearance_pass(pts, off, [col], settings=stiff,
                                fallback=Settings(mode="bend"))
    assert (st == Status.UNRESOLVED).sum() < unresolved.sum()
    same = np.repeat(~unresolved, np.diff(off))
    np.testing.assert_array_equal(got[same], first[same])
    np.testing.assert_array_equal(st[~unresolved], st1[~unresolved])
    V, F = ball
    crossing = oracle.segments_hit_mesh(got, off, V, F, abs_eps=oracle.float32_margin(got, V))
    resolved = np.isin(st, (Status.FREE, Status.COLLIDING, Status.RECOVERING))
    assert not (crossing & resolved).any()
    assert crossing[st == Status.UNRESOLVED].all()  # still crossing: and it says so
