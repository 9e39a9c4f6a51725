"""The setups of this Blender session: one :class:`Runtime` each, their status and errors.

A setup's runtime lives only in this session (never in bpy properties): the core
``Solver``, one core ``Collider`` per collider object (kept across frames, so that rigid
motion never rebuilds a BVH), the bounded memory cache, and the status and statistics the
panel shows. It is keyed by the setup id plus the source object's session id, so a
duplicated source never shares the original's. :func:`prune` drops the runtimes of
setups that are gone (a source deleted in the UI), memory cache and all.

A setup belongs to one scene (:func:`owner`): the one Add FurCollide ran in, recorded
on the source (``owner_scene``). A hair object linked into several scenes (a character
collection in several shots) is set up in that one only: in the others its output shows
the source as groomed and nothing of the setup's cache or bake is touched
(:mod:`..frame.scenes`); :func:`setups` lists a scene's own setups, and :func:`foreign_message`
says where a setup belongs.

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

from ... import core
from ...core import framecache, splines
from ...core.pipeline.frame import RootHistory
from ..blender import bridge


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
    #: The spline margin of the last frame solved and what it was computed from.
    drawn: splines.DrawnMargin = field(default_factory=splines.DrawnMargin)
    #: Follow Collider Motion: frame -> {collider uid: core Placement} of cached frames.
    placements: dict = field(default_factory=dict)
    growth: object = None  # colliders.ColliderEntry of the growth surface
    memory: framecache.MemoryCache = field(default_factory=framecache.MemoryCache)
    solver_frame: int | None = None  # frame whose result the solver state holds
    hold: tuple | None = None  # (frame, world positions, status) of newest frame
    #: What every frame of the shot shares, seen last (``fingerprints.structure``: which
    #: objects collide, Mode, ...); a change drops the playback cache.
    signature: str | None = None
    #: ``keyed.fingerprint`` seen last: the depsgraph check looks for changed values
    #: only when it changed (keys edited, a setting changed without an update).
    values_seen: int | None = None
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
    time_state: float | None = None  # fingerprints.time_key seen last
    history: RootHistory = field(default_factory=RootHistory)  # jiggle
    groom: tuple | None = None  # (bind_id, frame.groom.GroomBinding): render groom
    groom_shown: tuple | None = None  # (frame, guides) the groom output shows
    children: object = None  # frame.children.ChildrenState: the children output
    #: Why the playback cache is empty (until the start frame is solved again): the
    #: reason the frames that are not cached give, e.g. "'Box' moved: the playback
    #: cache was dropped".
    dropped: str = ""
    dropped_why: str = ""  # the change itself ("'Box' moved")...
    dropped_at: int | None = None  # ...and the frame it was seen at...
    dropped_from: int = 0  # ...and the first frame dropped
    #: ((scene name, frame), frame-inputs record) the frame handler last evaluated: the
    #: depsgraph check compares the scene with it (an update that changes nothing the
    #: frame was solved or shown from is the animation evaluated again, not an edit).
    seen: tuple | None = None
    #: Objects the depsgraph reported updated while the current frame's inputs held (the
    #: animation evaluated again, or a key moved on another frame), since the playback
    #: cache was last dropped; and the cached frames known to hold since: the frame it
    #: was seen at, the frames solved after. A cached frame whose inputs changed only
    #: in those objects is solved again from a verified previous frame (a key moved
    #: ahead of it); any other change drops the playback cache (see frame.rules).
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

    def restart(self, start: int, limit_mb: float) -> None:
        """The start frame ``start`` is solved again: the playback cache starts over
        (with the Memory Limit ``limit_mb``), nothing dropped before is said any more."""
        self.memory.clear()
        self.verified.clear()
        self.trusted.clear()
        self.dropped = ""
        self.memory.start = start
        self.memory.limit = int(limit_mb * 1024 * 1024)

    def drop_from(self, first: int, why: str, start: int, frame: int | None = None) -> bool:
        """Drop the cached frames from ``first`` on (every one when ``first`` is the
        start frame ``start`` or before it: :meth:`drop_cache`): ``why`` (a change seen
        at ``frame``) made them other than they were solved. True when frames were
        dropped."""
        if first <= start:
            return self.drop_cache(why, start, frame)
        had = any(k >= first for k in self.memory.frames) or (
            self.solver_frame is not None and self.solver_frame >= first)
        self.drop_frames_after(first - 1, start)
        self.trusted.clear()
        if had and why:
            self.dropped = f"{why}: the frames from {first} on were dropped"
            self.dropped_why, self.dropped_at, self.dropped_from = why, frame, first
        return had

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
            self.dropped_why, self.dropped_at, self.dropped_from = why, frame, start
        return had


registry: dict[str, Runtime] = {}
#: The runtimes a setup uses in the scenes it does not belong to (what the output was
#: last written with there, the render groom's binding): (setup key, scene session id)
#: -> Runtime. Never the setup's own cache: :func:`foreign_runtime`.
foreign: dict[tuple, Runtime] = {}

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
    key = _key(ob)
    registry.pop(key, None)
    for k in [k for k in foreign if k[0] == key]:
        del foreign[k]


def forget_all() -> None:
    """Forget every runtime and what was learnt of the setups' scenes (a new file)."""
    registry.clear()
    foreign.clear()
    _owner_uids.clear()
    _adopted.clear()


