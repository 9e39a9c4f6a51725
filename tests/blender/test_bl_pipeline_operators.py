"""The fur pipeline operators: Fur Sampler (counts, determinism, selection, area of
interest, generated and odd grooms), Collider Distance, Children from Guides."""

import sys

import bpy
import numpy as np
import pytest
from helpers import (
    activate,
    demo_build,
    dense_groom,
    make_box,
    make_hair,
    make_surface,
    no_faces,
    play,
    world,
)

pytestmark = pytest.mark.blender




def hair_from_sizes(name, sizes, spacing=0.1):
    """A hair object with one vertical curve of ``sizes[i]`` points per entry."""
    hc = bpy.data.hair_curves.new(name)
    if len(sizes):
        hc.add_curves(list(sizes))
        P = [(spacing * i - 0.3, 0.05 * i - 0.2, 0.1 * j)
             for i, n in enumerate(sizes) for j in range(n)]
        hc.position_data.foreach_set("vector", np.array(P, np.float32).ravel())
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def _pipeline():
    return sys.modules["bl_ext.fcdev.furcollide.core.pipeline"]


def _roots(ob):
    d = ob.data
    offs = np.empty(len(d.curves) + 1, np.int32)
    d.curve_offset_data.foreach_get("value", offs)
    P = np.empty(len(d.points) * 3, np.float32)
    d.position_data.foreach_get("vector", P)
    return P.reshape(-1, 3)[offs[:-1]], offs


def _sample(ob, **kw):
    activate(ob)
    assert bpy.ops.furcollide.fur_sampler(**kw) == {"FINISHED"}
    guides = bpy.context.view_layer.objects.active
    assert guides != ob and guides.type == "CURVES"
    return guides


def test_sampler_count_surface_and_source_untouched(fc):
    hair, surf = dense_groom(fc)
    C = len(hair.data.curves)
    before = fc.positions(hair).copy()
    guides = _sample(hair, fraction=0.2, seed=7)
    assert len(guides.data.curves) == round(0.2 * C)
    # the source is untouched
    assert len(hair.data.curves) == C
    assert np.array_equal(fc.positions(hair), before)
    # guides are curves of the groom, roots on the surface (z = 0, inside the square)
    roots, offs = _roots(guides)
    assert np.allclose(roots[:, 2], 0.0, atol=1e-6)
    assert (np.abs(roots[:, :2]) <= 1.0 + 1e-6).all()
    src_P = before.reshape(-1, 5, 3)
    got = fc.positions(guides).reshape(-1, 5, 3)
    src_roots = src_P[:, 0]
    idx = [int(np.argmin(np.linalg.norm(src_roots - r, axis=1))) for r in got[:, 0]]
    assert np.array_equal(got, src_P[idx])
    # surface, UV map, UV coordinates of the kept curves, placement
    assert guides.data.surface == surf and guides.data.surface_uv_map == "UVMap"
    uv_src = np.empty(C * 2, np.float32)
    hair.data.attributes["surface_uv_coordinate"].data.foreach_get("vector", uv_src)
    uv = np.empty(len(guides.data.curves) * 2, np.float32)
    guides.data.attributes["surface_uv_coordinate"].data.foreach_get("vector", uv)
    assert np.array_equal(uv.reshape(-1, 2), uv_src.reshape(-1, 2)[idx])
    assert guides.parent == hair.parent
    assert np.allclose(np.array(guides.matrix_world), np.array(hair.matrix_world))
    assert guides.users_collection[0] == hair.users_collection[0]


