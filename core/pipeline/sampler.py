"""Fur Sampler (paper section 2): a uniform, well-spaced subset of curves to use as guides.

Poisson-disk-like selection on the growth surface: dart throwing over a
seeded random order of the roots (a root is kept if no kept root lies
within a radius ``r``), with ``r`` chosen by bisection so that about
``fraction`` of the curves survive, then filled to the exact target with
the roots farthest from the kept ones. Dart throwing keeps one root per
``~r^2`` of *surface area* whatever the groom's density, so the guides are
uniform per area (no clumps where the groom is dense, no holes).

Vectorized: the dart throwing is computed as the lexicographically-first
maximal independent set of the "closer than r" graph (Luby's rounds with
fixed priorities), which is exactly the sequential result.
"""

from __future__ import annotations

import math

import numpy as np

from ..curves import as_points
from ..errors import InputError
from ..mesh import check_surface, triangle_areas

#: Bisection steps on the radius.
_BISECT = 14
#: Random sequential adsorption in 2D jams at ~0.547 disk coverage:
#: ``n pi (r / 2)^2 = 0.547 A``, i.e. ``n ~ 0.7 A / r^2``.
_JAMMING = 0.7


def neighbor_pairs(X, r):
    """All pairs ``(i, j)``, ``i != j``, with ``|X_i - X_j| < r`` (both orders).

    Parameters
    ----------
    X : (n, 3) ndarray of float64
    r : float > 0

    Returns
    -------
    i, j : (e,) ndarray of int64
    d : (e,) ndarray of float64
        Their distances.
    """
    n = len(X)
    if n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    lo = X.min(0)
    cell = np.floor((X - lo) / r).astype(np.int64)
    dims = cell.max(0) + 3
    k = ((cell[:, 0] + 1) * dims[1] + (cell[:, 1] + 1)) * dims[2] + (cell[:, 2] + 1)
    order = np.argsort(k, kind="stable")
    ks = k[order]
    # occupied cells (sorted keys), their first point and point count
    ucell, start, count = np.unique(ks, return_index=True, return_counts=True)
    I, J = [], []
    for dx in (-1, 0, 1):  # 27 neighbour cells; keys are linear in the cell
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                q = ucell + (dx * dims[1] + dy) * dims[2] + dz  # still sorted
                a = np.searchsorted(ucell, q)
                a = np.minimum(a, len(ucell) - 1)
                hit = ucell[a] == q
                src, dst = np.flatnonzero(hit), a[hit]
                # every point of cell src x every point of cell dst
                ns, nd = count[src], count[dst]
                npair = ns * nd
                tot = int(npair.sum())
                pid = np.repeat(np.arange(len(src)), npair)
                local = np.arange(tot) - np.repeat(np.cumsum(npair) - npair, npair)
                i = order[start[src][pid] + local // nd[pid]]
                j = order[start[dst][pid] + local % nd[pid]]
                keep = i != j
                I.append(i[keep])
                J.append(j[keep])
    i = np.concatenate(I)
    j = np.concatenate(J)
    d = np.linalg.norm(X[i] - X[j], axis=1)
    close = d < r
    return i[close], j[close], d[close]


def dart_throwing(X, r, priority, pairs=None):
    """Sequential dart throwing in ``priority`` order, computed in parallel rounds.

    Parameters
    ----------
    X : (n, 3) ndarray
    r : float
        Minimum distance between kept points.
    priority : (n,) ndarray of int
        A permutation: lower is thrown first.
    pairs : (i, j), optional
        Precomputed :func:`neighbor_pairs` within ``r``.

    Returns
    -------
    (n,) bool
        Kept points: no two closer than ``r``, every other point within
        ``r`` of a kept one that precedes it.
    """
    n = len(X)
    i, j = pairs if pairs is not None else neighbor_pairs(X, r)[:2]
    keep = np.zeros(n, bool)
    open_ = np.ones(n, bool)
    prio = np.asarray(priority, np.int64)
    while open_.any():
        live = open_[i] & open_[j]
        i, j = i[live], j[live]
        m = np.full(n, np.iinfo(np.int64).max)
        np.minimum.at(m, i, prio[j])
        win = open_ & (prio < m)
        keep |= win
        open_ &= ~win
        open_[i[win[j]]] = False  # neighbours of winners are out
    return keep


def sample_guides(roots, surface_V, surface_F, fraction=0.15, seed=0, mask=None):
    """Fur Sampler: indices of a uniform, well-spaced subset of curves.

    Parameters
    ----------
    roots : (C, 3) array_like of float
        Root positions of the render groom (on the growth surface).
    surface_V : (n, 3) array_like of float
        Growth surface vertices (for its area, which sets the initial radius).
    surface_F : (m, 3) array_like of int
        Its triangles.
    fraction : float, default 0.15
        In (0, 1]: share of the (eligible) curves to keep.
    seed : int, default 0
        Same seed, same guides.
    mask : (C,) array_like of bool, optional
        Area of interest: only these curves can be picked (the target is
        ``fraction`` of them).

    Returns
    -------
    (k,) ndarray of int64
        Sorted curve indices, ``k = max(1, round(fraction * eligible))``
        (all eligible curves when that is more).

    Raises
    ------
    InputError
        Malformed roots, fraction or mask.
    ColliderError
        Malformed surface.
    """
    X = as_points(roots, "roots")
    C = len(X)
    bad = ~np.isfinite(X).all(axis=1)
    if bad.any():
        raise InputError(f"roots: curve {int(np.argmax(bad))} has a non-finite root")
    V, F = check_surface(surface_V, surface_F, "growth surface")
    try:
        fraction = float(fraction)
    except (TypeError, ValueError):
        raise InputError(f"fraction must be a number, got {fraction!r}") from None
    if not 0 < fraction <= 1:
        raise InputError(f"fraction must be in (0, 1], got {fraction}")
    if mask is None:
        elig = np.arange(C)
    else:
        m = np.asarray(mask)
        if m.shape != (C,):
            raise InputError(f"mask must have shape ({C},), got {m.shape}")
        elig = np.flatnonzero(m.astype(bool))
    n = len(elig)
    if n == 0:
        return np.zeros(0, np.int64)
    k = min(n, max(1, round(fraction * n)))
    if k == n:
        return elig.astype(np.int64)
    Xe = X[elig]
    prio = np.empty(n, np.int64)
    prio[np.random.default_rng(seed).permutation(n)] = np.arange(n)
    area = float(triangle_areas(V, F).sum()) * n / C
    ext = float(np.linalg.norm(Xe.max(0) - Xe.min(0)))
    r = math.sqrt(_JAMMING * area / k) if area > 0 else ext / math.sqrt(k)
    r = r if r > 0 else 1.0

    cache = {}

    def run(r):
        # neighbour pairs are computed once for a radius a bit above r, then filtered
        if cache.get("r", -1.0) < r:
            cache["r"] = 1.3 * r
            cache["pairs"] = neighbor_pairs(Xe, cache["r"])
        i, j, d = cache["pairs"]
        close = d < r
        keep = dart_throwing(Xe, r, prio, (i[close], j[close]))
        return keep, int(keep.sum())

    # bracket: r_small keeps more than k, r_big at most k
    r_small = r_big = None
    keep_big = None
    keep, cnt = run(r)
    for _ in range(60):
        if cnt > k:
            r_small = r
            if r_big is not None:
                break
            r *= 1.5
        else:
            r_big, keep_big = r, keep
            if cnt == k or r_small is not None:
                break
            r /= 1.5
        keep, cnt = run(r)
    if r_small is not None and keep_big is not None and keep_big.sum() < k:
        for _ in range(_BISECT):
            r = math.sqrt(r_small * r_big)
            keep, cnt = run(r)
            if cnt > k:
                r_small = r
            else:
                r_big, keep_big = r, keep
                if cnt >= 0.995 * k:
                    break
    if keep_big is None:  # could not get down to k (coincident roots): first k in order
        keep_big = np.zeros(n, bool)
        keep_big[np.argsort(prio)[:k]] = True
    keep = keep_big
    short = k - int(keep.sum())
    if short > 0:
        i, j, d = cache["pairs"]
        close = d < r_big
        keep = _fill(Xe, keep, r_big, short, prio, (i[close], j[close], d[close]))
    return np.sort(elig[keep]).astype(np.int64)


def _fill(X, keep, r, short, prio, pairs):
    """Add ``short`` points, farthest from the kept ones first, spread among themselves."""
    cand = np.flatnonzero(~keep)
    i, j, d = pairs
    to_kept = keep[j] & ~keep[i]
    near = np.full(len(X), r)
    np.minimum.at(near, i[to_kept], d[to_kept])
    # farthest first (ties: dart order)
    rank = np.lexsort((prio[cand], -near[cand]))
    order = np.empty(len(cand), np.int64)
    order[rank] = np.arange(len(cand))
    Xc = X[cand]
    spread = dart_throwing(Xc, 0.5 * r, order)
    pick = cand[spread][np.argsort(order[spread])][:short]
    out = keep.copy()
    out[pick] = True
    short -= len(pick)
    if short > 0:  # still short: next in farthest-first order
        rest = cand[rank][~out[cand[rank]]][:short]
        out[rest] = True
    return out
