"""Where a collider is and where it was: its world matrix, its previous placement
and the velocity of its surface (Follow Collider Motion).

:class:`Pose` owns the matrix (and its inverse) and the previous placement
(:class:`Placement`); a new shape is set through it too (:meth:`Pose.place`,
:meth:`Pose.set_vertices`), so that the vertices it replaces become the
previous ones. It maps world space to the collider's local space (its own
space centred on the mesh: :meth:`Pose.local_map`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import tolerances as tol
from ..closest import barycentric
from ..errors import ColliderError
from ..rotations import apply, det3, inv_affine, norm_bound


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


@dataclass(frozen=True)
class Placement:
    """Where a collider was: its world ``matrix`` (4, 4) float64 and its own
    ``vertices`` (n, 3) float32 (read-only), see ``Collider.previous``."""

    matrix: np.ndarray
    vertices: np.ndarray


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
    """

    def __init__(self, mesh, matrix, nearest_faces):
        self.mesh = mesh
        self.M, self.Minv = as_matrix(matrix)
        self._nearest_faces = nearest_faces
        # The previous placement (see previous): None unknown, else [matrix,
        # vertices], a part None where it is the current one.
        self._prev = None

    # ------------------------------------------------------------- update
    def set_matrix(self, M):
        """Assign the matrix (checked): an update of the matrix part."""
        M = as_matrix(M)
        self._remember(matrix=True)
        self.M, self.Minv = M

    def set_vertices(self, V2):
        """Assign the vertices (checked against the topology): an update of the
        shape part (a new shape version when they changed)."""
        mesh = self.mesh
        V2 = mesh.check_vertices(V2)
        self._remember(vertices=True)
        if np.array_equal(V2, mesh.V):
            return
        mesh.set_shape(V2)

    def place(self, matrix=None, vertices=None):
        """This frame's placement as one update (see ``Collider.place``)."""
        mesh = self.mesh
        M = None if matrix is None else as_matrix(matrix)
        V2 = None if vertices is None else mesh.check_vertices(vertices)
        self._prev = [self.M, mesh.V]
        if M is not None:
            self.M, self.Minv = M
        if V2 is not None and not np.array_equal(V2, mesh.V):
            mesh.set_shape(V2)

    def _remember(self, matrix=False, vertices=False):
        """Assigning one part of the placement: its current value becomes that
        part of :attr:`previous` (the other part's stays as it was)."""
        if self._prev is None:
            self._prev = [None, None]
        if matrix:
            self._prev[0] = self.M
        if vertices:
            self._prev[1] = self.mesh.V

    @property
    def previous(self) -> Placement | None:
        """The placement before the last update, or None when none is known."""
        if self._prev is None:
            return None
        M, V = self._prev
        M = self.M if M is None else M
        V = (self.mesh.V if V is None else V).view()
        V.flags.writeable = False
        return Placement(M.copy(), V)

    def set_previous(self, matrix=None, vertices=None):
        """Set :attr:`previous` explicitly (None: that part did not move)."""
        M = None if matrix is None else as_matrix(matrix)[0]
        V2 = None if vertices is None else self.mesh.check_vertices(vertices,
                                                                    "previous vertices")
        if V2 is not None and np.array_equal(V2, self.mesh.V):
            V2 = None  # (the current vertices: no deformation)
        self._prev = [M, V2]

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
        # out by the clearance margin
        pad = (offset_wo * tol.OFFSET_MAX_STRETCH * 1.01 + 1e-6 * (float(np.abs(c_wo).max()) + 1.0)
               + 2.0 * self.mesh.margin * norm_bound(self.M[:3, :3]))
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
        M0, V0 = self._prev
        moved_m = M0 is not None and not np.array_equal(M0, self.M)
        moved_v = V0 is not None and V0 is not mesh.V
        if not (moved_m or moved_v):
            return out
        M0 = self.M if M0 is None else M0
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
