"""numpy <-> Blender data bridge (the only place that touches bulk bpy data).

Every transfer goes through ``foreach_get``/``foreach_set`` on float32 /
int32 buffers of the exact size Blender reports; a size mismatch raises
:class:`BridgeError` with the object's name instead of corrupting data.
No geometry math here beyond applying 4x4 matrices.
"""

from __future__ import annotations

import hashlib
from contextlib import contextmanager

import bpy
import numpy as np

from ...core import splines
from ...core.framecache import curve_point_mask
from ...core.status import Status
from . import compat

#: Per-curve status attribute written on the output (core ``Status`` codes).
STATUS_ATTRIBUTE = "furcollide_status"
#: Point colour attribute for the viewport's *Attribute* colour mode.
COLOR_ATTRIBUTE = "furcollide_color"

_RGBA = {
    Status.FREE: (0.60, 0.60, 0.60, 1.0),  # grey
    Status.COLLIDING: (1.00, 0.45, 0.05, 1.0),  # orange
    Status.RECOVERING: (0.10, 0.55, 1.00, 1.0),  # blue
    Status.PINCHED: (0.90, 0.05, 0.70, 1.0),  # magenta
    Status.UNRESOLVED: (1.00, 0.00, 0.00, 1.0),  # red
    Status.DISABLED: (0.15, 0.15, 0.15, 1.0),  # dark grey
    Status.INVALID: (1.00, 0.85, 0.00, 1.0),  # yellow: fix the source curve
}
#: RGBA (len(Status), 4) float32, one row per core ``Status`` code.
STATUS_COLORS = np.array([_RGBA[s] for s in Status], np.float32)

# Attributes never copied from the source to the output. ``curve_type`` goes through
# the API (``set_types``): written as a plain attribute it leaves Blender's per-type
# curve counts wrong. The other built-in curve attributes (handles and their types,
# NURBS order, knots mode and weights, resolution, cyclic) are copied as they are,
# then :func:`tag_changed` drops the caches Blender derived from them.
_SKIP_ATTRIBUTES = {
    "position",
    STATUS_ATTRIBUTE,
    COLOR_ATTRIBUTE,
    "curve_type",
}
_CURVE_TYPES = ("CATMULL_ROM", "POLY", "BEZIER", "NURBS")


#: Object types that can collide: meshes, and everything Blender turns into one
#: (a Bezier rope with a bevel, a NURBS surface, text, metaballs).
COLLIDER_TYPES = frozenset({"MESH", "CURVE", "SURFACE", "FONT", "META"})


class BridgeError(ValueError):
    """Blender data does not have the size or layout FurCollide expects."""


# ----------------------------------------------------------------- matrices
def is_render(depsgraph) -> bool:
    """Is ``depsgraph`` a render's (F12, an animation render) rather than the viewport's?"""
    return getattr(depsgraph, "mode", "VIEWPORT") == "RENDER"


def matrix(ob, inverted=False) -> np.ndarray:
    """World matrix of ``ob`` (or its inverse) as a float64 (4, 4) array."""
    m = ob.matrix_world
    return np.array(m.inverted_safe() if inverted else m, dtype=np.float64)


def translation(t) -> np.ndarray:
    """The 4x4 matrix translating by ``t`` (3,)."""
    M = np.eye(4)
    M[:3, 3] = t
    return M


def is_identity(M: np.ndarray) -> bool:
    """Is the 4x4 ``M`` exactly the identity?"""
    return np.array_equal(M, _IDENTITY)


def transform(P: np.ndarray, M: np.ndarray) -> np.ndarray:
    """Apply the affine 4x4 ``M`` to points ``P`` (n, 3); returns float32.

    An identity matrix returns ``P`` itself when it already is float32 (no
    copy; callers never write into the result); otherwise the product is
    computed in float32 (Blender's own precision).
    """
    P = np.asarray(P, np.float32)
    if is_identity(M):
        return P
    M32 = np.asarray(M, np.float32)
    out = P @ np.ascontiguousarray(M32[:3, :3].T)
    out += M32[:3, 3]
    return out


