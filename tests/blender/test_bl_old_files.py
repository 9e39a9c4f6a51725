"""Files and presets saved by an earlier version open with the same values.

``data/old_settings/`` was saved by the version before the angles became Blender angles
and the choices' identifiers upper case (``data/make_old_files.py`` says how: Blender
4.2, so every lane reads it). It holds two baked setups: 'Fur' with every angle and
choice off its default and a Max Angle map; 'Grass' with Max Angle keyed (Bezier, then
linear) and Scale Angle driven (``30 + frame``, in degrees then). ``expected.json`` and
``expected_points.npz`` are what that version read back; ``Old_Look.py`` is a user
preset its Add Preset wrote.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
from pathlib import Path

import bpy
import numpy as np
import pytest
from helpers import ADDON, activate, positions, reopen, save_in

pytestmark = pytest.mark.blender

DATA = Path(__file__).with_name("data") / "old_settings"
EXPECTED = json.loads((DATA / "expected.json").read_text())
ANGLES = ("rotation_precision", "max_angle", "scale_angle")


@pytest.fixture
def old_file(tmp_path):
    """The earlier version's file (and its bake beside it), opened from a copy."""
    shutil.copytree(DATA, tmp_path / "old")
    path = tmp_path / "old" / "old_settings.blend"
    reopen(str(path))
    return path


def _core(fc, ob):
    return ob.furcollide.to_core_kwargs()


def _versioning():
    return sys.modules[ADDON + ".operators.settings.versioning"]


def test_settings_open_with_the_same_values(fc, old_file):
    fur, grass = bpy.data.objects["Fur"], bpy.data.objects["Grass"]
    s = fur.furcollide
    want = EXPECTED["settings"]["Fur"]
    core = _core(fc, fur)
    for name in ANGLES:  # the core gets the same degrees, bit for bit
        assert core[name] == np.float32(want[name]), name
        assert getattr(s, name) == pytest.approx(math.radians(want[name]), rel=1e-6), name
    assert (s.mode, s.pinch_resolution) == ("SOFT", "GROWTH_SURFACE")  # (stored as numbers)
    assert (core["mode"], core["pinch_resolution"]) == ("soft", "growth_surface")
    assert s.max_angle_map == "angle_w" and s.shrink
    g = grass.furcollide
    assert (g.mode, _core(fc, grass)["rotation_precision"]) == ("STIFF", np.float32(0.7))
    rna = s.bl_rna.properties
    assert all(rna[n].subtype == "ANGLE" and rna[n].unit == "ROTATION" for n in ANGLES)
    assert s.settings_version == grass.furcollide.settings_version == 1


def test_keys_and_drivers_give_the_same_degrees_at_every_frame(fc, old_file):
    """Max Angle keyed in degrees and Scale Angle driven in degrees are converted once
    to radians: each frame gives the degrees the earlier version gave."""
    scene = bpy.context.scene
    grass = bpy.data.objects["Grass"]
    keyed = fc.settings.keyed
    for f in range(1, 9):
        want = EXPECTED["frames"][str(f)]["Grass"]
        values = keyed.values(grass, frame=f)  # (without going there)
        scene.frame_set(f)
        core = _core(fc, grass)
        assert core["max_angle"] == pytest.approx(want["max_angle"], rel=1e-6), f
        assert core["scale_angle"] == pytest.approx(want["scale_angle"], rel=1e-6), f
        assert values["furcollide.max_angle"] == core["max_angle"], f  # predicted = set


def test_the_bakes_stay_valid_and_show_what_was_baked(fc, old_file):
    """Every baked frame is shown as it was baked. The bake of 'Fur' (angles set, a map)
    stays valid on every frame; so does the bake of 'Grass' (Max Angle keyed) on its
    keys and wherever its converted keys give the degrees of then to the last bit; a
    frame between keys where they give a float32 step more says that Max Angle changed
    there, and nothing else (user guide, "Files of earlier versions")."""
    scene = bpy.context.scene
    points = np.load(DATA / "expected_points.npz")
    valid = {"Fur": 0, "Grass": 0}
    for f in range(1, 9):
        scene.frame_set(f)
        for name in ("Fur", "Grass"):
            ob = bpy.data.objects[name]
            assert ob.furcollide.is_baked
            np.testing.assert_array_equal(positions(ob.furcollide.output),
                                          points[f"{name}_{f}"])
            why = fc.store.baked.settings_change(ob, scene)
            level, msg = fc.store.report.status_for(ob)
            if name == "Fur" or f in (1, 5, 8):
                assert why == "" and not ob.furcollide.is_outdated, (f, name, why)
                assert level == "INFO", (f, name, msg)
            else:
                assert why in ("", f"Max Angle changed at frame {f}"), (f, why)
            valid[name] += why == ""
    assert valid["Fur"] == 8 and valid["Grass"] >= 6, valid


def test_saved_again_it_is_not_converted_twice(fc, old_file, tmp_path):
    grass = bpy.data.objects["Grass"]
    scene = bpy.context.scene
    scene.frame_set(3)
    before = _core(fc, grass)
    path = save_in(tmp_path, "again.blend")
    reopen(path)
    grass = bpy.data.objects["Grass"]
    bpy.context.scene.frame_set(3)
    assert _core(fc, grass) == before
    # enabling the add-on again with the file open converts nothing either
    assert _versioning().migrate_all() == 0


def test_an_old_preset_applies_as_it_was_meant(fc, old_file):
    fur = bpy.data.objects["Fur"]
    s = fur.furcollide
    activate(fur)
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    want = EXPECTED["preset"]
    assert bpy.ops.furcollide.preset_apply(filepath=str(DATA / "Old_Look.py"),
                                           menu_idname="FURCOLLIDE_MT_presets") == {
        "FINISHED"}
    core = _core(fc, fur)
    for name in ("rotation_precision", "max_angle", "scale_angle", "recovery_rate"):
        assert core[name] == np.float32(want[name]), name
    assert (s.mode, s.pinch_resolution) == ("STIFF", "GROWTH_SURFACE")
