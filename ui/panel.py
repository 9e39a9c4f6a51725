"""View3D > Sidebar > FurCollide: the panel, its sub-panels and the colliders list."""

import bpy
from bpy.types import Panel, UIList

from ..core import framecache
from ..operators.frame import topology
from ..operators.frame.clock import STAGES
from ..operators.frame.colliders import collider_lines, in_scene
from ..operators.ops import bake as bake_ops
from ..operators.ops.common import active_setup, backend_message
from ..operators.ops.scene import drops_frames, needs_lock
from ..operators.store import playback, registry, report
from .text import note, warning

#: What the panel says before a setup: Add FurCollide takes the *active* hair (the object
#: selected last) and the other selected objects as its colliders.
HINT = "Select the colliders, then Shift-click the hair last"
#: The one-line warnings of the scene's settings, each beside the button that fixes it
#: (:mod:`..operators.ops.scene`).
LOCK_WARNING = "Renders unlocked"
SYNC_WARNING = "Playback Sync"

#: List icon per collider object type (a mesh, or what Blender turns into one).
_TYPE_ICONS = {"CURVE": "CURVE_DATA", "SURFACE": "SURFACE_DATA", "FONT": "FONT_DATA",
               "META": "META_DATA", "EMPTY": "OUTLINER_OB_GROUP_INSTANCE"}


