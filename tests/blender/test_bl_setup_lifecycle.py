"""Setting up, removing and copying setups: the output FurCollide owns, duplicated
setups, outputs deleted, replaced or swapped, hidden and excluded setups, undo, the
registry pruned when a source is deleted, and errors as status messages (the handlers
never raise)."""

import math

import bpy
import numpy as np
import pytest
from helpers import (
    SHOT_FRAMES,
    activate,
    assert_unchanged,
    duplicate,
    groom_scene,
    make_hair,
    no_traceback,
    offsets_of,
    play,
    play_checked,
    positions,
    reference_frames,
    same_frames,
    save_as,
    set_core,
    snapshot,
    sweep_setup,
    world,
)

from core import Status

pytestmark = pytest.mark.blender

_EXTREMES = {
    "offset_1000": dict(collision_offset=1000.0),
    "offset_1e6_soft": dict(collision_offset=1e6, mode="soft"),
    "precision_min": dict(rotation_precision=0.001),
    "precision_min_soft": dict(rotation_precision=0.001, mode="soft"),
    "precision_max": dict(rotation_precision=45.0, max_angle=45.0),
    "max_angle_min": dict(rotation_precision=0.001, max_angle=0.01),
    "no_recovery_full_plasticity": dict(recovery_rate=0.0, plasticity=1.0),
    "instant_recovery_full_plasticity_soft": dict(recovery_rate=1.0, plasticity=1.0,
                                                  mode="soft"),
    "instant_recovery_stiff": dict(recovery_rate=1.0, mode="stiff"),
    "shrink_to_nothing": dict(shrink=True, scale_minimum=0.001, scale_angle=0.01),
    "soft_every_cv": dict(mode="soft", affected_connected_cvs=10000, cv_falloff=1.0),
}


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
    assert out.modifiers[0].name == fc.blender.dependencies.DEPENDENCY_MODIFIER
    # evaluated right away at the start frame
    assert s.stat_frame == bpy.context.scene.frame_start
    st = out.data.attributes[fc.blender.bridge.STATUS_ATTRIBUTE]
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
    assert fc.frame.spine.evaluate(fc.Setup(hair, sc, dg)) == fc.frame.rules.Outcome.HIDDEN
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
    rt = fc.store.registry.get_runtime(hair, create=False)
    kept = fc.store.registry.get_runtime(other, create=False)
    assert len(rt.cache.memory) == 6 and len(kept.cache.memory) == 6
    assert len(fc.store.registry.registry) == 2

    hair.furcollide.show_result = False  # the source shows (and can be selected)
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    hair.select_set(True)
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.object.delete() == {"FINISHED"}  # the output's pointer keeps it alive
    assert hair.name in bpy.data.objects and not hair.users_scene
    bpy.context.view_layer.update()  # the depsgraph check
    assert list(fc.store.registry.registry.values()) == [kept] and len(kept.cache.memory) == 6
    assert fc.store.registry.get_runtime(hair, create=False) is None

    other.name = "Renamed"  # a rename is not a deletion
    scene.frame_set(3)
    assert list(fc.store.registry.registry.values()) == [kept]
    bpy.data.objects.remove(other)  # removed from the file by a script
    scene.frame_set(4)  # the frame handler prunes too
    assert fc.store.registry.registry == {}


