"""Collider: closedness, lazy rebuilds, rigid motion through the matrix,
deformation through vertices, several colliders at once."""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes

from core import Collider, Settings, Solver, Status
from core.collider.inside import Inside


def test_closed_flag():
    for V, F in (scenes.uv_sphere(), scenes.icosphere(), scenes.box()):
        assert Collider(V, F).closed
        assert Collider(V, F, double_sided=True).closed  # topology only
        assert not Collider(V, F[1:]).closed  # a hole
        F2 = F.copy()
        F2[0] = F2[0, ::-1]  # one face flipped: repaired (meshfix), still closed
        col = Collider(V, F2)
        assert col.closed and col.repairs.flipped == 1
    V, F = scenes.grid()
    assert not Collider(V, F).closed
    # two disjoint closed boxes are closed
    V1, F1 = scenes.box([0, 0, 0], [1, 1, 1])
    V2, F2 = scenes.box([2, 0, 0], [3, 1, 1])
    assert Collider(np.vstack([V1, V2]), np.vstack([F1, F2 + len(V1)])).closed
    # a non-manifold edge (three faces) is not closed
    V3 = np.vstack([V1, [[0.5, 0.5, 3.0]]])
    F3 = np.vstack([F1, [[0, 1, 8]]])
    assert not Collider(V3, F3).closed


def _one_curve():
    return scenes.pack([scenes.curly_curve([0, 0, 0], [0, 0, 1], 1.0, 6, 0.1)])


def test_matrix_moves_collider_without_rebuild():
    pts, offs = _one_curve()
    V, F = scenes.uv_sphere([0, 0, 0], 0.3, 24, 12)
    col = Collider(V, F, matrix=scenes.translation([3, 0, 0.8]))
    solver = Solver(offs, Settings(mode="stiff", recovery_rate=1.0))
    r = solver.step(pts, [col])
    assert np.asarray(r.status)[0] == Status.FREE
    assert col.build_count == 1 or col.build_count == 0
    count = max(col.build_count, 1)
    for x in (0.5, 0.2, 0.05, 1.0, 3.0):
        M = scenes.affine(scenes.rotation_matrix([1, 2, 3], x), t=[x, 0, 0.8])
        col.matrix = M
        r = solver.step(pts, [col])
        geom.assert_no_intersection(r.points, offs, r.status, [(oracle.transform(V, M), F)])
    assert col.build_count == count
    assert np.asarray(r.status)[0] == Status.FREE and np.array_equal(r.points, pts)


def test_vertices_rebuild_only_when_changed():
    pts, offs = _one_curve()
    V, F = scenes.uv_sphere([0.1, 0, 0.8], 0.3, 24, 12)
    col = Collider(V, F)
    solver = Solver(offs, Settings(mode="bend"))
    solver.step(pts, [col])
    assert col.build_count == 1
    col.vertices = V.copy()  # identical values, new array
    solver.step(pts, [col])
    assert col.build_count == 1
    col.vertices = V * 1.0
    col.matrix = scenes.translation([0.01, 0, 0])
    solver.step(pts, [col])
    assert col.build_count == 1
    V2 = V.copy()
    V2[3] += 1e-3
    col.vertices = V2
    col.vertices = V2 * 1.0  # two sets before a query: one rebuild at most
    solver.step(pts, [col])
    assert col.build_count == 2
    solver.step(pts, [col])
    assert col.build_count == 2
    # in-place mutation of the caller's array must not leak into the collider
    V2[:] += 5.0
    r = solver.step(pts, [col])
    assert col.build_count == 2
    assert np.asarray(r.status)[0] != Status.FREE


