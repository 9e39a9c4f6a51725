"""The render groom stage: a dense groom follows the collided guides (paper section 2).

``furcollide.groom_bind`` (:mod:`..ops.groom`) binds an existing render groom to a setup's
guides (:class:`core.pipeline.GroomBinding`, saved on the groom output object: this module
keeps its storage, :func:`store_groom` and :func:`load_groom`). Every frame the frame
rules show, :func:`run` deforms the render curves with the guides just written
(:meth:`core.pipeline.GroomBinding.deform`), then the **clearance pass**
(:func:`core.pipeline.clearance_pass`) frees the render curves that still cross a
collider, and writes the result with its ``furcollide_status`` and ``furcollide_color``
(as the guides' output). What the stage does, frame by frame:

* it checks the groom against its binding (:func:`groom_changes`): another Render
  Groom, its curves edited, Guides per Curve changed. The groom output keeps following
  the guides with the bound curves and the status says what to press;
* it computes only when its inputs changed (the guides, the Surface, the colliders and
  the groom's settings): a held frame, a still scene or a repeated frame writes what it
  computed last;
* a baked frame shows the groom baked with it (:func:`bake_frame` writes it) while its
  binding and settings are the bake's;
* when the guides' frame fails (an error, a topology change, an outdated frame), the
  groom follows the last good guides, carried with their Surface to the current frame
  (:func:`follow_last_guides`), so its roots stay on the skin and the clearance pass
  still runs against the colliders of this frame; with none in memory (a file just
  opened) it follows the guides as their output shows them.

Render curves the solver cannot work with (a zero-length segment, a NaN point) are set
aside at Bind Groom and shown as they are, in yellow (``Status.INVALID``); curves the
clearance pass cannot free are ``UNRESOLVED`` (red). Both are counted in the stats.
"""

from __future__ import annotations

import io
import re

import bpy
import numpy as np

from ... import core
from ...core import Status, framecache, pipeline
from ...core.pipeline import GroomBinding
from ..blender import bridge
from ..store import report
from ..store.registry import get_runtime
from .clock import clock
from .colliders import collider_list, in_scene
from .output import Stage, hide_in_viewport

#: Custom property (bytes of an ``np.savez`` file) on the groom output object with
#: the render groom binding (reference poses, guide weights, optional root binding).
GROOM_PROPERTY = "_furcollide_groom"
#: Name of the render groom's arrays in a bake file (:func:`framecache.write_frame`).
BAKE_PART = "groom"


# ------------------------------------------------------------------ frame
def run(setup, guides_world, baked=None) -> Stage | None:
    """The render groom follows the guides the output shows (deform + clearance pass);
    what it adds to the frame's status and statistics (None: no groom output here).

    Parameters
    ----------
    setup : setup.Setup
    guides_world : (P, 3) float32 ndarray or None
        The guides' world points the output shows now; None when the guides' frame
        failed: the groom then follows the last good guides (:func:`follow_last_guides`).
    baked : (int, framecache.ShownFrame) or None
        The baked frame the output shows, as read from its file (its render groom is
        shown while it is the bound one); None: the frame does not show a bake.

    Raises
    ------
    ValueError
        The groom output cannot be written (its messages name what to press).
    """
    depsgraph = setup.depsgraph
    out = setup.s.groom.output
    if depsgraph is None or not in_scene(out, depsgraph.scene):
        return None
    state = groom_state(setup.ob, setup.rt)
    state.note, state.fresh = "", []
    binding = state.binding
    note = groom_changes(setup, binding)
    if guides_world is not None and guides_world.shape != binding.guides_ref.shape:
        note = note or (
            f"Render groom: the guides now have {len(guides_world)} points but were bound "
            f"with {len(binding.guides_ref)}: press Bind Groom again (the groom follows "
            "the last guides it could use)")
        guides_world = None
    if guides_world is None:
        stats = _follow(setup, state)
        return Stage(stats, note or state.note or binding.note, guides_ok=False,
                     fresh=tuple(state.fresh))
    shown, outdated = None, False
    if setup.subframe != 0.0:
        shown = _baked_blend(setup, state) if setup.s.is_baked else None
    elif baked is not None:
        shown, outdated = _baked(setup, state, *baked)
    if shown is not None:
        points, status, stats = shown
        if setup.subframe == 0.0:
            state.remember_guides(guides_world, _surface_now(setup, binding)[0])
    else:
        points, status, stats = _compute(setup, state, guides_world)
    _write(setup, state, points, status)
    return Stage(stats, note or state.note or binding.note, outdated=outdated,
                 fresh=tuple(state.fresh))


