"""A collider's previous placement and its surface velocity (``Collider.previous``,
``place``, ``set_previous``, ``forget_previous``, ``velocities``): what Follow
Collider Motion turns curves along."""

from __future__ import annotations

import numpy as np
import pytest
import scenes

from core import Collider, ColliderError


def _ball(**kw):
    V, F = scenes.icosphere([0, 0, 0], 1.0, 2)
    return Collider(V, F, **kw), V, F


def _points_on(col, n=20, seed=0):
    rng = np.random.default_rng(seed)
    V = col.vertices.astype(np.float64)
    Fc = col.faces[rng.integers(0, len(col.faces), n)]
    w = rng.dirichlet([1, 1, 1], n)
    local = np.einsum("ki,kij->kj", w, V[Fc])
    M = col.matrix
    return local @ M[:3, :3].T + M[:3, 3]


def test_a_new_collider_has_no_previous_placement_and_no_velocity():
    col, _, _ = _ball()
    assert col.previous is None
    assert np.array_equal(col.velocities(_points_on(col)), np.zeros((20, 3)))


def test_translation_is_the_velocity_everywhere():
    col, _, _ = _ball(matrix=scenes.affine(t=[1.0, 2.0, 3.0]))
    col.matrix = scenes.affine(t=[1.5, 2.0, 2.75])
    p = _points_on(col)
    np.testing.assert_allclose(col.velocities(p), np.tile([0.5, 0.0, -0.25], (20, 1)),
                               atol=1e-12)
    np.testing.assert_array_equal(col.previous.matrix, scenes.affine(t=[1.0, 2.0, 3.0]))


def test_rotation_and_scale_give_each_point_its_own_motion():
    M0 = scenes.affine(t=[0.3, 0, 0], s=0.5)
    col, _, _ = _ball(matrix=M0)
    M1 = scenes.affine(R=scenes.rotation_matrix([0, 0, 1], 0.1), t=[0.4, 0, 0], s=0.6)
    col.matrix = M1
    p = _points_on(col)
    x = (p - M1[:3, 3]) @ np.linalg.inv(M1[:3, :3]).T  # own space
    want = p - (x @ M0[:3, :3].T + M0[:3, 3])
    np.testing.assert_allclose(col.velocities(p), want, atol=1e-12)


def test_deformation_moves_points_with_their_faces():
    """A face's points move with its vertices (barycentric weights), under the
    matrix too; with the hit faces given or looked up."""
    col, V, F = _ball(matrix=scenes.affine(t=[0, 0, 1.0], s=2.0))
    rng = np.random.default_rng(3)
    faces = rng.integers(0, len(F), 30)
    w = rng.dirichlet([2, 2, 2], 30)
    V0 = col.vertices.astype(np.float64)
    col.vertices = V * np.array([1.0, 1.0, 1.3]) + [0.1, 0.0, 0.0]  # stretched, shifted
    V1 = col.vertices.astype(np.float64)
    p_prev = np.einsum("ki,kij->kj", w, V0[F[faces]]) * 2.0 + [0, 0, 1.0]
    p_now = np.einsum("ki,kij->kj", w, V1[F[faces]]) * 2.0 + [0, 0, 1.0]
    np.testing.assert_allclose(col.velocities(p_now, faces=faces), p_now - p_prev, atol=1e-6)
    np.testing.assert_allclose(col.velocities(p_now), p_now - p_prev, atol=1e-6)


def test_still_collider_has_exactly_zero_velocity():
    col, V, _ = _ball(matrix=scenes.affine(R=scenes.rotation_matrix([1, 2, 3], 0.7),
                                           t=[1e3, -2e3, 5.0], s=0.37))
    p = _points_on(col)
    col.place(matrix=col.matrix, vertices=V)  # the same placement again: an update
    assert col.previous is not None
    assert np.array_equal(col.velocities(p), np.zeros_like(p))
    col.matrix = col.matrix
    col.vertices = V.copy()
    assert np.array_equal(col.velocities(p), np.zeros_like(p))


def test_place_is_one_update_of_both_parts():
    col, V, _ = _ball()
    M1 = scenes.affine(t=[0, 0, 1.0])
    col.place(matrix=M1, vertices=V * 1.1)
    prev = col.previous
    assert np.array_equal(prev.matrix, np.eye(4))
    assert np.array_equal(prev.vertices, V.astype(np.float32))
    col.place(matrix=M1)  # vertices unchanged: they did not move in this update
    assert np.array_equal(col.previous.matrix, M1)
    assert np.array_equal(col.previous.vertices, col.vertices)
    assert not col.previous.vertices.flags.writeable
    p = _points_on(col)
    assert np.array_equal(col.velocities(p), np.zeros_like(p))


def test_each_setter_updates_its_own_part():
    col, V, _ = _ball()
    M1 = scenes.affine(t=[0, 0, 1.0])
    col.matrix = M1
    assert np.array_equal(col.previous.matrix, np.eye(4))
    assert np.array_equal(col.previous.vertices, col.vertices)  # (not assigned: as now)
    col.vertices = V * 1.2
    assert np.array_equal(col.previous.vertices, V.astype(np.float32))
    assert np.array_equal(col.previous.matrix, np.eye(4))  # the matrix's part stays


def test_set_and_forget_previous():
    col, V, _ = _ball(matrix=scenes.affine(t=[0, 0, 1.0]))
    p = _points_on(col)
    col.set_previous(matrix=scenes.affine(t=[0, 0, 0.8]))
    np.testing.assert_allclose(col.velocities(p), np.tile([0, 0, 0.2], (20, 1)), atol=1e-12)
    col.set_previous(vertices=V * 0.5)  # matrix None: as now
    assert np.array_equal(col.previous.matrix, col.matrix)
    v = col.velocities(p)
    np.testing.assert_allclose(v, (p - [0, 0, 1.0]) * 0.5, atol=1e-6)  # grew twice as big
    col.set_previous(vertices=V)  # the current vertices: no deformation
    assert np.array_equal(col.velocities(p), np.zeros_like(p))
    col.forget_previous()
    assert col.previous is None
    assert np.array_equal(col.velocities(p), np.zeros_like(p))
    with pytest.raises(ColliderError, match="previous vertices have shape"):
        col.set_previous(vertices=V[:5])
    with pytest.raises(ColliderError, match="4x4"):
        col.set_previous(matrix=np.eye(3))


def test_empty_collider_and_no_points():
    col = Collider(np.zeros((0, 3)), np.zeros((0, 3), int))
    col.matrix = scenes.affine(t=[1, 0, 0])
    assert col.velocities(np.ones((3, 3))).shape == (3, 3)
    ball, _, _ = _ball()
    ball.matrix = scenes.affine(t=[1, 0, 0])
    assert ball.velocities(np.zeros((0, 3))).shape == (0, 3)
