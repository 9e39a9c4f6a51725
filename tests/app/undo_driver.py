"""Undo and redo after every FurCollide operator an artist uses, in the real application.

Run *inside* Blender (with its UI, under Xvfb) by ``test_real_blender_undo.py``, never
imported by pytest::

    blender start.blend -p 0 0 1600 900 --python undo_driver.py -- ZIP WORKDIR

Like ``ui_driver.py``, everything runs from ``bpy.app.timers`` (one generator; each
``yield`` hands control back to Blender's event loop for that many seconds). The
operators are called as a button calls them: ``'INVOKE_DEFAULT'`` with an undo push
(``bpy.ops.x.y('INVOKE_DEFAULT', True)``; without it a Python call pushes no undo
step); a setting changed from Python is followed by ``ed.undo_push``, as a click in the
panel would be. Undo and redo are ``ed.undo`` / ``ed.redo``, or a real Ctrl+Z key press
(xdotool) during playback and during the modal bake.

1. install the zip; the add-on's panels are re-registered open with their drawing
   methods wrapped (an exception raised while drawing is kept, then re-raised);
2. a small scene (a 10 x 10 hair on a grid Skin, an animated Ball, a far Wall, a Groom),
   Add FurCollide, the reference frames: every frame played from frame 1 in Bend and in
   Stiff; saved as ``base.blend``;
3. one scenario per operator (Bake, Free Bake, Reset Cache, Fur Attach Bind, Fur
   Sampler, Bind Groom, Add / Remove Collider, Remove FurCollide, Ctrl+Z during
   playback, Ctrl+Z during the modal bake, undo back to a frame that showed a held
   frame, an edit after a file opened over a pending refresh), each from ``base.blend``
   opened again: do it, undo, redo, play frames;
4. after every step a *snap* of the setup (frame, settings, bake flags, files, status,
   and whether the output is the frame it claims to be: with an INFO status it must be
   bit for bit the reference frame of its mode, or the baked frame); ``result.json``.
"""

from __future__ import annotations

import glob
import json
import os
import shutil
import subprocess
import sys
import time
import traceback

import bpy
import numpy as np
from bpy.app.handlers import persistent

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from driver_session import Report, install, override, select, start, ui  # noqa: E402
from driver_session import instrument_ui as instrument  # noqa: E402

ADDON = "bl_ext.user_default.furcollide"
ARGS = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
ZIP, WORK = ARGS[0], ARGS[1]
BASE = os.path.join(WORK, "base.blend")
FRAMES = range(1, 9)
result: dict = {"steps": [], "errors": [], "snaps": [], "draw_errors": [],
                "blender": bpy.app.version_string}
M: dict = {"scenario": "setup"}
T0 = time.perf_counter()


run_report = Report("undo_driver", WORK, result)
log, save_result = run_report.log, run_report.save


def show_sidebar():
    """Show the sidebar on the FurCollide tab (the tab exists once it was drawn)."""
    _win, area, _region, _side = ui()
    area.spaces.active.show_region_ui = True
    area.tag_redraw()
    yield 0.3
    _win, area, _region, side = ui()
    side.active_panel_category = "FurCollide"
    area.tag_redraw()


# ------------------------------------------------------------- drawing errors
def instrument_ui():
    """Re-register the add-on's UI classes open, their drawing errors kept."""
    instrument(list(sys.modules[ADDON + ".ui"].classes),
               lambda cls, name: f"{M['scenario']}: {cls.__name__}.{name}",
               result["draw_errors"])


# ----------------------------------------------------------------- the scene
def grid(name):
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=10, y_subdivisions=10, size=1.2)
    ob = bpy.context.active_object
    ob.name = name
    return ob


