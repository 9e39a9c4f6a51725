"""Collider promises not held elsewhere: the errors a bad matrix gets, the faces of
an empty collider, a shell per Collision Offset kept while several are in use, an
offset shell that follows a change of the matrix's stretch, and the inside test
at the corners of the collider's grid."""

from __future__ import annotations

import numpy as np
import oracle
import pytest
import scenes

from core import Collider, ColliderError
from core.collider.inside import Inside


@pytest.mark.parametrize(("matrix", "words"), [
    (np.diag([1.0, 1.0, np.nan, 1.0]), "non-finite entries"),
    (np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 2.0]]), "affine"),
    (np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0.5, 0, 0, 1.0]]), "affine"),
    (np.diag([1.0, 0.0, 1.0, 1.0]), "singular"),
    (np.eye(3), "4x4"),
])
def test_a_bad_matrix_is_refused_with_what_is_wrong(matrix, words):
    V, F = scenes.box()
    with pytest.raises(ColliderError, match=f"^collider matrix .*{words}"):
        Collider(V, F, matrix=matrix)
    col = Collider(V, F)
    with pytest.raises(ColliderError, match=f"^collider matrix .*{words}"):
        col.matrix = matrix
    np.testing.assert_array_equal(col.matrix, np.eye(4))  # unchanged


def test_an_empty_collider_has_no_faces_of_the_documented_shape():
    for F in (np.zeros((0, 3), np.int64), []):
        col = Collider(np.zeros((0, 3)), F)
        assert col.empty and col.faces.shape == (0, 3) and col.faces.dtype == np.int32


def test_shells_of_several_offsets_are_kept_while_in_use():
    """One collider queried with three offsets in turn builds each shell once."""
    V, F = scenes.uv_sphere([0, 0, 0], 0.5, 24, 12)
    col = Collider(V, F)
    rng = np.random.default_rng(2)
    o, d = rng.normal(size=(200, 3)), rng.normal(size=(200, 3))
    want = {off: Collider(V, F).segment_hits(o, d, off) for off in (0.0, 0.05, 0.2)}
    for _ in range(3):
        for off in (0.0, 0.05, 0.2):
            np.testing.assert_array_equal(col.segment_hits(o, d, off), want[off])
    assert col.build_count == 3


def test_an_offset_shell_follows_a_new_stretch_of_the_matrix():
    """The offset is in world units: after the matrix stretches the collider
    along one axis, its offset shell is the one of a collider made with that
    matrix (the BVH of the shell is rebuilt; a plain move never rebuilds it)."""
    V, F = scenes.uv_sphere([0, 0, 0], 0.5, 24, 12)
    rng = np.random.default_rng(3)
    o, d = rng.uniform(-1.2, 1.2, size=(400, 3)), 0.3 * rng.normal(size=(400, 3))
    off = 0.1
    col = Collider(V, F)
    b = np.sqrt(2.0 - 1.1**2)  # the same trace as the identity: only the shape of M^T M differs
    for M in (np.diag([1.0, 1.0, 1.0, 1.0]), np.diag([1.1, b, 1.0, 1.0]),
              np.diag([2.0, 1.0, 1.0, 1.0]), np.diag([1.0, 1.0, 3.0, 1.0])):
        col.matrix = M
        fresh = Collider(V, F, matrix=M)
        np.testing.assert_array_equal(col.segment_hits(o, d, off), fresh.segment_hits(o, d, off))
        np.testing.assert_array_equal(col.contains(o, off), fresh.contains(o, off))
        np.testing.assert_array_equal(col.contains(o, off), fresh.contains(o, off))
    built = col.build_count
    col.matrix = scenes.affine(t=(0.3, -0.2, 0.1)) @ np.diag([1.0, 1.0, 3.0, 1.0])
    col.segment_hits(o, d, off)
    assert col.build_count == built


