"""The stages around the solver in the frame handler (paper sections 2 and 4).

Thin glue: every computation is a :mod:`..core.pipeline` call.

* **Motion before collision** (``Stage = Before Collision``): wind and/or jiggle
  move the input curves; FurCollide resolves the moved curves.
* **Motion after collision** (``Stage = After Collision``): wind and/or jiggle
  move the collided curves, restricted per point by the **Region of Influence**
  (:func:`core.pipeline.region_of_influence`) to less than its **Fur Collider
  Distance**, so the result stays collision free.
* **Collider distance attribute**: ``furcollide_collider_distance`` on the
  output, the distance of every point's segments to the colliders.
* **Render groom**: a dense groom bound to the guides (``furcollide.groom_bind``)
  follows the collided guides (:func:`core.pipeline.deform_groom`), then the
  **clearance pass** (:func:`core.pipeline.clearance_pass`) frees the render
  curves that still cross a collider; their count is a panel statistic.

Jiggle needs the roots of the last frames: the handler records them
(:class:`RootHistory`) while it plays; frames it never saw take the roots of
the nearest later frame it saw (hair at rest before the start frame).
"""

from __future__ import annotations

import io

import bpy
import numpy as np

from . import bridge

#: Per-point attribute with the Fur Collider Distance on the output.
DISTANCE_ATTRIBUTE = "furcollide_collider_distance"
#: Custom property (bytes of an ``np.savez`` file) on the groom output object with
#: the render groom binding (reference poses, guide weights, optional root binding).
GROOM_PROPERTY = "_furcollide_groom"
#: Frames of root history kept per setup for jiggle (its window is at most 240).
HISTORY_FRAMES = 480


def _pipeline():
    from ..core import pipeline

    return pipeline


def fps(scene) -> float:
    """Frames per second of ``scene``."""
    return scene.render.fps / (scene.render.fps_base or 1.0)


# ------------------------------------------------------------- root history
class RootHistory:
    """Curve roots (world) per whole frame, recorded by the handler for jiggle."""

    def __init__(self):
        self.frames: dict[int, np.ndarray] = {}
        self.key = None  # curve layout the roots belong to

    def record(self, f: int, roots: np.ndarray, key) -> None:
        if key != self.key:
            self.frames.clear()
            self.key = key
        self.frames[int(f)] = np.asarray(roots, np.float32).copy()
        if len(self.frames) > HISTORY_FRAMES:  # forget the frames farthest from f
            far = sorted(self.frames, key=lambda k: (abs(k - f), k))[HISTORY_FRAMES:]
            for k in far:
                del self.frames[k]

    def drop_after(self, f: int) -> None:
        for k in [k for k in self.frames if k > f]:
            del self.frames[k]

    def lookup(self, f: int) -> np.ndarray:
        """Roots at frame ``f``: recorded, else those of the nearest later recorded frame."""
        got = self.frames.get(int(round(f)))
        if got is not None:
            return got
        later = [k for k in self.frames if k > f]
        k = min(later) if later else max(self.frames)
        return self.frames[k]


# -------------------------------------------------------------------- motion
def _wind(m, points, offsets, f, scene):
    return _pipeline().wind(
        points, offsets, f, direction=tuple(m.wind_direction), strength=m.wind_strength,
        frequency=m.wind_frequency, turbulence=m.wind_turbulence, falloff=m.wind_falloff,
        seed=m.wind_seed, scale=m.wind_scale, fps=fps(scene),
    )


def _jiggle(m, points, offsets, f, scene, history):
    return _pipeline().jiggle(
        points, offsets, history.lookup, frame=f, fps=fps(scene),
        stiffness=m.jiggle_stiffness, damping=m.jiggle_damping, amount=m.jiggle_amount,
        falloff=m.jiggle_falloff,
    )


def apply_motion(ob, stage, points, offsets, f, scene, history) -> np.ndarray | None:
    """Wind then jiggle of the setup on ``ob`` that run at ``stage`` ('INPUT' or
    'OUTPUT'); None when none does. ``points`` (P, 3) world; returns float64."""
    m = ob.furcollide.motion
    out = None
    if m.use_wind and m.wind_stage == stage and m.wind_strength > 0:
        out = _wind(m, points if out is None else out, offsets, f, scene)
    if m.use_jiggle and m.jiggle_stage == stage and m.jiggle_amount > 0 and history.frames:
        out = _jiggle(m, points if out is None else out, offsets, f, scene, history)
    return out


def needs_history(ob) -> bool:
    m = ob.furcollide.motion
    return bool(m.use_jiggle)


