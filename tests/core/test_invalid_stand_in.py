"""An invalid curve (a non-finite point) is left as it is and costs nothing near
the colliders: the step works on a tiny stand-in at its own root, so a collider
no valid curve can reach is never built for it, with one ray thread or two."""

from __future__ import annotations

import numpy as np
import scenes

from core import Collider, Settings, Solver, Status


def test_an_invalid_curve_far_from_every_collider_builds_none():
    valid = scenes.straight_curve([10.0, 0.0, 0.0], [0, 0, 1], 1.0, 5)
    invalid = scenes.straight_curve([20.0, 3.0, -4.0], [0, 0, 1], 1.0, 5)
    invalid[3] = np.nan
    pts, offs = scenes.pack([valid, invalid])
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 0.5, 24, 12)  # at the origin, out of reach
    for threads in (1, 2):
        col = Collider(V, F, deforming=True)
        solver = Solver(offs, Settings(mode="bend", threads=threads))
        for k in range(3):
            col.vertices = V * (1.0 + 0.01 * k)
            r = solver.step(pts, [col])
            np.testing.assert_array_equal(np.asarray(r.status), [Status.FREE, Status.INVALID])
            np.testing.assert_array_equal(r.points[:5], pts[:5])
            assert np.isfinite(r.points).all()
        assert col.build_count == 0, threads


def _repaired(curve):
    """README: an invalid curve is output as given, each non-finite point replaced
    by the nearest finite one before it on its curve (after it for leading ones;
    the origin when the curve has none). Written point by point."""
    out = curve.copy()
    ok = np.isfinite(curve).all(axis=1)
    for i in range(len(curve)):
        if ok[i]:
            continue
        before = [j for j in range(i) if ok[j]]
        after = [j for j in range(i + 1, len(curve)) if ok[j]]
        out[i] = curve[before[-1]] if before else curve[after[0]] if after else 0.0
    return out


def test_invalid_curves_are_output_as_given_with_their_gaps_filled():
    nan = np.nan
    rng = np.random.default_rng(7)
    patterns = [[0, 1, 1, 1, 1], [1, 1, 1, 1, 0], [1, 0, 0, 1, 1], [0, 0, 1, 0, 1],
                [0, 0, 0, 0, 0], [1, 1, 1, 1, 1], [0, 1, 0, 1, 0], [1, 1, 1, 0, 0],
                [0, 0, 0, 0, 1], [1, 0, 0, 0, 0]]
    curves = []
    for k, pat in enumerate(patterns * 2):
        c = scenes.straight_curve([0.3 * k, rng.uniform(-1, 1), 0.0], [0, 0, 1], 1.0, 5)
        c[np.asarray(pat) == 0] = [nan, 0.0, nan] if k % 2 else nan
        curves.append(c)
    pts, offs = scenes.pack(curves)
    r = Solver(offs, Settings(mode="soft")).step(pts, [])
    status = np.asarray(r.status)
    for c, pat in enumerate(patterns * 2):
        got = r.points[offs[c]:offs[c + 1]]
        if all(pat):
            assert status[c] == Status.FREE
            np.testing.assert_array_equal(got, curves[c])
        else:
            assert status[c] == Status.INVALID
            np.testing.assert_array_equal(got, _repaired(curves[c]))
