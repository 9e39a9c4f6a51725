"""Rotation Precision: the batched search for the smallest clearing angle.

Every round of the search is one batched ray query for all curves still
searching, which is what keeps the solver fast (see ``gallop_bisect``).
"""

from __future__ import annotations

import numpy as np

#: A step that is not there: none known (a bracket's ``lo`` or ``hi``) or none
#: found (an answer). Steps themselves count from 0.
NONE = -1


def _steps(x, name):
    """``x`` as int64 steps; a float array is refused rather than truncated (a step
    computed as a float, NaN included, is a caller's bug, not a step)."""
    x = np.asarray(x)
    if x.size and x.dtype.kind not in "iu":
        raise TypeError(f"gallop_bisect: {name} must be integer steps, got {x.dtype}")
    return x.astype(np.int64, copy=False)


def gallop_bisect(n, test, k_max, lo=None, hi=None, width=4, stride=None):
    """Smallest integer ``k`` in ``(lo, k_max]`` with ``test`` true, per item.

    A ``width``-ary gallop-then-bisect: each round probes ``width`` values
    per unsettled item (galloping: ``lo + stride * 1, 2, 4, ...``; once a good
    probe is known: evenly inside the bracket) and calls ``test`` once for all
    of them, i.e. one batched ray query per round. Where ``test`` is monotone
    the result is exactly the first good ``k``; otherwise it is a good ``k``
    right after a bad one.

    Parameters
    ----------
    n : int
        Number of items.
    test : callable(items (m,) int, ks (m,) int) -> (m,) bool
        ``items`` may repeat (several probes of one item).
    k_max : (n,) int
        Largest admissible ``k``.
    lo : (n,) int, optional
        Known bad ``k`` (default 0).
    hi : (n,) int, optional
        Known good ``k`` (-1 = unknown: gallop first).
    width : int
        Probes per item per round.
    stride : (n,) int, optional
        First gallop stride (default 1).

    Returns
    -------
    (n,) int
        The good ``k`` found, -1 where none up to ``k_max``.
    """
    lo = np.zeros(n, np.int64) if lo is None else _steps(lo, "lo").copy()
    hi = np.full(n, NONE, np.int64) if hi is None else _steps(hi, "hi").copy()
    stride = np.ones(n, np.int64) if stride is None else np.maximum(_steps(stride, "stride"), 1)
    k_max = np.broadcast_to(_steps(k_max, "k_max"), (n,))
    ladder = 2 ** np.arange(width)
    frac = np.arange(1, width + 1) / (width + 1)
    for _ in range(128):  # bounded: each round multiplies the stride or divides the bracket
        gallop = (hi < 0) & (lo < k_max)
        bisect = (hi >= 0) & (hi - lo > 1)
        items = np.flatnonzero(gallop | bisect)
        if len(items) == 0:
            break
        g = gallop[items][:, None]
        l, h = lo[items][:, None], hi[items][:, None]
        probes = np.where(
            g,
            np.minimum(l + stride[items][:, None] * ladder, k_max[items][:, None]),
            np.clip(l + np.ceil((h - l) * frac).astype(np.int64), l + 1, h),
        )
        good = test(np.repeat(items, width), probes.ravel()).reshape(len(items), width)
        anyg = good.any(axis=1)
        first = np.argmax(good, axis=1)
        rows = np.arange(len(items))
        k_first = probes[rows, first]
        k_before = np.where(first > 0, probes[rows, np.maximum(first - 1, 0)], lo[items])
        hit_i = items[anyg]
        hi[hit_i] = k_first[anyg]
        lo[hit_i] = k_before[anyg]
        miss_i = items[~anyg]
        lo[miss_i] = probes[~anyg, -1]
        stride[miss_i] *= 2**width
    return hi


def scan_bisect(n, test, k_max, probes=16, width=4):
    """Smallest integer ``k`` in ``[1, k_max]`` with ``test`` true, per item,
    for tests that need not be monotone in ``k``.

    One round probes ``probes`` evenly spread steps up to ``k_max`` (one
    batched query); the search then bisects (``width`` probes per round,
    :func:`gallop_bisect`) between the first clearing probe and the probe
    before it. A window of clearing steps wider than ``k_max / probes`` is
    always found, where a gallop from 1 can jump over it (Soft: a segment
    starting right next to a collider clears only in a window of angles).
    Where ``test`` is monotone the result is exactly the first good ``k``.

    Returns
    -------
    (n,) int
        The good ``k`` found, -1 where none of the scan's probes is good.
    """
    k_max = np.broadcast_to(np.asarray(k_max, np.int64), (n,))
    hi = np.full(n, NONE, np.int64)
    lo = np.zeros(n, np.int64)
    it = np.flatnonzero(k_max >= 1)
    if len(it) == 0:
        return hi
    frac = np.arange(1, probes + 1) / probes
    ks = np.maximum(np.ceil(k_max[it][:, None] * frac - 1e-9).astype(np.int64), 1)
    ks = np.maximum.accumulate(ks, axis=1)
    good = test(np.repeat(it, probes), ks.ravel()).reshape(ks.shape)
    anyg = good.any(axis=1)
    first = np.argmax(good, axis=1)
    rows = np.arange(len(it))
    g = it[anyg]
    hi[g] = ks[rows, first][anyg]
    lo[g] = np.where(first > 0, ks[rows, np.maximum(first - 1, 0)], 0)[anyg]
    out = np.full(n, NONE, np.int64)
    if len(g):
        out[g] = gallop_bisect(len(g), lambda i, k: test(g[i], k), k_max[g],
                               lo=lo[g], hi=hi[g], width=width)
    return out