def hair(name, n, surface):
    """n x n straight hairs of 5 CVs on z = 0, one unit long, grown on ``surface``."""
    g = (np.arange(n) - (n - 1) / 2) * (0.8 / n)
    X, Y = np.meshgrid(g, g, indexing="ij")
    roots = np.stack([X.ravel(), Y.ravel(), np.zeros(n * n)], 1)
    P = (roots[:, None, :] + np.linspace(0, 1, 5)[None, :, None] * [0, 0, 1.0]).reshape(-1, 3)
    hc = bpy.data.hair_curves.new(name)
    hc.add_curves([5] * (n * n))
    hc.position_data.foreach_set("vector", P.astype(np.float32).ravel())
    hc.surface = surface
    hc.surface_uv_map = surface.data.uv_layers[0].name
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def cube(name, location, key_x=None):
    """A 0.4 cube; with ``key_x`` its x is keyed from ``location`` (frame 1) to it (8)."""
    bpy.ops.mesh.primitive_cube_add(size=0.4, location=location)
    ob = bpy.context.active_object
    ob.name = name
    if key_x is not None:
        ob.keyframe_insert("location", frame=1)
        ob.location.x = key_x
        ob.keyframe_insert("location", frame=8)
    return ob


def ob(name):
    return bpy.data.objects.get(name)


def positions(o):
    P = np.empty(len(o.data.points) * 3, np.float32)
    o.data.position_data.foreach_get("vector", P)
    return P.reshape(-1, 3)


# ------------------------------------------------------------------- actions
def op(name, *args, **kw):
    """``bpy.ops.furcollide.<name>`` as a button calls it (invoke, undo push)."""
    with override():
        try:
            return sorted(getattr(bpy.ops.furcollide, name)("INVOKE_DEFAULT", True, *args, **kw))
        except RuntimeError as exc:  # a poll refused, or the operator reported an error
            return [f"error: {exc}"]


def ed(name, **kw):
    with override():
        try:
            return sorted(getattr(bpy.ops.ed, name)(**kw))
        except RuntimeError as exc:
            return [f"error: {exc}"]


def push(message):
    """What a click in the panel does after a setting changed: an undo step."""
    return ed("undo_push", message=message)


def key(keys):
    """A real key press over the 3D view (XTEST through the X server)."""
    subprocess.run(["xdotool", "mousemove", "600", "450", "key", keys], capture_output=True)


def running_bake():
    return bool(M["ops_bake"].PROGRESS.get(bpy.context.scene.name))


def wait_bake(timeout=120):
    t0 = time.perf_counter()
    yield 0.3
    while running_bake() and time.perf_counter() - t0 < timeout:
        yield 0.1
    yield 0.3  # (the undo push of a finished modal operator comes after it)


def settled(timeout=30):
    """After an edit, an undo or a redo: the refresh it scheduled has run (a loaded
    machine runs the timer late; until then the frame shown is marked outdated)."""
    t0 = time.perf_counter()
    yield 0.5
    while refresh_pending() and time.perf_counter() - t0 < timeout:
        yield 0.1


def refresh_pending():
    """A refresh timer is registered (one a file opened dropped does not count)."""
    return any(bpy.app.timers.is_registered(fn)
               for fn in M["invalidation"]._pending_refresh.values())


def play(frames, label=None):
    """Go through ``frames`` as playback does (frame_set), a snap after each."""
    for f in frames:
        bpy.context.scene.frame_set(f)
        yield 0.05
        if label:
            snap(f"{label} {f}")


def bake_files():
    """{file name: (size, mtime_ns)} of the setup's bake folder (undo must never
    delete or rewrite one)."""
    d = M.get("bake_dir")
    return {os.path.basename(p): (os.stat(p).st_size, os.stat(p).st_mtime_ns)
            for p in sorted(glob.glob(os.path.join(d, "frame_*.npz")))} if d else {}


