"""QA probes (hunt): wrong pictures an artist or TD would see, found through the core.

Each probe checks an invariant of the guide (no resolved curve crosses a collider, roots
never move, no NaN, same input -> same output, statuses tell the truth) on a case the
other core tests do not build: hollow (nested) closed colliders, one bad curve in a
ragged groom, teleporting colliders, mode switches mid-shot, the clearance pass against
the full solve.
"""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes

from core import Collider, Settings, Solver, Status
from core.pipeline import clearance_pass

EXCLUDED = (Status.PINCHED, Status.UNRESOLVED, Status.DISABLED, Status.INVALID)


def hollow_ball(r_out=1.0, r_in=0.8, center=(0.0, 0.0, 0.0)):
    """A hollow ball (a helmet, a Solidify'd sphere): an outer shell wound outward and an
    inner shell wound inward (its normals face the cavity), both closed, correct."""
    Vo, Fo = scenes.icosphere(center, r_out, subdivisions=3)
    Vi, Fi = scenes.icosphere(center, r_in, subdivisions=3)
    V = np.concatenate([Vo, Vi])
    F = np.concatenate([Fo, Fi[:, ::-1] + len(Vo)])
    return V, F


def _cavity_fur(rng, n=20, half=0.3, length=0.2, npts=3):
    roots = rng.uniform(-half, half, (n, 3))
    t = np.linspace(0.0, length, npts)
    pts = (roots[:, None, :] + t[None, :, None] * np.array([0.0, 0.0, 1.0])).reshape(-1, 3)
    return pts.astype(np.float32), np.arange(0, n * npts + 1, npts), roots


# ------------------------------------------------------------ colliders
def test_roots_in_the_cavity_of_a_hollow_ball_are_not_pinched():
    """Fur growing inside a correctly modelled hollow ball (a head under a helmet made
    with Solidify) is outside the collider's solid: its roots are not pinched, and
    nothing says faces were 'turned outward' (they already were right)."""
    V, F = hollow_ball()
    rng = np.random.default_rng(0)
    pts, offs, roots = _cavity_fur(rng)
    assert not oracle.points_inside_closed_mesh(roots, V, F).any()  # the oracle agrees
    col = Collider(V.astype(np.float32), F)
    res = Solver(offs, Settings()).step(pts, [col])
    assert not (res.status == Status.PINCHED).any(), res.status
    assert col.repairs.flipped == 0, col.repairs.describe()


def test_fur_in_a_hollow_ball_keeps_the_collision_offset_from_the_inner_wall():
    """Fur inside the cavity whose tips pierce the inner wall: resolved, clear of the
    wall, and at least (about) the Collision Offset away from it."""
    V, F = hollow_ball(r_out=1.0, r_in=0.5)
    rng = np.random.default_rng(1)
    pts, offs, roots = _cavity_fur(rng, n=30, half=0.15, length=0.45, npts=5)
    res = Solver(offs, Settings(mode="bend", collision_offset=0.03)).step(
        pts, [Collider(V, F)])
    st = np.asarray(res.status)
    assert (st == Status.COLLIDING).sum() >= 5, st
    geom.assert_no_intersection(res.points, offs, st, [(V, F)], excluded=EXCLUDED)
    keep = ~np.isin(st, EXCLUDED)
    # (the cavity wall is at 0.5: the fur stays within 0.5 - offset of the centre)
    far = np.array([np.linalg.norm(res.points[offs[c]:offs[c + 1]], axis=1).max()
                    for c in range(len(offs) - 1)])
    assert (far[keep] <= 0.5 - 0.025).all(), far[keep].max()


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_two_separate_closed_balls_both_pinch(mode):
    """Two disjoint balls in one mesh (an asset's parts), one wound inward: each is a
    closed part of its own; roots inside either are pinched, the rest resolved clear."""
    Va, Fa = scenes.uv_sphere([-0.5, 0, 0.1], 0.3, 24, 12)
    Vb, Fb = scenes.uv_sphere([0.5, 0, 0.1], 0.3, 24, 12)
    V = np.concatenate([Va, Vb])
    F = np.concatenate([Fa, Fb[:, ::-1] + len(Va)])
    rng = np.random.default_rng(4)
    pts, offs = scenes.fur_on_plane(rng, n_curves=120, extent=0.9, n_cvs=(3, 7),
                                    length=(0.4, 0.8))
    res = Solver(offs, Settings(mode=mode)).step(pts, [Collider(V, F)])
    roots = pts[offs[:-1]]
    Vok = np.concatenate([Va, Vb])
    Fok = np.concatenate([Fa, Fb + len(Va)])
    inside = oracle.points_inside_closed_mesh(roots, Vok, Fok)
    assert inside.sum() >= 4
    np.testing.assert_array_equal(res.status == Status.PINCHED, inside)
    geom.assert_no_intersection(res.points, offs, res.status, [(Vok, Fok)],
                                excluded=EXCLUDED)



