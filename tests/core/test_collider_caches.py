"""A collider's derived grids are functions of its shape: built once per shape,
reused by every query while the vertices stay (a rigid collider moves through its
matrix only), and rebuilt once when they change (README "Colliders": the BVH and
the grids are rebuilt only for a new shape). Counted on the builders themselves."""

from __future__ import annotations

import numpy as np
import scenes

import core.collider as collider_mod
from core import Collider


def test_the_grids_are_built_once_per_shape(monkeypatch):
    calls = {"occupancy": 0, "cells": 0}
    build_occ = Collider._build_occupancy
    mark = collider_mod.mark_boxes

    def counted_occ(self):
        calls["occupancy"] += 1
        return build_occ(self)

    def counted_mark(*a, **k):
        calls["cells"] += 1
        return mark(*a, **k)

    monkeypatch.setattr(Collider, "_build_occupancy", counted_occ)
    monkeypatch.setattr(collider_mod, "mark_boxes", counted_mark)
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 0.5, 24, 12)
    col = Collider(V, F)
    rng = np.random.default_rng(5)
    P = rng.uniform(-0.7, 0.7, size=(300, 3))
    first = [col.contains(P), col.near_surface(P, 0.05)]
    for k in range(4):
        shift = np.array([0.25 * k, 0.0, 0.0])
        col.matrix = scenes.translation(shift)  # a move: the same shape
        got = [col.contains(P + shift), col.near_surface(P + shift, 0.05)]
        for a, b in zip(first, got, strict=True):
            np.testing.assert_array_equal(a, b)
    assert calls == {"occupancy": 1, "cells": 1}, calls
    col.vertices = V * 1.1  # a new shape: each grid once more
    for _ in range(3):
        col.contains(P)
        col.contains(P)
        col.near_surface(P, 0.05)
    assert calls == {"occupancy": 2, "cells": 2}, calls
