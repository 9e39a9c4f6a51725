"""The README's quick start walked in the real application (app lane).

Run *inside* Blender (with its UI, under Xvfb) by ``test_real_blender_quickstart.py``,
never imported by pytest::

    blender start.blend -p 0 0 1600 900 --python quickstart_driver.py -- ZIP WORKDIR

From ``bpy.app.timers`` (one generator; each ``yield`` hands control back to Blender's
event loop), as a new user would, from an empty file:

1. install the packaged zip; delete every object of the start file;
2. build the objects: a hair object ``Fur`` (a patch of upright hairs), a ``Ball`` falling
   into it over frames 1-12, a camera and a light;
3. quick start step 1, *select the colliders, then Shift-click the hair last*: a real
   click on the ball and a real Shift-click on the hair (xdotool, X events Blender reads
   like a mouse's); where a click reaches nothing, ``view3d.select`` at the same pixel
   with the viewport's context (what the click runs) and the result says so. *Sidebar
   (N)*: a real N key press; the FurCollide tab;
4. step 2, **Add FurCollide**, and step 3, the panel's *Play Every Frame* button (its
   Playback Sync warning, Sync first set to sync with audio) and a preset: the panel's
   buttons, each its operator called with the sidebar's context (Blender's Python cannot
   press a panel button by its position: ``Window.event_simulate`` needs
   ``--enable-event-simulate``, which turns off the real mouse and keys the steps above
   use);
5. step 4, the start frame and Play (``screen.animation_play``) to the end;
6. step 5, save, **Bake** (the modal bake, ``INVOKE_DEFAULT``), render one frame
   (``render.render(write_still=True)``), recording the output's curves the render's
   own depsgraph gets; crossings of those curves with the ball there (Blender's BVH as
   the oracle), and of the curves Blender evaluates from them (Resample Curve,
   Evaluated);
7. ``result.json`` after every step, screenshots, quit.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import bpy
import numpy as np
from mathutils import Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from driver_session import (  # noqa: E402
    Report,
    collider_tree,
    crossing_curves,
    install,
    redraw,
    start,
    ui,
)

ADDON = "bl_ext.user_default.furcollide"
ARGS = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
ZIP, WORK = ARGS[0], ARGS[1]
FRAMES = (1, 12)
RENDERED = 10  # the ball deep in the fur
result: dict = {"steps": [], "errors": [], "blender": bpy.app.version_string}


run_report = Report("quickstart_driver", WORK, result)
log, save_result, step, shot = run_report.log, run_report.save, run_report.step, run_report.shot


# ----------------------------------------------------------------- scene
def fur(n=40, npts=6, length=0.5, half=0.5):
    """A patch of ``n`` x ``n`` upright hairs (a little lean each) on z = 0."""
    rng = np.random.default_rng(0)
    xs = np.linspace(-half, half, n)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    C = n * n
    roots = np.stack([X.ravel(), Y.ravel(), np.zeros(C)], 1)
    lean = rng.normal(0, 0.08, (C, 2))
    t = np.linspace(0, 1, npts)[None, :, None]
    tip = np.concatenate([lean, np.ones((C, 1))], 1)
    tip *= length / np.linalg.norm(tip, axis=1, keepdims=True)
    P = (roots[:, None, :] + t * tip[:, None, :]).reshape(-1, 3)
    hc = bpy.data.hair_curves.new("Fur")
    hc.add_curves([npts] * C)
    hc.position_data.foreach_set("vector", P.astype(np.float32).ravel())
    ob = bpy.data.objects.new("Fur", hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def ball():
    b = bpy.data.objects.new("Ball", bpy.data.meshes.new("Ball"))
    bpy.context.scene.collection.objects.link(b)
    import bmesh

    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=32, v_segments=16, radius=0.25)
    bm.to_mesh(b.data)
    bm.free()
    b.location = (0.05, 0.0, 1.0)
    b.keyframe_insert("location", frame=FRAMES[0])
    b.location.z = 0.3
    b.keyframe_insert("location", frame=FRAMES[1])
    return b


def camera_and_light():
    scene = bpy.context.scene
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    cam.location = (0.0, -3.0, 1.4)
    cam.rotation_euler = (np.radians(70), 0.0, 0.0)
    scene.camera = cam
    light = bpy.data.objects.new("Light", bpy.data.lights.new("Light", "SUN"))
    scene.collection.objects.link(light)


# ----------------------------------------------------------------- clicks
def pixel_of(co):
    """The screen pixel (x, y down from the top) where the viewport draws world point
    ``co``, and the region's own coordinates of it."""
    from bpy_extras.view3d_utils import location_3d_to_region_2d

    win, area, region, _ = ui()
    rx, ry = location_3d_to_region_2d(region, region.data, Vector(co))
    return (int(region.x + rx), int(win.height - (region.y + ry))), (int(rx), int(ry))


def xdotool(*args):
    return subprocess.run(["xdotool", *args], capture_output=True, text=True)


