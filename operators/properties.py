"""FurCollide settings stored on the source hair object (``Object.furcollide``).

Solver fields mirror :class:`core.Settings` (same names, same defaults);
the rest describes the setup: colliders, per-curve enable attribute, the
output object, the cache. Every property that changes the result
invalidates the cached frames after the current one (``update=``).
Read-only statistics are computed properties (``get=``) served by the
runtime registry, so the frame handler never writes RNA data on the source.
"""


import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)
from bpy.types import PropertyGroup

from . import runtime

# ------------------------------------------------------------------ updates


def _source_of(self):
    ob = self.id_data
    return ob


def _invalidate(self, context):
    runtime.invalidate(_source_of(self), reason="settings changed")


def _invalidate_colliders(self, context):
    runtime.invalidate(_source_of(self), reason="colliders changed", colliders=True)


def _invalidate_range(self, context):
    ob = _source_of(self)
    s = ob.furcollide
    if s.frame_end < s.frame_start:
        s.frame_end = s.frame_start
        return
    rt = runtime.get_runtime(ob, create=False)
    if rt is not None and rt.memory.start == s.frame_start:
        # Only the end moved: frames inside the new range stay valid.
        runtime.invalidate(ob, reason="frame range changed", from_frame=s.frame_end)
    else:
        runtime.invalidate(ob, reason="frame range changed", from_frame=s.frame_start - 1)


def _set_memory_limit(self, context):
    rt = runtime.get_runtime(_source_of(self), create=False)
    if rt is not None:
        rt.memory.limit = int(self.memory_limit * 1024 * 1024)


def _toggle_result(self, context):
    runtime.apply_visibility(_source_of(self))


def _is_mesh(self, ob):
    return ob.type == "MESH"


def _is_hair(self, ob):
    return ob.type == "CURVES"


def _stat(name, default=0):
    def get(self):
        return runtime.stats_for(self.id_data).get(name, default)

    return get


# ----------------------------------------------------------------- groups
class FurCollideCollider(PropertyGroup):
    """One collision mesh of a FurCollide setup."""

    object: PointerProperty(
        name="Collider",
        type=bpy.types.Object,
        poll=_is_mesh,
        update=_invalidate_colliders,
        description="Mesh the hair must not pass through. Its evaluated shape is used "
        "every frame, so armatures, shape keys, modifiers and cloth all count",
    )
    enabled: BoolProperty(
        name="Enabled",
        default=True,
        update=_invalidate_colliders,
        description="Collide with this mesh. Turn off to let the hair pass through it",
    )
    double_sided: BoolProperty(
        name="Double Sided",
        default=False,
        update=_invalidate_colliders,
        description="Treat the mesh as a thin sheet that blocks hair from both sides "
        "(cloth, leaves). Off: a closed body with an inside; hair rooted inside it "
        "counts as pinched",
    )
    use_offset: BoolProperty(
        name="Own Offset",
        default=False,
        update=_invalidate_colliders,
        description="Use this collider's own Collision Offset instead of the setup's",
    )
    collision_offset: FloatProperty(
        name="Collision Offset",
        default=0.0,
        min=0.0,
        soft_max=0.1,
        subtype="DISTANCE",
        unit="LENGTH",
        update=_invalidate_colliders,
        description="Gap kept between the hair and this mesh (needs Own Offset)",
    )


