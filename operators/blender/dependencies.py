"""The output's dependency modifier: it makes Blender evaluate a setup's inputs.

FurCollide reads the evaluated source, colliders and growth surface in its frame handler.
A render depsgraph evaluates only what is visible in renders, so the output (and the
render groom output) carries a pass-through geometry-nodes modifier, *FurCollide Inputs*,
first in its stack, whose Object Info nodes reference every input. It is kept in step
with the setup's inputs (:func:`dependencies_stale`, :func:`update_dependencies`).
"""

from __future__ import annotations

import bpy

from ..frame.colliders import collider_objects

#: Name of the pass-through geometry-nodes modifier FurCollide puts first on
#: the output. It references the source, colliders and growth surface so the
#: render depsgraph evaluates them even when they are hidden from render.
DEPENDENCY_MODIFIER = "FurCollide Inputs"


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
    colliders (including the collider collection's meshes, and the entries disabled
    at this frame: their Enabled may be keyed on at another) and the surface."""
    refs = [ob]
    for r in collider_objects(ob, disabled=True):
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
