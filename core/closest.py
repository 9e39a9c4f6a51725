"""Exact closest point on a triangle mesh, vectorized.

Used for the growth surface (Attract to Growth Surface, Put to Growth
Surface): few queries per frame, so a uniform grid with a ring search is
enough. Queries that the ring search cannot settle within a few rings fall
back to brute force, so the answer is always exact.
"""

from __future__ import annotations

import numpy as np

_GRID_CELLS = 32  # cells along the longest side of the mesh's bounds
_MAX_RING = 2
_BRUTE_PAIRS = 4_000_000  # point-triangle pairs per brute-force chunk


def closest_on_triangles(p, a, b, c):
    """Closest point of triangle (a, b, c) to p, row by row (Ericson 5.1.5).

    Parameters
    ----------
    p, a, b, c : (k, 3) ndarray of float64

    Returns
    -------
    (k, 3) ndarray
    """
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = np.where(denom != 0, vb / denom, 0.0)
        w = np.where(denom != 0, vc / denom, 0.0)
        out = a + ab * v[:, None] + ac * w[:, None]  # interior
        # edge bc
        e = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        t = np.where(e, (d4 - d3) / np.where(e, (d4 - d3) + (d5 - d6), 1.0), 0.0)
        out = np.where(e[:, None], b + (c - b) * t[:, None], out)
        # edge ac
        e = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        t = np.where(e, d2 / np.where(e, d2 - d6, 1.0), 0.0)
        out = np.where(e[:, None], a + ac * t[:, None], out)
        # edge ab
        e = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        t = np.where(e, d1 / np.where(e, d1 - d3, 1.0), 0.0)
        out = np.where(e[:, None], a + ab * t[:, None], out)
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    return out


class _Grid:
    def __init__(self, V, F):
        tri = V[F]  # (m, 3, 3)
        lo, hi = tri.min(1), tri.max(1)
        glo = lo.min(0)
        size = float((hi.max(0) - glo).max()) or 1.0
        self.h = size / _GRID_CELLS
        self.glo = glo
        ilo = np.floor((lo - glo) / self.h).astype(np.int64)
        ihi = np.floor((hi - glo) / self.h).astype(np.int64)
        span = ihi - ilo + 1
        count = span.prod(1)
        tid = np.repeat(np.arange(len(F)), count)
        # Enumerate the cells of each triangle's box.
        start = np.repeat(np.cumsum(count) - count, count)
        local = np.arange(len(tid)) - start
        sx, sy = span[tid, 0], span[tid, 1]
        cx = ilo[tid, 0] + local % sx
        cy = ilo[tid, 1] + (local // sx) % sy
        cz = ilo[tid, 2] + local // (sx * sy)
        keys = self._key(cx, cy, cz)
        order = np.argsort(keys, kind="stable")
        self.keys = keys[order]
        self.tris = tid[order]

    @staticmethod
    def _key(x, y, z):
        return ((x + 1024) * 4096 + (y + 1024)) * 4096 + (z + 1024)

    def cell(self, q):
        return np.floor((q - self.glo) / self.h).astype(np.int64)


def _ring_offsets(r):
    g = np.arange(-r, r + 1)
    d = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return d[np.abs(d).max(1) == r]


def _pairs_min(q_idx, t_idx, Q, V, F, best_d, best_t):
    """Update best distance/triangle with candidate (query, triangle) pairs."""
    if len(q_idx) == 0:
        return
    tri = F[t_idx]
    p = closest_on_triangles(Q[q_idx], V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]])
    d = np.linalg.norm(p - Q[q_idx], axis=1)
    # Lexicographic (query, distance, triangle) so ties break deterministically.
    order = np.lexsort((t_idx, d, q_idx))
    q_s, d_s, t_s = q_idx[order], d[order], t_idx[order]
    first = np.ones(len(q_s), bool)
    first[1:] = q_s[1:] != q_s[:-1]
    q_s, d_s, t_s = q_s[first], d_s[first], t_s[first]
    better = (d_s < best_d[q_s]) | ((d_s == best_d[q_s]) & (t_s < best_t[q_s]))
    best_d[q_s[better]] = d_s[better]
    best_t[q_s[better]] = t_s[better]


def closest_points_on_mesh(V, F, Q, grid=None):
    """Closest point on mesh (V, F) to each query point.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int, m >= 1
    Q : (k, 3) float64
    grid : object or None
        The acceleration grid returned by a previous call on the same mesh.

    Returns
    -------
    P : (k, 3) float64
        Closest points.
    face : (k,) int64
        Triangle of each closest point.
    grid : object
        Pass it back in for the next query on the same mesh.
    """
    Q = np.asarray(Q, np.float64)
    k = len(Q)
    if grid is None:
        grid = _Grid(V, F)
    best_d = np.full(k, np.inf)
    best_t = np.full(k, -1, np.int64)
    qc = grid.cell(Q)
    active = np.arange(k)
    for r in range(_MAX_RING + 1):
        if len(active) == 0:
            break
        offs = _ring_offsets(r)
        cells = qc[active][:, None, :] + offs[None]  # (a, c, 3)
        keys = grid._key(cells[..., 0], cells[..., 1], cells[..., 2]).ravel()
        lo = np.searchsorted(grid.keys, keys, "left")
        hi = np.searchsorted(grid.keys, keys, "right")
        n = hi - lo
        q_of = np.repeat(np.repeat(active, len(offs)), n)
        start = np.repeat(lo - (np.cumsum(n) - n), n)
        t_of = grid.tris[start + np.arange(int(n.sum()))]
        _pairs_min(q_of, t_of, Q, V, F, best_d, best_t)
        done = best_d[active] <= r * grid.h
        active = active[~done]
    if len(active):  # far queries: exact brute force in bounded chunks
        step = max(1, _BRUTE_PAIRS // len(F))
        for a in range(0, len(active), step):
            qa = active[a : a + step]
            q_of = np.repeat(qa, len(F))
            t_of = np.tile(np.arange(len(F)), len(qa))
            _pairs_min(q_of, t_of, Q, V, F, best_d, best_t)
    tri = F[best_t]
    P = closest_on_triangles(Q, V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]])
    return P, best_t, grid
