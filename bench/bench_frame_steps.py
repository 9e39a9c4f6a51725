"""How a played frame walks through the glue: calls between ``operators`` modules (not a test).

Run: ``.venv/bin/python bench/bench_frame_steps.py [--frames 8] [--repo PATH]``

Scene: 36 hair curves, a box sweeping through them (rigid, keyframed), a growth
surface. Plays ``scene.frame_set`` forward once (frame 1 solves from the groom), then
counts, for each normally played frame (a step from the frame before, and a cached
frame scrubbed to), with ``sys.setprofile``:

* ``steps``: Python calls from one module of the add-on's ``operators`` package into
  another (a call inside a module is not a step);
* the calls of a few functions the frame's path should make once: the output written,
  the status set, the colliders listed, the settings' fingerprints (signature and
  structure) computed.

``--repo`` measures another checkout (an A/B of two trees, each run in its own
process).
"""

from __future__ import annotations

import argparse
import collections
import os
import shutil
import sys
import tempfile
from pathlib import Path

_USER = tempfile.mkdtemp(prefix="furcollide_user_")
os.environ["BLENDER_USER_RESOURCES"] = _USER

import bpy  # noqa: E402  (after BLENDER_USER_RESOURCES)
import numpy as np  # noqa: E402

ADDON = "bl_ext.fcsteps.furcollide"
OPS = ADDON + ".operators"

#: Functions counted by name (wherever they live in either layout).
WATCHED = {
    "write": ("frame_outputs", "output"),  # the output hair written
    "set_status": ("registry", "report"),  # the setup's status set
    "collider_objects": ("colliders",),  # the setup's colliders listed
    "signature": ("setup", "fingerprints"),  # the settings' fingerprint
    "structure": ("setup", "fingerprints"),  # what every frame shares...
    "structures": ("fingerprints",),  # ...with and without identities, in one pass
}


def enable_addon(repo: Path, dev_dir: Path):
    import addon_utils  # needs bpy first

    (dev_dir / "furcollide").symlink_to(repo, target_is_directory=True)
    repos = bpy.context.preferences.extensions.repos
    repos.new(name="fcsteps", module="fcsteps", custom_directory=str(dev_dir), source="USER")
    mod = addon_utils.enable(ADDON, default_set=True, handle_error=None)
    assert mod is not None, "FurCollide add-on failed to enable"


def build_scene(n_frames: int):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, n_frames
    hc = bpy.data.hair_curves.new("Fur")
    nx = ny = 6
    hc.add_curves([5] * (nx * ny))
    xs = (np.arange(nx) - (nx - 1) / 2) * 0.2
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    roots = np.stack([X.ravel(), Y.ravel(), np.zeros(nx * ny)], 1)
    t = np.linspace(0, 1.0, 5)
    P = (roots[:, None, :] + t[None, :, None] * np.array([0, 0, 1.0])).reshape(-1, 3)
    hc.position_data.foreach_set("vector", P.astype(np.float32).ravel())
    hair = bpy.data.objects.new("Fur", hc)
    scene.collection.objects.link(hair)
    bpy.ops.mesh.primitive_cube_add(size=0.5, location=(-1.2, 0.0, 0.6))
    box = bpy.context.active_object
    box.keyframe_insert("location", frame=1)
    box.location = (1.2, 0.0, 0.6)
    box.keyframe_insert("location", frame=n_frames)
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    box.select_set(True)
    hair.select_set(True)
    bpy.context.view_layer.objects.active = hair
    scene.frame_set(1)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    hair.furcollide.frame_end = n_frames
    return scene, hair


def _short(module: str) -> str:
    return module[len(OPS) + 1:] if module.startswith(OPS + ".") else module


def count_frame(scene, f):
    """(cross-module steps, Counter of watched calls, Counter of steps by edge)."""
    steps = 0
    watched = collections.Counter()
    edges = collections.Counter()

    def prof(frame, event, _arg):
        nonlocal steps
        if event != "call":
            return
        callee = frame.f_globals.get("__name__", "")
        if not callee.startswith(OPS):
            return
        name = frame.f_code.co_name
        tail = _short(callee).rpartition(".")[2]
        if name in WATCHED and tail in WATCHED[name]:
            watched[name] += 1
        back = frame.f_back
        caller = back.f_globals.get("__name__", "") if back is not None else ""
        if caller.startswith(OPS) and caller != callee:
            steps += 1
            edges[(_short(caller), _short(callee))] += 1

    sys.setprofile(prof)
    try:
        scene.frame_set(f)
    finally:
        sys.setprofile(None)
    return steps, watched, edges


def run(n_frames: int, repo: Path, show_edges: bool):
    dev = Path(tempfile.mkdtemp(prefix="furcollide_dev_"))
    try:
        enable_addon(repo, dev)
        scene, _hair = build_scene(n_frames)
        scene.frame_set(1)
        played = [count_frame(scene, f) for f in range(2, n_frames + 1)]
        scrubbed = [count_frame(scene, f) for f in range(2, n_frames + 1)]
        print(f"tree: {repo}")
        for what, rows in (("played (a step)", played), ("scrubbed (cached)", scrubbed)):
            steps = [r[0] for r in rows]
            total = collections.Counter()
            for r in rows:
                total.update(r[1])
            calls = ", ".join(f"{k} {total[k] / len(rows):.1f}" for k in WATCHED)
            print(f"  {what}: {np.median(steps):.0f} steps between modules a frame "
                  f"(min {min(steps)}, max {max(steps)}); calls a frame: {calls}")
            if show_edges:
                edges = collections.Counter()
                for r in rows:
                    edges.update(r[2])
                for (a, b), n in edges.most_common():
                    print(f"    {n / len(rows):5.1f}  {a} -> {b}")
    finally:
        link = dev / "furcollide"
        if link.is_symlink():
            link.unlink()  # the link only, never the repository behind it
        shutil.rmtree(dev, ignore_errors=True)
        shutil.rmtree(_USER, ignore_errors=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--repo", type=Path, default=Path(__file__).resolve().parents[1])
    ap.add_argument("--edges", action="store_true", help="the steps by caller -> callee")
    a = ap.parse_args()
    run(a.frames, a.repo.resolve(), a.edges)
