"""Small vectorized rotation helpers (axis-angle, quaternions, frames).

Quaternions are ``(w, x, y, z)`` arrays of shape (k, 4); angles in radians.
"""

from __future__ import annotations

import numpy as np

from . import tolerances as tol


def normalize(v):
    """Row-normalize (k, 3); zero rows stay zero."""
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def det3(A):
    """Determinant of a 3x3 matrix, closed form (no LAPACK: see :func:`apply`)."""
    return float(
        A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1])
        - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
        + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0])
    )


def inv_affine(M):
    """Inverse of a 4x4 affine matrix via the 3x3 adjugate (no LAPACK)."""
    A = M[:3, :3]
    adj = np.array(
        [
            [
                A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1],
                A[0, 2] * A[2, 1] - A[0, 1] * A[2, 2],
                A[0, 1] * A[1, 2] - A[0, 2] * A[1, 1],
            ],
            [
                A[1, 2] * A[2, 0] - A[1, 0] * A[2, 2],
                A[0, 0] * A[2, 2] - A[0, 2] * A[2, 0],
                A[0, 2] * A[1, 0] - A[0, 0] * A[1, 2],
            ],
            [
                A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0],
                A[0, 1] * A[2, 0] - A[0, 0] * A[2, 1],
                A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0],
            ],
        ]
    )
    Ai = adj / det3(A)
    out = np.eye(4)
    out[:3, :3] = Ai
    out[:3, 3] = -np.einsum("ij,j->i", Ai, M[:3, 3])
    return out


def norm_bound(A):
    """An upper bound of the spectral norm of a 3x3 matrix (its Frobenius
    norm): the largest length a unit vector can get, without an SVD."""
    return float(np.sqrt(np.einsum("ij,ij->", A, A)))


def apply(A, x):
    """Rows of ``x`` (k, 3) mapped by the 3x3 ``A`` (``x @ A.T``).

    einsum rather than ``@``: numpy's BLAS would start its own thread pool
    for these tall, thin products, spinning against the ray tracer's threads
    for no gain. For the same reason the core calls no LAPACK routine
    (``np.linalg.inv``, ``det``, ``svd``) in a per-frame path: OpenBLAS
    workers woken by them spin for a while after each call.
    """
    return np.einsum("ij,kj->ki", A, x)


def stable_perpendicular(v):
    """A unit vector perpendicular to each unit row of ``v``, continuous per octant.

    Uses the world axis least aligned with ``v`` (deterministic).
    """
    e = np.zeros_like(v)
    e[np.arange(len(v)), np.argmin(np.abs(v), axis=1)] = 1.0
    return normalize(np.cross(v, e))


def rotate(v, axis, angle):
    """Rodrigues: rotate rows of ``v`` about unit ``axis`` rows by ``angle`` (k,)."""
    c = np.cos(angle)[:, None]
    s = np.sin(angle)[:, None]
    return v * c + np.cross(axis, v) * s + axis * (dot(axis, v)[:, None] * (1.0 - c))


def rotate_soa(v, axis, angle):
    """:func:`rotate` on component arrays: ``v`` (3, ..., n) rotated about
    ``axis`` (n, 3) by ``angle`` (..., n), returned as (3, ..., n).

    The same arithmetic as :func:`rotate` (bit-identical results), with every
    elementwise pass over long contiguous rows instead of rows of 3.
    """
    c, s = np.cos(angle), np.sin(angle)
    axis = np.ascontiguousarray(axis.T)  # components as contiguous rows
    a0, a1, a2 = axis
    v0, v1, v2 = v
    along = v0 * a0
    p = v1 * a1
    along += p
    np.multiply(v2, a2, out=p)
    along += p
    along *= np.subtract(1.0, c, out=p)
    out = np.empty_like(v)
    q = np.empty_like(p)
    for i, (j, k) in enumerate(((1, 2), (2, 0), (0, 1))):
        np.multiply(axis[j], v[k], out=p)
        p -= np.multiply(axis[k], v[j], out=q)  # (axis x v)_i
        p *= s
        o = out[i]
        np.multiply(v[i], c, out=o)
        o += p
        o += np.multiply(axis[i], along, out=p)
    return out