def foreign_runtime(ob, scene) -> Runtime:
    """The runtime the setup on ``ob`` uses in ``scene``, a scene it does not belong to
    (:mod:`..frame.scenes`): its own, so nothing there touches the setup's cache."""
    key = (_key(ob), scene.session_uid)
    rt = foreign.get(key)
    if rt is None:
        rt = foreign[key] = Runtime(ob.furcollide.uid)
    rt.name = ob.name
    return rt


def prune() -> int:
    """Forget the runtimes (memory caches included) of setups that are gone: their
    source was removed from the file or is in no scene any more (a source deleted in
    the UI stays alive while its output points at it), or is no longer that setup.
    Returns how many were forgotten.

    Cheap when nothing is gone (one name look-up per runtime); a renamed source
    costs one pass over the file's hair objects.
    """
    if not registry and not foreign:
        return 0
    runtimes = [*registry.items(), *((k[0], rt) for k, rt in foreign.items())]
    keys = {key for key, _rt in runtimes}
    alive = set()
    for key, rt in runtimes:
        ob = bpy.data.objects.get(rt.name)
        if ob is not None and _alive(ob) and _key(ob) == key:
            alive.add(key)
    if len(alive) < len(keys):  # gone, or renamed: look at every hair object
        for ob in bpy.data.objects:
            if ob.type == "CURVES" and _alive(ob) and _key(ob) in keys:
                alive.add(_key(ob))
    gone = [key for key in registry if key not in alive]
    for key in gone:
        del registry[key]
    for key in [k for k in foreign if k[0] not in alive]:
        del foreign[key]
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


def setups(scene, owned=True):
    """Source objects of the FurCollide setups that belong to ``scene`` (:func:`owner`);
    ``owned=False``: of every setup whose source is in ``scene``."""
    obs = [ob for ob in scene.objects if ob.type == "CURVES" and ob.furcollide.is_setup]
    return [ob for ob in obs if belongs(ob, scene)] if owned else obs


# ------------------------------------------------------------- scenes
#: Setup key -> session id of the scene it belongs to, as last seen: a scene renamed in
#: this session is still found (its new name is recorded when it is next evaluated).
_owner_uids: dict = {}
#: Setup key -> the scene name adopted where ``owner_scene`` cannot be written (a setup
#: linked from a library).
_adopted: dict = {}


