"""Blender's curve layout: ``points`` (P, 3) + ``offsets`` (C+1,), shared checks."""

from __future__ import annotations

import numpy as np

from .errors import InputError


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
