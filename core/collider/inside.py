"""A collider's inside test (paper 3.1: pinched roots) and closest points.

:class:`Inside` owns what the inside test keeps per shape and offset: the
answers of grid cells no triangle touches (one traced centre per cell) and
which cells the triangles touch. :class:`Closest` owns the closest-point
index of the current shape.
"""

from __future__ import annotations

import numpy as np

from .. import tolerances as tol
from ..closest import closest_points_on_mesh
from ..proximity import mark_boxes
from ..rotations import apply, norm_bound
from ..rotations import dot as rot_dot
from .grid import cell_index
from .mesh import PerShape
from .shells import ShellFaces

#: Fixed, irrational-ish unit directions for the parity (inside) test.
#: Three votes make the test robust to a ray grazing an edge or a vertex.
PARITY_DIRS = np.array(
    [
        [0.5773502691896258, 0.5773502691896258, 0.5773502691896258],
        [-0.2672612419124244, 0.8017837257372732, -0.5345224838248488],
        [0.6246950475544243, -0.2498780190217697, -0.7399400733959437],
    ]
)
PARITY_DIRS /= np.linalg.norm(PARITY_DIRS, axis=1, keepdims=True)


def keep_recent(cache, version, most):
    """Make room in ``cache`` (key -> (shape version, value)) for one more entry:
    entries of other shapes go, then the oldest beyond ``most - 1``."""
    for k in [k for k, v in cache.items() if v[0] != version]:
        del cache[k]
    while len(cache) >= most:
        del cache[next(iter(cache))]


def cells(q, h, dims):
    """Flat cell index of points ``q`` (3, k) in a grid of cell size ``h``
    and ``dims`` cells (-1 off the grid)."""
    c = [cell_index(q[i] / h, dims[i]) for i in range(3)]
    ok = (c[0] >= 0) & (c[0] < dims[0]) & (c[1] >= 0) & (c[1] < dims[1])
    ok &= (c[2] >= 0) & (c[2] < dims[2])
    flat = (c[0] * dims[1] + c[1]) * dims[2] + c[2]
    return np.where(ok, flat, -1)


