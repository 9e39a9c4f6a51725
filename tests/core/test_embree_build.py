"""The embree BVH build (core.rays.EmbreeBackend): only embreex's public API, the
fast object-fed TriangleMesh gives the very same hits as plain arrays, and any
refusal or wrong build falls back to plain arrays."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core import Collider, rays

embreex = pytest.importorskip("embreex")
from embreex import mesh_construction, rtcore_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def reference_scene(V, F):
    s = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(s, np.ascontiguousarray(V, np.float32),
                                   np.ascontiguousarray(F, np.int32))
    return s


def random_mesh(rng, n=60, m=120):
    return rng.normal(size=(n, 3)), rng.integers(0, n, size=(m, 3))


def rays_through(rng, k=3000):
    o = rng.normal(size=(k, 3)).astype(np.float32) * 2
    d = (rng.normal(size=(k, 3)) * 1.5).astype(np.float32)
    return o, d


@settings(max_examples=examples(25), deadline=None)
@given(n=st.integers(3, 200), m=st.integers(1, 400), seed=st.integers(0, 2**31 - 1))
def test_fast_build_gives_the_hits_of_plain_arrays(n, m, seed):
    rng = np.random.default_rng(seed)
    V, F = random_mesh(rng, n, m)
    o, d = rays_through(rng)
    be = rays.EmbreeBackend(V, F, rays.triangle_rows(F))
    ref = reference_scene(V, F)
    tmax = np.ones(len(o), np.float32)
    a = be._scene.run(o, d, dists=tmax.copy(), output=1)
    b = ref.run(o, d, dists=tmax.copy(), output=1)
    for key in ("primID", "tfar", "u", "v", "Ng"):
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_a_refused_fast_build_falls_back_to_plain_arrays(monkeypatch):
    """An embreex that rejects object arrays costs time, never a result."""
    rng = np.random.default_rng(2)
    V, F = random_mesh(rng)
    o, d = rays_through(rng)
    expected = rays.EmbreeBackend(V, F).first_hit(o, d, 1.0)
    real = mesh_construction.TriangleMesh
    calls = []

    def picky(scene, verts, idx=None):
        calls.append(verts.dtype)
        if verts.dtype == object:
            raise TypeError("object arrays are not supported")
        return real(scene, verts, idx)

    monkeypatch.setattr(rays._mc, "TriangleMesh", picky)
    be = rays.EmbreeBackend(V, F, rays.triangle_rows(F))
    assert calls == [np.dtype(object), np.dtype(np.float32)]
    np.testing.assert_array_equal(be.first_hit(o, d, 1.0), expected)


def test_a_wrong_fast_build_is_detected_and_redone(monkeypatch):
    """Should the object-fed build put the triangles elsewhere (a future embreex
    reading them differently), the probe ray notices and the plain build is used."""
    rng = np.random.default_rng(3)
    V, F = random_mesh(rng)
    o, d = rays_through(rng)
    expected = rays.EmbreeBackend(V, F).first_hit(o, d, 1.0)
    real = mesh_construction.TriangleMesh

    def shifted(scene, verts, idx=None):
        if verts.dtype == object:
            verts = np.asarray(verts, np.float32) + np.float32(100.0)
            idx = np.array([list(r) for r in idx], np.int32)
        return real(scene, verts, idx)

    monkeypatch.setattr(rays._mc, "TriangleMesh", shifted)
    be = rays.EmbreeBackend(V, F, rays.triangle_rows(F))
    np.testing.assert_array_equal(be.first_hit(o, d, 1.0), expected)


def test_deforming_collider_results_do_not_depend_on_history():
    """A deforming collider's BVH is a function of its vertices: stepping to the same
    shape again, or building the collider at that shape, gives bit-identical hits."""
    rng = np.random.default_rng(5)
    V, F = random_mesh(rng, 300, 600)
    o, d = rays_through(rng)
    V2 = V + rng.normal(scale=0.05, size=V.shape)

    def hits(col):
        be, _ = col.shells.backend(0.0)
        return be.hit_details(o - col.mesh.center.astype(np.float32), d, 1.0)

    col = Collider(V, F, drop_degenerate=True)
    first = hits(col)
    col.vertices = V2
    hits(col)
    col.vertices = V
    for a, b, c in zip(first, hits(col), hits(Collider(V, F, drop_degenerate=True)),
                       strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)


def test_nothing_calls_into_a_library_directly():
    """No ctypes in the add-on: the real Blender application links its own Embree,
    and a call into the wrong library crashed it (the artist's unsaved work lost)."""
    for folder in ("core", "operators", "ui"):
        for path in (ROOT / folder).rglob("*.py"):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                names = []
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom):
                    names = [node.module or ""]
                assert not any(n.split(".")[0] == "ctypes" for n in names), path


@settings(max_examples=examples(20), deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_any_hit_agrees_with_first_hit(seed):
    """The occlusion query (any_hit, used by every probe) answers exactly as the
    closest-hit query, rays grazing the mesh included."""
    rng = np.random.default_rng(seed)
    V, F = random_mesh(rng, 300, 600)
    o, d = rays_through(rng, 20_000)
    be = rays.EmbreeBackend(V, F, rays.triangle_rows(F))
    for threads in (1, 2):
        np.testing.assert_array_equal(be.any_hit(o, d, 1.0, threads),
                                      be.first_hit(o, d, 1.0, threads) >= 0)
