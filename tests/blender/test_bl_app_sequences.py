"""The handler sequences of the Blender application, replayed on the ``bpy`` wheel.

Recorded in Debian's Blender 4.3 with its UI (``tests/app``), with an animated rigid
collider and a shape-keyed one:

* **play** (``screen.animation_play``): ``frame_change_pre/post`` for the current frame,
  then one ``depsgraph_update_post`` *at that frame* reporting the animated colliders
  (transform, geometry) as updated, then ``frame_change_pre/post`` for every next frame;
* **arrow keys / timeline** (``screen.frame_offset``, ``frame_jump``): one
  ``depsgraph_update_post`` at the *new* frame, reporting the animated colliders, before
  its ``frame_change_pre/post``;
* an **edit** (a collider moved by hand): one ``depsgraph_update_post`` at the frame.

The ``bpy`` wheel's ``frame_set`` fires no ``depsgraph_update_post``, so the other
lanes never saw the first two. Here the same depsgraph updates come from the real
depsgraph: setting ``scene.frame_current`` and ``view_layer.update()`` evaluates the
animation again and reports the animated objects, without the frame handlers.
Geometry is checked with the brute-force oracle of ``tests/core`` (``check_frame``).
"""

import bpy
import numpy as np
import pytest
from helpers import check_frame, make_box, make_hair, positions, sweep_box

pytestmark = pytest.mark.blender

FRAMES = (1, 10)


