"""Fur Attach operators (paper section 2): Bind and Unbind (the input stage is in
:mod:`..frame.attach`).

``furcollide.fur_attach_bind`` binds the source's curves to its Surface at the reference
frame with :func:`core.pipeline.bind`; the frame rules then move them rigidly with the
evaluated Surface (``use_fur_attach``). ``furcollide.fur_attach_unbind`` forgets the
binding.
"""

from __future__ import annotations

import uuid

import numpy as np
from bpy.types import Operator

from ...core import pipeline
from ..blender import bridge
from ..blender.dependencies import update_dependencies
from ..frame.attach import clear_binding, has_binding, store_binding
from ..store import registry
from ..store.invalidation import invalidate
from .common import SetupOperator, active_setup, evaluate_now, redraw, reports_errors


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
        with registry.handlers_held():
            try:
                if move:
                    scene.frame_set(ref)
                dg = context.evaluated_depsgraph_get()
                V, F = bridge.surface_mesh_world(surf, dg)
                topology = bridge.mesh_topology_key(surf.evaluated_get(dg).data)
                src_eval = src.evaluated_get(dg)
                offs = bridge.curve_offsets(src_eval.data)
                P = bridge.get_positions(src_eval.data).astype(np.float64)
                M = bridge.matrix(src_eval)
            finally:
                if move:
                    scene.frame_set(f0, subframe=sub0)
        if len(F) == 0:
            self.report({"ERROR"}, f"The Surface '{surf.name}' has no faces")
            return {"CANCELLED"}
        if len(offs) < 2:
            self.report({"ERROR"}, f"'{src.name}' has no curves to bind")
            return {"CANCELLED"}
        Pw = P @ M[:3, :3].T + M[:3, 3]
        binding = pipeline.bind(Pw, offs, V, F, drop_degenerate=True)
        attach_id = uuid.uuid4().hex
        store_binding(src, binding, topology, attach_id)
        s.attach_id = attach_id
        s.use_fur_attach = True
        update_dependencies(src)  # the Surface, even when hidden from render
        # Every frame's input changes: drop every cached frame (see property_helpers.update_attach).
        invalidate(src, scene, reason="Fur Attach was bound", from_frame=s.frame_start - 1)
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
        if not has_binding(src) and not src.furcollide.use_fur_attach:
            return "The source hair is not bound (Fur Attach)"
        if src.furcollide.is_baked:
            return "The setup is baked: free the bake before unbinding"
        return ""

    @reports_errors
    def execute(self, context):
        src = active_setup(context)
        s = src.furcollide
        clear_binding(src)
        s.attach_id = ""
        s.use_fur_attach = False  # its update drops every cached frame
        invalidate(src, context.scene, reason="Fur Attach was unbound",
                   from_frame=s.frame_start - 1)
        err = evaluate_now(context, src)
        self.report({"INFO"}, f"Fur Attach: unbound '{src.name}'")
        if err:
            self.report({"WARNING"}, f"FurCollide: {err}")
        redraw(context)
        return {"FINISHED"}


classes = (FURCOLLIDE_OT_fur_attach_bind, FURCOLLIDE_OT_fur_attach_unbind)
