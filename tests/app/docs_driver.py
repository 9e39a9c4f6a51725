"""The documentation's screenshots, taken in the real Blender application.

Run *inside* Blender (with its UI, under Xvfb, in the chroot of
``scripts/blender_chroot.sh``) by ``scripts/docs_images.py`` (``make docs-images``),
never imported by pytest::

    blender start.blend -p 0 0 W H --python docs_driver.py -- ZIP WORKDIR

Like the app lane's other drivers, everything runs from ``bpy.app.timers`` (one
generator; each ``yield`` hands control back to Blender's event loop, so it really
redraws). It walks the README's quick start on the demo scene (``demo_scene.py``, copied
next to this file):

1. build the demo scene, install the packaged zip;
2. in the *Layout* workspace, the sidebar as an artist sees it (the panels open or
   closed as registered): no setup (the colliders selected, then the hair), Add
   FurCollide (a fresh setup), the demo's settings and Lock Interface, frames 1-28
   played; the viewport with the status colours; the outliner (source and output);
3. in a copy of the workspace whose sidebar never drew FurCollide, every panel
   registered open, each sub-panel shown alone under the main panel and cropped;
4. the file saved, Bake, the baked sidebar.

Every picture is a full screenshot (``import -window root``) cropped with ImageMagick
to a region Blender reports (the sidebar, the outliner, the camera frame), the
sidebar's to the bottom of what it draws. ``result.json`` lists each picture and what
the setup's status was.
"""

from __future__ import annotations

import os
import subprocess
import sys

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import demo_scene as ds  # noqa: E402
from driver_session import Report, install, redraw, select, start, ui  # noqa: E402

ADDON = "bl_ext.user_default.furcollide"
ARGS = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
ZIP, WORK = ARGS[0], ARGS[1]
SHOTS = os.path.join(WORK, "shots")  # full screenshots
IMG = os.path.join(WORK, "img")  # the cropped pictures
STILL = ds.STILL_FRAME
#: The demo's settings (scripts/demo.py SETTINGS: the core's names and values).
SETTINGS = {
    "Fur": dict(mode="bend", rotation_precision=0.5, collision_offset=0.008,
                recovery_rate=0.3, pinch_resolution="growth_surface"),
    "Grass": dict(mode="bend", rotation_precision=0.5, collision_offset=0.004,
                  recovery_rate=0.06, plasticity=0.5),
}
#: The sub-panels shown alone, in the sidebar's order: (class name, picture).
SECTIONS = (
    ("FURCOLLIDE_PT_colliders", "panel-colliders"),
    ("FURCOLLIDE_PT_resolution", "panel-resolution"),
    ("FURCOLLIDE_PT_shrink", "panel-shrink"),
    ("FURCOLLIDE_PT_recovery", "panel-recovery"),
    ("FURCOLLIDE_PT_pinch", "panel-pinch"),
    ("FURCOLLIDE_PT_enable", "panel-enable"),
    ("FURCOLLIDE_PT_cache", "panel-cache"),
    ("FURCOLLIDE_PT_stats", "panel-last-frame"),
    ("FURCOLLIDE_PT_pipeline", "panel-pipeline"),
)
#: Columns at the sidebar's right edge left out when finding where its panels end (the
#: category tabs run down there).
TABS = 34
result: dict = {"steps": [], "errors": [], "images": {}, "blender": bpy.app.version_string}


run_report = Report("docs_driver", WORK, result)
log, save_result, step = run_report.log, run_report.save, run_report.step


# ------------------------------------------------------------------ pictures
def grab(name):
    """A screenshot of the whole X screen (the Blender window fills it)."""
    os.makedirs(SHOTS, exist_ok=True)
    path = os.path.join(SHOTS, name + ".png")
    subprocess.run(["import", "-window", "root", path], check=True, capture_output=True)
    return path


def pixels(path):
    """(H, W, 3) float colours of a PNG, top row first (read by Blender itself)."""
    img = bpy.data.images.load(path, check_existing=False)
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, 4)[::-1, :, :3]


