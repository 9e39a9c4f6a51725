"""Bake, free, resume after a crash, save/reload."""

import os

import bpy
import numpy as np
import pytest
from conftest import bake_crashing_at

pytestmark = pytest.mark.blender


def saved_scene(fc, tmp_path, **kw):
    hair, box = fc.make_scene(**kw)
    out = fc.setup(hair, [box])
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "shot.blend"))
    return hair, box, out


def frames_of(out, frames):
    rec = {}
    for f in frames:
        bpy.context.scene.frame_set(f)
        rec[f] = out_positions(out)
    return rec


def out_positions(out):
    d = out.data
    P = np.empty(len(d.points) * 3, np.float32)
    d.position_data.foreach_get("vector", P)
    return P.reshape(-1, 3)


def test_bake_unsaved_file_is_refused(fc):
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    with pytest.raises(RuntimeError, match="Save the .blend file first"):
        bpy.ops.furcollide.bake()
    assert not hair.furcollide.is_baked


def test_bake_matches_playback_and_free(fc, tmp_path, capsys):
    hair, box, out = saved_scene(fc, tmp_path)
    live = frames_of(out, range(1, 13))
    bpy.context.scene.frame_set(4)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    s = hair.furcollide
    assert s.is_baked and s.bake_path.startswith("//furcollide_cache")
    d = bpy.path.abspath(s.bake_path)
    assert fc.cache.list_frames(d) == list(range(1, 13))
    assert "frame 12 (12/12)" in capsys.readouterr().out
    assert bpy.context.scene.frame_current == 4
    # a baked setup only reads: identical frames, in any order
    rt = fc.registry.get_runtime(hair)
    for f in (12, 3, 7, 1, 12):
        bpy.context.scene.frame_set(f)
        assert np.array_equal(out_positions(out), live[f]), f
        assert s.stat_frame == f
    assert rt.solver_frame is None or rt.memory.frames == {}
    # motion-blur subframes blend the two baked frames (never step)
    bpy.context.scene.frame_set(5, subframe=0.25)
    want = live[5] + (live[6] - live[5]) * np.float32(0.25)
    assert np.allclose(out_positions(out), want, atol=1e-6)
    bpy.context.scene.frame_set(5)
    assert np.array_equal(out_positions(out), live[5])
    with pytest.raises(RuntimeError, match="Free Bake first"):
        bpy.ops.furcollide.bake()
    # an unrelated file in the cache folder survives Free Bake
    keep = os.path.join(d, "notes.txt")
    open(keep, "w").close()
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    assert not s.is_baked and fc.cache.list_frames(d) == []
    assert os.path.exists(keep)


def test_resume_after_crash(fc, tmp_path, monkeypatch):
    hair, box, out = saved_scene(fc, tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    full = {f: fc.cache.read_frame(d, f) for f in range(1, 13)}
    mtimes = {f: os.stat(fc.cache.frame_path(d, f)).st_mtime_ns for f in range(1, 13)}
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}

    # 1) a crash (exception) in the middle of frame 7
    bake_crashing_at(fc, monkeypatch, 7)
    assert not hair.furcollide.is_baked
    assert fc.cache.list_frames(d) == list(range(1, 7))

    # the file is saved (as an artist would) and reopened in a "new session"
    path = bpy.data.filepath
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    hair = bpy.data.objects["Fur"]
    bpy.context.view_layer.objects.active = hair

    # 2) a hard kill leaves a stale temp file and loses frames 5-6
    for f in (5, 6):
        os.remove(fc.cache.frame_path(d, f))
    open(fc.cache.frame_path(d, 5) + ".tmp", "wb").write(b"garbage")
    before = {f: os.stat(fc.cache.frame_path(d, f)).st_mtime_ns for f in range(1, 5)}
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert hair.furcollide.is_baked
    for f in range(1, 5):  # not rewritten: resumed after frame 4
        assert os.stat(fc.cache.frame_path(d, f)).st_mtime_ns == before[f]
    for f in range(1, 13):
        p, st, offs, state = fc.cache.read_frame(d, f)
        assert np.array_equal(p, full[f][0]), f
        assert np.array_equal(st, full[f][1])
        for k in state:
            assert np.array_equal(state[k], full[f][3][k]), (f, k)
    assert mtimes  # original bake existed
    # free removes the stale temp file too, and nothing else
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    assert not os.path.exists(d) or os.listdir(d) == []


