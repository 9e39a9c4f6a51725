"""Exact closest point on a triangle mesh, vectorized: the one closest-point search.

Used for the growth surface (Attract to Growth Surface, Put to Growth
Surface, through ``Collider.closest_points``) and by the fur pipeline (Fur
Attach's binding, surface values). An expanding search over the mesh's
proximity grid (:mod:`core.proximity`), exact, ties to the lowest face.
"""

from __future__ import annotations

import numpy as np

from . import tolerances as tol
from .proximity import TriangleGrid


def barycentric(p, a, b, c):
    """Barycentric coordinates (k, 3) of points ``p`` (k, 3) in the planes of the
    triangles (a, b, c), unclamped; zero rows for degenerate (zero-area) triangles."""
    v0, v1, v2 = b - a, c - a, p - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = d00 * d11 - d01 * d01
    ok = den > 0
    v = np.divide(d11 * d20 - d01 * d21, den, out=np.zeros_like(den), where=ok)
    w = np.divide(d00 * d21 - d01 * d20, den, out=np.zeros_like(den), where=ok)
    bary = np.stack([1 - v - w, v, w], axis=1)
    bary[~ok] = 0.0
    return bary


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


#: Queries per block of the search (bounds the candidate pairs in memory).
_QUERY_BLOCK = 8192
#: Triangles sampled for the first upper bound of a query far from the mesh.
_SAMPLES = 2048