def fresh(name):
    """Open base.blend again (a new undo history) for scenario ``name``."""
    M["scenario"] = name
    shutil.rmtree(M["bake_dir"], ignore_errors=True)  # (the last scenario's bake)
    bpy.ops.wm.open_mainfile(filepath=BASE)
    yield 0.5  # (the UI is rebuilt in the event loop: touching it before crashes)
    select(ob("Fur"))
    yield from show_sidebar()
    bpy.context.scene.frame_set(1)
    yield 0.3
    result["steps"].append(name)
    save_result()


# --------------------------------------------------------------------- snaps
def snap(label, **extra):
    """The setup's state now, and whether its output is what its status claims:
    ``claims_current`` (an INFO status, not outdated, in the frame range) and
    ``matches`` (the output is, bit for bit, the reference frame of its mode, or the
    baked frame; None when there is nothing to compare with)."""
    registry, report = M["registry"], M["report"]
    scene = bpy.context.scene
    f = scene.frame_current
    d = {"scenario": M["scenario"], "label": label, "frame": f,
         "t": round(time.perf_counter() - T0, 2)}  # (seconds into the session)
    fur = ob("Fur")
    s = fur.furcollide
    rt = registry.get_runtime(fur, create=False)
    out = s.output
    level, message = report.status_for(fur)
    d.update(is_setup=s.is_setup, is_baked=s.is_baked, bake_path=s.bake_path,
             output=getattr(out, "name", None), level=level, message=message,
             outdated=bool(s.is_outdated), baking=bool(rt and rt.baking),
             cached=sorted(rt.cache.memory.frames) if rt else None, mode=s.mode,
             colliders=[getattr(c.object, "name", None) for c in s.colliders],
             use_fur_attach=s.use_fur_attach, bound=bool(s.attach_id),
             groom_output=getattr(s.groom.output, "name", None),
             source_hidden=fur.hide_get(), files=bake_files(),
             running=running_bake(), wall_x=round(ob("Wall").location.x, 3))
    if s.is_setup and out is not None:
        P = positions(out)
        if s.is_baked:
            path = os.path.join(bpy.path.abspath(s.bake_path), f"frame_{min(f, 8):06d}.npz")
            ref = np.load(path)["points"] if os.path.exists(path) else None
        else:
            ref = M["ref"][s.mode].get(f)
        d["matches"] = None if ref is None else bool(np.array_equal(P, ref))
        d["claims_current"] = level == "INFO" and not s.is_outdated and s.enabled and (
            s.frame_start <= f)
    d.update(extra)
    result["snaps"].append(d)
    save_result()
    log(json.dumps(d, default=str))
    return d


# -------------------------------------------------------------------- setup
def build():
    """The scene, Add FurCollide, the reference frames; saved as base.blend."""
    scene = bpy.context.scene
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    scene.frame_start, scene.frame_end = FRAMES[0], FRAMES[-1]
    scene.frame_set(1)
    scene.render.use_lock_interface = True
    skin = grid("Skin")
    fur = hair("Fur", 10, skin)
    ball = cube("Ball", (-1.0, 0, 0.6), key_x=1.0)
    cube("Wall", (5.0, 5.0, 5.0))  # far from the hair: a collider that changes nothing
    hair("Groom", 14, skin)
    select(fur, ball)
    result["add"] = op("add")
    fur = ob("Fur")
    ref = {}
    for mode in ("STIFF", "BEND"):
        fur.furcollide.mode = mode
        ref[mode] = {}
        for f in FRAMES:
            scene.frame_set(f)
            ref[mode][f] = positions(fur.furcollide.output).copy()
    M["ref"] = ref
    result["ref_moves"] = {m: float(np.abs(r[8] - r[1]).max()) for m, r in ref.items()}
    result["ref_modes_differ"] = not np.array_equal(ref["STIFF"][8], ref["BEND"][8])
    scene.frame_set(1)
    select(fur)
    op("reset")  # only the start frame cached: the file says nothing of a lost cache
    bpy.ops.wm.save_as_mainfile(filepath=BASE)
    M["bake_dir"] = M["bake"].directory_from_settings(fur)


