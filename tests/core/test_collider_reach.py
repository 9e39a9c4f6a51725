"""A deforming collider without an inside test (an open sheet, a double-sided mesh)
builds, each frame, only the runs of its triangles near what the curves can reach
(``Collider.set_reach``, ``tol.REACH_*``): a shirt or a body much larger than the fur
on it pays for the part near the fur.

Against the reference, the same collider built whole every frame (no ``deforming``
hint): the same bits; the same bits whatever frames came before; a segment outside
the reach still gets the whole mesh's answer; no curve through the true mesh. A
collider with an inside test (closed, single-sided) never builds a part."""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes

from core import Collider, Settings, Solver
from core import tolerances as tol
from core.rays import make_backend, make_parts_backend, triangle_rows


def _sheet(n=100, size=20.0):
    """A 20 x 20 open sheet (20,000 triangles), far larger than the fur's patch."""
    V, F = scenes.grid(size=size, n=n, z=0.3)
    return V.astype(np.float32), F


def _wave(V, f):
    """The sheet at frame ``f``: waves running over it (a deformation every frame)."""
    W = V.astype(np.float64)
    W[:, 2] += 0.05 * np.sin(1.3 * W[:, 0] + 0.7 * f) + 0.04 * np.cos(0.9 * W[:, 1] - 0.4 * f)
    return W.astype(np.float32)


def _fur():
    rng = np.random.default_rng(3)
    return scenes.fur_on_plane(rng, n_curves=200, n_cvs=(3, 8), length=(0.4, 0.7),
                               extent=0.6, curly=0.2)


def _play(hint, frames=range(5), mode="bend", double=False, offset=0.0, col=None,
          solver=None):
    """Solve the fur under the waving sheet; per frame (points, status, vertices)."""
    V, F = _sheet()
    pts, offs = _fur()
    if col is None:
        col = Collider(_wave(V, frames[0]), F, double_sided=double, deforming=hint)
    if solver is None:
        solver = Solver(offs, Settings(mode=mode, collision_offset=offset))
    out = []
    for f in frames:
        Vw = _wave(V, f)
        col.vertices = Vw
        res = solver.step(pts, [col])
        out.append((np.asarray(res.points).copy(), np.asarray(res.status).copy(), Vw))
    return out, col, solver, pts, offs, F


@pytest.mark.parametrize("mode, double, offset", [
    ("bend", False, 0.0), ("stiff", True, 0.03), ("soft", False, 0.0)])
def test_a_part_gives_the_whole_builds_bits(mode, double, offset):
    """Every frame: the bits of the collider built whole, no curve through the true
    sheet, roots where they were; each build a part of a fraction of the shell."""
    part, col, _, pts, offs, F = _play(True, mode=mode, double=double, offset=offset)
    whole, ref, _, _, _, _ = _play(None, mode=mode, double=double, offset=offset)
    touched = 0
    for f, ((p, st, Vw), (q, sq, _)) in enumerate(zip(part, whole, strict=True)):
        assert p.tobytes() == q.tobytes() and st.tobytes() == sq.tobytes(), f
        keep = ~np.isin(st, geom.EXCLUDED)  # (the culled oracle: a big sheet)
        assert len(oracle.curves_crossing(p, offs, [(Vw, F)], select=keep)) == 0, f
        geom.assert_roots_exact(pts, p, offs)
        touched += np.count_nonzero(st != 0)
    assert touched > 0  # the sheet did reach the fur
    _, _, whole_faces = ref.shells.built[-1]
    assert whole_faces.cover is None and len(whole_faces.real) >= 2 * len(F)  # (both sides)
    _, _, faces = col.shells.built[-1]
    assert faces.cover is not None and len(faces.real) < 0.4 * len(whole_faces.real)
    assert col.build_count == len(part)  # (one part a frame, never the whole)


def test_the_part_built_depends_on_the_frame_never_on_the_frames_before():
    """Frame 6 solved after frames 0-5, or from their state on a collider that saw
    no other frame (a scrub, a resumed bake): the same bits."""
    played, _, solver, _, _, _ = _play(True, frames=range(6))
    state = solver.state
    _, _, offs = None, None, _fur()[1]
    fresh = Solver(offs, Settings(mode="bend"))
    fresh.state = state
    ref, _, _, _, _, _ = _play(True, frames=range(6, 7), solver=fresh)
    again, _, _, _, _, _ = _play(True, frames=range(6, 7), solver=solver)
    assert ref[0][0].tobytes() == again[0][0].tobytes()
    assert ref[0][1].tobytes() == again[0][1].tobytes()


