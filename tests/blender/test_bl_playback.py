"""The frame rules in playback: scrubbing back is exact, jumps ahead hold, subframes and
repeated frames never step, setting and mode changes mid-shot, deleted colliders,
negative start frames, jumps past the end, fps changes."""

import bpy
import numpy as np
import pytest
from helpers import (
    REAL_FRAMES,
    assert_same_frames,
    check_demo_frame,
    check_frame,
    frame_of,
    offsets_of,
    play_demo,
    positions,
    positions_per_frame,
    preroll_scene,
    real_size_fur,
    record,
    reset_cache,
    same_frame,
    set_core,
    status_of,
)

pytestmark = pytest.mark.blender




def test_scrub_back_is_exact_and_jump_holds(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    rt = fc.store.registry.get_runtime(hair)
    rec = positions_per_frame(out, range(1, 13))
    assert len(rt.cache.memory) == 12
    assert any(not np.array_equal(rec[f], fc.positions(hair)) for f in rec)
    for f in (5, 1, 12, 7):
        bpy.context.scene.frame_set(f)
        assert np.array_equal(fc.positions(out), rec[f]), f
        assert hair.furcollide.stat_frame == f
        assert not hair.furcollide.is_outdated
    # forget everything, stand on frame 1 (solved), then jump ahead
    bpy.context.scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    bpy.context.scene.frame_set(9)
    assert hair.furcollide.is_outdated
    assert "not cached" in hair.furcollide.status_message
    assert np.array_equal(fc.positions(out), rec[1])  # holds the newest cached frame
    # playing on from the cache gives bit-identical frames again
    rec2 = positions_per_frame(out, range(2, 13))
    for f in rec2:
        assert np.array_equal(rec2[f], rec[f]), f
    assert not hair.furcollide.is_outdated


def test_subframes_and_repeats_do_not_step(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    rt = fc.store.registry.get_runtime(hair)
    rec = positions_per_frame(out, range(1, 7))
    sc = bpy.context.scene
    sc.frame_set(6, subframe=0.5)
    assert np.array_equal(fc.positions(out), rec[6])
    assert sorted(rt.cache.memory.frames) == list(range(1, 7))
    sc.frame_set(6)
    sc.frame_set(6)
    assert np.array_equal(fc.positions(out), rec[6])
    assert rt.solve.frame == 6


def test_setting_change_drops_the_playback_cache(fc):
    """Like Blender's point cache: a setting changed mid-shot drops every cached frame
    (earlier ones too: they were solved with the old value), the shown frame is marked
    outdated and every frame says why until the start frame is played again."""
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    rt = fc.store.registry.get_runtime(hair)
    rec = positions_per_frame(out, range(1, 13))
    bpy.context.scene.frame_set(6)
    hair.furcollide.mode = "STIFF"
    assert len(rt.cache.memory) == 0
    assert hair.furcollide.is_outdated
    assert hair.furcollide.status_message == (
        "Frame 6 is outdated: Mode changed. The playback cache is dropped: go to "
        "frame 1 and play, or press Bake.")
    for f in (3, 9):  # earlier or later: not shown as current, not stepped
        bpy.context.scene.frame_set(f)
        assert hair.furcollide.is_outdated and len(rt.cache.memory) == 0
        assert "(Mode changed: the playback cache was dropped)" in (
            hair.furcollide.status_message)
        assert np.array_equal(fc.positions(out), rec[6])  # the output is left as it was
    positions_per_frame(out, range(1, 13))  # the advice
    assert not hair.furcollide.is_outdated and len(rt.cache.memory) == 12
    # a shorter end keeps the frames inside the new range...
    hair.furcollide.frame_end = 4
    assert sorted(rt.cache.memory.frames) == [1, 2, 3, 4]
    # ... a new start drops everything
    hair.furcollide.frame_start = 2
    assert len(rt.cache.memory) == 0
    # the thread count changes nothing in the result: the cache stays
    positions_per_frame(out, range(2, 5))
    hair.furcollide.threads = 1
    assert sorted(rt.cache.memory.frames) == [2, 3, 4]


def clean_run(fc, mode, frames, **settings):
    """The output per frame of a fresh setup in ``mode`` (a new file, the same shot)."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    set_core(hair.furcollide, mode=mode, **settings)
    return positions_per_frame(out, frames)


@pytest.mark.parametrize("change", [{"mode": "soft"}, {"recovery_rate": 0.9}],
                         ids=["mode", "recovery"])
def test_a_change_mid_animation_needs_the_start_frame_and_the_advice_works(fc, change):
    """The issue's case: play 1-10 in Stiff, change Mode (or a slider) and play on.
    No later frame is stepped from the old state or freezes for good: each says the
    cache was dropped and to play from frame 1, and following that gives exactly a
    clean play with the new setting, with no resolved curve crossing the box."""
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    s = hair.furcollide
    s.mode = "STIFF"
    positions_per_frame(out, range(1, 11))
    set_core(s, **change)
    for f in (11, 12):
        bpy.context.scene.frame_set(f)
        assert s.is_outdated and "Play from frame 1" in s.status_message, s.status_message
    got = {}
    for f in range(1, 13):  # the advice
        bpy.context.scene.frame_set(f)
        check_frame(hair, out, [box])
        got[f] = fc.positions(out).copy()
    assert not s.is_outdated
    ref = clean_run(fc, change.get("mode", "stiff"), range(1, 13),
                    **{k: v for k, v in change.items() if k != "mode"})
    for f in got:
        np.testing.assert_array_equal(got[f], ref[f], err_msg=f"frame {f}")


@pytest.mark.parametrize("seen", ["signature", "previous-frame-record"])
def test_a_change_without_an_update_callback_is_not_stepped_from(fc, monkeypatch, seen):
    """A setting changed where no update callback runs (undo, a driver: here the
    callback's invalidation is switched off). Whichever check sees it first (the
    setup's signature, or the record of the cached previous frame the step would
    start from), frame 7 is not stepped from frame 6's Bend state."""
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    rt = fc.store.registry.get_runtime(hair)
    positions_per_frame(out, range(1, 7))
    monkeypatch.setattr(fc.store.invalidation, "invalidate", lambda *a, **k: None)
    hair.furcollide.mode = "SOFT"
    if seen == "previous-frame-record":
        fc.frame.record.forget_structure(rt)  # (as after a shorter frame range)
    bpy.context.scene.frame_set(7)
    s = hair.furcollide
    assert s.is_outdated and len(rt.cache.memory) == 0
    assert "Frame 7 is outdated: Mode changed" in s.status_message, s.status_message
    positions_per_frame(out, range(1, 8))
    assert not s.is_outdated and s.status_message == ""


def test_mode_change_then_play_from_start(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    positions_per_frame(out, range(1, 8))
    bpy.context.scene.frame_set(1)
    hair.furcollide.mode = "SOFT"
    rec = positions_per_frame(out, range(1, 8))
    assert hair.furcollide.status_message == ""
    assert not hair.furcollide.is_outdated
    assert len(rec) == 7


def test_deleted_and_renamed_collider(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    ref = positions_per_frame(out, range(1, 13))
    hits = {}
    for f in range(6, 13):
        bpy.context.scene.frame_set(f)
        hits[f] = hair.furcollide.stat_colliding
    assert any(hits.values())
    # renaming mid-animation changes nothing
    bpy.context.scene.frame_set(1)
    bpy.ops.furcollide.reset()
    positions_per_frame(out, range(2, 6))
    box.name = "Renamed Box"
    rec = positions_per_frame(out, range(6, 13))
    for f in rec:
        assert np.array_equal(rec[f], ref[f]), f
    # deleting it mid-animation: no error; like any change of the colliders it drops
    # the playback cache, and the frames from the start frame on are solved without it
    bpy.context.scene.frame_set(5)
    bpy.data.objects.remove(box)
    bpy.context.scene.frame_set(6)
    s = hair.furcollide
    assert s.is_outdated and "a collider was removed" in s.status_message, s.status_message
    assert "Play from frame 1" in s.status_message or "go to frame 1" in s.status_message
    for f in range(1, 13):  # the advice
        bpy.context.scene.frame_set(f)
        assert s.stat_colliding == 0, f
        assert s.status_message == "" and not s.is_outdated
    np.testing.assert_array_equal(fc.positions(out), fc.positions(hair))
    assert s.colliders[0].object is None


def test_collider_deleted_in_the_ui_stops_colliding(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    box.select_set(True)
    bpy.context.view_layer.objects.active = box
    assert bpy.ops.object.delete() == {"FINISHED"}  # our pointer keeps it alive
    bpy.context.view_layer.objects.active = hair
    for f in range(1, 13):
        bpy.context.scene.frame_set(f)
        assert hair.furcollide.stat_colliding == 0, f
    assert np.array_equal(fc.positions(out), fc.positions(hair))


def test_jump_past_an_uncached_end_frame_holds_the_newest_cached_frame(fc):
    """Cached 1..5 of 1..12, then a jump to frame 20 (after the end): like any jump
    past the cache the newest cached frame (5) is held and the setup is outdated,
    whichever frame was on screen before the jump."""
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 12), nx=5, ny=5)
    out = fc.setup(hair, [box])
    s = hair.furcollide
    rec = record(scene, out, range(1, 6))
    assert not np.array_equal(rec[5][0], rec[2][0])
    shown = {}
    for before in (2, 5):
        scene.frame_set(before)
        scene.frame_set(20)
        assert s.is_outdated and "not cached" in s.status_message, s.status_message
        shown[before] = positions(out).copy()
    np.testing.assert_array_equal(shown[5], rec[5][0])
    np.testing.assert_array_equal(shown[2], shown[5], err_msg="depends on the frame shown before")


def test_negative_start_frame_plays_scrubs_and_holds(fc):
    """A setup starting at frame -4: before it the output is the source, frames
    from -4 on are solved, scrubbing back over negative frames is exact."""
    scene, hair, box, out = preroll_scene(fc)
    s = hair.furcollide
    scene.frame_set(-6)
    assert s.status_message == "Before the start frame"
    np.testing.assert_array_equal(positions(out), positions(hair))
    rec = {}
    for f in range(-4, 4):
        scene.frame_set(f)
        check_frame(hair, out, [box])
        rec[f] = (positions(out).copy(), status_of(out).copy())
    assert any(rec[f][1].any() for f in rec)
    assert sorted(fc.store.registry.get_runtime(hair).cache.memory.frames) == list(range(-4, 4))
    assert_same_frames(rec, scene, out, [0, -3, 2, -4, 3], "scrubbed")
    scene.frame_set(5)
    np.testing.assert_array_equal(positions(out), rec[3][0])
    assert "holding frame 3" in s.status_message


def test_fps_change_mid_session_keeps_a_plain_setup_exact(fc):
    """Without motion stages nothing depends on the fps: changing it mid-play keeps
    the cache, and playing on equals a clean play."""
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 10), nx=5, ny=5)
    out = fc.setup(hair, [box])
    clean = record(scene, out, range(1, 11))
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    record(scene, out, range(1, 5))
    scene.render.fps = 30
    scene.render.fps_base = 1.001
    assert_same_frames(clean, scene, out, range(5, 11), "after the fps change")
    assert hair.furcollide.status_message == ""


def test_one_solve_serves_playback_and_scripts(fc):
    """The core's frame sequence from plain arrays (``core.pipeline.Shot``, scripts/demo.py's
    core path: no Blender object, no frame handler) gives, bit for bit, what playback
    wrote: one solve serves both."""
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 8))
    out = fc.setup(hair, [box])
    played = positions_per_frame(out, range(1, 9))  # source and output at the origin
    offsets = offsets_of(hair)
    C = len(offsets) - 1  # (the hair draws its curves as Catmull-Rom, Blender's default)
    shot = fc.core.pipeline.Shot(offsets, fc.settings.fingerprints.core_settings(hair),
                                 splines=fc.core.splines.Splines.catmull_rom(C))
    me = box.data
    V = np.empty(len(me.vertices) * 3, np.float32)
    me.attributes["position"].data.foreach_get("vector", V)
    me.calc_loop_triangles()
    F = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("vertices", F)
    collider = None
    for f in range(1, 9):
        scene.frame_set(f)
        M = np.array(box.matrix_world, np.float64)
        if collider is None:
            collider = fc.core.Collider(V.reshape(-1, 3), F.reshape(-1, 3), matrix=M,
                                        drop_degenerate=True, name=box.name)
        else:
            collider.matrix = M  # rigid: the BVH is kept, as in playback
        result = shot.frame(f, positions(hair), [collider])
        np.testing.assert_array_equal(result.points, played[f], err_msg=f"frame {f}")
        assert result.stats["frame"] == f
    assert any((p != positions(hair)).any() for p in played.values())  # the box met the hair


