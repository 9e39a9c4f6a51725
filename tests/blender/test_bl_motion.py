"""Wind, jiggle, the Region of Influence and the collider distance attribute: before and
after collision, cached, baked and rendered, jiggle bakes and frames viewed before
the start, Max Distance, a failing stage reported."""

import itertools

import bpy
import numpy as np
import pytest
from helpers import (
    PIPELINE_FRAMES,
    activate,
    bake_crashing_at,
    check_pipeline_frame,
    make_box,
    make_hair,
    no_faces,
    offsets_of,
    pipeline_scene,
    play,
    play_pipeline,
    poly,
    record,
    render_camera,
    reopen,
    same_pipeline_frame,
    save_in,
    segments_in_box,
    world,
)

pytestmark = pytest.mark.blender

STAGES = list(itertools.product(["INPUT", "OUTPUT"], repeat=2))


def attribute(ob, name):
    a = ob.data.attributes[name]
    d = np.empty(len(a.data), np.float32)
    a.data.foreach_get("value", d)
    return d


def _motion_scene(fc, frames=(1, 6)):
    """A 4 x 4 hair grid accelerating along +x (Bezier) through a static box."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    scene.frame_set(frames[0])
    hair = make_hair(nx=4, ny=4)
    hair.location = (0, 0, 0)
    hair.keyframe_insert("location", frame=frames[0])
    hair.location = (1.5, 0, 0)
    hair.keyframe_insert("location", frame=frames[1])
    box = make_box(location=(0.9, 0, 0.6))
    scene.frame_set(frames[0])
    out = fc.setup(hair, [box])
    hair.furcollide.frame_start, hair.furcollide.frame_end = frames
    return scene, hair, box, out


def _jiggle_scene(fc, start=1):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    hair = make_hair(nx=3, ny=3)
    hair.location = (0, 0, 0)
    hair.keyframe_insert("location", frame=1)
    hair.location = (2.0, 0, 0)
    hair.keyframe_insert("location", frame=8)
    scene.frame_set(1)
    out = fc.setup(hair, [make_box(location=(5, 5, 5))])
    s = hair.furcollide
    s.frame_start, s.frame_end = start, 8
    m = s.motion
    m.use_jiggle, m.jiggle_stage = True, "OUTPUT"
    m.jiggle_stiffness, m.jiggle_damping = 1.0, 0.2
    return scene, hair, out


def _wind_setup(fc):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 6), nx=4, ny=4)
    out = fc.setup(hair, [box])
    m = hair.furcollide.motion
    m.use_wind = True
    m.wind_stage = "OUTPUT"
    m.wind_strength = 0.1
    m.wind_frequency = 2.0
    m.wind_turbulence = 1.0
    scene.frame_set(1)
    return scene, hair, out


def box_scene(fc, location=(0.0, 0.0, 0.6), frames=(1, 8)):
    """Hair grid (6 x 6, 1 long) and a static box in it; a setup on the hair."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    scene.frame_set(frames[0])
    hair = make_hair()
    box = make_box(location=location)
    out = fc.setup(hair, [box])
    return hair, box, out


def _box_mesh(ob):
    me = ob.data
    V = np.array([ob.matrix_world @ v.co for v in me.vertices], np.float64)
    me.calc_loop_triangles()
    F = np.array([t.vertices[:] for t in me.loop_triangles], np.int64)
    return V, F


def test_wind_after_collision_region_of_influence_keeps_curves_out(fc):
    """Extreme wind toward a box after collision: without the Region of Influence it
    pushes curves into the box; with it, no segment crosses the box, yet hair moves."""
    scene = bpy.context.scene
    hair, box, out = box_scene(fc, location=(0.45, 0.0, 0.6))
    m = hair.furcollide.motion
    play(scene, range(1, 4))
    collided = world(out)
    offs = offsets_of(out)
    assert len(segments_in_box(collided, offs, box.location)) == 0

    m.use_wind, m.wind_stage = True, "OUTPUT"
    m.wind_direction, m.wind_strength, m.wind_turbulence = (1, 0, 0), 2.0, 0.0
    m.use_region_of_influence = False
    play(scene, range(1, 4))
    assert len(segments_in_box(world(out), offs, box.location)) > 0  # the test has teeth

    m.use_region_of_influence = True
    play(scene, range(1, 4))
    P = world(out)
    assert len(segments_in_box(P, offs, box.location)) == 0
    moved = np.linalg.norm(P - collided, axis=1)
    assert moved.max() > 0.1  # the far curves follow the wind
    np.testing.assert_array_equal(P[offs[:-1]], collided[offs[:-1]])  # roots stay
    # a cached frame shows the same result, bit for bit
    before = out.data.attributes["position"].data[7].vector[:]
    scene.frame_set(2)
    scene.frame_set(3)
    assert out.data.attributes["position"].data[7].vector[:] == before


