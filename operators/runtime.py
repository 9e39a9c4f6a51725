"""Per-setup runtime (solver, colliders, caches) and the frame handler.

The registry maps a setup's ``uid`` to a :class:`Runtime` that lives only in
this Blender session (never in bpy properties): the core ``Solver``, one
``Collider`` per collider object (kept alive across frames so rigid motion
never rebuilds a BVH), the bounded memory cache and the status/stats shown
in the panel.

Frame rules (``frame_change_post``; see README "Using it in Blender"):

* subframes (motion blur) never step: the output keeps the whole frame;
* ``f == frame_start``: reset the solver and solve;
* ``f`` cached (memory, or disk when baked): show it, bit for bit;
* ``f - 1`` cached: restore its solver state if needed and step;
* otherwise (jump ahead): hold the newest cached frame, mark outdated;
* ``f < frame_start``: the output follows the source; ``f > frame_end``:
  the end frame is held.

The handler never raises: errors become the setup's status message plus
one console line, and the output keeps its last good result.
"""

from __future__ import annotations

import io
import json
import os
import re
import traceback
import uuid
from dataclasses import dataclass, field

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..core import framecache
from . import bridge, stages

#: Name of the pass-through geometry-nodes modifier FurCollide puts first on
#: the output. It references the source, colliders and growth surface so the
#: render depsgraph evaluates them even when they are hidden from render.
DEPENDENCY_MODIFIER = "FurCollide Inputs"

_busy = False  # re-entrancy guard of the frame handler


def _core():
    from .. import core

    return core


# -------------------------------------------------------------- registry
@dataclass
class ColliderEntry:
    collider: object
    key: tuple
    double_sided: bool
    offset: float | None
    deforming: bool = False
    inputs: tuple = (0, 0)  # (matrix, shape) digests read this frame: collider_inputs


@dataclass
class Runtime:
    """Session-only state of one setup."""

    uid: str
    solver: object = None
    solver_key: tuple | None = None  # topology the solver was built for
    settings: object = None  # core.Settings in use
    topology: tuple | None = None
    offsets: np.ndarray | None = None
    colliders: dict = field(default_factory=dict)
    growth: ColliderEntry | None = None
    memory: framecache.MemoryCache = field(default_factory=framecache.MemoryCache)
    solver_frame: int | None = None  # frame whose result the solver state holds
    hold: tuple | None = None  # (frame, world positions, status) of newest frame
    signature: str | None = None  # colliders + settings seen last
    outdated: bool = False
    baking: bool = False
    status: tuple = ("INFO", "")
    printed: str = ""
    stats: dict = field(default_factory=dict)
    error: str = ""  # last solve error (kept visible while frames cannot be solved)
    written_status: tuple | None = None  # (data session uid, status, colours) last written
    attach: tuple | None = None  # (attach_id, core Binding, surface topology key): Fur Attach
    attach_state: tuple | None = None  # (use_fur_attach, attach_id) seen last
    time_state: float | None = None  # _time_key seen last
    history: stages.RootHistory = field(default_factory=stages.RootHistory)  # jiggle
    groom: tuple | None = None  # (bind_id, stages.GroomBinding): render groom
    groom_shown: tuple | None = None  # (frame, guides) the groom output shows
    written: tuple | None = None  # (world points, depsgraph) _write wrote in this evaluate
    #: Why the playback cache is empty (until the start frame is solved again): the
    #: reason the frames that are not cached give, e.g. "'Box' moved: the playback
    #: cache was dropped".
    dropped: str = ""

    def forget_solver(self):
        self.solver = None
        self.solver_frame = None
        self.colliders.clear()
        self.growth = None


registry: dict[str, Runtime] = {}


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
    return rt


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


# ------------------------------------------------------------ invalidation
def invalidate(ob, reason="", from_frame=None, colliders=False, refresh=True) -> None:
    """Drop the memory-cached frames after ``from_frame`` (default: current).

    A baked setup is not affected (its bake is read-only until freed).
    ``refresh`` re-evaluates the current frame soon (interactive sessions
    only; never from inside the frame handler).
    """
    ob = source_of(ob)
    if ob is None:
        return
    rt = get_runtime(ob, create=False)
    if rt is None:  # nothing cached (a file just opened), but the inputs may have changed
        if colliders:
            update_dependencies(ob)
        return
    s = ob.furcollide
    scene = bpy.context.scene
    f = scene.frame_current if from_frame is None else from_frame
    if f <= s.frame_start:
        rt.memory.clear()
        rt.hold = None
    else:
        rt.memory.drop_after(f)
        if rt.hold is not None and rt.hold[0] > f:
            rt.hold = None
    if rt.solver_frame is not None and rt.solver_frame > f:
        rt.solver_frame = None
    rt.history.drop_after(f)
    rt.groom_shown = None
    rt.signature = None  # accept the new settings without a second drop
    if colliders:
        rt.colliders.clear()
        rt.growth = None
        update_dependencies(ob)
    if refresh:
        _schedule_refresh(ob.name)


_pending_refresh: dict = {}  # object name -> timer function


def _schedule_refresh(name: str) -> None:
    """Re-evaluate the current frame soon (UI only: timers need an event loop)."""
    if bpy.app.background or name in _pending_refresh:
        return

    def refresh():
        global _busy
        if _busy:
            return 0.1  # the frame handler is running: try again soon
        _pending_refresh.pop(name, None)
        ob = None
        _busy = True
        try:
            ob = bpy.data.objects.get(name)
            scene = bpy.context.scene
            if ob is not None and scene is not None and ob.furcollide.is_setup:
                evaluate(scene, bpy.context.evaluated_depsgraph_get(), ob)
        except Exception as exc:  # noqa: BLE001 - a timer must never raise either
            record_error(ob, exc)
        finally:
            _busy = False
        return None

    _pending_refresh[name] = refresh
    bpy.app.timers.register(refresh, first_interval=0.05)


def clear_runtime(ob) -> None:
    """Forget everything held in memory for the setup on ``ob``."""
    registry.pop(_key(ob), None)


# -------------------------------------------------------------- helpers
def bake_directory(ob, create=False) -> str:
    """Absolute bake directory of the setup (raises ValueError if unsaved)."""
    s = ob.furcollide
    if s.bake_path:
        return bpy.path.abspath(s.bake_path)
    if not bpy.data.filepath and s.cache_directory.startswith("//"):
        raise ValueError(
            "Save the .blend file first: the bake cache is written next to it "
            f"('{s.cache_directory}')"
        )
    root = bpy.path.abspath(s.cache_directory)
    blend = os.path.splitext(os.path.basename(bpy.data.filepath))[0] or "untitled"
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", ob.name)
    return os.path.join(root, blend, f"{name}_{ensure_uid(ob)[:8]}")


def in_scene(o, scene=None) -> bool:
    """Is ``o`` linked into ``scene`` (default: the context scene)?

    Deleting an object in the UI can leave it alive (our pointers hold a
    user); such an object no longer collides.
    """
    scene = scene or bpy.context.scene
    return scene is not None and scene.objects.get(o.name) == o


#: Collection instances nested deeper than this are not followed.
_MAX_INSTANCE_DEPTH = 8


@dataclass(frozen=True)
class ColliderRef:
    """One collider: ``object``'s evaluated surface, placed in the world by its
    own matrix or, inside collection instances, through ``instancers`` (the
    instancing empties, outermost first)."""

    object: object
    double_sided: bool
    offset: float | None
    instancers: tuple = ()

    @property
    def objects(self) -> tuple:
        """Every object this collider reads (the instancers and the object)."""
        return (*self.instancers, self.object)

    @property
    def name(self) -> str:
        """``object``, or ``empty › object`` for an instance (reports, bake signatures)."""
        return " › ".join(o.name for o in self.objects)

    @property
    def uid(self):
        """Session key (an int for a scene object, as in earlier versions)."""
        if not self.instancers:
            return self.object.session_uid
        return tuple(o.session_uid for o in self.objects)

    def matrix(self, depsgraph):
        """World matrix (4, 4) of the evaluated collider, or None for the object's own."""
        if not self.instancers:
            return None
        M = np.eye(4)
        for e in self.instancers:
            M = M @ bridge.matrix(e.evaluated_get(depsgraph)) @ bridge.translation(
                -np.asarray(e.instance_collection.instance_offset, np.float64))
        return M @ bridge.matrix(self.object.evaluated_get(depsgraph))


