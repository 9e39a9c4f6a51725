"""Operators that create, edit and remove FurCollide setups."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty
from bpy.types import Operator

from . import bridge, runtime


def backend_message() -> str:
    """Non-empty when the ray tracer (embreex) cannot be used here."""
    try:
        from .. import core
    except ImportError as exc:  # pragma: no cover - depends on the platform
        return f"FurCollide's core could not be loaded: {exc}"
    return "" if core.embree_available() else core.embree_error()


def active_setup(context):
    """Source object of the setup of the active object (source or output)."""
    return runtime.source_of(getattr(context, "object", None))


def _redraw(context):
    screen = getattr(context, "screen", None)
    if screen is None:
        return
    for area in screen.areas:
        if area.type in {"VIEW_3D", "PROPERTIES"}:
            area.tag_redraw()


def _refresh(context):
    """Re-run the frame handler on the current frame (after an edit)."""
    scene = context.scene
    scene.frame_set(scene.frame_current, subframe=scene.frame_subframe)


class FURCOLLIDE_OT_add(Operator):
    """Make the active hair collide with the selected meshes: creates the output hair
    object that receives the result every frame and hides the source from render"""

    bl_idname = "furcollide.add"
    bl_label = "Add FurCollide"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        ob = context.active_object
        if ob is None or ob.type != "CURVES":
            cls.poll_message_set("Active object must be a hair Curves object")
            return False
        s = ob.furcollide
        if s.is_setup and s.output is not None and s.output.furcollide.source == ob:
            cls.poll_message_set("The active hair already has a FurCollide setup")
            return False
        if ob.furcollide.is_output:
            cls.poll_message_set("The active hair is a FurCollide output; select its source")
            return False
        msg = backend_message()
        if msg:
            cls.poll_message_set(msg)
            return False
        return True

    def execute(self, context):
        src = context.active_object
        scene = context.scene
        s = src.furcollide
        depsgraph = context.evaluated_depsgraph_get()
        src_eval = src.evaluated_get(depsgraph)
        if len(src_eval.data.curves) == 0:
            self.report({"ERROR"}, f"'{src.name}' has no curves to collide")
            return {"CANCELLED"}
        sizes = bridge.curve_offsets(src_eval.data)
        if len(sizes) > 1 and (sizes[1:] - sizes[:-1]).min() < 2:
            self.report({"ERROR"}, f"'{src.name}' has curves with fewer than 2 points")
            return {"CANCELLED"}

        hc = bpy.data.hair_curves.new(f"{src.data.name} FurCollide")
        bridge.copy_topology(src_eval.data, hc)
        for mat in src.data.materials:
            hc.materials.append(mat)
        hc.surface = src.data.surface
        hc.surface_uv_map = src.data.surface_uv_map
        out = bpy.data.objects.new(f"{src.name} FurCollide", hc)
        colls = list(src.users_collection) or [scene.collection]
        for coll in colls:
            coll.objects.link(out)
        out.parent = src.parent
        out.parent_type = src.parent_type
        out.parent_bone = src.parent_bone
        out.matrix_parent_inverse = src.matrix_parent_inverse.copy()
        out.matrix_basis = src.matrix_basis.copy()
        for i, slot in enumerate(src.material_slots):
            if slot.link == "OBJECT" and i < len(out.material_slots):
                out.material_slots[i].link = "OBJECT"
                out.material_slots[i].material = slot.material

        runtime.clear_runtime(src)
        s.uid = ""
        runtime.ensure_uid(src)
        s.is_setup = True
        s.output = out
        s.frame_start = scene.frame_start
        s.frame_end = scene.frame_end
        s.is_baked = False
        s.bake_path = ""
        s.colliders.clear()
        added = 0
        for o in context.selected_objects:
            if o.type == "MESH" and o != src:
                item = s.colliders.add()
                item.object = o
                added += 1
        s.collider_index = max(0, len(s.colliders) - 1)
        o = out.furcollide
        o.is_output = True
        o.source = src
        src.hide_render = True
        runtime.update_dependencies(src)
        runtime.apply_visibility(src)
        view_layer = context.view_layer
        view_layer.objects.active = src
        try:
            runtime.evaluate(scene, context.evaluated_depsgraph_get(), src)
        except Exception as exc:  # noqa: BLE001 - reported, the setup stays usable
            self.report({"WARNING"}, f"Set up, but the first frame failed: {exc}")
        self.report(
            {"INFO"},
            f"FurCollide: '{src.name}' -> '{out.name}' with {added} collider(s)",
        )
        _redraw(context)
        return {"FINISHED"}


class FURCOLLIDE_OT_remove(Operator):
    """Remove the FurCollide setup of the active hair: deletes the output object and
    shows the source again (bake files on disk are kept; use Free Bake first)"""

    bl_idname = "furcollide.remove"
    bl_label = "Remove FurCollide"
    bl_options = {"REGISTER", "UNDO"}

    keep_output: BoolProperty(
        name="Keep Output",
        default=False,
        description="Keep the output hair object (as plain hair with its last result)",
    )

    @classmethod
    def poll(cls, context):
        if active_setup(context) is None:
            cls.poll_message_set("Active object has no FurCollide setup")
            return False
        return True

    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        out = s.output
        runtime.clear_runtime(src)
        ng_name = f".FurCollide Inputs {s.uid[:8]}"
        if out is not None:
            if self.keep_output:
                mod = out.modifiers.get(runtime.DEPENDENCY_MODIFIER)
                if mod is not None:
                    out.modifiers.remove(mod)
                out.furcollide.is_output = False
                out.furcollide.source = None
            else:
                data = out.data
                bpy.data.objects.remove(out)
                if data.users == 0:
                    bpy.data.hair_curves.remove(data)
        ng = bpy.data.node_groups.get(ng_name)
        if ng is not None and ng.users == 0:
            bpy.data.node_groups.remove(ng)
        kept = s.bake_path
        s.is_setup = False
        s.output = None
        s.colliders.clear()
        s.is_baked = False
        s.bake_path = ""
        s.uid = ""
        src.hide_render = False
        try:
            src.hide_set(False)
        except RuntimeError:
            pass
        msg = f"Removed the FurCollide setup of '{src.name}'"
        if kept:
            msg += f" (bake files kept in {bpy.path.abspath(kept)})"
        self.report({"INFO"}, msg)
        _redraw(context)
        return {"FINISHED"}


class FURCOLLIDE_OT_collider_add(Operator):
    """Add the selected meshes as colliders (or an empty slot to fill in)"""

    bl_idname = "furcollide.collider_add"
    bl_label = "Add Collider"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if active_setup(context) is None:
            cls.poll_message_set("Active object has no FurCollide setup")
            return False
        return True

    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        have = {c.object for c in s.colliders if c.object is not None}
        new = [
            o
            for o in context.selected_objects
            if o.type == "MESH" and o not in have and o != src
        ]
        if not new:
            s.colliders.add()
        for o in new:
            item = s.colliders.add()
            item.object = o
        s.collider_index = len(s.colliders) - 1
        runtime.invalidate(src, reason="collider added", colliders=True)
        _refresh(context)
        names = ", ".join(o.name for o in new) or "an empty slot"
        self.report({"INFO"}, f"Added {names}")
        return {"FINISHED"}


class FURCOLLIDE_OT_collider_remove(Operator):
    """Remove the active collider from the list (the mesh itself is not deleted)"""

    bl_idname = "furcollide.collider_remove"
    bl_label = "Remove Collider"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        src = active_setup(context)
        if src is None:
            cls.poll_message_set("Active object has no FurCollide setup")
            return False
        s = src.furcollide
        if not (0 <= s.collider_index < len(s.colliders)):
            cls.poll_message_set("No collider selected in the list")
            return False
        return True

    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        i = s.collider_index
        name = s.colliders[i].object.name if s.colliders[i].object else "empty slot"
        s.colliders.remove(i)
        s.collider_index = min(i, max(0, len(s.colliders) - 1))
        runtime.invalidate(src, reason="collider removed", colliders=True)
        _refresh(context)
        self.report({"INFO"}, f"Removed collider {name}")
        return {"FINISHED"}


class FURCOLLIDE_OT_reset(Operator):
    """Forget the cached playback frames and re-read the source hair (use after
    changing the number of curves); the result is solved again from the start frame"""

    bl_idname = "furcollide.reset"
    bl_label = "Reset Cache"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        src = active_setup(context)
        if src is None:
            cls.poll_message_set("Active object has no FurCollide setup")
            return False
        if src.furcollide.is_baked:
            cls.poll_message_set("The setup is baked: Free Bake first")
            return False
        return True

    def execute(self, context):
        src = active_setup(context)
        runtime.clear_runtime(src)
        scene = context.scene
        try:
            runtime.evaluate(scene, context.evaluated_depsgraph_get(), src)
        except Exception as exc:  # noqa: BLE001
            self.report({"ERROR"}, f"Reset, but this frame failed: {exc}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Reset the FurCollide cache of '{src.name}'")
        _redraw(context)
        return {"FINISHED"}


classes = (
    FURCOLLIDE_OT_add,
    FURCOLLIDE_OT_remove,
    FURCOLLIDE_OT_collider_add,
    FURCOLLIDE_OT_collider_remove,
    FURCOLLIDE_OT_reset,
)
