"""Bad input raises typed ValueErrors that name the culprit; never a crash or NaN."""

from __future__ import annotations

import re

import numpy as np
import pytest
import scenes

from core import Collider, Settings, Solver, Status
from core.errors import ColliderError, InputError, SettingsError


def _names(msg, *tokens):
    """Does the message mention every token as a whole word?"""
    return all(re.search(rf"(?<![\w.]){re.escape(str(t))}(?![\w.])", msg) for t in tokens)


def _fur():
    """Three straight 3-CV curves under a sphere that hits curves 0 and 1."""
    curves = [scenes.straight_curve([x, 0, 0], [0, 0, 1], 1.0, 3) for x in (0.0, 0.15, 3.0)]
    return scenes.pack(curves)


def _sphere():
    V, F = scenes.uv_sphere(center=(0, 0, 1.0), radius=0.3, segments=16, rings=8)
    return Collider(V, F)


def test_error_hierarchy():
    for E in (InputError, ColliderError, SettingsError):
        assert issubclass(E, ValueError)


# ----------------------------------------------------------------- offsets
@pytest.mark.parametrize(
    ("offsets", "tokens"),
    [
        (np.array([[0, 3], [3, 6]]), ()),  # 2-D
        (np.array([1, 3, 6]), ()),  # does not start at 0
        (np.array([0, 3, 3, 6]), (1,)),  # curve 1 empty (not increasing)
        (np.array([0, 4, 3, 6]), (1,)),  # decreasing at curve 1
        (np.array([0, 3, 4, 7]), (1,)),  # curve 1 has a single point
        (np.array([0, 1]), (0,)),  # curve 0 has a single point
    ],
    ids=["2d", "not-from-0", "empty-curve", "decreasing", "one-point-curve", "one-point-only"],
)
def test_bad_offsets(offsets, tokens):
    with pytest.raises(InputError) as ei:
        Solver(offsets, Settings())
    msg = str(ei.value)
    assert "offset" in msg.lower() or "curve" in msg.lower(), msg
    assert _names(msg, *tokens), msg


def test_non_integer_offsets_rejected():
    with pytest.raises(InputError):
        Solver(np.array([0.0, 2.5, 5.0]), Settings())


def test_last_offset_must_match_points():
    pts, offs = _fur()
    solver = Solver(offs, Settings())
    for wrong in (pts[:-1], np.vstack([pts, pts[:1]])):
        with pytest.raises(InputError) as ei:
            solver.step(wrong, [])
        msg = str(ei.value)  # both counts, so the user sees which side is off
        assert _names(msg, len(wrong)) and _names(msg, offs[-1]), msg


def test_settings_type_checked():
    _, offs = _fur()
    with pytest.raises(SettingsError, match=r"core\.Settings.*dict"):
        Solver(offs, {"mode": "bend"})


# ----------------------------------------------------------------- points
@pytest.mark.parametrize(
    "make",
    [
        lambda p: p[:, :2],  # (P, 2)
        lambda p: p.reshape(-1),  # 1-D
        lambda p: np.round(p).astype(np.int64),  # int points
        lambda p: p[None],  # 3-D
        lambda p: p.astype(np.complex128),
    ],
    ids=["P2", "flat", "int", "3d", "complex"],
)
def test_bad_point_arrays(make):
    pts, offs = _fur()
    solver = Solver(offs, Settings())
    with pytest.raises(InputError) as ei:
        solver.step(make(pts), [_sphere()])
    assert "point" in str(ei.value).lower()


def _solved_without(pts, offs, col, c, mode="stiff"):
    """The step's result for every curve but ``c`` (switched off)."""
    enabled = np.ones(len(offs) - 1, bool)
    enabled[c] = False
    return Solver(offs, Settings(mode=mode)).step(pts, [col], enabled=enabled)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_point_marks_its_curve_invalid(bad):
    """One bad point (issue 15): its curve is INVALID and left as its input (the
    bad value replaced by the point before it, never NaN), named with its point
    in the step's problems; every other curve is solved as without it."""
    pts, offs = _fur()  # curves at points 0-2, 3-5, 6-8
    pts = pts.copy()
    pts[7, 1] = bad
    col = _sphere()
    res = Solver(offs, Settings(mode="stiff")).step(pts, [col])
    assert res.status[2] == Status.INVALID
    assert np.isfinite(res.points).all()
    np.testing.assert_array_equal(res.points[6], pts[6])
    np.testing.assert_array_equal(res.points[7], pts[6])  # the bad point: the one before
    np.testing.assert_array_equal(res.points[8], pts[8])
    msg = res.problems[0]
    assert _names(msg, 7) and _names(msg, 2) and "not finite" in msg, msg
    ref = _solved_without(pts, offs, col, 2)
    np.testing.assert_array_equal(res.points[:6], ref.points[:6])
    np.testing.assert_array_equal(res.status[:2], ref.status[:2])


