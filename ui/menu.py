"""3D Viewport › Object › FurCollide: Add, Bake, Free Bake and Remove, as other add-ons
put their commands in the Object menu (the sidebar and F3 reach them too)."""

import bpy
from bpy.types import Menu


class FURCOLLIDE_MT_object(Menu):
    """FurCollide commands for the active hair"""

    bl_label = "FurCollide"

    def draw(self, context):
        layout = self.layout
        layout.operator("furcollide.add", icon="MOD_PHYSICS")
        layout.separator()
        layout.operator("furcollide.bake", icon="REC")
        layout.operator("furcollide.free_bake", icon="TRASH")
        layout.separator()
        layout.operator("furcollide.remove", icon="X")


def draw_object_menu(self, context):
    """The FurCollide entry at the bottom of the Object menu."""
    self.layout.separator()
    self.layout.menu(FURCOLLIDE_MT_object.__name__, icon="MOD_PHYSICS")


classes = (FURCOLLIDE_MT_object,)


def register():
    bpy.types.VIEW3D_MT_object.append(draw_object_menu)


def unregister():
    bpy.types.VIEW3D_MT_object.remove(draw_object_menu)
