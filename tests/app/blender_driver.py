"""Drive the real Blender application (with its UI, under Xvfb) like an artist would.

Run *inside* Blender by ``test_real_blender.py`` (never imported by pytest)::

    blender start.blend -p 0 0 1600 900 --python blender_driver.py -- ZIP WORKDIR

Everything happens in ``bpy.app.timers`` callbacks (they fire only with a UI): one
generator, each ``yield`` hands control back to Blender's event loop (so it redraws,
plays, runs the modal bake) for that many seconds. Steps:

1. install the packaged zip with ``extensions.package_install_files`` and check the
   add-on really is enabled (the operator says FINISHED even when it is not);
2. build a paper-scale scene: 50,000 curves x 8 CVs on a Skin sphere, a rigid collider
   (Ball, ~130k triangles, animated transform, frames 1-12) and a deforming one (Blob,
   ~130k triangles, animated shape key, frames 13-24);
3. ``furcollide.add``, open the sidebar on the FurCollide tab, screenshot;
4. play the animation (``screen.animation_play``, every frame) and time it;
5. check zero crossings on a few frames with Blender's own BVH (``mathutils.bvhtree``)
   as an independent oracle;
6. bake with the modal operator (``INVOKE_DEFAULT``): screenshot the progress, press Esc
   with xdotool (a real X key event), check the cancel kept the finished frames; bake
   again to the end (it resumes); check a baked frame;
7. Children from Guides (a clear error where Blender ships no hair assets);
8. write ``result.json`` after every step, quit with ``wm.quit_blender``.

Screenshots are taken from outside Blender with ImageMagick's ``import -window root``
(Blender's own screen.screenshot draws black under Xvfb).
"""

from __future__ import annotations

import glob
import os
import subprocess
import sys
import time

import bmesh
import bpy
import numpy as np
from mathutils import Vector
from mathutils.bvhtree import BVHTree

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from driver_session import Report, install, override, select, start, ui  # noqa: E402

ADDON = "bl_ext.user_default.furcollide"
ARGS = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
ZIP, WORK = ARGS[0], ARGS[1]
N_CURVES, N_CV = int(os.environ.get("FC_APP_CURVES", 50000)), 8
FRAMES = (1, 24)  # 1-12: the Ball (rigid) moves; 13-24: the Blob (deforming) bulges
CHECK_FRAMES = (6, 12, 18, 24)
result: dict = {"steps": [], "errors": [], "blender": bpy.app.version_string,
                "python": sys.version.split()[0], "numpy": np.__version__}


run_report = Report("driver", WORK, result)
log, save_result, step, shot = run_report.log, run_report.save, run_report.step, run_report.shot


# ----------------------------------------------------------------- scene
def uv_sphere(name, radius, segments, rings, location):
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=rings, radius=radius,
                              calc_uvs=True)
    bm.to_mesh(me)
    bm.free()
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    bpy.context.scene.collection.objects.link(ob)
    return ob


def dense_sphere(name, radius, segments, rings, location):
    """A UV sphere of triangles (two poles, ``rings - 1`` rings of ``segments``) built
    with numpy: bmesh's ``create_uvsphere`` takes about 17 s at 512 x 128."""
    phi = np.pi * np.arange(1, rings) / rings
    th = 2 * np.pi * np.arange(segments) / segments
    ring = np.stack([np.outer(np.sin(phi), np.cos(th)), np.outer(np.sin(phi), np.sin(th)),
                     np.repeat(np.cos(phi)[:, None], segments, 1)], -1).reshape(-1, 3)
    V = radius * np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]])
    south, j = len(V) - 1, np.arange(segments)
    a = 1 + np.arange(rings - 2)[:, None] * segments + j  # ring i, then ring i + 1 below
    b = 1 + np.arange(rings - 2)[:, None] * segments + (j + 1) % segments
    F = np.concatenate([
        np.stack([np.zeros(segments, int), 1 + j, 1 + (j + 1) % segments], 1),
        np.stack([a, a + segments, b + segments], -1).reshape(-1, 3),
        np.stack([a, b + segments, b], -1).reshape(-1, 3),
        np.stack([np.full(segments, south), south - segments + (j + 1) % segments,
                  south - segments + j], 1)])
    me = bpy.data.meshes.new(name)
    me.from_pydata(V.tolist(), [], F.tolist())
    me.update()
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    bpy.context.scene.collection.objects.link(ob)
    return ob


