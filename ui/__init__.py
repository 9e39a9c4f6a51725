"""Sidebar panel, colliders list and presets (thin glue around :mod:`..operators`)."""

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