def test_sampler_deterministic_and_matches_core(fc):
    hair, surf = dense_groom(fc)
    a = fc.positions(_sample(hair, fraction=0.15, seed=3))
    b = fc.positions(_sample(hair, fraction=0.15, seed=3))
    c = fc.positions(_sample(hair, fraction=0.15, seed=4))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    # equals core.pipeline.sample_guides on the same (world) inputs
    roots, _ = _roots(hair)
    me = surf.data
    V = np.array([v.co for v in me.vertices])
    me.calc_loop_triangles()
    F = np.array([t.vertices[:] for t in me.loop_triangles])
    keep = _pipeline().sample_guides(roots, V, F, 0.15, 3)
    assert np.array_equal(a.reshape(-1, 5, 3), fc.positions(hair).reshape(-1, 5, 3)[keep])


def test_sampler_world_space_transform(fc):
    hair, surf = dense_groom(fc, uv=False)
    parent = bpy.data.objects.new("Rig", None)
    bpy.context.scene.collection.objects.link(parent)
    parent.location = (3, 0, 1)
    hair.parent = parent
    surf.parent = parent
    bpy.context.view_layer.update()
    guides = _sample(hair, fraction=0.1, seed=1)
    assert guides.parent == parent
    assert len(guides.data.curves) == 10
    assert "surface_uv_coordinate" not in guides.data.attributes
    M = np.array(guides.matrix_world)
    roots, _ = _roots(guides)
    world = roots @ M[:3, :3].T + M[:3, 3]
    assert np.allclose(world[:, 2], 1.0, atol=1e-5)


def test_sampler_selection(fc):
    hair, _ = dense_groom(fc)
    C = len(hair.data.curves)
    sel = np.zeros(C, bool)
    sel[:40] = True
    hair.data.selection_domain = "CURVE"
    attr = hair.data.attributes.get(".selection") or hair.data.attributes.new(
        ".selection", "BOOLEAN", "CURVE"
    )
    attr.data.foreach_set("value", sel)
    guides = _sample(hair, fraction=0.25, seed=0, use_selection=True)
    assert len(guides.data.curves) == 10
    src = fc.positions(hair).reshape(-1, 5, 3)[:40, 0]
    for r in _roots(guides)[0]:
        assert np.linalg.norm(src - r, axis=1).min() < 1e-6


def test_sampler_area_of_interest(fc):
    hair, surf = dense_groom(fc)
    vg = surf.vertex_groups.new(name="Back")
    vg.add([v.index for v in surf.data.vertices if v.co.x < -1e-6], 1.0, "REPLACE")
    guides = _sample(hair, fraction=0.25, seed=5, area="Back")
    roots, _ = _roots(guides)
    assert (roots[:, 0] < 0).all()
    # roots at x = -0.9 .. -0.3 are inside (weight 1); x = -0.1 interpolates to 0.4
    assert len(guides.data.curves) == round(0.25 * 40)
    # a float point attribute of the surface works as well
    a = surf.data.attributes.new("front", "FLOAT", "POINT")
    a.data.foreach_set("value", np.array([v.co.x > 1e-6 for v in surf.data.vertices], np.float32))
    roots = _roots(_sample(hair, fraction=0.5, seed=5, area="front"))[0]
    assert (roots[:, 0] > 0).all() and len(roots) == 20
    activate(hair)
    with pytest.raises(RuntimeError, match="no vertex group or float point attribute"):
        bpy.ops.furcollide.fur_sampler(area="Nope")


def test_sampler_generated_hair(fc):
    """Quick Fur: the original data has (almost) no curves, the evaluated one many."""
    surf = make_surface(n=4)
    activate(surf)
    assert bpy.ops.object.quick_fur(density="LOW") == {"FINISHED"}
    fur = bpy.context.active_object
    dg = bpy.context.evaluated_depsgraph_get()
    C = len(fur.evaluated_get(dg).data.curves)
    assert C > 10 * len(fur.data.curves)
    guides = _sample(fur, fraction=0.05, seed=2)
    assert len(guides.data.curves) == round(0.05 * C)
    assert guides.data.surface == surf
    assert "surface_uv_coordinate" in guides.data.attributes
    assert guides.parent == fur.parent
    # the guides are evaluated curves of the groom, at its evaluated pose
    ev = fur.evaluated_get(dg).data
    offs = np.empty(len(ev.curves) + 1, np.int32)
    ev.curve_offset_data.foreach_get("value", offs)
    P = np.empty(len(ev.points) * 3, np.float32)
    ev.position_data.foreach_get("vector", P)
    src_roots = P.reshape(-1, 3)[offs[:-1]]
    roots, _ = _roots(guides)
    near = [np.linalg.norm(src_roots - r, axis=1).min() for r in roots]
    assert max(near) < 1e-6
    assert np.abs(roots[:, 2]).max() < 0.01  # Quick Fur's noise moves roots slightly
    assert not guides.modifiers  # plain original data