class FURCOLLIDE_UL_colliders(UIList):
    """Colliders of a setup: object, enabled, double-sided."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        row = layout.row(align=True)
        ob = item.object
        missing = ob is not None and not in_scene(ob, context.scene)
        row.alert = missing
        icon = "ERROR" if missing else _TYPE_ICONS.get(getattr(ob, "type", ""), "MESH_DATA")
        row.prop(item, "object", text="", emboss=False, icon=icon)
        row.prop(item, "double_sided", text="", icon="MOD_SOLIDIFY", emboss=item.double_sided)
        icon = "CHECKBOX_HLT" if item.enabled else "CHECKBOX_DEHLT"
        row.prop(item, "enabled", text="", icon=icon)


class _Sub:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "FurCollide"
    bl_parent_id = "FURCOLLIDE_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        return active_setup(context) is not None

    def settings(self, context):
        return active_setup(context).furcollide

    def prepare(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = True  # keyframe decorators: settings can be keyed
        s = self.settings(context)
        # (greyed where the setup belongs to another scene: its settings are that scene's)
        layout.enabled = not s.is_baked and not registry.foreign_message(s.id_data)
        return layout, s


class FURCOLLIDE_PT_main(Panel):
    """FurCollide: collide the active hair with meshes."""

    bl_label = "FurCollide"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "FurCollide"

    @classmethod
    def poll(cls, context):
        ob = context.object
        return ob is not None and ob.type == "CURVES"

    def draw_header_preset(self, context):
        src = active_setup(context)
        if src is not None:
            # A baked setup only reads (its settings are greyed out): so are presets.
            self.layout.enabled = not src.furcollide.is_baked and not (
                registry.foreign_message(src))
            FURCOLLIDE_PT_presets.draw_panel_header(self.layout)

    def draw(self, context):
        layout = self.layout
        msg = backend_message()
        if msg:
            box = layout.box()
            box.label(text="Ray tracer unavailable", icon="ERROR")
            note(box, context, msg, icon="NONE", box=True)
        src = active_setup(context)
        if src is None:
            layout.operator("furcollide.add", icon="MOD_PHYSICS")
            note(layout, context, HINT)
            return
        s = src.furcollide
        layout.use_property_split = True
        layout.use_property_decorate = True
        col = layout.column()
        col.enabled = not registry.foreign_message(src)  # (another scene's setup)
        col.prop(s, "enabled")
        col.prop(s, "show_result")
        row = col.row()
        row.enabled = False
        row.prop(s, "output")
        level, message = report.status_shown(src)
        if message:
            icon = {"ERROR": "ERROR", "WARNING": "ERROR"}.get(level, "INFO")
            box = layout.box()
            note(box, context, message, icon=icon, box=True)
            if topology.BUTTON in message:  # (the fix the message names)
                box.operator("furcollide.use_rest_position", icon="MOD_MESHDEFORM")
        draw_scene_warnings(layout, context)
        layout.operator("furcollide.remove", icon="X")


def draw_scene_warnings(layout, context) -> None:
    """The scene settings a setup needs, when they are not so: one line each, with the
    button that sets them (:mod:`..operators.ops.scene`)."""
    scene = context.scene
    if needs_lock(scene):
        warning(layout, context, LOCK_WARNING, "furcollide.lock_interface", "Lock Interface")
    if drops_frames(scene):
        warning(layout, context, SYNC_WARNING, "furcollide.play_every_frame",
                "Play Every Frame")


class FURCOLLIDE_PT_colliders(_Sub, Panel):
    bl_label = "Colliders"
    bl_options = set()

    def draw(self, context):
        layout, s = self.prepare(context)
        layout.use_property_split = False
        row = layout.row()
        row.template_list(
            "FURCOLLIDE_UL_colliders", "", s, "colliders", s, "collider_index", rows=3
        )
        col = row.column(align=True)
        col.operator("furcollide.collider_add", icon="ADD", text="")
        col.operator("furcollide.collider_remove", icon="REMOVE", text="")
        if 0 <= s.collider_index < len(s.colliders):
            item = s.colliders[s.collider_index]
            col = layout.column()
            col.use_property_split = True
            col.prop(item, "double_sided")
            col.prop(item, "use_offset")
            sub = col.column()
            sub.active = item.use_offset
            sub.prop(item, "collision_offset")
            rt = registry.get_runtime(active_setup(context), create=False)
            for line in collider_lines(rt, item.object):  # repairs, no pinch detection
                note(col, context, line)
        col = layout.column()
        col.use_property_split = True
        col.prop(s, "collider_collection")
        sub = col.column()
        sub.active = s.collider_collection is not None
        sub.prop(s, "collection_double_sided", text="Double Sided")


def _map(col, s, name):
    """The map field under setting ``name`` (an attribute picked from the hair's)."""
    col.prop(s, f"{name}_map", text="Map", icon="GROUP_VERTEX")


class FURCOLLIDE_PT_resolution(_Sub, Panel):
    bl_label = "Resolution"
    bl_options = set()

    def draw(self, context):
        layout, s = self.prepare(context)
        col = layout.column()
        col.prop(s, "mode")
        col.prop(s, "rotation_precision")
        col.prop(s, "max_angle")
        _map(col, s, "max_angle")
        sub = col.column()
        sub.active = s.mode == "SOFT"
        sub.prop(s, "affected_connected_cvs")
        sub.prop(s, "cv_falloff")
        col.prop(s, "attract_to_growth_surface")
        col.prop(s, "follow_collider_motion")
        col.prop(s, "collision_offset")
        _map(col, s, "collision_offset")
        col.prop(s, "threads")


class FURCOLLIDE_PT_shrink(_Sub, Panel):
    bl_label = "Shrink"

    def draw_header(self, context):
        s = self.settings(context)
        self.layout.enabled = not s.is_baked
        self.layout.prop(s, "shrink", text="")

    def draw(self, context):
        layout, s = self.prepare(context)
        col = layout.column()
        col.active = s.shrink and s.mode != "SOFT"
        col.prop(s, "scale_minimum")
        _map(col, s, "scale_minimum")
        col.prop(s, "scale_angle")
        if s.mode == "SOFT":
            note(layout, context, "Shrink works in Stiff and Bend modes")


class FURCOLLIDE_PT_recovery(_Sub, Panel):
    bl_label = "Recovery & Plasticity"
    bl_options = set()  # (open: the paper's signature control)

    def draw(self, context):
        layout, s = self.prepare(context)
        col = layout.column()
        col.prop(s, "recovery_rate")
        _map(col, s, "recovery_rate")
        col.prop(s, "plasticity")
        _map(col, s, "plasticity")


class FURCOLLIDE_PT_pinch(_Sub, Panel):
    bl_label = "Pinch"

    def draw(self, context):
        layout, s = self.prepare(context)
        col = layout.column()
        col.prop(s, "pinch_resolution")
        col.prop(s, "recover_pinched")


class FURCOLLIDE_PT_enable(_Sub, Panel):
    bl_label = "Per-Curve Enable"

    def draw(self, context):
        layout, s = self.prepare(context)
        layout.prop(s, "enable_attribute", text="Attribute")


class FURCOLLIDE_PT_cache(_Sub, Panel):
    bl_label = "Cache"
    bl_options = set()

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        src = active_setup(context)
        s = src.furcollide
        # (a setup of another scene: its settings and cache are that scene's)
        foreign = (registry.owner(src, prefer=context.scene)
                   if registry.foreign_message(src, context.scene) else None)
        col = layout.column(align=True)
        col.enabled = not s.is_baked and foreign is None
        col.prop(s, "frame_start", text="Frame Start")
        col.prop(s, "frame_end", text="End")
        col = layout.column()
        col.enabled = not s.is_baked and foreign is None
        col.prop(s, "cache_directory", text="Directory")
        col.prop(s, "memory_limit", text="Memory (MB)")
        running = bake_ops.PROGRESS.get(context.scene.name)
        if running and hasattr(layout, "progress"):
            done, of = running
            layout.progress(factor=done / of, type="BAR", text=f"Baking {done} / {of} (Esc)")
        total = max(0, s.frame_end - s.frame_start + 1)
        n, where = cached_count(src)
        if foreign is not None:
            where += f" in scene '{foreign.name}'"
        note(layout, context, f"{n} of {total} frames {where}", icon="FILE_CACHE")
        rt = registry.get_runtime(src, create=False)
        if foreign is None and not s.is_baked and rt is not None and (
                rt.cache.dropped == playback.NOT_SAVED):
            note(layout, context, NOT_SAVED, icon="ERROR")
        if s.is_outdated:  # (the status above says why)
            note(layout, context, OUTDATED_BAKE if s.is_baked else OUTDATED, icon="ERROR")
        row = layout.row(align=True)
        if s.is_baked:
            row.operator("furcollide.free_bake", icon="TRASH")
        else:
            row.operator("furcollide.bake", icon="REC")
            if s.bake_path:
                row.operator("furcollide.free_bake", text="Free Partial", icon="TRASH")
        row = layout.row(align=True)
        row.operator("furcollide.bake_all")
        row.operator("furcollide.free_bake_all")
        layout.operator("furcollide.reset", icon="FILE_REFRESH")


#: The Cache section's warnings (each above the button it names).
NOT_SAVED = "Playback cache not saved: bake"
OUTDATED_BAKE = "Outdated bake: Free Bake, then Bake"
OUTDATED = "Outdated: play from the start or bake"


class FURCOLLIDE_PT_stats(_Sub, Panel):
    bl_label = "Last Frame"

    def draw(self, context):
        layout = self.layout
        s = self.settings(context)
        col = layout.column(align=True)
        col.label(text=f"Frame {s.stat_frame}")
        col.label(text=f"Colliding: {s.stat_colliding}")
        col.label(text=f"Recovering: {s.stat_recovering}")
        col.label(text=f"Pinched: {s.stat_pinched}")
        col.label(text=f"Unresolved: {s.stat_unresolved}")
        col.label(text=f"Disabled: {s.stat_disabled}")
        if s.stat_invalid:
            col.label(text=f"Invalid: {s.stat_invalid}", icon="ERROR")
        col.label(text=f"Solve: {s.stat_solve_ms:.1f} ms")
        g = s.groom
        if g.output is not None:
            col = layout.column(align=True)
            col.label(text=f"Render groom: {g.stat_fixed} fixed", icon="OUTLINER_OB_CURVES")
            col.label(text=f"Unresolved (red): {g.stat_unresolved}",
                      icon="ERROR" if g.stat_unresolved else "BLANK1")
            if g.stat_invalid:
                col.label(text=f"Invalid (yellow): {g.stat_invalid}", icon="ERROR")
        c = s.children
        if c.output is not None:
            col = layout.column(align=True)
            col.label(text=f"Children: {c.stat_children}, {c.stat_fixed} fixed",
                      icon="OUTLINER_DATA_CURVES")
            col.label(text=f"Unresolved (red): {c.stat_unresolved}",
                      icon="ERROR" if c.stat_unresolved else "BLANK1")
            if c.stat_invalid:
                col.label(text=f"Invalid (yellow): {c.stat_invalid}", icon="ERROR")
        draw_stage_times(layout, report.stats_for(s.id_data))


def draw_stage_times(layout, stats):
    """The last frame's milliseconds per pipeline stage (``operators/clock.py``; a
    stage that had nothing to do shows 0)."""
    if not any(stats.get(f"{k}_ms") for k in STAGES):
        return
    col = layout.column(align=True)
    col.label(text="Milliseconds per stage:", icon="TIME")
    for k in STAGES:
        col.label(text=f"{k.capitalize()}: {stats.get(f'{k}_ms', 0.0):.1f}", icon="BLANK1")


def cached_count(src) -> tuple[int, str]:
    """(number of frames, 'baked' / 'on disk' / 'cached') for the panel."""
    s = src.furcollide
    if s.is_baked or s.bake_path:
        try:
            frames = framecache.list_frames(bpy.path.abspath(s.bake_path))
        except OSError:
            frames = []
        n = sum(1 for f in frames if s.frame_start <= f <= s.frame_end)
        return n, "baked" if s.is_baked else "on disk (partial bake)"
    rt = registry.get_runtime(src, create=False)
    return (len(rt.cache.memory) if rt else 0), "cached"


from .presets import FURCOLLIDE_PT_presets  # noqa: E402  (avoid a cycle at import)

classes = (
    FURCOLLIDE_UL_colliders,
    FURCOLLIDE_PT_main,
    FURCOLLIDE_PT_colliders,
    FURCOLLIDE_PT_resolution,
    FURCOLLIDE_PT_shrink,
    FURCOLLIDE_PT_recovery,
    FURCOLLIDE_PT_pinch,
    FURCOLLIDE_PT_enable,
    FURCOLLIDE_PT_cache,
    FURCOLLIDE_PT_stats,
)
