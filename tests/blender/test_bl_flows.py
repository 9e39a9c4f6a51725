"""Artist / TD flows across features: motion-blur renders, a render groom over a
bake, colliders edited after binding a groom, removing a setup with a groom, a
duplicated setup object, hiding a setup while playing, and a Fur Attach setup
rendered with its growth surface hidden from render."""

import bpy
import numpy as np
import pytest
from conftest import activate, make_box, make_hair, make_surface, render_camera
from test_bl_attach import animate_transform, bind
from test_bl_stages import groom_scene, play, world

pytestmark = pytest.mark.blender

INPUTS = "FurCollide Inputs"


# ------------------------------------------------------------------ helpers
def _render(tmp_path, tag, watch, setup):
    """Render the animation; record every RENDER-depsgraph frame change (after
    FurCollide's handler): ``{(frame, subframe): [{name: world points}, ...]}`` and
    the setup's status message at each of them."""
    scene = bpy.context.scene
    scene.render.filepath = str(tmp_path / f"{tag}_####")
    seen, statuses = {}, []

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            key = (sc.frame_current, round(sc.frame_subframe, 3))
            seen.setdefault(key, []).append({o.name: world(o).copy() for o in watch})
            statuses.append((key, setup.furcollide.status_message))

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    return seen, statuses


def _check_render(seen, statuses, watch, frames):
    """Every rendered whole frame equals the viewport at that frame; nothing failed."""
    assert [s for s in statuses if s[1]] == [], "status set during the render"
    whole = sorted(k[0] for k in seen if k[1] == 0.0)
    assert sorted(set(whole)) == list(frames)
    scene = bpy.context.scene
    viewport = {}
    for f in frames:
        scene.frame_set(f)
        viewport[f] = {o.name: world(o).copy() for o in watch}
        for snap in seen[(f, 0.0)]:
            for o in watch:
                np.testing.assert_array_equal(snap[o.name], viewport[f][o.name],
                                              err_msg=f"{o.name} frame {f}")
    return viewport


def _node_objects(ob):
    mod = ob.modifiers[0]
    assert mod.name == INPUTS, [m.name for m in ob.modifiers]
    return {n.inputs["Object"].default_value for n in mod.node_group.nodes
            if n.bl_idname == "GeometryNodeObjectInfo"}


# --------------------------------------------------- 1. motion blur renders
@pytest.mark.parametrize("engine", ["BLENDER_WORKBENCH", "CYCLES"])
def test_motion_blur_render_plain_setup(fc, tmp_path, engine):
    """Workbench ignores motion blur; Cycles sets subframes (frame - 0.25, frame +
    0.25) through the frame handler, which must never step there."""
    hair, box = fc.make_scene(frames=(1, 4), nx=5, ny=5)
    out = fc.setup(hair, [box])
    scene = bpy.context.scene
    render_camera(scene, engine)
    scene.render.use_motion_blur = True
    box.hide_render = True
    seen, statuses = _render(tmp_path, "mb", [out], hair)
    assert hair.furcollide.status_message == ""
    viewport = _check_render(seen, statuses, [out], range(1, 5))
    # subframes keep the whole frame being rendered (README: "Never steps")
    for (f, sub), snaps in seen.items():
        if sub:
            whole = f + 1 if sub > 0.5 else f
            for snap in snaps:
                np.testing.assert_array_equal(snap[out.name], viewport[whole][out.name])
    if engine == "CYCLES":
        assert any(sub for _f, sub in seen), "Cycles did not render motion steps"
    assert any(not np.array_equal(viewport[f][out.name], viewport[1][out.name])
               for f in range(2, 5))
    # the same as a fresh play in the viewport
    bpy.context.view_layer.objects.active = hair
    bpy.ops.furcollide.reset()
    for f in range(1, 5):
        scene.frame_set(f)
        np.testing.assert_array_equal(world(out), viewport[f][out.name], err_msg=f"{f}")