_IDENTITY = np.eye(4)


# ------------------------------------------------------------------ curves
def curve_offsets(curves) -> np.ndarray:
    """``(C+1,)`` int32 point offsets of a ``bpy.types.Curves``."""
    n = len(curves.curves)
    offs = np.zeros(n + 1, np.int32)
    if n:
        curves.curve_offset_data.foreach_get("value", offs)
    return offs


def get_positions(curves) -> np.ndarray:
    """Point positions (P, 3) float32, in the object's local space."""
    n = len(curves.points)
    P = np.empty(n * 3, np.float32)
    if n:
        curves.position_data.foreach_get("vector", P)
    return P.reshape(-1, 3)


def set_positions(curves, P: np.ndarray) -> None:
    """Write local-space positions ``P`` (n, 3) into ``curves`` (original data), and
    make everything evaluated from them see them (:func:`tag_changed`).

    Positions equal bit for bit to the ones there are not written again: the tag
    makes Blender evaluate every Catmull-Rom, Bezier and NURBS curve again (for the
    object's bounds, at least), which frames that change nothing need not pay.
    """
    n = len(curves.points)
    if P.shape != (n, 3):
        raise BridgeError(
            f"'{curves.name}' has {n} points but {P.shape[0]} positions were given"
        )
    P = np.ascontiguousarray(P, np.float32)
    if n and np.array_equal(get_positions(curves).view(np.uint32), P.view(np.uint32)):
        return
    if n:
        curves.position_data.foreach_set("vector", P.ravel())
    tag_changed(curves)


def tag_changed(curves) -> None:
    """Tell Blender that the positions (and any curve attribute) of ``curves`` changed.

    Writing an attribute from Python (``foreach_set``) changes the data but not the
    caches Blender derived from it: the evaluated positions of Catmull-Rom, Bezier
    and NURBS curves, their evaluated point offsets, NURBS bases, tangents,
    normals, bounds, the per-type curve counts. The evaluated copy of the object
    shares those caches with the original (``CurvesGeometry``'s copy constructor
    shares its runtime caches), so a node that reads evaluated positions or lengths
    (Resample Curve, Trim Hair Curves; in renders too) got an earlier frame's shape,
    and the object's bounds were an earlier frame's. ``update_tag`` only asks for a
    new evaluation.

    ``add_curves([])`` adds nothing and calls ``tag_topology_changed`` on the
    original, which drops every one of those caches and has the curve types counted
    again: the public API that does it on every supported Blender (4.2 has no
    ``set_types``), for the cost of one pass over the curve offsets.
    """
    if len(curves.curves):
        curves.add_curves([])
    curves.update_tag()


def read_curve_mask(curves, name: str, n_curves: int) -> tuple[np.ndarray | None, str]:
    """Per-curve enable mask from attribute ``name``.

    Returns
    -------
    mask : (C,) bool ndarray or None
        ``None`` when the attribute is absent (every curve enabled).
    warning : str
        Non-empty when the attribute exists but cannot be used.
    """
    if not name:
        return None, ""
    attr = curves.attributes.get(name)
    if attr is None:
        return None, ""
    if attr.domain != "CURVE":
        return None, f"Attribute '{name}' is on the {attr.domain} domain; it must be per curve"
    kind = attr.data_type
    if kind == "BOOLEAN":
        buf = np.zeros(n_curves, bool)
    elif kind in {"INT", "INT8"}:
        buf = np.zeros(n_curves, np.int32)
    elif kind == "FLOAT":
        buf = np.zeros(n_curves, np.float32)
    else:
        return None, f"Attribute '{name}' has type {kind}; use Boolean, Integer or Float"
    if len(attr.data) != n_curves:
        raise BridgeError(f"attribute '{name}' has {len(attr.data)} values for {n_curves} curves")
    if n_curves:
        attr.data.foreach_get("value", buf)
    return (buf > 0.5) if kind == "FLOAT" else buf.astype(bool), ""


