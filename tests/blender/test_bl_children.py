"""Children from Guides on a deforming skin (issue 17 point 3): the children are placed
on the Surface's rest shape, so their number and places never change while the skin
deforms, and every child's root stays on the deformed skin; the operator and the panel
say plainly that children are not collided (a Render Groom is)."""

import bpy
import numpy as np
import pytest
from helpers import activate, draw_panel, make_box, make_hair, make_surface
from mathutils import Vector
from mathutils.bvhtree import BVHTree
from mathutils.geometry import barycentric_transform

pytestmark = pytest.mark.blender

FRAMES = range(1, 7)


def _bump_skin(n=8, half=1.0):
    """A UV-mapped square whose shape key raises a bump that slides along x (value 0
    at frame 1, 1 at frame 6)."""
    surf = make_surface(half=half, n=n)
    me = surf.data
    co = np.array([me.vertices[loop.vertex_index].co[:2] for loop in me.loops])
    me.uv_layers["UVMap"].data.foreach_set(
        "uv", ((co + half) / (2 * half)).astype(np.float32).ravel())
    surf.shape_key_add(name="Basis")
    key = surf.shape_key_add(name="Bump")
    for i, v in enumerate(me.vertices):
        x, y, _ = v.co
        g = float(np.exp(-2.0 * (x * x + y * y)))
        key.data[i].co = (x + 0.3 * g, y, 0.5 * g)
    key.value = 0.0
    key.keyframe_insert("value", frame=1)
    key.value = 1.0
    key.keyframe_insert("value", frame=6)
    return surf


def _children_scene(fc, density=300.0):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    scene.frame_set(1)
    hair = make_hair(nx=8, ny=8, spacing=0.22, length=0.5)
    surf = _bump_skin()
    hair.data.surface = surf
    hair.data.surface_uv_map = "UVMap"
    box = make_box(location=(5.0, 0.0, 0.0))  # (no collision: the skin alone moves them)
    scene.frame_set(1)
    out = fc.setup(hair, [box])
    hair.furcollide.frame_end = 6
    activate(hair)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    assert bpy.ops.furcollide.children_from_guides(density=density) == {"FINISHED"}
    return hair, surf, out


def _children(out):
    """World roots (C, 3) of the evaluated children and their count."""
    dg = bpy.context.evaluated_depsgraph_get()
    oe = out.evaluated_get(dg)
    d = oe.data
    offs = np.empty(len(d.curves) + 1, np.int32)
    d.curve_offset_data.foreach_get("value", offs)
    P = np.empty(len(d.points) * 3, np.float32)
    d.position_data.foreach_get("vector", P)
    M = np.array(oe.matrix_world)
    P = P.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    return P[offs[:-1]]


def _skin(surf):
    """(deformed world triangles (t, 3, 3), rest world triangles (t, 3, 3))."""
    dg = bpy.context.evaluated_depsgraph_get()
    se = surf.evaluated_get(dg)
    me = se.to_mesh()
    try:
        me.calc_loop_triangles()
        tris = np.array([t.vertices[:] for t in me.loop_triangles])
        V = np.array([v.co[:] for v in me.vertices])
    finally:
        se.to_mesh_clear()
    rest = np.array([v.co[:] for v in surf.data.shape_keys.key_blocks["Basis"].data])
    M = np.array(surf.matrix_world)
    V, rest = (a @ M[:3, :3].T + M[:3, 3] for a in (V, rest))
    return V[tris], rest[tris]


def test_children_stay_on_the_deforming_skin_with_a_stable_count(fc):
    """Every frame: the same number of children, each the same child (its root maps
    back onto the rest skin where it was at frame 1), its root on the deformed skin."""
    scene = bpy.context.scene
    hair, surf, out = _children_scene(fc)
    first = None
    for f in FRAMES:
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", hair.furcollide.status_message
        roots = _children(out)
        if first is None:
            first = roots
            assert len(roots) > 10 * len(hair.data.curves)
        assert len(roots) == len(first), f"frame {f}: the child count changed"
        now, rest = _skin(surf)
        if f == FRAMES[-1]:
            assert np.abs(now - rest).max() > 0.4  # the skin deformed (by half a hair)
        bvh = BVHTree.FromPolygons([Vector(p) for p in now.reshape(-1, 3)],
                                   [(3 * i, 3 * i + 1, 3 * i + 2) for i in range(len(now))])
        for i, r in enumerate(roots):
            loc, _n, t, dist = bvh.find_nearest(Vector(r))
            assert dist < 1e-4, f"frame {f}: child {i} is {dist:.4f} off the skin"
            back = barycentric_transform(loc, *map(Vector, now[t]), *map(Vector, rest[t]))
            assert (np.array(back) - first[i]).max() < 1e-4 and \
                (first[i] - np.array(back)).max() < 1e-4, f"frame {f}: child {i} moved"


def test_children_modifiers_wrap_blenders_group_once(fc):
    """The guides go to the rest shape before Interpolate Hair Curves and the children
    come back onto the deformed skin after it; running the operator again keeps one of
    each, in that order, and the Surface keeps Blender's rest position."""
    hair, surf, out = _children_scene(fc)
    assert surf.add_rest_position_attribute
    groups = len(bpy.data.node_groups)
    activate(hair)
    assert bpy.ops.furcollide.children_from_guides(density=200.0) == {"FINISHED"}
    names = [m.name for m in out.modifiers]
    assert names[1:] == ["FurCollide Rest Pose", "FurCollide Children",
                         "FurCollide Follow Surface"], names
    assert len(bpy.data.node_groups) == groups


def test_children_are_said_not_to_be_collided(fc, capsys):
    """No clearance pass runs on the children: the operator warns and the panel says
    that renders with no crossing need a Render Groom (Bind Groom)."""
    hair, surf, out = _children_scene(fc)
    said = capsys.readouterr().out
    assert "Children from Guides are not collided" in said
    assert "Render Groom" in said and "Bind Groom" in said and "clearance pass" in said
    activate(hair)
    labels = [e[1] for e in draw_panel(bpy.types.FURCOLLIDE_PT_pipeline) if e[0] == "label"]
    text = " ".join(t for t in labels if t)
    assert "Children are not collided" in text
    assert "For renders with no crossing, use a Render Groom (Bind Groom below)" in text