def instanced_collection(o):
    """The collection an empty instances (None for any other object)."""
    if o is None or o.type != "EMPTY" or o.instance_type != "COLLECTION":
        return None
    return o.instance_collection


def _collider_refs(o, double_sided, offset, out, seen, exclude, instancers=()):
    """Append ``o`` (or, for a collection instance, every collider in it) to ``out``."""
    coll = instanced_collection(o)
    if coll is not None:
        if len(instancers) < _MAX_INSTANCE_DEPTH and o not in instancers:
            for inner in coll.all_objects:
                _collider_refs(inner, double_sided, offset, out, seen, exclude,
                               (*instancers, o))
        return
    if not bridge.is_collider_type(o) or o in exclude:
        return
    ref = ColliderRef(o, double_sided, offset, instancers)
    if ref.uid not in seen:
        seen.add(ref.uid)
        out.append(ref)


def collider_objects(ob, scene=None) -> list[ColliderRef]:
    """Enabled colliders of setup ``ob``: the list's, then the collider
    collection's; collection instances (linked assets) are followed. The source
    and its growth Surface never collide (roots lie on the Surface: every curve
    would be pinched): see :func:`surface_as_collider`."""
    s = ob.furcollide
    out, seen = [], set()
    exclude = {ob, ob.data.surface}
    for c in s.colliders:
        o = c.object
        if o is None or not c.enabled or not in_scene(o, scene):
            continue
        offset = float(c.collision_offset) if c.use_offset else None
        _collider_refs(o, bool(c.double_sided), offset, out, seen, exclude)
    coll = s.collider_collection
    if coll is not None:
        for o in coll.all_objects:
            _collider_refs(o, bool(s.collection_double_sided), None, out, seen, exclude)
    return out


def surface_as_collider(ob) -> str:
    """A warning when the hair's Surface is among the setup's colliders (it is
    left out of them), else ''."""
    s, surf = ob.furcollide, ob.data.surface
    if surf is None:
        return ""
    listed = any(c.object == surf and c.enabled for c in s.colliders)
    coll = s.collider_collection
    if listed or (coll is not None and surf.name in coll.all_objects):
        return (f"'{surf.name}' is the hair's Surface: it does not collide (the roots lie "
                "on it). Remove it from the colliders")
    return ""


def core_settings(ob):
    """core.Settings for the setup's properties (raises SettingsError)."""
    return _core().Settings(**ob.furcollide.to_core_kwargs())


def signature(ob, stable=False, scene=None, identities=True) -> str:
    """Fingerprint of everything that changes the result except the input.

    ``stable=False`` identifies colliders by session id (renames do not
    count); ``stable=True`` by name, which survives saving and reloading
    (bake files, so a bake resumes in a new session). ``identities=False``
    leaves out which objects the colliders and the surface are (renames never
    count, nor sessions): the frame-inputs record, which digests their
    geometry instead.
    """
    s = ob.furcollide
    cols = [
        ((r.name if stable else r.uid), r.double_sided, r.offset) if identities
        else (r.double_sided, r.offset)
        for r in collider_objects(ob, scene)
    ]
    kw = s.to_core_kwargs()
    kw.pop("threads", None)
    surf = ob.data.surface
    surface = "" if surf is None else (surf.name if stable else surf.session_uid) if (
        identities) else True
    parts = [cols, kw, s.enable_attribute, s.frame_start, surface, bool(s.enabled)]
    if s.use_fur_attach:  # only when on: signatures (and bakes) without it are unchanged
        parts.append(["fur_attach", s.attach_id])
    if s.motion.active:  # likewise
        parts.append(["motion", s.motion.fingerprint()])
        t = _time_key(ob, scene or bpy.context.scene)
        if t is not None:  # wind and jiggle run on seconds: frame / fps
            parts.append(["fps", t])
    return json.dumps(parts)


def _time_key(ob, scene):
    """The scene's frames per second when the setup's result depends on it (wind,
    jiggle), else None."""
    m = ob.furcollide.motion
    return stages.fps(scene) if (m.use_wind or m.use_jiggle) else None


def apply_visibility(ob) -> None:
    """Show source or output in the viewport according to ``show_result``."""
    ob = source_of(ob)
    if ob is None:
        return
    s = ob.furcollide
    out = s.output
    for target, hide in ((ob, s.show_result), (out, not s.show_result)):
        if target is not None:
            hide_in_viewport(target, hide)


def hide_in_viewport(ob, hide: bool, render: bool | None = None) -> None:
    """Hide or show ``ob`` in the viewport (and in renders when ``render`` is given)."""
    if render is not None:
        ob.hide_render = render
    try:
        ob.hide_set(hide)
    except RuntimeError:  # not in the active view layer
        pass


def dependency_group_name(ob) -> str:
    """Name of the node group of the output's dependency modifier."""
    return f".FurCollide Inputs {ob.furcollide.uid[:8]}"


def owns_output(ob) -> bool:
    """Is ``ob``'s output its own (not missing, not the original's for a copy)?"""
    out = ob.furcollide.output
    return out is not None and out.furcollide.source == ob


def groom_owner(ob):
    """The setup that owns the render groom output ``ob``'s setup points at:
    ``ob`` itself, another setup (``ob`` is a copy of it), or None."""
    gout = ob.furcollide.groom.output
    if gout is None:
        return None
    if owns_output(ob):
        return ob
    for o in bpy.data.objects:
        s = getattr(o, "furcollide", None)
        if o != ob and s is not None and s.is_setup and s.groom.output == gout and owns_output(o):
            return o
    return None


def _dependency_refs(ob) -> list:
    """The objects the dependency modifier must reference: the source, the
    colliders (including the collider collection's meshes) and the surface."""
    refs = [ob]
    for r in collider_objects(ob):
        refs.extend(o for o in r.objects if o not in refs)
    if ob.data.surface is not None:
        refs.append(ob.data.surface)
    return refs


def _own_dependency_group(ob):
    """(node group, shared) of the setup's dependency modifier: the group its
    outputs' modifier uses (else the one named for it), and whether another
    object's modifier uses it too (a full copy of the scene keeps the setup's
    id and shares the group: each copy then needs its own)."""
    s = ob.furcollide
    ours = [t for t in (s.output, s.groom.output) if t is not None]
    mods = [t.modifiers.get(DEPENDENCY_MODIFIER) for t in ours]
    groups = [m.node_group for m in mods if m is not None and m.node_group is not None]
    ng = groups[0] if groups else bpy.data.node_groups.get(dependency_group_name(ob))
    if ng is None:
        return None, False
    mine = sum(1 for g in groups if g == ng) + int(ng.use_fake_user)
    return ng, ng.users > mine


def dependencies_stale(ob) -> bool:
    """Does the dependency modifier miss an input (a collider or a Surface set
    without an update callback, a render groom output of an older file)?"""
    s = ob.furcollide
    if not owns_output(ob):
        return False  # a copy of a setup: the outputs are the original's
    ng, shared = _own_dependency_group(ob)
    if ng is None or shared:
        return True
    have = {
        n.inputs["Object"].default_value
        for n in ng.nodes
        if n.bl_idname == "GeometryNodeObjectInfo"
    }
    if set(_dependency_refs(ob)) - have:
        return True
    for target in (s.output, s.groom.output):
        if target is not None:
            mod = target.modifiers.get(DEPENDENCY_MODIFIER)
            if mod is None or mod.node_group != ng:
                return True
    return False