class FurCollideSettings(PropertyGroup):
    """A FurCollide setup on a source hair object (or the link on its output)."""

    # ---------------------------------------------------------- identity
    is_setup: BoolProperty(name="Is Setup", default=False, options={"HIDDEN"})
    is_output: BoolProperty(name="Is Output", default=False, options={"HIDDEN"})
    uid: StringProperty(name="Setup ID", default="", options={"HIDDEN"})
    source: PointerProperty(
        name="Source",
        type=bpy.types.Object,
        poll=_is_hair,
        description="The hair object whose FurCollide setup writes into this object",
    )
    output: PointerProperty(
        name="Output",
        type=bpy.types.Object,
        poll=_is_hair,
        update=_invalidate,
        description="Hair object that receives the collided curves every frame. "
        "You may add your own modifiers to it (e.g. Interpolate Hair Curves)",
    )
    enabled: BoolProperty(
        name="Enabled",
        default=True,
        update=_invalidate,
        description="Solve collisions for this hair. Off: the output simply follows "
        "the source",
    )
    show_result: BoolProperty(
        name="Show Result",
        default=True,
        update=_toggle_result,
        description="Show the collided output in the viewport (on) or the original "
        "source hair (off). Rendering always uses the output",
    )

    # ---------------------------------------------------------- colliders
    colliders: CollectionProperty(type=FurCollideCollider, name="Colliders")
    collider_index: IntProperty(name="Active Collider", default=0, min=0)
    collider_collection: PointerProperty(
        name="Collider Collection",
        type=bpy.types.Collection,
        update=_invalidate_colliders,
        description="Every mesh in this collection also collides (with the setup's "
        "Collision Offset and the option below)",
    )
    collection_double_sided: BoolProperty(
        name="Collection Double Sided",
        default=False,
        update=_invalidate_colliders,
        description="Treat the meshes of the collider collection as thin sheets "
        "that block hair from both sides",
    )

    # ---------------------------------------------------------- resolution
    mode: EnumProperty(
        name="Mode",
        items=[
            ("stiff", "Stiff", "Rotate the whole curve at its root, keeping its shape. "
             "Good for short fur"),
            ("bend", "Bend", "Bend the curve evenly from root to tip. Good for long fur "
             "and grass"),
            ("soft", "Soft", "Let each colliding segment turn on its own and drag the "
             "next ones along. Hugs tight contacts such as cloth"),
        ],
        default="bend",
        update=_invalidate,
        description="How a colliding curve is turned out of the mesh",
    )
    rotation_precision: FloatProperty(
        name="Rotation Precision",
        default=0.25,
        min=0.001,
        max=45.0,
        soft_min=0.05,
        soft_max=5.0,
        precision=3,
        update=_invalidate,
        description="Angle step (degrees) used to search the smallest turn that frees "
        "a curve. Smaller is more exact and slower",
    )
    max_angle: FloatProperty(
        name="Max Angle",
        default=180.0,
        min=0.01,
        max=360.0,
        update=_invalidate,
        description="Largest turn (degrees) a curve may take. Curves that would need "
        "more keep their last collision-free shape and are flagged unresolved",
    )
    affected_connected_cvs: IntProperty(
        name="Affected Connected CVs",
        default=2,
        min=0,
        max=10000,
        soft_max=10,
        update=_invalidate,
        description="Soft mode: how many points after a colliding segment follow its "
        "turn",
    )
    cv_falloff: FloatProperty(
        name="CV Falloff",
        default=0.5,
        min=0.0,
        max=1.0,
        subtype="FACTOR",
        update=_invalidate,
        description="Soft mode: how quickly the following points stop turning along "
        "(0 = they turn fully, 1 = only the colliding segment turns)",
    )
    attract_to_growth_surface: BoolProperty(
        name="Attract to Growth Surface",
        default=False,
        update=_invalidate,
        description="Push colliding hair down toward the skin it grows from (pats fur "
        "or grass flat) instead of away along the collider's surface. Needs the "
        "hair's Surface object",
    )
    collision_offset: FloatProperty(
        name="Collision Offset",
        default=0.0,
        min=0.0,
        soft_max=0.1,
        subtype="DISTANCE",
        unit="LENGTH",
        update=_invalidate,
        description="Gap kept between the hair and every collider (a collider may use "
        "its own)",
    )
    threads: IntProperty(
        name="Threads",
        default=0,
        min=0,
        max=1024,
        update=_invalidate,
        description="Ray-tracing threads (0 = all CPUs). The result is identical for "
        "any count",
    )

    # -------------------------------------------------------------- shrink
    shrink: BoolProperty(
        name="Shrink",
        default=False,
        update=_invalidate,
        description="Shorten colliding curves as they turn (Stiff and Bend only); "
        "reduces fur crossing at very different angles",
    )
    scale_minimum: FloatProperty(
        name="Scale Minimum",
        default=0.5,
        min=0.001,
        max=1.0,
        subtype="FACTOR",
        update=_invalidate,
        description="Shortest a curve may become (fraction of its length)",
    )
    scale_angle: FloatProperty(
        name="Scale Angle",
        default=90.0,
        min=0.01,
        max=360.0,
        update=_invalidate,
        description="Turn (degrees) at which a curve reaches Scale Minimum; it shrinks "
        "gradually up to that angle",
    )

    # ---------------------------------------------------- recovery, plasticity
    recovery_rate: FloatProperty(
        name="Recovery Rate",
        default=0.2,
        min=0.0,
        max=1.0,
        subtype="FACTOR",
        update=_invalidate,
        description="How fast freed hair springs back to its groomed shape, per frame "
        "(1 = at once, 0 = never). Recovery stops where it would collide again",
    )
    plasticity: FloatProperty(
        name="Plasticity",
        default=0.0,
        min=0.0,
        max=1.0,
        subtype="FACTOR",
        update=_invalidate,
        description="How much of the deepest push the hair keeps after contact "
        "(0 = recovers fully, 1 = keeps the imprint, like trampled grass)",
    )

    # ---------------------------------------------------------------- pinch
    pinch_resolution: EnumProperty(
        name="Pinch Resolution",
        items=[
            ("stop", "Stop Solving", "Pinched hair keeps the shape it had before the "
             "pinch (no jitter trying to solve the impossible)"),
            ("growth_surface", "Put to Growth Surface", "Lay pinched hair down onto the "
             "skin it grows from (needs the hair's Surface object)"),
        ],
        default="stop",
        update=_invalidate,
        description="What hair does when its root is trapped inside a closed collider "
        "(e.g. an arm pressed into the body)",
    )
    recover_pinched: BoolProperty(
        name="Recover Pinched Fur",
        default=True,
        update=_invalidate,
        description="Let hair recover once it is no longer pinched. Off: it keeps the "
        "shape it had when the pinch ended",
    )

    # ------------------------------------------------------ per-curve enable
    enable_attribute: StringProperty(
        name="Enable Attribute",
        default="furcollide_enable",
        update=_invalidate,
        description="Per-curve attribute (Boolean, Integer or Float) on the evaluated "
        "source: curves where it is off keep their last shape and are not solved. "
        "Paint, select or animate it with geometry nodes. Missing = all curves solved",
    )

    # ----------------------------------------------------------------- cache
    frame_start: IntProperty(
        name="Start",
        default=1,
        update=_invalidate_range,
        description="Frame where the simulation starts from the groomed shape",
    )
    frame_end: IntProperty(
        name="End",
        default=250,
        update=_invalidate_range,
        description="Last frame that is solved and baked; later frames hold it",
    )
    cache_directory: StringProperty(
        name="Cache Directory",
        default="//furcollide_cache/",
        subtype="DIR_PATH",
        description="Where bakes are written. '//' is the folder of the saved .blend "
        "file; each setup gets its own sub-folder",
    )
    memory_limit: IntProperty(
        name="Memory Limit",
        default=512,
        min=16,
        soft_max=8192,
        subtype="NONE",
        update=_set_memory_limit,
        description="Megabytes of RAM the playback cache of this setup may use. Past "
        "it, old frames are dropped (bake to keep everything)",
    )
    is_baked: BoolProperty(name="Baked", default=False, options={"HIDDEN"})
    bake_path: StringProperty(name="Bake Path", default="", options={"HIDDEN"})

    # --------------------------------------------------- read-only statistics
    stat_frame: IntProperty(name="Frame", get=_stat("frame"), description="Frame of the stats")
    stat_colliding: IntProperty(
        name="Colliding", get=_stat("colliding"), description="Curves turned out of a collider"
    )
    stat_recovering: IntProperty(
        name="Recovering", get=_stat("recovering"), description="Curves springing back"
    )
    stat_pinched: IntProperty(
        name="Pinched", get=_stat("pinched"), description="Curves whose root is trapped"
    )
    stat_unresolved: IntProperty(
        name="Unresolved",
        get=_stat("unresolved"),
        description="Curves that could not be freed within Max Angle",
    )
    stat_disabled: IntProperty(
        name="Disabled", get=_stat("disabled"), description="Curves switched off"
    )
    stat_solve_ms: FloatProperty(
        name="Solve Time",
        get=_stat("solve_ms", 0.0),
        precision=1,
        description="Milliseconds the last solved frame took",
    )
    status_message: StringProperty(
        name="Status", get=lambda self: runtime.status_for(self.id_data)[1]
    )
    is_outdated: BoolProperty(
        name="Outdated", get=lambda self: runtime.is_outdated(self.id_data)
    )

    def to_core_kwargs(self) -> dict:
        """Keyword arguments of :class:`core.Settings` for these properties."""
        return {
            "mode": self.mode,
            "rotation_precision": float(self.rotation_precision),
            "max_angle": float(self.max_angle),
            "affected_connected_cvs": int(self.affected_connected_cvs),
            "cv_falloff": float(self.cv_falloff),
            "attract_to_growth_surface": bool(self.attract_to_growth_surface),
            "shrink": bool(self.shrink),
            "scale_minimum": float(self.scale_minimum),
            "scale_angle": float(self.scale_angle),
            "recovery_rate": float(self.recovery_rate),
            "plasticity": float(self.plasticity),
            "pinch_resolution": self.pinch_resolution,
            "recover_pinched": bool(self.recover_pinched),
            "collision_offset": float(self.collision_offset),
            "threads": int(self.threads) or None,
        }


#: Names of the solver properties (presets store exactly these).
SOLVER_PROPERTIES = (
    "mode",
    "rotation_precision",
    "max_angle",
    "affected_connected_cvs",
    "cv_falloff",
    "attract_to_growth_surface",
    "collision_offset",
    "shrink",
    "scale_minimum",
    "scale_angle",
    "recovery_rate",
    "plasticity",
    "pinch_resolution",
    "recover_pinched",
)

classes = (FurCollideCollider, FurCollideSettings)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Object.furcollide = PointerProperty(type=FurCollideSettings)


def unregister():
    del bpy.types.Object.furcollide
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
