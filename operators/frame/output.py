"""What a frame writes: the output hair's positions, status codes, colours and attributes.

FurCollide writes only into the output object it owns (never the source): the world
points are brought into the output's local space (:func:`output_local`, bit for bit for
the points the solver left alone when the output sits where the source sits), the
per-curve ``furcollide_status`` and the point colours are rewritten only where a
status changed, and per-point attributes (the collider distance) are set. Also here:
the output's curve layout follows the source's (:func:`sync_output`), and which of
source and output the viewport shows (:func:`apply_visibility`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core import framecache, splines
from ..blender import bridge, compat
from ..store.registry import source_of
from .clock import clock


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
    rt = setup.rt
    data = setup.s.output.data
    local = output_local(inputs, points_world, changed)
    bridge.set_positions(data, local)
    if setup.ob is not None:
        write_handles(data, source_splines(setup, inputs), inputs, points_world, local)
    if attributes:
        write_attributes(data, attributes)
    attr = data.attributes.get(bridge.STATUS_ATTRIBUTE)
    last = rt.written_status  # (data, status, colours) written last
    if last is not None and (
        attr is None or last[0] != data.session_uid or len(attr.data) != len(status)
    ):
        last = None  # the output data was replaced or edited: write everything
    if last is None or not np.array_equal(last[1], status):
        previous, colors = (last[1], last[2]) if last is not None else (None, None)
        colors = bridge.status_colors(status, inputs.offsets, previous, colors)
        bridge.write_status(data, status, inputs.offsets, colors)
        rt.written_status = (data.session_uid, status.copy(), colors)
    return points_world


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
        changed = framecache.rows_differ(points_world, inputs.points)
    local = inputs.local.copy()
    idx = np.flatnonzero(changed)
    if len(idx):
        local[idx] = bridge.transform(points_world[idx], inputs.m_out_inv)
    return local


@dataclass
class SourceSplines:
    """How the evaluated source draws its curves, as one frame reads it.

    Attributes
    ----------
    world : core.splines.Splines
        Types, NURBS data and Bezier handles, the handles in world space.
    points : (P, 3) float32 ndarray or None
        The source's world polygon the handles go with (Bezier only); the frame's
        input when neither Fur Attach nor motion moved it.
    left_local, right_local : (P, 3) float32 ndarrays or None
        The source's own handles (local space): written back as they are where the
        output sits on the source and a curve was not moved.
    """

    world: splines.Splines
    points: np.ndarray | None = None
    left_local: np.ndarray | None = None
    right_local: np.ndarray | None = None

    @property
    def has_handles(self) -> bool:
        return self.points is not None

    def at(self, points, offsets) -> splines.Splines:
        """The splines with the handles moved onto the polygon ``points`` (world)."""
        sp = self.world
        if not self.has_handles or points is self.points or np.array_equal(points, self.points):
            return sp
        return sp.with_handles(*splines.moved_handles(self.points, points, offsets,
                                                      sp.handle_left, sp.handle_right))


def source_splines(setup, inputs) -> SourceSplines:
    """The source's splines of this frame (read once per frame, kept on ``inputs``)."""
    if inputs.splines is None:
        src = setup.ob.evaluated_get(setup.depsgraph)
        data = src.data
        sp = bridge.read_splines(data)
        out = SourceSplines(sp)
        if (sp.has(splines.BEZIER) and sp.handle_left is not None
                and sp.handle_right is not None):
            M = bridge.matrix(src)
            local = inputs.local if inputs.local is not None else bridge.get_positions(data)
            # (as read_inputs transforms them: bit for bit ``inputs.raw`` without Fur Attach)
            out.points = bridge.transform(local, M)
            out.left_local, out.right_local = sp.handle_left, sp.handle_right
            sp.handle_left = bridge.transform(sp.handle_left, M).astype(np.float64)
            sp.handle_right = bridge.transform(sp.handle_right, M).astype(np.float64)
        inputs.splines = out
    return inputs.splines


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
    hl, hr = splines.moved_handles(inputs.points, points_world, offs,
                                   *_pair(source.at(inputs.points, offs)))
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
    old = rt.output_attributes
    same = (old is not None and old[0] == names
            and (radius is None) == (old[1] is None)
            and (radius is None or np.array_equal(radius, old[1])))
    if framecache.topology_key(bridge.curve_offsets(out.data)) != inputs.key:
        bridge.copy_topology(src, compat.emptied_curves(out))
    elif not same:  # (the output's points stay: a held frame is still shown)
        bridge.copy_attributes(src, out.data)
    rt.output_attributes = (names, radius)
    source_splines(setup, inputs)  # (the solve widens the clearance of spline curves)


# ---------------------------------------------------------------- viewport
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
