"""Colliders: ropes (bevelled curves), text, NURBS surfaces, collection instances,
collider collections, deforming and rigid colliders (BVH rebuilds), Subdivision
Surface, mirrored (negative scale) colliders, excluded collections, linked duplicates,
double-sided sheets and collision offsets, the source or its Surface listed as one."""

import bpy
import numpy as np
import pytest
from helpers import (
    activate,
    assert_unchanged,
    check_render,
    dependency_objects,
    evaluated_world_mesh,
    linear,
    make_box,
    make_hair,
    make_surface,
    no_traceback,
    offsets_of,
    oracle,
    play_checked,
    poly,
    positions,
    positions_per_frame,
    reference_frames,
    render_camera,
    render_watching,
    same_frames,
    segments_in_box,
    snapshot,
    status_of,
    sweep_box,
    sweep_setup,
    world,
    world_mesh,
)

from core import Status

pytestmark = pytest.mark.blender

PINCHED, UNRESOLVED = Status.PINCHED, Status.UNRESOLVED


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
    linear(ob)


def crossing_free_curves(out, V, F):
    """Curves not pinched/unresolved whose segments cross the mesh (V, F)."""
    hit = oracle.segments_hit_mesh(world(out), offsets_of(out), V, F)
    return np.flatnonzero(hit & ~np.isin(status_of(out), (PINCHED, UNRESOLVED)))


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


def _growing_box(frames=(1, 6)):
    """A box of edge 0.3 at (0, 0, 0.6) whose animated shape key doubles it."""
    box = make_box("Blob", size=0.3, location=(0, 0, 0.6))
    box.shape_key_add(name="Basis")
    grow = box.shape_key_add(name="Grow")
    for i, v in enumerate(box.data.vertices):
        grow.data[i].co = v.co * 2.0
    grow.value = 0.0
    grow.keyframe_insert("value", frame=frames[0])
    grow.value = 1.0
    grow.keyframe_insert("value", frame=frames[1])
    return box


def _world_bounds(ob):
    dg = bpy.context.evaluated_depsgraph_get()
    e = ob.evaluated_get(dg)
    V = np.array([v.co[:] for v in e.data.vertices], np.float64)
    M = np.array(e.matrix_world)
    W = V @ M[:3, :3].T + M[:3, 3]
    return W.min(0), W.max(0)


def _free_curves_in_box(out, lo, hi):
    P, offs = world(out), offsets_of(out)
    bad = segments_in_box(P, offs, (lo + hi) / 2, (hi - lo) / 2)
    free = np.flatnonzero(~np.isin(status_of(out), (PINCHED, UNRESOLVED)))
    return np.intersect1d(bad, free)


def _densify(P, offs, n=16):
    """n points along every segment of the curves, and their curve index."""
    t = np.linspace(0, 1, n)[:, None, None]
    sizes = np.diff(offs)
    curve = np.repeat(np.arange(len(sizes)), sizes - 1)
    s0 = np.arange(len(curve)) + curve
    pts = P[s0][None] * (1 - t) + P[s0 + 1][None] * t  # (n, segments, 3)
    return pts.reshape(-1, 3), np.tile(curve, n)


def _curves_inside_convex(out, ob, eps=1e-4):
    """Curves of ``out`` with a point strictly inside the convex evaluated mesh of
    ``ob`` (translated only)."""
    dg = bpy.context.evaluated_depsgraph_get()
    me = ob.evaluated_get(dg).data
    t = np.array(ob.matrix_world.translation)
    C = np.array([p.center[:] for p in me.polygons]) + t
    N = np.array([p.normal[:] for p in me.polygons])
    pts, curve = _densify(world(out), offsets_of(out))
    inside = (np.einsum("pk,fk->pf", pts, N) - np.einsum("fk,fk->f", C, N) < -eps).all(1)
    return np.unique(curve[inside])


def _hair_at(name, xy, npts=5, length=1.0):
    hc = bpy.data.hair_curves.new(name)
    hc.add_curves([npts] * len(xy))
    t = np.linspace(0, length, npts)
    P = np.array([(x, y, z) for x, y in xy for z in t], np.float32)
    hc.position_data.foreach_set("vector", P.ravel())
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def _mirrored_box(location, scale=(-1.0, 1.0, 1.0)):
    box = make_box(location=location)
    box.scale = scale
    bpy.context.view_layer.update()
    det = np.linalg.det(np.array(box.matrix_world)[:3, :3])
    assert (det < 0) == (np.prod(scale) < 0)
    return box


