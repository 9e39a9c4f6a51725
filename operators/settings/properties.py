"""FurCollide settings stored on the source hair object (``Object.furcollide``).

Solver fields mirror :class:`core.Settings` (same names, same defaults);
the rest describes the setup: colliders, per-curve enable attribute, the
output object, the cache. Every property that changes the result
drops the playback cache, as Blender's point cache does (``update=``, see
:mod:`.property_helpers`). The pipeline stages' settings are in
:mod:`.properties_pipeline`. Read-only statistics are computed properties
(``get=``) served by the runtime registry, so the frame handler never writes
RNA data on the source.
"""

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)
from bpy.types import PropertyGroup

from ..blender import compat
from ..store import report
from . import angles
from .core_values import core_value
from .properties_pipeline import FurCollideChildren, FurCollideGroom, FurCollideMotion
from .property_helpers import (
    NOT_ANIMATABLE,
    choice,
    factor,
    fixed,
    hidden,
    map_property,
    offset_property,
    poll_collider,
    poll_hair,
    stat,
    toggle,
    update_attach,
    update_collider_options,
    update_colliders,
    update_memory_limit,
    update_range,
    update_settings,
    update_show_result,
)


# ----------------------------------------------------------------- groups
class FurCollideCollider(PropertyGroup):
    """One collision mesh of a FurCollide setup."""

    object: PointerProperty(
        name="Collider",
        type=bpy.types.Object,
        poll=poll_collider,
        update=update_colliders,
        description="Mesh the hair must not pass through (or a curve with a bevel, such "
        "as a rope, a surface, text or a metaball; or a collection instance, such as a "
        "linked asset: every such object in it collides). Its evaluated shape is used "
        "every frame, so armatures, shape keys, modifiers and cloth all count",
    )
    enabled: toggle(
        "Enabled", True,
        "Collide with this mesh. Turn off to let the hair pass through it",
        update=update_colliders,
    )
    double_sided: toggle(
        "Double Sided", False,
        "Treat the mesh as a thin sheet that blocks hair from both sides (cloth, leaves). "
        "Off: a closed body with an inside; hair rooted inside it counts as pinched",
        update=update_collider_options,
    )
    use_offset: toggle(
        "Own Offset", False,
        "Use this collider's own Offset instead of the setup's",
        update=update_collider_options,
    )
    collision_offset: offset_property(
        "Gap kept between the hair and this mesh (needs Own Offset)", update_collider_options
    )