# ------------------------------------------------------------- the demo's scene
def test_a_setting_changed_mid_shot_drops_the_playback_cache(fc):
    """README "Time" > Invalidation: a changed setting drops the whole playback cache,
    as Blender's point cache does: played to 6, Recovery Rate changed, frame 7 is not
    stepped from frame 6 (solved with the old setting); the output keeps frame 6 and
    says why (not only the frames after the current one are dropped). Threads changes
    no result and drops nothing."""
    demo, hair, out = real_size_fur(n_fur=3000)
    first = play_demo(demo.scene, hair, out, range(1, 7))
    hair.furcollide.threads = 1
    demo.scene.frame_set(7)
    assert not hair.furcollide.is_outdated, hair.furcollide.status_message
    demo.scene.frame_set(6)
    hair.furcollide.recovery_rate = 0.8
    demo.scene.frame_set(7)
    s = hair.furcollide
    assert s.is_outdated and "Recovery Rate changed" in s.status_message, s.status_message
    same_frame(frame_of(out), first[6], "frame 7 after the change: the output held")


#: A choice and a number the next frame's state carries (Plasticity), at real size.
#: Every other setting's invalidation, keyed or changed, is
#: test_bl_keyed_settings.py's, on a small scene.
MID_SHOT = [("mode", "soft"), ("plasticity", 0.6)]


