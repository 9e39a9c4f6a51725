"""The setups of this Blender session: one :class:`Runtime` each, their status and errors.

A setup's runtime lives only in this session (never in bpy properties): the core
``Solver``, one core ``Collider`` per collider object (kept across frames, so that rigid
motion never rebuilds a BVH), the bounded memory cache, and the status and statistics the
panel shows. It is keyed by the setup id plus the source object's session id, so a
duplicated source never shares the original's. :func:`prune` drops the runtimes of
setups that are gone (a source deleted in the UI), memory cache and all.

Status messages and errors live here too: :func:`set_status` prints one console line per
distinct problem, :func:`record_error` turns an exception into the setup's status, and
:func:`describe` gives an exception's user-facing text.
"""

from __future__ import annotations

import os
import re
import traceback
import uuid
from contextlib import contextmanager
from dataclasses import dataclass, field

import bpy

from .. import core
from ..core import framecache
from . import bridge
from .motion import RootHistory


@dataclass
class Runtime:
    """Session-only state of one setup."""

    uid: str
    name: str = ""  # the source object's name when last looked up (see prune)
    solver: object = None  # core.Solver, built for ``topology`` (its settings: solver.settings)
    #: The source's curve layout (``framecache.topology_key``) the solver, the cached
    #: frames and the jiggle history belong to: :meth:`adopt_topology` changes it.
    topology: tuple | None = None
    colliders: dict = field(default_factory=dict)  # collider uid -> colliders.ColliderEntry
    growth: object = None  # colliders.ColliderEntry of the growth surface
    memory: framecache.MemoryCache = field(default_factory=framecache.MemoryCache)
    solver_frame: int | None = None  # frame whose result the solver state holds
    hold: tuple | None = None  # (frame, world positions, status) of newest frame
    signature: str | None = None  # colliders + settings seen last
    outdated: bool = False
    baking: bool = False
    status: tuple = ("INFO", "")
    printed: str = ""
    stats: dict = field(default_factory=dict)
    #: The status for the INVALID curves of the last solved frame (None: none).
    invalid_note: tuple | None = None
    error: str = ""  # last solve error (kept visible while frames cannot be solved)
    written_status: tuple | None = None  # (data session uid, status, colours) last written
    attach: tuple | None = None  # (attach_id, core Binding, surface topology key): Fur Attach
    attach_state: tuple | None = None  # (use_fur_attach, attach_id) seen last
    time_state: float | None = None  # setup.time_key seen last
    history: RootHistory = field(default_factory=RootHistory)  # jiggle
    groom: tuple | None = None  # (bind_id, groom_stage.GroomBinding): render groom
    groom_shown: tuple | None = None  # (frame, guides) the groom output shows
    children: object = None  # children_stage.ChildrenState: the children output
    #: Why the playback cache is empty (until the start frame is solved again): the
    #: reason the frames that are not cached give, e.g. "'Box' moved: the playback
    #: cache was dropped".
    dropped: str = ""
    dropped_why: str = ""  # the change itself ("'Box' moved")...
    dropped_at: int | None = None  # ...and the frame it was seen at
    #: ((scene name, frame), frame-inputs record) the frame handler last evaluated: the
    #: depsgraph check compares the scene with it (an update that changes nothing the
    #: frame was solved or shown from is the animation evaluated again, not an edit).
    seen: tuple | None = None
    #: Objects the depsgraph reported updated while the current frame's inputs held (the
    #: animation evaluated again, or a key moved on another frame), since the playback
    #: cache was last dropped; and the cached frames known to hold since: the frame it
    #: was seen at, the frames solved after. A cached frame whose inputs changed only
    #: in those objects is solved again from a verified previous frame (a key moved
    #: ahead of it); any other change drops the playback cache (see frame_rules).
    trusted: set = field(default_factory=set)
    verified: set = field(default_factory=set)
    #: Collider uid -> what was said about it once (``colliders._tell``), and what the
    #: next status says of colliders just built (``colliders.collider_note``).
    told: dict = field(default_factory=dict)
    fresh_notes: list = field(default_factory=list)
    #: What the output last got of the evaluated source's attributes
    #: (``bridge.attribute_state``; None: nothing yet, copy them on the next frame).
    output_attributes: tuple | None = None

    def forget_solver(self):
        self.solver = None
        self.solver_frame = None
        self.colliders.clear()
        self.growth = None

    def adopt_topology(self, key) -> bool:
        """Take the source's curve layout ``key``; True when it changed (the solver and
        the jiggle history, which belong to the old curves, are forgotten)."""
        changed = self.topology is not None and self.topology != key
        if changed:
            self.forget_solver()
            self.history.clear()
        self.topology = key
        return changed

    def drop_frames_after(self, f: int, start: int) -> None:
        """Forget the cached frames after ``f`` (every one when ``f`` is before the
        start frame ``start``), and what was derived from them."""
        self.verified = {k for k in self.verified if k <= f}
        if f < start:
            self.memory.clear()
            self.hold = None
        else:
            self.memory.drop_after(f)
            if self.hold is not None and self.hold[0] > f:
                self.hold = None
        if self.solver_frame is not None and self.solver_frame > f:
            self.solver_frame = None
        self.history.drop_after(f)
        self.groom_shown = None
        self.signature = None  # accept the new settings without a second drop

    def drop_cache(self, why: str, start: int, frame: int | None = None) -> bool:
        """Drop the whole playback cache, as Blender's point cache does on a change:
        the frames shown next are solved again from the start frame ``start`` on, and
        until then the frames that are not cached say ``why`` (the change, seen at
        ``frame``). True when frames (or a solver state) were dropped."""
        had = len(self.memory) > 0 or self.solver_frame is not None
        self.drop_frames_after(start - 1, start)
        self.solver_frame = None
        self.verified.clear()
        self.trusted.clear()
        if had and why:
            self.dropped = f"{why}: the playback cache was dropped"
            self.dropped_why, self.dropped_at = why, frame
        return had


