"""Children cleared live: the artist's own Geometry Nodes children stack, every frame.

When a setup's output carries a *children stack* (Children from Guides, or any
Geometry Nodes modifiers the artist adds to it: Interpolate, Clump, Frizz, Curl,
Noise...), what renders for that hair is that stack's result with FurCollide's
clearance pass (:func:`core.pipeline.clearance_pass`, the render groom's: each child
turned by the smallest rotation that clears every collider, Bend where turning cannot
free it, roots fixed, lengths kept; a child no collider comes near is left exactly as
the stack made it, so clumps and frizz stay as they are away from the colliders). The
stack's result is evaluated geometry, which cannot be written, so the cleared children
go into a **children output** FurCollide owns ("<source> Children"): it renders, and
the output, whose stack stays where the artist put it, is kept out of renders and
hidden in the viewport. Nothing is bound: the stack is evaluated again every frame, so
editing its density, clump or frizz shows on the next frame, and the child count may
change from frame to frame. Each child gets its own ``furcollide_status`` and colour
(not its guides'), and the Last Frame panel counts them.

The stack is evaluated on the guides once per played frame. Blender evaluates a frame
change in two passes: the scene at the new frame (the output still holds the last
frame's guides), then, after ``frame_change_post`` wrote the new guides, what that
changed. So the output carries the **guides gate** (:data:`GATE_MODIFIER`), a modifier
before the artist's stack that passes the guides on only while it is open. Before a
frame (``frame_change_pre``, :func:`before_frame`) it closes, and Blender's first pass
runs the stack on no guides (Interpolate Hair Curves still scatters its children on the
Surface: 110 ms of a 400 ms evaluation in ``make bench-pipeline``'s children figure);
:func:`run` then writes the guides, opens the gate, has the depsgraph evaluate the
output (``Depsgraph.update``, in renders too), reads the result, clears and writes the
children. The gate stays open, so Blender's second pass has nothing of the output to
evaluate again, and the output holds the stack's real result between frames.

The bake stores what renders (the children's points, status and layout,
:data:`BAKE_PART`), so a baked frame shows exactly what was baked, in the viewport and
in renders; a baked frame whose stack now gives other children says so.

Children versus Render Groom: the render groom is the artist's own dense groom,
bound once to the guides (Bind Groom) and deformed by them; the children are made
from the collided guides by the artist's Geometry Nodes stack on every frame. Both
get the same clearance pass; a setup may have either or both.
"""

from __future__ import annotations

import bpy
import numpy as np

from ...core import Status, framecache, pipeline
from ...core.curves import subset
from ..blender import bridge, compat
from ..blender.dependencies import DEPENDENCY_MODIFIER
from ..store import registry, report
from .clock import clock
from .colliders import collider_list, in_scene
from .groom import clearance_settings, world_splines
from .inputs import shown
from .output import Stage, hide_in_viewport

#: The modifier FurCollide puts on the output, right after its dependency modifier,
#: that passes the guides on to the artist's stack only while FurCollide opens it.
GATE_MODIFIER = "FurCollide Guides Gate"
#: Its input (True: the stack works on the guides; False: on nothing).
GATE_INPUT = "Open"
#: The children output's modifier referencing the output, so that a render depsgraph
#: evaluates the output's stack (the output itself is kept out of renders).
CHILDREN_INPUTS = "FurCollide Children Inputs"
#: Name of the children's arrays in a bake file (:func:`framecache.write_frame`).
BAKE_PART = "children"
#: What the children output's name adds to the source's.
SUFFIX = "Children"

# -------------------------------------------------------------------- stack
def stack_modifiers(out) -> list:
    """The artist's modifiers on the output ``out`` (FurCollide's own left out) that
    evaluate in the viewport or in renders: the children stack (empty: none)."""
    if out is None or out.type != "CURVES":
        return []
    return [m for m in out.modifiers
            if m.name not in (DEPENDENCY_MODIFIER, GATE_MODIFIER)
            and (m.show_viewport or m.show_render)]


def owns_children(ob) -> bool:
    """Is the setup on ``ob``'s children output its own (not a copy's, not gone)?"""
    ch = ob.furcollide.children.output
    return ch is not None and ch.furcollide.source == ob and bool(ch.users_scene)


