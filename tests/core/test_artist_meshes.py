"""Colliders as artists and importers make them (issue 15): flipped or mixed
windings, duplicated faces, unwelded seams, every vertex split (flat-shaded
exports), and combinations. A closed mesh stays closed for FurCollide (pinch
detection works), a Collision Offset shell stays outside the real surface, and
a really open mesh says so."""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes

from core import Collider, Settings, Solver, Status

EXCLUDED = (Status.PINCHED, Status.UNRESOLVED, Status.DISABLED)


def flip_all(V, F, rng):
    return V, F[:, ::-1]


def flip_some(V, F, rng):
    F = F.copy()
    w = rng.random(len(F)) < 0.3
    F[w] = F[w][:, ::-1]
    return V, F


def duplicate_some(V, F, rng):
    pick = rng.choice(len(F), size=max(3, len(F) // 20), replace=False)
    dup = F[pick]
    dup[::2] = dup[::2][:, ::-1]  # some duplicates wound the other way
    return V, np.concatenate([F, dup])


def split_seam(V, F, rng):
    """Vertices on one side (x > 0) get copies used by half their faces (a UV seam
    an import did not merge)."""
    V2 = np.concatenate([V, V])
    F2 = F.copy()
    right = (V[F].mean(axis=1)[:, 1] > 0)
    F2[right] = F2[right] + len(V)
    return V2, F2


def split_all(V, F, rng):
    """Every face its own three vertices (a flat-shaded export)."""
    return V[F].reshape(-1, 3), np.arange(3 * len(F)).reshape(-1, 3)


def everything(V, F, rng):
    V, F = split_all(V, F, rng)
    V, F = flip_some(V, F, rng)
    V, F = duplicate_some(V, F, rng)
    return flip_all(V, F, rng)


MAKERS = [flip_all, flip_some, duplicate_some, split_seam, split_all, everything]
SHAPES = {
    "sphere": lambda: scenes.uv_sphere([0, 0, 0], 0.5, 24, 12),
    "box": lambda: scenes.box([-0.45, -0.45, -0.45], [0.45, 0.45, 0.45]),
    "torus": lambda: scenes.torus([0, 0, 0], 0.4, 0.18, 32, 12),
}


@pytest.mark.parametrize("make", MAKERS, ids=lambda f: f.__name__)
@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_closed_meshes_stay_closed_and_outward(shape, make):
    rng = np.random.default_rng(1)
    V0, F0 = SHAPES[shape]()
    V, F = make(np.asarray(V0, float), np.asarray(F0), rng)
    col = Collider(V, F)
    assert col.closed, col.repairs
    assert col.detects_pinch
    # the repaired winding is outward: every point inside by the oracle is inside
    P = rng.uniform(-0.7, 0.7, size=(3000, 3))
    np.testing.assert_array_equal(col.contains(P), oracle.points_inside_closed_mesh(P, V0, F0))
    if make is flip_all:
        assert col.repairs.flipped == len(F0)


@pytest.mark.parametrize("make", MAKERS, ids=lambda f: f.__name__)
def test_roots_inside_are_pinched_whatever_the_mesh(make):
    """A ball sunk into fur: the roots inside are pinched, by any closed mesh."""
    rng = np.random.default_rng(2)
    pts, offs = scenes.fur_on_plane(rng, n_curves=80, extent=0.6, curly=0.1, n_cvs=(4, 8))
    V0, F0 = scenes.uv_sphere([0, 0, 0.15], 0.35, 24, 12)
    V, F = make(np.asarray(V0, float), np.asarray(F0), rng)
    res = Solver(offs, Settings()).step(pts, [Collider(V, F)])
    roots = pts[offs[:-1]]
    inside = oracle.points_inside_closed_mesh(roots, V0, F0)
    assert inside.sum() >= 5
    np.testing.assert_array_equal(res.status == Status.PINCHED, inside)


@pytest.mark.parametrize("make", MAKERS, ids=lambda f: f.__name__)
@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_collision_offset_shell_stays_outside(make, mode):
    """The issue's case: a ball wound inward lowered onto fur with a Collision
    Offset of 0.05. No resolved curve crosses the real surface, and none comes
    closer than (about) the offset."""
    rng = np.random.default_rng(3)
    pts, offs = scenes.fur_on_plane(rng, n_curves=60, extent=0.6, curly=0.1, n_cvs=(4, 8),
                                    length=(0.5, 0.9))
    V0, F0 = scenes.uv_sphere([0, 0, 0], 0.3, 32, 16)
    M = scenes.affine(t=[0.05, 0.0, 0.62])
    V, F = make(np.asarray(V0, float), np.asarray(F0), rng)
    res = Solver(offs, Settings(mode=mode, collision_offset=0.05)).step(
        pts, [Collider(V, F, matrix=M)])
    st = np.asarray(res.status)
    assert (st == Status.COLLIDING).sum() >= 5
    Vw = oracle.transform(V0, M)
    geom.assert_no_intersection(res.points, offs, st, [(Vw, F0)])
    keep = ~np.isin(st, EXCLUDED)
    d = oracle.curve_distance_to_sphere_center(res.points, offs, [0.05, 0.0, 0.62])
    assert (d[keep] >= 0.3 + 0.045).all(), d[keep].min()


def test_an_open_mesh_says_so():
    V, F = scenes.uv_sphere([0, 0, 0], 0.5, 24, 12)
    col = Collider(V, F[:-4])
    assert not col.closed and not col.detects_pinch
    assert col.repairs.open_edges > 0


def test_repairs_are_reported():
    rng = np.random.default_rng(4)
    V, F = scenes.box()
    Vs, Fs = everything(np.asarray(V, float), np.asarray(F), rng)
    r = Collider(Vs, Fs).repairs
    assert r.welded > 0 and r.duplicates > 0 and r.flipped > 0
    text = r.describe()
    assert "welded" in text and "duplicated" in text and "outward" in text
    assert Collider(V, F).repairs.describe() == ""


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
                                excluded=geom.EXCLUDED_OR_INVALID)


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
