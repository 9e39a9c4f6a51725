"""The render groom: a dense groom follows the collided guides with its clearance pass,
its output's inputs follow the setup's colliders, renders with the guides hidden,
baked guides, ragged or foreign grooms, Guides per Curve and binding again."""

import bpy
import numpy as np
import pytest
from helpers import (
    HALF,
    INPUTS,
    PIPELINE_FRAMES,
    QUIET,
    RESOLVED,
    activate,
    check_render,
    crossing_unmarked,
    cycles_motion_blur,
    demo_pipeline,
    dependency_objects,
    draw_panel,
    drawn_inside,
    duplicate,
    groom_scene,
    make_box,
    make_surface,
    offsets_of,
    pipeline_frame,
    pipeline_scene,
    pipeline_state,
    play,
    play_pipeline,
    poly,
    positions,
    ragged_groom,
    render_camera,
    render_recording,
    render_watching,
    reopen,
    same_pipeline_frame,
    save_in,
    seg_lengths,
    segments_in_box,
    status_of,
    world,
)

pytestmark = pytest.mark.blender




def _groom_bound(fc):
    guides, groom, box, out = groom_scene(fc)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    play(bpy.context.scene, range(1, 4))
    new = make_box("Wall", location=(0.0, 1.0, 0.6))
    return guides, out, guides.furcollide.groom.output, box, new


def _same_inputs(out, gout, must_have):
    assert gout.modifiers[0].name == INPUTS
    assert gout.modifiers[0].node_group == out.modifiers[0].node_group
    have = dependency_objects(gout)
    assert must_have <= have, (must_have, have)
    assert dependency_objects(out) == have


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


def test_render_groom_drawn_as_catmull_rom_clears_the_collider(fc):
    """A render groom drawn as Catmull-Rom (Blender's default hair type): the curves
    Blender draws through the cleared points dipped into the box once it pressed into
    the groom (20 to 21 drawn points in 8 to 10 of 144 curves, frames 5 to 8, 0
    control points). The clearance pass widens their clearance by their drawn margin:
    no drawn point inside, roots where the groom's are."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    roots = world(groom)[offsets_of(groom)[:-1]]
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    types = fc.blender.bridge.read_splines(gout.data).types
    assert (types == fc.core.splines.CATMULL_ROM).all()
    fixed = 0
    for f in range(1, 9):
        scene.frame_set(f)
        fixed += guides.furcollide.stat_groom_fixed
        assert drawn_inside(gout, [box]) == (0, 0), f"frame {f}"
        np.testing.assert_allclose(world(gout)[offsets_of(gout)[:-1]], roots, atol=1e-5)
    assert fixed > 0


def test_poly_render_groom_is_the_pass_without_a_margin_bit_for_bit(fc, monkeypatch):
    """A Poly render groom is drawn as its points: its clearance pass is the pass
    without splines, bit for bit."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    poly(groom)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    frames = range(1, 9)
    got = [positions(gout).copy() for f in frames if scene.frame_set(f) is None]
    assert guides.furcollide.stat_groom_fixed > 0
    monkeypatch.setattr(fc.frame.groom, "world_splines", lambda *a, **k: None)
    want = [positions(gout).copy() for f in frames if scene.frame_set(f) is None]
    for f, a, b in zip(frames, got, want, strict=True):
        np.testing.assert_array_equal(a, b, err_msg=f"frame {f}")


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
    name = fc.blender.dependencies.DEPENDENCY_MODIFIER
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

    guides, groom, box, out = groom_scene(fc)
    g = guides.furcollide.groom
    g.guides = 3
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    panel = bpy.types.FURCOLLIDE_PT_pipeline

    def text():  # (the panel's labels as read: a hint wraps at the sidebar's width)
        return " ".join(t for kind, t in draw_panel(panel) if kind == "label")

    hint = "Bound with 3: press Bind Groom again"
    assert hint not in text()
    g.guides = 5
    assert hint in text()
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    assert "Bound with 5: press Bind Groom again" not in text()


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
    seen, statuses = render_watching(tmp_path, "mbg", [out, gout], guides)
    assert guides.furcollide.status_message == ""
    viewport = check_render(seen, statuses, [out, gout], range(1, 7))
    for (f, sub), snaps in seen.items():
        if sub:
            whole = f + 1 if sub > 0.5 else f
            for snap in snaps:
                np.testing.assert_array_equal(snap[gout.name], viewport[whole][gout.name])
    assert any(not np.array_equal(viewport[f][gout.name], viewport[1][gout.name])
               for f in range(2, 7))


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
    seen, statuses = render_watching(tmp_path, "baked", [gout], guides)
    assert guides.furcollide.status_message == ""
    viewport = check_render(seen, statuses, [gout], range(1, 7))
    assert any(not np.array_equal(viewport[f][gout.name], viewport[1][gout.name])
               for f in range(2, 7))


