"""Proximity grids: of a triangle mesh (closest points, distances) and of points (knn).

:class:`TriangleGrid` registers each triangle in the grid cells that its
plane crosses within its bounding box (big triangles, a ground plane next
to a detailed character, are kept apart and tested by every search). Used by
:mod:`core.closest` (closest point on a mesh: the growth surface, Fur Attach)
and :mod:`core.pipeline.distance` (Fur Collider Distance). :func:`knn` (a
uniform grid of points) serves the render groom's binding and the far
queries of the closest-point search.
"""

from __future__ import annotations

import numpy as np

from . import tolerances as tol

#: Grid cells along the longest side, at most.
MAX_DIMS = 256
#: Pairs (query, reference) per chunk of the brute-force nearest neighbours.
KNN_CHUNK = 4_000_000


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


class TriangleGrid:
    """Uniform grid of triangle bounding boxes (cell size ``h``).

    Triangles whose box spans more than ``tolerances.GRID_BIG_CELLS`` cells (a ground
    plane next to a detailed character) are not registered in cells: they
    are in :attr:`big` and every search tests them.
    """

    def __init__(self, T, h):
        lo, hi = T.min(1), T.max(1)
        self.n_tris = len(T)
        self.glo = lo.min(0)
        ext = float((hi.max(0) - self.glo).max()) or 1.0
        self.h = h = max(h, ext / MAX_DIMS)
        self.dims = np.floor((hi.max(0) - self.glo) / h).astype(np.int64) + 1
        ilo = np.floor((lo - self.glo) / h).astype(np.int64)
        ihi = np.floor((hi - self.glo) / h).astype(np.int64)
        big = (ihi - ilo + 1).prod(1) > tol.GRID_BIG_CELLS
        self.big = np.flatnonzero(big)
        small = np.flatnonzero(~big)
        cell, owner = box_cells(ilo[small], ihi[small])
        # only the cells of the box that the triangle's plane crosses
        pl = planes(T)
        hit = plane_crosses_cells(pl, cell, small[owner], self.glo, h)
        cell, owner = cell[hit], owner[hit]
        keys = self.key(cell)
        order = np.argsort(keys, kind="stable")
        self.keys = keys[order]
        self.tris = small[owner[order]]
        self._slab_input = (T, pl[0])  # slabs: built on first use (distance searches)
        self._slab = None
        # dense lookup: triangles of cell key k are tris[start[k]:start[k + 1]]
        n_keys = int((self.dims + 2).prod())
        self.start = None
        if n_keys <= tol.GRID_DENSE_CELLS:
            self.start = np.zeros(n_keys + 1, np.int64)
            np.cumsum(np.bincount(self.keys, minlength=n_keys), out=self.start[1:])

    @property
    def slab_n(self):
        """(e,) unit mean normal of each cell's slab, at the cell's first slot in :attr:`tris`."""
        return self._slabs()[0]

    @property
    def slab_a(self):
        return self._slabs()[1]

    @property
    def slab_b(self):
        return self._slabs()[2]

    def _slabs(self):
        """Per occupied cell, a slab holding its triangles: ``a <= n . p <= b``.

        ``n`` is the cell's mean triangle normal (unit, or 0); ``a``/``b`` the
        range of ``n . v`` over the vertices of every triangle in the cell,
        so the whole triangles (not only their parts in the cell) are in
        the slab. Stored at the cell's first slot in :attr:`tris`.
        """
        if self._slab is not None:
            return self._slab
        T, normal = self._slab_input
        R = len(self.tris)
        slab_n = np.zeros((R, 3))
        slab_a = np.zeros(R)
        slab_b = np.zeros(R)
        if R == 0:
            self._slab = (slab_n, slab_a, slab_b)
            return self._slab
        head = np.flatnonzero(np.r_[True, self.keys[1:] != self.keys[:-1]])
        Tr = T[self.tris]
        n = normal[self.tris]
        nl = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.where(nl > 0, n / np.where(nl > 0, nl, 1.0), 0.0)
        nc = np.add.reduceat(n, head, axis=0)
        nl = np.linalg.norm(nc, axis=1, keepdims=True)
        nc = np.where(nl > 1e-6, nc / np.where(nl > 1e-6, nl, 1.0), 0.0)
        cell_of = np.repeat(np.arange(len(head)), np.diff(np.r_[head, R]))
        pv = np.einsum("rij,rj->ri", Tr, nc[cell_of])
        slab_n[head] = nc
        slab_a[head] = np.minimum.reduceat(pv.min(1), head)
        slab_b[head] = np.maximum.reduceat(pv.max(1), head)
        self._slab = (slab_n, slab_a, slab_b)
        return self._slab

    def candidates(self, ilo, ihi, q=None, rho=None):
        """(box, triangle) pairs of the boxes ``[ilo, ihi]`` (cells), deduplicated.

        With query points ``q`` (b, 3) and radii ``rho`` (b,), only the cells
        whose box comes within ``rho`` of the box's query count (every
        triangle within ``rho`` of it is still a candidate).

        Returns
        -------
        box, tri : (e,) int64
        """
        cell, owner = box_cells(ilo, ihi)
        if q is not None:
            lo = self.glo + cell * self.h - q[owner]
            gap = np.maximum(np.maximum(lo, -(lo + self.h)), 0.0)
            near = np.einsum("ij,ij->i", gap, gap) <= (rho[owner] * (1 + 1e-9)) ** 2
            cell, owner = cell[near], owner[near]
        keys = self.key(cell)
        if self.start is not None:
            lo = self.start[keys]
            n = self.start[keys + 1] - lo
        else:
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


