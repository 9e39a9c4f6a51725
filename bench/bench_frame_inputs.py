"""Cost of the frame-inputs check at paper scale (not a test).

Run: ``.venv/bin/python bench/bench_frame_inputs.py [--frames 10] [--repeat 5]
[--deforming]``

Scene (``bench_glue.build_scene``): 50,000 hair curves x 8 CVs on a moved and turned
hair object, a 130k-triangle UV sphere (rigid, keyframed) sweeping through them;
``--deforming`` gives the sphere a Displace modifier (a deforming collider).

Plays the frames once (solving them), then scrubs through the cached frames and
prints what the check that runs before a cached frame is shown costs per frame
(``frame_inputs.cached_frame_change``: reading every collider's matrix and shape, digesting
them, the source's positions and the settings, and comparing with the frame's record),
in wall-clock and main-thread CPU time, with its parts and its share of the handler.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import bench_glue  # noqa: F401  (sets BLENDER_USER_RESOURCES before bpy)
import bpy  # noqa: E402
import numpy as np  # noqa: E402


def _clock(fn, into):
    def wrapper(*args, **kw):
        t, c = time.perf_counter(), time.thread_time()
        try:
            return fn(*args, **kw)
        finally:
            into.append(((time.perf_counter() - t) * 1e3, (time.thread_time() - c) * 1e3))
    return wrapper


def _best(fn, repeat=50):
    fn()
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t) * 1e3)
    return float(np.median(ts))


def run(n_frames: int, repeat: int, deforming: bool):
    dev = Path(tempfile.mkdtemp(prefix="furcollide_dev_"))
    try:
        ops = bench_glue.enable_addon(dev)
        cache = sys.modules[bench_glue.ADDON + ".core.framecache"]
        scene, hair, n_tris = bench_glue.build_scene(n_frames)
        ball = next(o for o in scene.objects if o.type == "MESH")
        if deforming:
            ball.modifiers.new("Displace", "DISPLACE").strength = 0.01
            ops.store.registry.clear_runtime(hair)
        print(f"{len(hair.data.curves)} curves, {len(hair.data.points)} points, collider "
              f"{n_tris} triangles, {'deforming' if deforming else 'rigid'}")
        for f in range(1, n_frames + 2):  # solve (not measured)
            scene.frame_set(f)
        rt = ops.store.registry.get_runtime(hair)
        assert len(rt.cache.memory) == n_frames + 1, len(rt.cache.memory)

        checks, handler = [], []
        rules, spine = ops.frame.rules, ops.frame.spine
        real_check, real_eval = rules.cached_frame_change, spine.evaluate
        rules.cached_frame_change = _clock(real_check, checks)
        spine.evaluate = _clock(real_eval, handler)
        try:
            for _ in range(repeat):
                for f in range(1, n_frames + 2):
                    scene.frame_set(f)
                    assert ops.store.report.stats_for(hair).get("source") == "cache", f
        finally:
            rules.cached_frame_change, spine.evaluate = real_check, real_eval
        wall, cpu = np.median(np.array(checks), axis=0)
        h = np.median(np.array(handler)[:, 0])
        print(f"check per cached frame: median {wall:.3f} ms wall, {cpu:.3f} ms main-thread "
              f"CPU (best {min(c[0] for c in checks):.3f} ms; {len(checks)} frames); "
              f"handler for a cached frame {h:.1f} ms ({100 * wall / h:.1f} % of it)")

        # its parts, on the last frame
        dg = bpy.context.evaluated_depsgraph_get()
        setup = ops.frame.setup.Setup(hair, scene, dg)
        inp = ops.frame.inputs.read_inputs(setup)
        read = ops.settings.fingerprints.read_settings(hair, scene)
        ref = ops.frame.colliders.collider_objects(hair, scene)[0]
        parts = {
            "source digest (own positions + offsets + matrix)": lambda: cache.digest(
                inp.source_local, inp.offsets, inp.source_matrix),
            "collider read + digests": lambda: ops.frame.colliders.read_collider_inputs(
                ref.object, dg, ref.matrix(dg)),
            "settings signature": lambda: ops.settings.fingerprints.signature(
                hair, scene=scene, identities=False),
            "whole record (current_inputs)": lambda: ops.frame.record.current_inputs(setup, inp,
                                                                                read),
        }
        for name, fn in parts.items():
            print(f"  {name:38s} {_best(fn):.3f} ms")
    finally:
        link = dev / "furcollide"
        if link.is_symlink():
            link.unlink()  # the link only, never the repository behind it
        shutil.rmtree(dev, ignore_errors=True)


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--repeat", type=int, default=5, help="scrubs through the cached frames")
    ap.add_argument("--deforming", action="store_true", help="the sphere gets a modifier")
    a = ap.parse_args()
    run(a.frames, a.repeat, a.deforming)
