"""Draw every FurCollide panel in the real Blender UI, in every state, then undo and redo.

Run *inside* Blender (with its UI, under Xvfb) by ``test_real_blender_ui.py``, never
imported by pytest::

    blender start.blend -p 0 0 1600 900 --python ui_driver.py -- ZIP WORKDIR

Like ``blender_driver.py``, everything runs from ``bpy.app.timers`` (one generator; each
``yield`` hands control back to Blender's event loop for that many seconds, so it really
redraws). Steps:

1. install the packaged zip; every panel, menu and list class of the add-on is
   re-registered open (no ``DEFAULT_CLOSED``) with its ``draw`` / ``draw_header`` /
   ``draw_item`` wrapped to count the calls Blender makes and keep any exception (it is
   re-raised: Blender prints it, as it would for an artist);
2. the sidebar's FurCollide tab is shown and the states are set one after the other:
   no setup, a fresh setup, played, an error, outdated, Lock Interface on, baked, an
   outdated bake, no output. After each, the UI redraws and a screenshot is taken;
3. undo / redo (README "Limits": undo restores the output's data, not the playback
   cache): ``furcollide.add`` undone and redone, a setting change undone, frames played
   after each with the handlers' errors recorded;
4. ``result.json`` after every step; quit.
"""

from __future__ import annotations

import os
import subprocess
import sys

import bpy
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from driver_session import Report, install, override, redraw, select, start, ui  # noqa: E402
from driver_session import instrument_ui as instrument  # noqa: E402

ADDON = "bl_ext.user_default.furcollide"
ARGS = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
ZIP, WORK = ARGS[0], ARGS[1]
result: dict = {"steps": [], "errors": [], "draws": {}, "draw_errors": [],
                "blender": bpy.app.version_string}
_state = {"name": "start"}


run_report = Report("ui_driver", WORK, result)
log, save_result, step, shot = run_report.log, run_report.save, run_report.step, run_report.shot


# ------------------------------------------------------------- counting draws
def instrument_ui():
    """Re-register the add-on's UI classes open, with counted drawing methods."""
    classes = list(sys.modules[ADDON + ".ui"].classes)
    instrument(classes, lambda cls, name: f"{_state['name']}|{cls.__name__}.{name}",
               result["draw_errors"], result["draws"])
    return [c.__name__ for c in classes]


# ----------------------------------------------------------------- the scene
def hair(name, n=12, x=0.0):
    """n x n straight hairs, 5 CVs, on z = 0 around (x, 0)."""
    g = (np.arange(n) - (n - 1) / 2) * 0.08
    X, Y = np.meshgrid(g + x, g, indexing="ij")
    roots = np.stack([X.ravel(), Y.ravel(), np.zeros(n * n)], 1)
    P = (roots[:, None, :] + np.linspace(0, 1, 5)[None, :, None] * [0, 0, 1.0]).reshape(-1, 3)
    hc = bpy.data.hair_curves.new(name)
    hc.add_curves([5] * (n * n))
    hc.position_data.foreach_set("vector", P.astype(np.float32).ravel())
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def box(name, x0, x1, frames=(1, 8)):
    bpy.ops.mesh.primitive_cube_add(size=0.4, location=(x0, 0, 0.6))
    ob = bpy.context.active_object
    ob.name = name
    ob.keyframe_insert("location", frame=frames[0])
    ob.location.x = x1
    ob.keyframe_insert("location", frame=frames[1])
    return ob


def positions(ob):
    P = np.empty(len(ob.data.points) * 3, np.float32)
    ob.data.position_data.foreach_get("vector", P)
    return P.reshape(-1, 3)


def status(report, ob):
    return list(report.status_for(ob))


# -------------------------------------------------------------------- the run
def show(name, seconds=1.0):
    """Enter state ``name``: redraw, wait, screenshot."""
    _state["name"] = name
    redraw()
    yield seconds
    shot(name)
    step("state " + name)


