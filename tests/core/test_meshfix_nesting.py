"""How meshfix turns closed parts that lie inside one another, and duplicated faces.

The rule (core/meshfix.py, README "Colliders as artists make them"): a closed part
inside no other faces outward; a closed part wholly inside another keeps its
winding relative to that one (against it: a cavity wall; with it: a solid within
the solid). Faces doubled with opposite windings are the wall between two parts
touching face to face only when every edge they have is shared by two more faces.
Checked against the parity oracle on the mesh as the artist meant it.
"""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes

from core import Collider, Settings, Solver, Status
from core.meshfix import tidy


def _ball(r, center=(0.0, 0.0, 0.0)):
    return scenes.icosphere(center, r, subdivisions=2)


def _join(*parts):
    Vs, Fs, n = [], [], 0
    for V, F in parts:
        Vs.append(V)
        Fs.append(F + n)
        n += len(V)
    return np.concatenate(Vs), np.concatenate(Fs)


def _inside_per_core(V, F, P):
    """Roots inside the collider as the core sees it (its pinch test)."""
    col = Collider(V.astype(np.float32), F)
    return col.contains(P)


PROBES = np.array([[0, 0, 0], [0, 0, 0.7], [0.9, 0, 0], [0, 0, 1.2], [0.3, 0.1, -0.2]], float)


@pytest.mark.parametrize("whole_mesh_flipped", [False, True])
def test_a_hollow_ball_is_a_cavity_even_when_the_whole_mesh_is_flipped(whole_mesh_flipped):
    Vo, Fo = _ball(1.0)
    Vi, Fi = _ball(0.6)
    V, F = _join((Vo, Fo), (Vi, Fi[:, ::-1]))  # Solidify: the inner shell faces the cavity
    if whole_mesh_flipped:  # an import with the other handedness
        F = F[:, ::-1]
    t = tidy(V, F)
    assert t.closed
    assert t.flipped == (len(F) if whole_mesh_flipped else 0)
    # inside = in the wall only (between 0.6 and 1.0)
    want = np.array([False, True, True, False, False])
    np.testing.assert_array_equal(_inside_per_core(V, F, PROBES), want)


def test_a_solid_within_a_solid_wound_alike_stays_solid():
    """An eye inside a head, joined, both wound outward: inside either is inside."""
    Vo, Fo = _ball(1.0)
    Vi, Fi = _ball(0.4)
    V, F = _join((Vo, Fo), (Vi, Fi))
    t = tidy(V, F)
    assert t.closed and t.flipped == 0
    np.testing.assert_array_equal(_inside_per_core(V, F, PROBES),
                                  [True, True, True, False, True])


def test_overlapping_balls_both_face_outward_whatever_their_winding():
    """Two balls that intersect (an asset built from primitives): neither holds the
    other wholly, so each faces outward; inside is the union."""
    Va, Fa = _ball(0.6, (-0.3, 0, 0))
    Vb, Fb = _ball(0.6, (0.3, 0, 0))
    V, F = _join((Va, Fa), (Vb, Fb[:, ::-1]))  # one wound inward
    t = tidy(V, F)
    assert t.closed and t.flipped == len(Fb)
    P = np.array([[-0.7, 0, 0], [0.7, 0, 0], [0, 0, 0], [0, 0.7, 0]])
    union = oracle.points_inside_closed_mesh(P, Va, Fa) | oracle.points_inside_closed_mesh(
        P, Vb, Fb)
    np.testing.assert_array_equal(_inside_per_core(V, F, P), union)


@pytest.mark.parametrize("flip_copy", [False, True])
def test_a_doubled_face_in_one_ball_counts_once(flip_copy):
    """A duplicated face (either winding) in a single closed ball is not a wall
    between parts: one copy goes, the ball stays closed."""
    V, F = _ball(1.0)
    copy = F[:3, ::-1] if flip_copy else F[:3]
    t = tidy(V, np.concatenate([F, copy]))
    assert t.closed and t.shared == 0 and t.duplicates == 3
    assert len(t.faces) == len(F)


def test_the_wall_between_two_crates_goes_and_is_said():
    V1, F1 = scenes.box([0, 0, 0], [1, 1, 1])
    V2, F2 = scenes.box([1, 0, 0], [2, 1, 1])
    V, F = _join((V1, F1), (V2, F2))
    t = tidy(V, F)
    assert t.closed and t.shared == 4  # two triangles from each box
    assert "between touching parts" in t.describe()
    P = np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5], [2.5, 0.5, 0.5]])
    np.testing.assert_array_equal(_inside_per_core(V, F, P), [True, True, False])


@pytest.mark.parametrize("shape", ["torus", "bumpy", "flipped_torus"])
def test_one_closed_part_first_crossing_decides_as_the_full_walk(shape):
    """A collider of one closed part takes the side of the first crossing (one ray
    query per vote): the same answers as walking every crossing (winding number)."""
    import dataclasses

    if shape == "bumpy":
        V, F = scenes.bumpy_sphere((0, 0, 0), 1.0, amplitude=0.3, lobes=3)
    else:
        V, F = scenes.torus((0, 0, 0), 1.0, 0.35)
        if shape == "flipped_torus":
            F = F[:, ::-1]
    P = np.random.default_rng(5).uniform(-1.5, 1.5, (3000, 3))
    fast = Collider(V.astype(np.float32), F)
    assert fast.repairs.parts == 1
    walk = Collider(V.astype(np.float32), F)
    walk.mesh.repairs = dataclasses.replace(walk.repairs, parts=2)  # (forces the walk)
    a, b = fast.contains(P), walk.contains(P)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, oracle.points_inside_closed_mesh(
        P, V, F if shape != "flipped_torus" else F[:, ::-1]))


# ------------------------------------------------------- fur inside a hollow ball
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
    geom.assert_no_intersection(res.points, offs, st, [(V, F)],
                                excluded=geom.EXCLUDED_OR_INVALID)
    keep = ~np.isin(st, geom.EXCLUDED_OR_INVALID)
    # (the cavity wall is at 0.5: the fur stays within 0.5 - offset of the centre)
    far = np.array([np.linalg.norm(res.points[offs[c]:offs[c + 1]], axis=1).max()
                    for c in range(len(offs) - 1)])
    assert (far[keep] <= 0.5 - 0.025).all(), far[keep].max()


# ------------------------------------------------------- closed parts side by side
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
