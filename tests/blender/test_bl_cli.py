"""The command line (``blender -b --command furcollide ...``): exit codes, failures,
``--frames``, ``--scene``, ``--object``, ``info``, and ``bake_all`` from a Python
expression."""

import os

import bpy
import pytest
from helpers import bake_files, build_setup, make_hair, reopen, save_as, sweep_box

pytestmark = pytest.mark.blender




def _saved(fc, tmp_path, frames=(1, 6)):
    hair, box = fc.make_scene(frames=frames)
    fc.setup(hair, [box])
    path = str(tmp_path / "farm.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    return path


def _two_scene_file(fc, tmp_path):
    win = bpy.context.window
    bpy.context.scene.name = "A"
    build_setup(fc, "A")
    win.scene = bpy.data.scenes.new("B")
    build_setup(fc, "B")
    return save_as(tmp_path / "two.blend")  # B is the file's active scene


def _two_setups_file(fc, tmp_path, name="pair.blend"):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    hair_a = make_hair("FurA", nx=3, ny=3)
    hair_b = make_hair("FurB", nx=3, ny=3)
    hair_b.location = (0, 3, 0)
    box_a = sweep_box("BoxA", -1.0, 1.0, (1, 6))
    box_b = sweep_box("BoxB", -1.0, 1.0, (1, 6), y=3.0)
    scene.frame_set(1)
    fc.setup(hair_a, [box_a])
    fc.setup(hair_b, [box_b])
    return save_as(tmp_path / name)


def _setup_state(path, name):
    reopen(path)
    s = bpy.data.objects[name].furcollide
    return s.is_baked, (s.frame_start, s.frame_end)


def test_cli_bake_exit_codes(fc, tmp_path, capsys):
    assert fc.ops.cli._handle is not None  # registered with bpy.utils.register_cli_command
    path = _saved(fc, tmp_path)
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    assert fc.ops.cli.run(["bake", path, "--frames", "1-4"]) == 0
    out = capsys.readouterr().out
    assert "frame 4 (4/4)" in out and "baked Fur" in out
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    s = bpy.data.objects["Fur"].furcollide
    assert s.is_baked and (s.frame_start, s.frame_end) == (1, 4)
    assert fc.ops.cli.run(["info", path]) == 0
    assert "baked" in capsys.readouterr().out
    # already baked: success, nothing to do; --force re-bakes
    assert fc.ops.cli.run(["bake", path]) == 0
    assert fc.ops.cli.run(["bake", path, "--force", "--no-save"]) == 0
    assert fc.ops.cli.run(["free", path]) == 0
    bpy.ops.wm.open_mainfile(filepath=path)
    assert not bpy.data.objects["Fur"].furcollide.is_baked


def test_cli_failures(fc, tmp_path):
    assert fc.ops.cli.run(["bake", str(tmp_path / "missing.blend")]) == 2
    assert fc.ops.cli.run(["explode"]) == 2
    path = _saved(fc, tmp_path)
    assert fc.ops.cli.run(["bake", path, "--frames", "9-3"]) == 2
    assert fc.ops.cli.run(["bake", path, "--object", "Nope"]) == 2
    # a broken setup (its output object was deleted) fails with exit code 1
    bpy.ops.wm.open_mainfile(filepath=path)
    bpy.data.objects.remove(bpy.data.objects["Fur FurCollide"])
    bpy.ops.wm.save_mainfile()
    assert fc.ops.cli.run(["bake", path]) == 1
    empty = str(tmp_path / "empty.blend")
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.save_as_mainfile(filepath=empty)
    assert fc.ops.cli.run(["bake", empty]) == 2


def test_python_expr_bake_all(fc, tmp_path):
    # what `blender -b shot.blend --python-expr "import bpy; bpy.ops.furcollide.bake_all()"` runs
    path = _saved(fc, tmp_path)
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    assert bpy.ops.furcollide.bake_all() == {"FINISHED"}
    assert bpy.data.objects["Fur"].furcollide.is_baked


def test_cli_scene_option_bakes_a_non_active_scene(fc, tmp_path, capsys):
    path = _two_scene_file(fc, tmp_path)
    capsys.readouterr()
    code = fc.ops.cli.run(["bake", path, "--scene", "A"])
    err = capsys.readouterr().err
    assert code == 0, err
    reopen(path)
    assert bpy.data.objects["AFur"].furcollide.is_baked
    assert not bpy.data.objects["BFur"].furcollide.is_baked


@pytest.mark.parametrize("text, frames", [("3", (3, 3)), ("1-1", (1, 1)),
                                          ("20-22", (20, 22)), (" 2 - 4 ", (2, 4)),
                                          ("-2-1", (-2, 1))])
def test_cli_frames_accepted(fc, tmp_path, capsys, text, frames):
    path = _two_setups_file(fc, tmp_path)
    # out of the scene's range is fine too: --frames overrides the baked range
    assert fc.ops.cli.run(["bake", path, f"--frames={text}", "--object", "FurA"]) == 0
    out = capsys.readouterr().out
    n = frames[1] - frames[0] + 1
    assert f"frame {frames[1]} ({n}/{n})" in out and "baked FurA" in out
    assert _setup_state(path, "FurA") == (True, frames)
    d = bpy.path.abspath(bpy.data.objects["FurA"].furcollide.bake_path)
    assert bake_files(d) == sorted(f"frame_{f:06d}.npz" for f in range(frames[0], frames[1] + 1))


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
    assert fc.ops.cli.run(["bake", path, f"--frames={text}"]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert os.path.getmtime(path) == before  # never opened nor saved
    assert _setup_state(path, "FurA") == (False, (1, 6))
    assert _setup_state(path, "FurB") == (False, (1, 6))


def test_cli_info_lists_both_setups_and_object_bakes_one(fc, tmp_path, capsys):
    path = _two_setups_file(fc, tmp_path)
    capsys.readouterr()
    assert fc.ops.cli.run(["info", path]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("Fur")]
    assert sorted(ln.split(":")[0] for ln in lines) == ["FurA", "FurB"]
    assert all("frames 1-6, not baked, 0 files" in ln for ln in lines), lines
    assert any("colliders BoxA" in ln for ln in lines)
    assert any("colliders BoxB" in ln for ln in lines)

    assert fc.ops.cli.run(["bake", path, "--object", "FurB", "--frames", "2-5"]) == 0
    out = capsys.readouterr().out
    assert "baked FurB" in out and "FurCollide bake 'FurA'" not in out
    reopen(path)
    a, b = bpy.data.objects["FurA"].furcollide, bpy.data.objects["FurB"].furcollide
    assert b.is_baked and (b.frame_start, b.frame_end) == (2, 5)
    assert not a.is_baked and a.bake_path == "" and (a.frame_start, a.frame_end) == (1, 6)
    assert not os.path.exists(fc.store.bake.bake_directory(bpy.data.objects["FurA"]))
    assert fc.ops.cli.run(["info", path]) == 0
    info = capsys.readouterr().out
    assert "FurA: frames 1-6, not baked, 0 files" in info
    assert "FurB: frames 2-5, baked, 4 files" in info
    # --object on the other one bakes it; B is already baked and untouched
    assert fc.ops.cli.run(["bake", path, "--object", "FurA"]) == 0
    assert "baked FurA" in capsys.readouterr().out
    assert _setup_state(path, "FurA") == (True, (1, 6))
    assert _setup_state(path, "FurB") == (True, (2, 5))