def test_wind_before_collision_is_resolved_by_furcollide(fc):
    """Wind on the input: FurCollide resolves the blown curves (no crossing) and the
    result differs from the still hair; scrubbing gives the same frame again."""
    scene = bpy.context.scene
    hair, box, out = box_scene(fc, location=(0.5, 0.0, 0.6))
    play(scene, range(1, 5))
    still = world(out)
    m = hair.furcollide.motion
    m.use_wind, m.wind_stage = True, "INPUT"
    m.wind_direction, m.wind_strength = (1, 0, 0), 0.8
    play(scene, range(1, 5))
    P = world(out)
    offs = offsets_of(out)
    assert np.abs(P - still).max() > 0.05
    status = np.empty(len(offs) - 1, np.int8)
    out.data.attributes["furcollide_status"].data.foreach_get("value", status)
    free = np.flatnonzero(~np.isin(status, (3, 4)))  # pinched / unresolved excepted
    bad = segments_in_box(P, offs, box.location)
    assert not np.isin(bad, free).any()
    assert np.count_nonzero(status) > 0  # the wind pushed curves into the box
    # replay from the start gives bit-identical output
    bpy.ops.furcollide.reset()
    play(scene, range(1, 5))
    np.testing.assert_array_equal(world(out), P)


def test_motion_settings_invalidate_the_cache(fc):
    scene = bpy.context.scene
    hair, box, out = box_scene(fc, location=(2.0, 0.0, 0.6))
    play(scene, range(1, 4))
    rt = fc.store.registry.get_runtime(hair)
    assert 3 in rt.cache.memory
    hair.furcollide.motion.use_wind = True
    assert len(rt.cache.memory) == 0
    scene.frame_set(1)
    before = world(out)
    hair.furcollide.motion.wind_strength = 0.3
    scene.frame_set(1)
    assert not np.array_equal(world(out), before)