def _ensure_attribute(curves, name, kind, domain):
    attr = curves.attributes.get(name)
    if attr is not None and (attr.data_type != kind or attr.domain != domain):
        curves.attributes.remove(attr)
        attr = None
    if attr is None:
        attr = curves.attributes.new(name, kind, domain)
    return attr


def status_colors(status, offsets, previous=None, colors=None) -> np.ndarray:
    """Per-point RGBA (P, 4) float32 of the per-curve ``status`` codes.

    Given the ``previous`` status and its ``colors``, only the curves whose
    code changed are recoloured, in place (a few per frame, not all points).
    """
    codes = np.clip(status, 0, len(STATUS_COLORS) - 1).astype(np.intp)
    if previous is None or colors is None or previous.shape != status.shape:
        return np.repeat(STATUS_COLORS[codes], np.diff(offsets), axis=0)
    curves = np.flatnonzero(previous != status)
    if len(curves):
        sizes = offsets[curves + 1] - offsets[curves]
        colors[curve_point_mask(offsets, curves)] = np.repeat(
            STATUS_COLORS[codes[curves]], sizes, axis=0
        )
    return colors


def write_status(curves, status: np.ndarray, offsets: np.ndarray, colors=None) -> None:
    """Write per-curve ``furcollide_status`` and the per-point status colour
    (``colors`` from :func:`status_colors`, computed when not given)."""
    n = len(curves.curves)
    if status.shape != (n,):
        raise BridgeError(f"'{curves.name}' has {n} curves but {status.shape[0]} status codes")
    attr = _ensure_attribute(curves, STATUS_ATTRIBUTE, "INT", "CURVE")
    if n:
        attr.data.foreach_set("value", status.astype(np.int32))
    fresh = curves.attributes.get(COLOR_ATTRIBUTE) is None
    col = _ensure_attribute(curves, COLOR_ATTRIBUTE, "FLOAT_COLOR", "POINT")
    if colors is None:
        colors = status_colors(status, offsets)
    if len(colors):
        col.data.foreach_set("color", colors.ravel())
    if fresh:  # make it the active attribute once (the viewport's Attribute colour)
        try:
            curves.attributes.active = col
        except (AttributeError, TypeError, ValueError):  # API differs between versions
            pass


def copy_topology(src, dst) -> None:
    """Give ``dst`` (original Curves) the curve sizes and attributes of ``src``.

    ``src`` is usually the *evaluated* source data. ``dst`` has no curves
    (:func:`compat.emptied_curves`) or, from Blender 4.3 on, its curves are
    removed; every non-internal attribute of ``src`` (radius,
    ``surface_uv_coordinate``, custom attributes...) is copied.
    """
    offs = curve_offsets(src)
    sizes = np.diff(offs)
    if len(dst.curves):
        dst.remove_curves()
    if len(sizes):
        dst.add_curves(sizes.tolist())
    if len(curve_offsets(dst)) != len(offs) or not np.array_equal(curve_offsets(dst), offs):
        raise BridgeError(f"could not give '{dst.name}' the curve layout of '{src.name}'")
    copy_attributes(src, dst)
    _copy_curve_types(src, dst)
    set_positions(dst, get_positions(src))


def copy_attributes(src, dst) -> None:
    """Copy every non-internal POINT and CURVE attribute of ``src`` into ``dst`` (the
    same curve layout; positions, status and colours are left as they are)."""
    for attr in src.attributes:
        name = attr.name
        if name in _SKIP_ATTRIBUTES or name.startswith("."):
            continue
        if attr.domain not in {"POINT", "CURVE"}:
            continue
        try:
            _copy_attribute(attr, dst)
        except (RuntimeError, TypeError, ValueError, KeyError) as exc:
            print(f"FurCollide: attribute '{name}' not copied to '{dst.name}': {exc}")
    tag_changed(dst)  # (resolution, NURBS order, handle types change what is evaluated)