def follow_unsolved(setup, guides_world) -> None:
    """The render groom following guides that no solve moved (the setup shown in a scene
    it does not belong to, :mod:`.scenes`): deformed with them, no clearance pass, so
    nothing collides. Writes nothing when the groom no longer fits its binding."""
    depsgraph = setup.depsgraph
    out = setup.s.groom.output
    if depsgraph is None or not in_scene(out, depsgraph.scene) or not has_groom(out):
        return
    state = groom_state(setup.ob, setup.rt)
    binding = state.binding
    if guides_world.shape != binding.guides_ref.shape:
        return
    V, _note = _surface_now(setup, binding)
    points, status = binding.deform(np.asarray(guides_world, np.float64), V,
                                    threads=setup.s.core_threads)
    state.written = None  # (the setup's own scene writes this output too)
    _write(setup, state, points, status)


def forget_written(rt) -> None:
    """The groom output was written by another runtime (the setup shown in another
    scene): the next write of ``rt``'s writes its status and colours in full."""
    if isinstance(rt.groom, GroomState):
        rt.groom.written = None


def error_message(exc, setup=None) -> str:
    """The status of an error of this stage: "Render groom: ...", said once, its
    advice one that works on ``setup`` (:func:`advice`)."""
    text = report.describe(exc)
    text = text if text.startswith("Render groom:") else f"Render groom: {text}"
    return text if setup is None else advice(setup.ob, text)


#: What the stage's messages tell the artist to press when the binding must be made again.
BIND_AGAIN = "press Bind Groom again"
#: The same while the setup's bake holds the render groom (Bind Groom is greyed then).
FREE_AND_BIND = "press Free Bake, then Bind Groom again"


def advice(ob, text) -> str:
    """``text`` (a status of this stage) with advice that works when followed on the
    setup on ``ob``: while its bake holds the render groom, Bind Groom and the groom's
    settings are greyed ('free the bake before binding'), so it says Free Bake first."""
    if not ob.furcollide.groom.is_baked_with:
        return text
    return re.sub(r"press Bind Groom(?: again)?", FREE_AND_BIND, text)


def follow_last_guides(setup) -> None:
    """The guides' frame failed: the groom follows the last good guides (attached to
    the current Surface), so it neither freezes nor crosses the colliders. Never
    raises (an error here must not hide the guides' own, which is the status)."""
    try:
        if setup.s.groom.output is not None:
            run(setup, None)
    except Exception as exc:  # noqa: BLE001 - the guides' error is the one reported
        print(f"FurCollide '{setup.ob.name}': render groom: {exc}", flush=True)


def with_note(status, stage, ob) -> tuple[str, str]:
    """The frame's status ``(level, message)`` with what the groom check found
    (``stage``, :func:`run`'s): alone when the guides are fine, after their own warning
    otherwise; never over an error of the guides."""
    note = stage.note if stage is not None else ""
    level, msg = status
    if not note or level == "ERROR" or not stage.guides_ok and msg:
        return status
    note = advice(ob, note)
    if msg and note not in msg:
        note = f"{msg} {note}"
    return "WARNING", note


