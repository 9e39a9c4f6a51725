"""FurCollide settings stored on the source hair object (``Object.furcollide``).

Solver fields mirror :class:`core.Settings` (same names, same defaults);
the rest describes the setup: colliders, per-curve enable attribute, the
output object, the cache. Every property that changes the result
invalidates the cached frames after the current one (``update=``).
Read-only statistics are computed properties (``get=``) served by the
runtime registry, so the frame handler never writes RNA data on the source.
"""

import functools

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)
from bpy.types import PropertyGroup

from . import bridge, runtime

# ------------------------------------------------------------------ updates
# Update callbacks run inside Blender's UI: like the frame handler, they never
# raise (a failure is one console line; the next frame re-checks everything).


def _never_raises(update):
    @functools.wraps(update)
    def wrapper(self, context):
        try:
            update(self, context)
        except Exception as exc:  # noqa: BLE001
            print(f"FurCollide: {update.__name__.strip('_')} failed: {runtime.describe(exc)}")

    return wrapper


@_never_raises
def _invalidate(self, context):
    runtime.invalidate(self.id_data, reason="settings changed")


@_never_raises
def _invalidate_colliders(self, context):
    runtime.invalidate(self.id_data, reason="colliders changed", colliders=True)


@_never_raises
def _invalidate_range(self, context):
    ob = self.id_data
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


def _invalidate_every_frame(reason):
    """An update that drops every cached frame: for changes of every frame's input
    (Fur Attach, motion before collision) or output (motion after collision). The
    memory cache stores only the curves that differ from the input, so earlier frames
    would mix old results with the new input."""

    @_never_raises
    def update(self, context):
        ob = self.id_data
        runtime.invalidate(ob, reason=reason, from_frame=ob.furcollide.frame_start - 1)

    return update


_invalidate_attach = _invalidate_every_frame("Fur Attach changed")
_invalidate_all = _invalidate_every_frame("motion changed")


@_never_raises
def _set_memory_limit(self, context):
    rt = runtime.get_runtime(self.id_data, create=False)
    if rt is not None:
        rt.memory.limit = int(self.memory_limit * 1024 * 1024)


@_never_raises
def _toggle_result(self, context):
    runtime.apply_visibility(self.id_data)


def _is_collider_type(self, ob):
    return bridge.is_collider_type(ob) or runtime.instanced_collection(ob) is not None


def _is_hair(self, ob):
    return ob.type == "CURVES"


# ------------------------------------------------------ property factories
# The solver settings share a few shapes; each factory fixes the shape and
# leaves the name, default and the artist-facing tooltip to the call.


def _toggle(name, default, description, update=_invalidate):
    return BoolProperty(name=name, default=default, update=update, description=description)


def _factor(name, default, description):
    """A 0..1 slider."""
    return FloatProperty(
        name=name, default=default, min=0.0, max=1.0, subtype="FACTOR",
        update=_invalidate, description=description,
    )


def _degrees(name, default, description, **limits):
    """An angle in degrees (the unit of :class:`core.Settings`)."""
    limits = {"min": 0.01, "max": 360.0, **limits}
    return FloatProperty(
        name=name, default=default, update=_invalidate, description=description, **limits
    )


def _offset(description, update):
    """A collision offset (world distance)."""
    return FloatProperty(
        name="Collision Offset", default=0.0, min=0.0, soft_max=0.1, subtype="DISTANCE",
        unit="LENGTH", update=update, description=description,
    )


def _choice(name, items, default, description):
    """One of a few named behaviours (``items``: identifier, label, tooltip)."""
    return EnumProperty(
        name=name, items=items, default=default, update=_invalidate, description=description
    )


def _hidden(prop, name, default):
    """Internal bookkeeping, never drawn."""
    return prop(name=name, default=default, options={"HIDDEN"},
                description=f"{name} (set by FurCollide, not meant to be edited)")


