"""Collision meshes: validation, closedness, acceleration structure, queries.

A :class:`Collider` keeps its triangles in its own (object) space. Rigid
motion only changes :attr:`Collider.matrix`: rays are moved into the
collider's space, the BVH is never rebuilt. Deformation sets
:attr:`Collider.vertices`, which rebuilds the BVH lazily, and only when the
vertices really changed. :meth:`Collider.place` does both as one update and
remembers the placement before it (:attr:`Collider.previous`): the surface's
velocity at a point (:meth:`Collider.velocities`, Follow Collider Motion).

Naming: ``_wo`` is world space, ``_lo`` the collider's local space.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import partial

import numpy as np

from . import tolerances as tol
from .closest import barycentric, closest_points_on_mesh
from .errors import ColliderError
from .meshfix import Tidy, tidy
from .proximity import mark_boxes
from .rays import beside, make_backend, triangle_rows
from .rotations import apply, apply_soa, det3, inv_affine, norm_bound
from .rotations import dot as rot_dot

#: Fixed, irrational-ish unit directions for the parity (inside) test.
#: Three votes make the test robust to a ray grazing an edge or a vertex.
_PARITY_DIRS = np.array(
    [
        [0.5773502691896258, 0.5773502691896258, 0.5773502691896258],
        [-0.2672612419124244, 0.8017837257372732, -0.5345224838248488],
        [0.6246950475544243, -0.2498780190217697, -0.7399400733959437],
    ]
)
_PARITY_DIRS /= np.linalg.norm(_PARITY_DIRS, axis=1, keepdims=True)


def _unit(x, length):
    """Rows of ``x`` (k, 3) divided by their ``length`` (k, 1); zero rows where
    the length is 0 (a degenerate face's normal, a vertex whose normals cancel)."""
    return np.divide(x, length, out=np.zeros_like(x), where=length > 0)


def _angle_weighted(V, F, fn):
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
    return _unit(vn, np.linalg.norm(vn, axis=1, keepdims=True))


def _cell_index(x, n):
    """Integer cell index ``floor(x)`` of an axis of ``n`` cells, clipped in float
    first to [-1, n + 1] (far-away points must not overflow the int cast)."""
    return np.floor(np.clip(x, -1, n + 1)).astype(np.int64)


def _edge_keys(F, n):
    """One int64 key ``a * n + b`` (``a < b``) per face edge of ``F`` (m, 3) over
    ``n`` vertices, edges (0, 1), (1, 2), (2, 0) of every face in turn (3m,)."""
    e = np.sort(np.concatenate([F[:, [k, (k + 1) % 3]] for k in range(3)]))  # per row
    return e[:, 0].astype(np.int64) * n + e[:, 1]


def _as_vertices(V, what="vertices") -> np.ndarray:
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


def _as_matrix(M) -> tuple[np.ndarray, np.ndarray]:
    if M is None:
        return np.eye(4), np.eye(4)
    try:
        M = np.array(M, dtype=np.float64)
    except Exception as exc:
        raise ColliderError(f"collider matrix must be a 4x4 array: {exc}") from None
    if M.shape != (4, 4):
        raise ColliderError(f"collider matrix must be 4x4, got shape {M.shape}")
    if not np.isfinite(M).all():
        raise ColliderError("collider matrix has non-finite entries")
    if not np.allclose(M[3], [0, 0, 0, 1], atol=1e-9):
        raise ColliderError("collider matrix must be affine (last row 0, 0, 0, 1)")
    det = det3(M[:3, :3])
    scale = np.abs(M[:3, :3]).max()
    if not abs(det) > 1e-12 * max(scale, 1e-30) ** 3:
        raise ColliderError("collider matrix is singular (zero scale on some axis)")
    return M, inv_affine(M)


def _keep_recent(cache, version, most):
    """Make room in ``cache`` (key -> (shape version, value)) for one more entry:
    entries of other shapes go, then the oldest beyond ``most - 1``."""
    for k in [k for k, v in cache.items() if v[0] != version]:
        del cache[k]
    while len(cache) >= most:
        del cache[next(iter(cache))]


def clearance_levels(dist):
    """Per-curve distances ``dist`` (C,) grouped into at most
    ``tol.OFFSET_LEVELS`` levels (one offset shell each).

    Up to ``OFFSET_LEVELS`` distinct values are their own levels (exact).
    More: the range ``[min, max]`` is cut into ``OFFSET_LEVELS`` equal bins
    and each bin's level is the largest distance in it, so every curve is
    kept at least as far as it asked, and at most one bin width farther. The
    levels depend on the set of values only, never on the curves' order.

    Returns
    -------
    levels : (L,) float64, increasing
    group : (C,) int64
        Each curve's level.
    """
    u, inv = np.unique(dist, return_inverse=True)
    inv = inv.reshape(-1)
    L = tol.OFFSET_LEVELS
    if len(u) <= L:
        return u, inv
    lo, hi = float(u[0]), float(u[-1])
    b = np.minimum(np.floor((u - lo) / (hi - lo) * L), L - 1).astype(np.int64)
    # u is sorted: a bin's largest value is its last; bins only increase
    last = np.flatnonzero(np.r_[b[1:] != b[:-1], True])
    bins = np.cumsum(np.r_[0, (b[1:] != b[:-1]).astype(np.int64)])  # value -> level
    return u[last], bins[inv]


@dataclass(frozen=True)
class Placement:
    """Where a collider was: its world ``matrix`` (4, 4) float64 and its own
    ``vertices`` (n, 3) float32 (read-only), see :attr:`Collider.previous`."""

    matrix: np.ndarray
    vertices: np.ndarray


@dataclass(frozen=True)
class ShellFaces:
    """Which face of the collider each triangle of a built shell is.

    ``real`` (k,) int: the collider face; ``flip`` (k,) bool: the triangle
    faces the other way (the inner shell of an open or double-sided mesh).
    """

    real: np.ndarray
    flip: np.ndarray


class Collider:
    """A triangle mesh that curves must not pass through.

    Parameters
    ----------
    V : (n, 3) array_like of float
        Vertices in the collider's own space.
    F : (m, 3) array_like of int
        Triangles (indices into ``V``). ``m == 0`` is allowed: an empty
        collider never collides (a documented no-op).
    double_sided : bool
        Treat the mesh as a thin two-sided shell: curves are pushed back to
        the side their root is on, offsets apply on both sides, and it never
        reports pinches. Single-sided meshes push along the hit normal (or
        its inverse when a back face is crossed) and, when closed, detect
        pinched roots (roots inside the volume).
    matrix : (4, 4) array_like, optional
        Affine world transform (None = identity).
    offset : float, optional
        Collision offset of this collider (world units), overriding
        ``Settings.collision_offset`` (a number for every curve;
        ``Settings.clearance_margin`` is still added).
    drop_degenerate : bool
        Silently drop zero-area triangles instead of raising. The number
        dropped is in :attr:`dropped_faces`.
    backend : {'embree', 'numpy'}, optional
        Ray tracer; default embree. 'numpy' is the brute-force reference.
    name : str
        Used in error messages (e.g. the Blender object's name).
    deforming : bool or None
        A hint that the vertices change every frame (skinning, shape keys,
        cloth). It changes no result (the BVH is a function of the vertices
        and, with an offset, of the shell alone, so results never depend on
        the frames played before), only work: the inside test of a deforming
        collider never builds its fine per-shape grid (see
        :meth:`contains_grid`), which a second query of the same frame (the
        render groom's clearance pass after the guides) would otherwise build
        every frame for one use.

    Raises
    ------
    ColliderError
        Malformed vertices, faces or matrix; the message names the vertex
        or face at fault.
    """

    def __init__(
        self,
        V,
        F,
        double_sided=False,
        matrix=None,
        offset=None,
        drop_degenerate=False,
        backend=None,
        name="collider",
        deforming=None,
    ):
        self.name = str(name)
        self.deforming = None if deforming is None else bool(deforming)
        if backend not in (None, "embree", "numpy"):
            raise ColliderError(f"collider '{self.name}': unknown backend {backend!r}")
        self._backend_name = backend
        self.double_sided = bool(double_sided)
        self.offset = None if offset is None else self._check_offset(offset)
        V = _as_vertices(V, f"'{self.name}' vertices")
        F = self._check_faces(F, len(V))
        self.dropped_faces = 0
        self._V = V
        bad = self._degenerate(V, F)
        if bad.any():
            if not drop_degenerate:
                i = int(np.argmax(bad))
                raise ColliderError(
                    f"collider '{self.name}': face {i} {F[i].tolist()} is degenerate "
                    f"(zero area or repeated vertex); {int(bad.sum())} such faces "
                    f"(use drop_degenerate=True to ignore them)"
                )
            self.dropped_faces = int(bad.sum())
            F = F[~bad]
        # Welded seams, duplicated faces and windings repaired (meshfix): the
        # faces used from here on; the vertices are never moved.
        self.repairs = tidy(V, F) if len(F) else Tidy(F)
        F = self.repairs.faces
        self._F = F
        self._used = np.unique(F)  # vertices referenced by a face (topology only)
        self._all_used = len(self._used) == len(V)
        self.closed = self.repairs.closed
        self._M, self._Minv = _as_matrix(matrix)
        # The previous placement (see previous): None unknown, else [matrix,
        # vertices], a part None where it is the current one.
        self._prev = None
        self._version = 0
        self._key_memo = (None, -1, {})  # see _shell_key
        self._contains_seen = {}  # offset -> shape version of the last inside test
        self._normals_cache = (None, 0, None)  # see _face_normals
        self._built = []  # [(key, backend, ShellFaces)], see _backend
        # Builds may run on a ray thread (see prefetch): one lock for the BVHs,
        # one for the occupancy grid (built by whichever thread needs it first).
        self._build_lock = threading.Lock()
        self._occ_lock = threading.Lock()
        self._prefetching = None  # shell key of the last prefetch started
        #: Did the last solver step that saw this collider query it? (It then
        #: starts the next rebuild early: timing only, never a result.)
        self.queried = False
        self.build_count = 0
        self._geometry_cache = None
        self._rows_cache = {}  # shell layout -> prepared triangles (see _rows)
        self._derived = {}  # name -> (key, value), see derived()
        self._inside_answers = {}  # (fine?, offset) -> (shape version, answers): _answers
        self._touched = {}  # offset -> (shape version, cells): _surface_cells
        self._recenter()

    def _recenter(self):
        # The BVH is float32: keep its coordinates centred on the mesh, so a
        # collider modelled far from the origin keeps its full precision.
        lo, hi = self._geometry()
        self._center = 0.5 * (lo + hi)

    # ----------------------------------------------------------------- input
    def _check_offset(self, offset):
        try:
            offset = float(offset)
        except (TypeError, ValueError):
            raise ColliderError(f"collider '{self.name}': offset must be a number") from None
        if not (np.isfinite(offset) and 0 <= offset <= 1e6):
            raise ColliderError(
                f"collider '{self.name}': offset must be between 0 and 1e6, got {offset}"
            )
        return offset

    def _check_faces(self, F, n):
        try:
            F = np.asarray(F)
        except Exception as exc:  # ragged lists
            raise ColliderError(
                f"collider '{self.name}': faces must be an (m, 3) array: {exc}"
            ) from None
        if F.ndim != 2 or F.shape[1] != 3:
            if F.size == 0 and F.ndim == 1:
                return np.zeros((0, 3), np.int32)
            raise ColliderError(
                f"collider '{self.name}': faces must have shape (m, 3) (triangles), got {F.shape}"
            )
        if F.size == 0:
            return np.zeros((0, 3), np.int32)
        if not np.issubdtype(F.dtype, np.integer):
            if np.issubdtype(F.dtype, np.floating) and np.all(np.mod(F, 1) == 0):
                F = F.astype(np.int64)
            else:
                raise ColliderError(
                    f"collider '{self.name}': faces must be integers, got {F.dtype}"
                )
        bad = ((F < 0) | (F >= n)).any(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise ColliderError(
                f"collider '{self.name}': face {i} {F[i].tolist()} indexes a vertex out of "
                f"range (the mesh has {n} vertices)"
            )
        return F.astype(np.int32)

    @staticmethod
    def _degenerate(V, F):
        if len(F) == 0:
            return np.zeros(0, bool)
        V64 = V.astype(np.float64)
        diag = float(np.linalg.norm(V64.max(0) - V64.min(0))) or 1.0
        a = np.cross(V64[F[:, 1]] - V64[F[:, 0]], V64[F[:, 2]] - V64[F[:, 0]])
        area2 = np.einsum("ij,ij->i", a, a)  # (0 for a repeated vertex)
        return area2 <= (2 * tol.DEGENERATE_AREA_REL * diag**2) ** 2

    # ------------------------------------------------------------ properties
    @property
    def faces(self) -> np.ndarray:
        """(m, 3) int32 triangles (after dropping degenerate ones)."""
        return self._F

    @property
    def empty(self) -> bool:
        """True when the collider has no triangle (it never collides)."""
        return len(self._F) == 0

    @property
    def vertices(self) -> np.ndarray:
        """(n, 3) float32 vertices in the collider's own space (read-only view)."""
        v = self._V.view()
        v.flags.writeable = False
        return v

    @vertices.setter
    def vertices(self, V2):
        V2 = self._check_vertices(V2)
        self._remember(vertices=True)
        if np.array_equal(V2, self._V):
            return
        self._set_shape(V2)

    def _set_shape(self, V2):
        """New vertices (checked, changed): a new shape version."""
        # A deformation may collapse a triangle: legal (embree skips it, its
        # normal is zero), so no degenerate check here.
        self._V = V2
        self._version += 1
        self._geometry_cache = None
        self._recenter()

    @property
    def version(self) -> int:
        """Shape version: 0 at construction, +1 each time :attr:`vertices`
        changes. Derived data keyed on it stays valid while the collider only
        moves (see :meth:`derived`)."""
        return self._version

    def derived(self, name: str, key, build):
        """Data derived from this collider, cached on it under ``name``.

        Returns the cached value when it was made for ``key`` (hashable, e.g.
        ``(col.version, ...)``), else ``build()``, which is kept. For callers
        that index a collider their own way (distance fields, closest-point
        structures) without reaching into its attributes; the collider's own
        per-shape caches use it too, under names starting with ``_``.
        """
        hit = self._derived.get(name)
        if hit is not None and hit[0] == key:
            return hit[1]
        value = build()
        self._derived[name] = (key, value)
        return value

    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) float64 world transform (a copy)."""
        return self._M.copy()

    @matrix.setter
    def matrix(self, M):
        M = _as_matrix(M)
        self._remember(matrix=True)
        self._M, self._Minv = M

    def _check_vertices(self, V2, what="new vertices"):
        V2 = _as_vertices(V2, f"'{self.name}' vertices")
        if V2.shape != self._V.shape:
            raise ColliderError(
                f"collider '{self.name}': {what} have shape {V2.shape}, expected "
                f"{self._V.shape} (same topology); build a new Collider when topology changes"
            )
        return V2

    # ------------------------------------------------------------ placement
    def place(self, matrix=None, vertices=None):
        """Move the collider to this frame's placement: one update.

        The whole placement it had (matrix and vertices) becomes
        :attr:`previous`, then ``matrix`` and ``vertices`` (None: unchanged)
        are applied as assigning :attr:`matrix` and :attr:`vertices` would.
        Call it once per frame (step) with both parts: a part left unchanged
        then did not move since the previous frame.
        """
        M = None if matrix is None else _as_matrix(matrix)
        V2 = None if vertices is None else self._check_vertices(vertices)
        self._prev = [self._M, self._V]
        if M is not None:
            self._M, self._Minv = M
        if V2 is not None and not np.array_equal(V2, self._V):
            self._set_shape(V2)

    def _remember(self, matrix=False, vertices=False):
        """Assigning one part of the placement: its current value becomes that
        part of :attr:`previous` (the other part's stays as it was)."""
        if self._prev is None:
            self._prev = [None, None]
        if matrix:
            self._prev[0] = self._M
        if vertices:
            self._prev[1] = self._V

    @property
    def previous(self) -> Placement | None:
        """The placement the collider had before its last update, or None when
        none is known (a new collider, or after :meth:`forget_previous`).

        An update is :meth:`place` (both parts at once), or an assignment of
        :attr:`matrix` or :attr:`vertices` (that part only: assigning the
        same value again is an update in which it did not move). Follow
        Collider Motion takes each contact's velocity from it
        (:meth:`velocities`): update both parts once per frame, e.g. with
        :meth:`place`; a glue that resumes from a cached frame sets the
        previous frame's placement with :meth:`set_previous` to get the bits
        of playback.
        """
        if self._prev is None:
            return None
        M, V = self._prev
        M = self._M if M is None else M
        V = (self._V if V is None else V).view()
        V.flags.writeable = False
        return Placement(M.copy(), V)

    def set_previous(self, matrix=None, vertices=None):
        """Set :attr:`previous` explicitly: ``matrix`` (4, 4) and ``vertices``
        (n, 3) (same topology), each None for "where it is now" (that part
        did not move)."""
        M = None if matrix is None else _as_matrix(matrix)[0]
        V2 = None if vertices is None else self._check_vertices(vertices, "previous vertices")
        if V2 is not None and np.array_equal(V2, self._V):
            V2 = None  # (the current vertices: no deformation)
        self._prev = [M, V2]

    def forget_previous(self):
        """Forget the previous placement: the collider has no known motion
        (:meth:`velocities` are zero) until its next update."""
        self._prev = None

    def velocities(self, p_wo, faces=None) -> np.ndarray:
        """Velocity of the collider's surface at points ``p_wo`` (world units
        per update: from :attr:`previous` to now).

        Parameters
        ----------
        p_wo : (k, 3) array_like
            Points on (or near: an offset shell) the collider, world space,
            current placement.
        faces : (k,) array_like of int, optional
            The face of each point (indices into :attr:`faces`, e.g. a hit's
            face). Needed to follow a deformation (the point moves with its
            face's vertices, barycentric weights of its projection onto the
            face); without it the nearest face is looked up, only when the
            vertices moved.

        Returns
        -------
        (k, 3) float64
            Zero where nothing is known (no previous placement) and,
            exactly, where the collider did not move at all.
        """
        p_wo = np.asarray(p_wo, np.float64).reshape(-1, 3)
        k = len(p_wo)
        out = np.zeros((k, 3))
        if self._prev is None or k == 0 or self.empty:
            return out
        M0, V0 = self._prev
        moved_m = M0 is not None and not np.array_equal(M0, self._M)
        moved_v = V0 is not None and V0 is not self._V
        if not (moved_m or moved_v):
            return out
        M0 = self._M if M0 is None else M0
        x = apply(self._Minv[:3, :3], p_wo) + self._Minv[:3, 3]  # own space
        if moved_v:
            if faces is None:
                index = self.derived("_closest", self._version, lambda: [None])
                _, faces, index[0] = closest_points_on_mesh(
                    self._local_vertices(), self._F, x - self._center, index[0])
            f = self._F[np.asarray(faces, np.int64)]
            tri = self._V[f].astype(np.float64)  # (k, 3, 3)
            w = barycentric(x, tri[:, 0], tri[:, 1], tri[:, 2])
            w = np.clip(w, 0.0, None)
            total = w.sum(axis=1, keepdims=True)
            w = np.where(total > 0, w / np.where(total > 0, total, 1.0), 1.0 / 3.0)
            move = V0[f].astype(np.float64) - tri  # each corner's motion back in time
            x = x + np.einsum("ki,kij->kj", w, move)
        prev = apply(M0[:3, :3], x) + M0[:3, 3]
        return p_wo - prev

    # ------------------------------------------------------------ geometry
    def _geometry(self):
        """Local bounds ``(lo, hi)`` of the used vertices (cached per vertices)."""
        if self._geometry_cache is None:
            if len(self._F):
                Vu = self._used_components()
                lo = np.array([float(c.min()) for c in Vu])
                hi = np.array([float(c.max()) for c in Vu])
                self._geometry_cache = (lo, hi)
            else:
                self._geometry_cache = (np.zeros(3), np.zeros(3))
        return self._geometry_cache

    def _local_vertices(self):
        """The vertices in the centred local space of the BVH, float64 (n, 3)
        (the float32 vertices minus the float64 centre)."""
        return self._V - self._center

    def _used_components(self):
        """The used vertices as three contiguous float32 component arrays
        (cached per vertices): per-axis passes over (n, 3) rows are slow."""
        def build():
            Vt = self._V.T if self._all_used else self._V[self._used].T
            return [np.ascontiguousarray(c) for c in Vt]

        return self.derived("_components", self._version, build)

    def _corners(self):
        """The face corners (``F.T.ravel()``: corner k of every face, k = 0, 1, 2)
        sorted by vertex, stably (topology only, cached): ``(order, face of each
        sorted corner, first sorted corner of each vertex, those vertices)``."""
        if getattr(self, "_corner_cache", None) is None:
            corner = self._F.T.ravel()
            order = np.argsort(corner, kind="stable")
            first = np.flatnonzero(np.r_[True, corner[order][1:] != corner[order][:-1]])
            self._corner_cache = (order, order % len(self._F), first, corner[order][first])
        return self._corner_cache

    def _face_normals(self, prim):
        """Face normals (right-handed, local space) of triangles ``prim``.

        Unit normals, computed on demand: only hit triangles ever need one.
        Once the normals asked for one shape of the collider add up to a
        quarter of its faces (a rigid collider, frame after frame), all of
        them are computed once and looked up (the same values).
        """
        key, asked, table = self._normals_cache
        if key != self._version:
            key, asked, table = self._version, 0, None
        if table is None:
            asked += len(prim)
            if asked * 4 >= len(self._F):
                table = self._face_normals_of(np.arange(len(self._F)))
        self._normals_cache = (key, asked, table)
        if table is not None:
            return table[prim]
        return self._face_normals_of(prim)

    def _face_normals_of(self, prim):
        V = self._V
        F = self._F[prim]
        a = V[F[:, 0]].astype(np.float64)
        n = np.cross(V[F[:, 1]] - a, V[F[:, 2]] - a)
        return _unit(n, np.linalg.norm(n, axis=1, keepdims=True))

    def _offset_directions(self):
        """:meth:`_offset_directions_of` the current shape and matrix, kept for
        the shells of other offsets (per-curve clearance levels) of the same."""
        key = (self._version, self._M[:3, :3].tobytes())
        return self.derived("_offset_directions", key, self._offset_directions_of)

    def _offset_directions_of(self):
        """Local displacement of each vertex for a world offset of 1, (n, 3).

        Computed in world metric (the matrix's scale and shear included), so
        the shell keeps the offset in world units whatever the matrix. Each
        vertex moves along its angle-weighted normal (each face's normal
        weighted by its corner angle at the vertex: the same direction however
        the faces are triangulated), lengthened so that every face around it
        moves by the full offset: a box keeps the offset on its faces, not
        offset / sqrt(3), nor twice it at a corner split into two triangles.
        The lengthening is capped at ``tol.OFFSET_MAX_STRETCH`` (needle-sharp
        vertices).
        """
        S = self._M[:3, :3]
        Vw = apply(S, self._local_vertices())
        F = self._F
        fa = np.cross(Vw[F[:, 1]] - Vw[F[:, 0]], Vw[F[:, 2]] - Vw[F[:, 0]])
        if det3(S) < 0:  # a mirroring matrix flips the winding: keep normals outward
            fa = -fa
        fn = _unit(fa, np.linalg.norm(fa, axis=1, keepdims=True))
        n = len(self._V)
        vn = _angle_weighted(Vw, F, fn)
        # smallest cos(vertex normal, face normal) over the faces around each vertex
        cos = np.concatenate([rot_dot(vn[F[:, k]], fn) for k in range(3)])
        order, _, first, verts = self._corners()
        lowest = np.ones(n)
        lowest[verts] = np.minimum.reduceat(cos[order], first)
        stretch = 1.0 / np.clip(lowest, 1.0 / tol.OFFSET_MAX_STRETCH, 1.0)
        return apply(self._Minv[:3, :3], vn * stretch[:, None])

    def _occupancy(self):
        """Vertex occupancy grid of the (centred) local space, as a summed-area table.

        Every point of a triangle is within ``max_edge`` of one of its
        vertices, so a ball that comes within ``max_edge`` of no occupied cell
        cannot touch the mesh: an O(1) test per curve that is much tighter
        than the bounding box. Rebuilt with the vertices (O(n)).
        """
        if getattr(self, "_occ_key", None) == self._version:
            return self._occ
        with self._occ_lock:
            if getattr(self, "_occ_key", None) != self._version:
                self._build_occupancy()
            return self._occ

    def _build_occupancy(self):
        """Compute :meth:`_occupancy` (under its lock)."""
        lo_g, hi_g = self._geometry()
        lo, hi = lo_g - self._center, hi_g - self._center
        h = max(float((hi - lo).max()) / tol.OCCUPANCY_CELLS, 1e-30)
        dims = np.floor((hi - lo) / h).astype(np.int64) + 1
        flat = None
        for i, c in enumerate(self._used_components()):
            x = c.astype(np.float64)
            x -= self._center[i]
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
        if getattr(self, "_edges", None) is None:  # unique edges: topology only
            key = np.unique(_edge_keys(self._F, len(self._V)))
            self._edges = [
                np.ascontiguousarray(key // len(self._V)),
                np.ascontiguousarray(key % len(self._V)),
            ]
        a, b = self._edges
        sq = None
        for c in (self._V[:, i] for i in range(3)):
            c = np.ascontiguousarray(c)
            d = c.take(a)
            d -= c.take(b)
            d *= d
            sq = d if sq is None else sq + d
        max_edge = float(sq.max())
        # float32 edges: pad by a relative ulp margin to stay conservative
        max_edge = float(np.sqrt(max_edge)) * (1 + 1e-5)
        self._occ = (lo, h, dims, sat, max_edge)
        self._occ_key = self._version  # last: readers check it without the lock

    def near_surface(self, p_wo, radius_wo, offset_wo=0.0) -> np.ndarray:
        """Conservative test: can a ball (``p_wo``, ``radius_wo``) touch the mesh?

        Parameters
        ----------
        p_wo : (k, 3) ndarray
            Ball centres, world space.
        radius_wo : (k,) ndarray or float
            Radii, world units.

        Returns
        -------
        (k,) bool
            False only where the ball certainly misses the (offset) mesh.
        """
        k = len(p_wo)
        if self.empty or k == 0:
            return np.zeros(k, bool)
        q = self.grid_coords(np.asarray(p_wo, np.float64).T)
        return self.near_surface_grid(q, radius_wo, offset_wo)

    def grid_coords(self, p_wo):
        """World points given as components (3, k) in the occupancy grid's
        frame (local space minus the grid's corner), as components (3, k)."""
        lo = self._occupancy()[0]
        A, b = self.local_map()
        q = apply_soa(A, np.asarray(p_wo, np.float64))
        for i in range(3):
            q[i] += b[i]
            q[i] -= lo[i]
        return q

    def near_surface_grid(self, q, radius_wo, offset_wo=0.0) -> np.ndarray:
        """:meth:`near_surface` for centres given by :meth:`grid_coords`."""
        k = q.shape[1]
        if self.empty or k == 0:
            return np.zeros(k, bool)
        lo, h, dims, sat, max_edge = self._occupancy()
        A, b = self.local_map()
        stretch = norm_bound(A)  # at least the largest local length of a world unit
        reach = np.asarray(radius_wo, np.float64) + offset_wo * tol.OFFSET_MAX_STRETCH
        r = np.broadcast_to(reach * stretch + max_edge + h, (k,))
        # Summed-area table over the cells the ball's box covers, by flat
        # index (one gather per corner).
        outside = np.zeros(k, bool)
        corner = []
        step = (sat.shape[1] * sat.shape[2], sat.shape[2], 1)
        for i in range(3):
            i0 = _cell_index((q[i] - r) / h, dims[i])
            i1 = _cell_index((q[i] + r) / h, dims[i])
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

    def effective_offset(self, default: float) -> float:
        """This collider's offset in world units (its own, else ``default``)."""
        return self.offset if self.offset is not None else float(default)

    def clearance_groups(self, offset=0.0, margin=0.0, levels=None) -> list:
        """The offset shells the curves are tested against, and which curves.

        Parameters
        ----------
        offset : float or (C,) ndarray
            ``Settings.collision_offset`` (a number or one per curve); this
            collider's own :attr:`offset`, when it has one, replaces it.
        margin : float or (C,) ndarray
            ``Settings.clearance_margin``, added to the offset that applies.
        levels : (L,) ndarray, optional
            Increasing distances to round every curve's distance up to (the
            levels of a larger set of curves these are taken from, see
            ``Settings.take``), instead of this set's own.

        Returns
        -------
        list of (float, (C,) bool ndarray or None)
            ``(distance, curves)``: the curves (None: all of them) kept at
            ``distance`` from this collider. One distance for every curve is
            one group of all curves (``distance`` as the plain numbers give
            it, bit for bit); otherwise see :func:`clearance_levels` (at most
            ``tol.OFFSET_LEVELS`` groups, never less than a curve's own
            distance).
        """
        dist = self.clearance_distances(offset, margin)
        if not isinstance(dist, np.ndarray):
            return [(dist, None)]
        if len(dist) == 0:
            return [(0.0, None)]
        if levels is not None:  # the smallest level at least each distance
            j = np.searchsorted(levels, dist)
            used = np.unique(j)
            if len(used) == 1:
                return [(float(levels[used[0]]), None)]
            return [(float(levels[u]), j == u) for u in used]
        lo, hi = dist.min(), dist.max()
        if lo == hi:  # a uniform map: the plain number's shell
            return [(float(dist[0]), None)]
        levels, group = clearance_levels(dist)
        return [(float(levels[j]), group == j) for j in range(len(levels))]

    def clearance_distances(self, offset=0.0, margin=0.0):
        """The distance each curve asks to be kept from this collider (before
        any rounding): a float, or (C,) float64 when a map is involved."""
        base = self.offset if self.offset is not None else offset
        if not isinstance(base, np.ndarray) and not isinstance(margin, np.ndarray):
            return float(base) + float(margin)
        return np.asarray(base, np.float64) + margin

    def _shell_key(self, offset_wo):
        """What a shell depends on: the vertices, the offset and, for an offset,
        the matrix's rotation-invariant stretch ``M^T M`` (quantized, so float32
        jitter of a rigid transform never triggers a rebuild)."""
        if offset_wo <= 0:
            return (self._version, 0.0)
        # Every ray query asks: remembered per matrix (the setter replaces the
        # array, never writes into it) and shape.
        memo = self._key_memo
        if memo[0] is not self._M or memo[1] != self._version:
            memo = self._key_memo = (self._M, self._version, {})
        key = memo[2].get(offset_wo)
        if key is None:
            S = self._M[:3, :3]
            G = np.einsum("ki,kj->ij", S, S)
            g = float(np.trace(G)) / 3.0
            q = tuple(np.round(G / g, 6).ravel()) + (float(f"{g:.6g}"),)
            key = memo[2][offset_wo] = (self._version, float(f"{offset_wo:.9g}"), q)
        return key

    def _backend(self, offset_wo: float):
        """The ray backend for the shell at ``offset_wo`` (built lazily).

        A few shells are kept (several solvers may share one collider with
        different offsets, per-curve clearances use up to
        ``tol.OFFSET_LEVELS``), newest last.
        """
        with self._build_lock:
            return self._backend_locked(offset_wo)

    def prefetch(self, offset_wo: float, threads: int):
        """Start building the BVH that queries at ``offset_wo`` need on a ray
        thread, when the vertices or the offset changed.

        Embree builds without the GIL, so the build overlaps the caller's own
        work (the solver's set-up). Queries made meanwhile wait for it. The
        result never depends on it: only when the work is done.

        Returns
        -------
        callable or None
            Waits for the work (re-raising its error); None when nothing was
            started (nothing to do, one thread, or already under way).
        """
        if threads <= 1 or self.empty:
            return None
        key = self._shell_key(offset_wo)
        if key == self._prefetching or any(b[0] == key for b in self._built):
            return None
        self._prefetching = key
        return beside(partial(self._backend, offset_wo), threads)

    def _backend_locked(self, offset_wo: float):
        key = self._shell_key(offset_wo)
        for k, be, faces in self._built:
            if k == key:
                return be, faces
        V = self._local_vertices()
        F = self._F
        m, n = len(F), len(self._V)
        # Every shell keeps the clearance margin (see margin), plus the
        # Collision Offset when there is one.
        disp = self.margin * self._margin_directions()
        if offset_wo > 0:
            disp = disp + offset_wo * self._offset_directions()
        # Face blocks: [outer shell, (inner shell, surface)]. A closed
        # single-sided solid is only kept at a distance from outside (inside
        # is a pinch). Anything else (open sheets, double-sided meshes) gets
        # shells on both sides, the inner one facing inward, and keeps its
        # real surface too, so a curve slipping in between the shells from a
        # rim still collides: all of it with an offset, its rim faces only
        # for the bare margin (a curve can only slip in within it of a rim).
        blocks_V, blocks_F = [V + disp], [F]
        real, flip = [np.arange(m)], [np.zeros(m, bool)]
        if self.double_sided or not self.closed:
            keep = np.arange(m) if offset_wo > 0 else self._rim_faces()
            blocks_V += [V - disp, V]
            blocks_F += [F[:, ::-1] + n, F[keep] + 2 * n]
            real += [np.arange(m), keep]
            flip += [np.ones(m, bool), np.zeros(len(keep), bool)]
        V = np.concatenate(blocks_V)
        F = np.concatenate(blocks_F)
        faces = ShellFaces(np.concatenate(real), np.concatenate(flip))
        backend = make_backend(self._backend_name, V, F, rows=self._rows(F))
        self.build_count += 1
        # (room for every level of per-curve clearances, tol.OFFSET_LEVELS,
        # beside a few other offsets: several solvers may share a collider)
        self._built = [b for b in self._built
                       if b[0][0] == self._version][-(tol.OFFSET_LEVELS + 3):]
        self._built.append((key, backend, faces))
        return backend, faces

    @property
    def margin(self) -> float:
        """The clearance margin, in the collider's own units: every shell the
        curves are tested against lies this far out along the vertex
        normals, even with no Collision Offset.

        ``tol.CLEARANCE_ULPS`` float32 ulps of the collider's own coordinates
        (the largest of its size and its vertices' distance from its origin,
        rounded up to a power of two). A function of the vertices alone:
        moving, turning or scaling a collider never changes it, so its BVH
        is never rebuilt for motion.

        Embree tests in float32 and a curve's output is rounded to float32:
        without a margin a segment passing within rounding distance of a
        sharp edge can be clear for the solver and crossing for another
        (float64, or differently rounded) test of the same output.
        """
        lo, hi = self._geometry()
        r = max(float(np.abs(lo).max()), float(np.abs(hi).max()), float(np.linalg.norm(hi - lo)))
        r = 2.0 ** np.ceil(np.log2(max(r, 1e-30)))
        return tol.CLEARANCE_ULPS * float(np.finfo(np.float32).eps) * float(r)

    def _margin_directions(self):
        """Unit area-weighted vertex normals, local space, (n, 3) (cached per
        vertices): where the clearance margin moves each vertex.

        Cheaper than :meth:`_offset_directions` (a deforming collider pays
        it every frame): every face moves out by the margin times the cosine
        between its normal and its vertices' normals, a positive fraction of
        it wherever faces meet at less than 180 degrees.
        """
        if getattr(self, "_margin_key", None) == self._version:
            return self._margin_dirs
        comps = self._used_components() if self._all_used else [
            np.ascontiguousarray(self._V[:, i]) for i in range(3)]
        F = [np.ascontiguousarray(self._F[:, k]) for k in range(3)]
        # face normals (area-weighted) as components, float64
        p = [[c.take(F[k]).astype(np.float64) for c in comps] for k in range(3)]
        e1 = [p[1][i] - p[0][i] for i in range(3)]
        e2 = [p[2][i] - p[0][i] for i in range(3)]
        fa = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
              e1[0] * e2[1] - e1[1] * e2[0]]
        # sum over each vertex's corners: corners sorted by vertex once (topology)
        _, face_of, first, verts = self._corners()
        n = len(self._V)
        vn = np.zeros((n, 3))
        for i in range(3):
            vn[verts, i] = np.add.reduceat(fa[i].take(face_of), first)
        self._margin_dirs = _unit(vn, np.sqrt(np.einsum("ij,ij->i", vn, vn))[:, None])
        self._margin_key = self._version
        return self._margin_dirs

    def _rim_faces(self):
        """Faces with an edge no other face shares (an open mesh's rims;
        topology only, cached)."""
        if getattr(self, "_rim_cache", None) is None:
            keys = _edge_keys(self._F, len(self._V))
            _, inv, cnt = np.unique(keys, return_inverse=True, return_counts=True)
            once = (cnt[inv] == 1).reshape(3, -1).any(axis=0)
            self._rim_cache = np.flatnonzero(once)
        return self._rim_cache

    def _rows(self, F):
        """:func:`.rays.triangle_rows` of the shell faces ``F`` (a topology
        property: prepared once per layout, reused by every rebuild)."""
        if self._backend_name == "numpy":
            return None
        key = len(F)  # the layout: 1 to 3 blocks of this collider's faces
        if key not in self._rows_cache:
            self._rows_cache[key] = triangle_rows(F)
        return self._rows_cache[key]

    def bounds_world(self, offset_wo: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """World-space axis-aligned bounds (lo, hi), grown by the offset."""
        lo, hi = self._geometry()
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        c_wo = apply(self._M[:3, :3], corners) + self._M[:3, 3]
        # shell vertices move up to OFFSET_MAX_STRETCH times the offset, and
        # out by the clearance margin
        pad = (offset_wo * tol.OFFSET_MAX_STRETCH * 1.01 + 1e-6 * (float(np.abs(c_wo).max()) + 1.0)
               + 2.0 * self.margin * norm_bound(self._M[:3, :3]))
        return c_wo.min(0) - pad, c_wo.max(0) + pad

    def _to_local(self, o_wo, d_wo):
        A, b = self.local_map()
        return apply(A, o_wo) + b, apply(A, d_wo)

    def _normals_world(self, prim, faces):
        """Unit world normals of shell triangles ``prim`` (:class:`ShellFaces`
        ``faces``), oriented as their shell (the inner one faces inward)."""
        idx, flip = faces.real[prim], faces.flip[prim]
        n_lo = self._face_normals(idx) * np.where(flip, -1.0, 1.0)[:, None]
        n_wo = apply(self._Minv[:3, :3].T, n_lo)  # inverse-transpose for normals
        return _unit(n_wo, np.linalg.norm(n_wo, axis=1, keepdims=True))

    # ------------------------------------------------------------- queries
    def segment_hits(self, o_wo, d_wo, offset_wo=0.0, threads=1) -> np.ndarray:
        """Which segments ``o + t d, t in [0, 1]`` hit the collider.

        Parameters
        ----------
        o_wo, d_wo : (k, 3) ndarray
            Segment starts and vectors (end minus start), world space.

        Returns
        -------
        (k,) bool
        """
        if self.empty or len(o_wo) == 0:
            return np.zeros(len(o_wo), bool)
        return self.segment_hits_local(*self._to_local(o_wo, d_wo), offset_wo, threads)

    def local_map(self) -> tuple[np.ndarray, np.ndarray]:
        """``(A, b)`` with ``x_lo = A @ x_wo + b`` (vectors: ``A @ v``).

        The local space is the collider's own space shifted to the centre of
        its bounds (where the float32 BVH lives).
        """
        return self._Minv[:3, :3], self._Minv[:3, 3] - self._center

    def segment_hits_local(self, o_lo, d_lo, offset_wo=0.0, threads=1) -> np.ndarray:
        """:meth:`segment_hits` for segments already in the collider's space."""
        if self.empty or len(o_lo) == 0:
            return np.zeros(len(o_lo), bool)
        be, _ = self._backend(offset_wo)
        return be.any_hit(o_lo, d_lo, 1.0 + tol.T_SLACK, threads)

    def segment_hit_details(self, o_wo, d_wo, offset_wo=0.0, faces=False):
        """First hit of each segment: parameter, point and unit normal.

        Returns
        -------
        hit : (k,) bool
        t : (k,) float64
            Segment parameter of the hit in [0, 1] (inf for none).
        n_wo : (k, 3) float64
            Unit face normal (world), oriented as the shell that was hit.
        face : (k,) int64
            Only with ``faces=True``: the face hit (index into :attr:`faces`;
            for an offset shell, the face the shell's triangle is made of), -1
            for none.
        """
        k = len(o_wo)
        if self.empty or k == 0:
            out = np.zeros(k, bool), np.full(k, np.inf), np.zeros((k, 3))
            return (*out, np.full(k, -1, np.int64)) if faces else out
        be, shell = self._backend(offset_wo)
        o_lo, d_lo = self._to_local(o_wo, d_wo)
        prim, t = be.hit_details(o_lo, d_lo, 1.0 + tol.T_SLACK)
        hit = prim >= 0
        t = np.where(hit, np.minimum(t, 1.0), np.inf)  # (a hit in the slack: at the end)
        n_wo = np.zeros((k, 3))
        if hit.any():
            n_wo[hit] = self._normals_world(prim[hit], shell)
            if len(shell.real) == len(self._F):  # the mesh itself (no offset shell)
                self._vertex_pushes(n_wo, hit, prim, o_lo, d_lo, t)
        if not faces:
            return hit, t, n_wo
        face = np.full(k, -1, np.int64)
        face[hit] = shell.real[prim[hit]]
        return hit, t, n_wo, face

    def _vertex_pushes(self, n_wo, hit, prim, o_lo, d_lo, t):
        """Hits that land on a vertex (``tol.VERTEX_HIT_BARY``) push along the vertex's
        angle-weighted normal: the faces around a vertex all contain the hit, and which
        one the tracer reports is decided by rounding (a curve through a UV sphere's
        pole would take its rotation axis from it). ``n_wo`` is updated in place."""
        w = np.flatnonzero(hit)
        tri = self._V[self._F[prim[w]]] - self._center  # (h, 3, 3), as _local_vertices
        p = o_lo[w] + t[w, None] * d_lo[w]
        bary = barycentric(p, tri[:, 0], tri[:, 1], tri[:, 2])  # (0 rows: degenerate)
        corner = np.argmax(bary, axis=1)
        at = bary[np.arange(len(w)), corner] > 1.0 - tol.VERTEX_HIT_BARY
        if not at.any():
            return
        vn = apply(self._Minv[:3, :3].T, self._vertex_normals()[self._F[prim[w[at]], corner[at]]])
        vn = _unit(vn, np.linalg.norm(vn, axis=1, keepdims=True))
        good = vn.any(axis=1)  # (a vertex whose face normals cancel keeps its face's)
        n_wo[w[at][good]] = vn[good]

    def _vertex_normals(self):
        """Angle-weighted unit vertex normals (local space, the winding's side), per shape."""
        F = self._F
        return self.derived("_vertex_normals", self._version, lambda: _angle_weighted(
            self._local_vertices(), F, self._face_normals(np.arange(len(F)))))

    @property
    def detects_pinch(self) -> bool:
        """Only closed, single-sided colliders have an inside."""
        return self.closed and not self.double_sided

    def contains(self, p_wo, offset_wo=0.0) -> np.ndarray:
        """Parity inside test (paper 3.1): more back faces than front faces.

        Three fixed directions vote, so a ray that grazes an edge cannot flip
        the answer. Always False for open or double-sided colliders.

        Parameters
        ----------
        p_wo : (k, 3) ndarray
            Points, world space.

        Returns
        -------
        (k,) bool
        """
        k = len(p_wo)
        if not self.detects_pinch or k == 0:
            return np.zeros(k, bool)
        p_wo = np.asarray(p_wo, np.float64)
        return self.contains_grid(p_wo, self.grid_coords(p_wo.T), offset_wo)

    def contains_grid(self, p_wo, q, offset_wo=0.0) -> np.ndarray:
        """:meth:`contains` with the points' :meth:`grid_coords` ``q`` given.

        Points in a grid cell no triangle of the tested shell touches share
        the answer of the cell's centre (the segment between them stays in
        the cell, so crosses nothing), computed once per cell and shape of
        the collider; the rest are traced. A collider whose shape stays
        (rigid: any motion) uses a fine grid whose touched cells are found
        from the triangles once per shape, so only roots right next to the
        surface are traced. A collider deformed since the last call at that
        offset, or made with ``deforming=True``, uses the coarse occupancy grid (no
        per-triangle work every frame): points near a vertex are traced. Both
        give the answer of tracing every point.
        """
        k = len(p_wo)
        if not self.detects_pinch or k == 0:
            return np.zeros(k, bool)
        # (per offset: the shells of several per-curve clearance levels, asked
        # once each per frame, are each a first call for their shape)
        seen = self._contains_seen
        static = seen.get(offset_wo) == self._version and not self.deforming
        if offset_wo not in seen and len(seen) >= 2 * (tol.OFFSET_LEVELS + 3):
            seen.clear()
        seen[offset_wo] = self._version
        if static:
            lo, h, dims = self._inside_grid()
            cells = self._cells(q, h, dims)
            touched = self._surface_cells(offset_wo).reshape(-1)
            trace = cells < 0
            trace[cells >= 0] = touched[cells[cells >= 0]]
        else:
            lo, h, dims, _, _ = self._occupancy()
            cells = self._cells(q, h, dims)
            # near_surface pads by h + max_edge: a point it calls far has no
            # vertex within max_edge of its own cell: no triangle crosses it
            trace = self.near_surface_grid(q, 0.0, offset_wo)
        inside = self._answers(static, offset_wo, dims)
        out = np.zeros(k, bool)
        far = np.flatnonzero(~trace & (cells >= 0))
        if len(far):
            flat = cells[far]
            ins = inside.reshape(-1)
            val = ins[flat]
            unknown = np.unique(flat[val < 0])
            if len(unknown):
                u = np.stack(np.unravel_index(unknown, inside.shape), axis=1)
                centre_lo = lo + (u + 0.5) * h + self._center
                centre_wo = apply(self._M[:3, :3], centre_lo) + self._M[:3, 3]
                ins[unknown] = self._parity(centre_wo, offset_wo)
                val = ins[flat]
            out[far] = val > 0
        # off the grid only an offset shell can reach (the grid holds every
        # vertex): those are traced where it may, else outside
        traced = np.flatnonzero(trace)
        off = traced[cells[traced] < 0]
        if len(off):
            near = self.near_surface_grid(q[:, off], 0.0, offset_wo)
            traced = np.concatenate([traced[cells[traced] >= 0], off[near]])
        if len(traced):
            out[traced] = self._parity(p_wo[traced], offset_wo)
        return out

    @staticmethod
    def _cells(q, h, dims):
        """Flat cell index of points ``q`` (3, k) in a grid of cell size ``h``
        and ``dims`` cells (-1 off the grid)."""
        c = [_cell_index(q[i] / h, dims[i]) for i in range(3)]
        ok = (c[0] >= 0) & (c[0] < dims[0]) & (c[1] >= 0) & (c[1] < dims[1])
        ok &= (c[2] >= 0) & (c[2] < dims[2])
        flat = (c[0] * dims[1] + c[1]) * dims[2] + c[2]
        return np.where(ok, flat, -1)

    def _inside_grid(self):
        """``(lo, h, dims)``: the occupancy grid subdivided ``tol.INSIDE_SUBDIV``
        times per axis, for the inside test's per-cell answers."""
        lo, h, dims, _, _ = self._occupancy()
        return lo, h / tol.INSIDE_SUBDIV, dims * tol.INSIDE_SUBDIV

    def _answers(self, fine, offset_wo, dims):
        """The inside test's per-cell answers (int8 grid of ``dims``: -1 unknown,
        0 outside, 1 inside) of the shell at ``offset_wo`` on the fine or the
        coarse grid, kept per shape and offset (several offset levels of
        per-curve clearances each keep theirs)."""
        key = (bool(fine), offset_wo)
        hit = self._inside_answers.get(key)
        if hit is not None and hit[0] == self._version and hit[1].shape == tuple(dims):
            return hit[1]
        _keep_recent(self._inside_answers, self._version, 2 * (tol.OFFSET_LEVELS + 3))
        inside = np.full(tuple(dims), -1, np.int8)
        self._inside_answers[key] = (self._version, inside)
        return inside

    def _surface_cells(self, offset_wo):
        """(dims) bool grid: the cells of the occupancy grid that a triangle of
        the shell at ``offset_wo`` may touch (each triangle's bounding box,
        grown by how far the shell moves it; cached per shape and offset)."""
        hit = self._touched.get(offset_wo)
        if hit is not None and hit[0] == self._version:
            return hit[1]
        lo, h, dims = self._inside_grid()
        V = self._local_vertices()
        grow = self.margin * 1.01 + offset_wo * tol.OFFSET_MAX_STRETCH * 1.01 * norm_bound(
            self._Minv[:3, :3]) + 1e-9 * h
        F = [np.ascontiguousarray(self._F[:, k]) for k in range(3)]
        ilo = np.empty((len(self._F), 3), np.int64)
        ihi = np.empty_like(ilo)
        for i in range(3):
            x = np.ascontiguousarray(V[:, i])
            c0, c1, c2 = x.take(F[0]), x.take(F[1]), x.take(F[2])
            mn = np.minimum(np.minimum(c0, c1), c2)
            mx = np.maximum(np.maximum(c0, c1), c2)
            ilo[:, i] = np.floor((mn - grow - lo[i]) / h)
            ihi[:, i] = np.floor((mx + grow - lo[i]) / h)
        touched = mark_boxes(ilo, ihi, dims)
        _keep_recent(self._touched, self._version, tol.OFFSET_LEVELS + 3)
        self._touched[offset_wo] = (self._version, touched)
        return touched

    def _parity(self, p_wo, offset_wo):
        """Ray-parity inside test of world points (three votes).

        Each vote follows one fixed direction through the whole shell and
        counts back faces minus front faces crossed (the winding number: a
        point inside overlapping closed parts is inside); a collider of one
        closed part without an offset shell takes the first crossing's side
        instead (the same answer, one ray query). The first two votes are
        cast together, the third only where they disagree.
        """
        k = len(p_wo)
        be, _ = self._backend(offset_wo)
        p_lo = self._to_local(np.asarray(p_wo), np.zeros((k, 3)))[0]  # (float64)
        lo, hi = self._geometry()
        diag = float(np.linalg.norm(hi - lo)) or 1.0
        step = tol.PARITY_STEP_REL * diag
        shell = offset_wo * tol.OFFSET_MAX_STRETCH * norm_bound(self._Minv[:3, :3])
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

        if offset_wo == 0 and self.repairs.parts == 1:
            votes = first_facing  # one closed surface, wound outward: its first hit decides
        two = votes(np.concatenate([p_lo, p_lo]), np.repeat(_PARITY_DIRS[:2], k, axis=0))
        v1, v2 = two[:k], two[k:]
        out = v1 & v2
        split = np.flatnonzero(v1 != v2)
        if len(split):
            out[split] = votes(p_lo[split], np.broadcast_to(_PARITY_DIRS[2], (len(split), 3)))
        return out

    def closest_points(self, q_wo):
        """Closest point on the (un-inflated) mesh to each query and its normal.

        Parameters
        ----------
        q_wo : (k, 3) ndarray
            Query points, world space.

        Returns
        -------
        p_wo : (k, 3) float64
        n_wo : (k, 3) float64
            Unit face normal at the closest point.
        """
        k = len(q_wo)
        if self.empty or k == 0:
            return np.array(q_wo, np.float64), np.zeros((k, 3))
        q_lo = self._to_local(np.asarray(q_wo, np.float64), np.zeros((k, 3)))[0]
        index = self.derived("_closest", self._version, lambda: [None])  # built on first use
        p_lo, face, index[0] = closest_points_on_mesh(self._local_vertices(), self._F, q_lo,
                                                      index[0])
        p_wo = apply(self._M[:3, :3], p_lo + self._center) + self._M[:3, 3]
        m = len(self._F)
        return p_wo, self._normals_world(face, ShellFaces(np.arange(m), np.zeros(m, bool)))