def test_collider_added_after_groom_bind_reaches_the_groom_inputs(fc):
    guides, out, gout, box, new = _groom_bound(fc)
    activate(guides, new)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    _same_inputs(out, gout, {guides, box, new})


def test_collider_replaced_after_groom_bind_reaches_the_groom_inputs(fc):
    guides, out, gout, box, new = _groom_bound(fc)
    guides.furcollide.colliders[0].object = new
    _same_inputs(out, gout, {guides, new})
    assert box not in dependency_objects(gout)


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
    assert new in {r.object for r in fc.frame.colliders.collider_objects(guides)}
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
    seen, statuses = render_watching(tmp_path, "wall", [gout], guides)
    viewport = check_render(seen, statuses, [gout], range(1, 7))
    assert any(not np.array_equal(viewport[f][gout.name], viewport[1][gout.name])
               for f in range(2, 7))


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


def test_add_on_a_duplicated_groom_setup_leaves_the_original_groom_alone(fc):
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    ng = gout.modifiers[0].node_group
    play(scene, range(1, 5))
    ref = world(gout).copy()
    scene.frame_set(1)
    dup = duplicate(guides, dx=0.4)
    dup.data.surface = None
    scene.frame_set(2)
    assert "copy of the setup on 'Guides'" in dup.furcollide.status_message
    activate(dup, box)
    assert bpy.ops.furcollide.add() == {"FINISHED"}  # README: gives it its own output
    assert dup.furcollide.output not in (None, out)
    assert gout.modifiers[0].node_group == ng
    assert dup not in dependency_objects(gout)
    play(scene, range(1, 5))
    np.testing.assert_array_equal(world(gout), ref)


def test_render_groom_ragged_groom(fc, capsys):
    scene = bpy.context.scene
    guides, _groom, box, out = groom_scene(fc)
    rg = ragged_groom("Ragged", surf=guides.data.surface)
    ref = world(rg)
    roff = offsets_of(rg)
    assert len(set(np.diff(roff).tolist())) > 3  # really ragged
    guides.furcollide.groom.groom = rg
    activate(guides)
    capsys.readouterr()
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    assert "60 curves of 'Ragged' follow 25 guides" in capsys.readouterr().out
    gout = guides.furcollide.groom.output
    np.testing.assert_array_equal(offsets_of(gout), roff)
    np.testing.assert_allclose(world(gout), ref, atol=1e-5)  # identity at the reference
    moved = 0.0
    for f in range(1, 8):
        scene.frame_set(f)
        assert fc.store.report.status_for(guides) == ("INFO", ""), f
        P = world(gout)
        np.testing.assert_allclose(P[roff[:-1]], ref[roff[:-1]], atol=1e-5)  # roots stay
        np.testing.assert_allclose(seg_lengths(P, roff), seg_lengths(ref, roff), atol=1e-4)
        assert len(segments_in_box(P, roff, box.matrix_world.translation)) == 0, f
        moved = max(moved, float(np.abs(P - ref).max()))
    assert moved > 0.05
    np.testing.assert_array_equal(world(rg), ref)  # the groom itself is untouched
    # "Render curves fixed" counts the render curves the clearance pass moved: on each
    # frame, the curves where the groom output differs from the same frame without
    # the clearance pass (which must be the ones that crossed the box then)
    g = guides.furcollide.groom
    seen_fixed = 0
    for f in (3, 5, 7):
        g.use_clearance = True
        scene.frame_set(f)
        fixed, with_pass = guides.furcollide.stat_groom_fixed, world(gout)
        g.use_clearance = False
        scene.frame_set(f)
        without = world(gout)
        moved_curves = np.logical_or.reduceat((with_pass != without).any(axis=1), roff[:-1])
        assert fixed == int(moved_curves.sum()), (f, fixed, int(moved_curves.sum()))
        crossing = segments_in_box(without, roff, box.matrix_world.translation)
        assert set(crossing.tolist()) <= set(np.flatnonzero(moved_curves).tolist()), f
        seen_fixed = max(seen_fixed, fixed)
    assert seen_fixed > 0  # the pass had work on some frame