# ---------------------------------------------------------------- scenarios
def sc_bake():
    """Bake, undo, redo: undo takes back only the bake (its files stay), redo brings it
    back; frames played after each."""
    yield from fresh("bake")
    ob("Fur").furcollide.mode = "STIFF"
    push("Mode Stiff")  # an action before the bake: undoing the bake must keep it
    yield from play(FRAMES)
    snap("played")
    result["bake"] = op("bake")
    yield from wait_bake()
    snap("baked")
    yield from play(range(1, 5), "baked, play")
    yield from undo_redo("bake")
    # undone again, then Bake: the files left on disk are resumed, none is rewritten
    ed("undo")
    yield from settled()
    result["bake_again"] = op("bake")
    yield from wait_bake()
    snap("baked again")


def undo_redo(key, prefix=""):
    """Undo, then redo (results ``key_undo``, ``key_redo``), each followed by a snap
    (``prefix`` + "undone" / "redone") and the frames played."""
    for what, done in (("undo", "undone"), ("redo", "redone")):
        result[f"{key}_{what}"] = ed(what)
        yield from settled()
        snap(f"{prefix}{done}")
        yield from play(FRAMES, f"{prefix}{done}, play")


def sc_free_bake():
    """Free Bake, undo, redo: its files cannot come back; the setup says so."""
    yield from fresh("free_bake")
    op("bake")
    yield from wait_bake()
    snap("baked")
    ob("Wall").location.x = 6.0
    push("Move Wall")  # an action after the bake: undoing Free Bake must keep it
    result["free"] = op("free_bake")
    yield 0.3
    snap("freed")
    yield from undo_redo("free")


def sc_reset():
    """Reset Cache is no undo step (only the session's cache): Ctrl+Z after it undoes
    the action before it."""
    yield from fresh("reset")
    ob("Fur").furcollide.mode = "STIFF"
    push("Mode Stiff")
    yield from play(range(1, 6))
    result["reset"] = op("reset")
    snap("reset at 5")
    result["reset_undo"] = ed("undo")
    yield from settled()
    snap("undone")
    yield from play(range(6, 9), "undone, play on")
    result["reset_redo"] = ed("redo")
    yield from settled()
    snap("redone")
    yield from play(FRAMES, "redone, play")


def sc_attach():
    """Fur Attach Bind, undo (unbound), redo (bound again), play."""
    yield from fresh("fur_attach")
    yield from play(range(1, 5))
    result["bind"] = op("fur_attach_bind")
    snap("bound at 4")
    yield from play(range(5, 7), "bound, play")
    result["bind_undo"] = ed("undo")
    yield from settled()
    snap("undone", has_binding=M["fur_attach"].has_binding(ob("Fur")))
    yield from play(range(2, 9), "undone, play on")
    result["bind_redo"] = ed("redo")
    yield from settled()
    snap("redone", has_binding=M["fur_attach"].has_binding(ob("Fur")))
    yield from play(FRAMES, "redone, play")


def sc_sampler():
    """Fur Sampler, undo (the guides object goes), redo (it comes back)."""
    yield from fresh("fur_sampler")
    select(ob("Groom"))
    result["sampler"] = op("fur_sampler", fraction=0.2)
    guides = ob("Groom Guides")
    made = len(guides.data.curves) if guides else 0
    result["sampler_undo"] = ed("undo")
    yield from settled()
    gone = ob("Groom Guides") is None
    result["sampler_redo"] = ed("redo")
    yield from settled()
    guides = ob("Groom Guides")
    back = len(guides.data.curves) if guides else 0
    select(ob("Fur"))
    yield from play(FRAMES)
    snap("played", guides_made=made, guides_gone=gone, guides_back=back)


def groom_points():
    g = ob("Fur").furcollide.groom.output
    return None if g is None else positions(g).copy()