def _stat(name, key, description, prop=IntProperty, **kw):
    """A read-only statistic of the last frame, served by the runtime registry."""
    default = 0.0 if prop is FloatProperty else 0

    def get(self):
        return runtime.stats_for(self.id_data).get(key, default)

    return prop(name=name, get=get, description=description, **kw)


# ----------------------------------------------------------------- groups
class FurCollideCollider(PropertyGroup):
    """One collision mesh of a FurCollide setup."""

    object: PointerProperty(
        name="Collider",
        type=bpy.types.Object,
        poll=_is_collider_type,
        update=_invalidate_colliders,
        description="Mesh the hair must not pass through (or a curve with a bevel, such "
        "as a rope, a surface, text or a metaball; or a collection instance, such as a "
        "linked asset: every such object in it collides). Its evaluated shape is used "
        "every frame, so armatures, shape keys, modifiers and cloth all count",
    )
    enabled: _toggle(
        "Enabled", True,
        "Collide with this mesh. Turn off to let the hair pass through it",
        update=_invalidate_colliders,
    )
    double_sided: _toggle(
        "Double Sided", False,
        "Treat the mesh as a thin sheet that blocks hair from both sides (cloth, leaves). "
        "Off: a closed body with an inside; hair rooted inside it counts as pinched",
        update=_invalidate_colliders,
    )
    use_offset: _toggle(
        "Own Offset", False,
        "Use this collider's own Collision Offset instead of the setup's",
        update=_invalidate_colliders,
    )
    collision_offset: _offset(
        "Gap kept between the hair and this mesh (needs Own Offset)", _invalidate_colliders
    )


@_never_raises
def _groom_changed(self, context):
    runtime.refresh_groom(self.id_data)


_STAGES = [
    ("INPUT", "Before Collision", "Move the input curves; FurCollide then resolves the "
     "moved curves (strong wind bends hair around the colliders)"),
    ("OUTPUT", "After Collision", "Move the collided curves, restricted by the Region of "
     "Influence so they stay collision free (gentle motion on top of the result)"),
]


def _stage(what):
    return EnumProperty(
        name="Stage", items=_STAGES, default="OUTPUT", update=_invalidate_all,
        description=f"When the {what} is applied: before FurCollide (its input) or after it",
    )


def _motion_float(name, default, description, **kw):
    return FloatProperty(name=name, default=default, update=_invalidate_all,
                         description=description, **kw)


