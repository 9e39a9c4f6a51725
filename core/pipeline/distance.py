"""Fur Collider Distance (paper section 4).

For every CV of (collision-free) curves: the closest distance of that CV's
segments to the colliders. Segment-to-mesh distances are **exact** (up to
float64 rounding) for segments near a collider and a guaranteed **lower
bound** for segments far from every collider (see
:func:`collider_distance`): the result never overestimates the true
distance, which is what the Region of Influence needs.
"""

from __future__ import annotations

import numpy as np

from ..closest import closest_on_triangles, closest_points_on_mesh
from ..collider import Collider
from ..errors import InputError
from ._curves import check_curves, check_surface, layout

#: Segments whose search box spans more grid cells than this take the
#: lower-bound path (they are far from the collider compared to the cells).
_MAX_CELLS = 216
#: Sub-pieces of a far segment in the lower bound.
_FAR_PIECES = 4
#: Cell entries (segment, cell) per chunk of the exact search.
_CHUNK_CELLS = 1_000_000
#: Grid cells along the longest side, at most.
_MAX_DIMS = 256


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def segment_segment_distance(p1, q1, p2, q2):
    """Distance between segments ``[p1, q1]`` and ``[p2, q2]``, row by row.

    Ericson, *Real-Time Collision Detection* 5.1.9, vectorized.

    Parameters
    ----------
    p1, q1, p2, q2 : (k, 3) ndarray of float64

    Returns
    -------
    (k,) ndarray of float64
    """
    d1 = q1 - p1
    d2 = q2 - p2
    r = p1 - p2
    a = _dot(d1, d1)
    e = _dot(d2, d2)
    f = _dot(d2, r)
    c = _dot(d1, r)
    b = _dot(d1, d2)
    tiny = 1e-300
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > tiny * np.maximum(a * e, tiny),
                     np.clip((b * f - c * e) / np.where(denom != 0, denom, 1.0), 0, 1), 0.0)
        t = np.where(e > tiny, (b * s + f) / np.where(e > tiny, e, 1.0), 0.0)
        # t outside [0, 1]: clamp it and recompute s
        lo = t < 0
        hi = t > 1
        s = np.where(lo, np.clip(np.where(a > tiny, -c / np.where(a > tiny, a, 1.0), 0.0), 0, 1), s)
        s = np.where(hi, np.clip(np.where(a > tiny, (b - c) / np.where(a > tiny, a, 1.0), 0.0),
                                 0, 1), s)
        t = np.clip(t, 0, 1)
    c1 = p1 + d1 * s[:, None]
    c2 = p2 + d2 * t[:, None]
    return np.linalg.norm(c1 - c2, axis=1)


def segment_triangle_distance(a, b, t0, t1, t2):
    """Exact distance between segments ``[a, b]`` and triangles ``(t0, t1, t2)``.

    The minimum is reached at a segment end (point-triangle), on a triangle
    edge (segment-segment), or is 0 where the segment crosses the triangle.

    Parameters
    ----------
    a, b, t0, t1, t2 : (k, 3) ndarray of float64

    Returns
    -------
    (k,) ndarray of float64
    """
    d = np.linalg.norm(closest_on_triangles(a, t0, t1, t2) - a, axis=1)
    d = np.minimum(d, np.linalg.norm(closest_on_triangles(b, t0, t1, t2) - b, axis=1))
    for u, v in ((t0, t1), (t1, t2), (t2, t0)):
        d = np.minimum(d, segment_segment_distance(a, b, u, v))
    # proper crossing of the triangle's interior
    n = np.cross(t1 - t0, t2 - t0)
    sa = _dot(n, a - t0)
    sb = _dot(n, b - t0)
    cross = (sa * sb <= 0) & (sa != sb)
    if cross.any():
        i = np.flatnonzero(cross)
        x = a[i] + (b[i] - a[i]) * (sa[i] / (sa[i] - sb[i]))[:, None]
        ni = n[i]
        inside = (
            (_dot(ni, np.cross(t1[i] - t0[i], x - t0[i])) >= 0)
            & (_dot(ni, np.cross(t2[i] - t1[i], x - t1[i])) >= 0)
            & (_dot(ni, np.cross(t0[i] - t2[i], x - t2[i])) >= 0)
        )
        d[i[inside]] = 0.0
    return d


