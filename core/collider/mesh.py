"""A collider's triangles, checked and repaired, and its shape.

:class:`ColliderMesh` owns what a collider *is*, whatever its placement: the
faces (degenerate ones dropped, welded seams, duplicated faces and windings
repaired by :mod:`core.meshfix`), their topology (used vertices, corners by
vertex, unique edges, rim faces: computed once), the vertices in the
collider's own space with their shape version, centre and bounds, and the
normals of each shape. The other parts of a collider read it; only
:meth:`ColliderMesh.set_shape` changes it.
"""

from __future__ import annotations

import numpy as np

from .. import tolerances as tol
from ..errors import ColliderError
from ..mesh import degenerate_faces
from ..meshfix import Tidy, tidy
from ..rotations import dot as rot_dot


def unit(x, length):
    """Rows of ``x`` (k, 3) divided by their ``length`` (k, 1); zero rows where
    the length is 0 (a degenerate face's normal, a vertex whose normals cancel)."""
    return np.divide(x, length, out=np.zeros_like(x), where=length > 0)


def angle_weighted(V, F, fn):
    """Unit vertex normals (n, 3): each face's unit normal ``fn`` (m, 3) weighted by
    its corner angle at the vertex (the same direction however the faces around a
    vertex are triangulated); zero for a vertex whose normals cancel or that no face
    uses."""
    n = len(V)
    vn = np.zeros((n, 3))
    for k in range(3):
        e1 = V[F[:, (k + 1) % 3]] - V[F[:, k]]
        e2 = V[F[:, (k + 2) % 3]] - V[F[:, k]]
        angle = np.arctan2(np.linalg.norm(np.cross(e1, e2), axis=1), rot_dot(e1, e2))
        for i in range(3):
            vn[:, i] += np.bincount(F[:, k], weights=fn[:, i] * angle, minlength=n)
    return unit(vn, np.linalg.norm(vn, axis=1, keepdims=True))


def edge_keys(F, n):
    """One int64 key ``a * n + b`` (``a < b``) per face edge of ``F`` (m, 3) over
    ``n`` vertices, edges (0, 1), (1, 2), (2, 0) of every face in turn (3m,)."""
    e = np.sort(np.concatenate([F[:, [k, (k + 1) % 3]] for k in range(3)]))  # per row
    return e[:, 0].astype(np.int64) * n + e[:, 1]


def as_vertices(V, what="vertices") -> np.ndarray:
    """(n, 3) float32 vertices, checked (ColliderError naming the vertex at fault)."""
    try:
        V = np.asarray(V)
    except Exception as exc:  # ragged lists
        raise ColliderError(f"collider {what} must be an (n, 3) array: {exc}") from None
    if V.ndim != 2 or V.shape[1] != 3:
        raise ColliderError(f"collider {what} must have shape (n, 3), got {V.shape}")
    if not np.issubdtype(V.dtype, np.floating) and not np.issubdtype(V.dtype, np.integer):
        raise ColliderError(f"collider {what} must be numeric, got dtype {V.dtype}")
    V = V.astype(np.float32)
    if not np.isfinite(V.ravel()).all():  # flat first: the row-wise test is slow
        bad = ~np.isfinite(V).all(axis=1)
        raise ColliderError(
            f"collider {what}: vertex {int(np.argmax(bad))} is not finite "
            f"({int(bad.sum())} non-finite vertices)"
        )
    return V


