"""The stages around the solver in the frame handler: wind and jiggle before or after
collision, Region of Influence, the per-frame Fur Collider Distance attribute, Fur
Attach unbind and the render groom (guide deform + clearance pass)."""

import bpy
import numpy as np
import pytest
from conftest import make_box, make_hair, make_surface, render_camera

pytestmark = pytest.mark.blender

HALF = 0.25  # make_box(size=0.5)


def segments_in_box(P, offsets, center, half=HALF, shrink=1e-4):
    """Indices of curves with a segment meeting the axis-aligned box (slab test)."""
    lo = np.asarray(center, np.float64) - half + shrink
    hi = np.asarray(center, np.float64) + half - shrink
    P = np.asarray(P, np.float64)
    sizes = np.diff(offsets)
    curve = np.repeat(np.arange(len(sizes)), sizes - 1)
    s0 = np.arange(len(curve)) + curve  # first point of every segment
    a, d = P[s0], P[s0 + 1] - P[s0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - a) / d
        t2 = (hi - a) / d
    inside_slab = (a >= lo) & (a <= hi)  # d == 0 on an axis: inside that slab or never
    tmin = np.where(d == 0, np.where(inside_slab, -np.inf, np.inf), np.minimum(t1, t2))
    tmax = np.where(d == 0, np.where(inside_slab, np.inf, -np.inf), np.maximum(t1, t2))
    t0 = np.maximum(tmin.max(1), 0.0)
    t_1 = np.minimum(tmax.min(1), 1.0)
    hit = t0 <= t_1
    return np.unique(curve[hit])


def world(ob):
    d = ob.data
    P = np.empty(len(d.points) * 3, np.float32)
    d.position_data.foreach_get("vector", P)
    P = P.reshape(-1, 3).astype(np.float64)
    M = np.array(ob.matrix_world)
    return P @ M[:3, :3].T + M[:3, 3]


def offsets_of(ob):
    n = len(ob.data.curves)
    offs = np.zeros(n + 1, np.int32)
    ob.data.curve_offset_data.foreach_get("value", offs)
    return offs


def box_scene(fc, location=(0.0, 0.0, 0.6), frames=(1, 8)):
    """Hair grid (6 x 6, 1 long) and a static box in it; a setup on the hair."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    scene.frame_set(frames[0])
    hair = make_hair()
    box = make_box(location=location)
    out = fc.setup(hair, [box])
    return hair, box, out


def play(scene, frames):
    for f in frames:
        scene.frame_set(f)


# ------------------------------------------------------------------ wind
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
    rt = fc.registry.get_runtime(hair)
    assert 3 in rt.memory
    hair.furcollide.motion.use_wind = True
    assert len(rt.memory) == 0
    scene.frame_set(1)
    before = world(out)
    hair.furcollide.motion.wind_strength = 0.3
    scene.frame_set(1)
    assert not np.array_equal(world(out), before)


# ---------------------------------------------------------------- jiggle
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


# ------------------------------------------------------ collider distance
def test_collider_distance_attribute_every_frame_and_cached(fc):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 8))
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


def _box_mesh(ob):
    me = ob.data
    V = np.array([ob.matrix_world @ v.co for v in me.vertices], np.float64)
    me.calc_loop_triangles()
    F = np.array([t.vertices[:] for t in me.loop_triangles], np.int64)
    return V, F


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
    d = fc.bake.bake_directory(hair)
    attrs = fc.cache.read_attributes(d, 3)
    assert "furcollide_collider_distance" in attrs
    scene.frame_set(3)
    a = out.data.attributes["furcollide_collider_distance"]
    got = np.empty(len(a.data), np.float32)
    a.data.foreach_get("value", got)
    np.testing.assert_array_equal(got, attrs["furcollide_collider_distance"])


# ------------------------------------------------------------ Fur Attach
def test_fur_attach_unbind(fc):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 4
    scene.frame_set(1)
    hair = make_hair(nx=3, ny=3)
    surf = make_surface(n=4, uv=False)
    hair.data.surface = surf
    out = fc.setup(hair, [make_box(location=(5, 5, 5))])
    bpy.context.view_layer.objects.active = hair
    assert not bpy.ops.furcollide.fur_attach_unbind.poll()
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    surf.location = (0, 0, 1.0)  # the attached curves follow the surface
    scene.frame_set(1)
    assert abs(world(out)[0, 2] - 1.0) < 1e-5
    assert bpy.ops.furcollide.fur_attach_unbind() == {"FINISHED"}
    assert not hair.furcollide.use_fur_attach
    assert not fc.fur_attach.has_binding(hair)
    scene.frame_set(1)
    assert abs(world(out)[0, 2]) < 1e-6  # back to the source's own curves


# ------------------------------------------------------------ render groom
def groom_scene(fc):
    """Guides (5 x 5) and a dense groom (12 x 12) on one Surface, a box collider."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    surf = make_surface(half=1.2, n=6, uv=False)
    guides = make_hair("Guides", nx=5, ny=5, spacing=0.3)
    groom = make_hair("Groom", nx=12, ny=12, spacing=0.1)
    guides.data.surface = surf
    groom.data.surface = surf
    box = make_box(location=(-2.0, 0, 0.6))
    box.keyframe_insert("location", frame=1)
    box.location = (0.05, 0.05, 0.6)
    box.keyframe_insert("location", frame=6)
    scene.frame_set(1)
    out = fc.setup(guides, [box])
    guides.furcollide.frame_end = 8
    guides.furcollide.groom.groom = groom
    bpy.context.view_layer.objects.active = guides
    return guides, groom, box, out


