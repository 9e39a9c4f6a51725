"""What the real application draws for spline hair, played in its viewport (app lane).

Run *inside* Blender (with its UI, under Xvfb) by ``test_real_blender_curves.py``, never
imported by pytest::

    blender start.blend -p 0 0 1600 900 --python curves_driver.py -- ZIP WORKDIR

From ``bpy.app.timers`` (one generator; each ``yield`` hands control back to Blender's
event loop, so the viewport really redraws):

1. install the packaged zip;
2. a groom of 900 arched hairs, half Catmull-Rom and half Bezier (AUTO handles), a ball
   pressing into it over frames 1-12; Add FurCollide; a Resample Curve and (where this
   Blender ships the hair assets) a Trim Hair Curves modifier on the output (the README
   invites modifiers there);
3. play in the viewport (``screen.animation_play``), stop, then step with the arrow
   keys' operator (``screen.frame_offset``); at each stop, in the viewport's own
   depsgraph: the output's modifier result against the same stack on a fresh copy of
   the output's curves, and the crossings of the curves Blender evaluates (Resample
   Curve in Evaluated mode) with the ball (Blender's BVH as the oracle);
4. ``result.json`` after every step, screenshots, quit.
"""

from __future__ import annotations

import os
import subprocess
import sys

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from driver_session import (  # noqa: E402
    Report,
    collider_tree,
    crossing_curves,
    install,
    override,
    select,
    start,
    ui,
)

ADDON = "bl_ext.user_default.furcollide"
ARGS = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
ZIP, WORK = ARGS[0], ARGS[1]
FRAMES = (1, 12)
result: dict = {"steps": [], "errors": [], "checks": [], "blender": bpy.app.version_string}


run_report = Report("curves_driver", WORK, result)
log, save_result, step, shot = run_report.log, run_report.save, run_report.step, run_report.shot


# ----------------------------------------------------------------- scene
def groom(n=30, npts=7, length=0.9, spacing=0.03):
    rng = np.random.default_rng(0)
    xs = (np.arange(n) - (n - 1) / 2) * spacing
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    C = n * n
    lean = rng.uniform(0, 2 * np.pi, C)
    bend = rng.uniform(0.8, 1.6, C)
    t = np.linspace(0, 1, npts)
    seg = length / (npts - 1)
    pts = []
    for c in range(C):
        ang = bend[c] * t
        d = np.stack([np.sin(ang) * np.cos(lean[c]), np.sin(ang) * np.sin(lean[c]),
                      np.cos(ang)], 1)[:-1] * seg
        root = np.array([X.ravel()[c], Y.ravel()[c], 0.0])
        pts.append(np.vstack([root, root + np.cumsum(d, 0)]))
    P = np.vstack(pts)
    hc = bpy.data.hair_curves.new("Fur")
    hc.add_curves([npts] * C)
    hc.position_data.foreach_set("vector", P.astype(np.float32).ravel())
    bezier = np.arange(1, C, 2)
    if hasattr(hc, "set_types"):
        hc.set_types(type="BEZIER", indices=bezier.tolist())
    else:
        types = np.zeros(C, np.int32)
        types[bezier] = 2
        hc.attributes.new("curve_type", "INT8", "CURVE").data.foreach_set("value", types)
        hc.add_curves([])  # (has the types counted again)
    hl, hr = auto_handles(P, npts)
    for name, v, kind, key in (("handle_left", hl, "FLOAT_VECTOR", "vector"),
                               ("handle_right", hr, "FLOAT_VECTOR", "vector"),
                               ("handle_type_left", np.ones(len(P)), "INT8", "value"),
                               ("handle_type_right", np.ones(len(P)), "INT8", "value")):
        a = hc.attributes.new(name, kind, "POINT")
        dtype = np.float32 if kind.startswith("FLOAT") else np.int32
        a.data.foreach_set(key, np.ascontiguousarray(v, dtype).ravel())
    hc.add_curves([])
    ob = bpy.data.objects.new("Fur", hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def auto_handles(P, npts):
    Q = P.reshape(-1, npts, 3)
    prev = np.concatenate([2 * Q[:, :1] - Q[:, 1:2], Q[:, :-1]], 1)
    nxt = np.concatenate([Q[:, 1:], 2 * Q[:, -1:] - Q[:, -2:-1]], 1)
    pd, nd = Q - prev, nxt - Q
    pl = np.linalg.norm(pd, axis=2, keepdims=True)
    nl = np.linalg.norm(nd, axis=2, keepdims=True)
    d = nd / nl + pd / pl
    ln = np.linalg.norm(d, axis=2, keepdims=True) * 2.5614
    return ((Q - d * np.minimum(pl, 5 * nl) / ln).reshape(-1, 3),
            (Q + d * np.minimum(nl, 5 * pl) / ln).reshape(-1, 3))


def ball():
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.3, segments=32, ring_count=16,
                                         location=(0.02, -0.03, 1.4))
    b = bpy.context.active_object
    b.name = "Ball"
    b.keyframe_insert("location", frame=FRAMES[0])
    b.location.z = 0.5
    b.keyframe_insert("location", frame=FRAMES[1])
    return b


