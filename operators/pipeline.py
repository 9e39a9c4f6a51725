"""Fur pipeline operators (paper sections 2 and 4): thin glue around :mod:`..core.pipeline`.

* ``furcollide.fur_sampler``: a new guide hair object from a (possibly
  generated) render groom, with :func:`core.pipeline.sample_guides`.
* ``furcollide.collider_distance``: the per-point attribute
  ``furcollide_collider_distance`` on a setup's output, with
  :func:`core.pipeline.collider_distance`.
* ``furcollide.children_from_guides``: Blender's own *Interpolate Hair
  Curves* node group on a setup's output (render children from the
  collided guides).
* ``furcollide.fur_attach_bind``: Fur Attach, the optional input stage of a
  setup: binds the source's curves to its Surface at the reference frame with
  :func:`core.pipeline.bind`; the frame handler then moves them rigidly with
  the evaluated Surface (``use_fur_attach``). ``furcollide.fur_attach_unbind``
  forgets the binding.
* ``furcollide.groom_bind`` / ``furcollide.groom_remove``: guide deform of an
  existing render groom (:mod:`.stages`): binds it to the setup's guides at the
  current frame and creates the groom output the frame handler writes into.

Every computation is in world space.
"""

from __future__ import annotations

import os
import uuid

import bpy
import numpy as np
from bpy.props import (
    BoolProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)
from bpy.types import Operator, PropertyGroup

from ..core import framecache
from . import bridge, runtime, stages
from .setup import (
    SetupOperator,
    active_setup,
    evaluate_now,
    new_hair_object_like,
    redraw,
    refuse,
    reports_errors,
)

#: Per-point attribute written by ``furcollide.collider_distance``.
DISTANCE_ATTRIBUTE = stages.DISTANCE_ATTRIBUTE
#: Blender's bundled hair node-group assets (blender-facts 2.6).
HAIR_ASSETS = os.path.join("assets", "nodes", "procedural_hair_node_assets.blend")
INTERPOLATE_GROUP = "Interpolate Hair Curves"
#: Name of the modifier ``furcollide.children_from_guides`` adds.
CHILDREN_MODIFIER = "FurCollide Children"
NO_SURFACE_HAIR = "Active object must be a hair Curves object with a Surface"
#: Curve attributes carried over to the guides (kept curves only).
_GUIDE_ATTRIBUTES = {
    "surface_uv_coordinate": ("vector", np.float32, 2),
    "surface_normal": ("vector", np.float32, 3),
    "radius": ("value", np.float32, 1),
}


def _core_pipeline():
    from ..core import pipeline

    return pipeline


# ------------------------------------------------------------------ helpers
def surface_mesh_world(ob, depsgraph, matrix=None):
    """Evaluated mesh of object ``ob`` (a mesh, or a curve, text... turned into one):
    world vertices (n, 3) float64, triangles (m, 3); none for a curve without a surface.
    ``matrix``: its world matrix when not its own (a collection instance)."""
    oe = ob.evaluated_get(depsgraph)
    M = bridge.matrix(oe) if matrix is None else matrix
    with bridge.evaluated_mesh(oe) as me:
        if me is None:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        V = bridge.mesh_vertices(me).astype(np.float64)
        F = bridge.mesh_triangles(me).astype(np.int64)
    return V @ M[:3, :3].T + M[:3, 3], F


def surface_weights(surf, me, name):
    """Per-vertex weights (n,) float64 of the evaluated mesh ``me`` of ``surf`` from
    vertex group ``name`` (or else a POINT attribute ``name``); ValueError if neither."""
    n = len(me.vertices)
    vg = surf.vertex_groups.get(name)
    if vg is not None:
        w = np.zeros(n)
        gi = vg.index
        for v in me.vertices:
            for g in v.groups:
                if g.group == gi:
                    w[v.index] = g.weight
        return w
    attr = me.attributes.get(name)
    kinds = {"FLOAT": np.float32, "INT": np.int32, "INT8": np.int32, "BOOLEAN": bool}
    if attr is None or attr.domain != "POINT" or attr.data_type not in kinds:
        raise ValueError(
            f"The Surface '{surf.name}' has no vertex group or float point attribute '{name}'"
        )
    return _read(attr, "value", kinds[attr.data_type], 1).astype(np.float64)