def test_a_collider_given_its_rest_shape_cuts_its_runs_in_space():
    """Faces listed in any order (here shuffled): given its rest shape, the runs are
    cut along a walk in space over it, so the part near the fur stays small; the bits
    are still the whole build's, and the same whatever frame the collider was made
    at (the runs come from the rest shape, never from a shape seen)."""
    V, F = _sheet()
    F = F[np.random.default_rng(9).permutation(len(F))]
    pts, offs = _fur()

    def play(hint, made_at, frames=range(3, 5)):
        col = Collider(_wave(V, made_at), F, deforming=hint, rest=V)
        solver = Solver(offs, Settings(mode="bend"))
        got = []
        for f in frames:
            col.vertices = _wave(V, f)
            res = solver.step(pts, [col])
            got.append(np.asarray(res.points).tobytes() + np.asarray(res.status).tobytes())
        return got, col

    part, col = play(True, 0)
    again, _ = play(True, 4)
    whole, ref = play(None, 0)
    assert part == again == whole
    _, _, faces = col.shells.built[-1]
    _, _, all_faces = ref.shells.built[-1]
    assert faces.cover is not None and len(faces.real) < 0.4 * len(all_faces.real)


def _pair(V, F, frames, shape, settings, double=False, rest=None):
    """(bits of a reachable-part collider, of the whole build) over ``frames``
    (``shape(f)``: the vertices at frame ``f``)."""
    pts, offs = _fur()
    got = []
    for hint in (True, None):
        col = Collider(shape(frames[0]), F, double_sided=double, deforming=hint, rest=rest)
        solver = Solver(offs, settings)
        bits = []
        for f in frames:
            col.vertices = shape(f)
            res = solver.step(pts, [col])
            bits.append(np.asarray(res.points).tobytes() + np.asarray(res.status).tobytes())
        got.append(bits)
    return got


def test_a_shape_of_other_bounds_gets_its_own_reach_box():
    """The sheet growing and shrinking from frame to frame (its bounds, and so the
    reach grid, change while the fur's reach rounds to the same cells): each frame's
    part is cut with that shape's box, the whole build's bits every frame (and,
    audited, every segment within it)."""
    V, F = scenes.grid(size=4.0, n=80, z=0.3)

    def shape(f):
        W = V * np.array([1.0 + 0.06 * (f % 2), 1.0 + 0.06 * (f % 2), 1.0])
        return _wave(W.astype(np.float32), f)

    part, whole = _pair(V, F, range(4), shape, Settings(mode="bend"))
    assert part == whole
    # the box is that of the shape the collider has, whatever shape set it before
    lo, hi = np.array([-1.33, -1.33, -0.5]), np.array([1.33, 1.33, 1.0])
    col = Collider(shape(0), F, deforming=True)
    col.set_reach(lo, hi)
    col.vertices = shape(1)
    got = col.set_reach(lo, hi)
    fresh = Collider(shape(1), F, deforming=True).set_reach(lo, hi)
    assert got.key == fresh.key
    assert np.array_equal(got.lo, fresh.lo) and np.array_equal(got.hi, fresh.hi)


def test_an_offset_shell_standing_out_of_a_small_sheet_keeps_its_offset():
    """A Collision Offset larger than a cell of the reach grid (a leaf, an ear, a
    collar): the shells stand out of the mesh's bounds, and the part still holds every
    triangle of them the curves can reach (the whole build's bits), on both sides."""
    V, F = scenes.grid(size=2.0, n=60, z=0.45)
    for double in (False, True):
        part, whole = _pair(V, F, range(3), lambda f: _wave(V.astype(np.float32), f),
                            Settings(mode="stiff", collision_offset=0.2), double=double)
        assert part == whole, double


def test_a_collider_placed_by_its_rigid_fit_forgets_the_reach():
    """A deforming collider whose shape one frame only moved rigidly from its rest
    shape is placed by the fit (its rest shape's shells, built whole): the step
    forgets the reach an earlier frame set, so nothing is built around a stale one."""
    V, F = _sheet()
    pts, offs = _fur()
    col = Collider(_wave(V, 0), F, deforming=True, rest=V)
    solver = Solver(offs, Settings(mode="bend"))
    solver.step(pts, [col])
    assert col.shells.reach is not None
    M = scenes.affine(scenes.rotation_matrix([0, 0, 1], 0.05), t=(0.01, 0.0, 0.02))
    col.vertices = (V @ M[:3, :3].T.astype(np.float32) + M[:3, 3].astype(np.float32))
    solver.step(pts, [col])
    assert col.pose.allowance > 0 and not col.builds_reach
    assert col.shells.reach is None
    assert all(faces.cover is None for _, _, faces in col.shells.built)


