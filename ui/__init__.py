"""The user interface: View3D > Sidebar > FurCollide (``panel``), its Fur Pipeline
sub-panel (``pipeline_panel``), the colliders list and the setting presets (``presets``).
Thin: it draws the settings and calls the operators of :mod:`..operators`."""

from . import panel, pipeline_panel, presets

classes = presets.classes + panel.classes + pipeline_panel.classes


def register():
    import bpy

    for cls in classes:
        bpy.utils.register_class(cls)
    presets.install_shipped_presets()


def unregister():
    import bpy

    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
