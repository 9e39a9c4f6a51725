"""max_angle lowered mid-shot: the next frame steps from the cached state with the new
setting (``StepContext.load_state`` starts a curve turned further than the new Max Angle
from it). The warm start and the full search still agree bit for bit, and no curve
reported COLLIDING is turned further than the new Max Angle."""

from __future__ import annotations

import numpy as np
import pytest
import scenes

from core import Collider, Settings, Solver, Status

_BALL = scenes.uv_sphere((0.0, 0.0, 0.0), 1.0, 32, 16)


def _sweep(f):
    t = f / 40
    return scenes.affine(t=(-0.6 + 1.2 * t, 0.0, 0.75 - 0.2 * np.sin(np.pi * t)), s=0.35)


def _fur_grid(n=10, ext=0.6, length=0.6, ncv=8):
    xs = np.linspace(-ext, ext, n)
    curves = [scenes.straight_curve([x, y, 0.0], [0.15 * x, 0.1 * y, 1.0], length, ncv)
              for x in xs for y in xs]
    return scenes.pack(curves, np.float32)


def _state_before_max_angle_change(mode):
    """Play a ball pressing into a fur patch 25 frames (Max Angle 180), then
    snapshot: the artist lowers Max Angle to 60 here and plays on."""
    pts, offs = _fur_grid()
    V, F = _BALL
    col = Collider(V.astype(np.float32), F)
    solver = Solver(offs, Settings(mode=mode))
    for f in range(25):
        col.matrix = _sweep(f)
        solver.step(pts, [col])
    col.matrix = _sweep(25)
    return pts, offs, col, solver.state


@pytest.mark.parametrize("mode", ["stiff", "bend"])
def test_lowering_max_angle_mid_shot_warm_start_equals_full_search(mode):
    """README: the warm start's result is bit-identical to the full search from the same
    state, also after Max Angle is lowered mid-shot (a setting changed during playback:
    the next frame steps from the cached state with the new settings)."""
    pts, offs, col, snap = _state_before_max_angle_change(mode)
    out = {}
    for warm in (True, False):
        s = Solver(offs, Settings(mode=mode, max_angle=60.0))
        s.state = snap
        s.warm_start = warm
        out[warm] = s.step(pts, [col])
    np.testing.assert_array_equal(out[True].status, out[False].status)
    np.testing.assert_array_equal(out[True].points, out[False].points)


def test_lowering_max_angle_mid_shot_no_colliding_curve_beyond_it():
    """Max Angle is the largest rotation before a curve counts as unresolvable (Bend: of
    the tip segment). After it is lowered to 60 degrees mid-shot, a curve reported
    COLLIDING has its tip segment turned by at most 60 degrees (plus a precision step)."""
    pts, offs, col, snap = _state_before_max_angle_change("bend")
    s = Solver(offs, Settings(mode="bend", max_angle=60.0))
    s.state = snap
    res = s.step(pts, [col])
    P, I = np.asarray(res.points, np.float64), pts.astype(np.float64)
    a = I[offs[1:] - 1] - I[offs[1:] - 2]
    b = P[offs[1:] - 1] - P[offs[1:] - 2]
    cos = np.einsum("ij,ij->i", a, b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    turn = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    colliding = np.asarray(res.status) == Status.COLLIDING
    over = np.flatnonzero(colliding & (turn > 60.0 + 0.5))
    assert len(over) == 0, f"COLLIDING curves {over.tolist()} turned {turn[over].round(1)} deg"