def update_dependencies(ob) -> None:
    """(Re)build the pass-through dependency modifier of the output (and of the
    render groom output, if any).

    The modifier's node group holds Object Info nodes for the source, the
    colliders (including the collider collection's meshes; no Collection Info
    node, which would make a cycle when the collection holds the output) and
    the growth surface; nothing is connected, the geometry passes through
    unchanged. It only makes Blender evaluate those objects for the output,
    including in render depsgraphs where they are hidden.
    """
    s = ob.furcollide
    out = s.output
    if not owns_output(ob):
        return  # missing, or a copy of a setup: never touch the original's outputs
    ng, shared = _own_dependency_group(ob)
    if ng is None or shared or ng.bl_idname != "GeometryNodeTree":
        ng = bpy.data.node_groups.new(dependency_group_name(ob), "GeometryNodeTree")
        ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
        ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    ng.nodes.clear()
    gin = ng.nodes.new("NodeGroupInput")
    gout = ng.nodes.new("NodeGroupOutput")
    ng.links.new(gin.outputs[0], gout.inputs[0])
    for i, o in enumerate(_dependency_refs(ob)):
        node = ng.nodes.new("GeometryNodeObjectInfo")
        node.inputs["Object"].default_value = o
        node.location = (-300, -150 * i)
    # The render groom output needs them too: with the guides and their output
    # hidden from render, it is what pulls them into the render depsgraph.
    for target in (out, s.groom.output):
        if target is not None:
            _attach_dependencies(target, ng)


def _attach_dependencies(target, ng) -> None:
    """Give ``target`` the dependency modifier (first in its stack) using ``ng``."""
    mod = target.modifiers.get(DEPENDENCY_MODIFIER)
    if mod is None:
        mod = target.modifiers.new(DEPENDENCY_MODIFIER, "NODES")
        mod.show_expanded = False
    index = list(target.modifiers).index(mod)
    if index != 0 and hasattr(target.modifiers, "move"):  # first, before the artist's own
        target.modifiers.move(index, 0)
    mod.node_group = ng


# -------------------------------------------------------------- Fur Attach
#: Custom property (bytes of an ``np.savez`` file) on the source object holding the
#: Fur Attach binding (``core.pipeline.Binding.arrays()`` plus the surface topology
#: key). Saved with the .blend file; the leading underscore hides it in the UI.
ATTACH_PROPERTY = "_furcollide_attach"


def store_binding(ob, binding, topology_key, attach_id) -> None:
    """Persist ``binding`` on the source ``ob`` and keep it in its runtime."""
    buf = io.BytesIO()
    np.savez(buf, topology_key=np.asarray(topology_key, np.int64), **binding.arrays())
    if ATTACH_PROPERTY in ob.keys():
        # Blender truncates bytes assigned over an existing bytes property at
        # their first NUL byte: a second Bind would corrupt the binding.
        del ob[ATTACH_PROPERTY]
    ob[ATTACH_PROPERTY] = buf.getvalue()
    rt = get_runtime(ob)
    if rt is not None:
        rt.attach = (attach_id, binding, tuple(int(k) for k in topology_key))


def has_binding(ob) -> bool:
    """Does the source ``ob`` hold a Fur Attach binding?"""
    try:
        return ATTACH_PROPERTY in ob.keys()
    except (TypeError, AttributeError):
        return False


def clear_binding(ob) -> None:
    """Forget the Fur Attach binding of the source ``ob``."""
    if has_binding(ob):
        del ob[ATTACH_PROPERTY]
    rt = get_runtime(ob, create=False)
    if rt is not None:
        rt.attach = None


def load_binding(ob):
    """(Binding, surface topology key) of the source ``ob`` (cached in its runtime).

    Raises ValueError when the setup has no binding.
    """
    s = ob.furcollide
    rt = get_runtime(ob)
    if rt.attach is not None and rt.attach[0] == s.attach_id:
        return rt.attach[1], rt.attach[2]
    if not has_binding(ob):
        raise ValueError(
            "Fur Attach is on but the curves are not bound to the Surface: "
            "press Bind (Fur Pipeline > Fur Attach)"
        )
    from ..core.pipeline import Binding

    raw = ob[ATTACH_PROPERTY]
    if not isinstance(raw, bytes):
        raw = bytes(raw)
    with np.load(io.BytesIO(raw), allow_pickle=False) as d:
        binding = Binding.from_arrays(d)
        key = tuple(int(k) for k in d["topology_key"])
    rt.attach = (s.attach_id, binding, key)
    return binding, key


def attached_points(ob, depsgraph, offsets) -> np.ndarray:
    """Fur Attach input stage: the bound curves moved rigidly with the evaluated
    Surface of the source ``ob`` (world space, (P, 3) float64)."""
    binding, key = load_binding(ob)
    surf = ob.data.surface
    if surf is None or surf.type != "MESH":
        raise ValueError(
            "Fur Attach needs the hair's Surface mesh (Object Data > Surface)"
        )
    if not np.array_equal(binding.offsets, offsets):
        C, P = len(binding.offsets) - 1, int(binding.offsets[-1])
        raise ValueError(
            f"Fur Attach: the source hair has {len(offsets) - 1} curves / {int(offsets[-1])} "
            f"points but was bound with {C} / {P}: press Bind again"
        )
    se = surf.evaluated_get(depsgraph)
    me = se.data
    now = bridge.mesh_topology_key(me)
    if not bridge.same_topology(now, key):
        what = (
            f"{now[0]} vertices / {now[1]} faces, bound: {key[0]} / {key[1]}"
            if tuple(now[:2]) != tuple(key[:2])
            else "its vertices or faces were reordered"
        )
        raise ValueError(
            f"Fur Attach: the Surface '{surf.name}' changed topology since binding "
            f"({what}): press Bind again"
        )
    V = bridge.mesh_vertices(me).astype(np.float64)
    M = bridge.matrix(se)
    return binding.apply(V @ M[:3, :3].T + M[:3, 3])


# ---------------------------------------------------------------- inputs
@dataclass
class Inputs:
    points: np.ndarray  # world (P, 3) float32
    offsets: np.ndarray
    key: tuple
    m_out_inv: np.ndarray  # world -> output's local space
    enabled: np.ndarray | None
    warning: str
    #: The source's own local positions when the output has the same world matrix
    #: (the usual case): unchanged points are written back from here, untouched.
    local: np.ndarray | None = None
    #: The input before motion (the caches store the result relative to it, so a
    #: cached frame never needs the motion again); ``points`` when there is none.
    raw: np.ndarray | None = None
    depsgraph: object = None

    def __post_init__(self):
        if self.raw is None:
            self.raw = self.points


def prepare_input(ob, rt, inp, scene, f) -> None:
    """Record the roots for jiggle and apply the motion that runs before collision."""
    if stages.needs_history(ob) and f >= ob.furcollide.frame_start:
        # (before the start frame the hair counts as at rest: frames viewed there
        # must not change a bake, which starts at the start frame)
        rt.history.record(f, inp.points[inp.offsets[:-1]], inp.key)
    moved = stages.apply_motion(ob, "INPUT", inp.points, inp.offsets, f, scene, rt.history)
    if moved is not None:
        inp.points = np.asarray(moved, np.float32)
        inp.local = None


def _shown(obj, depsgraph) -> bool:
    """Is ``obj`` evaluated in ``depsgraph`` (not hidden from it)?"""
    return obj is not None and obj.evaluated_get(depsgraph).is_evaluated


def read_inputs(ob, depsgraph) -> Inputs:
    """Evaluated source positions (world), offsets, enable mask."""
    s = ob.furcollide
    src = ob.evaluated_get(depsgraph)
    if not src.is_evaluated:
        raise RuntimeError("the source is not evaluated in this depsgraph")
    data = src.data
    offs = bridge.curve_offsets(data)
    key = framecache.topology_key(offs)
    P = bridge.get_positions(data)
    M = bridge.matrix(src)
    out = s.output.evaluated_get(depsgraph)
    M_out = bridge.matrix(out)
    mask, warning = bridge.read_curve_mask(data, s.enable_attribute, len(offs) - 1)
    M_out_inv = bridge.matrix(out, inverted=True)
    if s.use_fur_attach:  # the input stage: curves follow the evaluated growth surface
        world = np.asarray(attached_points(ob, depsgraph, offs), np.float32)
        return Inputs(world, offs, key, M_out_inv, mask, warning, None, depsgraph=depsgraph)
    # Equal up to float noise: setting matrix_basis recomposes it from loc/rot/scale.
    local = P if np.allclose(M, M_out, rtol=1e-6, atol=1e-7) else None
    return Inputs(bridge.transform(P, M), offs, key, M_out_inv, mask, warning, local,
                  depsgraph=depsgraph)