def output_stage(ob, points, offsets, f, scene, history, colliders):
    """Motion after collision with its Region of Influence, and the collider distance.

    Parameters
    ----------
    ob : the setup's source object.
    points : (P, 3) float32 ndarray
        The solver's collided curves (world).
    offsets : (C+1,) int ndarray
    f : int
        Frame.
    scene : bpy.types.Scene
    history : RootHistory
    colliders : list of core.Collider
        This frame's colliders.

    Returns
    -------
    points : (P, 3) float32 ndarray
        Final curves (``points`` itself when nothing moved them).
    attributes : dict
        ``{DISTANCE_ATTRIBUTE: (P,) float32}`` when the attribute is on.
    """
    m = ob.furcollide.motion
    pl = _pipeline()
    moved = apply_motion(ob, "OUTPUT", points, offsets, f, scene, history)
    attributes = {}
    distance = None
    if m.write_collider_distance:
        cap = float(m.distance_max) if m.distance_max > 0 else None
        distance = _distance(points, offsets, colliders, cap)
        if cap is not None:  # nothing within the cap (no collider either): the cap
            distance = np.minimum(distance, cap)
        attributes[DISTANCE_ATTRIBUTE] = np.asarray(distance, np.float32)
    if moved is None:
        return points, attributes
    if m.use_region_of_influence and colliders:
        reach = float(np.sqrt(((moved - points) ** 2).sum(1).max())) if len(points) else 0.0
        if distance is None or (m.distance_max > 0 and m.distance_max < reach):
            # RoI only clamps displacements longer than the distance: capped at the
            # longest displacement, the distance gives the same result, faster.
            distance = _distance(points, offsets, colliders, reach)
        moved = pl.region_of_influence(points, offsets, moved, distance, margin=m.roi_margin)
    return np.asarray(moved, np.float32), attributes


def _distance(points, offsets, colliders, cap):
    pl = _pipeline()
    if not colliders:
        return np.full(len(points), np.inf)
    return pl.collider_distance(points, offsets, colliders, max_distance=cap)


def write_attributes(data, attributes: dict) -> None:
    """Write per-point float attributes (name -> (P,) array) into hair ``data``."""
    for name, values in attributes.items():
        attr = data.attributes.get(name)
        if attr is not None and (attr.data_type != "FLOAT" or attr.domain != "POINT"):
            data.attributes.remove(attr)
            attr = None
        if attr is None:
            attr = data.attributes.new(name, "FLOAT", "POINT")
        if len(attr.data) != len(values):
            raise bridge.BridgeError(
                f"'{data.name}' has {len(attr.data)} points but {len(values)} values of "
                f"'{name}' were computed"
            )
        attr.data.foreach_set("value", np.ascontiguousarray(values, np.float32))


# -------------------------------------------------------------- render groom
class GroomBinding:
    """A render groom bound to a setup's guides (see ``furcollide.groom_bind``)."""

    def __init__(self, arrays: dict):
        pl = _pipeline()
        self.render_ref = np.asarray(arrays["render_ref"], np.float64)
        self.render_offsets = np.asarray(arrays["render_offsets"], np.int64)
        self.guides_ref = np.asarray(arrays["guides_ref"], np.float64)
        self.guide_offsets = np.asarray(arrays["guide_offsets"], np.int64)
        self.weights = pl.GroomWeights.from_arrays(
            {"index": arrays["weights_index"], "weight": arrays["weights_weight"]}
        )
        self.roots = None  # Binding of the render roots to the Surface (optional)
        self.surface_key = None
        if "root_face" in arrays:
            self.roots = pl.Binding.from_arrays(
                {k[5:]: arrays[k] for k in arrays if k.startswith("root_")}
            )
            self.surface_key = tuple(int(k) for k in arrays["surface_key"])

    @staticmethod
    def build(render_ref, render_offsets, guides_ref, guide_offsets, k, surface=None):
        """Bind (all world space, reference pose). ``surface``: (V, F, key) or None."""
        pl = _pipeline()
        render_ref = np.asarray(render_ref, np.float64)
        guides_ref = np.asarray(guides_ref, np.float64)
        weights = pl.bind_groom(render_ref[render_offsets[:-1]], guides_ref[guide_offsets[:-1]],
                                k=min(int(k), len(guide_offsets) - 1))
        arrays = {
            "render_ref": render_ref, "render_offsets": np.asarray(render_offsets, np.int64),
            "guides_ref": guides_ref, "guide_offsets": np.asarray(guide_offsets, np.int64),
            "weights_index": weights.index, "weights_weight": weights.weight,
        }
        if surface is not None:
            V, F, key = surface
            b = pl.bind(render_ref, render_offsets, V, F, drop_degenerate=True)
            arrays.update({"root_" + k: v for k, v in b.arrays().items()})
            arrays["surface_key"] = np.asarray(key, np.int64)
        return arrays

    def deform(self, guides_now, surface_V=None) -> np.ndarray:
        """(P, 3) float64 render curves following ``guides_now`` (world)."""
        roots = None
        if self.roots is not None and surface_V is not None:
            roots = self.roots.roots(surface_V)
        return _pipeline().deform_groom(
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


def groom_frame(ob, binding, guides_world, depsgraph, colliders):
    """Deform the render groom of the setup on ``ob`` and run its clearance pass.

    Returns
    -------
    points : (P, 3) float32 ndarray (world)
    n_fixed : int
        Render curves the clearance pass moved (0 when it is off).
    """
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
        from ..core import Settings

        # Stiff (the minimal rotation at the root, shape kept) with the setup's own
        # Collision Offset: render strands keep the same gap as the guides.
        settings = Settings(mode="stiff", collision_offset=ob.furcollide.collision_offset)
        pts, _status, n_fixed = _pipeline().clearance_pass(
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
