"""Setting up through furcollide.add / remove and the collider operators."""

import bpy
import pytest

pytestmark = pytest.mark.blender


def test_add_creates_output(fc):
    import numpy as np

    hair, box = fc.make_scene()
    n = len(hair.data.curves)
    uv = np.random.default_rng(1).random(n * 2).astype(np.float32)
    hair.data.attributes.new("surface_uv_coordinate", "FLOAT2", "CURVE").data.foreach_set(
        "vector", uv
    )
    hair.data.attributes.new("radius", "FLOAT", "POINT").data.foreach_set(
        "value", np.full(len(hair.data.points), 0.01, np.float32)
    )
    mat = bpy.data.materials.new("FurMat")
    hair.data.materials.append(mat)
    ground = bpy.data.objects.new("Skin", bpy.data.meshes.new("Skin"))
    bpy.context.scene.collection.objects.link(ground)
    hair.data.surface = ground
    hair.data.surface_uv_map = "UVMap"
    out = fc.setup(hair, [box])
    s = hair.furcollide
    assert s.is_setup and out is not None and out.furcollide.is_output
    assert out.furcollide.source == hair
    assert hair.hide_render and not out.hide_render
    assert [c.object for c in s.colliders] == [box]
    assert len(out.data.curves) == len(hair.data.curves)
    assert out.modifiers[0].name == fc.dependencies.DEPENDENCY_MODIFIER
    # evaluated right away at the start frame
    assert s.stat_frame == bpy.context.scene.frame_start
    st = out.data.attributes[fc.bridge.STATUS_ATTRIBUTE]
    assert st.domain == "CURVE" and st.data_type == "INT"
    got = np.empty(n * 2, np.float32)
    out.data.attributes["surface_uv_coordinate"].data.foreach_get("vector", got)
    assert np.array_equal(got, uv)
    assert out.data.attributes["radius"].data[0].value == pytest.approx(0.01)
    assert list(out.data.materials) == [mat]
    assert out.data.surface == ground and out.data.surface_uv_map == "UVMap"
    assert out.users_collection[0] == hair.users_collection[0]


def test_play_collides(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    sc = bpy.context.scene
    moved = 0
    for f in range(sc.frame_start, sc.frame_end + 1):
        sc.frame_set(f)
        moved += int(hair.furcollide.stat_colliding > 0)
        assert hair.furcollide.status_message == ""
    assert moved > 0
    assert fc.positions(out).shape == fc.positions(hair).shape


def test_duplicated_source_gets_its_own_setup(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    dup = hair.copy()
    dup.data = hair.data.copy()
    dup.name = "Fur Copy"
    bpy.context.scene.collection.objects.link(dup)
    bpy.context.scene.frame_set(2)
    assert "copy of the setup on 'Fur'" in dup.furcollide.status_message
    assert hair.furcollide.status_message == ""
    bpy.context.scene.frame_set(1)
    out2 = fc.setup(dup, [box])
    assert out2 != out and out2.furcollide.source == dup
    assert dup.furcollide.uid != hair.furcollide.uid
    bpy.context.scene.frame_set(2)
    bpy.context.scene.frame_set(3)
    assert dup.furcollide.status_message == "" and hair.furcollide.status_message == ""


def test_output_pointed_at_a_groom_is_refused(fc):
    import numpy as np

    hair, box = fc.make_scene()
    other = fc.make_scene.__globals__["make_hair"](name="Groom", nx=2, ny=2)
    before = fc.positions(other).copy()
    fc.setup(hair, [box])
    hair.furcollide.output = other
    bpy.context.scene.frame_set(2)
    assert "not a FurCollide output" in hair.furcollide.status_message
    assert np.array_equal(fc.positions(other), before)
    hair.furcollide.output = hair
    bpy.context.scene.frame_set(3)
    assert "not a FurCollide output" in hair.furcollide.status_message


def test_hidden_setup_is_skipped_quietly(fc):
    """A setup whose source and output are both out of the depsgraph (hidden
    from it) is skipped without an error; shown again, it plays as usual."""
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    sc = bpy.context.scene
    hair.hide_viewport = out.hide_viewport = True
    dg = bpy.context.evaluated_depsgraph_get()
    assert fc.frame_rules.evaluate(fc.Setup(hair, sc, dg)) == fc.frame_rules.Outcome.HIDDEN
    for f in range(sc.frame_start, sc.frame_start + 4):
        sc.frame_set(f)
        assert hair.furcollide.status_message == ""
    hair.hide_viewport = out.hide_viewport = False
    moved = 0
    for f in range(sc.frame_start, sc.frame_end + 1):
        sc.frame_set(f)
        assert hair.furcollide.status_message == ""
        moved += int(hair.furcollide.stat_colliding > 0)
    assert moved > 0


def test_a_deleted_source_drops_its_runtime_and_memory_cache(fc):
    """The registry is pruned: a source deleted in the UI (kept alive by its output's
    pointer, in no scene) or removed from the file loses its runtime and playback
    cache at the next depsgraph check or frame change; other setups keep theirs."""
    scene = bpy.context.scene
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    other = fc.make_scene()[0]
    other.name = "Other"
    fc.setup(other, [box])
    for f in range(1, 7):
        scene.frame_set(f)
    rt = fc.registry.get_runtime(hair, create=False)
    kept = fc.registry.get_runtime(other, create=False)
    assert len(rt.memory) == 6 and len(kept.memory) == 6
    assert len(fc.registry.registry) == 2

    hair.furcollide.show_result = False  # the source shows (and can be selected)
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    hair.select_set(True)
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.object.delete() == {"FINISHED"}  # the output's pointer keeps it alive
    assert hair.name in bpy.data.objects and not hair.users_scene
    bpy.context.view_layer.update()  # the depsgraph check
    assert list(fc.registry.registry.values()) == [kept] and len(kept.memory) == 6
    assert fc.registry.get_runtime(hair, create=False) is None

    other.name = "Renamed"  # a rename is not a deletion
    scene.frame_set(3)
    assert list(fc.registry.registry.values()) == [kept]
    bpy.data.objects.remove(other)  # removed from the file by a script
    scene.frame_set(4)  # the frame handler prunes too
    assert fc.registry.registry == {}