def _sync_collider(entry, o, depsgraph, double_sided=False, offset=None, matrix=None,
                   name=None) -> ColliderEntry:
    """The core Collider of mesh object ``o`` at this frame.

    ``entry`` (from the previous frame) is kept while the evaluated mesh has the
    same topology and options: only its vertices and matrix are updated, so a
    rigid collider never rebuilds its BVH. Otherwise a new entry is built.
    ``matrix``: the world matrix when it is not ``o``'s own (a collection instance).
    """
    oe = o.evaluated_get(depsgraph)
    M = bridge.matrix(oe) if matrix is None else matrix
    deforming = is_deforming(o, depsgraph.scene)
    with bridge.evaluated_mesh(oe) as me:
        key, V = _mesh_reading(me)
        changed = (
            entry is None
            or entry.key != key
            or entry.double_sided != double_sided
            or entry.offset != offset
            or entry.deforming != deforming
        )
        if changed:
            F = np.zeros((0, 3), np.int32) if me is None else bridge.mesh_triangles(me)
    if changed:
        col = _core().Collider(
            V, F, double_sided=double_sided, matrix=M, offset=offset, drop_degenerate=True,
            name=name or o.name, deforming=deforming,
        )
        return ColliderEntry(col, key, double_sided, offset, deforming,
                             collider_inputs(M, V, key))
    if not np.array_equal(V, entry.collider.vertices):  # deforming: the core refits
        entry.collider.vertices = V
    entry.collider.matrix = M
    entry.inputs = collider_inputs(M, V, key)
    return entry


def _mesh_reading(me) -> tuple:
    """(shape key, local vertices (n, 3) float32) of an evaluated collider mesh.

    The key (vertex, face and corner counts, and a digest of the corners' vertex
    indices) changes when the triangulation can change; ``me`` None (a curve
    without bevel or extrusion) has no surface: nothing collides.
    """
    if me is None:
        return ("no surface",), np.zeros((0, 3), np.float32)
    corners = bridge.mesh_corner_verts(me)
    return (len(me.vertices), len(me.polygons), len(corners), framecache.digest(corners)), \
        bridge.mesh_vertices(me)


def is_deforming(o, scene) -> bool:
    """Does collider ``o`` change shape from frame to frame (deform modifiers,
    shape keys, cloth, geometry nodes; for a curve, text or metaball also animated
    or hooked data)? Then its BVH is built for speed (see
    ``core.Collider(deforming=...)``). A property of the object's set-up, never of
    the frames seen, so results do not depend on the playback history."""
    try:
        if o.is_deform_modified(scene, "PREVIEW"):
            return True
    except (AttributeError, TypeError, RuntimeError):
        pass
    if o.type != "MESH":
        data = o.data
        if getattr(data, "animation_data", None) is not None or getattr(data, "shape_keys", None):
            return True
        if any(m.show_viewport for m in o.modifiers):
            return True
    return any(m.type == "NODES" and m.show_viewport for m in o.modifiers)


def _collider_list(ob, rt, depsgraph):
    cols = {}
    for r in collider_objects(ob, depsgraph.scene):
        cols[r.uid] = _sync_collider(rt.colliders.get(r.uid), r.object, depsgraph,
                                     r.double_sided, r.offset, r.matrix(depsgraph), r.name)
    rt.colliders = cols  # forgets deleted colliders
    return [e.collider for e in cols.values()]


def _growth(ob, rt, settings, depsgraph):
    if not (settings.attract_to_growth_surface or settings.pinch_resolution == "growth_surface"):
        return None
    surf = ob.data.surface
    if surf is None:
        raise ValueError(
            "Attract to Growth Surface / Put to Growth Surface need the hair's Surface "
            "object (Object Data > Surface)"
        )
    if surf.type != "MESH":
        raise ValueError(
            f"the hair's Surface '{surf.name}' is a {surf.type.lower()} object, not a mesh: "
            "Attract to Growth Surface / Put to Growth Surface need a mesh Surface"
        )
    rt.growth = _sync_collider(rt.growth, surf, depsgraph)
    return rt.growth.collider


# ------------------------------------------------------------ frame inputs
# A cached frame (memory or bake) keeps a record of what it was solved from; it is
# shown only while the current inputs give the same record (see README "Time").


def collider_inputs(M, V, key) -> tuple[int, int]:
    """(matrix digest, shape digest) of a collider as read at one frame.

    Parameters
    ----------
    M : (4, 4) float64 ndarray
        Its world matrix, compared bit for bit.
    V : (n, 3) float32 ndarray
        Its evaluated vertices in its own space (rigid or deforming alike: reading
        and digesting 65,000 vertices takes about 0.05 ms).
    key : tuple
        The shape key of :func:`_mesh_reading` (counts, digest of the corners).
    """
    return (framecache.digest(np.asarray(M, np.float64)),
            framecache.digest(V, np.frombuffer(repr(key).encode(), np.uint8)))


def read_collider_inputs(o, depsgraph, matrix=None) -> tuple[int, int]:
    """:func:`collider_inputs` of object ``o`` as ``depsgraph`` evaluates it now
    (``matrix``: its world matrix when it is not its own, see :meth:`ColliderRef.matrix`)."""
    oe = o.evaluated_get(depsgraph)
    M = bridge.matrix(oe) if matrix is None else matrix
    with bridge.evaluated_mesh(oe) as me:
        key, V = _mesh_reading(me)
    return collider_inputs(M, V, key)


def uses_growth(settings) -> bool:
    """Does the solve read the growth surface? (core Settings or the setup's properties)"""
    return bool(settings.attract_to_growth_surface
                or settings.pinch_resolution == "growth_surface")


def frame_inputs(inp, sig, colliders, flags, surface) -> dict:
    """The frame-inputs record of one frame: part name -> 64-bit digest.

    Parameters
    ----------
    inp : Inputs
        The frame's input: world positions before motion (``raw``), offsets and
        the per-curve enable mask.
    sig : str
        The settings: :func:`signature` without the objects' identities (their
        geometry is digested; renaming an object or a new session never counts).
    colliders : list of (int, int)
        :func:`collider_inputs` of each collider, in :func:`collider_objects` order.
    flags : list of (bool, float or None)
        Each collider's Double Sided and Collision Offset, in the same order.
    surface : (int, int) or None
        The growth surface's, when the solve reads it.

    Returns
    -------
    dict
        Ordered as :func:`describe_change` reports the first difference: the
        colliders' number and options, the settings, the source, the enable mask,
        each collider's matrix and shape, the surface's.
    """
    rec = {"colliders": framecache.text_digest(repr(list(flags))),
           "settings": framecache.text_digest(sig),
           "source": framecache.digest(inp.raw, inp.offsets)}
    if inp.enabled is not None:
        rec["enabled"] = framecache.digest(inp.enabled)
    for i, (matrix, shape) in enumerate(colliders):
        rec[f"collider {i} matrix"] = matrix
        rec[f"collider {i} shape"] = shape
    if surface is not None:
        rec["surface matrix"], rec["surface shape"] = surface
    return rec


def solved_inputs(ob, rt, inp, scene) -> dict:
    """The record of the frame just solved, from the colliders as the solve read them."""
    growth = rt.growth if rt.growth is not None and uses_growth(rt.settings) else None
    entries = list(rt.colliders.values())
    return frame_inputs(inp, signature(ob, scene=scene, identities=False),
                        [e.inputs for e in entries], [(e.double_sided, e.offset) for e in entries],
                        growth.inputs if growth is not None else None)


