"""Files and scenes: two scenes in one file, scene copies, Save As / Save Copy / Revert,
moving a .blend with its bake, appended and library-linked setups, renames, the
add-on disabled and enabled again, an edit seen in a scene the window does not show."""

import os
import shutil
from pathlib import Path

import bpy
import numpy as np
import pytest
from helpers import (
    ADDON,
    SHOT_FRAMES,
    activate,
    assert_unchanged,
    bake_files,
    build_setup,
    draw_enabled,
    frames_on_disk,
    groom_scene,
    make_box,
    make_hair,
    make_surface,
    no_traceback,
    play_checked,
    positions,
    reference_frames,
    render_camera,
    reopen,
    same_frames,
    save_as,
    save_in,
    small_setup,
    snapshot,
    status_of,
    sweep_box,
    sweep_setup,
    world,
)

pytestmark = pytest.mark.blender




def _fc_handlers():
    return [h for h in bpy.app.handlers.frame_change_post
            if "furcollide" in getattr(h, "__module__", "")]


def input_objects(out):
    """Objects the output's FurCollide Inputs modifier references."""
    mod = out.modifiers.get("FurCollide Inputs")
    assert mod is not None and mod.node_group is not None, [m.name for m in out.modifiers]
    return {n.inputs["Object"].default_value for n in mod.node_group.nodes
            if n.bl_idname == "GeometryNodeObjectInfo"}


def _depsgraph_update(ob):
    """An edit that fires depsgraph_update_post (as any click in the UI does)."""
    ob.location.x += 0.0
    bpy.context.view_layer.update()


def _library_then_new_file(fc, tmp_path):
    """A setup saved as lib.blend, then a new empty file with the same frame range;
    returns (the library's path, the setup's reference result)."""
    hair, box, out = sweep_setup(fc)
    ref = reference_frames(fc, bpy.context.scene, hair)
    lib = save_as(tmp_path / "lib.blend")
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = SHOT_FRAMES
    return lib, ref


def test_an_edit_in_a_scene_the_window_does_not_show_is_seen_at_its_own_frame(fc):
    """The depsgraph check of scene B, while the window shows scene A at another frame,
    compares B's collider with what B's frame handler saw at B's current frame (6),
    not at A's: an update that changes nothing keeps B's cache, an edit drops it and
    names the collider."""
    win = bpy.context.window
    sc_a = bpy.context.scene
    sc_b = bpy.data.scenes.new("B")
    win.scene = sc_b
    hair, box = fc.make_scene(frames=(1, 8))  # in B, the window's scene now
    fc.setup(hair, [box])
    for f in range(1, 7):
        sc_b.frame_set(f)
    rt = fc.store.registry.get_runtime(hair)
    assert sorted(rt.cache.memory.frames) == [1, 2, 3, 4, 5, 6]
    win.scene = sc_a
    sc_a.frame_set(2)
    assert bpy.context.scene == sc_a and sc_b.frame_current == 6
    box.data.update()  # re-evaluated, unchanged
    sc_b.view_layers[0].depsgraph.update()
    assert sorted(rt.cache.memory.frames) == [1, 2, 3, 4, 5, 6]
    box.data.vertices[0].co.z += 0.01  # an edit of B's collider, seen by B's depsgraph
    box.data.update()
    sc_b.view_layers[0].depsgraph.update()
    assert len(rt.cache.memory) == 0
    assert "Frame 6 is outdated: 'Box' changed shape" in hair.furcollide.status_message


