"""Shared helpers of the fur pipeline: input checks and curve layout.

Curves use Blender's layout: ``points`` (P, 3) and ``offsets`` (C+1,) int,
curve ``i`` is ``points[offsets[i]:offsets[i + 1]]``.
"""

from __future__ import annotations

import numbers

import numpy as np

from .. import tolerances as tol
from ..errors import ColliderError, InputError
from ..layout import check_offsets
from ..rays import default_threads


def thread_count(threads) -> int:
    """Threads a stage may use: ``threads`` (a positive integer), or every CPU
    for None (as :attr:`core.settings.Settings.threads`)."""
    if threads is None:
        return default_threads()
    if isinstance(threads, (bool, np.bool_)) or not isinstance(threads, numbers.Integral) \
            or threads < 1:
        raise InputError(f"threads must be a positive integer or None, got {threads!r}")
    return int(threads)


def check_curves(points, offsets, name="points", finite=True):
    """Validate and return ``(points float64 (P, 3), offsets int64 (C+1,))``.

    ``finite=False`` accepts non-finite points (a caller that sets such curves
    aside, as the solver does: :func:`bad_curves`).

    Raises
    ------
    InputError
        Malformed arrays; the message names the curve or point at fault.
    """
    off = check_offsets(offsets, min_curves=0)
    pts = as_points(points, name)
    if len(pts) != off[-1]:
        raise InputError(f"{name} has {len(pts)} rows but offsets describe {int(off[-1])} points")
    if finite and not np.isfinite(pts).all():  # (one pass; rows only to name the culprit)
        i = int(np.argmax(~np.isfinite(pts).all(axis=1)))
        c = int(np.searchsorted(off, i, "right") - 1)
        raise InputError(f"{name}: point {i} (curve {c}) is not finite: {pts[i].tolist()}")
    return pts, off


def as_points(points, name="points"):
    """(k, 3) float64 array (no finiteness check)."""
    try:
        pts = np.asarray(points)
    except Exception as exc:
        raise InputError(f"{name} must be a (k, 3) float array: {exc}") from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"{name} must have shape (k, 3), got {pts.shape}")
    if not (np.issubdtype(pts.dtype, np.floating) or np.issubdtype(pts.dtype, np.integer)):
        raise InputError(f"{name} must be numeric, got dtype {pts.dtype}")
    return pts.astype(np.float64)


def check_finite(a, name, off=None):
    a = np.asarray(a, np.float64)
    if np.isfinite(a).all():
        return a
    bad = ~np.isfinite(a.reshape(len(a), -1)).all(axis=1) if a.ndim > 1 else ~np.isfinite(a)
    if bad.any():
        i = int(np.argmax(bad))
        where = f"row {i}"
        if off is not None:
            where += f" (curve {int(np.searchsorted(off, i, 'right') - 1)})"
        raise InputError(f"{name}: {where} is not finite")
    return a


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
    """(m,) bool: degenerate faces, by the colliders' rule (``Collider`` drops the same).

    Repeated vertices, or an area at most ``tolerances.DEGENERATE_AREA_REL``
    times the squared diagonal of the mesh's bounding box.
    """
    diag = float(np.linalg.norm(V.max(0) - V.min(0))) or 1.0
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 0] == F[:, 2])
    return rep | (triangle_areas(V, F) <= tol.DEGENERATE_AREA_REL * diag**2)


def layout(off):
    """Per-point indices of the layout.

    Returns
    -------
    curve : (P,) int64
        Curve of each point.
    index : (P,) int64
        Index of each point within its curve (0 = root).
    seg_start : (S,) int64
        First point of each segment (every point but the tips).
    """
    P = int(off[-1])
    sizes = np.diff(off)
    curve = np.repeat(np.arange(len(sizes)), sizes)
    index = np.arange(P) - off[curve]
    is_tip = np.zeros(P, bool)
    is_tip[off[1:] - 1] = True
    return curve, index, np.flatnonzero(~is_tip)


def row_norm(v):
    """Lengths of the rows of ``v`` (k, 3): ``np.linalg.norm(v, axis=1)`` in long passes."""
    return np.sqrt(np.einsum("ij,ij->i", v, v))


def uniform_size(off):
    """The common point count of the curves, or 0 when they differ (or there is none)."""
    if len(off) < 2:
        return 0
    n = int(off[1] - off[0])
    return n if int(off[-1]) == n * (len(off) - 1) and (np.diff(off) == n).all() else 0


def segmented_cumsum(x, off):
    """Cumulative sum of rows of ``x`` restarting at every curve (inclusive).

    ``x`` is per point (P, ...); the result at point j of a curve is
    ``x[root] + ... + x[j]`` of that curve. Computed on a padded
    (C, max_len, ...) array so rounding never carries across curves.
    """
    sizes = np.diff(off)
    C = len(sizes)
    if C == 0:
        return np.zeros_like(x, dtype=np.float64)
    n = uniform_size(off)
    if n:  # every curve n points: the padded array is x itself
        return np.cumsum(np.asarray(x, np.float64).reshape((C, n) + x.shape[1:]),
                         axis=1).reshape(x.shape)
    curve = np.repeat(np.arange(C), sizes)
    index = np.arange(len(x)) - off[curve]
    pad = np.zeros((C, int(sizes.max())) + x.shape[1:])
    pad[curve, index] = x
    return np.cumsum(pad, axis=1)[curve, index]