class FurCollideSettings(PropertyGroup):
    """A FurCollide setup on a source hair object (or the link on its output)."""

    # ---------------------------------------------------------- identity
    is_setup: hidden(BoolProperty, "Is Setup", False)
    is_output: hidden(BoolProperty, "Is Output", False)
    uid: hidden(StringProperty, "Setup ID", "")
    source: PointerProperty(
        name="Source",
        type=bpy.types.Object,
        poll=poll_hair,
        description="The hair object whose FurCollide setup writes into this object",
    )
    output: PointerProperty(
        name="Output",
        type=bpy.types.Object,
        poll=poll_hair,
        update=update_settings,
        description="Hair object that receives the collided curves every frame. "
        "You may add your own modifiers to it (e.g. Interpolate Hair Curves)",
    )
    enabled: toggle(
        "Enabled", True,
        "Solve collisions for this hair. Off: the output simply follows the source",
    )
    show_result: toggle(
        "Show Result", True,
        "Show the collided output in the viewport (on) or the original source hair (off). "
        "Rendering always uses the output",
        update=update_show_result,
    )

    # ---------------------------------------------------------- colliders
    colliders: CollectionProperty(
        type=FurCollideCollider,
        name="Colliders",
        description="Meshes this hair collides with, each with its own options",
    )
    collider_index: IntProperty(
        name="Active Collider",
        default=0,
        min=0,
        description="The collider selected in the list (its options are shown below it)",
    )
    collider_collection: PointerProperty(
        name="Collection",
        type=bpy.types.Collection,
        update=update_colliders,
        description="Collider Collection: every mesh in this collection (and every curve "
        "with a bevel, surface, text or metaball) also collides, with the setup's Offset "
        "and Double Sided below",
    )
    collection_double_sided: toggle(
        "Collection Double Sided", False,
        "Treat the meshes of the collider collection as thin sheets that block hair from "
        "both sides",
        update=update_collider_options,
    )

    # ---------------------------------------------------------- resolution
    mode: choice(
        "Mode",
        [
            ("STIFF", "Stiff", "Rotate the whole curve at its root, keeping its shape. "
             "Good for short fur"),
            ("BEND", "Bend", "Bend the curve evenly from root to tip. Good for long fur "
             "and grass"),
            ("SOFT", "Soft", "Let each colliding segment turn on its own and drag the "
             "next ones along. Hugs tight contacts such as cloth"),
        ],
        "BEND",
        fixed("How a colliding curve is turned out of the mesh",
              "a curve's state in one mode (its angle, or each segment's turn) means "
              "nothing in another, so a switch mid-shot would pop. Use two setups"),
        animatable=False,
    )
    rotation_precision: angles.angle(
        "rotation_precision", "Precision",
        "The angle step used to search the smallest turn that frees a curve. Smaller is "
        "more exact and slower (the paper's Rotation Precision)",
        update_settings, soft_min=0.05, soft_max=5.0, precision=3,
    )
    max_angle: angles.angle(
        "max_angle", "Max Angle",
        "Largest turn a curve may take. Curves that would need more keep their last "
        "collision-free shape and are flagged unresolved",
        update_settings,
    )
    affected_connected_cvs: IntProperty(
        name="Affected CVs",
        default=2,
        min=0,
        max=10000,
        soft_max=10,
        update=update_settings,
        description="Soft mode: how many points after a colliding segment follow its turn "
        "(the paper's Affected Connected CVs)",
    )
    cv_falloff: factor(
        "CV Falloff", 0.5,
        "Soft mode: how quickly the following points stop turning along "
        "(0 = they turn fully, 1 = only the colliding segment turns)",
    )
    attract_to_growth_surface: toggle(
        "Attract to Skin", False,
        "Push colliding hair down toward the skin it grows from (pats fur or grass flat) "
        "instead of away along the collider's surface. Needs the hair's Surface object "
        "(the paper's Attract to Growth Surface)",
    )
    follow_collider_motion: toggle(
        "Follow Collider", False,
        "Lay colliding hair over in the direction the collider moves where it touches "
        "(a hand stroking fur, a ball rolling through grass) instead of away from its "
        "surface; where the collider does not move there, as without it (or toward the "
        "skin with Attract to Skin)",
    )
    collision_offset: offset_property(
        "Gap kept between the hair and every collider (a collider may use its own)",
        update_settings,
    )
    threads: IntProperty(
        name="Threads",
        default=0,
        min=0,
        max=1024,
        # (no update: the result is the same for any count, the cache stays valid)
        description="Threads a frame uses (0 = all CPUs): for its rays, and with many "
        "curves for two halves at once of the solve, of Fur Attach, of the wind and of "
        "the render groom. The result is identical for any count",
    )

    # -------------------------------------------------------------- shrink
    shrink: toggle(
        "Shrink", False,
        "Shorten colliding curves as they turn (Stiff and Bend only); reduces fur "
        "crossing at very different angles",
    )
    scale_minimum: FloatProperty(
        name="Min Scale",
        default=0.5,
        min=0.001,
        max=1.0,
        subtype="FACTOR",
        update=update_settings,
        description="The shortest a curve may become, as a fraction of its length (the "
        "paper's Scale Minimum)",
    )
    scale_angle: angles.angle(
        "scale_angle", "Scale Angle",
        "Turn at which a curve reaches Min Scale; it shrinks gradually up to that angle",
        update_settings,
    )

    # ---------------------------------------------------- recovery, plasticity
    recovery_rate: factor(
        "Recovery Rate", 0.2,
        "How fast freed hair springs back to its groomed shape, per frame "
        "(1 = at once, 0 = never). Recovery stops where it would collide again",
    )
    plasticity: factor(
        "Plasticity", 0.0,
        "How much of the deepest push the hair keeps after contact "
        "(0 = recovers fully, 1 = keeps the imprint, like trampled grass)",
    )

    # ------------------------------------------------------------ parameter maps
    plasticity_map: map_property("Plasticity")
    recovery_rate_map: map_property("Recovery Rate")
    collision_offset_map: map_property("Offset")
    max_angle_map: map_property("Max Angle")
    scale_minimum_map: map_property("Min Scale")

    # ---------------------------------------------------------------- pinch
    pinch_resolution: choice(
        "Pinched Hair",
        [
            ("STOP", "Stop Solving", "Pinched hair keeps the shape it had before the "
             "pinch (no jitter trying to solve the impossible)"),
            ("GROWTH_SURFACE", "Lay on Surface", "Lay pinched hair down onto the skin it "
             "grows from (needs the hair's Surface object; the paper's Put to Growth "
             "Surface)"),
        ],
        "STOP",
        "What hair does when its root is trapped inside a closed collider (e.g. an arm "
        "pressed into the body; the paper's Pinch Resolution)",
    )
    recover_pinched: toggle(
        "Recover", True,
        "Let hair recover once it is no longer pinched. Off: it keeps the shape it had "
        "when the pinch ended (the paper's Recover Pinched Fur)",
    )

    # ------------------------------------------------------ per-curve enable
    enable_attribute: StringProperty(
        name="Enable Attribute",
        default="furcollide_enable",
        update=update_settings,
        description="Per-curve attribute (Boolean, Integer or Float) on the evaluated "
        "source: curves where it is off keep their last shape and are not solved. "
        "Paint, select or animate it with geometry nodes. Missing = all curves solved",
    )

    # ----------------------------------------------------------------- cache
    frame_start: IntProperty(
        name="Start",
        default=1,
        update=update_range,
        options=NOT_ANIMATABLE,
        description=fixed("Frame where the simulation starts from the groomed shape",
                          "the frame range is the shot's"),
    )
    frame_end: IntProperty(
        name="End",
        default=250,
        update=update_range,
        options=NOT_ANIMATABLE,
        description=fixed("Last frame that is solved and baked; later frames hold it",
                          "the frame range is the shot's"),
    )
    cache_directory: StringProperty(
        name="Cache Directory",
        default="//furcollide_cache/",
        subtype="DIR_PATH",
        options=compat.BLEND_RELATIVE_PATH,
        description="Where bakes are written. '//' is the folder of the saved .blend "
        "file; each setup gets its own sub-folder",
    )
    memory_limit: IntProperty(
        name="Memory Limit",
        default=512,
        min=16,
        soft_max=8192,
        subtype="NONE",
        options=NOT_ANIMATABLE,
        update=update_memory_limit,
        description="Megabytes of RAM the playback cache of this setup may use. Past "
        "it, old frames are dropped (bake to keep everything)",
    )
    is_baked: hidden(BoolProperty, "Baked", False)

    # ------------------------------------------------------------ Fur Attach
    use_fur_attach: toggle(
        "Fur Attach", False,
        fixed("Move the source's curves rigidly with the evaluated growth surface from the "
              "Bind Frame on, instead of using the source's own animation (press Bind "
              "first)", "it changes every frame's input curves at once"),
        update=update_attach, animatable=False,
    )
    attach_reference_frame: IntProperty(
        name="Bind Frame",
        default=1,
        options=NOT_ANIMATABLE,
        description=fixed("Frame whose surface and curves Bind uses: each curve is tied to "
                          "the surface triangle under its root there. Press Bind again "
                          "after changing it", "Bind reads it once"),
    )
    attach_id: hidden(StringProperty, "Attach ID", "")

    # ---------------------------------------- wind, jiggle, render groom
    motion: PointerProperty(
        type=FurCollideMotion, name="Motion",
        description="Wind, jiggle, Region of Influence and the collider distance attribute",
    )
    groom: PointerProperty(
        type=FurCollideGroom, name="Render Groom",
        description="A dense render groom that follows the collided guides",
    )
    children: PointerProperty(
        type=FurCollideChildren, name="Children",
        description="The output's own children stack, cleared of the colliders every frame",
    )
    bake_path: hidden(StringProperty, "Bake Path", "")
    #: How this object's settings are keyed (:mod:`.versioning`): 0, saved before the
    #: angles were Blender angles (their keys in degrees), or :data:`CURRENT_VERSION`.
    settings_version: hidden(IntProperty, "Settings Version", 0)
    #: The scene this setup belongs to (Add FurCollide records it): in any other scene
    #: the hair is in, the output shows the source as groomed (registry.owner).
    owner_scene: hidden(StringProperty, "Scene", "")
    #: Frames the playback cache held when the file was last saved (the cache itself is
    #: not saved): after reopening, the frames that are not cached say so (handlers).
    cached_at_save: hidden(IntProperty, "Frames Cached At Save", 0)

    # --------------------------------------------------- read-only statistics
    stat_frame: stat("Frame", "frame", "Frame the statistics below belong to")
    stat_colliding: stat("Colliding", "colliding", "Curves turned out of a collider")
    stat_recovering: stat("Recovering", "recovering", "Curves springing back to their groom")
    stat_pinched: stat("Pinched", "pinched", "Curves whose root is trapped inside a collider")
    stat_unresolved: stat(
        "Unresolved", "unresolved", "Curves that could not be freed within Max Angle"
    )
    stat_disabled: stat("Disabled", "disabled", "Curves switched off by the enable attribute")
    stat_invalid: stat(
        "Invalid", "invalid",
        "Source curves FurCollide cannot solve (a zero-length segment, a NaN or infinite "
        "point): shown as they are, in yellow",
    )
    stat_groom_fixed: stat(
        "Render Curves Fixed", "groom_fixed",
        "Render groom curves the clearance pass moved out of a collider on the last frame",
    )
    stat_solve_ms: stat(
        "Solve Time", "solve_ms", "Milliseconds the last solved frame took",
        prop=FloatProperty, precision=1,
    )
    status_message: StringProperty(
        name="Status",
        get=lambda self: report.status_shown(self.id_data)[1],
        description="What FurCollide did on the last frame, or what went wrong",
    )
    is_outdated: BoolProperty(
        name="Outdated",
        get=lambda self: report.is_outdated(self.id_data),
        description="The shown frame could not be solved from the previous one: play from "
        "the start frame or bake",
    )

    @property
    def core_threads(self) -> int | None:
        """Threads as the core takes them (None: all CPUs, the property's 0), for the
        solver and every pipeline stage."""
        return self.threads or None

    def to_core_kwargs(self) -> dict:
        """Keyword arguments of :class:`core.Settings` for these properties (the angles
        in degrees, the choices in the core's spelling: :func:`core_value`)."""
        kw = {name: core_value(self, name) for name in SOLVER_PROPERTIES}
        kw["threads"] = self.core_threads
        return kw


#: Names of the :class:`core.Settings` fields stored here (presets store exactly
#: these; ``threads`` is a machine setting, not part of a look).
SOLVER_PROPERTIES = (
    "mode",
    "rotation_precision",
    "max_angle",
    "affected_connected_cvs",
    "cv_falloff",
    "attract_to_growth_surface",
    "follow_collider_motion",
    "shrink",
    "scale_minimum",
    "scale_angle",
    "recovery_rate",
    "plasticity",
    "pinch_resolution",
    "recover_pinched",
    "collision_offset",
)

#: The version of the settings' storage (:attr:`FurCollideSettings.settings_version`):
#: 1, the angles are Blender angles (keyed in radians) and the choices upper case.
CURRENT_VERSION = 1

classes = (FurCollideCollider, FurCollideMotion, FurCollideGroom, FurCollideChildren,
           FurCollideSettings)


def register():
    from . import versioning

    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Object.furcollide = PointerProperty(type=FurCollideSettings)
    versioning.register()


def unregister():
    from . import versioning

    versioning.unregister()
    del bpy.types.Object.furcollide
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
