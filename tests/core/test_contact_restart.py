"""A contact pushed back the other way starts again from the input shape.

A curve keeps the axis of its first hit until it has recovered, and a collision only
turns it further about it. A collider arriving from the other side of a curve still
turned would then whip it the long way round, under that collider; instead such a
contact is solved again as a new one from the input shape when that moves the curve
less (``rigid.restart_contacts``). Checked: no pop larger than the colliders' motion
explains, the picture of a fresh solve, the warm start equal to the full search bit
for bit, a curve whose input shape is clear going back to it FREE.
"""

from __future__ import annotations

import numpy as np
import oracle
import pytest
import scenes

from core import Collider, Settings, Solver, Status

_BALL = scenes.uv_sphere((0.0, 0.0, 0.0), 1.0, 32, 16)


def _ball(center, radius=0.3):
    V, F = _BALL
    return Collider(V.astype(np.float32), F, matrix=scenes.affine(t=center, s=radius))


def _other_side_shot():
    """One upright curve (8 CVs, length 1). Ball A (r 0.3) slides in from +x at 0.1 per
    frame, presses the curve toward -x (frames 7-9), and slides back out; ball B slides
    in from -x at 0.1 per frame and stops pressing the curve's other side (from frame 13
    on). Every collider moves by at most 0.1 per frame."""
    def centres(f):
        ax = 1.0 - 0.1 * f if f <= 8 else 0.2 + 0.1 * (f - 8)
        bx = min(-0.25, -1.6 + 0.1 * f)
        return (ax, 0.0, 0.8), (bx, 0.0, 0.8)
    return centres


@pytest.mark.parametrize("plasticity", [0.0, 0.6])
@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_a_collider_from_the_other_side_does_not_whip_the_curve_around(mode, plasticity):
    """Grass trampled from the right, then a second foot from the left: the curve is
    pushed back over by about the rotation a fresh solve needs (a few degrees), not
    swung 40-50 degrees the other way, under the second ball, in a single frame."""
    pts, offs = scenes.pack([scenes.straight_curve([0, 0, 0], [0, 0, 1], 1.0, 8)],
                            np.float32)
    centres = _other_side_shot()
    a, b = _ball(centres(0)[0]), _ball(centres(0)[1])
    solver = Solver(offs, Settings(mode=mode, plasticity=plasticity))
    prev, worst, worst_frame = None, 0.0, -1
    for f in range(22):
        ca, cb = centres(f)
        a.matrix = scenes.affine(t=ca, s=0.3)
        b.matrix = scenes.affine(t=cb, s=0.3)
        res = solver.step(pts, [a, b])
        P = np.asarray(res.points, np.float64)
        if res.status[0] == Status.FREE:  # FREE: exactly the input shape
            assert np.array_equal(res.points, pts), f"frame {f}"
        if prev is not None:
            jump = float(np.linalg.norm(P - prev, axis=1).max())
            if jump > worst:
                worst, worst_frame = jump, f
        prev = P
    # (a collider moves 0.1 per frame; the recovery moves the tip by < 0.05 per frame)
    assert worst <= 0.3, f"a CV jumped {worst:.3f} in one frame (frame {worst_frame})"
    # only ball B touches the curve now: its picture is about a fresh solve's
    assert res.status[0] == Status.COLLIDING
    fresh = Solver(offs, Settings(mode=mode)).step(pts, [b])
    tip, tip_fresh = P[-1], np.asarray(fresh.points, np.float64)[-1]
    assert np.linalg.norm(tip - tip_fresh) <= 0.15, (tip, tip_fresh)


@pytest.mark.parametrize("plasticity", [0.0, 0.6])
@pytest.mark.parametrize("mode", ["stiff", "bend"])
def test_a_contact_started_again_is_the_same_for_the_warm_and_the_full_search(mode, plasticity):
    """The restart depends only on the search's answer: the warm start (default) and the
    full search give the same curves, bit for bit, on every frame of the shot that
    starts contacts again; and no resolved curve crosses a ball."""
    pts, offs = scenes.pack([scenes.straight_curve([x, 0, 0], [0, 0, 1], 1.0, 8)
                             for x in (-0.05, 0.0, 0.05)], np.float32)
    centres = _other_side_shot()
    solvers = {}
    for warm in (True, False):
        solvers[warm] = Solver(offs, Settings(mode=mode, plasticity=plasticity))
        solvers[warm].warm_start = warm
    V, F = _BALL
    for f in range(22):
        out = {}
        for warm, solver in solvers.items():
            cols = [_ball(c) for c in centres(f)]
            out[warm] = solver.step(pts, cols)
        np.testing.assert_array_equal(out[True].points, out[False].points)
        np.testing.assert_array_equal(out[True].status, out[False].status)
        ok = np.isin(np.asarray(out[True].status), [Status.FREE, Status.COLLIDING,
                                                    Status.RECOVERING])
        for c in centres(f):
            Vw = V * 0.3 + np.asarray(c)
            hit = oracle.segments_hit_mesh(np.asarray(out[True].points, np.float64), offs, Vw, F)
            assert not (hit & ok).any(), f"frame {f}: a resolved curve crosses a ball"


@pytest.mark.parametrize("mode", ["stiff", "bend"])
def test_a_contact_pushed_back_past_its_input_shape_returns_to_it_free(mode):
    """Ball A leans the curve over (26 degrees Stiff, 69 Bend); then A is gone and ball
    B fills the space from that lean to far beyond it, but not the upright input: the
    kept axis would turn the curve the long way round past B; the input shape is clear
    and moves it less, so it goes back there (bit for bit) and is FREE, not COLLIDING."""
    pts, offs = scenes.pack([scenes.straight_curve([0.0, 0.0, 0.0], [0, 0, 1], 1.0, 6)])
    V, F = _BALL
    solver = Solver(offs, Settings(mode=mode))
    solver.step(pts, [Collider(V, F, matrix=scenes.affine(t=[0.1, 0.0, 0.7], s=0.4))])
    assert solver.state["angle"][0] > np.radians(20)
    a = np.radians(45.0)
    B = Collider(V, F, matrix=scenes.affine(t=[-0.7 * np.sin(a), 0, 0.7 * np.cos(a)], s=0.3))
    res = solver.step(pts, [B])
    assert np.array_equal(res.points, pts)
    assert res.status[0] == Status.FREE
