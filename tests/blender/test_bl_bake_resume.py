"""Bake, resume and free: a bake equals playback, a crash or a failed frame keeps the
finished frames and the next bake resumes (only while the settings and inputs hold),
sub-range bakes, unwritable bake directories, frame steps, negative frames, copies
that share a bake."""

import contextlib
import math
import os
import struct
import subprocess
import zipfile

import bpy
import numpy as np
import pytest
from helpers import (
    DEMO_FUR,
    REAL_FRAMES,
    activate,
    assert_same_frames,
    bake_crashing_at,
    bake_files,
    bake_files_of,
    bake_setup,
    build_setup,
    curves_crossing,
    demo_build,
    draw_enabled,
    frame_of,
    frames_on_disk,
    make_hair,
    no_traceback,
    offsets_of,
    play_demo,
    positions,
    preroll_scene,
    real_size_fur,
    record,
    reopen,
    same_frame,
    save_as,
    save_in,
    seg_lengths,
    set_core,
    small_setup,
    status_of,
    sweep_box,
    sweep_setup,
    world,
    world_meshes,
)

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


def _add_curve(hair):
    hair.data.add_curves([5])
    P = np.empty(len(hair.data.points) * 3, np.float32)
    hair.data.position_data.foreach_get("vector", P)
    P = P.reshape(-1, 3)
    P[-5:] = [(2.0, 2.0, z) for z in np.linspace(0, 1, 5)]
    hair.data.position_data.foreach_set("vector", P.ravel())


def _partial_bake(fc, tmp_path, monkeypatch):
    hair, _box, _out = build_setup(fc, "")
    path = save_as(tmp_path / "ro.blend")
    activate(hair)
    bake_crashing_at(fc, monkeypatch, 4)  # frames 1-3 on disk, bake_path kept
    bpy.ops.wm.save_mainfile()
    d = bpy.path.abspath(hair.furcollide.bake_path)
    assert bake_files(d) == [f"frame_{f:06d}.npz" for f in (1, 2, 3)]
    return path, d


def _cli_fails_naming(fc, capsys, path, target):
    capsys.readouterr()
    assert fc.ops.cli.run(["bake", path]) == 1
    cap = capsys.readouterr()
    err = cap.err + cap.out
    assert "furcollide: bake failed: 'Fur' frame 4" in cap.err, cap.err
    assert target in cap.err
    assert "Traceback" not in err
    return cap


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
    rt = fc.store.registry.get_runtime(hair)
    for f in (12, 3, 7, 1, 12):
        bpy.context.scene.frame_set(f)
        assert np.array_equal(out_positions(out), live[f]), f
        assert s.stat_frame == f
    assert rt.solve.frame is None or rt.cache.memory.frames == {}
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


def _fingerprint(fc, d, f):
    with np.load(fc.cache.frame_path(d, f), allow_pickle=False) as z:
        key = next(k for k in z.files if k.endswith("__fingerprint"))
        return z[key].tobytes().decode()


def test_changed_settings_do_not_resume(fc, tmp_path, monkeypatch, capsys):
    """README: if the settings changed, the bake starts over: frames 1-4 of the
    interrupted bake are written again with the new settings (new files, each with
    the new value in its record), and the result is a clean bake of the new settings.
    (The fingerprint holds what every frame shares; the values are each frame's.)"""
    hair, box, out = saved_scene(fc, tmp_path)
    bake_crashing_at(fc, monkeypatch, 5)
    d = bpy.path.abspath(hair.furcollide.bake_path)
    assert fc.cache.list_frames(d) == [1, 2, 3, 4]
    old = {f: os.stat(fc.cache.frame_path(d, f)).st_ino for f in range(1, 5)}
    old_fp = _fingerprint(fc, d, 1)
    hair.furcollide.recovery_rate = 0.9
    capsys.readouterr()
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert "resuming" not in capsys.readouterr().out
    new_fp = fc.store.bake.settings_fingerprint(hair)
    assert new_fp == old_fp  # (Recovery Rate is a value of each frame)
    for f in range(1, 13):
        assert _fingerprint(fc, d, f) == new_fp, f
        rec = fc.cache.read_inputs(d, f)
        assert rec["values"]["furcollide.recovery_rate"] == pytest.approx(0.9), f
    for f in range(1, 5):  # rewritten (os.replace: a new file), not kept
        assert os.stat(fc.cache.frame_path(d, f)).st_ino != old[f], f
    resumed = {f: fc.cache.read_frame(d, f) for f in range(1, 13)}
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    for f in range(1, 13):
        p, st, _offs, _state = fc.cache.read_frame(d, f)
        np.testing.assert_array_equal(p, resumed[f][0], err_msg=f"frame {f}")
        np.testing.assert_array_equal(st, resumed[f][1], err_msg=f"frame {f}")


