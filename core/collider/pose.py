"""Where a collider is and where it was: its world matrix, its previous placement
and the velocity of its surface (Follow Collider Motion).

:class:`Pose` owns the matrix (and its inverse) and the previous placement
(:class:`Placement`); a new shape is set through it too (:meth:`Pose.place`,
:meth:`Pose.set_vertices`), so that the vertices it replaces become the
previous ones. It maps world space to the collider's local space (its own
space centred on the mesh: :meth:`Pose.local_map`).

Rigid parts handed over as vertices
-----------------------------------
A hat, belt or buckle skinned to one bone arrives as new vertices every frame,
although it only moves rigidly. A collider given its *rest shape*
(``Collider(rest=...)``: the undeformed mesh, which its topology and repairs
are then made of) checks every new set of vertices, the first one included:
when they are, to within ``tol.RIGID_FIT_ULPS`` float32 ulps, the rest shape
moved by one rigid transform (:func:`rigid_fit`), the pose keeps the
structures of the rest shape (the mesh's shape is the rest shape, built once)
and places them with the fitted transform: the
*effective* matrix :attr:`Pose.M` is the user's matrix times the fit. The
fit's residual is covered by the shells (``Shells``), which are then built
that much farther out (:attr:`Pose.allowance`); everything else (the occupancy grid, the inside
test, normals, velocities) works on the fitted placement as on any rigid
motion. The public placement (:attr:`Pose.user_M`, :attr:`Pose.vertices`,
:attr:`Pose.previous`) is always what the caller gave.

The fit is always against the rest shape, never against the last shape built:
a frame's result is a function of the rest shape and that frame's placement,
whatever frame the collider was constructed at and whatever frames were played
before. It is not bit-identical to a collider without a rest shape (which
builds every new shape: another BVH), only as safe (the allowance) and within
the solver's own precision of it (tests/core/test_collider_rigid_fit.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import tolerances as tol
from ..closest import barycentric
from ..errors import ColliderError
from ..rotations import apply, det3, inv_affine, kabsch, norm_bound, quat_fit, quat_matrix


def as_matrix(M) -> tuple[np.ndarray, np.ndarray]:
    """``(M, M^-1)`` (4, 4) float64 of an affine world transform (None: identity),
    checked (ColliderError saying what is wrong)."""
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


def ulps_of(r) -> float:
    """One float32 ulp of coordinates of magnitude up to ``r``, rounded up to a
    power of two (as ``Collider.margin``: a function of the magnitude's binade)."""
    return float(np.finfo(np.float32).eps) * float(2.0 ** np.ceil(np.log2(max(r, 1e-30))))


def rigid_fit(ref, V, used, lo, hi):
    """A rigid transform ``T`` (4, 4) that moves every used vertex of ``ref`` to
    within ``allowance`` of its place in ``V``: ``(T, allowance)``, or None when
    there is none.

    ``allowance`` is the largest distance found (the residual) rounded up to a
    power of two times one float32 ulp (:func:`ulps_of`) of the largest of the
    extent ``hi - lo``, the coordinates of the used ``ref`` vertices (their
    bounds ``lo``, ``hi``) and those of their fitted places; at most
    ``tol.RIGID_FIT_ULPS`` of them. Float32 skinning leaves residuals under one
    ulp: the allowance is one ulp every frame, and the shells it asks for
    (``Shells``) are built once and kept while the collider moves. The rotation
    is fitted to a spread sample of the used vertices (``tol.RIGID_FIT_SAMPLE``:
    Horn's quaternion, :func:`rotations.quat_fit`; Kabsch where that is not
    trusted), then checked on the sample (a collider that deforms is turned down there, at a small
    cost) and on every used vertex. Only the check decides: the fit need not be
    the best one, only within the allowance.

    Parameters
    ----------
    ref, V : (n, 3) float32
        The vertices the collider's structures describe, and the new ones.
    used : (k,) int or None
        The vertices faces use (None: all).
    lo, hi : (3,) float64
        Bounds of the used vertices of ``ref``.
    """
    n = len(ref) if used is None else len(used)
    if n == 0:
        return None
    k = min(n, tol.RIGID_FIT_SAMPLE)
    pick = np.linspace(0, n - 1, k).astype(np.int64)
    if used is not None:
        pick = used[pick]
    a = ref[pick].astype(np.float64)
    b = V[pick].astype(np.float64)
    # A rigid motion keeps distances: one that moves every vertex by at most the
    # tolerance changes the distance between two of them by at most twice it (a
    # deforming collider is turned down here, before any fit).
    half = k // 2
    da, db = a[half:2 * half] - a[:half], b[half:2 * half] - b[:half]
    change = np.abs(np.sqrt(np.einsum("ki,ki->k", da, da))
                    - np.sqrt(np.einsum("ki,ki->k", db, db))).max(initial=0.0)
    lo_b, hi_b = b.min(axis=0), b.max(axis=0)
    r = max(float(np.abs(lo).max()), float(np.abs(hi).max()), float(np.linalg.norm(hi - lo)),
            float(np.abs(lo_b).max()), float(np.abs(hi_b).max()))
    if change > 2.0 * tol.RIGID_FIT_ULPS * ulps_of(2.0 * r):
        return None
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    a -= ca
    b -= cb
    H = np.einsum("ki,kj->ij", a, b)[None]
    q, ok = quat_fit(H)
    R = quat_matrix(q)[0] if ok[0] else kabsch(H)[0][0]
    t = cb - apply(R, ca[None])[0]
    # the fitted places' coordinates: within half the diagonal of the moved centre
    size = float(np.linalg.norm(hi - lo))
    moved = apply(R, (0.5 * (lo + hi))[None])[0] + t
    r = max(float(np.abs(lo).max()), float(np.abs(hi).max()), size,
            float(np.abs(moved).max()) + 0.5 * size)
    ulp = ulps_of(r)
    limit = tol.RIGID_FIT_ULPS * ulp

    def residual(x, y):
        """The largest distance between ``T x`` and ``y`` (rows, float32), computed
        on component arrays (long passes: most of a fit's time)."""
        sq = None
        for i in range(3):
            d = y[:, i].astype(np.float64)
            for j in range(3):
                d -= R[i, j] * x[:, j]
            d -= t[i]
            d *= d
            sq = d if sq is None else sq + d
        return float(np.sqrt(sq.max()))

    if residual(ref[pick], V[pick]) > limit:
        return None
    off = residual(ref, V) if used is None else residual(ref[used], V[used])
    if not off <= limit:
        return None
    # the allowance: the residual rounded up to a power of two times an ulp
    # (float32 skinning leaves under one: one ulp, the same every frame), so
    # that the few shells it asks for are built once and kept (see Shells)
    allowance = ulp * float(2.0 ** np.ceil(np.log2(max(off / ulp, 1.0))))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T, allowance


@dataclass(frozen=True)
class Placement:
    """Where a collider was: its world ``matrix`` (4, 4) float64 and its own
    ``vertices`` (n, 3) float32 (read-only), see ``Collider.previous``."""

    matrix: np.ndarray
    vertices: np.ndarray


@dataclass(frozen=True)
class Shape:
    """Vertices a collider was given, and how its structures place them.

    ``vertices`` (n, 3) float32: as given; ``ref``: the mesh's vertices at the
    time (the shape its structures describe); ``fit`` (4, 4) or None:
    ``vertices`` are ``ref`` moved by this rigid transform (within the fit's
    tolerance), None when they are ``ref`` itself; ``allowance``: the distance
    the fit may be off by (own units, 0 without a fit).
    """

    vertices: np.ndarray
    ref: np.ndarray
    fit: np.ndarray | None = None
    allowance: float = 0.0


class Pose:
    """A collider's placement: matrix, previous placement, velocities.

    Parameters
    ----------
    mesh : ColliderMesh
        The collider's mesh (its vertices are the shape part of a placement).
    matrix : (4, 4) array_like or None
        World transform (None: identity).
    nearest_faces : callable
        ``nearest_faces(x_lo) -> (k,) int``: the face nearest each local point
        (the closest-point part), for velocities of a deformation without faces.

    Attributes
    ----------
    M, Minv : (4, 4) float64
        The effective world transform of the mesh's vertices (the user's matrix
        times the rigid fit of the last vertices given, when there is one) and
        its inverse: what every query maps with.
    user_M : (4, 4) float64
        The matrix as given.
    shape : Shape
        The vertices as given and how they are placed.
    user_version : int
        +1 each time the vertices given change (``Collider.version``).
    """

    def __init__(self, mesh, matrix, nearest_faces, fit_rest=False):
        self.mesh = mesh
        self.user_M, _ = as_matrix(matrix)
        self.shape = Shape(mesh.V, mesh.V)
        # The rest shape every fit is against, None without fits (its bounds
        # kept: the mesh's change); fit_rest: the mesh was made of it.
        self.rest = mesh.V if fit_rest else None
        self.rest_bounds = tuple(b.copy() for b in mesh.bounds())
        self.user_version = 0
        self._nearest_faces = nearest_faces
        self._set_effective()
        # The previous placement (see previous): None unknown, else [matrix,
        # Shape], a part None where it is the current one.
        self._prev = None

    def _set_effective(self):
        fit = self.shape.fit
        if fit is None:
            self.M = self.user_M
        else:
            self.M = np.einsum("ij,jk->ik", self.user_M, fit)
        self.Minv = inv_affine(self.M)

    @property
    def allowance(self) -> float:
        """How far the fitted placement of the mesh may be from the vertices
        given (own units; 0 without a fit): the shells lie that much farther out."""
        return self.shape.allowance

    @property
    def vertices(self) -> np.ndarray:
        """The vertices as given (n, 3) float32."""
        return self.shape.vertices

    # ------------------------------------------------------------- update
    def set_matrix(self, M):
        """Assign the matrix (checked): an update of the matrix part."""
        M, _ = as_matrix(M)
        self._remember(matrix=True)
        self.user_M = M
        self._set_effective()

    def set_vertices(self, V2):
        """Assign the vertices (checked against the topology): an update of the
        shape part (a new shape when they changed and did not only move rigidly)."""
        V2 = self.mesh.check_vertices(V2)
        self._remember(vertices=True)
        self._set_shape(V2)

    def place(self, matrix=None, vertices=None):
        """This frame's placement as one update (see ``Collider.place``)."""
        mesh = self.mesh
        M = None if matrix is None else as_matrix(matrix)[0]
        V2 = None if vertices is None else mesh.check_vertices(vertices)
        self._prev = [self.user_M, self.shape]
        if M is not None:
            self.user_M = M
        if V2 is not None:
            self._set_shape(V2)
        else:
            self._set_effective()

    def start(self, V2):
        """The first vertices (checked), of a collider made of its rest shape:
        placed as any later ones are, with no previous placement and no new
        version (``Collider.version`` stays 0)."""
        V2 = self.mesh.check_vertices(V2, "vertices")
        self.shape = self.fitted(V2)
        if self.shape.ref is not self.mesh.V:
            self.mesh.set_shape(self.shape.ref)
        self._set_effective()

    def _set_shape(self, V2):
        """New vertices given (checked): placed by a rigid fit of the mesh's shape,
        or a new shape; the effective matrix follows."""
        if not np.array_equal(V2, self.shape.vertices):
            self.user_version += 1
            self.shape = self.fitted(V2)
            if self.shape.ref is not self.mesh.V:  # V2, or the rest shape again
                self.mesh.set_shape(self.shape.ref)
        self._set_effective()

    def fitted(self, V2) -> Shape:
        """The :class:`Shape` of vertices ``V2`` (same topology) against the rest
        shape: the rest shape itself, a rigid fit of it, or ``V2`` as a new one
        (its ``ref`` is then ``V2``); without a rest shape, the mesh's current
        shape or a new one."""
        mesh = self.mesh
        ref = mesh.V if self.rest is None else self.rest
        if np.array_equal(V2, ref):
            return Shape(ref, ref)
        if self.rest is not None and tol.RIGID_FIT_ULPS > 0 and len(mesh.F):
            fit = rigid_fit(ref, V2, None if mesh.all_used else mesh.used, *self.rest_bounds)
            if fit is not None:
                return Shape(V2, ref, *fit)
        return Shape(V2, V2)

    def _remember(self, matrix=False, vertices=False):
        """Assigning one part of the placement: its current value becomes that
        part of :attr:`previous` (the other part's stays as it was)."""
        if self._prev is None:
            self._prev = [None, None]
        if matrix:
            self._prev[0] = self.user_M
        if vertices:
            self._prev[1] = self.shape

    @property
    def previous(self) -> Placement | None:
        """The placement before the last update, or None when none is known."""
        if self._prev is None:
            return None
        M, S = self._prev
        M = self.user_M if M is None else M
        V = (self.shape if S is None else S).vertices.view()
        V.flags.writeable = False
        return Placement(M.copy(), V)

    def set_previous(self, matrix=None, vertices=None):
        """Set :attr:`previous` explicitly (None: that part did not move)."""
        M = None if matrix is None else as_matrix(matrix)[0]
        S = None
        if vertices is not None:
            V2 = self.mesh.check_vertices(vertices, "previous vertices")
            if not np.array_equal(V2, self.shape.vertices):
                S = self.fitted(V2)  # (the current vertices: no deformation)
        self._prev = [M, S]

    def forget_previous(self):
        """No known motion until the next update."""
        self._prev = None

    # ------------------------------------------------------------ mapping
    def local_map(self) -> tuple[np.ndarray, np.ndarray]:
        """``(A, b)`` with ``x_lo = A @ x_wo + b`` (vectors: ``A @ v``): the local
        space is the collider's own space shifted to the centre of its bounds."""
        return self.Minv[:3, :3], self.Minv[:3, 3] - self.mesh.center

    def to_local(self, o_wo, d_wo):
        """Points ``o_wo`` and vectors ``d_wo`` (k, 3) in the local space."""
        A, b = self.local_map()
        return apply(A, o_wo) + b, apply(A, d_wo)

    def bounds_world(self, offset_wo: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """World-space axis-aligned bounds (lo, hi), grown by the offset."""
        lo, hi = self.mesh.bounds()
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        c_wo = apply(self.M[:3, :3], corners) + self.M[:3, 3]
        # shell vertices move up to OFFSET_MAX_STRETCH times the offset, and
        # out by the clearance margin (and a fitted placement's allowance)
        stretch = norm_bound(self.M[:3, :3])
        pad = (offset_wo * tol.OFFSET_MAX_STRETCH * 1.01 + 1e-6 * (float(np.abs(c_wo).max()) + 1.0)
               + 2.0 * self.mesh.margin * stretch)
        if self.allowance:
            pad += self.allowance * tol.OFFSET_MAX_STRETCH * 1.01 * stretch
        return c_wo.min(0) - pad, c_wo.max(0) + pad

    # ---------------------------------------------------------- velocities
    def velocities(self, p_wo, faces=None) -> np.ndarray:
        """Velocity of the surface at points ``p_wo`` (world units per update),
        see ``Collider.velocities``."""
        mesh = self.mesh
        p_wo = np.asarray(p_wo, np.float64).reshape(-1, 3)
        k = len(p_wo)
        out = np.zeros((k, 3))
        if self._prev is None or k == 0 or len(mesh.F) == 0:
            return out
        M0, S0 = self._prev
        M0 = self.user_M if M0 is None else M0
        S0 = self.shape if S0 is None else S0
        # The previous placement of the mesh, as the current one is: an effective
        # matrix and the vertices it places (the same array: a rigid motion).
        if S0.fit is not None:
            M0 = np.einsum("ij,jk->ik", M0, S0.fit)
        V0 = S0.ref
        moved_m = not np.array_equal(M0, self.M)
        moved_v = V0 is not mesh.V
        if not (moved_m or moved_v):
            return out
        x = apply(self.Minv[:3, :3], p_wo) + self.Minv[:3, 3]  # own space
        if moved_v:
            if faces is None:
                faces = self._nearest_faces(x - mesh.center)
            f = mesh.F[np.asarray(faces, np.int64)]
            tri = mesh.V[f].astype(np.float64)  # (k, 3, 3)
            w = barycentric(x, tri[:, 0], tri[:, 1], tri[:, 2])
            w = np.clip(w, 0.0, None)
            total = w.sum(axis=1, keepdims=True)
            w = np.where(total > 0, w / np.where(total > 0, total, 1.0), 1.0 / 3.0)
            move = V0[f].astype(np.float64) - tri  # each corner's motion back in time
            x = x + np.einsum("ki,kij->kj", w, move)
        prev = apply(M0[:3, :3], x) + M0[:3, 3]
        return p_wo - prev