def box_of(r):
    """(x, y, w, h) of area or region ``r`` in screen pixels, y down from the top."""
    win = bpy.context.window_manager.windows[0]
    return r.x, win.height - (r.y + r.height), r.width, r.height


def content_bottom(px, box, skip=TABS):
    """The screen row just below the last drawn row of sidebar ``box`` (its bottom rows
    are the region's background; the ``skip`` columns at its right, the tabs, are left
    out)."""
    x, y, w, h = box
    sub = px[y:y + h, x:x + w - skip]
    bg = sub[h - 4, (w - skip) // 2]
    rows = np.flatnonzero((np.abs(sub - bg).max(axis=2) > 0.03).any(axis=1))
    rows = rows[rows < h - 6]
    return y + (int(rows.max()) + 1 if len(rows) else 0)


def crop(src, name, x, y, w, h, width=None, colors=None, caption=""):
    """Crop ``src`` to (x, y, w, h) into ``IMG/name.png`` (scaled to ``width``,
    reduced to ``colors``), recorded in result.json with its ``caption``."""
    os.makedirs(IMG, exist_ok=True)
    out = os.path.join(IMG, name + ".png")
    cmd = ["magick", src, "-crop", f"{w}x{h}+{x}+{y}", "+repage"]
    if width and w > width:
        cmd += ["-resize", f"{width}x"]
    if colors:
        cmd += ["-dither", "None", "-colors", str(colors)]
    cmd += ["-strip", "-define", "png:compression-level=9", out]
    subprocess.run(cmd, check=True, capture_output=True)
    result["images"][name] = {"box": [x, y, w, h], "bytes": os.path.getsize(out),
                              "caption": caption}
    save_result()
    log(f"{name}.png {w}x{h} ({os.path.getsize(out) // 1024} KB)")


def settle(seconds=2.5):
    """Redraw, twice: new panels slide into place over a few redraws."""
    redraw()
    yield seconds / 2
    redraw()
    yield seconds / 2


def sidebar(name, caption):
    """Redraw, then crop the 3D view's sidebar from its top to its last drawn row."""
    yield from settle()
    _, _, _, side = ui()
    path = grab(name)
    x, y, w, h = box_of(side)
    bottom = content_bottom(pixels(path), (x, y, w, h))
    crop(path, name, x, y, w, min(h, bottom - y + 6), colors=256, caption=caption)


def status(ob):
    reg = sys.modules[ADDON + ".operators.store.report"]
    return list(reg.status_shown(ob))


def ui_classes():
    return list(sys.modules[ADDON + ".ui"].classes)


def reregister(classes, keep, open_all=False):
    """Unregister the add-on's panels, then register ``keep`` of them again (every
    panel open when ``open_all``: a panel Blender never drew opens as registered)."""
    for cls in reversed(classes):
        if getattr(cls, "is_registered", False):
            bpy.utils.unregister_class(cls)
    for cls in classes:
        if cls.__name__ not in keep:
            continue
        if open_all and issubclass(cls, bpy.types.Panel):
            cls.bl_options = set(getattr(cls, "bl_options", set())) - {"DEFAULT_CLOSED"}
        bpy.utils.register_class(cls)


# ---------------------------------------------------------------------- run
def run():
    yield 1.0
    subprocess.run(["xdotool", "mousemove", "800", "450", "key", "Escape"], capture_output=True)
    yield 0.5
    demo = ds.build()  # (reads the factory startup file: before the add-on is installed)
    scene = demo.scene
    yield 1.0
    prefs = bpy.context.preferences
    if hasattr(prefs.system, "use_region_overlap"):
        prefs.system.use_region_overlap = False  # a solid sidebar to crop
    install(run_report, ZIP, ADDON)
    win = bpy.context.window_manager.windows[0]
    layout_ws = win.workspace
    with bpy.context.temp_override(window=win):
        bpy.ops.workspace.duplicate()  # its sidebar never drew FurCollide (step 3)
    docs_ws = win.workspace if win.workspace != layout_ws else None
    win.workspace = layout_ws
    yield 1.0
    docs_ws = docs_ws or next(w for w in bpy.data.workspaces if w != layout_ws
                              and w.name.startswith(layout_ws.name))
    step("workspaces", layout=layout_ws.name, docs=docs_ws.name)

    # --------------------------------------------- the quick start, in Layout
    win, area, region, side = ui()
    space = area.spaces.active
    space.show_region_ui = True
    space.region_3d.view_perspective = "CAMERA"
    redraw()
    yield 0.5
    fur, grass = demo.fur, demo.grass
    select(fur, demo.pusher, demo.cloth)  # the colliders, then the hair (active) last
    redraw()
    yield 1.0  # (the FurCollide tab appears once a hair object is active and drawn)
    win, area, region, side = ui()
    side.active_panel_category = "FurCollide"
    core_values = sys.modules[ADDON + ".operators.settings.core_values"]
    yield from sidebar("sidebar-no-setup", "No setup: the colliders selected, then the "
                       "hair (active): Add FurCollide")
    with bpy.context.temp_override(window=win, area=area, region=region):
        add_fur = sorted(bpy.ops.furcollide.add())
    yield from sidebar("sidebar-setup", "A fresh setup of the hair 'Fur'")
    out = fur.furcollide.output
    select(grass, demo.ball)
    with bpy.context.temp_override(window=win, area=area, region=region):
        add_grass = sorted(bpy.ops.furcollide.add())
    for ob in (fur, grass):
        # (the core's names and values: angles in degrees, choices in lower case)
        core_values.set_core_values(ob.furcollide, **SETTINGS[ob.name])
    sync = scene.sync_mode
    if sync != "NONE":  # the panel's Playback Sync warning: its button
        with bpy.context.temp_override(window=win, area=area, region=side):
            bpy.ops.furcollide.play_every_frame()
    step("setups", sync=sync, add=[add_fur, add_grass], output=out.name,
         grass_output=grass.furcollide.output.name)
    for f in range(scene.frame_start, STILL + 1):
        scene.frame_set(f)
        if f % 4 == 0:
            yield 0.05
    select(fur)
    step("played", status_played=status(fur), colliding=fur.furcollide.stat_colliding,
         pinched=fur.furcollide.stat_pinched)
    yield from sidebar("sidebar-played", f"Frames 1-{STILL} played")

    # the outliner: source (hidden) and output
    outliner = next(a for a in win.screen.areas if a.type == "OUTLINER")
    outliner.spaces.active.show_restrict_column_render = True
    outliner.tag_redraw()
    yield 1.0
    path = grab("outliner")
    x, y, w, h = box_of(outliner)
    bright = (pixels(path)[y:y + h, x:x + w].max(axis=2) > 0.45).any(axis=1)  # text, icons
    bottom = y + int(np.flatnonzero(bright).max()) + 1  # (its row stripes run on below)
    crop(path, "outliner", x, y, w, min(h, bottom - y + 8), colors=128,
         caption="The outliner: each source hidden, its output beside it")

    # the viewport in the status colours, through the camera: Material Preview with a
    # material whose Attribute node reads furcollide_color (Blender 4.3's Solid mode
    # draws hair curves without their colour attributes)
    status_mat = status_material()
    for ob in (out, grass.furcollide.output):
        ob.data.materials.clear()
        ob.data.materials.append(status_mat)
    space.show_region_ui = False
    space.overlay.show_overlays = False
    space.shading.type = "MATERIAL"
    scene.view_settings.view_transform = "Standard"  # the colours as they are
    win, area, region, side = ui()
    with bpy.context.temp_override(window=win, area=area, region=region):
        bpy.ops.view3d.view_center_camera()
    for _ in range(12):  # (EEVEE compiles its shaders in the background)
        redraw()
        yield 5.0
    win, area, region, side = ui()
    path = grab("viewport")
    x, y, w, h = camera_frame(scene, region)
    crop(path, "viewport-status", x, y, w, h, width=800, colors=128,
         caption=f"Frame {STILL} in the status colours")
    space.overlay.show_overlays = True
    space.shading.type = "SOLID"
    space.show_region_ui = True

    # ------------------- every sub-panel alone, in a sidebar that never drew them
    classes = ui_classes()
    names = {c.__name__ for c in classes}
    reregister(classes, names, open_all=True)
    win.workspace = docs_ws
    yield 1.5
    win, area, region, side = ui()
    with bpy.context.temp_override(window=win, area=area, region=region):
        bpy.ops.screen.screen_full_area()  # the whole window: room for Fur Pipeline
    yield 1.0
    win, area, region, side = ui()
    area.spaces.active.show_region_ui = True
    redraw()
    yield 0.5
    select(fur)
    redraw()
    yield 1.0
    win, area, region, side = ui()
    side.active_panel_category = "FurCollide"
    core_values = sys.modules[ADDON + ".operators.settings.core_values"]
    sections = [n for n, _ in SECTIONS]
    base = names - set(sections)  # the main panel, the list, the presets
    reregister(classes, base)
    yield from settle()
    win, area, region, side = ui()
    path = grab("main-only")
    x, y, w, h = box_of(side)
    top = content_bottom(pixels(path), (x, y, w, h))
    crop(path, "panel-main", x, y, w, top - y + 6, colors=256,
         caption=f"The main panel after frames 1-{STILL}")
    for cls_name, picture in SECTIONS:
        reregister(classes, base | {cls_name})
        yield from settle()
        win, area, region, side = ui()
        path = grab(picture)
        x, y, w, h = box_of(side)
        bottom = content_bottom(pixels(path), (x, y, w, h))
        crop(path, picture, x, top - 2, w - TABS, bottom - top + 8, colors=256,
             caption=f"{cls_name} after frames 1-{STILL}")
    reregister(classes, names)
    with bpy.context.temp_override(window=win, area=area, region=region):
        bpy.ops.screen.back_to_previous()
    yield 0.5
    win.workspace = layout_ws
    yield 1.5

    # ------------------------------------------------------------------ bake
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(WORK, "docs.blend"))
    select(fur)
    win, area, region, side = ui()
    with bpy.context.temp_override(window=win, area=area, region=region):
        baked = sorted(bpy.ops.furcollide.bake())
    scene.frame_set(STILL)
    step("baked", bake_return=baked, is_baked=bool(fur.furcollide.is_baked),
         status_baked=status(fur))
    yield from sidebar("sidebar-baked", f"Baked, frame {STILL} shown")
    step("done")


