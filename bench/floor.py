"""The floor: the least work any segment-vs-mesh collider must do per frame.

One embree ray per segment (all of them, no culling), split over ``threads``
pinned worker threads, plus the numpy set-up of those rays from the CV
positions. For a rigid collider the CVs are first moved into the collider's
own space with the inverse world matrix (the scene is never rebuilt); for a
deforming collider a fresh ``TriangleMesh`` is built and committed from the
moved vertices (embree's BVH commit happens lazily in the first ``run``).

Only numpy + embreex; nothing from ``core``.
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from embreex import mesh_construction as mc
from embreex import rtcore_scene as rs


def _cpus() -> list[int]:
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return list(range(os.cpu_count() or 1))


class PinnedPool:
    """A thread pool whose worker ``i`` is pinned to CPU ``i % ncpu`` (Linux).

    On 2-vCPU VMs an unpinned 2-thread pool sometimes lands both workers on
    one CPU and runs at 1-thread speed; pinning removes that bimodality.
    """

    def __init__(self, threads: int, pin: bool = True):
        self.threads = max(1, int(threads))
        self._cpus = _cpus()
        self._next = 0
        self._lock = threading.Lock()
        self._pin = pin and hasattr(os, "sched_setaffinity")
        self.pool = ThreadPoolExecutor(self.threads, initializer=self._init)
        # start every worker now so pinning is not inside a timed region
        list(self.pool.map(lambda _: time.sleep(0.01), range(self.threads)))

    def _init(self):
        if not self._pin:
            return
        with self._lock:
            cpu = self._cpus[self._next % len(self._cpus)]
            self._next += 1
        os.sched_setaffinity(0, {cpu})  # 0 = the calling thread on Linux

    def shutdown(self):
        self.pool.shutdown()


def build_scene(V: np.ndarray, F: np.ndarray):
    scene = rs.EmbreeScene()
    mc.TriangleMesh(scene, np.ascontiguousarray(V, np.float32), np.ascontiguousarray(F, np.int32))
    return scene


def segment_index(offsets: np.ndarray) -> np.ndarray:
    """Index of the first CV of every segment (precomputed once, topology)."""
    P = int(offsets[-1])
    is_start = np.ones(P, dtype=bool)
    is_start[offsets[1:] - 1] = False
    return np.flatnonzero(is_start)


def setup_rays(points: np.ndarray, seg0: np.ndarray, inv: np.ndarray | None):
    """Origins, directions (segment vectors) and tfar = 1 for every segment.

    With ``inv`` (the collider's inverse world matrix) the CVs are first
    moved into the collider's space. This is the fastest plain-numpy form we
    found (``np.take`` beats fancy indexing 3x; a flat add of the tiled
    translation beats a (P,3)+(3,) broadcast), so the floor is not inflated.
    """
    if inv is not None:
        p = points @ inv[:3, :3].T.astype(np.float32)
        p.reshape(-1).__iadd__(np.tile(inv[:3, 3].astype(np.float32), len(p)))
    else:
        p = points
    org = np.take(p, seg0, axis=0)
    dirs = np.take(p, seg0 + 1, axis=0)
    dirs -= org
    return org, dirs, np.ones(len(org), dtype=np.float32)


def trace(scene, org, dirs, dists, pool: PinnedPool):
    """First hit of every ray, split in ``pool.threads`` contiguous chunks."""
    n = len(org)
    k = pool.threads
    bounds = [n * i // k for i in range(k + 1)]

    def run(i):
        a, b = bounds[i], bounds[i + 1]
        return scene.run(org[a:b], dirs[a:b], dists=dists[a:b], query="INTERSECT", output=1)

    parts = list(pool.pool.map(run, range(k)))
    return np.concatenate([p["primID"] for p in parts])


def measure_rigid(points, offsets, V, F, M, pool, repeats=15):
    """Floor ms per frame for a rigid collider (median of ``repeats``)."""
    scene = build_scene(V, F)
    seg0 = segment_index(offsets)
    inv = np.linalg.inv(M)
    trace(scene, *setup_rays(points, seg0, inv), pool)  # lazy commit, warm-up
    t_set, t_ray, tot, hits = [], [], [], 0
    for _ in range(repeats):
        t0 = time.perf_counter()
        rays = setup_rays(points, seg0, inv)
        t1 = time.perf_counter()
        prim = trace(scene, *rays, pool)
        t2 = time.perf_counter()
        t_set.append(t1 - t0)
        t_ray.append(t2 - t1)
        tot.append(t2 - t0)
        hits = int((prim >= 0).sum())
    ms = lambda x: 1000.0 * float(np.median(x))  # noqa: E731
    return {"total": ms(tot), "setup": ms(t_set), "rays": ms(t_ray), "hit_segments": hits}


def measure_deforming(points, offsets, Vw, F, pool, repeats=7):
    """Floor ms per frame for a deforming collider given in world space:
    TriangleMesh build + commit (first run) + ray set-up + rays."""
    seg0 = segment_index(offsets)
    F = np.ascontiguousarray(F, np.int32)
    t_build, t_set, t_ray, tot = [], [], [], []
    for i in range(repeats):
        # a fresh array every time, like a new frame's vertices
        Vi = np.ascontiguousarray(Vw * np.float32(1.0 + 1e-6 * i), np.float32)
        t0 = time.perf_counter()
        scene = build_scene(Vi, F)
        t1 = time.perf_counter()
        rays = setup_rays(points, seg0, None)
        t2 = time.perf_counter()
        trace(scene, *rays, pool)  # includes the lazy BVH commit
        t3 = time.perf_counter()
        t_build.append(t1 - t0)
        t_set.append(t2 - t1)
        t_ray.append(t3 - t2)
        tot.append(t3 - t0)
        del scene
    ms = lambda x: 1000.0 * float(np.median(x))  # noqa: E731
    return {
        "total": ms(tot),
        "mesh_build": ms(t_build),
        "setup": ms(t_set),
        "rays+commit": ms(t_ray),
    }
