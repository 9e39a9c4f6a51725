"""What is written into the output: untouched curves stay bit for bit the source's own
positions, a moved output gets every point transformed, and the status attribute and
colours follow the status."""

import math

import bpy
import numpy as np
import pytest
from helpers import play

pytestmark = pytest.mark.blender




def _turned_setup(fc):
    hair, box = fc.make_scene()
    hair.location = (0.05, -0.1, 0.0)
    hair.rotation_euler = (0.0, 0.0, 0.5)
    bpy.context.view_layer.update()
    out = fc.setup(hair, [box])
    play(bpy.context.scene, range(1, 7))
    assert hair.furcollide.stat_colliding > 0
    return hair, out


def _world_result(fc, hair):
    """This frame's solved world positions, as the memory cache rebuilds them."""
    rt = fc.store.registry.get_runtime(hair)
    inp = fc.frame.inputs.read_inputs(
        fc.Setup(hair, bpy.context.scene, bpy.context.evaluated_depsgraph_get()))
    points, status_of, _stats = rt.cache.memory.get(bpy.context.scene.frame_current,
                                                    inp.world(), inp.offsets)
    return inp, points


def test_output_in_the_source_space_keeps_untouched_curves_exact(fc):
    hair, out = _turned_setup(fc)
    inp, world = _world_result(fc, hair)
    assert inp.local is not None  # the output sits where the source sits
    changed = fc.cache.rows_differ(world, inp.world())
    assert 0 < changed.sum() < len(changed)
    got = fc.positions(out)
    src = fc.positions(hair)
    assert np.array_equal(got[~changed], src[~changed])  # bit for bit, no round trip
    M_inv = np.linalg.inv(np.array(out.matrix_world))
    want = world[changed] @ M_inv[:3, :3].T.astype(np.float32) + M_inv[:3, 3]
    assert np.allclose(got[changed], want, atol=1e-5)


def test_a_cached_frame_is_written_from_the_source_without_its_world_positions(
        fc, monkeypatch):
    """Scrubbing back to a cached frame writes bit for bit what playing it wrote, and
    transforms only the points the solver moved (into the output's space): never every
    point of the source to world space and back."""
    hair, out = _turned_setup(fc)
    scene = bpy.context.scene
    fc.store.registry.clear_runtime(hair)
    played = {}
    for f in range(1, 7):
        scene.frame_set(f)
        played[f] = fc.positions(out).copy()
    sizes = []
    real = fc.blender.bridge.transform

    def spy(P, M):
        sizes.append(len(P))
        return real(P, M)

    monkeypatch.setattr(fc.blender.bridge, "transform", spy)
    for f in (3, 5, 2, 6):
        sizes.clear()
        scene.frame_set(f)
        assert fc.store.report.stats_for(hair).get("source") == "cache", f
        assert fc.positions(out).tobytes() == played[f].tobytes(), f
        moved = int(fc.cache.rows_differ(played[f], fc.positions(hair)).sum())
        assert sum(sizes) <= moved < len(played[f]), (f, sizes, moved)


def test_moved_output_gets_every_point_transformed(fc):
    hair, out = _turned_setup(fc)
    out.location = (2.0, 0.0, 0.0)  # the artist moves the output away
    bpy.context.view_layer.update()
    fc.store.registry.clear_runtime(hair)
    play(bpy.context.scene, range(1, 7))
    inp, world = _world_result(fc, hair)
    assert inp.local is None
    got = fc.positions(out)
    M = np.array(out.matrix_world, np.float32)
    got_world = got @ M[:3, :3].T + M[:3, 3]
    assert np.allclose(got_world, world, atol=1e-5)


def test_status_colours_updated_in_place_match_a_full_recolour(fc):
    rng = np.random.default_rng(3)
    sizes = rng.integers(2, 9, 300)
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32)
    before = rng.integers(0, 6, 300).astype(np.int8)
    colors = fc.blender.bridge.status_colors(before, offsets)
    after = before.copy()
    after[rng.choice(300, 40, replace=False)] = rng.integers(0, 6, 40)
    got = fc.blender.bridge.status_colors(after, offsets, before, colors.copy())
    assert np.array_equal(got, fc.blender.bridge.status_colors(after, offsets))
    assert got.shape == (offsets[-1], 4) and got.dtype == np.float32


def test_status_colour_attribute_follows_the_status(fc):
    hair, out = _turned_setup(fc)
    data = out.data
    status = np.empty(len(data.curves), np.int32)
    data.attributes[fc.blender.bridge.STATUS_ATTRIBUTE].data.foreach_get("value", status)
    col = np.empty(len(data.points) * 4, np.float32)
    data.attributes[fc.blender.bridge.COLOR_ATTRIBUTE].data.foreach_get("color", col)
    offsets = fc.blender.bridge.curve_offsets(data)
    want = fc.blender.bridge.status_colors(status.astype(np.int8), offsets)
    assert (status > 0).any()
    assert np.array_equal(col.reshape(-1, 4), want)


# ------------------------------------------------ the status palette (an oracle)
#: README "Using it in Blender", furcollide_color: the colour of each status, by name
#: (INVALID, yellow, is the glue's: the README's table does not list it yet).
README_COLOURS = {0: "grey", 1: "orange", 2: "blue", 3: "magenta", 4: "red", 5: "dark",
                  6: "yellow"}