def test_deforming_collider_is_respected():
    """A sphere inflating frame by frame (vertices change, same topology)."""
    rng = np.random.default_rng(3)
    pts, offs = scenes.fur_on_plane(rng, n_curves=25, curly=0.2, extent=0.6, n_cvs=(3, 8))
    V0, F = scenes.uv_sphere([0, 0, 0], 1.0, 24, 12)
    center = np.array([0.0, 0.0, 1.1])
    col = Collider(V0 * 0.3 + center, F)
    solver = Solver(offs, Settings(mode="bend", recovery_rate=0.3))
    builds = []
    for f in range(8):
        r = 0.3 + 0.04 * f
        Vw = V0 * r + center
        col.vertices = Vw
        res = solver.step(pts, [col])
        builds.append(col.build_count)
        geom.assert_no_intersection(res.points, offs, res.status, [(Vw, F)])
        geom.assert_roots_exact(pts, res.points, offs)
        geom.assert_lengths_kept(pts, res.points, offs, rtol=1e-9)
    assert builds == list(range(1, 9))


def test_multiple_colliders_single_and_double_sided():
    """A closed single-sided sphere and an open double-sided plane."""
    rng = np.random.default_rng(8)
    pts, offs = scenes.fur_on_plane(rng, n_curves=40, curly=0.2, extent=0.8, n_cvs=(3, 10))
    Vs, Fs = scenes.uv_sphere([0.3, 0.2, 0.8], 0.35, 24, 12)
    Vp, Fp = scenes.quad([-1.5, -1.5, 0.75], [3, 0, -0.3], [0, 3, 0.2])
    cols = [Collider(Vs, Fs), Collider(Vp, Fp, double_sided=True)]
    for mode in ("stiff", "bend", "soft"):
        res = Solver(offs, Settings(mode=mode)).step(pts, cols)
        status = np.asarray(res.status)
        assert np.count_nonzero(status == Status.COLLIDING) >= 10
        geom.assert_no_intersection(res.points, offs, status, [(Vs, Fs), (Vp, Fp)])
        # order of colliders does not matter
        res2 = Solver(offs, Settings(mode=mode)).step(pts, cols[::-1])
        assert np.array_equal(res.points, res2.points)
        assert np.array_equal(status, np.asarray(res2.status))


def test_same_collider_object_used_by_two_solvers():
    pts, offs = _one_curve()
    V, F = scenes.uv_sphere([0.1, 0, 0.8], 0.3, 24, 12)
    col = Collider(V, F)
    a = Solver(offs, Settings(mode="stiff")).step(pts, [col])
    b = Solver(offs, Settings(mode="stiff")).step(pts, [col])
    assert np.array_equal(a.points, b.points)
    assert col.build_count == 1


def test_same_collider_twice_in_the_list():
    rng = np.random.default_rng(2)
    pts, offs = scenes.fur_on_plane(rng, n_curves=30, extent=0.6)
    V, F = scenes.uv_sphere([0, 0, 0.8], 0.4, 24, 12)
    col = Collider(V, F)
    for mode in ("stiff", "bend", "soft"):
        a = Solver(offs, Settings(mode=mode)).step(pts, [col])
        b = Solver(offs, Settings(mode=mode)).step(pts, [col, col])
        assert np.array_equal(a.points, b.points)
        assert np.array_equal(np.asarray(a.status), np.asarray(b.status))


def test_sheared_and_scaled_matrices():
    """Non-orthogonal collider matrices (shear, non-uniform scale)."""
    rng = np.random.default_rng(4)
    pts, offs = scenes.fur_on_plane(rng, n_curves=40, extent=0.8, curly=0.2)
    V, F = scenes.uv_sphere([0, 0, 0], 1.0, 24, 12)
    A = np.array([[0.5, 0.3, 0.0], [0.0, 0.25, 0.1], [0.1, 0.0, 0.35]])
    M = scenes.affine(A, t=[0.1, -0.1, 0.8])
    for mode in ("stiff", "bend", "soft"):
        res = Solver(offs, Settings(mode=mode)).step(pts, [Collider(V, F, matrix=M)])
        status = np.asarray(res.status)
        assert np.count_nonzero(status == Status.COLLIDING) >= 3
        geom.assert_no_intersection(res.points, offs, status, [(oracle.transform(V, M), F)])
    # roots inside the sheared ellipsoid are pinched, others not
    M2 = scenes.affine(A * 2.0, t=[0.0, 0.0, 0.0])
    Vw = oracle.transform(V, M2)
    inside = oracle.points_inside_closed_mesh(pts[offs[:-1]], Vw, F)
    res = Solver(offs, Settings()).step(pts, [Collider(V, F, matrix=M2)])
    assert inside.any() and not inside.all()
    assert np.array_equal(np.asarray(res.status) == Status.PINCHED, inside)