def _read(attr, key, dtype, width):
    n = len(attr.data)
    buf = np.empty(n * width, dtype)
    if n:
        attr.data.foreach_get(key, buf)
    return buf.reshape(n, width) if width > 1 else buf


def selected_curves(curves, offsets):
    """Per-curve selection (C,) bool of a Curves data-block, or None when it has none.

    The hidden ``.selection`` attribute is on the POINT or CURVE domain; a curve
    counts as selected when any of its points is.
    """
    attr = curves.attributes.get(".selection")
    if attr is None:
        return None
    C = len(offsets) - 1
    vals = _read(attr, "value", bool if attr.data_type == "BOOLEAN" else np.float32, 1)
    sel = vals > 0.5 if vals.dtype != bool else vals
    if attr.domain == "CURVE" and len(sel) == C:
        return sel
    if attr.domain == "POINT" and len(sel) == offsets[-1]:
        if C == 0:
            return np.zeros(0, bool)
        return np.logical_or.reduceat(sel, offsets[:-1]) & (np.diff(offsets) > 0)
    return None


def _copy_attribute(src, dst, name, domain, idx):
    """Copy attribute ``name`` of ``src`` to ``dst`` for the items ``idx`` of
    ``domain`` ('CURVE' or 'POINT'); False when ``src`` has no such attribute."""
    attr = src.attributes.get(name)
    spec = _GUIDE_ATTRIBUTES.get(name)
    if attr is None or spec is None or attr.domain != domain:
        return False
    key, dtype, width = spec
    vals = _read(attr, key, dtype, width)[idx]
    out = dst.attributes.new(name, attr.data_type, domain)
    if len(out.data) != len(vals):
        raise bridge.BridgeError(f"attribute '{name}': {len(out.data)} != {len(vals)}")
    if len(vals):
        out.data.foreach_set(key, np.ascontiguousarray(vals, dtype).ravel())
    return True


def new_guides_object(src, data_eval, keep, context):
    """New hair object with the curves ``keep`` of ``data_eval`` (the evaluated
    data of ``src``) as original data, placed and parented like ``src``."""
    offs = bridge.curve_offsets(data_eval)
    sizes = np.diff(offs)
    P = bridge.get_positions(data_eval)

    def fill(hc):
        if len(keep):
            hc.add_curves(sizes[keep].tolist())
        point_idx = framecache.curve_point_mask(offs, np.asarray(keep, np.int64))
        bridge.set_positions(hc, P[point_idx])
        for name in _GUIDE_ATTRIBUTES:
            if not _copy_attribute(data_eval, hc, name, "CURVE", keep):
                _copy_attribute(data_eval, hc, name, "POINT", point_idx)

    return new_hair_object_like(src, "Guides", context.scene, fill)


def hair_assets_path() -> str:
    """Path of Blender's bundled hair node-group assets ('' when not found)."""
    roots = []
    try:
        roots.append(bpy.utils.system_resource("DATAFILES"))
    except (ValueError, TypeError):
        pass
    for kind in ("LOCAL", "SYSTEM"):
        try:
            roots.append(os.path.join(bpy.utils.resource_path(kind), "datafiles"))
        except (ValueError, TypeError):
            pass
    for root in roots:
        if root:
            path = os.path.join(root, HAIR_ASSETS)
            if os.path.isfile(path):
                return path
    return ""