def test_output_keeps_user_modifiers_and_remove_keep_output(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    user = out.modifiers.new("My Smooth", "NODES")
    play(bpy.context.scene, range(1, 4))
    bpy.context.scene.frame_set(1)
    bpy.ops.furcollide.reset()
    assert out.modifiers.get("My Smooth") == user
    assert out.modifiers[0].name == fc.blender.dependencies.DEPENDENCY_MODIFIER
    assert bpy.ops.furcollide.remove(keep_output=True) == {"FINISHED"}
    assert out.name in bpy.data.objects and out.modifiers.get("My Smooth")
    assert out.modifiers.get(fc.blender.dependencies.DEPENDENCY_MODIFIER) is None
    assert not out.furcollide.is_output


def test_invalid_setting_combination_is_a_status_not_a_traceback(fc, capsys):
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    s = hair.furcollide
    s.rotation_precision = math.radians(10.0)
    s.max_angle = math.radians(5.0)  # core: max_angle must be >= rotation_precision
    bpy.context.scene.frame_set(1)
    assert "max_angle" in s.status_message
    assert "Traceback" not in capsys.readouterr().err
    s.max_angle = math.radians(90.0)
    bpy.context.scene.frame_set(1)
    assert s.status_message == ""


def test_frame_handler_and_update_callbacks_never_raise(fc, monkeypatch, capsys):
    hair, box = fc.make_scene()
    fc.setup(hair, [box])

    def broken(*_args, **_kw):
        raise RuntimeError("simulated failure")

    monkeypatch.setattr(fc.store.registry, "setups", broken)
    # the handler cannot even list the setups: one line, no raise
    play(bpy.context.scene, range(1, 3))
    assert "frame handler failed: simulated failure" in capsys.readouterr().out
    monkeypatch.undo()
    monkeypatch.setattr(fc.store.invalidation, "invalidate", broken)
    hair.furcollide.plasticity = 0.3  # the update callback fails: one line, no raise
    assert "failed: simulated failure" in capsys.readouterr().out
    assert hair.furcollide.plasticity == pytest.approx(0.3)


def test_duplicated_setup_errors_and_leaves_the_original_alone(fc):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 6))
    out = fc.setup(hair, [box])
    clean = {}
    for f in range(1, 6):
        scene.frame_set(f)
        clean[f] = world(out).copy()
    bpy.context.view_layer.objects.active = hair
    bpy.ops.furcollide.reset()
    scene.frame_set(1)
    dup = duplicate(hair, dx=0.3)  # the copy's curves differ from the original's
    for f in range(1, 6):
        scene.frame_set(f)
        level, msg = fc.store.report.status_for(dup)
        assert level == "ERROR" and "copy of the setup on 'Fur'" in msg, msg
        assert hair.furcollide.status_message == ""
        np.testing.assert_array_equal(world(out), clean[f], err_msg=f"frame {f}")
    assert out.furcollide.source == hair


def test_remove_on_a_duplicate_keeps_the_original_output(fc):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 6))
    out = fc.setup(hair, [box])
    name = out.name
    dup = duplicate(hair)
    scene.frame_set(2)
    assert "copy of the setup on 'Fur'" in dup.furcollide.status_message
    activate(dup)
    bpy.ops.furcollide.remove()
    assert name in bpy.data.objects, "the original's output was deleted"
    assert hair.furcollide.output == bpy.data.objects[name]
    scene.frame_set(1)
    scene.frame_set(2)
    assert hair.furcollide.status_message == ""


@pytest.mark.parametrize("with_groom", [False, True])
def test_hide_while_playing_then_show_and_jump(fc, with_groom):
    scene = bpy.context.scene
    if with_groom:
        hair, groom, box, out = groom_scene(fc)
        assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
        gout = hair.furcollide.groom.output
        watched = [out, gout]
    else:
        hair, box = fc.make_scene(frames=(1, 8))
        out = fc.setup(hair, [box])
        gout = None
        watched = [out]
    fresh = {}
    for f in range(1, 8):
        scene.frame_set(f)
        fresh[f] = [world(o).copy() for o in watched]
    assert any(not np.array_equal(fresh[f][0], fresh[1][0]) for f in fresh)
    bpy.context.view_layer.objects.active = hair
    bpy.ops.furcollide.reset()
    scene.frame_set(1)

    def check(f):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        for o, want in zip(watched, fresh[f], strict=True):
            np.testing.assert_array_equal(world(o), want, err_msg=f"{o.name} frame {f}")

    for f in range(1, 4):
        check(f)
    hidden = [hair, out] + ([gout] if gout is not None else [])
    for o in hidden:
        o.hide_viewport = True
    for f in range(4, 6):
        scene.frame_set(f)
        assert hair.furcollide.status_message == ""
    for o in hidden:
        o.hide_viewport = False
    for f in (2, 3, 1, 2, 3, 4, 5, 6, 7, 4, 6):  # cached frames, then on from frame 3
        check(f)


