"""Keyed and driven settings: the value a setting has at a frame is an input of that frame.

A box sweeps through a hair grid while one setting is keyed (or driven) at a time.
Playback, scrubbing, a bake and its resume use each frame's value: no frame is outdated,
no resolved curve crosses the box, the bake equals playback bit for bit, and a cached
frame is solved once. Editing a key drops only the frames from the first one whose
value changed, and the status names the setting and the frame. Mode cannot be keyed
(a curve's state in one mode means nothing in another): Blender refuses the key.
"""

import math

import bpy
import numpy as np
import pytest
from helpers import (
    activate,
    bake_crashing_at,
    bake_setup,
    check_frame,
    fcurves,
    make_hair,
    poly,
    positions,
    status_of,
    sweep_box,
)

pytestmark = pytest.mark.blender

FRAMES = (1, 14)


def _shot(fc):
    """A 7 x 7 grid and a box that sweeps through it over FRAMES and leaves."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = FRAMES
    hair = make_hair(nx=7, ny=7, npts=6)
    box = sweep_box(x0=-1.3, x1=1.3, frames=(1, 10), size=0.5, z=0.55)
    scene.frame_set(FRAMES[0])
    out = fc.setup(hair, [box])
    s = hair.furcollide
    s.frame_end = FRAMES[1]
    return scene, hair, box, out


def _key(owner, prop, a, b, frames=(2, 9), linear=True):
    """Key ``owner.prop`` from ``a`` at ``frames[0]`` to ``b`` at ``frames[1]``."""
    setattr(owner, prop, a)
    owner.keyframe_insert(prop, frame=frames[0])
    setattr(owner, prop, b)
    owner.keyframe_insert(prop, frame=frames[1])
    if linear:
        for fcu in fcurves(owner.id_data):
            for k in fcu.keyframe_points:
                k.interpolation = "LINEAR"


def _keyed_recovery(s, hair):
    _key(s, "recovery_rate", 0.1, 0.9)


def _keyed_plasticity(s, hair):
    _key(s, "plasticity", 0.0, 0.8)


def _keyed_offset(s, hair):
    _key(s, "collision_offset", 0.0, 0.05)


def _keyed_precision(s, hair):
    _key(s, "rotation_precision", math.radians(2.0), math.radians(0.25))  # (keyed in radians)


def _keyed_collider_enabled(s, hair):
    _key(s.colliders[0], "enabled", False, True, frames=(1, 8), linear=False)


def _keyed_wind(s, hair):
    s.motion.use_wind = True
    _key(s.motion, "wind_strength", 0.02, 0.2)


def _driven_offset(s, hair):
    fcu = s.driver_add("collision_offset")
    fcu.driver.type = "SCRIPTED"
    fcu.driver.use_self = False
    fcu.driver.expression = "0.004 * frame"


KEYED = {
    "recovery_rate": _keyed_recovery,
    "plasticity": _keyed_plasticity,
    "collision_offset": _keyed_offset,
    "rotation_precision": _keyed_precision,
    "collider_enabled": _keyed_collider_enabled,
    "wind_strength": _keyed_wind,
    "driven_offset": _driven_offset,
}


@pytest.fixture
def solves(fc, monkeypatch):
    """Count the frames solved (frame -> times)."""
    counts = {}
    real = fc.frame.solve.solve_frame

    def spy(setup, inp, **kw):
        counts[setup.frame] = counts.get(setup.frame, 0) + 1
        return real(setup, inp, **kw)

    monkeypatch.setattr(fc.frame.solve, "solve_frame", spy)
    return counts


def _play(scene, hair, out, box, frames):
    """Play ``frames``: none is outdated, and no resolved curve crosses the box where it
    collides (its entry is enabled there). {frame: (positions, status)}."""
    got = {}
    for f in frames:
        scene.frame_set(f)
        s = hair.furcollide
        assert not s.is_outdated, (f, s.status_message)
        # (wind after collision, held back by the Region of Influence, moves points
        # on their own: it keeps no lengths)
        check_frame(hair, out, [box] if s.colliders[0].enabled else [], status=None,
                    lengths=not s.motion.use_wind)
        got[f] = (positions(out).copy(), status_of(out).copy())
    return got


def _same(a, b, what):
    for f in a:
        np.testing.assert_array_equal(a[f][0], b[f][0], err_msg=f"{what}: frame {f}")
        np.testing.assert_array_equal(a[f][1], b[f][1], err_msg=f"{what}: frame {f}")


@pytest.mark.parametrize("which", sorted(KEYED))
def test_a_keyed_setting_plays_scrubs_and_bakes_as_one_shot(fc, which, solves, tmp_path):
    scene, hair, box, out = _shot(fc)
    KEYED[which](hair.furcollide, hair)
    solves.clear()
    frames = range(FRAMES[0], FRAMES[1] + 1)
    played = _play(scene, hair, out, box, frames)
    assert all(n == 1 for n in solves.values()), solves
    assert sorted(solves) == list(frames)
    # Scrubbing back and forth shows the cached frames: nothing is solved again.
    scrub = _play(scene, hair, out, box, [*reversed(frames), *frames])
    assert all(n == 1 for n in solves.values()), solves
    _same({f: scrub[f] for f in frames}, played, "scrubbed")
    # The bake equals playback, and its frames are current.
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"))
    bake_setup(hair)
    baked = _play(scene, hair, out, box, frames)
    _same(baked, played, "baked")
    assert hair.furcollide.status_message == "" or "baked" not in hair.furcollide.status_message


def test_the_keyed_values_change_the_result(fc):
    """Plasticity keyed to 0.8 keeps an imprint the unkeyed 0 does not (the key is used)."""
    scene, hair, box, out = _shot(fc)
    frames = range(FRAMES[0], FRAMES[1] + 1)
    plain = _play(scene, hair, out, box, frames)
    _keyed_plasticity(hair.furcollide, hair)
    scene.frame_set(FRAMES[0])
    keyed = _play(scene, hair, out, box, frames)
    assert not np.array_equal(plain[FRAMES[1]][0], keyed[FRAMES[1]][0])


def test_bake_equals_a_script_stepping_the_core_with_each_frames_values(fc):
    """Playback equals core.Solver stepped by a script with the frame's keyed values."""
    from core import Collider, Settings, Solver  # the core the add-on ships

    scene, hair, box, out = _shot(fc)
    poly(hair)  # (drawn as its polygon: the core's Solver alone, no spline margin)
    _keyed_recovery(hair.furcollide, hair)
    _keyed_plasticity(hair.furcollide, hair)
    frames = range(FRAMES[0], FRAMES[1] + 1)
    played = _play(scene, hair, out, box, frames)
    offs = fc.blender.bridge.curve_offsets(hair.data)
    solver = None
    for f in frames:
        scene.frame_set(f)
        kw = hair.furcollide.to_core_kwargs()
        if solver is None:
            solver = Solver(offs, Settings(**kw))
        solver.settings = Settings(**kw)
        dg = bpy.context.evaluated_depsgraph_get()
        be = box.evaluated_get(dg)
        me = be.data
        V = np.array([v.co for v in me.vertices], np.float64)
        me.calc_loop_triangles()
        F = np.array([t.vertices[:] for t in me.loop_triangles], np.int64)
        col = Collider(V, F, matrix=np.array(be.matrix_world))
        res = solver.step(positions(hair).astype(np.float32), [col])
        np.testing.assert_array_equal(res.points.astype(np.float32), played[f][0],
                                      err_msg=f"frame {f}")


