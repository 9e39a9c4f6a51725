"""What the real-application drivers share (run inside Blender, never imported by pytest).

``app_session.run_session`` copies this file next to the driver it runs; a driver
imports it from its own folder. The drivers run from ``bpy.app.timers``: one generator
whose each ``yield`` hands control back to Blender's event loop for that many seconds.
"""

from __future__ import annotations

import traceback

import bpy


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