def test_render_groom_follows_guides_with_clearance(fc):
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    groom_before = world(groom)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    g = guides.furcollide.groom
    gout = g.output
    assert gout is not None and gout != groom
    assert groom.hide_render
    roff = offsets_of(gout)
    # at the reference pose the guides do not collide: identity
    np.testing.assert_allclose(world(gout), groom_before, atol=1e-5)
    play(scene, range(1, 8))
    P = world(gout)
    assert np.abs(P - groom_before).max() > 0.05  # the groom follows the guides
    assert len(segments_in_box(P, roff, box.matrix_world.translation)) == 0
    np.testing.assert_allclose(P[roff[:-1]], groom_before[roff[:-1]], atol=1e-5)  # roots
    np.testing.assert_array_equal(world(groom), groom_before)  # the groom is untouched
    fixed_on = guides.furcollide.stat_groom_fixed
    # without the clearance pass, the blend between guides leaves render curves inside
    g.use_clearance = False
    scene.frame_set(6)
    scene.frame_set(7)
    crossing = segments_in_box(world(gout), roff, box.matrix_world.translation)
    assert len(crossing) > 0
    assert fixed_on >= len(crossing) > 0  # the pass reported the curves it fixed


def test_render_groom_remove_restores_the_groom(fc):
    guides, groom, box, out = groom_scene(fc)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    name = guides.furcollide.groom.output.name
    assert bpy.ops.furcollide.groom_remove() == {"FINISHED"}
    assert bpy.data.objects.get(name) is None
    assert not groom.hide_render
    assert guides.furcollide.groom.output is None
    assert not bpy.ops.furcollide.groom_remove.poll()


def test_render_groom_bind_refuses_the_guides_themselves(fc):
    guides, groom, box, out = groom_scene(fc)
    guides.furcollide.groom.groom = guides
    assert not bpy.ops.furcollide.groom_bind.poll()


