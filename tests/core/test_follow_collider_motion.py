"""Follow Collider Motion (``Settings.follow_collider_motion``): fur pushed by a
moving collider lays over the way the collider moves at the contact.

A ball rolling through a field of straight grass blades: the blades it starts to
push lean along its velocity at the contact point (the mean cosine between each
blade's tip displacement on the ground and that velocity on the ground is above
0.8), with no blade crossing it (oracle); a hand (plate) stroking fur lays it
along the stroke. Where the collider does not move (still, or no previous
placement known) the result is the paper's, bit for bit. The axis is kept until
the curve has recovered (no pop when the collider stops), the thread count never
changes a bit, and a solver restored from ``Solver.state`` with the collider's
previous placement continues as playback did.
"""

from __future__ import annotations

import contextlib

import numpy as np
import oracle
import pytest
import scenes
from geom import EXCLUDED

import core.step
from core import Collider, Settings, Solver, Status

MODES = ("stiff", "bend", "soft")
R, Z, SPEED = 0.5, 0.7, 0.08  # the ball: radius, centre height, distance per frame


def _grass(n=20, length=1.0, cvs=6):
    """``n`` x ``n`` straight vertical blades over [-1.5, 1.5] x [-0.75, 0.75]."""
    g = (np.arange(n) + 0.5) / n
    X, Y = np.meshgrid(-1.5 + 3.0 * g, -0.75 + 1.5 * g, indexing="ij")
    return scenes.pack([scenes.straight_curve([x, y, 0.0], [0, 0, 1.0], length, cvs)
                        for x, y in zip(X.ravel(), Y.ravel(), strict=True)])


def _rolling(f, heading=(1.0, 0.0)):
    """The ball's world matrix at frame ``f``: rolling without slipping along
    ``heading`` (a unit ground direction) from x = -1.6."""
    h = np.array([heading[0], heading[1], 0.0])
    centre = np.array([-1.6, 0.0, Z]) + SPEED * f * h
    spin = np.cross([0.0, 0.0, 1.0], h)  # rolling: the top moves along the heading
    return scenes.affine(R=scenes.rotation_matrix(spin, SPEED * f / R), t=centre, s=R)


def _ball_velocity(M0, M1, p):
    """Independent of the core: the velocity of the ball's material point now at
    ``p`` (k, 3) from placement ``M0`` to ``M1``."""
    x = (p - M1[:3, 3]) @ np.linalg.inv(M1[:3, :3]).T
    return p - (x @ M0[:3, :3].T + M0[:3, 3])


def _first_contact(root, M):
    """Where a vertical blade at ``root`` first meets the ball (world matrix ``M``,
    unit sphere): the lower crossing of its line with the sphere."""
    c, r = M[:3, 3], np.linalg.norm(M[:3, 0])
    rho2 = ((root[:, :2] - c[:2]) ** 2).sum(1)
    z = c[2] - np.sqrt(np.maximum(r * r - rho2, 0.0))
    return np.column_stack([root[:, :2], np.maximum(z, 0.0)])


def _uv_ball():
    return scenes.uv_sphere([0, 0, 0], 1.0, 32, 16)


def _roll(mode, follow, frames=16, n=20, threads=None, attract=False, still=False,
          deforming=False, forget=False):
    """Roll the ball through the grass; per frame (points, status); the blades
    that start a contact at each frame; the final solver."""
    pts, offs = _grass(n)
    V, F = _uv_ball()
    Vg, Fg = scenes.grid(size=6.0, n=4, z=0.0)
    s = Settings(mode=mode, follow_collider_motion=follow, threads=threads,
                 attract_to_growth_surface=attract)
    M0 = _rolling(4 if still else 0)
    col = Collider(V, F, matrix=None if deforming else M0)
    if deforming:
        col.vertices = oracle.transform(V, M0)
    solver = Solver(offs, s)
    out, new, prev = [], [], np.zeros(len(offs) - 1, int)
    for f in range(1, frames + 1):
        M = _rolling(4 if still else f)
        if deforming:
            col.place(vertices=oracle.transform(V, M))
        else:
            col.place(matrix=M)
        if forget:
            col.forget_previous()
        res = solver.step(pts, [col], growth=Collider(Vg, Fg) if attract else None)
        st = np.asarray(res.status).copy()
        out.append((res.points.copy(), st))
        new.append(np.flatnonzero((st == Status.COLLIDING) & (prev == Status.FREE)))
        prev = st
    return pts, offs, out, new, solver


