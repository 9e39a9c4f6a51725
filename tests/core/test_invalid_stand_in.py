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
