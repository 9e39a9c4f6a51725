"""View3D > Sidebar > FurCollide > Fur Pipeline: Fur Sampler, Fur Attach, wind and
jiggle, Region of Influence and Fur Collider Distance, children and the render groom."""

from bpy.types import Panel

from ..operators.fur_attach import has_binding
from ..operators.groom_stage import BIND_AGAIN, advice
from ..operators.ops_common import active_setup
from ..operators.ops_sampler import NO_SURFACE_HAIR
from .panel import FURCOLLIDE_PT_main


def draw_attach(layout, src):
    """Fur Attach: the setup's optional input stage."""
    s = src.furcollide
    box = layout.box()
    box.label(text="Fur Attach (Input)", icon="SNAP_FACE")
    col = box.column()
    col.enabled = not s.is_baked  # a baked setup only reads its bake
    has_surface = src.data.surface is not None and src.data.surface.type == "MESH"
    bound = has_binding(src)
    row = col.row()
    row.enabled = bound or s.use_fur_attach
    row.prop(s, "use_fur_attach")
    col.prop(s, "attach_reference_frame")
    row = col.row(align=True)
    row.enabled = has_surface and not s.is_baked
    row.operator("furcollide.fur_attach_bind", icon="LINKED")
    sub = row.row(align=True)
    sub.enabled = bound or s.use_fur_attach
    sub.operator("furcollide.fur_attach_unbind", icon="UNLINKED")
    if not has_surface:
        col.label(text="Fur Attach needs the source's Surface", icon="INFO")
    elif not bound:
        col.label(text="Not bound: press Bind", icon="INFO")


def draw_motion(layout, src):
    """Wind and jiggle, before or after collision."""
    m = src.furcollide.motion
    box = layout.box()
    box.label(text="Wind & Jiggle", icon="FORCE_WIND")
    col = box.column()
    col.enabled = not src.furcollide.is_baked
    col.prop(m, "use_wind")
    sub = col.column()
    sub.enabled = m.use_wind
    for name in ("wind_stage", "wind_direction", "wind_strength", "wind_frequency",
                 "wind_turbulence", "wind_falloff", "wind_scale", "wind_seed"):
        sub.prop(m, name)
    col.separator()
    col.prop(m, "use_jiggle")
    sub = col.column()
    sub.enabled = m.use_jiggle
    for name in ("jiggle_stage", "jiggle_stiffness", "jiggle_damping", "jiggle_amount",
                 "jiggle_falloff"):
        sub.prop(m, name)


def draw_influence(layout, src):
    """Region of Influence and the per-frame Fur Collider Distance attribute."""
    m = src.furcollide.motion
    box = layout.box()
    box.label(text="Region of Influence", icon="DRIVER_DISTANCE")
    col = box.column()
    col.enabled = not src.furcollide.is_baked
    after = (m.use_wind and m.wind_stage == "OUTPUT") or (
        m.use_jiggle and m.jiggle_stage == "OUTPUT")
    col.prop(m, "use_region_of_influence")
    sub = col.column()
    sub.enabled = m.use_region_of_influence
    sub.prop(m, "roi_margin")
    if not after:
        col.label(text="Restricts motion After Collision (none is on)", icon="INFO")
    elif not m.use_region_of_influence:
        col.label(text="Motion after collision may push hair into colliders", icon="ERROR")
    col.separator()
    col.prop(m, "write_collider_distance")
    sub = col.column()
    sub.enabled = m.write_collider_distance
    sub.prop(m, "distance_max")
    col.operator("furcollide.collider_distance", text="Collider Distance Now",
                 icon="DRIVER_DISTANCE")


