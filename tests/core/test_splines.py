"""The splines Blender draws through the solved points (``core.splines``): their bounds
hold against independent evaluations (Catmull-Rom with Blender's end rule, cubic
Bezier, NURBS by Cox-de Boor), through every kind of solve each mode can make, and
handles move with their point's rotation."""

from __future__ import annotations

import numpy as np
import pytest

from core import Settings, splines
from core.splines import ALIGN, AUTO, BEZIER, CATMULL_ROM, FREE, NURBS, POLY, VECTOR

SEEDS = range(6)


# ------------------------------------------------------------- oracles (no core)
def _cr_curve(Q, n=64):
    """Samples of Blender's non-cyclic Catmull-Rom through ``Q`` (end points repeated)."""
    if len(Q) < 2:
        return Q.copy()
    ext = np.vstack([Q[:1], Q, Q[-1:]])
    t = np.linspace(0.0, 1.0, n)[:, None]
    out = []
    for i in range(len(Q) - 1):
        p0, p1, p2, p3 = ext[i], ext[i + 1], ext[i + 2], ext[i + 3]
        out.append(0.5 * (2 * p1 + (p2 - p0) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t**2
                          + (-p0 + 3 * p1 - 3 * p2 + p3) * t**3))
    return np.vstack(out)


def _bezier_curve(Q, hl, hr, n=64):
    t = np.linspace(0.0, 1.0, n)[:, None]
    out = []
    for i in range(len(Q) - 1):
        b0, b1, b2, b3 = Q[i], hr[i], hl[i + 1], Q[i + 1]
        out.append((1 - t) ** 3 * b0 + 3 * (1 - t) ** 2 * t * b1 + 3 * (1 - t) * t**2 * b2
                   + t**3 * b3)
    return np.vstack(out)


def _basis(i, k, t, knots):
    """Cox-de Boor basis N_(i,k) (order k) at parameters ``t``."""
    if k == 1:
        last = knots[i + 1] == knots[-1]
        return ((knots[i] <= t) & ((t < knots[i + 1]) | (last & (t == knots[i + 1])))) * 1.0
    out = np.zeros_like(t)
    den = knots[i + k - 1] - knots[i]
    if den > 0:
        out += (t - knots[i]) / den * _basis(i, k - 1, t, knots)
    den = knots[i + k] - knots[i + 1]
    if den > 0:
        out += (knots[i + k] - t) / den * _basis(i + 1, k - 1, t, knots)
    return out


def _blender_knots(m, k, mode):
    """Blender's ``curves::nurbs::calculate_knots`` for a non-cyclic curve of ``m``
    points, order ``k`` (modes 0 NORMAL, 1 ENDPOINT, 2 BEZIER, 3 ENDPOINT_BEZIER)."""
    is_bezier, is_end = mode in (2, 3), mode in (1, 3)
    repeat_inner = k - 1 if is_bezier else 1
    head = k if is_end else (min(2, repeat_inner) if is_bezier else 1)
    tail = k if is_end else 0
    knots = np.zeros(m + k)
    r, current = head, 0.0
    for i in range(m + k - tail):
        knots[i] = current
        r -= 1
        if r == 0:
            current += 1.0
            r = repeat_inner
    for i in range(tail):
        knots[m + k - tail + i] = current + (knots[i] - knots[0])
    return knots


def _nurbs_curve(Q, w, k, mode, n=400):
    m = len(Q)
    knots = _blender_knots(m, k, int(mode))
    t = np.linspace(knots[k - 1], knots[m], n)
    N = np.stack([_basis(i, k, t, knots) * w[i] for i in range(m)], 1)
    return (N @ Q) / N.sum(1, keepdims=True)


def _polyline_distance(X, Q):
    """Distance of each point of ``X`` to the polyline through ``Q``."""
    A, D = Q[:-1], Q[1:] - Q[:-1]
    dd = np.maximum((D * D).sum(1), 1e-300)
    t = np.clip(np.einsum("kmj,mj->km", X[:, None] - A[None], D) / dd, 0, 1)
    return np.linalg.norm(X[:, None] - A[None] - t[..., None] * D[None], axis=2).min(1)


