"""Render groom operators (paper section 2): Bind Groom and Remove Groom Output (the
per-frame stage is in :mod:`..frame.groom`).

``furcollide.groom_bind`` binds an existing render groom to the setup's guides at the
current frame and creates the groom output the frame rules write into.
"""

from __future__ import annotations

import uuid

import numpy as np
from bpy.types import Operator

from ..blender import bridge, compat
from ..blender.dependencies import update_dependencies
from ..frame.colliders import in_scene
from ..frame.groom import build_binding, remove_groom, store_groom
from ..frame.inputs import read_inputs
from ..frame.output import hide_in_viewport
from ..frame.setup import Setup
from .common import (
    SetupOperator,
    active_setup,
    evaluate_now,
    new_hair_object_like,
    redraw,
    reports_errors,
)


def _hair_world(ob, depsgraph):
    """Evaluated hair ``ob``: (world points (P, 3) float64, offsets (C+1,))."""
    oe = ob.evaluated_get(depsgraph)
    offs = bridge.curve_offsets(oe.data)
    P = bridge.transform(bridge.get_positions(oe.data), bridge.matrix(oe))
    return np.asarray(P, np.float64), offs


class FURCOLLIDE_OT_groom_bind(SetupOperator, Operator):
    """Render groom follows the guides: bind the Render Groom to this setup's guides at
    the current frame (its reference pose) and create the groom output hair object,
    which then follows the collided guides every frame; the groom itself is untouched
    (hidden)"""

    bl_idname = "furcollide.groom_bind"
    bl_label = "Bind Groom"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        g = src.furcollide.groom.groom
        if g is None:
            return "Choose the Render Groom (a hair object) first"
        if g.type != "CURVES":
            return f"'{g.name}' is not a hair Curves object"
        if g == src or g == src.furcollide.output or g == src.furcollide.groom.output:
            return "The Render Groom must be another hair object than the guides"
        if src.furcollide.groom.is_baked_with:
            return "The setup's bake holds this render groom: free the bake before binding"
        return ""

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        g = s.groom
        groom = g.groom
        scene = context.scene
        dg = context.evaluated_depsgraph_get()
        render_ref, roff = _hair_world(groom, dg)
        if len(roff) < 2:
            self.report({"ERROR"}, f"The Render Groom '{groom.name}' has no curves")
            return {"CANCELLED"}
        if np.diff(roff).min() < 2:
            i = int(np.argmax(np.diff(roff) < 2))
            self.report({"ERROR"}, f"'{groom.name}': curve {i} has fewer than 2 points")
            return {"CANCELLED"}
        inp = read_inputs(Setup(src, scene, dg))  # the guides' input (before motion) now
        surface = None
        surf = src.data.surface
        if surf is not None and surf.type == "MESH" and groom.data.surface == surf:
            # render roots stay exactly on the shared Surface (Fur Attach of the roots)
            V, F = bridge.surface_mesh_world(surf, dg)
            surface = (V, F, bridge.mesh_topology_key(surf.evaluated_get(dg).data))
        arrays, notes = build_binding(
            render_ref, roff, inp.world(), inp.offsets, g.guides, surface, groom=groom
        )
        out = g.output
        if out is None or out.type != "CURVES" or not in_scene(out, scene):
            out = new_hair_object_like(
                groom, "FurCollide", scene,
                lambda hc: bridge.copy_topology(groom.evaluated_get(dg).data, hc),
            )
        elif not np.array_equal(bridge.curve_offsets(out.data), roff):
            bridge.copy_topology(groom.evaluated_get(dg).data, compat.emptied_curves(out))
        store_groom(out, arrays)
        g.output = out
        g.bind_id = uuid.uuid4().hex
        g.bound_guides = g.guides
        update_dependencies(src)  # renders with the guides hidden still see them
        hide_in_viewport(groom, True, render=True)
        err = evaluate_now(context, src)
        roots = "on the Surface" if surface is not None else "following the guides"
        self.report(
            {"INFO"},
            f"Render groom: {len(roff) - 1} curves of '{groom.name}' follow "
            f"{len(inp.offsets) - 1} guides into '{out.name}' (roots {roots})",
        )
        for note in notes:
            self.report({"WARNING"}, f"Render groom: {note}")
        if err:
            self.report({"WARNING"}, f"FurCollide: {err}")
        redraw(context)
        return {"FINISHED"}


class FURCOLLIDE_OT_groom_remove(SetupOperator, Operator):
    """Delete the groom output object and show the Render Groom again"""

    bl_idname = "furcollide.groom_remove"
    bl_label = "Remove Groom Output"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        return "" if src.furcollide.groom.output is not None else "No groom output to remove"

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        remove_groom(src)
        self.report({"INFO"}, f"Removed the render groom output of '{src.name}'")
        redraw(context)
        return {"FINISHED"}


classes = (FURCOLLIDE_OT_groom_bind, FURCOLLIDE_OT_groom_remove)
