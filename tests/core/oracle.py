"""Independent brute-force geometry oracle for the core tests.

Nothing here imports :mod:`core`. Everything is float64 numpy, chunked so
that the (segments x triangles) pair arrays stay small.

Segment-triangle intersection is Moller-Trumbore. Because the core works in
float32 (embree) and the solver stops at the *first* clearing rotation step,
a resolved curve may legitimately graze a surface. The oracle therefore has a
tolerance ``eps`` (relative, on the barycentric coordinates and on the segment
parameter): ``eps > 0`` shrinks the triangle and the segment (only robust,
"sure" hits count), ``eps < 0`` grows them (anything that might be a hit
counts).
"""

from __future__ import annotations

import numpy as np

#: Default margin for "sure" hits (invariant checks: a curve that the solver
#: says is clear must not *surely* intersect anything).
SURE = 1e-5
#: Default margin for "maybe" hits (used to skip borderline cases).
MAYBE = -1e-4

_CHUNK = 1 << 18  # pairs per chunk


def transform(V, M):
    """Apply a 4x4 matrix (None = identity) to (n,3) points, float64."""
    V = np.asarray(V, dtype=np.float64).reshape(-1, 3)
    if M is None:
        return V.copy()
    M = np.asarray(M, dtype=np.float64)
    return V @ M[:3, :3].T + M[:3, 3]


def curve_segments(points, offsets):
    """Return (a, b, curve_index, segment_index) of every segment."""
    points = np.asarray(points, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.int64)
    a_idx, cid, sid = [], [], []
    for c in range(len(offsets) - 1):
        s, e = int(offsets[c]), int(offsets[c + 1])
        n = e - s - 1
        a_idx.append(np.arange(s, e - 1))
        cid.append(np.full(n, c))
        sid.append(np.arange(n))
    if not a_idx:
        z = np.zeros((0, 3))
        return z, z, np.zeros(0, np.int64), np.zeros(0, np.int64)
    a_idx = np.concatenate(a_idx)
    return points[a_idx], points[a_idx + 1], np.concatenate(cid), np.concatenate(sid)