def test_moved_blend_with_its_bake_and_without(fc, tmp_path, capsys):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    a.mkdir()
    c.mkdir()
    hair, box, out = small_setup(fc, frames=(1, 6))
    path = save_in(a)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    s = hair.furcollide
    assert s.bake_path.startswith("//")  # relative: it moves with the file
    d = bpy.path.abspath(s.bake_path)
    baked = {f: fc.cache.read_frame(d, f)[0] for f in range(1, 7)}
    bpy.context.scene.frame_set(1)
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    shutil.move(str(a), str(b))  # the .blend and furcollide_cache/ together
    reopen(str(b / os.path.basename(path)))
    hair = bpy.data.objects["Fur"]
    out, s = hair.furcollide.output, hair.furcollide
    assert s.is_baked
    for f in (4, 1, 6, 2, 5, 3):
        bpy.context.scene.frame_set(f)
        np.testing.assert_array_equal(fc.positions(out), baked[f], err_msg=f"frame {f}")
        assert s.status_message == ""

    # now only the .blend moves: the bake is left behind in b/
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    shutil.move(str(b / "shot.blend"), str(c / "shot.blend"))
    capsys.readouterr()
    reopen(str(c / "shot.blend"))
    hair = bpy.data.objects["Fur"]
    s = hair.furcollide
    for f in (3, 4):
        bpy.context.scene.frame_set(f)
        level, msg = fc.store.report.status_for(hair)
        assert level == "ERROR" and "missing" in msg, msg
        assert str(c / "furcollide_cache") in msg  # where they were looked for
        assert s.is_outdated
    err = capsys.readouterr()
    assert "Traceback" not in err.err + err.out
    activate(hair)
    labels = [e[1] for e in draw_enabled(bpy.types.FURCOLLIDE_PT_cache) if e[0] == "label"]
    assert "0 of 6 frames baked" in labels
    # Free Bake (nothing left to delete here) and play: the same frames, solved again
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    out = s.output
    for f in range(1, 7):
        bpy.context.scene.frame_set(f)
        assert s.status_message == "", (f, s.status_message)
        np.testing.assert_array_equal(fc.positions(out), baked[f], err_msg=f"frame {f}")
    assert os.path.isdir(b / "furcollide_cache")  # the other copy's bake is untouched


def test_two_scenes_keep_their_setups_and_outputs_apart(fc, tmp_path):
    win = bpy.context.window
    sc_a = bpy.context.scene
    sc_a.name = "A"
    hair_a, _box_a, out_a = build_setup(fc, "A")
    sc_b = bpy.data.scenes.new("B")
    win.scene = sc_b
    hair_b, _box_b, out_b = build_setup(fc, "B")
    assert fc.store.registry.setups(sc_a) == [hair_a] and fc.store.registry.setups(sc_b) == [hair_b]
    path = save_as(tmp_path / "two.blend")

    # playing B never evaluates A
    rest_a = fc.positions(out_a).copy()
    rt_a = fc.store.registry.get_runtime(hair_a)
    frames_a = sorted(rt_a.cache.memory.frames)  # the add operator solved frame 1
    for f in range(1, 7):
        sc_b.frame_set(f)
        assert hair_b.furcollide.status_message == "", (f, hair_b.furcollide.status_message)
    assert len(fc.store.registry.get_runtime(hair_b).cache.memory) == 6
    assert sorted(rt_a.cache.memory.frames) == frames_a and sc_a.frame_current == 1
    np.testing.assert_array_equal(fc.positions(out_a), rest_a)
    moved_b = fc.positions(out_b).copy()
    assert not np.array_equal(moved_b, fc.positions(hair_b)), "the box never touched B"

    # Bake All bakes every unbaked setup of *the scene* (README): B only
    assert bpy.ops.furcollide.bake_all() == {"FINISHED"}
    assert hair_b.furcollide.is_baked and not hair_a.furcollide.is_baked
    assert hair_a.furcollide.bake_path == ""
    dir_b = bpy.path.abspath(hair_b.furcollide.bake_path)
    assert len(bake_files(dir_b)) == 6
    assert not os.path.exists(fc.store.bake.bake_directory(hair_a))
    np.testing.assert_array_equal(fc.positions(out_a), rest_a)

    # now bake A from A: B's frame, bake and output stay as they were
    sc_b.frame_set(4)
    out_b_4 = fc.positions(out_b).copy()
    win.scene = sc_a
    activate(hair_a)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert hair_a.furcollide.is_baked and sc_b.frame_current == 4
    np.testing.assert_array_equal(fc.positions(out_b), out_b_4)
    assert len(bake_files(dir_b)) == 6
    dir_a = bpy.path.abspath(hair_a.furcollide.bake_path)
    assert dir_a != dir_b and len(bake_files(dir_a)) == 6
    # freeing B's bake from B leaves A's files
    win.scene = sc_b
    assert bpy.ops.furcollide.free_bake_all() == {"FINISHED"}
    assert bake_files(dir_b) == [] and len(bake_files(dir_a)) == 6 and hair_a.furcollide.is_baked

    # the CLI bakes the file's active scene only (like Bake All)
    reopen(path)  # saved with B active and nothing baked
    assert bpy.context.scene.name == "B"
    assert fc.ops.cli.run(["bake", path]) == 0
    reopen(path)
    a, b = bpy.data.objects["AFur"].furcollide, bpy.data.objects["BFur"].furcollide
    assert b.is_baked and not a.is_baked and a.bake_path == ""
    assert fc.ops.cli.run(["info", path, "--scene", "Nope"]) == 2