def click(co, shift=False):
    """A real left click (Shift held: ``shift``) on world point ``co``: a generator, each
    X event in its own turn of Blender's event loop (Blender reads Shift from its own key
    event, as a user's hand would press it before the button). Returns xdotool's
    results."""
    (x, y), _ = pixel_of(co)
    done = [xdotool("mousemove", str(x), str(y))]
    yield 0.3
    if shift:
        done.append(xdotool("keydown", "shift"))
        yield 0.3
    done.append(xdotool("click", "1"))
    yield 0.5
    if shift:
        done.append(xdotool("keyup", "shift"))
        yield 0.3
    return done


def select_op(co, shift=False):
    """What the click runs: ``view3d.select`` at the pixel, with the viewport's context."""
    win, area, region, _ = ui()
    _, loc = pixel_of(co)
    with bpy.context.temp_override(window=win, area=area, region=region):
        return bpy.ops.view3d.select(location=loc, extend=False, toggle=shift,
                                     deselect_all=not shift)


def selection():
    vl = bpy.context.view_layer
    return (getattr(vl.objects.active, "name", None),
            sorted(o.name for o in vl.objects if o.select_get()))


def press(idname, region="sidebar", **props):
    """A panel's button: its operator invoked with the context the sidebar gives."""
    win, area, main, side = ui()
    mod, _, op = idname.partition(".")
    with bpy.context.temp_override(window=win, area=area,
                                   region=side if region == "sidebar" else main):
        return sorted(getattr(getattr(bpy.ops, mod), op)("INVOKE_DEFAULT", **props))


# ----------------------------------------------------------------- checks
def world_points(ob):
    d = ob.data
    P = np.empty(len(d.points) * 3, np.float32)
    d.position_data.foreach_get("vector", P)
    M = np.array(ob.matrix_world)
    offs = np.empty(len(d.curves) + 1, np.int32)
    d.curve_offset_data.foreach_get("value", offs)
    return P.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3], offs