def test_sampler_poll_and_errors(fc):
    hair, _ = dense_groom(fc)
    hair.data.surface = None
    activate(hair)
    with pytest.raises(RuntimeError, match="must be a hair Curves object with a Surface"):
        bpy.ops.furcollide.fur_sampler()
    mesh = make_surface("Other")
    activate(mesh)
    with pytest.raises(RuntimeError, match="must be a hair Curves object with a Surface"):
        bpy.ops.furcollide.fur_sampler()
    # a surface without faces: reported, nothing created
    empty = bpy.data.objects.new("Empty", bpy.data.meshes.new("Empty"))
    bpy.context.scene.collection.objects.link(empty)
    hair.data.surface = empty
    activate(hair)
    n = len(bpy.data.objects)
    with pytest.raises(RuntimeError, match="has no faces"):
        bpy.ops.furcollide.fur_sampler()
    assert len(bpy.data.objects) == n


def test_collider_distance(fc):
    hair, box = fc.make_scene(animate=False)
    out = fc.setup(hair, [box])
    activate(box)
    with pytest.raises(RuntimeError, match="no FurCollide setup"):
        bpy.ops.furcollide.collider_distance()
    activate(out)
    assert bpy.ops.furcollide.collider_distance() == {"FINISHED"}
    attr = out.data.attributes["furcollide_collider_distance"]
    assert attr.domain == "POINT" and attr.data_type == "FLOAT"
    d = np.empty(len(out.data.points), np.float32)
    assert len(attr.data) == len(d)
    attr.data.foreach_get("value", d)
    assert (d >= 0).all() and np.isfinite(d).all()
    # equals the core computed directly (world space)
    offs = np.empty(len(out.data.curves) + 1, np.int32)
    out.data.curve_offset_data.foreach_get("value", offs)
    M = np.array(out.matrix_world)
    P = fc.positions(out).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    Mb = np.array(box.matrix_world)
    V = np.array([v.co for v in box.data.vertices]) @ Mb[:3, :3].T + Mb[:3, 3]
    box.data.calc_loop_triangles()
    F = np.array([t.vertices[:] for t in box.data.loop_triangles])
    ref = _pipeline().collider_distance(P, offs, [(V, F)])
    assert np.allclose(d, ref, rtol=1e-5, atol=1e-6)
    assert d.min() < 0.3  # hairs under the box get close to it


def test_collider_distance_needs_a_collider(fc):
    hair, box = fc.make_scene(animate=False)
    fc.setup(hair, [box])
    hair.furcollide.colliders[0].enabled = False
    activate(hair)
    with pytest.raises(RuntimeError, match="no enabled collider"):
        bpy.ops.furcollide.collider_distance()
    assert "furcollide_collider_distance" not in hair.furcollide.output.data.attributes