@pytest.mark.parametrize("engine", ["BLENDER_WORKBENCH", "CYCLES"])
def test_motion_blur_render_groom(fc, tmp_path, engine):
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    for o in (guides, out, groom, box):
        o.hide_render = True
    scene.frame_start, scene.frame_end = 1, 6
    render_camera(scene, engine)
    scene.render.use_motion_blur = True
    scene.frame_set(1)
    seen, statuses = _render(tmp_path, "mbg", [out, gout], guides)
    assert guides.furcollide.status_message == ""
    viewport = _check_render(seen, statuses, [out, gout], range(1, 7))
    for (f, sub), snaps in seen.items():
        if sub:
            whole = f + 1 if sub > 0.5 else f
            for snap in snaps:
                np.testing.assert_array_equal(snap[gout.name], viewport[whole][gout.name])
    assert any(not np.array_equal(viewport[f][gout.name], viewport[1][gout.name])
               for f in range(2, 7))


# ------------------------------------------------ 2. render groom over a bake
@pytest.mark.parametrize("order", ["bind_then_bake", "bake_then_bind"])
def test_render_groom_of_a_baked_setup_with_guides_hidden(fc, tmp_path, order):
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    guides.furcollide.frame_end = 6
    scene.frame_start, scene.frame_end = 1, 6
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "groom.blend"))
    activate(guides)
    if order == "bind_then_bake":
        assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
        assert bpy.ops.furcollide.bake() == {"FINISHED"}
    else:
        assert bpy.ops.furcollide.bake() == {"FINISHED"}
        scene.frame_set(1)
        assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    assert guides.furcollide.is_baked
    gout = guides.furcollide.groom.output
    for o in (guides, out, groom, box):
        o.hide_render = True
    render_camera(scene)
    scene.frame_set(1)
    seen, statuses = _render(tmp_path, "baked", [gout], guides)
    assert guides.furcollide.status_message == ""
    viewport = _check_render(seen, statuses, [gout], range(1, 7))
    assert any(not np.array_equal(viewport[f][gout.name], viewport[1][gout.name])
               for f in range(2, 7))


# ------------------------------------ 3. colliders changed after a groom bind
def _groom_bound(fc):
    guides, groom, box, out = groom_scene(fc)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    play(bpy.context.scene, range(1, 4))
    new = make_box("Wall", location=(0.0, 1.0, 0.6))
    return guides, out, guides.furcollide.groom.output, box, new


def _same_inputs(out, gout, must_have):
    assert gout.modifiers[0].name == INPUTS
    assert gout.modifiers[0].node_group == out.modifiers[0].node_group
    have = _node_objects(gout)
    assert must_have <= have, (must_have, have)
    assert _node_objects(out) == have


def test_collider_added_after_groom_bind_reaches_the_groom_inputs(fc):
    guides, out, gout, box, new = _groom_bound(fc)
    activate(guides, new)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    _same_inputs(out, gout, {guides, box, new})


def test_collider_replaced_after_groom_bind_reaches_the_groom_inputs(fc):
    guides, out, gout, box, new = _groom_bound(fc)
    guides.furcollide.colliders[0].object = new
    _same_inputs(out, gout, {guides, new})
    assert box not in _node_objects(gout)


def test_collider_collection_after_groom_bind_reaches_the_groom_inputs(fc):
    guides, out, gout, box, new = _groom_bound(fc)
    coll = bpy.data.collections.new("Colliders")
    bpy.context.scene.collection.children.link(coll)
    coll.objects.link(new)
    guides.furcollide.collider_collection = coll
    _same_inputs(out, gout, {guides, box, new})