def two_boxes(touch):
    """Two closed boxes in one mesh (two crates joined with Ctrl-J): side by side
    touching along a face, along an edge, or apart."""
    Va, Fa = scenes.box([-0.5, -0.25, 0.0], [0.0, 0.25, 0.5])
    lo, hi = {"face": ([0.0, -0.25, 0.0], [0.5, 0.25, 0.5]),
              "edge": ([0.0, 0.25, 0.0], [0.5, 0.75, 0.5]),
              "apart": ([0.01, -0.25, 0.0], [0.5, 0.25, 0.5])}[touch]
    Vb, Fb = scenes.box(lo, hi)
    return np.concatenate([Va, Vb]), np.concatenate([Fa, Fb + len(Va)])


@pytest.mark.parametrize("touch", [
    "apart",
    "face",
    "edge",
])
def test_two_closed_boxes_in_one_mesh_still_detect_pinches(touch):
    """Each box is closed and wound outward: a root inside either is pinched (the
    parity oracle on the mesh as given), before and after the core's repairs."""
    V, F = two_boxes(touch)
    P = np.random.default_rng(0).uniform(-0.6, 0.8, (1500, 3))
    inside = oracle.points_inside_closed_mesh(P, V, F)
    assert inside.sum() > 100
    col = Collider(V, F)
    assert col.detects_pinch, col.repairs
    np.testing.assert_array_equal(col.contains(P), inside)


@pytest.mark.parametrize("scale", [1.0, 2.0924042])
def test_a_seam_whose_copies_differ_by_one_ulp_is_welded(scale):
    """An unwelded seam whose vertex copies are not bit-identical (an exporter's float32
    rounding, a mirror seam): the copies are ~3e-8 apart, 50x closer than WELD_REL of the
    mesh's size, so the ball is closed and detects pinches."""
    V, F = scenes.uv_sphere([0.1, 0.2, 0.3], 0.5, 32, 16)
    V = (V * scale).astype(np.float32)
    right = V[F].mean(axis=1)[:, 1] > 0.2 * scale
    V2 = np.concatenate([V, np.nextafter(V, np.float32(4))])
    F2 = F.copy()
    F2[right] += len(V)
    gap = float(np.abs(V2[len(V):] - V).max())
    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    assert gap < 0.1 * 1e-6 * diag  # (tolerances.WELD_REL = 1e-6)
    col = Collider(V2, F2)
    assert col.closed and col.repairs.open_edges == 0, col.repairs.describe()

# ------------------------------------------------------ one bad curve, ragged groom
def _sweep(f):
    return scenes.affine(scenes.rotation_matrix([0, 1, 0.3], 0.2 * f),
                         t=[-0.7 + 0.3 * f, 0.05 * f, 0.6 - 0.05 * f])


@pytest.mark.parametrize("bad", ["nan", "duplicated_point", "inf_root"])
@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_one_bad_curve_changes_no_other_curve(mode, bad):
    """A ragged groom with one broken curve (a NaN CV, a duplicated CV, an infinite
    root): every other curve is solved bit for bit as in the groom without the break,
    on every frame of a sweep; the broken one is INVALID, never NaN, and its root stays."""
    rng = np.random.default_rng(7)
    pts, offs = scenes.fur_on_plane(rng, n_curves=60, curly=0.3, extent=0.9, n_cvs=(2, 9),
                                    length=(0.5, 1.0))
    pts = pts.astype(np.float32)
    k = 23
    assert offs[k + 1] - offs[k] >= 3
    broken = pts.copy()
    if bad == "nan":
        broken[offs[k] + 1] = np.nan
    elif bad == "duplicated_point":
        broken[offs[k] + 2] = broken[offs[k] + 1]
    else:
        broken[offs[k]] = np.inf
    V, F = scenes.uv_sphere([0, 0, 0], 0.4, 24, 12)
    col = Collider(V, F)
    a, b = Solver(offs, Settings(mode=mode)), Solver(offs, Settings(mode=mode))
    others = np.ones(len(offs) - 1, bool)
    others[k] = False
    rows = np.repeat(others, np.diff(offs))
    touched = 0
    for f in range(6):
        col.matrix = _sweep(f)
        ra = a.step(pts, [col])
        rb = b.step(broken, [col])
        assert np.isfinite(rb.points).all()
        assert rb.status[k] == Status.INVALID
        assert rb.problems and f"curve {k}" in rb.problems[0], rb.problems
        np.testing.assert_array_equal(rb.status[others], ra.status[others], err_msg=f"{f}")
        np.testing.assert_array_equal(rb.points[rows], ra.points[rows], err_msg=f"{f}")
        touched += int((ra.status != 0).sum())
        if bad != "inf_root":
            assert np.array_equal(rb.points[offs[k]], broken[offs[k]])
    assert touched > 10