@pytest.mark.slow
@pytest.mark.parametrize("name,value", MID_SHOT, ids=[f"{n}={v}" for n, v in MID_SHOT])
def test_a_setting_changed_mid_shot(fc, name, value):
    """Played to 14 (Bend), a setting changed: the frames after it are held and say why
    (the whole playback cache is dropped), scrubbed back a frame cached with the old
    setting is not shown (the output keeps what it showed). Played from the start:
    every frame holds the promises (checked every sixth frame), and equals a fresh
    solve (Reset Cache) with the new setting. Set back and played again: the first
    session's frames bit for bit. (The crossing oracle runs on frames 2, 8, 14 and 20:
    before the pusher, entering, pinching, with the cloth on the fur; every frame in
    test_bl_demo_scale.py's test_demo_played_scrubbed_and_jumped.)"""
    demo, hair, out = real_size_fur()
    s = hair.furcollide
    scene = demo.scene
    first = play_demo(demo.scene, hair, out, range(1, 15))
    before = fc.settings.core_values.core_value(s, name)
    set_core(s, **{name: value})
    for f in (15, 16, 8, 3):
        scene.frame_set(f)
        said = f"{s.bl_rna.properties[name].name} changed"
        assert s.is_outdated and said in s.status_message, (
            f, s.status_message)
        same_frame(frame_of(out), first[14], f"frame {f} after the change: the output held")
    new = {}
    for f in REAL_FRAMES:
        new.update(play_demo(demo.scene, hair, out, [f]))
        if f % 6 == 2:
            check_demo_frame(demo, hair, out, what=f"{name}={value}, frame {f}")
    reset_cache(hair)
    for f, got in play_demo(demo.scene, hair, out).items():
        same_frame(got, new[f], f"{name}={value}: replayed vs fresh, frame {f}")
    set_core(s, **{name: before})
    for f, got in play_demo(demo.scene, hair, out, range(1, 15)).items():
        same_frame(got, first[f], f"{name} set back, frame {f}")