def test_addon_disable_enable_with_operators_registers_handlers_once(fc):
    hair, _box, out = build_setup(fc, "")
    scene = bpy.context.scene
    for f in range(1, 4):
        scene.frame_set(f)
    assert len(_fc_handlers()) == 1
    for _ in range(2):
        assert bpy.ops.preferences.addon_disable(module=ADDON) == {"FINISHED"}
        assert _fc_handlers() == []
        scene.frame_set(2)  # nothing runs, nothing breaks
        assert bpy.ops.preferences.addon_enable(module=ADDON) == {"FINISHED"}
        assert len(_fc_handlers()) == 1
        for name in ("depsgraph_update_post", "load_post", "save_pre"):
            lst = getattr(bpy.app.handlers, name)
            mine = [h.__name__ for h in lst if "furcollide" in getattr(h, "__module__", "")]
            assert mine and len(mine) == len(set(mine)), (name, mine)  # each one once
    # the setup still plays after re-enabling, from the start frame
    s = hair.furcollide
    assert s.is_setup and s.output == out
    moved = False
    for f in range(1, 7):
        scene.frame_set(f)
        assert s.status_message == "", (f, s.status_message)
        assert s.stat_frame == f
        moved |= not np.array_equal(fc.positions(out), fc.positions(hair))
    assert moved, "the setup did not collide after re-enabling"
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}


@pytest.mark.parametrize("kind", ["FULL_COPY", "LINK_COPY"])
def test_scene_copy_plays_in_both_scenes_or_shows_the_source(fc, kind, capsys):
    """A full copy has its own setup (its own hair, output and box) and plays in both
    scenes. A linked copy holds the same objects, so the setup stays the first scene's
    (a hair can be set up in one scene only): the copy shows the source as groomed and
    says where the setup is, and the first scene still plays its frames."""
    scene_a = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    groom = snapshot(hair)
    ref = reference_frames(fc, scene_a, hair)
    assert bpy.ops.scene.new(type=kind) == {"FINISHED"}
    scene_b = bpy.context.scene
    assert scene_b != scene_a
    if kind == "FULL_COPY":
        (hair_b,) = fc.store.registry.setups(scene_b)
        assert hair_b != hair and hair_b.furcollide.output not in (None, out)
        assert hair_b.furcollide.output.furcollide.source == hair_b
        assert [c.object.name for c in hair_b.furcollide.colliders] == ["Box.001"]
        same_frames(play_checked(scene_b, hair_b), ref)
        assert hair_b.furcollide.owner_scene == scene_b.name
    else:
        assert fc.store.registry.setups(scene_b) == []
        assert fc.store.registry.setups(scene_b, owned=False) == [hair]  # the same objects
        for f in range(1, 7):
            scene_b.frame_set(f)
            np.testing.assert_array_equal(positions(out), positions(hair), err_msg=f"{f}")
            assert f"is set up in scene '{scene_a.name}'" in hair.furcollide.status_message
    bpy.context.window.scene = scene_a
    same_frames(play_checked(scene_a, hair), ref)
    if kind == "FULL_COPY":  # playing A never touched B's output
        np.testing.assert_array_equal(positions(hair_b.furcollide.output), ref[6])
    assert_unchanged(hair, groom)
    no_traceback(capsys)


