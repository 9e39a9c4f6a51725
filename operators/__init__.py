"""Blender operators, settings and the frame handler (thin glue around :mod:`..core`).

Modules
-------
properties  settings stored on the source hair object (``Object.furcollide``)
bridge      numpy <-> bpy transfers with size checks
cache       bounded memory cache and atomic disk bake files
runtime     per-setup registry and the ``frame_change_post`` handler
setup       add / remove / collider add & remove / reset operators
bake        bake / bake all / free bake / free all operators
cli         ``blender -b --command furcollide ...``
pipeline    fur pipeline operators (sampler, collider distance, children)
"""

from . import bake, cli, pipeline, properties, runtime, setup

classes = setup.classes + bake.classes + pipeline.classes


def register():
    import bpy

    properties.register()
    for cls in classes:
        bpy.utils.register_class(cls)
    pipeline.register()
    runtime.register()
    cli.register()


def unregister():
    import bpy

    cli.unregister()
    runtime.unregister()
    pipeline.unregister()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    properties.unregister()