def _world_mesh(col, i):
    """World-space ``(V float64, F int64)`` of a Collider or a ``(V, F)`` pair."""
    if isinstance(col, Collider):
        if col.empty:
            return None
        V = col.vertices.astype(np.float64)
        M = col.matrix
        return V @ M[:3, :3].T + M[:3, 3], col.faces.astype(np.int64)
    try:
        V, F = col
    except Exception:
        raise InputError(
            f"colliders[{i}] must be a core.Collider or a (V, F) pair, got {type(col).__name__}"
        ) from None
    if np.asarray(F).size == 0:
        return None
    return check_surface(V, F, f"colliders[{i}]")


class _TriGrid:
    """Uniform grid of triangle bounding boxes (cell size ``h``)."""

    def __init__(self, T, h):
        lo, hi = T.min(1), T.max(1)
        self.glo = lo.min(0)
        ext = float((hi.max(0) - self.glo).max()) or 1.0
        self.h = h = max(h, ext / _MAX_DIMS)
        self.dims = np.floor((hi.max(0) - self.glo) / h).astype(np.int64) + 1
        ilo = np.floor((lo - self.glo) / h).astype(np.int64)
        ihi = np.floor((hi - self.glo) / h).astype(np.int64)
        cell, owner = _box_cells(ilo, ihi)
        keys = self.key(cell)
        order = np.argsort(keys, kind="stable")
        self.keys = keys[order]
        self.tris = owner[order]

    def key(self, cell):
        d = self.dims + 2
        c = cell + 1
        return (c[:, 0] * d[1] + c[:, 1]) * d[2] + c[:, 2]