def interpolate_group():
    """Blender's 'Interpolate Hair Curves' node group (appended once from the
    bundled assets); raises FileNotFoundError when the assets are missing."""
    for ng in bpy.data.node_groups:
        if ng.get("furcollide_asset") == INTERPOLATE_GROUP and ng.bl_idname == "GeometryNodeTree":
            return ng
    path = hair_assets_path()
    if not path:
        raise FileNotFoundError(
            "Blender's hair node assets (datafiles/"
            + HAIR_ASSETS.replace(os.sep, "/")
            + ") were not found in this Blender installation"
        )
    with bpy.data.libraries.load(path, link=False) as (src, dst):
        if INTERPOLATE_GROUP not in src.node_groups:
            raise FileNotFoundError(f"'{INTERPOLATE_GROUP}' is not in {path}")
        dst.node_groups = [INTERPOLATE_GROUP]
    ng = dst.node_groups[0]
    if ng is None:
        raise FileNotFoundError(f"could not load '{INTERPOLATE_GROUP}' from {path}")
    ng["furcollide_asset"] = INTERPOLATE_GROUP
    return ng


def group_inputs(ng) -> dict:
    """``{(name, socket_type): identifier}`` of a node group's input sockets."""
    out = {}
    for item in ng.interface.items_tree:
        if item.item_type == "SOCKET" and item.in_out == "INPUT":
            out.setdefault((item.name, item.socket_type), item.identifier)
    return out


# ---------------------------------------------------------------- settings
# Each setting is declared once: the scene settings group shows it in the panel and
# the operators take it as an argument (Adjust Last Operation, scripts).
def _prop_fraction():
    return FloatProperty(
        name="Fraction",
        default=0.15,
        min=0.001,
        max=1.0,
        subtype="FACTOR",
        description="Share of the groom's curves kept as guides (0.15 keeps 15 %)",
    )


def _prop_seed():
    return IntProperty(
        name="Seed",
        default=0,
        min=0,
        description="Random seed of the sampler: the same seed gives the same guides",
    )


def _prop_use_selection():
    return BoolProperty(
        name="Only Selected",
        default=False,
        description="Pick guides only among the selected curves of the groom (sculpt mode "
        "selection), when it has one",
    )


def _prop_area():
    return StringProperty(
        name="Area of Interest",
        default="",
        description="Vertex group (or float point attribute) of the Surface: guides are "
        "picked only where its weight is at least 0.5 (empty: everywhere)",
    )


def _prop_density():
    return FloatProperty(
        name="Density",
        default=10.0,
        min=0.0,
        soft_max=10000.0,
        description="Child curves per unit of surface area created around the guides",
    )


def _prop_guides():
    return IntProperty(
        name="Interpolation Guides",
        default=4,
        min=1,
        soft_max=16,
        description="Number of nearest guides each child curve interpolates",
    )


class FURCOLLIDE_PG_pipeline(PropertyGroup):
    """Fur pipeline settings of the scene (shown in the Fur Pipeline panel)."""

    fraction: _prop_fraction()
    seed: _prop_seed()
    use_selection: _prop_use_selection()
    area: _prop_area()
    density: _prop_density()
    guides: _prop_guides()


