"""A collider given its rest shape (``Collider(rest=...)``) whose vertices only
moved rigidly from it (a hat, belt or buckle skinned to one bone: the motion
arrives as vertices) keeps the structures of its rest shape, placed by the fitted
motion (``core.collider.pose``, ``tol.RIGID_FIT_ULPS``).

What it must give, against the rebuilt path (the same collider without a rest
shape: every new shape built, the reference): no curve through the true (given) mesh, and
every curve's segments within one Rotation Precision step of the rebuilt
path's; a collider that truly deforms, even by a hundred-thousandth of its
size, is still rebuilt."""

from __future__ import annotations

import geom
import numpy as np
import pytest
import scenes

from core import Collider, ColliderError, Settings, Solver
from core import tolerances as tol
from core.collider.pose import rigid_fit, ulps_of


def _motion(f, far=0.0):
    """A skinned bone's world matrix at frame ``f`` (turning, sliding, dipping)."""
    R = scenes.rotation_matrix([0.3, 1.0, 0.2], 0.21 * f)
    return scenes.affine(R, t=(far + 0.05 * f, -0.02 * f, 1.0 - 0.035 * f))


def _skinned(V, M):
    """What a float32 skinning gives: a float32 matrix times float32 vertices."""
    M32 = M.astype(np.float32)
    return (V.astype(np.float32) @ M32[:3, :3].T + M32[:3, 3]).astype(np.float32)


def _accessory(kind):
    """(local vertices float32, faces, double_sided): a closed hat-like ball, or an
    open brim-like sheet (double-sided)."""
    if kind == "ball":
        V, F = scenes.uv_sphere([0.05, -0.02, 0.0], 0.35, 24, 12)
        return V.astype(np.float32), F, False
    V, F = scenes.grid(size=1.2, n=12, z=0.0)
    return V.astype(np.float32), F, True


def _play(kind, mode, fit, frames=6, far=0.0, offset=0.0, deform=None):
    """Play the accessory's motion as vertices (``fit``: the rigid fit on or off);
    per frame (points, status, true world vertices), and the collider."""
    V, F, double = _accessory(kind)
    rng = np.random.default_rng(11)
    pts, offs = scenes.fur_on_plane(rng, n_curves=70, curly=0.2, extent=0.6, n_cvs=(3, 8))
    pts = pts + np.array([far, 0.0, 0.0])
    col = Collider(_skinned(V, _motion(0, far)), F, double_sided=double,
                   rest=V if fit else None)
    solver = Solver(offs, Settings(mode=mode, collision_offset=offset, recovery_rate=0.3))
    out = []
    for f in range(frames):
        Vw = _skinned(V, _motion(f, far))
        if deform is not None:
            Vw = deform(Vw, f)
        col.vertices = Vw
        res = solver.step(pts, [col])
        out.append((np.asarray(res.points, np.float64).copy(), np.asarray(res.status).copy(),
                    Vw, col.build_count))
    return out, offs, F, col, pts


def _segment_angles_deg(p, q, offs):
    """Per-segment angle (degrees) between two results of the same curves."""
    starts = np.ones(len(p), bool)
    starts[offs[:-1]] = False  # a segment ends at every point but a root
    a = p[1:] - p[:-1]
    b = q[1:] - q[:-1]
    keep = starts[1:]
    return np.degrees(geom.angle_between(a[keep], b[keep]))


@pytest.mark.parametrize("kind, mode, far, offset", [
    ("ball", "bend", 0.0, 0.0),
    ("ball", "stiff", 0.0, 0.04),
    ("ball", "soft", 0.0, 0.0),
    ("ball", "bend", 100.0, 0.0),
    ("ball", "stiff", 100.0, 0.0),
    ("sheet", "bend", 0.0, 0.02),
])
def test_a_skinned_accessory_gives_the_rebuilt_paths_result_without_rebuilding(kind, mode, far,
                                                                              offset):
    """Rigid motion as vertices: no build after the first frame, 0 crossings
    against the true mesh every frame, every segment within one Rotation Precision
    step of the rebuilt path (which builds every frame).

    Near the origin the two agree to 1e-3 degrees; 100 units away (float32 ulps,
    and so the fit's allowance, 128 times larger) a curve's search may end one
    step apart (the 1 % slack: the step is about an axis through the hit point,
    which moves by a few ulps). Soft mode, whose tip sums the steps of several
    colliding segments, is checked near the origin."""
    fitted, offs, F, col, pts = _play(kind, mode, True, far=far, offset=offset)
    rebuilt, _, _, ref, _ = _play(kind, mode, False, far=far, offset=offset)
    # the rest shape's shell(s), grown by the fit's allowance, built on frame 0 only
    assert fitted[-1][3] == fitted[0][3]
    assert ref.build_count >= len(rebuilt)
    step = Settings().rotation_precision
    touched = 0
    for f, ((p, st, Vw, _), (q, _, _, _)) in enumerate(zip(fitted, rebuilt, strict=True)):
        geom.assert_no_intersection(p, offs, st, [(Vw, F)])
        geom.assert_roots_exact(pts, p, offs)
        ang = _segment_angles_deg(p, q, offs)
        assert ang.max(initial=0.0) <= step * 1.01, (f, ang.max())
        touched += np.count_nonzero(st != 0)
    assert touched > 0  # the accessory did reach the fur


