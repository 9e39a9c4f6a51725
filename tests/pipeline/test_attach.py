"""Fur Attach: identity at rest, exact rigid motion, roots stay on their triangles."""

from __future__ import annotations

import numpy as np
import pipe_oracle as po
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core.errors import ColliderError, InputError
from core.pipeline import Binding, bind

PROP = settings(max_examples=examples(15))


def _scene(seed):
    rng = np.random.default_rng(seed)
    V, F = po.icosphere((0.3, -0.2, 0.1), 1.0, sub=2)
    V = V * (1 + 0.1 * rng.normal(size=(len(V), 1)))
    pts, off = po.fur_on_mesh(rng, V, F, 40, 5)
    return rng, V, F, pts, off


def _seg_len(p, off):
    A, B, _ = po.segments(p, off)
    return np.linalg.norm(B - A, axis=1)


@PROP
@given(seed=st.integers(0, 10_000))
def test_identity_at_reference_pose(seed):
    _, V, F, pts, off = _scene(seed)
    b = bind(pts, off, V, F)
    np.testing.assert_allclose(b.apply(V), pts, atol=1e-9, rtol=0)
    assert b.root_distance.max() < 1e-9


@PROP
@given(seed=st.integers(0, 10_000), angle=st.floats(-3.1, 3.1),
       axis=st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda a: np.linalg.norm(a) > 0.1),
       t=st.tuples(*[st.floats(-5, 5)] * 3))
def test_rigid_surface_motion_is_exact_rigid_motion(seed, angle, axis, t):
    _, V, F, pts, off = _scene(seed)
    b = bind(pts, off, V, F)
    R = po.rotation(axis, angle)
    out = b.apply(V @ R.T + np.asarray(t))
    np.testing.assert_allclose(out, pts @ R.T + np.asarray(t), atol=1e-9, rtol=0)


@PROP
@given(seed=st.integers(0, 10_000), amp=st.floats(0.0, 0.3))
def test_deformation_roots_on_triangles_curves_rigid(seed, amp):
    rng, V, F, pts, off = _scene(seed)
    b = bind(pts, off, V, F)
    V2 = V + amp * rng.normal(size=V.shape) + [0, 0, 1.0]
    out = b.apply(V2)
    roots = out[off[:-1]]
    T = V2[F[b.face]]
    np.testing.assert_array_equal(roots, np.einsum("ck,cki->ci", b.bary, T))
    assert (b.bary >= 0).all() and np.allclose(b.bary.sum(1), 1)
    # on the triangle's plane
    n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("ij,ij->i", roots - T[:, 0], n), 0, atol=1e-12)
    # each curve moves rigidly: lengths kept, shape kept
    np.testing.assert_allclose(_seg_len(out, off), _seg_len(pts, off), rtol=1e-9)
    for i in range(0, len(off) - 1, 7):
        a, c = pts[off[i]:off[i + 1]], out[off[i]:off[i + 1]]
        da = np.linalg.norm(a[:, None] - a[None], axis=-1)
        dc = np.linalg.norm(c[:, None] - c[None], axis=-1)
        np.testing.assert_allclose(da, dc, atol=1e-9)


@PROP
@given(seed=st.integers(0, 10_000), amp=st.floats(0.01, 0.3))
def test_the_curves_depend_only_on_the_used_vertices(seed, amp):
    """``used_vertices`` (what a frame-inputs record digests for Fur Attach) is
    exactly what ``apply`` reads: every other vertex moved, the curves stay bit for
    bit; one used vertex moved, a curve moves."""
    rng, V, F, pts, off = _scene(seed)
    b = bind(pts, off, V, F)
    used = b.used_vertices
    np.testing.assert_array_equal(used, np.unique(F[b.face]))
    free = np.setdiff1d(np.arange(len(V)), used)
    assert len(free)  # (40 curves on a 320-triangle sphere)
    V2 = V.copy()
    V2[free] += amp * rng.normal(size=(len(free), 3))
    np.testing.assert_array_equal(b.apply(V2), b.apply(V))
    V3 = V.copy()
    V3[used[rng.integers(len(used))]] += amp
    assert (b.apply(V3) != b.apply(V)).any()