def bake_frame(setup, guides_world) -> tuple[dict, dict] | None:
    """The render groom of a frame being baked: computed (and written, so the bake
    shows it) from the guides just baked; returns (its arrays for the bake file, its
    statistics), or None when the setup has no render groom."""
    g = setup.s.groom
    out = g.output
    if out is None or not has_groom(out) or not in_scene(out, setup.depsgraph.scene):
        return None
    state = groom_state(setup.ob, setup.rt)
    if guides_world.shape != state.binding.guides_ref.shape:
        return None  # (the guides changed since Bind Groom: not baked, computed live)
    points, status, stats = _compute(setup, state, guides_world)
    _write(setup, state, points, status)
    g.baked_id = g.bind_id
    return {"points": np.asarray(points, np.float32), "status": status,
            "key": np.frombuffer(settings_key(setup.ob).encode(), np.uint8),
            "fixed": np.array([stats["groom_fixed"]], np.int64)}, stats


def settings_key(ob) -> str:
    """What the baked render groom depends on besides the guides: the binding and the
    clearance pass's settings."""
    s = ob.furcollide
    g = s.groom
    return f"{g.bind_id}|{bool(g.use_clearance)}|{float(s.collision_offset)!r}"


def groom_binding(ob, rt):
    """The render groom binding of the setup on ``ob`` (cached in its runtime ``rt``)."""
    return groom_state(ob, rt).binding


def groom_state(ob, rt) -> GroomState:
    """The render groom's session state of the setup on ``ob`` (loaded on first use,
    again after Bind Groom)."""
    g = ob.furcollide.groom
    if not isinstance(rt.groom, GroomState) or rt.groom.bind_id != g.bind_id:
        rt.groom = GroomState(g.bind_id, load_groom(g.output))
    return rt.groom


def remove_groom(src) -> None:
    """Delete the setup's groom output and show its Render Groom again."""
    g = src.furcollide.groom
    remove_groom_output(g.output)
    g.output = None
    g.bind_id = ""
    if g.groom is not None:
        hide_in_viewport(g.groom, False, render=False)
    rt = get_runtime(src, create=False)
    if rt is not None:
        rt.groom = None


class GroomState:
    """What the render groom stage keeps between frames (in the setup's runtime)."""

    __slots__ = ("bind_id", "binding", "key", "result", "written", "last_guides", "carried",
                 "note", "fresh", "drawn")

    def __init__(self, bind_id, binding):
        self.bind_id = bind_id
        self.binding = binding
        self.key = None  # digests of the inputs of ``result``
        self.result = None  # (points (P, 3) float64 world, status (R,), stats)
        self.written = None  # (data session uid, status, colours) written last
        self.last_guides = None  # (guides world (Q, 3), Surface world (n, 3) or None)
        self.carried = None  # (last_guides, core Binding of them to the Surface)
        self.note = ""  # what the last computation found (shown after the checks)
        self.fresh = []  # what it said of the colliders it built (colliders._tell)
        #: The clearance pass's drawn margins (its curves' splines, last frame's).
        self.drawn = pipeline.ClearanceMargins()

    def remember_guides(self, guides, surface_V) -> None:
        self.last_guides = (np.array(guides, np.float64), surface_V)


# --------------------------------------------------------------- compute
def _surface_now(setup, binding):
    """(world vertices (n, 3) of the Surface the render roots are bound to, now, or
    None; a note when its topology changed since Bind Groom)."""
    surf = setup.ob.data.surface
    if binding.roots is None or surf is None or surf.type != "MESH":
        return None, ""
    se = surf.evaluated_get(setup.depsgraph)
    with bridge.evaluated_mesh(se) as me:
        if me is None:
            return None, ""
        if not bridge.same_topology(bridge.mesh_topology_key(me), binding.surface_key):
            return None, (
                f"Render groom: the Surface '{surf.name}' changed topology since Bind Groom "
                "(the render roots follow the guides): press Bind Groom again")
        V = bridge.mesh_vertices(me).astype(np.float64)
    return bridge.transform(V, bridge.matrix(se)), ""