def test_jiggle_lags_behind_accelerating_roots_and_repeats(fc):
    """Hair accelerating along x: with jiggle its tips lag (opposite to the
    acceleration) while roots follow the source; a replay repeats it exactly."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 12
    scene.frame_set(1)
    hair = make_hair(nx=3, ny=3)
    far = make_box(location=(5, 5, 5))
    hair.location = (0, 0, 0)
    hair.keyframe_insert("location", frame=1)
    hair.location = (2.0, 0, 0)
    hair.keyframe_insert("location", frame=12)  # Bezier: accelerates, then brakes
    out = fc.setup(hair, [far])
    m = hair.furcollide.motion
    m.use_jiggle, m.jiggle_stage, m.jiggle_amount = True, "OUTPUT", 1.0
    m.jiggle_stiffness, m.jiggle_damping = 1.0, 0.2
    play(scene, range(1, 6))
    P = world(out)
    src = world(hair)
    offs = offsets_of(out)
    np.testing.assert_allclose(P[offs[:-1]], src[offs[:-1]], atol=1e-5)
    tips = offs[1:] - 1
    lag = P[tips, 0] - src[tips, 0]
    assert (lag < -1e-3).all()  # accelerating +x: the tips trail behind
    bpy.ops.furcollide.reset()
    play(scene, range(1, 6))
    np.testing.assert_array_equal(world(out), P)


def test_collider_distance_attribute_every_frame_and_cached(fc):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 8))
    poly(hair)  # (touching curves: distance 0, whatever the field's cells)
    out = fc.setup(hair, [box])
    m = hair.furcollide.motion
    m.write_collider_distance = True
    dists = {}
    for f in range(1, 6):
        scene.frame_set(f)
        a = out.data.attributes.get("furcollide_collider_distance")
        assert a is not None and a.domain == "POINT"
        d = np.empty(len(a.data), np.float32)
        a.data.foreach_get("value", d)
        dists[f] = d
        # matches the core on the collided curves (no motion here)
        col = fc.core.Collider(*_box_mesh(box))
        ref = fc.core.pipeline.collider_distance(world(out), offsets_of(out), [col])
        np.testing.assert_allclose(d, ref, rtol=1e-5, atol=1e-6)
    assert not np.array_equal(dists[1], dists[5])  # follows the moving box
    scene.frame_set(3)  # a cached frame restores its own distances
    a = out.data.attributes["furcollide_collider_distance"]
    d = np.empty(len(a.data), np.float32)
    a.data.foreach_get("value", d)
    np.testing.assert_array_equal(d, dists[3])


def test_collider_distance_attribute_is_baked(fc, tmp_path):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 4))
    out = fc.setup(hair, [box])
    hair.furcollide.frame_end = 4
    hair.furcollide.motion.write_collider_distance = True
    hair.furcollide.cache_directory = str(tmp_path)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "d.blend"))
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = fc.store.bake.bake_directory(hair)
    attrs = fc.cache.read_attributes(d, 3)
    assert "furcollide_collider_distance" in attrs
    scene.frame_set(3)
    a = out.data.attributes["furcollide_collider_distance"]
    got = np.empty(len(a.data), np.float32)
    a.data.foreach_get("value", got)
    np.testing.assert_array_equal(got, attrs["furcollide_collider_distance"])


def test_a_failing_stage_is_reported_and_the_frame_solves_again(fc, monkeypatch):
    """A stage error is the setup's status (the handler never raises); the solver state
    is not mistaken for the previous frame's: solving the frame again gives the result of
    an uninterrupted run."""
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 6))
    out = fc.setup(hair, [box])
    hair.furcollide.motion.write_collider_distance = True
    play(scene, range(1, 6))
    clean = world(out)
    bpy.ops.furcollide.reset()
    play(scene, range(1, 5))
    stages = fc.core.pipeline.frame  # (the core's frame sequence: motion after collision)
    real = stages.after_collision

    def boom(*a, **k):
        raise ValueError("stage exploded")

    monkeypatch.setattr(stages, "after_collision", boom)
    scene.frame_set(5)
    assert "stage exploded" in hair.furcollide.status_message
    monkeypatch.setattr(stages, "after_collision", real)
    scene.frame_set(5)
    np.testing.assert_array_equal(world(out), clean)


@pytest.mark.parametrize("wind_stage,jiggle_stage", STAGES,
                         ids=[f"wind_{w}-jiggle_{j}" for w, j in STAGES])
def test_motion_stages_bake_then_render_match_the_viewport(fc, tmp_path, capsys, wind_stage,
                                                           jiggle_stage):
    scene, hair, box, out = _motion_scene(fc)
    still = {}  # no motion
    for f in range(1, 7):
        scene.frame_set(f)
        still[f] = world(out).copy()
    m = hair.furcollide.motion
    m.use_wind, m.wind_stage, m.wind_strength = True, wind_stage, 0.3
    m.use_jiggle, m.jiggle_stage = True, jiggle_stage
    m.jiggle_stiffness, m.jiggle_damping = 1.0, 0.2
    live = {}
    for f in range(1, 7):
        scene.frame_set(f)
        assert fc.store.report.status_for(hair) == ("INFO", ""), f
        live[f] = world(out).copy()
    assert max(np.abs(live[f] - still[f]).max() for f in range(2, 7)) > 0.02
    save_in(tmp_path)
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert hair.furcollide.is_baked
    viewport = {}
    for f in range(1, 7):
        scene.frame_set(f)
        viewport[f] = world(out).copy()
        np.testing.assert_allclose(viewport[f], live[f], atol=1e-5, err_msg=f"frame {f}")
    # render frames 3..5 (only the output visible)
    for o in (hair, box):
        o.hide_render = True
    render_camera(scene)
    scene.frame_start, scene.frame_end = 3, 5
    scene.render.filepath = str(tmp_path / "motion_####")
    seen = {}

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            seen[sc.frame_current] = (world(out).copy(), fc.store.report.status_for(hair))

    scene.frame_set(1)
    capsys.readouterr()
    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    log = capsys.readouterr()
    assert "Traceback" not in log.out + log.err
    assert sorted(seen) == [3, 4, 5]
    for f, (P, status) in seen.items():
        assert status == ("INFO", ""), (f, status)
        np.testing.assert_array_equal(P, viewport[f], err_msg=f"frame {f}")
    for f in (3, 4, 5):  # and the viewport afterwards still shows the same frames
        scene.frame_set(f)
        np.testing.assert_array_equal(world(out), viewport[f])


def test_jiggle_bake_started_mid_range_starts_over_at_the_start_frame(fc, tmp_path, capsys,
                                                                      monkeypatch):
    """README: "A bake with jiggle always starts over at the start frame instead of
    resuming" -- pressed mid-range, or after an interrupted bake."""
    scene, hair, out = _jiggle_scene(fc)
    save_in(tmp_path)
    scene.frame_set(5)  # mid-range, never played
    activate(hair)
    capsys.readouterr()
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    log = capsys.readouterr().out
    assert "frame 1 (1/8)" in log and "(8 frames solved)" in log, log
    assert scene.frame_current == 5  # the frame is restored
    d = bpy.path.abspath(hair.furcollide.bake_path)
    baked = {f: fc.cache.read_frame(d, f)[0] for f in range(1, 9)}
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    # the bake equals a play from the start frame
    for f in range(1, 9):
        scene.frame_set(f)
        np.testing.assert_allclose(world(out), baked[f], atol=1e-5, err_msg=f"frame {f}")
    assert np.abs(baked[5] - baked[1]).max() > 0.1

    # interrupted at frame 5, then Bake again: jiggle starts over, it never resumes
    scene.frame_set(3)
    bake_crashing_at(fc, monkeypatch, 5, match="frame 5: .*simulated crash.*bake again to resume")
    assert fc.cache.list_frames(d) == [1, 2, 3, 4] and not hair.furcollide.is_baked
    capsys.readouterr()
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    log = capsys.readouterr().out
    assert "resuming" not in log and "(8 frames solved)" in log, log
    for f in range(1, 9):
        np.testing.assert_array_equal(fc.cache.read_frame(d, f)[0], baked[f], err_msg=f"{f}")


