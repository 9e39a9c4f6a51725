"""What the real-application drivers share (run inside Blender, never imported by pytest).

``app_session.run_session`` copies this file next to the driver it runs; a driver
imports it from its own folder. The drivers run from ``bpy.app.timers``: one generator
whose each ``yield`` hands control back to Blender's event loop for that many seconds.
"""

from __future__ import annotations

import json
import os
import subprocess
import traceback

import bpy
import numpy as np
from mathutils import Vector
from mathutils.bvhtree import BVHTree


class Report:
    """A driver's ``result.json`` in its work folder, its log lines (prefixed with the
    driver's ``name``) and its screenshots (``shots/`` there, the whole X screen)."""

    def __init__(self, name, work, result):
        self.name, self.result = name, result
        self.path = os.path.join(work, "result.json")
        self.shots = os.path.join(work, "shots")

    def log(self, msg):
        print(f"{self.name}: {msg}", flush=True)

    def save(self):
        with open(self.path, "w") as fh:
            json.dump(self.result, fh, indent=1, default=str)

    def step(self, name, **data):
        """Record step ``name`` (and ``data`` into the result), save, log."""
        self.result["steps"].append(name)
        self.result.update(data)
        self.save()
        self.log(f"{name}: {data}" if data else name)

    def shot(self, name):
        """Screenshot ``shots/<name>.png``; its path (or why it failed) is recorded."""
        os.makedirs(self.shots, exist_ok=True)
        path = os.path.join(self.shots, name + ".png")
        proc = subprocess.run(["import", "-window", "root", path], capture_output=True,
                              text=True)
        self.result.setdefault("screenshots", []).append(
            path if proc.returncode == 0 else proc.stderr)
        self.save()


def install(report, zip_path, addon):
    """Install the packaged zip as Install from Disk does, recorded as the step
    ``install`` (what the operator returned, whether the add-on is enabled); raise
    unless it really is enabled (the operator says FINISHED even when it is not)."""
    ret = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                   enable_on_install=True)
    enabled = addon in bpy.context.preferences.addons
    report.step("install", install_return=sorted(ret), enabled=enabled)
    if not enabled:
        raise RuntimeError("the add-on is not enabled after package_install_files")


# ------------------------------------------------ the oracle: Blender's own BVH
def collider_tree(ob, depsgraph):
    """Blender's BVH of ``ob``'s mesh as ``depsgraph`` evaluates it, in world space."""
    oe = ob.evaluated_get(depsgraph)
    me = oe.to_mesh()
    M = np.array(oe.matrix_world)
    V = [tuple(M[:3, :3] @ np.array(v.co) + M[:3, 3]) for v in me.vertices]
    me.calc_loop_triangles()
    tree = BVHTree.FromPolygons(V, [tuple(t.vertices) for t in me.loop_triangles],
                                all_triangles=True)
    oe.to_mesh_clear()
    return tree


def crossing_curves(P, offs, tree, keep=None):
    """How many curves (of those ``keep``, a (C,) bool, allows; all when None) have a
    segment through the collider of ``tree``: points ``P`` (world), ``offs`` (C+1,)."""
    bad = 0
    for c in range(len(offs) - 1):
        if keep is not None and not keep[c]:
            continue
        for i in range(offs[c], offs[c + 1] - 1):
            a, b = Vector(P[i]), Vector(P[i + 1])
            d = b - a
            if d.length > 0 and tree.ray_cast(a, d.normalized(), d.length)[0] is not None:
                bad += 1
                break
    return bad


def redraw():
    """Ask every area of every window to draw again."""
    for win in bpy.context.window_manager.windows:
        for area in win.screen.areas:
            area.tag_redraw()


def ui():
    """(window, 3D view area, its WINDOW region, its sidebar region)."""
    win = bpy.context.window_manager.windows[0]
    area = max((a for a in win.screen.areas if a.type == "VIEW_3D"), key=lambda a: a.width)
    region = next(r for r in area.regions if r.type == "WINDOW")
    side = next(r for r in area.regions if r.type == "UI")
    return win, area, region, side


def override():
    """A context override for the 3D view's main region."""
    win, area, region, _ = ui()
    return bpy.context.temp_override(window=win, screen=win.screen, area=area, region=region)


def select(active, *others):
    """Select ``active`` and ``others`` only, ``active`` the active object."""
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for o in (active, *others):
        o.select_set(True)
    bpy.context.view_layer.objects.active = active


def instrument_ui(classes, key, errors, calls=None):
    """Re-register the add-on's UI ``classes`` with their panels open and every drawing
    method wrapped: ``key(cls, method name)`` names each call; an exception raised while
    drawing is appended to ``errors`` as ``"key: traceback"`` and raised again; ``calls``
    (a dict), if given, counts the calls per key."""
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    for cls in classes:
        if issubclass(cls, bpy.types.Panel):
            cls.bl_options = set(getattr(cls, "bl_options", set())) - {"DEFAULT_CLOSED"}
        for name in ("draw", "draw_header", "draw_header_preset", "draw_item"):
            _wrap(cls, name, key, errors, calls)
        bpy.utils.register_class(cls)


def _wrap(cls, name, key, errors, calls):
    fn = cls.__dict__.get(name)
    if fn is None or getattr(fn, "_wrapped", False):
        return

    def call(self, *args):
        k = key(cls, name)
        if calls is not None:
            calls[k] = calls.get(k, 0) + 1
        try:
            return fn(self, *args)
        except Exception:
            errors.append(f"{k}: {traceback.format_exc()}")
            raise

    # Blender checks a drawing method's argument count: keep the original's
    if name == "draw_item":
        def wrapped(self, context, layout, data, item, icon, active_data, active_propname,
                    index):
            return call(self, context, layout, data, item, icon, active_data, active_propname,
                        index)
    else:
        def wrapped(self, context):
            return call(self, context)
    wrapped._wrapped = True
    setattr(cls, name, wrapped)


def start(gen, result, save_result, log, persistent=False):
    """Drive the generator ``gen`` from a timer until it ends or raises (the traceback
    is kept in ``result["errors"]``), then save ``result`` and quit Blender.
    ``persistent``: the timer survives opening a file."""

    def tick():
        try:
            return next(gen)
        except StopIteration:
            result["finished"] = True
        except Exception:
            result["errors"].append(traceback.format_exc())
            log(result["errors"][-1])
        save_result()
        bpy.app.timers.register(_quit, first_interval=0.5)
        return None

    bpy.app.timers.register(tick, first_interval=1.0, persistent=persistent)


def _quit():
    bpy.ops.wm.quit_blender()
