"""Children: the output's own Geometry Nodes stack, cleared live every frame.

What renders for a hair whose output carries a children stack (Children from Guides, or
Blender's own Interpolate, Clump and Frizz Hair Curves added by hand) is that stack's
result with the clearance pass: the children output FurCollide makes renders, the output
does not. Measured on the curves Blender evaluates for every object that renders, on a
turning head and on an armature-skinned head with a shape key (each wearing a closed
hat): no resolved child crosses the hat, roots stay on the skin, clumps away from the
hat are as the stack made them, bake equals playback, renders equal the viewport. Also:
the stack runs on the guides once per played frame (the guides gate), Children from
Guides places its children on the Surface's rest shape (a stable count on a deforming
skin), and a source whose curve count changes every frame is explained, followed, fixed
with Use Rest Position, and refused by Bake.
"""

import os

import bpy
import numpy as np
import pytest
from helpers import (
    RESOLVED,
    activate,
    add_hair_asset,
    draw_panel,
    drawn_inside,
    evaluated_points,
    linear,
    make_box,
    make_hair,
    make_surface,
    offsets_of,
    oracle,
    render_camera,
    save_in,
    status_of,
    tris_world,
    world,
)
from mathutils import Vector
from mathutils.bvhtree import BVHTree
from mathutils.geometry import barycentric_transform

pytestmark = pytest.mark.blender

LAST = 5  # the heads turn from frame 1 to LAST
FRAMES = range(1, LAST + 1)


# ------------------------------------------------------------------ scenes
def _head(rigged):
    """A UV sphere head (radius 1, UV map "UVMap") and a closed hat on its crown
    (z 1.175 to 1.425), turning together from frame 1 to LAST: the head object rotates
    with the hat parented to it (``rigged`` False), or an armature's head bone turns
    both, skinned to it, while a shape key swells the crown (``rigged`` True)."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, LAST
    scene.frame_set(1)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=1.0)
    head = bpy.context.object
    head.name = "Head"
    bpy.ops.mesh.primitive_cylinder_add(vertices=20, radius=0.55, depth=0.25,
                                        location=(0.0, 0.0, 1.3))
    hat = bpy.context.object
    hat.name = "Hat"
    if not rigged:
        hat.parent = head
        head.keyframe_insert("rotation_euler", frame=1)
        head.rotation_euler = (0.4, 0.0, 0.8)
        head.keyframe_insert("rotation_euler", frame=LAST)
        linear(head)
        return head, hat
    rig = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    scene.collection.objects.link(rig)
    activate(rig)
    bpy.ops.object.mode_set(mode="EDIT")
    bone = rig.data.edit_bones.new("Head")
    bone.head, bone.tail = (0.0, 0.0, -1.0), (0.0, 0.0, 0.0)
    bpy.ops.object.mode_set(mode="OBJECT")
    for ob in (head, hat):
        vg = ob.vertex_groups.new(name="Head")
        vg.add(range(len(ob.data.vertices)), 1.0, "REPLACE")
        ob.modifiers.new("Armature", "ARMATURE").object = rig
    head.shape_key_add(name="Basis")
    crown = head.shape_key_add(name="Crown")
    for i, v in enumerate(head.data.vertices):
        z = max(v.co.z, 0.0)
        crown.data[i].co = v.co * (1.0 + 0.12 * z * z)
    crown.value = 0.0
    crown.keyframe_insert("value", frame=1)
    crown.value = 1.0
    crown.keyframe_insert("value", frame=LAST)
    pb = rig.pose.bones["Head"]
    pb.rotation_mode = "XYZ"
    pb.keyframe_insert("rotation_euler", frame=1)
    pb.rotation_euler = (0.35, 0.0, 0.6)
    pb.keyframe_insert("rotation_euler", frame=LAST)
    linear(rig, head.data.shape_keys)
    return head, hat


def _guides(head, rigged, density=25.0):
    """Hair made as an artist makes it: Empty Hair on the head (Surface Deform), its
    guides from Blender's Generate Hair Curves (about 300 on the whole head), scattered
    on the rest position on the skinned head (a stable count)."""
    activate(head)
    assert bpy.ops.object.curves_empty_hair_add() == {"FINISHED"}
    hair = bpy.context.object
    hair.name = "Hair"
    if rigged:
        head.add_rest_position_attribute = True
    add_hair_asset(hair, "Generate Hair Curves", at=0, surface=head, uv_map="UVMap",
                   rest=rigged, density=density, length=0.45, points=6, seed=1)
    return hair


def _children_stack(hair, out, head, rigged, density=150.0):
    """About 1,900 children on the output, clumped and frizzed by Blender's Clump and
    Frizz Hair Curves: from Blender's Interpolate Hair Curves added by hand on the
    turning head; from Children from Guides on the skinned head (Interpolate alone
    places its children on the undeformed skin there: up to 0.35 off the deformed one
    at frame 3; Children from Guides moves the guides to the rest shape and the
    children back onto the skin around it)."""
    if rigged:
        activate(hair)
        assert bpy.ops.furcollide.children_from_guides(density=density) == {"FINISHED"}
    else:
        add_hair_asset(out, "Interpolate Hair Curves", surface=head, uv_map="UVMap",
                       density=density, guides=4)
    add_hair_asset(out, "Clump Hair Curves", factor=0.8, clump_distance=0.15)
    add_hair_asset(out, "Frizz Hair Curves", frizz_distance=0.01)


def _groomed_head(fc, rigged):
    """(head, hat, hair, out): a head, its hat, guides colliding with the hat, the
    children stack on the output."""
    head, hat = _head(rigged)
    hair = _guides(head, rigged)
    bpy.context.scene.frame_set(1)
    out = fc.setup(hair, [hat])
    hair.furcollide.frame_end = LAST
    _children_stack(hair, out, head, rigged)
    return head, hat, hair, out


# ----------------------------------------------------------------- readers
def _status(ob):
    d = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    st = np.zeros(len(d.curves), np.int32)
    d.attributes["furcollide_status"].data.foreach_get("value", st)
    return st


def _crossing(P, offs, colliders):
    """(C,) bool: the curves (world points ``P``, layout ``offs``) that surely cross one
    of ``colliders`` (evaluated, world)."""
    bad = np.zeros(len(offs) - 1, bool)
    for ob in colliders:
        V, F = tris_world(ob)
        bad |= oracle.segments_hit_mesh(P, offs, V, F, abs_eps=oracle.float32_margin(P, V))
    return bad


def _skin(head):
    """BVH tree of the head's evaluated world surface."""
    V, F = tris_world(head)
    return BVHTree.FromPolygons([Vector(v) for v in V], [tuple(t) for t in F])


