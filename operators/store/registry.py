"""The setups of this Blender session: one :class:`Runtime` each, and their scene.

A setup's runtime lives only in this session (never in bpy properties). It is made of
parts, each changed only by the module that owns it: the playback cache
(:mod:`.playback`), the solver and its frame (:mod:`..frame.solve`), the core Colliders
kept across frames, so that rigid motion never rebuilds a BVH (:mod:`..frame.colliders`),
what the frame handler saw last (:mod:`..frame.record`), the status and statistics the
panel shows (:mod:`.report`), what the output got last (:mod:`..frame.output`), the
render groom's, the children's and Fur Attach's state (:mod:`..frame.groom`,
:mod:`..frame.children`, :mod:`..frame.attach`). It is keyed by the setup id plus the
source object's session id, so a duplicated source never shares the original's.
:func:`prune` drops the runtimes of setups that are gone (a source deleted in the UI),
memory cache and all.

A setup belongs to one scene (:func:`owner`): the one Add FurCollide ran in, recorded
on the source (``owner_scene``). A hair object linked into several scenes (a character
collection in several shots) is set up in that one only: in the others its output shows
the source as groomed and nothing of the setup's cache or bake is touched
(:mod:`..frame.scenes`); :func:`setups` lists a scene's own setups, and :func:`foreign_message`
says where a setup belongs.
"""

from __future__ import annotations

import uuid
from contextlib import contextmanager
from dataclasses import dataclass

import bpy

from ...core import framecache


@dataclass(slots=True)
class Runtime:
    """Session-only state of one setup: one part per job, each changed only by the
    functions of the module that owns it (others read it). The runtime and its parts
    have slots: no module can leave an attribute on them for another to find."""

    uid: str
    #: The frames cached in this session, and what was dropped
    #: (:class:`.playback.PlaybackCache`).
    cache: object
    #: The core Solver, the frame its state holds, the curve layout it belongs to, the
    #: jiggle's root history and the spline margin (:class:`..frame.solve.SolveState`).
    solve: object
    #: The core Colliders kept across frames, what was said of them, their placements
    #: at the cached frames (:class:`..frame.colliders.ColliderState`).
    colliders: object
    #: What the frame handler saw last: the structure, the values' fingerprint, Fur
    #: Attach, the time key, the frame-inputs record (:class:`..frame.record.Seen`).
    seen: object
    #: What the panel shows: status, outdated mark, statistics, errors
    #: (:class:`.report.Report`).
    report: object
    #: What the output got last: its status colours, the source's attributes
    #: (:class:`..frame.output.Written`).
    output: object
    #: The source's world positions last computed (:class:`..frame.inputs.InputState`).
    inputs: object
    name: str = ""  # the source object's name when last looked up (see prune)
    #: The render groom's binding and what it computed last (``frame.groom.GroomState``,
    #: :mod:`..frame.groom`; None until the stage first runs).
    groom: object = None
    #: The children stage's last clearance (``frame.children.ChildrenState``,
    #: :mod:`..frame.children`; None until the stage first runs).
    children: object = None
    #: (attach_id, core Binding, surface topology key): Fur Attach's binding as loaded
    #: (:mod:`..frame.attach`).
    attach: tuple | None = None
    #: A bake of this setup is running (:mod:`.bake`: it writes the frames; the frame
    #: handler keeps off).
    baking: bool = False


def new_runtime(uid, memory_limit_mb=framecache.DEFAULT_MEMORY_LIMIT_MB) -> Runtime:
    """A setup's runtime with every part empty, each made by its owner (its cache's
    Memory Limit ``memory_limit_mb``)."""
    from ..frame import colliders, inputs, output, record, solve  # (they read the registry)
    from . import playback, report

    return Runtime(uid, cache=playback.new(memory_limit_mb), solve=solve.SolveState(),
                   colliders=colliders.ColliderState(), seen=record.Seen(),
                   report=report.Report(), output=output.Written(),
                   inputs=inputs.InputState())


registry: dict[str, Runtime] = {}
#: The runtimes a setup uses in the scenes it does not belong to (what the output was
#: last written with there, the render groom's binding): (setup key, scene session id)
#: -> Runtime. Never the setup's own cache: :func:`foreign_runtime`.
foreign: dict[tuple, Runtime] = {}


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
        rt = registry[key] = new_runtime(uid, ob.furcollide.memory_limit)
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
        rt = foreign[key] = new_runtime(ob.furcollide.uid)
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
