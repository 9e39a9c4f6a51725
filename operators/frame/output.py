"""What a frame writes: the output hair, and the setup's status; once a frame.

FurCollide writes only into the output object it owns (never the source). A frame
shows one :class:`Shown` (:func:`show`): the output's curve layout first follows the
source's (:func:`sync_output`), the world points are brought into the output's local
space (:func:`output_local`, bit for bit for the points the solver left alone when the
output sits where the source sits), the per-curve ``furcollide_status`` and the point
colours are rewritten only where a status changed, and per-point attributes (the
collider distance) are set. Then the frame's status, statistics and outdated mark are
set, once (:func:`publish`). Also here: which of source and output the viewport shows
(:func:`apply_visibility`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core import framecache, splines
from ..blender import bridge, compat
from ..store import registry, report
from .clock import clock


@dataclass(frozen=True)
class Shown:
    """What a frame writes into the output: world points (P, 3) and status codes (C,),
    with the points that differ from the input (``changed``, computed when None) and
    per-point ``attributes`` (name -> (P,) array).

    With ``rows`` (k,) the frame is given as its difference from the input: ``points``
    (k, 3) are the world positions of those rows, every other point is the input's
    (a cached frame: :meth:`core.framecache.MemoryCache.get_moved`)."""

    points: np.ndarray
    status: np.ndarray
    changed: np.ndarray | None = None
    attributes: dict | None = None
    rows: np.ndarray | None = None


@dataclass(frozen=True)
class Stage:
    """What a stage after the output (the render groom, the children) adds to the
    frame: its ``stats`` (merged into the setup's statistics), a ``note`` for the
    status ('' when none), and whether what it shows is ``outdated`` (a part of the
    bake made with other settings). ``guides_ok``: the guides' frame was shown (a note
    then follows their own status; otherwise it only shows alone). ``fresh``: what was
    said of the colliders the stage built (:func:`.colliders.collider_list`)."""

    stats: dict
    note: str = ""
    outdated: bool = False
    guides_ok: bool = True
    fresh: tuple = ()


def show(setup, inputs, shown, sync=False, world=True):
    """The one write of a frame: the output's layout follows the source's (``sync``),
    then ``shown`` (a :class:`Shown`, or None: the output keeps what it shows) is
    written. Returns the world points written, or None.

    ``world=False``: the caller needs no world points back (no render groom follows
    them, no frame is held): a frame given by its ``rows`` is then written from the
    source's own positions without taking the input to world space (and None is
    returned), where that writes the same bits (:func:`local_rows`)."""
    if sync:
        sync_output(setup, inputs)
    if shown is None:
        return None
    if shown.rows is not None:
        if not world and local_rows(inputs):
            with clock.timing("write"):
                local = _on_source(inputs, shown.rows, shown.points)
                _write_local(setup, inputs, local, shown.status, shown.attributes)
            return None
        # (the rows differ from the input before motion, which a cached frame keeps)
        points = inputs.before_motion().copy()
        points[shown.rows] = shown.points
        shown = Shown(points, shown.status, None, shown.attributes)
    return write(setup, inputs, shown.points, shown.status, shown.changed, shown.attributes)


def local_rows(inputs) -> bool:
    """Can a frame given by the rows that differ from the input be written from the
    source's own positions (those rows taken to the output's space, the rest as they
    are), bit for bit what :func:`output_local` writes of it? Yes where the output
    sits on the source, unless both are at the origin with a source matrix only close
    to the identity (the world input is then written, not the source's positions) or
    Bezier handles follow the points (they need the world input)."""
    if inputs.local is None or inputs.source_matrix is None:
        return False
    if inputs.splines is not None and inputs.splines.has_handles:
        return False
    return not bridge.is_identity(inputs.m_out_inv) or bridge.is_identity(inputs.source_matrix)


def publish(setup, status, outdated=None, stats=None) -> None:
    """The frame's status ``(level, message)``, outdated mark and statistics (each
    None: unchanged), set once at the end of the frame (:func:`..store.report.publish`)."""
    report.publish(setup.ob, setup.rt, status, outdated, stats)


@dataclass(slots=True)
class Written:
    """The part of a setup's runtime with what its output got last, changed only here
    (the status colours are written again only where a status changed)."""

    status: tuple | None = None  # (data session uid, status, colours) last written
    #: What the output last got of the evaluated source's attributes
    #: (``bridge.attribute_state``; None: nothing yet, copy them on the next frame).
    attributes: tuple | None = None


def forget_written(rt) -> None:
    """Another runtime wrote into the output (the setup shown in another scene): the
    next write of ``rt``'s writes the status, colours and attributes in full."""
    rt.output.status = None
    rt.output.attributes = None


