"""The Blender glue: settings, operators and the frame handler around :mod:`..core`.

Thin: read evaluated Blender data into numpy (``foreach_get``), call the core, write
the result into the output hair (``foreach_set``), report errors. Each job has its
room (a sub-package), so the folder says what a change may touch:

frame/      what happens when Blender changes frame: the handlers, the spine (read
            once, decide, solve, write once), the frame rules, the stages after
settings/   the settings on the hair object (Blender properties) and reading them:
            keyed values, parameter maps, the motion settings, fingerprints
ops/        the operators (one module per concern) and the command line
store/      what a session keeps: the setups' runtimes, the playback cache, the
            status, what an edit drops, bake and baked frames
blender/    Blender I/O every room uses: numpy <-> bpy transfers, version
            differences, the outputs' dependency modifier

Each sub-package's docstring lists its modules, one line each.
"""

from .frame import handlers
from .ops import attach, bake, children, cli, groom, pipeline, sampler, scene, setup
from .settings import properties

classes = (
    setup.classes
    + bake.classes
    + sampler.classes
    + attach.classes
    + groom.classes
    + children.classes
    + pipeline.classes
    + scene.classes
)


def register():
    import bpy

    properties.register()
    for cls in classes:
        bpy.utils.register_class(cls)
    pipeline.register()
    handlers.register()
    cli.register()


def unregister():
    import bpy

    cli.unregister()
    handlers.unregister()
    pipeline.unregister()
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    properties.unregister()
