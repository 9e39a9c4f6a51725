"""Children operators: the children output (:mod:`..frame.children`) and Use Rest Position
(:mod:`..frame.topology`), the fix for a source whose curve count changes every frame."""

from __future__ import annotations

from bpy.types import Operator

from ..frame import children, topology
from ..store import registry
from .common import SetupOperator, active_setup, evaluate_now, redraw, reports_errors


class FURCOLLIDE_OT_children_output(SetupOperator, Operator):
    """Clear the output's children every frame: make the children output that renders
    the output's modifiers' result with the clearance pass (the output itself is then
    kept out of renders); made on its own on the next frame when Clear Children is on"""

    bl_idname = "furcollide.children_output"
    bl_label = "Make Children Output"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        s = src.furcollide
        if s.output is None or s.output.type != "CURVES":
            return "The FurCollide setup has no output hair object"
        if not children.stack_modifiers(s.output):
            return (f"'{s.output.name}' has no modifiers that make children (add Children "
                    "from Guides, or Interpolate Hair Curves, to it)")
        return ""

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        src.furcollide.children.use_children = True
        ch = children.create_children_output(src, context.scene)
        err = evaluate_now(context, src)
        self.report({"INFO"}, f"Children of '{src.furcollide.output.name}' are cleared into "
                    f"'{ch.name}' every frame")
        if err:
            self.report({"WARNING"}, f"FurCollide: {err}")
        redraw(context)
        return {"FINISHED"}


class FURCOLLIDE_OT_use_rest_position(SetupOperator, Operator):
    """Make the source's curves the same on every frame: its Generate or Interpolate Hair
    Curves scatter them on the Surface's rest position (their Surface Rest Position, and
    the Surface's Add Rest Position, turned on), then the playback cache is reset"""

    bl_idname = "furcollide.use_rest_position"
    bl_label = topology.BUTTON
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        if not topology.unrested(src):
            return (f"'{src.name}' has no modifier scattering its curves on a Surface "
                    "without its rest position")
        if src.furcollide.is_baked:
            return "The setup is baked: Free Bake first"
        return ""

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        done = topology.use_rest_position(src)
        registry.clear_runtime(src)  # (the curves change: as Reset Cache)
        scene = context.scene
        err = evaluate_now(context, src)
        self.report({"INFO"}, f"{'; '.join(done)}. Play from frame "
                    f"{src.furcollide.frame_start} (current frame {scene.frame_current})")
        if err:
            self.report({"WARNING"}, f"FurCollide: {err}")
        redraw(context)
        return {"FINISHED"}


classes = (FURCOLLIDE_OT_children_output, FURCOLLIDE_OT_use_rest_position)