# --------------------------------------------------------------------- gate
def gate_group():
    """The guides gate's node group (shared by every setup, created once): the
    geometry when Open, else nothing."""
    for ng in bpy.data.node_groups:
        if ng.get("furcollide_gate") == 1 and ng.bl_idname == "GeometryNodeTree":
            return ng
    ng = bpy.data.node_groups.new(".FurCollide Guides Gate", "GeometryNodeTree")
    ng["furcollide_gate"] = 1
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    sock = ng.interface.new_socket(GATE_INPUT, in_out="INPUT", socket_type="NodeSocketBool")
    sock.default_value = False
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    switch = ng.nodes.new("GeometryNodeSwitch")
    switch.input_type = "GEOMETRY"
    ng.links.new(gin.outputs[GATE_INPUT], switch.inputs["Switch"])
    ng.links.new(gin.outputs["Geometry"], switch.inputs["True"])
    ng.links.new(switch.outputs[0], gout.inputs["Geometry"])
    return ng


def _gate(out):
    """(gate modifier, its Open input's identifier), or (None, None) when missing."""
    mod = out.modifiers.get(GATE_MODIFIER)
    if mod is None or mod.type != "NODES" or mod.node_group is None:
        return None, None
    ident = compat.group_inputs(mod.node_group).get((GATE_INPUT, "NodeSocketBool"))
    return (mod, ident) if ident is not None else (None, None)


def ensure_gate(out) -> None:
    """Give the output the guides gate, right after its dependency modifier (before
    every modifier of the artist's)."""
    mod = out.modifiers.get(GATE_MODIFIER)
    if mod is None or mod.type != "NODES":
        mod = out.modifiers.new(GATE_MODIFIER, "NODES")
        mod.show_expanded = False
    ng = gate_group()
    if mod.node_group != ng:
        mod.node_group = ng
    names = [m.name for m in out.modifiers]
    at = 1 if DEPENDENCY_MODIFIER in names[:1] else 0
    compat.move_modifier(out, mod, at)


def set_gate(out, open_: bool) -> bool:
    """Open or close the output's guides gate (tagging the output when it changes);
    False when the output has no gate."""
    mod, ident = _gate(out)
    if mod is None:
        return False
    if bool(compat.modifier_input(mod, ident)) != open_:
        compat.set_modifier_input(mod, ident, open_)
        # Its geometry only: a bare update_tag() also tags the object's base flags,
        # which Depsgraph.update() in a frame handler (after Blender rebuilt the
        # relations for a modifier added, or in a render) evaluates against stale
        # view layer bases and crashes (Blender 5.0.1).
        out.update_tag(refresh={"DATA"})
    return True


def remove_gate(out) -> None:
    """Take the guides gate off the output (the stack works on the guides again)."""
    mod = out.modifiers.get(GATE_MODIFIER)
    if mod is not None:
        out.modifiers.remove(mod)


# ----------------------------------------------------------- children output
def _inputs_group(src, out):
    """The children output's dependency node group: an Object Info node of ``out``."""
    name = f".FurCollide Children Inputs {src.furcollide.uid[:8]}"
    ng = bpy.data.node_groups.get(name)
    if ng is None or ng.bl_idname != "GeometryNodeTree":
        ng = bpy.data.node_groups.new(name, "GeometryNodeTree")
        ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
        ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    ng.nodes.clear()
    gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    ng.links.new(gin.outputs[0], gout.inputs[0])
    ng.nodes.new("GeometryNodeObjectInfo").inputs["Object"].default_value = out
    return ng


def create_children_output(src, scene):
    """Create the setup's children output (or take it again), keep the output out of
    renders and hide it in the viewport, and give the output its guides gate.
    Returns the children output."""
    s = src.furcollide
    out = s.output
    ch = s.children.output
    if ch is None or ch.type != "CURVES" or ch.furcollide.source != src or not in_scene(
            ch, scene):
        hc = bpy.data.hair_curves.new(f"{src.data.name} {SUFFIX}")
        for mat in out.data.materials:
            hc.materials.append(mat)
        hc.surface = out.data.surface
        hc.surface_uv_map = out.data.surface_uv_map
        ch = bpy.data.objects.new(f"{src.name} {SUFFIX}", hc)
        for coll in list(out.users_collection) or [scene.collection]:
            coll.objects.link(ch)
        for i, slot in enumerate(out.material_slots):
            if slot.link == "OBJECT" and i < len(ch.material_slots):
                ch.material_slots[i].link = "OBJECT"
                ch.material_slots[i].material = slot.material
        ch.furcollide.is_output = True
        ch.furcollide.source = src
        s.children.output = ch
    mod = ch.modifiers.get(CHILDREN_INPUTS)
    if mod is None:
        mod = ch.modifiers.new(CHILDREN_INPUTS, "NODES")
        mod.show_expanded = False
    mod.node_group = _inputs_group(src, out)
    ensure_gate(out)
    out.hide_render = True
    hide_in_viewport(out, True)
    ch.hide_render = False
    hide_in_viewport(ch, not s.show_result)
    rt = registry.get_runtime(src, create=False)
    if rt is not None:
        rt.children = None
    return ch