def _box_cells(ilo, ihi):
    """Enumerate the integer cells of boxes ``[ilo, ihi]``: ``(cells (n, 3), owner (n,))``."""
    span = ihi - ilo + 1
    count = span.prod(1)
    owner = np.repeat(np.arange(len(ilo)), count)
    start = np.repeat(np.cumsum(count) - count, count)
    local = np.arange(len(owner)) - start
    sx, sy = span[owner, 0], span[owner, 1]
    cell = np.stack([
        ilo[owner, 0] + local % sx,
        ilo[owner, 1] + (local // sx) % sy,
        ilo[owner, 2] + local // (sx * sy),
    ], axis=1)
    return cell, owner


def segment_mesh_distance(A, B, V, F, grid=None):
    """Distance of each segment ``[A, B]`` to the triangle mesh ``(V, F)``.

    Parameters
    ----------
    A, B : (S, 3) ndarray of float64
        Segment ends, the mesh's space.
    V : (n, 3) ndarray of float64
    F : (m, 3) ndarray of int, m >= 1

    Returns
    -------
    dist : (S,) ndarray of float64
        Exact for segments whose search box (the segment's bounds grown by
        its endpoint distance) spans at most ``_MAX_CELLS`` grid cells; a
        lower bound ``max(0, d(m_i) - l / 2)`` over ``_FAR_PIECES`` pieces of
        length ``l`` (midpoints ``m_i``, ``d`` the exact point-to-mesh
        distance) for the others, never above the exact distance.
    exact : (S,) bool
        Which entries are exact.
    """
    S = len(A)
    if S == 0:
        return np.zeros(0), np.zeros(0, bool)
    T = V[F]  # (m, 3, 3)
    P, _, cgrid = closest_points_on_mesh(V, F, np.concatenate([A, B]))
    dp = np.linalg.norm(P - np.concatenate([A, B]), axis=1)
    U = np.minimum(dp[:S], dp[S:])
    ext = (T.max(1) - T.min(1)).max(1)
    seg = np.linalg.norm(B - A, axis=1)
    h = max(float(np.median(ext)), 0.5 * float(np.median(seg)), 1e-12)
    g = _TriGrid(T, h)
    blo = np.minimum(A, B) - U[:, None]
    bhi = np.maximum(A, B) + U[:, None]
    ilo = np.floor((blo - g.glo) / g.h)
    ihi = np.floor((bhi - g.glo) / g.h)
    ilo = np.clip(ilo, -1, g.dims).astype(np.int64)
    ihi = np.clip(ihi, -1, g.dims).astype(np.int64)
    ncell = (ihi - ilo + 1).prod(1)
    exact = ncell <= _MAX_CELLS
    dist = U.copy()
    near = np.flatnonzero(exact)
    # exact search, in chunks of bounded size
    csum = np.cumsum(ncell[near])
    start = 0
    while start < len(near):
        base = csum[start - 1] if start else 0
        stop = int(np.searchsorted(csum, base + _CHUNK_CELLS, "right"))
        stop = max(stop, start + 1)
        idx = near[start:stop]
        start = stop
        cell, owner = _box_cells(ilo[idx], ihi[idx])
        keys = g.key(cell)
        lo = np.searchsorted(g.keys, keys, "left")
        n = np.searchsorted(g.keys, keys, "right") - lo
        s_of = np.repeat(owner, n)
        first = np.repeat(lo - (np.cumsum(n) - n), n)
        t_of = g.tris[first + np.arange(int(n.sum()))]
        pair = np.unique(s_of * len(F) + t_of)
        s_of, t_of = pair // len(F), pair % len(F)
        si = idx[s_of]
        d = segment_triangle_distance(A[si], B[si], T[t_of, 0], T[t_of, 1], T[t_of, 2])
        np.minimum.at(dist, si, d)
    far = np.flatnonzero(~exact)
    if len(far):
        k = _FAR_PIECES
        t = (np.arange(k) + 0.5) / k
        a, b = A[far], B[far]
        mid = (a[:, None, :] + (b - a)[:, None, :] * t[None, :, None]).reshape(-1, 3)
        Pm, _, _ = closest_points_on_mesh(V, F, mid, cgrid)
        dm = np.linalg.norm(Pm - mid, axis=1).reshape(-1, k)
        lb = np.maximum(dm - (seg[far] / (2 * k))[:, None], 0.0).min(1)
        dist[far] = np.minimum(U[far], lb)
    return dist, exact


def collider_distance(points, offsets, colliders, return_exact=False):
    """Fur Collider Distance: per CV, the distance of its segments to the colliders.

    The distance of CV ``j`` is the smallest distance to any collider of
    the (one or two) segments that end at it; a root uses its first
    segment, a tip its last. Store it on the collision-free curves
    (``furcollide_collider_distance``) and pass it to
    :func:`region_of_influence`.

    Parameters
    ----------
    points : (P, 3) array_like of float
        Curves, world space.
    offsets : (C+1,) array_like of int
        Curve ``i`` is ``points[offsets[i]:offsets[i + 1]]``.
    colliders : sequence of Collider or (V, F) pairs
        Meshes (a Collider's ``matrix`` is applied; its collision offset is
        *not* subtracted: the distance is to the mesh itself). Empty
        colliders are ignored.
    return_exact : bool
        Also return which CV distances are exact.

    Returns
    -------
    distance : (P,) ndarray of float64
        ``inf`` when there is no collider. Exact (float64 rounding) for
        segments near a collider; for segments far from it (their
        distance spans many grid cells) a lower bound within a fraction of
        the segment's length. It never exceeds the true distance.
    exact : (P,) ndarray of bool
        Only with ``return_exact``.

    Raises
    ------
    InputError
        Malformed curves (the message names the curve or point).
    ColliderError
        Malformed ``(V, F)`` collider.
    """
    pts, off = check_curves(points, offsets)
    if isinstance(colliders, Collider):
        colliders = [colliders]
    P = len(pts)
    _, _, s0 = layout(off)
    A, B = pts[s0], pts[s0 + 1]
    seg_d = np.full(len(s0), np.inf)
    seg_exact = np.ones(len(s0), bool)
    for i, col in enumerate(colliders):
        mesh = _world_mesh(col, i)
        if mesh is None:
            continue
        d, ex = segment_mesh_distance(A, B, *mesh)
        better = d < seg_d
        seg_exact = np.where(better, ex, seg_exact)
        seg_d = np.minimum(seg_d, d)
    dist = np.full(P, np.inf)
    exact = np.ones(P, bool)
    # segment k runs from point s0[k] to s0[k] + 1
    for end in (s0, s0 + 1):
        take = seg_d < dist[end]
        dist[end[take]] = seg_d[take]
        exact[end[take]] = seg_exact[take]
    if return_exact:
        return dist, exact
    return dist