def write(setup, inputs, points_world, status, changed=None, attributes=None) -> np.ndarray:
    """Write world positions, status codes and per-point ``attributes`` (name ->
    (P,) array) into the output's original data.

    Parameters
    ----------
    setup : setup.Setup
    inputs : inputs.FrameInputs
        The frame's inputs (offsets, the output's inverse matrix, the source's own
        local positions).
    points_world : (P, 3) float32 ndarray
    status : (C,) int8 ndarray
        Core ``Status`` codes.
    changed : (P,) bool ndarray, optional
        The points that differ from the input (computed when not given).
    attributes : dict, optional

    Returns
    -------
    (P, 3) float32 ndarray
        ``points_world``: what the output shows now (the render groom follows it).
    """
    with clock.timing("write"):
        return _write(setup, inputs, points_world, status, changed, attributes)


def _write(setup, inputs, points_world, status, changed, attributes) -> np.ndarray:
    local = output_local(inputs, points_world, changed)
    _write_local(setup, inputs, local, status, attributes, points_world)
    return points_world


def _write_local(setup, inputs, local, status, attributes, points_world=None) -> None:
    """Write the output's local positions ``local``, its handles (``points_world``
    given), ``attributes`` and, where a status changed, the status and colours."""
    rt = setup.rt
    data = setup.s.output.data
    bridge.set_positions(data, local)
    if inputs.splines is not None and points_world is not None:
        write_handles(data, inputs.splines, inputs, points_world, local)
    if attributes:
        write_attributes(data, attributes)
    attr = data.attributes.get(bridge.STATUS_ATTRIBUTE)
    last = rt.output.status  # (data, status, colours) written last
    if last is not None and (
        attr is None or last[0] != data.session_uid or len(attr.data) != len(status)
    ):
        last = None  # the output data was replaced or edited: write everything
    if last is None or not np.array_equal(last[1], status):
        previous, colors = (last[1], last[2]) if last is not None else (None, None)
        colors = bridge.status_colors(status, inputs.offsets, previous, colors)
        bridge.write_status(data, status, inputs.offsets, colors)
        rt.output.status = (data.session_uid, status.copy(), colors)


def output_local(inputs, points_world, changed=None) -> np.ndarray:
    """``points_world`` in the output's local space.

    When the output sits where the source sits, the points the solver left
    alone (``changed`` False; computed when not given) are the source's own
    local positions, exactly; only the others are transformed.
    """
    if inputs.local is None:  # the output was moved away from the source
        return bridge.transform(points_world, inputs.m_out_inv)
    if bridge.is_identity(inputs.m_out_inv):  # both at the world origin
        return points_world
    if changed is None:
        changed = framecache.rows_differ(points_world, inputs.world())
    idx = np.flatnonzero(changed)
    return _on_source(inputs, idx, points_world[idx])


def _on_source(inputs, rows, points_world) -> np.ndarray:
    """The source's own local positions with ``rows`` set to ``points_world`` (k, 3)
    taken to the output's space (the output sitting on the source)."""
    local = inputs.local.copy()
    if len(rows):
        local[rows] = bridge.transform(points_world, inputs.m_out_inv)
    return local


