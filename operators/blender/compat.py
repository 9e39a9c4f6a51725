"""Blender-version differences, in one place.

FurCollide supports Blender 4.2 LTS, 4.5 LTS, 5.0 and 5.2 LTS (README, *Platforms*).
Where their Python APIs or bundled data differ, the rest of the add-on asks this module
instead of testing versions or attributes itself. Each difference below names the
versions it was seen on (the test matrix runs every test on each of them).

* **Hair node assets** (``procedural_hair_node_assets.blend``): 4.2-4.5 keep it in
  ``datafiles/assets/geometry_nodes/``, 5.0+ in ``datafiles/assets/nodes/``.
* **"Interpolate Hair Curves" interface**: 4.2-5.0 take the Surface as an Object input
  (``Surface``, ``NodeSocketObject``) and its UV map as an attribute input (``Surface UV
  Map``); 5.0 adds a ``Surface Input Type`` menu. 5.2 has no Surface input at all: the
  group reads the hair data-block's own ``surface`` and ``surface_uv_map``. Sockets are
  matched by name and type (:func:`interpolate_sockets`), never by position.
* **Rest position of the Surface**: the group's switch to place children on the
  Surface's ``frame.topology`` (not its deformed shape) is "Surface Rest Position" in
  4.2-5.0 and "Resting Surface" (on by default) in 5.2; every version reads the
  attribute Blender adds with ``Object.add_rest_position_attribute``.
* **Blend-relative path properties**: 4.5+ accept ``options={'PATH_SUPPORTS_BLEND_RELATIVE'}``
  on a path property (without it 5.0 warns when a script sets a ``//`` path), 4.2 refuses
  the option at registration (:data:`BLEND_RELATIVE_PATH`).
* **Built-in curve attributes created from Python**: 4.2 corrupts its memory creating
  ``nurbs_order`` with ``attributes.new`` (a crash at a later allocation, from about
  100 curves on); 4.5 and 5.0 do not (:data:`UNSAFE_NEW_CURVE_ATTRIBUTES`). 4.2 also
  has no ``Curves.set_types``: curve types are written as the ``curve_type``
  attribute there, then counted again by ``add_curves([])`` (``bridge.tag_changed``).
* **Geometry-nodes modifier inputs**: up to 5.0 they are ID properties
  (``mod["Input_15"] = 10``, ``mod["Input_18_use_attribute"]``); 5.2 replaced them with
  ``mod.properties.inputs.Input_15.value`` / ``.type`` / ``.attribute_name``
  (:func:`set_modifier_input`, :func:`modifier_input`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import bpy

#: The running Blender, as a tuple (major, minor, patch).
VERSION: tuple = tuple(bpy.app.version)

#: Options of a path property that takes ``//`` (blend-relative) paths: 4.5+ only.
BLEND_RELATIVE_PATH: set = (
    {"PATH_SUPPORTS_BLEND_RELATIVE"} if VERSION >= (4, 5, 0) else set()
)

#: Built-in curve attributes that ``attributes.new`` cannot create on this Blender
#: without corrupting its memory (4.2: ``nurbs_order``): the output draws them at
#: Blender's default (order 4) instead.
UNSAFE_NEW_CURVE_ATTRIBUTES: frozenset = (
    frozenset({"nurbs_order"}) if VERSION < (4, 5, 0) else frozenset()
)

#: Blender's bundled hair node-group assets (file name).
HAIR_ASSET_FILE = "procedural_hair_node_assets.blend"

#: Folders (relative to Blender's ``datafiles``) that hold the hair assets, newest
#: layout first: 5.0+ ``assets/nodes``, 4.2-4.5 ``assets/geometry_nodes``.
HAIR_ASSET_DIRS = (("assets", "nodes"), ("assets", "geometry_nodes"))

#: Name of the node group Children from Guides uses (the same on every version).
INTERPOLATE_GROUP = "Interpolate Hair Curves"


def hair_asset_candidates(version: tuple = VERSION) -> list[str]:
    """Relative paths (under ``datafiles``) where ``version`` keeps the hair assets,
    the expected one first."""
    dirs = list(HAIR_ASSET_DIRS)
    if tuple(version) < (5, 0, 0):
        dirs.reverse()
    return [os.path.join(*d, HAIR_ASSET_FILE) for d in dirs]


def datafiles_roots() -> list[str]:
    """Blender's ``datafiles`` folders (bundled first), existing ones only."""
    roots = []
    try:
        roots.append(bpy.utils.system_resource("DATAFILES"))
    except (ValueError, TypeError):
        pass
    for kind in ("LOCAL", "SYSTEM"):
        try:
            roots.append(os.path.join(bpy.utils.resource_path(kind), "datafiles"))
        except (ValueError, TypeError):
            pass
    out = []
    for r in roots:
        if r and os.path.isdir(r) and r not in out:
            out.append(r)
    return out


def find_datafile(relatives) -> str:
    """First existing ``<datafiles>/<relative>`` ('' when none exists)."""
    for root in datafiles_roots():
        for rel in relatives:
            path = os.path.join(root, rel)
            if os.path.isfile(path):
                return path
    return ""


