"""Colliders that are not meshes: a rope (a curve with a bevel), text, a NURBS
surface. Blender turns them into a mesh when it evaluates them; FurCollide
collides with that evaluated surface, as it does with a mesh's."""

import sys
from pathlib import Path

import bpy
import numpy as np
import pytest
from conftest import activate, make_box, make_hair, positions

from core import Status

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
import oracle  # noqa: E402  (the core tests' brute-force segment/triangle test)

pytestmark = pytest.mark.blender

PINCHED, UNRESOLVED = Status.PINCHED, Status.UNRESOLVED


# ------------------------------------------------------------------ helpers
def _linear(ob):
    act = ob.animation_data.action
    for fcu in getattr(act, "fcurves", []):
        for k in fcu.keyframe_points:
            k.interpolation = "LINEAR"


def make_rope(name="Rope", depth=0.08, x=0.0, z=0.6, bevel=True):
    """A straight rope along y (a poly curve with a round bevel and caps)."""
    cu = bpy.data.curves.new(name, "CURVE")
    cu.dimensions = "3D"
    sp = cu.splines.new("POLY")
    sp.points.add(3)
    for i, y in enumerate(np.linspace(-1.2, 1.2, 4)):
        sp.points[i].co = (0.0, float(y), 0.0, 1.0)
    if bevel:
        cu.bevel_depth = depth
        cu.bevel_resolution = 3
        cu.use_fill_caps = True
    ob = bpy.data.objects.new(name, cu)
    bpy.context.scene.collection.objects.link(ob)
    ob.location = (x, 0.0, z)
    return ob


def sweep(ob, x0, x1, frames):
    ob.location.x = x0
    ob.keyframe_insert("location", frame=frames[0])
    ob.location.x = x1
    ob.keyframe_insert("location", frame=frames[1])
    _linear(ob)


def world_mesh(oe, M):
    """Vertices (placed by the 4x4 ``M``) and triangles of evaluated object ``oe``."""
    me = oe.to_mesh()
    try:
        me.calc_loop_triangles()
        V = np.array([v.co for v in me.vertices], np.float64).reshape(-1, 3)
        F = np.array([t.vertices[:] for t in me.loop_triangles], np.int64).reshape(-1, 3)
    finally:
        oe.to_mesh_clear()
    M = np.array(M)
    return V @ M[:3, :3].T + M[:3, 3], F


def evaluated_world_mesh(ob):
    """World vertices and triangles of ``ob`` as the depsgraph evaluates it now."""
    oe = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    return world_mesh(oe, oe.matrix_world)


def world(ob):
    P = positions(ob).astype(np.float64)
    M = np.array(ob.matrix_world)
    return P @ M[:3, :3].T + M[:3, 3]


def offsets_of(ob):
    off = np.empty(len(ob.data.curves) + 1, np.int32)
    ob.data.curve_offset_data.foreach_get("value", off)
    return off


def status(out):
    st = np.zeros(len(out.data.curves), np.int8)
    out.data.attributes["furcollide_status"].data.foreach_get("value", st)
    return st


def crossing_free_curves(out, V, F):
    """Curves not pinched/unresolved whose segments cross the mesh (V, F)."""
    hit = oracle.segments_hit_mesh(world(out), offsets_of(out), V, F)
    return np.flatnonzero(hit & ~np.isin(status(out), (PINCHED, UNRESOLVED)))


def rope_scene(frames=(1, 8), **kw):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    hair = make_hair(nx=6, ny=6)
    rope = make_rope(**kw)
    sweep(rope, -0.9, 0.9, frames)
    scene.frame_set(frames[0])
    return hair, rope


def setup_with(hair, *colliders):
    activate(hair, *colliders)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    return hair.furcollide.output


# -------------------------------------------------------------------- tests
def test_rope_curve_with_a_bevel_collides(fc):
    """A rope (curve + bevel) swept through the fur: it is added from the
    selection, curves it meets turn away, none crosses its evaluated surface,
    roots stay put, and the source groom is untouched."""
    scene = bpy.context.scene
    hair, rope = rope_scene()
    before = positions(hair).copy()
    out = setup_with(hair, rope)
    assert [c.object for c in hair.furcollide.colliders] == [rope]
    offs = offsets_of(out)
    met = 0
    for f in range(1, 9):
        scene.frame_set(f)
        assert fc.registry.status_for(hair) == ("INFO", "")
        V, F = evaluated_world_mesh(rope)
        assert len(F) > 50  # the bevel's tube and caps
        assert crossing_free_curves(out, V, F).size == 0, f
        np.testing.assert_array_equal(world(out)[offs[:-1]], world(hair)[offs[:-1]])
        met += int((status(out) == Status.COLLIDING).sum())
        # the input itself crosses the rope where curves turned away
    assert met > 0
    np.testing.assert_array_equal(positions(hair), before)