def _blender_auto_handles(Q):
    """Blender's AUTO handles (``calculate_point_handles``) of an open curve."""
    prev = np.vstack([2 * Q[:1] - Q[1:2], Q[:-1]])
    nxt = np.vstack([Q[1:], 2 * Q[-1:] - Q[-2:-1]])
    pd, nd = Q - prev, nxt - Q
    pl = np.linalg.norm(pd, axis=1)
    nl = np.linalg.norm(nd, axis=1)
    d = nd / nl[:, None] + pd / pl[:, None]
    ln = np.linalg.norm(d, axis=1) * 2.5614
    hl = Q - d * (np.minimum(pl, 5 * nl) / ln)[:, None]
    hr = Q + d * (np.minimum(nl, 5 * pl) / ln)[:, None]
    return hl, hr


# ------------------------------------------------------------------- grooms
def _groom(rng, n=12, kmin=2, kmax=9, wiggle=0.3):
    sizes = rng.integers(kmin, kmax + 1, n)
    offs = np.concatenate([[0], np.cumsum(sizes)])
    pts = []
    for k in sizes:
        d = rng.normal(size=(k - 1, 3)) * wiggle + [0, 0, 1.0]
        d *= rng.uniform(0.05, 0.3, (k - 1, 1)) / np.linalg.norm(d, axis=1, keepdims=True)
        pts.append(np.vstack([np.zeros(3), np.cumsum(d, 0)]) + rng.normal(size=3))
    return np.vstack(pts), offs


def _curves(P, offs):
    return [P[a:b] for a, b in zip(offs[:-1], offs[1:], strict=True)]


def _random_rotation(rng, angle):
    ax = rng.normal(size=3)
    ax /= np.linalg.norm(ax)
    return _axis_angle(ax, angle)


def _axis_angle(ax, a):
    K = np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]], [-ax[1], ax[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def _solve_like(rng, Q, s: Settings):
    """A polyline the solver of ``s`` could make from ``Q``: the segments turned (and
    shrunk) as the mode turns them, any angle up to ``max_angle``."""
    d = np.diff(Q, axis=0)
    n = len(d)
    theta = rng.uniform(0, np.deg2rad(s.max_angle))
    ax = rng.normal(size=3)
    ax /= np.linalg.norm(ax)
    if s.mode == "stiff":
        angles = np.full(n, theta)
    elif s.mode == "bend":
        angles = theta * (np.arange(n) + 1) / n if rng.random() < 0.8 else np.full(n, theta)
    else:
        angles = None
    out = []
    for j in range(n):
        if angles is None:  # soft: every segment its own turn
            R = _random_rotation(rng, rng.uniform(0, np.pi))
            scale = 1.0
        else:
            R = _axis_angle(ax, angles[j])
            scale = 1.0
            if s.shrink:
                scale = 1 - (1 - s.scale_minimum) * min(angles[j] / np.deg2rad(s.scale_angle), 1)
        out.append(scale * (R @ d[j]))
    return np.vstack([Q[:1], Q[0] + np.cumsum(out, 0)])


# ------------------------------------------------------------------- tests
def test_the_cubic_maximum_is_the_sampled_one():
    rng = np.random.default_rng(0)
    c = rng.normal(size=(4, 500))
    t = np.linspace(0, 1, 20001)[:, None]
    sampled = (c[0] + c[1] * t + c[2] * t**2 + c[3] * t**3).max(0)
    got = splines._cubic_max01(*c)
    assert np.all(got >= sampled - 1e-12)
    np.testing.assert_allclose(got, sampled, atol=1e-7)


@pytest.mark.parametrize("seed", SEEDS)
def test_catmull_rom_stays_within_its_bound(seed):
    rng = np.random.default_rng(seed)
    P, offs = _groom(rng, wiggle=1.0 + seed)
    sp = splines.Splines.catmull_rom(len(offs) - 1)
    bound = splines.polygon_deviation(sp, P, offs)
    for c, Q in enumerate(_curves(P, offs)):
        far = _polyline_distance(_cr_curve(Q), Q).max()
        assert far <= bound[c] + 1e-12, (c, far, bound[c])
        assert bound[c] <= 3 * far + 1e-9  # and not far above it


def test_straight_and_two_point_catmull_rom_curves_need_no_margin():
    P = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2], [0, 0, 3.0], [1, 1, 1], [2, 0, 1.0]])
    offs = np.array([0, 4, 6])
    sp = splines.Splines.catmull_rom(2)
    np.testing.assert_allclose(splines.polygon_deviation(sp, P, offs), [0.0, 0.0], atol=1e-12)
    np.testing.assert_array_equal(
        splines.clearance_margin(sp, P, offs, Settings(mode="stiff")), [0.0, 0.0])