def test_points_in_the_corner_cells_of_the_grid():
    """Points in the first and last cells of the inside test's grid (the corners
    of the collider's bounds: outside a ball) are outside, on the coarse grid and
    on the fine one."""
    V, F = scenes.uv_sphere([0.2, -0.1, 0.3], 0.5, 24, 12)
    col = Collider(V, F)
    lo, hi = V.min(0), V.max(0)
    eps = 1e-4 * (hi - lo)
    corners = np.array([[x, y, z] for x in (lo[0] + eps[0], hi[0] - eps[0])
                        for y in (lo[1] + eps[1], hi[1] - eps[1])
                        for z in (lo[2] + eps[2], hi[2] - eps[2])])
    P = np.vstack([corners, [[0.2, -0.1, 0.3]]])  # and the centre: inside
    for _ in range(3):
        np.testing.assert_array_equal(col.contains(P), [False] * 8 + [True])
    # a box fills its grid's corner cells: points just inside its corners are inside
    lo, hi = np.array([-0.3, -0.2, 0.1]), np.array([0.5, 0.2, 0.4])
    box = Collider(*scenes.box(lo, hi))
    eps = 1e-3 * (hi - lo)
    P = np.array([lo + eps, hi - eps, [lo[0] + eps[0], hi[1] - eps[1], lo[2] + eps[2]],
                  lo - eps])
    for _ in range(3):
        np.testing.assert_array_equal(box.contains(P), [True, True, True, False])


@pytest.mark.parametrize("shift", [0.0, 100.0])
@pytest.mark.parametrize("scale", [0.01, 1.0, 100.0])
def test_degenerate_faces_are_found_at_any_scale(scale, shift):
    """A face is degenerate when its area is below ``DEGENERATE_AREA_REL`` times
    the squared diagonal of the collider's bounds: the same faces at any scale and
    wherever the collider is modelled. A sliver ten times above that stays, one ten
    times below it is dropped."""
    from core import tolerances

    def mesh(area_rel):
        diag2 = 2.0  # the bounds of (0, 0, 0)..(1, 1, 0)
        h = 2.0 * area_rel * tolerances.DEGENERATE_AREA_REL * diag2  # base 1: area h / 2
        V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.5, h, 0]], float) * scale
        return V + [shift, 0.0, 0.0], np.array([[0, 2, 1], [0, 1, 3]])

    V, F = mesh(10.0)
    col = Collider(V, F)  # no error: nothing degenerate
    assert col.dropped_faces == 0 and len(col.faces) == 2
    V, F = mesh(0.1)
    with pytest.raises(ColliderError, match="degenerate"):
        Collider(V, F)
    col = Collider(V, F, drop_degenerate=True)
    assert col.dropped_faces == 1 and len(col.faces) == 1


def test_an_open_collider_contains_nothing_in_bools():
    V, F = scenes.grid(size=2.0, n=4, z=0.0)
    for col in (Collider(V, F), Collider(*scenes.box(), double_sided=True)):
        got = col.contains(np.zeros((5, 3)))
        assert got.dtype == bool and got.shape == (5,) and not got.any()