def test_collider_copies_its_inputs():
    """Mutating the caller's arrays after handing them over changes nothing."""
    pts, offs = _one_curve()
    V, F = scenes.uv_sphere([0.1, 0, 0.8], 0.3, 24, 12)
    M = np.eye(4)
    ref = Solver(offs, Settings(mode="stiff")).step(pts, [Collider(V, F)])
    V2, F2, M2 = V.copy(), F.copy(), M.copy()
    col = Collider(V2, F2, matrix=M2)
    V2 += 10.0
    F2[:] = F2[:, ::-1]
    M2[:3, 3] = [5, 5, 5]
    r = Solver(offs, Settings(mode="stiff")).step(pts, [col])
    assert np.array_equal(r.points, ref.points)
    M3 = np.eye(4)
    col.matrix = M3
    M3[:3, 3] = [5, 5, 5]
    r = Solver(offs, Settings(mode="stiff")).step(pts, [col])
    assert np.array_equal(r.points, ref.points)


def test_early_build_on_a_ray_thread():
    """With two threads the solver starts a changed collider's BVH build
    during the set-up: once per change, never for a collider far from every
    curve, and with the same result as the lazy single-thread build."""
    pts, offs = _one_curve()
    V, F = scenes.uv_sphere([0.1, 0, 0.8], 0.3, 24, 12)
    far_V = V + np.float32(50.0)
    runs = {}
    for threads in (1, 2):
        near = Collider(V, F, deforming=True)
        far = Collider(far_V, F, deforming=True)
        solver = Solver(offs, Settings(mode="bend", threads=threads))
        out = []
        for k in range(4):
            wobble = (1.0 + 0.02 * k) * (V - V.mean(0)) + V.mean(0)
            near.vertices = wobble
            far.vertices = wobble + np.float32(50.0)
            r = solver.step(pts, [near, far])
            out.append((r.points.copy(), np.asarray(r.status).copy()))
            assert near.build_count == k + 1
            assert far.build_count == 0
        runs[threads] = out
    for (p1, s1), (p2, s2) in zip(runs[1], runs[2], strict=True):
        assert np.array_equal(p1, p2) and np.array_equal(s1, s2)
    assert (runs[1][0][1] != Status.FREE).any()  # the near collider is in play


def test_the_deforming_hint_changes_no_result():
    """deforming=None/False/True: the BVH is a function of the vertices alone, so
    the three give bit-identical results, before and after a deformation."""
    pts, offs = _one_curve()
    V, F = scenes.uv_sphere([0.1, 0, 0.8], 0.3, 24, 12)
    outs = []
    for flag in (None, False, True):
        col = Collider(V, F, deforming=flag)
        solver = Solver(offs, Settings(mode="bend", threads=1))
        r0 = solver.step(pts, [col])
        col.vertices = V * np.float32(1.05)
        r1 = solver.step(pts, [col])
        outs.append((r0.points, r1.points))
    for r0, r1 in outs[1:]:
        assert np.array_equal(r0, outs[0][0]) and np.array_equal(r1, outs[0][1])
    assert not np.array_equal(outs[0][1], pts)  # the sphere is in the way


