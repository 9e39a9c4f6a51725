"""Curves in Blender's layout: ``points`` (P, 3) + ``offsets`` (C+1,), their checks and
the one rule for the curves FurCollide cannot work with.

Curve ``i`` is ``points[offsets[i]:offsets[i + 1]]``. Every module of the core
(the solver, the fur pipeline) checks and walks curves with these functions.

Invalid curves
--------------
A curve is **invalid** when it has fewer than 2 points, a non-finite point, a
zero-length segment (not longer than ``tolerances.ZERO_SEGMENT_REL`` times its
curve's length) or a length that overflows. The solver leaves such curves as
they are and marks them ``Status.INVALID`` (it works on :func:`stand_ins` for
them and outputs :func:`given_rows`: never NaN); the render groom sets them aside
at bind time (:func:`invalid_curves`, :func:`as_given`) and its clearance pass
marks them as the solver would. The rule itself is :func:`degenerate` (lengths)
and :func:`non_finite` (points); each caller computes the lengths its fastest
way and hands them to it.
"""

from __future__ import annotations

import numpy as np

from . import tolerances as tol
from .errors import InputError

# ------------------------------------------------------------------ checks


def check_offsets(offsets, min_curves=1) -> np.ndarray:
    """Validate curve offsets: curve ``i`` is ``points[offsets[i]:offsets[i + 1]]``.

    Parameters
    ----------
    offsets : (C+1,) array_like of int
        Starts at 0, every curve has at least 2 points.
    min_curves : int
        Fewest curves accepted.

    Returns
    -------
    (C+1,) int64 ndarray

    Raises
    ------
    InputError
        The message names the curve at fault.
    """
    try:
        off = np.asarray(offsets)
    except Exception as exc:
        raise InputError(f"offsets must be a 1-D integer array: {exc}") from None
    if off.ndim != 1 or len(off) < min_curves + 1:
        raise InputError(
            f"offsets must be a 1-D array of C+1 >= {min_curves + 1} integers, "
            f"got shape {off.shape}"
        )
    if not np.issubdtype(off.dtype, np.integer):
        raise InputError(f"offsets must be integers, got dtype {off.dtype}")
    off = off.astype(np.int64)
    if off[0] != 0:
        raise InputError(f"offsets must start at 0, got {int(off[0])}")
    sizes = np.diff(off)
    if (sizes < 2).any():
        i = int(np.argmax(sizes < 2))
        if sizes[i] <= 0:
            raise InputError(f"offsets must increase: curve {i} has {int(sizes[i])} points")
        raise InputError(f"curve {i} has only 1 point; every curve needs at least 2")
    return off