def test_a_zero_length_segment_marks_its_curve_invalid():
    pts, offs = _fur()
    pts = pts.copy()
    pts[5] = pts[4]  # curve 1, segment 1
    col = _sphere()
    res = Solver(offs, Settings(mode="stiff")).step(pts, [col])
    assert res.status[1] == Status.INVALID
    np.testing.assert_array_equal(res.points[3:6], pts[3:6])
    msg = res.problems[0]
    assert "zero-length" in msg and _names(msg, 1) and _names(msg, 4), msg
    ref = _solved_without(pts, offs, col, 1)
    keep = np.r_[0:3, 6:9]
    np.testing.assert_array_equal(res.points[keep], ref.points[keep])


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_an_invalid_curve_keeps_its_state(mode):
    """A curve invalid for a frame keeps its local state: when it is good again
    the next frame equals a run in which that frame never happened for it. The
    other curves' state (Soft's per-segment rows too) moves on as usual; the sphere
    backs off on the invalid frame, so it must."""
    pts, offs = _fur()
    col = _sphere()
    s1 = Solver(offs, Settings(mode=mode, recovery_rate=0.5))
    s1.step(pts, [col])
    before = s1.state
    bad = pts.copy()
    bad[4] = np.nan
    col.matrix = scenes.translation([0.0, 0.0, 0.3])
    r = s1.step(bad, [col])
    assert r.status[1] == Status.INVALID and r.status[0] == Status.RECOVERING
    after = s1.state
    for key in ("angle", "axis", "frame", "active"):
        np.testing.assert_array_equal(after[key][1], before[key][1], err_msg=key)
    s2 = Solver(offs, Settings(mode=mode, recovery_rate=0.5))
    col.matrix = np.eye(4)
    s2.step(pts, [col])
    col.matrix = scenes.translation([0.0, 0.0, 0.3])
    s2.step(pts, [col], enabled=np.array([True, False, True]))
    for key, value in s2.state.items():  # every row, curve 0's moved on in both
        np.testing.assert_array_equal(s1.state[key], value, err_msg=key)
    col.matrix = np.eye(4)
    a, b = s1.step(pts, [col]), s2.step(pts, [col])
    assert np.array_equal(a.points, b.points)
    assert np.all(np.isfinite(a.points))
    assert np.array_equal(np.asarray(a.status), np.asarray(b.status))


def test_several_invalid_curves_are_counted_and_the_lowest_is_named():
    """The step's one problem names the lowest invalid curve, whatever made it invalid
    (here a zero-length segment in curve 0 and a NaN in curve 2), and counts them."""
    pts, offs = _fur()
    pts = pts.copy()
    pts[1] = pts[0]  # curve 0: zero-length first segment
    pts[7, 2] = np.nan  # curve 2
    res = Solver(offs, Settings(mode="stiff")).step(pts, [_sphere()])
    assert res.status.tolist() == [Status.INVALID, Status.COLLIDING, Status.INVALID]
    (msg,) = res.problems
    assert msg.startswith("curve 0") and "zero-length" in msg, msg
    assert msg.endswith(" (2 invalid curves: left as they are, not solved)"), msg
    pts[1] = pts[0] + [0, 0, 0.5]
    (msg,) = Solver(offs, Settings(mode="stiff")).step(pts, [_sphere()]).problems
    assert msg.startswith("curve 2") and msg.endswith(" (left as it is, not solved)"), msg


def test_a_curve_without_a_finite_point_is_output_at_the_origin():
    """_as_given: every point of a curve NaN: its output is the origin, never NaN."""
    pts, offs = _fur()
    pts = pts.copy()
    pts[3:6] = np.nan
    res = Solver(offs, Settings(mode="bend")).step(pts, [_sphere()])
    assert res.status[1] == Status.INVALID
    assert np.isfinite(res.points).all()
    np.testing.assert_array_equal(res.points[3:6], np.zeros((3, 3)))


