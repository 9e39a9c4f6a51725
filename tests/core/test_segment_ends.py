"""A segment that ends on a collider's surface is a contact, not a miss
(``tol.T_SLACK``: a hit at ray parameter up to ``1 + T_SLACK`` counts): float32 rays
must not let a curve's tip rest on a face unseen. ``segment_hits`` and
``segment_hit_details`` agree on it."""

from __future__ import annotations

import numpy as np
import pytest
import scenes

from core import Collider, tolerances


@pytest.mark.parametrize("double_sided", [False, True])
def test_a_segment_ending_on_the_shell_is_a_hit(double_sided):
    V, F = scenes.grid(size=2.0, n=4, z=0.0)
    col = Collider(V, F, double_sided=double_sided)
    shell = col.margin  # the outer clearance shell of the sheet z = 0
    xy = np.array([[x, y] for x in (-0.6, -0.1, 0.35, 0.8) for y in (-0.55, 0.15, 0.7)])
    k = len(xy)
    o = np.column_stack([xy, np.ones(k)])
    for frac, hit in ((-0.5, True), (0.0, True), (0.4, True), (3.0, False)):
        # the segment from z = 1 down to frac * T_SLACK (of its length) short of the shell
        end = shell + frac * tolerances.T_SLACK * (1.0 - shell)
        d = np.column_stack([np.zeros((k, 2)), np.full(k, end - 1.0)])
        np.testing.assert_array_equal(col.segment_hits(o, d), np.full(k, hit), err_msg=str(frac))
        h, t, n = col.segment_hit_details(o, d)
        np.testing.assert_array_equal(h, np.full(k, hit), err_msg=str(frac))
        if hit:
            assert (t <= 1.0).all() and (t > 1.0 - 2e-6).all()
            np.testing.assert_allclose(n, [[0.0, 0.0, 1.0]] * k, atol=1e-6)