registry: dict[str, Runtime] = {}

#: Why the playback cache is empty after a file saved with one was opened (the reason
#: the frames that are not cached give, as ``Runtime.dropped``, until the start frame
#: is solved again).
NOT_SAVED = "the playback cache is not saved with the file: bake to keep the frames"


def ensure_uid(ob) -> str:
    """The setup id of ``ob`` (created on first use)."""
    s = ob.furcollide
    if not s.uid:
        s.uid = uuid.uuid4().hex
    return s.uid


def _key(ob) -> str:
    # The setup id plus the object's session id: a duplicated source (same
    # setup id) never shares the original's runtime. Both survive undo.
    return f"{ob.furcollide.uid}:{ob.original.session_uid}"


def get_runtime(ob, create=True) -> Runtime | None:
    """Runtime of the setup on source ``ob``."""
    uid = ob.furcollide.uid
    if not uid:
        return None
    key = _key(ob)
    rt = registry.get(key)
    if rt is None and create:
        rt = registry[key] = Runtime(uid)
        rt.memory = framecache.MemoryCache(ob.furcollide.memory_limit)
    if rt is not None:
        rt.name = ob.name
    return rt


def clear_runtime(ob) -> None:
    """Forget everything held in memory for the setup on ``ob``."""
    registry.pop(_key(ob), None)


def prune() -> int:
    """Forget the runtimes (memory caches included) of setups that are gone: their
    source was removed from the file or is in no scene any more (a source deleted in
    the UI stays alive while its output points at it), or is no longer that setup.
    Returns how many were forgotten.

    Cheap when nothing is gone (one name look-up per runtime); a renamed source
    costs one pass over the file's hair objects.
    """
    if not registry:
        return 0
    alive = set()
    for key, rt in registry.items():
        ob = bpy.data.objects.get(rt.name)
        if ob is not None and _alive(ob) and _key(ob) == key:
            alive.add(key)
    if len(alive) < len(registry):  # gone, or renamed: look at every hair object
        for ob in bpy.data.objects:
            if ob.type == "CURVES" and _alive(ob) and _key(ob) in registry:
                alive.add(_key(ob))
    gone = [key for key in registry if key not in alive]
    for key in gone:
        del registry[key]
    return len(gone)


def _alive(ob) -> bool:
    s = getattr(ob, "furcollide", None)
    return s is not None and s.is_setup and bool(s.uid) and bool(ob.users_scene)


def source_of(ob):
    """Source object of the setup ``ob`` belongs to (itself, or its source)."""
    if ob is None:
        return None
    s = getattr(ob, "furcollide", None)
    if s is None:
        return None
    if s.is_setup:
        return ob
    if s.is_output and s.source is not None and s.source.furcollide.is_setup:
        return s.source
    return None


def setups(scene):
    """Source objects of every FurCollide setup in ``scene``."""
    return [ob for ob in scene.objects if ob.type == "CURVES" and ob.furcollide.is_setup]


# ------------------------------------------------------------ handler guard
_busy = False  # the frame handler (or a bake, or a look at another frame) is running


def busy() -> bool:
    """Is FurCollide evaluating already? (Handlers fired from inside it do nothing.)"""
    return _busy


@contextmanager
def handlers_held():
    """Within the block, FurCollide's frame handler and refresh timers do nothing (a
    bake, or a visit of another frame to read it, changes frames itself)."""
    global _busy
    was, _busy = _busy, True
    try:
        yield
    finally:
        _busy = was


# ------------------------------------------------------------- status, errors
def set_status(ob, level: str, message: str) -> None:
    """Set the setup's status; a new warning/error prints one console line."""
    rt = get_runtime(ob)
    if rt is None:
        return
    rt.status = (level, message)
    # One console line per distinct problem (frame numbers do not count).
    key = re.sub(r"\d+", "#", message) if level != "INFO" else ""
    if key and key != rt.printed:
        print(f"FurCollide '{ob.name}': {message}", flush=True)
    rt.printed = key


def stats_for(ob) -> dict:
    rt = get_runtime(ob, create=False)
    return rt.stats if rt else {}


def status_for(ob) -> tuple:
    rt = get_runtime(ob, create=False)
    return rt.status if rt else ("INFO", "")


def is_outdated(ob) -> bool:
    rt = get_runtime(ob, create=False)
    return bool(rt and rt.outdated)


def record_error(ob, exc: Exception) -> None:
    """A failed frame of the setup on ``ob``: its status message plus one console line
    (a traceback too with ``FURCOLLIDE_DEBUG`` set). Never raises."""
    message = describe(exc)
    try:
        rt = get_runtime(ob)
        if rt is not None:
            rt.error = message
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