def current_inputs(ob, inp, depsgraph) -> dict:
    """The record of the frame ``depsgraph`` shows now, read afresh (no solver needed):
    what a cached frame's record must equal to be shown."""
    scene = depsgraph.scene
    refs = collider_objects(ob, scene)
    cols = [read_collider_inputs(r.object, depsgraph, r.matrix(depsgraph)) for r in refs]
    surf = ob.data.surface
    surface = None
    if uses_growth(ob.furcollide) and surf is not None and surf.type == "MESH":
        surface = read_collider_inputs(surf, depsgraph)
    return frame_inputs(inp, signature(ob, scene=scene, identities=False), cols,
                        [(r.double_sided, r.offset) for r in refs], surface)


def describe_change(ob, part, scene, old=None, new=None) -> str:
    """The change :func:`framecache.first_change` found between the records ``old`` and
    ``new``, in words naming the object."""
    if part == "colliders":
        count = [sum(k.endswith(" matrix") and k.startswith("collider ") for k in r or {})
                 for r in (old, new)]
        if count[1] != count[0]:
            return f"a collider was {'added' if count[1] > count[0] else 'removed'}"
        return "a collider's Double Sided or Collision Offset changed"
    if part == "settings":
        return "the settings changed"
    if part == "source":
        return f"the source hair '{ob.name}' changed (groom, modifiers or placement)"
    if part == "enabled":
        return f"the enable attribute '{ob.furcollide.enable_attribute}' of '{ob.name}' changed"
    what, _, kind = part.rpartition(" ")
    change = "moved" if kind == "matrix" else "changed shape"
    if what == "surface":
        surf = ob.data.surface
        return f"the growth surface '{surf.name if surf is not None else '?'}' {change}"
    refs = collider_objects(ob, scene)
    i = int(what.split()[-1]) if what.startswith("collider ") else len(refs)
    return f"'{refs[i].name}' {change}" if i < len(refs) else "the colliders changed"


def cached_frame_change(ob, rt, inp, depsgraph, f) -> str:
    """Why memory-cached frame ``f`` no longer matches the current inputs ('' when it
    does, or when it was stored without a record)."""
    old = rt.memory.inputs(f)
    if old is None:
        return ""
    new = current_inputs(ob, inp, depsgraph)
    part = framecache.first_change(old, new)
    return describe_change(ob, part, depsgraph.scene, old, new) if part else ""


def baked_frame_change(ob, inp, depsgraph, directory, f) -> str:
    """Why baked frame ``f`` no longer matches the current inputs ('' when it does,
    or for files baked before FurCollide stored their inputs: not checked)."""
    old = framecache.read_inputs(directory, f)
    if old is None:
        return ""
    new = current_inputs(ob, inp, depsgraph)
    part = framecache.first_change(old, new)
    return describe_change(ob, part, depsgraph.scene, old, new) if part else ""


def _ensure_solver(ob, rt, inp):
    core = _core()
    settings = core_settings(ob)
    if rt.solver is None or rt.solver_key != inp.key:
        rt.solver = core.Solver(inp.offsets, settings)
        rt.solver_key = inp.key
        rt.solver_frame = None
        rt.memory.sparse = framecache.SparseState(rt.solver.state)
    elif rt.solver.settings != settings:
        if rt.solver.settings.mode != settings.mode:
            rt.solver_frame = None  # the solver resets on a mode change
        rt.solver.settings = settings
    rt.settings = settings
    return rt.solver


def _stats(status, frame, solve_ms=0.0, source="solved") -> dict:
    """Panel statistics: the number of curves per core ``Status`` (named in lower case;
    free curves are not counted), the frame, the solve time and where it came from."""
    Status = _core().Status
    counts = np.bincount(status.astype(np.intp, copy=False), minlength=len(Status))
    stats = {s.name.lower(): int(counts[s]) for s in Status if s != Status.FREE}
    stats.update(frame=int(frame), solve_ms=float(solve_ms), source=source)
    return stats


def _output_local(inp, points_world, changed=None) -> np.ndarray:
    """``points_world`` in the output's local space.

    When the output sits where the source sits, the points the solver left
    alone (``changed`` False; computed when not given) are the source's own
    local positions, exactly; only the others are transformed.
    """
    if inp.local is None:  # the output was moved away from the source
        return bridge.transform(points_world, inp.m_out_inv)
    if bridge.is_identity(inp.m_out_inv):  # both at the world origin
        return points_world
    if changed is None:
        changed = framecache.rows_differ(points_world, inp.points)
    local = inp.local.copy()
    idx = np.flatnonzero(changed)
    if len(idx):
        local[idx] = bridge.transform(points_world[idx], inp.m_out_inv)
    return local


def _write(ob, inp, points_world, status, changed=None, attributes=None) -> None:
    """Write world positions, status codes and per-point ``attributes`` (name ->
    (P,) array) into the output's original data."""
    data = ob.furcollide.output.data
    bridge.set_positions(data, _output_local(inp, points_world, changed))
    if attributes:
        stages.write_attributes(data, attributes)
    rt = get_runtime(ob)
    rt.written = (points_world, inp.depsgraph)
    attr = data.attributes.get(bridge.STATUS_ATTRIBUTE)
    last = rt.written_status  # (data, status, colours) written last
    if last is not None and (
        attr is None or last[0] != data.session_uid or len(attr.data) != len(status)
    ):
        last = None  # the output data was replaced or edited: write everything
    if last is None or not np.array_equal(last[1], status):
        previous, colors = (last[1], last[2]) if last is not None else (None, None)
        colors = bridge.status_colors(status, inp.offsets, previous, colors)
        bridge.write_status(data, status, inp.offsets, colors)
        rt.written_status = (data.session_uid, status.copy(), colors)


def _sync_output(ob, inp, depsgraph) -> None:
    """Give the output the evaluated source's topology when it differs."""
    out = ob.furcollide.output
    if framecache.topology_key(bridge.curve_offsets(out.data)) != inp.key:
        old = out.data
        if len(old.curves) and not hasattr(old, "remove_curves"):  # older Blender
            new = bpy.data.hair_curves.new(old.name)
            for mat in old.materials:
                new.materials.append(mat)
            new.surface, new.surface_uv_map = old.surface, old.surface_uv_map
            out.data = new
            if old.users == 0:
                bpy.data.hair_curves.remove(old)
        bridge.copy_topology(ob.evaluated_get(depsgraph).data, out.data)


def _check_topology(ob, rt, inp) -> bool:
    """Adopt or verify the source topology; False (with an error) on change."""
    if rt.topology is None or rt.topology == inp.key:
        rt.topology = inp.key
        rt.offsets = inp.offsets
        return True
    if len(rt.memory) == 0 and not ob.furcollide.is_baked:
        rt.forget_solver()
        rt.hold = None
        rt.topology = inp.key
        rt.offsets = inp.offsets
        return True
    old, new = rt.topology, inp.key
    what = "bake" if ob.furcollide.is_baked else "cached frames"
    set_status(
        ob,
        "ERROR",
        f"Source hair changed from {old[0]} curves / {old[1]} points to {new[0]} / {new[1]}: "
        f"the output keeps its last result and the {what} are kept. "
        f"Press {'Free Bake' if what == 'bake' else 'Reset'} to simulate the new curves.",
    )
    return False


# --------------------------------------------------------------- evaluate
def evaluate(scene, depsgraph, ob) -> str:
    """Run the frame rules (see :func:`_evaluate`), then the render groom stage."""
    rt = get_runtime(ob)
    rt.written = None
    what = _evaluate(scene, depsgraph, ob)
    if rt.written is not None and ob.furcollide.groom.output is not None:
        try:
            _groom_stage(ob, rt, scene.frame_current + scene.frame_subframe, *rt.written)
        except Exception as exc:  # noqa: BLE001 - the guides are written: only warn
            set_status(ob, "WARNING", f"Render groom: {describe(exc)}")
    return what