def box_cells(ilo, ihi):
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


def mark_boxes(ilo, ihi, dims) -> np.ndarray:
    """(dims) bool grid: the cells of boxes ``[ilo, ihi]`` (n, 3), clipped to the grid.

    A box at most 2 cells a side (a triangle smaller than the cells: nearly
    all of them) is its 8 corner cells; larger ones are summed into a
    difference grid (+-1 at their 8 corners) and integrated: O(cells + n)
    whatever their size.
    """
    dims = np.asarray(dims, np.int64)
    ilo = np.clip(ilo, 0, dims - 1)
    ihi = np.clip(ihi, 0, dims - 1)
    out = np.zeros(int(np.prod(dims)), bool)
    span = ihi - ilo + 1
    small = (span <= 2).all(axis=1)
    a, b = ilo[small].T, ihi[small].T
    for cx in (a[0], b[0]):
        for cy in (a[1], b[1]):
            xy = (cx * dims[1] + cy) * dims[2]
            out[xy + a[2]] = True
            out[xy + b[2]] = True
    big = np.flatnonzero(~small)
    if len(big):
        d1 = dims + 1
        diff = np.zeros(int(np.prod(d1)), np.int64)
        a, b = ilo[big].T, ihi[big].T + 1
        for cx, sx in ((a[0], 1), (b[0], -1)):
            for cy, sy in ((a[1], 1), (b[1], -1)):
                for cz, sz in ((a[2], 1), (b[2], -1)):
                    idx = (cx * d1[1] + cy) * d1[2] + cz
                    diff += np.bincount(idx, minlength=len(diff)) * (sx * sy * sz)
        g = diff.reshape(tuple(d1))
        for ax in range(3):
            np.cumsum(g, axis=ax, out=g)
        out |= (g[: dims[0], : dims[1], : dims[2]] > 0).reshape(-1)
    return out.reshape(tuple(dims))


def planes(T):
    """Triangle planes ``n . x = c`` (``n`` the unnormalized normal) and ``|n|_1``."""
    n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    return n, _dot(n, T[:, 0]), np.abs(n).sum(1)


def plane_crosses_cells(planes, cell, tri, glo, h):
    """(k,) bool: the plane of triangle ``tri`` meets cell ``cell`` (box overlap test).

    A triangle meets only cells that its plane meets, so dropping the
    others keeps every cell that holds a point of the triangle (with a
    little slack against rounding; degenerate triangles keep every cell).
    """
    n, c, l1 = planes
    centre = glo + (cell + 0.5) * h
    reach = 0.5 * h * l1[tri]
    off = np.abs(_dot(n[tri], centre) - c[tri])
    return off <= reach * (1 + 1e-6) + 1e-9 * h * l1.max(initial=0.0) * (
        1 + float(np.abs(glo).max()) / h)