def remove_children_output(src) -> None:
    """Delete the setup's children output; the output renders its own stack again."""
    s = src.furcollide
    ch = s.children.output
    s.children.output = None
    if ch is not None and ch.furcollide.source == src:
        data = ch.data
        bpy.data.objects.remove(ch)
        if data is not None and data.users == 0:
            bpy.data.hair_curves.remove(data)
    ng = bpy.data.node_groups.get(f".FurCollide Children Inputs {s.uid[:8]}")
    if ng is not None and ng.users == 0:
        bpy.data.node_groups.remove(ng)
    out = s.output
    if out is not None and out.furcollide.source == src:
        remove_gate(out)
        out.hide_render = False
        out.update_tag(refresh={"DATA"})
        hide_in_viewport(out, not s.show_result)
    rt = registry.get_runtime(src, create=False)
    if rt is not None:
        rt.children = None
        report.drop_stats(rt, "children")


def apply_visibility(src) -> None:
    """The children output follows Show Result (the output stays hidden while it
    exists: the children output shows what its modifiers make, cleared)."""
    s = src.furcollide
    if owns_children(src):
        hide_in_viewport(s.children.output, not s.show_result)
        if s.output is not None:
            hide_in_viewport(s.output, True)


def wants_children(setup) -> bool:
    """Should the frame make a children output now (the output carries a children
    stack, Clear Children is on, there is none yet)? Not in renders: objects are not
    made while Blender renders."""
    s = setup.s
    return (s.children.use_children and not owns_children(setup.ob)
            and bool(stack_modifiers(s.output)) and not bridge.is_render(setup.depsgraph))


# -------------------------------------------------------------------- state
class ChildrenState:
    """What the children stage keeps between frames (in the setup's runtime)."""

    __slots__ = ("key", "result", "drawn")

    def __init__(self):
        self.key = None  # digests of the inputs of ``result``
        self.result = None  # (points (P, 3) float32 world, status (C,), n_fixed)
        #: The clearance pass's drawn margins (the children's splines, last frame's).
        self.drawn = pipeline.ClearanceMargins()


def children_state(rt) -> ChildrenState:
    if not isinstance(rt.children, ChildrenState):
        rt.children = ChildrenState()
    return rt.children


# -------------------------------------------------------------------- frame
def run(setup, baked=None) -> Stage | None:
    """The children stage of a frame (after the guides and the render groom): the
    output's stack evaluated on the guides just written, cleared and written into the
    children output. Returns what it adds to the frame's status and statistics (None:
    no children here). Never raises (a problem is a note of the frame's status).

    ``baked``: (frame, ``framecache.ShownFrame``) of the baked frame the output shows
    (its children are shown while the stack makes the same curves); None: the frame
    does not show a bake."""
    try:
        if setup.depsgraph is None:
            return None
        if wants_children(setup):
            create_children_output(setup.ob, setup.scene)
            setup.depsgraph.update()  # (the depsgraph gets the new object)
        if not owns_children(setup.ob):
            return None
        if not shown(setup.s.children.output, setup.depsgraph):
            return None
        return _run(setup, baked)[0]
    except Exception as exc:  # noqa: BLE001 - the guides are written: only warn
        return Stage({}, f"Children: {report.describe(exc)}")


def with_note(status, stage) -> tuple[str, str]:
    """The frame's status ``(level, message)`` with a children note (``stage``'s) as a
    warning after it; never over an error of the guides."""
    note = stage.note if stage is not None else ""
    level, msg = status
    if not note or level == "ERROR" or note in msg:
        return status
    return "WARNING", f"{msg} {note}" if msg else note


def bake_frame(setup) -> tuple[dict, dict] | None:
    """The children of a frame being baked: cleared (always), written, and returned
    as (the bake file's part, their statistics); None: the setup's output makes no
    children."""
    if wants_children(setup):
        create_children_output(setup.ob, setup.scene)
    if not owns_children(setup.ob):
        return None
    stage, part = _run(setup, baking=True)
    return None if part is None else (part, stage.stats)


def before_frame(ob) -> None:
    """``frame_change_pre``: close the output's guides gate, so that Blender's first
    pass does not run the children stack on the last frame's guides (:func:`run` opens
    it)."""
    if owns_children(ob) and ob.furcollide.output is not None:
        set_gate(ob.furcollide.output, False)