def _off_skin(roots, bvh):
    return max((bvh.find_nearest(Vector(r))[3] for r in roots), default=0.0)


def _rendered(scene):
    """The hair objects that render (not hidden from renders)."""
    return [o for o in scene.objects if o.type == "CURVES" and not o.hide_render]


def _check_rendered(hair, head, hat, frame, least=1000):
    """At the frame shown: only the children output renders; none of its resolved
    children crosses the hat (its evaluated curves), roots on the skin, its own status.
    Returns (world points, offsets, status) of the children."""
    ch = hair.furcollide.children.output
    assert ch is not None
    assert _rendered(bpy.context.scene) == [ch], [o.name for o in _rendered(bpy.context.scene)]
    P, offs = evaluated_points(ch)
    st = _status(ch)
    assert len(st) == len(offs) - 1 > least
    bad = _crossing(P, offs, [hat]) & np.isin(st, RESOLVED)
    assert not bad.any(), f"frame {frame}: {int(bad.sum())} resolved children cross the hat"
    assert _off_skin(P[offs[:-1]], _skin(head)) < 1e-4, f"frame {frame}: a root off the skin"
    return P, offs, st


def _tip_to_clump_guide(P, offs, guide):
    """Distance of each child's tip to its clump guide's tip (``guide``: the stack's
    ``guide_curve_index``, -1 or out of range: none): (C,) float, NaN where none."""
    C = len(offs) - 1
    tips = P[offs[1:] - 1]
    ok = (guide >= 0) & (guide < C)
    d = np.full(C, np.nan)
    d[ok] = np.linalg.norm(tips[ok] - tips[guide[ok]], axis=1)
    return d


def _guide_index(ob):
    d = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    a = d.attributes.get("guide_curve_index")
    g = np.full(len(d.curves), -1, np.int32)
    if a is not None and a.domain == "CURVE":
        a.data.foreach_get("value", g)
    return g


