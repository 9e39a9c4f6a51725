"""The inside test's per-cell answers (``Collider.contains_grid``): a point whose
grid cell no triangle of the shell touches takes the answer of the cell's centre,
so which cells a triangle touches must cover all of the triangle, every corner of
it. Checked on a needle (a long thin cone) whose tip is the same corner of every
face around it, against an independent ray-parity oracle."""

from __future__ import annotations

import numpy as np
import pytest

from core import Collider


def _needle(corner, n=16, radius=0.1, length=1.0):
    """A closed cone, tip at (0, 0, length): vertex 0, corner ``corner`` of every
    side face (the same winding); the base ring at z = 0 and its centre."""
    a = 2 * np.pi * np.arange(n) / n
    ring = np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros(n)], axis=1)
    V = np.vstack([[0.0, 0.0, length], ring, [0.0, 0.0, 0.0]])
    i = np.arange(n)
    j = (i + 1) % n
    side = np.roll(np.stack([np.zeros(n, int), 1 + i, 1 + j], axis=1), corner, axis=1)
    base = np.stack([np.full(n, n + 1), 1 + j, 1 + i], axis=1)
    return V, np.vstack([side, base])


@pytest.mark.parametrize("corner", [0, 1, 2])
def test_points_near_a_needle_tip_get_the_traced_answer(corner):
    V, F = _needle(corner)
    col = Collider(V, F)
    assert col.closed and col.detects_pinch
    # a lattice around the upper half of the needle, where only the side faces
    # (tip first) reach
    g = np.linspace(-0.06, 0.06, 25)
    z = np.linspace(0.5, 0.99, 50)
    P = np.array([[x, y, w] for x in g for y in g for w in z])
    # the oracle: the needle's cross-section at height z is a regular 16-gon of
    # circumradius 0.1 (1 - z): inside within its inradius, outside beyond its
    # circumradius (points within 1e-3 of either left out)
    r = np.hypot(P[:, 0], P[:, 1])
    R = 0.1 * (1.0 - P[:, 2])
    inner = R * np.cos(np.pi / 16)
    want = r < inner - 1e-3
    keep = want | (r > R + 1e-3)
    P, want = P[keep], want[keep]
    assert 100 < want.sum() < len(P) - 100
    col.contains(P)  # the first call (a shape not yet seen static: coarse grid)
    for _ in range(2):  # the fine grid's per-cell answers, then cached
        np.testing.assert_array_equal(col.contains(P), want)
