"""recovery_rate and plasticity (paper 3.2.3-3.2.4), measured on the angle."""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes

from core import Collider, Settings, Solver, Status

PREC = 0.25


def _setup():
    curve = scenes.curly_curve([0, 0, 0], [0, 0, 1], 1.0, 7, amplitude=0.12, turns=0.8)
    pts, offs = scenes.pack([curve])
    V, F = scenes.uv_sphere([0.15, 0.0, 0.85], 0.3, 32, 16)
    V2, F2 = scenes.uv_sphere([0.1, 0.0, 0.7], 0.35, 32, 16)  # pushes further
    return pts, offs, Collider(V, F), Collider(V2, F2)


def _angle_deg(pts, out):
    return np.degrees(geom.rigid_angle(np.diff(pts, axis=0), np.diff(out, axis=0))[0])


@pytest.mark.parametrize("rate", [0.1, 0.3, 0.5, 0.9])
def test_recovery_rate_geometric_decay(rate):
    pts, offs, col, _ = _setup()
    solver = Solver(offs, Settings(mode="stiff", recovery_rate=rate, rotation_precision=PREC))
    r = solver.step(pts, [col])
    theta = _angle_deg(pts, r.points)
    assert np.asarray(r.status)[0] == Status.COLLIDING and theta > 5
    for _ in range(500):
        r = solver.step(pts, [])
        new = _angle_deg(pts, r.points)
        expect = theta * (1 - rate)
        if expect < PREC / 2:
            assert np.array_equal(r.points, pts)
            break
        assert new == pytest.approx(expect, abs=1e-7), (theta, new)
        assert np.asarray(r.status)[0] == Status.RECOVERING
        theta = new
    else:
        pytest.fail("never recovered")
    # stays put afterwards
    r = solver.step(pts, [])
    assert np.array_equal(r.points, pts) and np.asarray(r.status)[0] == Status.FREE


def test_recovery_rate_zero_keeps_the_rotation():
    pts, offs, col, _ = _setup()
    solver = Solver(offs, Settings(mode="stiff", recovery_rate=0.0))
    r1 = solver.step(pts, [col])
    assert np.asarray(r1.status)[0] == Status.COLLIDING
    for _ in range(5):
        r = solver.step(pts, [])
        np.testing.assert_allclose(r.points, r1.points, atol=1e-12)


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_recovery_stops_where_it_would_collide(mode):
    """Collider stays: recovery must not move the curve back into it; the
    curve stays where it was (no oscillation between frames)."""
    pts, offs, col, _ = _setup()
    solver = Solver(offs, Settings(mode=mode, recovery_rate=0.5))
    r1 = solver.step(pts, [col])
    V = oracle.transform(col.vertices, col.matrix)
    for _ in range(4):
        r = solver.step(pts, [col])
        assert not oracle.segments_hit_mesh(r.points, offs, V, col.faces)[0]
        np.testing.assert_allclose(r.points, r1.points, atol=1e-9)
        assert np.asarray(r.status)[0] == Status.COLLIDING


def test_partial_recovery_when_collider_backs_off():
    """The collider moves away a bit: the curve recovers part of the way but
    never into the collider, and never past its input."""
    pts, offs, col, _ = _setup()
    solver = Solver(offs, Settings(mode="stiff", recovery_rate=0.5))
    r = solver.step(pts, [col])
    theta = _angle_deg(pts, r.points)
    for f in range(1, 15):
        col.matrix = scenes.translation([0.02 * f, 0, 0.01 * f])
        r = solver.step(pts, [col])
        V = oracle.transform(col.vertices, col.matrix)
        assert not oracle.segments_hit_mesh(r.points, offs, V, col.faces)[0]
        new = _angle_deg(pts, r.points)
        assert new <= theta + 1e-9
        theta = new


@pytest.mark.parametrize("p", [0.0, 0.25, 0.5, 1.0])
def test_plasticity_target_is_fraction_of_max_angle(p):
    pts, offs, col, col2 = _setup()
    solver = Solver(offs, Settings(mode="stiff", recovery_rate=1.0, plasticity=p,
                                   rotation_precision=PREC))
    t1 = _angle_deg(pts, solver.step(pts, [col]).points)
    r2 = solver.step(pts, [col2])
    t2 = _angle_deg(pts, r2.points)
    assert t2 > t1 + 1  # the second collider pushes further: new maximum
    r = solver.step(pts, [])
    target = p * t2
    if target < PREC / 2:
        assert np.array_equal(r.points, pts)
    else:
        assert _angle_deg(pts, r.points) == pytest.approx(target, abs=1e-7)
    # the imprint is permanent: more frames change nothing
    r_again = solver.step(pts, [])
    np.testing.assert_allclose(r_again.points, r.points, atol=1e-12)
    if p == 1.0:
        np.testing.assert_allclose(r.points, r2.points, atol=1e-12)