def draw_groom(layout, src):
    """A dense render groom following the collided guides, with its clearance pass."""
    s = src.furcollide
    g = s.groom
    box = layout.box()
    box.label(text="Render Groom", icon="OUTLINER_OB_CURVES")
    col = box.column()
    settings = col.column()
    settings.enabled = not g.is_baked_with  # the bake holds this render groom
    settings.prop(g, "groom")
    settings.prop(g, "guides")
    if g.output is not None and g.bound_guides and g.guides != g.bound_guides:
        col.label(text=advice(src, f"Bound with {g.bound_guides}: {BIND_AGAIN}"), icon="INFO")
    settings.prop(g, "use_clearance")
    row = col.row(align=True)
    sub = row.row(align=True)
    sub.enabled = not g.is_baked_with
    sub.operator("furcollide.groom_bind", icon="LINKED")
    sub = row.row(align=True)
    sub.enabled = g.output is not None
    sub.operator("furcollide.groom_remove", text="", icon="X")
    if g.output is None:
        return
    col.label(text=f"Output: {g.output.name}", icon="OUTLINER_DATA_CURVES")
    if g.is_baked_with:
        col.label(text="Baked with the setup (Free Bake to change it)", icon="FILE_CACHE")
    if g.use_clearance:
        col.label(text=f"Render curves fixed: {g.stat_fixed}", icon="CHECKMARK")
        if g.stat_unresolved:
            col.label(text=f"Unresolved (red): {g.stat_unresolved}", icon="ERROR")
    if g.stat_invalid:
        col.label(text=f"Invalid (yellow): {g.stat_invalid}", icon="ERROR")


#: What the Children from Guides box says about collisions: the children are made by
#: Blender's node group from the collided guides, so nothing clears them.
CHILDREN_NOT_CLEARED = (
    "Children are not collided: between guides they can cross a collider.",
    "For renders with no crossing, use a Render Groom (Bind Groom below):",
    "it gets a clearance pass.",
)


class FURCOLLIDE_PT_pipeline(Panel):
    """Fur pipeline around FurCollide: guides from a groom, collider distance, children."""

    bl_label = "Fur Pipeline"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "FurCollide"
    bl_parent_id = FURCOLLIDE_PT_main.__name__
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        ob = context.object
        return ob is not None and ob.type == "CURVES"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = True  # keyframe decorators: stages can be keyed
        s = context.scene.furcollide_pipeline
        ob = context.object

        box = layout.box()
        box.label(text="Guides from Groom", icon="CURVES_DATA")
        col = box.column()
        col.prop(s, "fraction")
        col.prop(s, "seed")
        col.prop(s, "use_selection")
        surf = ob.data.surface
        if surf is not None and surf.type == "MESH":
            col.prop_search(s, "area", surf, "vertex_groups")
        else:
            col.prop(s, "area")
        row = col.row()
        row.enabled = ob.data.surface is not None
        op = row.operator("furcollide.fur_sampler", icon="PARTICLE_POINT")
        op.fraction, op.seed, op.use_selection = s.fraction, s.seed, s.use_selection
        op.area = s.area
        if ob.data.surface is None:
            col.label(text=NO_SURFACE_HAIR, icon="INFO")

        src = active_setup(context)
        if src is None:
            box = layout.box()
            box.label(text="Collided Output", icon="MOD_PHYSICS")
            box.column().label(text="Needs a FurCollide setup", icon="INFO")
            return
        draw_attach(layout, src)
        draw_motion(layout, src)
        draw_influence(layout, src)

        box = layout.box()
        box.label(text="Children from Guides", icon="MOD_PHYSICS")
        col = box.column()
        col.prop(s, "density")
        col.prop(s, "guides")
        row = col.row()
        row.enabled = src.data.surface is not None
        op = row.operator("furcollide.children_from_guides", icon="OUTLINER_DATA_CURVES")
        op.density, op.guides = s.density, s.guides
        if src.data.surface is None:
            col.label(text="Children need the source's Surface", icon="INFO")
        for i, line in enumerate(CHILDREN_NOT_CLEARED):
            col.label(text=line, icon="ERROR" if i == 0 else "BLANK1")
        draw_groom(layout, src)


classes = (FURCOLLIDE_PT_pipeline,)