def _compute(setup, state, guides_world, remember=True):
    """(points (P, 3) float64 world, status (R,) int8, stats) of the render groom on
    ``guides_world``; reuses the last result while its inputs are unchanged.
    ``remember``: these are the last good guides (not carried ones)."""
    s = setup.s
    g = s.groom
    binding = state.binding
    with clock.timing("attach"):  # (the render roots' Surface)
        V, surface_note = _surface_now(setup, binding)
    state.note = state.note or surface_note
    with clock.timing("clearance"):  # (its colliders, read at this frame)
        cols, fresh = collider_list(setup) if g.use_clearance else ([], [])
        entries = list(setup.rt.colliders.entries.values()) if g.use_clearance else []
    state.fresh += fresh
    guides = np.asarray(guides_world, np.float64)
    sp = None  # (an output with other curves than the bound ones: write_groom says so)
    if cols and np.array_equal(bridge.curve_offsets(g.output.data), binding.render_offsets):
        sp = world_splines(g.output, setup.depsgraph)
    key = (
        state.bind_id, settings_key(setup.ob), framecache.digest(guides),
        None if V is None else framecache.digest(V),
        tuple((e.inputs, e.double_sided, e.offset) for e in entries),
        None if sp is None else framecache.digest(sp.types),
    )
    if remember:
        state.remember_guides(guides, V)
    if key == state.key and state.result is not None:
        return state.result  # (nothing it depends on changed: a held or repeated frame)
    with clock.timing("groom"):
        points, status = binding.deform(guides, V, threads=s.core_threads)
    n_fixed = 0
    if cols:
        with clock.timing("clearance"):
            points, status, n_fixed = clearance(s, binding, points, status, cols, sp,
                                                state.drawn)
    stats = groom_stats(status, n_fixed)
    state.key, state.result = key, (points, status, stats)
    return points, status, stats


def clearance(s, binding, points, status, colliders, splines=None, margins=None):
    """The clearance pass on the deformed render curves (the invalid ones set aside).

    Stiff (the minimal rotation at the root, shape kept) with the setup's own
    Collision Offset, so render strands keep the same gap as the guides; the curves
    Stiff cannot free within Max Angle get a second try in Bend, and those still
    crossing are UNRESOLVED. ``splines`` (world, :func:`world_splines`): the curves
    Blender draws clear the colliders, not only their control points (``margins``:
    the pass's ``core.pipeline.ClearanceMargins``). Returns (points, status, n_fixed).
    """
    settings, fallback = clearance_settings(s)
    valid = status != Status.INVALID
    if valid.all():
        pts, st, n_fixed = pipeline.clearance_pass(points, binding.render_offsets, colliders,
                                                   settings=settings, fallback=fallback,
                                                   splines=splines, margins=margins)
        return pts, st, n_fixed
    rows, off = binding.subset(valid)
    sub = None if splines is None else splines.take(valid, binding.render_offsets)
    pts, st, n_fixed = pipeline.clearance_pass(points[rows], off, colliders,
                                               settings=settings, fallback=fallback,
                                               splines=sub, margins=margins)
    out = points.copy()
    out[rows] = pts
    status = status.copy()
    status[valid] = st
    return out, status, n_fixed


def clearance_settings(s):
    """(settings, fallback) core Settings of the clearance pass of the setup ``s``
    (``ob.furcollide``): Stiff, then Bend for the curves Stiff cannot free, with the
    setup's own Collision Offset (render strands keep the guides' gap) and Threads (a
    farm running one Blender per core sets 1). The render groom and the children
    (:mod:`.children`) share them."""
    common = {"collision_offset": s.collision_offset, "threads": s.core_threads}
    return core.Settings(mode="stiff", **common), core.Settings(mode="bend", **common)


def world_splines(ob, depsgraph, curves=None):
    """How Blender draws the curves of hair object ``ob`` (``curves``: its evaluated
    data, default its own): ``core.splines.Splines`` with the Bezier handles in world
    space (the space the clearance pass works in). The render groom and the children
    (:mod:`.children`) share it."""
    sp = bridge.read_splines(ob.data if curves is None else curves)
    if sp.handle_left is not None and sp.handle_right is not None:
        M = bridge.matrix(ob.evaluated_get(depsgraph))
        sp = sp.with_handles(bridge.transform(sp.handle_left, M).astype(np.float64),
                             bridge.transform(sp.handle_right, M).astype(np.float64))
    return sp