def test_full_copy_each_output_references_its_own_inputs(fc):
    scene_a = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    assert bpy.ops.scene.new(type="FULL_COPY") == {"FINISHED"}
    scene_b = bpy.context.scene
    hair_b = bpy.data.objects["Fur.001"]
    box_b = bpy.data.objects["Box.001"]
    _depsgraph_update(box_b)  # any edit in B
    bpy.context.window.scene = scene_a
    _depsgraph_update(box)  # any edit in A
    assert {hair, box} <= input_objects(out)
    bpy.context.window.scene = scene_b
    assert {hair_b, box_b} <= input_objects(hair_b.furcollide.output)


def test_save_as_to_another_folder_mid_session(fc, tmp_path, capsys):
    """No bake yet: the playback cache survives Save As, and the next bake goes next to
    the new file (nothing is written next to the old one)."""
    scene = bpy.context.scene
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    hair, box, out = sweep_setup(fc)
    save_as(a / "shot.blend")
    ref = reference_frames(fc, scene, hair)
    scene.frame_set(4)
    save_as(b / "shot_v2.blend")
    for f in (2, 6, 1, 5):  # cached frames, exactly
        scene.frame_set(f)
        assert hair.furcollide.status_message == ""
        np.testing.assert_array_equal(positions(out), ref[f], err_msg=f"frame {f}")
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    assert d.startswith(str(b)) and len(frames_on_disk(d)) == 6
    assert not os.path.exists(a / "furcollide_cache")
    no_traceback(capsys)


def test_save_as_to_another_folder_keeps_the_bake(fc, tmp_path, capsys):
    scene = bpy.context.scene
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    hair, box, out = sweep_setup(fc)
    save_as(a / "shot.blend")
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    baked = {f: fc.cache.read_frame(d, f)[0] for f in range(1, 7)}
    save_as(b / "shot_v2.blend")  # File > Save As, Remap Relative on (the default)
    problems = []
    for f in (3, 6, 1):
        scene.frame_set(f)
        msg = hair.furcollide.status_message
        if msg:
            problems.append((f, msg))
    no_traceback(capsys)
    assert len(frames_on_disk(d)) == 6  # the old file's bake is never touched
    assert problems == []
    for f in (2, 5):
        scene.frame_set(f)
        np.testing.assert_allclose(positions(out), baked[f], atol=1e-6)


def test_save_copy_to_another_folder_keeps_both_bakes_readable(fc, tmp_path, capsys):
    """File > Save Copy into another folder: the copy reads the same bake files,
    and the open file (still the original) keeps reading them too."""
    a, c = tmp_path / "a", tmp_path / "c" / "deeper"
    a.mkdir()
    c.mkdir(parents=True)
    hair, box, out = sweep_setup(fc)
    save_as(a / "shot.blend")
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    path = hair.furcollide.bake_path
    d = bpy.path.abspath(path)
    baked = {f: fc.cache.read_frame(d, f)[0] for f in range(1, 7)}
    bpy.ops.wm.save_as_mainfile(filepath=str(c / "copy.blend"), copy=True)
    assert bpy.data.filepath == str(a / "shot.blend")
    assert hair.furcollide.bake_path == path  # the open file is unchanged
    bpy.ops.wm.open_mainfile(filepath=str(c / "copy.blend"))
    hair = bpy.data.objects["Fur"]
    assert os.path.normpath(bpy.path.abspath(hair.furcollide.bake_path)) == os.path.normpath(d)
    out = hair.furcollide.output
    for f in (4, 2):
        bpy.context.scene.frame_set(f)
        assert hair.furcollide.status_message == ""
        np.testing.assert_allclose(positions(out), baked[f], atol=1e-6)
    no_traceback(capsys)


def test_revert_after_edits(fc, tmp_path, capsys):
    """Edits after the last save (settings, colliders, a moved source curve), then
    File > Revert: the saved setup comes back and plays the saved result."""
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    path = save_as(tmp_path / "shot.blend")
    ref = reference_frames(fc, scene, hair)
    groom = snapshot(hair)
    s = hair.furcollide
    s.mode = "SOFT"
    s.colliders[0].enabled = False
    extra = make_box("Extra", size=0.3, location=(0.2, 0.2, 0.3))
    activate(hair, extra)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    P = positions(hair)
    P[1] += (0.05, 0, 0)
    hair.data.position_data.foreach_set("vector", P.ravel())
    hair.data.update_tag()
    play_checked(scene, hair, range(1, 4))
    assert bpy.ops.wm.revert_mainfile() == {"FINISHED"}
    assert bpy.data.filepath == path
    hair = bpy.data.objects["Fur"]
    s = hair.furcollide
    assert s.mode == "BEND" and [c.object.name for c in s.colliders] == ["Box"]
    assert s.colliders[0].enabled and "Extra" not in bpy.data.objects
    assert_unchanged(hair, groom, "after Revert")
    scene = bpy.context.scene
    same_frames(play_checked(scene, hair), ref)
    no_traceback(capsys)