def test_roots_off_the_surface_are_snapped():
    rng, V, F, pts, off = _scene(1)
    lifted = pts + 0.05 * pts[np.repeat(off[:-1], np.diff(off))]  # push outward a bit
    b = bind(lifted, off, V, F)
    out = b.apply(V)
    assert b.root_distance.max() > 1e-3
    A0, B0, _ = po.segments(lifted, off)
    A1, B1, _ = po.segments(out, off)
    np.testing.assert_allclose(B1 - A1, B0 - A0, atol=1e-9)  # translated onto the surface
    b2 = bind(lifted, off, V, F, snap_roots=False)
    np.testing.assert_allclose(b2.apply(V), lifted, atol=1e-9)


def test_save_and_load(tmp_path):
    rng, V, F, pts, off = _scene(2)
    b = bind(pts, off, V, F)
    np.savez(tmp_path / "bind.npz", **b.arrays())
    b2 = Binding.from_arrays(np.load(tmp_path / "bind.npz"))
    V2 = V * 1.3
    np.testing.assert_array_equal(b.apply(V2), b2.apply(V2))


def test_collapsed_triangle_translates_only():
    V, F = po.grid(2.0, 2)
    pts, off = po.pack([np.array([[0.3, 0.2, 0], [0.3, 0.2, 1.0]])])
    b = bind(pts, off, V, F)
    V2 = V.copy()
    V2[F[b.face]] = V2[F[b.face[0], 0]]  # collapse that triangle to a point
    out = b.apply(V2)
    np.testing.assert_allclose(out - out[0], pts - pts[0], atol=1e-12)


def test_bad_input():
    rng, V, F, pts, off = _scene(3)
    with pytest.raises(ColliderError, match="no triangle"):
        bind(pts, off, V, np.zeros((0, 3), int))
    Fd = F.copy()
    Fd[5] = [Fd[5, 0], Fd[5, 0], Fd[5, 1]]
    with pytest.raises(ColliderError, match="face 5"):
        bind(pts, off, V, Fd)
    b = bind(pts, off, V, Fd, drop_degenerate=True)
    assert (b.face != 5).all()
    with pytest.raises(ColliderError, match="out of range"):
        bind(pts, off, V, F + len(V))
    with pytest.raises(InputError, match="offsets describe"):
        bind(pts, off[:-1], V, F)
    b = bind(pts, off, V, F)
    with pytest.raises(ColliderError, match="same topology"):
        b.apply(V[:-1])


def test_closest_faces_against_brute_force():
    from core.pipeline import closest_faces

    rng = np.random.default_rng(9)
    V, F = po.icosphere((0.1, 0, 0), 1.0, 2)
    Q = np.vstack([rng.normal(size=(300, 3)) * 0.6, rng.normal(size=(30, 3)) * 4])
    P, face = closest_faces(V, F, Q)
    ref = po.point_mesh_distance(Q, V, F)
    np.testing.assert_allclose(np.linalg.norm(P - Q, axis=1), ref, atol=1e-12)
    # P lies on its face
    T = V[F[face]]
    n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("ij,ij->i", P - T[:, 0], n), 0, atol=1e-12)


def test_degenerate_faces_follow_the_colliders_rule():
    """One rule (tolerances.DEGENERATE_AREA_REL, as Collider): a tiny but well-shaped
    triangle binds (it did not under the old 1e-12 rule); a sliver whose normal float64
    cannot orient (tolerances.ATTACH_FRAME_MIN_SIN) does not."""
    from core import Collider

    V, F = po.grid(2.0, 2)
    s = 3e-7 * 2 * np.sqrt(2)  # edges ~3e-7 of the diagonal: area ~4e-14 diag^2
    V = np.vstack([V, [[0.3, 0.3, 0.01], [0.3 + s, 0.3, 0.01], [0.3, 0.3 + s, 0.01]]])
    F = np.vstack([F, [[9, 10, 11]]])
    Collider(V, F)  # the collider keeps it
    pts, off = po.pack([np.array([[0.3 + s / 4, 0.3 + s / 4, 0.01], [0.3, 0.3, 0.5]])])
    b = bind(pts, off, V, F)
    assert b.face[0] == 8
    np.testing.assert_allclose(b.apply(V + 1.0), pts + 1.0, atol=1e-9)
    # a sliver: an angle of ~1e-13 rad
    V2 = np.vstack([V[:9], [[0.5, 0.5, 0], [1.5, 0.5, 0], [1.0, 0.5 + 1e-13, 0]]])
    with pytest.raises(ColliderError, match="face 8 .* degenerate"):
        bind(pts, off, V2, F)
    bind(pts, off, V2, F, drop_degenerate=True)