def test_pipeline_panel_draws_the_stages(fc):
    from test_bl_pipeline import _draw

    guides, groom, box, out = groom_scene(fc)
    panel = bpy.types.FURCOLLIDE_PT_pipeline
    log = _draw(panel)
    for idname in ("furcollide.fur_attach_unbind", "furcollide.groom_bind",
                   "furcollide.groom_remove"):
        assert ("operator", idname) in log
    for name in ("use_wind", "wind_stage", "wind_strength", "use_jiggle", "jiggle_stage",
                 "use_region_of_influence", "roi_margin", "write_collider_distance",
                 "distance_max", "groom", "use_clearance"):
        assert ("prop", name) in log
    assert ("label", "Restricts motion After Collision (none is on)") in log
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    guides.furcollide.motion.use_wind = True
    guides.furcollide.motion.use_region_of_influence = False
    log = _draw(panel)
    assert any(k == "label" and v and v.startswith("Render curves fixed") for k, v in log)
    assert ("label", "Motion after collision may push hair into colliders") in log


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
    real = fc.motion.output_stage

    def boom(*a, **k):
        raise ValueError("stage exploded")

    monkeypatch.setattr(fc.motion, "output_stage", boom)
    scene.frame_set(5)
    assert "stage exploded" in hair.furcollide.status_message
    monkeypatch.setattr(fc.motion, "output_stage", real)
    scene.frame_set(5)
    np.testing.assert_array_equal(world(out), clean)


def test_clearance_pass_keeps_the_setup_collision_offset(fc):
    """Render curves freed by the clearance pass keep the setup's Collision Offset from
    the collider, like the guides."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    guides.furcollide.collision_offset = 0.05
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    play(scene, range(1, 8))
    gout = guides.furcollide.groom.output
    roff = offsets_of(gout)
    center = box.matrix_world.translation
    # inside the box grown by most of the offset: no segment
    assert len(segments_in_box(world(gout), roff, center, half=HALF + 0.04)) == 0
    assert guides.furcollide.stat_groom_fixed > 0


def test_render_groom_renders_every_frame_with_the_guides_hidden(fc, tmp_path):
    """The usual render set-up: only the render groom is rendered (the guides,
    their FurCollide output, the groom source and the collider are hidden from
    render). Every rendered frame still shows that frame's render groom."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    for o in (guides, out, groom, box):
        o.hide_render = True
    assert not gout.hide_render
    scene.frame_start, scene.frame_end = 1, 7
    render_camera(scene)
    scene.render.filepath = str(tmp_path / "groom_####")
    seen = {}

    def spy(sc, depsgraph):  # runs after FurCollide's handler
        if depsgraph is not None and depsgraph.mode == "RENDER":
            seen[sc.frame_current] = world(gout).copy()

    scene.frame_set(1)
    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    assert sorted(seen) == list(range(1, 8))
    assert guides.furcollide.status_message == ""
    moved = 0
    for f in range(1, 8):
        scene.frame_set(f)
        np.testing.assert_array_equal(world(gout), seen[f], err_msg=f"frame {f}")
        moved += int(not np.array_equal(seen[f], seen[1]))
    assert moved > 0  # the render groom moved with the guides


def test_render_groom_output_of_an_older_file_gets_its_inputs_on_load(fc, tmp_path):
    guides, groom, box, out = groom_scene(fc)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    name = fc.dependencies.DEPENDENCY_MODIFIER
    assert gout.modifiers[0].name == name  # the bind gives it the modifier
    gout.modifiers.remove(gout.modifiers[name])  # as saved by an earlier version
    path = str(tmp_path / "old.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    gout = bpy.data.objects["Guides"].furcollide.groom.output
    assert gout.modifiers[0].name == name
    guides_out = bpy.data.objects["Guides FurCollide"]
    assert gout.modifiers[0].node_group == guides_out.modifiers[0].node_group


def test_render_groom_panel_hints_bind_again_after_guides_per_curve_changes(fc):
    from test_bl_pipeline import _draw

    guides, groom, box, out = groom_scene(fc)
    g = guides.furcollide.groom
    g.guides = 3
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    panel = bpy.types.FURCOLLIDE_PT_pipeline
    hint = ("label", "Bound with 3: press Bind Groom again")
    assert hint not in _draw(panel)
    g.guides = 5
    assert hint in _draw(panel)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    assert ("label", "Bound with 5: press Bind Groom again") not in _draw(panel)
