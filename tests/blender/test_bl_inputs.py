"""Inputs: growth surface, pinch, generated (procedural) source curves,
transforms and parents, enable-attribute problems, the output's own modifiers."""

import bpy
import numpy as np
import pytest

pytestmark = pytest.mark.blender


def _ground(size=4.0):
    me = bpy.data.meshes.new("Ground")
    h = size / 2
    me.from_pydata([(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)], [], [(0, 1, 2, 3)])
    ob = bpy.data.objects.new("Ground", me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def play(frames):
    for f in frames:
        bpy.context.scene.frame_set(f)


def test_attract_to_growth_surface_needs_surface(fc):
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    s = hair.furcollide
    s.attract_to_growth_surface = True
    play(range(1, 4))
    assert "Surface" in s.status_message  # clear message, no exception
    hair.data.surface = _ground()
    bpy.context.scene.frame_set(1)
    play(range(1, 8))
    assert s.status_message == ""
    assert s.stat_colliding + s.stat_recovering > 0


def test_pinch_detected_and_put_to_growth_surface(fc):
    hair, box = fc.make_scene(animate=False)
    box.location = (0, 0, 0)  # swallows the roots of the central curves
    hair.data.surface = _ground()
    out = fc.setup(hair, [box])
    s = hair.furcollide
    play(range(1, 4))
    assert s.stat_pinched > 0
    st = np.zeros(len(out.data.curves), np.int32)
    out.data.attributes["furcollide_status"].data.foreach_get("value", st)
    assert (st == fc.core.Status.PINCHED).sum() == s.stat_pinched
    s.pinch_resolution = "growth_surface"
    bpy.context.scene.frame_set(1)
    play(range(1, 4))
    assert s.stat_pinched > 0 and s.status_message == ""


def _generator_modifier(hair):
    """Geometry nodes that *create* the curves (like Quick Fur's stack)."""
    ng = bpy.data.node_groups.new("gen", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    go = ng.nodes.new("NodeGroupOutput")
    grid = ng.nodes.new("GeometryNodeMeshGrid")
    grid.inputs["Size X"].default_value = 1.0
    grid.inputs["Size Y"].default_value = 1.0
    grid.inputs["Vertices X"].default_value = 5
    grid.inputs["Vertices Y"].default_value = 5
    line = ng.nodes.new("GeometryNodeCurvePrimitiveLine")
    line.inputs["End"].default_value = (0, 0, 1)
    resample = ng.nodes.new("GeometryNodeResampleCurve")
    resample.inputs["Count"].default_value = 6
    inst = ng.nodes.new("GeometryNodeInstanceOnPoints")
    real = ng.nodes.new("GeometryNodeRealizeInstances")
    ng.links.new(line.outputs[0], resample.inputs[0])
    ng.links.new(grid.outputs[0], inst.inputs["Points"])
    ng.links.new(resample.outputs[0], inst.inputs["Instance"])
    ng.links.new(inst.outputs[0], real.inputs[0])
    ng.links.new(real.outputs[0], go.inputs[0])
    mod = hair.modifiers.new("gen", "NODES")
    mod.node_group = ng


def test_procedural_source_with_no_original_curves(fc):
    sc = bpy.context.scene
    sc.frame_start, sc.frame_end = 1, 12
    hc = bpy.data.hair_curves.new("Gen")
    hair = bpy.data.objects.new("Gen", hc)
    sc.collection.objects.link(hair)
    _generator_modifier(hair)
    box = fc.make_scene.__globals__["make_box"]()
    box.location = (-1.2, 0, 0.6)
    box.keyframe_insert("location", frame=1)
    box.location = (1.2, 0, 0.6)
    box.keyframe_insert("location", frame=12)
    sc.frame_set(1)
    assert len(hair.data.curves) == 0
    out = fc.setup(hair, [box])
    assert len(out.data.curves) == 25 and len(out.data.points) == 150
    play(range(1, 13))
    s = hair.furcollide
    assert s.status_message == ""
    hits = 0
    bpy.context.scene.frame_set(1)
    for f in range(1, 13):
        bpy.context.scene.frame_set(f)
        hits += s.stat_colliding
    assert hits > 0


def test_transformed_and_parented_source(fc):
    hair, box = fc.make_scene(animate=False)
    parent = bpy.data.objects.new("Rig", None)
    bpy.context.scene.collection.objects.link(parent)
    parent.location = (5, 0, 0)
    hair.parent = parent
    hair.location = (0, 3, 0)
    hair.rotation_euler = (0, 0, 0.5)
    box.location = (5.0, 3.0, 0.6)  # where the hair is in world space
    bpy.context.view_layer.update()
    out = fc.setup(hair, [box])
    assert out.parent == parent
    bpy.context.view_layer.update()
    assert np.allclose(np.array(out.matrix_world), np.array(hair.matrix_world))
    play(range(1, 3))
    assert hair.furcollide.stat_colliding > 0
    # before the start frame the output is the source, exactly (same local space)
    hair.furcollide.frame_start = 2
    bpy.context.scene.frame_set(1)
    assert np.allclose(fc.positions(out), fc.positions(hair), atol=1e-6)


def test_enable_attribute_on_wrong_domain_warns(fc):
    hair, box = fc.make_scene()
    hair.data.attributes.new("furcollide_enable", "FLOAT", "POINT")
    fc.setup(hair, [box])
    play(range(1, 3))
    assert "domain" in hair.furcollide.status_message
    assert hair.furcollide.stat_disabled == 0


def test_output_keeps_user_modifiers_and_remove_keep_output(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    user = out.modifiers.new("My Smooth", "NODES")
    play(range(1, 4))
    bpy.context.scene.frame_set(1)
    bpy.ops.furcollide.reset()
    assert out.modifiers.get("My Smooth") == user
    assert out.modifiers[0].name == fc.dependencies.DEPENDENCY_MODIFIER
    assert bpy.ops.furcollide.remove(keep_output=True) == {"FINISHED"}
    assert out.name in bpy.data.objects and out.modifiers.get("My Smooth")
    assert out.modifiers.get(fc.dependencies.DEPENDENCY_MODIFIER) is None
    assert not out.furcollide.is_output


def _sheet(z=0.5):
    me = bpy.data.meshes.new("Cloth")
    me.from_pydata([(-1, -1, z), (1, -1, z), (1, 1, z), (-1, 1, z)], [], [(0, 1, 2, 3)])
    ob = bpy.data.objects.new("Cloth", me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


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
    rt = fc.registry.get_runtime(hair)
    col = rt.colliders[sheet.session_uid].collider
    assert col.double_sided and col.offset == pytest.approx(0.05)


def test_invalid_setting_combination_is_a_status_not_a_traceback(fc, capsys):
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    s = hair.furcollide
    s.rotation_precision = 10.0
    s.max_angle = 5.0  # core: max_angle must be >= rotation_precision
    bpy.context.scene.frame_set(1)
    assert "max_angle" in s.status_message
    assert "Traceback" not in capsys.readouterr().err
    s.max_angle = 90.0
    bpy.context.scene.frame_set(1)
    assert s.status_message == ""


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
    rt = fc.registry.get_runtime(hair)
    flags = {e.collider.name: e.collider.deforming for e in rt.colliders.values()}
    assert flags == {"Box": True, "Still": False}
