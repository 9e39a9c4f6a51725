"""One frame of a shot from plain arrays (``core.pipeline.Shot``, ``core.pipeline.frame``):
attach, motion before collision, collide, motion after collision limited by the Region of
Influence, the collider distance attribute, statistics.

Each test checks the sequence against the same stages called one by one through the
public functions (the README's pipeline script), bit for bit, and that the result keeps
what the stages promise (no crossing, roots on the surface).
"""

from __future__ import annotations

import numpy as np
import pipe_oracle as po
import pytest

from core import Collider, Settings, Solver, Status
from core.pipeline import Motion, Shot, bind, collider_distance, jiggle, region_of_influence, wind
from core.pipeline.frame import DISTANCE_ATTRIBUTE, RootHistory


def _scene(seed=5):
    rng = np.random.default_rng(seed)
    Vs, Fs = po.grid(2.4, 10)
    pts, off = po.fur_on_mesh(rng, Vs, Fs, 300, 6, 0.6, noise=0.1)
    Vc, Fc = po.icosphere((0.0, 0.0, 0.0), 0.45, 2)
    return Vs, Fs, pts.astype(np.float32), off, Collider(Vc, Fc)


def _place(col, f):
    M = np.eye(4)
    M[:3, 3] = [0.05 * f, 0.1, 0.95 - 0.05 * f]
    col.place(M)


def _crossing(points, offsets, col):
    A, B, cid = po.segments(np.asarray(points, np.float64), offsets)
    V = col.vertices.astype(np.float64) @ col.matrix[:3, :3].T + col.matrix[:3, 3]
    return np.unique(cid[po.segments_cross_mesh(A, B, V, col.faces, eps=-1e-6)])


def test_a_shot_without_motion_is_the_solver():
    _, _, pts, off, col = _scene()
    shot = Shot(off, Settings(mode="bend"))
    solver = Solver(off, Settings(mode="bend"))
    for f in range(1, 7):
        _place(col, f)
        got = shot.frame(f, pts, [col])
        want = solver.step(pts, [col])
        np.testing.assert_array_equal(got.points, want.points)
        np.testing.assert_array_equal(got.status, want.status)
        assert got.attributes == {}
        np.testing.assert_array_equal(got.changed, (want.points != pts).any(axis=1))
        assert got.stats["colliding"] == want.count(Status.COLLIDING)
        assert got.stats["frame"] == f and got.stats["source"] == "solved"
    assert got.stats["colliding"] > 5  # the ball pressed into the fur


def test_the_stages_run_in_order_as_the_public_calls_do():
    """Wind before collision, then the solver, then wind and jiggle after collision limited
    by the Region of Influence, and the distance attribute: the same bits as the calls."""
    _, _, pts, off, col = _scene()
    m = Motion(use_wind=True, wind_stage="INPUT", wind_strength=0.1, use_jiggle=True,
               jiggle_stage="OUTPUT", jiggle_amount=3.0, write_collider_distance=True,
               distance_max=0.2)
    fps = 30.0
    shot = Shot(off, Settings(mode="bend"), motion=m, fps=fps, frame_start=2)
    solver = Solver(off, Settings(mode="bend"))
    history = RootHistory()
    for f in range(1, 8):
        _place(col, f)
        moving = pts + np.float32(0.02 * f * f)  # accelerating roots: jiggle moves them
        got = shot.frame(f, moving, [col])
        if f >= 2:
            history.record(f, moving[off[:-1]])
        blown = np.asarray(wind(moving, off, f, direction=(1.0, 0.0, 0.0), strength=0.1,
                                frequency=0.5, turbulence=0.5, falloff=1.5, seed=0,
                                scale=1.0, fps=fps), np.float32)
        res = solver.step(blown, [col])
        out = res.points
        jig = jiggle(out, off, history.lookup, frame=f, fps=fps, stiffness=2.0, damping=0.3,
                     amount=3.0, falloff=1.0) if history.frames else out  # (none seen yet)
        reach = float(np.sqrt(((jig - out) ** 2).sum(1).max()))
        dist = collider_distance(out, off, [col], max_distance=max(0.2, reach))
        want = np.asarray(region_of_influence(out, off, jig, dist, margin=0.99), np.float32)
        np.testing.assert_array_equal(got.points, want, err_msg=f"frame {f}")
        np.testing.assert_array_equal(got.status, res.status)
        np.testing.assert_array_equal(got.attributes[DISTANCE_ATTRIBUTE],
                                      np.minimum(dist, 0.2).astype(np.float32))
        np.testing.assert_array_equal(got.changed, (want != moving).any(axis=1))
        ok = np.flatnonzero(~np.isin(res.status, [Status.PINCHED, Status.UNRESOLVED]))
        assert not np.isin(_crossing(got.points, off, col), ok).any(), f
    assert sorted(shot.history.frames) == list(range(2, 8))  # from frame_start on
    assert np.abs(got.points - out).max() > 1e-3  # the jiggle moved the collided curves


def test_a_shot_with_a_binding_follows_the_surface():
    Vs, Fs, pts, off, col = _scene()
    b = bind(pts, off, Vs, Fs)
    shot = Shot(off, Settings(mode="stiff"), binding=b)
    plain = Shot(off, Settings(mode="stiff"))
    for f in range(1, 5):
        V_now = Vs + [0.0, 0.0, 0.02 * f]
        _place(col, f)
        got = shot.frame(f, colliders=[col], surface=V_now)
        want = plain.frame(f, np.asarray(b.apply(V_now), np.float32), [col])
        np.testing.assert_array_equal(got.points, want.points)
        np.testing.assert_array_equal(got.points[off[:-1]],
                                      np.asarray(b.roots(V_now), np.float32))


def test_motion_reads_any_object_with_the_setting_names():
    class Props:  # (e.g. a Blender property group)
        pass

    p = Props()
    for name, value in Motion(use_wind=True, wind_direction=(0, 1, 0)).__dict__.items():
        setattr(p, name, list(value) if name == "wind_direction" else value)
    m = Motion.of(p)
    assert m == Motion(use_wind=True, wind_direction=(0.0, 1.0, 0.0))
    assert m.active and not m.needs_history
    assert not Motion().active


def test_a_shot_reports_bad_input_by_name():
    _, _, pts, off, col = _scene()
    with pytest.raises(ValueError, match="rows but offsets describe"):
        Shot(off).frame(1, pts[:-1], [col])
