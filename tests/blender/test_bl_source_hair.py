"""The source hair as input: procedural (generated) curves, transformed and parented
sources, the per-curve enable attribute, the growth Surface (Attract / Put to Growth
Surface, pinches), curve counts that change, unit scale, far from the origin."""

import bpy
import numpy as np
import pytest
from helpers import (
    COLLIDING,
    FREE,
    PINCHED,
    RECOVERING,
    UNRESOLVED,
    activate,
    assert_same_frames,
    assert_unchanged,
    bake_setup,
    check_frame,
    linear,
    make_box,
    make_hair,
    make_surface,
    no_traceback,
    offsets_of,
    play,
    positions,
    positions_per_frame,
    record,
    render_camera,
    render_spy,
    save_in,
    seg_lengths,
    small_setup,
    snapshot,
    status_of,
    sweep_setup,
    world,
)

pytestmark = pytest.mark.blender




def _render_local_spy(fc, tmp_path, hair, out, tag):
    """Render the animation; {frame: (output local points, status, status message)}
    as the RENDER depsgraph's frame changes left them. (Local: the originals'
    matrix_world is the viewport's, not the rendered frame's.)"""
    return render_spy(fc, tmp_path, hair, out, tag, record=lambda: (
        positions(out).copy(), status_of(out).copy(), fc.store.report.status_for(hair)))


def _unit_run(fc, scale_length):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = scale_length
    if scale_length != 1.0:
        scene.unit_settings.length_unit = "CENTIMETERS"
    hair, box = fc.make_scene(frames=(1, 8), nx=5, ny=5)
    out = fc.setup(hair, [box])
    hair.furcollide.collision_offset = 0.03
    scene.frame_set(1)
    return record(scene, out, range(1, 9)), hair


def _ground(size=4.0):
    me = bpy.data.meshes.new("Ground")
    h = size / 2
    me.from_pydata([(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)], [], [(0, 1, 2, 3)])
    ob = bpy.data.objects.new("Ground", me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


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


def test_attract_to_growth_surface_needs_surface(fc):
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    s = hair.furcollide
    s.attract_to_growth_surface = True
    play(bpy.context.scene, range(1, 4))
    assert "Surface" in s.status_message  # clear message, no exception
    hair.data.surface = _ground()
    bpy.context.scene.frame_set(1)
    play(bpy.context.scene, range(1, 8))
    assert s.status_message == ""
    assert s.stat_colliding + s.stat_recovering > 0


def test_pinch_detected_and_put_to_growth_surface(fc):
    hair, box = fc.make_scene(animate=False)
    box.location = (0, 0, 0)  # swallows the roots of the central curves
    hair.data.surface = _ground()
    out = fc.setup(hair, [box])
    s = hair.furcollide
    play(bpy.context.scene, range(1, 4))
    assert s.stat_pinched > 0
    st = np.zeros(len(out.data.curves), np.int32)
    out.data.attributes["furcollide_status"].data.foreach_get("value", st)
    assert (st == fc.core.Status.PINCHED).sum() == s.stat_pinched
    s.pinch_resolution = "GROWTH_SURFACE"
    bpy.context.scene.frame_set(1)
    play(bpy.context.scene, range(1, 4))
    assert s.stat_pinched > 0 and s.status_message == ""


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
    play(bpy.context.scene, range(1, 13))
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
    play(bpy.context.scene, range(1, 3))
    assert hair.furcollide.stat_colliding > 0
    # before the start frame the output is the source, exactly (same local space)
    hair.furcollide.frame_start = 2
    bpy.context.scene.frame_set(1)
    assert np.allclose(fc.positions(out), fc.positions(hair), atol=1e-6)


def test_enable_attribute_on_wrong_domain_warns(fc):
    hair, box = fc.make_scene()
    hair.data.attributes.new("furcollide_enable", "FLOAT", "POINT")
    fc.setup(hair, [box])
    play(bpy.context.scene, range(1, 3))
    assert "domain" in hair.furcollide.status_message
    assert hair.furcollide.stat_disabled == 0


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


def test_source_topology_change_is_reported_and_nothing_lost(fc):
    """Curves added to the source mid-shot: the status says so and what to press (the
    button as it is drawn, Reset Cache); the cached frames are kept; the output follows
    the source, not collided, and is outdated (never frozen while marked current)."""
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    rt = fc.store.registry.get_runtime(hair)
    positions_per_frame(out, range(1, 7))
    n = len(hair.data.curves)
    hair.data.add_curves([5])
    P = fc.positions(hair)
    P[-5:] = [(2.0, 2.0, z) for z in np.linspace(0, 1, 5)]
    hair.data.position_data.foreach_set("vector", P.ravel())
    bpy.context.scene.frame_set(7)
    msg = hair.furcollide.status_message
    assert "changed" in msg and str(n) in msg and str(n + 1) in msg
    assert "press Reset Cache and play from frame 1" in msg, msg
    np.testing.assert_array_equal(fc.positions(out), fc.positions(hair))
    assert hair.furcollide.is_outdated
    assert len(rt.cache.memory) == 6
    assert len(out.data.curves) == n + 1
    bpy.context.scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    assert len(out.data.curves) == n + 1
    positions_per_frame(out, range(2, 5))
    assert hair.furcollide.status_message == ""


def test_source_data_swapped_for_more_curves_mid_play(fc, capsys):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc, frames=(1, 8))
    for f in range(1, 5):
        scene.frame_set(f)
    more = make_hair(name="More", nx=5, ny=5)
    data = more.data
    bpy.data.objects.remove(more)
    hair.data = data  # a new hair data block with 25 curves instead of 16
    for f in (5, 6, 2):
        scene.frame_set(f)
        level, msg = fc.store.report.status_for(hair)
        assert level == "ERROR" and "16" in msg and "25" in msg and "Reset Cache" in msg, msg
        # the output follows the source (not collided), outdated
        np.testing.assert_array_equal(fc.positions(out), fc.positions(hair))
        assert hair.furcollide.is_outdated
        assert len(out.data.curves) == 25
    assert "Traceback" not in capsys.readouterr().err
    scene.frame_set(4)
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}  # "Reset Cache"
    assert len(out.data.curves) == 25
    rec = {}
    hits = 0
    for f in range(1, 9):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        assert len(out.data.curves) == 25
        rec[f] = fc.positions(out).copy()
        hits += hair.furcollide.stat_colliding
    assert hits > 0
    # and the same as a fresh play of the new curves
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    for f in range(1, 9):
        scene.frame_set(f)
        np.testing.assert_array_equal(fc.positions(out), rec[f], err_msg=f"frame {f}")