def groom_stats(status, n_fixed) -> dict:
    """The render groom's panel statistics (keys ``groom_*``)."""
    counts = np.bincount(status.astype(np.intp), minlength=len(Status))
    return {"groom_fixed": int(n_fixed), "groom_unresolved": int(counts[Status.UNRESOLVED]),
            "groom_invalid": int(counts[Status.INVALID]),
            "groom_pinched": int(counts[Status.PINCHED]), "groom_curves": int(len(status))}


def _follow(setup, state) -> dict:
    """Write the groom following the last good guides, carried rigidly with their
    Surface triangles to the Surface of this frame. With none in this session (a file
    just opened: the playback cache is not saved), it follows the guides as their
    output shows them (as saved), its roots on this frame's Surface; nothing when
    the output shows other guides than the bound ones. Returns its statistics."""
    binding = state.binding
    if state.last_guides is None:
        guides = _guides_shown(setup, binding)
        if guides is None:
            return {}
        points, status, stats = _compute(setup, state, guides, remember=False)
        _write(setup, state, points, status)
        return stats
    guides, V_then = state.last_guides
    V, _ = _surface_now(setup, binding)
    if V is not None and V_then is not None and V.shape == V_then.shape and not np.array_equal(
        V, V_then
    ):
        guides = _carry(setup, state, guides, V_then, V)
    points, status, stats = _compute(setup, state, guides, remember=False)
    _write(setup, state, points, status)
    return stats


def _guides_shown(setup, binding):
    """The guides' world points (Q, 3) float64 as their output shows them now, or None
    when it shows other curves than the bound guides (or a non-finite point)."""
    out = setup.s.output
    if out is None or out.type != "CURVES":
        return None
    data = out.data
    offsets = bridge.curve_offsets(data)
    if len(offsets) != len(binding.guide_offsets) or not np.array_equal(
        offsets, binding.guide_offsets
    ):
        return None
    M = bridge.matrix(out.evaluated_get(setup.depsgraph))
    guides = bridge.transform(bridge.get_positions(data), M).astype(np.float64)
    return guides if np.isfinite(guides).all() else None


def _carry(setup, state, guides, V_then, V_now):
    """The last good guides moved rigidly with their root triangles from the Surface
    ``V_then`` (when they were shown) to ``V_now`` (Fur Attach of the guides)."""
    carried = state.carried
    if carried is None or carried[0] is not state.last_guides:
        surf = setup.ob.data.surface
        with bridge.evaluated_mesh(surf.evaluated_get(setup.depsgraph)) as me:
            F = bridge.mesh_triangles(me).astype(np.int64)
        b = pipeline.bind(guides, state.binding.guide_offsets, V_then, F, snap_roots=False,
                          drop_degenerate=True)
        carried = state.carried = (state.last_guides, b)
    return carried[1].apply(V_now, threads=setup.s.core_threads)


def _write(setup, state, points_world, status) -> None:
    """Write the render groom's world points, status codes and colours into the groom
    output's data (status and colours only where a code changed)."""
    out = setup.s.groom.output
    with clock.timing("write"):
        _write_data(setup, state, out, points_world, status)


def _write_data(setup, state, out, points_world, status) -> None:
    write_groom(out, points_world, state.binding.render_offsets, setup.depsgraph)
    data = out.data
    attr = data.attributes.get(bridge.STATUS_ATTRIBUTE)
    last = state.written
    if last is not None and (attr is None or last[0] != data.session_uid
                             or len(attr.data) != len(status)):
        last = None
    if last is None or not np.array_equal(last[1], status):
        offsets = state.binding.render_offsets
        prev, colors = (last[1], last[2]) if last is not None else (None, None)
        colors = bridge.status_colors(status, offsets, prev, colors)
        bridge.write_status(data, status, offsets, colors)
        state.written = (data.session_uid, status.copy(), colors)


