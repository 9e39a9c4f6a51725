"""operators/compat.py: the one place for Blender-version differences, on whichever
``bpy`` this lane runs (4.2, 4.5, 5.0 or 5.2: ``make test-matrix``)."""

import os
import sys

import bpy
import numpy as np
import pytest
from helpers import make_box, make_hair, make_surface

COMPAT = "bl_ext.fcdev.furcollide.operators.blender.compat"
PIPELINE = "bl_ext.fcdev.furcollide.operators.ops.pipeline"


@pytest.fixture
def compat():
    return sys.modules[COMPAT]


def test_version_is_the_running_blender(compat):
    assert compat.VERSION == tuple(bpy.app.version)
    assert compat.VERSION >= (4, 2, 0)  # blender_version_min


def test_hair_assets_are_found_where_this_version_keeps_them(compat):
    path = sys.modules[PIPELINE].hair_assets_path()
    assert os.path.isfile(path), compat.hair_asset_candidates()
    expected = "nodes" if compat.VERSION >= (5, 0, 0) else "geometry_nodes"
    assert os.path.basename(os.path.dirname(path)) == expected
    # the expected folder is tried first
    first = compat.hair_asset_candidates()[0]
    assert first.split(os.sep)[-2] == expected
    assert compat.hair_asset_candidates((4, 2, 0))[0].split(os.sep)[-2] == "geometry_nodes"
    assert compat.hair_asset_candidates((5, 2, 3))[0].split(os.sep)[-2] == "nodes"


def test_interpolate_sockets_match_this_version(compat):
    ng = sys.modules[PIPELINE].interpolate_group()
    s = compat.interpolate_sockets(ng)
    assert s.density and s.guides
    if compat.VERSION >= (5, 2, 0):
        # 5.2 changed the interface: the Surface comes from the hair data-block
        assert s.surface_object is None and s.surface_from_hair_data
    else:
        assert s.surface_object and s.surface_uv_map
    assert (s.surface_input_type is not None) == ((5, 0, 0) <= compat.VERSION < (5, 2, 0))


def test_unknown_interpolate_interface_is_an_error_naming_the_group(compat):
    ng = bpy.data.node_groups.new("Interpolate Hair Curves", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Density", in_out="INPUT", socket_type="NodeSocketFloat")
    with pytest.raises(ValueError, match="Interpolate Hair Curves.*does not know.*Density"):
        compat.interpolate_sockets(ng)


def test_modifier_inputs_round_trip(compat):
    ng = sys.modules[PIPELINE].interpolate_group()
    s = compat.interpolate_sockets(ng)
    ob = make_hair("Hair", nx=2, ny=2)
    mod = ob.modifiers.new("Children", "NODES")
    mod.node_group = ng
    compat.set_modifier_input(mod, s.density, 42.5)
    compat.set_modifier_input(mod, s.guides, 3)
    assert compat.modifier_input(mod, s.density) == 42.5
    assert compat.modifier_input(mod, s.guides) == 3
    if s.surface_uv_map is not None:
        assert compat.set_modifier_input_attribute(mod, s.surface_uv_map, "MyUV")
        assert compat.modifier_input_attribute(mod, s.surface_uv_map) == "MyUV"
    # an input that takes no attribute (an Object) says so
    if s.surface_object is not None:
        assert not compat.set_modifier_input_attribute(mod, s.surface_object, "x")
        surf = make_surface()
        compat.set_modifier_input(mod, s.surface_object, surf)
        assert compat.modifier_input(mod, s.surface_object) == surf


def _guides_on(fc, surf, uv_map="UVMap"):
    box = make_box(location=(3.0, 0, 0.6))  # away from the hair: nothing collides
    hair = make_hair("Guides", nx=4, ny=4, spacing=0.4)
    hair.data.surface = surf
    hair.data.surface_uv_map = uv_map
    out = fc.setup(hair, [box])
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    hair.select_set(True)
    bpy.context.view_layer.objects.active = hair
    return hair, out


def test_children_from_guides_grows_children_on_this_version(fc):
    surf = make_surface(half=1.0, n=8)
    hair, out = _guides_on(fc, surf)
    assert bpy.ops.furcollide.children_from_guides(density=60.0) == {"FINISHED"}
    dg = bpy.context.evaluated_depsgraph_get()
    ev = out.evaluated_get(dg).data
    n = len(ev.curves)
    assert n > 4 * len(out.data.curves), n  # ~ 60 per m^2 on a 2 m x 2 m surface
    P = np.empty(len(ev.points) * 3, np.float32)
    ev.position_data.foreach_get("vector", P)
    offs = np.empty(n + 1, np.int32)
    ev.curve_offset_data.foreach_get("value", offs)
    roots = P.reshape(-1, 3)[offs[:-1]]
    # the children grow on the Surface (z = 0), inside it
    assert np.abs(roots[:, 2]).max() < 1e-3
    assert np.abs(roots[:, :2]).max() <= 1.0 + 1e-4


def test_children_from_guides_names_a_missing_uv_map(fc):
    surf = make_surface(uv=False)
    _, out = _guides_on(fc, surf)
    with pytest.raises(RuntimeError, match="Surface 'Skin' has no UV map: Children"):
        bpy.ops.furcollide.children_from_guides()
    assert "FurCollide Children" not in out.modifiers
    surf.data.uv_layers.new(name="Other")
    hair = bpy.data.objects["Guides"]
    hair.data.surface_uv_map = "UVMap"
    with pytest.raises(RuntimeError, match="no UV map 'UVMap'.*it has: Other"):
        bpy.ops.furcollide.children_from_guides()
    assert "FurCollide Children" not in out.modifiers
    hair.data.surface_uv_map = ""  # no name: the Surface's render UV map is used
    assert bpy.ops.furcollide.children_from_guides() == {"FINISHED"}
    assert out.data.surface_uv_map == "Other"
