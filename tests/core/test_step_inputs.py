"""What ``Solver.step`` accepts besides arrays and lists of colliders, and the
errors it names (README "Python API": points as any (P, 3) float array-like, one
collider or a sequence of them; a wrong growth surface or a missing one named)."""

from __future__ import annotations

import numpy as np
import pytest
import scenes

from core import Collider, InputError, Settings, Solver


def _scene():
    pts, offs = scenes.pack([scenes.curly_curve([x, 0, 0], [0, 0, 1], 1.0, 6, 0.1)
                             for x in (-0.1, 0.0, 0.1)])
    V, F = scenes.uv_sphere([0.1, 0.0, 0.8], 0.3, 24, 12)
    return pts, offs, Collider(V, F)


def test_points_as_nested_lists_and_one_collider_alone():
    pts, offs, col = _scene()
    want = Solver(offs, Settings(mode="bend")).step(pts, [col])
    assert (np.asarray(want.status) != 0).any()
    for p, c in ((pts.tolist(), [col]), (pts, col), (pts.tolist(), col)):
        got = Solver(offs, Settings(mode="bend")).step(p, c)
        np.testing.assert_array_equal(got.points, want.points)
        np.testing.assert_array_equal(got.status, want.status)


def test_ragged_points_are_an_input_error():
    _, offs, _ = _scene()
    with pytest.raises(InputError, match="^points must be a \\(P, 3\\) float array"):
        Solver(offs, Settings()).step([[0.0, 0.0, 0.0], [1.0, 2.0]] * 9)


def test_a_wrong_or_missing_growth_surface_is_named():
    pts, offs, col = _scene()
    with pytest.raises(InputError, match="^growth must be a core.Collider, got str$"):
        Solver(offs, Settings()).step(pts, [col], growth="ground")
    with pytest.raises(InputError, match="^attract_to_growth_surface needs the growth surface"):
        Solver(offs, Settings(attract_to_growth_surface=True)).step(pts, [col])
    with pytest.raises(InputError, match="^pinch_resolution='growth_surface' needs the growth"):
        Solver(offs, Settings(pinch_resolution="growth_surface")).step(pts, [col])
