"""Build the FurCollide demo scene with the bpy API (no add-on needed).

Three FurCollide situations from the paper's Figure 1, side by side:

* **Fur on a body**: a furry ball (the growth surface, with UVs) whose fur
  is hit by an animated *Pusher* sphere that pushes through the fur and
  then into the skin (roots end up inside the pusher: *pinched*), and a
  thin single-sided *Cloth* that comes down and lies on the fur. The body
  turns slowly about its centre (for Fur Attach in the demo's pipeline).
* **Grass**: a patch of blades with a *Ball* rolling across it (Bend with
  recovery and plasticity leaves a trampled trail).

Everything is deterministic (fixed random seed). Hair objects are real
``Curves`` objects with ``surface``, ``surface_uv_map`` and the per-curve
``surface_uv_coordinate`` set, like Blender's own hair. Sizes are metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import bpy
import numpy as np
from mathutils import Euler, Vector

FRAME_START = 1
FRAME_END = 48
STILL_FRAME = 28  # pusher deepest, cloth resting, ball over the grass
#: The grass's painted path (a per-blade float attribute, 1 on the ball's track, 0.35
#: away from it) and its half-width (m): the grass setup's Plasticity map.
PATH_ATTRIBUTE = "trampled_path"
PATH_WIDTH = 0.12

BODY_CENTER = Vector((-0.8, 0.35, 0.85))
BODY_RADIUS = 0.52
FUR_LENGTH = 0.17

GRASS_CENTER = Vector((0.95, 0.45, 0.0))
GRASS_SIZE = (1.9, 1.5)
GRASS_LENGTH = (0.2, 0.32)
BALL_RADIUS = 0.25
BALL_END = 38  # the ball has crossed the patch by this frame

PUSHER_RADIUS = 0.27
PUSHER_DIR = Vector((-0.9, -0.4, -0.08)).normalized()  # from the left, below the cloth
PINCH_DEPTH = 0.1  # how deep the pusher goes into the skin at its deepest

CLOTH_REST = 0.10  # cloth height above the skin when resting (fur is 0.17)

# The body turns slowly about its centre (degrees at FRAME_END, XYZ Euler): a
# sphere turning in place keeps its shape, so hair that does not follow it
# (the plain setup) still sits on it, while Fur Attach carries the pipeline's
# guides and render groom around with the skin.
BODY_TURN = (8.0, 0.0, 40.0)


@dataclass
class DemoScene:
    """Handles to everything :func:`build` made."""

    scene: bpy.types.Scene
    body: bpy.types.Object
    fur: bpy.types.Object
    pusher: bpy.types.Object
    cloth: bpy.types.Object
    ground: bpy.types.Object
    grass: bpy.types.Object
    ball: bpy.types.Object
    camera: bpy.types.Object
    closeup: bpy.types.Object
    materials: dict = field(default_factory=dict)
    furcam: bpy.types.Object | None = None  # framing the body only (pipeline pictures)

    @property
    def setups(self):
        """(hair object, collider objects, settings name) per FurCollide setup."""
        return [
            (self.fur, [self.pusher, self.cloth], "fur"),
            (self.grass, [self.ball], "grass"),
        ]


# ----------------------------------------------------------------- helpers


def _material(name, color, roughness=0.5, hair=False, emission=0.0):
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # Blender < 5.0; 5.0 deprecates use_nodes
        mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    if hair:
        # A touch of sheen-like coat so strands read as strands at low res.
        bsdf.inputs["Coat Weight"].default_value = 0.15
    if emission:
        bsdf.inputs["Emission Color"].default_value = (*color, 1.0)
        bsdf.inputs["Emission Strength"].default_value = emission
    mat.diffuse_color = (*color, 1.0)
    return mat


def _status_material(name, attribute="furcollide_color"):
    """Hair material coloured by a point colour attribute (FurCollide's status colours)."""
    mat = _material(name, (0.6, 0.6, 0.6), 0.5, True)
    nt = mat.node_tree
    bsdf = nt.nodes.get("Principled BSDF")
    node = nt.nodes.new("ShaderNodeAttribute")
    node.attribute_name = attribute
    nt.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def distance_material(name, max_distance, attribute="furcollide_collider_distance"):
    """Hair material coloured by a point float attribute (FurCollide's collider
    distance): red on the colliders, yellow half way, blue at ``max_distance``
    and beyond (the cap of the attribute)."""
    mat = _material(name, (0.6, 0.6, 0.6), 0.5, True)
    nt = mat.node_tree
    bsdf = nt.nodes.get("Principled BSDF")
    node = nt.nodes.new("ShaderNodeAttribute")
    node.attribute_name = attribute
    scale = nt.nodes.new("ShaderNodeMapRange")  # 0..max_distance -> 0..1, clamped
    scale.inputs["From Min"].default_value = 0.0
    scale.inputs["From Max"].default_value = max_distance
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    els = ramp.color_ramp.elements
    els[0].position, els[0].color = 0.0, (0.9, 0.03, 0.02, 1.0)
    els[1].position, els[1].color = 1.0, (0.25, 0.5, 1.0, 1.0)
    mid = els.new(0.4)
    mid.color = (1.0, 0.8, 0.05, 1.0)
    nt.links.new(node.outputs["Fac"], scale.inputs["Value"])
    nt.links.new(scale.outputs["Result"], ramp.inputs["Fac"])
    nt.links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def _link(ob, collection=None):
    (collection or bpy.context.scene.collection).objects.link(ob)
    return ob


def mesh_object(name, V, F, corner_uv, normals, smooth=True):
    """A mesh object from triangles, with a "UVMap" and the sampling data.

    The geometry is generated here in numpy (not with bmesh primitives) so
    the scene is bit-for-bit reproducible; ``_sampling`` keeps the arrays
    :func:`sample_surface` needs (triangles, per-vertex unit normals and
    per-corner UVs), in the object's local space.
    """
    me = bpy.data.meshes.new(name)
    me.from_pydata(np.asarray(V, np.float64).tolist(), [], np.asarray(F).tolist())
    uv = me.uv_layers.new(name="UVMap")
    uv.data.foreach_set("uv", np.asarray(corner_uv, np.float32).ravel())
    me.update()
    if smooth:
        me.shade_smooth()
    ob = _link(bpy.data.objects.new(name, me))
    _SAMPLING[ob.name] = (
        np.asarray(V, np.float64),
        np.asarray(F, np.int64),
        np.asarray(normals, np.float64),
        np.asarray(corner_uv, np.float64),
    )
    return ob


_SAMPLING: dict = {}


def uv_sphere(name, radius, segments=48, rings=24):
    """A closed (welded) UV sphere made of triangles, with UVs."""
    th = np.linspace(0.0, np.pi, rings + 1)[1:-1]  # ring polar angles
    ph = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    ring = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    N = np.concatenate([[[0, 0, 1]], ring.reshape(-1, 3), [[0, 0, -1]]])
    top, bot = 0, len(N) - 1

    def vid(i, j):  # ring i (0..rings-2), segment j (wraps)
        return 1 + i * segments + (j % segments)

    def uv(i, j):  # ring i in -1..rings-1 (-1 = top pole), unwrapped segment j
        return (j / segments, 1.0 - (i + 1) / rings)

    F, UV = [], []
    for j in range(segments):
        F.append((top, vid(0, j), vid(0, j + 1)))
        UV.append((((j + 0.5) / segments, 1.0), uv(0, j), uv(0, j + 1)))
        last = rings - 2
        F.append((vid(last, j), bot, vid(last, j + 1)))
        UV.append((uv(last, j), ((j + 0.5) / segments, 0.0), uv(last, j + 1)))
    for i in range(rings - 2):
        for j in range(segments):
            a, b, c, d = vid(i, j), vid(i + 1, j), vid(i + 1, j + 1), vid(i, j + 1)
            F += [(a, b, c), (a, c, d)]
            UV += [
                (uv(i, j), uv(i + 1, j), uv(i + 1, j + 1)),
                (uv(i, j), uv(i + 1, j + 1), uv(i, j + 1)),
            ]
    return mesh_object(name, N * radius, F, UV, N)


def grid(name, size_x, size_y, nx, ny, flip=False):
    """A flat triangulated grid in XY (normals +Z, or -Z if ``flip``), centred, with UVs."""
    u = np.linspace(0.0, 1.0, nx + 1)
    v = np.linspace(0.0, 1.0, ny + 1)
    U, W = np.meshgrid(u, v, indexing="ij")
    V = np.stack([(U - 0.5) * size_x, (W - 0.5) * size_y, np.zeros_like(U)], -1).reshape(-1, 3)
    UVv = np.stack([U, W], -1).reshape(-1, 2)
    F = []
    for i in range(nx):
        for j in range(ny):
            a, b = i * (ny + 1) + j, (i + 1) * (ny + 1) + j
            F += [(a, b, b + 1), (a, b + 1, a + 1)]
    F = np.array(F)[:, ::-1] if flip else np.array(F)
    N = np.tile([0.0, 0.0, -1.0 if flip else 1.0], (len(V), 1))
    return mesh_object(name, V, F, UVv[F], N, smooth=False)


def sample_surface(ob, count, rng):
    """Area-weighted random points on a :func:`mesh_object`'s triangles.

    Returns world positions, unit normals (smooth) and UVs, each per sample.
    """
    co, F, nrm, cuv = _SAMPLING[ob.name]
    M = np.array(ob.matrix_world, np.float64)
    co = co @ M[:3, :3].T + M[:3, 3]
    nrm = nrm @ np.linalg.inv(M[:3, :3])
    a, b, c = co[F[:, 0]], co[F[:, 1]], co[F[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    t = rng.choice(len(F), size=count, p=area / area.sum())
    r1, r2 = rng.random(count), rng.random(count)
    s = np.sqrt(r1)
    w = np.stack([1 - s, s * (1 - r2), s * r2], 1)  # uniform barycentrics
    pos = np.einsum("ij,ijk->ik", w, co[F[t]])
    n = np.einsum("ij,ijk->ik", w, nrm[F[t]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    uvs = np.einsum("ij,ijk->ik", w, cuv[t])
    return pos, n, uvs


def make_hair(name, surface, points, n_cv, uvs, radius_root, radius_tip, material):
    """A hair ``Curves`` object on ``surface`` from (C*n_cv, 3) world points."""
    count = len(points) // n_cv
    hc = bpy.data.hair_curves.new(name)
    hc.add_curves([n_cv] * count)
    hc.position_data.foreach_set("vector", points.astype(np.float32).ravel())
    rad = np.tile(np.linspace(radius_root, radius_tip, n_cv, dtype=np.float32), count)
    attr = hc.attributes.get("radius") or hc.attributes.new("radius", "FLOAT", "POINT")
    attr.data.foreach_set("value", rad)
    uv_attr = hc.attributes.get("surface_uv_coordinate") or hc.attributes.new(
        "surface_uv_coordinate", "FLOAT2", "CURVE"
    )
    uv_attr.data.foreach_set("vector", uvs.astype(np.float32).ravel())
    hc.surface = surface
    hc.surface_uv_map = surface.data.uv_layers.active.name
    hc.materials.append(material)
    hc.update_tag()
    return _link(bpy.data.objects.new(name, hc))


def _grow(roots, normals, comb, lengths, n_cv, bend, rng, jitter=0.12):
    """Curves from ``roots`` along ``normals``, bending towards ``comb``.

    Segment ``k`` leans ``bend * k / (n_cv - 2)`` of the way from the
    (jittered) normal to the comb direction: a groomed, gently curved strand.
    """
    count = len(roots)
    d0 = normals + rng.normal(0.0, jitter, (count, 3))
    d0 /= np.linalg.norm(d0, axis=1, keepdims=True)
    comb = comb / np.linalg.norm(comb, axis=1, keepdims=True)
    seg = (lengths / (n_cv - 1))[:, None]
    pts = np.empty((count, n_cv, 3))
    pts[:, 0] = roots
    for k in range(1, n_cv):
        f = bend * (k - 1) / max(1, n_cv - 2)
        d = (1 - f) * d0 + f * comb
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        pts[:, k] = pts[:, k - 1] + seg * d
    return pts.reshape(-1, 3)


def _key_location(ob, frames_locs, interpolation="BEZIER"):
    for f, loc in frames_locs:
        ob.location = loc
        ob.keyframe_insert("location", frame=f)
    _set_interpolation(ob, interpolation)


def _set_interpolation(ob, interpolation):
    ad = ob.animation_data
    if ad is None or ad.action is None:
        return
    fcurves = getattr(ad.action, "fcurves", None)
    if fcurves is None:  # Blender 5.0 layered actions
        fcurves = []
        for layer in ad.action.layers:
            for strip in layer.strips:
                for bag in strip.channelbags:
                    fcurves.extend(bag.fcurves)
    for fc in fcurves:
        for kp in fc.keyframe_points:
            kp.interpolation = interpolation


# ----------------------------------------------------------------- scene


def build(fur_count=3500, grass_count=2500, seed=7, n_cv=8) -> DemoScene:
    """Reset to an empty scene and build the demo; return the handles."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.name = "FurCollide Demo"
    scene.frame_start, scene.frame_end = FRAME_START, FRAME_END
    scene.render.fps = 24
    rng = np.random.default_rng(seed)
    mats = {
        "skin": _material("Skin", (0.8, 0.62, 0.5), 0.6),
        "fur_before": _material("Fur (source, no collision)", (0.95, 0.33, 0.05), 0.45, True),
        "fur_after": _material("Fur (FurCollide result)", (0.05, 0.55, 0.85), 0.45, True),
        "grass_before": _material("Grass (source)", (0.85, 0.55, 0.05), 0.5, True),
        "grass_after": _material("Grass (FurCollide result)", (0.12, 0.55, 0.12), 0.5, True),
        "pusher": _material("Pusher", (0.85, 0.85, 0.82), 0.3),
        "cloth": _material("Cloth", (0.18, 0.12, 0.4), 0.8),
        "ball": _material("Ball", (0.9, 0.9, 0.88), 0.25),
        "soil": _material("Soil", (0.16, 0.11, 0.07), 0.9),
        "floor": _material("Floor", (0.22, 0.23, 0.25), 0.8),
        "guides": _material("Guides", (0.95, 0.8, 0.1), 0.45, True),
        "render_groom": _material("Render groom (FurCollide)", (0.1, 0.7, 0.55), 0.45, True),
        "status": _status_material("Guides by FurCollide status"),
    }

    # --- body with fur ------------------------------------------------------
    body = uv_sphere("Body", BODY_RADIUS, 64, 32)
    body.location = BODY_CENTER
    body.data.materials.append(mats["skin"])
    bpy.context.view_layer.update()
    roots, normals, uvs = sample_surface(body, fur_count, rng)
    for f, turn in ((FRAME_START, (0.0, 0.0, 0.0)), (FRAME_END, BODY_TURN)):
        body.rotation_euler = [math.radians(a) for a in turn]
        body.keyframe_insert("rotation_euler", frame=f)
    _set_interpolation(body, "LINEAR")
    # Groom: comb down and a little back (away from the camera).
    comb = np.tile(np.array([0.0, 0.35, -1.0]), (fur_count, 1))
    comb -= normals * np.einsum("ij,ij->i", comb, normals)[:, None]  # tangent part
    comb = comb + 0.6 * normals  # stay off the skin
    lengths = FUR_LENGTH * rng.uniform(0.8, 1.15, fur_count)
    pts = _grow(roots, normals, comb, lengths, n_cv, bend=0.75, rng=rng)
    fur = make_hair("Fur", body, pts, n_cv, uvs, 0.0075, 0.0025, mats["fur_before"])

    # --- pusher: through the fur, into the skin (pinch), back out -----------
    pusher = uv_sphere("Pusher", PUSHER_RADIUS, 32, 16)
    pusher.data.materials.append(mats["pusher"])
    d = PUSHER_DIR

    def at(gap):  # pusher centre with its surface ``gap`` above the skin
        return BODY_CENTER + d * (BODY_RADIUS + PUSHER_RADIUS + gap)

    _key_location(
        pusher,
        [
            (1, at(0.75)),
            (8, at(0.45)),
            (STILL_FRAME, at(-PINCH_DEPTH)),
            (38, at(0.05)),
            (FRAME_END, at(0.7)),
        ],
    )

    # --- cloth: a thin single-sided sheet that comes down onto the fur ------
    # Its front faces the fur (normals point down), the side it pushes towards.
    nx = ny = 28
    cloth = grid("Cloth", 1.0, 1.0, nx, ny, flip=True)
    me = cloth.data
    co = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3).astype(np.float64)
    x, y = co[:, 0] * 0.9, co[:, 1] * 0.9
    rr = BODY_RADIUS + CLOTH_REST
    r2 = x * x + y * y
    z = np.sqrt(np.maximum(rr * rr - r2, 0.0))
    # Past the shoulder the cloth hangs straight down (a simple drape).
    r = np.sqrt(r2)
    rim = 0.74 * rr
    over = np.maximum(r - rim, 0.0)
    z = np.where(r > rim, math.sqrt(rr * rr - rim * rim) - 1.3 * over, z)
    scale = np.where(r > rim, rim / np.maximum(r, 1e-9) + over / np.maximum(r, 1e-9) * 0.25, 1)
    x, y = x * scale, y * scale
    wrinkle = 0.008 * np.sin(9 * x + 3 * y) * np.sin(7 * y)
    co = np.stack([x, y, z + wrinkle], 1).astype(np.float32)
    me.vertices.foreach_set("co", co.ravel())
    me.update()
    me.shade_smooth()
    me.materials.append(mats["cloth"])
    cloth.rotation_euler = Euler((0.0, math.radians(-18), math.radians(25)))
    _key_location(
        cloth,
        [(1, BODY_CENTER + Vector((0, 0, 0.55))), (16, BODY_CENTER), (FRAME_END, BODY_CENTER)],
    )

    # --- grass patch with a rolling ball -------------------------------------
    ground = grid("Grass Ground", GRASS_SIZE[0], GRASS_SIZE[1], 24, 20)
    ground.location = GRASS_CENTER + Vector((0, 0, 0.002))
    ground.data.materials.append(mats["soil"])
    bpy.context.view_layer.update()
    groots, gnormals, guvs = sample_surface(ground, grass_count, rng)
    lean = np.column_stack(
        [rng.normal(0, 1, grass_count), rng.normal(0, 1, grass_count), np.zeros(grass_count)]
    )
    gcomb = gnormals + 0.55 * lean
    glen = rng.uniform(*GRASS_LENGTH, grass_count)
    gpts = _grow(groots, gnormals, gcomb, glen, n_cv, bend=0.4, rng=rng, jitter=0.1)
    grass = make_hair("Grass", ground, gpts, n_cv, guvs, 0.009, 0.002, mats["grass_before"])
    # A painted path along the ball's track (as an artist would weight-paint it and store
    # it per blade): the grass there keeps more of its imprint (a Plasticity map).
    yb = GRASS_CENTER.y - 0.1
    path = 0.35 + 0.65 * np.exp(-(((groots[:, 1] - yb) / PATH_WIDTH) ** 2))
    grass.data.attributes.new(PATH_ATTRIBUTE, "FLOAT", "CURVE").data.foreach_set(
        "value", path.astype(np.float32))

    ball = uv_sphere("Ball", BALL_RADIUS, 32, 16)
    ball.data.materials.append(mats["ball"])
    x0 = GRASS_CENTER.x - GRASS_SIZE[0] / 2 - BALL_RADIUS - 0.1
    x1 = GRASS_CENTER.x + GRASS_SIZE[0] / 2 + BALL_RADIUS + 0.05
    zb = BALL_RADIUS + 0.025
    _key_location(ball, [(1, (x0, yb, zb)), (BALL_END, (x1, yb, zb))], "LINEAR")
    for f, xx in ((1, x0), (BALL_END, x1)):
        ball.rotation_euler = (0.0, (xx - x0) / BALL_RADIUS, 0.0)
        ball.keyframe_insert("rotation_euler", frame=f)
    _set_interpolation(ball, "LINEAR")

    # --- floor, lights, camera, world -----------------------------------------
    floor = grid("Floor", 120.0, 120.0, 1, 1)
    floor.data.materials.append(mats["floor"])

    sun = bpy.data.lights.new("Key", "SUN")
    sun.energy = 3.5
    sun.angle = math.radians(8)
    key = _link(bpy.data.objects.new("Key", sun))
    key.rotation_euler = Euler((math.radians(50), math.radians(10), math.radians(-35)))
    fill = bpy.data.lights.new("Rim", "AREA")
    fill.energy = 250
    fill.size = 3.0
    rim_ob = _link(bpy.data.objects.new("Rim", fill))
    rim_ob.location = (0.5, 4.0, 3.5)
    rim_ob.rotation_euler = (
        (Vector((0, 0.4, 0.6)) - rim_ob.location).to_track_quat("-Z", "Y").to_euler()
    )

    world = bpy.data.worlds.new("World")
    if world.node_tree is None:
        world.use_nodes = True
    bg = world.node_tree.nodes.get("Background")
    bg.inputs["Color"].default_value = (0.05, 0.06, 0.08, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    scene.world = world

    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = 42
    cam = _link(bpy.data.objects.new("Camera", cam_data))
    cam.location = (0.0, -4.3, 2.55)
    target = Vector((0.0, 0.45, 0.55))
    cam.rotation_euler = (target - cam.location).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam

    # A close-up of the pinch, looking across the pusher's path (side-on).
    close_data = bpy.data.cameras.new("Camera Closeup")
    close_data.lens = 50
    close = _link(bpy.data.objects.new("Camera Closeup", close_data))
    contact = BODY_CENTER + PUSHER_DIR * BODY_RADIUS
    side = PUSHER_DIR.cross(Vector((0, 0, 1))).normalized()
    if side.y > 0:
        side = -side
    aim = contact - PUSHER_DIR * 0.22 + Vector((0, 0, 0.02))
    close.location = aim + side * 2.3 + Vector((0, 0, 1.05))
    close.rotation_euler = (aim - close.location).to_track_quat("-Z", "Y").to_euler()

    # The fur alone, from the front left: the pusher's side and the cloth on top.
    fur_data = bpy.data.cameras.new("Camera Fur")
    fur_data.lens = 50
    furcam = _link(bpy.data.objects.new("Camera Fur", fur_data))
    aim = BODY_CENTER + Vector((-0.15, 0.0, 0.1))
    furcam.location = aim + Vector((-0.55, -1.0, 0.55)).normalized() * 3.6
    furcam.rotation_euler = (aim - furcam.location).to_track_quat("-Z", "Y").to_euler()

    scene.frame_set(FRAME_START)
    return DemoScene(
        scene, body, fur, pusher, cloth, ground, grass, ball, cam, close, mats, furcam=furcam
    )


def hair_points(ob) -> np.ndarray:
    """World-space (P, 3) float32 points of a hair object's original data."""
    hc = ob.data
    p = np.empty(len(hc.points) * 3, np.float32)
    hc.position_data.foreach_get("vector", p)
    p = p.reshape(-1, 3)
    M = np.array(ob.matrix_world, np.float32)
    return (p @ M[:3, :3].T + M[:3, 3]).astype(np.float32)


def set_hair_points_world(ob, pts_world) -> None:
    hc = ob.data
    M = np.linalg.inv(np.array(ob.matrix_world, np.float64))
    p = (pts_world.astype(np.float64) @ M[:3, :3].T + M[:3, 3]).astype(np.float32)
    hc.position_data.foreach_set("vector", p.ravel())
    hc.update_tag()


def curve_offsets(ob) -> np.ndarray:
    hc = ob.data
    offs = np.empty(len(hc.curves) + 1, np.int32)
    hc.curve_offset_data.foreach_get("value", offs)
    return offs


def mesh_world(ob, depsgraph=None):
    """(local vertices float32, triangles int32) of an object's evaluated mesh."""
    ev = ob.evaluated_get(depsgraph) if depsgraph is not None else ob
    me = ev.to_mesh()
    try:
        me.calc_loop_triangles()
        V = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", V)
        F = np.empty(len(me.loop_triangles) * 3, np.int32)
        me.loop_triangles.foreach_get("vertices", F)
    finally:
        ev.to_mesh_clear()
    return V.reshape(-1, 3), F.reshape(-1, 3)
