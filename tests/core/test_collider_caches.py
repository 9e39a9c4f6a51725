"""A collider's derived grids are functions of its shape: built once per shape,
reused by every query while the vertices stay (a rigid collider moves through its
matrix only), and rebuilt once when they change (README "Colliders": the BVH and
the grids are rebuilt only for a new shape). Counted on the builders themselves."""

from __future__ import annotations

import numpy as np
import scenes

from core import Collider
from core.collider import grid, inside, mesh


def test_the_grids_are_built_once_per_shape(monkeypatch):
    calls = {"occupancy": 0, "cells": 0}
    build_occ = grid.Occupancy.build
    mark = inside.mark_boxes

    def counted_occ(self):
        calls["occupancy"] += 1
        return build_occ(self)

    def counted_mark(*a, **k):
        calls["cells"] += 1
        return mark(*a, **k)

    monkeypatch.setattr(grid.Occupancy, "build", counted_occ)
    monkeypatch.setattr(inside, "mark_boxes", counted_mark)
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


def _sphere_counting_normals(monkeypatch):
    """A UV sphere collider, and the sizes of the normal batches it computes."""
    sizes = []
    of = mesh.ColliderMesh.face_normals_of

    def counted(self, prim):
        sizes.append(len(prim))
        return of(self, prim)

    monkeypatch.setattr(mesh.ColliderMesh, "face_normals_of", counted)
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 0.5, 32, 16)
    return Collider(V, F), sizes


def test_face_normals_are_tabled_once_a_quarter_of_the_faces_was_asked(monkeypatch):
    """Hit normals are computed on demand; once the normals asked for one shape add
    up to a quarter of its faces, all of them are computed once and looked up."""
    col, sizes = _sphere_counting_normals(monkeypatch)
    m = len(col.faces)
    rng = np.random.default_rng(6)
    asked = 0
    for _ in range(12):
        o = rng.normal(size=(40, 3))
        o *= 2.0 / np.linalg.norm(o, axis=1, keepdims=True)
        hit, _, n = col.segment_hit_details(o, -o)
        assert hit.all()
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
        asked += int(hit.sum())
    assert asked >= m // 4 + 40
    assert sizes.count(m) == 1, sizes  # the whole table, computed once ...
    assert sizes[sizes.index(m) + 1:] == [], sizes  # ... and looked up from then on


def test_the_corner_order_is_sorted_once_per_topology(monkeypatch):
    """The corners-by-vertex order (the vertex normals of every shell) depends on
    the faces alone: sorted once, whatever the deformations and offsets."""
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 0.5, 24, 12)
    col = Collider(V, F)
    calls = []
    argsort = np.argsort

    def counted(a, *args, **kw):
        calls.append(len(a))
        return argsort(a, *args, **kw)

    monkeypatch.setattr(mesh.np, "argsort", counted)
    rng = np.random.default_rng(9)
    o, d = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    for k in range(4):
        col.vertices = V * (1.0 + 0.02 * k)
        for off in (0.0, 0.05):
            col.segment_hits(o, d, off)
    assert calls.count(3 * len(col.faces)) == 1, calls


def test_face_normals_are_tabled_at_exactly_a_quarter_of_the_faces(monkeypatch):
    """The table is made as soon as the normals asked add up to a quarter of the
    faces (not one query later)."""
    col, sizes = _sphere_counting_normals(monkeypatch)
    m = len(col.faces)
    assert m % 4 == 0
    o = np.random.default_rng(7).normal(size=(m // 4, 3))
    o *= 2.0 / np.linalg.norm(o, axis=1, keepdims=True)
    hit, _, _ = col.segment_hit_details(o, -o)
    assert hit.all()
    assert m in sizes, sizes


def test_an_open_sheets_rim_faces_are_found_once_per_topology(monkeypatch):
    """The rim faces (an open sheet's border, kept in its margin shells) depend on
    the faces alone: found once, whatever the deformations."""
    V, F = scenes.grid(size=2.0, n=6, z=0.0)
    col = Collider(V, F)
    assert not col.closed
    calls = []
    keys = mesh.edge_keys

    def counted(*a):
        calls.append(1)
        return keys(*a)

    monkeypatch.setattr(mesh, "edge_keys", counted)
    rng = np.random.default_rng(10)
    o, d = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    for k in range(4):
        col.vertices = V * np.float32(1.0 + 0.02 * k)
        col.segment_hits(o, d)
    assert len(calls) == 1, calls


def test_the_thread_count_reaches_the_tracer(monkeypatch):
    """``segment_hits(..., threads=n)`` splits its rays over ``n`` threads (the answer
    does not depend on it: only the time)."""
    from core import rays

    seen = []
    any_hit = rays.EmbreeBackend.any_hit

    def spy(self, o, d, tmax, threads=1):
        seen.append(threads)
        return any_hit(self, o, d, tmax, threads)

    monkeypatch.setattr(rays.EmbreeBackend, "any_hit", spy)
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 0.5, 24, 12)
    o, d = np.random.default_rng(4).normal(size=(2, 5000, 3))
    col = Collider(V, F)
    one = col.segment_hits(o, d, threads=1)
    np.testing.assert_array_equal(col.segment_hits(o, d, threads=2), one)
    assert seen == [1, 2]
