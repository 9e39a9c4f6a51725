"""A collider's vertex occupancy grid: can a ball touch the mesh?

:class:`Occupancy` owns a summed-area table of the cells of the collider's local
space that hold a used vertex, built once per shape. Every point of a
triangle is within ``max_edge`` (the longest edge) of one of its vertices, so
a ball that comes within ``max_edge`` of no occupied cell cannot touch the
mesh: an O(1) test per curve, much tighter than the bounding box. The inside
test reuses its cells (:mod:`.inside`).
"""

from __future__ import annotations

import threading

import numpy as np

from .. import tolerances as tol
from ..rotations import apply_soa, norm_bound


def cell_index(x, n):
    """Integer cell index ``floor(x)`` of an axis of ``n`` cells, clipped in float
    first to [-1, n + 1] (far-away points must not overflow the int cast)."""
    return np.floor(np.clip(x, -1, n + 1)).astype(np.int64)


class Occupancy:
    """The vertex occupancy grid of a collider's shape (see the module docstring).

    Parameters
    ----------
    mesh : ColliderMesh
    pose : Pose
        For the map from world space into the grid.
    """

    def __init__(self, mesh, pose):
        self.mesh, self.pose = mesh, pose
        self._grid = None  # (lo, h, dims, sat, max_edge) of shape version _key
        self._key = None
        # Built by whichever thread needs it first (the step's pinch test runs
        # on a ray thread).
        self._lock = threading.Lock()

    def get(self):
        """``(lo, h, dims, sat, max_edge)`` of the current shape: the grid's corner
        (local space), cell size, cell counts (3,), its summed-area table
        (dims + 1) int32 and the longest edge (padded for float32)."""
        version = self.mesh.version
        if self._key == version:
            return self._grid
        with self._lock:
            if self._key != version:
                self.build()
            return self._grid

    def build(self):
        """Compute :meth:`get`'s grid for the current shape (under its lock)."""
        mesh = self.mesh
        lo_g, hi_g = mesh.bounds()
        center = mesh.center
        lo, hi = lo_g - center, hi_g - center
        h = max(float((hi - lo).max()) / tol.OCCUPANCY_CELLS, 1e-30)
        dims = np.floor((hi - lo) / h).astype(np.int64) + 1
        flat = None
        for i, c in enumerate(mesh.components()):
            x = c.astype(np.float64)
            x -= center[i]
            x -= lo[i]
            x /= h
            ci = np.minimum(np.floor(x).astype(np.int64), dims[i] - 1)
            flat = ci if flat is None else flat * dims[i] + ci
        occ = (np.bincount(flat, minlength=int(dims.prod())) > 0).astype(np.int32)
        sat = np.zeros(dims + 1, np.int32)
        # int32 accumulators: cumsum would widen to int64 and back
        body = sat[1:, 1:, 1:]
        np.cumsum(occ.reshape(dims), axis=0, dtype=np.int32, out=body)
        np.cumsum(body, axis=1, dtype=np.int32, out=body)
        np.cumsum(body, axis=2, dtype=np.int32, out=body)
        a, b = mesh.edges()
        sq = None
        for c in (mesh.V[:, i] for i in range(3)):
            c = np.ascontiguousarray(c)
            d = c.take(a)
            d -= c.take(b)
            d *= d
            sq = d if sq is None else sq + d
        max_edge = float(sq.max())
        # float32 edges: pad by a relative ulp margin to stay conservative
        max_edge = float(np.sqrt(max_edge)) * (1 + 1e-5)
        self._grid = (lo, h, dims, sat, max_edge)
        self._key = mesh.version  # last: readers check it without the lock

    def grid_coords(self, p_wo):
        """World points given as components (3, k) in the grid's frame (local space
        minus the grid's corner), as components (3, k)."""
        lo = self.get()[0]
        A, b = self.pose.local_map()
        q = apply_soa(A, np.asarray(p_wo, np.float64))
        for i in range(3):
            q[i] += b[i]
            q[i] -= lo[i]
        return q

    def near_surface_grid(self, q, radius_wo, offset_wo=0.0) -> np.ndarray:
        """Can balls centred at grid coordinates ``q`` (3, k) of radius
        ``radius_wo`` (world) touch the shell at ``offset_wo``? False only where
        they certainly miss it."""
        k = q.shape[1]
        lo, h, dims, sat, max_edge = self.get()
        A, b = self.pose.local_map()
        stretch = norm_bound(A)  # at least the largest local length of a world unit
        reach = np.asarray(radius_wo, np.float64) + offset_wo * tol.OFFSET_MAX_STRETCH
        r = reach * stretch + max_edge + h
        if self.pose.allowance:  # a fitted placement's shells lie this much farther out
            r = r + self.pose.allowance * tol.OFFSET_MAX_STRETCH * 1.01
        r = np.broadcast_to(r, (k,))
        # Summed-area table over the cells the ball's box covers, by flat
        # index (one gather per corner).
        outside = np.zeros(k, bool)
        corner = []
        step = (sat.shape[1] * sat.shape[2], sat.shape[2], 1)
        for i in range(3):
            i0 = cell_index((q[i] - r) / h, dims[i])
            i1 = cell_index((q[i] + r) / h, dims[i])
            outside |= (i1 < 0) | (i0 >= dims[i])
            np.clip(i0, 0, dims[i] - 1, out=i0)
            np.clip(i1, 0, dims[i] - 1, out=i1)
            i1 += 1
            i0 *= step[i]
            i1 *= step[i]
            corner.append((i0, i1))
        (x0, x1), (y0, y1), (z0, z1) = corner
        flat = sat.reshape(-1)
        x0y0, x0y1, x1y0, x1y1 = x0 + y0, x0 + y1, x1 + y0, x1 + y1
        total = (
            flat[x1y1 + z1]
            - flat[x0y1 + z1]
            - flat[x1y0 + z1]
            - flat[x1y1 + z0]
            + flat[x0y0 + z1]
            + flat[x0y1 + z0]
            + flat[x1y0 + z0]
            - flat[x0y0 + z0]
        )
        return (total > 0) & ~outside