@pytest.mark.parametrize("seed", SEEDS)
def test_bezier_stays_within_its_bound(seed):
    rng = np.random.default_rng(seed)
    P, offs = _groom(rng)
    hl = P + rng.normal(size=P.shape) * 0.05
    hr = P + rng.normal(size=P.shape) * 0.05
    sp = splines.Splines(np.full(len(offs) - 1, BEZIER, np.int8), None, hl, hr)
    bound = splines.polygon_deviation(sp, P, offs)
    for c, (a, b) in enumerate(zip(offs[:-1], offs[1:], strict=True)):
        far = _polyline_distance(_bezier_curve(P[a:b], hl[a:b], hr[a:b]), P[a:b]).max()
        assert far <= bound[c] + 1e-12


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("order", [2, 3, 4, 5])
def test_nurbs_stays_within_its_bound(seed, order):
    rng = np.random.default_rng(seed)
    P, offs = _groom(rng, kmin=order, kmax=order + 6, wiggle=2.0)
    w = rng.uniform(0.2, 3.0, len(P))
    C = len(offs) - 1
    for mode in (0, 1, 2, 3):
        sp = splines.Splines(np.full(C, NURBS, np.int8), nurbs_order=np.full(C, order),
                             knots_mode=np.full(C, mode), nurbs_weight=w)
        bound = splines.polygon_deviation(sp, P, offs)
        for c, (a, b) in enumerate(zip(offs[:-1], offs[1:], strict=True)):
            if mode == 2 and b - a <= order:
                continue  # (Blender draws that one as its polygon)
            far = _polyline_distance(_nurbs_curve(P[a:b], w[a:b], order, mode), P[a:b]).max()
            assert far <= bound[c] + 1e-9, (mode, c, far, bound[c])
            if mode < 2:  # the modelled knots give a tight bound
                assert bound[c] <= 6 * far + 1e-9, (mode, c, far, bound[c])


def test_nurbs_with_fewer_points_than_its_order_is_its_polygon():
    P = np.array([[0, 0, 0], [1, 0, 1], [0, 0, 2.0]])
    sp = splines.Splines(np.array([NURBS], np.int8), nurbs_order=np.array([4]))
    assert splines.polygon_deviation(sp, P, np.array([0, 3]))[0] == 0.0


MODES = [
    Settings(mode="stiff"),
    Settings(mode="stiff", shrink=True, scale_minimum=0.3),
    Settings(mode="bend"),
    Settings(mode="bend", max_angle=60.0),
    Settings(mode="bend", shrink=True, scale_minimum=0.4, scale_angle=45.0),
    Settings(mode="soft"),
]


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("s", MODES, ids=lambda s: f"{s.mode}-{s.max_angle:g}-{s.shrink}")
def test_catmull_rom_margin_covers_every_solve_of_the_mode(seed, s):
    rng = np.random.default_rng(seed)
    P, offs = _groom(rng)
    sp = splines.Splines.catmull_rom(len(offs) - 1)
    margin = splines.clearance_margin(sp, P, offs, s)
    for c, Q in enumerate(_curves(P, offs)):
        for _ in range(8):
            S = _solve_like(rng, Q, s)
            far = _polyline_distance(_cr_curve(S), S).max()
            assert far <= margin[c] + 1e-9, (c, far, margin[c])