def test_rope_moving_as_a_whole_never_rebuilds(fc):
    """A rope that only moves (object animation) keeps its BVH, like a rigid mesh;
    one whose bevel grows is deforming: each frame collides with its new shape.
    (Its caps are re-triangulated as the shape changes, so it may even get new
    faces: then it is a new collider.)"""
    scene = bpy.context.scene
    hair, rope = rope_scene()
    setup_with(hair, rope)
    rt = fc.registry.get_runtime(hair)
    for f in range(1, 9):
        scene.frame_set(f)
    col = rt.colliders[rope.session_uid].collider
    assert col.build_count == 1
    assert fc.colliders.is_deforming(rope, scene) is False
    scene.frame_set(1)
    rope.data.bevel_depth = 0.05
    rope.data.keyframe_insert("bevel_depth", frame=1)
    rope.data.bevel_depth = 0.15
    rope.data.keyframe_insert("bevel_depth", frame=8)
    bpy.context.view_layer.update()
    assert fc.colliders.is_deforming(rope, scene) is True
    out = hair.furcollide.output
    for f in range(1, 9):
        scene.frame_set(f)
        V, F = evaluated_world_mesh(rope)
        assert crossing_free_curves(out, V, F).size == 0, f
        col = rt.colliders[rope.session_uid].collider
        radius = 0.05 + 0.1 * (f - 1) / 7  # the keyed bevel depth, linear in between
        assert abs(np.abs(col.vertices[:, 0]).max() - radius) < 0.03, f


def test_curve_without_a_surface_is_an_empty_collider(fc):
    """A curve with no bevel or extrusion has no surface: listed as a collider it
    collides with nothing and reports nothing; given a bevel later it collides."""
    scene = bpy.context.scene
    hair, rope = rope_scene(bevel=False)
    out = setup_with(hair, rope)
    for f in range(1, 9):
        scene.frame_set(f)
        assert fc.registry.status_for(hair) == ("INFO", "")
        np.testing.assert_allclose(world(out), world(hair), atol=1e-6)
    scene.frame_set(1)  # (an edit keeps the frames before the current one)
    rope.data.bevel_depth = 0.08
    bpy.context.view_layer.update()
    moved = 0
    for f in range(1, 9):
        scene.frame_set(f)
        V, F = evaluated_world_mesh(rope)
        assert crossing_free_curves(out, V, F).size == 0, f
        moved += int((np.abs(world(out) - world(hair)) > 1e-6).any(axis=1).sum())
    assert moved > 0