def test_collider_added_after_reopening_the_file_reaches_the_groom_inputs(fc, tmp_path):
    """The next day: open the file (nothing in memory yet) and add a collider."""
    guides, out, gout, box, new = _groom_bound(fc)
    path = str(tmp_path / "groom.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    guides, new = bpy.data.objects["Guides"], bpy.data.objects["Wall"]
    out, gout = guides.furcollide.output, guides.furcollide.groom.output
    activate(guides, new)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    play(bpy.context.scene, range(1, 3))
    assert [c.object for c in guides.furcollide.colliders][-1] == new
    _same_inputs(out, gout, {guides, bpy.data.objects["Box"], new})


def test_mesh_linked_into_the_collider_collection_reaches_the_groom_inputs(fc):
    """The collection is set first; a mesh linked into it later collides (it is read
    every frame) and must be evaluated for both outputs in renders too."""
    guides, out, gout, box, new = _groom_bound(fc)
    coll = bpy.data.collections.new("Colliders")
    bpy.context.scene.collection.children.link(coll)
    guides.furcollide.collider_collection = coll
    play(bpy.context.scene, range(1, 3))
    coll.objects.link(new)
    bpy.context.view_layer.update()
    play(bpy.context.scene, range(1, 4))
    assert new in {r.object for r in fc.colliders.collider_objects(guides)}
    _same_inputs(out, gout, {guides, box, new})


def test_render_groom_renders_a_collider_added_after_the_bind(fc, tmp_path):
    """The added collider moves through the groom and is hidden from render with
    everything else but the groom output: the render matches the viewport."""
    scene = bpy.context.scene
    guides, out, gout, box, new = _groom_bound(fc)
    box.location = (5, 5, 5)  # only the new wall matters
    new.location = (0.0, -2.0, 0.6)
    new.keyframe_insert("location", frame=1)
    new.location = (0.05, 0.05, 0.6)
    new.keyframe_insert("location", frame=6)
    activate(guides, new)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    for o in (guides, out, guides.furcollide.groom.groom, box, new):
        o.hide_render = True
    scene.frame_start, scene.frame_end = 1, 6
    render_camera(scene)
    scene.frame_set(1)
    seen, statuses = _render(tmp_path, "wall", [gout], guides)
    viewport = _check_render(seen, statuses, [gout], range(1, 7))
    assert any(not np.array_equal(viewport[f][gout.name], viewport[1][gout.name])
               for f in range(2, 7))


# ------------------------------------------ 4. remove a setup with a groom
def test_remove_setup_with_render_groom(fc):
    guides, groom, box, out = groom_scene(fc)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    play(bpy.context.scene, range(1, 4))
    gout = guides.furcollide.groom.output
    gname, gdata, oname = gout.name, gout.data.name, out.name
    assert groom.hide_render
    activate(guides)
    assert bpy.ops.furcollide.remove() == {"FINISHED"}
    assert bpy.data.objects.get(gname) is None and bpy.data.objects.get(oname) is None
    assert bpy.data.hair_curves.get(gdata) is None
    assert not groom.hide_render and not guides.hide_render
    assert guides.furcollide.groom.output is None
    orphans = [ng.name for ng in bpy.data.node_groups
               if ng.name.startswith(".FurCollide Inputs") and ng.users == 0]
    assert orphans == []
    play(bpy.context.scene, range(4, 6))  # nothing left to run, nothing fails


# ------------------------------------------------ 5. a duplicated setup object
def _duplicate(ob, dx=0.0):
    dup = ob.copy()
    dup.data = ob.data.copy()
    dup.name = ob.name + " Copy"
    dup.location.x += dx
    bpy.context.scene.collection.objects.link(dup)
    return dup


def test_duplicated_setup_errors_and_leaves_the_original_alone(fc):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 6))
    out = fc.setup(hair, [box])
    clean = {}
    for f in range(1, 6):
        scene.frame_set(f)
        clean[f] = world(out).copy()
    bpy.context.view_layer.objects.active = hair
    bpy.ops.furcollide.reset()
    scene.frame_set(1)
    dup = _duplicate(hair, dx=0.3)  # the copy's curves differ from the original's
    for f in range(1, 6):
        scene.frame_set(f)
        level, msg = fc.registry.status_for(dup)
        assert level == "ERROR" and "copy of the setup on 'Fur'" in msg, msg
        assert hair.furcollide.status_message == ""
        np.testing.assert_array_equal(world(out), clean[f], err_msg=f"frame {f}")
    assert out.furcollide.source == hair