# ----------------------------------------------------------------- bake
def _baked(setup, state, f, shown):
    """(the render groom baked with frame ``f`` the output shows: (points (P, 3) world,
    status, stats), else None: the bake holds no groom, or another one, computed live;
    outdated). ``shown``: that frame as read (:func:`framecache.read_shown`). A groom
    baked with other settings is shown all the same, the setup outdated."""
    held = None
    if shown is not None:  # (read with the guides' frame: no groom in it, none)
        held = shown.extra.get(BAKE_PART)
        if held is None:
            return None, False
    part = _baked_part(setup, state, f, held)
    if part is None:
        return None, False
    points = part["points"]  # (float32 as baked: written as they are, no float64 copy)
    status = np.asarray(part["status"], np.int8)
    # Baked with other groom settings: still shown, as the guides' baked frame is (it
    # is what renders), never as if current (the frame rules say it:
    # baked.settings_differ).
    outdated = part["key"].tobytes().decode() != settings_key(setup.ob)
    return (points, status, groom_stats(status, int(part["fixed"][0]))), outdated


def _baked_blend(setup, state):
    """At a motion-blur subframe of a baked setup, the render groom blended between
    the two baked frames around it, as the guides are (``rules.subframe``;
    from Frame End on, Frame End held): (points (P, 3) world, the first frame's status,
    stats), else None (a frame of the pair without the groom, or another groom bound
    since: computed live). Nothing is computed, and the groom moves over the shutter
    with its guides instead of being solved again at each motion step."""
    s = setup.s
    pair = framecache.subframe_pair(setup.frame, s.frame_start, s.frame_end)
    if pair is None:
        return None
    parts = [_baked_part(setup, state, k) for k in pair]
    if any(p is None for p in parts):
        return None
    pa, pb = (p["points"] for p in parts)
    points = framecache.subframe_blend(pa, pb, setup.subframe)
    status = np.asarray(parts[0]["status"], np.int8)
    return points, status, groom_stats(status, int(parts[0]["fixed"][0]))


def _baked_part(setup, state, f, part=None):
    """The render groom part of baked frame ``f`` (``part``: already read with the
    guides' frame), or None: not in the bake, unreadable, or of another groom bound
    since (then the groom is computed live)."""
    if part is None:
        try:
            part = framecache.read_extra(bpy.path.abspath(setup.s.bake_path), f, BAKE_PART)
        except (OSError, ValueError, KeyError):
            return None
    if part is None or part["points"].shape != state.binding.render_ref.shape:
        return None
    return part


# ----------------------------------------------------------------- checks
def groom_changes(setup, binding) -> str:
    """What changed in the render groom since Bind Groom, as a status naming it and
    what to press ('' when nothing did)."""
    g = setup.s.groom
    groom = g.groom
    bound = binding.groom_name
    if groom is None:
        choose = ("Press Free Bake and choose it again" if g.is_baked_with
                  else "Choose it again")
        return (f"Render groom: no Render Groom is chosen (bound: '{bound}'); the groom "
                f"output keeps following the guides. {choose}, or remove the groom "
                "output (X)")
    if bound and groom.name != bound:
        return (f"Render groom: the Render Groom is now '{groom.name}' but '{bound}' is "
                "bound: press Bind Groom")
    if binding.groom_digest is not None and groom.type == "CURVES":
        offs = bridge.curve_offsets(groom.data)
        C, P = len(offs) - 1, int(offs[-1])
        if (C, P) != binding.groom_counts:
            return (f"Render groom: '{groom.name}' now has {C} curves / {P} points but was "
                    f"bound with {binding.groom_counts[0]} / {binding.groom_counts[1]}: "
                    "press Bind Groom again (the groom output shows the bound curves)")
        if groom_digest(groom) != binding.groom_digest:
            return (f"Render groom: '{groom.name}' was edited since Bind Groom (its curves "
                    "were moved or reshaped): press Bind Groom again (the groom output "
                    "shows the bound shape)")
    oe = groom.evaluated_get(setup.depsgraph)
    if oe.is_evaluated and groom.type == "CURVES":
        offs = bridge.curve_offsets(oe.data)
        ref = binding.render_offsets
        if len(offs) != len(ref) or not np.array_equal(offs, ref):
            return (f"Render groom: '{groom.name}' now gives {len(offs) - 1} curves / "
                    f"{int(offs[-1])} points but was bound with {len(ref) - 1} / "
                    f"{int(ref[-1])} (its modifiers?): press Bind Groom again")
    bound_k = binding.guides_k or g.bound_guides
    if bound_k and g.guides != bound_k:
        return (f"Render groom: Guides per Curve is {g.guides} but the groom was bound with "
                f"{bound_k}: press Bind Groom again")
    return ""


