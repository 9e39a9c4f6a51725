"""Still more flows: two scenes in one file, CLI ``--frames`` edge cases and a
file with two setups, a bake directory that cannot be written, disabling and
re-enabling the add-on, a collider in an excluded collection, and linked
duplicates (one mesh, two collider objects)."""

import os

import bpy
import numpy as np
import pytest
from conftest import ADDON, activate, bake_crashing_at, make_box, make_hair
from test_bl_flows2 import _free_curves_in_box, _world_bounds

pytestmark = pytest.mark.blender


# ------------------------------------------------------------------ helpers
def _sweep_box(name, x0, x1, frames=(1, 6), y=0.0, size=0.5):
    """A box sweeping from x0 to x1 (linear keys) at height 0.6."""
    box = make_box(name, size=size, location=(x0, y, 0.6))
    box.keyframe_insert("location", frame=frames[0])
    box.location = (x1, y, 0.6)
    box.keyframe_insert("location", frame=frames[1])
    act = box.animation_data.action
    for fcu in getattr(act, "fcurves", []):
        for k in fcu.keyframe_points:
            k.interpolation = "LINEAR"
    return box


def _build(fc, prefix, frames=(1, 6), nx=4, ny=4):
    """Hair + a sweeping box in the context scene, with a setup; returns (hair, box, out)."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    hair = make_hair(prefix + "Fur", nx=nx, ny=ny)
    box = _sweep_box(prefix + "Box", -1.2, 1.2, frames)
    scene.frame_set(frames[0])
    out = fc.setup(hair, [box])
    return hair, box, out


def _save(path):
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return str(path)


def _reopen(path):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=path)


def _files(d):
    return sorted(f for f in os.listdir(d) if f.startswith("frame_")) if os.path.isdir(d) else []


def _fc_handlers():
    return [h for h in bpy.app.handlers.frame_change_post
            if "furcollide" in getattr(h, "__module__", "")]


# ------------------------------------------------------- 1. two scenes, one file
def test_two_scenes_keep_their_setups_and_outputs_apart(fc, tmp_path):
    win = bpy.context.window
    sc_a = bpy.context.scene
    sc_a.name = "A"
    hair_a, _box_a, out_a = _build(fc, "A")
    sc_b = bpy.data.scenes.new("B")
    win.scene = sc_b
    hair_b, _box_b, out_b = _build(fc, "B")
    assert fc.registry.setups(sc_a) == [hair_a] and fc.registry.setups(sc_b) == [hair_b]
    path = _save(tmp_path / "two.blend")

    # playing B never evaluates A
    rest_a = fc.positions(out_a).copy()
    rt_a = fc.registry.get_runtime(hair_a)
    frames_a = sorted(rt_a.memory.frames)  # the add operator solved frame 1
    for f in range(1, 7):
        sc_b.frame_set(f)
        assert hair_b.furcollide.status_message == "", (f, hair_b.furcollide.status_message)
    assert len(fc.registry.get_runtime(hair_b).memory) == 6
    assert sorted(rt_a.memory.frames) == frames_a and sc_a.frame_current == 1
    np.testing.assert_array_equal(fc.positions(out_a), rest_a)
    moved_b = fc.positions(out_b).copy()
    assert not np.array_equal(moved_b, fc.positions(hair_b)), "the box never touched B"

    # Bake All bakes every unbaked setup of *the scene* (README): B only
    assert bpy.ops.furcollide.bake_all() == {"FINISHED"}
    assert hair_b.furcollide.is_baked and not hair_a.furcollide.is_baked
    assert hair_a.furcollide.bake_path == ""
    dir_b = bpy.path.abspath(hair_b.furcollide.bake_path)
    assert len(_files(dir_b)) == 6
    assert not os.path.exists(fc.bake.bake_directory(hair_a))
    np.testing.assert_array_equal(fc.positions(out_a), rest_a)

    # now bake A from A: B's frame, bake and output stay as they were
    sc_b.frame_set(4)
    out_b_4 = fc.positions(out_b).copy()
    win.scene = sc_a
    activate(hair_a)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert hair_a.furcollide.is_baked and sc_b.frame_current == 4
    np.testing.assert_array_equal(fc.positions(out_b), out_b_4)
    assert len(_files(dir_b)) == 6
    dir_a = bpy.path.abspath(hair_a.furcollide.bake_path)
    assert dir_a != dir_b and len(_files(dir_a)) == 6
    # freeing B's bake from B leaves A's files
    win.scene = sc_b
    assert bpy.ops.furcollide.free_bake_all() == {"FINISHED"}
    assert _files(dir_b) == [] and len(_files(dir_a)) == 6 and hair_a.furcollide.is_baked

    # the CLI bakes the file's active scene only (like Bake All)
    _reopen(path)  # saved with B active and nothing baked
    assert bpy.context.scene.name == "B"
    assert fc.cli.run(["bake", path]) == 0
    _reopen(path)
    a, b = bpy.data.objects["AFur"].furcollide, bpy.data.objects["BFur"].furcollide
    assert b.is_baked and not a.is_baked and a.bake_path == ""
    assert fc.cli.run(["info", path, "--scene", "Nope"]) == 2


def _two_scene_file(fc, tmp_path):
    win = bpy.context.window
    bpy.context.scene.name = "A"
    _build(fc, "A")
    win.scene = bpy.data.scenes.new("B")
    _build(fc, "B")
    return _save(tmp_path / "two.blend")  # B is the file's active scene


def test_cli_scene_option_bakes_a_non_active_scene(fc, tmp_path, capsys):
    path = _two_scene_file(fc, tmp_path)
    capsys.readouterr()
    code = fc.cli.run(["bake", path, "--scene", "A"])
    err = capsys.readouterr().err
    assert code == 0, err
    _reopen(path)
    assert bpy.data.objects["AFur"].furcollide.is_baked
    assert not bpy.data.objects["BFur"].furcollide.is_baked


# --------------------------------------------------- 2. CLI --frames and two setups
def _two_setups_file(fc, tmp_path, name="pair.blend"):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    hair_a = make_hair("FurA", nx=3, ny=3)
    hair_b = make_hair("FurB", nx=3, ny=3)
    hair_b.location = (0, 3, 0)
    box_a = _sweep_box("BoxA", -1.0, 1.0)
    box_b = _sweep_box("BoxB", -1.0, 1.0, y=3.0)
    scene.frame_set(1)
    fc.setup(hair_a, [box_a])
    fc.setup(hair_b, [box_b])
    return _save(tmp_path / name)


def _setup_state(path, name):
    _reopen(path)
    s = bpy.data.objects[name].furcollide
    return s.is_baked, (s.frame_start, s.frame_end)


@pytest.mark.parametrize("text, frames", [("3", (3, 3)), ("1-1", (1, 1)),
                                          ("20-22", (20, 22)), (" 2 - 4 ", (2, 4)),
                                          ("-2-1", (-2, 1))])
def test_cli_frames_accepted(fc, tmp_path, capsys, text, frames):
    path = _two_setups_file(fc, tmp_path)
    # out of the scene's range is fine too: --frames overrides the baked range
    assert fc.cli.run(["bake", path, f"--frames={text}", "--object", "FurA"]) == 0
    out = capsys.readouterr().out
    n = frames[1] - frames[0] + 1
    assert f"frame {frames[1]} ({n}/{n})" in out and "baked FurA" in out
    assert _setup_state(path, "FurA") == (True, frames)
    d = bpy.path.abspath(bpy.data.objects["FurA"].furcollide.bake_path)
    assert _files(d) == sorted(f"frame_{f:06d}.npz" for f in range(frames[0], frames[1] + 1))


@pytest.mark.parametrize("text, message", [
    ("5-2", "--frames end 2 is before start 5"),
    ("abc", "--frames must look like 1-240, got 'abc'"),
    ("1-x", "--frames must look like 1-240, got '1-x'"),
    ("1-2-3", "--frames must look like 1-240"),
    ("1.5-3", "--frames must look like 1-240"),
    ("4--", "--frames must look like 1-240"),
    ("", "--frames must look like 1-240"),
    ("-3--5", "--frames end -5 is before start -3"),
])
def test_cli_frames_rejected(fc, tmp_path, capsys, text, message):
    path = _two_setups_file(fc, tmp_path)
    before = os.path.getmtime(path)
    assert fc.cli.run(["bake", path, f"--frames={text}"]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert os.path.getmtime(path) == before  # never opened nor saved
    assert _setup_state(path, "FurA") == (False, (1, 6))
    assert _setup_state(path, "FurB") == (False, (1, 6))


def test_cli_info_lists_both_setups_and_object_bakes_one(fc, tmp_path, capsys):
    path = _two_setups_file(fc, tmp_path)
    capsys.readouterr()
    assert fc.cli.run(["info", path]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("Fur")]
    assert sorted(ln.split(":")[0] for ln in lines) == ["FurA", "FurB"]
    assert all("frames 1-6, not baked, 0 files" in ln for ln in lines), lines
    assert any("colliders BoxA" in ln for ln in lines)
    assert any("colliders BoxB" in ln for ln in lines)

    assert fc.cli.run(["bake", path, "--object", "FurB", "--frames", "2-5"]) == 0
    out = capsys.readouterr().out
    assert "baked FurB" in out and "FurCollide bake 'FurA'" not in out
    _reopen(path)
    a, b = bpy.data.objects["FurA"].furcollide, bpy.data.objects["FurB"].furcollide
    assert b.is_baked and (b.frame_start, b.frame_end) == (2, 5)
    assert not a.is_baked and a.bake_path == "" and (a.frame_start, a.frame_end) == (1, 6)
    assert not os.path.exists(fc.bake.bake_directory(bpy.data.objects["FurA"]))
    assert fc.cli.run(["info", path]) == 0
    info = capsys.readouterr().out
    assert "FurA: frames 1-6, not baked, 0 files" in info
    assert "FurB: frames 2-5, baked, 4 files" in info
    # --object on the other one bakes it; B is already baked and untouched
    assert fc.cli.run(["bake", path, "--object", "FurA"]) == 0
    assert "baked FurA" in capsys.readouterr().out
    assert _setup_state(path, "FurA") == (True, (1, 6))
    assert _setup_state(path, "FurB") == (True, (2, 5))


# ------------------------------------------- 3. a bake directory that cannot be written
def _partial_bake(fc, tmp_path, monkeypatch):
    hair, _box, _out = _build(fc, "")
    path = _save(tmp_path / "ro.blend")
    activate(hair)
    bake_crashing_at(fc, monkeypatch, 4)  # frames 1-3 on disk, bake_path kept
    bpy.ops.wm.save_mainfile()
    d = bpy.path.abspath(hair.furcollide.bake_path)
    assert _files(d) == [f"frame_{f:06d}.npz" for f in (1, 2, 3)]
    return path, d


def _cli_fails_naming(fc, capsys, path, target):
    capsys.readouterr()
    assert fc.cli.run(["bake", path]) == 1
    cap = capsys.readouterr()
    err = cap.err + cap.out
    assert "furcollide: bake failed: 'Fur' frame 4" in cap.err, cap.err
    assert target in cap.err
    assert "Traceback" not in err
    return cap


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores directory permissions")
def test_read_only_bake_directory(fc, tmp_path, monkeypatch, capsys):
    path, d = _partial_bake(fc, tmp_path, monkeypatch)
    os.chmod(d, 0o555)
    try:
        _cli_fails_naming(fc, capsys, path, os.path.join(d, "frame_000004.npz"))
        assert _files(d)[:3] == [f"frame_{f:06d}.npz" for f in (1, 2, 3)]
    finally:
        os.chmod(d, 0o755)
    assert fc.cli.run(["bake", path]) == 0
    assert "resuming after frame 3" in capsys.readouterr().out
    assert len(_files(d)) == 6


def test_unwritable_frame_path_keeps_finished_frames(fc, tmp_path, monkeypatch, capsys):
    """(Works as root too.) A directory where frame 4's file must go: the error names
    the path, frames 1-3 stay, exit 1, and the next run resumes."""
    path, d = _partial_bake(fc, tmp_path, monkeypatch)
    blocker = os.path.join(d, "frame_000004.npz")
    os.mkdir(blocker)
    _cli_fails_naming(fc, capsys, path, blocker)
    assert [f for f in _files(d) if f.endswith(".npz")][:3] == \
        [f"frame_{f:06d}.npz" for f in (1, 2, 3)]
    _reopen(path)
    assert not bpy.data.objects["Fur"].furcollide.is_baked
    os.rmdir(blocker)
    assert fc.cli.run(["bake", path]) == 0
    assert "resuming after frame 3" in capsys.readouterr().out
    assert [f for f in _files(d) if f.endswith(".npz")] == \
        [f"frame_{f:06d}.npz" for f in range(1, 7)]


def test_file_where_the_bake_directory_should_be(fc, tmp_path, capsys):
    hair, _box, _out = _build(fc, "")
    blocker = tmp_path / "cache_is_a_file"
    blocker.write_text("not a directory")
    hair.furcollide.cache_directory = str(blocker) + os.sep
    path = _save(tmp_path / "blocked.blend")
    capsys.readouterr()
    assert fc.cli.run(["bake", path]) == 1
    cap = capsys.readouterr()
    assert "furcollide: bake failed: 'Fur' frame 1" in cap.err, cap.err
    assert str(blocker) in cap.err and "Traceback" not in cap.err + cap.out
    assert blocker.read_text() == "not a directory"
    # the operator: a report, no traceback
    _reopen(path)
    activate(bpy.data.objects["Fur"])
    with pytest.raises(RuntimeError, match="cache_is_a_file"):
        bpy.ops.furcollide.bake()
    assert not bpy.data.objects["Fur"].furcollide.is_baked


# --------------------------------------------- 4. disable / re-enable the add-on
def test_addon_disable_enable_with_operators_registers_handlers_once(fc):
    hair, _box, out = _build(fc, "")
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
        for name in ("depsgraph_update_post", "load_post"):
            lst = getattr(bpy.app.handlers, name)
            assert sum("furcollide" in getattr(h, "__module__", "") for h in lst) == 1, name
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


# --------------------------------------------- 5. a collider in an excluded collection
@pytest.mark.parametrize("how", ["list", "collection"])
def test_collider_in_an_excluded_collection(fc, how, capsys):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    hair = make_hair("Fur", nx=4, ny=4)
    box = _sweep_box("Box", -1.2, 1.2)
    coll = bpy.data.collections.new("Props")
    scene.collection.children.link(coll)
    coll.objects.link(box)
    scene.collection.objects.unlink(box)
    scene.frame_set(1)
    out = fc.setup(hair, [box] if how == "list" else [])
    if how == "collection":
        hair.furcollide.collider_collection = coll
    # reference: the collider counts while the collection is in the view layer
    ref = []
    for f in range(1, 7):
        scene.frame_set(f)
        ref.append(fc.positions(out).copy())
    assert any(not np.array_equal(p, fc.positions(hair)) for p in ref)

    bpy.context.view_layer.layer_collection.children["Props"].exclude = True
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    got = []
    for f in range(1, 7):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        got.append(fc.positions(out).copy())
    cap = capsys.readouterr()
    assert "Traceback" not in cap.out + cap.err
    # README: "Only meshes linked into the scene collide". The box is still linked into
    # the scene (only excluded from the view layer), so it keeps colliding.
    for f, (a, b) in enumerate(zip(ref, got, strict=True), 1):
        np.testing.assert_array_equal(a, b, err_msg=f"frame {f}")


# ------------------------------------------- 6. linked duplicates: one mesh, two objects
def test_linked_duplicate_colliders_both_collide(fc):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    hair = make_hair("Fur", nx=8, ny=4, spacing=0.2)
    left = _sweep_box("Left", -1.6, -0.4, size=0.3)
    right = left.copy()  # Alt-D: a new object sharing the mesh
    right.name = "Right"
    right.animation_data_clear()
    scene.collection.objects.link(right)
    right.location = (1.6, 0, 0.6)
    right.keyframe_insert("location", frame=1)
    right.location = (0.4, 0, 0.6)
    right.keyframe_insert("location", frame=6)
    right.scale = (1.2, 1.2, 1.2)
    assert right.data is left.data and left.data.users == 2
    scene.frame_set(1)
    out = fc.setup(hair, [left, right])
    assert [c.object.name for c in hair.furcollide.colliders] == ["Left", "Right"]
    rest = fc.positions(hair)
    for f in range(1, 7):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        for box in (left, right):
            lo, hi = _world_bounds(box)
            assert len(_free_curves_in_box(out, lo, hi)) == 0, (box.name, f)
    P = fc.positions(out)
    moved = np.linalg.norm(P - rest, axis=1) > 1e-4
    assert moved[rest[:, 0] < 0].any() and moved[rest[:, 0] > 0].any()
    rt = fc.registry.get_runtime(hair)
    assert {e.collider.name for e in rt.colliders.values()} == {"Left", "Right"}
    assert hair.furcollide.stat_colliding > 0