def test_render_groom_with_a_one_point_curve_is_refused(fc):
    guides, _groom, box, out = groom_scene(fc)
    bad = ragged_groom("Stubby", surf=guides.data.surface, one_point=3)
    guides.furcollide.groom.groom = bad
    activate(guides)
    n = len(bpy.data.objects)
    with pytest.raises(RuntimeError, match="'Stubby': curve 3 has fewer than 2 points"):
        bpy.ops.furcollide.groom_bind()
    assert len(bpy.data.objects) == n and guides.furcollide.groom.output is None
    assert not bad.hide_render


def test_render_groom_on_another_surface_follows_the_guides(fc, capsys):
    scene = bpy.context.scene
    guides, _groom, box, out = groom_scene(fc)
    other = make_surface("Other", half=1.0, n=3, uv=False)
    rg = ragged_groom("Foreign", surf=other, seed=4)
    ref = world(rg)
    roff = offsets_of(rg)
    guides.furcollide.groom.groom = rg
    activate(guides)
    capsys.readouterr()
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    assert "(roots following the guides)" in capsys.readouterr().out
    gout = guides.furcollide.groom.output
    np.testing.assert_allclose(world(gout), ref, atol=1e-5)
    for f in range(1, 8):
        scene.frame_set(f)
        assert fc.store.report.status_for(guides) == ("INFO", ""), f
        assert len(segments_in_box(world(gout), roff, box.matrix_world.translation)) == 0
    assert np.abs(world(gout) - ref).max() > 0.05
    # the other Surface moving does not move the roots (they follow the guides' roots)
    other.location = (0, 0, 1.0)
    scene.frame_set(1)
    np.testing.assert_allclose(world(gout)[roff[:-1]], ref[roff[:-1]], atol=1e-5)


def test_guides_per_curve_changed_after_binding_keeps_the_old_binding(fc):
    """README: "Bind again after changing Guides per Curve": until then the groom
    keeps its binding (no silent re-bind) and the status says what to press."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    g = guides.furcollide.groom
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    play(scene, range(1, 5))
    before = world(g.output).copy()
    rt = fc.store.registry.get_runtime(guides)
    assert fc.frame.groom.groom_binding(guides, rt).weights.index.shape[1] == 4
    g.guides = 1
    scene.frame_set(3)
    scene.frame_set(4)
    assert fc.store.report.status_for(guides) == (
        "WARNING", "Render groom: Guides per Curve is 1 but the groom was bound with 4: "
        "press Bind Groom again")
    assert fc.frame.groom.groom_binding(guides, rt).weights.index.shape[1] == 4
    np.testing.assert_array_equal(world(g.output), before)
    g.guides = 4
    scene.frame_set(3)
    assert fc.store.report.status_for(guides) == ("INFO", "")


def test_bind_groom_again_after_changing_guides_per_curve(fc):
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    g = guides.furcollide.groom
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    play(scene, range(1, 4))
    g.guides = 1
    scene.frame_set(1)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    play(scene, range(1, 6))
    status_for = fc.store.report.status_for
    assert status_for(guides) == ("INFO", ""), status_for(guides)
    rt = fc.store.registry.get_runtime(guides)
    assert fc.frame.groom.groom_binding(guides, rt).weights.index.shape[1] == 1


def test_threads_is_honoured_by_fur_attach_and_the_render_groom(fc, monkeypatch):
    """The Threads tooltip: with many curves a frame runs Fur Attach, the wind (after
    collision here) and the render groom in two halves at once (the threshold is
    lowered here: the scene is small); Threads 1 (a farm running one Blender per core)
    keeps them on the caller's thread. The frames are the same bit for bit."""
    import sys
    import threading

    from helpers import ADDON

    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    activate(guides)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    m = guides.furcollide.motion
    m.use_wind, m.wind_stage, m.wind_strength = True, "OUTPUT", 0.2
    monkeypatch.setattr(sys.modules[ADDON + ".core.tolerances"], "SPLIT_MIN_ITEMS", 1)
    seen = []  # (stage module, threads, thread idents of the halves)
    for stage in ("attach", "groom", "motion"):
        mod = sys.modules[ADDON + ".core.pipeline." + stage]

        def spy(fn, n, threads, min_n, real=mod.in_two, stage=stage):
            ids = set()

            def half(a, b):
                ids.add(threading.get_ident())
                fn(a, b)

            real(half, n, threads, min_n)
            seen.append((stage, threads, frozenset(ids)))

        monkeypatch.setattr(mod, "in_two", spy)
    frames = {}
    for threads in (2, 1):
        guides.furcollide.threads = threads
        scene.frame_set(1)
        activate(guides)
        assert bpy.ops.furcollide.reset() == {"FINISHED"}
        seen.clear()
        frames[threads] = []
        for f in range(1, 7):
            scene.frame_set(f)
            frames[threads].append((world(out), world(gout)))
        stages = {s for s, *_ in seen}
        assert stages == {"attach", "groom", "motion"}, seen
        me = frozenset({threading.get_ident()})
        if threads == 1:
            assert all(t == 1 and ids == me for _, t, ids in seen), seen
        else:
            assert all(t == 2 and len(ids) == 2 for _, t, ids in seen), seen
    for (a, ga), (b, gb) in zip(frames[2], frames[1], strict=True):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(ga, gb)