def cumsum_soa(d):
    """``np.cumsum(d, axis=1)`` (the same sequential sums, bit-identical) as
    one pass per step: numpy's accumulate is slow on short axes."""
    out = np.empty_like(d)
    out[:, 0] = d[:, 0]
    for j in range(1, d.shape[1]):
        np.add(out[:, j - 1], d[:, j], out=out[:, j])
    return out


def cumsum_owned(x, rep, starts):
    """``np.cumsum(x, axis=0)`` restarted at every owner's first row.

    Parameters
    ----------
    x : (k, ...) ndarray
        Rows grouped by owner (a curve's segments are consecutive).
    rep : (k,) int
        Owner of each row (0..n-1, non-decreasing).
    starts : (n,) int
        First row of each owner.

    Returns
    -------
    (k, ...) float64
        Each owner's own sequential sums, computed on a padded
        (n, longest, ...) array: a curve's result never depends on the
        curves batched before it (one global cumsum minus each curve's
        offset would carry their rounding), and equals :func:`cumsum_soa`'s
        for the same rows.
    """
    n = len(starts)
    if n == 0 or len(x) == 0:
        return np.zeros(x.shape, np.float64)
    pos = np.arange(len(x)) - starts[rep]
    pad = np.zeros((n, int(pos.max()) + 1) + x.shape[1:])
    pad[rep, pos] = x
    np.cumsum(pad, axis=1, out=pad)
    return pad[rep, pos]


def apply_soa(A, x):
    """:func:`apply` on component arrays: ``x`` (3, ...) mapped by the 3x3
    ``A``, returned as (3, ...) (the same sums in the same order)."""
    out = np.empty_like(x)
    tmp = np.empty_like(x[0])
    for i in range(3):
        o = out[i]
        np.multiply(x[0], A[i, 0], out=o)
        o += np.multiply(x[1], A[i, 1], out=tmp)
        o += np.multiply(x[2], A[i, 2], out=tmp)
    return out


def aos(v, out=None):
    """Component arrays (3, ns, n) to rows (n, ns, 3), C-contiguous."""
    if out is None:
        out = np.empty(v.shape[:0:-1] + (3,), v.dtype)
    for i in range(3):
        out[..., i] = v[i].T
    return out


def quat_rotate_soa(q, v):
    """:func:`quat_rotate` on component arrays: unit quaternions ``q`` (4, ...)
    rotating vectors ``v`` (3, ...), returned as (3, ...) (the arithmetic of
    :func:`quat_rotate`, term by term)."""
    w, u = q[0], q[1:]
    t = cross3(u, v)
    t *= 2.0
    out = cross3(u, t)
    for i in range(3):
        out[i] += v[i] + w * t[i]
    return out


def rows32(x):
    """Component arrays (3, ...) as float32 rows (k, 3) (rays for the tracer),
    in the order of ``x[0]``'s elements."""
    out = np.empty(x.shape[1:] + (3,), np.float32)
    for i in range(3):
        out[..., i] = x[i]
    return out.reshape(-1, 3)


def rotate_between(v, a, b):
    """Apply the minimal rotation taking unit ``a`` to unit ``b`` to ``v`` (rows)."""
    w = np.cross(a, b)
    c = dot(a, b)
    k = 1.0 / np.maximum(1.0 + c, 1e-12)
    return v * c[:, None] + np.cross(w, v) + w * (dot(w, v) * k)[:, None]


def quat_from_axis_angle(axis, angle):
    h = 0.5 * angle
    return np.concatenate([np.cos(h)[:, None], axis * np.sin(h)[:, None]], axis=1)


def quat_mul(p, q):
    pw, pv = p[:, :1], p[:, 1:]
    qw, qv = q[:, :1], q[:, 1:]
    w = pw * qw - dot(pv, qv)[:, None]
    v = pw * qv + qw * pv + np.cross(pv, qv)
    return np.concatenate([w, v], axis=1)