def _bezier_groom(rng, kinds):
    P, offs = _groom(rng, kmin=3)
    hl, hr = np.empty_like(P), np.empty_like(P)
    tl, tr = np.empty(len(P), np.int8), np.empty(len(P), np.int8)
    for c, (a, b) in enumerate(zip(offs[:-1], offs[1:], strict=True)):
        kind = kinds[c % len(kinds)]
        Q = P[a:b]
        al, ar = _blender_auto_handles(Q)
        if kind == AUTO:
            hl[a:b], hr[a:b] = al, ar
        elif kind == ALIGN:  # aligned, other lengths
            hl[a:b] = Q + (al - Q) * rng.uniform(0.3, 1.5, (b - a, 1))
            hr[a:b] = Q + (ar - Q) * rng.uniform(0.3, 1.5, (b - a, 1))
        elif kind == FREE:
            hl[a:b] = Q + rng.normal(size=Q.shape) * 0.04
            hr[a:b] = Q + rng.normal(size=Q.shape) * 0.04
        else:
            hl[a:b], hr[a:b] = Q, Q
        tl[a:b] = tr[a:b] = kind
    if VECTOR in kinds:
        splines.vector_handles(P, offs, hl, hr, tl, tr)
    return P, offs, splines.Splines(np.full(len(offs) - 1, BEZIER, np.int8), None, hl, hr,
                                    tl, tr)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("s", MODES, ids=lambda s: f"{s.mode}-{s.max_angle:g}-{s.shrink}")
def test_bezier_margin_covers_every_solve_with_handles_moved(seed, s):
    rng = np.random.default_rng(seed)
    P, offs, sp = _bezier_groom(rng, [AUTO, ALIGN, FREE, VECTOR])
    margin = splines.clearance_margin(sp, P, offs, s)
    for _ in range(6):
        S = np.vstack([_solve_like(rng, Q, s) for Q in _curves(P, offs)])
        hl, hr = splines.moved_handles(P, S, offs, sp.handle_left, sp.handle_right)
        splines.vector_handles(S, offs, hl, hr, sp.handle_type_left, sp.handle_type_right)
        for c, (a, b) in enumerate(zip(offs[:-1], offs[1:], strict=True)):
            far = _polyline_distance(_bezier_curve(S[a:b], hl[a:b], hr[a:b]), S[a:b]).max()
            assert far <= margin[c] + 1e-9, (c, far, margin[c])


@pytest.mark.parametrize("seed", SEEDS[:3])
@pytest.mark.parametrize("s", MODES, ids=lambda s: f"{s.mode}-{s.max_angle:g}-{s.shrink}")
def test_nurbs_margin_covers_every_solve_of_the_mode(seed, s):
    rng = np.random.default_rng(seed)
    P, offs = _groom(rng, kmin=4, kmax=8, wiggle=1.0)
    C = len(offs) - 1
    sp = splines.Splines(np.full(C, NURBS, np.int8), nurbs_order=np.full(C, 4),
                         knots_mode=np.ones(C, np.int64))
    margin = splines.clearance_margin(sp, P, offs, s)
    for c, Q in enumerate(_curves(P, offs)):
        for _ in range(4):
            S = _solve_like(rng, Q, s)
            far = _polyline_distance(_nurbs_curve(S, np.ones(len(S)), 4, 1), S).max()
            assert far <= margin[c] + 1e-9


def test_poly_cyclic_and_disabled_curves_get_no_margin():
    rng = np.random.default_rng(3)
    P, offs = _groom(rng, n=4, kmin=4)
    sp = splines.Splines(np.array([POLY, CATMULL_ROM, CATMULL_ROM, CATMULL_ROM], np.int8),
                         cyclic=np.array([False, True, False, False]))
    m = splines.clearance_margin(sp, P, offs, Settings(), enabled=[True, True, True, False])
    assert m[0] == 0 and m[1] == 0 and m[3] == 0 and m[2] > 0


