"""Fur pipeline operators on a setup's output (paper sections 2 and 4), and the Fur
Pipeline panel's scene settings: thin glue around :mod:`..core.pipeline`.

* ``furcollide.collider_distance``: the per-point attribute
  ``furcollide_collider_distance`` on a setup's output, with
  :func:`core.pipeline.collider_distance`.
* ``furcollide.children_from_guides``: Blender's own *Interpolate Hair
  Curves* node group on a setup's output (render children from the
  collided guides, cleared of the colliders every frame: :mod:`..frame.children`).
* ``Scene.furcollide_pipeline``: the settings the panel shows for the Fur Sampler
  (:mod:`.sampler`) and the children.

The other pipeline operators: Fur Sampler (:mod:`.sampler`), Fur Attach
(:mod:`.attach`), the render groom (:mod:`.groom`). Every computation is in
world space.
"""

from __future__ import annotations

import os

import bpy
import numpy as np
from bpy.props import (
    FloatProperty,
    IntProperty,
    PointerProperty,
)
from bpy.types import Operator, PropertyGroup

from ...core.pipeline.frame import DISTANCE_ATTRIBUTE
from ..blender import bridge, compat
from ..frame import children
from ..frame.colliders import collider_objects
from ..frame.output import write_attributes
from .common import SetupOperator, active_setup, evaluate_now, redraw, reports_errors
from .sampler import prop_area, prop_fraction, prop_seed, prop_use_selection

#: Where this Blender keeps its bundled hair node-group assets (under datafiles/,
#: the expected folder first: it moved between 4.5 and 5.0; see :mod:`..blender.compat`).
HAIR_ASSETS = tuple(compat.hair_asset_candidates())
INTERPOLATE_GROUP = compat.INTERPOLATE_GROUP
#: Name of the modifier ``furcollide.children_from_guides`` adds.
CHILDREN_MODIFIER = "FurCollide Children"
#: The modifier before it: the collided guides moved to the Surface's rest position.
REST_MODIFIER = "FurCollide Rest Pose"
#: The modifier after it: every child moved from the rest Surface onto the deformed one.
SURFACE_MODIFIER = "FurCollide Follow Surface"
#: Named attributes the roots groups store on the Surface (inside the group only).
_DEFORMED, _REST = "furcollide_deformed_position", "furcollide_rest_position"


def _core_pipeline():
    from ...core import pipeline

    return pipeline


def hair_assets_path() -> str:
    """Path of Blender's bundled hair node-group assets ('' when not found); where
    they live depends on the version (:mod:`..blender.compat`)."""
    return compat.find_datafile(HAIR_ASSETS)


def interpolate_group():
    """Blender's 'Interpolate Hair Curves' node group (appended once from the
    bundled assets); raises FileNotFoundError when the assets are missing."""
    for ng in bpy.data.node_groups:
        if ng.get("furcollide_asset") == INTERPOLATE_GROUP and ng.bl_idname == "GeometryNodeTree":
            return ng
    path = hair_assets_path()
    if not path:
        where = " or ".join("datafiles/" + rel.replace(os.sep, "/") for rel in HAIR_ASSETS)
        raise FileNotFoundError(
            f"Blender's hair node assets ({where}) were not found in this Blender installation"
        )
    with bpy.data.libraries.load(path, link=False) as (src, dst):
        if INTERPOLATE_GROUP not in src.node_groups:
            raise FileNotFoundError(f"'{INTERPOLATE_GROUP}' is not in {path}")
        dst.node_groups = [INTERPOLATE_GROUP]
    ng = dst.node_groups[0]
    if ng is None:
        raise FileNotFoundError(f"could not load '{INTERPOLATE_GROUP}' from {path}")
    ng["furcollide_asset"] = INTERPOLATE_GROUP
    return ng


group_inputs = compat.group_inputs