def groom_digest(groom) -> int:
    """Digest of the render groom's own curves (original data: its layout and points),
    what Bind Groom records and every frame compares."""
    data = groom.data
    return framecache.digest(bridge.curve_offsets(data), bridge.get_positions(data))


# -------------------------------------------------------------- binding
def build_binding(render_ref, render_offsets, guides_ref, guide_offsets, k, surface=None,
                  groom=None):
    """:meth:`core.pipeline.GroomBinding.build` with the render groom ``groom`` named in
    its messages and its name and curves recorded (:func:`groom_changes`).

    Returns (arrays for :func:`store_groom`, notes); ValueError when no render curve
    (or no guide) can be used.
    """
    name, record = "the render groom", None
    if groom is not None:
        offs = bridge.curve_offsets(groom.data)
        name = f"'{groom.name}'"
        record = {"groom_name": groom.name, "groom_digest": groom_digest(groom),
                  "groom_counts": (len(offs) - 1, int(offs[-1]))}
    return GroomBinding.build(render_ref, render_offsets, guides_ref, guide_offsets, k,
                              surface, name=name, record=record)


def store_groom(out, arrays: dict) -> None:
    """Save the groom binding on the groom output object ``out``."""
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    if GROOM_PROPERTY in out.keys():
        # Blender truncates bytes assigned over an existing bytes property at
        # their first NUL byte: a second Bind Groom would corrupt the binding.
        del out[GROOM_PROPERTY]
    out[GROOM_PROPERTY] = buf.getvalue()


def has_groom(out) -> bool:
    try:
        return out is not None and GROOM_PROPERTY in out.keys()
    except (TypeError, AttributeError, ReferenceError):
        return False


def load_groom(out) -> GroomBinding:
    """The groom binding saved on ``out`` (ValueError when there is none)."""
    if not has_groom(out):
        raise ValueError(
            f"'{out.name}' holds no render groom binding: press Bind Groom again"
        )
    raw = out[GROOM_PROPERTY]
    if not isinstance(raw, bytes):
        raw = bytes(raw)
    with np.load(io.BytesIO(raw), allow_pickle=False) as d:
        return GroomBinding({k: d[k] for k in d.files})


def write_groom(out, points_world, offsets, depsgraph) -> None:
    """Write the render groom's world points into the groom output's data."""
    if problem := bridge.write_refusal(out, "render groom output"):
        raise ValueError(problem)
    data = out.data
    have = bridge.curve_offsets(data)
    if len(have) != len(offsets) or not np.array_equal(have, offsets):
        raise ValueError(
            f"The groom output '{out.name}' has other curves than the bound groom "
            "(edited?): press Bind Groom again"
        )
    M_inv = bridge.matrix(out.evaluated_get(depsgraph), inverted=True)
    bridge.set_positions(data, bridge.transform(np.asarray(points_world, np.float32), M_inv))


def remove_groom_output(out) -> None:
    """Delete the groom output object (it belongs to FurCollide) and its data."""
    if out is None:
        return
    data = out.data
    bpy.data.objects.remove(out)
    if data is not None and data.users == 0:
        bpy.data.hair_curves.remove(data)