def _groom(ob, rt):
    """The render groom binding of the setup on ``ob`` (cached in its runtime)."""
    g = ob.furcollide.groom
    if rt.groom is None or rt.groom[0] != g.bind_id:
        rt.groom = (g.bind_id, stages.load_groom(g.output))
        rt.groom_shown = None
    return rt.groom[1]


def _groom_stage(ob, rt, f, guides_world, depsgraph) -> None:
    """The render groom follows the guides just written (deform + clearance pass)."""
    g = ob.furcollide.groom
    out = g.output
    if depsgraph is None or not in_scene(out, depsgraph.scene):
        return
    if rt.groom_shown is not None and rt.groom_shown[0] == f and np.array_equal(
        rt.groom_shown[1], guides_world
    ):
        return  # the same frame again (handlers fire for repeated frames)
    binding = _groom(ob, rt)
    cols = _collider_list(ob, rt, depsgraph) if g.use_clearance else []
    points, n_fixed = stages.groom_frame(ob, binding, guides_world, depsgraph, cols)
    stages.write_groom(out, points, binding.render_offsets, depsgraph)
    rt.groom_shown = (f, np.array(guides_world, copy=True))
    rt.stats = dict(rt.stats, groom_fixed=n_fixed)


def refresh_groom(ob) -> None:
    """The groom options changed: recompute the groom on the next evaluation."""
    ob = source_of(ob)
    rt = get_runtime(ob, create=False) if ob is not None else None
    if rt is not None:
        rt.groom_shown = None
        _schedule_refresh(ob.name)


def remove_groom(src) -> None:
    """Delete the setup's groom output and show its Render Groom again."""
    g = src.furcollide.groom
    stages.remove_groom_output(g.output)
    g.output = None
    g.bind_id = ""
    if g.groom is not None:
        hide_in_viewport(g.groom, False, render=False)
    rt = get_runtime(src, create=False)
    if rt is not None:
        rt.groom = rt.groom_shown = None



def _evaluate(scene, depsgraph, ob) -> str:
    """Run the frame rules (module docstring) for the setup on ``ob``.

    Parameters
    ----------
    scene : bpy.types.Scene
        Scene whose ``frame_current`` / ``frame_subframe`` are evaluated.
    depsgraph : bpy.types.Depsgraph
        Evaluated depsgraph (viewport or render) to read inputs from.
    ob : bpy.types.Object
        Source hair object of the setup.

    Returns
    -------
    str
        What was done: ``'reset'``, ``'step'``, ``'cache'``, ``'bake'``,
        ``'hold'``, ``'outdated'``, ``'passthrough'``, ``'subframe'``,
        ``'topology'``, ``'baking'`` or ``'hidden'`` (no output of the setup is
        in this depsgraph).

    Raises
    ------
    Exception
        Any error; the frame handler turns it into the status message, the
        bake into a report.
    """
    s = ob.furcollide
    rt = get_runtime(ob)
    if s.output is None:
        raise ValueError("the output hair object is missing: remove the setup and add it again")
    if s.output == ob or not s.output.furcollide.is_output:
        raise ValueError(
            f"'{s.output.name}' is not a FurCollide output: FurCollide only writes into "
            "the output object it created (remove the setup and add it again)"
        )
    if s.output.furcollide.source != ob:
        raise ValueError(
            f"this object is a copy of the setup on '{_owner_name(s.output)}': "
            "use Add FurCollide to give it its own output"
        )
    if problem := bridge.write_refusal(s.output, "output"):
        raise ValueError(problem)
    if rt.baking:
        return "baking"
    if not _shown(s.output, depsgraph) and not _shown(s.groom.output, depsgraph):
        # Nothing of this setup is in this depsgraph (its outputs are hidden from
        # it, e.g. from the render): nothing to show, so nothing to compute or to
        # report (its source is usually hidden too).
        return "hidden"
    f = scene.frame_current
    sub = scene.frame_subframe
    if sub != 0.0:
        # Never step on subframes (motion blur). A bake is blended between its
        # whole frames; otherwise the output keeps the whole frame.
        if s.is_baked and s.enabled:
            return _baked_subframe(ob, depsgraph, f, sub)
        return "subframe"
    # Before the input is read: its root history for this frame must survive.
    att = (bool(s.use_fur_attach), s.attach_id if s.use_fur_attach else "")
    if rt.attach_state is not None and att != rt.attach_state and not s.is_baked:
        # Fur Attach toggled or rebound without its update callback (undo, driver):
        # every frame's input changed, so no cached frame is valid.
        invalidate(ob, from_frame=s.frame_start - 1, refresh=False)
    rt.attach_state = att
    tk = _time_key(ob, scene)
    if None not in (tk, rt.time_state) and tk != rt.time_state and not s.is_baked:
        # The fps changed: wind and jiggle of every cached frame ran on the old
        # seconds. (Turning them on or off goes through the signature.)
        invalidate(ob, from_frame=s.frame_start - 1, refresh=False)
    rt.time_state = tk
    inp = read_inputs(ob, depsgraph)
    if not _check_topology(ob, rt, inp):
        return "topology"
    prepare_input(ob, rt, inp, scene, f)
    if not s.is_baked:  # a bake checks its own curve layout first
        _sync_output(ob, inp, depsgraph)

    sig = signature(ob, scene=scene)
    if rt.signature is not None and sig != rt.signature and not s.is_baked:
        # Changed without an update callback (deleted collider, undo, driver).
        invalidate(ob, from_frame=f - 1, refresh=False)
        rt.colliders.clear()
    rt.signature = sig

    level, msg = "INFO", ""
    if inp.warning:
        level, msg = "WARNING", inp.warning
    elif warn := surface_as_collider(ob):
        level, msg = "WARNING", warn
    start, end = s.frame_start, s.frame_end

    if not s.enabled or f < start:
        _sync_output(ob, inp, depsgraph)
        _write(ob, inp, inp.points, np.zeros(len(inp.offsets) - 1, np.int8))
        rt.outdated = False
        set_status(ob, level, msg or ("Disabled" if not s.enabled else "Before the start frame"))
        return "passthrough"

    if s.is_baked:
        return _evaluate_baked(ob, rt, inp, f, level, msg, depsgraph)

    if f > end:
        if rt.hold is not None and rt.hold[0] == end:
            _write(ob, inp, rt.hold[1], rt.hold[2])
            set_status(ob, level, msg or f"After the end frame: holding frame {end}")
            return "hold"
        return _hold(ob, rt, inp, f, reason=f"after the end frame, and frame {end} is not")

    if f in rt.memory:
        why = cached_frame_change(ob, rt, inp, depsgraph, f)
        if not why:
            out, status, stats = _show_cached(ob, rt, inp, f)
            if rt.hold is None and f == max(rt.memory.frames):
                rt.hold = (f, out, status)
            rt.stats = dict(stats, source="cache")
            rt.outdated = False
            set_status(ob, level, msg)
            return "cache"
        if f != start:
            return _outdated(ob, rt, f, why)
        # the start frame is solved again (below), which drops every cached frame

    if f != start and (f - 1) not in rt.memory:
        return _hold(ob, rt, inp, f)
    solver = _ensure_solver(ob, rt, inp)  # a mode change resets it: state unknown
    if f == start:
        solver.reset()
        rt.memory.clear()
        rt.dropped = ""
        rt.memory.start = start
        rt.memory.limit = int(s.memory_limit * 1024 * 1024)
    elif rt.solver_frame != f - 1:
        state = rt.memory.state(f - 1)
        if state is None:
            return _hold(ob, rt, inp, f)
        try:
            solver.state = state
        except ValueError as exc:  # saved with another mode
            rt.solver_frame = None
            return _hold(ob, rt, inp, f, reason=str(exc))
    res, cols = _step(ob, rt, solver, inp, depsgraph)
    rt.solver_frame = f  # the solver holds frame f now, even if a stage below fails
    points, attrs = _finish(ob, rt, inp, res, f, scene, cols)
    stats = _stats(res.status, f, res.timings.get("total", 0.0))
    changed = framecache.rows_differ(points, inp.raw)  # points the stages moved
    rt.memory.put(
        f, inp.raw, points, res.status, inp.offsets, solver.state, stats, changed, attrs,
        solved_inputs(ob, rt, inp, scene),
    )
    rt.solver_frame = f
    if rt.hold is None or f >= rt.hold[0]:
        rt.hold = (f, points, res.status)
    _write(ob, inp, points, res.status, changed, attrs)
    rt.stats = stats
    rt.error = ""
    rt.outdated = False
    set_status(ob, level, msg)
    return "reset" if f == start else "step"


