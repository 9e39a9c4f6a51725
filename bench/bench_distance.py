"""Benchmark of ``core.pipeline.collider_distance`` at guide scale.

Scenes (seeded, numpy only), around a closed, displaced UV sphere (130,048
triangles, radius ~1) used as a rigid ``Collider`` with a rotation +
translation matrix, 10,000 curves x 8 CVs, 0.2 long (segments ~0.029):

* ``scatter`` (default): roots ``--offset lo,hi`` segment lengths off the
  surface (default 0,4), random directions with a little wobble: some
  curves pass close to the collider, most stay within a few segment
  lengths. ``--offset 1,6`` and ``2,8`` give fewer near CVs.
* ``fur``: curves rooted on the collider itself (2-10 mm above it), tilted
  up to 80 degrees and curled: most CVs near it (the worst case).

Times (CPU time of this thread, min / median over repeats) of
``collider_distance`` uncapped and with ``max_distance = 0.2 x curve
length`` (the Region of Influence use), for the first call on a fresh
Collider (cold: grids and fields built) and for repeated calls (warm: the
structures cached on the Collider reused).

    .venv/bin/python bench/bench_distance.py [--scene scatter|fur] [--offset LO,HI]
        [--curves N] [--cvs N] [--repeat N] [--profile capped|uncapped]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from core import Collider  # noqa: E402
from core.pipeline import collider_distance  # noqa: E402

LENGTH = 0.2


def body(n_u=512, n_v=128, seed=0):
    """Closed displaced UV sphere: 2 * n_u * (n_v - 1) triangles."""
    rng = np.random.default_rng(seed)
    th = np.linspace(0, np.pi, n_v + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, n_u, endpoint=False)
    T, Ph = np.meshgrid(th, ph, indexing="ij")
    k = rng.normal(0, 1, (6, 3))
    dirs = np.stack([np.sin(T) * np.cos(Ph), np.sin(T) * np.sin(Ph), np.cos(T)], -1)
    bump = sum(0.02 * np.sin(4 * (dirs @ k[i]) + i) for i in range(6))
    ring = (dirs * (1 + bump)[..., None]).reshape(-1, 3)
    V = np.vstack([ring, [[0, 0, 1]], [[0, 0, -1]]])
    top, bot = len(ring), len(ring) + 1
    F = []
    for i in range(n_v - 2):
        for j in range(n_u):
            a, b = i * n_u + j, i * n_u + (j + 1) % n_u
            c, d = a + n_u, b + n_u
            F += [[a, c, b], [b, c, d]]
    for j in range(n_u):
        F.append([top, j, (j + 1) % n_u])
        a, b = (n_v - 2) * n_u + j, (n_v - 2) * n_u + (j + 1) % n_u
        F.append([bot, b, a])
    return V, np.array(F, np.int64)


def fur(V, n_curves, cvs, seed=1):
    """Curves from just above the body's vertices, leaving radially (tilted)."""
    rng = np.random.default_rng(seed)
    v = V[rng.choice(len(V) - 2, n_curves, replace=False)]
    n = v / np.linalg.norm(v, axis=1, keepdims=True)
    t = np.cross(n, rng.normal(0, 1, (n_curves, 3)))
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    tilt = np.radians(rng.uniform(0, 80, n_curves))
    root = v + n * rng.uniform(0.002, 0.01, (n_curves, 1))
    seg = LENGTH / (cvs - 1)
    curl = rng.uniform(0, 0.3, n_curves)
    pts = np.empty((n_curves, cvs, 3))
    pts[:, 0] = root
    for j in range(1, cvs):
        a = tilt + curl * j
        d = np.cos(a)[:, None] * n + np.sin(a)[:, None] * t
        pts[:, j] = pts[:, j - 1] + seg * d
    off = np.arange(n_curves + 1, dtype=np.int64) * cvs
    return pts.reshape(-1, 3), off


def scatter(V, n_curves, cvs, seed=2, offset=(0.0, 4.0)):
    """Curves around the body: roots ``offset`` (min, max) segment lengths off the
    surface, random directions (some pass close to it, most stay within a few
    segment lengths)."""
    rng = np.random.default_rng(seed)
    v = V[rng.choice(len(V) - 2, n_curves, replace=False)]
    n = v / np.linalg.norm(v, axis=1, keepdims=True)
    seg = LENGTH / (cvs - 1)
    root = v + n * seg * rng.uniform(*offset, (n_curves, 1))
    d = rng.normal(0, 1, (n_curves, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = np.where((d * n).sum(1, keepdims=True) < -0.3, -d, d)  # mostly not into the body
    wob = rng.normal(0, 0.15, (n_curves, cvs - 1, 3))
    dirs = d[:, None, :] + wob
    dirs /= np.linalg.norm(dirs, axis=2, keepdims=True)
    pts = np.concatenate([root[:, None], root[:, None] + np.cumsum(seg * dirs, 1)], 1)
    off = np.arange(n_curves + 1, dtype=np.int64) * cvs
    return pts.reshape(-1, 3), off


def timeit(fn, repeat):
    ts = []
    out = None
    for _ in range(repeat):
        t0 = time.thread_time()
        out = fn()
        ts.append(time.thread_time() - t0)
    return np.array(ts), out


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--curves", type=int, default=10_000)
    ap.add_argument("--cvs", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--scene", choices=["scatter", "fur"], default="scatter")
    ap.add_argument("--offset", default="0,4",
                    help="scatter: root distance range, in segment lengths (default 0,4)")
    ap.add_argument("--profile", choices=["capped", "uncapped"], default=None)
    args = ap.parse_args(argv)

    V, F = body()
    R = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = [0.3, -0.2, 1.0]
    if args.scene == "scatter":
        lo, hi = (float(x) for x in args.offset.split(","))
        pts, off = scatter(V, args.curves, args.cvs, offset=(lo, hi))
    else:
        pts, off = fur(V, args.curves, args.cvs)
    pts = pts @ R.T + M[:3, 3]  # grown around the collider in world space
    cap = 0.2 * LENGTH
    print(f"scene {args.scene} (offset {args.offset}): collider {len(F)} triangles; "
          f"curves: {args.curves} x {args.cvs} = {len(pts)} CVs; cap {cap:g}")

    if args.profile:
        import cProfile
        import pstats
        col = Collider(V, F, matrix=M)
        kw = {"max_distance": cap} if args.profile == "capped" else {}
        collider_distance(pts, off, [col], **kw)
        pr = cProfile.Profile()
        pr.enable()
        collider_distance(pts, off, [col], **kw)
        pr.disable()
        pstats.Stats(pr).sort_stats("tottime").print_stats(18)
        return

    def cold(**kw):
        return collider_distance(pts, off, [Collider(V, F, matrix=M)], **kw)

    col = Collider(V, F, matrix=M)
    for name, kw in (("uncapped", {}), ("capped", {"max_distance": cap})):
        try:
            tc, _ = timeit(lambda kw=kw: cold(**kw), max(1, args.repeat // 2))
            collider_distance(pts, off, [col], **kw)  # warm up: build what this mode uses
            tw, d = timeit(lambda kw=kw: collider_distance(pts, off, [col], **kw), args.repeat)
        except TypeError as exc:  # before max_distance existed
            print(f"{name}: {exc}")
            continue
        near = np.mean(d < cap)
        print(f"{name:9s} cold min {1e3 * tc.min():7.1f} ms  warm min {1e3 * tw.min():7.1f} "
              f"ms  median {1e3 * np.median(tw):7.1f} ms   ({100 * near:.0f}% CVs < cap)")


if __name__ == "__main__":
    main()