# ---------------------------------------------------------------- operators
class FURCOLLIDE_OT_fur_sampler(Operator):
    """Fur Sampler: create a new guide hair object from a uniform, well-spaced subset
    of the active groom's curves (also works on generated hair such as Quick Fur)"""

    bl_idname = "furcollide.fur_sampler"
    bl_label = "Fur Sampler"
    bl_options = {"REGISTER", "UNDO"}

    fraction: _prop_fraction()
    seed: _prop_seed()
    use_selection: _prop_use_selection()
    area: _prop_area()

    @classmethod
    def poll(cls, context):
        ob = getattr(context, "active_object", None)
        if ob is None or ob.type != "CURVES":
            return refuse(cls, NO_SURFACE_HAIR)
        surf = ob.data.surface
        if surf is None or surf.type != "MESH":
            return refuse(cls, NO_SURFACE_HAIR)
        return True

    @reports_errors
    def execute(self, context):
        src = context.active_object
        surf = src.data.surface
        if surf is None or surf.type != "MESH":
            self.report({"ERROR"}, f"'{src.name}' has no Surface mesh (Object Data > Surface)")
            return {"CANCELLED"}
        dg = context.evaluated_depsgraph_get()
        src_eval = src.evaluated_get(dg)
        data = src_eval.data
        offs = bridge.curve_offsets(data)
        C = len(offs) - 1
        if C == 0:
            self.report({"ERROR"}, f"'{src.name}' has no curves to sample")
            return {"CANCELLED"}
        V, F = surface_mesh_world(surf, dg)
        if len(F) == 0:
            self.report({"ERROR"}, f"The Surface '{surf.name}' has no faces")
            return {"CANCELLED"}
        P = bridge.get_positions(data)
        M = bridge.matrix(src_eval)
        roots = P[offs[:-1]].astype(np.float64) @ M[:3, :3].T + M[:3, 3]
        mask = None
        if self.use_selection:
            mask = selected_curves(data, offs)
            if mask is None and len(src.data.curves) == C:
                mask = selected_curves(src.data, offs)
            if mask is None:
                self.report({"WARNING"}, f"'{src.name}' has no curve selection: using all curves")
            elif not mask.any():
                self.report({"ERROR"}, f"No curve of '{src.name}' is selected")
                return {"CANCELLED"}
        if self.area:
            w = surface_weights(surf, surf.evaluated_get(dg).data, self.area)
            inside = _core_pipeline().surface_values(V, F, w, roots) >= 0.5
            mask = inside if mask is None else (mask & inside)
            if not mask.any():
                self.report({"ERROR"}, f"No curve root lies in the area '{self.area}'")
                return {"CANCELLED"}
        keep = _core_pipeline().sample_guides(roots, V, F, self.fraction, self.seed, mask)
        ob = new_guides_object(src, data, keep, context)
        for o in context.selected_objects:
            o.select_set(False)
        try:
            ob.select_set(True)
            context.view_layer.objects.active = ob
        except RuntimeError:  # not in the active view layer
            pass
        self.report(
            {"INFO"},
            f"Fur Sampler: created {len(keep)} guides from {C} curves "
            f"of '{src.name}' in '{ob.name}'",
        )
        redraw(context)
        return {"FINISHED"}


class _OutputOperator(SetupOperator):
    @classmethod
    def refusal(cls, context, src):
        out = src.furcollide.output
        if out is None or out.type != "CURVES":
            return "The FurCollide setup has no output hair object"
        return ""


class FURCOLLIDE_OT_collider_distance(_OutputOperator, Operator):
    """Fur Collider Distance: store on the output, for every point, the closest distance
    of its segments to the enabled colliders (attribute furcollide_collider_distance)"""

    bl_idname = "furcollide.collider_distance"
    bl_label = "Collider Distance"
    bl_options = {"REGISTER", "UNDO"}

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        out = src.furcollide.output
        dg = context.evaluated_depsgraph_get()
        cols = [surface_mesh_world(r.object, dg, r.matrix(dg))
                for r in runtime.collider_objects(src, context.scene)]
        cols = [c for c in cols if len(c[1])]
        if not cols:
            self.report({"ERROR"}, f"The setup of '{src.name}' has no enabled collider")
            return {"CANCELLED"}
        data = out.data
        offs = bridge.curve_offsets(data)
        if len(offs) < 2:
            self.report({"ERROR"}, f"The output '{out.name}' has no curves")
            return {"CANCELLED"}
        P = bridge.get_positions(data).astype(np.float64)
        M = bridge.matrix(out)
        Pw = P @ M[:3, :3].T + M[:3, 3]
        d = _core_pipeline().collider_distance(Pw, offs, cols)
        stages.write_attributes(data, {DISTANCE_ATTRIBUTE: d})
        data.update_tag()
        self.report(
            {"INFO"},
            f"Collider distance on '{out.name}': min {d.min():.4g}, "
            f"max {d.max():.4g} ({len(d)} points)",
        )
        return {"FINISHED"}