def test_margins_are_rounded_up_onto_few_values():
    m = np.geomspace(1e-4, 1e-2, 1000)
    q = splines.quantized(m)
    assert np.all(q >= m) and np.all(q <= m * 10 ** (1 / 16) * (1 + 1e-12))
    assert len(np.unique(q)) <= 2 * 16 + 1
    assert splines.quantized(np.zeros(3)).tolist() == [0.0, 0.0, 0.0]


# --------------------------------------------------------------- rotations
def test_a_rigid_turn_turns_every_point_by_it():
    """(Curves of three points or more: one segment alone does not fix the twist.)"""
    rng = np.random.default_rng(1)
    P, offs = _groom(rng, kmin=3)
    R = _random_rotation(rng, 1.1)
    S = (P - 0.5) @ R.T + 2.0
    got = splines.point_rotations(P, S, offs)
    np.testing.assert_allclose(got, np.broadcast_to(R, got.shape), atol=1e-12)


def test_handles_of_unmoved_curves_are_kept_bit_for_bit():
    rng = np.random.default_rng(2)
    P, offs = _groom(rng)
    S = P.copy()
    S[offs[1] + 1] += 0.01  # one point of the second curve moves
    hl, hr = P + 0.1, P - 0.1
    ml, mr = splines.moved_handles(P, S, offs, hl, hr)
    keep = np.ones(len(P), bool)
    keep[offs[1]:offs[2]] = False
    assert np.array_equal(ml[keep], hl[keep]) and np.array_equal(mr[keep], hr[keep])
    assert not np.array_equal(ml[~keep], hl[~keep])


def test_a_bent_point_turns_by_half_its_segments_angle_change():
    """Inner points: the handle's direction is off each segment's own turn by half the
    change of the angle between the point's segments; the ends turn exactly with
    their segment."""
    rng = np.random.default_rng(4)
    Q = np.cumsum(np.vstack([np.zeros(3), rng.normal(size=(5, 3)) * 0.1 + [0, 0, 0.2]]), 0)
    s = Settings(mode="bend", max_angle=120.0)
    S = _solve_like(np.random.default_rng(5), Q, s)
    R = splines.point_rotations(Q, S, np.array([0, len(Q)]))
    d0, d1 = np.diff(Q, axis=0), np.diff(S, axis=0)
    u0 = d0 / np.linalg.norm(d0, axis=1, keepdims=True)
    u1 = d1 / np.linalg.norm(d1, axis=1, keepdims=True)

    def ang(a, b):
        return np.arccos(np.clip(np.dot(a, b), -1, 1))

    np.testing.assert_allclose(R[0] @ u0[0], u1[0], atol=1e-12)
    np.testing.assert_allclose(R[-1] @ u0[-1], u1[-1], atol=1e-12)
    for i in range(1, len(Q) - 1):
        half = abs(ang(u1[i - 1], u1[i]) - ang(u0[i - 1], u0[i])) / 2
        assert ang(R[i] @ u0[i], u1[i]) == pytest.approx(half, abs=1e-9)
        assert ang(R[i] @ u0[i - 1], u1[i - 1]) == pytest.approx(half, abs=1e-9)


def test_handle_types_written_are_never_recomputed_over_the_moved_handles():
    tl = np.array([AUTO, AUTO, AUTO, AUTO, VECTOR, ALIGN, FREE], np.int8)
    tr = np.array([AUTO, ALIGN, FREE, VECTOR, VECTOR, ALIGN, FREE], np.int8)
    wl, wr = splines.written_handle_types(tl, tr)
    assert wl.tolist() == [ALIGN, ALIGN, FREE, FREE, VECTOR, ALIGN, FREE]
    assert wr.tolist() == [ALIGN, ALIGN, FREE, VECTOR, VECTOR, ALIGN, FREE]