def test_no_build_for_a_collider_out_of_reach_whatever_the_threads():
    """A ring whose box holds the curves but whose surface is out of their
    reach is never queried, so never built, with one thread or two."""
    pts, offs = _one_curve()  # from the origin, 1.0 long
    u = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    ring = np.concatenate(
        [np.stack([5 * np.cos(u), 5 * np.sin(u), np.full_like(u, z)], 1) for z in (0.0, 1.0)]
    )
    n = len(u)
    i, j = np.arange(n), (np.arange(n) + 1) % n
    F = np.concatenate([np.stack([i, j, i + n], 1), np.stack([j, j + n, i + n], 1)])
    for threads in (1, 2):
        col = Collider(ring, F, deforming=True)
        solver = Solver(offs, Settings(mode="bend", threads=threads))
        for k in range(3):
            col.vertices = ring * (1.0 + 0.01 * k)
            r = solver.step(pts, [col])
            assert np.array_equal(r.points, pts)
        assert col.build_count == 0


def test_a_failing_step_leaves_no_build_running():
    """A step that raises after starting a collider's build waits for it."""
    pts, offs = _one_curve()
    V, F = scenes.uv_sphere([0.1, 0, 0.8], 0.3, 24, 12)
    col = Collider(V, F, deforming=True)
    solver = Solver(offs, Settings(mode="bend", threads=2))
    solver.step(pts, [col])  # queried: the next step starts its build early
    col.vertices = V * np.float32(1.01)

    def broken(*a, **k):
        raise RuntimeError("simulated failure during the set-up")

    col.grid_coords = broken
    try:
        solver.step(pts, [col])
    except RuntimeError:
        pass
    else:  # pragma: no cover
        raise AssertionError("the step should have raised")
    assert not col.shells.lock.locked() and col.build_count == 2
    del col.grid_coords
    r = solver.step(pts, [col])  # and the solver goes on
    assert col.build_count == 2 and np.isfinite(r.points).all()


def test_inside_cell_cache_gives_the_answer_of_tracing_every_point():
    """contains(): points in cells no triangle of the shell touches take their
    cell's cached answer, the rest are traced; every answer equals tracing that
    very point (with and without an offset shell, and on a second query that
    reads the cache)."""
    rng = np.random.default_rng(7)
    for (V, F), M in (
        (scenes.torus([0, 0, 0], 1.0, 0.35, 48, 16), scenes.affine(t=[0.2, 0, 0])),
        (scenes.box([-0.5, -0.5, -0.5], [0.5, 0.5, 0.5]),
         scenes.affine(scenes.rotation_matrix([1, 1, 0], 0.3), s=1.3)),
    ):
        col = Collider(V, F, matrix=M)
        lo, hi = col.bounds_world(0.3)
        P = rng.uniform(lo - 0.2, hi + 0.2, size=(4000, 3))
        for off in (0.0, 0.05):
            for _ in range(2):
                got = col.contains(P, off)
                traced = col.inside.parity(P, off)
                np.testing.assert_array_equal(got, traced)
            assert got.any() and not got.all()


@pytest.mark.parametrize("kind", ["closed", "open sheet", "double-sided"])
def test_one_collider_shared_by_solvers_with_different_offsets(kind):
    """Several solvers may share one collider with different Collision Offsets: each
    gets the shell of its own offset (as with a collider of its own), in any order.
    (An open or double-sided collider's shell has other faces with an offset than
    without: every face of the real surface, or only its rims.)"""
    rng = np.random.default_rng(4)
    pts, offs = scenes.fur_on_plane(rng, n_curves=40, extent=0.5)
    if kind == "closed":
        V, F = scenes.uv_sphere([0, 0, 0.8], 0.35, 24, 12)
    else:
        V, F = scenes.grid(size=1.2, n=6, z=0.6)
    ds = kind == "double-sided"

    def collider():
        return Collider(V, F, double_sided=ds)

    shared = collider()
    for d in (0.0, 0.1, 0.5, 0.1, 0.0, 0.5):
        s = Settings(mode="stiff", collision_offset=d)
        got = Solver(offs, s).step(pts, [shared])
        want = Solver(offs, s).step(pts, [collider()])
        np.testing.assert_array_equal(got.points, want.points, err_msg=str(d))
        np.testing.assert_array_equal(got.status, want.status, err_msg=str(d))


