"""Shared test helpers: hypothesis presets and rotation analysis (numpy only)."""

from __future__ import annotations

import numpy as np
import oracle
from hypothesis import settings
from hypothesis_profiles import examples

from core import Status

#: Property-test sizes: the loaded hypothesis profile (tests/conftest.py: ``ci`` by
#: default, ``--hypothesis-profile=thorough`` for ten times as many fresh examples)
#: decides randomness, database and scale; health checks stay on.
FAST = settings(max_examples=examples(15))
MEDIUM = settings(max_examples=examples(30))

#: The core's status codes, by name (``core.Status`` is their only definition).
FREE, COLLIDING, RECOVERING, PINCHED, UNRESOLVED, DISABLED = (
    Status.FREE, Status.COLLIDING, Status.RECOVERING, Status.PINCHED, Status.UNRESOLVED,
    Status.DISABLED)
EXCLUDED = (PINCHED, UNRESOLVED, DISABLED)
#: The same and INVALID: for scenes that may hold a curve with a non-finite point or a
#: zero-length segment (the solver leaves it as its input, not solved).
EXCLUDED_OR_INVALID = (*EXCLUDED, Status.INVALID)


def fit_rotation(A, B):
    """Kabsch: rotation R (3x3) minimising sum |R a_i - b_i|^2, and the rms residual."""
    A = np.asarray(A, float)
    B = np.asarray(B, float)
    H = A.T @ B
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    D = np.diag([1.0, 1.0, d if d != 0 else 1.0])
    R = Vt.T @ D @ U.T
    res = np.sqrt(np.mean(np.sum((A @ R.T - B) ** 2, axis=1)))
    return R, res


def rotation_angle(R):
    """Angle (radians) of a rotation matrix."""
    return float(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0)))


def rotation_axis(R):
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    n = np.linalg.norm(w)
    if n < 1e-9:
        # angle 0 or pi: take the eigenvector of eigenvalue 1
        vals, vecs = np.linalg.eigh((R + R.T) / 2)
        return vecs[:, np.argmax(vals)]
    return w / n


def angle_between(u, v):
    """Row-wise angle (radians) between vectors."""
    u = np.asarray(u, float)
    v = np.asarray(v, float)
    nu = np.linalg.norm(u, axis=-1)
    nv = np.linalg.norm(v, axis=-1)
    c = np.einsum("...i,...i->...", u, v) / (nu * nv)
    s = np.linalg.norm(np.cross(u, v), axis=-1) / (nu * nv)
    return np.arctan2(s, c)


def common_axis_angles(seg_in, seg_out):
    """For a curve deformed by rotations about ONE common axis (stiff/bend):
    return (axis, per-segment signed angles in radians, mask of segments whose
    angle is well defined). Lengths may differ (shrink): directions are
    compared. Returns (None, None, None) when there is no rotation at all."""
    a = np.asarray(seg_in, float)
    b = np.asarray(seg_out, float)
    an = a / np.linalg.norm(a, axis=1, keepdims=True)
    bn = b / np.linalg.norm(b, axis=1, keepdims=True)
    D = bn - an
    if np.abs(D).max() < 1e-9:
        return None, None, None
    # the axis is orthogonal to every difference (rotation about it moves
    # vectors in planes orthogonal to it)
    _, s, Vt = np.linalg.svd(np.vstack([D, np.zeros((2, 3))]))
    axis = Vt[-1] if s[1] > 1e-7 * s[0] else None
    if axis is None:
        # differences are all parallel (rank 1): axis = cross(in, out) of the
        # most rotated segment
        k = int(np.argmax(np.linalg.norm(D, axis=1)))
        axis = np.cross(an[k], bn[k])
        axis /= np.linalg.norm(axis)
    pa = an - np.outer(an @ axis, axis)
    pb = bn - np.outer(bn @ axis, axis)
    ok = (np.linalg.norm(pa, axis=1) > 0.2) & (np.linalg.norm(pb, axis=1) > 0.2)
    ang = np.arctan2(np.cross(pa, pb) @ axis, np.einsum("ij,ij->i", pa, pb))
    # orient so the most rotated segment has a positive angle
    if ok.any() and ang[ok][np.argmax(np.abs(ang[ok]))] < 0:
        axis, ang = -axis, -ang
    return axis, ang, ok


def ramp(angle_deg, scale_minimum, scale_angle):
    """Paper 3.2.2: linear scale ramp, clamped."""
    return 1.0 - (1.0 - scale_minimum) * np.minimum(np.asarray(angle_deg) / scale_angle, 1.0)


def rotate_curve(curve, axis, angle_rad):
    """Rigidly rotate a curve about its root."""
    from scenes import rotation_matrix

    R = rotation_matrix(axis, angle_rad)
    c = np.asarray(curve, float)
    return c[0] + (c - c[0]) @ R.T


def assert_no_intersection(points, offsets, status, meshes, excluded=EXCLUDED, eps=oracle.SURE):
    """Every curve whose status is not excluded is clear of every (V_world, F).

    Crossings finer than a few float32 ulps of the absolute coordinates (the
    core ray-traces in float32) are not counted."""
    status = np.asarray(status)
    keep = ~np.isin(status, excluded)
    for k, (V, F) in enumerate(meshes):
        margin = oracle.float32_margin(points, V)
        hits = oracle.segments_hit_mesh(points, offsets, V, F, eps=eps, abs_eps=margin)
        bad = np.nonzero(hits & keep)[0]
        assert len(bad) == 0, (
            f"curves {bad[:10].tolist()} (status {status[bad[:10]].tolist()}) "
            f"intersect collider #{k}"
        )


def assert_roots_exact(points_in, points_out, offsets):
    roots = np.asarray(offsets[:-1])
    assert np.array_equal(points_in[roots], points_out[roots]), "roots moved"


def assert_lengths_kept(points_in, points_out, offsets, rtol, mask=None):
    from scenes import segment_lengths

    Li = segment_lengths(points_in, offsets)
    Lo = segment_lengths(points_out, offsets)
    for c, (a, b) in enumerate(zip(Li, Lo, strict=True)):
        if mask is not None and not mask[c]:
            continue
        np.testing.assert_allclose(b, a, rtol=rtol, atol=0,
                                   err_msg=f"curve {c} segment lengths changed")


def curve_max_displacement(p, q, offsets):
    d = np.linalg.norm(np.asarray(p, float) - np.asarray(q, float), axis=1)
    return np.array([d[offsets[i]:offsets[i + 1]].max() for i in range(len(offsets) - 1)])


def rigid_angle(seg_in, seg_out):
    """(angle_rad, unit axis) of the rotation taking seg_in to seg_out (rows).

    For (nearly) straight curves the rotation is not determined by the data;
    then the rotation is taken as the minimal one taking the first segment to
    its output (the core's axis is perpendicular to a straight curve, since
    it is built from the root-to-hit-point chord)."""
    a = np.asarray(seg_in, float)
    b = np.asarray(seg_out, float)
    an = a / np.linalg.norm(a, axis=1, keepdims=True)
    s = np.linalg.svd(an, compute_uv=False)
    if len(s) >= 2 and s[1] > 1e-6 * s[0]:
        R, _ = fit_rotation(a, b / (np.linalg.norm(b, axis=1) / np.linalg.norm(a, axis=1))[:, None])
        return rotation_angle(R), rotation_axis(R)
    ang = float(angle_between(a[0], b[0]))
    ax = np.cross(a[0], b[0])
    n = np.linalg.norm(ax)
    return ang, (ax / n if n > 0 else np.array([1.0, 0, 0]))