class FurCollideMotion(PropertyGroup):
    """Wind, jiggle (secondary motion) and the Region of Influence of a setup
    (paper section 4; core.pipeline.wind / jiggle / region_of_influence)."""

    use_wind: BoolProperty(
        name="Wind", default=False, update=_invalidate_all,
        description="Procedural wind: a steady push with gusts and turbulence from "
        "coherent noise, growing from root to tip. The same frame always gives the same "
        "wind, so scrubbing repeats",
    )
    wind_stage: _stage("wind")
    wind_direction: FloatVectorProperty(
        name="Direction", default=(1.0, 0.0, 0.0), size=3, subtype="XYZ",
        update=_invalidate_all,
        description="World direction the wind blows to (normalized; zero = turbulence only)",
    )
    wind_strength: _motion_float(
        "Strength", 0.05, "How far the wind pushes the tips (world units)",
        min=0.0, soft_max=1.0, subtype="DISTANCE", unit="LENGTH",
    )
    wind_frequency: _motion_float(
        "Frequency", 0.5, "How often gusts come, per second (Hz)", min=0.0, soft_max=5.0,
    )
    wind_turbulence: _motion_float(
        "Turbulence", 0.5, "Amount of gusts and side-to-side flutter (0 = steady push)",
        min=0.0, soft_max=2.0,
    )
    wind_falloff: _motion_float(
        "Falloff", 1.5, "Root-to-tip ramp exponent (1 = linear, larger = only the tips "
        "move)", min=0.0, soft_max=4.0,
    )
    wind_scale: _motion_float(
        "Gust Size", 1.0, "Size of the gust patterns (world units): smaller = neighbouring "
        "curves move more differently", min=1e-4, soft_max=10.0, subtype="DISTANCE",
        unit="LENGTH",
    )
    wind_seed: IntProperty(
        name="Seed", default=0, min=0, update=_invalidate_all,
        description="Noise seed: another value gives other gusts",
    )

    use_jiggle: BoolProperty(
        name="Jiggle", default=False, update=_invalidate_all,
        description="Secondary motion: curves lag and overshoot when the growth surface "
        "accelerates (a damped spring driven by each root's acceleration over the last "
        "frames). Play from the start frame so the history is known",
    )
    jiggle_stage: _stage("jiggle")
    jiggle_stiffness: _motion_float(
        "Stiffness", 2.0, "Natural frequency of the spring (Hz): higher = stiffer, faster",
        min=0.01, soft_max=10.0,
    )
    jiggle_damping: _motion_float(
        "Damping", 0.3, "Damping ratio (0 = oscillates on and on, 1 = no overshoot)",
        min=0.0, soft_max=2.0,
    )
    jiggle_amount: _motion_float(
        "Amount", 1.0, "Multiplier of the jiggle (0 = none)", min=0.0, soft_max=5.0,
    )
    jiggle_falloff: _motion_float(
        "Falloff", 1.0, "Root-to-tip ramp exponent (1 = linear, larger = only the tips "
        "move)", min=0.0, soft_max=4.0,
    )

    use_region_of_influence: BoolProperty(
        name="Region of Influence", default=True, update=_invalidate_all,
        description="Restrict motion applied after collision, per point, to less than its "
        "Fur Collider Distance, so collided curves stay collision free even in extreme "
        "wind. Off: after-collision motion may push hair into colliders",
    )
    roi_margin: _motion_float(
        "Margin", 0.99, "Fraction of its collider distance a point may travel "
        "(below 1 keeps a gap to the mesh)", min=0.01, max=1.0, subtype="FACTOR",
    )
    write_collider_distance: BoolProperty(
        name="Collider Distance Attribute", default=False, update=_invalidate_all,
        description="Every frame, store on the output the per-point attribute "
        "furcollide_collider_distance: the closest distance of each point's segments to "
        "the colliders (before motion after collision), for geometry nodes and shaders",
    )
    distance_max: _motion_float(
        "Max Distance", 0.0, "Distances beyond this are stored as this value, which is "
        "much faster (0 = exact everywhere)", min=0.0, soft_max=1.0, subtype="DISTANCE",
        unit="LENGTH",
    )

    @property
    def active(self) -> bool:
        """Does any stage of this group change the curves or write the attribute?"""
        return bool(self.use_wind or self.use_jiggle or self.write_collider_distance)

    def fingerprint(self) -> dict:
        """Every value that changes the result (for the setup's signature)."""
        return {
            k: (list(getattr(self, k)) if k == "wind_direction" else getattr(self, k))
            for k in MOTION_FIELDS
        }


#: Property names of :class:`FurCollideMotion` (read before registration moves them).
MOTION_FIELDS = tuple(FurCollideMotion.__annotations__)


class FurCollideGroom(PropertyGroup):
    """Guide deform of an existing render groom (paper section 2) and its clearance pass."""

    groom: PointerProperty(
        name="Render Groom",
        type=bpy.types.Object,
        poll=_is_hair,
        description="Dense hair that follows the collided guides (the FurCollide output): "
        "press Bind Groom at the reference pose. It is never modified",
    )
    output: PointerProperty(
        name="Groom Output",
        type=bpy.types.Object,
        poll=_is_hair,
        description="Hair object FurCollide writes the deformed render groom into every "
        "frame (created by Bind Groom)",
    )
    guides: IntProperty(
        name="Guides per Curve", default=4, min=1, max=32,
        description="How many nearest guides (by root, at the reference pose) each render "
        "curve blends. Press Bind Groom again after changing it",
    )
    use_clearance: BoolProperty(
        name="Clearance Pass", default=True, update=_groom_changed,
        description="Resolve render curves that still pass through a collider after the "
        "guide deform (FurCollide's minimal Stiff rotation, a fresh solve per frame); the "
        "count is shown below",
    )
    bind_id: _hidden(StringProperty, "Groom Bind ID", "")
    bound_guides: _hidden(IntProperty, "Bound Guides per Curve", 0)