def test_remove_on_a_duplicate_keeps_the_original_output(fc):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 6))
    out = fc.setup(hair, [box])
    name = out.name
    dup = _duplicate(hair)
    scene.frame_set(2)
    assert "copy of the setup on 'Fur'" in dup.furcollide.status_message
    activate(dup)
    bpy.ops.furcollide.remove()
    assert name in bpy.data.objects, "the original's output was deleted"
    assert hair.furcollide.output == bpy.data.objects[name]
    scene.frame_set(1)
    scene.frame_set(2)
    assert hair.furcollide.status_message == ""


def test_add_on_a_duplicated_groom_setup_leaves_the_original_groom_alone(fc):
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    ng = gout.modifiers[0].node_group
    play(scene, range(1, 5))
    ref = world(gout).copy()
    scene.frame_set(1)
    dup = _duplicate(guides, dx=0.4)
    dup.data.surface = None
    scene.frame_set(2)
    assert "copy of the setup on 'Guides'" in dup.furcollide.status_message
    activate(dup, box)
    assert bpy.ops.furcollide.add() == {"FINISHED"}  # README: gives it its own output
    assert dup.furcollide.output not in (None, out)
    assert gout.modifiers[0].node_group == ng
    assert dup not in _node_objects(gout)
    play(scene, range(1, 5))
    np.testing.assert_array_equal(world(gout), ref)


# ------------------------------------------------ 6. hidden while playing
@pytest.mark.parametrize("with_groom", [False, True])
def test_hide_while_playing_then_show_and_jump(fc, with_groom):
    scene = bpy.context.scene
    if with_groom:
        hair, groom, box, out = groom_scene(fc)
        assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
        gout = hair.furcollide.groom.output
        watched = [out, gout]
    else:
        hair, box = fc.make_scene(frames=(1, 8))
        out = fc.setup(hair, [box])
        gout = None
        watched = [out]
    fresh = {}
    for f in range(1, 8):
        scene.frame_set(f)
        fresh[f] = [world(o).copy() for o in watched]
    assert any(not np.array_equal(fresh[f][0], fresh[1][0]) for f in fresh)
    bpy.context.view_layer.objects.active = hair
    bpy.ops.furcollide.reset()
    scene.frame_set(1)

    def check(f):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        for o, want in zip(watched, fresh[f], strict=True):
            np.testing.assert_array_equal(world(o), want, err_msg=f"{o.name} frame {f}")

    for f in range(1, 4):
        check(f)
    hidden = [hair, out] + ([gout] if gout is not None else [])
    for o in hidden:
        o.hide_viewport = True
    for f in range(4, 6):
        scene.frame_set(f)
        assert hair.furcollide.status_message == ""
    for o in hidden:
        o.hide_viewport = False
    for f in (2, 3, 1, 2, 3, 4, 5, 6, 7, 4, 6):  # cached frames, then on from frame 3
        check(f)


# ------------------------------- 7. Fur Attach with the surface hidden from render
def _attached(fc, surface_first):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 5
    scene.frame_set(1)
    hair = make_hair(nx=4, ny=4)
    surf = make_surface(n=4, uv=False)
    animate_transform(surf, frames=(1, 5))
    wall = make_box("Wall", location=(0.6, 0.0, 0.6))
    scene.frame_set(1)
    if surface_first:
        hair.data.surface = surf
        out = fc.setup(hair, [wall])
    else:  # Add FurCollide first, then give the hair its Surface and Bind
        out = fc.setup(hair, [wall])
        hair.data.surface = surf
    hair.furcollide.frame_start, hair.furcollide.frame_end = 1, 5
    bind(hair)
    return hair, surf, wall, out


@pytest.mark.parametrize("surface_first", [True, False])
def test_fur_attach_render_with_the_surface_hidden(fc, tmp_path, surface_first):
    scene = bpy.context.scene
    hair, surf, wall, out = _attached(fc, surface_first)
    surf.hide_render = True
    wall.hide_render = True
    render_camera(scene)
    scene.frame_set(1)
    seen, statuses = _render(tmp_path, "attach", [out], hair)
    assert hair.furcollide.status_message == ""
    viewport = _check_render(seen, statuses, [out], range(1, 6))
    assert np.abs(viewport[5][out.name] - viewport[1][out.name]).max() > 0.1
    assert surf in _node_objects(out)