def sc_groom():
    """Bind Groom, undo (the groom output goes, the groom is shown again), redo, play:
    the render groom follows the guides again."""
    yield from fresh("groom")
    ob("Fur").furcollide.groom.groom = ob("Groom")
    push("Render Groom")
    result["groom_bind"] = op("groom_bind")
    snap("bound", groom_hidden=ob("Groom").hide_get())
    yield from play(range(1, 5))
    result["groom_undo"] = ed("undo")
    yield from settled()
    snap("undone", groom_hidden=ob("Groom").hide_get(),
         groom_objects=sorted(o.name for o in bpy.data.objects if "Groom" in o.name))
    yield from play(range(2, 9), "undone, play on")
    result["groom_redo"] = ed("redo")
    yield from settled()
    snap("redone", groom_hidden=ob("Groom").hide_get())
    bpy.context.scene.frame_set(1)
    yield 0.1
    g1 = groom_points()
    yield from play(FRAMES, "redone, play")
    g8 = groom_points()
    result["groom_follows"] = (None if g1 is None or g8 is None
                               else float(np.abs(g8 - g1).max()))


def sc_colliders():
    """Add Collider and Remove Collider, each undone and redone, frames played."""
    yield from fresh("colliders")
    yield from play(range(1, 5))
    select(ob("Fur"), ob("Wall"))
    result["collider_add"] = op("collider_add")
    snap("added at 4")
    result["collider_add_undo"] = ed("undo")
    yield from settled()
    snap("add undone")
    yield from play(range(2, 9), "add undone, play on")
    result["collider_add_redo"] = ed("redo")
    yield from settled()
    snap("add redone")
    select(ob("Fur"))
    ob("Fur").furcollide.collider_index = 1
    push("Select Wall in the list")
    result["collider_remove"] = op("collider_remove")
    snap("removed")
    yield from undo_redo("collider_remove", "remove ")


def sc_remove():
    """Remove FurCollide on a baked setup (it asks first: confirmed with Return; the files
    are kept), undo (setup, output and bake back), redo."""
    yield from fresh("remove")
    op("bake")
    yield from wait_bake()
    snap("baked")
    result["remove"] = op("remove")  # the button: Blender asks first
    yield 0.5
    result["remove_asked"] = ob("Fur").furcollide.is_setup  # (nothing removed yet)
    # the dialog's Remove: Return, with the mouse where the click left it
    subprocess.run(["xdotool", "key", "Return"], capture_output=True)
    yield 0.8
    result["removed"] = {"is_setup": ob("Fur").furcollide.is_setup,
                         "output": ob("Fur FurCollide") is not None,
                         "files": len(bake_files())}
    result["remove_undo"] = ed("undo")
    yield from settled()
    snap("undone")
    yield from play(FRAMES, "undone, play")
    result["remove_redo"] = ed("redo")
    yield from settled()
    result["remove_redone"] = {"is_setup": ob("Fur").furcollide.is_setup,
                               "output": ob("Fur FurCollide") is not None,
                               "source_hidden": ob("Fur").hide_get(),
                               "files": len(bake_files())}
    yield from play(range(1, 4))


def sc_playing():
    """Ctrl+Z during playback (a real key press), then play on."""
    yield from fresh("playing")
    ob("Fur").furcollide.mode = "STIFF"
    push("Mode Stiff")
    snap("edited, before its refresh")  # (the frame shown is the old mode's: outdated)
    yield from settled()
    scene = bpy.context.scene
    scene.sync_mode = "NONE"
    seen = []

    @persistent
    def after(scn, _dg=None):  # after FurCollide's handler: what the frame shows
        try:
            seen.append(snap(f"playing {scn.frame_current}"))
        except Exception:  # noqa: BLE001
            result["errors"].append(traceback.format_exc())

    bpy.app.handlers.frame_change_post.append(after)
    try:
        with override():
            bpy.ops.screen.animation_play()
        t0 = time.perf_counter()
        while bpy.context.scene.frame_current < 4 and time.perf_counter() - t0 < 30:
            yield 0.02
        key("ctrl+z")
        result["undo_while_playing_at"] = bpy.context.scene.frame_current
        t0 = time.perf_counter()
        yield 0.5
        n = len(seen)
        while (len(seen) < n + 8 or bpy.context.scene.frame_current < 8) and (
                time.perf_counter() - t0 < 30):
            yield 0.02
        with override():
            bpy.ops.screen.animation_cancel(restore_frame=False)
    finally:
        bpy.app.handlers.frame_change_post.remove(after)
    yield from settled()
    snap("stopped")