def check_faces(F, n, name):
    """(m, 3) int32 faces over ``n`` vertices, checked (``m == 0`` allowed)."""
    try:
        F = np.asarray(F)
    except Exception as exc:  # ragged lists
        raise ColliderError(
            f"collider '{name}': faces must be an (m, 3) array: {exc}"
        ) from None
    if F.ndim != 2 or F.shape[1] != 3:
        if F.size == 0 and F.ndim == 1:
            return np.zeros((0, 3), np.int32)
        raise ColliderError(
            f"collider '{name}': faces must have shape (m, 3) (triangles), got {F.shape}"
        )
    if F.size == 0:
        return np.zeros((0, 3), np.int32)
    if not np.issubdtype(F.dtype, np.integer):
        if np.issubdtype(F.dtype, np.floating) and np.all(np.mod(F, 1) == 0):
            F = F.astype(np.int64)
        else:
            raise ColliderError(
                f"collider '{name}': faces must be integers, got {F.dtype}"
            )
    bad = ((F < 0) | (F >= n)).any(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise ColliderError(
            f"collider '{name}': face {i} {F[i].tolist()} indexes a vertex out of "
            f"range (the mesh has {n} vertices)"
        )
    return F.astype(np.int32)


class PerShape:
    """One value kept for one key (a shape version, a matrix): :meth:`get` builds it
    again when the key changes."""

    __slots__ = ("key", "value")

    def __init__(self):
        self.key = self.value = None

    def get(self, key, build):
        if self.value is None or self.key != key:
            self.value = build()
            self.key = key
        return self.value


class ColliderMesh:
    """A collider's faces (checked, repaired), topology and shape.

    Parameters
    ----------
    V : (n, 3) array_like of float
        Vertices in the collider's own space.
    F : (m, 3) array_like of int
        Triangles (``m == 0``: an empty collider).
    name : str
        For messages.
    drop_degenerate : bool
        Drop zero-area faces (counted in :attr:`dropped_faces`) instead of raising.

    Attributes
    ----------
    V : (n, 3) float32
        The vertices (replaced, never written, by :meth:`set_shape`).
    F : (m, 3) int32
        The faces used (after dropping and repairs; fixed for the collider's life).
    version : int
        Shape version: 0 at construction, +1 for every new shape.
    center : (3,) float64
        Centre of the used vertices' bounds: the origin of the local space the
        float32 BVH lives in (a collider modelled far from the origin keeps its
        precision).
    repairs : meshfix.Tidy
    closed : bool
    dropped_faces : int
    """

    def __init__(self, V, F, name, drop_degenerate=False):
        self.name = name
        V = as_vertices(V, f"'{name}' vertices")
        F = check_faces(F, len(V), name)
        self.dropped_faces = 0
        bad = degenerate_faces(V, F)
        if bad.any():
            if not drop_degenerate:
                i = int(np.argmax(bad))
                raise ColliderError(
                    f"collider '{name}': face {i} {F[i].tolist()} is degenerate "
                    f"(zero area or repeated vertex); {int(bad.sum())} such faces "
                    f"(use drop_degenerate=True to ignore them)"
                )
            self.dropped_faces = int(bad.sum())
            F = F[~bad]
        # Welded seams, duplicated faces and windings repaired (meshfix): the
        # faces used from here on; the vertices are never moved.
        self.repairs = tidy(V, F) if len(F) else Tidy(F)
        self.F = F = self.repairs.faces
        self.closed = self.repairs.closed
        self.used = np.unique(F)  # vertices referenced by a face (topology only)
        self.all_used = len(self.used) == len(V)
        self.V = V
        self.version = 0
        # topology (faces only): computed on first use, kept for the collider's life
        self._corners = None
        self._edges = None
        self._rims = None
        # per shape
        self._components = PerShape()
        self._vertex_normals = PerShape()
        self._margin_dirs = PerShape()
        self._normals = (None, 0, None)  # (version, normals asked, table): face_normals
        self._set_bounds()

    # ------------------------------------------------------------- shape
    def check_vertices(self, V2, what="new vertices"):
        """New vertices of the same topology, checked (float32)."""
        V2 = as_vertices(V2, f"'{self.name}' vertices")
        if V2.shape != self.V.shape:
            raise ColliderError(
                f"collider '{self.name}': {what} have shape {V2.shape}, expected "
                f"{self.V.shape} (same topology); build a new Collider when topology changes"
            )
        return V2

    def set_shape(self, V2):
        """New vertices (checked, changed): a new shape version."""
        # A deformation may collapse a triangle: legal (embree skips it, its
        # normal is zero), so no degenerate check here.
        self.V = V2
        self.version += 1
        self._set_bounds()

    def _set_bounds(self):
        # The BVH is float32: keep its coordinates centred on the mesh, so a
        # collider modelled far from the origin keeps its full precision.
        if len(self.F):
            Vu = self.components()
            self.lo = np.array([float(c.min()) for c in Vu])
            self.hi = np.array([float(c.max()) for c in Vu])
        else:
            self.lo, self.hi = np.zeros(3), np.zeros(3)
        self.center = 0.5 * (self.lo + self.hi)

    def bounds(self):
        """Local bounds ``(lo, hi)`` of the used vertices (own space)."""
        return self.lo, self.hi

    def local_vertices(self):
        """The vertices in the centred local space of the BVH, float64 (n, 3)
        (the float32 vertices minus the float64 centre)."""
        return self.V - self.center

    def components(self):
        """The used vertices as three contiguous float32 component arrays
        (per shape): per-axis passes over (n, 3) rows are slow."""
        def build():
            Vt = self.V.T if self.all_used else self.V[self.used].T
            return [np.ascontiguousarray(c) for c in Vt]

        return self._components.get(self.version, build)

    @property
    def margin(self) -> float:
        """The clearance margin, in the collider's own units (see ``Collider.margin``):
        ``tol.CLEARANCE_ULPS`` float32 ulps of the largest of its size and its
        vertices' distance from its origin, rounded up to a power of two."""
        lo, hi = self.lo, self.hi
        r = max(float(np.abs(lo).max()), float(np.abs(hi).max()), float(np.linalg.norm(hi - lo)))
        r = 2.0 ** np.ceil(np.log2(max(r, 1e-30)))
        return tol.CLEARANCE_ULPS * float(np.finfo(np.float32).eps) * float(r)

    # ---------------------------------------------------------- topology
    def corners(self):
        """The face corners (``F.T.ravel()``: corner k of every face, k = 0, 1, 2)
        sorted by vertex, stably (topology only): ``(order, face of each sorted
        corner, first sorted corner of each vertex, those vertices)``."""
        if self._corners is None:
            corner = self.F.T.ravel()
            order = np.argsort(corner, kind="stable")
            first = np.flatnonzero(np.r_[True, corner[order][1:] != corner[order][:-1]])
            self._corners = (order, order % len(self.F), first, corner[order][first])
        return self._corners

    def edges(self):
        """The unique edges ``[a (e,), b (e,)]`` (topology only)."""
        if self._edges is None:
            n = len(self.V)
            key = np.unique(edge_keys(self.F, n))
            self._edges = [np.ascontiguousarray(key // n), np.ascontiguousarray(key % n)]
        return self._edges

    def rim_faces(self):
        """Faces with an edge no other face shares (an open mesh's rims; topology)."""
        if self._rims is None:
            keys = edge_keys(self.F, len(self.V))
            _, inv, cnt = np.unique(keys, return_inverse=True, return_counts=True)
            once = (cnt[inv] == 1).reshape(3, -1).any(axis=0)
            self._rims = np.flatnonzero(once)
        return self._rims

    # ----------------------------------------------------------- normals
    def face_normals(self, prim):
        """Face normals (right-handed, local space) of triangles ``prim``.

        Unit normals, computed on demand: only hit triangles ever need one.
        Once the normals asked for one shape of the collider add up to a
        quarter of its faces (a rigid collider, frame after frame), all of
        them are computed once and looked up (the same values).
        """
        key, asked, table = self._normals
        if key != self.version:
            key, asked, table = self.version, 0, None
        if table is None:
            asked += len(prim)
            if asked * 4 >= len(self.F):
                table = self.face_normals_of(np.arange(len(self.F)))
        self._normals = (key, asked, table)
        if table is not None:
            return table[prim]
        return self.face_normals_of(prim)

    def face_normals_of(self, prim):
        """Unit face normals (local space) of triangles ``prim``, computed."""
        V = self.V
        F = self.F[prim]
        a = V[F[:, 0]].astype(np.float64)
        n = np.cross(V[F[:, 1]] - a, V[F[:, 2]] - a)
        return unit(n, np.linalg.norm(n, axis=1, keepdims=True))

    def vertex_normals(self):
        """Angle-weighted unit vertex normals (local space, the winding's side), per shape."""
        F = self.F
        return self._vertex_normals.get(self.version, lambda: angle_weighted(
            self.local_vertices(), F, self.face_normals(np.arange(len(F)))))

    def margin_directions(self):
        """Unit area-weighted vertex normals, local space, (n, 3) (per shape):
        where the clearance margin moves each vertex.

        Cheaper than the offset directions (a deforming collider pays it every
        frame): every face moves out by the margin times the cosine between its
        normal and its vertices' normals, a positive fraction of it wherever
        faces meet at less than 180 degrees.
        """
        return self._margin_dirs.get(self.version, self._margin_directions)

    def _margin_directions(self):
        comps = self.components() if self.all_used else [
            np.ascontiguousarray(self.V[:, i]) for i in range(3)]
        F = [np.ascontiguousarray(self.F[:, k]) for k in range(3)]
        # face normals (area-weighted) as components, float64
        p = [[c.take(F[k]).astype(np.float64) for c in comps] for k in range(3)]
        e1 = [p[1][i] - p[0][i] for i in range(3)]
        e2 = [p[2][i] - p[0][i] for i in range(3)]
        fa = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
              e1[0] * e2[1] - e1[1] * e2[0]]
        # sum over each vertex's corners: corners sorted by vertex once (topology)
        _, face_of, first, verts = self.corners()
        n = len(self.V)
        vn = np.zeros((n, 3))
        for i in range(3):
            vn[verts, i] = np.add.reduceat(fa[i].take(face_of), first)
        return unit(vn, np.sqrt(np.einsum("ij,ij->i", vn, vn))[:, None])
