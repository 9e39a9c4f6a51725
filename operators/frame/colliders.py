"""Colliders: which objects collide with a setup, and their core ``Collider`` each frame.

* :func:`collider_objects` lists a setup's colliders (:class:`ColliderRef`): the list's
  enabled entries, then the collider collection's objects; collection instances (linked
  assets) are followed. The source and its growth Surface never collide.
* :func:`sync_collider` keeps one core ``Collider`` per collider across frames
  (:class:`ColliderEntry`, in the setup's runtime's :class:`ColliderState`, changed only
  here): a rigid collider only updates its matrix and never rebuilds its BVH; a new
  topology or option builds a new one.
* :func:`read_for_solve` reads the colliders (and growth surface) a frame is solved
  against.
* :func:`collider_inputs` is a collider's part of the frame-inputs record (its matrix
  and shape digests, see :mod:`.inputs`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from ... import core
from ...core import framecache
from ...core.collider import Placement
from ..blender import bridge


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


def collider_objects(ob, scene=None, disabled=False) -> list[ColliderRef]:
    """Enabled colliders of setup ``ob``: the list's, then the collider
    collection's; collection instances (linked assets) are followed. The source
    and its growth Surface never collide (roots lie on the Surface: every curve
    would be pinched): see :func:`surface_as_collider`. ``disabled``: the list's
    disabled entries too (an Enabled keyed on at another frame)."""
    s = ob.furcollide
    out, seen = [], set()
    exclude = {ob, ob.data.surface}
    for c in s.colliders:
        o = c.object
        if o is None or not (c.enabled or disabled) or not in_scene(o, scene):
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


@dataclass(slots=True)
class ColliderState:
    """The part of a setup's runtime with its colliders, changed only here."""

    entries: dict = field(default_factory=dict)  # collider uid -> ColliderEntry
    growth: object = None  # ColliderEntry of the growth surface
    #: Follow Collider Motion: frame -> {collider uid: core Placement} of cached frames.
    placements: dict = field(default_factory=dict)
    #: Collider uid -> what was said about it once (:func:`_tell`).
    told: dict = field(default_factory=dict)


def forget(rt) -> None:
    """Forget the core Colliders of the setup's runtime ``rt`` (which objects collide,
    or the curves they collide with, changed): the next frame builds them again."""
    rt.colliders.entries.clear()
    rt.colliders.growth = None


@dataclass
class ColliderEntry:
    """A collider's core ``Collider`` as the last frame left it, with what decides
    whether the next frame can update it (topology key, options, deforming) and its
    part of that frame's inputs record."""

    collider: object
    key: tuple
    double_sided: bool
    offset: float | None
    deforming: bool = False
    inputs: tuple = (0, 0)  # (matrix, shape) digests read this frame: collider_inputs


