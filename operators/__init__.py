"""The Blender glue: settings, operators and the frame handler around :mod:`..core`.

Thin: read evaluated Blender data into numpy (``foreach_get``), call the core, write
the result into the output hair (``foreach_set``), report errors. A frame reads top to
bottom: ``handlers`` -> ``frame_rules`` -> ``frame_inputs`` -> ``frame_solve`` ->
``frame_outputs`` -> ``groom_stage`` -> ``children_stage``.

Modules
-------
handlers             Blender's handlers: thin loops over the setups, never raise
frame_rules          what a frame does (solve, show cached, hold, pass through): Outcome
frame_inputs         the evaluated source read into FrameInputs; the frame-inputs record
frame_solve          solve_frame(setup, inputs) -> FrameResult: core.pipeline.frame's sequence
frame_outputs        writing the output hair: positions, status, colours, attributes
groom_stage          the render groom follows the collided guides (+ clearance pass); its storage
children_stage       the output's own children stack, cleared live into the children output
rest_position        a source whose curves change every frame: the message and the fix
motion               the motion settings read into core.pipeline.frame.Motion
colliders            which objects collide; their core Colliders kept across frames
fur_attach           Fur Attach's binding (storage) and the attached input curves
setup                Setup (one setup as one evaluation sees it), settings, signature
registry             per-setup session state (Runtime), status messages, errors
invalidation         what an edit drops (cached frames), and the refresh after it
dependencies         the output's "FurCollide Inputs" modifier (render dependencies)
bake                 bake and resume (BakeJob), bake directories, free
bridge               numpy <-> bpy transfers with size checks
properties           the settings on the source hair object (Object.furcollide)
properties_pipeline  the fur pipeline stages' settings (motion, render groom)
property_helpers     the settings' update callbacks and property factories
ops_common           what every operator shares (poll messages, reports, refresh)
ops_setup            Add / Remove FurCollide, Add / Remove Collider, Reset Cache
ops_bake             Bake, Bake All, Free Bake, Free All Bakes
ops_sampler          Fur Sampler
ops_attach           Fur Attach Bind / Unbind
ops_groom            Bind Groom, Remove Groom Output
ops_children         Make Children Output, Use Rest Position
pipeline             Collider Distance, Children from Guides, the pipeline scene settings
cli                  ``blender -b --command furcollide ...``
"""

from . import (
    cli,
    handlers,
    ops_attach,
    ops_bake,
    ops_children,
    ops_groom,
    ops_sampler,
    ops_setup,
    pipeline,
    properties,
)

classes = (
    ops_setup.classes
    + ops_bake.classes
    + ops_sampler.classes
    + ops_attach.classes
    + ops_groom.classes
    + ops_children.classes
    + pipeline.classes
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