def _step(ob, rt, solver, inp, depsgraph):
    """Solve this frame: (core StepResult, the core Colliders used)."""
    cols = _collider_list(ob, rt, depsgraph)
    growth = _growth(ob, rt, solver.settings, depsgraph)
    return solver.step(inp.points, cols, growth=growth, enabled=inp.enabled), cols


def _finish(ob, rt, inp, res, f, scene, cols):
    """The stages after the solver: (final world points, per-point attributes)."""
    if not ob.furcollide.motion.active:
        return res.points, {}
    return stages.output_stage(ob, res.points, inp.offsets, f, scene, rt.history, cols)


def _show_cached(ob, rt, inp, f):
    """Write memory-cached frame ``f`` to the output; returns (points, status, stats)."""
    out, status, stats = rt.memory.get(f, inp.raw, inp.offsets)
    _write(ob, inp, out, status, attributes=rt.memory.attributes(f))
    return out, status, stats


def _outdated(ob, rt, f, why) -> str:
    """Cached frame ``f`` (not the start frame) was solved from inputs that no longer
    hold: drop the playback cache (the frames stepped from it would not be what a
    bake gives either), keep the output as it is and mark the setup outdated."""
    start = ob.furcollide.frame_start
    invalidate(ob, from_frame=start - 1, refresh=False)
    rt.dropped = f"{why}: the playback cache was dropped"
    rt.outdated = True
    set_status(ob, "WARNING", f"Frame {f} is outdated: {why} since it was cached. The playback "
               f"cache is dropped: go to frame {start} and play, or press Bake.")
    return "outdated"


def _hold(ob, rt, inp, f, reason=""):
    """Jump ahead past the cache: hold the newest cached frame, mark outdated."""
    rt.outdated = True
    reason = reason or rt.dropped
    k = rt.memory.newest_before(f)
    if rt.hold is not None and rt.hold[0] == k:
        _write(ob, inp, rt.hold[1], rt.hold[2])
        held = f"holding frame {k}"
    elif k is not None and k in rt.memory:  # (whatever frame was shown before the jump)
        out, status, _stats = _show_cached(ob, rt, inp, k)
        rt.hold = (k, out, status)
        held = f"holding frame {k}"
    else:
        held = "showing the last result"
    start = ob.furcollide.frame_start
    if rt.error:
        set_status(ob, "ERROR", f"{rt.error} (frame {f} not solved: fix it, then go back to "
                   f"frame {start})")
        return "outdated"
    why = f" ({reason})" if reason else ""
    set_status(
        ob,
        "WARNING",
        f"Frame {f} is not cached{why}: {held}. Play from frame {start} or bake.",
    )
    return "outdated"


def _evaluate_baked(ob, rt, inp, f, level, msg, depsgraph):
    s = ob.furcollide
    directory = bpy.path.abspath(s.bake_path)
    fe = min(f, s.frame_end)
    if not os.path.exists(framecache.frame_path(directory, fe)):
        frames = [k for k in framecache.list_frames(directory) if k < fe]
        rt.outdated = True
        if frames:
            fe = frames[-1]
        else:
            set_status(ob, "ERROR", f"Bake files are missing in {directory}")
            return "outdated"
    points, status, offsets, _state = framecache.read_frame(directory, fe)
    if not np.array_equal(offsets, inp.offsets):
        set_status(
            ob,
            "ERROR",
            "The bake was made for other curves (the source changed): output keeps its "
            "last result. Free Bake to simulate the new curves.",
        )
        return "topology"
    _sync_output(ob, inp, depsgraph)
    _write(ob, inp, points, status, attributes=framecache.read_attributes(directory, fe))
    rt.stats = _stats(status, fe, source="bake")
    why = baked_frame_change(ob, inp, depsgraph, directory, fe) if fe == f else ""
    if why:  # still shown (it is what renders), never as if current
        rt.outdated = True
        set_status(ob, "WARNING", f"Frame {f} of the bake is outdated: {why} since it was "
                   "baked. The baked frame is still shown: press Free Bake, then Bake.")
    elif fe == min(f, s.frame_end):
        rt.outdated = False
        set_status(ob, level, msg)
    else:
        set_status(ob, "WARNING", f"Frame {f} is missing from the bake: holding frame {fe}")
    return "bake"


def _owner_name(out) -> str:
    src = out.furcollide.source
    return src.name if src is not None else "?"


def _baked_subframe(ob, depsgraph, f, sub):
    s = ob.furcollide
    directory = bpy.path.abspath(s.bake_path)
    a, b = f, f + 1
    if not (s.frame_start <= a and b <= s.frame_end):
        return "subframe"
    if not (os.path.exists(framecache.frame_path(directory, a)) and os.path.exists(
        framecache.frame_path(directory, b)
    )):
        return "subframe"
    pa, status, offs, _ = framecache.read_frame(directory, a)
    pb = framecache.read_frame(directory, b)[0]
    data = s.output.data
    if pa.shape != pb.shape or len(data.points) != len(pa):
        return "subframe"
    w = np.float32(sub)
    points = pa + (pb - pa) * w
    inp = Inputs(points, offs, framecache.topology_key(offs),
                 bridge.matrix(s.output.evaluated_get(depsgraph), inverted=True), None, "",
                 depsgraph=depsgraph)
    _write(ob, inp, points, status)
    return "subframe"


# -------------------------------------------------------------------- bake
def settings_fingerprint(ob) -> str:
    """What a bake file must match to be resumed from."""
    return signature(ob, stable=True)


def bake_frame(scene, depsgraph, ob, f, directory, trust_solver) -> dict:
    """Solve frame ``f`` of a bake and write it to ``directory``.

    Parameters
    ----------
    scene, depsgraph : Blender scene and its evaluated depsgraph at ``f``.
    ob : bpy.types.Object
        Source hair object of the setup.
    f : int
        Frame to solve (``frame_start`` resets the solver).
    directory : str
        Absolute bake directory.
    trust_solver : bool
        The solver's state is frame ``f - 1``'s (just solved by this bake);
        otherwise that state is read from ``f - 1``'s file.

    Returns
    -------
    dict
        The frame's stats (curve counts per status, ``solve_ms``).
    """
    s = ob.furcollide
    rt = get_runtime(ob)
    inp = read_inputs(ob, depsgraph)
    if rt.topology is not None and rt.topology != inp.key:
        rt.forget_solver()
    rt.topology, rt.offsets = inp.key, inp.offsets
    prepare_input(ob, rt, inp, scene, f)
    _sync_output(ob, inp, depsgraph)
    solver = _ensure_solver(ob, rt, inp)
    if f == s.frame_start:
        solver.reset()
    elif not trust_solver:
        _p, _st, offsets, stored = framecache.read_frame(directory, f - 1)
        if not np.array_equal(offsets, inp.offsets):
            raise ValueError(f"bake frame {f - 1} was made for other curves")
        solver.state = framecache.decode_state(stored, rt.memory.sparse)
    res, cols = _step(ob, rt, solver, inp, depsgraph)
    rt.solver_frame = f
    points, attrs = _finish(ob, rt, inp, res, f, scene, cols)
    fp = settings_fingerprint(ob)
    state = solver.state
    state["fingerprint"] = np.frombuffer(fp.encode(), np.uint8)
    framecache.write_frame(directory, f, points, res.status, inp.offsets, state, rt.memory.sparse,
                      attrs, inputs=solved_inputs(ob, rt, inp, scene))
    _write(ob, inp, points, res.status, attributes=attrs)
    rt.solver_frame = f
    rt.stats = _stats(res.status, f, res.timings.get("total", 0.0), "bake")
    return rt.stats


