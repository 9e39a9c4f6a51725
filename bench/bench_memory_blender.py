"""Memory of a FurCollide setup in Blender at scale (issue 15; not a test).

Run: ``.venv/bin/python bench/bench_memory_blender.py [--side 448] [--frames 24]
[--limit 64] [--trace] [--top 12]``

Scene (the issue's): a grid of ``side x side`` hair curves x 8 CVs on a skin plane
(448 x 448 = 200,704 curves, 1.6 M points) and a ball (64 x 32 UV sphere) lowered
onto them over the frames. Prints, in MB:

* ``rss``: the process's resident memory (``VmRSS`` of ``/proc/self/status``):
  Blender's own data (the source, the output and their evaluated copies) and ours;
* ``numpy``: what ``tracemalloc`` sees allocated and still alive (numpy's buffers
  report to it; Blender's C allocations do not) (``--trace``: slower);
* ``cache``: the playback cache's own count (``MemoryCache.nbytes``);
* ``peak``: the most ``tracemalloc`` saw allocated at once since the row before
  (``--trace``): what the frame's temporaries add to ``numpy`` for a moment, and
  what the allocator keeps at hand afterwards;

before **Add FurCollide**, after it, and after each frame played; then, with
``--trace``, the ``--top`` allocation sites that grew over Add and over the frames
after the cache limit was reached.

``--mode``: the setup's Mode (Stiff by default). ``--sink``: the frames the ball
takes to sink (then it stays: the same work every frame).

``--limit``: the setup's Memory Limit (MB) for the playback cache, small by default
so that the frames after it is reached show whether memory stays flat.
"""

from __future__ import annotations

import argparse
import gc
import os
import shutil
import sys
import tempfile
import tracemalloc
from pathlib import Path

_USER = tempfile.mkdtemp(prefix="furcollide_user_")
os.environ["BLENDER_USER_RESOURCES"] = _USER

import bpy  # noqa: E402  (after BLENDER_USER_RESOURCES)
import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ADDON = "bl_ext.fcmem.furcollide"
MB = 1024 * 1024


def rss_mb() -> float:
    """Resident memory of this process, MB."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def enable_addon(dev_dir: Path):
    import addon_utils  # needs bpy first

    (dev_dir / "furcollide").symlink_to(REPO, target_is_directory=True)
    repos = bpy.context.preferences.extensions.repos
    repos.new(name="fcmem", module="fcmem", custom_directory=str(dev_dir), source="USER")
    mod = addon_utils.enable(ADDON, default_set=True, handle_error=None)
    assert mod is not None, "FurCollide add-on failed to enable"
    return sys.modules[ADDON + ".operators"]


def build_scene(side: int, n_frames: int, sink: int | None = None):
    """The fur grid (``side`` x ``side`` curves x 8 CVs, spacing 0.005) on a skin
    plane, and a ball lowered onto it over ``sink`` frames (default: all
    ``n_frames``; it then stays there); (scene, hair, ball)."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, n_frames + 1
    npts, spacing = 8, 0.005
    hc = bpy.data.hair_curves.new("Fur")
    hc.add_curves([npts] * (side * side))
    xs = (np.arange(side) - (side - 1) / 2) * spacing
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    roots = np.stack([X.ravel(), Y.ravel(), np.zeros(side * side)], 1)
    t = np.linspace(0, 0.3, npts)
    P = (roots[:, None, :] + t[None, :, None] * np.array([0.0, 0.0, 1.0])).reshape(-1, 3)
    hc.position_data.foreach_set("vector", P.astype(np.float32).ravel())
    del P, roots, X, Y
    hair = bpy.data.objects.new("Fur", hc)
    scene.collection.objects.link(hair)
    half = side * spacing / 2 + 0.1
    bpy.ops.mesh.primitive_plane_add(size=2 * half, location=(0, 0, 0))
    skin = bpy.context.active_object
    skin.name = "Skin"
    hc.surface = skin
    bpy.ops.mesh.primitive_uv_sphere_add(segments=64, ring_count=32, radius=0.4)
    ball = bpy.context.active_object
    ball.name = "Ball"
    ball.location = (0.0, 0.0, 0.75)  # touching the tips from frame 2 on
    ball.keyframe_insert("location", frame=1)
    ball.location = (0.0, 0.0, 0.25)
    ball.keyframe_insert("location", frame=(sink or n_frames) + 1)
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    ball.select_set(True)
    hair.select_set(True)
    bpy.context.view_layer.objects.active = hair
    scene.frame_set(1)
    return scene, hair, ball


