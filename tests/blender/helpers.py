"""Scene builders and readers shared by the Blender tests (``from helpers import ...``).

Builders make small, deterministic scenes with real Blender data (hair grids, boxes,
surfaces, sweeping colliders); readers return numpy arrays (positions, offsets, world
points, status codes); the rest plays frames, saves and reopens files, and records
what a panel draws. Test files import from here, never from each other.
"""

from __future__ import annotations

import inspect
import itertools
import os
import sys
import types
from pathlib import Path

import bpy
import numpy as np
import pytest

from core import Status

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
import oracle  # noqa: E402, F401  (the core tests' brute-force segment/triangle oracle)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "pipeline"))
import pipe_oracle  # noqa: E402  (the pipeline tests' brute-force distances)

#: The add-on's module name: the tests register this checkout from a "dev" repository.
ADDON = "bl_ext.fcdev.furcollide"

INPUTS = "FurCollide Inputs"
FREE, COLLIDING, RECOVERING, PINCHED, UNRESOLVED = (
    Status.FREE, Status.COLLIDING, Status.RECOVERING, Status.PINCHED, Status.UNRESOLVED)
RESOLVED = (FREE, COLLIDING, RECOVERING)
INVALID = Status.INVALID
SHOT_FRAMES = (1, 6)
HALF = 0.25

# ----------------------------------------------------------------- builders
def make_hair(name="Fur", nx=6, ny=6, npts=5, length=1.0, spacing=0.2):
    """A grid of straight vertical hairs on z = 0 (nx * ny curves)."""
    hc = bpy.data.hair_curves.new(name)
    hc.add_curves([npts] * (nx * ny))
    xs = (np.arange(nx) - (nx - 1) / 2) * spacing
    ys = (np.arange(ny) - (ny - 1) / 2) * spacing
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    roots = np.stack([X.ravel(), Y.ravel(), np.zeros(nx * ny)], 1)
    t = np.linspace(0, length, npts)
    P = (roots[:, None, :] + t[None, :, None] * np.array([0, 0, 1.0])).reshape(-1, 3)
    hc.position_data.foreach_set("vector", P.astype(np.float32).ravel())
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def make_surface(name="Skin", half=1.0, n=8, z=0.0, uv=True):
    """A subdivided square (n x n quads) on z, as a growth surface; ``uv``: with a
    UV map named UVMap (Fur Attach needs none)."""
    xs = np.linspace(-half, half, n + 1)
    verts = [(x, y, z) for y in xs for x in xs]
    faces = [
        (j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i)
        for j in range(n) for i in range(n)
    ]
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    if uv:
        me.uv_layers.new(name="UVMap")
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def make_box(name="Box", size=0.5, location=(0, 0, 0.6)):
    """A closed cube mesh object (12 triangles) of edge ``size``."""
    h = size / 2
    verts = [(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h, h)]
    faces = [
        (0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1),
        (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3),
    ]
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    ob.location = location
    return ob


