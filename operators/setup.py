"""Operators that create, edit and remove FurCollide setups, and what every
FurCollide operator shares: finding the setup, poll messages, error reports and
refreshing the current frame after an edit."""

from __future__ import annotations

import functools

import bpy
from bpy.props import BoolProperty
from bpy.types import Operator

from . import bridge, runtime

NO_SETUP = "Active object has no FurCollide setup"


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


def refuse(cls, message: str) -> bool:
    """``poll`` helper: show ``message`` as the reason and return False."""
    cls.poll_message_set(message)
    return False


class SetupOperator:
    """Mixin of the operators that act on the active object's setup.

    ``poll`` refuses with :data:`NO_SETUP` when there is no setup, or with
    the reason :meth:`refusal` returns for it.
    """

    @classmethod
    def refusal(cls, context, src) -> str:
        """Why the operator cannot run on the setup of ``src`` ('' = it can)."""
        return ""

    @classmethod
    def poll(cls, context):
        src = active_setup(context)
        message = NO_SETUP if src is None else cls.refusal(context, src)
        return refuse(cls, message) if message else True


def reports_errors(execute):
    """Decorate ``execute``: an unexpected error becomes a report, not a traceback."""

    @functools.wraps(execute)
    def wrapper(self, context):
        try:
            return execute(self, context)
        except Exception as exc:  # noqa: BLE001 - reported to the artist
            self.report({"ERROR"}, f"FurCollide: {runtime.describe(exc)}")
            return {"CANCELLED"}

    return wrapper


def evaluate_now(context, src) -> str:
    """Solve the current frame of the setup on ``src``; returns an error or ''.

    Does nothing while the frame handler runs (an operator called from a handler
    or a bake): that run writes the frame itself.
    """
    if runtime._busy:
        return ""
    try:
        runtime.evaluate(context.scene, context.evaluated_depsgraph_get(), src)
    except Exception as exc:  # noqa: BLE001 - the caller reports it
        return runtime.describe(exc)
    return ""


def refresh(context) -> None:
    """Re-run the frame handler on the current frame (after an edit)."""
    scene = context.scene
    scene.frame_set(scene.frame_current, subframe=scene.frame_subframe)


def redraw(context) -> None:
    """Redraw the 3D views and property editors (the panel shows new state)."""
    screen = getattr(context, "screen", None)
    if screen is None:
        return
    for area in screen.areas:
        if area.type in {"VIEW_3D", "PROPERTIES"}:
            area.tag_redraw()


# ---------------------------------------------------------------- operators
def _selected_colliders(context, exclude=()):
    """Selected objects that can collide (meshes, bevelled curves, text...,
    collection instances), in selection order, minus ``exclude``."""
    return [o for o in context.selected_objects
            if (bridge.is_collider_type(o) or runtime.instanced_collection(o) is not None)
            and o not in exclude]


def new_hair_object_like(src, suffix, scene, fill):
    """New hair object "<src> <suffix>" placed, parented and linked like ``src``,
    with its materials, surface and UV map. ``fill(curves_data)`` writes the
    curves; if it raises, the half-made data is removed again."""
    hc = bpy.data.hair_curves.new(f"{src.data.name} {suffix}")
    try:
        fill(hc)
    except Exception:
        bpy.data.hair_curves.remove(hc)
        raise
    for mat in src.data.materials:
        hc.materials.append(mat)
    hc.surface = src.data.surface
    hc.surface_uv_map = src.data.surface_uv_map
    ob = bpy.data.objects.new(f"{src.name} {suffix}", hc)
    for coll in list(src.users_collection) or [scene.collection]:
        coll.objects.link(ob)
    ob.parent = src.parent
    ob.parent_type = src.parent_type
    ob.parent_bone = src.parent_bone
    ob.matrix_parent_inverse = src.matrix_parent_inverse.copy()
    ob.matrix_basis = src.matrix_basis.copy()
    return ob


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
            return refuse(cls, "The active hair already has a FurCollide setup")
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

        runtime.clear_runtime(src)
        s = src.furcollide
        owner = runtime.groom_owner(src)
        if owner is not None and owner != src:  # a copy: the render groom is the original's
            s.groom.output = None
            s.groom.bind_id = ""
        s.uid = ""
        runtime.ensure_uid(src)
        s.is_setup = True
        s.output = out
        s.frame_start = scene.frame_start
        s.frame_end = scene.frame_end
        s.is_baked = False
        s.bake_path = ""
        s.colliders.clear()
        colliders = _selected_colliders(context, exclude={src})
        for o in colliders:
            s.colliders.add().object = o
        s.collider_index = max(0, len(s.colliders) - 1)
        out.furcollide.is_output = True
        out.furcollide.source = src
        src.hide_render = True
        runtime.update_dependencies(src)
        runtime.apply_visibility(src)
        context.view_layer.objects.active = src
        error = evaluate_now(context, src)
        if error:  # the setup stays usable
            self.report({"WARNING"}, f"Set up, but the first frame failed: {error}")
        self.report(
            {"INFO"},
            f"FurCollide: '{src.name}' -> '{out.name}' with {len(colliders)} collider(s)",
        )
        redraw(context)
        return {"FINISHED"}


class FURCOLLIDE_OT_remove(SetupOperator, Operator):
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

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        out = s.output if runtime.owns_output(src) else None  # a copy: the original's
        if runtime.groom_owner(src) in (None, src):
            runtime.remove_groom(src)
        else:  # a copy: the render groom is the original's
            s.groom.output = None
            s.groom.bind_id = ""
        runtime.clear_runtime(src)
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
        ng = bpy.data.node_groups.get(runtime.dependency_group_name(src))
        if ng is not None and ng.users == 0:
            bpy.data.node_groups.remove(ng)
        kept = s.bake_path
        s.is_setup = False
        s.output = None
        s.colliders.clear()
        s.is_baked = False
        s.bake_path = ""
        s.uid = ""
        runtime.hide_in_viewport(src, False, render=False)
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
        if not new:
            s.colliders.add()
        for o in new:
            s.colliders.add().object = o
        s.collider_index = len(s.colliders) - 1
        runtime.invalidate(src, reason="collider added", colliders=True)
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
        runtime.invalidate(src, reason="collider removed", colliders=True)
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
        runtime.clear_runtime(src)
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