def _knn_brute(Q, X, k):
    """Chunked brute force of :func:`knn`."""
    index = np.empty((len(Q), k), np.int64)
    dist = np.empty((len(Q), k))
    step = max(1, KNN_CHUNK // max(len(X), 1))
    xx = np.einsum("ij,ij->i", X, X)
    for a in range(0, len(Q), step):
        q = Q[a:a + step]
        d2 = np.maximum(xx[None] - 2 * q @ X.T + np.einsum("ij,ij->i", q, q)[:, None], 0)
        if k < len(X):
            part = np.argpartition(d2, k - 1, axis=1)[:, :k]
        else:
            part = np.broadcast_to(np.arange(len(X)), d2.shape)
        d = np.linalg.norm(X[part] - q[:, None], axis=-1)
        order = np.lexsort((part, d), axis=1)
        index[a:a + step] = np.take_along_axis(part, order, 1)
        dist[a:a + step] = np.take_along_axis(d, order, 1)
    return index, dist


def knn(Q, X, k):
    """``k`` nearest rows of ``X`` to each row of ``Q``.

    A uniform grid answers the queries whose ``k``-th neighbour lies within
    one cell (all candidates in the 27 cells around the query); the others
    fall back to a chunked brute force. Exact either way.

    Returns
    -------
    index : (q, k) int64
        Sorted by distance (ties: lower index first).
    dist : (q, k) float64
    """
    Q = np.asarray(Q, np.float64)
    X = np.asarray(X, np.float64)
    k = min(k, len(X))
    nq = len(Q)
    if nq * len(X) <= KNN_CHUNK or len(X) < 8 * k:
        return _knn_brute(Q, X, k)
    lo = X.min(0)
    ext = float((X.max(0) - lo).max()) or 1.0
    h = ext * np.sqrt(2.0 * k / len(X))  # ~2k points per cell on a surface
    dims = np.floor((X.max(0) - lo) / h).astype(np.int64) + 1

    def key(c):
        c = np.clip(c, -1, dims) + 1
        return (c[:, 0] * (dims[1] + 2) + c[:, 1]) * (dims[2] + 2) + c[:, 2]

    kx = key(np.floor((X - lo) / h).astype(np.int64))
    order = np.argsort(kx, kind="stable")
    ks = kx[order]
    qc = np.floor((Q - lo) / h).astype(np.int64)
    index = np.empty((nq, k), np.int64)
    dist = np.empty((nq, k))
    good = np.zeros(nq, bool)
    step = max(1, KNN_CHUNK // (27 * 4 * k))
    for a in range(0, nq, step):
        qi = np.arange(a, min(nq, a + step))
        I, J = [], []
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for dz in (-1, 0, 1):
                    kk = key(qc[qi] + [dx, dy, dz])
                    s0 = np.searchsorted(ks, kk, "left")
                    m = np.searchsorted(ks, kk, "right") - s0
                    I.append(np.repeat(qi, m))
                    J.append(order[np.repeat(s0 - (np.cumsum(m) - m), m)
                                   + np.arange(int(m.sum()))])
        i, j = np.concatenate(I), np.concatenate(J)
        d = np.linalg.norm(X[j] - Q[i], axis=1)
        o = np.lexsort((j, d, i))
        i, j, d = i[o], j[o], d[o]
        first = np.searchsorted(i, qi)
        count = np.searchsorted(i, qi, "right") - first
        ok = count >= k
        sel = first[ok][:, None] + np.arange(k)
        ok_idx = qi[ok]
        kth = d[sel[:, -1]]
        exact = kth <= h  # every point within h of the query is in its 27 cells
        index[ok_idx[exact]] = j[sel[exact]]
        dist[ok_idx[exact]] = d[sel[exact]]
        good[ok_idx[exact]] = True
    rest = np.flatnonzero(~good)
    if len(rest):
        index[rest], dist[rest] = _knn_brute(Q[rest], X, k)
    return index, dist