def test_appended_setup_plays_and_bakes_in_another_file(fc, tmp_path, capsys):
    lib, ref = _library_then_new_file(fc, tmp_path)
    save_as(tmp_path / "shot.blend")
    scene = bpy.context.scene
    with bpy.data.libraries.load(lib, link=False) as (_src, dst):
        dst.objects = ["Fur", "Fur FurCollide", "Box"]
    for o in dst.objects:
        scene.collection.objects.link(o)
    hair = bpy.data.objects["Fur"]
    assert hair.library is None and hair.furcollide.output.name == "Fur FurCollide"
    groom = snapshot(hair)
    same_frames(play_checked(scene, hair), ref)
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    assert d.startswith(str(tmp_path / "furcollide_cache" / "shot"))
    assert len(frames_on_disk(d)) == 6
    same_frames(play_checked(scene, hair), ref)
    assert_unchanged(hair, groom)
    no_traceback(capsys)


def test_library_linked_setup_is_reported(fc, tmp_path, capsys):
    lib, ref = _library_then_new_file(fc, tmp_path)
    scene = bpy.context.scene
    with bpy.data.libraries.load(lib, link=True) as (_src, dst):
        dst.objects = ["Fur", "Fur FurCollide", "Box"]
    for o in dst.objects:
        scene.collection.objects.link(o)
    hair = bpy.data.objects["Fur"]
    assert hair.library is not None
    groom = snapshot(hair)
    msgs = {}
    got = {}
    for f in range(1, 7):
        scene.frame_set(f)
        msgs[f] = hair.furcollide.status_message
        got[f] = positions(hair.furcollide.output).copy()
    no_traceback(capsys)
    assert_unchanged(hair, groom)
    for f in range(1, 7):  # either it shows the result, or it says why it cannot
        if not np.array_equal(got[f], ref[f]):
            assert "lib" in msgs[f].lower() or "linked" in msgs[f].lower(), (f, msgs[f])


def test_renames_while_playing_and_after_a_bake(fc, tmp_path, capsys):
    """Source, output and collider objects and their data renamed between frames (odd
    characters too): nothing is dropped or solved differently; a bake made under one
    name is found and freed under another."""
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    save_as(tmp_path / "shot.blend")
    ref = reference_frames(fc, scene, hair)
    groom = snapshot(hair)
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    renames = [(hair, "Fell/ü: 1"), (hair.data, "Fell Data"), (out, "Result"),
               (out.data, "Result Data"), (box, "Kiste"), (box.data, "Kiste Mesh")]
    for f in range(1, 7):
        ob, name = renames[f - 1]
        ob.name = name
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        np.testing.assert_array_equal(positions(out), ref[f], err_msg=f"frame {f}")
    box.name = "Kiste 2"  # after the play: scrubbing back is still exact
    same_frames(play_checked(scene, hair, (3, 1, 6, 2)), ref)
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    assert os.path.basename(d).startswith("Fell_1_") and len(frames_on_disk(d)) == 6
    hair.name, box.name, out.name = "Third Name", "Box 3", "Out 3"
    same_frames(play_checked(scene, hair, (2, 5)), ref)
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    assert frames_on_disk(d) == []
    assert_unchanged(hair, groom)
    no_traceback(capsys)


def test_renaming_the_surface_keeps_the_playback_cache(fc, capsys):
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc)
    hair.data.surface = make_surface("Skin", half=1.0, n=2)
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    ref = reference_frames(fc, scene, hair)
    hair.data.surface.name = "Haut"  # renamed at frame 1: nothing changes
    for f in (3, 6, 2):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        np.testing.assert_array_equal(positions(out), ref[f], err_msg=f"frame {f}")
    no_traceback(capsys)