class FurCollideSettings(PropertyGroup):
    """A FurCollide setup on a source hair object (or the link on its output)."""

    # ---------------------------------------------------------- identity
    is_setup: _hidden(BoolProperty, "Is Setup", False)
    is_output: _hidden(BoolProperty, "Is Output", False)
    uid: _hidden(StringProperty, "Setup ID", "")
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
    enabled: _toggle(
        "Enabled", True,
        "Solve collisions for this hair. Off: the output simply follows the source",
    )
    show_result: _toggle(
        "Show Result", True,
        "Show the collided output in the viewport (on) or the original source hair (off). "
        "Rendering always uses the output",
        update=_toggle_result,
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
        name="Collider Collection",
        type=bpy.types.Collection,
        update=_invalidate_colliders,
        description="Every mesh in this collection (and every curve with a bevel, surface, "
        "text or metaball) also collides, with the setup's Collision Offset and the option "
        "below",
    )
    collection_double_sided: _toggle(
        "Collection Double Sided", False,
        "Treat the meshes of the collider collection as thin sheets that block hair from "
        "both sides",
        update=_invalidate_colliders,
    )

    # ---------------------------------------------------------- resolution
    mode: _choice(
        "Mode",
        [
            ("stiff", "Stiff", "Rotate the whole curve at its root, keeping its shape. "
             "Good for short fur"),
            ("bend", "Bend", "Bend the curve evenly from root to tip. Good for long fur "
             "and grass"),
            ("soft", "Soft", "Let each colliding segment turn on its own and drag the "
             "next ones along. Hugs tight contacts such as cloth"),
        ],
        "bend",
        "How a colliding curve is turned out of the mesh",
    )
    rotation_precision: _degrees(
        "Rotation Precision", 0.25,
        "Angle step (degrees) used to search the smallest turn that frees a curve. "
        "Smaller is more exact and slower",
        min=0.001, max=45.0, soft_min=0.05, soft_max=5.0, precision=3,
    )
    max_angle: _degrees(
        "Max Angle", 180.0,
        "Largest turn (degrees) a curve may take. Curves that would need more keep their "
        "last collision-free shape and are flagged unresolved",
    )
    affected_connected_cvs: IntProperty(
        name="Affected Connected CVs",
        default=2,
        min=0,
        max=10000,
        soft_max=10,
        update=_invalidate,
        description="Soft mode: how many points after a colliding segment follow its turn",
    )
    cv_falloff: _factor(
        "CV Falloff", 0.5,
        "Soft mode: how quickly the following points stop turning along "
        "(0 = they turn fully, 1 = only the colliding segment turns)",
    )
    attract_to_growth_surface: _toggle(
        "Attract to Growth Surface", False,
        "Push colliding hair down toward the skin it grows from (pats fur or grass flat) "
        "instead of away along the collider's surface. Needs the hair's Surface object",
    )
    collision_offset: _offset(
        "Gap kept between the hair and every collider (a collider may use its own)",
        _invalidate,
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
    shrink: _toggle(
        "Shrink", False,
        "Shorten colliding curves as they turn (Stiff and Bend only); reduces fur "
        "crossing at very different angles",
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
    scale_angle: _degrees(
        "Scale Angle", 90.0,
        "Turn (degrees) at which a curve reaches Scale Minimum; it shrinks gradually up "
        "to that angle",
    )

    # ---------------------------------------------------- recovery, plasticity
    recovery_rate: _factor(
        "Recovery Rate", 0.2,
        "How fast freed hair springs back to its groomed shape, per frame "
        "(1 = at once, 0 = never). Recovery stops where it would collide again",
    )
    plasticity: _factor(
        "Plasticity", 0.0,
        "How much of the deepest push the hair keeps after contact "
        "(0 = recovers fully, 1 = keeps the imprint, like trampled grass)",
    )

    # ---------------------------------------------------------------- pinch
    pinch_resolution: _choice(
        "Pinch Resolution",
        [
            ("stop", "Stop Solving", "Pinched hair keeps the shape it had before the "
             "pinch (no jitter trying to solve the impossible)"),
            ("growth_surface", "Put to Growth Surface", "Lay pinched hair down onto the "
             "skin it grows from (needs the hair's Surface object)"),
        ],
        "stop",
        "What hair does when its root is trapped inside a closed collider "
        "(e.g. an arm pressed into the body)",
    )
    recover_pinched: _toggle(
        "Recover Pinched Fur", True,
        "Let hair recover once it is no longer pinched. Off: it keeps the shape it had "
        "when the pinch ended",
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
    is_baked: _hidden(BoolProperty, "Baked", False)

    # ------------------------------------------------------------ Fur Attach
    use_fur_attach: _toggle(
        "Fur Attach", False,
        "Move the source's curves rigidly with the evaluated growth surface from the "
        "reference frame, instead of using the source's own animation (press Bind first)",
        update=_invalidate_attach,
    )
    attach_reference_frame: IntProperty(
        name="Reference Frame",
        default=1,
        description="Frame whose surface and curves Bind uses: each curve is tied to the "
        "surface triangle under its root there. Press Bind again after changing it",
    )
    attach_id: _hidden(StringProperty, "Attach ID", "")

    # ---------------------------------------- wind, jiggle, render groom
    motion: PointerProperty(
        type=FurCollideMotion, name="Motion",
        description="Wind, jiggle, Region of Influence and the collider distance attribute",
    )
    groom: PointerProperty(
        type=FurCollideGroom, name="Render Groom",
        description="A dense render groom that follows the collided guides",
    )
    bake_path: _hidden(StringProperty, "Bake Path", "")

    # --------------------------------------------------- read-only statistics
    stat_frame: _stat("Frame", "frame", "Frame the statistics below belong to")
    stat_colliding: _stat("Colliding", "colliding", "Curves turned out of a collider")
    stat_recovering: _stat("Recovering", "recovering", "Curves springing back to their groom")
    stat_pinched: _stat("Pinched", "pinched", "Curves whose root is trapped inside a collider")
    stat_unresolved: _stat(
        "Unresolved", "unresolved", "Curves that could not be freed within Max Angle"
    )
    stat_disabled: _stat("Disabled", "disabled", "Curves switched off by the enable attribute")
    stat_groom_fixed: _stat(
        "Render Curves Fixed", "groom_fixed",
        "Render groom curves the clearance pass moved out of a collider on the last frame",
    )
    stat_solve_ms: _stat(
        "Solve Time", "solve_ms", "Milliseconds the last solved frame took",
        prop=FloatProperty, precision=1,
    )
    status_message: StringProperty(
        name="Status",
        get=lambda self: runtime.status_for(self.id_data)[1],
        description="What FurCollide did on the last frame, or what went wrong",
    )
    is_outdated: BoolProperty(
        name="Outdated",
        get=lambda self: runtime.is_outdated(self.id_data),
        description="The shown frame could not be solved from the previous one: play from "
        "the start frame or bake",
    )

    def to_core_kwargs(self) -> dict:
        """Keyword arguments of :class:`core.Settings` for these properties."""
        kw = {name: getattr(self, name) for name in SOLVER_PROPERTIES}
        kw["threads"] = self.threads or None
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
    "shrink",
    "scale_minimum",
    "scale_angle",
    "recovery_rate",
    "plasticity",
    "pinch_resolution",
    "recover_pinched",
    "collision_offset",
)

classes = (FurCollideCollider, FurCollideMotion, FurCollideGroom, FurCollideSettings)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Object.furcollide = PointerProperty(type=FurCollideSettings)


def unregister():
    del bpy.types.Object.furcollide
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