def evaluated_curves(out):
    """The curves Blender evaluates from the output (its splines: Resample Curve in
    Evaluated mode, in world space)."""
    ng = bpy.data.node_groups.new("Evaluated", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    go = ng.nodes.new("NodeGroupOutput")
    info = ng.nodes.new("GeometryNodeObjectInfo")
    info.transform_space = "RELATIVE"
    info.inputs["Object"].default_value = out
    r = ng.nodes.new("GeometryNodeResampleCurve")
    if "Mode" in r.inputs:
        r.inputs["Mode"].default_value = "Evaluated"
    else:
        r.mode = "EVALUATED"
    ng.links.new(info.outputs["Geometry"], r.inputs["Curve"])
    ng.links.new(r.outputs[0], go.inputs[0])
    probe = bpy.data.objects.new("Probe", bpy.data.hair_curves.new("Probe"))
    bpy.context.scene.collection.objects.link(probe)
    probe.modifiers.new("probe", "NODES").node_group = ng
    pe = probe.evaluated_get(bpy.context.evaluated_depsgraph_get())
    got = world_points(pe)
    bpy.data.objects.remove(probe)
    bpy.data.node_groups.remove(ng)
    return got


# ----------------------------------------------------------------- the run
def run():
    yield 1.0
    subprocess.run(["xdotool", "mousemove", "800", "450", "key", "Escape"], capture_output=True)
    yield 0.5
    install(run_report, ZIP, ADDON)

    # an empty file: nothing of the start file's objects
    scene = bpy.context.scene
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob)
    scene.frame_start, scene.frame_end = FRAMES
    scene.frame_set(FRAMES[0])
    hair, b = fur(), ball()
    camera_and_light()
    scene.frame_set(FRAMES[0])
    win, area, region, side = ui()
    space = area.spaces.active
    space.shading.type = "SOLID"
    space.region_3d.view_perspective = "PERSP"  # (the start file's view, framed below)
    for ob in bpy.context.view_layer.objects:
        ob.select_set(ob in (hair, b))
    with bpy.context.temp_override(window=win, area=area, region=region):
        bpy.ops.view3d.view_selected()
    for ob in bpy.context.view_layer.objects:
        ob.select_set(False)
    bpy.context.view_layer.objects.active = None
    redraw()
    yield 1.0
    step("built", objects=sorted(o.name for o in bpy.data.objects),
         sync_at_start=scene.sync_mode, lock_at_start=scene.render.use_lock_interface)

    # 1. the colliders (a click), then Shift-click the hair last
    target_ball = tuple(b.matrix_world.translation)
    target_hair = (-0.3, 0.0, 0.25)  # mid-height in the patch, clear of the ball
    how = "xdotool"
    clicks = []
    for co, shift in ((target_ball, False), (target_hair, True)):
        done = yield from click(co, shift)
        yield 0.5
        clicks.append({"pixel": pixel_of(co)[0], "rc": [d.returncode for d in done],
                       "err": " ".join(d.stderr.strip() for d in done),
                       "selection": list(selection())})
        shot(f"0_click_{len(clicks)}")
    clicked = selection()
    if clicked != ("Fur", ["Ball", "Fur"]):
        how = "view3d.select"  # (the click's operator at the same pixels)
        for ob in bpy.context.view_layer.objects:
            ob.select_set(False)
        select_op(target_ball)
        select_op(target_hair, shift=True)
        yield 0.5
    step("selected", select_how=how, clicks=clicks, after_clicks=list(clicked),
         selection=list(selection()))
    # the sidebar (N) and its FurCollide tab
    subprocess.run(["xdotool", "mousemove", "700", "450", "key", "n"], capture_output=True)
    yield 1.0
    if not space.show_region_ui:
        space.show_region_ui = True
        result["sidebar_how"] = "show_region_ui"
    redraw()
    yield 1.0
    win, area, region, side = ui()
    side.active_panel_category = "FurCollide"
    redraw()
    yield 1.0
    result["sidebar"] = {"width": side.width,
                         "ui_scale": bpy.context.preferences.system.ui_scale}
    shot("1_selected")

    # 2. Add FurCollide
    add = press("furcollide.add")
    out = hair.furcollide.output
    yield 0.5
    step("added", add_return=add, is_setup=bool(hair.furcollide.is_setup),
         colliders=[c.object.name for c in hair.furcollide.colliders if c.object],
         output=getattr(out, "name", None), source_renders=not hair.hide_render,
         lock_after_add=scene.render.use_lock_interface)
    # 3. the Sync warning's button (a scene that syncs to audio, as many animators' do:
    # the start file's Sync is Play Every Frame), and a preset from the panel's header
    scene.sync_mode = "AUDIO_SYNC"
    redraw()
    yield 1.0
    shot("2_sync_warning")
    sync_pressed = press("furcollide.play_every_frame")
    presets = bpy.utils.preset_paths("furcollide")
    preset = next((os.path.join(p, f) for p in presets for f in sorted(os.listdir(p))
                   if f.startswith("Short_Fur")), None)
    applied = press("furcollide.preset_apply", filepath=preset,
                    menu_idname="FURCOLLIDE_MT_presets") if preset else None
    redraw()
    yield 1.0
    shot("2_added")
    step("scene_settings", sync_pressed=sync_pressed, sync_after=scene.sync_mode,
         preset=preset and os.path.basename(preset), preset_return=applied,
         mode=hair.furcollide.mode)

    # 4. the start frame, Play to the end
    press("screen.frame_jump", region="main", end=False)
    press("screen.animation_play", region="main")
    waited, seen = 0.0, set()
    while scene.frame_current < FRAMES[1] and waited < 300:
        seen.add(scene.frame_current)
        yield 0.05
        waited += 0.05
    press("screen.animation_cancel", region="main", restore_frame=False)
    yield 1.0
    s = hair.furcollide
    step("played", frames_seen=sorted(seen), frame=scene.frame_current,
         outdated=bool(s.is_outdated), status=s.status_message,
         colliding=int(s.stat_colliding), unresolved=int(s.stat_unresolved))
    shot("3_played")

    # 5. save, Bake, render
    path = os.path.join(WORK, "quickstart.blend")
    saved = sorted(bpy.ops.wm.save_as_mainfile(filepath=path))
    bake_ret = press("furcollide.bake")
    t0 = time.perf_counter()
    ops_bake = sys.modules[ADDON + ".operators.ops.bake"]
    while (ops_bake.PROGRESS.get(scene.name) or not s.is_baked) and \
            time.perf_counter() - t0 < 300:
        yield 0.2
    step("baked", saved=saved, bake_return=bake_ret, is_baked=bool(s.is_baked),
         bake_s=round(time.perf_counter() - t0, 1))
    scene.frame_set(RENDERED)
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x, scene.render.resolution_y = 320, 180
    scene.render.filepath = os.path.join(WORK, "render.png")
    rendered = {}

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            P, offs = world_points(out)
            rendered[sc.frame_current] = (P.copy(), offs.copy(), collider_tree(b, depsgraph))

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        render_ret = sorted(bpy.ops.render.render(write_still=True))
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    yield 0.5
    frame = rendered.get(RENDERED)
    dg = bpy.context.evaluated_depsgraph_get()
    viewport_P, _ = world_points(out)
    EP, eoffs = evaluated_curves(out)
    step("rendered", render_return=render_ret, render_frames=sorted(rendered),
         image=os.path.isfile(scene.render.filepath),
         curves=(len(frame[1]) - 1) if frame else 0,
         crossings_rendered=crossing_curves(frame[0], frame[1], frame[2]) if frame else None,
         rendered_is_viewport=bool(frame and np.array_equal(frame[0], viewport_P)),
         crossings_evaluated=crossing_curves(EP, eoffs, collider_tree(b, dg)),
         colliding_rendered=int(s.stat_colliding), status_rendered=s.status_message)
    shot("4_rendered")
    step("done")


log(f"Blender {bpy.app.version_string}")
save_result()
start(run(), result, save_result, log)
