"""Region of Influence (paper section 4).

Motion added after collision (wind, jiggle, or any displacement) is
restricted per CV to within its collider distance, so collision-free
curves stay collision free.
"""

from __future__ import annotations

import numpy as np

from ..curves import as_points, check_curves, row_norm
from ..errors import InputError


def region_of_influence(points, offsets, displaced, distance, margin=0.99):
    """Restrict each CV's displacement to less than ``margin`` times its collider distance.

    Every CV keeps the direction of its displacement ``displaced - points``
    and its length is clamped to ``margin * distance``; roots never move.
    Why this is safe: a CV's distance is at most the distance of each of
    its segments, so both ends of a segment move by less than that
    segment's distance ``D``; every point of the segment moves by a convex
    combination of its ends' displacements, i.e. by less than ``D``, so it
    cannot reach the mesh. The straight-line motion from ``points`` to the
    result is collision free too. With a lower-bound ``distance`` (see
    :func:`~core.pipeline.collider_distance`) the guarantee holds as well.

    Parameters
    ----------
    points : (P, 3) array_like of float
        Collision-free curves (e.g. FurCollide's output), world space.
    offsets : (C+1,) array_like of int
    displaced : (P, 3) array_like of float
        The same curves with the motion applied.
    distance : (P,) array_like of float
        Collider distance of every CV of ``points`` (>= 0, ``inf`` allowed).
    margin : float, default 0.99
        In (0, 1]: fraction of the distance a CV may travel. Below 1 keeps a
        gap to the mesh (1 allows reaching it: touching, not crossing).

    Returns
    -------
    (P, 3) ndarray of float64

    Raises
    ------
    InputError
        Malformed arrays, negative or NaN distances, margin outside (0, 1].

    Notes
    -----
    Known artifact: CVs near a collider barely move while their neighbours
    far from it follow the wind, so curves can bunch up near colliders.
    Denser guides (shorter segments, more curves) reduce it.
    """
    pts, off = check_curves(points, offsets)
    disp = as_points(displaced, "displaced")
    if disp.shape != pts.shape:
        raise InputError(f"displaced has shape {disp.shape}, expected {pts.shape}")
    if not np.isfinite(disp).all():
        i = int(np.argmax(~np.isfinite(disp).all(axis=1)))
        c = int(np.searchsorted(off, i, "right") - 1)
        raise InputError(f"displaced: point {i} (curve {c}) is not finite")
    d = np.asarray(distance, np.float64)
    if d.shape != (len(pts),):
        raise InputError(f"distance must have shape ({len(pts)},), got {d.shape}")
    if not (d >= 0).all():  # NaN compares false
        i = int(np.argmax(~(d >= 0)))
        c = int(np.searchsorted(off, i, "right") - 1)
        raise InputError(f"distance of point {i} (curve {c}) must be >= 0, got {d[i]}")
    margin = float(margin)
    if not 0 < margin <= 1:
        raise InputError(f"margin must be in (0, 1], got {margin}")
    u = disp - pts
    L = row_norm(u)
    limit = margin * d
    over = L > limit
    scale = np.where(over, limit / np.where(over, L, 1.0), 1.0)
    out = pts + u * scale[:, None]
    out[off[:-1]] = pts[off[:-1]]
    return out