def colour_name(rgba):
    """The name a person gives an RGB colour, from its hue, saturation and value
    (the standard library's colorsys; nothing from the add-on)."""
    import colorsys

    h, s, v = colorsys.rgb_to_hsv(*(float(c) for c in rgba[:3]))
    h *= 360
    if v < 0.3:
        return "dark"
    if s < 0.15:
        return "grey"
    for name, lo, hi in (("red", -15, 12), ("orange", 12, 42), ("yellow", 42, 70),
                         ("green", 70, 170), ("cyan", 170, 195), ("blue", 195, 255),
                         ("purple", 255, 285), ("magenta", 285, 345)):
        if lo <= (h - 360 if h >= 345 else h) < hi:
            return name
    return "?"


def _colours_of(out):
    data = out.data
    col = np.empty(len(data.points) * 4, np.float32)
    data.attributes["furcollide_color"].data.foreach_get("color", col)
    return col.reshape(-1, 4)


def _enable(hair, off):
    a = hair.data.attributes.new("furcollide_enable", "BOOLEAN", "CURVE")
    a.data.foreach_set("value", ~np.isin(np.arange(len(hair.data.curves)), off))


def test_every_status_shows_the_readmes_colour(fc):
    """Two setups between them show every status; every point of every output curve
    has the colour the README names for its curve's status (classified by hue, not
    compared with the add-on's own palette), and all statuses 0-6 occur."""
    from helpers import make_box, make_hair, offsets_of, setup, status_of, sweep_box

    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 10
    fur = make_hair("Fur", nx=6, ny=6)
    sweep_box("Sweep", -1.2, 1.5, (1, 6))  # in, through and out: then recovering
    make_box("Trap", size=0.3, location=(0.5, 0.5, 0.0))  # roots inside: pinched
    _enable(fur, [0, 1])  # disabled
    P = np.empty(len(fur.data.points) * 3, np.float32)
    fur.data.position_data.foreach_get("vector", P)
    P = P.reshape(-1, 3)
    P[5 * 7 + 2] = np.nan  # curve 7 has a non-finite point: invalid
    fur.data.position_data.foreach_set("vector", P.ravel())
    out_a = setup(fur, [bpy.data.objects["Sweep"], bpy.data.objects["Trap"]])
    stuck = make_hair("Stuck", nx=3, ny=3)
    stuck.location.x = 3.0
    make_box("Wall", size=0.6, location=(3.0, 0.0, 0.6))
    out_b = setup(stuck, [bpy.data.objects["Wall"]])
    stuck.furcollide.max_angle = math.radians(1.0)  # nothing clears within 1 degree
    seen = set()
    for f in range(1, 11):
        scene.frame_set(f)
        for out in (out_a, out_b):
            status = status_of(out)
            names = [colour_name(c) for c in _colours_of(out)]
            offs = offsets_of(out)
            for c, code in enumerate(status):
                got = set(names[offs[c]:offs[c + 1]])
                assert got == {README_COLOURS[int(code)]}, (f, out.name, c, int(code), got)
            seen |= set(status.tolist())
    assert seen == set(README_COLOURS), seen


def test_the_palette_has_one_readme_colour_per_status(fc):
    """Every status code's colour is the one the README names (a swap of two colours,
    or a new code without a colour, fails here even if no scene shows it)."""
    palette = fc.blender.bridge.STATUS_COLORS
    codes = [int(s) for s in fc.core.Status]
    assert len(palette) == len(codes)
    assert {c: colour_name(palette[c]) for c in codes} == {c: README_COLOURS[c] for c in codes}


# ------------------------------------------ the evaluated source's other attributes
def _radius_modifier(ob, value):
    """A geometry-nodes modifier on ``ob`` setting every curve's radius (what the
    artist uses for the render width); returns its Set Curve Radius node."""
    ng = bpy.data.node_groups.new("Width", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gi, go = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    sr = ng.nodes.new("GeometryNodeSetCurveRadius")
    sr.inputs["Radius"].default_value = value
    ng.links.new(gi.outputs[0], sr.inputs["Curve"])
    ng.links.new(sr.outputs[0], go.inputs[0])
    ob.modifiers.new("Width", "NODES").node_group = ng
    return sr


def _radii(ob):
    d = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    r = np.empty(len(d.points), np.float32)
    d.attributes["radius"].data.foreach_get("value", r)
    return r


def test_the_output_follows_the_evaluated_sources_radius(fc):
    """README: each frame FurCollide reads the *evaluated* source (after its modifiers)
    and the output has its curves. The artist widens the fur after Add (the source's
    Set Curve Radius modifier: 0.01 -> 0.05) and plays: the output, which is what
    renders (the source is hidden from render), gets the new width, and keeps it after
    Reset Cache (no Remove + Add, which would delete the output and the artist's
    modifiers on it)."""
    hair, box = fc.make_scene()
    sr = _radius_modifier(hair, 0.01)
    out = fc.setup(hair, [box])
    np.testing.assert_allclose(_radii(out), 0.01)
    sr.inputs["Radius"].default_value = 0.05
    scene = bpy.context.scene
    for f in range(1, 5):
        scene.frame_set(f)
    np.testing.assert_allclose(_radii(hair), 0.05)
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    scene.frame_set(1)
    np.testing.assert_allclose(_radii(out), 0.05)