def test_leading_non_finite_points_take_the_first_finite_one_after_them():
    """_as_given: non-finite points at the start of an invalid curve are replaced by
    the first finite point after them (here the curve's last point)."""
    pts, offs = _fur()
    pts = pts.copy()
    pts[3:5] = np.nan  # curve 1: points 3 and 4, only point 5 is finite
    res = Solver(offs, Settings(mode="stiff")).step(pts, [_sphere()])
    assert res.status[1] == Status.INVALID
    np.testing.assert_array_equal(res.points[3:6], np.repeat(pts[5:6], 3, axis=0))


@pytest.mark.parametrize("mask", [np.array([1, 0, 1]), np.array([2.5, 0.0, -1.0]),
                                  np.array([1, 0, 1], np.uint8)])
def test_enabled_as_numbers_means_nonzero(mask):
    """The enabled mask may be integers or floats (an attribute read from Blender):
    non-zero is enabled."""
    pts, offs = _fur()
    want = Solver(offs, Settings()).step(pts, [_sphere()], enabled=mask != 0)
    got = Solver(offs, Settings()).step(pts, [_sphere()], enabled=mask)
    np.testing.assert_array_equal(got.points, want.points)
    np.testing.assert_array_equal(got.status, want.status)
    assert got.status[1] == Status.DISABLED


@pytest.mark.parametrize(("mask", "word"), [
    (np.array([1, 0, 1], np.complex128), "booleans"), (np.array(["a", "b", "c"]), "booleans"),
    (np.array([1.0, np.nan, 0.0]), "non-finite")])
def test_enabled_of_another_kind_is_refused(mask, word):
    pts, offs = _fur()
    with pytest.raises(InputError, match=word):
        Solver(offs, Settings()).step(pts, [_sphere()], enabled=mask)


def test_enabled_wrong_length_and_shape():
    pts, offs = _fur()
    solver = Solver(offs, Settings())
    for enabled in (np.ones(2, bool), np.ones(4, bool), np.ones((3, 1), bool)):
        with pytest.raises(InputError) as ei:
            solver.step(pts, [_sphere()], enabled=enabled)
        assert "enabled" in str(ei.value).lower()


# ----------------------------------------------------------------- colliders
def _good_mesh():
    return scenes.box()


def test_vertices_shape_dtype_and_finite():
    V, F = _good_mesh()
    with pytest.raises(ColliderError, match="(?i)vert"):
        Collider(V[:, :2], F)
    with pytest.raises(ColliderError, match="(?i)vert"):
        Collider(V.reshape(-1), F)
    with pytest.raises(ColliderError, match="(?i)vert"):
        Collider(V.astype(np.complex128), F)
    for bad in (np.nan, np.inf):
        V2 = V.copy()
        V2[5, 2] = bad
        with pytest.raises(ColliderError) as ei:
            Collider(V2, F)
        assert _names(str(ei.value), 5), str(ei.value)


def test_faces_shape_and_dtype():
    V, F = _good_mesh()
    with pytest.raises(ColliderError, match="(?i)face"):
        Collider(V, F[:, :2])
    with pytest.raises(ColliderError, match="(?i)face"):
        Collider(V, F.reshape(-1))
    with pytest.raises(ColliderError, match="(?i)face"):
        Collider(V, F.astype(np.float64) + 0.5)


@pytest.mark.parametrize("value", [8, 100, -1])
def test_face_index_out_of_range_named(value):
    V, F = _good_mesh()  # 8 vertices, 12 faces
    F = F.copy()
    F[9, 1] = value
    with pytest.raises(ColliderError) as ei:
        Collider(V, F)
    msg = str(ei.value)
    assert "face" in msg.lower() and _names(msg, 9), msg