def arc_length(points, off):
    """Normalized arc length per point: 0 at roots, 1 at tips.

    Returns
    -------
    s : (P,) float64
    seg_len : (P,) float64
        Length of the segment ending at each point (0 at roots).
    """
    P = len(points)
    seg_len = np.zeros(P)
    d = row_norm(np.diff(points, axis=0))
    seg_len[1:] = d
    seg_len[off[:-1]] = 0.0
    cum = segmented_cumsum(seg_len, off)
    total = cum[off[1:] - 1]
    sizes = np.diff(off)
    tot = np.repeat(total, sizes)
    _, index, _ = layout(off)
    n = np.repeat(sizes - 1, sizes)
    # zero-length curves: fall back to the CV index
    s = np.where(tot > 0, cum / np.where(tot > 0, tot, 1.0), index / np.maximum(n, 1))
    return s, seg_len


def rechain(points, off, moved):
    """Keep every segment's length: re-chain the moved segment directions from the root.

    Segment j of the result has the direction of ``moved[j+1] - moved[j]``
    and the length of ``points[j+1] - points[j]``; roots are ``points``'
    roots. A moved segment of zero length keeps its original direction.

    Parameters
    ----------
    points, moved : (P, 3) float64
    off : (C+1,) int64

    Returns
    -------
    (P, 3) float64
    """
    P = len(points)
    v0 = np.zeros((P, 3))
    v1 = np.zeros((P, 3))
    v0[1:] = np.diff(points, axis=0)
    v1[1:] = np.diff(moved, axis=0)
    L0 = row_norm(v0)
    L1 = row_norm(v1)
    ok = L1 > 1e-300
    v = np.where(ok[:, None], v1 * (L0 / np.where(ok, L1, 1.0))[:, None], v0)
    v[off[:-1]] = points[off[:-1]]  # the root itself starts the chain
    return segmented_cumsum(v, off)


def bad_curves(points, offsets):
    """Curves no FurCollide step can work with, by the solver's rules.

    A curve is bad when it has fewer than 2 points, a non-finite point, a
    zero-length segment (shorter than ``tolerances.ZERO_SEGMENT_REL`` times its
    curve's length) or a length that overflows. The solver leaves such curves as
    they are and marks them ``Status.INVALID``; the render groom does the same.

    Parameters
    ----------
    points : (P, 3) float ndarray
        May hold non-finite values.
    offsets : (C+1,) int ndarray

    Returns
    -------
    bad : (C,) bool ndarray
    reason : str
        What is wrong with the first bad curve, naming it ('' when none is bad).
    """
    pts = np.asarray(points, np.float64)
    off = np.asarray(offsets, np.int64)
    C = len(off) - 1
    sizes = np.diff(off)
    bad = sizes < 2
    curve = np.repeat(np.arange(C), sizes)
    finite = np.isfinite(pts).all(axis=1)
    nonfinite = np.zeros(C, bool)
    nonfinite[curve[~finite]] = True
    d = np.diff(pts, axis=0)
    with np.errstate(invalid="ignore", over="ignore"):
        L = np.sqrt(np.einsum("ij,ij->i", d, d)) if len(d) else np.zeros(0)
    _, _, s0 = layout(off)
    L = L[s0] if len(s0) else np.zeros(0)
    scurve = curve[s0]
    with np.errstate(invalid="ignore", over="ignore"):
        total = np.bincount(scurve, L, minlength=C)
    short = np.full(C, np.inf)
    with np.errstate(invalid="ignore"):
        if len(L):
            np.minimum.at(short, scurve, L)
        zero = ~(short > tol.ZERO_SEGMENT_REL * total) & (sizes >= 2)
    overflow = ~np.isfinite(total) & ~nonfinite & (sizes >= 2)
    bad = bad | nonfinite | zero | overflow
    if not bad.any():
        return bad, ""
    c = int(np.argmax(bad))
    if sizes[c] < 2:
        why = f"curve {c} has fewer than 2 points"
    elif nonfinite[c]:
        i = int(off[c] + np.argmax(~finite[off[c]:off[c + 1]]))
        why = f"curve {c}: point {i} is not finite ({pts[i].tolist()})"
    elif overflow[c]:
        why = f"curve {c} is too large: its length overflows (coordinates ~1e19+)"
    else:
        seg = np.flatnonzero(scurve == c)
        k = int(s0[seg[int(np.argmin(L[seg]))]])
        why = f"curve {c} has a zero-length segment between points {k} and {k + 1}"
    return bad, why


def as_given(points, offsets, which):
    """``points`` with every non-finite point of the curves ``which`` (bool (C,))
    replaced by the nearest finite one before it on its curve (after it for leading
    ones; the origin when the curve has none), as the solver outputs its INVALID
    curves: an output never holds NaN. Returns a float64 copy."""
    out = np.array(points, np.float64)
    off = np.asarray(offsets, np.int64)
    ok = np.isfinite(out).all(axis=1)
    sizes = np.diff(off)
    rows = np.flatnonzero(np.repeat(np.asarray(which, bool), sizes) & ~ok)
    if not len(rows):
        return out
    curve = np.repeat(np.arange(len(sizes)), sizes)
    for i in rows:  # (rare: only the invalid curves' non-finite points)
        c = curve[i]
        a, b = int(off[c]), int(off[c + 1])
        before = np.flatnonzero(ok[a:i])
        after = np.flatnonzero(ok[i:b])
        if len(before):
            out[i] = out[a + before[-1]]
        elif len(after):
            out[i] = out[i + after[0]]
        else:
            out[i] = 0.0
    return out