def shot(fc):
    """A hair grid, a box sweeping through it (rigid, keyed) and a box that swells into
    it (a keyed shape key: a deforming collider); returns (scene, hair, out, colliders)."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = FRAMES
    scene.frame_set(FRAMES[0])
    hair = make_hair(nx=8, ny=8, npts=5, spacing=0.15)
    ball = sweep_box("Ball", x0=-1.4, x1=1.4, frames=FRAMES, size=0.45, z=0.55)
    blob = make_box("Blob", size=0.3, location=(0.5, 0.5, 1.3))
    blob.shape_key_add(name="Basis")
    key = blob.shape_key_add(name="Down")
    for v in key.data:
        v.co.z -= 0.6
    key.value = 0.0
    key.keyframe_insert("value", frame=FRAMES[0])
    key.value = 1.0
    key.keyframe_insert("value", frame=FRAMES[1])
    scene.frame_set(FRAMES[0])
    out = fc.setup(hair, [ball, blob])
    return scene, hair, out, [ball, blob]


def animation_evaluated_again(scene):
    """What pressing play does in the application, after the frame handler ran: the
    depsgraph evaluates the animation of the current frame again and reports it."""
    seen = []

    def spy(_scene, depsgraph=None):
        seen.extend(u.id.name for u in depsgraph.updates if isinstance(u.id, bpy.types.Object))

    bpy.app.handlers.depsgraph_update_post.append(spy)
    try:
        scene.frame_current = scene.frame_current
        bpy.context.view_layer.update()
    finally:
        bpy.app.handlers.depsgraph_update_post.remove(spy)
    assert {"Ball", "Blob"} <= set(seen), seen  # the update really reports them


def arrow_key(scene, f):
    """What the arrow keys (or a click in the timeline) do in the application: the
    depsgraph update of the new frame first, then the frame handlers."""
    scene.frame_current = f
    bpy.context.view_layer.update()
    scene.frame_set(f)


def play_like_the_app(scene, hair, out, colliders, frames):
    """Press play at ``frames[0]`` (already shown) and play ``frames[1:]``: every frame
    is solved or shown from the cache, none is held, none crosses; {frame: output}."""
    s = hair.furcollide
    animation_evaluated_again(scene)
    got = {frames[0]: positions(out).copy()}
    for f in frames[1:]:
        scene.frame_set(f)
        assert not s.is_outdated, (f, s.status_message)
        check_frame(hair, out, colliders)  # status "" and no resolved curve crossing
        got[f] = positions(out).copy()
    return got


def test_play_steps_every_frame_then_replays_from_the_cache(fc):
    """The real-Blender lane's failure: pressing play at the start frame dropped the
    whole cache (the animated colliders' update at frame 1), so every later frame was
    'not cached'. Now it steps every frame; played again, every frame comes from the
    cache, bit for bit."""
    scene, hair, out, colliders = shot(fc)
    rt = fc.store.registry.get_runtime(hair)
    scene.frame_set(1)
    first = play_like_the_app(scene, hair, out, colliders, range(1, 11))
    assert sorted(rt.cache.memory.frames) == list(range(1, 11))
    scene.frame_set(1)
    sources = []
    again = {}
    animation_evaluated_again(scene)
    for f in range(2, 11):
        scene.frame_set(f)
        sources.append(rt.report.stats["source"])
        again[f] = positions(out).copy()
    assert sources == ["cache"] * 9, sources
    for f in again:
        np.testing.assert_array_equal(again[f], first[f], err_msg=f"frame {f}")


def test_the_colliders_really_collide_in_that_shot(fc):
    """(The shot is not trivial: both colliders push curves on some frames.)"""
    scene, hair, out, colliders = shot(fc)
    colliding = []
    for f in range(1, 11):
        scene.frame_set(f)
        colliding.append(hair.furcollide.stat_colliding)
    assert max(colliding[:6]) > 0 and colliding[-1] > 0, colliding


def test_play_from_the_middle_of_the_shot(fc):
    scene, hair, out, colliders = shot(fc)
    rt = fc.store.registry.get_runtime(hair)
    for f in range(1, 6):
        scene.frame_set(f)
    play_like_the_app(scene, hair, out, colliders, range(5, 11))
    assert sorted(rt.cache.memory.frames) == list(range(1, 11))


def test_arrow_keys_and_the_start_frame_keep_the_cache(fc):
    """Scrubbing with the arrow keys over cached frames, to a frame before the start
    and back, shows each frame from the cache: nothing is dropped (a depsgraph update
    at frame 0 used to drop every frame, as 'before the start')."""
    scene, hair, out, colliders = shot(fc)
    rt = fc.store.registry.get_runtime(hair)
    ref = {}
    for f in range(1, 11):
        scene.frame_set(f)
        ref[f] = positions(out).copy()
    for f in (9, 8, 3, 2, 1, 0, 1, 2):
        arrow_key(scene, f)
        assert sorted(rt.cache.memory.frames) == list(range(1, 11)), f
        if f >= 1:
            assert rt.report.stats["source"] == "cache", f
            np.testing.assert_array_equal(positions(out), ref[f], err_msg=f"frame {f}")
            assert not hair.furcollide.is_outdated
    play_like_the_app(scene, hair, out, colliders, range(2, 11))


def test_a_collider_moved_by_hand_during_a_pause_still_drops_the_cache(fc):
    """An edit is still an edit: the Ball moved along z (not keyed) at cached frame 5
    reports the same kind of update, but frame 5's inputs changed: the playback cache
    is dropped and the status says so; following it gives a clean play."""
    scene, hair, out, colliders = shot(fc)
    rt = fc.store.registry.get_runtime(hair)
    for f in range(1, 11):
        scene.frame_set(f)
    arrow_key(scene, 5)
    ball = colliders[0]
    ball.location.z = 0.45
    bpy.context.view_layer.update()
    s = hair.furcollide
    assert len(rt.cache.memory) == 0 and s.is_outdated
    assert s.status_message == ("Frame 5 is outdated: 'Ball' moved. The playback cache is "
                                "dropped: go to frame 1 and play, or press Bake.")
    arrow_key(scene, 6)
    assert s.is_outdated and "('Ball' moved: the playback cache was dropped)" in (
        s.status_message)
    scene.frame_set(1)  # the advice
    got = play_like_the_app(scene, hair, out, colliders, range(1, 11))
    rt2 = fc.store.registry.get_runtime(hair)
    assert sorted(rt2.cache.memory.frames) == list(range(1, 11))
    # what a clean session gives with the ball there from the start
    hair_name = hair.name
    del hair, out
    clean = {}
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene, hair, out, colliders = shot(fc)
    colliders[0].location.z = 0.45
    for f in range(1, 11):
        scene.frame_set(f)
        clean[f] = positions(out).copy()
    assert hair.name == hair_name
    for f in got:
        np.testing.assert_array_equal(got[f], clean[f], err_msg=f"frame {f}")


def test_the_depsgraph_check_never_raises(fc, monkeypatch, capsys):
    """A failure inside the check is one console line naming the setup, never an
    exception into Blender, and the other setups are still checked."""
    scene, hair, out, colliders = shot(fc)
    for f in range(1, 4):
        scene.frame_set(f)

    def broken(*_a, **_k):
        raise RuntimeError("simulated failure")

    monkeypatch.setattr(fc.store.invalidation, "edit_seen", broken)
    colliders[0].location.z = 0.45
    bpy.context.view_layer.update()  # must not raise
    assert "depsgraph update check failed: simulated failure" in capsys.readouterr().out
