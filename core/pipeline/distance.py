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
#: Triangle grids with at most this many cells get a dense cell -> triangles lookup.
_DENSE_CELLS = 1 << 23
#: Cells along the longest side of the near lower-bound field (over the mesh's box).
_NEAR_DIMS = 128
#: The near field holds distances up to this many cells (beyond: "at least that").
_NEAR_WINDOW = 8
#: Sub-pieces of a segment in the first (cheap) lower bound.
_NEAR_PIECES = 2
#: Pair (segment, triangle) entries per chunk of the exact search.
_CHUNK_PAIRS = 400_000


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
        # dense lookup: triangles of cell key k are tris[start[k]:start[k + 1]]
        n_keys = int((self.dims + 2).prod())
        self.start = None
        if n_keys <= _DENSE_CELLS:
            self.start = np.zeros(n_keys + 1, np.int64)
            np.cumsum(np.bincount(self.keys, minlength=n_keys), out=self.start[1:])

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

    def __init__(self, T, h_min, box=None, dims=_FIELD_DIMS, window=None):
        lo, hi = T.min(1), T.max(1)
        blo, bhi = (lo.min(0), hi.max(0)) if box is None else box
        self.glo = blo
        ext = float((bhi - blo).max()) or 1.0
        self.h = h = max(ext / dims, h_min)
        self.dims = dims = np.floor((bhi - blo) / h).astype(np.int64) + 1
        self.ghi = self.glo + dims * h
        ilo = np.clip(np.floor((lo - self.glo) / h).astype(np.int64), 0, dims - 1)
        ihi = np.clip(np.floor((hi - self.glo) / h).astype(np.int64), 0, dims - 1)
        cell, _ = _box_cells(ilo, ihi)
        if window is None:
            D2 = np.full(tuple(dims), np.inf)
            D2[cell[:, 0], cell[:, 1], cell[:, 2]] = 0.0
            for axis in range(3):
                D2 = np.moveaxis(_minplus(np.moveaxis(D2, axis, 0)), 0, axis)
            self.D = np.sqrt(D2)
        else:
            # only distances up to `window` cells: beyond, (window + 1) is a lower bound
            D2 = np.full(tuple(dims), np.float32(np.inf), np.float32)
            D2[cell[:, 0], cell[:, 1], cell[:, 2]] = 0.0
            for axis in range(3):
                D2 = _minplus_window(D2, axis, window)
            self.D = np.sqrt(np.minimum(D2, np.float32((window + 1) ** 2)))

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


def _minplus_window(D2, axis, w):
    """``out[i] = min_{|i - j| <= w} D2[j] + (i - j)^2`` along ``axis``.

    Overestimates only values above ``w^2``: the caller clamps to
    ``(w + 1)^2`` (a nearest cell outside the window is farther than that).
    """
    out = D2.copy()
    n = D2.shape[axis]
    for s in range(1, min(w, n - 1) + 1):
        a = [slice(None)] * 3
        b = [slice(None)] * 3
        a[axis], b[axis] = slice(s, None), slice(None, -s)
        s2 = np.float32(s * s)
        np.minimum(out[tuple(a)], D2[tuple(b)] + s2, out=out[tuple(a)])
        np.minimum(out[tuple(b)], D2[tuple(a)] + s2, out=out[tuple(b)])
    return out


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