# -------------------------------------------------------------- teleports
@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_a_teleporting_collider_leaves_nothing_crossing(mode):
    """A ball that jumps (a cut, a keyed teleport) between far places of the groom, and
    back onto the same spot: no resolved curve crosses it, roots never move, lengths are
    kept, no NaN; and after it leaves, every curve recovers its groomed shape."""
    rng = np.random.default_rng(11)
    pts, offs = scenes.fur_on_plane(rng, n_curves=90, curly=0.2, extent=1.0, n_cvs=(3, 8),
                                    length=(0.5, 0.9))
    V, F = scenes.uv_sphere([0, 0, 0], 0.3, 24, 12)
    col = Collider(V, F)
    solver = Solver(offs, Settings(mode=mode, recovery_rate=1.0))
    places = [(-0.6, -0.5, 0.55), (0.6, 0.5, 0.45), (-0.6, -0.5, 0.55), (0.0, 0.6, 0.3),
              (0.6, -0.6, 0.6), (5.0, 5.0, 5.0), (5.0, 5.0, 5.0), (5.0, 5.0, 5.0)]
    hit = 0
    for t in places:
        col.matrix = scenes.translation(t)
        res = solver.step(pts, [col])
        assert np.isfinite(res.points).all()
        geom.assert_roots_exact(pts, res.points, offs)
        Vw = oracle.transform(V, col.matrix)
        geom.assert_no_intersection(res.points, offs, res.status, [(Vw, F)],
                                    excluded=EXCLUDED)
        if mode != "soft":
            geom.assert_lengths_kept(pts, res.points, offs, rtol=1e-4)
        hit += int((res.status == Status.COLLIDING).sum())
    assert hit > 10
    # gone for two frames at recovery rate 1: back to the groom
    assert (res.status == Status.FREE).all(), res.status
    np.testing.assert_allclose(res.points, pts, atol=1e-6)


# ------------------------------------------------------------ mode switch
@pytest.mark.parametrize("modes", [("stiff", "soft"), ("soft", "bend"), ("bend", "stiff")])
def test_switching_mode_mid_shot_keeps_the_invariants(modes):
    """Settings switched to another mode mid-shot (the solver resets): every frame after
    keeps no resolved crossing, roots exact, no NaN; the switched solver equals a fresh
    solver in the new mode started at the switch."""
    rng = np.random.default_rng(5)
    pts, offs = scenes.fur_on_plane(rng, n_curves=70, curly=0.2, extent=0.9, n_cvs=(3, 8))
    V, F = scenes.uv_sphere([0, 0, 0], 0.4, 24, 12)
    col = Collider(V, F)
    solver = Solver(offs, Settings(mode=modes[0]))
    fresh = Solver(offs, Settings(mode=modes[1]))
    for f in range(6):
        col.matrix = _sweep(f)
        if f == 3:
            solver.settings = Settings(mode=modes[1])
        res = solver.step(pts, [col])
        geom.assert_roots_exact(pts, res.points, offs)
        assert np.isfinite(res.points).all()
        geom.assert_no_intersection(res.points, offs, res.status,
                                    [(oracle.transform(V, col.matrix), F)], excluded=EXCLUDED)
        if f >= 3:
            ref = fresh.step(pts, [col])
            np.testing.assert_array_equal(res.points, ref.points)
            np.testing.assert_array_equal(res.status, ref.status)
    snap = solver.state  # a snapshot of the new mode restores into a solver of that mode
    other = Solver(offs, Settings(mode=modes[1]))
    other.state = snap
    with pytest.raises(ValueError, match="another mode"):
        Solver(offs, Settings(mode=modes[0])).state = snap


# ------------------------------------------------------------ clearance pass
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


# ----------------------------------------------------------------- render groom
def _bend(pts, offs, angle):
    """Each curve bent about x at its root by ``angle`` (radians) times its arc fraction."""
    out = pts.copy()
    for c in range(len(offs) - 1):
        s, e = offs[c], offs[c + 1]
        n = e - s - 1
        p = pts[s]
        for j in range(n):
            R = scenes.rotation_matrix([1, 0, 0], angle * (j + 1) / n)
            out[s + j + 1] = p + (pts[s + j + 1] - pts[s + j]) @ R.T
            p = out[s + j + 1]
    return out


@pytest.mark.parametrize("move", ["still", "rigid", "bent"])
def test_render_curves_lying_on_ragged_guides_follow_them(move):
    """README: a render curve lying on a guide follows it exactly (and a still guide set
    leaves the groom unchanged, a rigid motion moves it rigidly), with guides and render
    curves of mixed CV counts."""
    from core.pipeline import bind_groom, deform_groom

    rng = np.random.default_rng(3)
    g_pts, g_off = scenes.fur_on_plane(rng, n_curves=12, curly=0.0, lean=0.2, extent=1.0,
                                       n_cvs=(2, 9))
    roots = g_pts[g_off[:-1]]
    w = bind_groom(roots, roots, k=1)
    if move == "still":
        now = g_pts.copy()
    elif move == "rigid":
        R = scenes.rotation_matrix([0.2, 1, 0.4], 0.7)
        now = g_pts @ R.T + [0.3, -0.2, 0.1]
    else:
        now = _bend(g_pts, g_off, 0.6)
    out = deform_groom(g_pts, g_off, g_pts, now, g_off, w)
    assert np.isfinite(out).all()
    np.testing.assert_allclose(out, now, atol=1e-9)
