"""Fur pipeline operators on a setup's output (paper sections 2 and 4), and the Fur
Pipeline panel's scene settings: thin glue around :mod:`..core.pipeline`.

* ``furcollide.collider_distance``: the per-point attribute
  ``furcollide_collider_distance`` on a setup's output, with
  :func:`core.pipeline.collider_distance`.
* ``furcollide.children_from_guides``: Blender's own *Interpolate Hair
  Curves* node group on a setup's output (render children from the
  collided guides).
* ``Scene.furcollide_pipeline``: the settings the panel shows for the Fur Sampler
  (:mod:`.ops_sampler`) and the children.

The other pipeline operators: Fur Sampler (:mod:`.ops_sampler`), Fur Attach
(:mod:`.ops_attach`), the render groom (:mod:`.ops_groom`). Every computation is in
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

from . import bridge, compat
from .colliders import collider_objects
from .frame_outputs import write_attributes
from .motion import DISTANCE_ATTRIBUTE
from .ops_common import (
    SetupOperator,
    active_setup,
    redraw,
    reports_errors,
)
from .ops_sampler import prop_area, prop_fraction, prop_seed, prop_use_selection

#: Where this Blender keeps its bundled hair node-group assets (under datafiles/,
#: the expected folder first: it moved between 4.5 and 5.0; see :mod:`.compat`).
HAIR_ASSETS = tuple(compat.hair_asset_candidates())
INTERPOLATE_GROUP = compat.INTERPOLATE_GROUP
#: Name of the modifier ``furcollide.children_from_guides`` adds.
CHILDREN_MODIFIER = "FurCollide Children"


def _core_pipeline():
    from ..core import pipeline

    return pipeline


def hair_assets_path() -> str:
    """Path of Blender's bundled hair node-group assets ('' when not found); where
    they live depends on the version (:mod:`.compat`)."""
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


# ---------------------------------------------------------------- settings
# Each setting is declared once: the scene settings group shows it in the panel and
# the operators take it as an argument (Adjust Last Operation, scripts).
def _prop_density():
    return FloatProperty(
        name="Density",
        default=10.0,
        min=0.0,
        soft_max=10000.0,
        description="Child curves per unit of surface area created around the guides",
    )


def _prop_guides():
    return IntProperty(
        name="Interpolation Guides",
        default=4,
        min=1,
        soft_max=16,
        description="Number of nearest guides each child curve interpolates",
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


class FURCOLLIDE_OT_children_from_guides(_OutputOperator, Operator):
    """Children from Guides: add Blender's Interpolate Hair Curves to the output, so
    dense render children grow on the source's Surface and follow the collided guides"""

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
        out.data.surface = surf
        out.data.surface_uv_map = uv_name
        out.update_tag()
        self.report(
            {"INFO"},
            f"Children from guides on '{out.name}' (surface '{surf.name}', UV map "
            f"'{uv_name}', density {self.density:g})",
        )
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
