"""What the panel shows of a setup: its status message, outdated mark and statistics;
errors in words.

A setup's runtime (:class:`.registry.Runtime`) holds one :class:`Report`, changed only
here: a frame sets it once, at its end (:func:`..frame.output.publish`); an edit, a
baked setup's check, a file opened or a failed frame set it between frames.
:func:`set_status` prints one console line per distinct problem,
:func:`record_error` turns an exception into the setup's status, and :func:`describe`
gives an exception's user-facing text.
"""

from __future__ import annotations

import os
import re
import traceback
from dataclasses import dataclass, field

from ... import core
from ..blender import bridge
from . import registry


@dataclass(slots=True)
class Report:
    """The part of a setup's runtime the panel shows."""

    status: tuple = ("INFO", "")  # (level, message)
    printed: str = ""  # the console line printed last, frame numbers left out
    outdated: bool = False  # the frame shown is outdated
    stats: dict = field(default_factory=dict)  # the last frame's statistics
    #: The status for the INVALID curves of the last solved frame (None: none).
    invalid_note: tuple | None = None
    error: str = ""  # last solve error (kept visible while frames cannot be solved)


def set_status(ob, level: str, message: str) -> None:
    """Set the status of the setup on ``ob``; a new warning/error prints one console
    line."""
    rt = registry.get_runtime(ob)
    if rt is None:
        return
    rep = rt.report
    rep.status = (level, message)
    # One console line per distinct problem (frame numbers do not count).
    key = re.sub(r"\d+", "#", message) if level != "INFO" else ""
    if key and key != rep.printed:
        print(f"FurCollide '{ob.name}': {message}", flush=True)
    rep.printed = key


def publish(ob, rt, status=None, outdated=None, stats=None) -> None:
    """A frame's status ``(level, message)``, outdated mark and statistics (each None:
    unchanged) for the setup on ``ob`` with runtime ``rt``."""
    if outdated is not None:
        rt.report.outdated = outdated
    if stats is not None:
        rt.report.stats = stats
    if status is not None:
        set_status(ob, *status)


def mark_outdated(rt, outdated=True) -> None:
    """The frame the setup shows is (not) outdated."""
    rt.report.outdated = outdated


def solved(rt, invalid_note) -> None:
    """A frame was solved: the last error is gone, ``invalid_note`` says what the core
    left as it is (None: nothing)."""
    rt.report.error = ""
    rt.report.invalid_note = invalid_note


def drop_stats(rt, prefix) -> None:
    """Forget the statistics whose name starts with ``prefix`` (a stage removed)."""
    rt.report.stats = {k: v for k, v in rt.report.stats.items() if not k.startswith(prefix)}


def stats_for(ob) -> dict:
    rt = registry.get_runtime(ob, create=False)
    return rt.report.stats if rt else {}


def status_for(ob) -> tuple:
    rt = registry.get_runtime(ob, create=False)
    return rt.report.status if rt else ("INFO", "")


def status_shown(ob, scene=None) -> tuple:
    """The status the panel shows for the setup on ``ob`` in ``scene`` (default: the
    context scene): where it belongs to another scene, that
    (:func:`.registry.foreign_message`); else :func:`status_for`."""
    msg = registry.foreign_message(ob, scene)
    return ("WARNING", msg) if msg else status_for(ob)


def is_outdated(ob, scene=None) -> bool:
    """Is the frame the setup on ``ob`` shows outdated? Never in a scene it does not
    belong to (its output shows the source there)."""
    rt = registry.get_runtime(ob, create=False)
    return bool(rt and rt.report.outdated) and not registry.foreign_message(ob, scene)


def record_error(ob, exc: Exception) -> None:
    """A failed frame of the setup on ``ob``: its status message plus one console line
    (a traceback too with ``FURCOLLIDE_DEBUG`` set). Never raises."""
    message = describe(exc)
    try:
        rt = registry.get_runtime(ob)
        if rt is not None:
            rt.report.error = message
        set_status(ob, "ERROR", message)
    except Exception:  # noqa: BLE001 - the object or the add-on is gone
        print(f"FurCollide: {message}", flush=True)
    if os.environ.get("FURCOLLIDE_DEBUG"):
        traceback.print_exception(exc)


def describe(exc: Exception) -> str:
    """The user-facing text of ``exc``: the message of the errors FurCollide raises on
    purpose, else the exception's type and message."""
    if isinstance(exc, core.FurCollideError | ImportError):
        return str(exc)
    if isinstance(exc, ValueError | RuntimeError | bridge.BridgeError):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"