@pytest.mark.parametrize("off", [0.0, 0.003])
def test_only_points_next_to_the_surface_are_traced(monkeypatch, off):
    """``contains`` on a collider that keeps its shape answers a point in a grid
    cell no triangle of the shell touches with its cell's answer: once the cells
    are known, only points within a few cells of the shell are traced one by one
    (the collider moved far from the origin, with and without an offset)."""
    c = np.array([0.1, 0.0, -0.2])
    V, F = scenes.uv_sphere(c, 0.5, 32, 16)
    move = np.array([6.0, -4.0, 3.0])
    col = Collider(V, F, matrix=scenes.translation(move))
    rng = np.random.default_rng(8)
    lo, hi = V.min(0) + 1e-3, V.max(0) - 1e-3
    P = rng.uniform(lo, hi, size=(3000, 3))  # on the grid, its corner cells too
    P[:8] = [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    r = np.linalg.norm(P - c, axis=1)
    P = P + move
    col.contains(P, off)
    first = col.contains(P, off)  # the fine grid: its cells' answers now known
    traced = []
    parity = Inside.parity

    def spy(self, p_wo, offset_wo):
        traced.append(np.array(p_wo))
        return parity(self, p_wo, offset_wo)

    monkeypatch.setattr(Inside, "parity", spy)
    got = col.contains(P, off)
    np.testing.assert_array_equal(got, first)
    far = np.abs(r - 0.5) > 0.02 + 4 * off
    np.testing.assert_array_equal(got[far], r[far] < 0.5)
    t = np.concatenate(traced) if traced else np.zeros((0, 3))
    # a traced point's cell meets a triangle's bounding box, grown by how far the
    # shell moves it (OFFSET_MAX_STRETCH offsets at most)
    tri = V[F]
    box = float(np.linalg.norm(tri.max(axis=1) - tri.min(axis=1), axis=1).max())
    h = 1.0 / 128  # a fine cell: the bounds' largest side / (64 x 2)
    dist = np.abs(np.linalg.norm(t - move - c, axis=1) - 0.5)
    assert 0 < len(t) < len(P) * (0.5 if off == 0 else 0.8)
    # (the shell's reach per world unit of offset, bounded without an SVD: 4 * |A|_F)
    reach = 4.0 * 1.01 * np.sqrt(3) * off
    assert dist.max() < box + reach + 2 * np.sqrt(3) * h, (dist.max(), box)


@pytest.mark.parametrize("scale", [1.0, 1000.0])
@pytest.mark.parametrize("off", [0.0, 0.1, 0.4])
def test_world_bounds_hold_the_offset_shell_and_little_more(off, scale):
    """``bounds_world(offset)`` holds every point the offset shell can reach (its
    vertices move out at most ``OFFSET_MAX_STRETCH`` offsets) and is no looser than
    that reach by more than a few per cent (curves are candidates by these bounds)."""
    from core import tolerances

    V, F = scenes.box([-0.3, -0.2, 0.1], [0.5, 0.2, 0.4])
    M = scenes.affine(scenes.rotation_matrix([0, 0, 1], 0.3), t=(1.0, 2.0, -0.5), s=scale)
    col = Collider(V, F, matrix=M)
    lo, hi = col.bounds_world(off)
    Vw = V @ M[:3, :3].T + M[:3, 3]
    reach = off * tolerances.OFFSET_MAX_STRETCH
    assert (lo <= Vw.min(0) - off).all() and (hi >= Vw.max(0) + off).all()
    assert (lo >= Vw.min(0) - 1.05 * reach - 1e-4 * scale).all()
    assert (hi <= Vw.max(0) + 1.05 * reach + 1e-4 * scale).all()
    rng = np.random.default_rng(1)
    o = rng.uniform(lo - scale, hi + scale, size=(300, 3))
    hit, t, _ = col.segment_hit_details(o, (Vw.mean(0) - o) * 2.0, off)
    p = o[hit] + t[hit, None] * (Vw.mean(0) - o[hit]) * 2.0
    assert hit.sum() > 100 and (p >= lo).all() and (p <= hi).all()


def test_a_turning_collider_with_an_offset_never_rebuilds_its_shell():
    """A rigid collider turning and moving (its matrix read from Blender in float32,
    so its rotation part is orthonormal only to float32 rounding) keeps its offset
    shell: the shell depends on the matrix's stretch, and rounding is no stretch."""
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 0.5, 24, 12)
    col = Collider(V, F)
    rng = np.random.default_rng(12)
    o, d = rng.normal(size=(100, 3)), rng.normal(size=(100, 3))
    for k in range(24):
        R = scenes.rotation_matrix([1.0, 2.0, 3.0 + k], 0.37 * k)
        M = scenes.affine(R, t=(0.1 * k, -0.2, 0.05 * k)).astype(np.float32)
        col.matrix = M
        col.segment_hits(o, d, 0.05)
    assert col.build_count == 1


def test_derived_data_is_kept_per_key():
    """``derived`` builds once per key and again for a new one (the collider's own
    per-shape caches go through it too)."""
    col = Collider(*scenes.box())
    calls = []

    def build():
        calls.append(len(calls))
        return len(calls)

    assert col.derived("x", (col.version, 1), build) == 1
    assert col.derived("x", (col.version, 1), build) == 1
    assert col.derived("y", (col.version, 1), build) == 2  # another name
    assert col.derived("x", (col.version, 2), build) == 3
    col.vertices = col.vertices * np.float32(2.0)
    assert col.derived("x", (col.version, 2), build) == 4  # a new shape: a new key
    assert len(calls) == 4