def attribute_state(src) -> tuple:
    """What of ``src``'s attributes the output copies, cheaply: (the list of copied
    attributes with their domain and type, the radius values or None). Compared frame
    to frame (:func:`frame.output.sync_output`): a new, removed or retyped attribute,
    or another radius (the render width), copies them all again."""
    names = tuple(sorted((a.name, a.domain, a.data_type) for a in src.attributes
                         if a.name not in _SKIP_ATTRIBUTES and not a.name.startswith(".")
                         and a.domain in {"POINT", "CURVE"}))
    radius = src.attributes.get("radius")
    values = None
    if radius is not None and radius.data_type == "FLOAT":
        values = np.empty(len(radius.data), np.float32)
        if len(values):
            radius.data.foreach_get("value", values)
    return names, values


def _copy_curve_types(src, dst) -> None:
    attr = src.attributes.get("curve_type")
    n = len(src.curves)
    if attr is None or not n:
        return
    types = np.empty(n, np.int32)
    attr.data.foreach_get("value", types)
    if hasattr(dst, "set_types"):  # (not in 4.2) the API keeps the type counts
        for code in np.unique(types):
            if 0 <= code < len(_CURVE_TYPES) and _CURVE_TYPES[code] != "CATMULL_ROM":
                idx = np.flatnonzero(types == code)
                dst.set_types(type=_CURVE_TYPES[code], indices=idx.tolist())
        return
    # 4.2: as an attribute; tag_changed (set_positions) has the types counted again
    _copy_attribute(attr, dst)


# ----------------------------------------------------------------- splines
def attribute_values(curves, name: str, domain: str, n: int, width: int = 1):
    """Values of attribute ``name`` on ``domain`` as an ndarray ((n,) or (n, width)),
    or None when ``curves`` has no such attribute (or one of another domain, type or
    size)."""
    attr = curves.attributes.get(name)
    spec = None if attr is None else _VALUE_KEYS.get(attr.data_type)
    if spec is None or attr.domain != domain or spec[2] != width or len(attr.data) != n:
        return None
    key, dtype, _ = spec
    buf = np.empty(n * width, dtype)
    if n:
        attr.data.foreach_get(key, buf)
    return buf if width == 1 else buf.reshape(n, width)


def read_splines(curves) -> splines.Splines:
    """How Blender draws the curves of ``curves``: their types and, where used, the
    Bezier handles (local space) and types, NURBS orders, knots modes and weights."""
    C, P = len(curves.curves), len(curves.points)
    types = attribute_values(curves, "curve_type", "CURVE", C)
    types = np.zeros(C, np.int8) if types is None else types.astype(np.int8)
    cyclic = attribute_values(curves, "cyclic", "CURVE", C)
    sp = splines.Splines(types, None if cyclic is None else cyclic.astype(bool))
    if sp.has(splines.BEZIER):
        sp.handle_left = attribute_values(curves, "handle_left", "POINT", P, 3)
        sp.handle_right = attribute_values(curves, "handle_right", "POINT", P, 3)
        for side in ("left", "right"):
            t = attribute_values(curves, f"handle_type_{side}", "POINT", P)
            setattr(sp, f"handle_type_{side}",
                    np.zeros(P, np.int8) if t is None else t.astype(np.int8))
    if sp.has(splines.NURBS):
        sp.nurbs_order = attribute_values(curves, "nurbs_order", "CURVE", C)
        sp.knots_mode = attribute_values(curves, "knots_mode", "CURVE", C)
        sp.nurbs_weight = attribute_values(curves, "nurbs_weight", "POINT", P)
    return sp


