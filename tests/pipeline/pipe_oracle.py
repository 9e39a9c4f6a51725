"""Brute-force numpy oracles and scenes for the pipeline tests (independent of core)."""

from __future__ import annotations

import numpy as np


def pack(curves):
    pts = np.concatenate(curves).astype(np.float64)
    off = np.concatenate([[0], np.cumsum([len(c) for c in curves])]).astype(np.int64)
    return pts, off


def segments(points, offsets):
    """All segments: (A, B, curve index)."""
    A, B, cid = [], [], []
    for i in range(len(offsets) - 1):
        c = points[offsets[i]:offsets[i + 1]]
        A.append(c[:-1])
        B.append(c[1:])
        cid += [i] * (len(c) - 1)
    return np.concatenate(A), np.concatenate(B), np.array(cid)


def point_segment_distance(p, a, b):
    """(k, m) distances of points p (k, 3) to segments a, b (m, 3)."""
    ab = b - a
    ap = p[:, None, :] - a[None]
    t = np.clip((ap * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300), 0, 1)
    return np.linalg.norm(ap - t[..., None] * ab[None], axis=-1)


def point_mesh_distance(p, V, F, chunk=2000):
    """(k,) exact distance of points to a triangle mesh, all pairs."""
    if len(p) > chunk:
        return np.concatenate([point_mesh_distance(p[a:a + chunk], V, F, chunk)
                               for a in range(0, len(p), chunk)])
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    ap = p[:, None, :] - a[None]
    h = (ap * n[None]).sum(-1)
    proj = p[:, None, :] - h[..., None] * n[None]
    inside = np.ones(h.shape, bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= (np.cross(v - u, proj - u[None]) * n[None]).sum(-1) >= 0
    d = np.where(inside, np.abs(h), np.inf)
    for u, v in ((a, b), (b, c), (c, a)):
        d = np.minimum(d, point_segment_distance(p, u, v))
    return d.min(1)


def segment_mesh_distance_sampled(A, B, V, F, n=401):
    """(S,) upper estimate of segment-mesh distance by sampling n points per segment.

    The exact distance lies in [est - |AB| / (2 (n - 1)), est].
    """
    t = np.linspace(0, 1, n)
    q = (A[:, None, :] + t[None, :, None] * (B - A)[:, None, :]).reshape(-1, 3)
    return point_mesh_distance(q, V, F).reshape(len(A), n).min(1)


def segments_cross_mesh(A, B, V, F, eps=1e-12):
    """(S,) bool: segment [A, B] intersects a triangle (Moller-Trumbore, all pairs)."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = b - a, c - a
    d = (B - A)[:, None, :]
    pv = np.cross(d, e2[None])
    det = (pv * e1[None]).sum(-1)
    ok = np.abs(det) > 1e-300
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tv = A[:, None, :] - a[None]
    u = (tv * pv).sum(-1) * inv
    qv = np.cross(tv, e1[None])
    v = (d * qv).sum(-1) * inv
    t = (e2[None] * qv).sum(-1) * inv
    hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t >= -eps) & (t <= 1 + eps)
    return hit.any(1)


def icosphere(center=(0, 0, 0), radius=1.0, sub=2):
    t = (1 + 5**0.5) / 2
    V = [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t],
         [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]]
    F = [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]]
    V = [np.array(v, float) / np.linalg.norm(v) for v in V]
    for _ in range(sub):
        cache = {}
        F2 = []

        def mid(i, j, cache=cache):
            key = (min(i, j), max(i, j))
            if key not in cache:
                m = V[i] + V[j]
                V.append(m / np.linalg.norm(m))
                cache[key] = len(V) - 1
            return cache[key]

        for a, b, c in F:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            F2 += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        F = F2
    return np.array(V) * radius + np.asarray(center, float), np.array(F, np.int64)


def grid(size=2.0, n=4, z=0.0):
    x = np.linspace(-size / 2, size / 2, n + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], 1)
    F = []
    for i in range(n):
        for j in range(n):
            a = i * (n + 1) + j
            b, c, d = a + n + 1, a + n + 2, a + 1
            F += [[a, b, c], [a, c, d]]
    return V, np.array(F, np.int64)


def fur_on_plane(rng, n_curves=30, n_cvs=5, length=0.5, extent=1.0, tilt=0.3):
    roots = np.c_[rng.uniform(-extent, extent, (n_curves, 2)), np.zeros(n_curves)]
    curves = []
    for r in roots:
        d = np.array([*rng.normal(0, tilt, 2), 1.0])
        d /= np.linalg.norm(d)
        curves.append(r + np.linspace(0, length, n_cvs)[:, None] * d)
    return pack(curves)


def rotation(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def fur_on_mesh(rng, V, F, n_curves=40, n_cvs=5, length=0.3, noise=0.3):
    """Curves rooted exactly on random points of the mesh, growing along the face normal."""
    face = rng.integers(0, len(F), n_curves)
    b = rng.dirichlet([1, 1, 1], n_curves)
    T = V[F[face]]
    roots = np.einsum("ck,cki->ci", b, T)
    n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    curves = []
    for r, d in zip(roots, n, strict=True):
        steps = d * length / (n_cvs - 1) + rng.normal(0, noise * length / n_cvs, (n_cvs - 1, 3))
        curves.append(np.vstack([r, r + np.cumsum(steps, 0)]))
    return pack(curves)


def sphere_and_ground(seed=12):
    """A ground plane of 2 huge triangles next to a fine sphere, and 15 curves between:
    (points, offsets, V, F)."""
    rng = np.random.default_rng(seed)
    Vs, Fs = icosphere((0, 0, 0.5), 0.3, 3)
    Vp = np.array([[-50, -50, -0.2], [50, -50, -0.1], [50, 50, 0.3], [-50, 50, 0.0]])
    Fp = np.array([[0, 1, 2], [0, 2, 3]]) + len(Vs)
    curves = []
    for _ in range(15):
        root = np.r_[rng.uniform(-0.8, 0.8, 2), 0.2]
        curves.append(root + np.cumsum(rng.normal(0, 0.08, (4, 3)), 0))
    pts, off = pack(curves)
    return pts, off, np.vstack([Vs, Vp]), np.vstack([Fs, Fp])


# ------------------------------------------------- exact segment-triangle distance
def _rowdot(u, v):
    return (u * v).sum(-1)


def point_segment_distance_rows(p, a, b):
    """(n,) distance of p[i] to segment [a[i], b[i]] (a point when a == b)."""
    ab = b - a
    L2 = _rowdot(ab, ab)
    t = np.clip(_rowdot(p - a, ab) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def segment_segment_distance_rows(p0, p1, q0, q1):
    """(n,) distance between segments [p0, p1] and [q0, q1], row by row.

    |p0 + s u - q0 - t v|^2 is a convex quadratic on the unit square: its minimum is
    the unconstrained one when that lies inside, else on an edge of the square, i.e.
    an end point of one segment against the other segment."""
    d = np.minimum.reduce([point_segment_distance_rows(p0, q0, q1),
                           point_segment_distance_rows(p1, q0, q1),
                           point_segment_distance_rows(q0, p0, p1),
                           point_segment_distance_rows(q1, p0, p1)])
    u, v, w = p1 - p0, q1 - q0, p0 - q0
    a, b, c = _rowdot(u, u), _rowdot(u, v), _rowdot(v, v)
    dd, e = _rowdot(u, w), _rowdot(v, w)
    den = a * c - b * b
    ok = den > 1e-14 * a * c
    den = np.where(ok, den, 1.0)
    s = (b * e - c * dd) / den
    t = (a * e - b * dd) / den
    inside = ok & (s >= 0) & (s <= 1) & (t >= 0) & (t <= 1)
    gap = np.linalg.norm(w + s[:, None] * u - t[:, None] * v, axis=1)
    return np.where(inside, np.minimum(d, gap), d)


def point_triangle_distance_rows(p, a, b, c):
    """(n,) exact distance of p[i] to triangle (a[i], b[i], c[i]) (non-degenerate)."""
    n = np.cross(b - a, c - a)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    h = _rowdot(p - a, n)
    q = p - h[:, None] * n
    inside = np.ones(len(p), bool)
    for u, v in ((a, b), (b, c), (c, a)):
        inside &= _rowdot(np.cross(v - u, q - u), n) >= 0
    d = np.minimum.reduce([point_segment_distance_rows(p, a, b),
                           point_segment_distance_rows(p, b, c),
                           point_segment_distance_rows(p, c, a)])
    return np.where(inside, np.abs(h), d)


def segment_crosses_triangle_rows(p0, p1, a, b, c):
    """(n,) bool: the segment meets the triangle's interior (Moller-Trumbore, no
    tolerance; coplanar segments count as not crossing: their distance is then an end
    point's or an edge's, which the caller takes anyway)."""
    e1, e2, d = b - a, c - a, p1 - p0
    pv = np.cross(d, e2)
    det = _rowdot(e1, pv)
    ok = det != 0
    inv = 1.0 / np.where(ok, det, 1.0)
    tv = p0 - a
    uu = _rowdot(tv, pv) * inv
    qv = np.cross(tv, e1)
    vv = _rowdot(d, qv) * inv
    t = _rowdot(e2, qv) * inv
    return ok & (uu >= 0) & (vv >= 0) & (uu + vv <= 1) & (t >= 0) & (t <= 1)


def segment_triangle_distance(p0, p1, a, b, c):
    """(n,) exact distance between segment [p0, p1] and triangle (a, b, c), row by row,
    written from its definition: 0 where they meet, else the smallest of the two end
    points' distances to the triangle and the segment's distances to its three edges
    (two disjoint convex sets are closest at an end point or an edge)."""
    p0, p1, a, b, c = (np.asarray(x, np.float64).reshape(-1, 3) for x in (p0, p1, a, b, c))
    d = np.minimum.reduce([point_triangle_distance_rows(p0, a, b, c),
                           point_triangle_distance_rows(p1, a, b, c),
                           segment_segment_distance_rows(p0, p1, a, b),
                           segment_segment_distance_rows(p0, p1, b, c),
                           segment_segment_distance_rows(p0, p1, c, a)])
    return np.where(segment_crosses_triangle_rows(p0, p1, a, b, c), 0.0, d)


def brute_segments(A, B, V, F):
    """(S,) exact segment-mesh distance: every segment against every triangle, with the
    oracle's own segment-triangle distance above (nothing from core)."""
    S, m = len(A), len(F)
    si = np.repeat(np.arange(S), m)
    ti = np.tile(np.arange(m), S)
    T = np.asarray(V, np.float64)[F]
    d = segment_triangle_distance(A[si], B[si], T[ti, 0], T[ti, 1], T[ti, 2])
    return d.reshape(S, m).min(1)


def brute_cv(points, offsets, meshes):
    """(P,) exact per-CV distance (min over the CV's segments and the meshes)."""
    A, B, _ = segments(points, offsets)
    seg = np.full(len(A), np.inf)
    for V, F in meshes:
        seg = np.minimum(seg, brute_segments(A, B, V, F))
    out = np.full(len(points), np.inf)
    k = 0
    for i in range(len(offsets) - 1):
        for j in range(offsets[i], offsets[i + 1] - 1):
            out[j] = min(out[j], seg[k])
            out[j + 1] = min(out[j + 1], seg[k])
            k += 1
    return out