def build_scene():
    scene = bpy.context.scene
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob)
    scene.frame_start, scene.frame_end = FRAMES
    scene.frame_set(FRAMES[0])
    skin = uv_sphere("Skin", 1.0, 64, 32, (0, 0, 0))
    if not skin.data.uv_layers:
        skin.data.uv_layers.new(name="UVMap")
    # Ball: rigid, ~130k triangles, passes through the fur layer (1.0 < r < 1.25) on +x
    ball = dense_sphere("Ball", 0.5, 512, 128, (2.6, 0, 0))
    ball.keyframe_insert("location", frame=1)
    ball.location = (1.62, 0, 0)
    ball.keyframe_insert("location", frame=12)
    # Blob: deforming (shape key), ~130k triangles, bulges into the fur on -x
    blob = dense_sphere("Blob", 0.5, 512, 128, (-1.62, 0, 0))
    blob.shape_key_add(name="Basis")
    key = blob.shape_key_add(name="Bulge")
    co = np.empty(len(blob.data.vertices) * 3, np.float32)
    blob.data.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3) * np.array([1.2, 1.1, 0.9], np.float32)
    key.data.foreach_set("co", co.ravel())
    key.value = 0.0
    key.keyframe_insert("value", frame=12)
    key.value = 1.0
    key.keyframe_insert("value", frame=24)
    # Fur: 50,000 curves x 8 CVs, straight out of the Skin, 0.25 long
    rng = np.random.default_rng(7)
    n = rng.normal(size=(N_CURVES, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t = np.linspace(0.0, 0.25, N_CV)
    P = (n[:, None, :] * (1.0 + t[None, :, None])).reshape(-1, 3).astype(np.float32)
    hc = bpy.data.hair_curves.new("Fur")
    hc.add_curves([N_CV] * N_CURVES)
    hc.position_data.foreach_set("vector", P.ravel())
    hc.surface = skin
    hc.surface_uv_map = "UVMap"
    fur = bpy.data.objects.new("Fur", hc)
    scene.collection.objects.link(fur)
    tris = sum(len(p.vertices) - 2 for p in ball.data.polygons)
    return fur, ball, blob, P, tris


# ----------------------------------------------------------------- oracle
def world_mesh(ob, dg):
    oe = ob.evaluated_get(dg)
    me = oe.to_mesh()
    me.calc_loop_triangles()
    V = np.empty(len(me.vertices) * 3, np.float64)
    me.vertices.foreach_get("co", V)
    F = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("vertices", F)
    oe.to_mesh_clear()
    M = np.array(oe.matrix_world)
    V = V.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]
    return V, F.reshape(-1, 3)


def crossings(out, colliders):
    """Curves of ``out`` (evaluated, world space) with a segment through a collider."""
    dg = bpy.context.evaluated_depsgraph_get()
    oe = out.evaluated_get(dg)
    d = oe.data
    P = np.empty(len(d.points) * 3, np.float32)
    d.position_data.foreach_get("vector", P)
    M = np.array(oe.matrix_world)
    P = P.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    offs = np.empty(len(d.curves) + 1, np.int32)
    d.curve_offset_data.foreach_get("value", offs)
    seg = np.ones(len(P) - 1, bool)
    seg[offs[1:-1] - 1] = False  # no segment from a tip to the next root
    a_idx = np.nonzero(seg)[0]
    curve_of = np.searchsorted(offs, a_idx, side="right") - 1
    bad = set()
    tested = 0
    for ob in colliders:
        V, F = world_mesh(ob, dg)
        lo, hi = V.min(0) - 1e-4, V.max(0) + 1e-4
        A, B = P[a_idx], P[a_idx + 1]
        near = np.all((np.maximum(A, B) >= lo) & (np.minimum(A, B) <= hi), axis=1)
        tree = BVHTree.FromPolygons(V.tolist(), F.tolist(), all_triangles=True)
        for i in np.nonzero(near)[0]:
            a, b = Vector(A[i]), Vector(B[i])
            dvec = b - a
            length = dvec.length
            if length == 0.0:
                continue
            hit = tree.ray_cast(a, dvec / length, length)
            if hit[0] is not None:
                bad.add(int(curve_of[i]))
        tested += int(near.sum())
    return len(bad), tested


# ----------------------------------------------------------------- the run
def run():
    yield 1.0
    # close the splash screen (a real key press, like an artist would)
    subprocess.run(["xdotool", "mousemove", "800", "450", "key", "Escape"], capture_output=True)
    yield 0.5
    # 1. install the packaged zip, check it is really enabled
    install(run_report, ZIP, ADDON)
    import embreex  # the bundled cp313 wheel, unpacked into the user's .local

    step("bundled", module_file=getattr(sys.modules.get(ADDON), "__file__", None),
         embreex_file=embreex.__file__)
    pkg = sys.modules[ADDON]
    registry = sys.modules[ADDON + ".operators.store.registry"]
    report = sys.modules[ADDON + ".operators.store.report"]
    bake = sys.modules[ADDON + ".operators.store.bake"]
    ops_bake = sys.modules[ADDON + ".operators.ops.bake"]  # the modal bake's PROGRESS
    core = sys.modules[ADDON + ".core"]
    step("backend", embree_available=bool(core.embree_available()),
         embree_error=core.embree_error(), addon_version=getattr(pkg, "__name__", ""))

    # 2. the paper-scale scene
    t0 = time.perf_counter()
    fur, ball, blob, P0, tris = build_scene()
    step("scene", curves=len(fur.data.curves), points=len(fur.data.points),
         collider_triangles=tris, scene_s=round(time.perf_counter() - t0, 2))
    yield 0.5

    # 3. Add FurCollide (the Ball and the Blob selected, the Fur active)
    select(fur, ball, blob)
    t0 = time.perf_counter()
    with override():
        ret = bpy.ops.furcollide.add()
    out = fur.furcollide.output
    step("add", add_return=sorted(ret), add_s=round(time.perf_counter() - t0, 2),
         output=getattr(out, "name", None),
         colliders=[c.object.name for c in fur.furcollide.colliders])
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(WORK, "scene.blend"))
    win, area, region, side = ui()
    space = area.spaces.active
    space.show_region_ui = True
    space.shading.type = "SOLID"
    yield 0.5
    win, area, region, side = ui()
    try:
        side.active_panel_category = "FurCollide"
        tab = side.active_panel_category
    except (AttributeError, TypeError) as exc:
        tab = f"could not select the tab: {exc}"
    with override():
        bpy.ops.view3d.view_all(center=False)
    step("sidebar", sidebar_tab=tab, panel_registered=hasattr(bpy.types, "FURCOLLIDE_PT_main"))
    yield 3.0
    shot("1_panel_after_add")

    # 4. play every frame (rigid Ball 1-12, deforming Blob 13-24), timed
    scene = bpy.context.scene
    scene.sync_mode = "NONE"  # play every frame, as fast as it goes
    statuses = {}

    def on_frame(scn, _dg=None):
        st = report.status_for(fur)
        statuses[scn.frame_current] = list(st) if st else None

    bpy.app.handlers.frame_change_post.append(on_frame)
    scene.frame_set(FRAMES[0])
    yield 0.5
    with override():
        bpy.ops.screen.animation_play()
    t0 = time.perf_counter()
    timeline = []
    while scene.frame_current < FRAMES[1] and time.perf_counter() - t0 < 300:
        timeline.append((scene.frame_current, round(time.perf_counter() - t0, 3)))
        yield 0.05
    wall = time.perf_counter() - t0
    with override():
        bpy.ops.screen.animation_cancel(restore_frame=False)
    bpy.app.handlers.frame_change_post.remove(on_frame)
    t_rigid = next((t for f, t in timeline if f >= 12), wall)
    rt = registry.get_runtime(fur, create=False)
    step("play", played_to=scene.frame_current, play_wall_s=round(wall, 2),
         fps_rigid=round(11 / max(t_rigid, 1e-6), 2),
         fps_deforming=round(12 / max(wall - t_rigid, 1e-6), 2),
         statuses={str(k): v for k, v in sorted(statuses.items())},
         cached_after_play=sorted(rt.cache.memory.frames) if rt else None)
    yield 2.0
    shot("2_panel_after_playback")

    # 4b. the arrow keys (screen.frame_offset: a depsgraph update of the new frame comes
    # before its frame handlers) over the cached frames: each is shown from the cache
    scrub = []
    for delta in (-1, -1, -1, 1):
        with override():
            bpy.ops.screen.frame_offset(delta=delta)
        yield 0.3
        rt = registry.get_runtime(fur, create=False)
        scrub.append({"frame": scene.frame_current, "source": rt.report.stats.get("source"),
                      "cached": len(rt.cache.memory), "status": list(report.status_for(fur))})
    step("scrub", scrub=scrub)

    # 5. zero crossings on a few frames (independent oracle: Blender's BVH)
    cross = {}
    for f in CHECK_FRAMES:
        scene.frame_set(f)
        n_bad, tested = crossings(out, [ball, blob])
        moved = float(np.abs(_positions(out) - P0).max())
        cross[str(f)] = {"crossing_curves": n_bad, "segments_near": tested,
                         "max_move": round(moved, 4), "status": list(report.status_for(fur))}
        yield 0.1
    src_now = _positions(fur)
    step("crossings", crossings=cross, source_untouched=bool(np.array_equal(src_now, P0)))

    # 6. the modal bake: progress, Esc, resume
    scene.frame_set(FRAMES[0])
    with override():
        ret = bpy.ops.furcollide.bake("INVOKE_DEFAULT")
    step("bake_invoke", bake_invoke_return=sorted(ret))
    t0 = time.perf_counter()
    seen = []
    while time.perf_counter() - t0 < 300:
        prog = ops_bake.PROGRESS.get(scene.name)
        seen.append(prog)
        if prog and prog[0] >= 5:
            break
        if not prog and fur.furcollide.is_baked:
            break
        yield 0.1
    yield 0.2
    shot("3_panel_baking_progress")
    prog_before_esc = ops_bake.PROGRESS.get(scene.name)
    # a real key press: XTEST through the X server, to the window under the pointer
    xd = subprocess.run(["xdotool", "mousemove", "800", "450", "key", "Escape"],
                        capture_output=True, text=True)
    t1 = time.perf_counter()
    while ops_bake.PROGRESS.get(scene.name) and time.perf_counter() - t1 < 30:
        yield 0.1
    directory = bake.bake_directory(fur)
    files_after_esc = sorted(os.path.basename(p) for p in glob.glob(os.path.join(directory, "*")))
    step("bake_esc", progress_seen=[p for p in seen if p][-3:], progress_before_esc=prog_before_esc,
         xdotool_rc=xd.returncode, xdotool_err=xd.stderr.strip(),
         running_after_esc=bool(ops_bake.PROGRESS.get(scene.name)),
         baked_after_esc=bool(fur.furcollide.is_baked), files_after_esc=files_after_esc)
    yield 1.5
    shot("4_panel_after_esc")

    # resume to the end
    with override():
        ret = bpy.ops.furcollide.bake("INVOKE_DEFAULT")
    t0 = time.perf_counter()
    while not fur.furcollide.is_baked and time.perf_counter() - t0 < 600:
        yield 0.2
    bake_s = time.perf_counter() - t0
    files_done = sorted(os.path.basename(p) for p in glob.glob(os.path.join(directory, "*")))
    baked_cross = {}
    for f in CHECK_FRAMES:
        scene.frame_set(f)
        n_bad, tested = crossings(out, [ball, blob])
        baked_cross[str(f)] = {"crossing_curves": n_bad, "segments_near": tested,
                               "status": list(report.status_for(fur))}
    step("bake_resume", resume_return=sorted(ret), baked=bool(fur.furcollide.is_baked),
         resume_s=round(bake_s, 2), files_done=files_done, baked_crossings=baked_cross)
    yield 2.0
    shot("5_panel_baked")

    # 7. Children from Guides on the real application's hair assets
    select(fur)
    with override():
        try:
            ret = bpy.ops.furcollide.children_from_guides(density=20.0)
            children = {"return": sorted(ret)}
        except RuntimeError as exc:
            children = {"error": str(exc)}
    pipeline = sys.modules[ADDON + ".operators.ops.pipeline"]
    children["assets"] = pipeline.hair_assets_path()
    step("children", children=children)
    bpy.ops.wm.save_mainfile()
    step("done")


def _positions(ob):
    d = ob.data
    P = np.empty(len(d.points) * 3, np.float32)
    d.position_data.foreach_get("vector", P)
    return P.reshape(-1, 3)


log(f"Blender {bpy.app.version_string}, Python {sys.version.split()[0]}, numpy {np.__version__}")
save_result()
start(run(), result, save_result, log)