def test_a_segment_outside_the_reach_gets_the_whole_meshs_answer():
    """After a step set the reach near the fur, a query far from it (a script's, a
    distance check's) is traced against the whole shell, built then."""
    _, col, _, _, _, F = _play(True, frames=range(1))
    built = col.build_count
    o = np.array([[8.0, 8.0, 1.0], [0.0, 0.0, 1.0], [-9.0, 6.0, -1.0]])
    d = np.array([[0.0, 0.0, -2.0], [0.0, 0.0, -2.0], [0.0, 0.0, 2.0]])
    hit, t, _ = col.segment_hit_details(o, d)
    assert hit.all()
    assert col.build_count == built + 1  # (the whole shell, once)
    V = _wave(_sheet()[0], 0)
    whole = make_backend("numpy", V.astype(np.float64), F)
    prim, tt = whole.hit_details(o, d, 1.0)
    assert (prim >= 0).all()
    assert np.allclose(t, tt, atol=1e-5)
    assert col.segment_hits(o[:2], d[:2]).all()


def test_solvers_asking_for_the_same_cells_share_one_build():
    """Two solvers of one frame whose curves round to the same cells of the reach
    grid (guides and the render groom on the same patch) build once."""
    V, F = _sheet()
    pts, offs = _fur()
    col = Collider(_wave(V, 0), F, deforming=True)
    a = Solver(offs, Settings(mode="bend"))
    b = Solver(offs, Settings(mode="stiff"))
    a.step(pts, [col])
    built = col.build_count
    b.step(pts + np.float64(1e-4), [col])  # (a touch elsewhere: the same cells)
    assert col.build_count == built


def test_colliders_with_an_inside_test_or_no_hint_build_whole():
    """A closed single-sided collider (its inside test traces whole rays) and one
    without the deforming hint never build a part; a reach that covers about the
    whole collider builds it whole too (``tol.REACH_MIN_SAVING``)."""
    V, F = scenes.uv_sphere(radius=0.3, segments=64, rings=32)
    closed = Collider(V, F, deforming=True)
    assert not closed.builds_reach
    closed.set_reach(np.full(3, -0.1), np.full(3, 0.1))
    assert closed.shells.reach is None
    Vs, Fs = _sheet()
    assert not Collider(Vs, Fs).builds_reach
    near = Collider(Vs, Fs, deforming=True)
    near.set_reach(np.full(3, -12.0), np.full(3, 12.0))
    be, faces = near.shells.backend(0.0)
    assert faces.cover is None and len(faces.real) >= 2 * len(Fs)


def test_parts_answer_as_one_mesh_in_their_order():
    """make_parts_backend: triangle i of part j is the parts' triangle sum(sizes
    before j) + i, with Embree (one geometry per part) as with numpy."""
    V, F = scenes.grid(size=2.0, n=12, z=0.0)
    V = V.astype(np.float32)
    cuts = [0, 50, 51, 200, len(F)]
    parts = []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        ids, local = np.unique(F[a:b], return_inverse=True)
        local = local.reshape(-1, 3)
        parts.append((V[ids], local, triangle_rows(local)))
    rng = np.random.default_rng(5)
    o = np.c_[rng.uniform(-1, 1, (400, 2)), np.ones(400)]
    d = np.tile([0.0, 0.0, -2.0], (400, 1))
    want, wt = make_backend("numpy", V, F).hit_details(o, d, 1.0)
    for name in ("embree", "numpy"):
        prim, t = make_parts_backend(name, parts).hit_details(o, d, 1.0)
        assert make_parts_backend(name, parts).first_hit(o, d, 1.0).tolist() == prim.tolist()
        hit = prim >= 0
        assert (hit == (want >= 0)).all(), name
        # (a ray through an edge may report either face: same point, same t)
        assert np.allclose(t[hit], wt[hit], atol=1e-6), name
        same = prim == want
        assert same.mean() > 0.95, name
        assert make_parts_backend(name, parts).any_hit(o, d, 1.0).tolist() == hit.tolist()


def test_the_reach_tolerances_are_stated_tolerances():
    assert tol.REACH_CHUNK_FACES >= 256 and 0 < tol.REACH_MIN_SAVING < 1
    assert tol.REACH_GRID >= 2 and 0 <= tol.REACH_GROW_REL < 1