def write_handles(data, source, inputs, points_world, local) -> None:
    """Write the output's Bezier handles: each moves with its control point (the
    source's polygon to the frame's input, then the input to ``points_world``), in
    the output's local space; handle types as :func:`splines.written_handle_types`
    says (VECTOR handles recomputed on their segments). Nothing without Bezier
    curves.

    ``local`` (P, 3) are the output's local positions just written.
    """
    if not source.has_handles:
        return
    sp, offs = source.world, inputs.offsets
    world = inputs.world()
    hl, hr = splines.moved_handles(world, points_world, offs, *_pair(source.at(world, offs)))
    L = bridge.transform(hl, inputs.m_out_inv)
    R = bridge.transform(hr, inputs.m_out_inv)
    moved = _moved_curves(source.points, points_world, offs)
    if inputs.local is not None:  # the output sits on the source: unmoved curves as they are
        keep = ~np.repeat(moved, np.diff(offs))
        L[keep], R[keep] = source.left_local[keep], source.right_local[keep]
    tl, tr = splines.written_handle_types(sp.handle_type_left, sp.handle_type_right)
    if moved.any():  # (unmoved curves keep their VECTOR handles bit for bit too)
        sel = np.repeat(moved, np.diff(offs))
        sub = np.concatenate([[0], np.cumsum(np.diff(offs)[moved])])
        Ls, Rs = L[sel].astype(np.float64), R[sel].astype(np.float64)
        cyc = None if sp.cyclic is None else sp.cyclic[moved]
        splines.vector_handles(local[sel], sub, Ls, Rs, tl[sel], tr[sel], cyc)
        L[sel], R[sel] = Ls, Rs
    bridge.write_handles(data, L, R, tl, tr)


def _pair(sp):
    return sp.handle_left, sp.handle_right


def _moved_curves(before, after, offsets) -> np.ndarray:
    """(C,) bool: curves with a point that differs between ``before`` and ``after``."""
    differ = framecache.rows_differ(after, before)
    out = np.zeros(len(offsets) - 1, bool)
    idx = np.flatnonzero(differ)
    if len(idx):
        out[np.searchsorted(offsets, idx, side="right") - 1] = True
    return out


def write_attributes(data, attributes: dict) -> None:
    """Write per-point float attributes (name -> (P,) array) into hair ``data``."""
    for name, values in attributes.items():
        attr = data.attributes.get(name)
        if attr is not None and (attr.data_type != "FLOAT" or attr.domain != "POINT"):
            data.attributes.remove(attr)
            attr = None
        if attr is None:
            attr = data.attributes.new(name, "FLOAT", "POINT")
        if len(attr.data) != len(values):
            raise bridge.BridgeError(
                f"'{data.name}' has {len(attr.data)} points but {len(values)} values of "
                f"'{name}' were computed"
            )
        attr.data.foreach_set("value", np.ascontiguousarray(values, np.float32))


def sync_output(setup, inputs) -> None:
    """Give the output the evaluated source's curves and attributes when they differ.

    Copied again when the curve layout differs, when the list of the source's
    attributes changed, when its radius (the render width) changed, and on the first
    frame a runtime evaluates (a file opened, Reset Cache): other attribute values
    changed after Add (a colour painted again) follow with Reset Cache.
    """
    ob = setup.ob
    out = ob.furcollide.output
    src = ob.evaluated_get(setup.depsgraph).data
    names, radius = bridge.attribute_state(src)
    rt = setup.rt
    old = rt.output.attributes
    same = (old is not None and old[0] == names
            and (radius is None) == (old[1] is None)
            and (radius is None or np.array_equal(radius, old[1])))
    if framecache.topology_key(bridge.curve_offsets(out.data)) != inputs.key:
        bridge.copy_topology(src, compat.emptied_curves(out))
    elif not same:  # (the output's points stay: a held frame is still shown)
        bridge.copy_attributes(src, out.data)
    rt.output.attributes = (names, radius)


# ---------------------------------------------------------------- viewport
def apply_visibility(ob) -> None:
    """Show source or output in the viewport according to ``show_result``."""
    ob = registry.source_of(ob)
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