@pytest.mark.parametrize(("rate", "p"), [(0.3, 0.5), (0.5, 0.25)])
def test_partial_recovery_toward_a_plastic_target_per_frame(rate, p):
    """README: each frame the angle moves ``recovery_rate`` of the way to the target
    ``plasticity * largest angle``, and lands on it within half a precision step."""
    pts, offs, col, _ = _setup()
    solver = Solver(offs, Settings(mode="stiff", recovery_rate=rate, plasticity=p,
                                   rotation_precision=PREC))
    theta = _angle_deg(pts, solver.step(pts, [col]).points)
    target = p * theta
    for _ in range(100):
        new = _angle_deg(pts, solver.step(pts, []).points)
        expect = theta - rate * (theta - target)
        if expect - target < PREC / 2:
            assert new == pytest.approx(target, abs=1e-7)
            break
        assert new == pytest.approx(expect, abs=1e-7), (theta, new, target)
        theta = new
    else:
        pytest.fail("never reached the target")


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_plasticity_one_keeps_max_rotation(mode):
    pts, offs, col, _ = _setup()
    solver = Solver(offs, Settings(mode=mode, recovery_rate=0.4, plasticity=1.0))
    r1 = solver.step(pts, [col])
    assert np.asarray(r1.status)[0] == Status.COLLIDING
    for _ in range(10):
        r = solver.step(pts, [])
        np.testing.assert_allclose(r.points, r1.points, atol=1e-9)


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_plasticity_half_converges_between(mode):
    pts, offs, col, _ = _setup()
    solver = Solver(offs, Settings(mode=mode, recovery_rate=0.5, plasticity=0.5))
    r1 = solver.step(pts, [col])
    d1 = np.linalg.norm(r1.points[-1] - pts[-1])
    for _ in range(60):
        r = solver.step(pts, [])
    d = np.linalg.norm(r.points[-1] - pts[-1])
    assert 0.25 * d1 < d < 0.75 * d1
    if mode == "stiff":
        assert _angle_deg(pts, r.points) == pytest.approx(0.5 * _angle_deg(pts, r1.points),
                                                          abs=PREC / 2 + 1e-7)


def test_collision_overrides_recovery_then_recovers():
    pts, offs, col, _ = _setup()
    solver = Solver(offs, Settings(mode="bend", recovery_rate=1.0))
    seen = []
    for f in range(6):
        cols = [col] if f in (0, 1, 3) else []
        r = solver.step(pts, cols)
        seen.append(int(np.asarray(r.status)[0]))
        if not cols:
            assert np.array_equal(r.points, pts)
    assert seen[0] == Status.COLLIDING and seen[3] == Status.COLLIDING


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
@pytest.mark.parametrize("rate", [0.1, 0.5])
def test_recovery_is_gradual_and_monotone_per_segment(mode, rate):
    """After the collider leaves, every segment's angle to its input shrinks
    monotonically, none starts turning, and recovery takes about
    log(precision / angle) / log(1 - rate) frames, not one or two."""
    pts, offs, col, _ = _setup()
    solver = Solver(offs, Settings(mode=mode, recovery_rate=rate, rotation_precision=PREC))
    r = solver.step(pts, [col])
    seg_in = np.diff(pts, axis=0)
    prev = np.degrees(geom.angle_between(seg_in, np.diff(r.points, axis=0)))
    assert prev.max() > 5
    start = prev.max()
    frames = 0
    while not np.array_equal(r.points, pts):
        r = solver.step(pts, [])
        frames += 1
        ang = np.degrees(geom.angle_between(seg_in, np.diff(r.points, axis=0)))
        assert np.all(ang <= prev + 1e-9), f"frame {frames}: segment angles {prev} -> {ang}"
        assert np.all(ang >= (1 - rate) * prev - PREC - 1e-9), (
            f"frame {frames}: recovered faster than rate {rate}: {prev} -> {ang}")
        prev = ang
        assert frames < 500
    expected = np.log((PREC / 2) / start) / np.log(1 - rate)
    assert frames >= 0.5 * expected, (frames, expected)