def _lean_cosines(pts, offs, out, new, frames_of=_rolling):
    """Cosine between each new contact's tip displacement on the ground and the
    ball's velocity at its first contact point on the ground."""
    tips, roots = offs[1:] - 1, offs[:-1]
    cos = []
    for f, (res, idx) in enumerate(zip(out, new, strict=True), start=1):
        if len(idx) == 0:
            continue
        M0, M1 = frames_of(f - 1), frames_of(f)
        v = _ball_velocity(M0, M1, _first_contact(pts[roots[idx]], M1))[:, :2]
        d = (res[0][tips[idx]] - pts[tips[idx]])[:, :2]
        cos.append(np.einsum("ij,ij->i", d, v)
                   / (np.linalg.norm(d, axis=1) * np.linalg.norm(v, axis=1)))
    return np.concatenate(cos)


def _assert_no_crossing(offs, out, frames_of=_rolling):
    V, F = _uv_ball()
    for f, (p, st) in enumerate(out, start=1):
        bad = oracle.curves_crossing(p, offs, [(oracle.transform(V, frames_of(f)), F)],
                                     select=~np.isin(st, EXCLUDED))
        assert len(bad) == 0, f"frame {f}: curves {bad[:10]} cross the ball"


def _assert_same(a, b, what):
    for f, ((pa, sa), (pb, sb)) in enumerate(zip(a, b, strict=True), start=1):
        assert np.array_equal(sa, sb), f"{what}: status differs at frame {f}"
        assert pa.tobytes() == pb.tobytes(), f"{what}: points differ at frame {f}"


# ----------------------------------------------------------- rolling ball
@pytest.mark.parametrize("mode", MODES)
def test_rolling_ball_lays_blades_along_its_motion(mode):
    pts, offs, out, new, _ = _roll(mode, True)
    cos = _lean_cosines(pts, offs, out, new)
    assert len(cos) >= 100
    assert cos.mean() > 0.8, cos.mean()
    _assert_no_crossing(offs, out)
    # the paper's direction (away along the normal) is another one
    pts, offs, out0, new0, _ = _roll(mode, False)
    assert _lean_cosines(pts, offs, out0, new0).mean() < cos.mean() - 0.1
    _assert_no_crossing(offs, out0)


def test_rolling_ball_heading_sideways():
    """The same along another heading: the blades follow it, not the x axis."""
    heading = (np.sqrt(0.5), np.sqrt(0.5))

    def frames_of(f):
        return _rolling(f, heading)

    pts, offs = _grass()
    V, F = _uv_ball()
    col = Collider(V, F, matrix=frames_of(0))
    solver = Solver(offs, Settings(mode="bend", follow_collider_motion=True))
    out, new, prev = [], [], np.zeros(len(offs) - 1, int)
    for f in range(1, 13):
        col.place(matrix=frames_of(f))
        res = solver.step(pts, [col])
        st = np.asarray(res.status).copy()
        out.append((res.points.copy(), st))
        new.append(np.flatnonzero((st == Status.COLLIDING) & (prev == Status.FREE)))
        prev = st
    cos = _lean_cosines(pts, offs, out, new, frames_of)
    assert len(cos) >= 50 and cos.mean() > 0.8, cos.mean()
    _assert_no_crossing(offs, out, frames_of)


def test_deforming_ball_is_followed_too():
    """The ball moved by its vertices (a deforming collider, no matrix)."""
    pts, offs, out, new, _ = _roll("bend", True, deforming=True)
    cos = _lean_cosines(pts, offs, out, new)
    assert len(cos) >= 100 and cos.mean() > 0.8, cos.mean()
    _assert_no_crossing(offs, out)


def test_attract_and_follow_moving_ball_follows():
    pts, offs, out, new, _ = _roll("bend", True, attract=True, frames=10)
    cos = _lean_cosines(pts, offs, out, new)
    assert len(cos) >= 50 and cos.mean() > 0.8, cos.mean()
    _assert_no_crossing(offs, out)


# ---------------------------------------------- no motion: the paper's bits
@pytest.mark.parametrize("mode", MODES)
def test_still_ball_gives_the_paper_bits(mode):
    """A ball placed every frame where it was (velocity exactly zero), or a moving
    one whose previous placement is unknown: follow on = follow off, bit for bit."""
    _, _, ref, _, _ = _roll(mode, False, still=True, frames=4)
    _, offs, got, _, _ = _roll(mode, True, still=True, frames=4)
    assert sum(int((st == Status.COLLIDING).sum()) for _, st in ref) >= 30
    _assert_same(got, ref, f"{mode}: still ball")
    _assert_no_crossing(offs, got, lambda f: _rolling(4))
    _, _, ref, _, _ = _roll(mode, False, frames=5)
    _, _, got, _, _ = _roll(mode, True, frames=5, forget=True)
    _assert_same(got, ref, f"{mode}: no previous placement")


def test_still_ball_with_attract_gives_the_attract_bits():
    _, _, ref, _, _ = _roll("stiff", False, attract=True, still=True, frames=3)
    _, _, got, _, _ = _roll("stiff", True, attract=True, still=True, frames=3)
    _assert_same(got, ref, "still ball, attract")