def quat_rotate(q, v):
    """Rotate rows of ``v`` by unit quaternions ``q``."""
    w, u = q[:, :1], q[:, 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_angle(q):
    """Rotation angle in [0, pi] of each unit quaternion."""
    return 2.0 * np.arctan2(np.linalg.norm(q[:, 1:], axis=1), np.abs(q[:, 0]))


def quat_canonical(q):
    """Same rotation with ``w >= 0`` (so slerp takes the short way)."""
    return np.where(q[:, :1] < 0, -q, q)


def quat_slerp(p, q, t):
    """Spherical interpolation from ``p`` to ``q`` by ``t`` (k,) in [0, 1]."""
    d = dot(p, q)
    q = np.where(d[:, None] < 0, -q, q)
    d = np.abs(d)
    t = np.broadcast_to(np.asarray(t, np.float64), d.shape)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    small = s < 1e-9
    a = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / np.where(small, 1.0, s))
    b = np.where(small, t, np.sin(t * theta) / np.where(small, 1.0, s))
    out = p * a[:, None] + q * b[:, None]
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    # Exact at the ends: t = 0 is p and t = 1 is q, bit for bit.
    out = np.where((t == 0)[:, None], p, out)
    return np.where((t == 1)[:, None], q, out)


def rotation_axis(c, d):
    """Unit axis turning vector ``c`` toward direction ``d`` (rows).

    Falls back to a deterministic perpendicular of ``c`` when they are
    parallel (any axis turns ``c`` away from itself).
    """
    a = np.cross(c, d)
    n = np.linalg.norm(a, axis=1)
    cn = np.linalg.norm(c, axis=1) * np.maximum(np.linalg.norm(d, axis=1), 1e-300)
    bad = n <= tol.PARALLEL_EPS * np.maximum(cn, 1e-300)
    a = normalize(a)
    if bad.any():
        a[bad] = stable_perpendicular(normalize(c[bad]))
    return a


def dot3(a, b):
    """Row dots of component arrays (3, k): the sums of :func:`dot`."""
    out = a[0] * b[0]
    out += a[1] * b[1]
    out += a[2] * b[2]
    return out


def norm3(v):
    """Row lengths of component arrays (3, k), as ``np.linalg.norm``."""
    return np.sqrt(dot3(v, v))


