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

from ..closest import closest_on_triangles
from ..collider import Collider
from ..errors import InputError
from ._curves import check_curves, check_surface, layout

#: Segments whose search box spans more grid cells than this take the
#: lower-bound path (they are far from the collider compared to the cells).
_MAX_CELLS = 512
#: Sub-pieces of a segment in the distance-field lower bound.
_FAR_PIECES = 8
#: Cells along the longest side of the lower-bound distance field, at most.
_FIELD_DIMS = 64
#: Extra distance fields over the mesh's box grown by these multiples of its size.
_FIELD_PADS = (0.5, 2.0)
#: Cell entries (segment, cell) per chunk of the exact search.
_CHUNK_CELLS = 1_000_000
#: Grid cells along the longest side, at most.
_MAX_DIMS = 256
#: Triangles spanning more grid cells than this are tested by every search.
_BIG_CELLS = 4096


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
    """Uniform grid of triangle bounding boxes (cell size ``h``).

    Triangles whose box spans more than ``_BIG_CELLS`` cells (a ground
    plane next to a detailed character) are not registered in cells: they
    are in :attr:`big` and every search tests them.
    """

    def __init__(self, T, h):
        lo, hi = T.min(1), T.max(1)
        self.n_tris = len(T)
        self.glo = lo.min(0)
        ext = float((hi.max(0) - self.glo).max()) or 1.0
        self.h = h = max(h, ext / _MAX_DIMS)
        self.dims = np.floor((hi.max(0) - self.glo) / h).astype(np.int64) + 1
        ilo = np.floor((lo - self.glo) / h).astype(np.int64)
        ihi = np.floor((hi - self.glo) / h).astype(np.int64)
        big = (ihi - ilo + 1).prod(1) > _BIG_CELLS
        self.big = np.flatnonzero(big)
        small = np.flatnonzero(~big)
        cell, owner = _box_cells(ilo[small], ihi[small])
        keys = self.key(cell)
        order = np.argsort(keys, kind="stable")
        self.keys = keys[order]
        self.tris = small[owner[order]]

    def candidates(self, ilo, ihi):
        """(box, triangle) pairs of the boxes ``[ilo, ihi]`` (cells), deduplicated.

        Returns
        -------
        box, tri : (e,) int64
        """
        cell, owner = _box_cells(ilo, ihi)
        keys = self.key(cell)
        lo = np.searchsorted(self.keys, keys, "left")
        n = np.searchsorted(self.keys, keys, "right") - lo
        b_of = np.repeat(owner, n)
        t_of = self.tris[np.repeat(lo - (np.cumsum(n) - n), n) + np.arange(int(n.sum()))]
        if len(self.big):
            nb = len(ilo)
            b_of = np.concatenate([b_of, np.repeat(np.arange(nb), len(self.big))])
            t_of = np.concatenate([t_of, np.tile(self.big, nb)])
        m = int(self.n_tris)
        pair = np.unique(b_of * m + t_of)
        return pair // m, pair % m

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


class _LowerBoundField:
    """Conservative distance field of a mesh: a lower bound of the distance anywhere.

    Every cell touched by a triangle's bounding box is *occupied*; the exact
    squared distance (in cells) from every cell to the nearest occupied one
    is a separable min-plus transform along x, y and z. A point in cell
    ``c`` is then at least ``(sqrt(D2[c]) - sqrt(3)) * h`` from the mesh
    (cell centres apart minus two half diagonals). A point ``q`` outside
    the grid's box is projected onto it (``q'``): for any mesh point ``p``
    in the box, the angle at ``q'`` is at least 90 degrees, so
    ``|q - p|^2 >= |q - q'|^2 + |q' - p|^2``.
    """

    def __init__(self, T, h_min, box=None):
        lo, hi = T.min(1), T.max(1)
        blo, bhi = (lo.min(0), hi.max(0)) if box is None else box
        self.glo = blo
        ext = float((bhi - blo).max()) or 1.0
        self.h = h = max(ext / _FIELD_DIMS, h_min)
        self.dims = dims = np.floor((bhi - blo) / h).astype(np.int64) + 1
        self.ghi = self.glo + dims * h
        ilo = np.clip(np.floor((lo - self.glo) / h).astype(np.int64), 0, dims - 1)
        ihi = np.clip(np.floor((hi - self.glo) / h).astype(np.int64), 0, dims - 1)
        cell, _ = _box_cells(ilo, ihi)
        D2 = np.full(tuple(dims), np.inf)
        D2[cell[:, 0], cell[:, 1], cell[:, 2]] = 0.0
        for axis in range(3):
            D2 = np.moveaxis(_minplus(np.moveaxis(D2, axis, 0)), 0, axis)
        self.D = np.sqrt(D2)

    def __call__(self, q):
        """(k,) lower bounds of the distance of points ``q`` (k, 3) to the mesh."""
        qc = np.clip(q, self.glo, self.ghi)
        out = np.linalg.norm(q - qc, axis=1)
        c = np.clip(np.floor((qc - self.glo) / self.h).astype(np.int64), 0, self.dims - 1)
        inside = (self.D[c[:, 0], c[:, 1], c[:, 2]] - np.sqrt(3.0)) * self.h
        # p in the box and q' the projection of q: the angle at q' is >= 90 degrees
        return np.sqrt(out**2 + np.maximum(inside, 0.0) ** 2)