def roots_group(to_rest: bool):
    """The node group moving every curve of a hair geometry rigidly so that its root
    goes from the deformed Surface to the same point of its rest shape (``to_rest``)
    or back.

    Inputs: Geometry (curves) and Surface (object). The Surface's evaluated mesh is read
    twice: as it is (deformed) and moved to its ``frame.topology`` attribute (the
    shape before shape keys and modifiers; without the attribute both are the same and
    nothing moves). Each curve's root is found on one of them (Sample Nearest Surface,
    once per curve) and the matching point of the other gives the curve's offset.
    Children from Guides uses it around Blender's Interpolate Hair Curves, which
    places children on the rest shape (so their number and places never change while
    the skin deforms) and interpolates the guides there.
    """
    tag = f"{'to_rest' if to_rest else 'to_surface'}:1"
    for ng in bpy.data.node_groups:
        if ng.get("furcollide_roots") == tag and ng.bl_idname == "GeometryNodeTree":
            return ng
    name = ".FurCollide Roots " + ("to Rest" if to_rest else "to Surface")
    ng = bpy.data.node_groups.new(name, "GeometryNodeTree")
    ng["furcollide_roots"] = tag
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Surface", in_out="INPUT", socket_type="NodeSocketObject")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, link = ng.nodes, ng.links.new

    def node(kind, **props):
        n = nodes.new(kind)
        for k, v in props.items():
            setattr(n, k, v)
        return n

    def named(attribute):
        n = node("GeometryNodeInputNamedAttribute", data_type="FLOAT_VECTOR")
        n.inputs["Name"].default_value = attribute
        return n

    def store(geometry, attribute, value):
        n = node("GeometryNodeStoreNamedAttribute", data_type="FLOAT_VECTOR", domain="POINT")
        n.inputs["Name"].default_value = attribute
        link(geometry, n.inputs["Geometry"])
        link(value, n.inputs["Value"])
        return n.outputs["Geometry"]

    def set_position(geometry, position, selection=None):
        n = node("GeometryNodeSetPosition")
        link(geometry, n.inputs["Geometry"])
        link(position, n.inputs["Position"])
        if selection is not None:
            link(selection, n.inputs["Selection"])
        return n.outputs["Geometry"]

    gin, gout = node("NodeGroupInput"), node("NodeGroupOutput")
    info = node("GeometryNodeObjectInfo", transform_space="RELATIVE")
    link(gin.outputs["Surface"], info.inputs["Object"])
    position = node("GeometryNodeInputPosition").outputs["Position"]
    deformed = store(info.outputs["Geometry"], _DEFORMED, position)
    rest = named("rest_position")
    rest_mesh = store(set_position(deformed, rest.outputs["Attribute"], rest.outputs["Exists"]),
                      _REST, position)
    if to_rest:
        mesh = set_position(rest_mesh, named(_DEFORMED).outputs["Attribute"])
        value = named(_REST).outputs["Attribute"]
    else:
        mesh, value = rest_mesh, named(_DEFORMED).outputs["Attribute"]
    # per curve (evaluated on the curve domain): its root, and where the root goes
    first = node("GeometryNodePointsOfCurve")
    first.inputs["Sort Index"].default_value = 0
    root = node("GeometryNodeFieldAtIndex", domain="POINT", data_type="FLOAT_VECTOR")
    link(first.outputs["Point Index"], root.inputs["Index"])
    link(position, root.inputs["Value"])
    sample = node("GeometryNodeSampleNearestSurface", data_type="FLOAT_VECTOR")
    link(mesh, sample.inputs["Mesh"])
    link(value, sample.inputs["Value"])
    link(root.outputs["Value"], sample.inputs["Sample Position"])
    offset = node("ShaderNodeVectorMath", operation="SUBTRACT")
    link(sample.outputs["Value"], offset.inputs[0])
    link(root.outputs["Value"], offset.inputs[1])
    per_point = node("GeometryNodeFieldAtIndex", domain="CURVE", data_type="FLOAT_VECTOR")
    link(node("GeometryNodeCurveOfPoint").outputs["Curve Index"], per_point.inputs["Index"])
    link(offset.outputs["Vector"], per_point.inputs["Value"])
    move = node("GeometryNodeSetPosition")
    link(gin.outputs["Geometry"], move.inputs["Geometry"])
    link(per_point.outputs["Value"], move.inputs["Offset"])
    link(move.outputs["Geometry"], gout.inputs["Geometry"])
    return ng


def _roots_modifier(out, name, to_rest, surf):
    """The roots modifier ``name`` of ``out`` (added when missing), reading ``surf``."""
    mod = out.modifiers.get(name)
    if mod is None or mod.type != "NODES":
        mod = out.modifiers.new(name, "NODES")
        mod.show_expanded = False
    ng = roots_group(to_rest)
    mod.node_group = ng
    compat.set_modifier_input(mod, group_inputs(ng)[("Surface", "NodeSocketObject")], surf)
    return mod


