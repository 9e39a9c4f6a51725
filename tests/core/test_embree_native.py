"""The zero-copy embreex geometry (core.embree_native): same hits as embreex's own
TriangleMesh, buffers kept alive, a safe fallback when it cannot be used."""

from __future__ import annotations

import gc
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core import embree_native, rays

embreex = pytest.importorskip("embreex")
from embreex import mesh_construction, rtcore_scene  # noqa: E402

PROP = settings(max_examples=25, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck))


def reference_scene(V, F):
    s = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(s, np.ascontiguousarray(V, np.float32),
                                   np.ascontiguousarray(F, np.int32))
    return s


def random_mesh(rng, n=60, m=120):
    V = rng.normal(size=(n, 3))
    F = rng.integers(0, n, size=(m, 3))
    return V, F


def rays_through(rng, k=3000):
    o = rng.normal(size=(k, 3)).astype(np.float32) * 2
    d = (rng.normal(size=(k, 3)) * 1.5).astype(np.float32)
    return o, d


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="Linux only")
def test_available_on_linux():
    assert embree_native.available(), embree_native.unavailable_reason()


@PROP
@given(seed=st.integers(0, 10_000))
def test_same_hits_as_embreex_triangle_mesh(seed):
    rng = np.random.default_rng(seed)
    V, F = random_mesh(rng)
    o, d = rays_through(rng)
    ref = reference_scene(V, F)
    if not embree_native.available():
        pytest.skip(embree_native.unavailable_reason())
    scene, _keep = embree_native.triangle_scene(np.asarray(V, np.float32), F)
    tmax = np.ones(len(o), np.float32)
    np.testing.assert_array_equal(scene.run(o, d, dists=tmax.copy()),
                                  ref.run(o, d, dists=tmax.copy()))
    a = scene.run(o, d, dists=tmax.copy(), output=1)
    b = ref.run(o, d, dists=tmax.copy(), output=1)
    for key in ("primID", "tfar", "u", "v", "Ng"):
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def test_backend_keeps_the_shared_buffers_alive():
    rng = np.random.default_rng(1)
    V, F = random_mesh(rng, 200, 400)
    o, d = rays_through(rng, 5000)
    expected = reference_scene(V, F).run(o, d, dists=np.ones(len(o), np.float32))
    be = rays.EmbreeBackend(V.copy(), F.copy())
    gc.collect()
    junk = [np.full((200, 4), 1e9, np.float32) for _ in range(200)]  # reuse freed memory
    np.testing.assert_array_equal(be.first_hit(o, d, 1.0), expected)
    del junk


def test_fallback_when_unavailable(monkeypatch):
    """Without the zero-copy path the backend builds with TriangleMesh, same hits."""
    rng = np.random.default_rng(2)
    V, F = random_mesh(rng)
    o, d = rays_through(rng)
    native = rays.EmbreeBackend(V, F)

    def refuse(*_a, **_k):
        raise embree_native.NativeUnavailable("test")

    monkeypatch.setattr(embree_native, "triangle_scene", refuse)
    fallback = rays.EmbreeBackend(V, F)
    assert fallback._shared is None
    np.testing.assert_array_equal(fallback.first_hit(o, d, 1.0), native.first_hit(o, d, 1.0))


def test_layout_check_refuses_foreign_objects():
    class Fake:
        is_committed = 0

    with pytest.raises(embree_native.NativeUnavailable):
        embree_native._handles(Fake(), Fake())


@PROP
@given(seed=st.integers(0, 10_000))
def test_fast_build_gives_the_same_hits(seed):
    """Embree's low-quality build (deforming colliders) traverses another BVH: the
    first hit of every ray is still the same."""
    if not embree_native.available():
        pytest.skip(embree_native.unavailable_reason())
    rng = np.random.default_rng(seed)
    V, F = random_mesh(rng, 300, 600)
    o, d = rays_through(rng)
    fast = rays.EmbreeBackend(V, F, fast_build=True)
    ref = reference_scene(V, F).run(o, d, dists=np.ones(len(o), np.float32))
    np.testing.assert_array_equal(fast.first_hit(o, d, 1.0), ref)


def test_deforming_collider_results_do_not_depend_on_history():
    """A deforming collider's BVH is a function of its vertices: stepping to the same
    shape again, or building the collider at that shape, gives bit-identical hits."""
    from core import Collider

    rng = np.random.default_rng(5)
    V, F = random_mesh(rng, 300, 600)
    o, d = rays_through(rng)
    V2 = V + rng.normal(scale=0.05, size=V.shape)

    def hits(col):
        be, _ = col._backend(0.0)
        return be.hit_details(o - col._center.astype(np.float32), d, 1.0)

    col = Collider(V, F, deforming=True, drop_degenerate=True)
    first = hits(col)
    col.vertices = V2
    hits(col)
    col.vertices = V
    for a, b, c in zip(first, hits(col), hits(Collider(V, F, deforming=True, drop_degenerate=True)),
                       strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