def _holds(scene, ob) -> bool:
    return scene is not None and scene.objects.get(ob.name) == ob


def owner(ob, prefer=None):
    """The scene the setup on ``ob`` belongs to (None when ``ob`` is in no scene).

    The scene recorded on it (Add FurCollide records the scene it ran in) while that
    scene still holds ``ob`` (renamed in this session too). Otherwise (a file made
    before FurCollide recorded it, the recorded scene deleted, a full copy of the
    scene) the scene that holds ``ob`` and the most of its listed colliders; between
    equals ``prefer`` (the scene being evaluated or shown) when it is one of them, else
    the first. The scene that evaluates or bakes it then records it (:func:`adopt`).
    """
    s = ob.furcollide
    key = _key(ob) if s.uid else None
    name = s.owner_scene or _adopted.get(key, "")
    holders = list(ob.users_scene)
    for sc in holders:
        if sc.name == name:
            return sc
    uid = _owner_uids.get(key) if name else None  # (renamed in this session?)
    for sc in holders:
        if uid is not None and sc.session_uid == uid:
            return sc
    if len(holders) <= 1:
        return holders[0] if holders else None
    listed = [c.object for c in s.colliders if c.object is not None and c.enabled]
    score = {sc.name: sum(_holds(sc, o) for o in listed) for sc in holders}
    best = max(score.values())
    top = [sc for sc in holders if score[sc.name] == best]
    return prefer if prefer in top else top[0]


def belongs(ob, scene) -> bool:
    """Does the setup on ``ob`` belong to ``scene`` (:func:`owner`)?"""
    if scene is None:
        return False
    if ob.furcollide.owner_scene == scene.name and _holds(scene, ob):
        return True
    return owner(ob, prefer=scene) == scene


def adopt(ob, scene) -> None:
    """Record ``scene`` as the scene the setup on ``ob`` belongs to (it evaluates or
    bakes it there); in memory only when ``ob`` cannot be written (linked data)."""
    s = ob.furcollide
    key = _key(ob)
    _owner_uids[key] = scene.session_uid
    if s.owner_scene == scene.name:
        return
    try:
        s.owner_scene = scene.name
    except (AttributeError, TypeError, RuntimeError):
        _adopted[key] = scene.name


def foreign_message(ob, scene=None) -> str:
    """What the setup on ``ob`` says in ``scene`` (default: the context scene) when it
    belongs to another scene ('' when it belongs there, or ``ob`` is not in it)."""
    scene = scene or bpy.context.scene
    if not _holds(scene, ob) or belongs(ob, scene):
        return ""
    own = owner(ob, prefer=scene)
    return (f"'{ob.name}' is set up in scene '{own.name}' (a hair can be set up in one "
            f"scene only): here it shows its source as groomed, without collisions. "
            f"Switch to scene '{own.name}' to play, bake or change the setup")


def refusal_in(ob, scene) -> str:
    """An operator's refusal for the setup on ``ob`` in ``scene`` ('' = none): it
    belongs to another scene."""
    if not _holds(scene, ob) or belongs(ob, scene):
        return ""
    own = owner(ob, prefer=scene)
    return (f"'{ob.name}' is set up in scene '{own.name}' (a hair can be set up in one "
            f"scene only): switch to scene '{own.name}'")


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


def status_shown(ob, scene=None) -> tuple:
    """The status the panel shows for the setup on ``ob`` in ``scene`` (default: the
    context scene): where it belongs to another scene, that
    (:func:`foreign_message`); else :func:`status_for`."""
    msg = foreign_message(ob, scene)
    return ("WARNING", msg) if msg else status_for(ob)


def is_outdated(ob, scene=None) -> bool:
    """Is the frame the setup on ``ob`` shows outdated? Never in a scene it does not
    belong to (its output shows the source there)."""
    rt = get_runtime(ob, create=False)
    return bool(rt and rt.outdated) and not foreign_message(ob, scene)


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