def segment_hits(A, B, V, F, eps=SURE, abs_eps=0.0):
    """(S,) bool: does segment A[i]->B[i] cross any triangle of (V, F)?

    ``eps`` > 0 requires the crossing to be ``eps`` inside the triangle
    (barycentric) and inside the segment (parameter); ``eps`` < 0 accepts
    crossings that far outside. Segments (nearly) parallel to a triangle's
    plane never "surely" hit it; they "maybe" hit when eps < 0 and the
    segment passes close to the plane.

    ``abs_eps`` (world units) adds an absolute margin on top: the crossing
    point must be that far inside every edge, and both segment ends that far
    from the triangle's plane (or, for eps < 0, may be that far outside).
    Use it for the float32 limit of the core: geometry finer than a few
    float32 ulps of the absolute coordinates is not decidable in float32.
    """
    A = np.asarray(A, dtype=np.float64).reshape(-1, 3)
    B = np.asarray(B, dtype=np.float64).reshape(-1, 3)
    V = np.asarray(V, dtype=np.float64).reshape(-1, 3)
    F = np.asarray(F, dtype=np.int64).reshape(-1, 3)
    S, T = len(A), len(F)
    out = np.zeros(S, dtype=bool)
    if S == 0 or T == 0:
        return out
    v0, v1, v2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = v1 - v0, v2 - v0
    scale = np.linalg.norm(np.cross(e1, e2), axis=1)  # 2*area, for det scaling
    # cull triangles by bounding boxes first (cheap and exact)
    tmin = np.minimum(np.minimum(v0, v1), v2)
    tmax = np.maximum(np.maximum(v0, v1), v2)
    pad = (np.abs(eps) + 1e-12) * (tmax - tmin).max(axis=1, initial=0)[:, None] + 1e-12 + abs_eps
    smin, smax = np.minimum(A, B), np.maximum(A, B)
    spad = (np.abs(eps) + 1e-12) * np.linalg.norm(B - A, axis=1)[:, None] + abs_eps
    step = max(1, _CHUNK // max(T, 1))
    for s0 in range(0, S, step):
        s1 = min(S, s0 + step)
        a, b = A[s0:s1], B[s0:s1]
        # bbox overlap (S_chunk, T)
        ov = np.all(
            (smin[s0:s1, None, :] - spad[s0:s1, None, :] <= tmax[None] + pad[None])
            & (smax[s0:s1, None, :] + spad[s0:s1, None, :] >= tmin[None] - pad[None]),
            axis=2,
        )
        si, ti = np.nonzero(ov)
        if len(si) == 0:
            continue
        d = (b - a)[si]
        o = a[si]
        E1, E2, P0 = e1[ti], e2[ti], v0[ti]
        p = np.cross(d, E2)
        det = np.einsum("ij,ij->i", E1, p)
        dlen = np.linalg.norm(d, axis=1)
        par = np.abs(det) <= 1e-12 * dlen * scale[ti] + 1e-300
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.where(par, 1.0, det)
            tv = o - P0
            u = np.einsum("ij,ij->i", tv, p) * inv
            q = np.cross(tv, E1)
            v = np.einsum("ij,ij->i", d, q) * inv
            t = np.einsum("ij,ij->i", E2, q) * inv
        if abs_eps > 0:
            # heights of the triangle over each edge, and the segment's extent
            # along the plane normal
            n = np.cross(E1, E2)
            area2 = np.linalg.norm(n, axis=1)
            e0 = np.linalg.norm(E2 - E1, axis=1)  # opposite v0
            h0 = area2 / np.maximum(e0, 1e-300)
            h1 = area2 / np.maximum(np.linalg.norm(E2, axis=1), 1e-300)  # opposite v1
            h2 = area2 / np.maximum(np.linalg.norm(E1, axis=1), 1e-300)  # opposite v2
            dn = np.abs(np.einsum("ij,ij->i", d, n)) / np.maximum(area2, 1e-300)
            sgn = 1.0 if eps >= 0 else -1.0
            tb0 = eps + sgn * abs_eps / np.maximum(h0, 1e-300)
            tb1 = eps + sgn * abs_eps / np.maximum(h1, 1e-300)
            tb2 = eps + sgn * abs_eps / np.maximum(h2, 1e-300)
            tt = eps + sgn * abs_eps / np.maximum(dn, 1e-300)
        else:
            tb0 = tb1 = tb2 = tt = eps
        hit = (
            ~par
            & (u >= tb1)
            & (v >= tb2)
            & (1.0 - u - v >= tb0)
            & (t >= tt)
            & (t <= 1.0 - tt)
        )
        if eps < 0 and par.any():
            # nearly coplanar segment: count as "maybe" if close to the plane
            n = np.cross(E1, E2)
            nn = np.linalg.norm(n, axis=1)
            da = np.abs(np.einsum("ij,ij->i", a[si] - P0, n)) / np.maximum(nn, 1e-300)
            db = np.abs(np.einsum("ij,ij->i", b[si] - P0, n)) / np.maximum(nn, 1e-300)
            near = np.minimum(da, db) <= -eps * (dlen + 1e-12) * 10
            hit |= par & near
        if hit.any():
            out[s0 + np.unique(si[hit])] = True
    return out


def float32_margin(*arrays, ulps=16):
    """Absolute margin: ``ulps`` float32 ulps of the largest coordinate."""
    m = max((float(np.abs(np.asarray(a, np.float64)).max(initial=0.0)) for a in arrays),
            default=0.0)
    return ulps * float(np.finfo(np.float32).eps) * max(m, 1e-30)


def segments_hit_mesh(points, offsets, V_world, F, eps=SURE, abs_eps=0.0):
    """(C,) bool: does any segment of curve c cross the mesh (V_world, F)?"""
    A, B, cid, _ = curve_segments(points, offsets)
    C = len(offsets) - 1
    hits = segment_hits(A, B, V_world, F, eps, abs_eps)
    out = np.zeros(C, dtype=bool)
    np.logical_or.at(out, cid, hits)
    return out


def _leaves(V, F, size=48):
    """The triangles of (V, F) split by their centroids (median cuts along the longest
    axis) into groups of at most ``size``: [(triangle indices, lo, hi)]."""
    T = V[F]
    lo_t, hi_t, cen = T.min(1), T.max(1), T.mean(1)
    out, todo = [], [np.arange(len(F))]
    while todo:
        idx = todo.pop()
        if len(idx) <= size:
            out.append((idx, lo_t[idx].min(0), hi_t[idx].max(0)))
            continue
        c = cen[idx]
        ax = int(np.argmax(c.max(0) - c.min(0)))
        order = idx[np.argsort(c[:, ax], kind="stable")]
        todo += [order[: len(order) // 2], order[len(order) // 2:]]
    return out


def curves_crossing(points, offsets, meshes, select=None):
    """Indices of the curves (of ``select``, a (C,) bool mask; all when None) that
    surely cross one of ``meshes`` ((V, F) in the points' space): the answer of
    :func:`segments_hit_mesh` with the float32 margin (:func:`float32_margin`), fast
    enough for real-size scenes: a segment is tested only against the groups of
    triangles whose (padded) bounding box its own meets."""
    offs = np.asarray(offsets)
    C = len(offs) - 1
    sel = np.ones(C, bool) if select is None else np.asarray(select, bool)
    P = np.asarray(points, np.float64)
    curve = np.repeat(np.arange(C), np.diff(offs) - 1)
    s0 = np.arange(len(curve)) + curve  # first point of every segment
    use = sel[curve]
    s0, curve = s0[use], curve[use]
    A, B = P[s0], P[s0 + 1]
    smin, smax = np.minimum(A, B), np.maximum(A, B)
    bad = np.zeros(C, bool)
    for V, F in meshes:
        V = np.asarray(V, np.float64)
        margin = float32_margin(P, V)
        pad = 2 * margin + 1e-9 * float(np.abs(V).max())
        # (every leaf's box lies in the mesh's: the segments outside it meet no leaf)
        lo, hi = V.min(0), V.max(0)
        cand = np.flatnonzero(np.all(smin <= hi + pad, 1) & np.all(smax >= lo - pad, 1))
        cmin, cmax = smin[cand], smax[cand]
        for tri, lo, hi in _leaves(V, np.asarray(F)):
            near = cand[np.all(cmin <= hi + pad, 1) & np.all(cmax >= lo - pad, 1)]
            if len(near):
                hit = segment_hits(A[near], B[near], V, F[tri], abs_eps=margin)
                bad[curve[near[hit]]] = True
    return np.flatnonzero(bad)


def first_hit_segment(points, offsets, V_world, F, eps=SURE):
    """(C,) int: index of the first (from the root) segment crossing the mesh, -1 if none."""
    A, B, cid, sid = curve_segments(points, offsets)
    C = len(offsets) - 1
    hits = segment_hits(A, B, V_world, F, eps)
    out = np.full(C, -1, dtype=np.int64)
    for c in range(C):
        m = (cid == c) & hits
        if m.any():
            out[c] = int(sid[m].min())
    return out


def ray_crossings(O, D, V, F):
    """(n,) int: number of triangles crossed by rays O + t D, t > 0 (every ray against
    every triangle, Moller-Trumbore, in chunks of ray x triangle pairs)."""
    O = np.asarray(O, dtype=np.float64).reshape(-1, 3)
    D = np.asarray(D, dtype=np.float64).reshape(-1, 3)
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    v0, v1, v2 = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = v1 - v0, v2 - v0
    counts = np.zeros(len(O), dtype=np.int64)
    step = max(1, _CHUNK // max(len(F), 1))
    for s in range(0, len(O), step):
        o, d = O[s:s + step, None, :], D[s:s + step, None, :]  # (k, 1, 3) against (m, 3)
        p = np.cross(d, e2)
        det = np.einsum("kmi,kmi->km", np.broadcast_to(e1, p.shape), p)
        ok = np.abs(det) > 1e-15
        inv = 1.0 / np.where(ok, det, 1.0)
        tv = o - v0
        u = np.einsum("kmi,kmi->km", tv, p) * inv
        q = np.cross(tv, e1)
        v = np.einsum("kmi,kmi->km", np.broadcast_to(d, q.shape), q) * inv
        t = np.einsum("kmi,kmi->km", np.broadcast_to(e2, q.shape), q) * inv
        counts[s:s + step] = np.count_nonzero(
            ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0), axis=1)
    return counts


_DIRS = np.array(
    [[0.5377, 0.1834, 0.8229], [-0.4336, 0.8622, -0.2622], [0.3188, -0.8077, -0.4959]]
)


def points_inside_closed_mesh(P, V, F):
    """(n,) bool: parity test on 3 fixed generic rays, majority vote."""
    dirs = _DIRS / np.linalg.norm(_DIRS, axis=1, keepdims=True)
    P = np.asarray(P, dtype=np.float64).reshape(-1, 3)
    votes = np.zeros(len(P), dtype=np.int64)
    for d in dirs:
        votes += ray_crossings(P, np.broadcast_to(d, P.shape), V, F) % 2
    return votes >= 2


def winding_number(P, T):
    """(n,) generalized winding number of points ``P`` (n, 3) for triangles ``T``
    (m, 3, 3): the solid angle each triangle subtends from the point (Van Oosterom
    and Strackee), summed, over 4 pi. 1 inside a closed outward-wound surface, 0
    outside, k where k sheets of a self-overlapping surface enclose the point."""
    P = np.asarray(P, dtype=np.float64).reshape(-1, 3)
    T = np.asarray(T, dtype=np.float64)
    out = np.zeros(len(P))
    step = max(1, _CHUNK // max(len(T), 1))
    for s in range(0, len(P), step):
        a, b, c = (T[None, :, k] - P[s:s + step, None] for k in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        det = np.einsum("pki,pki->pk", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pki,pki->pk", a, b) * lc
               + np.einsum("pki,pki->pk", b, c) * la + np.einsum("pki,pki->pk", c, a) * lb)
        out[s:s + step] = (2.0 * np.arctan2(det, den)).sum(axis=1) / (4.0 * np.pi)
    return out


def point_segment_distance(c, A, B):
    """(S,) distance from point c to segments A[i]->B[i]."""
    A = np.asarray(A, dtype=np.float64)
    B = np.asarray(B, dtype=np.float64)
    c = np.asarray(c, dtype=np.float64)
    d = B - A
    dd = np.einsum("ij,ij->i", d, d)
    t = np.clip(np.einsum("ij,ij->i", c - A, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    return np.linalg.norm(A + t[:, None] * d - c, axis=1)


def curve_distance_to_sphere_center(points, offsets, center):
    """(C,) min distance from a sphere's centre to each curve (segments)."""
    A, B, cid, _ = curve_segments(points, offsets)
    d = point_segment_distance(center, A, B)
    C = len(offsets) - 1
    out = np.full(C, np.inf)
    np.minimum.at(out, cid, d)
    return out


def distance_to_plane(points, origin, normal):
    """Unsigned distance of points to an infinite plane."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    return np.abs((np.asarray(points, dtype=np.float64) - origin) @ n)