def test_children_from_guides(fc):
    hair, surf = dense_groom(fc, nx=6, ny=6)
    box = bpy.data.objects["Box"]  # made by fc.make_scene
    out = fc.setup(hair, [box])
    activate(hair)
    assert bpy.ops.furcollide.children_from_guides(density=100.0) == {"FINISHED"}
    mod = out.modifiers["FurCollide Children"]
    assert mod.type == "NODES" and mod.node_group is not None
    assert out.modifiers[0].name == fc.blender.dependencies.DEPENDENCY_MODIFIER
    compat = sys.modules["bl_ext.fcdev.furcollide.operators.blender.compat"]
    sockets = compat.interpolate_sockets(mod.node_group)
    if sockets.surface_object is not None:  # 4.2-5.0; 5.2 reads the hair data's Surface
        assert compat.modifier_input(mod, sockets.surface_object) == surf
    assert out.data.surface == surf and out.data.surface_uv_map == "UVMap"
    assert compat.modifier_input(mod, sockets.density) == 100.0
    dg = bpy.context.evaluated_depsgraph_get()
    n_eval = len(out.evaluated_get(dg).data.curves)
    assert n_eval > len(out.data.curves) == 36
    # running it again reuses the modifier and the node group
    groups = len(bpy.data.node_groups)
    assert bpy.ops.furcollide.children_from_guides(density=50.0) == {"FINISHED"}
    assert len([m for m in out.modifiers if m.name.startswith("FurCollide Children")]) == 1
    assert len(bpy.data.node_groups) == groups
    # Blender's rest position of the Surface is on (children are placed on its rest
    # shape); turning it on edited the Surface, so play from the start again
    assert surf.add_rest_position_attribute
    # the frame handler still writes the guides
    play(bpy.context.scene, [1, 2])
    assert hair.furcollide.status_message == ""


def test_children_needs_surface_and_assets(fc, monkeypatch):
    hair, box = fc.make_scene(animate=False)
    fc.setup(hair, [box])
    activate(hair)
    with pytest.raises(RuntimeError, match="no Surface"):
        bpy.ops.furcollide.children_from_guides()
    hair.data.surface = make_surface()
    mod = sys.modules["bl_ext.fcdev.furcollide.operators.ops.pipeline"]
    monkeypatch.setattr(mod, "HAIR_ASSETS", ("assets/nodes/missing.blend",))
    with pytest.raises(RuntimeError, match="were not found"):
        bpy.ops.furcollide.children_from_guides()
    assert "FurCollide Children" not in hair.furcollide.output.modifiers


def test_sampler_on_odd_grooms(fc):
    scene = bpy.context.scene
    surf = make_surface(uv=False)

    # 0 curves: refused, nothing created
    empty = hair_from_sizes("Empty", [])
    empty.data.surface = surf
    activate(empty)
    n_objects = len(bpy.data.objects)
    with pytest.raises(RuntimeError, match="'Empty' has no curves to sample"):
        bpy.ops.furcollide.fur_sampler()
    assert len(bpy.data.objects) == n_objects

    # 1 curve: the guide is that curve
    one = hair_from_sizes("One", [5])
    one.data.surface = surf
    activate(one)
    assert bpy.ops.furcollide.fur_sampler() == {"FINISHED"}
    g = bpy.context.view_layer.objects.active
    assert g.name == "One Guides" and len(g.data.curves) == 1
    np.testing.assert_array_equal(fc.positions(g), fc.positions(one))

    # curves of 1 point: sampled (roots only count), but a setup on them is refused
    dots = hair_from_sizes("Dots", [1, 1, 1, 1])
    dots.data.surface = surf
    activate(dots)
    assert bpy.ops.furcollide.fur_sampler(fraction=0.5) == {"FINISHED"}
    g = bpy.context.view_layer.objects.active
    assert len(g.data.curves) == 2 and len(g.data.points) == 2
    activate(g, make_box())
    with pytest.raises(RuntimeError, match="has curves with fewer than 2 points"):
        bpy.ops.furcollide.add()
    assert not g.furcollide.is_setup

    # a fraction that rounds to 0 guides still gives one guide (never an empty object)
    grid = make_hair("Grid", nx=6, ny=6)
    grid.data.surface = surf  # no UV map on this Surface: not needed
    activate(grid)
    assert bpy.ops.furcollide.fur_sampler(fraction=0.001) == {"FINISHED"}
    g = bpy.context.view_layer.objects.active
    assert len(g.data.curves) == 1
    assert g.data.surface == surf and "surface_uv_coordinate" not in g.data.attributes
    activate(grid)
    assert bpy.ops.furcollide.fur_sampler(fraction=0.5, seed=3) == {"FINISHED"}
    assert len(bpy.context.view_layer.objects.active.data.curves) == 18

    # a Surface that is not a mesh (Blender accepts any object there): refused
    for other in (bpy.data.objects.new("Ctrl", None),
                  bpy.data.objects.new("Path", bpy.data.curves.new("Path", "CURVE"))):
        scene.collection.objects.link(other)
        grid.data.surface = other
        activate(grid)
        n_objects = len(bpy.data.objects)
        assert not bpy.ops.furcollide.fur_sampler.poll()
        with pytest.raises(RuntimeError, match="must be a hair Curves object with a Surface"):
            bpy.ops.furcollide.fur_sampler()
        assert len(bpy.data.objects) == n_objects


