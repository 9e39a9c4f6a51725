"""Fur Attach: curves bound to the growth Surface follow its animation (transforms,
shape keys, modifiers), Bind / Unbind and their refusals, edited or reordered
Surfaces, bakes and renders with the Surface hidden, save and reload."""

import math

import bmesh
import bpy
import numpy as np
import pytest
from helpers import (
    activate,
    check_render,
    dependency_objects,
    draw_panel,
    linear,
    make_box,
    make_hair,
    make_surface,
    mesh_object,
    no_faces,
    offsets_of,
    pipeline_scene,
    play,
    play_pipeline,
    render_camera,
    render_watching,
    save_in,
    seg_lengths,
    world,
)

pytestmark = pytest.mark.blender




def animate_transform(surf, frames=(1, 8)):
    """Keyframed location + rotation of the surface object."""
    surf.location, surf.rotation_euler = (0, 0, 0), (0, 0, 0)
    surf.keyframe_insert("location", frame=frames[0])
    surf.keyframe_insert("rotation_euler", frame=frames[0])
    surf.location = (0.4, -0.2, 0.3)
    surf.rotation_euler = (0.5, -0.3, 0.8)
    surf.keyframe_insert("location", frame=frames[1])
    surf.keyframe_insert("rotation_euler", frame=frames[1])
    linear(surf)


def animate_shape_key(surf, frames=(1, 8)):
    """A shape key bending the surface (z = 0.4 sin(2x) + 0.2 y^2), value 0 -> 1."""
    surf.shape_key_add(name="Basis")
    key = surf.shape_key_add(name="Bend")
    for i, v in enumerate(surf.data.vertices):
        x, y, _z = v.co
        key.data[i].co = (x, y, 0.4 * math.sin(2 * x) + 0.2 * y * y)
    key.value = 0.0
    key.keyframe_insert("value", frame=frames[0])
    key.value = 1.0
    key.keyframe_insert("value", frame=frames[1])
    linear(surf.data.shape_keys)