# ------------------------------------------------------------------- tests
@pytest.mark.parametrize("rigged", [False, True], ids=["turning", "skinned"])
def test_children_stack_cleared_live_on_a_head_with_a_hat(fc, rigged):
    """Interpolate (or Children from Guides), Clump and Frizz on the output: every frame
    the children output holds the stack's children cleared of the hat (their own
    status, counted in the Last Frame panel), roots on the skin."""
    scene = bpy.context.scene
    head, hat, hair, out = _groomed_head(fc, rigged)
    fixed, counts = 0, set()
    for f in FRAMES:
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        _P, offs, st = _check_rendered(hair, head, hat, f)
        c = hair.furcollide.children
        assert c.stat_children == len(st) and c.stat_unresolved == int((st == 4).sum())
        fixed += c.stat_fixed
        counts.add(len(st))
    # The hat crosses children on every frame: 60 to a few hundred over the shot, as the
    # children Blender's assets make differ from one Blender session to the next.
    assert fixed > 30, fixed
    assert out.hide_render and hair.hide_render
    if rigged:  # (Children from Guides: on the rest shape, the same children)
        assert len(counts) == 1


def test_clumps_kept_where_no_collider_is_near(fc):
    """The clearance pass leaves every child the hat does not come near exactly as the
    stack made it: the tip to clump-guide distances there are unchanged, bit for bit
    (the children on the source came apart: issue 34)."""
    scene = bpy.context.scene
    head, hat, hair, out = _groomed_head(fc, rigged=False)
    scene.frame_set(3)
    c = hair.furcollide.children
    P, offs = evaluated_points(c.output)
    c.use_viewport = False  # the stack's own children, not cleared
    scene.frame_set(3)
    Q, offs_q = evaluated_points(c.output)
    np.testing.assert_array_equal(offs, offs_q)
    guide = _guide_index(c.output)
    V, _F = tris_world(hat)
    lo, hi = V.min(0) - 0.1, V.max(0) + 0.1
    starts = np.repeat(np.arange(len(offs) - 1), np.diff(offs))
    near = np.zeros(len(offs) - 1, bool)
    near[starts[((Q > lo) & (Q < hi)).all(1)]] = True
    far = ~near & ~near[np.clip(guide, 0, len(near) - 1)]
    assert far.sum() > 0.5 * len(far)
    got, made = _tip_to_clump_guide(P, offs, guide), _tip_to_clump_guide(Q, offs, guide)
    assert np.isfinite(made[far]).sum() > 100  # (clumped children there)
    np.testing.assert_array_equal(got[far], made[far])
    moved = (np.abs(P - Q).max(1) > 0)
    assert moved.any() and not moved[np.isin(starts, np.flatnonzero(far))].any()
    med_got, med_made = np.nanmedian(got), np.nanmedian(made)
    assert abs(med_got - med_made) < 0.1 * med_made, (med_got, med_made)


def test_the_curves_drawn_through_the_children_clear_the_hat(fc):
    """Interpolate Hair Curves makes Catmull-Rom children (Blender's default type):
    cleared as polylines through their points, the curves Blender draws dipped into the
    hat between cleared points (27 to 115 drawn points in 8 to 19 of 1,859 children a
    frame over three runs, 0 control points). The pass widens their clearance by their
    drawn margin: no drawn point inside the hat, no resolved child crossing it, roots on
    the skin."""
    scene = bpy.context.scene
    head, hat, hair, out = _groomed_head(fc, rigged=False)
    for f in FRAMES:
        scene.frame_set(f)
        ch = hair.furcollide.children.output
        types = fc.blender.bridge.read_splines(ch.data).types
        assert (types == fc.core.splines.CATMULL_ROM).all()
        _check_rendered(hair, head, hat, f)
        assert drawn_inside(ch, [hat], _status(ch)) == (0, 0), f"frame {f}"


def test_stack_runs_on_the_guides_once_per_played_frame(fc):
    """Blender's first pass of a frame change runs the output's stack on no guides (the
    gate is closed), FurCollide then evaluates it once on the guides it wrote, and
    Blender's second pass has nothing of it to evaluate again."""
    scene = bpy.context.scene
    head, hat, hair, out = _groomed_head(fc, rigged=False)
    scene.frame_set(1)
    seen = []

    def count(what):
        def spy(*args):
            dg = args[1] if len(args) > 1 and args[1] is not None else \
                bpy.context.evaluated_depsgraph_get()
            seen.append((what, len(out.evaluated_get(dg).data.curves)))
        return spy

    first_pass = count("first pass")
    updates = count("update")
    before = count("before")
    bpy.app.handlers.frame_change_post.insert(0, first_pass)  # (before FurCollide's)
    bpy.app.handlers.depsgraph_update_post.append(updates)
    bpy.app.handlers.frame_change_pre.insert(0, before)  # (the last frame, as it ended)
    try:
        for f in (2, 3, 4):
            scene.frame_set(f)
    finally:
        bpy.app.handlers.frame_change_post.remove(first_pass)
        bpy.app.handlers.depsgraph_update_post.remove(updates)
        bpy.app.handlers.frame_change_pre.remove(before)
    firsts = [n for w, n in seen if w == "first pass"]
    full = [n for w, n in seen if w == "update"]
    assert firsts == [0, 0, 0], seen  # (no stale run on the last frame's guides)
    assert len(full) == 3 and min(full) > 1000, seen  # once per frame, on the guides
    assert [n for w, n in seen if w == "before"][1:] == full[:-1]  # (kept until the next)