def test_children_from_guides_on_odd_setups(fc):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 4
    box = make_box(location=(0, 0, 0.6))
    # a hair with 0 curves cannot even become a setup
    empty = hair_from_sizes("Empty", [])
    activate(empty, box)
    with pytest.raises(RuntimeError, match="has no curves to collide"):
        bpy.ops.furcollide.add()

    # 1 curve, on a Surface without a UV map: a clear error, nothing added; with a
    # UV map children grow, and the handler is fine
    one = hair_from_sizes("One", [5])
    surf = make_surface(uv=False)
    one.data.surface = surf
    out = fc.setup(one, [box])
    activate(one)
    with pytest.raises(RuntimeError, match="'Skin' has no UV map"):
        bpy.ops.furcollide.children_from_guides(density=50.0)
    assert "FurCollide Children" not in out.modifiers
    surf.data.uv_layers.new(name="UVMap")
    assert bpy.ops.furcollide.children_from_guides(density=50.0) == {"FINISHED"}
    dg = bpy.context.evaluated_depsgraph_get()
    assert len(out.evaluated_get(dg).data.curves) > 10
    play(scene, range(1, 4))
    assert fc.store.report.status_for(one) == ("INFO", "")

    # a Surface that is not a mesh: refused with the reason, nothing changed
    ctrl = bpy.data.objects.new("Ctrl", None)
    scene.collection.objects.link(ctrl)
    grid = make_hair("Grid", nx=3, ny=3)
    out2 = fc.setup(grid, [box])
    grid.data.surface = ctrl
    activate(grid)
    with pytest.raises(RuntimeError, match="no Surface mesh"):
        bpy.ops.furcollide.children_from_guides()
    assert "FurCollide Children" not in out2.modifiers


def test_children_from_guides_refuses_a_surface_without_faces(fc):
    hair, box = fc.make_scene(animate=False, nx=3, ny=3)
    out = fc.setup(hair, [box])
    hair.data.surface = no_faces()
    activate(hair)
    with pytest.raises(RuntimeError, match="no faces"):
        bpy.ops.furcollide.children_from_guides()
    assert "FurCollide Children" not in out.modifiers


# ------------------------------------------------------- on the demo's body
def test_fur_sampler_gives_the_same_guides_at_any_frame(fc):
    """README: "The same Seed always gives the same guides". Run again later in the shot
    (the demo's body, the groom's Surface, has turned by frame 12): the same curves."""
    demo = demo_build(fur_count=3000, grass_count=50)
    got = []
    for f in (1, 12, 1):
        demo.scene.frame_set(f)
        activate(demo.fur)
        assert bpy.ops.furcollide.fur_sampler(fraction=0.15, seed=3) == {"FINISHED"}
        g = bpy.context.view_layer.objects.active
        got.append(world(g))
    assert len(got[0]) == 450 * 8
    for g in got[1:]:
        np.testing.assert_array_equal(g, got[0])
