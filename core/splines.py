"""The curve Blender draws through hair control points, and how far it strays.

FurCollide solves every curve as the polyline through its control points. Blender
draws Catmull-Rom, Bezier and NURBS hair as splines through (or near) those points
(its ``CurvesGeometry::evaluated_positions``); this module says how far such a spline
can leave its control polygon, before and after a solve, and carries Bezier handles
along with the solved points. Pure numpy, vectorized over all curves.

What Blender evaluates (``source/blender/blenkernel/intern/curve_*.cc``, 4.2-5.x):

* **Catmull-Rom** (``curve_catmull_rom.cc``): segment ``P1 -> P2`` with neighbours
  ``P0``, ``P3`` is the uniform Catmull-Rom cubic; a non-cyclic curve repeats its end
  points (the first segment uses ``P0, P0, P1, P2``, the last ``.., Pn-1, Pn, Pn``), so
  the tangent at an end is half its segment, along it. In Hermite form with tangents
  ``m1 = (P2 - P0) / 2``, ``m2 = (P3 - P1) / 2`` and chord ``d = P2 - P1``::

      P(t) - (P1 + t d) = h10(t) (m1 - d) + h11(t) (m2 - d)

  with ``h10 = t (1 - t)^2 >= 0`` and ``h11 = -t^2 (1 - t) <= 0``; ``m1 - d`` and
  ``m2 - d`` are half the second differences at ``P1`` and ``P2``.
* **Bezier** (``curve_bezier.cc``): segment ``i`` is the cubic with control points
  ``P_i, handle_right_i, handle_left_(i+1), P_(i+1)``, from the *stored* handles
  (evaluation never recomputes them). It lies in the convex hull of those four points.
  A segment whose two handles are VECTOR is drawn as one straight line. AUTO and
  VECTOR handles are recomputed from the positions only by editing tools and nodes
  (``calculate_auto_handles``: AUTO along ``next/|next| + prev/|prev|``, VECTOR a
  third of the way to the neighbour); an ALIGN handle opposite a non-ALIGN one is
  turned to face it; two ALIGN handles and FREE handles are left alone.
* **NURBS** (``curve_nurbs.cc``): every evaluated point is a weighted mix (positive
  basis times positive ``nurbs_weight``, normalized) of ``order`` consecutive control
  points, so the curve lies in the union of the convex hulls of the windows of
  ``order`` consecutive points. A curve with fewer points than its order (or an
  invalid Bezier-knots count) is drawn as its control polygon.
* **Poly**: the control polygon itself.

Bounds are distances from the control polygon, in the units of the points: a spline
whose bound is ``b`` never comes closer to a collider than its polygon's clearance
minus ``b``. Cyclic curves are not bounded (their closing segment is not part of the
solved polyline): their bound is 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from math import comb

import numpy as np

from . import tolerances as tol
from .curves import subset, uniform_size
from .rotations import stable_perpendicular

#: ``curve_type`` codes (``CurveType`` in DNA_curves_types.h).
CATMULL_ROM, POLY, BEZIER, NURBS = 0, 1, 2, 3
#: Bezier handle types (``HandleType``).
FREE, AUTO, VECTOR, ALIGN = 0, 1, 2, 3
#: NURBS ``knots_mode`` codes (``KnotsMode``); CUSTOM exists from Blender 5.0.
KNOTS_NORMAL, KNOTS_ENDPOINT, KNOTS_BEZIER, KNOTS_ENDPOINT_BEZIER, KNOTS_CUSTOM = range(5)
#: Blender's defaults for absent attributes.
DEFAULT_ORDER = 4


@dataclass
class Splines:
    """How Blender draws each curve of a hair: its type and the data of that type.

    Attributes
    ----------
    types : (C,) int8 ndarray
        ``curve_type`` codes (Blender's default, when the attribute is absent, is
        Catmull-Rom).
    cyclic : (C,) bool ndarray or None
    handle_left, handle_right : (P, 3) float ndarray or None
        Bezier handle positions, in the space of the points they go with.
    handle_type_left, handle_type_right : (P,) int8 ndarray or None
    nurbs_order : (C,) int ndarray or None
        (Blender's default 4 when None.)
    knots_mode : (C,) int ndarray or None
    nurbs_weight : (P,) float ndarray or None
    """

    types: np.ndarray
    cyclic: np.ndarray | None = None
    handle_left: np.ndarray | None = None
    handle_right: np.ndarray | None = None
    handle_type_left: np.ndarray | None = None
    handle_type_right: np.ndarray | None = None
    nurbs_order: np.ndarray | None = None
    knots_mode: np.ndarray | None = None
    nurbs_weight: np.ndarray | None = None

    @classmethod
    def catmull_rom(cls, n_curves: int) -> Splines:
        """Every curve Catmull-Rom: Blender's hair without a ``curve_type`` attribute."""
        return cls(np.zeros(n_curves, np.int8))

    def has(self, code: int) -> bool:
        """Does any curve have type ``code``?"""
        return bool(np.any(self.types == code))

    @property
    def drawn_as_polygon(self) -> bool:
        """Is every curve drawn as its control polygon (Poly)?"""
        return bool(np.all(self.types == POLY))

    def with_handles(self, handle_left, handle_right) -> Splines:
        """A copy with other handle positions."""
        return Splines(self.types, self.cyclic, handle_left, handle_right,
                       self.handle_type_left, self.handle_type_right, self.nurbs_order,
                       self.knots_mode, self.nurbs_weight)

    def take(self, curves, offsets) -> Splines:
        """The splines of the curves ``curves`` ((C,) bool) of the layout ``offsets``
        (C+1,), as a curve set of their own (``core.curves.subset``)."""
        curves = np.asarray(curves, bool)
        rows, _ = subset(np.asarray(offsets, np.int64), curves)

        def per(a, idx):
            return None if a is None else np.asarray(a)[idx]

        return Splines(per(self.types, curves), per(self.cyclic, curves),
                       per(self.handle_left, rows), per(self.handle_right, rows),
                       per(self.handle_type_left, rows), per(self.handle_type_right, rows),
                       per(self.nurbs_order, curves), per(self.knots_mode, curves),
                       per(self.nurbs_weight, rows))


# ------------------------------------------------------------------ layout
class _Layout:
    """Per-point bookkeeping of a curve layout ``offsets`` (C+1,)."""

    def __init__(self, offsets):
        offs = np.asarray(offsets, np.int64)
        self.offsets = offs
        self.sizes = np.diff(offs)
        self.C = len(self.sizes)
        self.P = int(offs[-1]) if len(offs) else 0
        nz = self.sizes > 0
        self.first = np.zeros(self.P, bool)
        self.last = np.zeros(self.P, bool)
        self.first[offs[:-1][nz]] = True
        self.last[offs[1:][nz] - 1] = True
        self.curve = np.repeat(np.arange(self.C), self.sizes)
        #: segment i runs from point i to point i + 1 (no segment at a curve's last point)
        self.seg = ~self.last

    def segments(self, points):
        """(P, 3) segment vectors (zero rows where no segment starts)."""
        d = np.zeros((self.P, 3))
        if self.P > 1:
            d[:-1] = points[1:] - points[:-1]
        d[self.last] = 0.0
        return d

    def per_curve_max(self, values, where):
        """(C,) largest of point-indexed ``values`` over the points ``where`` of each
        curve (0 where none; a non-finite value, of a curve with a non-finite point the
        solver leaves alone, counts as 0)."""
        out = np.zeros(self.C)
        if self.P == 0:
            return out
        v = np.where(where & np.isfinite(values), values, 0.0)
        nz = self.sizes > 0
        out[nz] = np.maximum.reduceat(v, self.offsets[:-1][nz])
        return np.maximum(out, 0.0)


def _norm(v):
    return np.sqrt(np.einsum("...i,...i->...", v, v))


def _unit(v):
    n = _norm(v)
    return np.divide(v, n[..., None], out=np.zeros_like(v), where=n[..., None] > 0), n


def _point_segment_distance(q, a, d):
    """Distance of points ``q`` (k, 3) to the segments ``a + t d``, t in [0, 1]."""
    dd = np.einsum("ij,ij->i", d, d)
    t = np.divide(np.einsum("ij,ij->i", q - a, d), dd, out=np.zeros(len(d)), where=dd > 0)
    t = np.clip(t, 0.0, 1.0)
    return _norm(q - a - t[:, None] * d)


def _cubic_max01(c0, c1, c2, c3):
    """Largest value on t in [0, 1] of ``c0 + c1 t + c2 t^2 + c3 t^3`` (arrays)."""
    c0, c1, c2, c3 = np.broadcast_arrays(*(np.asarray(c, np.float64) for c in (c0, c1, c2, c3)))
    best = np.maximum(c0, c0 + c1 + c2 + c3)
    # stationary points: c1 + 2 c2 t + 3 c3 t^2 = 0
    qa, qb, qc = 3.0 * c3, 2.0 * c2, c1
    disc = qb * qb - 4.0 * qa * qc
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.sqrt(np.maximum(disc, 0.0))
        # numerically stable roots; a vanishing qa leaves the linear root
        q = -0.5 * (qb + np.copysign(sq, qb))
        r1 = np.where(qa != 0, q / qa, np.nan)
        r2 = np.where(q != 0, qc / q, np.where(qb != 0, -qc / qb, np.nan))
    for r in (r1, r2):
        ok = (disc >= 0) & np.isfinite(r) & (r > 0) & (r < 1)
        t = np.where(ok, r, 0.0)
        v = c0 + t * (c1 + t * (c2 + t * c3))
        best = np.where(ok, np.maximum(best, v), best)
    return best


# Hermite basis terms as cubic coefficients (c0, c1, c2, c3)
_H10 = np.array([0.0, 1.0, -2.0, 1.0])  # t (1 - t)^2 >= 0
_H11 = np.array([0.0, 0.0, -1.0, 1.0])  # -t^2 (1 - t) <= 0
_T = np.array([0.0, 1.0, 0.0, 0.0])


def _poly(*terms):
    """Sum of ``coefficient_array * basis`` terms: cubic coefficients (4, k)."""
    out = 0.0
    for w, basis in terms:
        out = out + np.asarray(w, np.float64)[None, ...] * basis[:, None]
    return out


def _across_max(alpha, beta):
    """``max_t alpha t (1 - t)^2 + beta t^2 (1 - t)`` on [0, 1] for alpha, beta >= 0, in
    closed form: the root of the derivative, ``t = a / (2 a - b + sqrt(a^2 - a b + b^2))``
    with ``a >= b`` (the cubic is symmetric under ``t -> 1 - t``, alpha <-> beta)."""
    swap = beta > alpha
    a = np.where(swap, beta, alpha)
    b = np.where(swap, alpha, beta)
    den = 2.0 * a - b + np.sqrt(a * a - a * b + b * b)
    t = np.divide(a, den, out=np.zeros_like(a), where=den > 0)
    u = 1.0 - t
    return t * u * (a * u + b * t)


def _hermite_bound(L, a_perp, a_lo, a_hi, b_perp, b_lo, b_hi):
    """Bound on the distance of a Catmull-Rom segment from its chord.

    ``L`` (k,) chord lengths; the segment is ``chord + h10 a + h11 b`` with ``a``
    having a component across the chord of length at most ``a_perp`` and one along it
    in ``[a_lo, a_hi]`` (likewise ``b``). Across: at most ``max_t h10 a_perp + |h11|
    b_perp``; along, the point stays within the chord unless the along coordinate
    ``t L + h10 a_par + h11 b_par`` leaves ``[0, L]``: that overshoot is added. With
    ``h10 <= min(t, (1 - t) / 4)`` and ``|h11| <= min(t / 4, 1 - t)`` it cannot, unless
    ``|a_lo| + |b_hi| / 4 > L`` or ``|a_hi| / 4 + |b_lo| > L``: only those segments
    (sharp bends, uneven segments) get the cubic maxima.
    """
    out = _across_max(a_perp, b_perp)
    maybe = np.flatnonzero((np.abs(a_lo) + 0.25 * np.abs(b_hi) > L)
                           | (0.25 * np.abs(a_hi) + np.abs(b_lo) > L))
    if len(maybe):
        L, a_lo, a_hi, b_lo, b_hi = (x[maybe] for x in (L, a_lo, a_hi, b_lo, b_hi))
        # lowest along coordinate: smallest a_par (h10 >= 0), largest b_par (h11 <= 0)
        below = _cubic_max01(*_poly((-L, _T), (-a_lo, _H10), (-b_hi, _H11)))
        above = _cubic_max01(*_poly((L, _T), (a_hi, _H10), (b_lo, _H11))) - L
        out[maybe] += np.maximum(0.0, np.maximum(below, above))
    return out


def _hermite_upper(L, a_perp, a_lo, a_hi, b_perp, b_lo, b_hi):
    """A cheap upper bound of :func:`_hermite_bound` (same arguments): ``4/27`` is the
    largest ``h10`` and ``|h11|``, so the across term is at most ``4/27 (a_perp +
    b_perp)`` and, on the segments where the along coordinate may leave the chord, the
    overshoot at most ``4/27 (max(|a_lo|, |a_hi|) + max(|b_lo|, |b_hi|))``. Widened by
    ``tol.SPLINE_BOUND_SLACK`` over the float rounding of either form."""
    out = a_perp + b_perp
    maybe = ((np.abs(a_lo) + 0.25 * np.abs(b_hi) > L)
             | (0.25 * np.abs(a_hi) + np.abs(b_lo) > L))
    out = out + np.where(maybe, np.maximum(np.abs(a_lo), np.abs(a_hi))
                         + np.maximum(np.abs(b_lo), np.abs(b_hi)), 0.0)
    return out * (4.0 / 27.0 * (1.0 + tol.SPLINE_BOUND_SLACK))


# ------------------------------------------------------------ measured bounds
def polygon_deviation(splines: Splines, points, offsets) -> np.ndarray:
    """How far each curve Blender draws can be from its control polygon, (C,).

    A bound (not the exact distance) computed from the curve's own points and
    handles: Catmull-Rom by the Hermite form, Bezier by the convex hull of each
    segment's control points, NURBS by the convex hulls of its windows. 0 for Poly,
    cyclic and single-point curves.

    Parameters
    ----------
    splines : Splines
    points : (P, 3) float ndarray
    offsets : (C+1,) int ndarray
    """
    with np.errstate(invalid="ignore", over="ignore"):  # (non-finite curves count 0)
        return _polygon_deviation(splines, points, offsets)


def _polygon_deviation(splines: Splines, points, offsets) -> np.ndarray:
    lay = _Layout(offsets)
    P = np.asarray(points, np.float64)
    per_seg = np.zeros(lay.P)
    types = np.asarray(splines.types)[lay.curve] if lay.P else np.zeros(0, np.int8)
    open_ = ~_cyclic(splines, lay)[lay.curve] if lay.P else np.zeros(0, bool)
    d = lay.segments(P)
    cr = lay.seg & (types == CATMULL_ROM) & open_
    if cr.any():
        per_seg[cr] = _catmull_rom_measured(lay, d, cr)
    bz = lay.seg & (types == BEZIER) & open_
    if bz.any() and splines.handle_left is not None and splines.handle_right is not None:
        per_seg[bz] = _bezier_measured(P, d, bz, splines)
    out = lay.per_curve_max(per_seg, lay.seg)
    nurbs = (np.asarray(splines.types) == NURBS) & ~_cyclic(splines, lay)
    if nurbs.any():
        out = np.maximum(out, _nurbs_bound(splines, lay, P, d, nurbs, None))
    return np.nan_to_num(out, nan=0.0, posinf=0.0)


def _cyclic(splines, lay):
    if splines.cyclic is None:
        return np.zeros(lay.C, bool)
    return np.asarray(splines.cyclic, bool)


def _catmull_rom_measured(lay, d, mask):
    """Per-segment bound of the Catmull-Rom segments ``mask`` (point-indexed)."""
    L = _norm(d)
    e = np.divide(d, L[:, None], out=np.zeros_like(d), where=L[:, None] > 0)
    prev = _shifted(d, 1)  # (zero at a curve's first point: d is zero at its last)
    nxt = _shifted(d, -1)
    # a = m_j - d_j: -d_j / 2 at a curve's first point, else (d_(j-1) - d_j) / 2;
    # b = m_(j+1) - d_j: -d_j / 2 at its last point, else (d_(j+1) - d_j) / 2
    a = np.where(lay.first[:, None], -0.5 * d, 0.5 * (prev - d))
    b = np.where(_shifted(lay.last, -1, True)[:, None], -0.5 * d, 0.5 * (nxt - d))
    j = np.flatnonzero(mask)
    a, b, e, L = a[j], b[j], e[j], L[j]
    a_par = np.einsum("ij,ij->i", a, e)
    b_par = np.einsum("ij,ij->i", b, e)
    a_perp = _norm(a - a_par[:, None] * e)
    b_perp = _norm(b - b_par[:, None] * e)
    return _hermite_bound(L, a_perp, a_par, a_par, b_perp, b_par, b_par)


def _shifted(x, k, fill=0):
    """``x`` moved by ``k`` rows (``out[i] = x[i - k]``), ``fill`` where nothing is."""
    out = np.full_like(x, fill)
    if k > 0:
        out[k:] = x[:-k]
    else:
        out[:k] = x[-k:]
    return out


def _bezier_measured(P, d, mask, splines):
    j = np.flatnonzero(mask)
    a, dj = P[j], d[j]
    hr = np.asarray(splines.handle_right, np.float64)[j]
    hl = np.asarray(splines.handle_left, np.float64)[j + 1]
    out = np.maximum(_point_segment_distance(hr, a, dj), _point_segment_distance(hl, a, dj))
    tr, tl = splines.handle_type_right, splines.handle_type_left
    if tr is not None and tl is not None:  # two VECTOR handles: drawn as the chord itself
        out[(np.asarray(tr)[j] == VECTOR) & (np.asarray(tl)[j + 1] == VECTOR)] = 0.0
    return out


def _nurbs_valid(splines, lay, curves):
    """Curves of ``curves`` (indices) Blender evaluates as NURBS: (curves, orders,
    knots modes)."""
    order = (np.full(lay.C, DEFAULT_ORDER) if splines.nurbs_order is None
             else np.asarray(splines.nurbs_order, np.int64))[curves]
    mode = (np.zeros(lay.C, np.int64) if splines.knots_mode is None
            else np.asarray(splines.knots_mode, np.int64))[curves]
    n = lay.sizes[curves]
    ok = (order >= 2) & (n >= order)
    ok &= ~((mode == KNOTS_BEZIER) & (n <= order))  # (non-cyclic curves only here)
    return curves[ok], order[ok], mode[ok]


def _bspline_basis(knots, k, t):
    """Cox-de Boor: (len(t), len(knots) - k) B-spline basis of order ``k`` at ``t``
    (parameters inside knot spans)."""
    U = np.asarray(knots, np.float64)
    T = np.asarray(t, np.float64)[:, None]
    N = ((U[:-1] <= T) & (T < U[1:])).astype(np.float64)
    for r in range(2, k + 1):
        nb = len(U) - r
        den1 = U[r - 1:r - 1 + nb] - U[:nb]
        den2 = U[r:r + nb] - U[1:1 + nb]
        a = np.divide(T - U[:nb], den1, out=np.zeros((len(T), nb)), where=den1 > 0)
        b = np.divide(U[r:r + nb] - T, den2, out=np.zeros((len(T), nb)), where=den2 > 0)
        N = a * N[:, :nb] + b * N[:, 1:nb + 1]
    return N


@lru_cache(maxsize=64)
def _bezier_extraction(n: int, k: int, mode: int) -> tuple:
    """The Bezier pieces of a non-cyclic NURBS of ``n`` points, order ``k`` and knots
    ``mode`` (NORMAL: uniform knots; ENDPOINT: clamped uniform, as Blender's
    ``calculate_knots`` makes them): per half of each nonzero knot span, (the first
    point of its window of ``k`` points, the (k, k) matrix taking the window's points
    to that half's Bezier control points). Each piece of the curve (rational too, with positive
    weights) lies in the convex hull of its Bezier points, which are close to the
    control polygon where the window's points are (a uniform cubic's are within
    a sixth of a second difference of it)."""
    if mode == KNOTS_ENDPOINT:
        knots = np.concatenate([np.zeros(k), np.arange(1, n - k + 1), np.full(k, n - k + 1)])
    else:
        knots = np.arange(n + k, dtype=np.float64)
    p = k - 1
    s = (np.arange(k) + 1.0) / (k + 1.0)  # sample parameters inside each span
    bern = np.stack([comb(p, m) * s**m * (1 - s) ** (p - m) for m in range(k)], 1)
    inv_bern = np.linalg.inv(bern)  # (once per layout: cached)
    # de Casteljau halves: the two halves of a piece hug the polygon closer
    half_l = np.array([[comb(i, j) / 2.0**i if j <= i else 0.0 for j in range(k)]
                       for i in range(k)])
    half_r = half_l[::-1, ::-1]
    out = []
    for i in range(k - 1, n):
        if knots[i + 1] <= knots[i]:
            continue
        t = knots[i] + s * (knots[i + 1] - knots[i])
        first = i - k + 1
        N = _bspline_basis(knots, k, t)[:, first:first + k]
        A = inv_bern @ N
        for half in (half_l, half_r):
            H = half @ A
            H[np.abs(H) < 1e-12] = 0.0
            out.append((first, H))
    return tuple(out)


def _nurbs_bound(splines, lay, P, d, nurbs, coef):
    """(C,) bound of the NURBS curves ``nurbs`` (C,) bool.

    Each piece of the curve lies in the convex hull of its Bezier points
    (:func:`_bezier_extraction`; for knots modes it does not model, Bezier and
    custom knots, the window's own points, a looser hull), so within
    ``min_s max_b dist(B_b, segment s)`` of the polygon over the window's segments
    ``s`` (the distance to one segment is convex). ``coef(curves, m)``, when given,
    is how much two segments ``m`` apart can turn against each other in a solve: a
    Bezier point, a fixed convex mix of the window's points, moves from segment
    ``s`` by at most its mix of the points' own moves.
    """
    out = np.zeros(lay.C)
    curves, orders, modes = _nurbs_valid(splines, lay, np.flatnonzero(nurbs))
    if not len(curves):
        return out
    seglen = _norm(d)
    wts = (np.ones(lay.P) if splines.nurbs_weight is None
           else np.asarray(splines.nurbs_weight, np.float64))
    modeled = np.where(np.isin(modes, (KNOTS_NORMAL, KNOTS_ENDPOINT)), modes, -1)
    keys = np.stack([lay.sizes[curves], orders, modeled], 1)
    for n, k, mode in np.unique(keys, axis=0):
        cs = curves[np.all(keys == (n, k, mode), axis=1)]
        idx = lay.offsets[cs][:, None] + np.arange(n)
        Q, w, L = P[idx], wts[idx], seglen[idx]
        if mode < 0:  # the windows themselves
            pieces = [(f, np.eye(k)) for f in range(n - k + 1)]
        else:
            pieces = _bezier_extraction(int(n), int(k), int(mode))
        best = np.zeros(len(cs))
        if coef is not None:  # (gap, curve) turn coefficients, and the path matrices
            cm = np.stack([coef(cs, m) for m in range(k)])
            paths = [_window_paths(s_, k) for s_ in range(k - 1)]
        for first, A in pieces:
            Wq, wq, Lq = Q[:, first:first + k], w[:, first:first + k], L[:, first:first + k - 1]
            mix = A[None] * wq[:, None, :]
            mix /= mix.sum(2, keepdims=True)  # (m, Bezier point, window point), convex
            B = np.einsum("mbq,mqx->mbx", mix, Wq)
            piece = np.full(len(cs), np.inf)
            for s_ in range(k - 1):
                a, dv = Wq[:, s_], Wq[:, s_ + 1] - Wq[:, s_]
                rel = B - a[:, None, :]
                dd = np.einsum("mx,mx->m", dv, dv)[:, None]
                t = np.clip(np.divide(np.einsum("mbx,mx->mb", rel, dv), dd,
                                      out=np.zeros(rel.shape[:2]), where=dd > 0), 0.0, 1.0)
                dist = _norm(rel - t[..., None] * dv[:, None, :])
                if coef is not None:
                    gaps = np.abs(np.arange(k - 1) - s_)
                    # (m, window point): the path sums in one fixed order (a BLAS
                    # product's order depends on how many curves it takes)
                    w_ = Lq * cm[gaps].T
                    moves = np.zeros((len(cs), k))
                    for j in range(k - 1):
                        moves += w_[:, j, None] * paths[s_][:, j]
                    dist = dist + np.einsum("mbq,mq->mb", mix, moves)
                piece = np.minimum(piece, dist.max(1))
            best = np.maximum(best, piece)
        out[cs] = np.maximum(out[cs], np.where(np.isfinite(best), best, 0.0))
    return out


def _window_paths(s, k):
    """(k, k - 1) 0/1: the segments between window point ``q`` and segment ``s`` (those
    whose turn against ``s`` moves ``q`` relative to it)."""
    M = np.zeros((k, k - 1))
    for q in range(k):
        js = range(s + 1, q) if q > s else range(q, s)
        M[q, list(js)] = 1.0
    return M


def _ramp(counts):
    """0, 1, .., counts[0]-1, 0, 1, .., counts[1]-1, ... (concatenated)."""
    counts = np.asarray(counts, np.int64)
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    starts = np.repeat(np.cumsum(counts) - counts, counts)
    return np.arange(total) - starts


# --------------------------------------------------------- through a solve
def turn_allowance(settings, nseg) -> tuple[np.ndarray, np.ndarray]:
    """How much two segments ``m`` apart in one curve can turn against each other in
    a solve: per curve the angle ``phi`` (C,) between neighbouring segments
    (radians, at most pi), and per curve (C,) the largest difference of Shrink scales
    between neighbours per radian of that angle (``max_angle`` and ``scale_minimum``
    may be per-curve arrays: parameter maps).

    * Stiff turns the whole curve rigidly: 0 (Shrink then scales every segment
      alike).
    * Bend turns segment ``j`` of ``n`` by ``(j + 1) / n`` of the curve's angle about
      one axis, at most ``max_angle``: neighbours differ by ``max_angle / n`` (a curve
      Bend solves as Stiff differs by 0); Shrink scales them by ``1 - (1 -
      scale_minimum) * min(angle / scale_angle, 1)``.
    * Soft turns each segment on its own: pi (any angle); lengths are kept.
    """
    nseg = np.maximum(np.asarray(nseg, np.float64), 1.0)
    C = len(nseg)
    if settings.mode == "stiff":
        phi = np.zeros(C)
    elif settings.mode == "bend":
        phi = np.minimum(np.deg2rad(np.asarray(settings.max_angle, np.float64)) / nseg, np.pi)
    else:
        phi = np.full(C, np.pi)
    shrink = np.zeros(C)
    if settings.shrink and settings.mode == "bend":
        shrink = shrink + (1.0 - np.asarray(settings.scale_minimum, np.float64)) / np.deg2rad(
            settings.scale_angle)
    return phi, shrink


def _turn_coefficient(phi, shrink, m):
    """Largest ``|s_j R_j - s_k R_k|`` (operator norm) of two segments ``m`` apart:
    ``2 sin(m phi / 2)`` for the rotation, plus the Shrink scale difference, at most 2
    (both have length at most their input's)."""
    ang = np.minimum(m * phi, np.pi)
    return np.minimum(2.0 * np.sin(0.5 * ang) + np.minimum(shrink * ang, 1.0), 2.0)


def clearance_margin(splines: Splines, points, offsets, settings, enabled=None) -> np.ndarray:
    """A bound, per curve, on how far the curve Blender draws can be from the
    polyline the solver keeps clear, for any solve of ``settings`` from ``points``.

    Widening a curve's clearance by this margin keeps its drawn spline out of every
    collider wherever its polyline keeps the widened clearance.

    Parameters
    ----------
    splines : Splines
        Handle positions (Bezier) in the space of ``points`` (world).
    points : (P, 3) float ndarray
        The frame's input curves (world): the solve turns their segments.
    offsets : (C+1,) int ndarray
    settings : core.Settings
        ``mode``, ``max_angle`` and the Shrink settings bound the turns
        (:func:`turn_allowance`).
    enabled : (C,) bool ndarray, optional
        Curves not enabled get 0 (they are not solved).

    Returns
    -------
    (C,) float64 ndarray
        0 for Poly, cyclic and disabled curves.

    Notes
    -----
    * Catmull-Rom: the second difference at an inner point, ``|s_j R_j d_j - s_(j-1)
      R_(j-1) d_(j-1)|``, grows by at most ``c_1 max(|d_j|, |d_(j-1)|)`` (c from
      :func:`_turn_coefficient`) and is at most ``|d_j| + |d_(j-1)|``; the ends keep
      their tangent along their segment whatever the turn. The Hermite bound follows
      with unknown directions.
    * Bezier: a handle moves with its point's rotation (:func:`point_rotations`),
      which is off its segment's turn by half the change of the angle between the
      point's two segments, at most ``phi / 2`` (exactly 0 at a curve's ends): its
      distance from the segment grows by at most ``2 sin(phi / 4) |h|``, and never
      exceeds ``|h|`` (the point is on the segment). VECTOR handles are on it.
    * NURBS: a window point's distance from the window's segment ``s`` grows by at
      most ``sum_j c_|j-s| |d_j|`` over the window's other segments.
    """
    with np.errstate(invalid="ignore", over="ignore"):  # (non-finite curves count 0)
        return _clearance_margin(splines, points, offsets, settings, enabled)


def _clearance_margin(splines: Splines, points, offsets, settings, enabled=None) -> np.ndarray:
    lay = _Layout(offsets)
    P = np.asarray(points, np.float64)
    out = np.zeros(lay.C)
    if lay.P == 0 or splines.drawn_as_polygon:
        return out
    phi_c, shrink = turn_allowance(settings, lay.sizes - 1)
    types = np.asarray(splines.types)
    open_c = ~_cyclic(splines, lay)
    d = lay.segments(P)
    seglen = _norm(d)
    per_seg = np.zeros(lay.P)
    cr = lay.seg & (types == CATMULL_ROM)[lay.curve] & open_c[lay.curve]
    if cr.any():
        per_seg[cr] = _catmull_rom_margin(lay, d, seglen, cr, phi_c, shrink, settings)
    bz = lay.seg & (types == BEZIER)[lay.curve] & open_c[lay.curve]
    if bz.any() and splines.handle_left is not None and splines.handle_right is not None:
        per_seg[bz] = _bezier_margin(lay, P, d, bz, splines, phi_c)
    out = lay.per_curve_max(per_seg, lay.seg)
    nurbs = (types == NURBS) & open_c
    if nurbs.any():
        def coef(curves, m):
            return _turn_coefficient(phi_c[curves], shrink[curves], m)
        out = np.maximum(out, _nurbs_bound(splines, lay, P, d, nurbs, coef))
    out = np.nan_to_num(out, nan=0.0, posinf=0.0)
    # float noise of straight curves is no curvature: no margin below it
    longest = lay.per_curve_max(seglen, lay.seg)
    out[out <= tol.SPLINE_MARGIN_NOISE * longest] = 0.0
    if enabled is not None:
        out[~np.asarray(enabled, bool)] = 0.0
    return out


def largest_margin(splines: Splines, points, offsets, settings, enabled=None) -> float:
    """``clearance_margin(splines, points, offsets, settings, enabled).max()`` (0.0 for
    no curve), the same bits, computed in full only on the curves that can hold it.

    What every user of the margin needs is the largest (one widening for every curve
    of a solve: :func:`core.pipeline.frame.drawn_clearance`). Each Catmull-Rom curve
    gets a cheap upper bound of its margin (:func:`_hermite_upper`); the exact margin
    of the ``tol.SPLINE_MARGIN_SEEDS`` curves of the largest bounds is a lower bound
    of the largest, and only the curves whose bound exceeds it are measured in full
    (with every Bezier and NURBS curve, measured in full always): no other curve can
    hold the largest margin. A curve's margin depends on its own points, splines and
    settings only (every sum in a fixed order), so measuring it among fewer curves
    gives the same bits. Where that would not save work (Soft, where the bounds of a
    groom are alike; mostly other curve types; most curves passing the bar; a few
    hundred curves) every curve is measured.

    Raises
    ------
    core.errors.SettingsError
        A parameter map of ``settings`` without one value per curve.
    """
    with np.errstate(invalid="ignore", over="ignore"):  # (non-finite curves count 0)
        return _largest_margin(splines, points, offsets, settings, enabled)


def _largest_margin(splines, points, offsets, settings, enabled):
    lay = _Layout(offsets)
    if lay.P == 0 or splines.drawn_as_polygon:
        return 0.0
    P = np.asarray(points, np.float64)
    offs = lay.offsets
    settings.check_curve_count(lay.C)
    types = np.asarray(splines.types)
    open_c = ~_cyclic(splines, lay)
    cr = (types == CATMULL_ROM) & open_c
    # Few curves, Soft (every turn allowed: the bounds of a groom are alike) or few
    # Catmull-Rom curves (the others are measured in full anyway): measure every curve
    if (lay.C <= 4 * tol.SPLINE_MARGIN_SEEDS or settings.mode == "soft"
            or 2 * np.count_nonzero(cr) < lay.C):
        return float(_clearance_margin(splines, P, offs, settings, enabled).max())
    phi_c, shrink = turn_allowance(settings, lay.sizes - 1)
    n = uniform_size(offs)
    if n > 1:
        bound, longest = _catmull_rom_upper_uniform(P.reshape(lay.C, n, 3), phi_c, shrink,
                                                    settings)
    else:
        bound, longest = _catmull_rom_upper(lay, P, cr, phi_c, shrink, settings)
    bound[~cr] = 0.0
    # every other drawn curve is measured in full; a non-finite bound tells nothing
    bound[(~cr & (types != POLY) & open_c) | ~(bound < np.inf)] = np.inf
    # a margin at most the noise of its curve counts 0 (as in clearance_margin)
    bound[~(bound > tol.SPLINE_MARGIN_NOISE * longest)] = 0.0
    if enabled is not None:
        bound[~np.asarray(enabled, bool)] = 0.0

    def measured(idx):
        which = np.zeros(lay.C, bool)
        which[idx] = True
        rows, sub = subset(offs, which)
        idx = np.flatnonzero(which)
        return _clearance_margin(splines.take(which, offs), P[rows], sub, settings.take(idx),
                                 None if enabled is None else np.asarray(enabled, bool)[idx])

    k = tol.SPLINE_MARGIN_SEEDS
    seeds = np.argpartition(-bound, k)[:k]
    lower = float(measured(seeds).max())
    bound[seeds] = 0.0  # (measured)
    rest = np.flatnonzero(bound > lower)
    if 2 * len(rest) > lay.C:  # (a groom of even margins: measuring all costs less)
        return float(_clearance_margin(splines, P, offs, settings, enabled).max())
    return max(lower, float(measured(rest).max())) if len(rest) else lower


def _catmull_rom_upper(lay, P, cr, phi_c, shrink, settings):
    """(upper bound of each curve's Catmull-Rom margin, inf where one of its
    segments' is not finite; its longest segment) (C,) of any layout."""
    d = lay.segments(P)
    seglen = _norm(d)
    mask = lay.seg & cr[lay.curve]
    upper = np.zeros(lay.P)
    if mask.any():
        upper[mask] = _hermite_upper(*_catmull_rom_terms(lay, d, seglen, mask, phi_c,
                                                         shrink, settings))
    upper[~np.isfinite(upper)] = np.inf
    nz = lay.sizes > 0
    bound = np.zeros(lay.C)
    bound[nz] = np.maximum.reduceat(np.where(lay.seg, upper, 0.0), lay.offsets[:-1][nz])
    return bound, lay.per_curve_max(seglen, lay.seg)


def _catmull_rom_upper_uniform(P3, phi_c, shrink, settings):
    """:func:`_catmull_rom_upper` of ``C`` curves of ``n`` points each, ``P3`` (C, n, 3),
    as every curve were Catmull-Rom: the same bound in whole (C, n - 1) columns, with
    no gather (a groom's usual layout; the bound's rounding is within its slack)."""
    d = P3[:, 1:] - P3[:, :-1]  # (C, m, 3): segment j from point j to j + 1
    L = _norm(d)
    c1 = _turn_coefficient(phi_c, shrink, 1)[:, None]
    # A at each inner point j (segments j - 1 and j), as _catmull_rom_terms
    A = 0.5 * np.minimum(_norm(d[:, 1:] - d[:, :-1]) + c1 * np.maximum(L[:, 1:], L[:, :-1]),
                         L[:, 1:] + L[:, :-1])  # (C, m - 1): points 1 .. m - 1
    if settings.shrink and settings.mode != "soft":
        smin = np.broadcast_to(np.asarray(settings.scale_minimum, np.float64), (len(L),))
        L_min = L * smin[:, None]
    else:
        L_min = L
    # (_hermite_upper with the end rule written out: a curve's first segment has no
    # across term at its start and -L_min / 2 along it, its last likewise at its end;
    # only the along terms' sizes count)
    def upper(a_perp, b_perp, a_abs, b_abs, L_min):
        return _hermite_upper(L_min, a_perp, a_abs, a_abs, b_perp, b_abs, b_abs)

    m = L.shape[1]
    if m == 1:
        half = 0.5 * L_min[:, 0]
        bound = upper(0.0, 0.0, half, half, L_min[:, 0])
    else:
        bound = np.maximum(upper(0.0, A[:, 0], 0.5 * L_min[:, 0], A[:, 0], L_min[:, 0]),
                           upper(A[:, -1], 0.0, A[:, -1], 0.5 * L_min[:, -1], L_min[:, -1]))
        if m > 2:
            Al, Ar = A[:, :-1], A[:, 1:]
            inner = upper(Al, Ar, Al, Ar, L_min[:, 1:-1])
            inner[~np.isfinite(inner)] = np.inf
            bound = np.maximum(bound, inner.max(axis=1))
    bound[~np.isfinite(bound)] = np.inf
    longest = np.where(np.isfinite(L), L, 0.0).max(axis=1)
    return bound, np.maximum(longest, 0.0)


def _catmull_rom_margin(lay, d, seglen, mask, phi_c, shrink, settings):
    return _hermite_bound(*_catmull_rom_terms(lay, d, seglen, mask, phi_c, shrink, settings))


def _catmull_rom_terms(lay, d, seglen, mask, phi_c, shrink, settings):
    """The arguments of :func:`_hermite_bound` for the Catmull-Rom segments ``mask``
    (point-indexed) through any solve of ``settings``."""
    c1 = _turn_coefficient(phi_c, shrink, 1)[lay.curve]
    prev_len = _shifted(seglen, 1)
    # half the second difference at each point (its two segments), grown by the turn:
    # a segment's start uses its first point's, its end the next point's
    A = 0.5 * np.minimum(_norm(d - _shifted(d, 1)) + c1 * np.maximum(seglen, prev_len),
                         seglen + prev_len)
    B = _shifted(A, -1)
    end = _shifted(lay.last, -1, True)
    j = np.flatnonzero(mask)
    A, B, L, start, end = A[j], B[j], seglen[j], lay.first[j], end[j]
    # Shrink may shorten the chord (by scale_minimum at most) while the ends' along
    # terms shrink with it: the along test uses the shortest chord.
    if settings.shrink and settings.mode != "soft":
        smin = np.broadcast_to(np.asarray(settings.scale_minimum, np.float64), (lay.C,))
        L_min = L * smin[lay.curve[j]]
    else:
        L_min = L
    half = -0.5 * L_min
    return (L_min, np.where(start, 0.0, A), np.where(start, half, -A),
            np.where(start, half, A), np.where(end, 0.0, B),
            np.where(end, half, -B), np.where(end, half, B))


def _bezier_margin(lay, P, d, mask, splines, phi_c):
    j = np.flatnonzero(mask)
    a, dj = P[j], d[j]
    hr = np.asarray(splines.handle_right, np.float64)[j]
    hl = np.asarray(splines.handle_left, np.float64)[j + 1]
    grow = 2.0 * np.sin(np.minimum(phi_c[lay.curve[j]], np.pi) / 4.0)
    out = np.zeros(len(j))
    for h, at, types in ((hr, j, splines.handle_type_right),
                         (hl, j + 1, splines.handle_type_left)):
        length = _norm(h - P[at])
        dist = _point_segment_distance(h, a, dj)
        # a curve's end handle turns exactly with its segment
        end = lay.first[at] | lay.last[at]
        bound = np.minimum(length, dist + np.where(end, 0.0, grow) * length)
        if types is not None:
            bound[np.asarray(types)[at] == VECTOR] = 0.0  # recomputed onto the segment
        out = np.maximum(out, bound)
    return out


def quantized(margin) -> np.ndarray:
    """``margin`` rounded UP onto a geometric grid of ``tol.SPLINE_MARGIN_STEPS``
    steps per decade (0 stays 0): a margin that follows an animated groom by a few
    ulps keeps the same value, so the colliders' offset shells are not rebuilt."""
    m = np.asarray(margin, np.float64)
    out = np.zeros_like(m)
    pos = m > 0
    if pos.any():
        k = np.ceil(np.log10(m[pos]) * tol.SPLINE_MARGIN_STEPS - 1e-9)
        out[pos] = 10.0 ** (k / tol.SPLINE_MARGIN_STEPS)
        out[pos] = np.maximum(out[pos], m[pos])  # (never below the bound)
    return out


class DrawnMargin:
    """How much farther than its solved polygon each curve must keep from the
    colliders, so that the curve Blender draws through its points clears them too:
    :func:`clearance_margin`, rounded up by :func:`quantized` (0 for Poly curves).

    Keeps the last margin and what it was computed from: a groom that does not move
    (a collider passing through still fur) gives the same margin every frame without
    computing it again. One per shot (a setup, a script's :class:`Shot`).
    """

    def __init__(self):
        self._key = None
        self._margin = None
        self._largest = None

    def __call__(self, splines: Splines, points, offsets, settings, enabled=None):
        """(C,) float64 margins of the curves ``points`` / ``offsets`` drawn as
        ``splines``, through any solve of ``settings``."""
        key = self._key_of(settings, splines, points, offsets, enabled)
        if self._key is not None and self._margin is not None and _same_key(self._key, key):
            return self._margin
        margin = quantized(clearance_margin(splines, points, offsets, settings, enabled))
        self._key, self._margin = key, margin
        self._largest = float(margin.max()) if len(margin) else 0.0
        return margin

    def largest(self, splines: Splines, points, offsets, settings, enabled=None) -> float:
        """The largest of :meth:`__call__`'s margins (0.0 for none), the same bits,
        without measuring every curve in full (:func:`largest_margin`); kept as
        ``__call__`` keeps its margins."""
        key = self._key_of(settings, splines, points, offsets, enabled)
        if self._key is not None and self._largest is not None and _same_key(self._key, key):
            return self._largest
        largest = float(quantized(largest_margin(splines, points, offsets, settings, enabled)))
        self._key, self._margin, self._largest = key, None, largest
        return largest

    @staticmethod
    def _key_of(settings, sp, points, offsets, enabled) -> tuple:
        """(the settings that bound the turns, copies of every array the margin reads)."""
        s = settings
        arrays = (points, offsets, enabled, sp.types, sp.cyclic, sp.handle_left,
                  sp.handle_right, sp.handle_type_left, sp.handle_type_right, sp.nurbs_order,
                  sp.knots_mode, sp.nurbs_weight)
        # (max_angle and scale_minimum may be per-curve arrays: compared by their bytes)
        turns = tuple(v.tobytes() if isinstance(v, np.ndarray) else v
                      for v in (s.mode, s.max_angle, s.shrink, s.scale_minimum, s.scale_angle))
        return (turns, *(None if a is None else np.array(a) for a in arrays))


def _same_key(a, b) -> bool:
    if a[0] != b[0]:
        return False
    for x, y in zip(a[1:], b[1:], strict=True):
        if (x is None) != (y is None):
            return False
        if x is not None and not (x.shape == y.shape and np.array_equal(x, y)):
            return False
    return True


# ------------------------------------------------------------ handle rotations
def _minimal_arc(a, b):
    """(k, 3, 3) minimal rotations taking unit rows ``a`` to unit rows ``b``
    (identity for zero rows; a half turn about a perpendicular for opposite ones)."""
    k = len(a)
    R = np.broadcast_to(np.eye(3), (k, 3, 3)).copy()
    ok = (_norm(a) > 0) & (_norm(b) > 0)
    if not ok.any():
        return R
    a, b = a[ok], b[ok]
    v = np.cross(a, b)
    c = np.einsum("ij,ij->i", a, b)
    opposite = c < -1.0 + tol.PARALLEL_EPS
    # Rodrigues with K = [v]x: I + K + K^2 / (1 + c), and K^2 = v v^T - |v|^2 I
    f = 1.0 / np.where(opposite, 1.0, 1.0 + c)
    Rk = (v[:, :, None] * v[:, None, :]) * f[:, None, None]
    Rk[:, [0, 1, 2], [0, 1, 2]] += (1.0 - np.einsum("ij,ij->i", v, v) * f)[:, None]
    Rk[:, 0, 1] -= v[:, 2]
    Rk[:, 0, 2] += v[:, 1]
    Rk[:, 1, 2] -= v[:, 0]
    Rk[:, 1, 0] += v[:, 2]
    Rk[:, 2, 0] -= v[:, 1]
    Rk[:, 2, 1] += v[:, 0]
    if opposite.any():
        p = stable_perpendicular(a[opposite])
        Rk[opposite] = 2.0 * (p[:, :, None] * p[:, None, :]) - np.eye(3)
    R[ok] = Rk
    return R


def _frame(b, n):
    """(k, 3, 3) frames with columns ``b, n x b, n`` of unit rows ``b`` ⟂ ``n``."""
    return np.stack([b, np.cross(n, b), n], axis=2)


def point_rotations(before, after, offsets) -> np.ndarray:
    """The rotation of each control point from ``before`` to ``after``, (P, 3, 3).

    An inner point takes the rotation mapping the bisector of its two segment
    directions, and the normal of their plane, from before to after (the minimal
    rotation of the bisector where either pair is straight or folded): it is off
    each of its segments' own turns by half the change of the angle between them,
    and a curve turned rigidly turns its points by exactly that rotation. A
    curve's first and last points take their segment's turn: the neighbour's
    rotation, then the minimal rotation onto their segment's direction. A curve of
    one segment turns by that segment's minimal rotation; single points and zero
    segments keep the identity where nothing defines a turn.

    Parameters
    ----------
    before, after : (P, 3) float ndarrays
    offsets : (C+1,) int ndarray
    """
    lay = _Layout(offsets)
    R = np.broadcast_to(np.eye(3), (lay.P, 3, 3)).copy()
    if lay.P < 2:
        return R
    u0, _ = _unit(lay.segments(np.asarray(before, np.float64)))
    u1, _ = _unit(lay.segments(np.asarray(after, np.float64)))
    prev0, prev1 = np.zeros_like(u0), np.zeros_like(u1)
    prev0[1:], prev1[1:] = u0[:-1], u1[:-1]
    prev0[lay.first], prev1[lay.first] = 0.0, 0.0
    has_in = _norm(prev0) > 0
    has_out = _norm(u0) > 0
    is_inner = has_in & has_out & ~lay.first & ~lay.last
    inner = np.flatnonzero(is_inner)
    if len(inner):
        R[inner] = _inner_rotations(prev0[inner], u0[inner], prev1[inner], u1[inner])
    # points with one usable segment: the root and tip rules
    one = np.flatnonzero(~is_inner & (has_in | has_out))
    if len(one):
        out_side = has_out[one]
        a = np.where(out_side[:, None], u0[one], prev0[one])
        b = np.where(out_side[:, None], u1[one], prev1[one])
        nb = np.clip(one + np.where(out_side, 1, -1), 0, lay.P - 1)  # along that segment
        base = np.where(is_inner[nb][:, None, None], R[nb], np.eye(3))
        turned = np.einsum("kij,kj->ki", base, a)
        R[one] = np.matmul(_minimal_arc(turned, b), base)
    return R


def _inner_rotations(a0, b0, a1, b1):
    """Rotations of inner points whose segment directions turn from (a0, b0) to
    (a1, b1) (unit rows, (k, 3) each)."""
    bis0, bis1 = a0 + b0, a1 + b1
    n0, n1 = np.cross(a0, b0), np.cross(a1, b1)
    folded0 = _norm(bis0) <= tol.PARALLEL_EPS
    folded1 = _norm(bis1) <= tol.PARALLEL_EPS
    # a folded pair (180 degrees) has no bisector: any direction across it
    if folded0.any():
        bis0[folded0] = stable_perpendicular(b0[folded0])
    if folded1.any():
        bis1[folded1] = stable_perpendicular(b1[folded1])
    bis0, _ = _unit(bis0)
    bis1, _ = _unit(bis1)
    s0, s1 = _norm(n0), _norm(n1)
    planar = (s0 > tol.PARALLEL_EPS) & (s1 > tol.PARALLEL_EPS) & ~folded0 & ~folded1
    R = np.empty((len(a0), 3, 3))
    if planar.any():
        F0 = _frame(bis0[planar], n0[planar] / s0[planar, None])
        F1 = _frame(bis1[planar], n1[planar] / s1[planar, None])
        R[planar] = np.matmul(F1, F0.transpose(0, 2, 1))
    if not planar.all():
        R[~planar] = _minimal_arc(bis0[~planar], bis1[~planar])
    return R


def moved_handles(before, after, offsets, handle_left, handle_right):
    """Handles that move with their control point from ``before`` to ``after``.

    Each handle keeps its offset from its point, turned by the point's rotation
    (:func:`point_rotations`) and scaled as its own segment's length (the right
    handle's segment is the next, the left's the previous; a curve end uses its one
    segment). Points that did not move and whose segments did not turn keep their
    handles exactly.

    Parameters
    ----------
    before, after : (P, 3) float ndarrays
    offsets : (C+1,) int ndarray
    handle_left, handle_right : (P, 3) float ndarrays
        In the space of ``before``.

    Returns
    -------
    handle_left, handle_right : (P, 3) float64 ndarrays
        In the space of ``after``.
    """
    lay = _Layout(offsets)
    before = np.asarray(before, np.float64)
    after = np.asarray(after, np.float64)
    hl = np.array(handle_left, np.float64)
    hr = np.array(handle_right, np.float64)
    # only curves with a moved point are touched: the others keep their handles bit
    # for bit (a translation alone moves them along)
    moved_pt = np.any(before != after, axis=1)
    moved_c = np.zeros(lay.C, bool)
    moved_c[lay.curve[moved_pt]] = True
    if not moved_c.any():
        return hl, hr
    pts = moved_c[lay.curve]
    sub_offs = np.concatenate([[0], np.cumsum(lay.sizes[moved_c])])
    b, a = before[pts], after[pts]
    R = point_rotations(b, a, sub_offs)
    sub = _Layout(sub_offs)
    len0, len1 = _norm(sub.segments(b)), _norm(sub.segments(a))
    ratio = np.divide(len1, len0, out=np.ones_like(len0), where=len0 > 0)
    ratio[sub.last] = 1.0
    right = ratio.copy()  # the next segment's
    right[sub.last] = np.concatenate([[1.0], ratio[:-1]])[sub.last]  # tip: its last segment
    left = np.ones_like(ratio)
    left[1:] = ratio[:-1]
    left[sub.first] = ratio[sub.first]  # root: its first segment
    single = sub.first & sub.last
    left[single] = right[single] = 1.0
    hl[pts] = a + np.einsum("kij,kj->ki", R, hl[pts] - b) * left[:, None]
    hr[pts] = a + np.einsum("kij,kj->ki", R, hr[pts] - b) * right[:, None]
    return hl, hr


def written_handle_types(left, right):
    """The handle types written with moved handles, and why.

    Blender never recomputes handles when it evaluates a curve, but its tools and
    nodes (Set Position, editing, and the handle rules of every later change)
    recompute AUTO and VECTOR handles from the positions, and turn an ALIGN handle
    to face a non-ALIGN partner. The output must draw the handles that moved with
    their points whatever runs after it, so:

    * AUTO becomes ALIGN when the point's other handle is AUTO or ALIGN (AUTO handles
      are aligned, one rotation keeps them so, and two ALIGN handles are never
      touched), else FREE (an ALIGN handle would be turned toward a FREE or VECTOR
      partner).
    * VECTOR stays VECTOR: it is recomputed onto its segment (:func:`vector_handles`),
      which is what a VECTOR handle means and draws those segments straight.
    * ALIGN and FREE stay: moving both handles of a point by one rotation keeps an
      aligned pair aligned.

    Parameters
    ----------
    left, right : (P,) int ndarrays of handle type codes

    Returns
    -------
    left, right : (P,) int8 ndarrays
    """
    left = np.asarray(left, np.int8)
    right = np.asarray(right, np.int8)
    paired_l = np.isin(right, (AUTO, ALIGN))
    paired_r = np.isin(left, (AUTO, ALIGN))
    out_l = np.where(left == AUTO, np.where(paired_l, ALIGN, FREE), left).astype(np.int8)
    out_r = np.where(right == AUTO, np.where(paired_r, ALIGN, FREE), right).astype(np.int8)
    return out_l, out_r


def vector_handles(points, offsets, handle_left, handle_right, type_left, type_right,
                   cyclic=None):
    """Set the VECTOR handles of ``handle_left``/``handle_right`` (in place) as Blender
    computes them: a third of the way to the neighbouring point (a non-cyclic
    curve's missing neighbour is its end point mirrored, ``2 P_0 - P_1``)."""
    lay = _Layout(offsets)
    P = np.asarray(points, np.float64)
    if lay.P == 0:
        return handle_left, handle_right
    cyc = np.zeros(lay.C, bool) if cyclic is None else np.asarray(cyclic, bool)
    idx = np.arange(lay.P)
    start = lay.offsets[:-1][lay.curve]
    end = lay.offsets[1:][lay.curve] - 1
    single = start == end
    prev_i = np.where(lay.first, np.where(cyc[lay.curve], end, idx), idx - 1)
    next_i = np.where(lay.last, np.where(cyc[lay.curve], start, idx), idx + 1)
    prev = P[np.clip(prev_i, 0, lay.P - 1)]
    nxt = P[np.clip(next_i, 0, lay.P - 1)]
    mirror_prev = lay.first & ~cyc[lay.curve] & ~single
    mirror_next = lay.last & ~cyc[lay.curve] & ~single
    prev[mirror_prev] = 2.0 * P[mirror_prev] - nxt[mirror_prev]
    nxt[mirror_next] = 2.0 * P[mirror_next] - prev[mirror_next]
    vl = np.asarray(type_left) == VECTOR
    vr = np.asarray(type_right) == VECTOR
    handle_left[vl] = P[vl] + (prev[vl] - P[vl]) / 3.0
    handle_right[vr] = P[vr] + (nxt[vr] - P[vr]) / 3.0
    return handle_left, handle_right