def test_disable_enable_cleans_up_and_keeps_data(fc):
    import addon_utils

    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    hair.furcollide.plasticity = 0.7
    name = fc.package.__name__
    addon_utils.disable(name, default_set=True)
    try:
        for lst in (bpy.app.handlers.frame_change_post, bpy.app.handlers.load_post,
                    bpy.app.handlers.depsgraph_update_post):
            assert not any("furcollide" in getattr(h, "__module__", "") for h in lst)
        assert not hasattr(bpy.types.Object, "furcollide")
        assert not hasattr(bpy.types, "FURCOLLIDE_OT_add")
        assert not hasattr(bpy.types, "FURCOLLIDE_PT_main")
        bpy.context.scene.frame_set(3)  # nothing runs, nothing breaks
    finally:
        assert addon_utils.enable(name, default_set=True, handle_error=None) is not None
    s = bpy.data.objects["Fur"].furcollide
    assert s.is_setup and s.plasticity == pytest.approx(0.7)
    bpy.context.scene.frame_set(1)
    assert s.stat_frame == 1


# ------------------------------------------- one hair in several scenes (shots)
def _two_shots(fc):
    """A character collection (the hair) linked into shot A, which has a sweeping ball,
    and into shot B, which has none; the setup made in A, the window showing A.
    Returns (A, B, hair, ball, out)."""
    sc_a = bpy.context.scene
    sc_a.name = "A"
    sc_a.frame_start, sc_a.frame_end = SHOT_FRAMES
    char = bpy.data.collections.new("Character")
    sc_a.collection.children.link(char)
    hair = make_hair("Fur", nx=4, ny=4)
    char.objects.link(hair)
    sc_a.collection.objects.unlink(hair)
    ball = sweep_box("Ball", -1.2, 1.2, SHOT_FRAMES)
    sc_b = bpy.data.scenes.new("B")
    sc_b.frame_start, sc_b.frame_end = SHOT_FRAMES
    sc_b.collection.children.link(char)
    sc_a.frame_set(1)
    out = fc.setup(hair, [ball])
    assert set(out.users_scene) == {sc_a, sc_b}  # (the output is the character's too)
    assert hair.furcollide.owner_scene == "A"
    return sc_a, sc_b, hair, ball, out


def _show(scene):
    """Show ``scene`` in the window (as the scene selector does: Blender evaluates its
    current frame, running the frame handlers)."""
    bpy.context.window.scene = scene
    assert bpy.context.scene == scene


def _cache_bits(rt):
    """Every cached frame of a runtime, as bytes (and its inputs record)."""
    return {f: (fr.curves.tobytes(), fr.points.tobytes(), fr.status_idx.tobytes(),
                fr.status_val.tobytes(), repr(fr.inputs))
            for f, fr in rt.cache.memory.frames.items()}


def _file_bits(d):
    """The bake files of directory ``d``: name -> bytes."""
    return {n: (d / n).read_bytes() for n in bake_files(str(d))}


def _counting_solves(fc, monkeypatch):
    calls = []
    real = fc.frame.solve.solve_frame

    def counting(setup, inp, **kw):
        calls.append((setup.scene.name, setup.frame))
        return real(setup, inp, **kw)

    monkeypatch.setattr(fc.frame.solve, "solve_frame", counting)
    return calls


def _refusal(op):
    """The poll message of operator ``op`` (a ``bpy.ops`` function), '' when it runs."""
    if op.poll():
        return ""
    with pytest.raises(RuntimeError) as err:
        op()
    return str(err.value)


SETUP_OPERATORS = ("bake", "free_bake", "reset", "remove", "collider_add", "collider_remove",
                   "fur_attach_bind", "fur_attach_unbind", "groom_bind", "groom_remove",
                   "collider_distance", "children_from_guides")


