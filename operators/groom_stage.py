"""The render groom stage: a dense groom follows the collided guides (paper section 2).

``furcollide.groom_bind`` (:mod:`.ops_groom`) binds an existing render groom to a setup's
guides (:class:`GroomBinding`, saved on the groom output object). Every frame the frame
rules show, :func:`run` deforms the render curves with the guides just written
(:func:`core.pipeline.deform_groom`), then the **clearance pass**
(:func:`core.pipeline.clearance_pass`) frees the render curves that still cross a
collider; their count is a panel statistic. The groom output is recomputed from the
shown guides; it is not cached or baked itself.
"""

from __future__ import annotations

import io

import bpy
import numpy as np

from .. import core
from ..core import pipeline
from . import bridge
from .colliders import collider_list, in_scene
from .frame_outputs import hide_in_viewport
from .registry import get_runtime

#: Custom property (bytes of an ``np.savez`` file) on the groom output object with
#: the render groom binding (reference poses, guide weights, optional root binding).
GROOM_PROPERTY = "_furcollide_groom"


def run(setup, guides_world) -> None:
    """The render groom follows the guides just written (deform + clearance pass).

    ``guides_world`` (P, 3): the guides' world points the output shows now.
    """
    rt, depsgraph = setup.rt, setup.depsgraph
    g = setup.s.groom
    out = g.output
    f = setup.frame + setup.subframe
    if depsgraph is None or not in_scene(out, depsgraph.scene):
        return
    if rt.groom_shown is not None and rt.groom_shown[0] == f and np.array_equal(
        rt.groom_shown[1], guides_world
    ):
        return  # the same frame again (handlers fire for repeated frames)
    binding = groom_binding(setup.ob, rt)
    cols = collider_list(setup) if g.use_clearance else []
    points, n_fixed = groom_frame(setup, binding, guides_world, cols)
    write_groom(out, points, binding.render_offsets, depsgraph)
    rt.groom_shown = (f, np.array(guides_world, copy=True))
    rt.stats = dict(rt.stats, groom_fixed=n_fixed)


def groom_binding(ob, rt):
    """The render groom binding of the setup on ``ob`` (cached in its runtime ``rt``)."""
    g = ob.furcollide.groom
    if rt.groom is None or rt.groom[0] != g.bind_id:
        rt.groom = (g.bind_id, load_groom(g.output))
        rt.groom_shown = None
    return rt.groom[1]


def remove_groom(src) -> None:
    """Delete the setup's groom output and show its Render Groom again."""
    g = src.furcollide.groom
    remove_groom_output(g.output)
    g.output = None
    g.bind_id = ""
    if g.groom is not None:
        hide_in_viewport(g.groom, False, render=False)
    rt = get_runtime(src, create=False)
    if rt is not None:
        rt.groom = rt.groom_shown = None


# -------------------------------------------------------------- binding
class GroomBinding:
    """A render groom bound to a setup's guides (see ``furcollide.groom_bind``)."""

    def __init__(self, arrays: dict):
        self.render_ref = np.asarray(arrays["render_ref"], np.float64)
        self.render_offsets = np.asarray(arrays["render_offsets"], np.int64)
        self.guides_ref = np.asarray(arrays["guides_ref"], np.float64)
        self.guide_offsets = np.asarray(arrays["guide_offsets"], np.int64)
        self.weights = pipeline.GroomWeights.from_arrays(
            {"index": arrays["weights_index"], "weight": arrays["weights_weight"]}
        )
        self.roots = None  # Binding of the render roots to the Surface (optional)
        self.surface_key = None
        if "root_face" in arrays:
            self.roots = pipeline.Binding.from_arrays(
                {k[5:]: arrays[k] for k in arrays if k.startswith("root_")}
            )
            self.surface_key = tuple(int(k) for k in arrays["surface_key"])

    @staticmethod
    def build(render_ref, render_offsets, guides_ref, guide_offsets, k, surface=None):
        """Bind (all world space, reference pose). ``surface``: (V, F, key) or None."""
        render_ref = np.asarray(render_ref, np.float64)
        guides_ref = np.asarray(guides_ref, np.float64)
        weights = pipeline.bind_groom(render_ref[render_offsets[:-1]],
                                      guides_ref[guide_offsets[:-1]],
                                      k=min(int(k), len(guide_offsets) - 1))
        arrays = {
            "render_ref": render_ref, "render_offsets": np.asarray(render_offsets, np.int64),
            "guides_ref": guides_ref, "guide_offsets": np.asarray(guide_offsets, np.int64),
            "weights_index": weights.index, "weights_weight": weights.weight,
        }
        if surface is not None:
            V, F, key = surface
            b = pipeline.bind(render_ref, render_offsets, V, F, drop_degenerate=True)
            arrays.update({"root_" + k: v for k, v in b.arrays().items()})
            arrays["surface_key"] = np.asarray(key, np.int64)
        return arrays

    def deform(self, guides_now, surface_V=None) -> np.ndarray:
        """(P, 3) float64 render curves following ``guides_now`` (world)."""
        roots = None
        if self.roots is not None and surface_V is not None:
            roots = self.roots.roots(surface_V)
        return pipeline.deform_groom(
            self.render_ref, self.render_offsets, self.guides_ref, guides_now,
            self.guide_offsets, self.weights, render_roots_now=roots,
        )