class _MeshIndex:
    """Search structures of one triangle mesh (its own space), built lazily, kept.

    A :class:`~core.Collider` keeps its index (see :func:`_collider_index`)
    as long as its vertices do not change, so a rigid collider builds its
    grids and distance fields once.
    """

    def __init__(self, V, F):
        T = np.ascontiguousarray(V[F], dtype=np.float64)  # (m, 3, 3)
        self.T = T
        tlo, thi = T.min(1), T.max(1)
        self.lo, self.hi = tlo.min(0), thi.max(0)
        self.size = float((self.hi - self.lo).max()) or 1.0
        self.tri_h = max(float(np.median((thi - tlo).max(1))), 1e-9 * self.size, 1e-300)
        self.centroid = T.mean(1)
        self.radius = np.linalg.norm(T - self.centroid[:, None], axis=2).max(1)
        self.eps = 1e-12 * (self.size + float(np.abs(self.lo).max()))  # rounding slack
        self._grids = {}
        self._fields = {}

    def grid(self, h):
        """Triangle grid with cells of at least ``h`` (``tri_h * 2^k``, cached)."""
        k = max(0, int(np.ceil(np.log2(max(h / self.tri_h, 1.0)) - 1e-9)))
        g = self._grids.get(k)
        if g is None:
            g = self._grids[k] = _TriGrid(self.T, self.tri_h * 2.0**k)
        return g

    def field(self, box=None, near=False):
        """Lower-bound field: ``near`` (fine, windowed) or over ``box`` (cached by box)."""
        key = "near" if near else (None if box is None else
                                   tuple(np.concatenate(box).round(12).tolist()))
        f = self._fields.get(key)
        if f is None:
            if near:
                # cells about half a triangle: finer is of little use to the search
                dims = int(np.clip(2 * self.size / self.tri_h, 16, _NEAR_DIMS))
                f = _LowerBoundField(self.T, 0.0, dims=dims, window=_NEAR_WINDOW)
            else:
                f = _LowerBoundField(self.T, self.tri_h, box)
            if len(self._fields) > 8:  # padded boxes follow the queries: keep a few
                self._fields.pop(next(k for k in self._fields if k != "near"))
            self._fields[key] = f
        return f

    def lower_bound(self, A, B, pieces, cap=None):
        """(S,) lower bound of the segments' distance (``pieces`` samples each).

        With ``cap`` (scalar), the coarse fields are used only if the near
        field cannot reach the cap.
        """
        S = len(A)
        t = (np.arange(pieces) + 0.5) / pieces
        q = (A[:, None, :] + (B - A)[:, None, :] * t[None, :, None]).reshape(-1, 3)
        near = self.field(near=True)
        lb = near(q)
        reach = (_NEAR_WINDOW + 1 - np.sqrt(3.0)) * near.h
        if cap is None or cap > reach:
            lb = np.maximum(lb, self.field()(q))
            # coarser fields around the mesh for the points outside its box
            # (boxes rounded outward to 1/8 of the mesh's size, so they are reused)
            for pad in _FIELD_PADS:
                qlo = np.maximum(q.min(0), self.lo - pad * self.size)
                qhi = np.minimum(q.max(0), self.hi + pad * self.size)
                if (qlo < self.lo).any() or (qhi > self.hi).any():
                    u = self.size / 8
                    qlo = self.lo - np.ceil((self.lo - qlo) / u) * u
                    qhi = self.hi + np.ceil((qhi - self.hi) / u) * u
                    lb = np.maximum(lb, self.field((np.minimum(qlo, self.lo),
                                                    np.maximum(qhi, self.hi)))(q))
        seg = np.linalg.norm(B - A, axis=1)
        return np.maximum(lb.reshape(S, pieces) - (seg / (2 * pieces))[:, None], 0.0).min(1)


def _similarity(M3):
    """Scale ``s`` if ``M3 = s * Q`` with ``Q`` orthogonal (distances scale by ``s``), else None."""
    G = M3.T @ M3
    s2 = float(np.trace(G)) / 3.0
    if s2 > 0 and np.abs(G - s2 * np.eye(3)).max() <= 1e-12 * s2:
        return np.sqrt(s2)
    return None


def _collider_index(col):
    """``(index, M3, t, scale)``: ``col``'s mesh index and the map from world to its space.

    A world point ``x`` is ``(x - t) @ inv(M3).T`` in the index's space and a
    distance there times ``scale`` is the world distance. Rigid (similarity)
    transforms keep the collider's own space, so the index survives motion
    and is cached on the Collider until its vertices change; other
    transforms index the world mesh (cached for that matrix).
    """
    M = col.matrix
    M3, t = M[:3, :3], M[:3, 3]
    s = _similarity(M3)
    key = (col._version, id(col._V), None if s is not None else M.tobytes())
    cached = getattr(col, "_distance_index", None)
    if cached is not None and cached[0] == key:
        index = cached[1]
    else:
        V = col.vertices.astype(np.float64)
        if s is None:
            V = V @ M3.T + t
        index = _MeshIndex(V, col.faces.astype(np.int64))
        col._distance_index = (key, index)
    if s is None:
        return index, np.eye(3), np.zeros(3), 1.0
    return index, M3, t, s