def test_text_and_surface_in_a_collider_collection(fc):
    """Extruded text and a NURBS surface in the collider collection collide; the
    hair object itself in that collection does not."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    hair = make_hair(nx=6, ny=6)
    coll = bpy.data.collections.new("Props")
    scene.collection.children.link(coll)
    txt = bpy.data.objects.new("Sign", bpy.data.curves.new("Sign", "FONT"))
    txt.data.body = "I"
    txt.data.extrude = 0.2
    txt.data.size = 1.5
    coll.objects.link(txt)
    txt.rotation_euler = (np.pi / 2, 0.0, 0.0)  # standing up, its face toward -y
    sweep(txt, -1.0, 0.6, (1, 6))
    txt.location.z = 0.3
    bpy.ops.object.select_all(action="DESELECT")
    bpy.context.view_layer.objects.active = None
    bpy.ops.surface.primitive_nurbs_surface_sphere_add(radius=0.25, location=(0.3, 0.3, 1.2))
    ball = bpy.context.active_object
    for c in list(ball.users_collection):
        c.objects.unlink(ball)
    coll.objects.link(ball)
    scene.frame_set(1)
    out = setup_with(hair)
    hair.furcollide.collider_collection = coll
    coll.objects.link(hair)  # the source itself never collides with itself
    names = {r.name for r in fc.colliders.collider_objects(hair, scene)}
    assert names == {"Sign", ball.name}
    moved = 0
    for f in range(1, 7):
        scene.frame_set(f)
        assert fc.registry.status_for(hair) == ("INFO", "")
        for ob in (txt, ball):
            V, F = evaluated_world_mesh(ob)
            assert len(F) > 0
            assert crossing_free_curves(out, V, F).size == 0, (f, ob.name)
        moved += int((np.abs(world(out) - world(hair)) > 1e-6).any(axis=1).sum())
    assert moved > 0


def test_add_collider_and_pointer_accept_curves_not_hair(fc):
    """Add Collider takes a selected rope or text, never the hair or an empty; the
    list's pointer accepts the same types."""
    hair = make_hair()
    box = make_box()
    out = setup_with(hair, box)
    rope = make_rope()
    empty = bpy.data.objects.new("Empty", None)
    bpy.context.scene.collection.objects.link(empty)
    other = make_hair("Other")
    activate(hair, rope, empty, other)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    assert [c.object for c in hair.furcollide.colliders] == [box, rope]
    # the list's poll (what the eyedropper and search offer)
    poll = fc.property_helpers.poll_collider
    assert [poll(None, o) for o in (box, rope, empty, other, hair)] == [
        True, True, False, False, False]
    # a hair object put in the list from Python is skipped, never solved against
    hair.furcollide.colliders.add().object = other
    names = [r.name for r in fc.colliders.collider_objects(hair)]
    assert names == [box.name, rope.name]
    assert out is not None


def test_collider_distance_and_bake_with_a_rope(fc, tmp_path):
    """Collider Distance measures to the rope's surface; a bake with a rope
    matches playback and resumes only over the same rope."""
    scene = bpy.context.scene
    hair, rope = rope_scene(frames=(1, 5))
    out = setup_with(hair, rope)
    scene.frame_set(3)
    activate(hair)
    assert bpy.ops.furcollide.collider_distance() == {"FINISHED"}
    a = out.data.attributes["furcollide_collider_distance"]
    d = np.empty(len(a.data), np.float32)
    a.data.foreach_get("value", d)
    assert np.isfinite(d).all() and (d >= 0).all()
    assert d.min() < 0.05  # some curves rest against the rope
    played = {}
    for f in range(1, 6):
        scene.frame_set(f)
        played[f] = world(out).copy()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "rope.blend"))
    hair = bpy.data.objects["Fur"]
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    out = hair.furcollide.output
    for f in range(1, 6):
        scene.frame_set(f)
        np.testing.assert_array_equal(world(out), played[f])


# ------------------------------------------------------- collection instances
def instance_meshes(empty):
    """World meshes of everything ``empty`` instances, from Blender's own list of
    instances (``depsgraph.object_instances``): the oracle for the placement."""
    dg = bpy.context.evaluated_depsgraph_get()
    return [world_mesh(inst.object, inst.matrix_world) for inst in dg.object_instances
            if inst.is_instance and inst.parent is not None and inst.parent.original == empty
            and inst.object.type == "MESH"]  # (a curve is listed as a curve and as its mesh)


def prop_asset(name="Prop"):
    """A collection not linked to the scene (as a linked asset is), holding a box
    and a rope, with an instance offset."""
    coll = bpy.data.collections.new(name)
    box = make_box(name + "Box", size=0.4, location=(0.3, 0.0, 0.2))
    rope = make_rope(name + "Rope", depth=0.06, x=0.3, z=0.7)
    for o in (box, rope):
        bpy.context.scene.collection.objects.unlink(o)
        coll.objects.link(o)
    coll.instance_offset = (0.3, 0.0, 0.0)
    return coll, box, rope


def instance_of(coll, name="PropInstance"):
    empty = bpy.data.objects.new(name, None)
    empty.instance_type = "COLLECTION"
    empty.instance_collection = coll
    bpy.context.scene.collection.objects.link(empty)
    return empty