def _savez_failing_midway_in(frame):
    """np.savez as seen by the bake: writing ``frame``'s file stops halfway with an
    OSError (a full disk, a killed process), after half of a real file is written."""
    real = np.savez

    def savez(fh, **arrays):
        if f"frame_{frame:06d}.npz" not in os.path.basename(getattr(fh, "name", "")):
            return real(fh, **arrays)
        import io

        buf = io.BytesIO()
        real(buf, **arrays)
        fh.write(buf.getvalue()[: len(buf.getvalue()) // 2])
        fh.flush()
        raise OSError(28, "No space left on device (simulated)")

    return savez


def test_a_failure_while_writing_a_frame_keeps_the_previous_frames_and_resumes(
        fc, tmp_path, monkeypatch):
    """README "Bake": a crash never leaves a half-written frame. Writing frame 7 fails
    halfway: frames 1-6 are kept, frame 7 does not exist, and the next Bake resumes
    after frame 6 (1-6 untouched) and equals an uninterrupted bake bit for bit."""
    hair, box, out = saved_scene(fc, tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    full = {f: fc.cache.read_frame(d, f) for f in range(1, 13)}
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    with monkeypatch.context() as m:
        m.setattr(fc.cache.np, "savez", _savez_failing_midway_in(7))
        with pytest.raises(RuntimeError, match="frame 7.*No space left"):
            bpy.ops.furcollide.bake()
    assert not hair.furcollide.is_baked
    assert fc.cache.list_frames(d) == [1, 2, 3, 4, 5, 6]
    assert not os.path.exists(fc.cache.frame_path(d, 7))
    kept = {f: os.stat(fc.cache.frame_path(d, f)).st_ino for f in range(1, 7)}
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert hair.furcollide.is_baked
    for f in range(1, 7):  # resumed after frame 6: not rewritten
        assert os.stat(fc.cache.frame_path(d, f)).st_ino == kept[f], f
    for f in range(1, 13):
        p, st, offs, state = fc.cache.read_frame(d, f)
        np.testing.assert_array_equal(p, full[f][0], err_msg=f"frame {f}")
        np.testing.assert_array_equal(st, full[f][1], err_msg=f"frame {f}")
        assert set(state) == set(full[f][3]), f
        for k in state:
            np.testing.assert_array_equal(state[k], full[f][3][k], err_msg=f"{f} {k}")




@pytest.mark.parametrize("keep", [0, 3, 0.5])
def test_resume_does_not_trust_a_partial_frame_file(fc, tmp_path, monkeypatch, capsys, keep):
    """A frame file cut short (copied from a full disk, written by a tool that does not
    write atomically: 0 bytes, 3 bytes or half of it) is not a finished frame: the next
    Bake resumes before it, without an error, and equals an uninterrupted bake."""
    hair, box, out = saved_scene(fc, tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    full = {f: fc.cache.read_frame(d, f)[0] for f in range(1, 13)}
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    bake_crashing_at(fc, monkeypatch, 7)
    path6 = fc.cache.frame_path(d, 6)
    data = open(path6, "rb").read()
    cut = keep if isinstance(keep, int) else int(len(data) * keep)
    with open(path6, "wb") as fh:
        fh.write(data[:cut])
    capsys.readouterr()
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert hair.furcollide.is_baked
    for f in range(1, 13):
        np.testing.assert_array_equal(fc.cache.read_frame(d, f)[0], full[f], err_msg=f"{f}")
    no_traceback(capsys)


@pytest.mark.parametrize("damage", ["cut", "bytes"])
def test_a_damaged_baked_frame_says_which_file_and_what_to_do(fc, tmp_path, capsys, damage):
    """A bake file damaged after the bake (cut short, or bytes changed: a bad copy, a
    failing disk) is not shown: the setup's status names the frame and the file and
    says Free Bake, then Bake; no traceback, the output keeps its last result, and
    the other baked frames are still shown."""
    hair, box, out = saved_scene(fc, tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    baked = frames_of(out, range(1, 13))
    d = bpy.path.abspath(hair.furcollide.bake_path)
    path6 = fc.cache.frame_path(d, 6)
    data = bytearray(open(path6, "rb").read())
    if damage == "cut":
        data = data[: len(data) // 2]
    else:  # inside the points' data: their CRC no longer matches
        with zipfile.ZipFile(path6) as zf:
            info = zf.getinfo("points.npy")
        name_len, extra_len = struct.unpack("<HH", data[info.header_offset + 26:
                                                         info.header_offset + 30])
        start = info.header_offset + 30 + name_len + extra_len + 200
        for i in range(start, start + 40):
            data[i] ^= 0xFF
    open(path6, "wb").write(bytes(data))
    s = hair.furcollide
    bpy.context.scene.frame_set(5)
    capsys.readouterr()
    bpy.context.scene.frame_set(6)
    level, message = fc.store.report.status_for(hair)
    assert level == "ERROR", message
    assert message == s.status_message
    assert "Frame 6 of the bake cannot be read" in s.status_message
    assert path6 in s.status_message and "Free Bake, then Bake" in s.status_message
    assert np.array_equal(out_positions(out), baked[5])  # the last result kept
    no_traceback(capsys)
    bpy.context.scene.frame_set(7)
    assert np.array_equal(out_positions(out), baked[7])
    assert fc.store.report.status_for(hair)[0] != "ERROR", s.status_message


def test_save_reload_keeps_settings_and_bake(fc, tmp_path):
    hair, box, out = saved_scene(fc, tmp_path)
    s = hair.furcollide
    s.mode = "SOFT"
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
    assert s.is_setup and s.is_baked and s.mode == "SOFT"
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


def test_setting_change_on_a_bake_then_free_and_bake_again(fc, tmp_path):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    s = hair.furcollide
    save_in(tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(s.bake_path)
    old = {f: fc.cache.read_frame(d, f)[0] for f in range(1, 9)}

    # README: "A baked setup only reads. Its settings are greyed out until Free Bake."
    activate(hair)
    log = draw_enabled(bpy.types.FURCOLLIDE_PT_resolution)
    assert ("prop", "mode", False) in log and ("prop", "rotation_precision", False) in log
    s.mode = "STIFF"  # a script can still change it
    s.rotation_precision = math.radians(2.0)
    # the bake still shows its own frames, bit for bit, never a re-solve, but
    # marked outdated: they were baked with other settings (issue 14)
    for f in (3, 8, 1, 5, 6):
        scene.frame_set(f)
        np.testing.assert_array_equal(fc.positions(out), old[f], err_msg=f"frame {f}")
        assert s.stat_frame == f and s.is_outdated
        assert "settings" in s.status_message and "Free Bake" in s.status_message
    assert ("label", "Outdated bake: Free Bake, then Bake", True) in draw_enabled(
        bpy.types.FURCOLLIDE_PT_cache)
    with pytest.raises(RuntimeError, match="Free Bake first"):
        bpy.ops.furcollide.bake()

    # Free Bake at frame 5: nothing new is solved there yet. Whatever the output
    # shows while the new result is unknown is flagged outdated (never silently old).
    scene.frame_set(5)
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    log = draw_enabled(bpy.types.FURCOLLIDE_PT_resolution)
    assert ("prop", "mode", True) in log  # editable again
    for f in (6, 7):
        scene.frame_set(f)
        assert s.is_outdated and fc.store.report.status_for(hair)[0] == "WARNING"
        assert "not cached" in s.status_message
    assert ("label", "Outdated: play from the start or bake", True) in draw_enabled(
        bpy.types.FURCOLLIDE_PT_cache)

    # play from the start: the new settings' result
    live = {}
    for f in range(1, 9):
        scene.frame_set(f)
        assert s.status_message == "" and not s.is_outdated, (f, s.status_message)
        live[f] = fc.positions(out).copy()
    assert any(not np.array_equal(live[f], old[f]) for f in live), "the change changed nothing"

    # bake again: the files and the playback are the new result on every frame
    scene.frame_set(3)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert fc.cache.list_frames(d) == list(range(1, 9))
    for f in range(1, 9):
        np.testing.assert_array_equal(fc.cache.read_frame(d, f)[0], live[f], err_msg=f"{f}")
    for f in (8, 2, 5, 1, 7):
        scene.frame_set(f)
        np.testing.assert_array_equal(fc.positions(out), live[f], err_msg=f"frame {f}")
        assert s.status_message == ""


def test_interrupted_bake_does_not_resume_over_an_edited_collider(fc, tmp_path, monkeypatch):
    """README: the next Bake resumes after the last frame whose files match the
    current settings and colliders; editing a collider invalidates."""
    hair, box, out = small_setup(fc)
    save_in(tmp_path)
    bake_crashing_at(fc, monkeypatch, 5)
    d = fc.store.bake.bake_directory(hair)
    assert fc.cache.list_frames(d) == [1, 2, 3, 4]
    for v in box.data.vertices:  # the artist makes the collider bigger
        v.co *= 1.5
    box.data.update()
    bpy.context.view_layer.update()
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    resumed = {f: fc.cache.read_frame(d, f)[0] for f in range(1, 9)}
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    assert bpy.ops.furcollide.bake() == {"FINISHED"}  # a clean bake of the edited scene
    for f in range(1, 9):
        np.testing.assert_array_equal(resumed[f], fc.cache.read_frame(d, f)[0],
                                      err_msg=f"frame {f}")


def test_sub_range_bake_before_inside_after(fc, tmp_path):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc, frames=(1, 10))
    s = hair.furcollide
    s.frame_start, s.frame_end = 4, 7
    source = fc.positions(hair).copy()
    # live play over the whole scene: frame 4 solves from the groomed shape
    live = {}
    for f in range(1, 11):
        scene.frame_set(f)
        live[f] = fc.positions(out).copy()
        assert fc.store.report.status_for(hair)[0] == "INFO", (f, s.status_message)
        assert not s.is_outdated, f
    for f in (1, 2, 3):
        np.testing.assert_array_equal(live[f], source, err_msg=f"frame {f}")
    for f in (8, 9, 10):  # README: after Frame End, Frame End is held
        np.testing.assert_array_equal(live[f], live[7], err_msg=f"frame {f}")
    assert any(not np.array_equal(live[f], source) for f in range(4, 8))
    save_in(tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(s.bake_path)
    assert fc.cache.list_frames(d) == [4, 5, 6, 7]
    baked = {f: fc.cache.read_frame(d, f)[0] for f in range(4, 8)}
    for f in range(4, 8):
        np.testing.assert_array_equal(baked[f], live[f], err_msg=f"frame {f}")
    for f in (1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 9, 2, 6, 10, 4, 3):
        scene.frame_set(f)
        P = fc.positions(out)
        level, msg = fc.store.report.status_for(hair)
        assert level == "INFO", (f, msg)
        if f < 4:  # README: before Frame Start the output follows the source
            np.testing.assert_array_equal(P, source, err_msg=f"frame {f}")
            assert not np.any(status_of(out)), f
        elif f <= 7:  # baked frames, bit for bit
            np.testing.assert_array_equal(P, baked[f], err_msg=f"frame {f}")
            assert s.stat_frame == f
        else:  # README: after Frame End, Frame End is held
            np.testing.assert_array_equal(P, baked[7], err_msg=f"frame {f}")
            assert s.stat_frame == 7 and msg == ""
        assert not s.is_outdated


@contextlib.contextmanager
def _read_only(d, fc, monkeypatch):
    """Make folder ``d`` read-only for this process. As a user: chmod 555. As root
    (who ignores permissions): the immutable attribute (``chattr +i``: no file can be
    created in it, not even by root); where the file system has no such attribute,
    creating a file in ``d`` fails with EACCES as it would for a user (the bake's
    ``open``)."""
    if os.geteuid() != 0:
        os.chmod(d, 0o555)
        try:
            yield "chmod"
        finally:
            os.chmod(d, 0o755)
        return
    r = subprocess.run(["chattr", "+i", d], capture_output=True, text=True)
    if r.returncode == 0:
        try:
            yield "chattr"
        finally:
            subprocess.run(["chattr", "-i", d], check=True)
        return
    real_open = open

    def denied(path, *args, **kw):
        if os.path.dirname(os.path.abspath(os.fspath(path))) == os.path.abspath(d):
            raise PermissionError(13, "Permission denied", os.fspath(path))
        return real_open(path, *args, **kw)

    with monkeypatch.context() as m:
        m.setattr(fc.cache, "open", denied, raising=False)
        yield "simulated"


def test_read_only_bake_directory(fc, tmp_path, monkeypatch, capsys):
    """A bake folder that cannot be written (as a user or as root): the error names
    the frame's file, exit code 1, frames 1-3 stay; once writable, the bake resumes."""
    path, d = _partial_bake(fc, tmp_path, monkeypatch)
    with _read_only(d, fc, monkeypatch) as how:
        with pytest.raises(OSError):  # really read-only for this process
            open(os.path.join(d, "probe"), "wb") if how != "simulated" else fc.cache.open(
                os.path.join(d, "probe"), "wb")
        _cli_fails_naming(fc, capsys, path, os.path.join(d, "frame_000004.npz"))
        assert bake_files(d)[:3] == [f"frame_{f:06d}.npz" for f in (1, 2, 3)]
    assert fc.ops.cli.run(["bake", path]) == 0
    assert "resuming after frame 3" in capsys.readouterr().out
    assert len(bake_files(d)) == 6


def test_unwritable_frame_path_keeps_finished_frames(fc, tmp_path, monkeypatch, capsys):
    """(Works as root too.) A directory where frame 4's file must go: the error names
    the path, frames 1-3 stay, exit 1, and the next run resumes."""
    path, d = _partial_bake(fc, tmp_path, monkeypatch)
    blocker = os.path.join(d, "frame_000004.npz")
    os.mkdir(blocker)
    _cli_fails_naming(fc, capsys, path, blocker)
    assert [f for f in bake_files(d) if f.endswith(".npz")][:3] == \
        [f"frame_{f:06d}.npz" for f in (1, 2, 3)]
    reopen(path)
    assert not bpy.data.objects["Fur"].furcollide.is_baked
    os.rmdir(blocker)
    assert fc.ops.cli.run(["bake", path]) == 0
    assert "resuming after frame 3" in capsys.readouterr().out
    assert [f for f in bake_files(d) if f.endswith(".npz")] == \
        [f"frame_{f:06d}.npz" for f in range(1, 7)]


def test_file_where_the_bake_directory_should_be(fc, tmp_path, capsys):
    hair, _box, _out = build_setup(fc, "")
    blocker = tmp_path / "cache_is_a_file"
    blocker.write_text("not a directory")
    hair.furcollide.cache_directory = str(blocker) + os.sep
    path = save_as(tmp_path / "blocked.blend")
    capsys.readouterr()
    assert fc.ops.cli.run(["bake", path]) == 1
    cap = capsys.readouterr()
    assert "furcollide: bake failed: 'Fur' frame 1" in cap.err, cap.err
    assert str(blocker) in cap.err and "Traceback" not in cap.err + cap.out
    assert blocker.read_text() == "not a directory"
    # the operator: a report, no traceback
    reopen(path)
    activate(bpy.data.objects["Fur"])
    with pytest.raises(RuntimeError, match="cache_is_a_file"):
        bpy.ops.furcollide.bake()
    assert not bpy.data.objects["Fur"].furcollide.is_baked


def test_negative_start_frame_bake_and_free(fc, tmp_path):
    """Baking a setup that starts at frame -4 marks it baked, writes one file per
    frame, reads back the played frames, and Free Bake removes every file."""
    scene, hair, _box, out = preroll_scene(fc)
    played = record(scene, out, range(-4, 4))
    save_in(tmp_path)
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    directory = bpy.path.abspath(hair.furcollide.bake_path)
    assert len(os.listdir(directory)) == 8
    assert hair.furcollide.is_baked, "the bake of frames -4..3 was not marked baked"
    assert_same_frames(played, scene, out, what="baked")
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    assert not os.path.exists(directory), os.listdir(directory)


def test_bake_with_a_frame_step_solves_every_frame(fc, tmp_path):
    """Scene › Frame Step 3 only changes what playback and render show: the bake
    still solves every frame of the range, equal to a play of every frame."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 7
    scene.frame_set(1)
    hair = make_hair(nx=5, ny=5)
    box = sweep_box(frames=(1, 7))
    scene.frame_set(1)
    out = fc.setup(hair, [box])
    played = record(scene, out, range(1, 8))
    scene.frame_step = 3
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    save_in(tmp_path)
    bake_setup(hair)
    assert scene.frame_step == 3 and scene.frame_current == 1
    assert bake_files_of(hair) == [f"frame_{f:06d}.npz" for f in range(1, 8)]
    assert_same_frames(played, scene, out, what="baked")


@pytest.mark.parametrize("copy", ["duplicated_source", "full_copy_scene"])
def test_free_bake_on_a_copy_keeps_the_originals_bake(fc, copy, tmp_path, capsys):
    scene = bpy.context.scene
    hair, box, out = sweep_setup(fc, frames=(1, 4))
    save_as(tmp_path / "shot.blend")
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    assert len(frames_on_disk(d)) == 4
    if copy == "duplicated_source":
        dup = hair.copy()
        dup.data = hair.data.copy()
        dup.name = "Fur Copy"
        scene.collection.objects.link(dup)
        scene.frame_set(2)
        assert "copy of the setup on 'Fur'" in dup.furcollide.status_message
    else:
        assert bpy.ops.scene.new(type="FULL_COPY") == {"FINISHED"}
        dup = bpy.data.objects["Fur.001"]
    activate(dup)
    try:
        bpy.ops.furcollide.free_bake()  # refused or done: either way ...
    except RuntimeError:
        pass
    no_traceback(capsys)
    # ... the original's bake is still there and still plays
    assert hair.furcollide.is_baked
    assert len(frames_on_disk(d)) == 4


# ------------------------------------------------------------ the Cache Directory
def test_a_new_cache_directory_after_a_failed_bake_is_used(fc, tmp_path):
    """The Cache Directory points at a file (a typo, an unmounted share): Bake fails at
    frame 1. The artist fixes the Directory (Cache panel, still editable) and presses
    Bake again: it must bake there, not fail again on the old path."""
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    blocker = tmp_path / "cache_is_a_file"
    blocker.write_text("not a directory")
    hair.furcollide.cache_directory = str(blocker) + os.sep
    save_in(tmp_path)
    with pytest.raises(RuntimeError, match="Not a directory"):
        bpy.ops.furcollide.bake()
    good = tmp_path / "good cache"
    hair.furcollide.cache_directory = str(good) + os.sep
    bpy.ops.furcollide.bake()  # (the new directory, not the old path's error again)
    assert hair.furcollide.is_baked
    assert os.path.abspath(bpy.path.abspath(hair.furcollide.bake_path)).startswith(str(good))


def test_a_partial_bake_resumed_after_a_directory_change_goes_to_the_new_directory(
        fc, tmp_path, monkeypatch):
    """A bake crashes at frame 4 (frames 1-3 on disk, next to the .blend). The artist
    then points Directory at the farm share and presses Bake: every frame must end up
    on the share (the render nodes read only it)."""
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    save_in(tmp_path)
    bake_crashing_at(fc, monkeypatch, 4)
    share = tmp_path / "farm share"
    hair.furcollide.cache_directory = str(share) + os.sep
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    assert os.path.abspath(d).startswith(str(share)), d
    assert len(bake_files(d)) == 12


def test_a_relative_cache_directory_set_from_a_script_does_not_warn(fc):
    """README: the Directory defaults to ``//furcollide_cache/`` ('//' = next to the
    .blend). A TD's script setting another relative folder the same way gets no warning
    (Blender 5.0 warns "FurCollideSettings.cache_directory: does not support blend
    relative "//" prefix" for a property not marked as a relative path, the file
    browser's Relative Path option) and the value is stored as given."""
    import warnings

    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        hair.furcollide.cache_directory = "//shot cache/"
    assert hair.furcollide.cache_directory == "//shot cache/"
    assert [str(w.message) for w in caught] == []


# ------------------------------------------------- the demo's scene at real size
@pytest.mark.slow
@pytest.mark.parametrize("mode", ["bend", "soft"])
def test_a_bake_resumed_after_a_crash_gives_the_played_frames(fc, tmp_path, monkeypatch,
                                                              mode):
    """A bake that crashed at frame 21 (the pinch, where the warm start's memory
    matters: the resumed bake starts from the state in frame 20's file), resumed with
    Threads 1: every baked frame equals the played one bit for bit (README: "The next
    Bake resumes after the last frame whose files match"; each file holds "the full
    solver state")."""
    demo, hair, out = real_size_fur(mode, threads=2)
    first = play_demo(demo.scene, hair, out)
    save_in(tmp_path)
    demo.scene.frame_set(1)
    activate(hair)
    bake_crashing_at(fc, monkeypatch, 21)
    hair.furcollide.threads = 1
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    for f in REAL_FRAMES:
        demo.scene.frame_set(f)
        assert not hair.furcollide.is_outdated, hair.furcollide.status_message
        same_frame(frame_of(out), first[f], f"{mode}: resumed bake, frame {f}")


# ----------------------------------------------- the demo's grass and fur, Bake All
#: The Grass Trampling preset (ui/preset_files/Grass_Trampling.py), in the core's names
#: and units (``helpers.set_core``).
GRASS_TRAMPLING = dict(
    mode="bend",
    rotation_precision=0.5,
    max_angle=170.0,
    collision_offset=0.01,
    recovery_rate=0.05,
    plasticity=0.6,
    pinch_resolution="stop",
)


def grass_and_fur(n_grass, n_fur, last):
    """The demo's grass (the Grass Trampling preset, Ball) and fur (the demo's fur
    settings, Pusher and Cloth; its range ends 8 frames earlier) setups. Returns
    (demo, [grass output, fur output])."""
    demo = demo_build(fur_count=n_fur, grass_count=n_grass)
    scene = demo.scene
    scene.frame_start, scene.frame_end = 1, last
    for hair, cols, values, end in (
        (demo.grass, [demo.ball], GRASS_TRAMPLING, last),
        (demo.fur, [demo.pusher, demo.cloth], DEMO_FUR, last - 8),
    ):
        activate(hair, *cols)
        assert bpy.ops.furcollide.add() == {"FINISHED"}
        set_core(hair.furcollide, **values)
        hair.furcollide.frame_start, hair.furcollide.frame_end = 1, end
    scene.frame_set(1)
    return demo, [demo.grass.furcollide.output, demo.fur.furcollide.output]


def shown(scene, outs, frames, check=None):
    rec = {}
    for f in frames:
        scene.frame_set(f)
        if check is not None:
            check(f)
        rec[f] = [frame_of(o) for o in outs]
    return rec


def same_shots(got, want, what):
    for f in got:
        for k, (a, b) in enumerate(zip(got[f], want[f], strict=True)):
            same_frame(a, b, f"{what}, frame {f}, setup {k}")


@pytest.mark.slow
def test_grass_bake_all_played_back_freed_and_baked_again(fc, tmp_path):
    """README "Bake (disk cache)" on the demo's two setups at the demo's size (2,500
    blades of Grass Trampling under the rolling ball, 40 frames; the fur besides, with a
    shorter range): played with checks (no resolved blade crosses the ball, roots and
    lengths kept); Bake All; the baked frames played and scrubbed are the played frames
    bit for bit, nothing said; Free All Bakes, Plasticity and the fur's Recovery Rate
    changed, Bake All again: the new bake is what playing the shot with the new settings
    gives, bit for bit, and the change shows (the trail is another)."""
    last = 40
    demo, outs = grass_and_fur(2500, 500, last)
    scene, grass = demo.scene, demo.grass
    g = grass.furcollide
    offs, src = offsets_of(grass), positions(grass)

    def check(f):
        assert g.status_message == "" and not g.is_outdated, (f, g.status_message)
        if f % 4:
            return
        st = status_of(g.output)
        bad = curves_crossing(world(g.output), offs, world_meshes([demo.ball]), st)
        assert len(bad) == 0, (f, bad[:5])
        P = positions(g.output)
        np.testing.assert_array_equal(P[offs[:-1]], src[offs[:-1]])
        np.testing.assert_allclose(
            seg_lengths(P, offs), seg_lengths(src, offs), rtol=2e-4, atol=1e-6
        )

    played = shown(scene, outs, range(1, last + 1), check)
    trail = played[last][0][1]
    assert (trail == 2).sum() > 200, np.bincount(trail)  # trampled blades recovering
    save_in(tmp_path)
    scene.frame_set(1)
    assert bpy.ops.furcollide.bake_all() == {"FINISHED"}
    assert g.is_baked and demo.fur.furcollide.is_baked
    same_shots(shown(scene, outs, range(1, last + 1), check), played, "baked")
    same_shots(shown(scene, outs, [30, 5, last, 17, 1, 29]), played, "baked, scrubbed")
    activate(grass)
    assert bpy.ops.furcollide.free_bake_all() == {"FINISHED"}
    assert not g.is_baked and not demo.fur.furcollide.is_baked
    g.plasticity = 0.3
    demo.fur.furcollide.recovery_rate = 0.5
    scene.frame_set(1)
    assert bpy.ops.furcollide.bake_all() == {"FINISHED"}
    rebaked = shown(scene, outs, range(1, last + 1), check)
    activate(grass)
    assert bpy.ops.furcollide.free_bake_all() == {"FINISHED"}
    scene.frame_set(1)
    same_shots(shown(scene, outs, range(1, last + 1), check), rebaked, "played after")
    assert not np.array_equal(rebaked[last][0][0], played[last][0][0])
