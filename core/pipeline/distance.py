"""Fur Collider Distance (paper section 4).

For every CV of (collision-free) curves: the closest distance of that CV's
segments to the colliders, never above the true distance (what the Region
of Influence needs to stay collision free).

By default (the per-frame path) the distance comes from a **node field** of
each collider (:class:`_NodeField`): exact distances at the nodes of a grid
within one cell of the mesh, a Euclidean transform beyond, and 1-Lipschitz
bounds between nodes. It is at most ``tolerances.DISTANCE_FIELD_CELLS``
cells below the true distance, the cell being the collider's median
triangle size, halved until it is at most half the curves' median segment
length. Built once per collider shape (about a second for 130,000
triangles), then a few gathers per segment.

``exact=True`` (and colliders whose field would be too big) use the **exact
search**, per collider, in its own space for a rigid ``Collider``:

1. a lower bound of every segment from a windowed distance field of the
   mesh's occupied cells (two samples per segment); with ``max_distance``,
   segments whose bound reaches the cap are done;
2. capped: a coarse triangle grid with a *slab* per cell (the range of its
   triangles along their mean normal) proves most of the remaining
   segments clear of the cap, cell by cell, without touching triangles;
3. an expanding exact search over a fine triangle grid (radius capped):
   cells are culled by distance and slab, (segment, triangle) pairs by a
   plane bound, after one exact test of the nearest-centroid triangle;
   the survivors get the exact segment-triangle distance.

The fields and grids of a :class:`~core.Collider` are cached on it through
``Collider.derived`` (keyed on its vertices; a similarity ``matrix`` moves
the queries, not the mesh), so a rigid collider builds them once; ``(V, F)``
pairs are indexed per call. The method and its field depend only on the
inputs, never on earlier calls: the same input gives the same output.
"""

from __future__ import annotations

import numpy as np

from .. import rotations as rot
from .. import tolerances as tol
from ..closest import closest_on_triangles
from ..collider import Collider
from ..curves import check_curves, layout, row_norm
from ..errors import InputError
from ..mesh import check_surface
from ..proximity import TriangleGrid as _TriGrid
from ..proximity import box_cells as _box_cells
from ..proximity import plane_crosses_cells as _plane_crosses_cells
from ..proximity import planes as _planes

#: Sub-pieces of a segment in the distance-field lower bound.
_FAR_PIECES = 8
#: Cells along the longest side of the lower-bound distance field, at most.
_FIELD_DIMS = 64
#: Extra distance fields over the mesh's box grown by these multiples of its size.
_FIELD_PADS = (0.5, 2.0)
#: Cell entries (segment, cell) per chunk of the exact search.
_CHUNK_CELLS = 1_000_000
#: Cells along the longest side of the near lower-bound field (over the mesh's box).
_NEAR_DIMS = 128
#: The near field holds distances up to this many cells (beyond: "at least that").
_NEAR_WINDOW = 8
#: Sub-pieces of a segment in the first (cheap) lower bound.
_NEAR_PIECES = 2
#: Pair (segment, triangle) entries per chunk of the exact search.
_CHUNK_PAIRS = 400_000
#: Node field windows (cells beyond its band) are multiples of this, at most _NODE_WINDOW_MAX.
_NODE_WINDOW_STEP = 8
_NODE_WINDOW_MAX = 32
#: Segments are bounded by the node field in pieces at most this many cells long...
_NODE_PIECE = 2.0
#: ...in at most this many pieces.
_NODE_MAX_PIECES = 64


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