def top_growth(before, after, n, label):
    stats = after.compare_to(before, "lineno")
    print(f"\n  {label}: the {n} allocation sites that grew most (tracemalloc, MB)")
    for st in stats[:n]:
        if st.size_diff <= 0:
            break
        fr = st.traceback[0]
        name = fr.filename.split("furcollide/")[-1] if "furcollide/" in fr.filename else (
            "/".join(fr.filename.split("/")[-2:]))
        print(f"  {st.size_diff / MB:9.1f} {st.count_diff:7d}  {name}:{fr.lineno}")


def run(side, n_frames, limit, trace, top, sink=None, mode="stiff"):
    dev = Path(tempfile.mkdtemp(prefix="furcollide_dev_"))
    try:
        ops = enable_addon(dev)
        scene, hair, _ball = build_scene(side, n_frames, sink)
        if trace:
            tracemalloc.start(1)
        gc.collect()
        traced = (lambda: tracemalloc.get_traced_memory()[0] / MB) if trace else (
            lambda: float("nan"))
        snap = (lambda: tracemalloc.take_snapshot()) if trace else (lambda: None)
        print(f"  Blender {bpy.app.version_string}: {len(hair.data.curves):,} curves, "
              f"{len(hair.data.points):,} points; Memory Limit {limit} MB")
        print(f"  {'':>14} {'rss':>9} {'numpy':>9} {'cache':>9} {'peak':>9}")

        def row(label, rt=None):
            gc.collect()
            cache = rt.cache.memory.nbytes / MB if rt is not None else 0.0
            peak = tracemalloc.get_traced_memory()[1] / MB if trace else float("nan")
            r = (rss_mb(), traced(), cache, peak)
            print(f"  {label:>14} {r[0]:9.1f} {r[1]:9.1f} {r[2]:9.1f} {r[3]:9.1f}", flush=True)
            if trace:
                tracemalloc.reset_peak()
            return r

        hair.furcollide.mode = mode  # (before Add: its first frame is solved in it)
        base = row("before Add")
        s0 = snap()
        assert bpy.ops.furcollide.add() == {"FINISHED"}
        hair.furcollide.memory_limit = limit
        rt = ops.store.registry.get_runtime(hair)
        added = row("after Add", rt)
        s1 = snap()
        rows, snaps, full_at = [], {}, None
        for f in range(2, n_frames + 2):
            scene.frame_set(f)
            rows.append((f, *row(f"frame {f}", rt)))
            if full_at is None and rt.cache.memory.nbytes > 0.9 * limit * MB:
                full_at = f
            snaps[f] = snap()
        print(f"\n  Add: +{added[0] - base[0]:.0f} MB resident, +{added[1] - base[1]:.0f} MB "
              "numpy (tracemalloc)")
        after = [r for r in rows if full_at is not None and r[0] > full_at]
        if len(after) >= 2:
            per = (after[-1][1] - after[0][1]) / (after[-1][0] - after[0][0])
            res = [r[1] for r in after]
            print(f"  after the cache limit (frame {full_at} on): {per:+.2f} MB resident "
                  f"per frame over frames {after[0][0]}-{after[-1][0]} (between "
                  f"{min(res):.0f} and {max(res):.0f} MB)")
        per_all = (rows[-1][1] - rows[0][1]) / max(1, rows[-1][0] - rows[0][0])
        last = rows[-8:]
        print(f"  playback: {per_all:+.2f} MB resident per frame over frames "
              f"{rows[0][0]}-{rows[-1][0]} (cache {rows[-1][3]:.0f} MB at the end); "
              f"frames {last[0][0]}-{last[-1][0]}: {np.mean([r[1] for r in last]):.0f} MB "
              f"resident on average, {np.mean([r[2] for r in last]):.0f} MB numpy")
        if trace:
            top_growth(s0, s1, top, "Add")
            first = min(snaps) if full_at is None else full_at + 1
            if first < max(snaps):
                top_growth(snaps[first], snaps[max(snaps)], top,
                           f"frames {first}-{max(snaps)}")
    finally:
        link = dev / "furcollide"
        if link.is_symlink():
            link.unlink()  # the link only, never the repository behind it
        shutil.rmtree(dev, ignore_errors=True)
        shutil.rmtree(_USER, ignore_errors=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--side", type=int, default=448, help="curves per side of the grid")
    ap.add_argument("--frames", type=int, default=24)
    ap.add_argument("--limit", type=int, default=64, help="Memory Limit of the cache, MB")
    ap.add_argument("--trace", action="store_true", help="tracemalloc (slower)")
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--sink", type=int, default=None,
                    help="frames the ball takes to sink (default: --frames); then it stays")
    ap.add_argument("--mode", default="stiff", choices=("stiff", "bend", "soft"))
    a = ap.parse_args()
    run(a.side, a.frames, a.limit, a.trace, a.top, a.sink, a.mode)