@pytest.mark.parametrize("what", ["object", "data"])
def test_output_removed_then_play_and_buttons(fc, what, capsys):
    """bpy.data removal of the output (or of its curves data, which takes the object
    with it): a clear message on play and from the buttons, the groom untouched, and
    Add FurCollide makes a new output that plays as before."""
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    groom = snapshot(hair)
    ref = reference_frames(fc, scene, hair)
    if what == "object":
        bpy.data.objects.remove(out)
    else:
        bpy.data.hair_curves.remove(out.data)
    assert hair.furcollide.output is None
    for f in (1, 2, 3):
        scene.frame_set(f)
        assert "output hair object is missing" in hair.furcollide.status_message
    activate(hair)
    with pytest.raises(RuntimeError, match="output hair object is missing"):
        bpy.ops.furcollide.reset()
    with pytest.raises(RuntimeError, match="'Fur': the output hair object is missing"):
        bpy.ops.furcollide.bake()
    assert_unchanged(hair, groom, "after the output was removed")
    # Add FurCollide again: a new output, the same colliders, the same result
    scene.frame_set(1)
    activate(hair, box)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    out2 = hair.furcollide.output
    assert out2 is not None and out2.name in scene.objects
    same_frames(play_checked(scene, hair), ref)
    assert_unchanged(hair, groom, "after Add again")
    no_traceback(capsys)


@pytest.mark.parametrize("how", ["deleted_in_the_ui", "appended_without_its_output"])
def test_output_not_in_the_scene_is_reported(fc, how, tmp_path, capsys):
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    reference_frames(fc, scene, hair)
    if how == "deleted_in_the_ui":
        activate(out)
        hair.select_set(False)
        assert bpy.ops.object.delete() == {"FINISHED"}  # X > Delete in the viewport
    else:
        lib = save_as(tmp_path / "lib.blend")
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.frame_start, scene.frame_end = SHOT_FRAMES
        with bpy.data.libraries.load(lib, link=False) as (_src, dst):
            dst.objects = ["Fur", "Box"]  # the artist picks the hair and the box
        for o in dst.objects:
            scene.collection.objects.link(o)
        hair = bpy.data.objects["Fur"]
    groom = snapshot(hair)
    out = hair.furcollide.output
    assert out is not None and not out.users_scene  # alive, but in no scene
    for f in range(1, 5):
        scene.frame_set(f)
    no_traceback(capsys)
    assert_unchanged(hair, groom)
    # what the artist sees must say that the output is gone
    msg = hair.furcollide.status_message
    assert "output" in msg.lower(), repr(msg)


@pytest.mark.parametrize("whose", ["the_source", "another_groom"])
def test_output_data_replaced_never_writes_a_groom(fc, whose, capsys):
    """The output's curves data swapped (Object Data > browse) for the source's own
    data, or for another groom's: FurCollide must not write into either."""
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    other = make_hair("Groom", nx=2, ny=2, npts=4)
    other.location = (3, 0, 0)
    victim = hair if whose == "the_source" else other
    groom = snapshot(victim)
    out.data = victim.data
    for f in range(1, 7):
        scene.frame_set(f)
    no_traceback(capsys)
    assert_unchanged(victim, groom, "after playing")
    assert out.name in hair.furcollide.status_message, hair.furcollide.status_message


def test_linked_duplicate_of_the_output(fc, capsys):
    """Alt-D on the output: both objects show the result; Remove FurCollide keeps the
    duplicate with the last result; a full duplicate of the output is not a source."""
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    groom = snapshot(hair)
    ref = reference_frames(fc, scene, hair)
    twin = out.copy()  # Alt-D: a new object, the same curves data
    twin.name = "Twin"
    twin.location = (0, 3, 0)
    scene.collection.objects.link(twin)
    assert twin.data is out.data and out.data.users == 2
    same_frames(play_checked(scene, hair), ref)
    np.testing.assert_array_equal(positions(twin), ref[6])
    # the twin counts as the setup's output (it shares its data): Add is refused
    activate(twin)
    with pytest.raises(RuntimeError, match="is a FurCollide output; select its source"):
        bpy.ops.furcollide.add()
    # Shift-D of the output: its own data, never written
    copy = out.copy()
    copy.data = out.data.copy()
    copy.name = "Copy"
    scene.collection.objects.link(copy)
    frozen = positions(copy).copy()
    scene.frame_set(3)
    np.testing.assert_array_equal(positions(copy), frozen)
    # Remove on the source deletes the output object; the shared data stays with the twin
    activate(hair)
    assert bpy.ops.furcollide.remove() == {"FINISHED"}
    assert "Fur FurCollide" not in bpy.data.objects and twin.data is not None
    np.testing.assert_array_equal(positions(twin), ref[3])
    for f in (4, 5):
        scene.frame_set(f)  # nothing writes into the twin any more
    np.testing.assert_array_equal(positions(twin), ref[3])
    assert_unchanged(hair, groom)
    no_traceback(capsys)