class LowerBoundField:
    """Conservative distance field of a mesh: a lower bound of the distance anywhere.

    Every cell touched by a triangle's bounding box is *occupied*. A point
    in cell ``c`` and a mesh point in occupied cell ``c'`` are at least
    ``(|c_a - c'_a| - 1)+ * h`` apart along every axis ``a``, so
    ``D2[c] = min_c' sum_a ((|c_a - c'_a| - 1)+)^2`` (a separable min-plus
    transform along x, y and z) gives the lower bound ``sqrt(D2[c]) * h``
    (at least as tight as centre distance minus a cell diagonal). With a
    ``window`` of ``w`` cells, only distances up to ``w`` cells are kept
    (beyond, ``w`` cells is the bound). A point ``q`` outside
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
        cell, owner = _box_cells(ilo, ihi)
        cell = cell[_plane_crosses_cells(_planes(T), cell, owner, self.glo, h)]
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
            self.D = np.sqrt(np.minimum(D2, np.float32(window**2)))

    def __call__(self, q):
        """(k,) lower bounds of the distance of points ``q`` (k, 3) to the mesh."""
        qc = np.clip(q, self.glo, self.ghi)
        out = np.linalg.norm(q - qc, axis=1)
        c = np.clip(np.floor((qc - self.glo) / self.h).astype(np.int64), 0, self.dims - 1)
        inside = self.D[c[:, 0], c[:, 1], c[:, 2]] * self.h
        # p in the box and q' the projection of q: the angle at q' is >= 90 degrees
        return np.sqrt(out**2 + inside.astype(np.float64) ** 2)


class _NodeField:
    """Lower bounds of the distance to a mesh from exact distances at grid nodes.

    A grid of spacing ``h`` over the mesh's box grown by ``w + 2`` cells.
    Nodes within ``h`` of the mesh (the *band*) hold their exact distance
    (every such node is a corner of a cell the mesh crosses, and its closest
    triangle is registered in one of its 8 cells). Any other node ``x`` is
    farther than ``0.866 h``, and the straight path to its closest mesh point
    crosses the level set ``d = 0.134 h`` within ``0.866 h`` of a band node,
    so ``d(x) >= (E(x) - sqrt(3) + 1) h``, ``E`` the Euclidean distance (in
    cells) to the nearest band node: a windowed separable transform, exact
    up to ``w`` cells, clamped beyond. Distances are stored as float32
    rounded down, so every node value is a lower bound.

    A query piece (a part of a segment at most two cells long, ends ``a``,
    ``b``) is bounded by the 8 corners ``c`` of its cell: ``d(y) >= D(c) -
    |y - c|`` for every point ``y`` (1-Lipschitz), so its distance is at
    least ``max_c D(c) - max(|a - c|, |b - c|)``. The bound is at most
    ``2 * (sqrt(3) / 2 + 1 / 2) h`` below the truth in the band, plus
    ``sqrt(3) h`` beyond it (``DISTANCE_FIELD_CELLS`` in core.tolerances).
    """

    def __init__(self, T, lo, hi, h, w):
        self.h = h = float(h)
        self.w = w
        pad = (w + 2) * h
        self.glo = lo - pad
        self.ghi = hi + pad
        self.dims = dims = np.floor((self.ghi - self.glo) / h).astype(np.int64) + 2
        self.box = (lo, hi)
        self.reach = (w + 1 - np.sqrt(3.0)) * h  # node values are at most this
        # cells the mesh crosses (box cells of each triangle its plane meets)
        ilo = np.floor((T.min(1) - self.glo) / h).astype(np.int64)
        ihi = np.floor((T.max(1) - self.glo) / h).astype(np.int64)
        cell, owner = _box_cells(ilo, ihi)
        planes = _planes(T)
        keep = _plane_crosses_cells(planes, cell, owner, self.glo, h)
        cell, owner = cell[keep], owner[keep]
        ckey = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
        corner = np.array([(i * dims[1] + j) * dims[2] + k
                           for i in (0, 1) for j in (0, 1) for k in (0, 1)])
        # (corner node, triangle of one of its cells) pairs, deduplicated
        m = len(T)
        pair = np.unique((ckey[:, None] + corner[None]).ravel() * m + np.repeat(owner, 8))
        nk, tri = pair // m, pair % m
        q = self.glo + np.stack(np.unravel_index(nk, tuple(dims)), 1) * h
        # only triangles whose plane is within h of the node can put it in the band
        n, c, _ = planes
        nl = np.linalg.norm(n, axis=1)
        off = np.abs(np.einsum("ij,ij->i", n[tri], q) - c[tri])
        near = off <= (h * (1 + 1e-9) + 1e-12 * self.glo.__abs__().max()) * nl[tri]
        near |= nl[tri] == 0
        nk, tri, q = nk[near], tri[near], q[near]
        d = np.empty(len(q))
        for a in range(0, len(q), _CHUNK_PAIRS):
            sl = slice(a, a + _CHUNK_PAIRS)
            t = tri[sl]
            d[sl] = np.linalg.norm(
                closest_on_triangles(q[sl], T[t, 0], T[t, 1], T[t, 2]) - q[sl], axis=1)
        first = np.flatnonzero(np.r_[True, nk[1:] != nk[:-1]])
        dn = np.minimum.reduceat(d, first)
        nodes = nk[first]
        band = dn <= h  # exact: the closest triangle is within the node's 8 cells
        E2 = np.full(tuple(dims), np.float32(np.inf), np.float32)
        E2.reshape(-1)[nodes[band]] = 0.0
        for axis in range(3):
            E2 = _minplus_window(E2, axis, w, offset=0)
        E = np.sqrt(np.minimum(E2, np.float32(w * w)), out=E2).reshape(-1)
        D = np.maximum((E + np.float32(1 - np.sqrt(3.0))) * np.float32(h),
                       np.float32(0.866 * h))
        d32 = dn.astype(np.float32)
        d32 = np.where(d32 > dn, np.nextafter(d32, np.float32(0)), d32)  # round down
        D[nodes] = np.where(band, d32, np.maximum(D[nodes], np.float32(h)))
        self.D = D
        self.nbytes = D.nbytes

    def lower_bound(self, A, B):
        """(S,) lower bounds of the distance of segments ``[A, B]`` (the mesh's space)."""
        h = self.h
        S = len(A)
        # component arrays in cell units from the grid's corner
        a = [(A[:, i] - self.glo[i]) / h for i in range(3)]
        d = [(B[:, i] - A[:, i]) / h for i in range(3)]
        L = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        # pieces per segment: a function of the segment alone (never of the others); a
        # very long segment (over _NODE_MAX_PIECES pieces) gets longer pieces: a looser
        # bound, still a bound
        m = np.clip(np.ceil(L / _NODE_PIECE), 1, _NODE_MAX_PIECES).astype(np.int64)
        out = np.empty(S)
        for n in np.unique(m):  # segments cut in n pieces, together
            sel = None if (m == n).all() else np.flatnonzero(m == n)
            an = a if sel is None else [x[sel] for x in a]
            dn = d if sel is None else [x[sel] for x in d]
            best = None
            for k in range(int(n)):
                lo = [an[i] + dn[i] * (k / n) for i in range(3)]
                hi = [an[i] + dn[i] * ((k + 1) / n) for i in range(3)]
                p = self._pieces(lo, hi)
                best = p if best is None else np.minimum(best, p, out=best)
            if sel is None:
                out[:] = best
            else:
                out[sel] = best
        return np.maximum(out, 0.0)

    def _pieces(self, a, b):
        """Lower bounds of pieces ``[a, b]`` (component arrays, cell units from the grid's
        corner), from the 8 nodes of the cell of their midpoints."""
        h, dims = self.h, self.dims
        base = None
        sq = []
        gap2 = None
        for i in range(3):
            c = np.floor(0.5 * (a[i] + b[i]))
            np.clip(c, 0, dims[i] - 2, out=c)
            ra, rb = a[i] - c, b[i] - c
            sq.append(((ra * ra, rb * rb), ((ra - 1) ** 2, (rb - 1) ** 2)))
            ci = c.astype(np.int64)
            base = ci if base is None else base * dims[i] + ci
            # a piece is at least as far from the mesh as its box from the mesh's box
            # (what bounds the pieces outside the grid)
            g = np.maximum(np.maximum((self.box[0][i] - self.glo[i]) / h - np.maximum(a[i], b[i]),
                                      np.minimum(a[i], b[i]) - (self.box[1][i] - self.glo[i]) / h),
                           0.0)
            gap2 = g * g if gap2 is None else gap2 + g * g
        best = np.sqrt(gap2) * h
        for i in (0, 1):
            for j in (0, 1):
                for k in (0, 1):
                    da = sq[0][i][0] + sq[1][j][0] + sq[2][k][0]
                    db = sq[0][i][1] + sq[1][j][1] + sq[2][k][1]
                    np.maximum(da, db, out=da)
                    np.sqrt(da, out=da)
                    da *= -h
                    da += self.D.take(base + ((i * dims[1] + j) * dims[2] + k))
                    np.maximum(best, da, out=best)
        return best


def _minplus(D2):
    """``out[i] = min_j D2[j] + ((|i - j| - 1)+)^2`` along axis 0 (chunked over the others)."""
    n = D2.shape[0]
    sq = np.maximum(np.abs(np.arange(n)[:, None] - np.arange(n)[None, :]) - 1, 0)
    sq = sq.astype(np.float64) ** 2
    flat = D2.reshape(n, -1)
    out = np.empty_like(flat)
    step = max(1, 4_000_000 // (n * n))
    for a in range(0, flat.shape[1], step):
        out[:, a:a + step] = (flat[None, :, a:a + step] + sq[:, :, None]).min(1)
    return out.reshape(D2.shape)


def _minplus_window(D2, axis, w, offset=1):
    """``out[i] = min_{|i - j| <= w} D2[j] + ((|i - j| - offset)+)^2`` along ``axis``.

    Overestimates only values above ``w^2``: the caller clamps to ``w^2``
    (a cell outside the window costs at least that).
    """
    out = D2.copy()
    n = D2.shape[axis]
    for s in range(1, min(w, n - 1) + 1):
        a = [slice(None)] * 3
        b = [slice(None)] * 3
        a[axis], b[axis] = slice(s, None), slice(None, -s)
        s2 = np.float32(max(s - offset, 0) ** 2)
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
        n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
        nl = np.linalg.norm(n, axis=1, keepdims=True)
        self.normal = np.where(nl > 0, n / np.where(nl > 0, nl, 1.0), 0.0)
        # unit outward in-plane normals of the edges (v0v1, v1v2, v2v0) and offsets
        e = np.roll(T, -1, axis=1) - T
        m = np.cross(e, self.normal[:, None, :])
        ml = np.linalg.norm(m, axis=2, keepdims=True)
        self.edge_n = np.where(ml > 0, m / np.where(ml > 0, ml, 1.0), 0.0)
        self.edge_c = np.einsum("mki,mki->mk", self.edge_n, T)
        self._grids = {}
        self._fields = {}
        self._node_fields = {}

    def node_field(self, h, w):
        """:class:`_NodeField` of spacing ``h`` and window ``w`` (the last two kept)."""
        f = self._node_fields.get((h, w))
        if f is None:
            if len(self._node_fields) >= 2:
                self._node_fields.pop(next(iter(self._node_fields)))
            f = self._node_fields[(h, w)] = _NodeField(self.T, self.lo, self.hi, h, w)
        return f

    def node_plan(self, seg_len, cap):
        """``(h, w)`` of the node field for segments of median length ``seg_len``
        capped at ``cap`` (None: no cap), or None when the field would be too big.

        ``h`` is the median triangle size, halved until it is at most half the
        segment length; ``w`` covers the cap with 6 cells to spare (rounded up to
        ``_NODE_WINDOW_STEP``), at most ``_NODE_WINDOW_MAX``. A pure function of
        the mesh and the query, so results never depend on earlier calls.
        """
        h = self.tri_h
        if seg_len > 0:
            h /= 2.0 ** max(0, int(np.ceil(np.log2(self.tri_h / (0.5 * seg_len)) - 1e-9)))
        w = _NODE_WINDOW_MAX
        if cap is not None and np.isfinite(cap):
            w = min(w, _NODE_WINDOW_STEP * int(np.ceil((cap / h + 6) / _NODE_WINDOW_STEP)))
        dims = np.floor((self.hi - self.lo + 2 * (w + 2) * h) / h) + 2
        if float(np.prod(dims)) > tol.DISTANCE_NODE_MAX:
            return None
        return h, w

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
                f = LowerBoundField(self.T, 0.0, dims=dims, window=_NEAR_WINDOW)
            else:
                f = LowerBoundField(self.T, self.tri_h, box)
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
        reach = _NEAR_WINDOW * near.h
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
    """Smallest singular value ``s`` of ``M3`` if it is a similarity, else None.

    ``|M3 x| >= s |x|``: a local distance times ``s`` never exceeds the
    world distance, and is within the matrix's (tiny) anisotropy of it.
    """
    sv = np.linalg.svd(M3, compute_uv=False)
    if sv[-1] > 0 and sv[0] <= sv[-1] * (1 + tol.SIMILARITY_REL):
        return float(sv[-1])
    return None


def _collider_index(col):
    """``(index, M3, t, scale)``: ``col``'s mesh index and the map from world to its space.

    A world point ``x`` is ``(x - t) @ inv(M3).T`` in the index's space and a
    distance there times ``scale`` is the world distance (exactly for a
    similarity; for one up to float32 rounding, a lower bound within that
    rounding, relative 1e-5 at most). Rigid (similarity) transforms keep
    the collider's own space, so the index survives motion and is cached on
    the Collider until its vertices change; other transforms index the
    world mesh (cached for that matrix only).
    """
    M = col.matrix
    M3, t = M[:3, :3], M[:3, 3]
    s = _similarity(M3)
    key = (col.version, None if s is not None else M.tobytes())

    def build():
        V = col.vertices.astype(np.float64)
        if s is None:
            V = V @ M3.T + t
        return _MeshIndex(V, col.faces.astype(np.int64))

    index = col.derived("distance_index", key, build)
    if s is None:
        return index, np.eye(3), np.zeros(3), 1.0
    return index, M3, t, s


def segment_mesh_distance(A, B, V, F, max_distance=None):
    """Distance of each segment ``[A, B]`` to the triangle mesh ``(V, F)``.

    An expanding search over a grid of the triangles finds the exact
    distance of segments near the mesh; segments whose search box would
    span more than ``tolerances.DISTANCE_MAX_CELLS`` grid cells (far from the mesh compared to
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
    return _exact_distance(_MeshIndex(np.asarray(V, np.float64), np.asarray(F)), A, B,
                           np.inf if cap is None else cap)


def _segment_distance(ix, A, B, cap, exact=False):
    """``(dist, exact)`` of segments ``[A, B]`` (the index's space), capped at ``cap``.

    ``cap`` is a scalar or an (S,) array (``inf``: no cap). The node field
    (:class:`_NodeField`) unless ``exact`` or the field would be too big for
    the mesh; else the exact search (:func:`_exact_distance`).
    """
    if exact or len(A) == 0:
        return _exact_distance(ix, A, B, cap)
    capv = np.broadcast_to(np.asarray(cap, np.float64), (len(A),))
    finite = np.isfinite(capv).all()
    plan = ix.node_plan(float(np.median(row_norm(B - A))),
                        float(capv.max()) if finite else None)
    if plan is None:
        return _exact_distance(ix, A, B, cap)
    nf = ix.node_field(*plan)
    # segments whose box is at least their cap from the mesh's box are done (a small
    # collider next to a big groom: most segments)
    gap = np.maximum(np.maximum(ix.lo - np.maximum(A, B), np.minimum(A, B) - ix.hi), 0.0)
    lb = np.sqrt(np.einsum("ij,ij->i", gap, gap))
    near = np.flatnonzero(lb < capv)
    if len(near) == len(A):
        lb = nf.lower_bound(A, B)
    elif len(near):
        lb[near] = nf.lower_bound(A[near], B[near])
    # segments the field cannot bound up to their cap: the coarse fields too
    far = np.flatnonzero((lb < capv) & (lb >= nf.reach - 3 * nf.h))
    if len(far):
        lb[far] = np.maximum(lb[far], ix.lower_bound(A[far], B[far], _FAR_PIECES))
    lb = np.maximum(lb - ix.eps, 0.0)
    return np.minimum(lb, capv), lb >= capv


def _exact_distance(ix, A, B, cap):
    """``(dist, exact)`` by the exact search: exact near the mesh, lower bounds far.

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
    # capped: a coarse grid's cells and slabs prove most of the rest clear of the cap
    i = np.flatnonzero(~exact & np.isfinite(capv))
    if len(i):
        gc = ix.grid(max(g.h, (float(np.median(seg)) + 2 * float(capv[i].max())) / 2.5))
        clear = ~_may_reach(A[i], B[i], capv[i], gc, ix.eps)
        dist[i[clear]] = capv[i[clear]]
        exact[i[clear]] = True
    # expanding exact search: radius rho, done where the best found is <= rho
    rho = np.minimum(lb + g.h, capv)
    best = np.full(S, np.inf)
    far = np.zeros(S, bool)
    todo = np.flatnonzero(~exact)
    while len(todo):
        r = rho[todo]
        ilo = np.clip(np.floor((np.minimum(A[todo], B[todo]) - r[:, None] - g.glo) / g.h),
                      -1, g.dims).astype(np.int64)
        ihi = np.clip(np.floor((np.maximum(A[todo], B[todo]) + r[:, None] - g.glo) / g.h),
                      -1, g.dims).astype(np.int64)
        ok = (ihi - ilo + 1).prod(1) <= tol.DISTANCE_MAX_CELLS
        far[todo[~ok]] = True
        todo, ilo, ihi = todo[ok], ilo[ok], ihi[ok]
        _search(A, B, ix, g, todo, ilo, ihi, rho, capv, best)
        # every triangle within rho of a segment is a candidate: best <= rho is exact,
        # and a search at the cap that found nothing closer proves the cap
        found = best[todo] <= rho[todo]
        done = found | (rho[todo] >= capv[todo])
        exact[todo[done]] = True
        dist[todo[done]] = np.where(found[done], best[todo[done]], capv[todo[done]])
        todo = todo[~done]
        # next radius: an upper bound of the distance when one is known, else a bit more
        nxt = best[todo]
        grow = np.minimum(2 * rho[todo], rho[todo] + 2 * g.h)
        rho[todo] = np.minimum(np.where(np.isfinite(nxt), nxt, grow), capv[todo])
    if far.any():
        # far segments: the finer lower bound (more pieces, coarse fields included)
        i = np.flatnonzero(far)
        lb8 = ix.lower_bound(A[i], B[i], _FAR_PIECES)
        dist[i] = np.minimum(np.maximum(dist[i], lb8), capv[i])
        exact[i] = lb8 >= capv[i]
    return dist, exact


def _may_reach(A, B, rho, g, eps):
    """(S,) bool: some cell of grid ``g`` within ``rho`` of the segment, slab included.

    False proves that no triangle is within ``rho`` (as in :func:`_search`).
    """
    out = np.zeros(len(A), bool)
    if len(g.big):
        out[:] = True  # big triangles are in no cell
        return out
    ilo = np.clip(np.floor((np.minimum(A, B) - rho[:, None] - g.glo) / g.h),
                  -1, g.dims).astype(np.int64)
    ihi = np.clip(np.floor((np.maximum(A, B) + rho[:, None] - g.glo) / g.h),
                  -1, g.dims).astype(np.int64)
    ncell = (ihi - ilo + 1).prod(1)
    csum = np.cumsum(ncell)
    start = 0
    while start < len(A):
        base = csum[start - 1] if start else 0
        stop = max(int(np.searchsorted(csum, base + _CHUNK_CELLS, "right")), start + 1)
        cell, owner = _box_cells(ilo[start:stop], ihi[start:stop])
        owner += start
        start = stop
        keys = g.key(cell)
        if g.start is not None:
            lo = g.start[keys]
            occ = g.start[keys + 1] > lo
        else:
            lo = np.searchsorted(g.keys, keys, "left")
            occ = np.searchsorted(g.keys, keys, "right") > lo
        cell, owner, lo = cell[occ], owner[occ], lo[occ]
        ok = _cell_bound(A[owner], B[owner], g, cell, lo) <= rho[owner] + eps
        out[owner[ok]] = True
    return out


def _cell_bound(a, b, g, cell, lo):
    """Lower bound of the distance of segments ``[a, b]`` to the triangles of ``cell``.

    The closest point of the closest triangle lies in one of its cells, in
    that cell's box and slab (see :meth:`_TriGrid._slabs`): at least the
    slab gap along the slab normal ``n`` and, across ``n``, the distance of
    the cell centre to the projected segment minus half a cell diagonal
    (each minimized over the segment separately).
    """
    nc = g.slab_n[lo]
    centre = g.glo + (cell + 0.5) * g.h
    ha, hb = _dot(nc, a), _dot(nc, b)
    gap = np.maximum(np.minimum(ha, hb) - g.slab_b[lo], g.slab_a[lo] - np.maximum(ha, hb))
    hc = _dot(nc, centre)
    pa = a - centre - nc * (ha - hc)[:, None]
    pb = b - centre - nc * (hb - hc)[:, None]
    lat = np.maximum(_point_segment(np.zeros_like(pa), pa, pb) - 0.5 * np.sqrt(3.0) * g.h, 0.0)
    gap = np.maximum(gap, 0.0)
    return np.sqrt(gap * gap + lat * lat) * (1 - 1e-9)


def _search(A, B, ix, g, idx, ilo, ihi, rho, cap, best):
    """Exact distances of segments ``idx`` to the triangles within ``rho`` of them.

    Updates ``best`` (smallest exact distance found). Cells farther than
    ``rho`` from the segment are dropped, then the (segment, triangle)
    pairs are culled by :func:`_pairs`.
    """
    if len(idx) == 0:
        return
    ncell = (ihi - ilo + 1).prod(1)
    csum = np.cumsum(ncell)
    T = ix.T
    m = len(T)
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
        # occupied cells whose slab and box can be within rho of the segment
        keep = n > 0
        sk = si[keep]
        keep[keep] = _cell_bound(A[sk], B[sk], g, cell[keep], lo[keep]) <= rho[sk] + ix.eps
        lo, n, si = lo[keep], n[keep], si[keep]
        tot = int(n.sum())
        ti = g.tris[np.repeat(lo - (np.cumsum(n) - n), n) + np.arange(tot)]
        si = np.repeat(si, n)
        if len(g.big):
            si = np.concatenate([si, np.repeat(part, len(g.big))])
            ti = np.concatenate([ti, np.tile(g.big, len(part))])
        # a triangle is in several cells: one pair each (sorted by segment)
        pair = np.unique(si * m + ti)
        for a in range(0, len(pair), _CHUNK_PAIRS):
            p = pair[a:a + _CHUNK_PAIRS]
            _pairs(A, B, ix, T, p // m, p % m, rho, cap, best)


def _pairs(A, B, ix, T, si, ti, rho, cap, best):
    """Exact distances of the (segment, triangle) pairs that can matter, into ``best``.

    ``si`` sorted. Each segment's triangle with the nearest centroid is
    tested exactly first (unless the search is at the cap and its bounding
    sphere is beyond the cap), which gives an upper bound close to the
    distance; the other pairs are tested only if their bounding sphere,
    then their :func:`_plane_bound`, are within ``min(rho, best)``.
    Culling never drops the closest triangle when it is within ``rho``
    (the bounds have a hair of slack against rounding).
    """
    if len(si) == 0:
        return
    a, b = A[si], B[si]
    dc = _point_segment(ix.centroid[ti], a, b)
    sphere = dc - ix.radius[ti] * (1 + 1e-9) - ix.eps  # bounding-sphere bound
    head = np.flatnonzero(np.r_[True, si[1:] != si[:-1]])
    grp = np.repeat(np.arange(len(head)), np.diff(np.r_[head, len(si)]))
    low = np.minimum.reduceat(dc, head)
    cand = np.flatnonzero(dc <= low[grp])
    cand = cand[np.r_[True, grp[cand[1:]] != grp[cand[:-1]]]]  # one per segment
    first = np.zeros(len(si), bool)
    first[cand] = (sphere[cand] <= rho[si[cand]]) | (rho[si[cand]] < cap[si[cand]])
    _exact_pairs(A, B, T, si[first], ti[first], best)
    bound = np.minimum(rho[si], best[si])
    keep = np.flatnonzero(~first & (sphere <= bound))
    keep = keep[_plane_bound(a[keep], b[keep], ix, ti[keep]) <= bound[keep]]
    _exact_pairs(A, B, T, si[keep], ti[keep], best)


def _exact_pairs(A, B, T, si, ti, best):
    if len(si) == 0:
        return
    d = segment_triangle_distance(A[si], B[si], T[ti, 0], T[ti, 1], T[ti, 2])
    _min_into(best, si, d)


def _plane_bound(a, b, ix, ti):
    """Lower bound of the distance of segments ``[a, b]`` to triangles ``ti``.

    With the triangle's unit normal ``n``, centroid ``c`` and radius ``r``:
    a point ``q`` of the segment and ``p`` of the triangle are apart by at
    least their height difference over the plane (0 if the segment crosses
    it) and, in the plane, at least ``|q' - c| - r`` (``q'`` the projection)
    and at least the distance of both ends outside one edge's line; each
    minimized over the segment separately.
    """
    n = ix.normal[ti]
    c = ix.centroid[ti]
    ua, ub = a - c, b - c
    ha, hb = _dot(n, ua), _dot(n, ub)
    h = np.where(ha * hb <= 0, 0.0, np.minimum(np.abs(ha), np.abs(hb)))
    pa = ua - n * ha[:, None]
    pb = pa - (ub - n * hb[:, None])  # pa - pb'
    L2 = _dot(pb, pb)
    t = np.clip(_dot(pa, pb) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
    lat = np.linalg.norm(pa - pb * t[:, None], axis=1)
    lat = np.maximum(lat - ix.radius[ti] * (1 + 1e-9), 0.0)
    # separating edges: in the plane, the segment is at least as far from the
    # triangle as both its ends are outside one edge's line
    en, ec = ix.edge_n[ti], ix.edge_c[ti]
    sa = np.einsum("kei,ki->ke", en, a) - ec
    sb = np.einsum("kei,ki->ke", en, b) - ec
    lat = np.maximum(lat, np.minimum(sa, sb).max(1) * (1 - 1e-9))
    return np.sqrt(h * h + lat * lat) * (1 - 1e-9) - ix.eps


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


def collider_distance(points, offsets, colliders, return_exact=False, max_distance=None,
                      exact=False):
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
        colliders are ignored. Pass Colliders for per-frame use: their
        search structures are cached on them while their vertices do not
        change (a rigid, rotation + uniform scale + translation ``matrix``
        can change freely); ``(V, F)`` pairs rebuild them every call.
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
        longer than ``cap``. Capped values count as exact. ``None`` or
        ``inf``: no cap.
    exact : bool, default False
        Use the exact search (slow on large colliders: about a second per
        frame for 7,500 guides at a 130,000-triangle collider) instead of the
        node field (see Returns).

    Returns
    -------
    distance : (P,) ndarray of float64
        ``inf`` when there is no collider; never above the true distance (so
        the Region of Influence stays safe), and at most
        ``tolerances.DISTANCE_FIELD_CELLS`` cells of the collider's distance
        field below it: the cell ``h`` is the collider's median triangle size,
        halved until it is at most half the curves' median segment length
        (about 1.3 cells below on average). A collider whose field would be
        too big for that (``tolerances.DISTANCE_NODE_MAX`` nodes: a huge collider next to short
        curves) and ``exact=True`` use the exact search instead: exact (float64
        rounding) for segments near a collider (within a few triangle sizes
        or segment lengths), a lower bound from coarse distance fields
        farther away (within a few percent of the collider's size). With
        ``max_distance``: at most ``max_distance``.
    exact : (P,) ndarray of bool
        Only with ``return_exact``: true where the distance is known to be
        exact: ``min(true distance, max_distance)`` where the cap is proven;
        with the exact search, also where it found the distance.

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
            M = np.eye(4)
            M[:3, :3] = M3
            Minv = rot.inv_affine(M)[:3, :3]  # closed form: no LAPACK per frame
            Al, Bl = rot.apply(Minv, A - t), rot.apply(Minv, B - t)
        # the best distance so far caps this collider's search too
        d, ex = _segment_distance(ix, Al, Bl, seg_d / scale, exact)
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