def write_handles(curves, left, right, type_left, type_right) -> None:
    """Write Bezier handle positions (P, 3) (local space) and types (P,) into
    ``curves``, and tag the change when anything differs from what is there."""
    n = len(curves.points)
    changed = False
    for name, values, kind, key in (
        ("handle_left", left, "FLOAT_VECTOR", "vector"),
        ("handle_right", right, "FLOAT_VECTOR", "vector"),
        ("handle_type_left", type_left, "INT8", "value"),
        ("handle_type_right", type_right, "INT8", "value"),
    ):
        attr = _ensure_attribute(curves, name, kind, "POINT")
        if len(attr.data) != n:
            raise BridgeError(f"'{curves.name}' has {n} points but '{name}' has "
                              f"{len(attr.data)} values")
        dtype = np.float32 if kind == "FLOAT_VECTOR" else np.int32
        new = np.ascontiguousarray(values, dtype).ravel()
        if not n:
            continue
        old = np.empty_like(new)
        attr.data.foreach_get(key, old)
        if not np.array_equal(old.view(np.uint32), new.view(np.uint32)):
            attr.data.foreach_set(key, new)
            changed = True
    if changed:
        tag_changed(curves)


#: Blender's values of built-in curve attributes it does not store.
_DEFAULTS = {"nurbs_order": splines.DEFAULT_ORDER}

_VALUE_KEYS = {
    "FLOAT": ("value", np.float32, 1),
    "INT": ("value", np.int32, 1),
    "INT8": ("value", np.int32, 1),
    "BOOLEAN": ("value", bool, 1),
    "FLOAT_VECTOR": ("vector", np.float32, 3),
    "FLOAT_COLOR": ("color", np.float32, 4),
    "BYTE_COLOR": ("color", np.float32, 4),
    "FLOAT2": ("vector", np.float32, 2),
    "QUATERNION": ("value", np.float32, 4),
    "INT32_2D": ("value", np.int32, 2),
}


def _copy_attribute(attr, dst) -> None:
    spec = _VALUE_KEYS.get(attr.data_type)
    if spec is None:
        return
    key, dtype, width = spec
    n = len(attr.data)
    buf = np.empty(n * width, dtype)
    if n:
        attr.data.foreach_get(key, buf)
    out = dst.attributes.get(attr.name)
    if out is not None and (out.data_type != attr.data_type or out.domain != attr.domain):
        dst.attributes.remove(out)
        out = None
    if out is None and attr.name in compat.UNSAFE_NEW_CURVE_ATTRIBUTES:
        if n and np.any(buf != _DEFAULTS.get(attr.name, 0)):
            print(f"FurCollide: '{dst.name}' draws its NURBS curves of order 4: Blender "
                  f"{bpy.app.version_string} cannot be given '{attr.name}' from Python")
        return
    if out is None:
        out = dst.attributes.new(attr.name, attr.data_type, attr.domain)
    if len(out.data) != n:
        raise BridgeError(f"attribute '{attr.name}' size differs ({len(out.data)} != {n})")
    if n:
        out.data.foreach_set(key, buf)


# ---------------------------------------------------------------- meshes
def mesh_corner_verts(me) -> np.ndarray:
    """(corners,) int32 vertex index of every face corner (``loops.vertex_index``).

    Read from the mesh's ``.corner_vert`` attribute when it has one (Blender
    3.6+): one copy, about 0.02 ms for 260,000 corners, where
    ``loops.foreach_get`` takes about 10 ms.
    """
    n = len(me.loops)
    corners = np.empty(n, np.int32)
    if n:
        attr = me.attributes.get(".corner_vert")
        if attr is not None and attr.domain == "CORNER" and attr.data_type == "INT" and len(
            attr.data
        ) == n:
            attr.data.foreach_get("value", corners)
        else:
            me.loops.foreach_get("vertex_index", corners)
    return corners


def mesh_topology_key(me) -> tuple:
    """Key that changes when a mesh's triangulation can change: its counts and a
    64-bit hash of its corner vertex indices (same counts, reordered or rewired
    faces: Sort Mesh Elements, a re-import, geometry nodes). Fur Attach saves it
    with a binding: the hash must stay the same from version to version."""
    corners = mesh_corner_verts(me)
    digest = hashlib.blake2b(corners.tobytes(), digest_size=8).digest()
    return (len(me.vertices), len(me.polygons), len(corners),
            int.from_bytes(digest, "little", signed=True))