class FURCOLLIDE_OT_children_from_guides(_OutputOperator, Operator):
    """Children from Guides: add Blender's Interpolate Hair Curves to the output, so
    dense render children grow on the source's Surface and follow the collided guides"""

    bl_idname = "furcollide.children_from_guides"
    bl_label = "Children from Guides"
    bl_options = {"REGISTER", "UNDO"}

    density: _prop_density()
    guides: _prop_guides()

    @classmethod
    def refusal(cls, context, src):
        msg = super().refusal(context, src)
        if msg:
            return msg
        surf = src.data.surface
        if surf is None or surf.type != "MESH":
            return "The source hair has no Surface mesh (Object Data > Surface)"
        if len(surf.data.polygons) == 0:
            return f"The Surface '{surf.name}' has no faces to grow children on"
        return ""

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        out = src.furcollide.output
        surf = src.data.surface
        try:
            ng = interpolate_group()
        except FileNotFoundError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        ids = group_inputs(ng)
        surface_id = ids.get(("Surface", "NodeSocketObject"))
        if surface_id is None:
            self.report({"ERROR"}, f"'{ng.name}' has no Surface object input")
            return {"CANCELLED"}
        mod = out.modifiers.get(CHILDREN_MODIFIER)
        if mod is None or mod.type != "NODES":
            mod = out.modifiers.new(CHILDREN_MODIFIER, "NODES")
        mod.node_group = ng
        mod[surface_id] = surf
        values = {
            ("Density", "NodeSocketFloat"): float(self.density),
            ("Interpolation Guides", "NodeSocketInt"): int(self.guides),
        }
        for key, value in values.items():
            if key in ids:
                mod[ids[key]] = value
        uv_id = ids.get(("Surface UV Map", "NodeSocketVector"))
        uv_name = src.data.surface_uv_map or out.data.surface_uv_map
        if uv_id is not None and uv_name and f"{uv_id}_attribute_name" in mod.keys():
            mod[f"{uv_id}_use_attribute"] = True
            mod[f"{uv_id}_attribute_name"] = uv_name
        out.data.surface = surf
        if uv_name:
            out.data.surface_uv_map = uv_name
        out.update_tag()
        self.report(
            {"INFO"},
            f"Children from guides on '{out.name}' (surface '{surf.name}', "
            f"density {self.density:g})",
        )
        redraw(context)
        return {"FINISHED"}