class MeshProximity:
    """Closest-point structures of one triangle mesh: its triangles and proximity
    grids (:class:`~core.proximity.TriangleGrid`) of cell ``tri_h * 2^k``, built
    on first use and kept. Pass it back to :func:`closest_points_on_mesh`."""

    def __init__(self, V, F):
        self.T = np.ascontiguousarray(np.asarray(V, np.float64)[np.asarray(F)])
        ext = (self.T.max(1) - self.T.min(1)).max(1)
        self.tri_h = max(float(np.median(ext)), 1e-12) if len(ext) else 1.0
        self.centroid = self.T.mean(1)
        self.radius = np.linalg.norm(self.T - self.centroid[:, None], axis=2).max(1)
        lo = self.T.min((0, 1)) if len(self.T) else np.zeros(3)
        self.eps = 1e-12 * (float(np.abs(lo).max()) + float(ext.max(initial=0.0)) + 1.0)
        self._grids = {}

    def sample_bound(self, q):
        """(k,) an upper bound of the distance of points ``q`` to the mesh: the exact
        distance to the best of about ``_SAMPLES`` spread triangles (nearest centroid),
        close to the distance for points far from the mesh."""
        step = max(1, len(self.T) // _SAMPLES)
        ts = np.arange(0, len(self.T), step)
        out = np.empty(len(q))
        for a in range(0, len(q), 256):
            qa = q[a:a + 256]
            d2 = ((qa[:, None, :] - self.centroid[ts][None]) ** 2).sum(-1)
            t = ts[np.argmin(d2, 1)]
            p = closest_on_triangles(qa, self.T[t, 0], self.T[t, 1], self.T[t, 2])
            out[a:a + 256] = np.linalg.norm(p - qa, axis=1)
        return out * (1 + 1e-12)

    def grid(self, level):
        g = self._grids.get(level)
        if g is None:
            g = self._grids[level] = TriangleGrid(self.T, self.tri_h * 2.0**level)
        return g


def closest_points_on_mesh(V, F, Q, grid=None):
    """Exact closest point on mesh (V, F) to each query point.

    An expanding search over the mesh's proximity grid (cell about the median
    triangle size), starting small (queries usually lie on or near the
    surface): a query is settled once the closest triangle found is within
    the searched radius, since every triangle within it was a candidate. A
    query whose search box grows past ``tolerances.CLOSEST_MAX_CELLS`` cells continues on a
    grid of twice the cell size (up to one that holds the whole mesh in a
    few cells), and a query that found no triangle yet starts from its
    distance to a sample of the triangles (an upper bound): only the cells
    within it are searched, so far queries do not test every triangle. Ties
    go to the lowest face index.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int, m >= 1
    Q : (k, 3) float64
    grid : MeshProximity or None
        The structures returned by a previous call on the same mesh.

    Returns
    -------
    P : (k, 3) float64
        Closest points.
    face : (k,) int64
        Triangle of each closest point.
    grid : MeshProximity
        Pass it back in for the next query on the same mesh.
    """
    Q = np.asarray(Q, np.float64)
    if grid is None:
        grid = MeshProximity(V, F)
    T = grid.T
    k = len(Q)
    best = np.full(k, np.inf)
    face = np.full(k, -1, np.int64)
    if k == 0:
        return np.zeros((0, 3)), face, grid
    rho = np.full(k, 0.25 * grid.grid(0).h)
    level = np.zeros(k, np.int64)
    todo = np.arange(k)
    while len(todo):
        left = []
        for lv in np.unique(level[todo]):
            sel = todo[level[todo] == lv]
            g = grid.grid(int(lv))
            r = rho[sel][:, None]
            ilo = np.clip(np.floor((Q[sel] - r - g.glo) / g.h), -1, g.dims).astype(np.int64)
            ihi = np.clip(np.floor((Q[sel] + r - g.glo) / g.h), -1, g.dims).astype(np.int64)
            fit = ((ihi - ilo + 1).prod(1) <= tol.CLOSEST_MAX_CELLS) | bool((g.dims <= 2).all())
            out = sel[~fit]
            level[out] += 1  # searched again on a coarser grid
            lost = out[~np.isfinite(best[out])] if lv >= 2 else out[:0]
            if len(lost):  # far from the mesh: start from the nearest vertex's distance
                rho[lost] = np.minimum(rho[lost], grid.sample_bound(Q[lost]))
            left.append(out)
            sel, ilo, ihi = sel[fit], ilo[fit], ihi[fit]
            for a in range(0, len(sel), _QUERY_BLOCK):
                b = slice(a, a + _QUERY_BLOCK)
                # cells within rho only: what keeps far queries cheap
                box, ti = g.candidates(ilo[b], ihi[b], Q[sel[b]], rho[sel[b]])
                _point_pairs(Q, grid, sel[b][box], ti, best, face)
            more = sel[best[sel] > rho[sel]]
            # next radius: the best distance found (an upper bound), else twice as far
            rho[more] = np.where(np.isfinite(best[more]), best[more], 2 * rho[more])
            left.append(more)
        todo = np.concatenate(left)
    P = closest_on_triangles(Q, T[face, 0], T[face, 1], T[face, 2])
    return P, face, grid


def closest_faces(V, F, Q):
    """:func:`closest_points_on_mesh` without the structures: ``(P (k, 3), face (k,))``."""
    P, face, _ = closest_points_on_mesh(V, F, Q)
    return P, face


def _point_pairs(Q, prox, qi, ti, best, face):
    """Update ``best`` / ``face`` with the (query, triangle) pairs (ties: lowest face).

    ``qi`` sorted. Each query's triangle with the nearest centroid is tested
    first; then only the triangles whose bounding sphere comes within the best
    distance so far (every triangle that can be as close, ties included).
    """
    if len(qi) == 0:
        return
    T = prox.T
    dc = np.linalg.norm(Q[qi] - prox.centroid[ti], axis=1)
    head = np.flatnonzero(np.r_[True, qi[1:] != qi[:-1]])
    grp = np.repeat(np.arange(len(head)), np.diff(np.r_[head, len(qi)]))
    low = np.minimum.reduceat(dc, head)
    cand = np.flatnonzero(dc <= low[grp])
    cand = cand[np.r_[True, grp[cand[1:]] != grp[cand[:-1]]]]  # one per query
    _exact_pairs(Q, T, qi[cand], ti[cand], best, face)
    keep = dc - prox.radius[ti] * (1 + 1e-9) - prox.eps <= best[qi]
    keep[cand] = False
    _exact_pairs(Q, T, qi[keep], ti[keep], best, face)


def _exact_pairs(Q, T, qi, ti, best, face):
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