@pytest.mark.parametrize("deform", [False, True])
def test_far_away_points_are_far_without_a_warning(deform):
    """Points far beyond the collider (a stray CV at 1e30) are outside and far from
    it, and no float-to-int overflow warning reaches the console (the grid indices
    are clipped before the integer cast), on the fine grid and on the coarse one."""
    import warnings

    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 1.0, 16, 8)
    col = Collider(V, F)
    far = np.array([[1e30, 0, 0], [-1e30, 0, 0], [0, 1e25, -1e25], [3e19, 3e19, 3e19],
                    [0.0, 0.0, 0.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for _ in range(2):  # the first call of a shape, then the fine grid's
            if deform:
                col.vertices = col.vertices * np.float32(1.001)
            assert not col.near_surface(far[:4], 0.1).any()
            np.testing.assert_array_equal(col.contains(far), [False] * 4 + [True])


@pytest.mark.parametrize("s", [1e-6, 1e4])
def test_a_uniform_scale_is_never_singular(s):
    """The singular-matrix check is relative to the matrix's own scale: a collider
    scaled to micrometres (or up by 1e4) is accepted and tests inside as scaled."""
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 1.0, 16, 8)
    M = np.diag([s, s, s, 1.0])
    M[:3, 3] = 1e6 * s, -3e5, 0.0  # (far from the origin: the translation is no scale)
    col = Collider(V, F, matrix=M)
    P = np.array([[0.0, 0, 0], [2.0 * s, 0, 0]]) + M[:3, 3]
    np.testing.assert_array_equal(col.contains(P), [True, False])
    col.matrix = M  # the setter too


def test_near_surface_is_tight_to_a_few_grid_cells():
    """``near_surface`` is conservative (a ball holding a vertex is near) and tight:
    a ball farther (per axis) than its radius times the matrix's Frobenius bound plus
    the longest edge plus two grid cells from every vertex is far (the summed-area
    table counts exactly the cells the ball's box covers)."""
    from core import tolerances

    rng = np.random.default_rng(3)
    centres = np.vstack([[0, 0, 0], [1, 1, 1], rng.uniform(0, 1, (40, 3))])
    V = (np.repeat(centres, 3, axis=0) + rng.normal(scale=0.004, size=(3 * len(centres), 3)))
    F = np.arange(len(V)).reshape(-1, 3)
    col = Collider(V, F)
    Vf = col.vertices.astype(np.float64)
    h = float((Vf.max(0) - Vf.min(0)).max()) / tolerances.OCCUPANCY_CELLS
    edge = max(float(np.linalg.norm(Vf[F[:, k]] - Vf[F[:, (k + 1) % 3]], axis=1).max())
               for k in range(3))
    P = np.vstack([rng.uniform(-0.1, 1.1, (20000, 3)),
                   rng.uniform(-0.05, 0.05, (4000, 3)) + rng.integers(0, 2, (4000, 3))])
    r = rng.uniform(0.0, 0.03, len(P))
    near = col.near_surface(P, r)
    cheb = np.abs(P[:, None] - Vf[None]).max(axis=2).min(axis=1)
    eucl = np.linalg.norm(P[:, None] - Vf[None], axis=2).min(axis=1)
    assert near[eucl < r].all()
    loose = cheb > r * np.sqrt(3.0) + edge + 2.0 * h + 1e-9
    assert loose.sum() > len(P) // 2
    assert not (near & loose).any(), np.flatnonzero(near & loose)[:5]


def test_prefetch_starts_nothing_on_one_thread_or_an_empty_collider():
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 1.0, 16, 8)
    assert Collider(V, F).prefetch(0.0, 1) is None
    assert Collider(np.zeros((0, 3)), []).prefetch(0.0, 2) is None
    wait = Collider(V, F).prefetch(0.0, 2)
    assert wait is not None
    wait()


def test_an_empty_query_or_collider_answers_in_bools():
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 1.0, 16, 8)
    empty = Collider(np.zeros((0, 3)), [])
    for col, P in ((empty, np.zeros((4, 3))), (Collider(V, F), np.zeros((0, 3)))):
        q = np.zeros((3, len(P)))
        for got in (col.near_surface(P, 0.1), col.near_surface_grid(q, 0.1),
                    col.contains(P), col.segment_hits(P, P)):
            assert got.dtype == bool and got.shape == (len(P),) and not got.any()


@pytest.mark.parametrize("off", [0.5, 1.0])
def test_inside_an_offset_shell_that_folds_is_its_winding_number(off):
    """A Collision Offset larger than a collider's dents folds its shell over itself;
    inside is then where the shell winds round a point a positive number of times
    (the generalized winding number of the shell's triangles, an independent oracle),
    not the side of the first crossing, which a folded shell gets wrong."""
    V, F = scenes.bumpy_sphere(amplitude=0.5, lobes=4)
    col = Collider(V, F, backend="numpy")
    assert col.repairs.parts == 1
    be, _ = col.shells.backend(off)
    T = np.stack([be._v0, be._v0 + be._e1, be._v0 + be._e2], axis=1) + col.mesh.center
    P = np.random.default_rng(0).uniform(-2.5, 2.5, (3000, 3))
    w = oracle.winding_number(P, T)
    clear = np.abs(w - np.round(w)) < 0.01  # not on the shell
    assert (np.round(w[clear]) > 1).any() or (np.round(w[clear]) < 0).any()  # it folds
    np.testing.assert_array_equal(col.contains(P, off)[clear], w[clear] > 0.5)