def resample_group(mode=None, count=16, source=None):
    ng = bpy.data.node_groups.new("Resample", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gi, go = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    r = ng.nodes.new("GeometryNodeResampleCurve")
    if mode == "EVALUATED":
        if "Mode" in r.inputs:
            r.inputs["Mode"].default_value = "Evaluated"
        else:
            r.mode = "EVALUATED"
    else:
        r.inputs["Count"].default_value = count
    if source is not None:  # the curves of another object, in world space
        info = ng.nodes.new("GeometryNodeObjectInfo")
        info.transform_space = "RELATIVE"
        info.inputs["Object"].default_value = source
        ng.links.new(info.outputs["Geometry"], r.inputs["Curve"])
    else:
        ng.links.new(gi.outputs[0], r.inputs["Curve"])
    ng.links.new(r.outputs[0], go.inputs[0])
    return ng


def trim_group():
    """Blender's Trim Hair Curves, or None where this Blender ships no hair assets
    (Debian's package has none)."""
    path = sys.modules[ADDON + ".operators.ops.pipeline"].hair_assets_path()
    if not path:
        return None
    with bpy.data.libraries.load(path, link=False) as (_s, dst):
        dst.node_groups = ["Trim Hair Curves"]
    return dst.node_groups[0]


def stack(ob, groups):
    compat = sys.modules[ADDON + ".operators.blender.compat"]
    for ng in groups:
        mod = ob.modifiers.new(ng.name, "NODES")
        mod.node_group = ng
        if ng.name.startswith("Trim"):
            ids = compat.group_inputs(ng)
            compat.set_modifier_input(mod, ids[("Length", "NodeSocketFloat")], 0.6)


def evaluated(ob):
    e = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    P = np.empty(len(e.points) * 3, np.float32)
    e.position_data.foreach_get("vector", P)
    offs = np.zeros(len(e.curves) + 1, np.int32)
    e.curve_offset_data.foreach_get("value", offs)
    return P.reshape(-1, 3), offs


def fresh(out, groups):
    """The output's curves copied into new data (no cache shared with the output's)
    with the same modifiers."""
    bridge = sys.modules[ADDON + ".operators.blender.bridge"]
    hc = bpy.data.hair_curves.new("Fresh")
    bridge.copy_topology(out.data, hc)
    ob = bpy.data.objects.new("Fresh", hc)
    bpy.context.scene.collection.objects.link(ob)
    ob.matrix_world = out.matrix_world
    stack(ob, groups)
    return ob


def drawn_crossings(out, collider, status):
    """Resolved curves whose evaluated curve (what Blender draws) crosses ``collider``."""
    probe = bpy.data.objects.new("Probe", bpy.data.hair_curves.new("Probe"))
    bpy.context.scene.collection.objects.link(probe)
    mod = probe.modifiers.new("probe", "NODES")
    mod.node_group = resample_group("EVALUATED", source=out)
    P, offs = evaluated(probe)
    bpy.data.objects.remove(probe)
    tree = collider_tree(collider, bpy.context.evaluated_depsgraph_get())
    return crossing_curves(P, offs, tree, keep=np.isin(status, (0, 1, 2)))  # resolved


def check(fur, out, b, groups, how):
    scene = bpy.context.scene
    got, offs = evaluated(out)
    ref = fresh(out, groups)
    want, offs_want = evaluated(ref)
    bpy.data.objects.remove(ref)
    st = np.zeros(len(out.data.curves), np.int32)
    out.data.attributes["furcollide_status"].data.foreach_get("value", st)
    same = bool(np.array_equal(offs, offs_want)) and len(got) == len(want)
    result["checks"].append({
        "how": how, "frame": scene.frame_current, "same_layout": same,
        "max_difference": float(np.abs(got - want).max()) if same else None,
        "crossing_curves": drawn_crossings(out, b, st),
        "colliding": int(fur.furcollide.stat_colliding),
    })
    save_result()


# ----------------------------------------------------------------- the run
def run():
    yield 1.0
    subprocess.run(["xdotool", "mousemove", "800", "450", "key", "Escape"], capture_output=True)
    yield 0.5
    install(run_report, ZIP, ADDON)
    scene = bpy.context.scene
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob)
    scene.frame_start, scene.frame_end = FRAMES
    scene.frame_set(FRAMES[0])
    fur, b = groom(), ball()
    scene.frame_set(FRAMES[0])
    select(fur, b)
    with override():
        ret = bpy.ops.furcollide.add()
    out = fur.furcollide.output
    groups = [g for g in (resample_group(), trim_group()) if g is not None]
    stack(out, groups)
    step("setup", add_return=sorted(ret), output=getattr(out, "name", None),
         modifiers=[m.name for m in out.modifiers])
    win, area, region, side = ui()
    area.spaces.active.shading.type = "SOLID"
    with override():
        bpy.ops.view3d.view_all(center=False)
    yield 1.0

    scene.sync_mode = "NONE"
    with override():
        bpy.ops.screen.animation_play()
    waited = 0.0
    while scene.frame_current < FRAMES[1] - 2 and waited < 300:
        yield 0.05
        waited += 0.05
    with override():
        bpy.ops.screen.animation_cancel(restore_frame=False)
    yield 1.0
    check(fur, out, b, groups, "played")
    shot("1_played")
    for delta in (1, 1, -1, -2):
        with override():
            bpy.ops.screen.frame_offset(delta=delta)
        yield 0.5
        check(fur, out, b, groups, f"frame_offset {delta:+d}")
    shot("2_stepped")
    step("done")


log(f"Blender {bpy.app.version_string}")
save_result()
start(run(), result, save_result, log)