class FURCOLLIDE_OT_fur_attach_bind(SetupOperator, Operator):
    """Fur Attach: tie every curve of the source to the Surface triangle under its root
    at the reference frame; the curves then move rigidly with the animated Surface"""

    bl_idname = "furcollide.fur_attach_bind"
    bl_label = "Bind"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        surf = src.data.surface
        if surf is None or surf.type != "MESH":
            return "The source hair has no Surface mesh (Object Data > Surface)"
        if src.furcollide.is_baked:
            return "The setup is baked: free the bake before binding"
        return ""

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        surf = src.data.surface
        msg = self.refusal(context, src) if src is not None else "No FurCollide setup"
        if msg:
            self.report({"ERROR"}, msg)
            return {"CANCELLED"}
        scene = context.scene
        f0, sub0 = scene.frame_current, scene.frame_subframe
        ref = int(s.attach_reference_frame)
        move = ref != f0 or sub0 != 0.0
        # The surface and the curves are read as evaluated at the reference frame
        # (deformers, shape keys and armatures included). The frame handlers are
        # held off while visiting it, and the frame is restored afterwards.
        busy = runtime._busy
        runtime._busy = True
        try:
            if move:
                scene.frame_set(ref)
            dg = context.evaluated_depsgraph_get()
            V, F = surface_mesh_world(surf, dg)
            topology = bridge.mesh_topology_key(surf.evaluated_get(dg).data)
            src_eval = src.evaluated_get(dg)
            offs = bridge.curve_offsets(src_eval.data)
            P = bridge.get_positions(src_eval.data).astype(np.float64)
            M = bridge.matrix(src_eval)
        finally:
            if move:
                scene.frame_set(f0, subframe=sub0)
            runtime._busy = busy
        if len(F) == 0:
            self.report({"ERROR"}, f"The Surface '{surf.name}' has no faces")
            return {"CANCELLED"}
        if len(offs) < 2:
            self.report({"ERROR"}, f"'{src.name}' has no curves to bind")
            return {"CANCELLED"}
        Pw = P @ M[:3, :3].T + M[:3, 3]
        binding = _core_pipeline().bind(Pw, offs, V, F, drop_degenerate=True)
        attach_id = uuid.uuid4().hex
        runtime.store_binding(src, binding, topology, attach_id)
        s.attach_id = attach_id
        s.use_fur_attach = True
        runtime.update_dependencies(src)  # the Surface, even when hidden from render
        # Every frame's input changes: drop every cached frame (see _invalidate_attach).
        runtime.invalidate(src, reason="Fur Attach bound", from_frame=s.frame_start - 1)
        err = evaluate_now(context, src)
        far = float(binding.root_distance.max()) if len(binding.root_distance) else 0.0
        self.report(
            {"INFO"},
            f"Fur Attach: bound {len(offs) - 1} curves of '{src.name}' to '{surf.name}' "
            f"at frame {ref} (farthest root {far:.4g} from the surface)",
        )
        size = float(np.linalg.norm(V.max(0) - V.min(0))) or 1.0
        off = binding.root_distance > 1e-4 * size
        if off.any():
            self.report(
                {"WARNING"},
                f"Fur Attach: {int(off.sum())} roots were not on the Surface at frame {ref} "
                f"(up to {far:.4g} away): those curves were moved onto it",
            )
        if err:
            self.report({"WARNING"}, f"FurCollide: {err}")
        redraw(context)
        return {"FINISHED"}


class FURCOLLIDE_OT_fur_attach_unbind(SetupOperator, Operator):
    """Fur Attach: forget the binding; the setup uses the source's own curves again"""

    bl_idname = "furcollide.fur_attach_unbind"
    bl_label = "Unbind"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        if not runtime.has_binding(src) and not src.furcollide.use_fur_attach:
            return "The source hair is not bound (Fur Attach)"
        if src.furcollide.is_baked:
            return "The setup is baked: free the bake before unbinding"
        return ""

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        runtime.clear_binding(src)
        s.attach_id = ""
        s.use_fur_attach = False  # its update drops every cached frame
        runtime.invalidate(src, reason="Fur Attach unbound", from_frame=s.frame_start - 1)
        err = evaluate_now(context, src)
        self.report({"INFO"}, f"Fur Attach: unbound '{src.name}'")
        if err:
            self.report({"WARNING"}, f"FurCollide: {err}")
        redraw(context)
        return {"FINISHED"}


def _hair_world(ob, depsgraph):
    """Evaluated hair ``ob``: (world points (P, 3) float64, offsets (C+1,))."""
    oe = ob.evaluated_get(depsgraph)
    offs = bridge.curve_offsets(oe.data)
    P = bridge.transform(bridge.get_positions(oe.data), bridge.matrix(oe))
    return np.asarray(P, np.float64), offs


