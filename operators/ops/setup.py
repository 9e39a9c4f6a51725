"""Operators that create, edit and remove FurCollide setups: Add, Remove, Add / Remove
Collider, Reset Cache."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty
from bpy.types import Operator

from ..blender import bridge, dependencies
from ..frame import children, output
from ..frame.colliders import instanced_collection
from ..frame.groom import remove_groom
from ..settings.properties import CURRENT_VERSION
from ..store import registry
from ..store.invalidation import invalidate
from .common import (
    SetupOperator,
    active_setup,
    backend_message,
    evaluate_now,
    new_hair_object_like,
    redraw,
    refresh,
    refuse,
    reports_errors,
)
from .scene import needs_lock


def _selected_colliders(context, exclude=()):
    """Selected objects that can collide (meshes, bevelled curves, text...,
    collection instances), in selection order, minus ``exclude``."""
    return [o for o in context.selected_objects
            if (bridge.is_collider_type(o) or instanced_collection(o) is not None)
            and o not in exclude]


def _new_output(src, src_eval, scene):
    """Create the output hair object of ``src``: evaluated topology, the source's
    materials, surface, parent and transform, linked where the source is."""
    out = new_hair_object_like(
        src, "FurCollide", scene, lambda hc: bridge.copy_topology(src_eval.data, hc)
    )
    for i, slot in enumerate(src.material_slots):
        if slot.link == "OBJECT" and i < len(out.material_slots):
            out.material_slots[i].link = "OBJECT"
            out.material_slots[i].material = slot.material
    return out


class FURCOLLIDE_OT_add(Operator):
    """Make the active hair collide with the selected meshes (or bevelled curves, text):
    creates the output hair object that receives the result every frame and hides the
    source from render"""

    bl_idname = "furcollide.add"
    bl_label = "Add FurCollide"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = context.active_object
        if ob is None or ob.type != "CURVES":
            return refuse(cls, "Active object must be a hair Curves object")
        s = ob.furcollide
        if s.is_setup and s.output is not None and s.output.furcollide.source == ob:
            return refuse(cls, registry.refusal_in(ob, context.scene)
                          or "The active hair already has a FurCollide setup")
        if s.is_output:
            return refuse(cls, "The active hair is a FurCollide output; select its source")
        msg = backend_message()
        return refuse(cls, msg) if msg else True

    @reports_errors
    def execute(self, context):
        src = context.active_object
        scene = context.scene
        src_eval = src.evaluated_get(context.evaluated_depsgraph_get())
        if len(src_eval.data.curves) == 0:
            self.report({"ERROR"}, f"'{src.name}' has no curves to collide")
            return {"CANCELLED"}
        sizes = bridge.curve_offsets(src_eval.data)
        if len(sizes) > 1 and (sizes[1:] - sizes[:-1]).min() < 2:
            self.report({"ERROR"}, f"'{src.name}' has curves with fewer than 2 points")
            return {"CANCELLED"}
        out = _new_output(src, src_eval, scene)

        registry.clear_runtime(src)
        s = src.furcollide
        owner = dependencies.groom_owner(src)
        if owner is not None and owner != src:  # a copy: the render groom is the original's
            s.groom.output = None
            s.groom.bind_id = ""
        s.uid = ""
        registry.ensure_uid(src)
        s.is_setup = True
        s.settings_version = CURRENT_VERSION  # (keys made from now on: radians)
        s.output = out
        registry.adopt(src, scene)  # the setup belongs to this scene (registry.owner)
        s.frame_start = scene.frame_start
        s.frame_end = scene.frame_end
        s.is_baked = False
        s.bake_path = ""
        s.colliders.clear()
        colliders = _selected_colliders(context, exclude={src})
        for o in colliders:
            s.colliders.add().object = o
        s.collider_index = max(0, len(s.colliders) - 1)
        locked = needs_lock(scene)  # (renders from the UI need it: ops/scene.py)
        scene.render.use_lock_interface = True
        out.furcollide.is_output = True
        out.furcollide.source = src
        src.hide_render = True
        dependencies.update_dependencies(src)
        output.apply_visibility(src)
        context.view_layer.objects.active = src
        error = evaluate_now(context, src)
        if error:  # the setup stays usable
            self.report({"WARNING"}, f"Set up, but the first frame failed: {error}")
        self.report(
            {"INFO"},
            f"FurCollide: '{src.name}' -> '{out.name}' with {len(colliders)} collider(s)"
            + ("; Render > Lock Interface turned on (renders from the UI need it)"
               if locked else ""),
        )
        redraw(context)
        return {"FINISHED"}


class FURCOLLIDE_OT_remove(SetupOperator, Operator):
    """Remove the FurCollide setup of the active hair: deletes the output object and
    shows the source again (bake files on disk are kept; use Free Bake first)"""

    bl_idname = "furcollide.remove"
    bl_label = "Remove FurCollide"
    bl_options = {"REGISTER", "UNDO"}
    #: The question the button asks first (Delete asks too in Blender's own menus).
    CONFIRM = "Remove FurCollide and delete its output?"

    keep_output: BoolProperty(
        name="Keep Output",
        default=False,
        description="Keep the output hair object (as plain hair with its last result)",
    )

    def invoke(self, context, event):
        """From a button or a menu: ask first (the output is deleted)."""
        src = active_setup(context)
        what = f"'{src.furcollide.output.name}'" if src.furcollide.output else "the output"
        return context.window_manager.invoke_confirm(
            self, event, title=self.CONFIRM,
            message=f"Deletes {what} and shows '{src.name}' again (bake files are kept)",
            confirm_text="Remove", icon="WARNING")

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        out = s.output if dependencies.owns_output(src) else None  # a copy: the original's
        if dependencies.groom_owner(src) in (None, src):
            remove_groom(src)
        else:  # a copy: the render groom is the original's
            s.groom.output = None
            s.groom.bind_id = ""
        if children.owns_children(src):  # (a copy's is the original's: kept)
            children.remove_children_output(src)
        s.children.output = None
        registry.clear_runtime(src)
        if out is not None:
            if self.keep_output:
                mod = out.modifiers.get(dependencies.DEPENDENCY_MODIFIER)
                if mod is not None:
                    out.modifiers.remove(mod)
                out.furcollide.is_output = False
                out.furcollide.source = None
            else:
                data = out.data
                bpy.data.objects.remove(out)
                if data.users == 0:
                    bpy.data.hair_curves.remove(data)
        ng = bpy.data.node_groups.get(dependencies.dependency_group_name(src))
        if ng is not None and ng.users == 0:
            bpy.data.node_groups.remove(ng)
        kept = s.bake_path
        s.is_setup = False
        s.output = None
        s.colliders.clear()
        s.is_baked = False
        s.bake_path = ""
        s.uid = ""
        s.owner_scene = ""
        output.hide_in_viewport(src, False, render=False)
        msg = f"Removed the FurCollide setup of '{src.name}'"
        if kept:
            msg += f" (bake files kept in {bpy.path.abspath(kept)})"
        self.report({"INFO"}, msg)
        redraw(context)
        return {"FINISHED"}


class FURCOLLIDE_OT_collider_add(SetupOperator, Operator):
    """Add the selected meshes, bevelled curves or text objects as colliders (or an empty
    slot to fill in)"""

    bl_idname = "furcollide.collider_add"
    bl_label = "Add Collider"
    bl_options = {"REGISTER", "UNDO"}

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        have = {c.object for c in s.colliders if c.object is not None}
        new = _selected_colliders(context, exclude=have | {src})
        # (before the list changes: its update callbacks would say less)
        invalidate(src, context.scene, reason="a collider was added", refresh=False)
        if not new:
            s.colliders.add()
        for o in new:
            s.colliders.add().object = o
        s.collider_index = len(s.colliders) - 1
        invalidate(src, context.scene, reason="a collider was added", colliders=True)
        refresh(context)
        names = ", ".join(o.name for o in new) or "an empty slot"
        self.report({"INFO"}, f"Added {names}")
        return {"FINISHED"}


class FURCOLLIDE_OT_collider_remove(SetupOperator, Operator):
    """Remove the active collider from the list (the mesh itself is not deleted)"""

    bl_idname = "furcollide.collider_remove"
    bl_label = "Remove Collider"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        s = src.furcollide
        if 0 <= s.collider_index < len(s.colliders):
            return ""
        return "No collider selected in the list"

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        i = s.collider_index
        name = s.colliders[i].object.name if s.colliders[i].object else "empty slot"
        s.colliders.remove(i)
        s.collider_index = min(i, max(0, len(s.colliders) - 1))
        invalidate(src, context.scene, reason="a collider was removed", colliders=True)
        refresh(context)
        self.report({"INFO"}, f"Removed collider {name}")
        return {"FINISHED"}


class FURCOLLIDE_OT_reset(SetupOperator, Operator):
    """Forget the cached playback frames and re-read the source hair (use after
    changing the number of curves); the result is solved again from the start frame"""

    bl_idname = "furcollide.reset"
    bl_label = "Reset Cache"
    bl_options = {"REGISTER"}

    @classmethod
    def refusal(cls, context, src):
        return "The setup is baked: Free Bake first" if src.furcollide.is_baked else ""

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        registry.clear_runtime(src)
        error = evaluate_now(context, src)
        if error:
            self.report({"ERROR"}, f"Reset, but this frame failed: {error}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Reset the FurCollide cache of '{src.name}'")
        redraw(context)
        return {"FINISHED"}


classes = (
    FURCOLLIDE_OT_add,
    FURCOLLIDE_OT_remove,
    FURCOLLIDE_OT_collider_add,
    FURCOLLIDE_OT_collider_remove,
    FURCOLLIDE_OT_reset,
)