def _slightly_bent_setup():
    n = 6
    z = np.linspace(0, 1, n)
    pts = np.stack([0.02 * z**2, np.zeros(n), z], 1)
    V, F = scenes.uv_sphere([0.15, 0.0, 0.85], 0.3, 24, 12)
    return pts, np.array([0, n]), Collider(V, F)


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
@pytest.mark.parametrize("scene", ["curly", "slightly-bent"])
def test_recovery_rate_zero_holds_every_mode(mode, scene):
    if scene == "curly":
        pts, offs, col, _ = _setup()
    else:
        pts, offs, col = _slightly_bent_setup()
    solver = Solver(offs, Settings(mode=mode, recovery_rate=0.0))
    r1 = solver.step(pts, [col])
    assert np.asarray(r1.status)[0] == Status.COLLIDING
    for f in range(3):
        r = solver.step(pts, [])
        np.testing.assert_allclose(r.points, r1.points, atol=1e-12, err_msg=f"frame {f + 2}")
        # nothing is rotating back: not RECOVERING
        assert np.asarray(r.status)[0] != Status.RECOVERING, f"frame {f + 2}"


def test_recovery_follows_animated_input():
    """The growth surface moves (input curves rotate and translate rigidly):
    recovery still decays the angle relative to the *current* input."""
    pts, offs, col, _ = _setup()
    rate = 0.3
    solver = Solver(offs, Settings(mode="stiff", recovery_rate=rate, rotation_precision=PREC))
    r = solver.step(pts, [col])
    theta = _angle_deg(pts, r.points)
    assert theta > 5
    for f in range(1, 40):
        R = scenes.rotation_matrix([0.2, 1.0, 0.3], 0.05 * f)
        moved = pts @ R.T + [0.02 * f, -0.01 * f, 0.0]
        r = solver.step(moved, [])
        expect = theta * (1 - rate)
        if expect < PREC / 2:
            assert np.array_equal(r.points, moved)
            return
        assert _angle_deg(moved, r.points) == pytest.approx(expect, abs=1e-6)
        theta = expect
    pytest.fail("never recovered")


def test_soft_lands_on_its_plastic_target():
    """Soft: each frame every segment goes ``recovery_rate`` of the way to its
    plastic target and, within half a precision step of it, lands on it (README
    Recovery Rate): the steps shrink by ``1 - recovery_rate`` until one takes the
    whole rest, and the curve then keeps that shape (the imprint)."""
    pts, offs, col, _ = _setup()
    rate = 0.5
    solver = Solver(offs, Settings(mode="soft", recovery_rate=rate, plasticity=0.5,
                                   rotation_precision=PREC))
    prev = solver.step(pts, [col]).points
    moves = []
    for _ in range(20):
        r = solver.step(pts, [])
        moves.append(float(np.abs(r.points - prev).max()))
        prev = r.points
    moves = np.array(moves)
    landed = int(np.argmax(moves < 1e-12))
    assert 3 < landed <= 12, moves
    assert (moves[landed:] < 1e-12).all(), moves
    # until the landing, each move is (1 - rate) of the one before (a slerp toward
    # a fixed target); the landing step takes the whole rest (at least as much)
    ratio = moves[1:landed - 1] / moves[: landed - 2]
    np.testing.assert_allclose(ratio[2:], 1 - rate, rtol=0.05)
    assert moves[landed - 1] >= 0.9 * (1 - rate) * moves[landed - 2]
    assert not np.array_equal(prev, pts)  # the imprint: not back at the input


def test_half_a_step_from_rest_is_kept_below_it_lands_on_rest():
    """Recovery lands on exactly zero *below* half a Rotation Precision step
    (``tol.SNAP_FRACTION``): a curve turned one step recovers at Recovery Rate 0.5 to
    exactly half a step (still RECOVERING), then to zero (FREE)."""

    V, F = scenes.uv_sphere((0.0, 0.0, 0.0), 1.0, 32, 16)
    pts, offs = scenes.pack([scenes.straight_curve([0, 0, 0], [0, 0, 1], 1.0, 8)], np.float32)
    p = np.deg2rad(1.0)
    s = Solver(offs, Settings(mode="stiff", recovery_rate=0.5, rotation_precision=1.0))
    col = Collider(V.astype(np.float32), F, matrix=scenes.affine(t=(0.2, 0.0, 1.0), s=0.2))
    s.step(pts, [col])
    assert s.state["angle"][0] == p  # one step
    col.matrix = scenes.affine(t=(5.0, 0.0, 1.0), s=0.2)  # gone
    res = s.step(pts, [col])
    assert s.state["angle"][0] == 0.5 * p and res.status[0] == Status.RECOVERING
    res = s.step(pts, [col])
    assert s.state["angle"][0] == 0.0 and res.status[0] == Status.FREE
    np.testing.assert_array_equal(res.points, pts)
