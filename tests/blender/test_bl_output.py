"""What is written into the output: untouched curves stay bit for bit the source's own
positions, a moved output gets every point transformed, and the status attribute and
colours follow the status."""

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
    rt = fc.registry.get_runtime(hair)
    inp = fc.frame_inputs.read_inputs(
        fc.Setup(hair, bpy.context.scene, bpy.context.evaluated_depsgraph_get()))
    points, status_of, _stats = rt.memory.get(bpy.context.scene.frame_current, inp.points,
                                            inp.offsets)
    return inp, points


def test_output_in_the_source_space_keeps_untouched_curves_exact(fc):
    hair, out = _turned_setup(fc)
    inp, world = _world_result(fc, hair)
    assert inp.local is not None  # the output sits where the source sits
    changed = fc.cache.rows_differ(world, inp.points)
    assert 0 < changed.sum() < len(changed)
    got = fc.positions(out)
    src = fc.positions(hair)
    assert np.array_equal(got[~changed], src[~changed])  # bit for bit, no round trip
    M_inv = np.linalg.inv(np.array(out.matrix_world))
    want = world[changed] @ M_inv[:3, :3].T.astype(np.float32) + M_inv[:3, 3]
    assert np.allclose(got[changed], want, atol=1e-5)


def test_moved_output_gets_every_point_transformed(fc):
    hair, out = _turned_setup(fc)
    out.location = (2.0, 0.0, 0.0)  # the artist moves the output away
    bpy.context.view_layer.update()
    fc.registry.clear_runtime(hair)
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
    colors = fc.bridge.status_colors(before, offsets)
    after = before.copy()
    after[rng.choice(300, 40, replace=False)] = rng.integers(0, 6, 40)
    got = fc.bridge.status_colors(after, offsets, before, colors.copy())
    assert np.array_equal(got, fc.bridge.status_colors(after, offsets))
    assert got.shape == (offsets[-1], 4) and got.dtype == np.float32


def test_status_colour_attribute_follows_the_status(fc):
    hair, out = _turned_setup(fc)
    data = out.data
    status = np.empty(len(data.curves), np.int32)
    data.attributes[fc.bridge.STATUS_ATTRIBUTE].data.foreach_get("value", status)
    col = np.empty(len(data.points) * 4, np.float32)
    data.attributes[fc.bridge.COLOR_ATTRIBUTE].data.foreach_get("color", col)
    offsets = fc.bridge.curve_offsets(data)
    want = fc.bridge.status_colors(status.astype(np.int8), offsets)
    assert (status > 0).any()
    assert np.array_equal(col.reshape(-1, 4), want)