def _minplus(D2):
    """``out[i] = min_j D2[j] + (i - j)^2`` along axis 0 (chunked over the others)."""
    n = D2.shape[0]
    sq = (np.arange(n)[:, None] - np.arange(n)[None, :]).astype(np.float64) ** 2
    flat = D2.reshape(n, -1)
    out = np.empty_like(flat)
    step = max(1, 4_000_000 // (n * n))
    for a in range(0, flat.shape[1], step):
        out[:, a:a + step] = (flat[None, :, a:a + step] + sq[:, :, None]).min(1)
    return out.reshape(D2.shape)


def _check_cap(max_distance):
    """Validated ``max_distance``: None (no cap) or a float >= 0 (inf means no cap)."""
    if max_distance is None:
        return None
    if isinstance(max_distance, (bool, np.bool_)):
        raise InputError(f"max_distance must be a number >= 0 or None, got {max_distance!r}")
    try:
        cap = float(max_distance)
    except (TypeError, ValueError):
        raise InputError(
            f"max_distance must be a number >= 0 or None, got {max_distance!r}"
        ) from None
    if np.isnan(cap) or cap < 0:
        raise InputError(f"max_distance must be a number >= 0 or None, got {cap}")
    return None if np.isinf(cap) else cap


def segment_mesh_distance(A, B, V, F, max_distance=None):
    """Distance of each segment ``[A, B]`` to the triangle mesh ``(V, F)``.

    An expanding search over a grid of the triangles finds the exact
    distance of segments near the mesh; segments whose search box would
    span more than ``_MAX_CELLS`` grid cells (far from the mesh compared to
    its triangles) get a conservative lower bound from distance fields of
    the mesh's occupied cells instead (64 cells along the mesh's box, and
    along that box grown by 0.5 and 2 times its size on every side, where
    the query points reach there; off by at most ~3 cells of the finest
    field covering the point).

    Parameters
    ----------
    A, B : (S, 3) ndarray of float64
        Segment ends, the mesh's space.
    V : (n, 3) ndarray of float64
    F : (m, 3) ndarray of int, m >= 1
    max_distance : float >= 0, optional
        Cap: return ``min(distance, max_distance)``. Segments whose lower
        bound already reaches the cap get no exact search, and the
        expanding search stops at the cap.

    Returns
    -------
    dist : (S,) ndarray of float64
        Never above the exact distance (nor above ``max_distance``); exact
        (float64 rounding) where ``exact``.
    exact : (S,) bool
        With a cap, ``dist == min(distance, max_distance)`` counts as exact.

    Raises
    ------
    InputError
        ``max_distance`` negative, NaN or not a number.
    """
    cap = _check_cap(max_distance)
    S = len(A)
    if S == 0:
        return np.zeros(0), np.zeros(0, bool)
    T = V[F]  # (m, 3, 3)
    ext = (T.max(1) - T.min(1)).max(1)
    seg = np.linalg.norm(B - A, axis=1)
    h = max(float(np.median(ext)), 0.5 * float(np.median(seg)), 1e-12)
    g = _TriGrid(T, h)
    # lower bound of every segment: pieces of it against distance fields
    k = _FAR_PIECES
    t = (np.arange(k) + 0.5) / k
    mid = (A[:, None, :] + (B - A)[:, None, :] * t[None, :, None]).reshape(-1, 3)
    lb_pt = _LowerBoundField(T, g.h)(mid)
    # coarser fields around the mesh for the curves outside its box
    mlo, mhi = T.min((0, 1)), T.max((0, 1))
    size = float((mhi - mlo).max())
    for pad in _FIELD_PADS:
        qlo = np.maximum(mid.min(0), mlo - pad * size)
        qhi = np.minimum(mid.max(0), mhi + pad * size)
        if (qlo < mlo).any() or (qhi > mhi).any():
            box = (np.minimum(qlo, mlo), np.maximum(qhi, mhi))
            lb_pt = np.maximum(lb_pt, _LowerBoundField(T, g.h, box)(mid))
    lb = np.maximum(lb_pt.reshape(S, k) - (seg / (2 * k))[:, None], 0.0).min(1)
    capv = np.inf if cap is None else cap
    dist = np.minimum(lb, capv)
    exact = lb >= capv
    # expanding exact search: radius rho, done where the best found is <= rho
    rho = np.minimum(lb + g.h, capv)
    best = np.full(S, np.inf)
    todo = np.flatnonzero(~exact)
    while len(todo):
        r = rho[todo]
        ilo = np.clip(np.floor((np.minimum(A[todo], B[todo]) - r[:, None] - g.glo) / g.h),
                      -1, g.dims).astype(np.int64)
        ihi = np.clip(np.floor((np.maximum(A[todo], B[todo]) + r[:, None] - g.glo) / g.h),
                      -1, g.dims).astype(np.int64)
        ok = (ihi - ilo + 1).prod(1) <= _MAX_CELLS
        todo, ilo, ihi = todo[ok], ilo[ok], ihi[ok]
        _search(A, B, T, g, todo, ilo, ihi, best)
        # every triangle within rho of a segment is in its box: best <= rho is exact,
        # and a search at the cap that found nothing closer proves the cap
        found = best[todo] <= rho[todo]
        done = found | (rho[todo] >= capv)
        exact[todo[done]] = True
        dist[todo[done]] = np.where(found[done], best[todo[done]], capv)
        todo = todo[~done]
        # next radius: the best found so far is an upper bound (final search)
        rho[todo] = np.minimum(
            np.where(np.isfinite(best[todo]), best[todo], 2 * rho[todo]), capv)
    return dist, exact


def _search(A, B, T, g, idx, ilo, ihi, best):
    """Exact distances of segments ``idx`` to the triangles in their boxes, into ``best``."""
    ncell = (ihi - ilo + 1).prod(1)
    csum = np.cumsum(ncell)
    start = 0
    while start < len(idx):
        base = csum[start - 1] if start else 0
        stop = max(int(np.searchsorted(csum, base + _CHUNK_CELLS, "right")), start + 1)
        part = slice(start, stop)
        start = stop
        box, ti = g.candidates(ilo[part], ihi[part])
        si = idx[part][box]
        d = segment_triangle_distance(A[si], B[si], T[ti, 0], T[ti, 1], T[ti, 2])
        np.minimum.at(best, si, d)


def collider_distance(points, offsets, colliders, return_exact=False, max_distance=None):
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
    max_distance : float >= 0, optional
        Cap (e.g. the largest displacement the Region of Influence will
        clamp): every returned distance is ``min(distance, max_distance)``
        (``max_distance`` without colliders), still never above the true
        distance. Segments that are provably at least ``max_distance`` from
        every collider skip the exact search, so a small cap is much
        faster. :func:`region_of_influence` gives the same result with
        ``min(distance, cap)`` as with ``distance`` when no displacement is
        longer than ``cap``. Capped values count as exact.

    Returns
    -------
    distance : (P,) ndarray of float64
        ``inf`` when there is no collider. Exact (float64 rounding) for
        segments near a collider (within a few triangle sizes or segment
        lengths); for segments farther away a lower bound from distance
        fields of the collider (typically within a few percent of the
        collider's size below the truth, more for CVs farther away than the
        collider's size). It never exceeds the true distance. With
        ``max_distance``: at most ``max_distance``.
    exact : (P,) ndarray of bool
        Only with ``return_exact``. With ``max_distance``, true where the
        distance is exactly ``min(true distance, max_distance)``.

    Raises
    ------
    InputError
        Malformed curves (the message names the curve or point), or
        ``max_distance`` negative, NaN or not a number.
    ColliderError
        Malformed ``(V, F)`` collider.
    """
    pts, off = check_curves(points, offsets)
    cap = _check_cap(max_distance)
    if isinstance(colliders, Collider):
        colliders = [colliders]
    P = len(pts)
    _, _, s0 = layout(off)
    A, B = pts[s0], pts[s0 + 1]
    seg_d = np.full(len(s0), np.inf if cap is None else cap)
    seg_exact = np.ones(len(s0), bool)
    for i, col in enumerate(colliders):
        mesh = _world_mesh(col, i)
        if mesh is None:
            continue
        d, ex = segment_mesh_distance(A, B, *mesh, max_distance=cap)
        better = d < seg_d
        seg_exact = np.where(better, ex, seg_exact)
        seg_d = np.minimum(seg_d, d)
    dist = np.full(P, np.inf if cap is None else cap)
    exact = np.ones(P, bool)
    # segment k runs from point s0[k] to s0[k] + 1
    for end in (s0, s0 + 1):
        take = seg_d < dist[end]
        dist[end[take]] = seg_d[take]
        exact[end[take]] = seg_exact[take]
    if return_exact:
        return dist, exact
    return dist


def closest_faces(V, F, Q):
    """Exact closest point of a triangle mesh to each query, and its triangle.

    An expanding search over a grid of the triangles (cell ~ the median
    triangle size), with a brute-force fallback for queries whose search
    box grows past ``_MAX_CELLS`` cells. Ties go to the lowest face index.

    Parameters
    ----------
    V : (n, 3) ndarray of float64
    F : (m, 3) ndarray of int, m >= 1
    Q : (k, 3) ndarray of float64

    Returns
    -------
    P : (k, 3) ndarray of float64
        Closest points.
    face : (k,) int64
    """
    Q = np.asarray(Q, np.float64)
    k = len(Q)
    T = V[F]
    m = len(T)
    if k == 0:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    ext = (T.max(1) - T.min(1)).max(1)
    g = _TriGrid(T, max(float(np.median(ext)), 1e-12))
    best = np.full(k, np.inf)
    face = np.full(k, -1, np.int64)
    rho = np.full(k, 0.25 * g.h)  # roots usually lie on the surface: start small
    todo = np.arange(k)
    while len(todo):
        r = rho[todo][:, None]
        ilo = np.clip(np.floor((Q[todo] - r - g.glo) / g.h), -1, g.dims).astype(np.int64)
        ihi = np.clip(np.floor((Q[todo] + r - g.glo) / g.h), -1, g.dims).astype(np.int64)
        ok = (ihi - ilo + 1).prod(1) <= _MAX_CELLS
        brute = todo[~ok]
        todo, ilo, ihi = todo[ok], ilo[ok], ihi[ok]
        if len(brute):
            step = max(1, _CHUNK_CELLS // m)
            for a in range(0, len(brute), step):
                qi = np.repeat(brute[a:a + step], m)
                ti = np.tile(np.arange(m), len(brute[a:a + step]))
                _point_pairs(Q, T, qi, ti, best, face)
        if len(todo):
            box, ti = g.candidates(ilo, ihi)
            _point_pairs(Q, T, todo[box], ti, best, face)
        done = best[todo] <= rho[todo]
        todo = todo[~done]
        rho[todo] = np.where(np.isfinite(best[todo]), best[todo], 2 * rho[todo])
    P = closest_on_triangles(Q, T[face, 0], T[face, 1], T[face, 2])
    return P, face


def _point_pairs(Q, T, qi, ti, best, face):
    """Update ``best`` / ``face`` with the (query, triangle) pairs (ties: lowest face)."""
    if len(qi) == 0:
        return
    p = closest_on_triangles(Q[qi], T[ti, 0], T[ti, 1], T[ti, 2])
    d = np.linalg.norm(p - Q[qi], axis=1)
    o = np.lexsort((ti, d, qi))
    qi, ti, d = qi[o], ti[o], d[o]
    first = np.ones(len(qi), bool)
    first[1:] = qi[1:] != qi[:-1]
    qi, ti, d = qi[first], ti[first], d[first]
    better = (d < best[qi]) | ((d == best[qi]) & (ti < face[qi]))
    best[qi[better]] = d[better]
    face[qi[better]] = ti[better]
