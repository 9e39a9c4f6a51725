"""Nothing FurCollide runs inside Blender raises into it (README "Headless and batch"):
the depsgraph check (``depsgraph_update_post``) and the refresh timer turn any error into
the setup's status message and one console line, whatever fails inside them.

Faults are injected into each function the handlers call; Blender itself fires the
depsgraph handler (``view_layer.update()`` after an edit), and prints "Error in
bpy.app.handlers..." with a traceback to stderr if a handler raises: the tests read
the process's own stderr (``capfd``). Timers never fire headless, so the refresh timer
is taken from ``bpy.app.timers.register`` and called as Blender would call it.
"""

from __future__ import annotations

import sys
import types

import bpy
import pytest
from helpers import ADDON, play, small_setup

pytestmark = pytest.mark.blender


def _module(name):
    return sys.modules[f"{ADDON}.operators.{name}"]


class Injected(RuntimeError):
    pass


def _raiser(*_args, **_kw):
    raise Injected("injected fault")


def _no_handler_error(capfd):
    cap = capfd.readouterr()
    text = cap.out + cap.err
    assert "Error in bpy.app.handlers" not in text, text
    assert "Traceback" not in text, text
    return text


#: What the depsgraph check calls, by the module name it looks it up in.
DEPSGRAPH_CALLS = [
    ("store.registry", "prune"),
    ("store.registry", "setups"),
    ("store.registry", "get_runtime"),
    ("frame.handlers", "dependencies_stale"),
    ("frame.handlers", "collider_objects"),
    ("frame.handlers", "structure"),
    ("store.invalidation", "invalidate"),
]


@pytest.mark.parametrize(("module", "name"), DEPSGRAPH_CALLS,
                         ids=[f"{m}.{n}" for m, n in DEPSGRAPH_CALLS])
def test_depsgraph_check_never_raises(fc, capfd, monkeypatch, module, name):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    play(scene, range(1, 5))
    capfd.readouterr()
    other = bpy.data.objects.new("Other", None)
    scene.collection.objects.link(other)
    bpy.context.view_layer.update()
    capfd.readouterr()
    monkeypatch.setattr(_module(module), name, _raiser)
    # an edit of something else (the check compares the setup's signature), then of
    # a collider (it drops the cached frames): between them they reach every call
    other.location.x += 1.0
    bpy.context.view_layer.update()
    box.scale.x *= 1.2
    bpy.context.view_layer.update()
    text = _no_handler_error(capfd)
    lines = [ln for ln in text.splitlines() if "injected fault" in ln]
    assert 1 <= len(lines) <= 2, text  # at most one console line per check
    # called directly, with a depsgraph listing the edit, it returns normally too
    dg = types.SimpleNamespace(mode="VIEWPORT", updates=[types.SimpleNamespace(
        id=box, is_updated_geometry=True, is_updated_transform=True)])
    assert _module("frame.handlers").on_depsgraph_update_post(scene, dg) is None


def test_a_depsgraph_check_error_becomes_the_setups_status(fc, capfd, monkeypatch):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    play(scene, range(1, 5))
    monkeypatch.setattr(_module("store.invalidation"), "invalidate", _raiser)
    box.scale.x *= 1.2
    bpy.context.view_layer.update()
    _no_handler_error(capfd)
    level, message = fc.store.report.status_for(hair)
    assert level == "ERROR" and "injected fault" in message, (level, message)


def test_depsgraph_check_with_a_deleted_collider_and_source(fc, capfd):
    """Objects deleted between two checks (the registry still names them)."""
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    play(scene, range(1, 4))
    bpy.data.objects.remove(box)
    bpy.context.view_layer.update()
    play(scene, range(4, 6))
    bpy.data.objects.remove(hair)
    bpy.context.view_layer.update()
    play(scene, range(6, 8))
    _no_handler_error(capfd)


# ------------------------------------------------------------------ the refresh timer
@pytest.fixture
def timers(monkeypatch):
    """Make :func:`invalidation.schedule_refresh` schedule as in the UI: ``bpy`` as the
    module sees it has ``app.background`` False and a ``timers.register`` that keeps
    the functions (Blender calls them later; here the test does)."""
    inv = _module("store.invalidation")
    registered = []
    app = types.SimpleNamespace(
        background=False,
        timers=types.SimpleNamespace(
            register=lambda fn, first_interval=0.0: registered.append(fn),
            is_registered=lambda fn: fn in registered,
            unregister=lambda fn: registered.remove(fn)))
    fake = types.SimpleNamespace(app=app, data=bpy.data, context=bpy.context)
    monkeypatch.setattr(inv, "bpy", fake)
    yield registered
    inv._pending_refresh.clear()


def test_refresh_timer_refreshes_the_current_frame(fc, timers, monkeypatch):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    play(scene, range(1, 4))
    assert fc.store.report.status_for(hair) == ("INFO", "")
    hair.furcollide.recovery_rate = 0.9  # a setting: drops frames, schedules a refresh
    assert len(timers) == 1
    # the setting's update already says so (the playback cache was dropped) ...
    assert fc.store.report.status_for(hair)[1].startswith("Frame 3 is outdated: Recovery Rate")
    fc.store.report.set_status(hair, "INFO", "")
    seen = []
    evaluate = fc.frame.spine.evaluate
    monkeypatch.setattr(fc.frame.spine, "evaluate",
                        lambda setup: seen.append((setup.ob.name, setup.frame)) or
                        evaluate(setup))
    assert timers[0]() is None  # done: not rescheduled
    # ... and the timer evaluated the current frame again, which says it once more
    assert seen == [(hair.name, 3)], seen
    level, message = fc.store.report.status_for(hair)
    assert level == "WARNING" and message.startswith("Frame 3 is outdated: Recovery Rate "
                                                     "changed"), message


@pytest.mark.parametrize("fault", ["evaluate", "Setup", "deleted", "busy"])
def test_refresh_timer_never_raises(fc, capfd, monkeypatch, timers, fault):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    play(scene, range(1, 4))
    hair.furcollide.recovery_rate = 0.9
    (refresh,) = timers
    inv = _module("store.invalidation")
    capfd.readouterr()
    if fault == "evaluate":
        monkeypatch.setattr(fc.frame.spine, "evaluate", _raiser)
    elif fault == "Setup":
        monkeypatch.setattr(fc.frame.scenes, "Setup", _raiser)  # (the refresh goes through it)
    elif fault == "deleted":
        bpy.data.objects.remove(hair)
    else:
        monkeypatch.setattr(inv.registry, "busy", lambda: True)
        assert refresh() == pytest.approx(0.1)  # the frame handler runs: try again soon
        monkeypatch.setattr(inv.registry, "busy", lambda: False)
        monkeypatch.setattr(fc.frame.spine, "evaluate", _raiser)
    assert refresh() is None
    text = _no_handler_error(capfd)
    if fault != "deleted":
        level, message = fc.store.report.status_for(hair)
        assert level == "ERROR" and "injected fault" in message, (level, message)
        assert sum("injected fault" in ln for ln in text.splitlines()) == 1, text