def test_jiggle_bake_does_not_depend_on_frames_viewed_before_the_start(fc, tmp_path):
    scene, hair, out = _jiggle_scene(fc, start=4)  # the hair already moves at 1..3
    save_in(tmp_path)
    activate(hair)
    scene.frame_set(4)
    fc.store.registry.clear_runtime(hair)  # a fresh session
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    fresh = {f: fc.cache.read_frame(d, f)[0] for f in range(4, 9)}
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    play(scene, (1, 2, 3))  # the artist looked at the frames before the start
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    for f in range(4, 9):
        np.testing.assert_allclose(fc.cache.read_frame(d, f)[0], fresh[f], atol=1e-5,
                                   err_msg=f"frame {f}")


def test_distance_attribute_max_distance_zero_is_exact_and_a_cap_clamps(fc):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 4))
    out = fc.setup(hair, [box])
    m = hair.furcollide.motion
    m.write_collider_distance = True
    assert m.distance_max == 0.0  # the default: exact everywhere
    exact = {}
    for f in range(1, 5):
        scene.frame_set(f)
        assert fc.store.report.status_for(hair) == ("INFO", "")
        d = attribute(out, "furcollide_collider_distance")
        me = box.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
        V = np.array([box.matrix_world @ v.co for v in me.vertices])
        me.calc_loop_triangles()
        F = np.array([t.vertices[:] for t in me.loop_triangles])
        ref = fc.core.pipeline.collider_distance(world(out), offsets_of(out), [(V, F)])
        assert np.isfinite(d).all() and (d >= 0).all()
        np.testing.assert_allclose(d, ref, rtol=1e-5, atol=1e-6)
        exact[f] = d
    assert max(d.max() for d in exact.values()) > 0.3
    cap = 0.1
    m.distance_max = cap
    for f in range(1, 5):
        scene.frame_set(f)
        d = attribute(out, "furcollide_collider_distance")
        assert (d <= np.float32(cap)).all()
        near = exact[f] < 0.5 * cap
        assert near.any() or f < 3
        np.testing.assert_allclose(d[near], exact[f][near], rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(d[exact[f] >= cap], np.float32(cap))
    # a negative Max Distance cannot be entered
    m.distance_max = -1.0
    assert m.distance_max == 0.0


def test_collider_of_zero_faces(fc, capsys):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 6))
    wire = no_faces()
    out = fc.setup(hair, [wire])
    activate(hair)
    # Collider Distance Now: nothing to measure to
    with pytest.raises(RuntimeError, match="The setup of 'Fur' has no enabled collider"):
        bpy.ops.furcollide.collider_distance()
    assert "furcollide_collider_distance" not in out.data.attributes
    # every frame: the setup solves (nothing collides), the attribute is inf (README:
    # inf without colliders) with Max Distance 0 and the cap with a Max Distance
    m = hair.furcollide.motion
    m.write_collider_distance = True
    play(scene, range(1, 4))
    assert fc.store.report.status_for(hair) == ("INFO", "")
    np.testing.assert_allclose(world(out), world(hair), atol=1e-6)
    assert np.isposinf(attribute(out, "furcollide_collider_distance")).all()
    m.distance_max = 0.2
    play(scene, range(1, 4))
    np.testing.assert_array_equal(attribute(out, "furcollide_collider_distance"),
                                  np.float32(0.2))
    # with a real collider next to it, the empty one changes nothing
    s = hair.furcollide
    item = s.colliders.add()
    item.object = box
    m.distance_max = 0.0
    play(scene, range(1, 4))
    assert fc.store.report.status_for(hair) == ("INFO", "")
    with_wire = attribute(out, "furcollide_collider_distance")
    assert np.isfinite(with_wire).all()
    assert bpy.ops.furcollide.collider_distance() == {"FINISHED"}  # Now: the box counts
    np.testing.assert_allclose(attribute(out, "furcollide_collider_distance"), with_wire,
                               rtol=1e-5, atol=1e-6)
    log = capsys.readouterr()
    assert "Traceback" not in log.out + log.err