def _run(setup, baked=None, baking=False) -> tuple[Stage, dict | None]:
    """Evaluate, clear and write the children (see the module docstring): (what the
    stage adds to the frame, the bake part when ``baking``)."""
    s, rt, dg = setup.s, setup.rt, setup.depsgraph
    out = s.output
    state = children_state(rt)
    render = bridge.is_render(dg)
    if not render:  # (no modifier is added while Blender renders)
        ensure_gate(out)
    with clock.timing("children"):
        set_gate(out, True)
        dg.update()  # (evaluated objects read before this are stale now)
    with clock.timing("children"):
        stack = _stack_result(setup)
    if stack is None:
        return Stage({}), None
    data, offsets, world = stack
    from_bake, note, outdated = _baked_children(setup, offsets, world, baked)
    clear = render or baking or s.children.use_viewport
    fresh = ()
    if from_bake is not None:
        points, status, n_fixed = from_bake
    elif clear:
        points, status, n_fixed, fresh = _clear(setup, state, data, offsets, world)
    else:  # (Clear in Viewport off: the stack's result as it is)
        points, status, n_fixed = world.astype(np.float32), np.zeros(
            len(offsets) - 1, np.int8), 0
    with clock.timing("write"):
        _write(setup, data, offsets, points, status)
    stage = Stage(children_stats(status, n_fixed, cleared=clear or from_bake is not None),
                  note, outdated, fresh=fresh)
    if not baking:
        return stage, None
    return stage, {"points": np.asarray(points, np.float32), "status": status,
            "offsets": np.asarray(offsets, np.int32),
            "stack": _digest_array(world), "key": np.frombuffer(
                settings_key(setup.ob).encode(), np.uint8),
            "fixed": np.array([n_fixed], np.int64)}


def _stack_result(setup):
    """(evaluated curves data, offsets (C+1,), world points (P, 3) float64) of the
    output's stack as the depsgraph evaluated it, or None when the output is not
    evaluated in it."""
    oe = setup.s.output.evaluated_get(setup.depsgraph)
    if not oe.is_evaluated:
        return None
    data = oe.data
    offsets = bridge.curve_offsets(data)
    world = bridge.transform(bridge.get_positions(data), bridge.matrix(oe)).astype(np.float64)
    return data, offsets, world


def settings_key(ob) -> str:
    """What the baked children depend on besides the stack's result: the clearance
    pass's settings."""
    return f"children|{float(ob.furcollide.collision_offset)!r}"


def _digest_array(points):
    return np.array([framecache.digest(np.asarray(points, np.float32))], np.uint64).view(
        np.int64)


def _baked_children(setup, offsets, world, baked):
    """((points, status, n_fixed) from the bake, or None: computed live; a note when the
    bake is not what the stack gives now, or ''; whether what is shown is outdated).
    ``baked``: as :func:`run`'s; at a subframe of a baked setup the two baked frames
    around it are blended."""
    s = setup.s
    if setup.subframe != 0.0:
        if not (s.is_baked and s.enabled):
            return None, "", False
        return _baked_blend(setup, offsets), "", False
    if baked is None:
        return None, "", False
    f, shown_frame = baked
    part = None if shown_frame is None else shown_frame.extra.get(BAKE_PART)
    if part is None and shown_frame is None:
        try:
            part = framecache.read_extra(bpy.path.abspath(s.bake_path), f, BAKE_PART)
        except (OSError, ValueError, KeyError):
            part = None
    if part is None:
        return None, "", False
    if not np.array_equal(part["offsets"], offsets):
        return None, (
            f"Children: the output's stack now makes {len(offsets) - 1} children, the bake "
            f"holds {len(part['offsets']) - 1} (its stack was edited since the bake): they "
            "are cleared live. Press Free Bake, then Bake"), False
    note, outdated = "", False
    if int(part["stack"][0]) != int(_digest_array(world)[0]):
        outdated = True
        note = ("Children: the output's stack gives other children than when they were "
                "baked (the bake's are shown): press Free Bake, then Bake")
    if part["key"].tobytes().decode() != settings_key(setup.ob):
        outdated = True
    return (np.asarray(part["points"], np.float32), np.asarray(part["status"], np.int8),
            int(part["fixed"][0])), note, outdated


def _baked_blend(setup, offsets):
    """At a motion-blur subframe of a baked setup, the children blended between the
    two baked frames around it (as the guides are), when both hold the children the
    stack makes now; else None (cleared live)."""
    s = setup.s
    pair = framecache.subframe_pair(setup.frame, s.frame_start, s.frame_end)
    if pair is None:
        return None
    parts = []
    for f in pair:
        try:
            part = framecache.read_extra(bpy.path.abspath(s.bake_path), f, BAKE_PART)
        except (OSError, ValueError, KeyError):
            return None
        if part is None or not np.array_equal(part["offsets"], offsets):
            return None
        parts.append(part)
    points = framecache.subframe_blend(parts[0]["points"], parts[1]["points"], setup.subframe)
    return points, np.asarray(parts[0]["status"], np.int8), int(parts[0]["fixed"][0])


