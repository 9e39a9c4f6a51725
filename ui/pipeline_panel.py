"""View3D > Sidebar > FurCollide > Fur Pipeline: Fur Sampler, Fur Attach, wind and
jiggle, Region of Influence and Fur Collider Distance, the children (cleared live) and
the render groom."""

from bpy.types import Panel

from ..operators.frame.attach import has_binding
from ..operators.frame.children import owns_children, stack_modifiers
from ..operators.frame.groom import BIND_AGAIN, advice
from ..operators.ops.common import active_setup
from ..operators.ops.sampler import NO_SURFACE_HAIR
from .panel import FURCOLLIDE_PT_main
from .text import note


def draw_attach(layout, context, src):
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
        note(col, context, "Fur Attach needs the source's Surface", box=True)
    elif not bound:
        note(col, context, "Not bound: press Bind", box=True)


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


def _titled(layout, owner, name, enabled=True):
    """A box whose title is the checkbox ``owner.name`` (the setting's whole name, as a
    panel header's checkbox) with its keyframe decorator; returns its column."""
    box = layout.box()
    row = box.row()
    row.use_property_split = False
    row.enabled = enabled
    row.prop(owner, name)
    row.prop_decorator(owner, name)
    col = box.column()
    col.enabled = enabled
    return col


def draw_influence(layout, context, src):
    """Region of Influence, and the per-frame Collider Distance attribute."""
    m = src.furcollide.motion
    editable = not src.furcollide.is_baked
    col = _titled(layout, m, "use_region_of_influence", editable)
    after = (m.use_wind and m.wind_stage == "OUTPUT") or (
        m.use_jiggle and m.jiggle_stage == "OUTPUT")
    sub = col.column()
    sub.enabled = m.use_region_of_influence
    sub.prop(m, "roi_margin")
    if not after:
        note(col, context, "Restricts motion After Collision (none is on)", box=True)
    elif not m.use_region_of_influence:
        note(col, context, "Motion after collision may push hair into colliders",
             icon="ERROR", box=True)
    col = _titled(layout, m, "write_collider_distance", editable)
    sub = col.column()
    sub.enabled = m.write_collider_distance
    sub.prop(m, "distance_max")
    col.operator("furcollide.collider_distance", text="Collider Distance Now",
                 icon="DRIVER_DISTANCE")


def draw_groom(layout, context, src):
    """A dense render groom following the collided guides, with its clearance pass."""
    s = src.furcollide
    g = s.groom
    box = layout.box()
    box.label(text="Render Groom", icon="OUTLINER_OB_CURVES")
    col = box.column()
    settings = col.column()
    settings.enabled = not g.is_baked_with  # the bake holds this render groom
    settings.prop(g, "groom")
    row = settings.row()
    row.use_property_split = False  # (its whole name: it is not animatable, no key dot)
    row.prop(g, "guides")
    if g.output is not None and g.bound_guides and g.guides != g.bound_guides:
        note(col, context, advice(src, f"Bound with {g.bound_guides}: {BIND_AGAIN}"),
             box=True)
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
    note(col, context, f"Output: {g.output.name}", icon="OUTLINER_DATA_CURVES", box=True)
    if g.is_baked_with:
        note(col, context, "Baked with the setup (Free Bake to change it)", icon="FILE_CACHE",
             box=True)
    if g.use_clearance:
        col.label(text=f"Render curves fixed: {g.stat_fixed}", icon="CHECKMARK")
        if g.stat_unresolved:
            col.label(text=f"Unresolved (red): {g.stat_unresolved}", icon="ERROR")
    if g.stat_invalid:
        col.label(text=f"Invalid (yellow): {g.stat_invalid}", icon="ERROR")


#: How the children relate to the Render Groom (the Children box says it).
CHILDREN_AND_GROOM = (
    "Children are made from the collided guides by the output's modifiers every frame; a "
    "Render Groom (below) is your own dense groom bound to the guides. Both get the same "
    "clearance pass."
)


def draw_children(layout, context, src, settings):
    """Children: the output's own Geometry Nodes stack, cleared live into the children
    output (Children from Guides adds Blender's Interpolate Hair Curves to it)."""
    s = src.furcollide
    c = s.children
    box = layout.box()
    box.label(text="Children", icon="OUTLINER_DATA_CURVES")
    col = box.column()
    inputs = col.column(align=True)
    inputs.use_property_split = False  # (Children from Guides' inputs: never keyed)
    inputs.prop(settings, "density")
    inputs.prop(settings, "guides")
    row = col.row()
    row.enabled = src.data.surface is not None
    op = row.operator("furcollide.children_from_guides", icon="OUTLINER_DATA_CURVES")
    op.density, op.guides = settings.density, settings.guides
    if src.data.surface is None:
        note(col, context, "Children need the source's Surface", box=True)
    col.prop(c, "use_children")
    sub = col.column()
    sub.enabled = c.use_children
    sub.prop(c, "use_viewport")
    stack = stack_modifiers(s.output)
    if not stack:
        note(col, context, "No modifiers on the output make children", box=True)
    elif not c.use_children:
        note(col, context, "Children are not cleared: they can cross a collider",
             icon="ERROR", box=True)
    elif not owns_children(src):
        note(col, context, "Not cleared yet: play a frame, or", icon="ERROR", box=True)
        col.operator("furcollide.children_output", icon="OUTLINER_DATA_CURVES")
    else:
        note(col, context, f"Output: {c.output.name}", icon="OUTLINER_DATA_CURVES", box=True)
        note(col, context, f"From: {', '.join(m.name for m in stack)}", icon="MODIFIER",
             box=True)
        col.label(text=f"Children: {c.stat_children}, fixed: {c.stat_fixed}", icon="CHECKMARK")
        if c.stat_unresolved:
            col.label(text=f"Unresolved (red): {c.stat_unresolved}", icon="ERROR")
        if c.stat_invalid:
            col.label(text=f"Invalid (yellow): {c.stat_invalid}", icon="ERROR")
        if not c.use_viewport:
            note(col, context, "Viewport: not cleared (renders and bakes are)", box=True)
    note(col, context, CHILDREN_AND_GROOM, box=True)


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
            note(col, context, NO_SURFACE_HAIR, box=True)

        src = active_setup(context)
        if src is None:
            box = layout.box()
            box.label(text="Collided Output", icon="MOD_PHYSICS")
            note(box, context, "Needs a FurCollide setup", box=True)
            return
        draw_attach(layout, context, src)
        draw_motion(layout, src)
        draw_influence(layout, context, src)
        draw_children(layout, context, src, s)
        draw_groom(layout, context, src)


classes = (FURCOLLIDE_PT_pipeline,)