def sc_baking():
    """Ctrl+Z (a real key press) while the modal bake runs, then play."""
    yield from fresh("baking")
    ob("Fur").furcollide.mode = "STIFF"
    push("Mode Stiff")
    result["baking_invoke"] = op("bake")
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < 60:
        prog = M["ops_bake"].PROGRESS.get(bpy.context.scene.name)
        if prog and prog[0] >= 2:
            break
        yield 0.02
    snap("baking")
    key("ctrl+z")
    yield 1.0
    snap("undone while baking")
    yield from wait_bake()
    yield from play(FRAMES, "after, play")
    result["baking_files"] = bake_files()


def sc_held():
    """Undo back to a step taken while the output held an older frame (a jump ahead),
    after every frame was played: the frame shown must be the cached one, or say so."""
    yield from fresh("held")
    scene = bpy.context.scene
    scene.frame_set(5)  # a jump ahead: frame 1 is held
    yield 0.1
    snap("jumped to 5")
    ob("Wall").location.x = 6.0
    push("Move Wall")
    ob("Wall").location.x = 7.0
    push("Move Wall again")
    yield from play(FRAMES)
    snap("played")
    result["held_undo"] = ed("undo")
    snap("undone, before its refresh")  # (what undo_post left: never claims current)
    yield from settled()
    snap("undone")
    result["held_redo"] = ed("redo")
    yield from settled()
    snap("redone")


def sc_reopen():
    """A setting changed just before a file is opened (a script): the refresh it
    scheduled is dropped with the old file's timers; the next edit in the new file
    still solves the current frame again (and so does an undo: see sc_held)."""
    yield from fresh("reopen")
    ob("Fur").furcollide.mode = "STIFF"  # a refresh is scheduled...
    bpy.ops.wm.open_mainfile(filepath=BASE)  # ...and dropped with the file's timers
    yield 0.5
    bpy.context.scene.frame_set(1)
    yield 0.1
    snap("opened")
    ob("Fur").furcollide.mode = "STIFF"  # an edit in the new file: frame 1 solved again
    yield from settled()
    snap("edited")


# -------------------------------------------------------------------- the run
def run():
    yield 1.0
    key("Escape")  # the splash screen
    yield 0.5
    install(run_report, ZIP, ADDON)
    for name, module in (("registry", "store.registry"), ("report", "store.report"),
                         ("ops_bake", "ops.bake"),
                         ("bake", "store.bake"), ("fur_attach", "frame.attach"),
                         ("invalidation", "store.invalidation")):
        M[name] = sys.modules[f"{ADDON}.operators.{module}"]
    instrument_ui()
    build()
    yield from show_sidebar()
    for scenario in (sc_bake, sc_free_bake, sc_reset, sc_attach, sc_sampler, sc_groom,
                     sc_colliders, sc_remove, sc_playing, sc_baking, sc_held, sc_reopen):
        try:
            yield from scenario()
        except Exception:  # one scenario's failure is recorded; the others still run
            result["errors"].append(f"{M['scenario']}: {traceback.format_exc()}")
            log(result["errors"][-1])
        save_result()
    yield 0.5
    result["steps"].append("done")


log(f"Blender {bpy.app.version_string}, Python {sys.version.split()[0]}")
save_result()
start(run(), result, save_result, log, persistent=True)