def unit3(v, n=None):
    """:func:`normalize` on component arrays (3, k); zero rows stay zero."""
    n = norm3(v) if n is None else n
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def cross3(a, b):
    """``np.cross`` on component arrays (3, k) (the same products)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    for i, (j, k) in enumerate(((1, 2), (2, 0), (0, 1))):
        np.multiply(a[j], b[k], out=out[i])
        out[i] -= a[k] * b[j]
    return out


def curve_frames(t, u_shape, shape_ratio, prev_ref=None):
    """Per-curve orthonormal frames, rows (e0, e1, e2), shape (k, 3, 3).

    ``e0`` is the root segment direction ``t``. ``e1`` follows the curve's own
    shape (its tip offset perpendicular to ``t``) when the curve is bent
    enough, and otherwise a *reference* perpendicular carried from frame to
    frame by the minimal rotation of the root segment, blending between the
    two so the frame never jumps. The reference is pure transport (no shape
    in it), so a curve that does not move keeps exactly the same frame.

    Parameters
    ----------
    t : (3, k) components of the unit root segment directions.
    u_shape : (3, k) tip minus root, made perpendicular to ``t``.
    shape_ratio : (k,) ``|u_shape|`` over the curve length.
    prev_ref : (k, 3, 3) or None
        The previous step's references (rows ``t``, reference, their cross);
        None: no history.

    Returns
    -------
    frames : (k, 3, 3)
    ref : (k, 3, 3)
        The references to pass as ``prev_ref`` next time.
    e1 : (3, k)
        The frames' second rows as components (``e0`` is ``t``).

    The work is done on component arrays with the arithmetic of
    :func:`normalize`, :func:`dot`, :func:`rotate_between` and ``np.cross``.
    """
    if prev_ref is None:
        carried = np.ascontiguousarray(stable_perpendicular(t.T).T)
    else:
        a = np.ascontiguousarray(prev_ref[:, 0].T)
        v = np.ascontiguousarray(prev_ref[:, 1].T)
        # rotate_between(v, a, t)
        w = cross3(a, t)
        c = dot3(a, t)
        kk = 1.0 / np.maximum(1.0 + c, 1e-12)
        carried = v * c
        carried += cross3(w, v)
        carried += w * (dot3(w, v) * kk)
        carried = carried - dot3(carried, t) * t
        n = norm3(carried)
        bad = n < 0.5
        carried = unit3(carried, n)
        if bad.any():
            carried[:, bad] = stable_perpendicular(t[:, bad].T).T
    alpha = np.clip(
        (shape_ratio - tol.FRAME_SHAPE_LO) / (tol.FRAME_SHAPE_HI - tol.FRAME_SHAPE_LO), 0.0, 1.0
    )
    e1 = alpha * unit3(u_shape)
    e1 += (1.0 - alpha) * carried
    e1 = e1 - dot3(e1, t) * t
    n = norm3(e1)
    bad = n < 1e-6
    e1 = unit3(e1, n)
    e1[:, bad] = carried[:, bad]
    k = t.shape[1]
    frames = np.empty((k, 3, 3))
    ref = np.empty((k, 3, 3))
    for out, e in ((frames, e1), (ref, carried)):
        out[:, 0] = t.T
        out[:, 1] = e.T
        out[:, 2] = cross3(t, e).T
    return frames, ref, e1


# ------------------------------------------------ quaternion fits (fur pipeline)
def quat_swing(a, b):
    """Minimal rotation quaternions (k, 4) taking unit rows ``a`` to unit rows ``b``.

    Antiparallel rows (within ``1e-12``) get the half turn about a
    deterministic perpendicular axis.
    """
    c = np.sum(a * b, -1)
    q = np.concatenate([(1.0 + c)[..., None], np.cross(a, b)], -1)
    anti = c < -1 + 1e-12
    if anti.any():
        aa = a[anti]
        e = np.zeros_like(aa)
        e[np.arange(len(aa)), np.argmin(np.abs(aa), -1)] = 1.0
        q[anti] = np.concatenate([np.zeros((len(aa), 1)), np.cross(aa, e)], -1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_from_matrix(R):
    """Unit quaternions (k, 4) of rotation matrices ``R`` (k, 3, 3) (Shepperd's method)."""
    t = np.stack([R[:, 0, 0] + R[:, 1, 1] + R[:, 2, 2], R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], 1)
    case = np.argmax(t, 1)
    q = np.empty((len(R), 4))
    for c in range(4):
        s = case == c
        if not s.any():
            continue
        r = R[s]
        if c == 0:
            w = np.sqrt(1 + r[:, 0, 0] + r[:, 1, 1] + r[:, 2, 2]) * 2
            q[s] = np.stack([0.25 * w, (r[:, 2, 1] - r[:, 1, 2]) / w,
                             (r[:, 0, 2] - r[:, 2, 0]) / w, (r[:, 1, 0] - r[:, 0, 1]) / w], 1)
        else:
            i = c - 1
            j, k = (i + 1) % 3, (i + 2) % 3
            w = np.sqrt(1 + r[:, i, i] - r[:, j, j] - r[:, k, k]) * 2
            out = np.empty((int(s.sum()), 4))
            out[:, 0] = (r[:, k, j] - r[:, j, k]) / w
            out[:, 1 + i] = 0.25 * w
            out[:, 1 + j] = (r[:, j, i] + r[:, i, j]) / w
            out[:, 1 + k] = (r[:, k, i] + r[:, i, k]) / w
            q[s] = out
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def quat_matrix(q):
    """Rotation matrices (k, 3, 3) of unit quaternions ``q`` (k, 4) ``(w, x, y, z)``."""
    w, x, y, z = np.asarray(q, np.float64).T
    R = np.empty((len(w), 3, 3))
    R[:, 0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[:, 0, 1] = 2.0 * (x * y - w * z)
    R[:, 0, 2] = 2.0 * (x * z + w * y)
    R[:, 1, 0] = 2.0 * (x * y + w * z)
    R[:, 1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[:, 1, 2] = 2.0 * (y * z - w * x)
    R[:, 2, 0] = 2.0 * (x * z - w * y)
    R[:, 2, 1] = 2.0 * (y * z + w * x)
    R[:, 2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return R


def _minors_sym4(a00, a01, a02, a03, a11, a12, a13, a22, a23, a33):
    """The 2x2 minors of the top (``s``) and bottom (``c``) row pairs of symmetric
    4x4 matrices given by their upper-triangle component arrays (g,) (Laplace)."""
    s0 = a00 * a11 - a01 * a01
    s1 = a00 * a12 - a01 * a02
    s2 = a00 * a13 - a01 * a03
    s3 = a01 * a12 - a11 * a02
    s4 = a01 * a13 - a11 * a03
    s5 = a02 * a13 - a12 * a03
    c0 = a02 * a13 - a03 * a12
    c1 = a02 * a23 - a03 * a22
    c2 = a02 * a33 - a03 * a23
    c3 = a12 * a23 - a13 * a22
    c4 = a12 * a33 - a13 * a23
    c5 = a22 * a33 - a23 * a23
    return (s0, s1, s2, s3, s4, s5), (c0, c1, c2, c3, c4, c5)


def _det_sym4(s, c):
    """Determinants (g,) from :func:`_minors_sym4`'s minors."""
    return s[0] * c[5] - s[1] * c[4] + s[2] * c[3] + s[3] * c[2] - s[4] * c[1] + s[5] * c[0]


def _adjugate_sym4(a00, a01, a02, a03, a11, a12, a13, a22, a23, a33):
    """Adjugate (4, 4, g) of symmetric 4x4 matrices given by their upper-triangle
    component arrays (g,)."""
    (s0, s1, s2, s3, s4, s5), (c0, c1, c2, c3, c4, c5) = _minors_sym4(
        a00, a01, a02, a03, a11, a12, a13, a22, a23, a33)
    B = np.empty((4, 4) + np.shape(a00))
    B[0, 0] = a11 * c5 - a12 * c4 + a13 * c3
    B[0, 1] = -a01 * c5 + a02 * c4 - a03 * c3
    B[0, 2] = a13 * s5 - a23 * s4 + a33 * s3
    B[0, 3] = -a12 * s5 + a22 * s4 - a23 * s3
    B[1, 0] = -a01 * c5 + a12 * c2 - a13 * c1
    B[1, 1] = a00 * c5 - a02 * c2 + a03 * c1
    B[1, 2] = -a03 * s5 + a23 * s2 - a33 * s1
    B[1, 3] = a02 * s5 - a22 * s2 + a23 * s1
    B[2, 0] = a01 * c4 - a11 * c2 + a13 * c0
    B[2, 1] = -a00 * c4 + a01 * c2 - a03 * c0
    B[2, 2] = a03 * s4 - a13 * s2 + a33 * s0
    B[2, 3] = -a02 * s4 + a12 * s2 - a23 * s0
    B[3, 0] = -a01 * c3 + a11 * c1 - a12 * c0
    B[3, 1] = a00 * c3 - a01 * c1 + a02 * c0
    B[3, 2] = -a03 * s3 + a13 * s1 - a23 * s0
    B[3, 3] = a02 * s3 - a12 * s1 + a22 * s0
    return B


def quat_fit(H):
    """Best rotations (g, 4) for correlation matrices ``H = sum a b^T`` (g, 3, 3),
    without an SVD (Horn's quaternion method, solved as in Theobald's QCP).

    The rotation maximizing ``sum b . R a`` is the unit eigenvector of the
    largest eigenvalue of a symmetric 4x4 matrix ``N(H)``. That eigenvalue is
    found by Newton's method on ``N``'s characteristic polynomial from an upper
    bound (monotone: every root is real), the eigenvector as a row of the
    adjugate of ``N - lambda I``, all on component arrays. :func:`kabsch` does
    the same with a batched SVD, about five times slower.

    Parameters
    ----------
    H : (g, 3, 3) array_like of float

    Returns
    -------
    q : (g, 4) ndarray of float64
        Unit quaternions, ``w >= 0``.
    ok : (g,) ndarray of bool
        Where the fit is trusted (within ~3e-14 of :func:`kabsch`'s): the top
        eigenvalue stands clear of the next (``tol.QUAT_FIT_GAP``), Newton
        converged (``tol.QUAT_FIT_ITERS``) and ``q`` is an eigenvector of that
        eigenvalue (near a double root, rounding can throw Newton off its
        monotone path: this catches it). Elsewhere (nearly collinear
        vectors, vectors that fix no rotation, a zero ``H``) use
        :func:`kabsch`; ``q`` is then unspecified but finite.
    """
    H = np.asarray(H, np.float64)
    g = len(H)
    h = H.reshape(g, 9).T
    f = np.sqrt(np.einsum("ig,ig->g", h, h))  # (the fit does not depend on the scale:
    good = np.isfinite(f) & (f > 0)           # |H| = 1 keeps the quartic in range)
    h = np.divide(h, f, out=np.zeros_like(h), where=good)
    xx, xy, xz, yx, yy, yz, zx, zy, zz = h
    n00, n11 = xx + yy + zz, xx - yy - zz
    n22, n33 = yy - xx - zz, zz - xx - yy
    n01, n02, n03 = yz - zy, zx - xz, xy - yx
    n12, n13, n23 = xy + yx, zx + xz, yz + zy
    bound = np.sqrt(3.0)  # >= s1 + s2 + s3 >= the top eigenvalue of N, as |H| = 1
    # N's characteristic polynomial lam^4 + c2 lam^2 + c1 lam + c0 (N is traceless)
    c2 = np.full(g, -2.0)
    c1 = -8.0 * (xx * (yy * zz - yz * zy) - xy * (yx * zz - yz * zx)
                 + xz * (yx * zy - yy * zx))
    c0 = _det_sym4(*_minors_sym4(n00, n01, n02, n03, n11, n12, n13, n22, n23, n33))
    lam = np.full(g, bound)
    tiny = 4.0 * np.finfo(np.float64).eps * bound
    done = np.zeros(g, bool)
    for _ in range(tol.QUAT_FIT_ITERS):  # from above the top root: monotone
        l2 = lam * lam
        P = ((l2 + c2) * lam + c1) * lam + c0
        dP = (4.0 * l2 + 2.0 * c2) * lam + c1
        step = np.divide(P, dP, out=np.zeros(g), where=dP > 0)
        np.maximum(step, 0.0, out=step)  # (rounding below the root: stay)
        lam -= step
        done = step <= tiny
        if done.all():
            break
    B = _adjugate_sym4(n00 - lam, n01, n02, n03, n11 - lam, n12, n13, n22 - lam, n23,
                       n33 - lam)
    diag = np.abs(np.stack([B[0, 0], B[1, 1], B[2, 2], B[3, 3]]))
    row = np.argmax(diag, 0)
    q = np.take_along_axis(B, row[None, None], 0)[0].T  # (g, 4): adj is symmetric
    norm = np.sqrt(np.einsum("gi,gi->g", q, q))
    ok = done & good & (diag.max(0) >= tol.QUAT_FIT_GAP * bound**3)
    q = np.where(ok[:, None], q / np.where(norm > 0, norm, 1.0)[:, None],
                 np.array([1.0, 0.0, 0.0, 0.0]))
    w, x, y, z = q.T
    res = np.abs((n00 - lam) * w + n01 * x + n02 * y + n03 * z)
    for r in ((n01 * w + (n11 - lam) * x + n12 * y + n13 * z),
              (n02 * w + n12 * x + (n22 - lam) * y + n23 * z),
              (n03 * w + n13 * x + n23 * y + (n33 - lam) * z)):
        np.maximum(res, np.abs(r), out=res)
    ok &= res <= tol.QUAT_FIT_RESIDUAL * bound
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q, ok


def kabsch(H):
    """Best rotations for correlation matrices ``H = sum a b^T`` (g, 3, 3) (Kabsch).

    Returns
    -------
    R : (g, 3, 3)
        The proper rotations maximizing ``sum b . R a``.
    S : (g, 3)
        Singular values of ``H`` (descending): a small second one means the
        vectors do not fix a rotation.

    Batched 3x3 SVDs: bind-time or per-guide work, not per render CV.
    """
    U, S, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("gji,gkj->gik", Vt, U)))  # det(V U^T)
    d[d == 0] = 1.0
    D = np.ones((len(H), 3))
    D[:, 2] = d
    return np.einsum("gji,gj,gkj->gik", Vt, D, U), S