def test_editing_a_key_keeps_every_frame_before_the_first_changed_value(fc, solves):
    scene, hair, box, out = _shot(fc)
    s = hair.furcollide
    s.recovery_rate = 0.2
    s.keyframe_insert("recovery_rate", frame=1)
    s.keyframe_insert("recovery_rate", frame=8)
    s.recovery_rate = 0.9
    s.keyframe_insert("recovery_rate", frame=12)
    frames = range(FRAMES[0], FRAMES[1] + 1)
    for fcu in fcurves(hair):
        for k in fcu.keyframe_points:
            k.interpolation = "LINEAR"
    _play(scene, hair, out, box, frames)
    solves.clear()
    # The graph editor moves the last key's value (frames 9.. change, 1..8 do not).
    fcu = next(c for c in fcurves(hair) if c.data_path == "furcollide.recovery_rate")
    fcu.keyframe_points[-1].co.y = 0.5
    fcu.update()
    hair.update_tag()
    bpy.context.view_layer.update()
    rt = fc.store.registry.get_runtime(hair)
    assert sorted(rt.cache.memory.frames) == list(range(1, 9)), sorted(rt.cache.memory.frames)
    scene.frame_set(14)
    assert "Recovery Rate" in s.status_message and "frame 9" in s.status_message, (
        s.status_message)
    # Playing on from the last frame kept solves only the changed frames.
    _play(scene, hair, out, box, range(8, 15))
    assert sorted(solves) == list(range(9, 15)), solves


def test_an_unkeyed_edit_drops_the_whole_playback_cache(fc):
    scene, hair, box, out = _shot(fc)
    _keyed_recovery(hair.furcollide, hair)
    _play(scene, hair, out, box, range(1, 8))
    hair.furcollide.plasticity = 0.5  # the same value on every frame: every frame changed
    rt = fc.store.registry.get_runtime(hair)
    assert len(rt.cache.memory) == 0