# ------------------------------------------------ the same frames every way shown
def _groom_frames(scene, gout, frames):
    rec = {}
    for f in frames:
        scene.frame_set(f)
        rec[f] = (world(gout).copy(), status_of(gout).copy())
    return rec


def _same(rec, scene, gout, frames, what):
    for f in frames:
        scene.frame_set(f)
        np.testing.assert_array_equal(world(gout), rec[f][0], err_msg=f"{what}: frame {f}")
        np.testing.assert_array_equal(status_of(gout), rec[f][1], err_msg=f"{what}: frame {f}")


def test_render_groom_is_the_same_played_scrubbed_baked_and_reopened(fc, tmp_path):
    """The render groom (deform + clearance pass) of each frame is bit for bit the same
    played, scrubbed back and forth, baked, and read from the bake after reopening the
    file; on every frame no resolved render curve crosses the box, no NaN, the groom
    itself never changes."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    groom_before = positions(groom).copy()
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    frames = range(1, 9)
    played = _groom_frames(scene, gout, frames)
    for f in frames:
        scene.frame_set(f)
        assert np.isfinite(world(gout)).all()
        assert len(crossing_unmarked(gout, [(box, True)], unmarked=RESOLVED)) == 0, f
    assert any((played[f][1] == 1).any() for f in frames)  # the clearance pass worked
    _same(played, scene, gout, (5, 2, 7, 7, 1, 8, 3), "scrubbed")
    path = save_in(tmp_path)
    activate(guides)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    _same(played, scene, gout, frames, "baked")
    bpy.ops.wm.save_mainfile()
    reopen(path)
    guides = bpy.data.objects["Guides"]
    gout = guides.furcollide.groom.output
    _same(played, bpy.context.scene, gout, (4, 8, 1, 6), "reopened")
    assert guides.furcollide.status_message == "", guides.furcollide.status_message
    np.testing.assert_array_equal(positions(bpy.data.objects["Groom"]), groom_before)


def test_reopened_unbaked_render_groom_replays_the_same(fc, tmp_path):
    """Saved mid-playback with a render groom, reopened, played from frame 1 (the
    advice): the groom output is the first session's, bit for bit."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    played = _groom_frames(scene, gout, range(1, 9))
    scene.frame_set(5)
    path = save_in(tmp_path)
    reopen(path)
    scene = bpy.context.scene
    guides = bpy.data.objects["Guides"]
    gout = guides.furcollide.groom.output
    np.testing.assert_array_equal(world(gout), played[5][0])  # what was saved
    scene.frame_set(7)
    msg = guides.furcollide.status_message
    assert "not saved with the file" in msg and "Play from frame 1" in msg, msg
    _same(played, scene, gout, range(1, 9), "replayed")
    assert guides.furcollide.status_message == ""


# ------------------------------------------------------------- in a shot
def test_groom_bound_again_mid_shot_on_a_moved_skin(fc):
    """Bind Groom pressed again at frame 4 (the skin has moved, the guides are attached
    to it): the groom's roots stay on the skin at every frame and every promise holds."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = pipeline_scene(fc)
    play_pipeline(guides, groom, box)
    scene.frame_set(4)
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    rec = play_pipeline(guides, groom, box)
    for f in (5, 2, 6):
        scene.frame_set(f)
        same_pipeline_frame(pipeline_frame(guides), rec[f], f"scrub {f}")


def test_render_groom_with_an_enable_attribute(fc):
    """The render groom itself carries furcollide_enable with curves off: the enable
    attribute is the setup source's (README "Per-curve enable"); the render groom's is
    not read, so every render curve follows the guides and gets the clearance pass
    (none left crossing unmarked, the switched-off ones included)."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    a = groom.data.attributes.new("furcollide_enable", "BOOLEAN", "CURVE")
    on = np.ones(len(groom.data.curves), bool)
    on[::2] = False
    a.data.foreach_set("value", on)
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    fixed_off = 0
    for f in PIPELINE_FRAMES:
        scene.frame_set(f)
        assert guides.furcollide.status_message == ""
        assert len(crossing_unmarked(gout, [box])) == 0, f
        st = status_of(gout)
        fixed_off += int((st[~on] == 1).sum())
    assert fixed_off > 0  # (curves switched off on the groom were moved too)


