"""Settings of a setup's fur pipeline stages: wind, jiggle, the Region of Influence and
the collider distance attribute (:class:`FurCollideMotion`, ``furcollide.motion``), the
render groom (:class:`FurCollideGroom`, ``furcollide.groom``) and the children cleared
live (:class:`FurCollideChildren`, ``furcollide.children``). Registered with the setup's
own settings (:mod:`.properties`)."""

import bpy
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)
from bpy.types import PropertyGroup

from .property_helpers import (
    NOT_ANIMATABLE,
    fixed,
    hidden,
    poll_hair,
    stat,
    update_children,
    update_children_viewport,
    update_groom,
    update_motion,
)

_STAGES = [
    ("INPUT", "Before Collision", "Move the input curves; FurCollide then resolves the "
     "moved curves (strong wind bends hair around the colliders)"),
    ("OUTPUT", "After Collision", "Move the collided curves, restricted by the Region of "
     "Influence so they stay collision free (gentle motion on top of the result)"),
]


def _stage(what):
    return EnumProperty(
        name="Stage", items=_STAGES, default="OUTPUT", update=update_motion,
        description=f"When the {what} is applied: before FurCollide (its input) or after it",
    )


def _motion_float(name, default, description, **kw):
    return FloatProperty(name=name, default=default, update=update_motion,
                         description=description, **kw)


class FurCollideMotion(PropertyGroup):
    """Wind, jiggle (secondary motion) and the Region of Influence of a setup
    (paper section 4; core.pipeline.wind / jiggle / region_of_influence)."""

    use_wind: BoolProperty(
        name="Wind", default=False, update=update_motion,
        description="Procedural wind: a steady push with gusts and turbulence from "
        "coherent noise, growing from root to tip. The same frame always gives the same "
        "wind, so scrubbing repeats",
    )
    wind_stage: _stage("wind")
    wind_direction: FloatVectorProperty(
        name="Direction", default=(1.0, 0.0, 0.0), size=3, subtype="XYZ",
        update=update_motion,
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
        name="Seed", default=0, min=0, update=update_motion,
        description="Noise seed: another value gives other gusts",
    )

    use_jiggle: BoolProperty(
        name="Jiggle", default=False, update=update_motion,
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
        name="Region of Influence", default=True, update=update_motion,
        description="Restrict motion applied after collision, per point, to less than its "
        "Fur Collider Distance, so collided curves stay collision free even in extreme "
        "wind. Off: after-collision motion may push hair into colliders",
    )
    roi_margin: _motion_float(
        "Margin", 0.99, "Fraction of its collider distance a point may travel "
        "(below 1 keeps a gap to the mesh)", min=0.01, max=1.0, subtype="FACTOR",
    )
    write_collider_distance: BoolProperty(
        name="Collider Distance Attribute", default=False, update=update_motion,
        description="Every frame, store on the output the per-point attribute "
        "furcollide_collider_distance: the closest distance of each point's segments to "
        "the colliders (before motion after collision), for geometry nodes and shaders",
    )
    distance_max: _motion_float(
        "Max Distance", 0.0, "Distances beyond this are stored as this value, which is "
        "much faster (0 = no cap). Every stored distance is a lower bound of the true one, "
        "a few cells of the collider's distance field at most", min=0.0, soft_max=1.0,
        subtype="DISTANCE",
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
        name="Groom",
        type=bpy.types.Object,
        poll=poll_hair,
        update=update_groom,
        description="Dense hair that follows the collided guides (the FurCollide output): "
        "press Bind Groom at the reference pose. It is never modified",
    )
    output: PointerProperty(
        name="Groom Output",
        type=bpy.types.Object,
        poll=poll_hair,
        description="Hair object FurCollide writes the deformed render groom into every "
        "frame (created by Bind Groom)",
    )
    guides: IntProperty(
        name="Guides per Curve", default=4, min=1, max=32, update=update_groom,
        options=NOT_ANIMATABLE,
        description=fixed("How many nearest guides (by root, at the reference pose) each "
                          "render curve blends. Press Bind Groom again after changing it",
                          "Bind Groom reads it once"),
    )
    use_clearance: BoolProperty(
        name="Clearance Pass", default=True, update=update_groom,
        description="Resolve render curves that still pass through a collider after the "
        "guide deform (FurCollide's minimal Stiff rotation, Bend where turning cannot "
        "free a curve; a fresh solve per frame); the counts are shown below",
    )
    bind_id: hidden(StringProperty, "Groom Bind ID", "")
    bound_guides: hidden(IntProperty, "Bound Guides per Curve", 0)
    #: The Bind ID of the render groom the setup's bake holds ('' when none).
    baked_id: hidden(StringProperty, "Baked Groom Bind ID", "")

    stat_fixed: stat(
        "Render Curves Fixed", "groom_fixed",
        "Render curves the clearance pass moved out of a collider on the last frame",
    )
    stat_unresolved: stat(
        "Render Curves Unresolved", "groom_unresolved",
        "Render curves the clearance pass could not free on the last frame (red in the "
        "groom output)",
    )
    stat_invalid: stat(
        "Render Curves Invalid", "groom_invalid",
        "Render curves FurCollide cannot solve (a zero-length segment, a NaN point): shown "
        "as they are, in yellow",
    )

    @property
    def is_baked_with(self) -> bool:
        """Does the setup's bake hold this render groom (its settings are the bake's)?"""
        src = self.id_data
        return bool(src.furcollide.is_baked and self.bind_id and self.baked_id == self.bind_id)


class FurCollideChildren(PropertyGroup):
    """The output's own children stack, cleared of the colliders every frame
    (:mod:`..frame.children`)."""

    use_children: BoolProperty(
        name="Clear Children", default=True, update=update_children,
        description="When the output carries Geometry Nodes modifiers (Children from "
        "Guides, Interpolate, Clump, Frizz...), render their result with the clearance "
        "pass every frame, in a children output FurCollide makes (the output itself is "
        "then kept out of renders). Off: the output renders its modifiers as they are, "
        "children crossing the colliders",
    )
    use_viewport: BoolProperty(
        name="Clear in Viewport", default=True, update=update_children_viewport,
        description="Run the clearance pass on the children in the viewport too. Off: "
        "faster playback, the children shown as the stack makes them; renders and bakes "
        "always clear them",
    )
    output: PointerProperty(
        name="Children Output", type=bpy.types.Object, poll=poll_hair,
        description="Hair object FurCollide writes the cleared children into every frame "
        "(made when the output carries modifiers)",
    )
    stat_children: stat("Children", "children", "Children the output's stack made on the "
                         "last frame")
    stat_fixed: stat("Children Fixed", "children_fixed",
                     "Children the clearance pass turned out of a collider on the last frame")
    stat_unresolved: stat("Children Unresolved", "children_unresolved",
                          "Children the clearance pass could not free (red)")
    stat_invalid: stat("Children Invalid", "children_invalid",
                       "Children FurCollide cannot solve (a zero-length segment, fewer "
                       "than 2 points): shown as they are, in yellow")