def test_playing_another_shot_never_touches_the_setup(fc, monkeypatch, capsys):
    """The hair is also in shot B. Playing B shows the source as groomed there (the ball
    is not in B), solves nothing and leaves A's playback cache bit for bit; every
    operator that would touch the setup refuses in B naming A; showing A again shows
    A's frame at once, from its cache."""
    sc_a, sc_b, hair, ball, out = _two_shots(fc)
    played = play_checked(sc_a, hair)
    assert any(not np.array_equal(p, positions(hair)) for p in played.values())
    sc_a.frame_set(4)
    rt = fc.store.registry.get_runtime(hair)
    before = _cache_bits(rt)
    assert sorted(before) == list(range(1, 7))
    solves = _counting_solves(fc, monkeypatch)

    _show(sc_b)  # at B's frame 1
    np.testing.assert_array_equal(positions(out), positions(hair))
    msg = hair.furcollide.status_message
    assert msg.startswith("'Fur' is set up in scene 'A' (a hair can be set up in one scene "
                          "only): here it shows its source as groomed, without collisions")
    assert "Free" not in msg and not hair.furcollide.is_outdated
    setups = fc.store.registry.setups
    assert setups(sc_b) == [] and setups(sc_b, owned=False) == [hair]
    activate(hair)
    for name in SETUP_OPERATORS:
        why = _refusal(getattr(bpy.ops.furcollide, name))
        assert "'Fur' is set up in scene 'A'" in why and "switch to scene 'A'" in why, (name, why)
    assert "set up in scene 'A'" in _refusal(bpy.ops.furcollide.add)
    for name in ("bake_all", "free_bake_all"):
        assert "('Fur' is set up in scene 'A')" in _refusal(getattr(bpy.ops.furcollide, name))
    for f in (2, 3, 6, 5, 1):
        sc_b.frame_set(f)
        np.testing.assert_array_equal(positions(out), positions(hair), err_msg=f"B {f}")
        assert status_of(out).max() == 0  # (every curve FREE: nothing collided)
    for dx in (0.1, -0.1):  # updates seen by B's depsgraph are not B's to judge
        ball.location.x += dx
        hair.data.update_tag()
        bpy.context.view_layer.update()
    assert solves == [] and _cache_bits(rt) == before

    _show(sc_a)  # back at A's frame 4: A's cached frame, at once
    np.testing.assert_array_equal(positions(out), played[4])
    assert hair.furcollide.status_message == ""
    same_frames(play_checked(sc_a, hair), played)
    assert solves == [] and _cache_bits(rt) == before
    no_traceback(capsys)


def test_a_bake_of_one_shot_is_neither_shown_nor_freed_in_another(fc, tmp_path, capsys):
    """Baked in A. Shown in B, the output is the source (no dent of a ball B does not
    have), nothing is outdated and no advice deletes A's bake: every operator the panels
    draw that runs in B, and the command line on B, leave A's bake files as they were.
    Shown again, A shows its bake."""
    sc_a, sc_b, hair, ball, out = _two_shots(fc)
    path = save_as(tmp_path / "shots.blend")
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = Path(bpy.path.abspath(hair.furcollide.bake_path))
    files = _file_bits(d)
    assert len(files) == 6
    baked = {f: fc.cache.read_frame(str(d), f)[0] for f in range(1, 7)}
    sc_a.frame_set(3)
    np.testing.assert_array_equal(positions(out), baked[3])

    _show(sc_b)
    for f in range(1, 7):
        sc_b.frame_set(f)
        np.testing.assert_array_equal(positions(out), positions(hair), err_msg=f"B {f}")
        assert not hair.furcollide.is_outdated
        assert "Free" not in hair.furcollide.status_message
    activate(hair)
    ran = []
    for panel in [c for c in bpy.types.Panel.__subclasses__()
                  if c.__name__.startswith("FURCOLLIDE_PT")]:
        for kind, name, enabled in draw_enabled(panel):
            if kind == "label" and name:
                assert "Free Bake" not in name, (panel.__name__, name)
            if kind != "operator" or not enabled or not name.startswith("furcollide."):
                continue
            op = getattr(bpy.ops.furcollide, name.partition(".")[2])
            if op.poll():  # (what B lets anyone press)
                ran.append(name)
                op()
    assert "furcollide.free_bake" not in ran and "furcollide.bake" not in ran, ran
    assert _file_bits(d) == files and hair.furcollide.is_baked
    bpy.ops.wm.save_mainfile()  # saved showing B: the command line's default scene
    for args in (["bake", path], ["bake", path, "--scene", "B", "--force"],
                 ["free", path, "--scene", "B"], ["free", path, "--object", "Fur"]):
        capsys.readouterr()
        assert fc.ops.cli.run(args) == 2, args
        err = capsys.readouterr().err
        assert "'Fur' is set up in scene 'A', not 'B'" in err and "--scene 'A'" in err, err
        assert _file_bits(d) == files, args
    reopen(path)
    sc_a, sc_b = bpy.data.scenes["A"], bpy.data.scenes["B"]
    hair = bpy.data.objects["Fur"]
    out = hair.furcollide.output
    assert bpy.context.scene == sc_b and hair.furcollide.is_baked
    sc_b.frame_set(2)
    np.testing.assert_array_equal(positions(out), positions(hair))

    _show(sc_a)  # at A's frame 3
    np.testing.assert_array_equal(positions(out), baked[3])
    assert hair.furcollide.status_message == ""
    for f in (5, 1):
        sc_a.frame_set(f)
        np.testing.assert_array_equal(positions(out), baked[f], err_msg=f"A {f}")
    assert _file_bits(d) == files
    no_traceback(capsys)