@pytest.mark.parametrize("how", ["collection_disabled", "collection_excluded"])
def test_setup_in_a_disabled_collection_then_enabled(fc, how, capsys):
    """Source, output and collider in a collection that is disabled in viewports (or
    excluded from the view layer): playing skips the setup quietly and never writes;
    enabled again, it plays from the start as before."""
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc, collection="Setup")
    assert out.users_collection[0].name == "Setup"
    groom = snapshot(hair)
    ref = reference_frames(fc, scene, hair)
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    coll = bpy.data.collections["Setup"]
    layer = bpy.context.view_layer.layer_collection.children["Setup"]

    def disable(v):
        if how == "collection_disabled":
            coll.hide_viewport = v
        else:
            layer.exclude = v

    disable(True)
    frozen = positions(out).copy()
    for f in range(1, 7):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        np.testing.assert_array_equal(positions(out), frozen, err_msg=f"frame {f}")
    disable(False)
    scene.frame_set(4)  # a jump: frame 4 was never solved, so it is held and outdated
    assert hair.furcollide.is_outdated or hair.furcollide.status_message == ""
    same_frames(play_checked(scene, hair), ref)
    assert_unchanged(hair, groom)
    no_traceback(capsys)


@pytest.mark.parametrize("which", ["source", "collider"])
def test_source_or_collider_disabled_in_viewports_still_counts(fc, which, capsys):
    """The source (or the collider) disabled in viewports (monitor icon): the FurCollide
    Inputs modifier still brings it in, so the result does not change."""
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    ref = reference_frames(fc, scene, hair)
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    (hair if which == "source" else box).hide_viewport = True
    same_frames(play_checked(scene, hair), ref)
    (hair if which == "source" else box).hide_viewport = False
    same_frames(play_checked(scene, hair), ref)
    no_traceback(capsys)


def test_two_view_layers_setup_excluded_in_one(fc, capsys):
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc, collection="Setup")
    groom = snapshot(hair)
    ref = reference_frames(fc, scene, hair)
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    layer_a = bpy.context.view_layer
    layer_b = scene.view_layers.new("Background")
    layer_b.layer_collection.children["Setup"].exclude = True
    win = bpy.context.window
    win.view_layer = layer_b
    before = positions(out).copy()
    for f in range(1, 7):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        p = positions(out)  # untouched, or the very result of the layer that shows it
        assert np.array_equal(p, before) or np.array_equal(p, ref[f]), f
    win.view_layer = layer_a
    same_frames(play_checked(scene, hair), ref)
    # and the other way round: shown only in the second layer
    layer_a.layer_collection.children["Setup"].exclude = True
    layer_b.layer_collection.children["Setup"].exclude = False
    win.view_layer = layer_b
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    same_frames(play_checked(scene, hair), ref)
    assert_unchanged(hair, groom)
    no_traceback(capsys)


@pytest.mark.parametrize("name", list(_EXTREMES))
def test_extreme_valid_settings_give_finite_output(fc, name, capsys):
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    groom = snapshot(hair)
    s = hair.furcollide
    set_core(s, **_EXTREMES[name])
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    for f in list(range(1, 7)) + [3, 6]:
        scene.frame_set(f)
        assert s.status_message == "", (f, s.status_message)
        P = positions(out)
        assert np.isfinite(P).all(), f
        st = np.zeros(len(out.data.curves), np.int32)
        out.data.attributes["furcollide_status"].data.foreach_get("value", st)
        assert np.isin(st, list(Status)).all(), st
        # roots never move
        np.testing.assert_array_equal(P[offsets_of(out)[:-1]], groom[0][groom[1][:-1]])
    assert_unchanged(hair, groom)
    no_traceback(capsys)


# Undo needs a window (headless Blender has no undo stack): it is tested in the real
# application, tests/app/test_real_blender_ui.py (undo and redo of Add FurCollide and of a
# setting, frames played after each).


def test_remove_setup(fc):
    hair, box = fc.make_scene()
    out = fc.setup(hair, [box])
    name = out.name
    assert bpy.ops.furcollide.remove() == {"FINISHED"}
    assert name not in bpy.data.objects
    assert not hair.furcollide.is_setup and not hair.hide_render
