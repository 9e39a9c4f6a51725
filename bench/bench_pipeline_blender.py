"""Blender end-to-end figure of the fur pipeline (run by ``bench_pipeline.py --blender``).

The demo's pipeline (``scripts/demo.py``: Fur Sampler -> FurCollide on the
guides with Fur Attach -> wind after collision, Region of Influence and the
collider distance attribute -> render groom with its clearance pass), its
render groom scaled to ``--curves`` curves, set up through the add-on's
operators with the ``bpy`` wheel and played frame by frame
(``scene.frame_set``: the add-on's frame handler runs every stage).

The per-stage times are the add-on's own: the *Last Frame* statistics of the
setup (``operators/clock.py``; ``attach_ms`` ... ``write_ms``), what the panel
shows. The stages:

* attach: Fur Attach of the guides and the Surface of the render roots;
* collide: FurCollide on the guides (``Solver.step``);
* motion: wind, jiggle, the collider distance and the Region of Influence;
* groom: the render groom following the guides (``GroomDeformer``);
* clearance: the clearance pass (with reading its colliders);
* write: ``foreach_set`` into the outputs (positions, status, colours, attributes);
* rest: everything else in the frame (reading the evaluated inputs, colliders,
  caches, the depsgraph, Blender's own evaluation), the frame's wall time minus
  the stages.

Then the setup is baked (the bake holds the render groom too) and the baked
frames are played again: a baked frame is shown by reading its file, the render
groom included (no stage runs), next to the time of reading that file alone.

Wall-clock milliseconds (the handler is single-threaded glue around the core's
threads), median over the frames after the first.

    .venv/bin/python bench/bench_pipeline_blender.py [--curves 50000] [--frames 24]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = ROOT / "scripts"
STAGES = ("attach", "collide", "motion", "groom", "clearance", "write")


def play(bpy, scene, frames, stats_of):
    """Per frame: the setup's stage milliseconds, the rest and the frame's wall time."""
    rows = []
    for f in frames:
        t0 = time.perf_counter()
        scene.frame_set(f)
        total = 1e3 * (time.perf_counter() - t0)
        stats = stats_of()
        row = {k: float(stats.get(f"{k}_ms", 0.0)) for k in STAGES}
        row["total"] = total
        row["rest"] = total - sum(row[k] for k in STAGES)
        rows.append(row)
    return rows


def table(title, rows):
    steady = rows[1:] or rows
    med = {k: float(np.median([r[k] for r in steady])) for k in STAGES + ("rest", "total")}
    print(f"\n  {title} (ms per frame, median of frames 2..{len(rows)}; first frame "
          f"{rows[0]['total']:.0f} ms):")
    print("  " + "".join(f"{k:>10}" for k in STAGES + ("rest", "total")))
    print("  " + "".join(f"{med[k]:10.1f}" for k in STAGES + ("rest", "total")))
    print(f"  ({1000.0 / med['total']:.1f} frames/s)")
    return med


def main(argv=None):
    user = tempfile.mkdtemp(prefix="furcollide_bench_user_")
    try:
        return run(user, argv)
    finally:
        shutil.rmtree(user, ignore_errors=True)  # (the bake files too)


def run(user, argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--curves", type=int, default=50_000, help="render groom curves")
    ap.add_argument("--frames", type=int, default=24, help="frames played (from the start)")
    args = ap.parse_args(argv)
    os.environ["BLENDER_USER_RESOURCES"] = user
    sys.path.insert(0, str(SCRIPTS))
    import bpy
    import demo
    import demo_scene as ds

    demo.log = lambda msg: print(f"  {msg}", flush=True)
    t0 = time.perf_counter()
    scn = ds.build(fur_count=args.curves, grass_count=10)
    print(f"  Blender {bpy.app.version_string}: demo scene with {args.curves:,} render curves "
          f"built in {time.perf_counter() - t0:.1f} s", flush=True)
    mod = demo.enable_addon(bpy, user)
    if mod is None or not demo.has_pipeline_operators(bpy):
        print("  the add-on or its pipeline operators are not available: no Blender figure")
        return 1
    pkg = mod.__name__
    t0 = time.perf_counter()
    pipe = demo.pipeline_setup(bpy, scn)
    print(f"  pipeline set up in {time.perf_counter() - t0:.1f} s (sampler, attach bind, "
          "groom bind)", flush=True)

    registry = sys.modules[pkg + ".operators.registry"]
    framecache = sys.modules[pkg + ".core.framecache"]
    guides = pipe.guides
    scene = scn.scene
    start = scene.frame_start
    frames = list(range(start, start + args.frames))
    table(f"Blender end-to-end, {args.frames} frames played",
          play(bpy, scene, frames, lambda: registry.stats_for(guides)))

    # The bake holds the render groom: a baked frame only reads its file.
    s = guides.furcollide
    s.frame_start, s.frame_end = frames[0], frames[-1]
    bpy.ops.wm.save_as_mainfile(filepath=os.path.join(user, "bench.blend"))
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    guides.select_set(True)
    bpy.context.view_layer.objects.active = guides
    t0 = time.perf_counter()
    if bpy.ops.furcollide.bake() != {"FINISHED"} or not s.is_baked:
        print("  the bake failed: no baked figure")
        return 1
    print(f"\n  baked {len(frames)} frames in {time.perf_counter() - t0:.1f} s "
          f"(render groom baked: {s.groom.is_baked_with})", flush=True)
    med = table("Baked frames played", play(bpy, scene, frames,
                                              lambda: registry.stats_for(guides)))
    directory = bpy.path.abspath(s.bake_path)
    reads = []
    for f in frames[1:]:
        t0 = time.perf_counter()
        framecache.read_shown(directory, f)  # what a frame shown reads, all but the state
        reads.append(1e3 * (time.perf_counter() - t0))
    print(f"  reading a baked frame's file alone (guides, attributes, inputs record, render "
          f"groom): {np.median(reads):.1f} ms; shown: {med['total']:.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