class Inside:
    """The parity inside test of a closed single-sided collider, with per-cell
    answers (see ``Collider.contains_grid``).

    Parameters
    ----------
    mesh : ColliderMesh
    pose : Pose
    grid : Occupancy
    shells : Shells
    deforming : bool or None
        The collider's hint that its vertices change every frame: the fine grid
        of per-shape answers is never built then.
    """

    def __init__(self, mesh, pose, grid, shells, deforming):
        self.mesh, self.pose, self.grid, self.shells = mesh, pose, grid, shells
        self.deforming = deforming
        # (keyed by shell: the offset, or (offset, allowance) for a fitted placement)
        self._seen = {}  # shell -> shape version of the last inside test
        self._answers = {}  # (fine?, shell) -> (shape version, answers): answers
        self._touched = {}  # shell -> (shape version, cells): surface_cells

    def contains_grid(self, p_wo, q, offset_wo=0.0) -> np.ndarray:
        """Inside test of world points ``p_wo`` (k, 3) given their grid coordinates
        ``q`` (3, k) (the collider detects pinches, ``k > 0``)."""
        k = len(p_wo)
        version = self.mesh.version
        allowance = self.pose.allowance
        shell = (offset_wo, allowance) if allowance else offset_wo
        # (per offset: the shells of several per-curve clearance levels, asked
        # once each per frame, are each a first call for their shape; a fitted
        # placement keeps its shape whatever the hint says)
        seen = self._seen
        static = seen.get(shell) == version and (not self.deforming or allowance > 0)
        if shell not in seen and len(seen) >= 2 * (tol.OFFSET_LEVELS + 3):
            seen.clear()
        seen[shell] = version
        if static:
            lo, h, dims = self.inside_grid()
            flat_cells = cells(q, h, dims)
            touched = self.surface_cells(offset_wo, shell).reshape(-1)
            trace = flat_cells < 0
            trace[flat_cells >= 0] = touched[flat_cells[flat_cells >= 0]]
        else:
            lo, h, dims, _, _ = self.grid.get()
            flat_cells = cells(q, h, dims)
            # near_surface pads by h + max_edge: a point it calls far has no
            # vertex within max_edge of its own cell: no triangle crosses it
            trace = self.grid.near_surface_grid(q, 0.0, offset_wo)
        inside = self.answers(static, shell, dims)
        out = np.zeros(k, bool)
        far = np.flatnonzero(~trace & (flat_cells >= 0))
        if len(far):
            flat = flat_cells[far]
            ins = inside.reshape(-1)
            val = ins[flat]
            unknown = np.unique(flat[val < 0])
            if len(unknown):
                u = np.stack(np.unravel_index(unknown, inside.shape), axis=1)
                centre_lo = lo + (u + 0.5) * h + self.mesh.center
                M = self.pose.M
                centre_wo = apply(M[:3, :3], centre_lo) + M[:3, 3]
                ins[unknown] = self.parity(centre_wo, offset_wo)
                val = ins[flat]
            out[far] = val > 0
        # off the grid only an offset shell can reach (the grid holds every
        # vertex): those are traced where it may, else outside
        traced = np.flatnonzero(trace)
        off = traced[flat_cells[traced] < 0]
        if len(off):
            near = self.grid.near_surface_grid(q[:, off], 0.0, offset_wo)
            traced = np.concatenate([traced[flat_cells[traced] >= 0], off[near]])
        if len(traced):
            out[traced] = self.parity(p_wo[traced], offset_wo)
        return out

    def inside_grid(self):
        """``(lo, h, dims)``: the occupancy grid subdivided ``tol.INSIDE_SUBDIV``
        times per axis, for the inside test's per-cell answers."""
        lo, h, dims, _, _ = self.grid.get()
        return lo, h / tol.INSIDE_SUBDIV, dims * tol.INSIDE_SUBDIV

    def answers(self, fine, shell, dims):
        """The inside test's per-cell answers (int8 grid of ``dims``: -1 unknown,
        0 outside, 1 inside) of ``shell`` (the offset, or (offset, allowance) for a
        fitted placement) on the fine or the coarse grid, kept per shape and
        shell (several offset levels of per-curve clearances each keep theirs)."""
        version = self.mesh.version
        key = (bool(fine), shell)
        hit = self._answers.get(key)
        if hit is not None and hit[0] == version and hit[1].shape == tuple(dims):
            return hit[1]
        keep_recent(self._answers, version, 2 * (tol.OFFSET_LEVELS + 3))
        inside = np.full(tuple(dims), -1, np.int8)
        self._answers[key] = (version, inside)
        return inside

    def surface_cells(self, offset_wo, shell=None):
        """(dims) bool grid: the cells of the fine grid that a triangle of the
        shell at ``offset_wo`` may touch (each triangle's bounding box, grown by
        how far the shell moves it; kept per shape and ``shell``, by default the
        offset)."""
        mesh = self.mesh
        version = mesh.version
        shell = offset_wo if shell is None else shell
        hit = self._touched.get(shell)
        if hit is not None and hit[0] == version:
            return hit[1]
        lo, h, dims = self.inside_grid()
        V = mesh.local_vertices()
        grow = mesh.margin * 1.01 + offset_wo * tol.OFFSET_MAX_STRETCH * 1.01 * norm_bound(
            self.pose.Minv[:3, :3]) + 1e-9 * h
        if self.pose.allowance:
            grow = grow + self.pose.allowance * tol.OFFSET_MAX_STRETCH * 1.01
        F = [np.ascontiguousarray(mesh.F[:, k]) for k in range(3)]
        ilo = np.empty((len(mesh.F), 3), np.int64)
        ihi = np.empty_like(ilo)
        for i in range(3):
            x = np.ascontiguousarray(V[:, i])
            c0, c1, c2 = x.take(F[0]), x.take(F[1]), x.take(F[2])
            mn = np.minimum(np.minimum(c0, c1), c2)
            mx = np.maximum(np.maximum(c0, c1), c2)
            ilo[:, i] = np.floor((mn - grow - lo[i]) / h)
            ihi[:, i] = np.floor((mx + grow - lo[i]) / h)
        touched = mark_boxes(ilo, ihi, dims)
        keep_recent(self._touched, version, tol.OFFSET_LEVELS + 3)
        self._touched[shell] = (version, touched)
        return touched

    def parity(self, p_wo, offset_wo):
        """Ray-parity inside test of world points (three votes).

        Each vote follows one fixed direction through the whole shell and
        counts back faces minus front faces crossed (the winding number: a
        point inside overlapping closed parts is inside); a collider of one
        closed part without an offset shell takes the first crossing's side
        instead (the same answer, one ray query). The first two votes are
        cast together, the third only where they disagree.
        """
        mesh = self.mesh
        k = len(p_wo)
        be, _ = self.shells.backend(offset_wo, whole=True)
        p_lo = self.pose.to_local(np.asarray(p_wo), np.zeros((k, 3)))[0]  # (float64)
        lo, hi = mesh.bounds()
        diag = float(np.linalg.norm(hi - lo)) or 1.0
        step = tol.PARITY_STEP_REL * diag
        shell = offset_wo * tol.OFFSET_MAX_STRETCH * norm_bound(self.pose.Minv[:3, :3])
        shell += self.pose.allowance * tol.OFFSET_MAX_STRETCH
        far = 4.0 * (diag + 2.0 * shell) + float(np.abs(p_lo).max(initial=0.0)) * 2.0

        def votes(points, dirs):
            """(n,) bool per (point, direction) row: more back faces crossed."""
            o = points.copy()
            d = dirs * far
            balance = np.zeros(len(o), np.int32)
            active = np.arange(len(o))
            for _ in range(tol.PARITY_MAX_HITS):
                if len(active) == 0:
                    break
                prim, t, ng = be.hit_details(o[active], d[active], 1.0, normals=True)
                hit = prim >= 0
                active, t, ng = active[hit], t[hit], ng[hit]
                facing = rot_dot(ng.astype(np.float64), dirs[active])
                balance[active] += np.where(facing < 0, -1, 1)
                o[active] += (t * far + step)[:, None] * dirs[active]
            return balance > 0

        def first_facing(points, dirs):
            """:func:`votes` for one closed, outward-wound surface (meshfix made it
            so; no offset shell): along a ray from a point, the crossings alternate
            back and front faces, so the balance is that of the first crossing: a
            back face (inside) or a front face or none (outside). One query per
            point instead of one per crossing."""
            prim, _, ng = be.hit_details(points, dirs * far, 1.0, normals=True)
            hit = np.flatnonzero(prim >= 0)
            out = np.zeros(len(points), bool)
            out[hit] = rot_dot(ng[hit].astype(np.float64), dirs[hit]) >= 0
            return out

        # (a fitted placement's allowance, a few float32 ulps as the clearance
        # margin, leaves one closed surface as the margin does)
        if offset_wo == 0 and mesh.repairs.parts == 1:
            votes = first_facing  # one closed surface, wound outward: its first hit decides
        two = votes(np.concatenate([p_lo, p_lo]), np.repeat(PARITY_DIRS[:2], k, axis=0))
        v1, v2 = two[:k], two[k:]
        out = v1 & v2
        split = np.flatnonzero(v1 != v2)
        if len(split):
            out[split] = votes(p_lo[split], np.broadcast_to(PARITY_DIRS[2], (len(split), 3)))
        return out