# ---------------------------------------------------------------- settings
# Each setting is declared once: the scene settings group shows it in the panel and
# the operators take it as an argument (Adjust Last Operation, scripts).
def _prop_density():
    return FloatProperty(
        name="Density",
        default=10.0,
        min=0.0,
        soft_max=10000.0,
        options=set(),  # (an input of Children from Guides: nothing to key)
        description="Child curves per unit of surface area created around the guides",
    )


def _prop_guides():
    return IntProperty(
        name="Guides per Curve",
        default=4,
        min=1,
        soft_max=16,
        options=set(),
        description="How many nearest guides each child curve follows (Interpolate Hair "
        "Curves' Interpolation Guides)",
    )


class FURCOLLIDE_PG_pipeline(PropertyGroup):
    """Fur pipeline settings of the scene (shown in the Fur Pipeline panel)."""

    fraction: prop_fraction()
    seed: prop_seed()
    use_selection: prop_use_selection()
    area: prop_area()
    density: _prop_density()
    guides: _prop_guides()


class _OutputOperator(SetupOperator):
    @classmethod
    def refusal(cls, context, src):
        out = src.furcollide.output
        if out is None or out.type != "CURVES":
            return "The FurCollide setup has no output hair object"
        return ""


class FURCOLLIDE_OT_collider_distance(_OutputOperator, Operator):
    """Fur Collider Distance: store on the output, for every point, the closest distance
    of its segments to the enabled colliders (attribute furcollide_collider_distance)"""

    bl_idname = "furcollide.collider_distance"
    bl_label = "Collider Distance"
    bl_options = {"REGISTER", "UNDO"}

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        out = src.furcollide.output
        dg = context.evaluated_depsgraph_get()
        cols = [bridge.surface_mesh_world(r.object, dg, r.matrix(dg))
                for r in collider_objects(src, context.scene)]
        cols = [c for c in cols if len(c[1])]
        if not cols:
            self.report({"ERROR"}, f"The setup of '{src.name}' has no enabled collider")
            return {"CANCELLED"}
        data = out.data
        offs = bridge.curve_offsets(data)
        if len(offs) < 2:
            self.report({"ERROR"}, f"The output '{out.name}' has no curves")
            return {"CANCELLED"}
        P = bridge.get_positions(data).astype(np.float64)
        M = bridge.matrix(out)
        Pw = P @ M[:3, :3].T + M[:3, 3]
        d = _core_pipeline().collider_distance(Pw, offs, cols)
        write_attributes(data, {DISTANCE_ATTRIBUTE: d})
        data.update_tag()
        self.report(
            {"INFO"},
            f"Collider distance on '{out.name}': min {d.min():.4g}, "
            f"max {d.max():.4g} ({len(d)} points)",
        )
        return {"FINISHED"}


#: What Children from Guides says when Clear Children is off (the panel says it too).
_CHILDREN_NOTE = (
    "Children are not cleared (Clear Children is off): between guides they can cross a "
    "collider. Turn Clear Children on (Fur Pipeline > Children)."
)