# ------------------------------------------- the demo's pipeline, with motion blur
#: Wind after collision held by the Region of Influence.
DEMO_WIND = dict(use_wind=True, wind_stage="OUTPUT", wind_strength=0.04,
                 use_region_of_influence=True)


def baked_demo_pipeline(tmp_path, last, n_fur=4000):
    """The demo's pipeline (scripts/demo.py pipeline_setup: Fur Sampler 25 %, FurCollide on
    the guides with Fur Attach, :data:`DEMO_WIND`, the fur bound as the render groom with
    the clearance pass) over 1..``last``, saved in ``tmp_path`` and baked with its render
    groom. Returns (demo, guides, out, gout)."""
    demo, guides, out, gout = demo_pipeline(n_fur, last, DEMO_WIND)
    save_in(tmp_path)
    activate(guides)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert guides.furcollide.groom.is_baked_with
    return demo, guides, out, gout


def test_motion_blur_render_of_a_baked_render_groom(fc, tmp_path):
    """The demo's pipeline baked with its render groom, rendered with motion blur, the
    guides and the groom hidden from render (only the groom output renders): every whole
    frame is the bake (guides and render groom) bit for bit; at a subframe the guides
    and the render groom are the blends of their two baked frames (README *Time*: "A
    baked setup blends its two neighbouring baked frames"; nothing is computed, so the
    groom moves over the shutter with its guides instead of being solved again at each
    motion step, which made single curves jump 10-25 cm in a quarter frame); nothing
    said."""
    last = 14
    demo, guides, out, gout = baked_demo_pipeline(tmp_path, last)
    scene = demo.scene
    first = {}
    for f in range(1, last + 1):
        scene.frame_set(f)
        first[f] = pipeline_state(guides)
    for o in (guides, out, demo.fur, demo.grass):
        o.hide_render = True
    cycles_motion_blur(scene, tmp_path)
    seen = render_recording(guides, lambda dg: pipeline_state(guides))
    d = bpy.path.abspath(guides.furcollide.bake_path)
    fixed = 0
    for (f, sub), state, msg, outdated in seen:
        assert msg in QUIET and not outdated, (f, sub, msg)
        if sub == 0.0:
            for x, y in zip(state, first[f], strict=True):
                np.testing.assert_array_equal(x, y, err_msg=f"whole frame {f}")
            continue
        if 1 <= f < last:
            a, b = (fc.cache.read_frame(d, k, state=False)[0] for k in (f, f + 1))
            np.testing.assert_allclose(state[0], a + (b - a) * np.float32(sub), atol=1e-6)
            ga, gb = (fc.cache.read_extra(d, k, "groom")["points"] for k in (f, f + 1))
            np.testing.assert_allclose(state[2], ga + (gb - ga) * np.float32(sub), atol=1e-6)
            np.testing.assert_array_equal(state[3], first[f][3])
        fixed += int((state[2] != first[max(f, 1)][2]).any())
    assert fixed > 5
    for f in (last, 5):
        scene.frame_set(f)
        for x, y in zip(pipeline_state(guides), first[f], strict=True):
            np.testing.assert_array_equal(x, y, err_msg=f"after the render, frame {f}")


def test_motion_blur_of_frame_end_holds_the_baked_render_groom(fc, tmp_path):
    """README "Time": at a subframe a baked setup blends its neighbouring baked frames,
    "from Frame End on it shows Frame End, held as whole frames are"; README "Render
    Groom": a bake made after Bind Groom holds the render groom. So the motion step after
    Frame End shows Frame End's baked render groom, as its guides."""
    last = 14
    demo, guides, out, gout = baked_demo_pipeline(tmp_path, last)
    scene = demo.scene
    scene.frame_set(last)
    end = pipeline_state(guides)
    scene.frame_start = last - 1
    for o in (guides, out, demo.fur, demo.grass):
        o.hide_render = True
    cycles_motion_blur(scene, tmp_path)
    seen = render_recording(guides, lambda dg: pipeline_state(guides))
    steps = [(k, st) for k, st, *_ in seen if k[0] == last and k[1] > 0]
    assert steps, [k for k, *_ in seen]
    for key, st in steps:
        np.testing.assert_array_equal(st[0], end[0], err_msg=f"guides at {key}")
        np.testing.assert_array_equal(st[2], end[2], err_msg=f"render groom at {key}")