def test_the_fit_is_against_the_rest_shape_so_history_never_matters():
    """A frame's result depends on the rest shape and that frame's placement only:
    reached by playing every frame, by jumping straight to it, after a frame that
    truly deformed, or with the collider constructed at that very frame, the same
    bits."""
    V, F, _ = _accessory("ball")
    rng = np.random.default_rng(4)
    pts, offs = scenes.fur_on_plane(rng, n_curves=50, curly=0.2, extent=0.6, n_cvs=(3, 8))
    s = Settings(mode="bend")
    V0, V5 = _skinned(V, _motion(0)), _skinned(V, _motion(5))

    def frame5(path, first=V0):
        col = Collider(first, F, rest=V)
        for Vw in path:
            col.vertices = Vw
        return Solver(offs, s).step(pts, [col]), col

    played, c1 = frame5([_skinned(V, _motion(f)) for f in range(1, 6)])
    jumped, c2 = frame5([V5])
    squashed = _skinned(V, _motion(3)) * np.float32([1.0, 1.0, 0.9])
    after, c3 = frame5([_skinned(V, _motion(2)), squashed, V5])
    built_there, c4 = frame5([], first=V5)
    for r in (jumped, after, built_there):
        np.testing.assert_array_equal(r.points, played.points)
        np.testing.assert_array_equal(r.status, played.status)
    assert [c.build_count for c in (c1, c2, c3, c4)] == [1, 1, 1, 1]
    # the squashed frame a new shape, then the rest shape again (built again once)
    assert (c1.mesh.version, c3.mesh.version, c4.mesh.version) == (0, 2, 0)
    assert c4.version == 0 and c4.previous is None


def _two_parts():
    """A hat and a body in one mesh (two connected parts), local float32."""
    Va, Fa = scenes.uv_sphere([0.0, 0.0, 0.0], 0.3, 16, 8)
    Vb, Fb = scenes.uv_sphere([0.9, 0.0, 0.0], 0.3, 16, 8)
    V = np.concatenate([Va, Vb]).astype(np.float32)
    F = np.concatenate([Fa, Fb + len(Va)])
    return V, F, len(Va)


