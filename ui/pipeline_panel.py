"""View3D > Sidebar > FurCollide > Fur Pipeline: sampler, attach, collider distance,
children."""

from bpy.types import Panel

from ..operators import runtime
from ..operators.pipeline import NO_SURFACE_HAIR
from ..operators.setup import active_setup
from .panel import FURCOLLIDE_PT_main


def draw_attach(layout, src):
    """Fur Attach: the setup's optional input stage."""
    s = src.furcollide
    box = layout.box()
    box.label(text="Fur Attach (Input)", icon="SNAP_FACE")
    col = box.column()
    has_surface = src.data.surface is not None and src.data.surface.type == "MESH"
    bound = runtime.has_binding(src)
    row = col.row()
    row.enabled = bound or s.use_fur_attach
    row.prop(s, "use_fur_attach")
    col.prop(s, "attach_reference_frame")
    row = col.row()
    row.enabled = has_surface and not s.is_baked
    row.operator("furcollide.fur_attach_bind", icon="LINKED")
    if not has_surface:
        col.label(text="Fur Attach needs the source's Surface", icon="INFO")
    elif not bound:
        col.label(text="Not bound: press Bind", icon="INFO")


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
        layout.use_property_decorate = False
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

        box = layout.box()
        box.label(text="Collided Output", icon="MOD_PHYSICS")
        col = box.column()
        col.operator("furcollide.collider_distance", icon="DRIVER_DISTANCE")
        col.separator()
        col.prop(s, "density")
        col.prop(s, "guides")
        row = col.row()
        row.enabled = src.data.surface is not None
        op = row.operator("furcollide.children_from_guides", icon="OUTLINER_DATA_CURVES")
        op.density, op.guides = s.density, s.guides
        if src.data.surface is None:
            col.label(text="Children need the source's Surface", icon="INFO")


classes = (FURCOLLIDE_PT_pipeline,)
