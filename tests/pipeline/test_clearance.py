"""The clearance pass hands the solver only the curves that may change (issue 11).

Every other render curve must come back exactly as the solver, run with a fresh
state on every curve, returns it: unchanged and FREE, PINCHED (root inside a
closed collider) or INVALID. The pass's culling (bounding balls near the
surface, a per-segment distance field of colliders seen before, the inside
test of the roots) may only change the time, never a point or a status, nor
make a frame depend on the frames before it.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pipe_oracle as po
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core import Collider, Settings, Solver, Status, splines
from core.pipeline import ClearanceMargins, clearance_pass
from core.pipeline import groom as groom_mod

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
import oracle  # noqa: E402  (the core tests' oracle: imports nothing from core)
import scenes  # noqa: E402  (the core tests' scene builders)

PROP = settings(max_examples=examples(15), deadline=None)


def solve_all(pts, off, cols, s, fallback=None):
    """The reference: the solver on every curve (fresh state), then the fallback
    on the unresolved ones; ``n_fixed`` as the pass counts it."""
    res = Solver(off, s).step(pts, cols)
    out = np.asarray(res.points, np.float64).copy()
    status = res.status.copy()
    again = np.flatnonzero(status == Status.UNRESOLVED)
    if fallback is not None and len(again):
        rb = Solver(off, fallback).step(pts, cols)
        for c in again:
            if rb.status[c] != Status.UNRESOLVED:
                out[off[c]:off[c + 1]] = rb.points[off[c]:off[c + 1]]
                status[c] = rb.status[c]
    with np.errstate(invalid="ignore"):
        moved = np.logical_or.reduceat(np.any(out != pts, axis=1), off[:-1])
    return out, status, int((moved & (status != Status.INVALID)).sum())


def assert_same(got, want):
    np.testing.assert_array_equal(got[1], want[1])
    np.testing.assert_array_equal(got[0], want[0])
    assert got[2] == want[2]


def scene(rng, n_curves=300, ragged=False, inside=True):
    """Fur on a ground grid, a closed sphere sunk into the ground (roots inside it:
    pinched, some of them far from its surface), curves near it and through it."""
    V, F = po.grid(3.0, 6)
    if ragged:
        curves = []
        for _ in range(n_curves):
            p, _ = po.fur_on_mesh(rng, V, F, 1, int(rng.integers(2, 9)), 0.5, noise=0.3)
            curves.append(p)
        pts, off = po.pack(curves)
    else:
        pts, off = po.fur_on_mesh(rng, V, F, n_curves, 8, 0.5, noise=0.3)
    if inside:  # short curves deep inside the sphere (pinched, far from its surface)
        k = n_curves // 10
        r = np.c_[rng.uniform(-0.15, 0.15, (k, 2)), np.zeros(k)]
        for i, root in enumerate(r):
            a, b = off[i], off[i + 1]
            pts[a:b] = root + np.linspace(0, 0.1, b - a)[:, None] * [0, 0, 1]
    return pts, off


def sphere(rng, radius):
    Vs, Fs = po.icosphere((0, 0, 0), radius, 2)
    return Vs, Fs


def matrix(rng, scale=1.0, aniso=False):
    M = np.eye(4)
    S = np.diag([scale * rng.uniform(0.7, 1.4) if aniso else scale for _ in range(3)])
    M[:3, :3] = po.rotation(rng.normal(size=3), rng.uniform(0, np.pi)) @ S
    M[:3, 3] = [*rng.uniform(-0.3, 0.3, 2), rng.uniform(-0.1, 0.2)]
    return M


@PROP
@given(seed=st.integers(0, 10_000), radius=st.floats(0.3, 0.9), offset=st.floats(0.0, 0.05),
       mode=st.sampled_from(["stiff", "bend"]), ragged=st.booleans(), aniso=st.booleans(),
       two=st.booleans())
def test_every_frame_equals_solving_every_curve(seed, radius, offset, mode, ragged, aniso, two):
    """Frame after frame (the collider turning: the distance field is used from the
    second frame; then deformed: a new shape), the pass returns exactly what the
    solver returns on every curve, with a fallback, a NaN curve and a zero-length
    segment among them."""
    rng = np.random.default_rng(seed)
    pts, off = scene(rng, 200, ragged)
    pts[off[-2]] = np.nan
    c = len(off) - 3
    pts[off[c] + 1] = pts[off[c]]  # a zero-length segment
    Vs, Fs = sphere(rng, radius)
    cols = [Collider(Vs, Fs, matrix=matrix(rng, aniso=aniso), name="ball")]
    if two:
        Vg, Fg = po.grid(0.8, 3, z=0.0)
        cols.append(Collider(Vg, Fg, matrix=matrix(rng), double_sided=bool(rng.integers(2)),
                             offset=0.02, name="sheet"))
    s = Settings(mode=mode, collision_offset=offset)
    fb = Settings(mode="bend", collision_offset=offset)
    for frame in range(4):
        if frame == 3:  # a new shape: the first pass that sees it
            cols[0].vertices = Vs * rng.uniform(0.9, 1.1, 3)
        else:
            cols[0].matrix = matrix(rng, aniso=aniso)
        want = solve_all(pts, off, cols, s, fb)
        assert_same(clearance_pass(pts, off, cols, settings=s, fallback=fb), want)
        assert want[1][len(off) - 2] == Status.INVALID


@pytest.mark.parametrize("seed", [1, 2])
def test_parameter_maps_equal_solving_every_curve(seed):
    """Per-render-curve Collision Offset, Clearance Margin and Max Angle maps (and a
    fallback with its own): the pass still returns exactly what the solver returns
    on every curve (its culling reaches the largest distance asked; the solvers of
    subsets take their curves' values). A ball resting on the fur, then a sunk one
    (pinches)."""
    rng = np.random.default_rng(seed)
    pts, off = scene(rng, 200)
    R = len(off) - 1
    Vs, Fs = sphere(rng, 0.6)
    cols = [Collider(Vs, Fs, name="ball")]
    s = Settings(mode="stiff", collision_offset=rng.choice([0.0, 0.02, 0.06], R),
                 clearance_margin=rng.uniform(0.0, 0.03, R), max_angle=rng.uniform(20, 180, R))
    fb = Settings(mode="bend", collision_offset=s.collision_offset, clearance_margin=0.01)
    for lift in (0.7, 0.0):
        M = matrix(rng)
        M[2, 3] += lift
        cols[0].matrix = M
        want = solve_all(pts, off, cols, s, fb)
        assert (want[1] == (Status.COLLIDING if lift else Status.PINCHED)).sum() >= 10
        assert_same(clearance_pass(pts, off, cols, settings=s, fallback=fb), want)


def test_the_fast_path_runs_and_agrees_on_a_dense_groom(monkeypatch):
    """A groom most of whose curves come near the collider without touching it (as a
    hat over a scalp): from the second pass on the distance field leaves out
    most of them, the roots inside are still PINCHED, and the result is the
    solver's on every curve, with 0 crossings left."""
    rng = np.random.default_rng(5)
    pts, off = scene(rng, 600)
    Vs, Fs = sphere(rng, 0.55)
    col = Collider(Vs, Fs, matrix=matrix(rng), name="ball")
    calls = []
    real = groom_mod._ClearanceField.clear

    def spy(self, *a):
        r = real(self, *a)
        calls.append((len(r), int(r.sum())))
        return r

    monkeypatch.setattr(groom_mod._ClearanceField, "clear", spy)
    want = solve_all(pts, off, [col], Settings(mode="stiff"))
    for _ in range(2):
        got = clearance_pass(pts, off, [col])
        assert_same(got, want)
    assert len(calls) == 1 and calls[0][1] > 0, "the field must clear some curves"
    assert (want[1] == Status.PINCHED).sum() >= 50
    assert (want[1] == Status.COLLIDING).sum() > 0
    # no segment of a curve the pass left FREE or COLLIDING crosses the ball
    V = po_world(col)
    A, B, cid = po.segments(got[0], off)
    hit = po.segments_cross_mesh(A, B, V, Fs, eps=-1e-6)
    ok = np.isin(got[1], [Status.FREE, Status.COLLIDING, Status.RECOVERING])
    assert not ok[cid[hit]].any()


def po_world(col):
    V = np.asarray(col.vertices, np.float64)
    M = col.matrix
    return V @ M[:3, :3].T + M[:3, 3]


@pytest.mark.parametrize("ragged", [False, True])
def test_curve_order_and_batching_do_not_matter(ragged):
    """A curve's result does not depend on the other curves passed with it: the
    curves in reverse order, or in two batches, give the same curves back."""
    rng = np.random.default_rng(21)
    pts, off = scene(rng, 300, ragged)
    Vs, Fs = sphere(rng, 0.6)
    col = Collider(Vs, Fs, matrix=matrix(rng))
    clearance_pass(pts, off, [col])  # (the collider's shape is seen: the field is used)
    out, st0, _ = clearance_pass(pts, off, [col])
    curves = [pts[off[i]:off[i + 1]] for i in range(len(off) - 1)]
    rp, roff = po.pack(curves[::-1])
    rout, rst, _ = clearance_pass(rp, roff, [col])
    back = po.pack([rout[roff[i]:roff[i + 1]] for i in range(len(roff) - 1)][::-1])[0]
    np.testing.assert_array_equal(back, out)
    np.testing.assert_array_equal(rst[::-1], st0)
    h = len(curves) // 2
    parts = [po.pack(curves[:h]), po.pack(curves[h:])]
    res = [clearance_pass(p, o, [col]) for p, o in parts]
    np.testing.assert_array_equal(np.concatenate([r[0] for r in res]), out)
    np.testing.assert_array_equal(np.concatenate([r[1] for r in res]), st0)


def test_a_frame_does_not_depend_on_the_frames_before():
    """Scrubbing (a fresh collider each frame, nothing seen before) and playing (one
    collider moving, its distance field reused) give the same frames."""
    rng = np.random.default_rng(8)
    pts, off = scene(rng, 400)
    Vs, Fs = sphere(rng, 0.5)
    mats = [matrix(rng) for _ in range(5)]
    play = Collider(Vs, Fs)
    for M in mats:
        play.matrix = M
        got = clearance_pass(pts, off, [play])
        want = clearance_pass(pts, off, [Collider(Vs, Fs, matrix=M)])
        assert_same(got, want)


@PROP
@given(seed=st.integers(0, 10_000), aniso=st.booleans(), scale=st.floats(0.3, 3.0))
def test_the_field_clears_only_segments_that_are_far(seed, aniso, scale):
    """Every segment the distance field calls clear is farther than asked from the
    collider's world mesh (exact segment-triangle distances)."""
    rng = np.random.default_rng(seed)
    Vs, Fs = po.icosphere((0.1, -0.2, 0.3), 0.5, 1)
    col = Collider(Vs, Fs, matrix=matrix(rng, scale, aniso))
    V = po_world(col)
    k = 400
    c = V.mean(0) + rng.normal(0, 0.6 * scale, (k, 3))
    d = rng.normal(0, 0.05 * scale, (k, 3))
    pts = np.stack([c - d, c + d], 1).reshape(-1, 3)
    off = np.arange(k + 1) * 2
    need = 0.02 * scale
    ok = groom_mod._ClearanceField(col).clear(pts, off, np.arange(k), col.matrix, need,
                                             float(np.abs(pts).max()))
    assert ok.any() and not ok.all()
    A, B = pts[0::2][ok], pts[1::2][ok]
    T = V[Fs]
    m = len(Fs)
    dist = po.segment_triangle_distance(np.repeat(A, m, 0), np.repeat(B, m, 0),
                                        *(np.tile(T[:, i], (len(A), 1)) for i in range(3)))
    dist = dist.reshape(len(A), m).min(1)
    assert (dist > need).all()


@pytest.mark.parametrize("offset", [0.0, 0.04])
def test_clearance_pass_equals_solving_every_curve(offset):
    """clearance_pass solves only the curves whose box meets a collider's (offset)
    bounds: the result must equal one solve of the whole ragged groom, with a global
    Collision Offset and a collider's own offset, and a NaN curve among them."""
    rng = np.random.default_rng(9)
    pts, offs = scenes.fur_on_plane(rng, n_curves=150, curly=0.2, extent=2.0, n_cvs=(2, 9),
                                    length=(0.4, 0.9))
    pts[offs[40] + 1] = np.nan
    Va, Fa = scenes.uv_sphere([0, 0, 0], 0.35, 24, 12)
    Vb, Fb = scenes.box([-0.2, -0.2, -0.2], [0.2, 0.2, 0.2])
    cols = [Collider(Va, Fa, matrix=scenes.translation([-0.9, 0.3, 0.5])),
            Collider(Vb, Fb, matrix=scenes.translation([1.0, -0.8, 0.35]), offset=0.06)]
    settings = Settings(mode="stiff", collision_offset=offset)
    fallback = Settings(mode="bend", collision_offset=offset)
    out, st, n_fixed = clearance_pass(pts, offs, cols, settings=settings, fallback=fallback)
    ref = Solver(offs, settings).step(pts, cols)
    ref_pts, ref_st = np.asarray(ref.points, np.float64).copy(), ref.status.copy()
    again = np.flatnonzero(ref_st == Status.UNRESOLVED)
    if len(again):
        rb = Solver(offs, fallback).step(pts, cols)
        for c in again:
            if rb.status[c] != Status.UNRESOLVED:
                ref_pts[offs[c]:offs[c + 1]] = rb.points[offs[c]:offs[c + 1]]
                ref_st[c] = rb.status[c]
    np.testing.assert_array_equal(st, ref_st)
    np.testing.assert_array_equal(out, ref_pts)
    assert st[40] == Status.INVALID and np.isfinite(out).all()
    with np.errstate(invalid="ignore"):
        moved = np.logical_or.reduceat(np.any(out != pts, axis=1), offs[:-1])
    assert n_fixed == int((moved & (st != Status.INVALID)).sum()) > 0
    assert 0 < (st == Status.COLLIDING).sum() < 150


# ------------------------------------------------------------ the drawn curve
def _catmull_rom(Q, n=16):
    """Samples of Blender's non-cyclic Catmull-Rom through ``Q`` (end points repeated),
    ``n`` per segment: the curve Blender draws for hair of that type."""
    if len(Q) < 2:
        return Q.copy()
    ext = np.vstack([Q[:1], Q, Q[-1:]])
    t = np.linspace(0.0, 1.0, n)[:, None]
    out = []
    for i in range(len(Q) - 1):
        p0, p1, p2, p3 = ext[i:i + 4]
        out.append(0.5 * (2 * p1 + (p2 - p0) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t**2
                          + (-p0 + 3 * p1 - 3 * p2 + p3) * t**3))
    return np.vstack(out)


def _curly_fur_under_a_ball(seed):
    """Curly fur (4 to 9 points a curve) under a ball low enough to press into most
    of it: (points, offsets, colliders, world vertices, faces of the ball)."""
    rng = np.random.default_rng(seed)
    pts, off = scenes.fur_on_plane(rng, n_curves=250, curly=0.25, extent=0.6, n_cvs=(4, 9),
                                   length=(0.5, 0.9))
    V, F = scenes.uv_sphere([0, 0, 0], 0.3, 24, 12)
    M = scenes.translation([0.0, 0.0, 0.45])
    return pts, off, [Collider(V, F, matrix=M)], oracle.transform(V, M), F


def _drawn_inside(out, off, status, V, F):
    """(points, curves) of the resolved curves' drawn Catmull-Rom samples inside the
    closed mesh ``V``, ``F``."""
    ok = np.flatnonzero(np.isin(status, (Status.FREE, Status.COLLIDING)))
    drawn = [_catmull_rom(out[off[c]:off[c + 1]]) for c in ok]
    which = np.repeat(ok, [len(d) for d in drawn])
    D = np.vstack(drawn)
    inside = np.zeros(len(D), bool)
    # (only samples in the mesh's box can be inside it)
    box = ((D >= V.min(0)) & (D <= V.max(0))).all(1)
    inside[box] = oracle.points_inside_closed_mesh(D[box], V, F)
    return int(inside.sum()), len(np.unique(which[inside]))


@pytest.mark.parametrize("seed", [0, 1])
def test_the_drawn_catmull_rom_curve_clears_the_collider(seed):
    """Solved as polylines, Catmull-Rom curves dip into the ball between their cleared
    points (70 to 120 drawn samples in 13 to 21 curves of 250); with their splines
    the pass widens each solve's clearance by the drawn margin: no drawn sample
    inside, roots fixed, segment lengths kept, the same bits with the margins kept
    from the pass before."""
    pts, off, cols, V, F = _curly_fur_under_a_ball(seed)
    s, fb = Settings(mode="stiff"), Settings(mode="bend")
    out, st, _ = clearance_pass(pts, off, cols, settings=s, fallback=fb)
    assert _drawn_inside(out, off, st, V, F)[1] >= 5  # the polygons only: the wrong picture
    sp = splines.Splines.catmull_rom(len(off) - 1)
    margins = ClearanceMargins()
    out, st, n_fixed = clearance_pass(pts, off, cols, settings=s, fallback=fb, splines=sp,
                                      margins=margins)
    assert n_fixed > 50 and (st == Status.UNRESOLVED).sum() == 0
    assert _drawn_inside(out, off, st, V, F) == (0, 0)
    np.testing.assert_array_equal(out[off[:-1]], pts[off[:-1]])
    inner = np.ones(len(pts) - 1, bool)
    inner[off[1:-1] - 1] = False  # (a curve's last point to the next curve's root)
    np.testing.assert_allclose(np.linalg.norm(np.diff(out, axis=0), axis=1)[inner],
                               np.linalg.norm(np.diff(pts, axis=0), axis=1)[inner],
                               rtol=1e-6, atol=1e-9)
    again = clearance_pass(pts, off, cols, settings=s, fallback=fb, splines=sp,
                           margins=margins)
    assert_same(again, (out, st, n_fixed))


def test_the_fallback_widens_its_solve_by_the_drawn_margin_when_it_runs():
    """Stiff within 2 degrees frees few curves: the Bend fallback solves the rest, its
    clearance widened by its own drawn margin (measured only on a frame where it runs):
    no drawn sample of a resolved curve inside; where the fallback does not run, the
    pass is the same with or without a fallback."""
    pts, off, cols, V, F = _curly_fur_under_a_ball(0)
    sp = splines.Splines.catmull_rom(len(off) - 1)
    s, fb = Settings(mode="stiff", max_angle=2.0), Settings(mode="bend")
    alone = clearance_pass(pts, off, cols, settings=s, splines=sp)
    assert (alone[1] == Status.UNRESOLVED).sum() > 20
    margins = ClearanceMargins()
    out, st, _ = clearance_pass(pts, off, cols, settings=s, fallback=fb, splines=sp,
                                margins=margins)
    assert (st == Status.UNRESOLVED).sum() < (alone[1] == Status.UNRESOLVED).sum() // 2
    assert _drawn_inside(out, off, st, V, F) == (0, 0)
    assert margins.fallback.largest(sp, pts, off, fb) > 0
    free = Settings(mode="stiff")
    assert_same(clearance_pass(pts, off, cols, settings=free, fallback=fb, splines=sp),
                clearance_pass(pts, off, cols, settings=free, splines=sp))


def test_poly_curves_are_the_pass_without_splines_bit_for_bit():
    """Poly curves are drawn as their polygons: the pass with their splines is the pass
    without, bit for bit (and a pass on curves set aside keeps its own splines)."""
    pts, off, cols, _V, _F = _curly_fur_under_a_ball(2)
    s, fb = Settings(mode="stiff"), Settings(mode="bend")
    want = clearance_pass(pts, off, cols, settings=s, fallback=fb)
    poly = splines.Splines(np.full(len(off) - 1, splines.POLY, np.int8))
    assert_same(clearance_pass(pts, off, cols, settings=s, fallback=fb, splines=poly), want)
    with pytest.raises(groom_mod.InputError, match="splines describe 3 curves"):
        clearance_pass(pts, off, cols, splines=splines.Splines.catmull_rom(3))