def sync_collider(entry, o, depsgraph, double_sided=False, offset=None, matrix=None,
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
        key, V = mesh_reading(me)
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
        rest = rest_shape(o, key) if deforming else None
        if rest is not None:  # triangulated as the rest shape is (quads split alike)
            F = bridge.mesh_triangles(o.data)
        col = core.Collider(
            V, F, double_sided=double_sided, matrix=M, offset=offset, drop_degenerate=True,
            name=name or o.name, deforming=deforming, rest=rest,
        )
        return ColliderEntry(col, key, double_sided, offset, deforming,
                             collider_inputs(M, V, key))
    # One update a frame (Follow Collider Motion takes the motion since the previous
    # one); unchanged vertices are not assigned (a rigid collider keeps its BVH).
    same = np.array_equal(V, entry.collider.vertices)
    entry.collider.place(matrix=M, vertices=None if same else V)
    entry.inputs = collider_inputs(M, V, key)
    return entry


def rest_shape(o, key) -> np.ndarray | None:
    """The undeformed vertices (n, 3) float32 of mesh object ``o`` (its own mesh, local
    space) when its evaluated mesh has the same topology (shape ``key`` of
    :func:`mesh_reading`), as under an Armature modifier or shape keys; else None.

    Given to ``core.Collider(rest=...)``: a skinned hat, belt or buckle whose vertices
    only moved rigidly from it reuses the rest shape's BVH placed by the fitted motion
    instead of a build every frame (a shape that does not fit is built as before)."""
    if o.type != "MESH" or o.data is None or o.mode == "EDIT":
        return None
    rest_key, rest = mesh_reading(o.data)
    return rest if rest_key == key else None


def mesh_reading(me) -> tuple:
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


def collider_list(setup, refs=None) -> tuple[list, list]:
    """(the core Colliders of the setup's colliders at this frame, kept in its runtime;
    what there is to say about the ones just built: :func:`_tell`). ``refs``: the
    colliders (:func:`collider_objects`), when listed already."""
    rt, depsgraph = setup.rt, setup.depsgraph
    refs = collider_objects(setup.ob, depsgraph.scene) if refs is None else refs
    cols, notes = {}, []
    for r in refs:
        old = rt.colliders.entries.get(r.uid)
        cols[r.uid] = sync_collider(old, r.object, depsgraph, r.double_sided, r.offset,
                                    r.matrix(depsgraph), r.name)
        if cols[r.uid] is not old:
            notes += _tell(setup, r.uid, cols[r.uid].collider, r.object.type == "MESH")
    rt.colliders.entries = cols  # forgets deleted colliders
    return [e.collider for e in cols.values()], notes


# ------------------------------------------------------------- what was made of them
def open_mesh(col) -> str:
    """'no pinch detection for <name>: open mesh (...)' for a single-sided collider that
    is open even after the core's repairs (welded seams, duplicated faces ignored), so
    it has no inside; '' otherwise (closed, Double Sided, or no faces at all)."""
    rep = col.repairs
    if col.double_sided or col.closed or not len(rep.faces):
        return ""
    edges = f"{rep.open_edges} open edge{'s' if rep.open_edges != 1 else ''}" if (
        rep.open_edges) else "not closed"
    return f"no pinch detection for '{col.name}': open mesh ({edges})"


def repaired(col) -> str:
    """What the core repaired in ``col`` ("'Ball': 12 duplicated faces ignored, 430 faces
    turned outward"), '' when nothing."""
    text = col.repairs.describe()
    return f"'{col.name}': {text}" if text else ""


def _tell(setup, uid, col, mesh) -> list[str]:
    """A collider was built: say once (one console line, and the frame's status: the
    notes returned) what was repaired in it when it is a ``mesh`` object (a curve, text
    or surface is always tessellated with seams: nothing the artist could fix), and
    once that it detects no pinch when it is an open mesh."""
    said = setup.rt.colliders.told.setdefault(uid, set())
    notes = []
    for kind, text in (("repaired", repaired(col) if mesh else ""), ("open", open_mesh(col))):
        if text and kind not in said:
            said.add(kind)
            notes.append(text)
            what = "collider " if kind == "repaired" else ""
            print(f"FurCollide '{setup.ob.name}': {what}{text}", flush=True)
    return notes


def collider_note(rt, scene, refs, fresh=()) -> str:
    """The status note about a setup's colliders ('' when none): what was repaired in
    colliders just built (``fresh``: said once), the open meshes that detect no pinch
    (while they are colliders), and the colliders (``refs``) renders of ``scene`` see
    with other geometry than the viewport (:func:`render_note`)."""
    notes = list(fresh)
    for e in rt.colliders.entries.values():
        text = open_mesh(e.collider)
        if text and text not in notes:
            notes.append(text)
    notes.extend(render_note(scene, refs))
    return "Colliders: " + "; ".join(notes) if notes else ""


def collider_lines(rt, obj) -> list[str]:
    """For the panel: what the core made of the collider entry ``obj`` (an object, or a
    collection instance: each collider in it) at the last solved frame."""
    if rt is None or obj is None:
        return []
    lines = []
    for e in rt.colliders.entries.values():
        name = e.collider.name
        if name != obj.name and not name.startswith(obj.name + " › "):
            continue
        if obj.type == "MESH" and (text := repaired(e.collider)):
            lines.append("Repaired " + text)
        if text := open_mesh(e.collider):
            lines.append(text[:1].upper() + text[1:])
    return lines


def growth_collider(setup, settings):
    """The core Collider of the growth surface at this frame, when ``settings`` (core
    Settings) read it (else None); raises ValueError when the Surface cannot be one."""
    if not (settings.attract_to_growth_surface or settings.pinch_resolution == "growth_surface"):
        return None
    rt, surf = setup.rt, setup.ob.data.surface
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
    part = rt.colliders
    part.growth = sync_collider(part.growth, surf, setup.depsgraph)
    return part.growth.collider


def read_for_solve(setup, refs, continuous=True, fresh=False) -> tuple[list, object, list]:
    """(the core Colliders, the growth surface's or None, the notes about colliders
    just built: :func:`collider_list`) this frame is solved against; ``refs``: the
    setup's colliders (:func:`collider_objects`). The solver's settings decide whether
    the growth surface is read.

    With Follow Collider Motion, each collider's motion is the one since the previous
    frame, however the frame is reached: ``continuous`` (the colliders were last read
    for the previous frame), ``fresh`` (a frame solved from the groomed shape: no
    motion before it), else the previous frame's placements kept for it
    (:func:`keep_placements`; none kept: no motion known, the paper's direction)."""
    cols, notes = collider_list(setup, refs)
    growth = growth_collider(setup, setup.solver.settings)
    if not setup.solver.settings.follow_collider_motion:
        return cols, growth, notes
    rt, f = setup.rt, setup.frame
    if fresh or not continuous:
        kept = {} if fresh else rt.colliders.placements.get(f - 1, {})
        for uid, e in rt.colliders.entries.items():
            p = kept.get(uid)
            if p is None:
                e.collider.forget_previous()
            else:
                e.collider.set_previous(p.matrix, p.vertices)
    keep_placements(setup)
    return cols, growth, notes


def keep_placements(setup) -> None:
    """Keep where each collider is at this frame (Follow Collider Motion: a frame solved
    later from this one's cached state takes its colliders' motion since here), for the
    cached frames only."""
    rt = setup.rt
    part = rt.colliders
    part.placements = {k: v for k, v in part.placements.items() if k in rt.cache.memory.frames}
    part.placements[setup.frame] = {
        uid: Placement(e.collider.matrix, e.collider.vertices)
        for uid, e in part.entries.items()}


# ------------------------------------------------------- frame-inputs record
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
        The shape key of :func:`mesh_reading` (counts, digest of the corners).
    """
    return (framecache.digest(np.asarray(M, np.float64)),
            framecache.digest(V, np.frombuffer(repr(key).encode(), np.uint8)))


def renders_otherwise(o, scene=None) -> bool:
    """Does Blender evaluate collider ``o`` to other geometry in renders of ``scene``
    (default: the context scene) than in its viewport? (:func:`render_difference`)"""
    return bool(render_difference(o, scene))


def render_difference(o, scene=None) -> str:
    """What makes Blender evaluate collider ``o`` to other geometry in renders of
    ``scene`` (default: the context scene) than in its viewport, in words ('' when
    nothing FurCollide can see does).

    Every setting with a viewport and a render side that shapes a mesh: a modifier shown
    in only one of them; Subdivision Surface and Multiresolution levels as Simplify caps
    them (Max Subdivision, viewport and render: Blender's ``get_render_subsurf_level``);
    Screw steps; Ocean resolution; a geometry-nodes group with an *Is Viewport* node; a
    Particle Instance modifier's particle amounts (display percentage, child amounts,
    Simplify's Max Child Particles); a Volume to Mesh modifier under Simplify's Volume
    Resolution (viewport only); a curve's, surface's or text's Render Resolution, a
    metaball's. What a geometry-nodes group reads from other objects is not followed.
    """
    scene = scene or bpy.context.scene
    r = getattr(scene, "render", None)
    simplify = bool(r is not None and r.use_simplify)
    causes = []
    for m in getattr(o, "modifiers", ()):
        if m.show_render != m.show_viewport:
            where = "renders" if m.show_render else "the viewport"
            causes.append(f"modifier '{m.name}' is on in {where} only")
        elif m.show_render:
            causes.extend(_modifier_difference(m, r, simplify))
    causes.extend(_data_difference(o))
    return "; ".join(causes)


def _subdivision_level(level, r, render) -> int:
    """``level`` as Simplify caps it in renders (``render``) or in the viewport."""
    if r is None or not r.use_simplify:
        return level
    return min(level, r.simplify_subdivision_render if render else r.simplify_subdivision)


def _modifier_difference(m, r, simplify) -> list[str]:
    """The render/viewport differences of modifier ``m`` (shown in both), in words."""
    t = m.type
    if t in ("SUBSURF", "MULTIRES"):
        top = m.total_levels if t == "MULTIRES" else max(m.levels, m.render_levels)
        view = _subdivision_level(min(m.levels, top), r, False)
        rend = _subdivision_level(min(m.render_levels, top), r, True)
        if view == rend:
            return []
        by = "Simplify caps " if simplify and (view, rend) != (m.levels, m.render_levels) else ""
        return [f"{by}'{m.name}' at level {view} in the viewport, {rend} in renders"]
    if t == "SCREW" and m.steps != m.render_steps:
        return [f"'{m.name}' {m.steps} steps in the viewport, {m.render_steps} in renders"]
    if t == "OCEAN" and m.viewport_resolution != m.resolution:
        return [f"'{m.name}' resolution {m.viewport_resolution} in the viewport, "
                f"{m.resolution} in renders"]
    if t == "NODES" and _has_is_viewport(m.node_group):
        return [f"'{m.name}' has an Is Viewport node"]
    if t == "VOLUME_TO_MESH" and simplify and r.simplify_volumes < 1.0:
        return [f"Simplify's Volume Resolution ({r.simplify_volumes:.0%}) thins the volume "
                f"'{m.name}' reads in the viewport"]
    if t == "PARTICLE_INSTANCE":
        return _particle_difference(m, r, simplify)
    return []


def _particle_difference(m, r, simplify) -> list[str]:
    """A Particle Instance modifier's particles: fewer in the viewport than in renders?"""
    psys = m.particle_system if m.object is not None else None
    part = getattr(psys, "settings", None)
    if part is None:
        return []
    if part.display_percentage < 100:
        return [f"'{m.name}' instances {part.display_percentage}% of the particles in the "
                "viewport (Display Amount)"]
    if m.use_children and part.child_type != "NONE":
        view = getattr(part, "child_percent", getattr(part, "child_nbr", 0))
        rend = part.rendered_child_count
        if simplify:
            view = int(view * r.simplify_child_particles)
            rend = int(rend * r.simplify_child_particles_render)
        if view != rend:
            return [f"'{m.name}' instances {view} children per particle in the viewport, "
                    f"{rend} in renders"]
    return []


def _data_difference(o) -> list[str]:
    """A curve's, surface's, text's or metaball's own render resolution, in words."""
    data = getattr(o, "data", None)
    if o.type in ("CURVE", "FONT", "SURFACE"):
        out = []
        for axis in ("u", "v") if o.type == "SURFACE" else ("u",):
            ren = getattr(data, f"render_resolution_{axis}")
            view = getattr(data, f"resolution_{axis}")
            if ren and ren != view:  # (0: renders use the viewport's)
                out.append(f"Resolution {axis.upper()} {view} in the viewport, {ren} in renders")
        return out
    if o.type == "META" and data.render_resolution != data.resolution:
        return [f"metaball Resolution {data.resolution:g} in the viewport, "
                f"{data.render_resolution:g} in renders"]
    return []


#: Node groups nested deeper than this are not searched for an *Is Viewport* node.
_MAX_GROUP_DEPTH = 8


def _has_is_viewport(tree, depth=0, seen=None) -> bool:
    """Does node tree ``tree`` (or a group inside it) hold an *Is Viewport* node?"""
    seen = set() if seen is None else seen
    if tree is None or depth > _MAX_GROUP_DEPTH or tree in seen:
        return False
    seen.add(tree)
    for node in tree.nodes:
        if node.bl_idname == "GeometryNodeIsViewport":
            return True
        inner = getattr(node, "node_tree", None)
        if inner is not None and _has_is_viewport(inner, depth + 1, seen):
            return True
    return False


def render_note(scene, refs) -> list[str]:
    """For the status: each of the colliders ``refs`` that renders of ``scene`` evaluate
    to other geometry than its viewport, with the cause (:func:`render_difference`).

    Playback and bakes read the viewport's evaluation; a render shows a cached or baked
    frame as it is (the collider's other render shape is not an edit,
    :func:`.record.first_change`); only a frame first solved in a render is solved
    against the render shape."""
    out = []
    for r in refs:
        why = render_difference(r.object, scene)
        if why:
            out.append(f"'{r.name}' renders with other geometry than the viewport ({why}): "
                       "the playback cache and the bake are solved against its viewport "
                       "shape, and renders show them as they are")
    return out


def read_collider_inputs(o, depsgraph, matrix=None) -> tuple[int, int]:
    """:func:`collider_inputs` of object ``o`` as ``depsgraph`` evaluates it now
    (``matrix``: its world matrix when it is not its own, see :meth:`ColliderRef.matrix`)."""
    oe = o.evaluated_get(depsgraph)
    M = bridge.matrix(oe) if matrix is None else matrix
    with bridge.evaluated_mesh(oe) as me:
        key, V = mesh_reading(me)
    return collider_inputs(M, V, key)