def run():
    yield 1.0
    subprocess.run(["xdotool", "mousemove", "800", "450", "key", "Escape"], capture_output=True)
    yield 0.5
    install(run_report, ZIP, ADDON)
    report = sys.modules[ADDON + ".operators.store.report"]
    step("instrumented", ui_classes=instrument_ui())

    scene = bpy.context.scene
    for ob in list(bpy.data.objects):
        bpy.data.objects.remove(ob)
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    scene.render.use_lock_interface = False
    fur = hair("Fur")
    ball = box("Ball", -1.0, 1.0)
    select(fur, ball)  # the FurCollide tab exists once a hair object is active
    win, area, region, side = ui()
    area.spaces.active.show_region_ui = True
    redraw()
    yield 0.5
    win, area, region, side = ui()
    side.active_panel_category = "FurCollide"
    with override():
        bpy.ops.view3d.view_all(center=False)
    step("sidebar", sidebar_tab=side.active_panel_category)
    yield from show("no_setup")
    with override():
        bpy.ops.furcollide.add()
    out = fur.furcollide.output
    select(fur)
    yield from show("setup")
    for f in range(1, 5):
        scene.frame_set(f)
    yield from show("played")
    fur.furcollide.attract_to_growth_surface = True  # no Surface: an error
    scene.frame_set(1)
    scene.frame_set(2)
    result["error_status"] = status(report, fur)
    yield from show("error")
    fur.furcollide.attract_to_growth_surface = False
    for f in range(1, 6):
        scene.frame_set(f)
    ball.rotation_euler.z += 0.4  # not keyed: the cached frames no longer hold
    scene.frame_set(3)
    result["outdated"] = bool(fur.furcollide.is_outdated)
    yield from show("outdated")
    ball.rotation_euler.z -= 0.4
    # renders unlocked and Sync dropping frames: one line each with its button
    scene.render.use_lock_interface, scene.sync_mode = False, "AUDIO_SYNC"
    yield from show("scene_warnings")
    scene.render.use_lock_interface, scene.sync_mode = True, "NONE"
    yield from show("lock_interface_on")
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(WORK, "ui.blend"))
    with override():
        bpy.ops.furcollide.bake()
    result["baked"] = bool(fur.furcollide.is_baked)
    scene.frame_set(4)
    yield from show("baked")
    ball.rotation_euler.z += 0.4
    scene.frame_set(5)
    result["baked_outdated"] = bool(fur.furcollide.is_outdated)
    yield from show("baked_outdated")
    ball.rotation_euler.z -= 0.4
    with override():
        bpy.ops.furcollide.free_bake()
    bpy.data.objects.remove(out)
    scene.frame_set(2)
    yield from show("no_output")
    select(fur)
    with override():
        bpy.ops.furcollide.remove()
    step("states done")

    # ------------------------------------------------------------ undo / redo
    # (undo reloads Blender's data: every Python reference to it is re-read after one)
    _state["name"] = "undo"
    errors_before = len(result["draw_errors"])
    log_errors = []

    def watch(scn, _dg=None):
        for ob in bpy.data.objects:
            s = getattr(ob, "furcollide", None)
            if s is not None and s.is_setup:
                level, msg = report.status_for(ob)
                if level == "ERROR":
                    log_errors.append(f"frame {scn.frame_current}: {ob.name}: {msg}")

    bpy.app.handlers.frame_change_post.append(watch)
    bpy.context.scene.frame_set(1)
    fur2 = hair("Fur2", n=8, x=0.0)
    select(fur2, ball)
    with override():
        bpy.ops.ed.undo_push(message="before add")
        bpy.ops.furcollide.add()
        bpy.ops.ed.undo_push(message="add")
    out_name = bpy.data.objects["Fur2"].furcollide.output.name
    for f in range(1, 5):
        bpy.context.scene.frame_set(f)
    yield 0.5
    added = {"is_setup": bpy.data.objects["Fur2"].furcollide.is_setup,
             "output": out_name in bpy.data.objects}
    with override():
        bpy.ops.ed.undo()
    yield 0.5
    fur2 = bpy.data.objects["Fur2"]
    undone = {"is_setup": fur2.furcollide.is_setup, "output": out_name in bpy.data.objects,
              "hidden": fur2.hide_get()}
    for f in range(1, 6):
        bpy.context.scene.frame_set(f)
        yield 0.05
    with override():
        bpy.ops.ed.redo()
    yield 0.5
    fur2 = bpy.data.objects["Fur2"]
    redone = {"is_setup": fur2.furcollide.is_setup, "output": out_name in bpy.data.objects}
    select(fur2)
    with override():
        reset = sorted(bpy.ops.furcollide.reset())
    moved = 0.0
    for f in range(1, 9):
        bpy.context.scene.frame_set(f)
        yield 0.05
        o = bpy.data.objects.get(out_name)
        if o is not None:
            moved = max(moved, float(np.abs(positions(o) - positions(fur2)).max()))
    redone.update(reset=reset, moved=moved, status=status(report, fur2))
    # a setting change, undone
    bpy.context.scene.frame_set(1)
    with override():
        bpy.ops.ed.undo_push(message="before stiff")
    fur2.furcollide.mode = "STIFF"
    with override():
        bpy.ops.ed.undo_push(message="stiff")
    for f in range(1, 4):
        bpy.context.scene.frame_set(f)
    with override():
        bpy.ops.ed.undo()
    yield 0.5
    fur2 = bpy.data.objects["Fur2"]
    mode_after = fur2.furcollide.mode
    for f in range(1, 9):
        bpy.context.scene.frame_set(f)
        yield 0.05
    redraw()
    yield 0.5
    bpy.app.handlers.frame_change_post.remove(watch)
    step("undo", undo_added=added, undo_undone=undone, undo_redone=redone,
         undo_mode_after=mode_after, undo_final_status=status(report, fur2),
         undo_handler_errors=log_errors,
         undo_draw_errors=result["draw_errors"][errors_before:])
    shot("undo_done")
    step("done")


log(f"Blender {bpy.app.version_string}, Python {sys.version.split()[0]}")
save_result()
start(run(), result, save_result, log)