def test_bake_equals_playback_and_renders_equal_the_viewport(fc, tmp_path):
    """The skinned head: playback, a render of the played frames, the bake (which stores
    the children), the baked frames played and rendered, and a render of frames never
    played all show the same children, bit for bit."""
    scene = bpy.context.scene
    head, hat, hair, out = _groomed_head(fc, rigged=True)
    scene.frame_end = hair.furcollide.frame_end = 2
    ch = hair.furcollide.children.output
    live = {}
    for f in (1, 2):
        scene.frame_set(f)
        live[f] = evaluated_points(ch) + (_status(ch),)

    def same(got, f, what):
        for a, b in zip(got, live[f], strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"{what}, frame {f}")

    render_camera(scene)
    seen = {}

    def spy(sc, depsgraph):
        # (after FurCollide's handler: the render evaluates the children output's data,
        # written now, in its second pass; its only modifier passes them through)
        if depsgraph.mode == "RENDER":
            seen[sc.frame_current] = ((world(ch).copy(), offsets_of(ch).copy(),
                                       status_of(ch).astype(np.int32)),
                                      hair.furcollide.status_message)

    scene.render.filepath = str(tmp_path / "r_####")
    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
        for f in (1, 2):
            same(seen[f][0], f, "played, rendered")
            assert seen[f][1] == "", seen[f][1]
        save_in(tmp_path)
        activate(hair)
        assert bpy.ops.furcollide.bake() == {"FINISHED"} and hair.furcollide.is_baked
        for f in (1, 2):
            scene.frame_set(f)
            same(evaluated_points(ch) + (_status(ch),), f, "baked")
            assert hair.furcollide.status_message == ""
        seen.clear()
        bpy.ops.render.render(animation=True)
        for f in (1, 2):
            same(seen[f][0], f, "baked, rendered")
        activate(hair)
        assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
        assert bpy.ops.furcollide.reset() == {"FINISHED"}
        seen.clear()
        bpy.ops.render.render(animation=True)  # (nothing played: solved in the render)
        for f in (1, 2):
            same(seen[f][0], f, "rendered before it was played")
            assert seen[f][1] == "", seen[f][1]
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)


def test_stack_edits_show_on_the_next_frame(fc):
    """No bind step: a density edit in the stack shows on the next frame shown."""
    scene = bpy.context.scene
    head, hat, hair, out = _groomed_head(fc, rigged=False)
    scene.frame_set(1)
    n = hair.furcollide.children.stat_children
    compat = fc.package.operators.blender.compat
    mod = out.modifiers["Interpolate Hair Curves"]
    ident = compat.group_inputs(mod.node_group)[("Density", "NodeSocketFloat")]
    compat.set_modifier_input(mod, ident, 75.0)
    out.update_tag()
    scene.frame_set(2)
    m = hair.furcollide.children.stat_children
    assert 0.35 * n < m < 0.65 * n, (n, m)
    _check_rendered(hair, head, hat, 2, least=500)


def test_clear_children_off_renders_the_output(fc):
    """Clear Children off: the children output goes, the output renders its own stack
    (and the panel says the children are not cleared); on again: it comes back."""
    scene = bpy.context.scene
    head, hat, hair, out = _groomed_head(fc, rigged=False)
    scene.frame_set(1)
    c = hair.furcollide.children
    name = c.output.name
    c.use_children = False
    assert c.output is None and name not in bpy.data.objects
    assert not out.hide_render and "FurCollide Guides Gate" not in out.modifiers
    activate(hair)
    labels = " ".join(e[1] or "" for e in draw_panel(bpy.types.FURCOLLIDE_PT_pipeline)
                      if e[0] == "label")
    assert "Children are not cleared: they can cross a collider" in labels
    c.use_children = True
    scene.frame_set(2)
    assert c.output is not None and out.hide_render
    _check_rendered(hair, head, hat, 2)