def check_curves(points, offsets, name="points", finite=True):
    """Validate and return ``(points float64 (P, 3), offsets int64 (C+1,))``.

    ``finite=False`` accepts non-finite points (a caller that sets such curves
    aside, as the solver does: :func:`invalid_curves`).

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


def check_points(points, n_points, name="points"):
    """A step's input curves: ``points`` (P, 3) float32 or float64 as given
    (contiguous, never converted: the output keeps the input's dtype), ``P`` the
    layout's ``n_points``.

    Raises
    ------
    InputError
        Wrong shape, dtype or number of rows.
    """
    if not isinstance(points, np.ndarray):
        try:
            points = np.asarray(points)
        except Exception as exc:
            raise InputError(f"{name} must be a (P, 3) float array: {exc}") from None
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"{name} must have shape (P, 3), got {points.shape}")
    if points.dtype not in (np.float32, np.float64):
        raise InputError(f"{name} must be float32 or float64, got {points.dtype}")
    if len(points) != n_points:
        raise InputError(
            f"{name} has {len(points)} rows but offsets describe {n_points} points"
        )
    return np.ascontiguousarray(points)


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
    """``a`` as float64, or InputError naming its first non-finite row (and, with
    ``off``, that row's curve)."""
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


# ------------------------------------------------------------------ layout


class CurveLayout:
    """Where every curve's points and segments are (topology only, built once).

    Attributes
    ----------
    offsets : (C+1,) int64
        Curve ``i`` is ``points[offsets[i]:offsets[i + 1]]``.
    n_curves, n_points : int
    nseg : (C,) int64
        Segments per curve.
    soff : (C+1,) int64
        Curve ``i``'s segments are ``soff[i]:soff[i + 1]`` (segment ids).
    seg_start : (S,) int64
        First point of each segment.
    seg_curve, seg_j : (S,) int64
        Owner curve of each segment, and its index along the curve.
    w_bend : (S,) float64
        Bend's share of a curve's angle turning each segment, ``(j + 1) / n``.
    ns : int
        Segments per curve when every curve has the same count (the usual
        groom: the step then works on (C, ns) blocks), else 0.
    """

    def __init__(self, offsets):
        off = check_offsets(offsets)
        self.offsets = off
        self.n_curves = C = len(off) - 1
        self.n_points = int(off[-1])
        self.nseg = nseg = np.diff(off) - 1
        self.soff = np.concatenate([[0], np.cumsum(nseg)])
        is_last = np.zeros(self.n_points, bool)
        is_last[off[1:] - 1] = True
        self.seg_start = np.flatnonzero(~is_last)
        self.seg_curve = np.repeat(np.arange(C), nseg)
        self.seg_j = np.arange(len(self.seg_start)) - self.soff[self.seg_curve]
        self.w_bend = (self.seg_j + 1) / nseg[self.seg_curve]
        self.ns = int(nseg[0]) if C and (nseg == nseg[0]).all() else 0

    @property
    def n_segments(self) -> int:
        return len(self.seg_start)

    def segments(self, idx):
        """Segments of curves ``idx``: (segment ids, owner position in
        ``idx``, each curve's first position)."""
        cnt = self.nseg[idx]
        starts = np.cumsum(cnt) - cnt
        rep = np.repeat(np.arange(len(idx)), cnt)
        seg = self.soff[idx][rep] + (np.arange(int(cnt.sum())) - starts[rep])
        return seg, rep, starts

    def owner(self, points):
        """Curve of each point index in ``points`` (k,)."""
        return np.searchsorted(self.offsets, points, "right") - 1


def layout(off):
    """Per-point indices of the layout ``off`` (C+1,).

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


def uniform_size(off):
    """The common point count of the curves, or 0 when they differ (or there is none)."""
    if len(off) < 2:
        return 0
    n = int(off[1] - off[0])
    return n if int(off[-1]) == n * (len(off) - 1) and (np.diff(off) == n).all() else 0


def subset(offsets, which):
    """(rows, offsets) of the curves ``which`` (bool (C,)) of the layout ``offsets``:
    the points of those curves, and their layout as a curve set of their own."""
    idx = np.flatnonzero(which)
    sizes = np.diff(offsets)[idx]
    rows = np.repeat(offsets[idx] - (np.cumsum(sizes) - sizes), sizes) + np.arange(
        int(sizes.sum()))
    return rows, np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)


# ---------------------------------------------------------------- measures


def row_norm(v):
    """Lengths of the rows of ``v`` (k, 3): ``np.linalg.norm(v, axis=1)`` in long passes."""
    return np.sqrt(np.einsum("ij,ij->i", v, v))


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


# ----------------------------------------------------------- invalid curves


def degenerate(shortest, total):
    """The rule on lengths: (C,) bool, the curves with a zero-length segment (their
    ``shortest`` segment not longer than ``tolerances.ZERO_SEGMENT_REL`` times their
    ``total`` length, or of length 0) or whose length overflows (not finite).

    Parameters
    ----------
    shortest, total : (C,) float
        Each curve's shortest segment length and its length, however computed.
    """
    with np.errstate(invalid="ignore"):
        out = ~(shortest > tol.ZERO_SEGMENT_REL * total)
    out |= ~np.isfinite(total)
    return out


def degenerate_reason(c, total, k) -> str:
    """What is wrong with degenerate curve ``c`` (:func:`degenerate`) of length
    ``total``, ``k`` the first point of its shortest segment."""
    if not np.isfinite(total):
        return f"curve {c} is too large: its length overflows (coordinates ~1e19+)"
    return f"curve {c} has a zero-length segment between points {k} and {k + 1}"


def non_finite(points, offsets):
    """Curves with a non-finite point: ``(mask (C,) bool, reason)``, the reason
    naming the first such point and its curve ('' when there is none)."""
    C = len(offsets) - 1
    if np.isfinite(points.reshape(-1)).all():  # (one flat pass: the usual case)
        return np.zeros(C, bool), ""
    finite = np.isfinite(points).all(axis=1)
    rows = np.flatnonzero(~finite)
    owner = np.searchsorted(offsets, rows, "right") - 1
    bad = np.zeros(C, bool)
    bad[owner] = True
    i, c = int(rows[0]), int(owner[0])
    return bad, f"curve {c}: point {i} is not finite ({points[i].tolist()})"


def invalid_curves(points, offsets):
    """Curves no FurCollide step can work with (see the module's docstring).

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
    curve = np.repeat(np.arange(C), sizes)
    nonfinite, why_nonfinite = non_finite(pts, off)
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
    few = sizes < 2
    bad = few | nonfinite | (degenerate(short, total) & ~few)
    if not bad.any():
        return bad, ""
    c = int(np.argmax(bad))
    if few[c]:
        return bad, f"curve {c} has fewer than 2 points"
    if nonfinite[c]:  # (the first bad curve holds the first non-finite point)
        return bad, why_nonfinite
    seg = np.flatnonzero(scurve == c)
    k = int(s0[seg[int(np.argmin(L[seg]))]])
    return bad, degenerate_reason(c, total[c], k)


def invalid_report(bad, reasons) -> list:
    """A step's report on its INVALID curves ``bad`` (C,) bool: the first one's
    reason (``reasons``: (curve, reason) pairs) and how many there are."""
    if not bad.any():
        return []
    first = min(reasons, key=lambda r: r[0])[1]
    n = int(bad.sum())
    more = (f" ({n} invalid curves: left as they are, not solved)" if n > 1
            else " (left as it is, not solved)")
    return [first + more]


def stand_ins(points, offsets, bad):
    """``points`` with the invalid curves ``bad`` (C,) replaced by short straight
    ones at their root (never solved; only so a step's arithmetic stays finite)."""
    out = points.copy()
    pts = np.flatnonzero(np.repeat(bad, np.diff(offsets)))
    owner = np.searchsorted(offsets, pts, "right") - 1
    root = points[offsets[owner]].astype(np.float64)
    root = np.where(np.isfinite(root).all(axis=1)[:, None], root, 0.0)
    j = pts - offsets[owner]
    scale = 1e-6 * np.maximum(1.0, np.abs(root).max(axis=1))
    out[pts] = root + (j * scale)[:, None] * np.array([0.0, 0.0, 1.0])
    return out


def given_rows(points, offsets, bad):
    """The invalid curves' own points, as they are output: ``(rows, values)``,
    the rows of the curves ``bad`` (C,) bool and their points (``points``' dtype)
    with every non-finite point replaced by the nearest finite one before it on
    its curve (after it for leading ones; the origin when the curve has none):
    an output never holds NaN."""
    pts = np.flatnonzero(np.repeat(bad, np.diff(offsets)))
    p = points[pts].copy()
    ok = np.isfinite(p).all(axis=1)
    if ok.all():
        return pts, p
    owner = np.searchsorted(offsets, pts, "right") - 1
    idx = np.where(ok, np.arange(len(p)), -1)
    fwd = np.maximum.accumulate(idx)  # last finite point so far
    start = np.r_[0, np.flatnonzero(np.diff(owner)) + 1]
    first_of = np.repeat(start, np.diff(np.r_[start, len(p)]))
    fwd = np.where(fwd >= first_of, fwd, -1)  # (not from an earlier curve)
    # leading non-finite points: the first finite point of the curve
    nxt = np.where(ok, np.arange(len(p)), len(p))
    nxt = np.minimum.accumulate(nxt[::-1])[::-1]
    last_of = np.repeat(np.r_[start[1:], len(p)] - 1, np.diff(np.r_[start, len(p)]))
    nxt = np.where(nxt <= last_of, nxt, -1)
    src = np.where(fwd >= 0, fwd, nxt)
    # a finite point is its own source (its last finite point so far)
    return pts, np.where(src[:, None] >= 0, p[np.maximum(src, 0)], 0.0)


def as_given(points, offsets, which):
    """``points`` (float64 copy) with the curves ``which`` (bool (C,)) as the solver
    outputs its INVALID curves (:func:`given_rows`)."""
    out = np.array(points, np.float64)
    rows, values = given_rows(out, np.asarray(offsets, np.int64), np.asarray(which, bool))
    out[rows] = values
    return out
