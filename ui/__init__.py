"""The user interface: View3D > Sidebar > FurCollide (``panel``), its Fur Pipeline
sub-panel (``pipeline_panel``), the colliders list, the setting presets (``presets``) and
the Object menu's FurCollide entry (``menu``). Labels fit the sidebar (``text``).
Thin: it draws the settings and calls the operators of :mod:`..operators`."""

from . import menu, panel, pipeline_panel, presets

classes = presets.classes + panel.classes + pipeline_panel.classes + menu.classes


def register():
    import bpy

    for cls in classes:
        bpy.utils.register_class(cls)
    menu.register()
    presets.install_shipped_presets()


def unregister():
    import bpy

    menu.unregister()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