def test_a_part_that_truly_deforms_is_rebuilt_every_frame_with_the_rebuilt_paths_bits():
    """One part moves rigidly, the other breathes: the collider is rebuilt every
    frame, and gives exactly what the rebuilt path gives."""
    V, F, na = _two_parts()

    def deform(Vw, f):
        out = Vw.copy()
        c = out[na:].mean(axis=0)
        out[na:] = c + (out[na:] - c) * np.float32(1.0 + 0.05 * f)
        return out

    results = {}
    for fit in (True, False):
        col = Collider(V, F, rest=V if fit else None)
        rng = np.random.default_rng(2)
        pts, offs = scenes.fur_on_plane(rng, n_curves=40, curly=0.2, extent=1.2, n_cvs=(3, 6))
        solver = Solver(offs, Settings(mode="bend"))
        got = []
        for f in range(1, 5):
            Vw = deform(_skinned(V, _motion(f)), f)
            col.vertices = Vw
            res = solver.step(pts, [col])
            geom.assert_no_intersection(res.points, offs, res.status, [(Vw, F)])
            got.append(np.asarray(res.points).copy())
        results[fit] = (got, col.build_count)
    assert results[True][1] == results[False][1] == 4  # every frame played
    for a, b in zip(results[True][0], results[False][0], strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("scale", [1.0 + 2e-5, 1.0 - 2e-5])
def test_a_deformation_of_a_fifty_thousandth_of_the_coordinates_is_rebuilt(scale):
    """A scale that moves vertices by 2e-5 of the coordinates (more than
    ``tol.RIGID_FIT_ULPS`` float32 ulps of them) is a deformation: a new shape."""
    V, F, _ = _accessory("ball")
    col = Collider(V, F, rest=V)
    col.vertices = _skinned(V * np.float32(scale), _motion(2))
    assert col.pose.shape.fit is None and col.pose.allowance == 0.0
    assert col.mesh.version == 1
    col.vertices = _skinned(V, _motion(3))  # rigid again: the rest shape's structures
    assert col.pose.shape.fit is not None and col.mesh.version == 2


def test_the_fit_accepts_residuals_within_the_tolerance_and_refuses_above():
    """``rigid_fit``: a rigid motion plus noise well inside ``tol.RIGID_FIT_ULPS``
    float32 ulps is fitted, its allowance covers the noise and stays within the
    tolerance; noise a few times the tolerance is refused."""
    V, F, _ = _accessory("ball")
    M = _motion(3)
    Vw = (V.astype(np.float64) @ M[:3, :3].T + M[:3, 3])
    lo = V.min(axis=0).astype(np.float64)
    hi = V.max(axis=0).astype(np.float64)
    r = max(float(np.abs(Vw).max()) + float(np.linalg.norm(hi - lo)), float(np.abs(lo).max()),
            float(np.abs(hi).max()), float(np.linalg.norm(hi - lo)))
    limit = tol.RIGID_FIT_ULPS * ulps_of(r)
    rng = np.random.default_rng(0)
    d = rng.normal(size=V.shape)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    small = (Vw + 0.2 * limit * d).astype(np.float32)
    fit = rigid_fit(V, small, None, lo, hi)
    assert fit is not None
    T, allowance = fit
    moved = V.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    off = np.linalg.norm(moved - small, axis=1).max()
    assert off <= allowance <= tol.RIGID_FIT_ULPS * ulps_of(2.0 * r)
    assert allowance <= 2.0 * off  # the residual rounded up to a power of two ulps
    np.testing.assert_allclose(T[:3, :3], M[:3, :3], atol=1e-5)
    assert rigid_fit(V, (Vw + 4.0 * limit * d).astype(np.float32), None, lo, hi) is None


def test_the_fit_tolerance_is_a_stated_tolerance():
    """The fit tolerance lives in ``core/tolerances.py`` (with its reason) and
    switches the fit off at 0."""
    assert isinstance(tol.RIGID_FIT_ULPS, int) and tol.RIGID_FIT_ULPS > 0
    assert tol.RIGID_FIT_SAMPLE >= 16


def test_velocities_of_a_fitted_placement_are_those_of_the_same_motion_as_a_matrix():
    """Follow Collider Motion: the surface velocity of a skinned accessory is that
    of the same motion given as a matrix (to float32 precision)."""
    V, F, _ = _accessory("ball")
    by_vertices = Collider(_skinned(V, _motion(1)), F, rest=V)
    by_matrix = Collider(V, F, matrix=_motion(1))
    by_vertices.place(vertices=_skinned(V, _motion(2)))
    by_matrix.place(matrix=_motion(2))
    assert by_vertices.pose.shape.fit is not None
    M = _motion(2)
    p = (V[::7].astype(np.float64) * 1.1) @ M[:3, :3].T + M[:3, 3]
    np.testing.assert_allclose(by_vertices.velocities(p), by_matrix.velocities(p), atol=2e-5)
    np.testing.assert_array_equal(by_vertices.vertices, _skinned(V, _motion(2)))
    np.testing.assert_array_equal(by_vertices.previous.vertices, _skinned(V, _motion(1)))


def test_without_a_rest_shape_every_new_shape_is_built():
    """No rest shape: rigid motion as vertices is built every frame (no fit), as
    before; the rest shape must have the collider's topology."""
    V, F, _ = _accessory("ball")
    col = Collider(_skinned(V, _motion(0)), F)
    for f in range(1, 4):
        col.vertices = _skinned(V, _motion(f))
        assert col.pose.shape.fit is None and col.mesh.version == f
    with pytest.raises(ColliderError, match="vertices have shape"):
        Collider(V[:-1], F, rest=V)