def test_mode_cannot_be_keyed(fc):
    scene, hair, box, out = _shot(fc)
    with pytest.raises(TypeError, match="not animatable"):
        hair.furcollide.keyframe_insert("mode", frame=3)


def test_the_status_says_which_setting_changed_at_which_frame_of_a_bake(fc, tmp_path):
    scene, hair, box, out = _shot(fc)
    _keyed_recovery(hair.furcollide, hair)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"))
    bake_setup(hair)
    scene.frame_set(5)
    assert hair.furcollide.status_message == ""
    fcu = next(c for c in fcurves(hair) if c.data_path == "furcollide.recovery_rate")
    fcu.keyframe_points[-1].co.y = 0.3
    fcu.update()
    scene.frame_set(4)
    scene.frame_set(5)
    msg = hair.furcollide.status_message
    assert "Recovery Rate" in msg and "frame 5" in msg, msg
    assert hair.furcollide.is_outdated
    scene.frame_set(1)  # before the changed key (frames 1..2 hold 0.1): current
    assert hair.furcollide.status_message == "", hair.furcollide.status_message
    activate(hair)


def test_a_setup_enabled_again_starts_from_the_groom(fc, solves, tmp_path):
    """Enabled keyed off for frames 5-7: those frames show the source, frame 8 starts
    again from the groomed shape (as a start frame does); play, scrub and bake agree."""
    scene, hair, box, out = _shot(fc)
    s = hair.furcollide
    s.enabled = True
    s.keyframe_insert("enabled", frame=1)
    s.enabled = False
    s.keyframe_insert("enabled", frame=5)
    s.enabled = True
    s.keyframe_insert("enabled", frame=8)
    solves.clear()
    frames = range(FRAMES[0], FRAMES[1] + 1)
    played = {}
    for f in frames:
        scene.frame_set(f)
        assert not s.is_outdated, (f, s.status_message)
        if s.enabled:
            check_frame(hair, out, [box], status=None)
        else:
            np.testing.assert_array_equal(positions(out), positions(hair))
        played[f] = (positions(out).copy(), status_of(out).copy())
    assert sorted(solves) == [1, 2, 3, 4, 8, 9, 10, 11, 12, 13, 14], solves
    # Frame 8 is frame 1 of a new run: the same as a setup starting there.
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"))
    bake_setup(hair)
    for f in frames:
        scene.frame_set(f)
        np.testing.assert_array_equal(positions(out), played[f][0], err_msg=f"frame {f}")


def test_a_resumed_bake_of_keyed_settings_equals_playback(fc, monkeypatch, tmp_path, capsys):
    """A bake stopped at frame 7 resumes after frame 6 (each frame's values still hold
    there), and equals playback; after the ramp's last key is edited (frames 3.. change)
    a partial bake resumes after frame 2."""
    scene, hair, box, out = _shot(fc)
    _keyed_recovery(hair.furcollide, hair)
    frames = range(FRAMES[0], FRAMES[1] + 1)
    played = _play(scene, hair, out, box, frames)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"))
    activate(hair)
    bake_crashing_at(fc, monkeypatch, 7)
    capsys.readouterr()
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert "resuming after frame 6" in capsys.readouterr().out
    for f in frames:
        scene.frame_set(f)
        np.testing.assert_array_equal(positions(out), played[f][0], err_msg=f"frame {f}")
    # A key edited after a partial bake: the frames before its first changed value resume.
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    bake_crashing_at(fc, monkeypatch, 9)
    fcu = next(c for c in fcurves(hair) if c.data_path == "furcollide.recovery_rate")
    fcu.keyframe_points[-1].co.y = 0.5  # the ramp from frame 2 to 9: frames 3.. change
    fcu.update()
    capsys.readouterr()
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert "resuming after frame 2" in capsys.readouterr().out


def test_a_render_of_a_keyed_frame_is_the_played_frame(fc, solves):
    """F12 at a cached frame renders it as played: the render's frame handler finds the
    frame's values unchanged and solves nothing."""
    from helpers import render_camera

    scene, hair, box, out = _shot(fc)
    _keyed_plasticity(hair.furcollide, hair)
    frames = range(FRAMES[0], FRAMES[1] + 1)
    played = _play(scene, hair, out, box, frames)
    solves.clear()
    render_camera(scene)
    scene.frame_set(6)
    seen = []

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            seen.append(positions(out).copy())

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render()
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    assert seen and all(np.array_equal(p, played[6][0]) for p in seen)
    assert solves == {}, solves
    assert not hair.furcollide.is_outdated, hair.furcollide.status_message