def _clear(setup, state, data, offsets, world):
    """The clearance pass on the stack's children ``data`` (evaluated; reused while
    nothing it depends on changed): (points (P, 3) float32 world, status (C,) int8,
    n_fixed, what was said of the colliders built for it)."""
    s = setup.s
    with clock.timing("clearance"):
        cols, fresh = collider_list(setup)
        entries = list(setup.rt.colliders.entries.values())
        sp = world_splines(s.output, setup.depsgraph, data)
    key = (settings_key(setup.ob), framecache.digest(offsets),
           framecache.digest(world), tuple((e.inputs, e.double_sided, e.offset)
                                           for e in entries), framecache.digest(sp.types))
    if key == state.key and state.result is not None:
        return (*state.result, tuple(fresh))
    with clock.timing("clearance"):
        points, status, n_fixed = clear_children(s, world, offsets, cols, sp, state.drawn)
    state.key, state.result = key, (points, status, n_fixed)
    return points, status, n_fixed, tuple(fresh)


def clear_children(s, world, offsets, colliders, splines=None, margins=None):
    """The clearance pass (:func:`groom.clearance_settings`) on children ``world``
    (P, 3) of layout ``offsets``; curves of fewer than 2 points are set aside (shown
    as they are, ``Status.INVALID``). ``splines`` (world: :func:`groom.world_splines`):
    the curves Blender draws clear the colliders, not only their points (``margins``:
    the pass's ``core.pipeline.ClearanceMargins``). Returns (points float32, status
    int8, n_fixed)."""
    C = len(offsets) - 1
    status = np.zeros(C, np.int8)
    if C == 0 or not colliders:
        return world.astype(np.float32), status, 0
    settings, fallback = clearance_settings(s)
    short = np.diff(offsets) < 2
    if not short.any():
        pts, status, n_fixed = pipeline.clearance_pass(world, offsets, colliders,
                                                       settings=settings, fallback=fallback,
                                                       splines=splines, margins=margins)
        return np.asarray(pts, np.float32), status, n_fixed
    rows, sub = subset(offsets, ~short)
    out = world.copy()
    status[short] = Status.INVALID
    if len(sub) > 1:
        pts, st, n_fixed = pipeline.clearance_pass(
            world[rows], sub, colliders, settings=settings, fallback=fallback,
            splines=None if splines is None else splines.take(~short, offsets),
            margins=margins)
        out[rows] = pts
        status[~short] = st
    else:
        n_fixed = 0
    return out.astype(np.float32), status, n_fixed


def children_stats(status, n_fixed, cleared=True) -> dict:
    """The children's panel statistics (keys ``children*``)."""
    counts = np.bincount(status.astype(np.intp), minlength=len(Status))
    return {"children": int(len(status)), "children_fixed": int(n_fixed),
            "children_unresolved": int(counts[Status.UNRESOLVED]),
            "children_invalid": int(counts[Status.INVALID]),
            "children_pinched": int(counts[Status.PINCHED]),
            "children_cleared": bool(cleared)}


def _write(setup, data, offsets, points_world, status) -> None:
    """Write the children (their layout, attributes and materials as the stack made
    them; their cleared points; their own status and colours) into the children
    output."""
    ch = setup.s.children.output
    if problem := bridge.write_refusal(ch, "children output"):
        raise ValueError(problem)
    dst = ch.data
    if not np.array_equal(bridge.curve_offsets(dst), offsets):
        bridge.copy_topology(data, compat.emptied_curves(ch))
        dst = ch.data
    else:
        bridge.copy_attributes(data, dst)
    _sync_materials(data, dst)
    if dst.surface != setup.s.output.data.surface:
        dst.surface = setup.s.output.data.surface
    M_inv = bridge.matrix(ch.evaluated_get(setup.depsgraph), inverted=True)
    bridge.set_positions(dst, bridge.transform(np.asarray(points_world, np.float32), M_inv))
    bridge.write_status(dst, np.asarray(status, np.int8), offsets)


def _sync_materials(src, dst) -> None:
    """Give ``dst`` the materials of the evaluated children ``src`` (the stack may set
    its own: Generate's Hair Material, Set Material)."""
    want = [m.original if m is not None else None for m in src.materials]
    if [m for m in dst.materials] != want:
        dst.materials.clear()
        for m in want:
            dst.materials.append(m)