def test_changed_settings_do_not_resume(fc, tmp_path, capsys):
    hair, box, out = saved_scene(fc, tmp_path)
    real = fc.bake.bake_frame
    calls = []

    def crash(scene, depsgraph, ob, f, directory, trust_solver):
        calls.append(f)
        if f == 5:
            raise RuntimeError("boom")
        return real(scene, depsgraph, ob, f, directory, trust_solver)

    fc.bake.bake_frame = crash
    try:
        with pytest.raises(RuntimeError):
            bpy.ops.furcollide.bake()
    finally:
        fc.bake.bake_frame = real
    hair.furcollide.recovery_rate = 0.9
    capsys.readouterr()
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert "resuming" not in capsys.readouterr().out


def test_save_reload_keeps_settings_and_bake(fc, tmp_path):
    hair, box, out = saved_scene(fc, tmp_path)
    s = hair.furcollide
    s.mode = "soft"
    s.cv_falloff = 0.25
    s.plasticity = 0.5
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    baked = frames_of(out, range(1, 13))
    path = str(tmp_path / "shot.blend")
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    hair = bpy.data.objects["Fur"]
    s = hair.furcollide
    assert s.is_setup and s.is_baked and s.mode == "soft"
    assert s.cv_falloff == pytest.approx(0.25) and s.plasticity == pytest.approx(0.5)
    assert s.colliders[0].object.name == "Box"
    out = s.output
    assert out.furcollide.source == hair
    for f in (9, 2, 12):
        bpy.context.scene.frame_set(f)
        assert np.array_equal(out_positions(out), baked[f]), f


def test_bake_all_and_free_all(fc, tmp_path):
    hair, box, out = saved_scene(fc, tmp_path)
    hair2 = fc.make_scene.__globals__["make_hair"](name="Fur2", nx=3, ny=3)
    fc.setup(hair2, [box])
    assert bpy.ops.furcollide.bake_all() == {"FINISHED"}
    assert hair.furcollide.is_baked and hair2.furcollide.is_baked
    assert bpy.ops.furcollide.free_bake_all() == {"FINISHED"}
    assert not hair.furcollide.is_baked and not hair2.furcollide.is_baked


def _add_curve(hair):
    hair.data.add_curves([5])
    P = np.empty(len(hair.data.points) * 3, np.float32)
    hair.data.position_data.foreach_get("vector", P)
    P = P.reshape(-1, 3)
    P[-5:] = [(2.0, 2.0, z) for z in np.linspace(0, 1, 5)]
    hair.data.position_data.foreach_set("vector", P.ravel())


def test_baked_source_topology_change_keeps_everything(fc, tmp_path):
    hair, box, out = saved_scene(fc, tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    n = len(out.data.curves)
    bpy.context.scene.frame_set(6)
    shown = out_positions(out)
    _add_curve(hair)
    bpy.context.scene.frame_set(7)
    assert "Free Bake" in hair.furcollide.status_message
    assert np.array_equal(out_positions(out), shown) and len(out.data.curves) == n
    # the same in a new session (nothing in memory)
    bpy.ops.wm.save_mainfile()
    path = bpy.data.filepath
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=path)
    hair = bpy.data.objects["Fur"]
    out = hair.furcollide.output
    bpy.context.scene.frame_set(8)
    assert "other curves" in hair.furcollide.status_message
    assert len(out.data.curves) == n
    assert fc.cache.list_frames(d) == list(range(1, 13))
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    bpy.context.scene.frame_set(1)
    assert len(out.data.curves) == n + 1 and hair.furcollide.status_message == ""