def test_vector_handles_are_blenders():
    P = np.array([[0, 0, 0], [0, 0, 3.0], [3, 0, 3.0]])
    hl, hr = np.zeros_like(P), np.zeros_like(P)
    t = np.full(3, VECTOR)
    splines.vector_handles(P, np.array([0, 3]), hl, hr, t, t)
    np.testing.assert_allclose(hl, [[0, 0, -1], [0, 0, 2], [2, 0, 3]])
    np.testing.assert_allclose(hr, [[0, 0, 1], [1, 0, 3], [4, 0, 3]])


@pytest.mark.parametrize("kind", [CATMULL_ROM, NURBS])
def test_per_curve_settings_give_each_curve_its_own_margin(kind):
    """Parameter maps: Max Angle and Scale Minimum as (C,) arrays. A uniform array gives
    the number's margins; a mixed one gives each curve the margin of its own value."""
    rng = np.random.default_rng(5)
    P, offs = _groom(rng, wiggle=2.0)
    C = len(offs) - 1
    sp = splines.Splines(np.full(C, kind, np.int8))
    base = dict(mode="bend", shrink=True, scale_angle=60.0)
    lo = Settings(max_angle=40.0, scale_minimum=0.8, **base)
    hi = Settings(max_angle=150.0, scale_minimum=0.3, **base)
    m_lo = splines.clearance_margin(sp, P, offs, lo)
    m_hi = splines.clearance_margin(sp, P, offs, hi)
    uniform = Settings(max_angle=np.full(C, 40.0), scale_minimum=np.full(C, 0.8), **base)
    np.testing.assert_array_equal(splines.clearance_margin(sp, P, offs, uniform), m_lo)
    pick = np.arange(C) % 2 == 0
    mixed = Settings(max_angle=np.where(pick, 150.0, 40.0),
                     scale_minimum=np.where(pick, 0.3, 0.8), **base)
    got = splines.clearance_margin(sp, P, offs, mixed)
    np.testing.assert_allclose(got, np.where(pick, m_hi, m_lo), rtol=1e-12)
    drawn = splines.DrawnMargin()
    np.testing.assert_array_equal(drawn(sp, P, offs, mixed), drawn(sp, P, offs, mixed))


def test_take_keeps_each_curves_own_splines():
    """A subset of curves (the clearance pass sets some aside) keeps every curve's own
    type and per-point data, and so its own margin."""
    rng = np.random.default_rng(5)
    P, offs = _groom(rng, wiggle=1.0)
    C = len(offs) - 1
    sp = splines.Splines(np.arange(C, dtype=np.int8) % 4, np.zeros(C, bool),
                         rng.normal(size=(len(P), 3)), rng.normal(size=(len(P), 3)),
                         np.zeros(len(P), np.int8), np.zeros(len(P), np.int8),
                         np.full(C, 3), np.zeros(C, np.int8), rng.uniform(0.5, 2, len(P)))
    keep = np.arange(C) % 3 != 1
    sizes = np.diff(offs)[keep]
    sub_off = np.r_[0, np.cumsum(sizes)]
    rows = np.concatenate([np.arange(offs[c], offs[c + 1]) for c in np.flatnonzero(keep)])
    sub = sp.take(keep, offs)
    np.testing.assert_array_equal(sub.types, sp.types[keep])
    np.testing.assert_array_equal(sub.handle_left, sp.handle_left[rows])
    np.testing.assert_array_equal(sub.nurbs_weight, sp.nurbs_weight[rows])
    np.testing.assert_array_equal(sub.nurbs_order, sp.nurbs_order[keep])
    s = Settings(mode="bend")
    np.testing.assert_array_equal(splines.clearance_margin(sub, P[rows], sub_off, s),
                                  splines.clearance_margin(sp, P, offs, s)[keep])
    assert splines.Splines.catmull_rom(C).take(keep, offs).cyclic is None