def status_material():
    """A material showing each point's ``furcollide_color`` as it is (an Attribute node
    into an Emission shader: no lighting changes the colours)."""
    mat = bpy.data.materials.new("FurCollide Status")
    if mat.node_tree is None:
        mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "furcollide_color"
    emit = nt.nodes.new("ShaderNodeEmission")
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(attr.outputs["Color"], emit.inputs["Color"])
    nt.links.new(emit.outputs["Emission"], out.inputs["Surface"])
    return mat


def camera_frame(scene, region):
    """(x, y, w, h) on screen of the scene camera's frame in 3D view ``region``."""
    from bpy_extras.view3d_utils import location_3d_to_region_2d

    cam = scene.camera
    pts = [location_3d_to_region_2d(region, region.data, cam.matrix_world @ v)
           for v in cam.data.view_frame(scene=scene)]
    xs = [p.x for p in pts]
    ys = [p.y for p in pts]
    x0, x1 = int(round(min(xs))), int(round(max(xs)))
    y0, y1 = int(round(min(ys))), int(round(max(ys)))
    rx, ry, _, _ = box_of(region)
    return rx + x0, ry + (region.height - y1), x1 - x0, y1 - y0


log(f"Blender {bpy.app.version_string}, Python {sys.version.split()[0]}")
save_result()
start(run(), result, save_result, log, persistent=True)