@pytest.mark.parametrize("kind", ["collinear", "repeated-index", "coincident-vertices"])
def test_degenerate_triangles(kind):
    V, F = scenes.grid(size=2.0, n=2, z=0.5)  # 9 vertices, 8 faces
    V = np.vstack([V, [[0, 0, 2], [1, 1, 2], [2, 2, 2]]])  # collinear 9, 10, 11
    bad = {"collinear": [9, 10, 11], "repeated-index": [3, 3, 4],
           "coincident-vertices": [9, 12, 10]}[kind]
    if kind == "coincident-vertices":
        V = np.vstack([V, V[9]])
    F2 = np.vstack([F[:5], [bad], F[5:]])  # degenerate face index 5
    with pytest.raises(ColliderError) as ei:
        Collider(V, F2)
    msg = str(ei.value)
    assert "face" in msg.lower() and _names(msg, 5), msg
    # dropping it is allowed on request, and the rest still collides
    col = Collider(V, F2, drop_degenerate=True, double_sided=True)
    pts, offs = scenes.pack([scenes.straight_curve([0.1, 0.2, 0], [0, 0, 1], 1.0, 4)])
    res = Solver(offs, Settings(mode="stiff")).step(pts, [col])
    assert np.asarray(res.status)[0] == Status.COLLIDING
    assert np.all(np.isfinite(res.points))


@pytest.mark.parametrize(
    "M",
    [
        np.eye(3),
        np.eye(4)[:3],
        np.eye(4).ravel(),
        np.diag([1.0, 1.0, 0.0, 1.0]),  # singular
        np.where(np.eye(4) > 0, np.nan, 0.0),
        np.diag([np.inf, 1.0, 1.0, 1.0]),
        scenes.affine(R=[[1, 2, 3], [2, 4, 6], [0, 0, 1]]),  # rank 2
    ],
    ids=["3x3", "3x4", "flat", "singular", "nan", "inf", "rank2"],
)
def test_bad_matrix(M):
    V, F = _good_mesh()
    with pytest.raises(ColliderError, match="(?i)matrix"):
        Collider(V, F, matrix=M)
    col = Collider(V, F)
    with pytest.raises(ColliderError, match="(?i)matrix"):
        col.matrix = M
    # the collider keeps its previous, valid matrix
    assert np.array_equal(np.asarray(col.matrix, float), np.eye(4))


def test_vertices_setter_validates_and_keeps_topology():
    V, F = _good_mesh()
    col = Collider(V, F)
    with pytest.raises(ColliderError):
        col.vertices = V[:-1]  # different vertex count
    with pytest.raises(ColliderError):
        col.vertices = np.where(V > 0, np.nan, V)
    assert np.array_equal(np.asarray(col.vertices, float), V)


def test_negative_offset_rejected():
    V, F = _good_mesh()
    with pytest.raises(ColliderError, match="(?i)offset"):
        Collider(V, F, offset=-0.1)
    with pytest.raises(ColliderError, match="(?i)offset"):
        Collider(V, F, offset=np.nan)


def test_non_collider_in_list_rejected():
    pts, offs = _fur()
    V, F = _good_mesh()
    with pytest.raises(InputError, match=r"colliders\[0\] is a tuple, not a core\.Collider"):
        Solver(offs, Settings()).step(pts, [(V, F)])


# ----------------------------------------------------------------- empty collider
@pytest.mark.parametrize("nverts", [0, 5])
def test_empty_collider_is_noop(nverts):
    pts, offs = _fur()
    V = np.zeros((nverts, 3)) + np.arange(nverts)[:, None]
    col = Collider(V, np.zeros((0, 3), dtype=np.int64))
    for mode in ("stiff", "bend", "soft"):
        res = Solver(offs, Settings(mode=mode)).step(pts, [col])
        assert np.array_equal(res.points, pts)
        assert np.all(np.asarray(res.status) == Status.FREE)
        # next to a real collider it changes nothing either
        a = Solver(offs, Settings(mode=mode)).step(pts, [_sphere(), col])
        b = Solver(offs, Settings(mode=mode)).step(pts, [_sphere()])
        assert np.array_equal(a.points, b.points)
        assert np.array_equal(np.asarray(a.status), np.asarray(b.status))
    col.matrix = scenes.translation([1, 2, 3])
    res = Solver(offs, Settings()).step(pts, [col], growth=col)
    assert np.array_equal(res.points, pts)


def test_zero_curves():
    """An empty curve set is refused (offsets need C+1 >= 2 entries), naming offsets."""
    with pytest.raises(InputError, match=r"offsets.*C\+1 >= 2.*\(1,\)"):
        Solver(np.array([0]), Settings())