def make_scene(frames=(1, 12), nx=6, ny=6, animate=True):
    """Hair grid + a box sweeping through it along x over ``frames``."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    hair = make_hair(nx=nx, ny=ny)
    box = make_box()
    if animate:
        box.location = (-1.2, 0, 0.6)
        box.keyframe_insert("location", frame=frames[0])
        box.location = (1.2, 0, 0.6)
        box.keyframe_insert("location", frame=frames[1])
        for fc_ in box.animation_data.action.fcurves if hasattr(
            box.animation_data.action, "fcurves"
        ) else []:
            for k in fc_.keyframe_points:
                k.interpolation = "LINEAR"
    scene.frame_set(frames[0])
    return hair, box


def activate(ob, *selected):
    """Make ``ob`` the active object, with ``selected`` (and ``ob``) selected."""
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for o in selected:
        o.select_set(True)
    ob.select_set(True)
    bpy.context.view_layer.objects.active = ob


def set_core(s, **values):
    """Set setup properties ``s`` from :class:`core.Settings` names and values: angles in
    degrees, choices as the core spells them (``set_core(s, mode="bend",
    max_angle=120.0)``; the add-on's ``core_values.set_core_values``)."""
    sys.modules[ADDON + ".operators.settings.core_values"].set_core_values(s, **values)


def setup(hair, colliders):
    """Run furcollide.add with ``hair`` active and ``colliders`` selected."""
    activate(hair, *colliders)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    return hair.furcollide.output


def render_camera(scene, engine="BLENDER_WORKBENCH", px=32):
    """A small, fast render set-up: an orthographic camera looking at the
    origin from -Y, ``px`` x ``px`` pixels, Lock Interface on."""
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    cam.data.type = "ORTHO"
    cam.data.ortho_scale = 3.0
    cam.location = (0, -5, 0.5)
    cam.rotation_euler = (np.pi / 2, 0, 0)
    scene.render.engine = engine
    if engine == "CYCLES":
        scene.cycles.samples = 1
        scene.cycles.device = "CPU"
    scene.render.resolution_x = scene.render.resolution_y = px
    scene.render.use_lock_interface = True
    return cam


def positions(ob):
    """Original point positions of a hair object, (P, 3) float32."""
    d = ob.data
    P = np.empty(len(d.points) * 3, np.float32)
    d.position_data.foreach_get("vector", P)
    return P.reshape(-1, 3)


def bake_crashing_at(fc, monkeypatch, frame, match="simulated crash"):
    """Run furcollide.bake with a simulated crash in ``frame`` (the frames before
    it are kept on disk); the error message must match ``match``."""
    real = fc.store.bake.bake_frame

    def crashing(setup, directory, trust_solver):
        if setup.frame == frame:
            raise RuntimeError("simulated crash")
        return real(setup, directory, trust_solver)

    with monkeypatch.context() as m:
        m.setattr(fc.store.bake, "bake_frame", crashing)
        with pytest.raises(RuntimeError, match=match):
            bpy.ops.furcollide.bake()


# ------------------------------------------------------------------ readers
def offsets_of(ob):
    """``(C+1,)`` int32 curve offsets of a hair object's original data."""
    n = len(ob.data.curves)
    offs = np.zeros(n + 1, np.int32)
    if n:
        ob.data.curve_offset_data.foreach_get("value", offs)
    return offs


def world(ob):
    """World-space (P, 3) float64 points of a hair object's original data."""
    P = positions(ob).astype(np.float64)
    M = np.array(ob.matrix_world)
    return P @ M[:3, :3].T + M[:3, 3]


def status_of(out):
    """The per-curve ``furcollide_status`` codes (core ``Status``) of an output."""
    st = np.zeros(len(out.data.curves), np.int8)
    out.data.attributes["furcollide_status"].data.foreach_get("value", st)
    return st


def pipeline_state(guides):
    """What a pipeline setup on ``guides`` shows: (guides' world points, their status,
    the render groom's world points, its status), copies."""
    s = guides.furcollide
    return (world(s.output).copy(), status_of(s.output).copy(),
            world(s.groom.output).copy(), status_of(s.groom.output).copy())


def seg_lengths(P, offs):
    """Per-curve segment lengths (no segment between two curves)."""
    d = np.linalg.norm(np.diff(P, axis=0), axis=1)
    keep = np.ones(len(d), bool)
    keep[offs[1:-1] - 1] = False
    return d[keep]


# ---------------------------------------------------------------- animation
def fcurves(id_):
    """Every F-curve of ``id_``'s action (layered actions of Blender 4.4+ too)."""
    ad = getattr(id_, "animation_data", None)
    act = ad.action if ad else None
    if act is None:
        return []
    if hasattr(act, "fcurves"):
        return list(act.fcurves)
    out = []
    for layer in act.layers:
        for strip in layer.strips:
            for bag in strip.channelbags:
                out.extend(bag.fcurves)
    return out


def linear(*ids):
    """Make every keyframe of ``ids`` linear."""
    for id_ in ids:
        for fcu in fcurves(id_):
            for k in fcu.keyframe_points:
                k.interpolation = "LINEAR"


def sweep_box(name="Box", x0=-1.2, x1=1.2, frames=(1, 8), size=0.5, y=0.0, z=0.6,
              linear_keys=True):
    """A box sweeping from ``x0`` to ``x1`` at height ``z``, keyed at both ends of
    ``frames`` (linearly unless ``linear_keys`` is off)."""
    box = make_box(name, size=size, location=(x0, y, z))
    box.keyframe_insert("location", frame=frames[0])
    box.location = (x1, y, z)
    box.keyframe_insert("location", frame=frames[1])
    if linear_keys:
        linear(box)
    return box


# ---------------------------------------------------------------- playing
def play(scene, frames):
    """``scene.frame_set`` every frame of ``frames``."""
    for f in frames:
        scene.frame_set(f)


def positions_per_frame(out, frames):
    """Play ``frames`` in the context scene: ``{frame: out's positions}``."""
    scene = bpy.context.scene
    rec = {}
    for f in frames:
        scene.frame_set(f)
        rec[f] = positions(out).copy()
    return rec


# ------------------------------------------------------------------- files
def save_as(path):
    """Save the open file as ``path``; returns it as a string."""
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return str(path)


def save_in(tmp_path, name="shot.blend"):
    """Save the open file as ``name`` in ``tmp_path``; returns the path."""
    return save_as(tmp_path / name)


def reopen(path):
    """Open ``path`` from an empty session."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=path)


def bake_files(d):
    """The ``frame_*`` files in bake directory ``d`` (sorted; none when it is missing)."""
    return sorted(f for f in os.listdir(d) if f.startswith("frame_")) if os.path.isdir(d) else []


# ------------------------------------------------ shared by several test files
def render_watching(tmp_path, tag, watch, setup):
    """Render the animation; record every RENDER-depsgraph frame change (after
    FurCollide's handler): ``{(frame, subframe): [{name: world points}, ...]}`` and
    the setup's status message at each of them."""
    scene = bpy.context.scene
    scene.render.filepath = str(tmp_path / f"{tag}_####")
    seen, statuses = {}, []

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            key = (sc.frame_current, round(sc.frame_subframe, 3))
            seen.setdefault(key, []).append({o.name: world(o).copy() for o in watch})
            statuses.append((key, setup.furcollide.status_message))

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    return seen, statuses


def check_render(seen, statuses, watch, frames):
    """Every rendered whole frame equals the viewport at that frame; nothing failed."""
    assert [s for s in statuses if s[1]] == [], "status set during the render"
    whole = sorted(k[0] for k in seen if k[1] == 0.0)
    assert sorted(set(whole)) == list(frames)
    scene = bpy.context.scene
    viewport = {}
    for f in frames:
        scene.frame_set(f)
        viewport[f] = {o.name: world(o).copy() for o in watch}
        for snap in seen[(f, 0.0)]:
            for o in watch:
                np.testing.assert_array_equal(snap[o.name], viewport[f][o.name],
                                              err_msg=f"{o.name} frame {f}")
    return viewport


def dependency_objects(ob):
    mod = ob.modifiers[0]
    assert mod.name == INPUTS, [m.name for m in ob.modifiers]
    return {n.inputs["Object"].default_value for n in mod.node_group.nodes
            if n.bl_idname == "GeometryNodeObjectInfo"}


def duplicate(ob, dx=0.0):
    dup = ob.copy()
    dup.data = ob.data.copy()
    dup.name = ob.name + " Copy"
    dup.location.x += dx
    bpy.context.scene.collection.objects.link(dup)
    return dup


# ------------------------------------------------------------------ drawing
def _layout_rna():
    return bpy.types.UILayout.bl_rna


def _check_value(where, param, value):
    """``value`` fits the RNA parameter (or property) ``param``: type, enum item."""
    t = param.type
    if t == "STRING":
        assert isinstance(value, str), f"{where}: {param.identifier}={value!r} is not a str"
    elif t == "BOOLEAN":
        assert isinstance(value, bool | np.bool_), f"{where}: {param.identifier}={value!r}"
    elif t == "INT":
        assert isinstance(value, int | np.integer) and not isinstance(value, bool), (
            f"{where}: {param.identifier}={value!r} is not an int")
    elif t == "FLOAT":
        assert isinstance(value, float | int | np.floating) and not isinstance(value, bool), (
            f"{where}: {param.identifier}={value!r} is not a number")
        assert np.isfinite(value), f"{where}: {param.identifier}={value!r}"
    elif t == "ENUM":
        items = {e.identifier for e in param.enum_items}
        values = value if getattr(param, "is_enum_flag", False) else {value}
        for v in values:
            assert v in items, f"{where}: {param.identifier}={v!r} is not one of Blender's"


def _rna_property(data, name, where):
    """The RNA property ``name`` of ``data`` (an RNA struct, not a Python object)."""
    assert data is not None, f"{where}: data is None for property {name!r}"
    rna = getattr(data, "bl_rna", None)
    assert rna is not None, f"{where}: {data!r} is not an RNA struct"
    prop = rna.properties.get(name)
    assert prop is not None, f"{where}: {rna.identifier} has no property {name!r}"
    return prop


_LAYOUT_SERIAL = itertools.count()


class RnaLayout:
    """A recording stand-in for ``bpy.types.UILayout`` (panels cannot be drawn headless)
    that checks every call against Blender's own RNA, as the real layout would:

    * only functions and attributes ``UILayout`` has, with their parameter names, and
      values of the right type (icons and other enums among Blender's items);
    * every property name against the RNA of the object it is given (``prop``,
      ``prop_search``, ``template_list`` ...), every operator idname against the
      registered operators, every list type and menu or panel name against the
      registered classes;
    * ``template_list`` draws each item with the list class's ``draw_item``.

    Each call is logged as a dict (``kind``, ``name``, ``text``, ``icon``, and the
    effective ``enabled``, ``active`` and ``alert`` of the layout it was drawn in, its
    ``split`` and ``decorate`` (``use_property_split`` / ``_decorate``, as inherited),
    ``boxes`` (how many boxes it is in) and ``in_split`` (in a ``split()``)).
    """

    def __init__(self, log, context, parent=None, kind=None):
        object.__setattr__(self, "_log", log)
        object.__setattr__(self, "_context", context)
        object.__setattr__(self, "_parent", parent)
        object.__setattr__(self, "_attrs", {"enabled": True, "active": True, "alert": False})
        object.__setattr__(self, "_item", getattr(parent, "_item", None))
        object.__setattr__(self, "_kind", kind)
        # (a serial number, not id(): a freed layout's id is given to the next one)
        object.__setattr__(self, "_serial", next(_LAYOUT_SERIAL))

    def _inherited(self, key):
        """``use_property_split`` / ``_decorate`` as the layout has it (set here, or on
        the nearest layout it is in)."""
        if key in self._attrs:
            return bool(self._attrs[key])
        return self._parent._inherited(key) if self._parent is not None else False

    def _count(self, kind):
        up = self._parent._count(kind) if self._parent is not None else 0
        return up + (self._kind == kind)

    # attributes: only UILayout's, with values of their type
    def __setattr__(self, name, value):
        prop = _layout_rna().properties.get(name)
        assert prop is not None and not prop.is_readonly, f"UILayout has no settable {name!r}"
        _check_value(f"layout.{name}", prop, value)
        self._attrs[name] = value

    def __getattr__(self, name):
        if name.startswith("_"):
            raise AttributeError(name)
        if name in _layout_rna().properties:
            return self._attrs.get(name)
        fn = _layout_rna().functions.get(name)
        assert fn is not None, f"UILayout has no function {name!r}"
        return lambda *args, **kw: self._call(name, fn, args, kw)

    def _state(self, key):
        own = bool(self._attrs.get(key))
        if self._parent is None:
            return own
        if key == "alert":
            return own or self._parent._state(key)
        return own and self._parent._state(key)

    def _call(self, name, fn, args, kw):
        params = [p for p in fn.parameters if not p.is_output]
        names = [p.identifier for p in params]
        assert len(args) <= len(names), f"layout.{name}: {len(args)} positional arguments"
        given = dict(zip(names, args, strict=False))
        for k in kw:
            assert k in names, f"layout.{name}() has no parameter {k!r} ({names})"
            assert k not in given, f"layout.{name}: {k!r} given twice"
        given.update(kw)
        for p in params:
            if p.is_required:
                assert p.identifier in given, f"layout.{name}: {p.identifier!r} missing"
            if p.identifier in given and p.type != "POINTER":
                _check_value(f"layout.{name}", p, given[p.identifier])
        entry = {"kind": name, "text": given.get("text"), "icon": given.get("icon"),
                 "enabled": self._state("enabled"), "active": self._state("active"),
                 "alert": self._state("alert"), "list_item": self._item,
                 "split": self._inherited("use_property_split"),
                 "decorate": self._inherited("use_property_decorate"),
                 "boxes": self._count("box"), "in_split": self._count("split") > 0,
                 "layout": self._serial, "layout_kind": self._kind}
        handler = getattr(self, "_do_" + name, None)
        result = handler(given, entry) if handler else None
        self._log.append(entry)
        if name in ("row", "column", "box", "split", "column_flow", "grid_flow"):
            return RnaLayout(self._log, self._context, self, kind=name)
        return result

    def _do_prop(self, g, entry):
        _rna_property(g["data"], g["property"], "layout.prop")
        entry["name"] = g["property"]
        entry["data"] = g["data"]

    _do_prop_menu_enum = _do_prop
    _do_prop_decorator = _do_prop

    def _do_prop_search(self, g, entry):
        _rna_property(g["data"], g["property"], "layout.prop_search")
        target = _rna_property(g["search_data"], g["search_property"], "layout.prop_search")
        assert target.type == "COLLECTION", g["search_property"]
        entry["name"] = g["property"]
        entry["data"] = g["data"]

    def _do_operator(self, g, entry):
        idname = g["operator"]
        mod, _, op = idname.partition(".")
        assert hasattr(getattr(bpy.ops, mod), op), f"no operator {idname!r}"
        rna = getattr(getattr(bpy.ops, mod), op).get_rna_type()
        entry["name"] = idname
        return OperatorProperties(rna, idname)

    def _do_label(self, g, entry):
        entry["name"] = g.get("text", "")

    def _do_menu(self, g, entry):
        assert hasattr(bpy.types, g["menu"]), f"no menu {g['menu']!r}"
        entry["name"] = g["menu"]

    def _do_popover(self, g, entry):
        assert hasattr(bpy.types, g["panel"]), f"no panel {g['panel']!r}"
        entry["name"] = g["panel"]

    def _do_template_list(self, g, entry):
        cls = getattr(bpy.types, g["listtype_name"], None)
        assert cls is not None and issubclass(cls, bpy.types.UIList), g["listtype_name"]
        coll = _rna_property(g["dataptr"], g["propname"], "template_list")
        assert coll.type == "COLLECTION", g["propname"]
        active = _rna_property(g["active_dataptr"], g["active_propname"], "template_list")
        assert active.type == "INT", g["active_propname"]
        entry["name"] = g["listtype_name"]
        items = list(getattr(g["dataptr"], g["propname"]))
        entry["items"] = len(items)
        for i, item in enumerate(items):
            row = RnaLayout(self._log, self._context, self)
            object.__setattr__(row, "_item", i)
            self._log.append({"kind": "list_item", "name": g["listtype_name"], "index": i,
                              "text": None, "icon": None, "enabled": True, "active": True,
                              "alert": False})
            cls.draw_item(Bound(cls, layout=None), self._context, row, g["dataptr"], item, 0,
                          g["active_dataptr"], g["active_propname"], i)
            DRAWN.add(g["listtype_name"])


class OperatorProperties:
    """What ``layout.operator`` returns: only the operator's own properties can be set."""

    def __init__(self, rna, idname):
        object.__setattr__(self, "_rna", rna)
        object.__setattr__(self, "_idname", idname)

    def __setattr__(self, name, value):
        prop = self._rna.properties.get(name)
        assert prop is not None, f"{self._idname} has no property {name!r}"
        _check_value(self._idname, prop, value)


class Bound:
    """``self`` for a panel's or a list's methods called outside Blender: the class's
    methods bound to this object, its ``layout`` the recording one."""

    def __init__(self, cls, layout):
        self._cls = cls
        self.layout = layout

    def __getattr__(self, name):
        if name == "bl_idname" and not hasattr(self._cls, name):
            return self._cls.__name__  # what registering gives a class without one
        attr = getattr(self._cls, name)
        if inspect.isfunction(attr):
            return types.MethodType(attr, self)
        return attr


#: Panel and list classes whose drawing ran (any test in this process).
DRAWN: set = set()


def draw_rna(panel_cls, context=None, header=True):
    """Draw ``panel_cls`` (its header and header preset too) as Blender would when its
    ``poll`` passes, into an :class:`RnaLayout`; returns the log (a list of dicts), or
    None when the panel's poll refuses."""
    context = context or bpy.context
    if hasattr(panel_cls, "poll") and not panel_cls.poll(context):
        return None
    log = []
    if header:
        for name in ("draw_header", "draw_header_preset"):
            if hasattr(panel_cls, name):
                getattr(panel_cls, name)(Bound(panel_cls, RnaLayout(log, context)), context)
    panel_cls.draw(Bound(panel_cls, RnaLayout(log, context)), context)
    DRAWN.add(panel_cls.__name__)
    return log


def draw_panel(panel):
    """What ``panel`` draws, as ``(kind, name)`` pairs (labels: their text)."""
    log = draw_rna(panel, header=False) or []
    return [(_KIND.get(e["kind"], e["kind"]), e.get("name")) for e in log
            if e["kind"] in ("prop", "prop_search", "operator", "label")]


class EnabledLayout:
    """Records what a panel draws, with the effective ``enabled`` state of every
    property (panels cannot be drawn headless)."""

    def __init__(self, log, parent=None):
        self.log = log
        self.parent = parent
        self.enabled = True
        self.active = True
        self.alert = False
        self.use_property_split = self.use_property_decorate = None

    def _on(self):
        return self.enabled and (self.parent is None or self.parent._on())

    def _child(self, *args, **kw):
        return EnabledLayout(self.log, self)

    box = row = column = split = _child

    def prop(self, data, name, **kw):
        assert hasattr(data, name), name
        self.log.append(("prop", name, self._on()))

    def prop_search(self, data, name, *args, **kw):
        self.prop(data, name)

    def operator(self, idname, **kw):
        self.log.append(("operator", idname, self._on()))
        return type("Props", (), {})()

    def label(self, **kw):
        self.log.append(("label", kw.get("text"), self._on()))

    def separator(self, **kw):
        pass

    def prop_decorator(self, data, name, **kw):  # (a setting's keyframe dot)
        assert hasattr(data, name), name


def draw_enabled(panel):
    """What ``panel`` draws, as ``(kind, name, enabled)`` triples."""
    log = draw_rna(panel, header=False) or []
    return [(_KIND.get(e["kind"], e["kind"]), e.get("name"), e["enabled"]) for e in log
            if e["kind"] in ("prop", "prop_search", "operator", "label")]


_KIND = {"prop_search": "prop"}


def small_setup(fc, frames=(1, 8), nx=4, ny=4):
    hair, box = fc.make_scene(frames=frames, nx=nx, ny=ny)
    out = fc.setup(hair, [box])
    return hair, box, out


def render_spy(fc, tmp_path, hair, out, tag, record=None):
    """Render the animation; {frame: record()} as the RENDER depsgraph's frame
    changes left them (after FurCollide's handler). Default record: (world
    points, status, outdated)."""
    scene = bpy.context.scene
    scene.render.filepath = str(tmp_path / f"{tag}_####")
    seen = {}
    if record is None:
        def record():
            return (world(out).copy(), fc.store.report.status_for(hair),
                    hair.furcollide.is_outdated)

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            seen[sc.frame_current] = record()

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    return seen


def world_mesh(oe, M):
    """Vertices (placed by the 4x4 ``M``) and triangles of evaluated object ``oe``
    (``to_mesh``: also right for a mesh in edit mode)."""
    me = oe.to_mesh()
    try:
        me.calc_loop_triangles()
        V = np.array([v.co for v in me.vertices], np.float64).reshape(-1, 3)
        F = np.array([t.vertices[:] for t in me.loop_triangles], np.int64).reshape(-1, 3)
    finally:
        oe.to_mesh_clear()
    M = np.array(M)
    return V @ M[:3, :3].T + M[:3, 3], F


def evaluated_world_mesh(ob):
    """World vertices and triangles of ``ob`` as the depsgraph evaluates it now."""
    oe = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
    return world_mesh(oe, oe.matrix_world)


def mesh_object(name, verts, edges=(), faces=()):
    me = bpy.data.meshes.new(name)
    me.from_pydata(list(verts), list(edges), list(faces))
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def no_faces(name="Wire"):
    """A mesh with vertices and an edge but no face."""
    return mesh_object(name, [(0, 0, 0.5), (1, 0, 0.5)], [(0, 1)])


def ragged_groom(name, surf=None, n=60, seed=1, one_point=None):
    """A groom whose curves have 2 to 8 points each (ragged), roots on z = 0."""
    rng = np.random.default_rng(seed)
    sizes = rng.integers(2, 9, n)
    if one_point is not None:
        sizes[one_point] = 1
    hc = bpy.data.hair_curves.new(name)
    hc.add_curves(sizes.tolist())
    roots = np.c_[rng.uniform(-0.6, 0.6, (n, 2)), np.zeros(n)]
    lengths = rng.uniform(0.6, 1.2, n)
    P = [r + np.linspace(0, L, k)[:, None] * [0, 0, 1.0]
         for r, k, L in zip(roots, sizes, lengths, strict=True)]
    hc.position_data.foreach_set("vector", np.concatenate(P).astype(np.float32).ravel())
    hc.surface = surf
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def build_setup(fc, prefix, frames=(1, 6), nx=4, ny=4):
    """Hair + a sweeping box in the context scene, with a setup; returns (hair, box, out)."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    hair = make_hair(prefix + "Fur", nx=nx, ny=ny)
    box = sweep_box(prefix + "Box", -1.2, 1.2, frames)
    scene.frame_set(frames[0])
    out = fc.setup(hair, [box])
    return hair, box, out


def tris_world(ob, depsgraph=None):
    """World vertices (float64) and triangles of ``ob``'s evaluated mesh."""
    dg = depsgraph or bpy.context.evaluated_depsgraph_get()
    e = ob.evaluated_get(dg)
    me = e.data
    V = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", V)
    me.calc_loop_triangles()
    F = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("vertices", F)
    return oracle.transform(V.reshape(-1, 3), np.array(e.matrix_world)), F.reshape(-1, 3)


def resolved_crossing(out, colliders, status=None):
    """Curves whose status says resolved but that surely cross a collider."""
    P, offs = world(out), offsets_of(out)
    st = status_of(out) if status is None else status
    bad = np.zeros(len(offs) - 1, bool)
    for ob in colliders:
        V, F = tris_world(ob)
        margin = oracle.float32_margin(P, V)
        bad |= oracle.segments_hit_mesh(P, offs, V, F, abs_eps=margin)
    return np.flatnonzero(bad & np.isin(st, RESOLVED))


def crossing_unmarked(gout, colliders, unmarked=None):
    """Render curves of ``gout`` crossing a collider (the oracle, float32 margin) whose
    root is outside every closed collider and whose status does not say so.
    ``colliders``: objects (each taken as closed) or ``(object, closed)`` pairs;
    ``unmarked``: the statuses that do not say so (default: all but UNRESOLVED and
    INVALID)."""
    P, offs = world(gout), offsets_of(gout)
    st = status_of(gout)
    roots = P[offs[:-1]]
    crossing = np.zeros(len(offs) - 1, bool)
    inside = np.zeros(len(offs) - 1, bool)
    for c in colliders:
        ob, closed = c if isinstance(c, tuple) else (c, True)
        V, F = tris_world(ob)
        crossing |= oracle.segments_hit_mesh(P, offs, V, F, abs_eps=oracle.float32_margin(P, V))
        if closed:
            inside |= oracle.points_inside_closed_mesh(roots, V, F)
    says_not = (~np.isin(st, (UNRESOLVED, INVALID)) if unmarked is None
                else np.isin(st, unmarked))
    return np.flatnonzero(crossing & ~inside & says_not)


def check_frame(hair, out, colliders, exact_roots=True, lengths=True, status=""):
    """The per-frame invariants; returns the status codes. ``status``: the status
    message expected (None: not checked)."""
    s = hair.furcollide
    if status is not None:
        assert s.status_message == status, s.status_message
    offs = offsets_of(out)
    st = status_of(out)
    assert len(resolved_crossing(out, colliders, st)) == 0, resolved_crossing(out, colliders, st)
    src, res = oracle.transform(positions(hair), None), positions(out)
    if exact_roots:
        np.testing.assert_array_equal(res[offs[:-1]], positions(hair)[offs[:-1]])
    else:
        np.testing.assert_allclose(world(out)[offs[:-1]], world(hair)[offs[:-1]], atol=2e-5)
    if lengths:
        np.testing.assert_allclose(seg_lengths(res, offs), seg_lengths(src, offs),
                                   rtol=2e-4, atol=1e-6)
    return st


def bake_setup(hair):
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert hair.furcollide.is_baked


def bake_files_of(hair):
    d = bpy.path.abspath(hair.furcollide.bake_path)
    return sorted(f for f in os.listdir(d) if f.startswith("frame_")) if os.path.isdir(d) else []


def record(scene, out, frames):
    rec = {}
    for f in frames:
        scene.frame_set(f)
        rec[f] = (positions(out).copy(), status_of(out).copy())
    return rec


def assert_same_frames(rec, scene, out, frames=None, what=""):
    for f in frames or sorted(rec):
        scene.frame_set(f)
        np.testing.assert_array_equal(positions(out), rec[f][0], err_msg=f"{what} frame {f}")
        np.testing.assert_array_equal(status_of(out), rec[f][1], err_msg=f"{what} frame {f}")


def preroll_scene(fc):
    """A shot of frames 0..3 whose setup starts at frame -4 (a pre-roll so the fur
    has settled when the shot starts; Blender's scene range cannot go below 0, the
    setup's Frame Start can). The box sweeps from frame -4 to 3."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 0, 3
    hair = make_hair(nx=5, ny=5)
    box = sweep_box(frames=(-4, 3))
    scene.frame_set(0)
    out = fc.setup(hair, [box])
    s = hair.furcollide
    s.frame_start = -4
    assert (s.frame_start, s.frame_end) == (-4, 3)
    return scene, hair, box, out


def snapshot(ob):
    """What an artist groomed: positions and curve layout of ``ob``'s data."""
    return positions(ob).copy(), offsets_of(ob).copy()


def assert_unchanged(ob, snap, what=""):
    P, offs = snap
    np.testing.assert_array_equal(offsets_of(ob), offs, err_msg=f"{ob.name} layout {what}")
    np.testing.assert_array_equal(positions(ob), P, err_msg=f"{ob.name} positions {what}")


def sweep_setup(fc, frames=SHOT_FRAMES, nx=3, ny=3, collection=None):
    """Hair + sweeping box (optionally moved into a new collection) and a setup.
    Returns (hair, box, out)."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    hair = make_hair("Fur", nx=nx, ny=ny)
    box = sweep_box(frames=frames, linear_keys=False)
    if collection is not None:
        coll = bpy.data.collections.new(collection)
        scene.collection.children.link(coll)
        for o in (hair, box):
            coll.objects.link(o)
            scene.collection.objects.unlink(o)
    scene.frame_set(frames[0])
    out = fc.setup(hair, [box])
    return hair, box, out


def play_checked(scene, ob, frames=range(SHOT_FRAMES[0], SHOT_FRAMES[1] + 1), check_status=True):
    """Play ``frames``; the output's positions per frame. The status stays empty."""
    got = {}
    for f in frames:
        scene.frame_set(f)
        if check_status:
            assert ob.furcollide.status_message == "", (f, ob.furcollide.status_message)
        got[f] = positions(ob.furcollide.output).copy()
    return got


def reference_frames(fc, scene, hair):
    """Positions of every frame, played from the start; checks something collided."""
    ref = play_checked(scene, hair)
    assert any(not np.array_equal(p, positions(hair)) for p in ref.values()), "nothing collided"
    scene.frame_set(SHOT_FRAMES[0])
    return ref


def same_frames(got, ref):
    for f, p in got.items():
        np.testing.assert_array_equal(p, ref[f], err_msg=f"frame {f}")


def no_traceback(capsys):
    cap = capsys.readouterr()
    assert "Traceback" not in cap.out + cap.err, cap.out + cap.err
    return cap


def frames_on_disk(d):
    return sorted(f for f in os.listdir(d) if f.startswith("frame_")) if os.path.isdir(d) else []


def dense_groom(fc, nx=10, ny=10, uv=True):
    """Hair grid (roots on z = 0) attached to a surface, with surface UVs."""
    hair = fc.make_scene(nx=nx, ny=ny, animate=False)[0]
    surf = make_surface()
    hair.data.surface = surf
    hair.data.surface_uv_map = "UVMap"
    if uv:
        C = len(hair.data.curves)
        uvs = np.random.default_rng(3).random((C, 2)).astype(np.float32)
        hair.data.attributes.new("surface_uv_coordinate", "FLOAT2", "CURVE").data.foreach_set(
            "vector", uvs.ravel()
        )
    return hair, surf


def segments_in_box(P, offsets, center, half=HALF, shrink=1e-4):
    """Indices of curves with a segment meeting the axis-aligned box (slab test)."""
    lo = np.asarray(center, np.float64) - half + shrink
    hi = np.asarray(center, np.float64) + half - shrink
    P = np.asarray(P, np.float64)
    sizes = np.diff(offsets)
    curve = np.repeat(np.arange(len(sizes)), sizes - 1)
    s0 = np.arange(len(curve)) + curve  # first point of every segment
    a, d = P[s0], P[s0 + 1] - P[s0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - a) / d
        t2 = (hi - a) / d
    inside_slab = (a >= lo) & (a <= hi)  # d == 0 on an axis: inside that slab or never
    tmin = np.where(d == 0, np.where(inside_slab, -np.inf, np.inf), np.minimum(t1, t2))
    tmax = np.where(d == 0, np.where(inside_slab, np.inf, -np.inf), np.maximum(t1, t2))
    t0 = np.maximum(tmin.max(1), 0.0)
    t_1 = np.minimum(tmax.min(1), 1.0)
    hit = t0 <= t_1
    return np.unique(curve[hit])


def move_skin(surf, to, last):
    """Key ``surf`` from the origin at frame 1 to location ``to`` at frame ``last``
    (the skin moving under the hair), and go to frame 1."""
    surf.location = (0, 0, 0)
    surf.keyframe_insert("location", frame=1)
    surf.location = to
    surf.keyframe_insert("location", frame=last)
    bpy.context.scene.frame_set(1)


def groom_scene(fc):
    """Guides (5 x 5) and a dense groom (12 x 12) on one Surface, a box collider."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    surf = make_surface(half=1.2, n=6, uv=False)
    guides = make_hair("Guides", nx=5, ny=5, spacing=0.3)
    groom = make_hair("Groom", nx=12, ny=12, spacing=0.1)
    guides.data.surface = surf
    groom.data.surface = surf
    box = make_box(location=(-2.0, 0, 0.6))
    box.keyframe_insert("location", frame=1)
    box.location = (0.05, 0.05, 0.6)
    box.keyframe_insert("location", frame=6)
    scene.frame_set(1)
    out = fc.setup(guides, [box])
    guides.furcollide.frame_end = 8
    guides.furcollide.groom.groom = groom
    bpy.context.view_layer.objects.active = guides
    return guides, groom, box, out


# ------------------------------------------------- the fur pipeline through a shot
#: The frames of :func:`pipeline_scene`'s shot.
PIPELINE_FRAMES = range(1, 7)


def pipeline_scene(fc, skin="move"):
    """The groom scene as the README's pipeline: Fur Attach guides on a Surface that
    moves (``skin``: 'move' keyed location, 'shape' a shape key, 'armature' a bone),
    strong wind after collision held by the Region of Influence, the collider distance
    attribute, a render groom bound with its clearance pass. Returns
    (guides, groom, box, out, gout)."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    surf = guides.data.surface
    if skin == "move":
        surf.location = (0, 0, 0)
        surf.keyframe_insert("location", frame=1)
        surf.location = (0.1, 0.0, 0.05)
        surf.keyframe_insert("location", frame=6)
    elif skin == "shape":
        surf.shape_key_add(name="Basis")
        k = surf.shape_key_add(name="Bulge")
        co = np.empty(len(k.data) * 3, np.float32)
        k.data.foreach_get("co", co)
        co = co.reshape(-1, 3)
        co[:, 2] += 0.15 * np.exp(-(co[:, 0] ** 2 + co[:, 1] ** 2))
        k.data.foreach_set("co", co.ravel())
        k.value = 0.0
        k.keyframe_insert("value", frame=1)
        k.value = 1.0
        k.keyframe_insert("value", frame=6)
    elif skin == "armature":
        arm = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
        scene.collection.objects.link(arm)
        activate(arm)
        bpy.ops.object.mode_set(mode="EDIT")
        b = arm.data.edit_bones.new("Bone")
        b.head, b.tail = (0, 0, 0), (0, 0, 0.5)
        bpy.ops.object.mode_set(mode="OBJECT")
        vg = surf.vertex_groups.new(name="Bone")
        vg.add(list(range(len(surf.data.vertices))), 1.0, "REPLACE")
        mod = surf.modifiers.new("Armature", "ARMATURE")
        mod.object = arm
        pb = arm.pose.bones["Bone"]
        pb.rotation_mode = "XYZ"
        pb.rotation_euler = (0, 0, 0)
        pb.keyframe_insert("rotation_euler", frame=1)
        pb.rotation_euler = (0.15, 0, 0.3)
        pb.keyframe_insert("rotation_euler", frame=6)
    scene.frame_set(1)
    return wind_and_bind(guides, groom, box, out)


def wind_and_bind(guides, groom, box, out):
    """Wind and the collider distance on, Fur Attach and the groom bound: the shot's
    (guides, groom, box, output, groom output)."""
    s = guides.furcollide
    m = s.motion
    m.use_wind, m.wind_strength, m.wind_turbulence = True, 0.3, 1.0
    m.write_collider_distance, m.distance_max = True, 0.3
    activate(guides)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    return guides, groom, box, out, s.groom.output


def roots_off_surface(ob, surf, tol=1e-4):
    """Curves of hair object ``ob`` whose root is farther than ``tol`` from ``surf``'s
    evaluated mesh (world space)."""
    P, offs = world(ob), offsets_of(ob)
    V, F = tris_world(surf)
    d = pipe_oracle.point_mesh_distance(P[offs[:-1]].astype(np.float64), V, F)
    return np.flatnonzero(d > tol)


def check_pipeline_frame(guides, groom, box, colliders=None, what="", guides_clear=True,
                         groom_clear=True):
    """The README's per-frame promises for the whole pipeline. ``guides_clear``: the
    Region of Influence is on (off, wind after collision may push guides into a
    collider); ``groom_clear``: the Clearance Pass is on."""
    s = guides.furcollide
    colliders = [box] if colliders is None else colliders
    out, gout = s.output, s.groom.output
    surf = guides.data.surface
    if s.status_message == "":  # (a held frame says so: the guides are the last result)
        if guides_clear:
            assert len(resolved_crossing(out, colliders)) == 0, what
        assert len(roots_off_surface(out, surf)) == 0, what
    if groom_clear:
        bad = crossing_unmarked(gout, colliders)
        assert len(bad) == 0, (what, bad)
    assert len(roots_off_surface(gout, surf)) == 0, (what, roots_off_surface(gout, surf))
    ok = ~np.isin(status_of(gout), (INVALID,))
    goffs = offsets_of(gout)
    ref = seg_lengths(positions(groom), goffs)
    got = seg_lengths(positions(gout), goffs)
    per_seg_ok = np.repeat(ok, np.diff(goffs) - 1)
    np.testing.assert_allclose(got[per_seg_ok], ref[per_seg_ok], rtol=1e-3, atol=1e-5,
                               err_msg=what)


def distance_attribute(ob):
    """The output's ``furcollide_collider_distance`` (P,) float32, or None."""
    a = ob.data.attributes.get("furcollide_collider_distance")
    if a is None:
        return None
    d = np.empty(len(a.data), np.float32)
    a.data.foreach_get("value", d)
    return d


def pipeline_frame(guides):
    """What a pipeline setup on ``guides`` shows: :func:`pipeline_state` and the output's
    collider distance attribute."""
    s = guides.furcollide
    return (world(s.output).copy(), status_of(s.output).copy(),
            world(s.groom.output).copy(), status_of(s.groom.output).copy(),
            distance_attribute(s.output))


def same_pipeline_frame(a, b, what=""):
    """Two :func:`pipeline_frame` (or :func:`pipeline_state`) records are equal, bit for bit."""
    names = ("guides", "guide status", "groom", "groom status", "collider distance")
    for x, y, name in zip(a, b, names[:len(a)], strict=True):
        np.testing.assert_array_equal(x, y, err_msg=f"{what} {name}")


def play_pipeline(guides, groom, box, frames=PIPELINE_FRAMES, colliders=None, check=True, **kw):
    """Play ``frames`` (checked with :func:`check_pipeline_frame`, ``kw`` passed on):
    ``{frame: pipeline_frame(guides)}``."""
    scene = bpy.context.scene
    rec = {}
    for f in frames:
        scene.frame_set(f)
        if check:
            check_pipeline_frame(guides, groom, box, colliders, what=f"frame {f}", **kw)
        rec[f] = pipeline_frame(guides)
    return rec


def make_wall(name="Wall"):
    """A thin wall (a closed box) across the render curves between guides only: at
    x = 0.05 (the guides are at multiples of 0.3, the render curves of 0.1 + 0.05)."""
    w = make_box(name, size=1.0, location=(0.0, 0.0, 0.0))
    w.scale = (0.02, 0.6, 0.6)
    w.location = (0.05, 0.0, 0.7)
    return w


def wall_collider(guides, strength):
    """:func:`make_wall` in its own collection "Props" (so it can be excluded), with a
    Displace modifier of ``strength`` (so it can be switched off), added as a collider
    of ``guides``."""
    scene = bpy.context.scene
    coll = bpy.data.collections.new("Props")
    scene.collection.children.link(coll)
    wall = make_wall()
    coll.objects.link(wall)
    scene.collection.objects.unlink(wall)
    wall.modifiers.new("Push", "DISPLACE").strength = strength
    activate(guides, wall)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    return wall


#: The ways an artist switches a collider off (:func:`toggle_collider`); hidden or
#: excluded from the view layer, a collider is still in the scene and keeps colliding.
COLLIDER_CHANGES = ["hide_viewport", "hide_set", "exclude", "modifier_off", "disabled"]
KEEPS_COLLIDING = ("hide_viewport", "hide_set", "exclude")


def toggle_collider(kind, ob, guides, off):
    """Switch collider ``ob`` off (``off``) or on again, as an artist does."""
    scene = bpy.context.scene
    if kind == "hide_viewport":
        ob.hide_viewport = off
    elif kind == "hide_set":
        ob.hide_set(off)
    elif kind == "exclude":
        lc = bpy.context.view_layer.layer_collection.children[ob.users_collection[0].name]
        lc.exclude = off
    elif kind == "modifier_off":
        ob.modifiers["Push"].show_viewport = not off
    elif kind == "disabled":
        for c in guides.furcollide.colliders:
            if c.object == ob:
                c.enabled = not off
    scene.frame_set(scene.frame_current)


# ------------------------------------------------------------ the demo's scene
#: The demo's "fur" settings (scripts/demo.py SETTINGS["fur"]), in the core's names and
#: units (:func:`set_core`).
DEMO_FUR = dict(
    mode="bend",
    rotation_precision=0.5,
    collision_offset=0.008,
    recovery_rate=0.3,
    pinch_resolution="growth_surface",
)
#: What a demo setup on the fur says on a quiet frame: nothing, or the cloth's note.
CLOTH_NOTE = "Colliders: no pinch detection for 'Cloth': open mesh (112 open edges)"
QUIET = ("", CLOTH_NOTE)
#: Curves of fur on the demo's body at real size: enough that the cloth and the pusher
#: put more than core.tolerances.SPLIT_MIN_CURVES (4096) curves into a phase, so a step solves
#: its phases in two halves on two threads (the tests that need it check it).
REAL_SIZE = 20000
#: The real-size shot: the pusher reaches the fur at ~8, the cloth lands at 16, the pinch
#: from 19.
REAL_LAST = 24
REAL_FRAMES = range(1, REAL_LAST + 1)
#: Wind after collision with the Region of Influence and the collider distance, as the
#: demo's pipeline has them (scripts/demo.py pipeline_setup).
DEMO_PIPELINE_MOTION = dict(
    use_wind=True, wind_stage="OUTPUT", wind_strength=0.04, wind_direction=(1.0, 0.4, 0.0),
    wind_turbulence=0.8, wind_frequency=0.7, wind_scale=0.4, use_region_of_influence=True,
    write_collider_distance=True, distance_max=0.1)


def demo_build(fur_count, grass_count=50):
    """The demo's scene (``scripts/demo_scene.py``: a turning body with fur, a pusher and a
    cloth; grass under a rolling ball), built in an empty file; returns its handles."""
    scripts = str(Path(__file__).resolve().parents[2] / "scripts")
    if scripts not in sys.path:
        sys.path.insert(0, scripts)
    import demo_scene

    return demo_scene.build(fur_count=fur_count, grass_count=grass_count)


def demo_fur(n_fur, last, mode="bend", grass=50, scene_end=None, polygons=False, **settings):
    """The demo with a FurCollide setup on its body fur (pusher and cloth), the demo's
    settings (``mode`` and ``settings`` on top), Frame Range 1..``last``; the scene's range
    the same, or 1..``scene_end``; ``polygons``: its fur Poly (no spline margin). Returns
    (demo, fur, out)."""
    demo = demo_build(n_fur, grass)
    if polygons:
        poly(demo.fur)
    activate(demo.fur, demo.pusher, demo.cloth)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    s = demo.fur.furcollide
    set_core(s, **dict(DEMO_FUR, mode=mode, **settings))
    s.frame_start, s.frame_end = 1, last
    if scene_end is None:
        demo.scene.frame_start, demo.scene.frame_end = 1, last
    else:
        demo.scene.frame_end = scene_end
    demo.scene.frame_set(1)
    return demo, demo.fur, s.output


def real_size_fur(mode="bend", threads=0, n_fur=REAL_SIZE, **settings):
    """:func:`demo_fur` at real size over :data:`REAL_FRAMES` (the scene's range four
    frames longer), with ``threads``."""
    return demo_fur(n_fur, REAL_LAST, mode, scene_end=REAL_LAST + 4, threads=threads,
                    **settings)


def demo_pipeline(n_fur, last, motion, fraction=0.25, scene_range=True,
                  collider_offsets=False):
    """The demo's pipeline (scripts/demo.py pipeline_setup) on ``n_fur`` curves: Fur
    Sampler (``fraction``), FurCollide on the guides with the demo's settings over
    1..``last`` (the scene's range too with ``scene_range``; each collider with the
    setup's Collision Offset as its own with ``collider_offsets``), Fur Attach, the
    ``motion`` settings, the fur bound as the render groom with the clearance pass.
    Returns (demo, guides, out, gout)."""
    demo = demo_build(n_fur)
    scene = demo.scene
    if scene_range:
        scene.frame_start, scene.frame_end = 1, last
    scene.frame_set(1)
    activate(demo.fur)
    assert bpy.ops.furcollide.fur_sampler(fraction=fraction, seed=3) == {"FINISHED"}
    guides = bpy.context.view_layer.objects.active
    activate(guides, demo.pusher, demo.cloth)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    s = guides.furcollide
    set_core(s, **DEMO_FUR)
    s.frame_start, s.frame_end = 1, last
    if collider_offsets:
        for c in s.colliders:
            c.use_offset, c.collision_offset = True, DEMO_FUR["collision_offset"]
    activate(guides)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    m = s.motion
    for k, v in motion.items():
        setattr(m, k, v)
    s.groom.groom = demo.fur
    s.groom.use_clearance = True
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    return demo, guides, s.output, s.groom.output


def real_size_pipeline(n_fur=REAL_SIZE, fraction=0.25):
    """:func:`demo_pipeline` as the demo makes it, with ``n_fur`` render curves, over
    :data:`REAL_FRAMES`."""
    return demo_pipeline(n_fur, REAL_LAST, DEMO_PIPELINE_MOTION, fraction,
                         scene_range=False, collider_offsets=True)


def world_meshes(objects, depsgraph=None):
    """:func:`tris_world` of every object: [(V, F), ...]."""
    return [tris_world(o, depsgraph) for o in objects]


def curves_crossing(P, offs, meshes, st=None, keep=RESOLVED):
    """Curves whose status is in ``keep`` (all when ``st`` is None) that surely cross
    one of ``meshes`` ((V, F) in world space): ``oracle.curves_crossing`` (culled, with
    the float32 margin)."""
    return oracle.curves_crossing(P, offs, meshes, None if st is None else np.isin(st, keep))


def check_demo_frame(demo, hair, out, what="", lengths=True):
    """README's per-frame promises for a plain demo setup: no resolved curve crosses the
    pusher or the cloth, roots exactly the source's, lengths kept (no Shrink). Returns
    the statuses."""
    offs = offsets_of(out)
    st = status_of(out)
    bad = curves_crossing(world(out), offs, world_meshes([demo.pusher, demo.cloth]), st)
    assert len(bad) == 0, (what, len(bad), bad[:10], st[bad[:10]])
    src, res = positions(hair), positions(out)
    np.testing.assert_array_equal(res[offs[:-1]], src[offs[:-1]], err_msg=f"{what}: roots")
    if lengths:
        ok = np.repeat(st != INVALID, np.diff(offs) - 1)
        np.testing.assert_allclose(seg_lengths(res, offs)[ok], seg_lengths(src, offs)[ok],
                                   rtol=2e-4, atol=1e-6, err_msg=f"{what}: lengths")
    return st


def demo_checks(demo, hair, out):
    """:func:`check_demo_frame` as a ``check(frame)`` for :func:`play_demo`."""
    return lambda f: check_demo_frame(demo, hair, out, what=f"frame {f}")


def frame_of(out):
    """What ``out`` shows: (positions, statuses), copies."""
    return positions(out).copy(), status_of(out).copy()


def same_frame(a, b, what=""):
    """Two :func:`frame_of` records are equal, bit for bit."""
    np.testing.assert_array_equal(a[0], b[0], err_msg=f"{what}: positions")
    np.testing.assert_array_equal(a[1], b[1], err_msg=f"{what}: status")


def play_demo(scene, hair, out, frames=REAL_FRAMES, check=None):
    """frame_set every frame ({frame: :func:`frame_of`}); the setup says nothing but the
    cloth's note and is never outdated; ``check(frame)`` after each."""
    rec = {}
    for f in frames:
        scene.frame_set(f)
        assert hair.furcollide.status_message in QUIET, (f, hair.furcollide.status_message)
        assert not hair.furcollide.is_outdated, f
        if check is not None:
            check(f)
        rec[f] = frame_of(out)
    return rec


def reset_cache(hair):
    """Press Reset Cache on ``hair``'s setup."""
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}


def groom_snapshot(ob):
    """What the artist groomed: positions, layout, every attribute's values and the
    object's matrix."""
    d = ob.data
    attrs = {}
    for a in d.attributes:
        if a.name.startswith("."):
            continue
        n = len(a.data)
        key = ("vector" if a.data_type in ("FLOAT_VECTOR", "FLOAT2") else
               "color" if a.data_type in ("FLOAT_COLOR", "BYTE_COLOR") else "value")
        width = {"FLOAT_VECTOR": 3, "FLOAT2": 2, "FLOAT_COLOR": 4, "BYTE_COLOR": 4}.get(
            a.data_type, 1)
        buf = np.empty(n * width, np.float64 if key != "value" or a.data_type == "FLOAT"
                       else np.int64)
        if a.data_type == "BOOLEAN":
            buf = np.empty(n, bool)
        a.data.foreach_get(key, buf)
        attrs[(a.name, a.domain, a.data_type)] = buf
    return positions(ob).copy(), offsets_of(ob).copy(), attrs, np.array(ob.matrix_world)


def assert_groom_unchanged(ob, snap, what=""):
    """``ob`` is as :func:`groom_snapshot` recorded it, bit for bit."""
    now = groom_snapshot(ob)
    np.testing.assert_array_equal(now[0], snap[0], err_msg=f"{ob.name} positions {what}")
    np.testing.assert_array_equal(now[1], snap[1], err_msg=f"{ob.name} layout {what}")
    assert now[2].keys() == snap[2].keys(), (what, now[2].keys() ^ snap[2].keys())
    for k in snap[2]:
        np.testing.assert_array_equal(now[2][k], snap[2][k], err_msg=f"{ob.name} {k} {what}")
    np.testing.assert_array_equal(now[3], snap[3], err_msg=f"{ob.name} matrix {what}")


# ------------------------------------------------------ renders with motion blur
def cycles_motion_blur(scene, tmp_path, position="CENTER"):
    """Cycles (1 sample, 16 px) with motion blur at shutter ``position``, Lock Interface
    on, frames written to ``tmp_path``."""
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.device = "CPU"
    scene.render.resolution_x = scene.render.resolution_y = 16
    scene.render.use_lock_interface = True
    scene.render.use_motion_blur = True
    scene.render.motion_blur_position = position
    scene.render.filepath = str(tmp_path / "mb_####")


def render_recording(hair, record):
    """Render the animation; [((frame, subframe), record(depsgraph), status message,
    outdated)] for every RENDER-depsgraph frame change, after FurCollide's handler."""
    seen = []

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            s = hair.furcollide
            seen.append(
                (
                    (sc.frame_current, round(sc.frame_subframe, 3)),
                    record(depsgraph),
                    s.status_message,
                    s.is_outdated,
                )
            )

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    return seen


# ------------------------------------------------------- Blender's hair node assets
#: The inputs of Blender's bundled hair node groups (``procedural_hair_node_assets.blend``:
#: Generate, Interpolate, Clump, Frizz Hair Curves) the tests set, by what they mean:
#: ``(socket name, socket type)`` candidates, matched per version in this one place.
#: 4.2-5.0 take the Surface as an Object input and its UV map as an attribute input;
#: 5.2's Interpolate has neither and reads the hair data's own ``surface`` and
#: ``surface_uv_map`` (:func:`add_hair_asset` sets those on every version). The switch
#: that scatters on the Surface's rest position is "Surface Rest Position" up to 5.0,
#: "Resting Surface" in 5.2 (the add-on's ``operators/compat.py`` says the same).
HAIR_INPUTS = {
    "surface": (("Surface", "NodeSocketObject"),),
    "uv_map": (("Surface UV Map", "NodeSocketVector"),),
    "rest": (("Surface Rest Position", "NodeSocketBool"), ("Resting Surface", "NodeSocketBool")),
    "density": (("Density", "NodeSocketFloat"),),
    "length": (("Hair Length", "NodeSocketFloat"),),
    "points": (("Control Points", "NodeSocketInt"),),
    "seed": (("Seed", "NodeSocketInt"),),
    "guides": (("Interpolation Guides", "NodeSocketInt"),),
    "factor": (("Factor", "NodeSocketFloat"),),
    "clump_distance": (("Guide Distance", "NodeSocketFloat"),),
    "frizz_distance": (("Distance", "NodeSocketFloat"),),
}
#: Inputs a version may not have (the hair data's surface stands for them).
_HAIR_OPTIONAL = {"surface", "uv_map"}


def hair_asset_group(name):
    """Blender's bundled hair node group ``name`` (appended once per file)."""
    for ng in bpy.data.node_groups:
        if ng.get("test_hair_asset") == name:
            return ng
    compat = sys.modules[ADDON + ".operators.blender.compat"]
    path = compat.find_datafile(compat.hair_asset_candidates())
    assert path, "Blender's hair node assets are missing from this Blender"
    with bpy.data.libraries.load(path, link=False) as (src, dst):
        assert name in src.node_groups, (name, path)
        dst.node_groups = [name]
    ng = dst.node_groups[0]
    ng["test_hair_asset"] = name
    return ng


def add_hair_asset(ob, group, at=None, **inputs):
    """A Geometry Nodes modifier running Blender's hair node group ``group`` on hair
    ``ob`` (at stack position ``at``, default last), its ``inputs`` set by the keys of
    :data:`HAIR_INPUTS`. ``surface`` and ``uv_map`` also go to the hair data."""
    compat = sys.modules[ADDON + ".operators.blender.compat"]
    mod = ob.modifiers.new(group, "NODES")
    mod.node_group = hair_asset_group(group)
    ids = compat.group_inputs(mod.node_group)
    for key, value in inputs.items():
        if key == "surface":
            ob.data.surface = value
        elif key == "uv_map":
            ob.data.surface_uv_map = value
        ident = next((ids[c] for c in HAIR_INPUTS[key] if c in ids), None)
        if ident is None:
            assert key in _HAIR_OPTIONAL, f"'{group}' of Blender {bpy.app.version_string} " \
                f"has no input for {key!r}: {sorted(ids)}"
        elif key == "uv_map":
            compat.set_modifier_input_attribute(mod, ident, value)
        else:
            compat.set_modifier_input(mod, ident, value)
    if at is not None:
        compat.move_modifier(ob, mod, at)
    return mod


def evaluated_points(ob, depsgraph=None):
    """(world points (P, 3) float64, offsets (C+1,)) of ``ob``'s evaluated control
    points (after its modifiers; the curves Blender draws through them:
    :func:`evaluated_curves`)."""
    dg = depsgraph or bpy.context.evaluated_depsgraph_get()
    oe = ob.evaluated_get(dg)
    d = oe.data
    offs = np.zeros(len(d.curves) + 1, np.int32)
    if len(d.curves):
        d.curve_offset_data.foreach_get("value", offs)
    P = np.empty(len(d.points) * 3, np.float32)
    d.position_data.foreach_get("vector", P)
    return oracle.transform(P.reshape(-1, 3), np.array(oe.matrix_world)), offs


# ------------------------------------------------------------- evaluated curves
def _probe_group(ob):
    """Geometry nodes reading ``ob``'s evaluated geometry in world space (Object Info,
    Relative) and realizing the curves Blender draws (Resample Curve, Evaluated)."""
    ng = bpy.data.node_groups.new(".furcollide_probe", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    info = ng.nodes.new("GeometryNodeObjectInfo")
    info.transform_space = "RELATIVE"
    info.inputs["Object"].default_value = ob
    resample = ng.nodes.new("GeometryNodeResampleCurve")
    if "Mode" in resample.inputs:  # (a menu socket in newer Blenders)
        resample.inputs["Mode"].default_value = "Evaluated"
    else:
        resample.mode = "EVALUATED"
    out = ng.nodes.new("NodeGroupOutput")
    ng.links.new(info.outputs["Geometry"], resample.inputs["Curve"])
    ng.links.new(resample.outputs[0], out.inputs[0])
    return ng


def evaluated_curves(ob):
    """The curves Blender draws for hair object ``ob`` now (its modifiers included):
    world points (P, 3) float64 and offsets (C+1,). Every Catmull-Rom, Bezier and NURBS
    curve comes as its evaluated points, read through a temporary probe object (a
    Resample Curve in Evaluated mode on ``ob``'s evaluated geometry)."""
    ng = _probe_group(ob)
    data = bpy.data.hair_curves.new(".furcollide_probe")
    probe = bpy.data.objects.new(".furcollide_probe", data)
    bpy.context.scene.collection.objects.link(probe)
    try:
        mod = probe.modifiers.new("probe", "NODES")
        mod.node_group = ng
        e = probe.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
        P = np.empty(len(e.points) * 3, np.float32)
        if len(P):
            e.position_data.foreach_get("vector", P)
        offs = np.zeros(len(e.curves) + 1, np.int32)
        if len(e.curves):
            e.curve_offset_data.foreach_get("value", offs)
    finally:
        bpy.data.objects.remove(probe)
        bpy.data.hair_curves.remove(data)
        bpy.data.node_groups.remove(ng)
    return P.reshape(-1, 3).astype(np.float64), offs


def evaluated_crossing(out, colliders, status=None):
    """Curves whose status says resolved but whose *evaluated* curve (what Blender
    draws: :func:`evaluated_curves`) surely crosses a collider's evaluated mesh."""
    P, offs = evaluated_curves(out)
    st = status_of(out) if status is None else status
    assert len(offs) == len(st) + 1, "the evaluated output lost or gained curves"
    bad = np.zeros(len(offs) - 1, bool)
    for ob in colliders:
        V, F = evaluated_world_mesh(ob)
        bad |= oracle.segments_hit_mesh(P, offs, V, F, abs_eps=oracle.float32_margin(P, V))
    return np.flatnonzero(bad & np.isin(st, RESOLVED))


def drawn_inside(ob, colliders, status=None):
    """(points, curves): how many points of the curves Blender draws for ``ob``
    (:func:`evaluated_curves`) of resolved curves lie inside the closed evaluated
    meshes of ``colliders``, and in how many curves."""
    P, offs = evaluated_curves(ob)
    st = status_of(ob) if status is None else status
    assert len(offs) == len(st) + 1, "the evaluated curves lost or gained curves"
    inside = np.zeros(len(P), bool)
    for col in colliders:
        V, F = evaluated_world_mesh(col)
        box = ((P >= V.min(0)) & (P <= V.max(0))).all(1)  # (only these can be inside)
        inside[np.flatnonzero(box)[oracle.points_inside_closed_mesh(P[box], V, F)]] = True
    curve = np.repeat(np.arange(len(offs) - 1), np.diff(offs))
    inside &= np.isin(st, RESOLVED)[curve]
    return int(inside.sum()), len(np.unique(curve[inside]))


CURVE_TYPES = ("CATMULL_ROM", "POLY", "BEZIER", "NURBS")


def set_curve_type(ob, kind, indices=None):
    """Give the curves ``indices`` (all by default) of hair object ``ob`` the type
    ``kind`` ('CATMULL_ROM', 'POLY', 'BEZIER' or 'NURBS'). Returns ``ob``."""
    hc = ob.data
    C = len(hc.curves)
    idx = np.arange(C) if indices is None else np.asarray(indices)
    if hasattr(hc, "set_types"):
        hc.set_types(type=kind, indices=idx.tolist())
    else:  # 4.2: as an attribute; add_curves([]) has the types counted again
        attr = hc.attributes.get("curve_type") or hc.attributes.new("curve_type", "INT8",
                                                                     "CURVE")
        types = np.zeros(C, np.int32)
        attr.data.foreach_get("value", types)
        types[idx] = CURVE_TYPES.index(kind)
        attr.data.foreach_set("value", types)
        hc.add_curves([])
    return ob


def poly(ob):
    """Make every curve of hair object ``ob`` a Poly curve (Blender draws its control
    polygon): the solve then needs no margin for a spline (``core.splines.DrawnMargin``),
    for tests whose expectations are the polygon's exact clearance. Returns ``ob``."""
    return set_curve_type(ob, "POLY")


def property_groups():
    """The RNA of every FurCollide property group: a setup's, its colliders', motion,
    render groom and children, and the scene's pipeline settings."""
    s = bpy.types.Object.bl_rna.properties["furcollide"].fixed_type
    return [s, *(s.properties[n].fixed_type for n in ("colliders", "motion", "groom",
                                                      "children")),
            bpy.types.Scene.bl_rna.properties["furcollide_pipeline"].fixed_type]