# ----------------------------------------------------------- the largest margin
def _mixed_splines(rng, P, offs):
    """Mostly Catmull-Rom, with Poly, Bezier, NURBS and cyclic curves among them."""
    C = len(offs) - 1
    types = rng.choice([CATMULL_ROM] * 12 + [POLY, BEZIER, NURBS], C).astype(np.int8)
    return splines.Splines(types, rng.random(C) < 0.03, P + rng.normal(size=P.shape) * 0.02,
                           P + rng.normal(size=P.shape) * 0.02, np.zeros(len(P), np.int8),
                           np.zeros(len(P), np.int8), rng.integers(2, 9, C),
                           rng.integers(0, 4, C).astype(np.int8), rng.uniform(0.5, 2, len(P)))


@pytest.mark.parametrize("seed", SEEDS[:4])
@pytest.mark.parametrize("s", MODES, ids=lambda s: f"{s.mode}-{s.max_angle:g}-{s.shrink}")
def test_the_largest_margin_is_the_largest_of_every_curves(seed, s):
    """``largest_margin`` (what every solve widens by) measures only the curves that can
    hold the largest: the same bits as the largest of ``clearance_margin``, on grooms
    large enough to leave curves out, with every curve type, disabled curves, curves
    with a non-finite point and per-curve settings; curves of any sizes, or all of one
    size (2, 3 or 8 points: the bound's other form)."""
    rng = np.random.default_rng(seed)
    k = [(2, 9), (8, 8), (2, 2), (3, 3)][seed % 4]
    P, offs = _groom(rng, n=300, kmin=k[0], kmax=k[1], wiggle=rng.uniform(0.05, 1.0))
    C = len(offs) - 1
    cr = splines.Splines.catmull_rom(C)
    mixed = _mixed_splines(rng, P, offs)
    enabled = rng.random(C) < 0.9
    bad = P.copy()
    bad[offs[rng.integers(0, C, 5)] + 1] = np.nan
    per_curve = s.replace(max_angle=rng.uniform(5.0, 170.0, C)) if s.mode == "bend" else s
    for sp, pts, en, st in ((cr, P, None, s), (mixed, P, None, s), (cr, P, enabled, s),
                            (mixed, bad, enabled, s), (cr, P, None, per_curve)):
        want = splines.clearance_margin(sp, pts, offs, st, en).max()
        assert splines.largest_margin(sp, pts, offs, st, en) == want
    # the cheap bound that decides which curves are measured holds on every segment
    lay = splines._Layout(offs)
    d = lay.segments(P)
    phi, shrink = splines.turn_allowance(s, lay.sizes - 1)
    terms = splines._catmull_rom_terms(lay, d, splines._norm(d), lay.seg, phi, shrink, s)
    exact = splines._hermite_bound(*terms)
    assert np.all(splines._hermite_upper(*terms) >= exact) and (exact.max() > 0) == (k[1] > 2)
    if k[0] == k[1]:
        upper, _ = splines._catmull_rom_upper_uniform(P.reshape(-1, k[0], 3), phi, shrink, s)
        assert np.all(upper >= splines.clearance_margin(cr, P, offs, s))
    # the frame's largest, as the solves are widened (kept: a groom that did not move)
    drawn = splines.DrawnMargin()
    assert drawn.largest(mixed, P, offs, s) == splines.quantized(
        splines.clearance_margin(mixed, P, offs, s)).max()
    assert drawn.largest(mixed, P, offs, s) == drawn(mixed, P, offs, s).max()


def test_the_largest_margin_of_one_bent_curve_among_straight_ones():
    """One curve of ten thousand holds the margin: it is found (the bound of a straight
    curve is its float noise, which counts 0)."""
    n = 10_000
    offs = np.arange(n + 1) * 5
    P = np.zeros((5 * n, 3))
    P[:, 2] = np.tile(np.arange(5) * 0.1, n)
    P[:, 0] = np.repeat(np.arange(n) * 0.01, 5)
    P[5 * 7777 + 2, 1] = 0.05  # the one bent curve
    sp = splines.Splines.catmull_rom(n)
    s = Settings(mode="stiff")
    m = splines.clearance_margin(sp, P, offs, s)
    assert np.count_nonzero(m) == 1 and m[7777] > 0
    assert splines.largest_margin(sp, P, offs, s) == m[7777]
    assert splines.largest_margin(sp, np.where(P == 0.05, 0.0, P), offs, s) == 0.0