@pytest.mark.parametrize("how", ["played", "baked"])
def test_hair_parented_to_a_moving_body_against_a_static_collider(fc, tmp_path, how):
    """The body (and the hair parented to it) moves and turns into a static box:
    the output follows the body, its roots stay on the source's roots, it is
    collision free, and the render (from the memory cache, or from the bake) equals
    the play."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    body = make_surface("Body", half=0.7, n=4)
    for f, x, rz in ((1, -1.0, 0.0), (8, 0.4, 0.6)):
        body.location = (x, 0.0, 0.0)
        body.rotation_euler = (0.0, 0.0, rz)
        body.keyframe_insert("location", frame=f)
        body.keyframe_insert("rotation_euler", frame=f)
    linear(body)
    hair = make_hair(nx=5, ny=5)
    hair.parent = body
    box = make_box("Post", size=0.4, location=(0.4, 0.0, 0.6))
    scene.frame_set(1)
    out = fc.setup(hair, [box])
    assert out.parent == body
    src_local = positions(hair).copy()
    played = {}
    hits = 0
    for f in range(1, 9):
        scene.frame_set(f)
        np.testing.assert_allclose(np.array(out.matrix_world), np.array(hair.matrix_world))
        st = check_frame(hair, out, [box], exact_roots=False)
        hits += int((st == COLLIDING).sum())
        # curves the solver left alone are the source's own local positions, exactly
        offs = offsets_of(out)
        free = np.repeat(st == FREE, np.diff(offs))
        untouched = free & (positions(out) == src_local).all(1)
        assert untouched.sum() > 0
        played[f] = (positions(out).copy(), st.copy())
    assert hits > 0
    np.testing.assert_array_equal(positions(hair), src_local)  # the groom is untouched
    if how == "baked":
        save_in(tmp_path)
        bake_setup(hair)
        assert_same_frames(played, scene, out, what="baked")
    render_camera(scene, px=16)
    scene.frame_set(1)
    seen = _render_local_spy(fc, tmp_path, hair, out, "body")
    assert sorted(seen) == list(range(1, 9))
    for f, (P, st, (level, msg)) in seen.items():
        np.testing.assert_array_equal(P, played[f][0], err_msg=f"render frame {f}")
        np.testing.assert_array_equal(st, played[f][1], err_msg=f"render frame {f}")
        assert (level, msg) == ("INFO", ""), (f, level, msg)


def test_unit_scale_does_not_change_the_result(fc):
    """Scene › Units › Unit Scale 0.01 (a centimetre scene) only changes how values
    are displayed: the solve (with a collision offset) is bit-identical."""
    ref, _hair = _unit_run(fc, 1.0)
    got, hair = _unit_run(fc, 0.01)
    assert bpy.context.scene.unit_settings.scale_length == pytest.approx(0.01)
    assert hair.furcollide.collision_offset == pytest.approx(0.03)
    assert any(ref[f][1].any() for f in ref)
    for f in ref:
        np.testing.assert_array_equal(got[f][0], ref[f][0], err_msg=f"frame {f}")
        np.testing.assert_array_equal(got[f][1], ref[f][1], err_msg=f"frame {f}")


def test_set_far_from_the_origin(fc):
    """Hair and an animated box 10,000 units from the origin (a big set): collisions
    are found and resolved as near the origin, no false pinch, the roots stay on the
    source's roots (2e-5 in world space) and segment lengths within float32 rounding."""
    def run(far):
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        hair, box = fc.make_scene(frames=(1, 8), nx=5, ny=5)
        off = np.array([1e4, -1e4, 0.0]) if far else np.zeros(3)
        hair.location = off
        box.animation_data_clear()
        for f, x in ((1, -1.2), (8, 1.2)):
            box.location = off + (x, 0.0, 0.6)
            box.keyframe_insert("location", frame=f)
        linear(box)
        scene.frame_set(1)
        out = fc.setup(hair, [box])
        counts = []
        for f in range(1, 9):
            scene.frame_set(f)
            st = check_frame(hair, out, [box], exact_roots=not far, lengths=False)
            offs = offsets_of(out)
            L0 = seg_lengths(world(hair), offs)
            np.testing.assert_allclose(seg_lengths(world(out), offs), L0, atol=4e-3)
            counts.append(np.bincount(st, minlength=6))
        return np.array(counts)

    near, far = run(False), run(True)
    assert far[:, COLLIDING].sum() > 0
    assert far[:, PINCHED].sum() == 0 and far[:, UNRESOLVED].sum() == 0
    # as many curves are touched (colliding or recovering) frame by frame as near the
    # origin; which of the two a curve at the box's trailing edge is may differ
    touched = slice(COLLIDING, RECOVERING + 1)
    np.testing.assert_array_equal(far[:, touched].sum(1), near[:, touched].sum(1))


