"""Batch entry points (CLI command, bake_all) and rendering an animation."""

import bpy
import numpy as np
import pytest
from conftest import render_camera

pytestmark = pytest.mark.blender


def _saved(fc, tmp_path, frames=(1, 6)):
    hair, box = fc.make_scene(frames=frames)
    fc.setup(hair, [box])
    path = str(tmp_path / "farm.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    return path


def test_cli_bake_exit_codes(fc, tmp_path, capsys):
    assert fc.cli._handle is not None  # registered with bpy.utils.register_cli_command
    path = _saved(fc, tmp_path)
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    assert fc.cli.run(["bake", path, "--frames", "1-4"]) == 0
    out = capsys.readouterr().out
    assert "frame 4 (4/4)" in out and "baked Fur" in out
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    s = bpy.data.objects["Fur"].furcollide
    assert s.is_baked and (s.frame_start, s.frame_end) == (1, 4)
    assert fc.cli.run(["info", path]) == 0
    assert "baked" in capsys.readouterr().out
    # already baked: success, nothing to do; --force re-bakes
    assert fc.cli.run(["bake", path]) == 0
    assert fc.cli.run(["bake", path, "--force", "--no-save"]) == 0
    assert fc.cli.run(["free", path]) == 0
    bpy.ops.wm.open_mainfile(filepath=path)
    assert not bpy.data.objects["Fur"].furcollide.is_baked


def test_cli_failures(fc, tmp_path):
    assert fc.cli.run(["bake", str(tmp_path / "missing.blend")]) == 2
    assert fc.cli.run(["explode"]) == 2
    path = _saved(fc, tmp_path)
    assert fc.cli.run(["bake", path, "--frames", "9-3"]) == 2
    assert fc.cli.run(["bake", path, "--object", "Nope"]) == 2
    # a broken setup (its output object was deleted) fails with exit code 1
    bpy.ops.wm.open_mainfile(filepath=path)
    bpy.data.objects.remove(bpy.data.objects["Fur FurCollide"])
    bpy.ops.wm.save_mainfile()
    assert fc.cli.run(["bake", path]) == 1
    empty = str(tmp_path / "empty.blend")
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.save_as_mainfile(filepath=empty)
    assert fc.cli.run(["bake", empty]) == 2


def test_python_expr_bake_all(fc, tmp_path):
    # what `blender -b shot.blend --python-expr "import bpy; bpy.ops.furcollide.bake_all()"` runs
    path = _saved(fc, tmp_path)
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    assert bpy.ops.furcollide.bake_all() == {"FINISHED"}
    assert bpy.data.objects["Fur"].furcollide.is_baked


def _render_setup(fc, tmp_path):
    hair, box = fc.make_scene(frames=(1, 4), nx=8, ny=8)
    out = fc.setup(hair, [box])
    sc = bpy.context.scene
    render_camera(sc, px=48)
    sc.render.film_transparent = True
    box.hide_render = True  # the collider is hidden from render, yet it must count
    return hair, out


def _render(tmp_path, tag):
    sc = bpy.context.scene
    sc.render.filepath = str(tmp_path / f"{tag}_####")
    bpy.ops.render.render(animation=True)
    imgs = []
    for f in range(sc.frame_start, sc.frame_end + 1):
        im = bpy.data.images.load(str(tmp_path / f"{tag}_{f:04d}.png"))
        imgs.append(np.array(im.pixels[:]).reshape(-1, 4)[:, 3].copy())
        bpy.data.images.remove(im)
    return imgs


def test_render_animation_sees_result(fc, tmp_path):
    hair, out = _render_setup(fc, tmp_path)
    seen = {}

    def spy(scene, depsgraph):  # runs after FurCollide's handler
        if depsgraph is not None and depsgraph.mode == "RENDER":
            seen[scene.frame_current] = fc.positions(out).copy()

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        collided = _render(tmp_path, "on")
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    assert sorted(seen) == [1, 2, 3, 4]
    # every rendered frame got exactly the solved (cached) result
    rt = fc.registry.get_runtime(hair)
    assert sorted(rt.memory.frames) == [1, 2, 3, 4]
    for f in range(1, 5):
        bpy.context.scene.frame_set(f)
        assert np.array_equal(fc.positions(out), seen[f]), f
    moved = [f for f in seen if not np.array_equal(seen[f], fc.positions(hair))]
    assert moved, "the box never touched the hair"
    hair.furcollide.enabled = False
    plain = _render(tmp_path, "off")
    assert any(not np.array_equal(a, b) for a, b in zip(collided, plain, strict=True))


def test_render_after_reload_reads_the_bake(fc, tmp_path):
    hair, out = _render_setup(fc, tmp_path)
    path = str(tmp_path / "render.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    bpy.ops.wm.save_mainfile()
    d = bpy.path.abspath(hair.furcollide.bake_path)
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=path)  # a farm node: nothing in memory
    out = bpy.data.objects["Fur FurCollide"]
    seen = {}

    def spy(scene, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            seen[scene.frame_current] = fc.positions(out).copy()

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.context.scene.frame_start = 2  # render a sub-range
        _render(tmp_path, "farm")
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    assert sorted(seen) == [2, 3, 4]
    for f in seen:
        assert np.array_equal(seen[f], fc.cache.read_frame(d, f)[0]), f