def test_collection_instance_collides_where_blender_places_it(fc):
    """A collection instance (a linked asset) swept through the fur, rotated and
    scaled: everything in it collides where Blender draws it; moving the instance
    never rebuilds; Collider Distance measures to it."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    hair = make_hair(nx=6, ny=6)
    coll, box, rope = prop_asset()
    empty = instance_of(coll)
    empty.rotation_euler = (0.0, 0.0, 0.3)
    empty.scale = (1.2, 1.0, 1.1)
    empty.location.z = 0.1
    sweep(empty, -1.0, 0.9, (1, 8))
    scene.frame_set(1)
    out = setup_with(hair, empty)
    assert [c.object for c in hair.furcollide.colliders] == [empty]
    refs = fc.colliders.collider_objects(hair, scene)
    assert sorted(r.name for r in refs) == ["PropInstance › PropBox", "PropInstance › PropRope"]
    rt = fc.registry.get_runtime(hair)
    moved = 0
    for f in range(1, 9):
        scene.frame_set(f)
        assert fc.registry.status_for(hair) == ("INFO", "")
        meshes = instance_meshes(empty)
        assert len(meshes) == 2
        for V, F in meshes:
            assert crossing_free_curves(out, V, F).size == 0, f
        moved += int((np.abs(world(out) - world(hair)) > 1e-6).any(axis=1).sum())
    assert moved > 0
    assert all(e.collider.build_count == 1 for e in rt.colliders.values())
    activate(hair)
    assert bpy.ops.furcollide.collider_distance() == {"FINISHED"}
    a = out.data.attributes["furcollide_collider_distance"]
    d = np.empty(len(a.data), np.float32)
    a.data.foreach_get("value", d)
    assert np.isfinite(d).all() and d.min() < 0.05


def test_nested_instances_in_the_collider_collection_and_edits(fc):
    """An instance of a collection that itself holds an instance, put in the
    collider collection, collides where Blender places it; editing the asset's
    mesh at the current frame is seen on the next frames."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    hair = make_hair(nx=6, ny=6)
    inner, box, _rope = prop_asset("Inner")
    outer = bpy.data.collections.new("Outer")
    nested = bpy.data.objects.new("Nested", None)
    nested.instance_type = "COLLECTION"
    nested.instance_collection = inner
    nested.location = (0.0, 0.2, 0.0)
    outer.objects.link(nested)
    empty = instance_of(outer, "OuterInstance")
    sweep(empty, -1.0, 0.8, (1, 6))
    scene.frame_set(1)
    out = setup_with(hair)
    holder = bpy.data.collections.new("Colliders")
    scene.collection.children.link(holder)
    scene.collection.objects.unlink(empty)
    holder.objects.link(empty)
    hair.furcollide.collider_collection = holder
    names = sorted(r.name for r in fc.colliders.collider_objects(hair, scene))
    assert names == ["OuterInstance › Nested › InnerBox", "OuterInstance › Nested › InnerRope"]

    def check():
        for f in range(1, 7):
            scene.frame_set(f)
            assert fc.registry.status_for(hair) == ("INFO", "")
            meshes = instance_meshes(empty)  # nested: the outermost parent is reported
            assert len(meshes) == 2
            for V, F in meshes:
                assert crossing_free_curves(out, V, F).size == 0, f

    check()
    scene.frame_set(1)
    for v in box.data.vertices:  # the asset's box grows (edited in place)
        v.co = tuple(1.5 * c for c in v.co)
    box.data.update()
    bpy.context.view_layer.update()
    check()
    rt = fc.registry.get_runtime(hair)
    e = next(e for k, e in rt.colliders.items()
             if isinstance(k, tuple) and k[-1] == box.session_uid)
    assert np.abs(e.collider.vertices).max() > 0.29  # the grown box (half size 0.3)


def test_render_with_the_rope_and_the_instance_hidden(fc, tmp_path):
    """The usual render set-up hides the colliders from render: the rope and the
    instance (and the asset inside it) still reach the output through the
    FurCollide Inputs modifier, and every rendered frame equals the viewport's."""
    from conftest import render_camera
    from test_bl_flows import _check_render, _node_objects, _render

    scene = bpy.context.scene
    hair, rope = rope_scene(frames=(1, 5))
    coll, box, _ = prop_asset()
    empty = instance_of(coll)
    sweep(empty, 1.2, -0.2, (1, 5))
    scene.frame_set(1)
    out = setup_with(hair, rope, empty)
    assert {rope, empty, box} <= _node_objects(out)
    rope.hide_render = empty.hide_render = True
    render_camera(scene)
    seen, statuses = _render(tmp_path, "rope", [out], hair)
    viewport = _check_render(seen, statuses, [out], range(1, 6))
    assert any(np.abs(viewport[f][out.name] - world(hair)).max() > 0.05 for f in range(2, 6))