class FURCOLLIDE_OT_children_from_guides(_OutputOperator, Operator):
    """Children from Guides: add Blender's Interpolate Hair Curves to the output, so
    dense render children grow on the source's Surface and follow the collided guides;
    they are cleared of the colliders every frame (the children output renders them)"""

    bl_idname = "furcollide.children_from_guides"
    bl_label = "Children from Guides"
    bl_options = {"REGISTER", "UNDO"}

    density: _prop_density()
    guides: _prop_guides()

    @classmethod
    def refusal(cls, context, src):
        msg = super().refusal(context, src)
        if msg:
            return msg
        surf = src.data.surface
        if surf is None or surf.type != "MESH":
            return "The source hair has no Surface mesh (Object Data > Surface)"
        if len(surf.data.polygons) == 0:
            return f"The Surface '{surf.name}' has no faces to grow children on"
        return ""

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        out = src.furcollide.output
        surf = src.data.surface
        # Children are placed by the Surface's UV map (the asset samples it to attach
        # and deform them); without one Blender makes no usable children (5.0.1 gave
        # a single curve), so say so instead of a silent FINISHED.
        uv_maps = compat.uv_map_names(surf.data)
        uv_name = src.data.surface_uv_map
        if not uv_name and out.data.surface_uv_map in uv_maps:
            uv_name = out.data.surface_uv_map
        if not uv_maps:
            self.report(
                {"ERROR"},
                f"The Surface '{surf.name}' has no UV map: Children from Guides places "
                "children by the Surface's UVs (add one: Object Data > UV Maps, then unwrap)",
            )
            return {"CANCELLED"}
        if not uv_name:
            uv_name = next((uv.name for uv in surf.data.uv_layers if uv.active_render), uv_maps[0])
        elif uv_name not in uv_maps:
            self.report(
                {"ERROR"},
                f"The Surface '{surf.name}' has no UV map '{uv_name}' (the hair's Surface UV "
                f"Map); it has: {', '.join(uv_maps)}",
            )
            return {"CANCELLED"}
        try:
            ng = interpolate_group()
            sockets = compat.interpolate_sockets(ng)
        except (FileNotFoundError, ValueError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        mod = out.modifiers.get(CHILDREN_MODIFIER)
        if mod is None or mod.type != "NODES":
            mod = out.modifiers.new(CHILDREN_MODIFIER, "NODES")
        mod.node_group = ng
        # 4.2-5.0: the Surface is an Object input; 5.2 reads the hair data's own
        # surface and surface_uv_map (set below in every version).
        if sockets.surface_object is not None:
            compat.set_modifier_input(mod, sockets.surface_object, surf)
        if sockets.density is not None:
            compat.set_modifier_input(mod, sockets.density, float(self.density))
        if sockets.guides is not None:
            compat.set_modifier_input(mod, sockets.guides, int(self.guides))
        if sockets.surface_uv_map is not None:
            compat.set_modifier_input_attribute(mod, sockets.surface_uv_map, uv_name)
        # Children are placed (and their guides found) on the Surface's rest shape, so
        # their number and places never change while the skin deforms; the guides go
        # there before (REST_MODIFIER) and every child comes back onto the deformed
        # Surface after (SURFACE_MODIFIER). Blender needs the Surface's rest position.
        if sockets.rest_position is not None:
            compat.set_modifier_input(mod, sockets.rest_position, True)
        added_rest = not surf.add_rest_position_attribute
        if added_rest:  # (an edit of the Surface: the playback cache is dropped once)
            surf.add_rest_position_attribute = True
        pre = _roots_modifier(out, REST_MODIFIER, True, surf)
        post = _roots_modifier(out, SURFACE_MODIFIER, False, surf)
        at = list(out.modifiers).index(mod)
        compat.move_modifier(out, pre, at if list(out.modifiers).index(pre) > at else at - 1)
        at = list(out.modifiers).index(mod)
        compat.move_modifier(out, post, at + 1)
        out.data.surface = surf
        out.data.surface_uv_map = uv_name
        out.update_tag()
        cleared = src.furcollide.children.use_children
        if cleared:  # (what renders: the children with the clearance pass, every frame)
            ch = children.create_children_output(src, context.scene)
        err = evaluate_now(context, src)
        self.report(
            {"INFO"},
            f"Children from guides on '{out.name}' (surface '{surf.name}', UV map "
            f"'{uv_name}', density {self.density:g}), placed on the Surface's rest shape"
            + (f" ('Add Rest Position' turned on for '{surf.name}')" if added_rest else "")
            + (f"; cleared of the colliders into '{ch.name}' every frame" if cleared else ""),
        )
        if not cleared:
            self.report({"WARNING"}, _CHILDREN_NOTE)
        if err:
            self.report({"WARNING"}, f"FurCollide: {err}")
        redraw(context)
        return {"FINISHED"}


classes = (
    FURCOLLIDE_PG_pipeline,
    FURCOLLIDE_OT_collider_distance,
    FURCOLLIDE_OT_children_from_guides,
)


def register():
    """Add ``Scene.furcollide_pipeline`` (after the classes are registered)."""
    bpy.types.Scene.furcollide_pipeline = PointerProperty(type=FURCOLLIDE_PG_pipeline)


def unregister():
    if hasattr(bpy.types.Scene, "furcollide_pipeline"):
        del bpy.types.Scene.furcollide_pipeline
