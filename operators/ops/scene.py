"""The scene settings FurCollide needs, each set with one click from the panel's warning
(for the scene of the active setup: the panel shows the warnings only for a setup).

* **Lock Interface** (*Render › Lock Interface*): without it, a render started from the UI
  reads the hair while the frame handler writes it, and Blender can crash. Add FurCollide
  turns it on; the panel warns, with this button, when it is off.
* **Play Every Frame** (*Playback › Sync*): FurCollide solves each frame from the one
  before; a dropped frame is a jump ahead it cannot solve (the frame is held and the setup
  outdated). The panel warns, with this button, while Sync is anything else.
"""

from __future__ import annotations

from bpy.types import Operator

from .common import SetupOperator, redraw

#: ``scene.sync_mode``'s Play Every Frame.
EVERY_FRAME = "NONE"


def needs_lock(scene) -> bool:
    return not scene.render.use_lock_interface


def drops_frames(scene) -> bool:
    return scene.sync_mode != EVERY_FRAME


class FURCOLLIDE_OT_lock_interface(SetupOperator, Operator):
    """Turn on Render > Lock Interface: renders from the UI then cannot read the hair
    while FurCollide writes it (without it Blender can crash)"""

    bl_idname = "furcollide.lock_interface"
    bl_label = "Lock Interface"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        return "" if needs_lock(context.scene) else "Render > Lock Interface is already on"

    def execute(self, context):
        context.scene.render.use_lock_interface = True
        self.report({"INFO"}, "Render > Lock Interface is on")
        redraw(context)
        return {"FINISHED"}


class FURCOLLIDE_OT_play_every_frame(SetupOperator, Operator):
    """Set Playback > Sync to Play Every Frame: FurCollide solves each frame from the one
    before, so a frame dropped to keep up is a jump ahead it cannot solve"""

    bl_idname = "furcollide.play_every_frame"
    bl_label = "Play Every Frame"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        return "" if drops_frames(context.scene) else "Playback > Sync is Play Every Frame"

    def execute(self, context):
        context.scene.sync_mode = EVERY_FRAME
        self.report({"INFO"}, "Playback > Sync: Play Every Frame")
        redraw(context)
        return {"FINISHED"}


classes = (FURCOLLIDE_OT_lock_interface, FURCOLLIDE_OT_play_every_frame)