#: Two order-6 NURBS of 7 points whose window sums round differently when a BLAS product
#: takes one curve (gemv) or several (gemm).
_NURBS6_X = [[-0.0638830854654409, -0.3296146049811382, -1.8181040543096807],
             [-0.01808425179065621, -0.3156816147323942, -1.7982404086759751],
             [0.07815137658925154, -0.22049187590466068, -1.609622784650028],
             [0.0039822364641147745, -0.23524905538437965, -1.5991427804630842],
             [-0.005848125287705355, -0.28330911643507567, -1.3602132661895014],
             [0.011707610953554784, -0.26661931959686286, -1.1860244031941884],
             [0.03151340710124172, -0.16328222783832153, -1.0715242802179112]]
_NURBS6_Y = [[0.36195245508939805, -0.23345599826833113, 0.776671510953765],
             [0.33086205137182195, -0.2338517343564669, 0.9126417840800899],
             [0.3430134106400944, -0.2400948745457677, 0.9347308573681701],
             [0.3125498863130074, -0.1998214651918213, 1.0311570817984443],
             [0.31528411619353314, -0.1527500824473255, 1.055887428389826],
             [0.3034607138441243, -0.20722050640462963, 1.0200608167254017],
             [0.30582196269100104, -0.18768721543526978, 1.0940487782083315]]


def test_the_largest_margin_of_order_6_nurbs_measured_apart():
    """Two order-6 NURBS of one size and knots mode, 70 Bezier and 230 Catmull-Rom
    curves: the largest measures the two apart (one among the first 64 measured, or
    the other not enabled), and gets the same bits as measuring them together."""
    straight = [np.c_[np.zeros(4), np.full(4, i * 0.01), np.arange(4) * 0.1]
                for i in range(300)]
    curves = [np.array(_NURBS6_Y), np.array(_NURBS6_X)] + straight
    types = np.array([NURBS, NURBS] + [BEZIER] * 70 + [CATMULL_ROM] * 230, np.int8)
    P = np.vstack(curves)
    offs = np.r_[0, np.cumsum([len(q) for q in curves])]
    C = len(curves)
    sp = splines.Splines(types, None, P.copy(), P.copy(), None, None, np.full(C, 6),
                         np.full(C, splines.KNOTS_ENDPOINT_BEZIER), None)
    s = Settings(mode="bend")
    other = np.ones(C, bool)
    other[0] = False
    for en in (None, other):
        want = splines.clearance_margin(sp, P, offs, s, en)
        assert splines.largest_margin(sp, P, offs, s, en) == want.max()
    one = np.arange(C) == 1
    rows, sub = splines.subset(offs, one)
    assert (splines.clearance_margin(sp.take(one, offs), P[rows], sub, s)[0]
            == splines.clearance_margin(sp, P, offs, s)[1])


def test_a_parameter_map_of_another_length_is_named_before_the_margin():
    """A Max Angle map with one value too few, on a groom large enough to filter: the
    settings' own message (the field, its length, the curve count), from the largest
    margin and from the clearance pass."""
    from core.errors import SettingsError
    from core.pipeline import clearance_pass
    rng = np.random.default_rng(2)
    P, offs = _groom(rng, n=400)
    sp = splines.Splines.catmull_rom(400)
    s = Settings(mode="bend", max_angle=np.full(399, 30.0))
    with pytest.raises(SettingsError, match="max_angle has 399 values but there are 400"):
        splines.largest_margin(sp, P, offs, s)
    with pytest.raises(SettingsError, match="max_angle has 399 values but there are 400"):
        clearance_pass(P, offs, [], settings=Settings(mode="stiff"), fallback=s, splines=sp)
