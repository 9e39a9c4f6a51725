"""Follow Collider Motion in Blender: grass pushed by a rolling ball lays over along the
ball's motion; play, scrub (a frame solved again from a cached one), bake and a resumed
bake agree bit for bit, as for any other setting."""

import bpy
import numpy as np
import pytest
from helpers import activate, bake_crashing_at, bake_setup, check_frame, make_hair, positions

pytestmark = pytest.mark.blender

FRAMES = range(1, 13)


def _grass(fc, follow=True):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 12
    hair = make_hair(nx=9, ny=5, npts=5, length=0.6, spacing=0.12)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.3, location=(-1.0, 0.0, 0.35),
                                         segments=24, ring_count=12)
    ball = bpy.context.active_object
    ball.keyframe_insert("location", frame=1)
    ball.location = (1.0, 0.0, 0.35)
    ball.keyframe_insert("location", frame=12)
    from helpers import linear

    linear(ball)
    scene.frame_set(1)
    out = fc.setup(hair, [ball])
    s = hair.furcollide
    s.frame_end = 12
    s.follow_collider_motion = follow
    s.recovery_rate = 0.0  # (the blades stay where the ball laid them)
    return scene, hair, ball, out


def _play(scene, hair, ball, out):
    got = {}
    for f in FRAMES:
        scene.frame_set(f)
        assert not hair.furcollide.is_outdated, (f, hair.furcollide.status_message)
        check_frame(hair, out, [ball], status=None)
        got[f] = positions(out).copy()
    return got


def _lean(fc, hair, P):
    """Mean cosine between each moved blade's tip displacement (on the ground) and +x."""
    offs = fc.blender.bridge.curve_offsets(hair.data)
    tips = offs[1:] - 1
    d = (P[tips] - positions(hair)[tips])[:, :2]
    n = np.linalg.norm(d, axis=1)
    moved = n > 1e-3
    assert moved.sum() >= 5, moved.sum()
    return float(np.mean(d[moved, 0] / n[moved]))


def test_grass_lays_over_along_the_rolling_ball(fc):
    scene, hair, ball, out = _grass(fc)
    followed = _play(scene, hair, ball, out)
    assert _lean(fc, hair, followed[12]) > 0.8
    hair.furcollide.follow_collider_motion = False
    scene.frame_set(1)
    plain = _play(scene, hair, ball, out)
    assert _lean(fc, hair, plain[12]) < _lean(fc, hair, followed[12])


def test_a_still_collider_gives_the_papers_direction(fc):
    scene, hair, ball, out = _grass(fc)
    ball.animation_data_clear()
    ball.location = (0.0, 0.0, 0.35)
    followed = _play(scene, hair, ball, out)
    hair.furcollide.follow_collider_motion = False
    scene.frame_set(1)
    plain = _play(scene, hair, ball, out)
    for f in FRAMES:
        np.testing.assert_array_equal(followed[f], plain[f], err_msg=f"frame {f}")


def test_scrub_bake_and_resume_equal_playback(fc, monkeypatch, tmp_path):
    scene, hair, ball, out = _grass(fc)
    played = _play(scene, hair, ball, out)
    # Scrubbed: frames 7.. dropped by a key there, then solved again from cached frame 6
    # after the scene was shown at frame 12 (the colliders were read there last).
    rt = fc.store.registry.get_runtime(hair)
    fc.store.playback.drop_after(rt, 6, 1)
    scene.frame_set(6)
    for f in range(7, 13):
        scene.frame_set(f)
        np.testing.assert_array_equal(positions(out), played[f], err_msg=f"scrub {f}")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "grass.blend"))
    activate(hair)
    bake_crashing_at(fc, monkeypatch, 8)  # frames 1-7 on disk
    scene.frame_set(12)  # (the colliders read elsewhere before the resume)
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    for f in FRAMES:
        scene.frame_set(f)
        np.testing.assert_array_equal(positions(out), played[f], err_msg=f"baked {f}")
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    bake_setup(hair)
    for f in FRAMES:
        scene.frame_set(f)
        np.testing.assert_array_equal(positions(out), played[f], err_msg=f"bake {f}")