def _two_overlapping_spheres():
    """One mesh of two closed spheres that overlap (an artist's body of parts)."""
    c = np.array([[0.0, 0.0, 0.0], [0.45, 0.1, 0.05]])
    r = np.array([0.4, 0.3])
    Va, Fa = scenes.uv_sphere(c[0], r[0], 48, 24)
    Vb, Fb = scenes.uv_sphere(c[1], r[1], 48, 24)
    return np.vstack([Va, Vb]), np.vstack([Fa, Fb + len(Va)]), c, r


def test_inside_overlapping_closed_parts_is_inside():
    """The parity test counts back minus front faces (a winding number): a point
    inside either of two overlapping closed parts is inside, one in neither is not
    (points within 2 % of a radius of either sphere are left out: the mesh is a
    polygon there)."""
    V, F, c, r = _two_overlapping_spheres()
    col = Collider(V, F)
    rng = np.random.default_rng(5)
    p = rng.uniform([-0.5, -0.5, -0.5], [0.85, 0.5, 0.5], (3000, 3))
    dist = np.linalg.norm(p[:, None] - c[None], axis=2) / r  # (n, 2), 1 on a sphere
    clear = (np.abs(dist - 1.0) > 0.02).all(axis=1)
    p, inside = p[clear], (dist[clear] < 1.0).any(axis=1)
    assert inside.sum() > 500 and (~inside).sum() > 500
    assert ((dist[clear] < 1.0).all(axis=1)).sum() > 50  # in both parts
    np.testing.assert_array_equal(col.contains(p), inside)
    np.testing.assert_array_equal(col.inside.parity(p, 0.0), inside)
    # and the solver pinches exactly the curves rooted inside
    roots = p[:400]
    curves = [scenes.straight_curve(x, [0, 0, 1], 0.3, 3) for x in roots]
    pts, offs = scenes.pack(curves)
    res = Solver(offs, Settings(mode="stiff")).step(pts, [col])
    np.testing.assert_array_equal(res.status == Status.PINCHED, inside[:400])


def test_an_empty_collider_answers_in_the_documented_types():
    """A collider without faces hits nothing: bool flags, t = inf (float64), zero
    normals, for world and local queries."""
    col = Collider(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    assert col.empty
    o, d = np.zeros((4, 3)), np.ones((4, 3))
    for h in (col.segment_hits(o, d), col.segment_hits_local(o, d)):
        assert h.dtype == bool and h.shape == (4,) and not h.any()
    hit, t, n = col.segment_hit_details(o, d)
    assert hit.dtype == bool and not hit.any()
    assert t.dtype == np.float64 and np.isinf(t).all() and (t > 0).all()
    assert n.shape == (4, 3) and not n.any()
    q = np.arange(12, dtype=np.float32).reshape(4, 3)
    p, n = col.closest_points(q)  # no surface: the queries themselves, no normal
    assert p.dtype == np.float64 and np.array_equal(p, q)
    assert n.shape == (4, 3) and n.dtype == np.float64 and not n.any()


def test_the_third_parity_vote_decides_when_the_first_two_disagree(monkeypatch):
    """The inside test casts two rays per point and a third where they disagree (a
    ray grazing an edge can miss a face). Fault injection: the first direction's rays
    miss everything, so every point's two votes disagree; the third vote must give
    each point its true side."""
    V, F = scenes.uv_sphere([0, 0, 0], 0.5, 32, 16)
    col = Collider(V, F)
    rng = np.random.default_rng(9)
    p = rng.normal(size=(400, 3)) * 0.3
    r = np.linalg.norm(p, axis=1)
    p, inside = p[np.abs(r - 0.5) > 0.03], r[np.abs(r - 0.5) > 0.03] < 0.5
    be, _ = col.shells.backend(0.0)
    real = be.hit_details
    first = np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0)  # the first vote's direction

    def grazing(o, d, tmax, **kw):
        prim, t, *rest = real(o, d, tmax, **kw)
        u = d / np.linalg.norm(d, axis=1, keepdims=True)
        miss = np.abs(u @ first - 1.0) < 1e-9
        prim = np.where(miss, -1, prim)
        return (prim, t, *rest)

    monkeypatch.setattr(be, "hit_details", grazing)
    np.testing.assert_array_equal(col.inside.parity(p, 0.0), inside)


