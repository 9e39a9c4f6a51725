"""Blender end-to-end figure of the fur pipeline (run by ``bench_pipeline.py --blender``).

The demo's pipeline (``scripts/demo.py``: Fur Sampler -> FurCollide on the
guides with Fur Attach -> wind after collision, Region of Influence and the
collider distance attribute -> render groom with its clearance pass), its
render groom scaled to ``--curves`` curves, set up through the add-on's
operators with the ``bpy`` wheel and played frame by frame
(``scene.frame_set``: the add-on's frame handler runs every stage).

Per-stage times are taken from outside the add-on: the core calls it makes
are wrapped (nothing in ``operators/`` is changed), each time counted once,
in the outermost stage (the clearance pass's solver is clearance, not
collide):

* attach: ``Binding.apply`` / ``Binding.roots`` (guides' Fur Attach, render roots);
* collide: ``Solver.step`` (the guides);
* motion: ``wind``, ``jiggle``, ``collider_distance``, ``region_of_influence``;
* groom: ``deform_groom``;
* clearance: ``clearance_pass``;
* write: the glue's ``bridge.set_positions`` and ``stages.write_attributes``
  (``foreach_set`` into the outputs);
* rest: everything else in the frame (reading the evaluated inputs, colliders,
  caches, the depsgraph), the frame's wall time minus the stages.

Wall-clock milliseconds (the handler is single-threaded glue around the core's
threads), median over the frames after the first.

    .venv/bin/python bench/bench_pipeline_blender.py [--curves 50000] [--frames 24]
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = ROOT / "scripts"
STAGES = ("attach", "collide", "motion", "groom", "clearance", "write")


class Timer:
    """Per-stage wall time of the wrapped calls; nested calls count in the outermost."""

    def __init__(self):
        self.active = None
        self.frame = {}

    def wrap(self, owner, name, stage):
        fn = getattr(owner, name)
        timer = self

        @functools.wraps(fn)
        def timed(*args, **kwargs):
            if timer.active is not None:
                return fn(*args, **kwargs)
            timer.active = stage
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                timer.active = None
                timer.frame[stage] = timer.frame.get(stage, 0.0) + 1e3 * (
                    time.perf_counter() - t0)

        setattr(owner, name, timed)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--curves", type=int, default=50_000, help="render groom curves")
    ap.add_argument("--frames", type=int, default=24, help="frames played (from the start)")
    args = ap.parse_args(argv)
    user = tempfile.mkdtemp(prefix="furcollide_bench_user_")
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
    demo.pipeline_setup(bpy, scn)
    print(f"  pipeline set up in {time.perf_counter() - t0:.1f} s (sampler, attach bind, "
          "groom bind)", flush=True)

    core = sys.modules[pkg + ".core"]
    pl = sys.modules[pkg + ".core.pipeline"]
    bridge = sys.modules[pkg + ".operators.bridge"]
    stages = sys.modules[pkg + ".operators.stages"]
    timer = Timer()
    timer.wrap(pl.Binding, "apply", "attach")
    timer.wrap(pl.Binding, "roots", "attach")
    timer.wrap(core.Solver, "step", "collide")
    for name in ("wind", "jiggle", "collider_distance", "region_of_influence"):
        timer.wrap(pl, name, "motion")
    timer.wrap(pl, "deform_groom", "groom")
    timer.wrap(pl, "clearance_pass", "clearance")
    timer.wrap(bridge, "set_positions", "write")
    timer.wrap(stages, "write_attributes", "write")

    scene = scn.scene
    start = scene.frame_start
    rows = []
    for f in range(start, start + args.frames):
        timer.frame = {}
        t0 = time.perf_counter()
        scene.frame_set(f)
        total = 1e3 * (time.perf_counter() - t0)
        row = dict(timer.frame, total=total)
        row["rest"] = total - sum(timer.frame.values())
        rows.append(row)
    steady = rows[1:] or rows
    med = {k: float(np.median([r.get(k, 0.0) for r in steady]))
           for k in STAGES + ("rest", "total")}
    print(f"\n  Blender end-to-end, {args.frames} frames played (ms per frame, median of frames "
          f"2..{args.frames}; first frame {rows[0]['total']:.0f} ms):")
    print("  " + "".join(f"{k:>10}" for k in STAGES + ("rest", "total")))
    print("  " + "".join(f"{med[k]:10.1f}" for k in STAGES + ("rest", "total")))
    print(f"  ({1000.0 / med['total']:.1f} frames/s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