def test_make_children_output_button(fc):
    """Modifiers added to the output and no frame shown since: the panel says the
    children are not cleared yet and offers Make Children Output, which clears them."""
    scene = bpy.context.scene
    head, hat = _head(rigged=False)
    hair = _guides(head, rigged=False)
    scene.frame_set(1)
    out = fc.setup(hair, [hat])
    _children_stack(hair, out, head, rigged=False)
    assert hair.furcollide.children.output is None
    activate(hair)
    drawn = draw_panel(bpy.types.FURCOLLIDE_PT_pipeline)
    assert ("operator", "furcollide.children_output") in [e[:2] for e in drawn]
    assert bpy.ops.furcollide.children_output() == {"FINISHED"}
    _check_rendered(hair, head, hat, 1)


def test_resample_on_the_output_sees_the_guides_written(fc):
    """A Resample Curve modifier on the output: the children output holds the guides
    written this frame, resampled (its tips are the guides' tips)."""
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    ng = bpy.data.node_groups.new("Resample", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    resample = ng.nodes.new("GeometryNodeResampleCurve")
    resample.inputs["Count"].default_value = 9
    ng.links.new(gin.outputs[0], resample.inputs[0])
    ng.links.new(resample.outputs[0], gout.inputs[0])
    out.modifiers.new("Resample", "NODES").node_group = ng
    hair.furcollide.children.use_viewport = False  # (the stack's result as it is)
    moved = 0
    for f in range(1, 9):
        bpy.context.scene.frame_set(f)
        P, offs = evaluated_points(hair.furcollide.children.output)
        G, goffs = world(out), offsets_of(out)
        moved += int(np.abs(G - world(hair)).max() > 0.01)
        if np.abs(P[offs[1:] - 1] - G[goffs[1:] - 1]).max() > 1e-5:
            # Blender keeps the output's evaluated positions from before the write
            # (issue 29 item 2, fixed in bridge.py / frame/output.py by another branch)
            pytest.xfail(f"frame {f}: the stack saw positions from before the write "
                         "(issue 29)")
    assert moved


@pytest.mark.parametrize("keep", [False, True], ids=["removed", "kept"])
def test_remove_furcollide_removes_the_children_output(fc, keep):
    """Remove FurCollide deletes the children output with the output; with Keep Output
    the output renders its own modifiers again (no guides gate left on it)."""
    scene = bpy.context.scene
    head, hat, hair, out = _groomed_head(fc, rigged=False)
    scene.frame_set(1)
    name, out_name = hair.furcollide.children.output.name, out.name
    activate(hair)
    assert bpy.ops.furcollide.remove(keep_output=keep) == {"FINISHED"}
    assert name not in bpy.data.objects
    if keep:
        kept = bpy.data.objects[out_name]
        assert not kept.hide_render
        assert [m.name for m in kept.modifiers] == [
            "Interpolate Hair Curves", "Clump Hair Curves", "Frizz Hair Curves"]
    else:
        assert out_name not in bpy.data.objects
    scene.frame_set(2)  # (nothing left to write into)


# ------------------------------------------------- a source whose curves change
def _varying_source(fc):
    """The skinned head with the children on the source: Interpolate between Generate
    and Surface Deform, without the rest position, so their number changes every
    frame."""
    head, hat = _head(rigged=True)
    hair = _guides(head, rigged=True, density=12.0)
    add_hair_asset(hair, "Interpolate Hair Curves", at=1, surface=head, uv_map="UVMap",
                   density=60.0, guides=4, rest=False)
    bpy.context.scene.frame_set(1)
    out = fc.setup(hair, [hat])
    hair.furcollide.frame_end = LAST
    return head, hat, hair, out


def test_source_whose_count_changes_every_frame(fc, tmp_path, capsys):
    """Recognised and explained in one line naming the fix (the Use Rest Position
    button, drawn under the status); the output follows the skin (the source as it is)
    and is outdated; Bake refuses it with the same message and writes nothing; Use Rest
    Position fixes it."""
    scene = bpy.context.scene
    head, hat, hair, out = _varying_source(fc)
    counts = set()
    for f in range(1, 4):
        scene.frame_set(f)
        counts.add(len(evaluated_points(hair)[1]) - 1)
    assert len(counts) > 1, counts
    msg = hair.furcollide.status_message
    assert "'Interpolate Hair Curves' scatters its curves on the deforming Surface" in msg
    assert "Press Use Rest Position" in msg and "\n" not in msg, msg
    assert hair.furcollide.is_outdated
    P, offs = evaluated_points(out)
    Q, offs_q = evaluated_points(hair)
    np.testing.assert_array_equal(offs, offs_q)
    np.testing.assert_allclose(P, Q, atol=1e-5)  # the output follows the skin
    activate(hair)
    ops = [e[1] for e in draw_panel(bpy.types.FURCOLLIDE_PT_main) if e[0] == "operator"]
    assert "furcollide.use_rest_position" in ops
    save_in(tmp_path)
    with pytest.raises(RuntimeError, match="Press Use Rest Position"):
        bpy.ops.furcollide.bake()
    assert not hair.furcollide.is_baked
    d = bpy.path.abspath(fc.store.bake.directory_from_settings(hair))
    assert not os.path.isdir(d) or not os.listdir(d)
    assert bpy.ops.furcollide.use_rest_position() == {"FINISHED"}
    counts = set()
    for f in FRAMES:
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        counts.add(len(evaluated_points(hair)[1]) - 1)
    assert len(counts) == 1
    assert "Traceback" not in capsys.readouterr().err


# ------------------------------------- Children from Guides on a deforming skin
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


def _rest_and_now(surf):
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


def test_children_from_guides_stay_on_the_deforming_skin_with_a_stable_count(fc):
    """Every frame: the same number of children in the children output, each the same
    child (its root maps back onto the rest skin where it was at frame 1), its root on
    the deformed skin."""
    scene = bpy.context.scene
    hair, surf, out = _children_scene(fc)
    ch = hair.furcollide.children.output
    assert ch is not None and out.hide_render and not ch.hide_render
    first = None
    for f in range(1, 7):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", hair.furcollide.status_message
        P, offs = evaluated_points(ch)
        roots = P[offs[:-1]]
        if first is None:
            first = roots
            assert len(roots) > 10 * len(hair.data.curves)
        assert len(roots) == len(first), f"frame {f}: the child count changed"
        now, rest = _rest_and_now(surf)
        if f == 6:
            assert np.abs(now - rest).max() > 0.4  # the skin deformed (by half a hair)
        bvh = BVHTree.FromPolygons([Vector(p) for p in now.reshape(-1, 3)],
                                   [(3 * i, 3 * i + 1, 3 * i + 2) for i in range(len(now))])
        for i, r in enumerate(roots):
            loc, _n, t, dist = bvh.find_nearest(Vector(r))
            assert dist < 1e-4, f"frame {f}: child {i} is {dist:.4f} off the skin"
            back = barycentric_transform(loc, *map(Vector, now[t]), *map(Vector, rest[t]))
            assert (np.array(back) - first[i]).max() < 1e-4 and \
                (first[i] - np.array(back)).max() < 1e-4, f"frame {f}: child {i} moved"


def test_children_from_guides_wraps_blenders_group_once(fc):
    """The guides go to the rest shape before Interpolate Hair Curves and the children
    come back onto the deformed skin after it; running the operator again keeps one of
    each, in that order (after FurCollide's dependency modifier and guides gate), one
    children output, and the Surface keeps Blender's rest position."""
    hair, surf, out = _children_scene(fc)
    assert surf.add_rest_position_attribute
    groups = len(bpy.data.node_groups)
    objects = len(bpy.data.objects)
    activate(hair)
    assert bpy.ops.furcollide.children_from_guides(density=200.0) == {"FINISHED"}
    names = [m.name for m in out.modifiers]
    assert names == ["FurCollide Inputs", "FurCollide Guides Gate", "FurCollide Rest Pose",
                     "FurCollide Children", "FurCollide Follow Surface"], names
    assert len(bpy.data.node_groups) == groups and len(bpy.data.objects) == objects


def test_children_from_guides_says_they_are_cleared(fc, capsys):
    """The operator says where the cleared children go; the panel says how children
    relate to a Render Groom."""
    hair, surf, out = _children_scene(fc)
    said = capsys.readouterr().out
    ch = hair.furcollide.children.output
    assert f"cleared of the colliders into '{ch.name}' every frame" in said
    activate(hair)
    labels = " ".join(e[1] or "" for e in draw_panel(bpy.types.FURCOLLIDE_PT_pipeline)
                      if e[0] == "label")
    assert f"Output: {ch.name}" in labels
    assert "a Render Groom (below) is your own dense" in labels
    assert "Both get the same clearance pass." in labels