class Closest:
    """Closest points on a collider's mesh (un-inflated), with the search index of
    the current shape (built on first use, kept while the shape stays).

    Parameters
    ----------
    mesh : ColliderMesh
    """

    def __init__(self, mesh):
        self.mesh = mesh
        self._index = PerShape()  # [index] of the shape version (filled on first search)

    def nearest(self, q_lo):
        """``(points (k, 3), faces (k,))``: the closest point on the mesh to each
        local point ``q_lo`` (local space) and its face."""
        mesh = self.mesh
        index = self._index.get(mesh.version, lambda: [None])
        p_lo, face, index[0] = closest_points_on_mesh(mesh.local_vertices(), mesh.F, q_lo,
                                                      index[0])
        return p_lo, face

    def nearest_faces(self, q_lo):
        """The face nearest each local point ``q_lo`` (k, 3)."""
        return self.nearest(q_lo)[1]

    def closest_points(self, q_wo, pose, normals_world):
        """Closest point (world) on the mesh to each query ``q_wo`` (k, 3), placed by
        ``pose``, and its unit face normal (``normals_world(prim, ShellFaces)``: the
        shells' map of face normals to world)."""
        mesh = self.mesh
        k = len(q_wo)
        q_lo = pose.to_local(np.asarray(q_wo, np.float64), np.zeros((k, 3)))[0]
        p_lo, face = self.nearest(q_lo)
        M = pose.M
        p_wo = apply(M[:3, :3], p_lo + mesh.center) + M[:3, 3]
        m = len(mesh.F)
        return p_wo, normals_world(face, ShellFaces(np.arange(m), np.zeros(m, bool)))