def same_topology(now: tuple, bound: tuple) -> bool:
    """Does a mesh's :func:`mesh_topology_key` match one stored at binding time?
    (Keys saved by earlier versions hold the three counts only.)"""
    return tuple(now[: len(bound)]) == tuple(bound)


def write_refusal(target, what: str) -> str:
    """Why FurCollide must not write into hair object ``target`` (its output or
    render groom output, called ``what`` in the message), or ''.

    An object in no scene (deleted in the UI, or not appended with the hair), linked
    (read-only) data, and curves data that another, non-output object uses (the
    data was swapped for a groom's: writing would destroy that groom).
    """
    if not target.users_scene:
        return (f"the {what} '{target.name}' is in no scene (deleted, or not appended "
                "with the hair): remove the setup and add it again")
    lib = target.library or target.data.library
    if lib is not None:
        return (f"the {what} '{target.name}' is linked from '{lib.filepath}': FurCollide "
                "cannot write into linked data (make it local, or work in that file)")
    data = target.data
    if data.users > 1:
        for o in bpy.data.objects:
            if o.data == data and o != target and not o.furcollide.is_output:
                return (f"the {what} '{target.name}' uses the curves data '{data.name}' "
                        f"of '{o.name}': FurCollide would overwrite that groom. Give "
                        f"'{target.name}' its own data, or remove the setup and add it again")
    return ""


def is_collider_type(ob) -> bool:
    """Can object ``ob`` be a collider (see :data:`COLLIDER_TYPES`)?"""
    return ob is not None and ob.type in COLLIDER_TYPES


@contextmanager
def evaluated_mesh(oe):
    """The mesh of evaluated object ``oe``, for the ``with`` block.

    A mesh object's own evaluated data; for curves, surfaces, text and
    metaballs a temporary mesh (``to_mesh``, freed on leaving the block), or
    None where there is no surface (a curve without bevel or extrusion). So
    is a mesh in edit mode: its evaluated data then shows no vertices at all
    (Blender keeps the edits in a BMesh), ``to_mesh`` has them.
    """
    if oe.type == "MESH" and not getattr(oe.data, "is_editmode", False):
        yield oe.data
        return
    try:
        me = oe.to_mesh()
    except RuntimeError:  # nothing to tessellate (a metaball that is not the basis)
        me = None
    try:
        yield me
    finally:
        if me is not None:
            oe.to_mesh_clear()


def mesh_vertices(me) -> np.ndarray:
    """Vertex positions (n, 3) float32 in the mesh object's local space."""
    n = len(me.vertices)
    V = np.empty(n * 3, np.float32)
    if n:
        me.attributes["position"].data.foreach_get("vector", V)
    return V.reshape(-1, 3)


def mesh_triangles(me) -> np.ndarray:
    """Loop triangles (m, 3) int32 (``calc_loop_triangles`` is cached by Blender)."""
    me.calc_loop_triangles()
    m = len(me.loop_triangles)
    F = np.empty(m * 3, np.int32)
    if m:
        me.loop_triangles.foreach_get("vertices", F)
    return F.reshape(-1, 3)


def surface_mesh_world(ob, depsgraph, world_matrix=None):
    """Evaluated mesh of object ``ob`` (a mesh, or a curve, text... turned into one):
    world vertices (n, 3) float64, triangles (m, 3); none for a curve without a surface.
    ``world_matrix``: its world matrix when not its own (a collection instance)."""
    oe = ob.evaluated_get(depsgraph)
    M = matrix(oe) if world_matrix is None else world_matrix
    with evaluated_mesh(oe) as me:
        if me is None:
            return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
        V = mesh_vertices(me).astype(np.float64)
        F = mesh_triangles(me).astype(np.int64)
    return V @ M[:3, :3].T + M[:3, 3], F