def store_groom(out, arrays: dict) -> None:
    """Save the groom binding on the groom output object ``out``."""
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    if GROOM_PROPERTY in out.keys():
        # Blender truncates bytes assigned over an existing bytes property at
        # their first NUL byte: a second Bind Groom would corrupt the binding.
        del out[GROOM_PROPERTY]
    out[GROOM_PROPERTY] = buf.getvalue()


def has_groom(out) -> bool:
    try:
        return out is not None and GROOM_PROPERTY in out.keys()
    except (TypeError, AttributeError, ReferenceError):
        return False


def load_groom(out) -> GroomBinding:
    """The groom binding saved on ``out`` (ValueError when there is none)."""
    if not has_groom(out):
        raise ValueError(
            f"'{out.name}' holds no render groom binding: press Bind Groom again"
        )
    raw = out[GROOM_PROPERTY]
    if not isinstance(raw, bytes):
        raw = bytes(raw)
    with np.load(io.BytesIO(raw), allow_pickle=False) as d:
        return GroomBinding({k: d[k] for k in d.files})


def groom_frame(setup, binding, guides_world, colliders):
    """Deform the render groom of ``setup`` and run its clearance pass.

    Returns
    -------
    points : (P, 3) float32 ndarray (world)
    n_fixed : int
        Render curves the clearance pass moved (0 when it is off).
    """
    ob, depsgraph = setup.ob, setup.depsgraph
    g = ob.furcollide.groom
    if guides_world.shape != binding.guides_ref.shape:
        raise ValueError(
            f"Render groom: the guides now have {len(guides_world)} points but were bound "
            f"with {len(binding.guides_ref)}: press Bind Groom again"
        )
    V = None
    surf = ob.data.surface
    if binding.roots is not None and surf is not None and surf.type == "MESH":
        se = surf.evaluated_get(depsgraph)
        if bridge.same_topology(bridge.mesh_topology_key(se.data), binding.surface_key):
            V = bridge.transform(bridge.mesh_vertices(se.data).astype(np.float64),
                                 bridge.matrix(se))
    pts = binding.deform(np.asarray(guides_world, np.float64), V)
    n_fixed = 0
    if g.use_clearance and colliders:
        # Stiff (the minimal rotation at the root, shape kept) with the setup's own
        # Collision Offset: render strands keep the same gap as the guides.
        settings = core.Settings(mode="stiff", collision_offset=ob.furcollide.collision_offset)
        pts, _status, n_fixed = pipeline.clearance_pass(
            pts, binding.render_offsets, colliders, settings=settings
        )
    return np.asarray(pts, np.float32), int(n_fixed)


def write_groom(out, points_world, offsets, depsgraph) -> None:
    """Write the render groom's world points into the groom output's data."""
    if problem := bridge.write_refusal(out, "render groom output"):
        raise ValueError(problem)
    data = out.data
    have = bridge.curve_offsets(data)
    if len(have) != len(offsets) or not np.array_equal(have, offsets):
        raise ValueError(
            f"The groom output '{out.name}' has other curves than the bound groom "
            "(edited?): press Bind Groom again"
        )
    M_inv = bridge.matrix(out.evaluated_get(depsgraph), inverted=True)
    bridge.set_positions(data, bridge.transform(points_world, M_inv))


def remove_groom_output(out) -> None:
    """Delete the groom output object (it belongs to FurCollide) and its data."""
    if out is None:
        return
    data = out.data
    bpy.data.objects.remove(out)
    if data is not None and data.users == 0:
        bpy.data.hair_curves.remove(data)