@pytest.mark.parametrize("off", [0.05, 0.3])
def test_world_bounds_hold_a_needle_tips_offset_shell(off):
    """A needle's tip moves out the full ``OFFSET_MAX_STRETCH`` offsets (its faces are
    nearly parallel to its normal): ``bounds_world`` still holds the shell there."""
    from core import tolerances

    n, length, r = 24, 1.0, 0.03  # a cone along +x, 1.7 degrees half-angle
    a = 2 * np.pi * np.arange(n) / n
    V = np.vstack([[[length, 0.0, 0.0]], np.stack([np.zeros(n), r * np.cos(a), r * np.sin(a)], 1),
                   [[0.0, 0.0, 0.0]]])
    F = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]
                 + [[n + 1, 1 + (i + 1) % n, 1 + i] for i in range(n)])
    col = Collider(V, F)
    assert col.closed
    lo, hi = col.bounds_world(off)
    yz = np.random.default_rng(2).uniform(-1e-6, 1e-6, (50, 2))
    o = np.column_stack([np.full(50, 3.0), yz])
    hit, t, _ = col.segment_hit_details(o, np.tile([-3.0, 0.0, 0.0], (50, 1)), off)
    tip = 3.0 - 3.0 * t[hit]
    assert hit.all() and tip.min() > length + 0.99 * tolerances.OFFSET_MAX_STRETCH * off
    assert (tip <= hi[0]).all(), (tip.max(), hi[0])


@pytest.mark.parametrize("size", [1e-3, 100.0, 1e4])
def test_inside_at_any_size_of_the_model(size):
    """The inside test's rays reach the surface however large or small the collider
    is modelled (its own vertices, not its matrix): its centre is inside, a point
    beyond it outside, through the fine grid and the traced points alike."""
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], size, 24, 12)
    col = Collider(V, F)
    P = np.array([[0.0, 0.0, 0.0], [0.1 * size, 0.2 * size, 0.0], [0.0, 0.0, 0.999 * size],
                  [1.5 * size, 0.0, 0.0], [0.0, 0.0, 1.01 * size]])
    for _ in range(2):
        np.testing.assert_array_equal(col.contains(P), [True, True, True, False, False])


def test_hit_details_of_a_miss():
    """``segment_hit_details``: a miss has t = inf and a zero normal, a hit t in
    [0, 1] and a unit normal."""
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 1.0, 24, 12)
    col = Collider(V, F)
    o = np.array([[3.0, 0.0, 0.0], [0.3, 0.2, 3.0]])
    d = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -4.0]])
    hit, t, n = col.segment_hit_details(o, d)
    np.testing.assert_array_equal(hit, [False, True])
    assert t[0] == np.inf and not n[0].any()
    assert 0.45 < t[1] < 0.55 and abs(np.linalg.norm(n[1]) - 1.0) < 1e-12


def test_a_repeated_vertex_is_a_degenerate_face():
    V, F = scenes.box()
    F = np.vstack([F, [[0, 0, 1], [2, 3, 3], [4, 5, 4]]])
    with pytest.raises(ColliderError, match=f"face {len(F) - 3} "):
        Collider(V, F)
    assert Collider(V, F, drop_degenerate=True).dropped_faces == 3


def test_the_clearance_margin_moves_each_vertex_outward():
    """The clearance margin's directions (area-weighted vertex normals) point out of a
    sphere along its radius."""
    V, F = scenes.uv_sphere([0.2, 0.0, -0.1], 1.0, 24, 12)
    radial = (V - [0.2, 0.0, -0.1]) / np.linalg.norm(V - [0.2, 0.0, -0.1], axis=1,
                                                      keepdims=True)
    got = Collider(V, F).mesh.margin_directions()
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-12)
    assert np.einsum("ij,ij->i", got, radial).min() > 0.99


def test_float_faces_of_whole_numbers_are_faces():
    """Faces given as floats holding whole numbers (read from a text format) are
    accepted, and an error names the face with its integer indices."""
    V, F = scenes.box()
    col = Collider(V, F.astype(np.float64))
    np.testing.assert_array_equal(col.faces, Collider(V, F).faces)
    bad = F.astype(np.float64)
    bad[1, 2] = 9.0
    with pytest.raises(ColliderError, match=rf"face 1 \[{int(F[1, 0])}, {int(F[1, 1])}, 9\] "
                                            "indexes a vertex out of range"):
        Collider(V, bad)
