"""Frame handler rules: reset, step, cache hits, jumps, subframes, invalidation."""

import bpy
import numpy as np
import pytest

pytestmark = pytest.mark.blender


def play(fc, out, frames):
    sc = bpy.context.scene
    rec = {}
    for f in frames:
        sc.frame_set(f)
        rec[f] = fc.positions(out).copy()
    return rec


def test_scrub_back_is_exact_and_jump_holds(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    rt = fc.registry.get_runtime(hair)
    rec = play(fc, out, range(1, 13))
    assert len(rt.memory) == 12
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
    rec2 = play(fc, out, range(2, 13))
    for f in rec2:
        assert np.array_equal(rec2[f], rec[f]), f
    assert not hair.furcollide.is_outdated


def test_subframes_and_repeats_do_not_step(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    rt = fc.registry.get_runtime(hair)
    rec = play(fc, out, range(1, 7))
    sc = bpy.context.scene
    sc.frame_set(6, subframe=0.5)
    assert np.array_equal(fc.positions(out), rec[6])
    assert sorted(rt.memory.frames) == list(range(1, 7))
    sc.frame_set(6)
    sc.frame_set(6)
    assert np.array_equal(fc.positions(out), rec[6])
    assert rt.solver_frame == 6


def test_setting_change_invalidates_after_current(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    rt = fc.registry.get_runtime(hair)
    rec = play(fc, out, range(1, 13))
    bpy.context.scene.frame_set(6)
    hair.furcollide.mode = "stiff"
    assert sorted(rt.memory.frames) == list(range(1, 7))
    # an earlier cached frame was solved in the old mode: it is not shown as current
    bpy.context.scene.frame_set(3)
    assert hair.furcollide.is_outdated and "settings" in hair.furcollide.status_message
    assert len(rt.memory) == 0
    assert np.array_equal(fc.positions(out), rec[6])  # the output is left as it was
    play(fc, out, range(1, 13))
    # range changes invalidate: a shorter end drops the frames after it...
    hair.furcollide.frame_end = 4
    assert sorted(rt.memory.frames) == [1, 2, 3, 4]
    # ... a new start drops everything
    hair.furcollide.frame_start = 2
    assert len(rt.memory) == 0


def test_mode_change_mid_animation_needs_the_start_frame(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    play(fc, out, range(1, 7))
    hair.furcollide.mode = "soft"
    bpy.context.scene.frame_set(7)
    assert hair.furcollide.is_outdated and "another mode" in hair.furcollide.status_message
    # a non-mode setting continues from the cached state
    hair.furcollide.mode = "bend"
    bpy.context.scene.frame_set(6)
    hair.furcollide.recovery_rate = 0.9
    bpy.context.scene.frame_set(7)
    assert not hair.furcollide.is_outdated and hair.furcollide.stat_frame == 7


def test_mode_change_then_play_from_start(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    play(fc, out, range(1, 8))
    bpy.context.scene.frame_set(1)
    hair.furcollide.mode = "soft"
    rec = play(fc, out, range(1, 8))
    assert hair.furcollide.status_message == ""
    assert not hair.furcollide.is_outdated
    assert len(rec) == 7


def test_deleted_and_renamed_collider(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    ref = play(fc, out, range(1, 13))
    hits = {}
    for f in range(6, 13):
        bpy.context.scene.frame_set(f)
        hits[f] = hair.furcollide.stat_colliding
    assert any(hits.values())
    # renaming mid-animation changes nothing
    bpy.context.scene.frame_set(1)
    bpy.ops.furcollide.reset()
    play(fc, out, range(2, 6))
    box.name = "Renamed Box"
    rec = play(fc, out, range(6, 13))
    for f in rec:
        assert np.array_equal(rec[f], ref[f]), f
    # deleting it mid-animation: no error, later frames solved without it
    bpy.context.scene.frame_set(5)
    bpy.data.objects.remove(box)
    for f in range(6, 13):
        bpy.context.scene.frame_set(f)
        assert hair.furcollide.stat_colliding == 0, f
        assert hair.furcollide.status_message == ""
    assert hair.furcollide.colliders[0].object is None


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


def test_source_topology_change_is_reported_and_nothing_lost(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    rt = fc.registry.get_runtime(hair)
    rec = play(fc, out, range(1, 7))
    n = len(hair.data.curves)
    hair.data.add_curves([5])
    P = fc.positions(hair)
    P[-5:] = [(2.0, 2.0, z) for z in np.linspace(0, 1, 5)]
    hair.data.position_data.foreach_set("vector", P.ravel())
    bpy.context.scene.frame_set(7)
    msg = hair.furcollide.status_message
    assert "changed" in msg and str(n) in msg and str(n + 1) in msg
    assert np.array_equal(fc.positions(out), rec[6])
    assert len(rt.memory) == 6
    assert len(out.data.curves) == n
    bpy.context.scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    assert len(out.data.curves) == n + 1
    play(fc, out, range(2, 5))
    assert hair.furcollide.status_message == ""


def _enable_by_frame_modifier(hair, until):
    """GN modifier storing furcollide_enable = frame < until on every curve."""
    ng = bpy.data.node_groups.new("enable", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gi, go = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    store = ng.nodes.new("GeometryNodeStoreNamedAttribute")
    store.data_type = "BOOLEAN"
    store.domain = "CURVE"
    store.inputs["Name"].default_value = "furcollide_enable"
    t = ng.nodes.new("GeometryNodeInputSceneTime")
    cmp = ng.nodes.new("FunctionNodeCompare")
    cmp.data_type = "FLOAT"
    cmp.operation = "LESS_THAN"
    cmp.inputs[1].default_value = until
    ng.links.new(t.outputs["Frame"], cmp.inputs[0])
    ng.links.new(cmp.outputs[0], store.inputs["Value"])
    ng.links.new(gi.outputs[0], store.inputs[0])
    ng.links.new(store.outputs[0], go.inputs[0])
    mod = hair.modifiers.new("enable", "NODES")
    mod.node_group = ng


def test_animated_per_curve_enable(fc):
    hair, box = fc.make_scene()
    _enable_by_frame_modifier(hair, until=6)
    out = fc.setup(hair, [box])
    sc = bpy.context.scene
    for f in range(1, 6):
        sc.frame_set(f)
        assert hair.furcollide.stat_disabled == 0
    sc.frame_set(6)
    assert hair.furcollide.stat_disabled == len(hair.data.curves)
    st = np.zeros(len(out.data.curves), np.int32)
    out.data.attributes["furcollide_status"].data.foreach_get("value", st)
    assert (st == fc.core.Status.DISABLED).all()


def test_rigid_collider_never_rebuilds_deforming_does(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    rt = fc.registry.get_runtime(hair)
    play(fc, out, range(1, 13))
    col = rt.colliders[box.session_uid].collider
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
    assert len(rt.memory) == 0
    play(fc, out, range(1, 13))
    col = rt.colliders[box.session_uid].collider
    assert col.build_count > 3


def test_an_edit_in_a_scene_the_window_does_not_show_drops_after_its_own_frame(fc):
    """The depsgraph check of scene B, while the window shows scene A at another frame,
    drops B's cached frames after B's current frame (nothing, at its last cached
    frame), not after A's."""
    win = bpy.context.window
    sc_a = bpy.context.scene
    sc_b = bpy.data.scenes.new("B")
    win.scene = sc_b
    hair, box = fc.make_scene(frames=(1, 8))  # in B, the window's scene now
    fc.setup(hair, [box])
    for f in range(1, 7):
        sc_b.frame_set(f)
    rt = fc.registry.get_runtime(hair)
    assert sorted(rt.memory.frames) == [1, 2, 3, 4, 5, 6]
    win.scene = sc_a
    sc_a.frame_set(2)
    assert bpy.context.scene == sc_a and sc_b.frame_current == 6
    box.data.vertices[0].co.z += 0.01  # an edit of B's collider, seen by B's depsgraph
    box.data.update()
    sc_b.view_layers[0].depsgraph.update()
    assert sorted(rt.memory.frames) == [1, 2, 3, 4, 5, 6]
