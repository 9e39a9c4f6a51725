"""Sanity checks of the independent oracle and scene builders themselves."""

from __future__ import annotations

import numpy as np
import oracle
import scenes


def test_segment_hits_known_cases():
    V, F = scenes.quad([-1, -1, 0], [2, 0, 0], [0, 2, 0])  # unit-ish square z=0
    A = np.array([[0.1, 0.2, -1], [0.1, 0.2, 0.5], [3, 0, -1], [0.1, 0.2, 0.0],
                  [0.1, 0.2, -1]])
    B = np.array([[0.1, 0.2, 1], [0.1, 0.2, 2.0], [3, 0, 1], [0.5, 0.2, 0.0],
                  [0.1, 0.2, 0.0]])
    sure = oracle.segment_hits(A, B, V, F, eps=oracle.SURE)
    maybe = oracle.segment_hits(A, B, V, F, eps=oracle.MAYBE)
    exact = oracle.segment_hits(A, B, V, F, eps=0.0)
    # crossing, above, outside, coplanar, ending on the surface
    assert sure.tolist() == [True, False, False, False, False]
    assert maybe.tolist() == [True, False, False, True, True]
    assert exact[0] and not exact[1] and not exact[2]


def test_segments_hit_mesh_per_curve_and_first_hit():
    V, F = scenes.grid(size=2, n=2, z=0.5)
    pts, offs = scenes.pack([
        scenes.straight_curve([0.1, 0.3, 0], [0, 0, 1], 0.9, 5),  # crosses in segment 2
        scenes.straight_curve([0.1, 0.3, 0], [0, 0, 1], 0.4, 3),  # too short
        scenes.straight_curve([5, 5, 0], [0, 0, 1], 1.0, 3),  # outside
    ])
    assert oracle.segments_hit_mesh(pts, offs, V, F).tolist() == [True, False, False]
    assert oracle.first_hit_segment(pts, offs, V, F).tolist() == [2, -1, -1]


def test_parity_inside():
    V, F = scenes.uv_sphere([1, 2, 3], 0.5, 24, 12)
    P = np.array([[1, 2, 3], [1.3, 2, 3], [1.6, 2, 3], [1, 2, 4], [1, 2.45, 3]])
    assert oracle.points_inside_closed_mesh(P, V, F).tolist() == [True, True, False, False, True]
    Vb, Fb = scenes.box([0, 0, 0], [1, 2, 3])
    P = np.array([[0.5, 1, 1.5], [1.5, 1, 1.5], [0.99, 1.99, 2.99], [-0.01, 1, 1]])
    assert oracle.points_inside_closed_mesh(P, Vb, Fb).tolist() == [True, False, True, False]


def test_distances():
    A = np.array([[0, 0, 0], [0, 0, 0]], float)
    B = np.array([[2, 0, 0], [0, 0, 0]], float)
    np.testing.assert_allclose(oracle.point_segment_distance([1, 1, 0], A, B), [1, np.sqrt(2)])
    pts, offs = scenes.pack([np.array([[0, 0, 0], [0, 0, 1.0], [0, 1, 1]])])
    d = oracle.curve_distance_to_sphere_center(pts, offs, [0, 2, 1])
    np.testing.assert_allclose(d, [1.0])
    np.testing.assert_allclose(oracle.distance_to_plane([[0, 0, 3]], [0, 0, 1], [0, 0, 2]), [2])


def test_builders_closed_and_outward():
    for V, F in (scenes.uv_sphere(), scenes.icosphere(subdivisions=1), scenes.box(),
                 scenes.bumpy_sphere(), scenes.torus()):
        assert scenes.is_closed_consistent(F)
        assert scenes.signed_volume(V, F) > 0
        assert scenes.signed_volume(V, scenes.flip(F)) < 0
    V, F = scenes.grid()
    assert not scenes.is_closed_consistent(F)
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    assert np.all(n[:, 2] > 0)


def test_fur_builders():
    rng = np.random.default_rng(0)
    pts, offs = scenes.fur_on_plane(rng, n_curves=10, n_cvs=(2, 12))
    assert offs[0] == 0 and offs[-1] == len(pts) and np.all(np.diff(offs) >= 2)
    assert np.all(pts[offs[:-1], 2] == 0)
    assert min(x.min() for x in scenes.segment_lengths(pts, offs)) > 0
    pts, offs = scenes.fur_on_sphere(rng, [1, 0, 0], 2.0, n_curves=10)
    np.testing.assert_allclose(np.linalg.norm(pts[offs[:-1]] - [1, 0, 0], axis=1), 2.0)


def test_transform_and_rotation_helpers():
    R = scenes.rotation_matrix([0, 0, 1], np.pi / 2)
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    M = scenes.affine(R, t=[1, 2, 3], s=2.0)
    np.testing.assert_allclose(oracle.transform([[1, 0, 0]], M), [[1, 4, 3]], atol=1e-15)


def test_absolute_margin():
    V, F = scenes.quad([0, 0, 0], [1, 0, 0], [0, 1, 0])
    # crosses 1e-3 inside the x=1 edge, far from the corners
    A, B = np.array([[0.999, 0.6, -1.0]]), np.array([[0.999, 0.6, 1.0]])
    assert oracle.segment_hits(A, B, V, F, eps=1e-5)[0]
    assert not oracle.segment_hits(A, B, V, F, eps=1e-5, abs_eps=1e-2)[0]
    assert oracle.segment_hits(A, B, V, F, eps=1e-5, abs_eps=1e-4)[0]
    # ends 1e-3 below the plane
    A2, B2 = np.array([[0.5, 0.6, -1e-3]]), np.array([[0.5, 0.6, 1.0]])
    assert oracle.segment_hits(A2, B2, V, F, eps=1e-5)[0]
    assert not oracle.segment_hits(A2, B2, V, F, eps=1e-5, abs_eps=1e-2)[0]
    # "maybe" grows the triangle by abs_eps
    A3, B3 = np.array([[1.001, 0.6, -1.0]]), np.array([[1.001, 0.6, 1.0]])
    assert not oracle.segment_hits(A3, B3, V, F, eps=-1e-5)[0]
    assert oracle.segment_hits(A3, B3, V, F, eps=-1e-5, abs_eps=1e-2)[0]
    assert oracle.float32_margin([[0, 0, 2.0]], ulps=1) == 2 * np.finfo(np.float32).eps