def segment_mesh_distance(A, B, V, F, max_distance=None):
    """Distance of each segment ``[A, B]`` to the triangle mesh ``(V, F)``.

    An expanding search over a grid of the triangles finds the exact
    distance of segments near the mesh; segments whose search box would
    span more than ``_MAX_CELLS`` grid cells (far from the mesh compared to
    its triangles) get a conservative lower bound from distance fields of
    the mesh's occupied cells instead (64 cells along the mesh's box, and
    along that box grown by 0.5 and 2 times its size on every side, where
    the query points reach there; off by at most ~3 cells of the finest
    field covering the point, plus 1/16 of the segment).

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
    A = np.asarray(A, np.float64)
    B = np.asarray(B, np.float64)
    if len(A) == 0:
        return np.zeros(0), np.zeros(0, bool)
    return _segment_distance(_MeshIndex(np.asarray(V, np.float64), np.asarray(F)), A, B,
                             np.inf if cap is None else cap)


def _segment_distance(ix, A, B, cap):
    """``(dist, exact)`` of segments ``[A, B]`` (the index's space), capped at ``cap``.

    ``cap`` is a scalar or an (S,) array (``inf``: no cap).
    """
    S = len(A)
    capv = np.broadcast_to(np.asarray(cap, np.float64), (S,))
    seg = np.linalg.norm(B - A, axis=1)
    g = ix.grid(max(0.5 * float(np.median(seg)), ix.tri_h))
    scalar_cap = float(capv.max()) if np.isfinite(capv).all() else None
    lb = ix.lower_bound(A, B, _NEAR_PIECES, scalar_cap)
    dist = np.minimum(lb, capv)
    exact = lb >= capv
    # expanding exact search: radius rho, done where the best found is <= rho
    rho = np.minimum(lb + g.h, capv)
    best = np.full(S, np.inf)
    upper = np.full(S, np.inf)  # upper bounds of the distance (a triangle's centroid)
    far = np.zeros(S, bool)
    todo = np.flatnonzero(~exact)
    while len(todo):
        r = rho[todo]
        ilo = np.clip(np.floor((np.minimum(A[todo], B[todo]) - r[:, None] - g.glo) / g.h),
                      -1, g.dims).astype(np.int64)
        ihi = np.clip(np.floor((np.maximum(A[todo], B[todo]) + r[:, None] - g.glo) / g.h),
                      -1, g.dims).astype(np.int64)
        ok = (ihi - ilo + 1).prod(1) <= _MAX_CELLS
        far[todo[~ok]] = True
        todo, ilo, ihi = todo[ok], ilo[ok], ihi[ok]
        _search(A, B, ix, g, todo, ilo, ihi, rho, best, upper)
        # every triangle within rho of a segment is a candidate: best <= rho is exact,
        # and a search at the cap that found nothing closer proves the cap
        found = best[todo] <= rho[todo]
        done = found | (rho[todo] >= capv[todo])
        exact[todo[done]] = True
        dist[todo[done]] = np.where(found[done], best[todo[done]], capv[todo[done]])
        todo = todo[~done]
        # next radius: an upper bound of the distance when one is known, else a bit more
        nxt = np.minimum(best[todo], upper[todo])
        grow = np.minimum(2 * rho[todo], rho[todo] + 2 * g.h)
        rho[todo] = np.minimum(np.where(np.isfinite(nxt), nxt, grow), capv[todo])
    if far.any():
        # far segments: the finer lower bound (more pieces, coarse fields included)
        i = np.flatnonzero(far)
        lb8 = ix.lower_bound(A[i], B[i], _FAR_PIECES)
        dist[i] = np.minimum(np.maximum(dist[i], lb8), capv[i])
        exact[i] = lb8 >= capv[i]
    return dist, exact


def _search(A, B, ix, g, idx, ilo, ihi, rho, best, upper):
    """Exact distances of segments ``idx`` to the triangles within ``rho`` of them.

    Updates ``best`` (smallest exact distance found) and ``upper`` (smallest
    segment-to-centroid distance, an upper bound). Cells farther than
    ``rho`` from the segment are dropped, then triangles whose bounding
    sphere is farther than ``min(rho, upper)``, before the exact test.
    """
    if len(idx) == 0:
        return
    ncell = (ihi - ilo + 1).prod(1)
    csum = np.cumsum(ncell)
    T = ix.T
    half = 0.5 * np.sqrt(3.0) * g.h
    start = 0
    while start < len(idx):
        base = csum[start - 1] if start else 0
        stop = max(int(np.searchsorted(csum, base + _CHUNK_CELLS, "right")), start + 1)
        part = idx[start:stop]
        cell, owner = _box_cells(ilo[start:stop], ihi[start:stop])
        start = stop
        si = part[owner]
        keys = g.key(cell)
        if g.start is not None:
            lo = g.start[keys]
            n = g.start[keys + 1] - lo
        else:
            lo = np.searchsorted(g.keys, keys, "left")
            n = np.searchsorted(g.keys, keys, "right") - lo
        # occupied cells within rho (+ half a diagonal) of the segment
        keep = n > 0
        centre = g.glo + (cell[keep] + 0.5) * g.h
        sk = si[keep]
        keep[keep] = _point_segment(centre, A[sk], B[sk]) <= rho[sk] + half + ix.eps
        lo, n, si = lo[keep], n[keep], si[keep]
        tot = int(n.sum())
        ti = g.tris[np.repeat(lo - (np.cumsum(n) - n), n) + np.arange(tot)]
        si = np.repeat(si, n)
        if len(g.big):
            si = np.concatenate([si, np.repeat(part, len(g.big))])
            ti = np.concatenate([ti, np.tile(g.big, len(part))])
        for a in range(0, len(si), _CHUNK_PAIRS):
            _pairs(A, B, ix, T, si[a:a + _CHUNK_PAIRS], ti[a:a + _CHUNK_PAIRS],
                   rho, best, upper)


def _pairs(A, B, ix, T, si, ti, rho, best, upper):
    """Bounding-sphere cull, then the exact distance of (segment, triangle) pairs."""
    if len(si) == 0:
        return
    dc = _point_segment(ix.centroid[ti], A[si], B[si])
    _min_into(upper, si, dc)
    # (a hair of slack against rounding: never cull the closest triangle)
    keep = dc - ix.radius[ti] * (1 + 1e-9) <= np.minimum(rho[si], upper[si]) + ix.eps
    # and the nearest centroid of each segment, for a tight upper bound (next radius)
    keep |= dc <= upper[si]
    si, ti = si[keep], ti[keep]
    if len(si) == 0:
        return
    m = len(T)
    pair = np.unique(si * m + ti)
    si, ti = pair // m, pair % m
    d = segment_triangle_distance(A[si], B[si], T[ti, 0], T[ti, 1], T[ti, 2])
    _min_into(best, si, d)


def _min_into(out, i, v):
    """``out[i] = min(out[i], v)`` with repeated ``i`` (sort + reduceat)."""
    if len(i) == 0:
        return
    if len(i) > 1 and (i[1:] < i[:-1]).any():
        o = np.argsort(i, kind="stable")
        i, v = i[o], v[o]
    first = np.flatnonzero(np.r_[True, i[1:] != i[:-1]])
    u = i[first]
    out[u] = np.minimum(out[u], np.minimum.reduceat(v, first))


def _point_segment(p, a, b):
    """Distance of points ``p`` to segments ``[a, b]``, row by row."""
    ab = b - a
    ap = p - a
    L2 = _dot(ab, ab)
    t = np.clip(_dot(ap, ab) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
    return np.linalg.norm(ap - ab * t[:, None], axis=1)


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
        if isinstance(col, Collider):
            if col.empty:
                continue
            ix, M3, t, scale = _collider_index(col)
        else:
            mesh = _world_mesh(col, i)
            if mesh is None:
                continue
            ix, M3, t, scale = _MeshIndex(*mesh), np.eye(3), np.zeros(3), 1.0
        if len(s0) == 0:
            continue
        if scale == 1.0 and not (M3 - np.eye(3)).any() and not t.any():
            Al, Bl = A, B
        else:
            Minv = np.linalg.inv(M3).T
            Al, Bl = (A - t) @ Minv, (B - t) @ Minv
        # the best distance so far caps this collider's search too
        d, ex = _segment_distance(ix, Al, Bl, seg_d / scale)
        d = d * scale
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