def test_a_face_collapsed_by_a_deformation_keeps_the_offset_shell_whole():
    """Degenerate faces are dropped when a collider is built, but a deformation can
    collapse one later (a vertex pulled onto its neighbour; the topology stays). The
    offset shell must stay finite and closed there: dense fur under the collapsed
    faces is kept out of the mesh and about the offset away from it."""
    rng = np.random.default_rng(8)
    pts, offs = scenes.fur_on_plane(rng, n_curves=300, extent=0.25, n_cvs=(4, 6),
                                    length=(0.9, 1.1), curly=0.0)
    V, F = scenes.uv_sphere([0, 0, 1.0], 0.3, 16, 8)
    south = len(V) - 1
    V2 = V.copy()
    V2[south - 1] = V2[south]  # collapses the two faces that share both
    col = Collider(V, F)
    col.vertices = V2
    d = 0.1
    res = Solver(offs, Settings(mode="stiff", collision_offset=d)).step(pts, [col])
    assert np.isfinite(res.points).all()
    status = np.asarray(res.status)
    assert (status == Status.COLLIDING).sum() > 50
    geom.assert_no_intersection(res.points, offs, res.status, [(V2, F)])
    A, B, _, _ = oracle.curve_segments(res.points, offs)
    near = np.linalg.norm(np.stack([A, B]) - [0, 0, 1.0], axis=2).min()
    assert near > 0.3 + 0.5 * d, near  # (a mesh of chords: the shell is about d out)


def test_a_deforming_collider_queried_twice_a_frame_builds_no_fine_grid(monkeypatch):
    """The add-on queries a deforming collider twice per frame (the guides' pinch test,
    then the render groom's clearance pass): with ``deforming=True`` the inside test
    stays on the coarse grid (the fine per-shape grid would be built for one use every
    frame), with the same answers as without the hint."""
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 1.0, 32, 16)
    rng = np.random.default_rng(5)
    p = rng.uniform(-1.3, 1.3, (4000, 3))
    built = []
    surface_cells = Inside.surface_cells

    def spy(self, *a, **k):
        built.append(self)
        return surface_cells(self, *a, **k)

    monkeypatch.setattr(Inside, "surface_cells", spy)
    answers, cols = {}, {}
    for flag in (True, None):
        col = cols[flag] = Collider(V, F, deforming=flag)
        got = []
        for f in range(3):
            col.vertices = V * np.float32(1.0 + 0.02 * f)
            got.append([col.contains(p), col.contains(p)])  # two queries per frame
        answers[flag] = got
    assert not any(c is cols[True].inside for c in built)  # the hinted collider never built it
    assert any(c is cols[None].inside for c in built)  # (the heuristic alone, 2nd query)
    for f in range(3):
        r = np.linalg.norm(p, axis=1)
        scale = 1.0 + 0.02 * f
        for a, b in zip(answers[True][f], answers[None][f], strict=True):
            assert np.array_equal(a, b)
            clear = np.abs(r - scale) > 0.01  # away from the faceted surface
            assert np.array_equal(a[clear], (r < scale)[clear])