# --------------------------------------------------------------- stroking
@pytest.mark.parametrize("mode", MODES)
def test_stroking_hand_lays_fur_along_the_stroke(mode):
    """A plate pressed on vertical fur (its normal along the blades: the paper's
    direction is then a fixed perpendicular, +x here) and moved along ``u``: every
    blade lays over along ``u``. Then the hand stops, still pressing: the blades
    keep their axis (no pop to the paper's direction) until they recover."""
    pts, offs = _grass(12, length=0.6)
    tips = offs[1:] - 1
    Vp, Fp = scenes.grid(size=6.0, n=8, z=0.0)
    u = np.array([-0.6, 0.8, 0.0])

    def hand(t):
        return scenes.affine(t=t * u + [0.0, 0.0, 0.45])

    def lean(res):
        d = (res.points[tips] - pts[tips])[:, :2]
        return d @ u[:2] / np.linalg.norm(d, axis=1), d

    for follow in (False, True):
        col = Collider(Vp, Fp, matrix=hand(-0.1))
        solver = Solver(offs, Settings(mode=mode, follow_collider_motion=follow))
        col.place(matrix=hand(0.0))
        res = solver.step(pts, [col])
        assert (np.asarray(res.status) == Status.COLLIDING).all()
        cos, d = lean(res)
        if not follow:
            assert cos.mean() < 0.0, cos.mean()  # (the paper's: +x)
    assert cos.min() > 0.95, cos.min()
    axes = solver.state["axis"].copy() if mode != "soft" else None
    for _ in range(3):  # the hand stays (zero velocity): nothing pops
        col.place(matrix=hand(0.0))
        res = solver.step(pts, [col])
        assert (np.asarray(res.status) == Status.COLLIDING).all()
        _, e = lean(res)  # (recovery may settle it a step lower)
        cos = np.einsum("ij,ij->i", d, e) / (np.linalg.norm(d, axis=1)
                                             * np.linalg.norm(e, axis=1))
        assert cos.min() > 0.99, cos.min()
        if axes is not None:  # the same axis, kept in the curve's local frame
            assert solver.state["axis"].tobytes() == axes.tobytes()
    _assert_no_crossing_plate(res.points, offs, Vp, Fp, hand(0.0), np.asarray(res.status))


def _assert_no_crossing_plate(p, offs, V, F, M, st):
    bad = oracle.curves_crossing(p, offs, [(oracle.transform(V, M), F)],
                                 select=~np.isin(st, EXCLUDED))
    assert len(bad) == 0, bad


# ------------------------------------------------- threads, state, restore
@contextlib.contextmanager
def _split_from(n):
    old = core.tolerances.SPLIT_MIN_CURVES
    core.tolerances.SPLIT_MIN_CURVES = n
    try:
        yield
    finally:
        core.tolerances.SPLIT_MIN_CURVES = old


@pytest.mark.parametrize("mode", MODES)
def test_thread_count_never_changes_a_bit(mode):
    """Threads 1 and 2, and steps solved in two halves on two threads."""
    _, _, ref, _, s1 = _roll(mode, True, frames=8, threads=1)
    _, _, two, _, s2 = _roll(mode, True, frames=8, threads=2)
    _assert_same(two, ref, f"{mode}: threads=2")
    with _split_from(50):
        _, _, half, _, s3 = _roll(mode, True, frames=8, threads=2)
    _assert_same(half, ref, f"{mode}: split in halves")
    for k, a in s1.state.items():
        assert a.tobytes() == s2.state[k].tobytes() == s3.state[k].tobytes(), k


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("how", ["place", "set_previous"])
def test_restored_state_and_previous_placement_continue_as_playback(mode, how):
    """Playback to frame 12; a fresh solver and collider resumed after frame 6 from
    ``Solver.state`` (saved with the new setting) and the collider's previous
    placement (placed at frame 6 then moved on, or set explicitly) give the same
    frames 7-12, bit for bit."""
    pts, offs, ref, _, _ = _roll(mode, True, frames=12)
    V, F = _uv_ball()
    s = Settings(mode=mode, follow_collider_motion=True)
    solver = Solver(offs, s)
    col = Collider(V, F, matrix=_rolling(0))
    for f in range(1, 7):
        col.place(matrix=_rolling(f))
        solver.step(pts, [col])
    snap = {k: v.copy() for k, v in solver.state.items()}
    fresh = Solver(offs, s)
    fresh.state = snap
    if how == "place":
        col2 = Collider(V, F, matrix=_rolling(6))
    else:
        col2 = Collider(V, F, matrix=_rolling(7))
        col2.set_previous(matrix=_rolling(6))
    for f in range(7, 13):
        if how == "place" or f > 7:
            col2.place(matrix=_rolling(f))
        res = fresh.step(pts, [col2])
        assert np.array_equal(np.asarray(res.status), ref[f - 1][1]), f"frame {f}"
        assert res.points.tobytes() == ref[f - 1][0].tobytes(), f"frame {f}"