def test_distance_attribute_without_an_enabled_collider_honours_max_distance(fc):
    hair, box = fc.make_scene(frames=(1, 6))
    out = fc.setup(hair, [box])
    m = hair.furcollide.motion
    m.write_collider_distance, m.distance_max = True, 0.1
    hair.furcollide.colliders[0].enabled = False
    play(bpy.context.scene, range(1, 3))
    assert fc.store.report.status_for(hair) == ("INFO", "")
    np.testing.assert_array_equal(attribute(out, "furcollide_collider_distance"),
                                  np.float32(0.1))


def test_fps_change_with_wind_replays_like_a_clean_solve(fc):
    """Wind after collision depends on time (frame / fps). After the artist changes
    the fps, playing again from the start frame must show the new wind, the same as
    a clean solve (Reset Cache) or a bake would."""
    scene, hair, out = _wind_setup(fc)
    record(scene, out, range(1, 7))
    scene.render.fps = 12
    replay = record(scene, out, range(1, 7))
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    clean = record(scene, out, range(1, 7))
    assert any(not np.array_equal(clean[f][0], clean[1][0]) for f in clean)
    for f in range(2, 7):
        np.testing.assert_array_equal(replay[f][0], clean[f][0], err_msg=f"frame {f}")


# -------------------------------------------------- a pipeline setup
def test_jiggle_saved_and_reopened_mid_playback_then_played_from_the_start(fc, tmp_path):
    """Jiggle after collision on the armature-driven skin: saved at frame 3, reopened,
    played from the start frame: the first session's frames bit for bit (the jiggle
    history is rebuilt from the start)."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = pipeline_scene(fc, "armature")
    m = guides.furcollide.motion
    m.use_jiggle, m.jiggle_amount = True, 2.0
    scene.frame_set(1)
    first = play_pipeline(guides, groom, box)
    scene.frame_set(3)
    reopen(save_in(tmp_path))
    scene = bpy.context.scene
    guides, groom, box = (bpy.data.objects[n] for n in ("Guides", "Groom", "Box"))
    for f in (4, 6):
        scene.frame_set(f)
        check_pipeline_frame(guides, groom, box, what=f"reopened, held frame {f}")
    again = play_pipeline(guides, groom, box)
    for f in PIPELINE_FRAMES:
        same_pipeline_frame(again[f], first[f], f"jiggle, reopened and replayed: frame {f}")
