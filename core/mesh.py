"""Triangle meshes: the checks of the fur pipeline's surfaces, areas, and the one rule
for degenerate faces (growth surfaces and colliders alike).

Meshes are ``V`` (n, 3) vertices and ``F`` (m, 3) triangles (indices into ``V``).
"""

from __future__ import annotations

import numpy as np

from . import tolerances as tol
from .errors import ColliderError


def check_surface(V, F, name="surface"):
    """Validate a triangle mesh; return ``(V float64 (n, 3), F int64 (m, 3))``.

    Raises
    ------
    ColliderError
        Empty, non-finite or malformed mesh, indices out of range.
    """
    try:
        V = np.asarray(V, np.float64)
        F = np.asarray(F)
    except Exception as exc:
        raise ColliderError(f"{name} must be (n, 3) vertices and (m, 3) faces: {exc}") from None
    if V.ndim != 2 or V.shape[1] != 3:
        raise ColliderError(f"{name} vertices must have shape (n, 3), got {V.shape}")
    if F.size == 0:
        raise ColliderError(f"{name} has no triangle")
    if F.ndim != 2 or F.shape[1] != 3:
        raise ColliderError(f"{name} faces must have shape (m, 3) (triangles), got {F.shape}")
    if not np.issubdtype(F.dtype, np.integer):
        raise ColliderError(f"{name} faces must be integers, got dtype {F.dtype}")
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        raise ColliderError(f"{name}: vertex {int(np.argmax(bad))} is not finite")
    F = F.astype(np.int64)
    bad = ((F < 0) | (F >= len(V))).any(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise ColliderError(
            f"{name}: face {i} {F[i].tolist()} indexes a vertex out of range "
            f"(the mesh has {len(V)} vertices)"
        )
    return V, F


def triangle_areas(V, F):
    """(m,) float64 triangle areas."""
    a = V[F[:, 0]]
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - a, V[F[:, 2]] - a), axis=1)


def degenerate_faces(V, F):
    """(m,) bool: degenerate faces (colliders drop or refuse them, Fur Attach does not
    bind to them).

    A repeated vertex, or an area at most ``tolerances.DEGENERATE_AREA_REL`` times
    the squared diagonal of the mesh's bounding box (computed in float64, from the
    squared cross product: no square root).
    """
    if len(F) == 0:
        return np.zeros(0, bool)
    V64 = np.asarray(V).astype(np.float64)
    diag = float(np.linalg.norm(V64.max(0) - V64.min(0))) or 1.0
    a = np.cross(V64[F[:, 1]] - V64[F[:, 0]], V64[F[:, 2]] - V64[F[:, 0]])
    area2 = np.einsum("ij,ij->i", a, a)  # (0 for a repeated vertex)
    return area2 <= (2 * tol.DEGENERATE_AREA_REL * diag**2) ** 2