@pytest.mark.parametrize("surface", ["source", "output"])
def test_hair_object_as_the_surface_is_named_in_the_error(fc, surface, capsys):
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    groom = snapshot(hair)
    target = hair if surface == "source" else out
    hair.data.surface = target  # RNA accepts any object here
    hair.furcollide.attract_to_growth_surface = True
    activate(hair)
    with pytest.raises(RuntimeError, match="Surface"):
        bpy.ops.furcollide.reset()
    for f in (1, 2):
        scene.frame_set(f)
    msg = hair.furcollide.status_message
    assert_unchanged(hair, groom)
    no_traceback(capsys)
    assert "Surface" in msg
    assert target.name in msg and "mesh" in msg.lower(), msg


@pytest.mark.parametrize("bad", ["duplicate", "nan"])
def test_one_bad_curve_never_stops_the_groom(fc, capsys, bad):
    """Issue 15: one curve with a duplicated point (or a NaN point) is INVALID, shown
    as it is and in yellow, reported once by index with its reason; every other
    curve is solved on every frame, and the output never holds NaN."""
    hair, box = fc.make_scene()
    P = np.empty(len(hair.data.points) * 3, np.float32)
    hair.data.position_data.foreach_get("vector", P)
    P = P.reshape(-1, 3)
    offs = offsets_of(hair)
    c = 7
    k = offs[c] + 2
    P[k] = P[k - 1] if bad == "duplicate" else np.nan
    hair.data.position_data.foreach_set("vector", P.ravel())
    hair.data.update_tag()
    out = fc.setup(hair, [box])
    sc = bpy.context.scene
    hits = 0
    for f in range(1, 13):
        sc.frame_set(f)
        st = status_of(out)
        assert st[c] == fc.core.Status.INVALID
        pos = positions(out)
        assert np.isfinite(pos).all()
        others = np.delete(np.arange(len(st)), c)
        assert (st[others] != fc.core.Status.INVALID).all()
        hits += int((st == COLLIDING).sum())
        level, msg = fc.store.report.status_for(hair)
        assert level == "WARNING" and f"curve {c}" in msg, msg
        assert hair.furcollide.stat_invalid == 1
    assert hits > 0  # the box really went through the other curves
    printed = capsys.readouterr().out
    assert printed.count(f"curve {c}") == 1  # reported once, not every frame
    colors = np.empty(len(out.data.points) * 4, np.float32)
    out.data.attributes["furcollide_color"].data.foreach_get("color", colors)
    yellow = colors.reshape(-1, 4)[offs[c]]
    np.testing.assert_allclose(yellow, [1.0, 0.85, 0.0, 1.0])
