"""Parameter maps: Plasticity, Recovery Rate, Collision Offset, Max Angle and Scale Minimum
scaled curve by curve by a float attribute of the evaluated hair (curve domain, or point
domain read at the root). A uniform map equals the setting times its value; a map that
cannot be used warns, naming it, and the setting applies unmapped; a map's values are
inputs of their frame."""

import bpy
import numpy as np
import pytest
from helpers import check_frame, make_hair, positions, set_core, sweep_box

pytestmark = pytest.mark.blender

FRAMES = range(1, 11)


def _shot(fc):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 10
    hair = make_hair(nx=6, ny=6, npts=6)
    box = sweep_box(x0=-1.2, x1=1.2, frames=(1, 7), size=0.5, z=0.55)
    scene.frame_set(1)
    out = fc.setup(hair, [box])
    s = hair.furcollide
    s.frame_end = 10
    s.plasticity = 0.8
    s.recovery_rate = 0.5
    return scene, hair, box, out


def _play(scene, hair, out, box):
    got = {}
    for f in FRAMES:
        scene.frame_set(f)
        check_frame(hair, out, [box], status=None, lengths=not hair.furcollide.shrink)
        got[f] = positions(out).copy()
    return got


def _attribute(hair, name, values, domain="CURVE", kind="FLOAT"):
    attr = hair.data.attributes.new(name, kind, domain)
    attr.data.foreach_set("value", np.asarray(values, np.float32 if kind == "FLOAT"
                                              else np.int32))
    return attr


def _replay(scene, hair, out, box):
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    return _play(scene, hair, out, box)


@pytest.mark.parametrize("name", ["plasticity", "recovery_rate", "collision_offset",
                                  "max_angle", "scale_minimum"])
def test_a_uniform_map_equals_the_setting_times_its_value(fc, name):
    scene, hair, box, out = _shot(fc)
    s = hair.furcollide
    s.shrink = name == "scale_minimum"
    base = {"plasticity": 0.8, "recovery_rate": 0.5, "collision_offset": 0.04,
            "max_angle": 120.0, "scale_minimum": 0.6}[name]
    set_core(s, **{name: base * 0.5})  # (Max Angle in degrees)
    plain = _replay(scene, hair, out, box)
    set_core(s, **{name: base})
    _attribute(hair, "weight", np.full(len(hair.data.curves), 0.5))
    setattr(s, f"{name}_map", "weight")
    mapped = _replay(scene, hair, out, box)
    assert s.status_message == "", s.status_message
    for f in FRAMES:
        np.testing.assert_array_equal(mapped[f], plain[f], err_msg=f"frame {f}")


def test_each_curve_uses_its_own_value(fc):
    """Plasticity 1: the curves mapped 1 keep their imprint after the box left, those
    mapped 0 recover to the groom."""
    scene, hair, box, out = _shot(fc)
    s = hair.furcollide
    s.plasticity, s.recovery_rate = 1.0, 1.0
    C = len(hair.data.curves)
    w = (np.arange(C) % 2).astype(np.float32)
    _attribute(hair, "imprint", w)
    s.plasticity_map = "imprint"
    got = _replay(scene, hair, out, box)
    offs = fc.blender.bridge.curve_offsets(hair.data)
    tips = offs[1:] - 1
    moved = np.linalg.norm(got[10][tips] - positions(hair)[tips], axis=1) > 1e-4
    assert moved.any(), "nothing kept an imprint"
    assert not moved[w == 0].any(), np.flatnonzero(moved & (w == 0))


def test_a_point_map_is_read_at_the_root(fc):
    scene, hair, box, out = _shot(fc)
    s = hair.furcollide
    s.plasticity = 0.4
    plain = _replay(scene, hair, out, box)
    s.plasticity = 0.8
    P = len(hair.data.points)
    offs = fc.blender.bridge.curve_offsets(hair.data)
    v = np.full(P, 9.0, np.float32)  # only each root's value is read
    v[offs[:-1]] = 0.5
    _attribute(hair, "pw", v, domain="POINT")
    s.plasticity_map = "pw"
    mapped = _replay(scene, hair, out, box)
    np.testing.assert_array_equal(mapped[10], plain[10])


@pytest.mark.parametrize("bad,said", [
    ("missing", "is not an attribute of the evaluated hair"),
    ("int", "has type Int, not Float"),
    ("nan", "is not finite on curve 3"),
])
def test_a_map_that_cannot_be_used_warns_and_applies_unmapped(fc, bad, said):
    scene, hair, box, out = _shot(fc)
    s = hair.furcollide
    plain = _replay(scene, hair, out, box)
    C = len(hair.data.curves)
    if bad == "int":
        _attribute(hair, "w", np.ones(C), kind="INT")
    elif bad == "nan":
        v = np.ones(C)
        v[3] = np.nan
        _attribute(hair, "w", v)
    s.plasticity_map = "w"
    got = {}
    for f in FRAMES:
        scene.frame_set(f)
        assert f"Plasticity map 'w' {said}: Plasticity applies unmapped" in (
            s.status_message), s.status_message
        assert not s.is_outdated
        got[f] = positions(out).copy()
    for f in FRAMES:
        np.testing.assert_array_equal(got[f], plain[f], err_msg=f"frame {f}")


def test_a_map_made_by_geometry_nodes_on_the_hair(fc):
    """The recipe's last step: a Geometry Nodes modifier on the hair stores the map
    (here a constant 0.5 on the Curve domain); the evaluated attribute is used."""
    scene, hair, box, out = _shot(fc)
    s = hair.furcollide
    s.plasticity = 0.4
    plain = _replay(scene, hair, out, box)
    s.plasticity = 0.8
    ng = bpy.data.node_groups.new("Store Map", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gi = ng.nodes.new("NodeGroupInput")
    go = ng.nodes.new("NodeGroupOutput")
    store = ng.nodes.new("GeometryNodeStoreNamedAttribute")
    store.data_type = "FLOAT"
    store.domain = "CURVE"
    store.inputs["Name"].default_value = "painted"
    store.inputs["Value"].default_value = 0.5
    ng.links.new(gi.outputs[0], store.inputs["Geometry"])
    ng.links.new(store.outputs["Geometry"], go.inputs[0])
    hair.modifiers.new("Map", "NODES").node_group = ng
    s.plasticity_map = "painted"
    mapped = _replay(scene, hair, out, box)
    assert s.status_message == "", s.status_message
    np.testing.assert_array_equal(mapped[10], plain[10])


def test_map_values_are_inputs_of_their_frame(fc):
    """Painted again (the attribute's values changed): a cached frame is not shown as
    current; played again, the new values are used."""
    scene, hair, box, out = _shot(fc)
    s = hair.furcollide
    C = len(hair.data.curves)
    attr = _attribute(hair, "w", np.ones(C))
    s.plasticity_map = "w"
    _replay(scene, hair, out, box)
    attr.data.foreach_set("value", np.full(C, 0.25, np.float32))
    hair.data.update_tag()
    scene.frame_set(5)
    assert "parameter map" in s.status_message, s.status_message
    assert s.is_outdated


def test_the_panel_offers_the_hairs_float_attributes(fc):
    scene, hair, box, out = _shot(fc)
    C = len(hair.data.curves)
    _attribute(hair, "density", np.ones(C))
    _attribute(hair, "count", np.ones(C), kind="INT")
    prop = hair.furcollide.bl_rna.properties["plasticity_map"]
    assert prop.type == "STRING"
    maps = fc.frame.inputs.maps
    names = maps.suggestions(hair, bpy.context, "")
    assert "density" in names and "count" not in names, names