def test_a_setup_of_an_older_file_belongs_to_the_scene_of_its_colliders(fc):
    """A setup made before FurCollide recorded its scene (``owner_scene`` empty): it
    belongs to the scene that holds its hair and the most of its colliders, even when
    another scene is evaluated first, and records it there; between equals, to the
    first scene that evaluates it."""
    sc_a, sc_b, hair, ball, out = _two_shots(fc)
    s = hair.furcollide
    s.owner_scene = ""
    _show(sc_b)  # B first: the ball is only in A
    np.testing.assert_array_equal(positions(out), positions(hair))
    assert "set up in scene 'A'" in s.status_message and s.owner_scene == ""
    _show(sc_a)
    assert s.owner_scene == "A"
    sc_b.collection.objects.link(ball)  # now both shots hold the ball: equals
    s.owner_scene = ""
    _show(sc_b)
    assert s.owner_scene == "B" and s.status_message == ""
    _show(sc_a)
    assert "set up in scene 'B'" in s.status_message
    sc_b.name = "Shot B"  # renamed: still the one
    _show(sc_b)
    assert s.owner_scene == "Shot B" and s.status_message == ""


def test_another_shot_renders_the_source_and_its_render_groom_unsolved(fc, tmp_path):
    """The guides, their render groom and its Surface in shot A with the box, and in
    shot B without it. In B both outputs follow the source as groomed (the render groom
    deformed by the uncollided guides, no clearance pass: every curve FREE), in the
    viewport and in B's render; A's outputs show A's solve again when A is shown."""
    guides, groom, box, out = groom_scene(fc)
    sc_a = bpy.context.scene
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    played = {}
    for f in range(1, 7):
        sc_a.frame_set(f)
        played[f] = (world(out).copy(), world(gout).copy(), status_of(gout).copy())
    assert played[6][2].any() and not np.array_equal(played[6][0], world(guides))
    sc_b = bpy.data.scenes.new("B")
    sc_b.frame_start, sc_b.frame_end = 1, 8
    for o in (guides, groom, guides.data.surface, out, gout):
        sc_b.collection.objects.link(o)
    sc_b.frame_current = 6
    _show(sc_b)
    np.testing.assert_array_equal(world(out), world(guides))
    np.testing.assert_allclose(world(gout), world(groom), atol=1e-5)  # at rest: as groomed
    assert not status_of(gout).any() and not status_of(out).any()
    render_camera(sc_b, px=16)
    seen = {}

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            seen[sc.frame_current] = (world(out).copy(), world(gout).copy())

    sc_b.render.filepath = str(tmp_path / "b.png")
    bpy.app.handlers.frame_change_post.append(spy)
    try:
        assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    np.testing.assert_array_equal(seen[6][0], world(guides))
    np.testing.assert_allclose(seen[6][1], world(groom), atol=1e-5)
    _show(sc_a)  # A at frame 6: its cached guides and the groom solved with them
    np.testing.assert_array_equal(world(out), played[6][0])
    np.testing.assert_array_equal(world(gout), played[6][1])
    np.testing.assert_array_equal(status_of(gout), played[6][2])