class FURCOLLIDE_OT_groom_bind(SetupOperator, Operator):
    """Render groom follows the guides: bind the Render Groom to this setup's guides at
    the current frame (its reference pose) and create the groom output hair object,
    which then follows the collided guides every frame; the groom itself is untouched
    (hidden)"""

    bl_idname = "furcollide.groom_bind"
    bl_label = "Bind Groom"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        g = src.furcollide.groom.groom
        if g is None:
            return "Choose the Render Groom (a hair object) first"
        if g.type != "CURVES":
            return f"'{g.name}' is not a hair Curves object"
        if g == src or g == src.furcollide.output or g == src.furcollide.groom.output:
            return "The Render Groom must be another hair object than the guides"
        return ""

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        g = s.groom
        groom = g.groom
        scene = context.scene
        dg = context.evaluated_depsgraph_get()
        render_ref, roff = _hair_world(groom, dg)
        if len(roff) < 2:
            self.report({"ERROR"}, f"The Render Groom '{groom.name}' has no curves")
            return {"CANCELLED"}
        if np.diff(roff).min() < 2:
            i = int(np.argmax(np.diff(roff) < 2))
            self.report({"ERROR"}, f"'{groom.name}': curve {i} has fewer than 2 points")
            return {"CANCELLED"}
        inp = runtime.read_inputs(src, dg)  # the guides' input (before motion) now
        surface = None
        surf = src.data.surface
        if surf is not None and surf.type == "MESH" and groom.data.surface == surf:
            # render roots stay exactly on the shared Surface (Fur Attach of the roots)
            V, F = surface_mesh_world(surf, dg)
            surface = (V, F, bridge.mesh_topology_key(surf.evaluated_get(dg).data))
        arrays = stages.GroomBinding.build(
            render_ref, roff, inp.points, inp.offsets, g.guides, surface
        )
        out = g.output
        if out is None or out.type != "CURVES" or not runtime.in_scene(out, scene):
            out = new_hair_object_like(
                groom, "FurCollide", scene,
                lambda hc: bridge.copy_topology(groom.evaluated_get(dg).data, hc),
            )
        elif not np.array_equal(bridge.curve_offsets(out.data), roff):
            bridge.copy_topology(groom.evaluated_get(dg).data, out.data)
        stages.store_groom(out, arrays)
        g.output = out
        g.bind_id = uuid.uuid4().hex
        g.bound_guides = g.guides
        runtime.update_dependencies(src)  # renders with the guides hidden still see them
        runtime.hide_in_viewport(groom, True, render=True)
        err = evaluate_now(context, src)
        roots = "on the Surface" if surface is not None else "following the guides"
        self.report(
            {"INFO"},
            f"Render groom: {len(roff) - 1} curves of '{groom.name}' follow "
            f"{len(inp.offsets) - 1} guides into '{out.name}' (roots {roots})",
        )
        if err:
            self.report({"WARNING"}, f"FurCollide: {err}")
        redraw(context)
        return {"FINISHED"}


class FURCOLLIDE_OT_groom_remove(SetupOperator, Operator):
    """Delete the groom output object and show the Render Groom again"""

    bl_idname = "furcollide.groom_remove"
    bl_label = "Remove Groom Output"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def refusal(cls, context, src):
        return "" if src.furcollide.groom.output is not None else "No groom output to remove"

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        runtime.remove_groom(src)
        self.report({"INFO"}, f"Removed the render groom output of '{src.name}'")
        redraw(context)
        return {"FINISHED"}


classes = (
    FURCOLLIDE_PG_pipeline,
    FURCOLLIDE_OT_fur_attach_bind,
    FURCOLLIDE_OT_fur_attach_unbind,
    FURCOLLIDE_OT_groom_bind,
    FURCOLLIDE_OT_groom_remove,
    FURCOLLIDE_OT_fur_sampler,
    FURCOLLIDE_OT_collider_distance,
    FURCOLLIDE_OT_children_from_guides,
)


def register():
    """Add ``Scene.furcollide_pipeline`` (after the classes are registered)."""
    bpy.types.Scene.furcollide_pipeline = PointerProperty(type=FURCOLLIDE_PG_pipeline)


def unregister():
    if hasattr(bpy.types.Scene, "furcollide_pipeline"):
        del bpy.types.Scene.furcollide_pipeline