def scene_depsgraph(scene):
    """The evaluated depsgraph of ``scene`` (the context's one when it is the
    context scene; else its first view layer's, brought up to date): the CLI's
    ``--scene`` may name a scene no window shows."""
    if scene == bpy.context.scene:
        return bpy.context.evaluated_depsgraph_get()
    depsgraph = scene.view_layers[0].depsgraph
    depsgraph.update()
    return depsgraph


def resume_inputs_match(ob, directory, f, scene) -> bool:
    """Are frame ``f``'s inputs (source, colliders, surface, settings) what the
    partial bake solved at ``f`` (its frame-inputs record)? An edited collider or
    source means starting over: the settings fingerprint does not see geometry."""
    global _busy
    busy, _busy = _busy, True  # no live solve while looking
    try:
        scene.frame_set(f)
        depsgraph = scene_depsgraph(scene)
        old = framecache.read_inputs(directory, f)
        if old is None:  # baked before FurCollide stored the record: start over
            return False
        now = current_inputs(ob, read_inputs(ob, depsgraph), depsgraph)
        return framecache.first_change(old, now) is None
    finally:
        _busy = busy


def resume_frame(ob, directory) -> int | None:
    """Last frame of a contiguous, matching partial bake (None: start over)."""
    s = ob.furcollide
    if stages.needs_history(ob):
        return None  # jiggle needs the roots of every frame since the start: start over
    have = set(framecache.list_frames(directory))
    fp = settings_fingerprint(ob)
    last = None
    f = s.frame_start
    while f in have and f <= s.frame_end:
        try:
            with np.load(framecache.frame_path(directory, f), allow_pickle=False) as z:
                key = next((k for k in z.files if k.endswith("__fingerprint")), None)
                ok = key is not None and z[key].tobytes().decode() == fp
        except (OSError, ValueError, KeyError):
            ok = False
        if not ok:
            break
        last = f
        f += 1
    return last


# ---------------------------------------------------------------- handlers
@persistent
def on_frame_change_post(scene, depsgraph=None):
    """Evaluate every setup of ``scene``; never raises."""
    global _busy
    if _busy or depsgraph is None:
        return
    _busy = True
    try:
        for ob in setups(scene):
            try:
                evaluate(scene, depsgraph, ob)
            except Exception as exc:  # noqa: BLE001 - the handler must never raise
                record_error(ob, exc)
    except Exception as exc:  # noqa: BLE001 - not even while listing the setups
        print(f"FurCollide: frame handler failed: {describe(exc)}", flush=True)
    finally:
        _busy = False


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


@persistent
def on_depsgraph_update_post(scene, depsgraph=None):
    """Invalidate (never write) when colliders or the source were edited."""
    if _busy or depsgraph is None or getattr(depsgraph, "mode", "VIEWPORT") == "RENDER":
        return
    try:
        edited = set()
        for u in depsgraph.updates:
            if (u.is_updated_geometry or u.is_updated_transform) and isinstance(
                u.id, bpy.types.Object
            ):
                edited.add(u.id.original.name)
        if not edited and not any(True for _ in setups(scene)):
            return
        for ob in setups(scene):
            rt = get_runtime(ob, create=False)
            if (rt is None or not rt.baking) and dependencies_stale(ob):
                update_dependencies(ob)  # (a no-op next time: no update loop)
            if rt is None or rt.baking or ob.furcollide.is_baked:
                continue
            inputs = {ob.name} | {o.name for r in collider_objects(ob, scene) for o in r.objects}
            if ob.data.surface is not None:
                inputs.add(ob.data.surface.name)
            if edited & inputs and len(rt.memory):
                invalidate(ob, reason="source or collider edited")
            elif rt.signature is not None and signature(ob, scene=scene) != rt.signature:
                invalidate(ob, reason="colliders changed", colliders=True)
    except Exception as exc:  # noqa: BLE001
        print(f"FurCollide: depsgraph update check failed: {exc}")


@persistent
def on_load_post(*_args):
    """A new file: forget every runtime (caches belong to the old file), and
    complete the setups' dependency modifiers (render groom outputs of older
    files, inputs changed without an update callback): without them a render
    with those inputs hidden would not see them."""
    registry.clear()
    try:
        for ob in bpy.data.objects:
            s = getattr(ob, "furcollide", None)
            if s is None or not s.is_setup or s.output is None:
                continue
            if s.output.furcollide.source == ob and dependencies_stale(ob):
                update_dependencies(ob)
    except Exception as exc:  # noqa: BLE001 - a handler must never raise
        print(f"FurCollide: could not update the setups' inputs: {exc}", flush=True)


_save_remap: dict = {}  # object name -> bake_path before save_pre rewrote it


def _relative_bake_paths():
    for ob in bpy.data.objects:
        s = getattr(ob, "furcollide", None)
        if s is not None and s.is_setup and s.bake_path.startswith("//") and ob.library is None:
            yield ob, s


@persistent
def on_save_pre(filepath="", *_args):
    """Save As to another folder: keep each bake's relative path pointing at the
    same files (Blender remaps its own relative paths, not an add-on's)."""
    _save_remap.clear()
    try:
        old = bpy.data.filepath
        if not old or not filepath or os.path.dirname(old) == os.path.dirname(filepath):
            return
        start = os.path.dirname(os.path.abspath(filepath))
        for ob, s in _relative_bake_paths():
            target = bpy.path.abspath(s.bake_path)
            try:
                new = "//" + os.path.relpath(target, start).replace(os.sep, "/")
            except ValueError:  # another drive (Windows): keep it absolute
                new = target
            _save_remap[ob.name] = s.bake_path
            s.bake_path = new
    except Exception as exc:  # noqa: BLE001 - a handler must never raise
        print(f"FurCollide: could not remap the bake paths: {exc}", flush=True)


@persistent
def on_save_post(filepath="", *_args):
    """A *copy* was saved (File > Save Copy: the open file keeps its path): put
    back the bake paths :func:`on_save_pre` rewrote for it."""
    try:
        if filepath and os.path.abspath(bpy.data.filepath) != os.path.abspath(filepath):
            for name, path in _save_remap.items():
                ob = bpy.data.objects.get(name)
                if ob is not None:
                    ob.furcollide.bake_path = path
    except Exception as exc:  # noqa: BLE001
        print(f"FurCollide: could not restore the bake paths: {exc}", flush=True)
    finally:
        _save_remap.clear()


def describe(exc: Exception) -> str:
    core = None
    try:
        core = _core()
    except ImportError:
        pass
    if core is not None and isinstance(exc, core.FurCollideError | ImportError):
        return str(exc)
    if isinstance(exc, ValueError | RuntimeError | bridge.BridgeError):
        return str(exc)
    return f"{type(exc).__name__}: {exc}"


_HANDLERS = (
    ("frame_change_post", on_frame_change_post),
    ("depsgraph_update_post", on_depsgraph_update_post),
    ("load_post", on_load_post),
    ("save_pre", on_save_pre),
    ("save_post", on_save_post),
)


def register():
    for name, fn in _HANDLERS:
        lst = getattr(bpy.app.handlers, name)
        for h in list(lst):  # survive "Reload Scripts"
            if getattr(h, "__name__", "") == fn.__name__ and "furcollide" in getattr(
                h, "__module__", ""
            ):
                lst.remove(h)
        lst.append(fn)


def unregister():
    for name, fn in _HANDLERS:
        lst = getattr(bpy.app.handlers, name)
        if fn in lst:
            lst.remove(fn)
    for fn in _pending_refresh.values():
        if bpy.app.timers.is_registered(fn):
            bpy.app.timers.unregister(fn)
    _pending_refresh.clear()
    registry.clear()