def attached_scene(fc, colliders=(), frames=(1, 8), before_setup=None):
    """Hair grid with roots on a Surface plane, a FurCollide setup on it."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    scene.frame_set(frames[0])
    hair = make_hair(nx=5, ny=5)
    surf = make_surface(n=6, uv=False)
    hair.data.surface = surf
    if before_setup is not None:
        before_setup(surf)
    scene.frame_set(frames[0])
    out = fc.setup(hair, list(colliders))
    hair.furcollide.frame_start, hair.furcollide.frame_end = frames
    return hair, surf, out


def bind(hair, frame=1):
    activate(hair)
    hair.furcollide.attach_reference_frame = frame
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    assert hair.furcollide.use_fur_attach


def surface_world(surf):
    dg = bpy.context.evaluated_depsgraph_get()
    se = surf.evaluated_get(dg)
    me = se.data
    V = np.empty(len(me.vertices) * 3, np.float32)
    me.attributes["position"].data.foreach_get("vector", V)
    M = np.array(se.matrix_world)
    return V.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3]


def output_world(fc, out):
    M = np.array(out.matrix_world)
    return fc.positions(out).astype(np.float64) @ M[:3, :3].T + M[:3, 3]


def check_follows(fc, hair, surf, out, frames):
    """Every frame: roots exactly at their bound barycentric points, rigid curves."""
    binding, _key = fc.frame.attach.load_binding(hair)
    offs = offsets_of(out)
    ref = seg_lengths(output_world(fc, out), offs)
    moved = 0.0
    for f in frames:
        bpy.context.scene.frame_set(f)
        assert fc.store.report.status_for(hair)[0] == "INFO", fc.store.report.status_for(hair)
        V = surface_world(surf)
        P = output_world(fc, out)
        np.testing.assert_allclose(P[offs[:-1]], binding.roots(V), atol=1e-5)
        np.testing.assert_allclose(P, binding.apply(V), atol=1e-5)  # nothing collides
        np.testing.assert_allclose(seg_lengths(P, offs), ref, atol=1e-5)
        moved = max(moved, float(np.abs(P - fc.positions(hair)).max()))
    assert moved > 0.1  # the surface animation did move the curves


def _inside_box(P, center, half):
    return (np.abs(P - np.asarray(center)) < half - 1e-4).all(axis=1)


def _densify(P, offs, n=8):
    t = np.linspace(0, 1, n)[:, None, None]
    a, b = P[:-1], P[1:]
    keep = np.ones(len(a), bool)
    keep[offs[1:-1] - 1] = False
    return (a[keep][None] * (1 - t) + b[keep][None] * t).reshape(-1, 3)


def played_list(fc, out, frames):
    res = []
    for f in frames:
        bpy.context.scene.frame_set(f)
        res.append(fc.positions(out).copy())
    return res


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


def _attach_scene(fc, nx=3, ny=3):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    scene.frame_set(1)
    hair = make_hair(nx=nx, ny=ny)
    out = fc.setup(hair, [make_box(location=(5, 5, 5))])
    return scene, hair, out


def _attach_bound(fc):
    """The attach scene, its hair bound to a fresh 4 x 4 Surface (no UV map)."""
    scene, hair, out = _attach_scene(fc)
    surf = make_surface(n=4, uv=False)
    hair.data.surface = surf
    activate(hair)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    return scene, hair, out, surf


def test_attach_follows_transform_animation(fc):
    hair, surf, out = attached_scene(fc)
    animate_transform(surf)
    bpy.context.scene.frame_set(1)
    bind(hair)
    check_follows(fc, hair, surf, out, range(1, 9))


def test_attach_follows_shape_key_and_modifier(fc):
    hair, surf, out = attached_scene(fc)
    animate_shape_key(surf)
    mod = surf.modifiers.new("Twist", "SIMPLE_DEFORM")  # a deforming modifier on top
    mod.deform_method, mod.deform_axis, mod.angle = "TWIST", "X", 0.3
    bpy.context.scene.frame_set(1)
    bind(hair)
    check_follows(fc, hair, surf, out, range(1, 9))


def test_bind_at_another_reference_frame_restores_the_frame(fc):
    hair, surf, out = attached_scene(fc)
    animate_transform(surf)
    scene = bpy.context.scene
    scene.frame_set(1)
    # the hair sits on the surface's pose at frame 5
    bpy.context.scene.frame_set(5)
    M = np.array(surf.matrix_world)
    P = fc.positions(hair).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    hair.data.position_data.foreach_set("vector", P.astype(np.float32).ravel())
    hair.data.update_tag()
    scene.frame_set(1)
    bind(hair, frame=5)
    assert scene.frame_current == 1
    binding, _ = fc.frame.attach.load_binding(hair)
    assert binding.root_distance.max() < 1e-5
    for f in range(1, 6):  # play up to the reference frame
        scene.frame_set(f)
    np.testing.assert_allclose(output_world(fc, out), P, atol=1e-5)  # identity at ref
    check_follows(fc, hair, surf, out, range(1, 9))


def test_attached_curves_still_collide(fc):
    box = make_box("Wall", size=0.5, location=(0.75, 0.0, 0.6))
    hair, surf, out = attached_scene(fc, colliders=[box])
    surf.location = (0, 0, 0)
    surf.keyframe_insert("location", frame=1)
    surf.location = (0.5, 0, 0)
    surf.keyframe_insert("location", frame=8)
    linear(surf)
    bpy.context.scene.frame_set(1)
    bind(hair)
    offs = offsets_of(out)
    binding, _ = fc.frame.attach.load_binding(hair)
    penetrating_input = 0
    for f in range(1, 9):
        bpy.context.scene.frame_set(f)
        assert fc.store.report.status_for(hair)[0] != "ERROR", fc.store.report.status_for(hair)
        V = surface_world(surf)
        P = output_world(fc, out)
        np.testing.assert_allclose(P[offs[:-1]], binding.roots(V), atol=1e-5)
        assert not _inside_box(_densify(P, offs), box.location, 0.25).any(), f
        penetrating_input += int(_inside_box(_densify(binding.apply(V), offs), box.location,
                                             0.25).any())
    assert penetrating_input > 0  # the attached input did run into the wall


def test_option_off_is_the_previous_behaviour(fc):
    box = make_box("Wall", size=0.5, location=(-0.6, 0.0, 0.6))
    box.keyframe_insert("location", frame=1)
    box.location = (0.6, 0, 0.6)
    box.keyframe_insert("location", frame=8)
    linear(box)
    hair, surf, out = attached_scene(fc, colliders=[box], before_setup=animate_transform)
    sig = fc.settings.fingerprints.signature(hair)
    before = played_list(fc, out, range(1, 9))
    bpy.context.scene.frame_set(1)
    bind(hair)
    attached = played_list(fc, out, range(1, 9))
    assert max(np.abs(a - b).max() for a, b in zip(attached, before, strict=True)) > 0.1
    hair.furcollide.use_fur_attach = False
    assert fc.settings.fingerprints.signature(hair) == sig
    after = played_list(fc, out, range(1, 9))
    for a, b in zip(after, before, strict=True):
        np.testing.assert_array_equal(a, b)


def test_save_reload_keeps_the_binding(fc, tmp_path):
    hair, surf, out = attached_scene(fc)
    animate_shape_key(surf)
    bpy.context.scene.frame_set(1)
    bind(hair)
    expected = fc.frame.attach.load_binding(hair)[0].arrays()
    path = str(tmp_path / "attach.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.open_mainfile(filepath=path)
    hair = bpy.data.objects["Fur"]
    assert hair.furcollide.use_fur_attach and fc.frame.attach.has_binding(hair)
    got = fc.frame.attach.load_binding(hair)[0].arrays()
    for k, v in expected.items():
        np.testing.assert_array_equal(got[k], v)
    check_follows(fc, hair, bpy.data.objects["Skin"], hair.furcollide.output, range(1, 9))


def test_poll_and_errors(fc):
    hair, box = fc.make_scene(nx=3, ny=3)
    activate(box)
    with pytest.raises(RuntimeError, match="no FurCollide setup"):
        bpy.ops.furcollide.fur_attach_bind()
    fc.setup(hair, [box])
    activate(hair)
    with pytest.raises(RuntimeError, match="no Surface mesh"):
        bpy.ops.furcollide.fur_attach_bind()
    # option on without a binding: a clear error, the output keeps its result
    hair.furcollide.use_fur_attach = True
    bpy.context.scene.frame_set(2)
    level, msg = fc.store.report.status_for(hair)
    assert level == "ERROR" and "press Bind" in msg


def test_surface_topology_change_is_an_error(fc):
    hair, surf, out = attached_scene(fc)
    animate_transform(surf)
    bpy.context.scene.frame_set(1)
    bind(hair)
    bpy.context.scene.frame_set(2)
    held = fc.positions(out).copy()
    surf.modifiers.new("Subdivide", "SUBSURF").levels = 1
    bpy.context.scene.frame_set(3)
    level, msg = fc.store.report.status_for(hair)
    assert level == "ERROR" and "changed topology" in msg and "Bind again" in msg
    np.testing.assert_array_equal(fc.positions(out), held)  # holds the last result
    # binding again on the new topology works
    bpy.context.scene.frame_set(1)
    bind(hair)
    check_follows(fc, hair, surf, out, range(1, 5))


def test_panel_draws_attach(fc):

    hair, surf, out = attached_scene(fc)
    s = hair.furcollide
    assert s.use_fur_attach is False and s.attach_reference_frame == 1  # off by default
    assert not fc.frame.attach.has_binding(hair)
    panel = bpy.types.FURCOLLIDE_PT_pipeline
    activate(hair)
    log = draw_panel(panel)
    assert ("operator", "furcollide.fur_attach_bind") in log
    assert ("prop", "use_fur_attach") in log and ("prop", "attach_reference_frame") in log
    assert ("label", "Not bound: press Bind") in log
    bind(hair)
    activate(out)  # the output shows its source's setup
    log = draw_panel(panel)
    assert ("operator", "furcollide.fur_attach_bind") in log
    assert ("label", "Not bound: press Bind") not in log


def test_bake_with_fur_attach(fc, tmp_path):
    hair, surf, out = attached_scene(fc, before_setup=animate_transform)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"))
    bind(hair)
    live = played_list(fc, out, range(1, 9))
    bpy.context.scene.frame_set(1)
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert hair.furcollide.is_baked
    with pytest.raises(RuntimeError, match="free the bake"):
        bpy.ops.furcollide.fur_attach_bind()
    for f in (8, 3, 1):
        bpy.context.scene.frame_set(f)
        np.testing.assert_array_equal(fc.positions(out), live[f - 1])


def test_roots_off_the_surface_are_snapped_with_a_warning(fc, capsys):
    hair, surf, out = attached_scene(fc, before_setup=animate_transform)
    surf.location.z = -0.05  # every root 0.05 above the surface at frame 1
    surf.keyframe_insert("location", frame=1)
    bpy.context.scene.frame_set(1)
    bind(hair)
    assert "25 roots were not on the Surface" in capsys.readouterr().out
    check_follows(fc, hair, surf, out, range(1, 9))


def test_rebinding_without_callback_drops_the_cache(fc):
    """Undo or a driver can change the binding without an update callback."""
    hair, surf, out = attached_scene(fc, before_setup=animate_transform)
    bind(hair)
    played_list(fc, out, range(1, 6))
    rt = fc.store.registry.get_runtime(hair)
    assert len(rt.cache.memory) == 5
    hair.furcollide.attach_id = "rebound elsewhere"  # hidden: no update callback
    bpy.context.scene.frame_set(5)
    assert len(rt.cache.memory) == 0 and fc.store.report.is_outdated(hair)
    check_follows(fc, hair, surf, out, range(1, 9))


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
    assert not fc.frame.attach.has_binding(hair)
    scene.frame_set(1)
    assert abs(world(out)[0, 2]) < 1e-6  # back to the source's own curves


def test_attach_bind_refuses_surfaces_it_cannot_use(fc):
    scene, hair, out = _attach_scene(fc)
    s = hair.furcollide
    wire = no_faces()
    flat = mesh_object("Flat", [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)],
                       faces=[(0, 1, 2), (1, 2, 3)])  # every face has zero area
    for surf, why in ((wire, "The Surface 'Wire' has no faces"),
                      (flat, "every face is degenerate")):
        hair.data.surface = surf
        activate(hair)
        with pytest.raises(RuntimeError, match=why):
            bpy.ops.furcollide.fur_attach_bind()
        assert not s.use_fur_attach and not fc.frame.attach.has_binding(hair)
    play(scene, range(1, 4))  # the setup still solves its source's own curves
    assert fc.store.report.status_for(hair) == ("INFO", "")
    np.testing.assert_allclose(world(out), world(hair), atol=1e-6)
    # not a mesh: the operator is not even offered
    ctrl = bpy.data.objects.new("Ctrl", None)
    scene.collection.objects.link(ctrl)
    hair.data.surface = ctrl
    activate(hair)
    assert not bpy.ops.furcollide.fur_attach_bind.poll()
    with pytest.raises(RuntimeError, match="no Surface mesh"):
        bpy.ops.furcollide.fur_attach_bind()


def test_attach_bind_far_from_the_surface_snaps_with_a_warning(fc, capsys):
    scene, hair, out = _attach_scene(fc)
    surf = make_surface(n=4, uv=False, z=-50.0)
    hair.data.surface = surf
    activate(hair)
    capsys.readouterr()
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    log = capsys.readouterr().out
    assert "9 roots were not on the Surface at frame 1 (up to 50 away)" in log, log
    assert "Traceback" not in log
    play(scene, range(1, 4))
    assert fc.store.report.status_for(hair) == ("INFO", "")
    P, offs = world(out), offsets_of(out)
    np.testing.assert_allclose(P[offs[:-1], 2], -50.0, atol=1e-5)  # roots on the Surface
    # the curves were translated whole: same shape
    np.testing.assert_allclose(P - P[np.repeat(offs[:-1], np.diff(offs))],
                               world(hair) - world(hair)[np.repeat(offs[:-1], np.diff(offs))],
                               atol=1e-5)


@pytest.mark.parametrize("edit", ["add_vertex", "subdivide"])
def test_attach_surface_edited_after_bind(fc, capsys, edit):
    scene, hair, out, surf = _attach_bound(fc)
    play(scene, range(1, 3))
    held = fc.positions(out).copy()
    me = surf.data
    if edit == "add_vertex":
        me.vertices.add(1)
        want = "(26 vertices / 16 faces, bound: 25 / 16)"
    else:
        bm = bmesh.new()
        bm.from_mesh(me)
        bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=1, use_grid_fill=True)
        bm.to_mesh(me)
        bm.free()
        want = "(81 vertices / 64 faces, bound: 25 / 16)"
    me.update()
    capsys.readouterr()
    for f in (3, 4, 1):
        scene.frame_set(f)
        level, msg = fc.store.report.status_for(hair)
        assert level == "ERROR", (f, msg)
        assert "Surface 'Skin' changed topology since binding" in msg and want in msg, msg
        assert "press Bind again" in msg
        np.testing.assert_array_equal(fc.positions(out), held)  # keeps its last result
    log = capsys.readouterr()
    assert "Traceback" not in log.out + log.err
    # Bind again on the edited Surface: solved again
    scene.frame_set(1)
    activate(hair)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    play(scene, range(1, 4))
    assert fc.store.report.status_for(hair) == ("INFO", "")


def test_attach_surface_vertex_order_change_is_reported(fc):
    scene, hair, out, surf = _attach_bound(fc)
    play(scene, range(1, 3))
    before = fc.positions(out).copy()
    me = surf.data
    V = np.array([v.co[:] for v in me.vertices])
    F = [tuple(p.vertices) for p in me.polygons]
    perm = np.random.default_rng(0).permutation(len(V))
    inv = np.argsort(perm)
    me.clear_geometry()
    me.from_pydata(V[perm].tolist(), [], [tuple(int(inv[i]) for i in f) for f in F])
    me.update()
    scene.frame_set(3)
    level, msg = fc.store.report.status_for(hair)
    # either the change is reported, or the hair stays where the (same) surface is
    assert level == "ERROR" or np.abs(fc.positions(out) - before).max() < 1e-5, msg


def test_attach_bind_again_then_reopen_keeps_the_binding(fc, tmp_path):
    scene, hair, out, surf = _attach_bound(fc)
    surf.data.vertices.add(1)  # README: the topology changed, press Bind again
    surf.data.update()
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    play(bpy.context.scene, range(1, 3))
    assert fc.store.report.status_for(hair) == ("INFO", "")
    path = save_in(tmp_path)
    bpy.ops.wm.open_mainfile(filepath=path)
    hair = bpy.data.objects["Fur"]
    play(bpy.context.scene, range(1, 3))
    assert fc.store.report.status_for(hair) == ("INFO", "")


@pytest.mark.parametrize("surface_first", [True, False])
def test_fur_attach_render_with_the_surface_hidden(fc, tmp_path, surface_first):
    scene = bpy.context.scene
    hair, surf, wall, out = _attached(fc, surface_first)
    surf.hide_render = True
    wall.hide_render = True
    render_camera(scene)
    scene.frame_set(1)
    seen, statuses = render_watching(tmp_path, "attach", [out], hair)
    assert hair.furcollide.status_message == ""
    viewport = check_render(seen, statuses, [out], range(1, 6))
    assert np.abs(viewport[5][out.name] - viewport[1][out.name]).max() > 0.1
    assert surf in dependency_objects(out)


def test_attach_surface_edited_on_a_baked_setup_says_free_bake_first(fc, tmp_path):
    """Bind is refused on a baked setup: the advice says Free Bake first, and
    following it (Free Bake, Bind) solves again."""
    scene, hair, out, surf = _attach_bound(fc)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"))
    scene.frame_start, scene.frame_end = 1, 3
    scene.frame_set(1)
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    scene.frame_set(2)
    baked2 = fc.positions(out).copy()
    scene.frame_set(1)
    surf.data.vertices.add(1)
    surf.data.update()
    scene.frame_set(2)
    np.testing.assert_array_equal(fc.positions(out), baked2)  # the bake is still shown
    level, msg = fc.store.report.status_for(hair)
    assert "changed topology since binding" in msg, msg
    assert "press Free Bake, then Bind again" in msg, msg
    activate(hair)
    with pytest.raises(RuntimeError, match="free the bake"):
        bpy.ops.furcollide.fur_attach_bind()  # refused while baked, as the advice says
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    scene.frame_set(1)
    activate(hair)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    play(scene, range(1, 4))
    assert fc.store.report.status_for(hair) == ("INFO", "")


def test_an_edit_away_from_the_roots_keeps_the_playback_cache(fc):
    """The frame-inputs record digests only the Surface vertices Fur Attach reads
    (those of the bound triangles): a vertex no curve is bound to, moved while the
    frames are cached, changes nothing (the cache and the frame stay); a bound one
    is an edit that names the Surface."""
    scene, hair, out, surf = _attach_bound(fc)
    rt = fc.store.registry.get_runtime(hair)
    play(scene, range(1, 5))
    assert sorted(rt.cache.memory.frames) == [1, 2, 3, 4]
    used = fc.frame.attach.load_binding(hair)[0].used_vertices
    free = np.setdiff1d(np.arange(len(surf.data.vertices)), used)
    assert len(free)
    surf.data.vertices[int(free[0])].co.z += 0.3
    surf.data.update()
    bpy.context.view_layer.update()  # (the depsgraph check runs)
    assert sorted(rt.cache.memory.frames) == [1, 2, 3, 4]
    scene.frame_set(3)
    assert fc.store.report.status_for(hair) == ("INFO", "")
    assert rt.report.stats["source"] == "cache"
    surf.data.vertices[int(used[0])].co.z += 0.3
    surf.data.update()
    bpy.context.view_layer.update()
    assert len(rt.cache.memory) == 0
    level, msg = fc.store.report.status_for(hair)
    assert f"the Surface '{surf.name}' the curves are attached to" in msg, msg


# -------------------------------------------------- a pipeline setup
def test_guides_fur_attach_bound_again_mid_shot(fc):
    """Fur Attach pressed Bind again at frame 3 (another reference frame) after Bind
    Groom: every frame still holds the promises."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = pipeline_scene(fc)
    play_pipeline(guides, groom, box)
    scene.frame_set(3)
    activate(guides)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    play_pipeline(guides, groom, box)
    assert guides.furcollide.status_message == "", guides.furcollide.status_message
