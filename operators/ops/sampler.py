"""Fur Sampler (paper section 2): a new guide hair object from a render groom.

``furcollide.fur_sampler`` picks a uniform, well-spaced subset of a (possibly generated)
groom's curves with :func:`core.pipeline.sample_guides` and copies them, at the groom's
evaluated pose, into a new hair object placed like the groom.
"""

from __future__ import annotations

import numpy as np
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty
from bpy.types import Operator

from ...core import framecache, pipeline
from ..blender import bridge
from .common import new_hair_object_like, redraw, refuse, reports_errors

NO_SURFACE_HAIR = "Active object must be a hair Curves object with a Surface"
#: Curve attributes carried over to the guides (kept curves only).
_GUIDE_ATTRIBUTES = {
    "surface_uv_coordinate": ("vector", np.float32, 2),
    "surface_normal": ("vector", np.float32, 3),
    "radius": ("value", np.float32, 1),
}


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


# ---------------------------------------------------------------- settings
# Each setting is declared once: the scene settings group (``Scene.furcollide_pipeline``,
# :mod:`.pipeline`) shows it in the panel and the operator takes it as an argument
# (Adjust Last Operation, scripts).
def prop_fraction():
    return FloatProperty(
        name="Fraction",
        default=0.15,
        min=0.001,
        max=1.0,
        subtype="FACTOR",
        description="Share of the groom's curves kept as guides (0.15 keeps 15 %)",
    )


def prop_seed():
    return IntProperty(
        name="Seed",
        default=0,
        min=0,
        description="Random seed of the sampler: the same seed gives the same guides",
    )


def prop_use_selection():
    return BoolProperty(
        name="Only Selected",
        default=False,
        description="Pick guides only among the selected curves of the groom (sculpt mode "
        "selection), when it has one",
    )


def prop_area():
    return StringProperty(
        name="Area",
        default="",
        description="Area of interest: a vertex group (or float point attribute) of the "
        "Surface; guides are picked only where its weight is at least 0.5 (empty: "
        "everywhere)",
    )


class FURCOLLIDE_OT_fur_sampler(Operator):
    """Fur Sampler: create a new guide hair object from a uniform, well-spaced subset
    of the active groom's curves (also works on generated hair such as Quick Fur)"""

    bl_idname = "furcollide.fur_sampler"
    bl_label = "Fur Sampler"
    bl_options = {"REGISTER", "UNDO"}

    fraction: prop_fraction()
    seed: prop_seed()
    use_selection: prop_use_selection()
    area: prop_area()

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
        V, F = bridge.surface_mesh_world(surf, dg)
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
            inside = pipeline.surface_values(V, F, w, roots) >= 0.5
            mask = inside if mask is None else (mask & inside)
            if not mask.any():
                self.report({"ERROR"}, f"No curve root lies in the area '{self.area}'")
                return {"CANCELLED"}
        keep = pipeline.sample_guides(roots, V, F, self.fraction, self.seed, mask)
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


classes = (FURCOLLIDE_OT_fur_sampler,)