@dataclass(frozen=True)
class InterpolateSockets:
    """Input identifiers of "Interpolate Hair Curves" on this Blender (None: absent).

    ``surface_object`` is None on 5.2+, whose group takes the Surface (and its UV map)
    from the hair data-block (``Curves.surface`` / ``surface_uv_map``).
    """

    surface_object: str | None
    surface_input_type: str | None
    surface_uv_map: str | None
    density: str | None
    guides: str | None
    #: The switch placing the children on the Surface's rest position (all versions).
    rest_position: str | None = None

    @property
    def surface_from_hair_data(self) -> bool:
        return self.surface_object is None


def group_inputs(ng) -> dict:
    """``{(name, socket_type): identifier}`` of a node group's input sockets."""
    out = {}
    for item in ng.interface.items_tree:
        if item.item_type == "SOCKET" and item.in_out == "INPUT":
            out.setdefault((item.name, item.socket_type), item.identifier)
    return out


def interpolate_sockets(ng) -> InterpolateSockets:
    """Match the inputs of this Blender's "Interpolate Hair Curves" by name and type.

    Raises
    ------
    ValueError
        The group has neither a Surface object input (4.2-5.0) nor the 5.2 layout
        (no Surface input, a ``Resting Surface`` switch): an interface this add-on
        does not know. The message names the group and its inputs.
    """
    ids = group_inputs(ng)
    names = {name for name, _ in ids}
    sockets = InterpolateSockets(
        surface_object=ids.get(("Surface", "NodeSocketObject")),
        surface_input_type=ids.get(("Surface Input Type", "NodeSocketMenu")),
        surface_uv_map=ids.get(("Surface UV Map", "NodeSocketVector")),
        density=ids.get(("Density", "NodeSocketFloat")),
        guides=ids.get(("Interpolation Guides", "NodeSocketInt")),
        rest_position=ids.get(("Surface Rest Position", "NodeSocketBool"))
        or ids.get(("Resting Surface", "NodeSocketBool")),
    )
    known_52 = "Surface" not in names and "Resting Surface" in names
    if sockets.surface_object is None and not known_52:
        listed = ", ".join(f"{n} ({t.removeprefix('NodeSocket')})" for n, t in ids)
        raise ValueError(
            f"'{ng.name}' of Blender {bpy.app.version_string} has an interface FurCollide "
            f"does not know (no Surface object input; inputs: {listed})"
        )
    return sockets


def _modifier_uses_idprops(mod) -> bool:
    # Up to 5.0 a nodes modifier's inputs are ID properties; 5.2 has ``properties``.
    return getattr(mod, "properties", None) is None


def set_modifier_input(mod, identifier: str, value) -> None:
    """Set the value of input ``identifier`` of a geometry-nodes modifier."""
    if _modifier_uses_idprops(mod):
        mod[identifier] = value
    else:
        getattr(mod.properties.inputs, identifier).value = value


def modifier_input(mod, identifier: str):
    """The value of input ``identifier`` of a geometry-nodes modifier."""
    if _modifier_uses_idprops(mod):
        return mod[identifier]
    return getattr(mod.properties.inputs, identifier).value


def set_modifier_input_attribute(mod, identifier: str, name: str) -> bool:
    """Feed input ``identifier`` from the named attribute ``name``; False when that
    input takes no attribute."""
    if _modifier_uses_idprops(mod):
        if f"{identifier}_attribute_name" not in mod.keys():
            return False
        mod[f"{identifier}_use_attribute"] = True
        mod[f"{identifier}_attribute_name"] = name
        return True
    inp = getattr(mod.properties.inputs, identifier, None)
    if inp is None or not hasattr(inp, "attribute_name"):
        return False
    inp.type = "ATTRIBUTE"
    inp.attribute_name = name
    return True


def modifier_input_attribute(mod, identifier: str) -> str:
    """Name of the attribute feeding input ``identifier`` ('' when it takes a value)."""
    if _modifier_uses_idprops(mod):
        if not mod.get(f"{identifier}_use_attribute"):
            return ""
        return mod.get(f"{identifier}_attribute_name", "")
    inp = getattr(mod.properties.inputs, identifier, None)
    if inp is None or getattr(inp, "type", "VALUE") != "ATTRIBUTE":
        return ""
    return inp.attribute_name


def move_modifier(ob, mod, index: int) -> None:
    """Put modifier ``mod`` of ``ob`` at position ``index`` of its stack
    (``ObjectModifiers.move``, present on every supported version)."""
    have = list(ob.modifiers).index(mod)
    if have != index:
        ob.modifiers.move(have, index)


def uv_map_names(mesh) -> list[str]:
    """Names of a mesh's UV maps (the same API on every supported version)."""
    return [uv.name for uv in mesh.uv_layers]


def emptied_curves(ob):
    """``ob``'s hair curves data with no curves, ready for ``add_curves``.

    ``Curves.remove_curves`` is missing from Blender 4.2 (it came in 4.3):
    there ``ob`` gets a new, empty hair curves datablock carrying the old
    one's materials and surface, and the old one is removed when nothing
    else uses it.
    """
    old = ob.data
    if not len(old.curves):
        return old
    if hasattr(old, "remove_curves"):
        old.remove_curves()
        return old
    new = bpy.data.hair_curves.new(old.name)
    for mat in old.materials:
        new.materials.append(mat)
    new.surface, new.surface_uv_map = old.surface, old.surface_uv_map
    ob.data = new
    if old.users == 0:
        bpy.data.hair_curves.remove(old)
    return new