def _sheet(z=0.5):
    me = bpy.data.meshes.new("Cloth")
    me.from_pydata([(-1, -1, z), (1, -1, z), (1, 1, z), (-1, 1, z)], [], [(0, 1, 2, 3)])
    ob = bpy.data.objects.new("Cloth", me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


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
        assert fc.store.report.status_for(hair) == ("INFO", "")
        V, F = evaluated_world_mesh(rope)
        assert len(F) > 50  # the bevel's tube and caps
        assert crossing_free_curves(out, V, F).size == 0, f
        np.testing.assert_array_equal(world(out)[offs[:-1]], world(hair)[offs[:-1]])
        met += int((status_of(out) == Status.COLLIDING).sum())
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
    rt = fc.store.registry.get_runtime(hair)
    for f in range(1, 9):
        scene.frame_set(f)
    col = rt.colliders.entries[rope.session_uid].collider
    assert col.build_count == 1
    assert fc.frame.colliders.is_deforming(rope, scene) is False
    scene.frame_set(1)
    rope.data.bevel_depth = 0.05
    rope.data.keyframe_insert("bevel_depth", frame=1)
    rope.data.bevel_depth = 0.15
    rope.data.keyframe_insert("bevel_depth", frame=8)
    bpy.context.view_layer.update()
    assert fc.frame.colliders.is_deforming(rope, scene) is True
    out = hair.furcollide.output
    for f in range(1, 9):
        scene.frame_set(f)
        V, F = evaluated_world_mesh(rope)
        assert crossing_free_curves(out, V, F).size == 0, f
        col = rt.colliders.entries[rope.session_uid].collider
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
        assert fc.store.report.status_for(hair) == ("INFO", "")
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
    names = {r.name for r in fc.frame.colliders.collider_objects(hair, scene)}
    assert names == {"Sign", ball.name}
    moved = 0
    for f in range(1, 7):
        scene.frame_set(f)
        assert fc.store.report.status_for(hair) == ("INFO", "")
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
    poll = fc.settings.property_helpers.poll_collider
    assert [poll(None, o) for o in (box, rope, empty, other, hair)] == [
        True, True, False, False, False]
    # a hair object put in the list from Python is skipped, never solved against
    hair.furcollide.colliders.add().object = other
    names = [r.name for r in fc.frame.colliders.collider_objects(hair)]
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
    refs = fc.frame.colliders.collider_objects(hair, scene)
    assert sorted(r.name for r in refs) == ["PropInstance › PropBox", "PropInstance › PropRope"]
    rt = fc.store.registry.get_runtime(hair)
    moved = 0
    for f in range(1, 9):
        scene.frame_set(f)
        assert fc.store.report.status_for(hair) == ("INFO", "")
        meshes = instance_meshes(empty)
        assert len(meshes) == 2
        for V, F in meshes:
            assert crossing_free_curves(out, V, F).size == 0, f
        moved += int((np.abs(world(out) - world(hair)) > 1e-6).any(axis=1).sum())
    assert moved > 0
    assert all(e.collider.build_count == 1 for e in rt.colliders.entries.values())
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
    names = sorted(r.name for r in fc.frame.colliders.collider_objects(hair, scene))
    assert names == ["OuterInstance › Nested › InnerBox", "OuterInstance › Nested › InnerRope"]

    def check():
        for f in range(1, 7):
            scene.frame_set(f)
            assert fc.store.report.status_for(hair) == ("INFO", "")
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
    rt = fc.store.registry.get_runtime(hair)
    e = next(e for k, e in rt.colliders.entries.items()
             if isinstance(k, tuple) and k[-1] == box.session_uid)
    assert np.abs(e.collider.vertices).max() > 0.29  # the grown box (half size 0.3)


def test_render_with_the_rope_and_the_instance_hidden(fc, tmp_path):
    """The usual render set-up hides the colliders from render: the rope and the
    instance (and the asset inside it) still reach the output through the
    FurCollide Inputs modifier, and every rendered frame equals the viewport's."""

    scene = bpy.context.scene
    hair, rope = rope_scene(frames=(1, 5))
    coll, box, _ = prop_asset()
    empty = instance_of(coll)
    sweep(empty, 1.2, -0.2, (1, 5))
    scene.frame_set(1)
    out = setup_with(hair, rope, empty)
    assert {rope, empty, box} <= dependency_objects(out)
    rope.hide_render = empty.hide_render = True
    render_camera(scene)
    seen, statuses = render_watching(tmp_path, "rope", [out], hair)
    viewport = check_render(seen, statuses, [out], range(1, 6))
    assert any(np.abs(viewport[f][out.name] - world(hair)).max() > 0.05 for f in range(2, 6))


def test_rigid_collider_never_rebuilds_deforming_does(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    rt = fc.store.registry.get_runtime(hair)
    positions_per_frame(out, range(1, 13))
    col = rt.colliders.entries[box.session_uid].collider
    assert col.build_count == 1
    # a deforming collider (animated modifier) is rebuilt when its shape changes;
    # editing a collider invalidates the frames after the current one
    bpy.context.scene.frame_set(1)
    mod = box.modifiers.new("grow", "DISPLACE")
    mod.strength = 0.0
    mod.keyframe_insert("strength", frame=1)
    mod.strength = 0.2
    mod.keyframe_insert("strength", frame=12)
    bpy.context.view_layer.update()  # fires depsgraph_update_post, as the UI does
    assert len(rt.cache.memory) == 0
    positions_per_frame(out, range(1, 13))
    col = rt.colliders.entries[box.session_uid].collider
    assert col.build_count > 3


def test_double_sided_sheet_and_own_offset(fc):
    hair, box = fc.make_scene(animate=False)
    box.location = (5, 5, 5)  # out of the way
    sheet = _sheet()
    fc.setup(hair, [sheet])
    s = hair.furcollide
    c = s.colliders[0]
    c.double_sided = True
    bpy.context.scene.frame_set(1)
    assert s.stat_colliding == len(hair.data.curves)  # every hair crosses the sheet
    assert s.stat_pinched == 0  # an open sheet never pinches
    # an own offset on the collider is used instead of the setup's
    c.use_offset = True
    c.collision_offset = 0.05
    bpy.context.scene.frame_set(1)
    assert s.status_message == "" and s.stat_colliding == len(hair.data.curves)
    rt = fc.store.registry.get_runtime(hair)
    col = rt.colliders.entries[sheet.session_uid].collider
    assert col.double_sided and col.offset == pytest.approx(0.05)


def test_deforming_colliders_get_the_fast_bvh_build(fc):
    """A collider with shape keys (or deform modifiers, cloth, geometry nodes) is built
    as a deforming core Collider; a plain one is not. Decided from the object's set-up,
    so results never depend on which frames were played before."""
    hair, box = fc.make_scene(frames=(1, 4))
    still = bpy.data.objects.new("Still", box.data.copy())
    bpy.context.scene.collection.objects.link(still)
    still.location = (5, 5, 5)
    box.shape_key_add(name="Basis")
    box.shape_key_add(name="Squash").value = 0.5
    fc.setup(hair, [box, still])
    bpy.context.scene.frame_set(2)
    rt = fc.store.registry.get_runtime(hair)
    flags = {e.collider.name: e.collider.deforming for e in rt.colliders.entries.values()}
    assert flags == {"Box": True, "Still": False}


def test_two_setups_share_a_deforming_collider(fc):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    scene.frame_set(1)
    hair_a = make_hair("FurA", nx=4, ny=4)
    hair_b = make_hair("FurB", nx=3, ny=3, spacing=0.25)
    blob = _growing_box()
    scene.frame_set(1)  # the key's value at frame 1 (0), not the value keyed last
    wall = make_box("Wall", size=0.5, location=(0.0, 0.45, 0.6))  # rigid, B only
    out_a = fc.setup(hair_a, [blob])
    out_b = fc.setup(hair_b, [blob, wall])
    rt_a, rt_b = fc.store.registry.get_runtime(hair_a), fc.store.registry.get_runtime(hair_b)
    contact = {hair_a.name: 0, hair_b.name: 0}
    alone = {}
    for f in range(1, 7):
        scene.frame_set(f)
        lo, hi = _world_bounds(blob)
        for hair, out in ((hair_a, out_a), (hair_b, out_b)):
            s = hair.furcollide
            assert s.status_message == "", (hair.name, f, s.status_message)
            assert len(_free_curves_in_box(out, lo, hi)) == 0, (hair.name, f)
            contact[hair.name] += s.stat_colliding
        wl, wh = _world_bounds(wall)
        assert len(_free_curves_in_box(out_b, wl, wh)) == 0, f
        alone[f] = fc.positions(out_a).copy()
    assert all(contact.values()), contact
    assert hi[0] - lo[0] == pytest.approx(0.6, abs=1e-5)  # the key really animated
    flags_a = {e.collider.name: e.collider.deforming for e in rt_a.colliders.entries.values()}
    flags_b = {e.collider.name: e.collider.deforming for e in rt_b.colliders.entries.values()}
    assert flags_a == {"Blob": True} and flags_b == {"Blob": True, "Wall": False}
    is_deforming = fc.frame.colliders.is_deforming
    assert is_deforming(blob, scene) and not is_deforming(wall, scene)
    # each setup owns its core collider; A's result does not depend on B
    assert rt_a.colliders.entries[blob.session_uid].collider is not \
        rt_b.colliders.entries[blob.session_uid].collider
    hair_b.furcollide.enabled = False
    activate(hair_a)
    scene.frame_set(1)
    bpy.ops.furcollide.reset()
    for f in range(1, 7):
        scene.frame_set(f)
        np.testing.assert_array_equal(fc.positions(out_a), alone[f], err_msg=f"frame {f}")


def test_subdivision_surface_collider_collides_as_evaluated(fc):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 3
    scene.frame_set(1)
    # x = 0.23 crosses the cage (|x| <= 0.25) but not the subdivided shape (|x| <= 0.21)
    # (Poly: the polygon's own clearance, no spline margin)
    hair = poly(_hair_at("Fur", [(0.23, 0.0), (0.0, 0.0), (0.7, 0.0)]))
    box = make_box(location=(0, 0, 0.6))
    sub = box.modifiers.new("Subdivision", "SUBSURF")
    sub.levels = sub.render_levels = 2
    lo, hi = _world_bounds(box)
    assert hi[0] < 0.215  # the evaluated mesh is the subdivided one
    out = fc.setup(hair, [box])
    src = fc.positions(hair).copy()
    scene.frame_set(2)
    scene.frame_set(1)
    st = status_of(out)
    P = fc.positions(out)
    assert st[1] != 0 and st[0] == 0 and st[2] == 0, st
    np.testing.assert_array_equal(P[0:5], src[0:5])  # passes beside the rounded shape
    assert np.abs(P[5:10] - src[5:10]).max() > 0.05
    assert len(_curves_inside_convex(out, box)) == 0
    assert list(_curves_inside_convex(hair, box)) == [1]  # the input crosses it
    # the same collider without its modifier: the cage collides, x = 0.23 too
    sub.show_viewport = False
    bpy.context.view_layer.update()
    scene.frame_set(2)
    scene.frame_set(1)
    st = status_of(out)
    assert st[0] != 0 and st[1] != 0 and st[2] == 0, st
    assert np.abs(fc.positions(out)[0:5] - src[0:5]).max() > 0.01
    assert len(_free_curves_in_box(out, *_world_bounds(box))) == 0
    assert list(_curves_inside_convex(hair, box)) == [0, 1]


@pytest.mark.parametrize("scale", [(-1.0, 1.0, 1.0), (1.0, 1.0, -1.0), (-1.0, -1.0, -1.0)])
def test_mirrored_collider_pushes_out_and_pinches(fc, scale):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 3
    scene.frame_set(1)
    hair = make_hair(nx=4, ny=4)  # x, y in {-0.3, -0.1, 0.1, 0.3}
    box = _mirrored_box((0, 0, 0.6), scale)
    assert np.linalg.det(np.array(box.matrix_world)[:3, :3]) < 0
    out = fc.setup(hair, [box])
    scene.frame_set(1)
    st = status_of(out)
    assert hair.furcollide.status_message == ""
    assert np.count_nonzero(st == Status.COLLIDING) >= 4, st
    assert not np.isin(st, (PINCHED, UNRESOLVED)).any(), st
    assert len(segments_in_box(world(out), offsets_of(out), box.location)) == 0
    # pinch: the box swallows the roots of the 4 central curves only
    box.location = (0, 0, 0)
    bpy.context.view_layer.update()
    scene.frame_set(2)
    scene.frame_set(1)
    roots = fc.positions(hair)[offsets_of(hair)[:-1]]
    inside = (np.abs(roots[:, :2]) < 0.25).all(axis=1)
    assert inside.sum() == 4
    st = status_of(out)
    assert (st[inside] == PINCHED).all() and not (st[~inside] == PINCHED).any(), st
    assert hair.furcollide.stat_pinched == 4


@pytest.mark.parametrize("mirrored", [False, True])
def test_mirrored_collider_keeps_the_collision_offset(fc, mirrored):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 3
    scene.frame_set(1)
    hair = make_hair(nx=4, ny=4)
    box = _mirrored_box((0, 0, 0.6), (-1.0, 1.0, 1.0) if mirrored else (1.0, 1.0, 1.0))
    out = fc.setup(hair, [box])
    hair.furcollide.collision_offset = 0.05
    scene.frame_set(2)
    scene.frame_set(1)
    assert hair.furcollide.status_message == ""
    assert hair.furcollide.stat_colliding >= 4
    lo, hi = np.array(box.location) - 0.25, np.array(box.location) + 0.25
    assert len(_free_curves_in_box(out, lo, hi)) == 0
    # and at least most of the offset is kept (grown box, a little slack)
    assert len(_free_curves_in_box(out, lo - 0.04, hi + 0.04)) == 0


@pytest.mark.parametrize("how", ["list", "collection"])
def test_collider_in_an_excluded_collection(fc, how, capsys):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    hair = make_hair("Fur", nx=4, ny=4)
    box = sweep_box("Box", -1.2, 1.2, (1, 6))
    coll = bpy.data.collections.new("Props")
    scene.collection.children.link(coll)
    coll.objects.link(box)
    scene.collection.objects.unlink(box)
    scene.frame_set(1)
    out = fc.setup(hair, [box] if how == "list" else [])
    if how == "collection":
        hair.furcollide.collider_collection = coll
    # reference: the collider counts while the collection is in the view layer
    ref = []
    for f in range(1, 7):
        scene.frame_set(f)
        ref.append(fc.positions(out).copy())
    assert any(not np.array_equal(p, fc.positions(hair)) for p in ref)

    bpy.context.view_layer.layer_collection.children["Props"].exclude = True
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    got = []
    for f in range(1, 7):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        got.append(fc.positions(out).copy())
    cap = capsys.readouterr()
    assert "Traceback" not in cap.out + cap.err
    # README: "Only meshes linked into the scene collide". The box is still linked into
    # the scene (only excluded from the view layer), so it keeps colliding.
    for f, (a, b) in enumerate(zip(ref, got, strict=True), 1):
        np.testing.assert_array_equal(a, b, err_msg=f"frame {f}")


def test_linked_duplicate_colliders_both_collide(fc):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    hair = make_hair("Fur", nx=8, ny=4, spacing=0.2)
    left = sweep_box("Left", -1.6, -0.4, (1, 6), size=0.3)
    right = left.copy()  # Alt-D: a new object sharing the mesh
    right.name = "Right"
    right.animation_data_clear()
    scene.collection.objects.link(right)
    right.location = (1.6, 0, 0.6)
    right.keyframe_insert("location", frame=1)
    right.location = (0.4, 0, 0.6)
    right.keyframe_insert("location", frame=6)
    right.scale = (1.2, 1.2, 1.2)
    assert right.data is left.data and left.data.users == 2
    scene.frame_set(1)
    out = fc.setup(hair, [left, right])
    assert [c.object.name for c in hair.furcollide.colliders] == ["Left", "Right"]
    rest = fc.positions(hair)
    for f in range(1, 7):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        for box in (left, right):
            lo, hi = _world_bounds(box)
            assert len(_free_curves_in_box(out, lo, hi)) == 0, (box.name, f)
    P = fc.positions(out)
    moved = np.linalg.norm(P - rest, axis=1) > 1e-4
    assert moved[rest[:, 0] < 0].any() and moved[rest[:, 0] > 0].any()
    rt = fc.store.registry.get_runtime(hair)
    assert {e.collider.name for e in rt.colliders.entries.values()} == {"Left", "Right"}
    assert hair.furcollide.stat_colliding > 0


def test_source_output_and_a_repeated_collider_in_the_list(fc, capsys):
    """The source and the output in their own collider list and the box listed twice:
    the hair never collides with itself, the box counts once, nothing fails."""
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    groom = snapshot(hair)
    ref = reference_frames(fc, scene, hair)
    s = hair.furcollide
    for o in (hair, box, out):
        s.colliders.add().object = o  # Python skips the list's mesh-only filter
    assert [c.object.name for c in s.colliders] == ["Box", "Fur", "Box", "Fur FurCollide"]
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    same_frames(play_checked(scene, hair), ref)
    # Add Collider with the box (and the hair itself) selected adds nothing twice
    activate(hair, box)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    assert len(s.colliders) == 5 and s.colliders[-1].object is None  # an empty slot
    same_frames(play_checked(scene, hair), ref)
    assert_unchanged(hair, groom)
    no_traceback(capsys)


@pytest.mark.parametrize("skin", ["open_sheet", "closed_body"])
def test_surface_listed_as_a_collider(fc, skin, capsys):
    """The hair's Surface also selected as a collider (the usual mistake: select the
    body and the props, then the hair). README: the growth surface is not a collider
    and cannot be one. Either it is left out (same result as without it) or the
    status names it."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 4
    hair = make_hair("Fur", nx=3, ny=3, length=0.5)
    if skin == "open_sheet":
        body = make_surface("Skin", half=1.0, n=2)
    else:
        body = make_box("Skin", size=2.0, location=(0, 0, -1.0))  # top face at z = 0
    hair.data.surface = body
    box = make_box("Box", size=0.5, location=(0, 0, 0.4))  # static, through every curve
    scene.frame_set(1)
    out = fc.setup(hair, [box])
    ref = play_checked(scene, hair, range(1, 5))
    assert hair.furcollide.stat_colliding == 9
    groom = snapshot(hair)
    activate(hair, body)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    assert [c.object.name for c in hair.furcollide.colliders] == ["Box", "Skin"]
    scene.frame_set(1)
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}  # solve every frame again
    got = play_checked(scene, hair, range(1, 5), check_status=False)
    msg = hair.furcollide.status_message
    assert_unchanged(hair, groom)
    no_traceback(capsys)
    assert out.name in scene.objects
    if "Skin" not in msg:
        same_frames(got, ref)


def test_collision_offset_keeps_the_offset_not_twice(fc, capsys):
    """Hair whose tips stop 0.35 below a static box, Collision Offset 0.3: the hair is
    farther than the offset from the box everywhere, so nothing may move or pinch."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 2
    hair = make_hair("Fur", nx=3, ny=3, length=0.1)  # tips at z = 0.1
    make_box("Box", size=0.5, location=(0, 0, 0.7))  # bottom face at z = 0.45
    scene.frame_set(1)
    out = fc.setup(hair, [bpy.data.objects["Box"]])
    hair.furcollide.collision_offset = 0.3
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    scene.frame_set(2)
    no_traceback(capsys)
    s = hair.furcollide
    assert (s.stat_pinched, s.stat_colliding, s.stat_unresolved) == (0, 0, 0)
    np.testing.assert_array_equal(positions(out), positions(hair))


def test_collider_collection_holding_everything(fc):
    hair, box = fc.make_scene()
    coll = bpy.data.collections.new("Everything")
    bpy.context.scene.collection.children.link(coll)
    out = fc.setup(hair, [])
    for o in (hair, box, out):
        coll.objects.link(o)
    hair.furcollide.collider_collection = coll
    for f in range(1, 8):
        bpy.context.scene.frame_set(f)
        assert hair.furcollide.status_message == ""
    assert hair.furcollide.stat_colliding > 0
    names = {r.name for r in fc.frame.colliders.collider_objects(hair)}
    assert names == {"Box"}
