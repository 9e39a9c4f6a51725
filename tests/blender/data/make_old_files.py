"""Make the files an earlier version of FurCollide saved (test data, kept in git).

``test_bl_old_files.py`` opens them with this version: settings, keys, drivers, maps,
bakes and presets saved before the angles became Blender angles (radians, the ANGLE
subtype) and the choices' identifiers upper case must keep their values. Run from the
repository root with the OLDEST supported ``bpy`` (every lane must read the file)::

    git archive 916081a | tar -x -C /tmp/fc_old      # the version before the change
    /var/cache/furcollide/venvs/bpy-4.2/bin/python tests/blender/data/make_old_files.py \
        /tmp/fc_old tests/blender/data/old_settings

It writes ``old_settings/old_settings.blend`` (two setups, baked), its bake folder
``furcollide_cache/`` and ``Old_Look.py`` (a user preset written by the old Add Preset),
``expected.json`` (what the old version read back: values and statuses per frame) and
``expected_points.npz`` (the outputs' points per frame).
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="fc_old_user_")
import bpy  # noqa: E402, I001  (first: it puts addon_utils on the path)
import addon_utils  # noqa: E402
import numpy as np  # noqa: E402

OLD, OUT = Path(sys.argv[1]).resolve(), Path(sys.argv[2]).resolve()
ADDON = "bl_ext.fcold.furcollide"
#: Fur: every angle and choice off its default, a Max Angle map; Grass: Max Angle keyed,
#: Scale Angle driven.
FUR = dict(mode="soft", rotation_precision=0.5, max_angle=77.7, scale_angle=33.3,
           pinch_resolution="growth_surface", shrink=True, recovery_rate=0.3)
GRASS = dict(mode="stiff", rotation_precision=0.7, shrink=True)
GRASS_KEYS = ((1, 120.0), (5, 45.0), (8, 60.0))  # max_angle, degrees (Bezier, then linear)
PRESET = dict(mode="stiff", rotation_precision=0.3, max_angle=150.0, scale_angle=45.5,
              pinch_resolution="growth_surface", recovery_rate=0.25)


def enable():
    dev = Path(tempfile.mkdtemp(prefix="fc_old_dev_"))
    (dev / "furcollide").symlink_to(OLD, target_is_directory=True)
    repos = bpy.context.preferences.extensions.repos
    repos.new(name="fcold", module="fcold", custom_directory=str(dev), source="USER")
    assert addon_utils.enable(ADDON, default_set=True, handle_error=None) is not None


def hair(name, x, n=4, npts=5):
    hc = bpy.data.hair_curves.new(name)
    hc.add_curves([npts] * (n * n))
    g = (np.arange(n) - (n - 1) / 2) * 0.2
    X, Y = np.meshgrid(g + x, g, indexing="ij")
    roots = np.stack([X.ravel(), Y.ravel(), np.zeros(n * n)], 1)
    P = (roots[:, None, :] + np.linspace(0, 1, npts)[None, :, None] * [0, 0, 1.0])
    hc.position_data.foreach_set("vector", P.reshape(-1).astype(np.float32))
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def box(name, x):
    bpy.ops.mesh.primitive_cube_add(size=0.5, location=(x - 1.0, 0, 0.6))
    ob = bpy.context.active_object
    ob.name = name
    ob.keyframe_insert("location", frame=1)
    ob.location.x = x + 1.0
    ob.keyframe_insert("location", frame=8)
    return ob


def skin(x):
    bpy.ops.mesh.primitive_plane_add(size=1.2, location=(x, 0, 0))
    ob = bpy.context.active_object
    ob.name = "Skin"
    return ob


def activate(ob, *others):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for o in (ob, *others):
        o.select_set(True)
    bpy.context.view_layer.objects.active = ob


def positions(ob):
    P = np.empty(len(ob.data.points) * 3, np.float32)
    ob.data.position_data.foreach_get("vector", P)
    return P.reshape(-1, 3)


def main():
    enable()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    fur, grass = hair("Fur", 0.0), hair("Grass", 3.0)
    fur.data.surface = skin(0.0)
    w = fur.data.attributes.new("angle_w", "FLOAT", "CURVE")
    w.data.foreach_set("value", np.linspace(0.5, 1.5, len(fur.data.curves), dtype=np.float32))
    ball, ball2 = box("Ball", 0.0), box("Ball2", 3.0)
    activate(fur, ball)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    activate(grass, ball2)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    for k, v in FUR.items():
        setattr(fur.furcollide, k, v)
    fur.furcollide.max_angle_map = "angle_w"
    s = grass.furcollide
    for k, v in GRASS.items():
        setattr(s, k, v)
    for f, v in GRASS_KEYS:
        s.max_angle = v
        grass.keyframe_insert("furcollide.max_angle", frame=f)
    act = grass.animation_data.action
    fcs = act.fcurves if hasattr(act, "fcurves") else []
    for fcu in fcs:
        fcu.keyframe_points[-1].interpolation = "LINEAR"
        fcu.keyframe_points[-2].interpolation = "LINEAR"
    drv = grass.driver_add("furcollide.scale_angle").driver
    drv.type = "SCRIPTED"
    drv.expression = "30 + frame"
    scene.render.use_lock_interface = True
    OUT.mkdir(parents=True, exist_ok=True)
    for p in OUT.glob("*"):
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    path = OUT / "old_settings.blend"
    bpy.context.preferences.filepaths.save_version = 0  # no .blend1
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True)
    for ob in (fur, grass):
        activate(ob)
        assert bpy.ops.furcollide.bake() == {"FINISHED"}, ob.name
    expected = {"blender": bpy.app.version_string, "frames": {}}
    points = {}
    reg = sys.modules[ADDON + ".operators.store.registry"]
    for f in range(1, 9):
        scene.frame_set(f)
        expected["frames"][f] = {
            ob.name: {"status": list(reg.status_for(ob)),
                      "outdated": bool(ob.furcollide.is_outdated),
                      "max_angle": ob.furcollide.max_angle,
                      "scale_angle": ob.furcollide.scale_angle}
            for ob in (fur, grass)}
        for ob in (fur, grass):
            points[f"{ob.name}_{f}"] = positions(ob.furcollide.output)
    np.savez_compressed(OUT / "expected_points.npz", **points)
    scene.frame_set(1)
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=True)
    # a user preset saved by the old Add Preset (from the output: it stores its source's)
    activate(fur)
    for k, v in PRESET.items():
        setattr(fur.furcollide, k, v)
    assert bpy.ops.furcollide.preset_add(name="Old Look") == {"FINISHED"}
    folder = bpy.utils.user_resource("SCRIPTS", path="presets/furcollide")
    shutil.copyfile(os.path.join(folder, "Old_Look.py"), OUT / "Old_Look.py")
    expected["settings"] = {
        ob.name: {k: getattr(ob.furcollide, k) for k in (
            "mode", "rotation_precision", "max_angle", "scale_angle", "pinch_resolution",
            "max_angle_map")} for ob in (grass,)}
    expected["settings"]["Fur"] = dict(FUR, max_angle_map="angle_w")
    expected["preset"] = PRESET
    (OUT / "expected.json").write_text(json.dumps(expected, indent=1))
    print("made", sorted(str(p.relative_to(OUT)) for p in OUT.rglob("*") if p.is_file()))
    sys.stdout.flush()
    os._exit(0)  # (bpy 4.2 can crash at exit)


main()
