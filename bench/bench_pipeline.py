"""Fur pipeline benchmark (``make bench-pipeline``): every per-frame stage, timed.

The scene of issue 11 (procedural, seeded, numpy only): a head-like growth
surface (a deformed UV sphere, ~20,000 triangles) turning and nodding over
48 frames; a render groom of 50,000 curves x 8 CVs on its scalp; 7,500
guides picked by ``sample_guides`` (15 %), bound with Fur Attach and
collided in Bend with a 130,000-triangle closed shell (a hood-like
ellipsoid) that rests on the head and swings +-25 degrees.

Per frame, in the order of the add-on's frame handler:

* ``attach``: ``Binding.apply`` of the render groom's Fur Attach;
* ``collide``: the guides' Fur Attach and ``Solver.step`` (FurCollide itself;
  not a pipeline stage, printed for scale);
* ``motion``: ``wind`` after collision + ``collider_distance`` (capped at the
  longest displacement, as the add-on does) + ``region_of_influence``;
* ``groom``: the render groom following the guides (``GroomDeformer.deform``, its
  bind-time work made once with the scene; roots from its Fur Attach);
* ``clearance``: ``clearance_pass`` of the deformed render groom;
* ``clear_all``: for scale, what the clearance pass did before it culled the
  curves that cannot change (the solver, fresh, Stiff, on every render curve:
  the same points and statuses). Printed, not a pipeline stage.

Each stage's time is printed as a ratio to the *rigid floor* measured in the
same run, interleaved with the frames (``bench/floor.py``: one embree ray per
segment of the 50,000-curve groom on 2 pinned threads plus the numpy set-up,
the collider moved by its matrix). Both wall time and CPU time (all threads
of the process) are given; the CPU ratio is the one to trust on a busy
machine. Then the linear-scaling check (each stage from 10k to 500k render
curves) and each stage's peak memory (tracemalloc, numpy's allocations), and
the Blender end-to-end figure (``bench_pipeline_blender.py``: the demo's
pipeline at the same render-curve count, played through the operators).
Targets are printed with PASS/MISS, never asserted.

    .venv/bin/python bench/bench_pipeline.py            # everything (~10 min)
    .venv/bin/python bench/bench_pipeline.py --quick    # smoke run (~20 s)
    .venv/bin/python bench/bench_pipeline.py --no-scaling --frames 8
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
for p in (str(ROOT), str(HERE)):
    if p not in sys.path:
        sys.path.insert(0, p)

import floor  # noqa: E402
import scene as core_scene  # noqa: E402
from cpu import OpenBlas, single_blas  # noqa: E402

from core import Collider, Settings, Solver  # noqa: E402
from core.pipeline import (  # noqa: E402
    GroomDeformer,
    bind,
    bind_groom,
    clearance_pass,
    collider_distance,
    region_of_influence,
    sample_guides,
    wind,
)

BLAS = OpenBlas()

#: Targets of issue 11, as ratios to the rigid floor of the same run.
TARGETS = {"groom": 3.0, "motion": 1.0, "clearance": 3.0, "attach": 0.5}
STAGES = ("attach", "collide", "motion", "groom", "clearance", "clear_all")
HEAD_CENTRE = np.array([0.0, 0.0, 0.0])
SWING_DEG = 25.0


# ------------------------------------------------------------------ scene
def head_surface(tris=20_000):
    """A head-like closed surface (V float64, F int64): an egg-shaped skull, narrower
    at the temples, a jaw, a brow and a nose bump; ~1 unit tall."""
    V, F = core_scene.uv_sphere(tris)
    V = V.astype(np.float64)
    x, y, z = V.T
    jaw = np.clip(-z, 0, 1)
    sx = 0.78 * (1 - 0.28 * jaw**2)
    sy = 0.95 * (1 - 0.15 * jaw**2) * (1 + 0.06 * np.clip(-y, 0, 1))
    W = np.stack([x * sx, y * sy, z * (1.0 + 0.08 * np.clip(z, 0, 1))], 1)
    # brow ridge and nose on the front (-y)
    front = np.clip(-y, 0, 1)
    W[:, 1] -= 0.06 * front**4 * np.exp(-((z - 0.25) / 0.12) ** 2)
    W[:, 1] -= 0.12 * front**8 * np.exp(-((z + 0.05) / 0.15) ** 2 - (x / 0.1) ** 2)
    return W, F.astype(np.int64)


def scalp_curves(V, F, curves, cvs=8, seed=3):
    """Render groom: roots uniformly (by area) on the scalp, hair combed back and down."""
    rng = np.random.default_rng(seed)
    T = V[F]
    c = T.mean(1)
    n = np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    scalp = (c[:, 2] > 0.05) | ((c[:, 1] > 0.1) & (c[:, 2] > -0.55))
    p = np.where(scalp, area, 0.0)
    tri = rng.choice(len(F), curves, p=p / p.sum())
    u, v = rng.random(curves), rng.random(curves)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = T[tri]
    roots = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    nrm = n[tri]
    comb = np.array([0.0, 0.6, -1.0])
    comb /= np.linalg.norm(comb)
    side = comb - (nrm @ comb)[:, None] * nrm
    side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-9)
    length = rng.uniform(0.18, 0.3, curves)
    lift = np.radians(rng.uniform(25, 55, curves))  # leaves the skin at this angle
    droop = np.radians(rng.uniform(10, 40, curves))  # then bends toward the skin
    pts = np.empty((curves, cvs, 3))
    pts[:, 0] = roots
    seg = (length / (cvs - 1))[:, None]
    for k in range(cvs - 1):
        a = lift - droop * k / max(cvs - 2, 1)
        d = nrm * np.sin(a)[:, None] + side * np.cos(a)[:, None]
        pts[:, k + 1] = pts[:, k] + seg * d
    off = np.arange(curves + 1, dtype=np.int64) * cvs
    return pts.reshape(-1, 3), off


def _rot(axis, angle):
    return core_scene._rot(axis, angle)


def head_pose(frame, frames):
    """4x4 rigid world matrix of the head: a slow turn and a nod."""
    u = frame / max(frames - 1, 1)
    R = _rot([0, 0, 1], math.radians(20) * math.sin(2 * math.pi * u)) @ _rot(
        [1, 0, 0], math.radians(8) * math.sin(4 * math.pi * u))
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = [0.02 * u, 0.0, 0.01 * math.sin(2 * math.pi * u)]
    return M


def head_vertices(V, frame, frames):
    """World vertices of the head at ``frame``: its pose plus a small jaw/skin wave."""
    M = head_pose(frame, frames)
    W = V.copy()
    W[:, 2] += 0.01 * np.sin(3 * V[:, 0] + 0.4 * frame) * np.clip(-V[:, 2], 0, 1)
    return W @ M[:3, :3].T + M[:3, 3]


def _cap(k, axes, theta_max):
    """Vertices of an ellipsoid cap: the pole, then ``k`` rings of ``2 k`` points."""
    theta = np.linspace(0.0, theta_max, k + 1)[1:]
    lon = np.linspace(0.0, 2 * math.pi, 2 * k, endpoint=False)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    ring = np.stack([st * np.cos(lon), st * np.sin(lon), np.broadcast_to(ct, (k, 2 * k))], -1)
    return np.concatenate([[[0.0, 0.0, 1.0]], ring.reshape(-1, 3)]) * np.asarray(axes)


def _cap_faces(k, base):
    n = 2 * k
    j = np.arange(n)

    def vid(r, j):
        return base + 1 + r * n + j % n

    faces = [np.stack([np.full(n, base), vid(0, j), vid(0, j + 1)], 1)]
    r = np.arange(k - 1)[:, None]
    a, b, c, d = vid(r, j), vid(r, j + 1), vid(r + 1, j), vid(r + 1, j + 1)
    faces += [np.stack([a, c, d], -1).reshape(-1, 3), np.stack([a, d, b], -1).reshape(-1, 3)]
    return np.concatenate(faces)


def shell(tris, gap=0.13, thickness=0.2, theta_max=1.2):
    """The shell, a closed helmet around the skull (its own space, float32 V, int32 F):
    an inner cap ``gap`` above the skin's ellipsoid, an outer cap ``thickness``
    farther, joined at the rim; about ``tris`` triangles. Hair that rises more
    than ``gap`` off the scalp crosses its inner surface."""
    k = max(4, round(math.sqrt(tris / 8.0)))
    skin = np.array([0.78, 0.96, 1.08])
    outer = _cap(k, skin + gap + thickness, theta_max)
    inner = _cap(k, skin + gap, theta_max)
    n = len(outer)
    fo = _cap_faces(k, 0)
    fi = _cap_faces(k, n)[:, ::-1]  # facing the head: the solid is between the caps
    j = np.arange(2 * k)
    a, b = n - 2 * k + j, n - 2 * k + (j + 1) % (2 * k)  # outer rim
    c, d = a + n, b + n  # inner rim
    rim = np.concatenate([np.stack([a, c, d], 1), np.stack([a, d, b], 1)])
    V = np.concatenate([outer, inner])
    F = np.concatenate([fo, fi, rim]).astype(np.int32)
    return np.ascontiguousarray(V, np.float32), F


def shell_matrix(frame, frames):
    """The shell rests on the head, around the skull, and swings +-25 degrees
    about the head's x axis (its pose follows the head's turn)."""
    u = frame / max(frames - 1, 1)
    M = np.eye(4)
    M[:3, :3] = _rot([1, 0, 0], math.radians(SWING_DEG) * math.sin(2 * math.pi * u))
    return head_pose(frame, frames) @ M


class Scene:
    """The whole pipeline's bound inputs for ``curves`` render curves."""

    def __init__(self, curves, cvs=8, tris=130_000, head_tris=20_000, fraction=0.15,
                 frames=48, log=print, threads=2):
        self.frames = frames
        self.threads = threads  # every stage's (the floor's pool has 2 as well)
        t0 = time.perf_counter()
        self.V, self.F = head_surface(head_tris)
        self.render, self.roff = scalp_curves(self.V, self.F, curves, cvs)
        rroots = self.render[self.roff[:-1]]
        ts = time.perf_counter()
        gidx = sample_guides(rroots, self.V, self.F, fraction, seed=1)
        self.t_sample = time.perf_counter() - ts
        sizes = np.diff(self.roff)[gidx]
        rows = (self.roff[gidx][:, None] + np.arange(cvs)).ravel()
        self.guides = self.render[rows]
        self.goff = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        tb = time.perf_counter()
        self.gbind = bind(self.guides, self.goff, self.V, self.F)
        self.rbind = bind(self.render, self.roff, self.V, self.F)
        self.t_bind = time.perf_counter() - tb
        self.weights = bind_groom(rroots, self.guides[self.goff[:-1]], 4)
        self.deformer = GroomDeformer(self.render, self.roff, self.guides, self.goff,
                                      self.weights)
        self.SV, self.SF = shell(tris)
        self.col = Collider(self.SV, self.SF, matrix=shell_matrix(0, frames), name="shell")
        self.solver = Solver(self.goff, Settings(mode="bend", threads=threads))
        self.frame = -1
        log(f"  scene  : {curves:,} render curves x {cvs} CVs, {len(self.goff) - 1:,} guides "
            f"(sample_guides {self.t_sample:.1f} s, bind x2 {self.t_bind:.1f} s), head "
            f"{len(self.F):,} triangles, shell {len(self.SF):,} triangles "
            f"[built in {time.perf_counter() - t0:.1f} s]")

    def advance(self, frame):
        """Step the guides' solver up to ``frame`` (untimed), return the frame's inputs."""
        while self.frame < frame:
            self.frame += 1
            Vn = head_vertices(self.V, self.frame, self.frames)
            self.col.matrix = shell_matrix(self.frame, self.frames)
            g_in = self.gbind.apply(Vn, threads=self.threads)
            self.res = self.solver.step(g_in, [self.col])
            self.Vn, self.g_in = Vn, g_in
        return self.Vn


# ------------------------------------------------------------------ stages
def stage_attach(sc, Vn):
    """Fur Attach of the render groom (the guides' is timed with collide)."""
    return sc.rbind.apply(Vn, threads=sc.threads)


def stage_motion(sc, guides_out, frame):
    """Wind after collision, its collider distance capped at the longest
    displacement (as core/pipeline/frame.py does), the Region of Influence."""
    blown = wind(guides_out, sc.goff, frame, direction=(1.0, 0.3, -0.2), strength=0.08,
                 turbulence=0.5)
    reach = float(np.sqrt(((blown - guides_out) ** 2).sum(1).max()))
    dist = collider_distance(guides_out, sc.goff, [sc.col], max_distance=reach)
    return region_of_influence(guides_out, sc.goff, blown, dist)


def stage_groom(sc, guides_final, render_attached):
    return sc.deformer.deform(guides_final, render_attached[sc.roff[:-1]], threads=sc.threads)


def stage_clearance(sc, render_now):
    return clearance_pass(render_now, sc.roff, [sc.col])


class Clock:
    """Wall and process CPU time (all threads) of a block."""

    def __enter__(self):
        self.w0, self.c0 = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc):
        self.wall = 1e3 * (time.perf_counter() - self.w0)
        self.cpu = 1e3 * (time.process_time() - self.c0)


def floor_once(sc, pts, M, pool, scn, seg0):
    """One rigid-floor frame of the render groom (wall ms, CPU ms)."""
    with single_blas(), Clock() as c:
        inv = np.linalg.inv(M)
        floor.trace(scn, *floor.setup_rays(pts, seg0, inv), pool)
    return c.wall, c.cpu


def run_frames(sc, args, pool):
    """Time every stage on ``args.frames`` frames of the shot; floors interleaved."""
    scn = floor.build_scene(sc.SV, sc.SF)
    seg0 = floor.segment_index(sc.roff)
    rest32 = np.asarray(sc.render, np.float32)
    floor.trace(scn, *floor.setup_rays(rest32, seg0, None), pool)  # commit
    start = args.first_frame
    frames = list(range(start, start + args.frames))
    rec = {k: {"wall": [], "cpu": []} for k in STAGES + ("floor",)}
    info = {"fixed": [], "colliding": []}
    first = {}
    for i, f in enumerate(frames):
        sc.advance(f - 1)
        Vn = head_vertices(sc.V, f, sc.frames)
        sc.col.matrix = shell_matrix(f, sc.frames)
        out = {}
        with Clock() as c:
            out["attach"] = stage_attach(sc, Vn)
        t = {"attach": c}
        with Clock() as c:
            g_in = sc.gbind.apply(Vn, threads=sc.threads)
            res = sc.solver.step(g_in, [sc.col])
        sc.frame, sc.res, sc.Vn = f, res, Vn
        t["collide"] = c
        g_out = np.asarray(res.points, np.float64)
        with Clock() as c:
            g_fin = stage_motion(sc, g_out, f)
        t["motion"] = c
        with Clock() as c:
            r_now = stage_groom(sc, g_fin, out["attach"])
        t["groom"] = c
        with Clock() as c:
            _pts, _st, n_fixed = stage_clearance(sc, r_now)
        t["clearance"] = c
        with Clock() as c:
            Solver(sc.roff, Settings(mode="stiff")).step(r_now, [sc.col])
        t["clear_all"] = c
        info["fixed"].append(n_fixed)
        info["colliding"].append(int((np.asarray(res.status) == 1).sum()))
        fw, fc = floor_once(sc, np.asarray(r_now, np.float32), sc.col.matrix, pool, scn, seg0)
        if i == 0:
            first = {k: v.wall for k, v in t.items()}
            continue  # the first frame builds caches: reported apart
        for k, v in t.items():
            rec[k]["wall"].append(v.wall)
            rec[k]["cpu"].append(v.cpu)
        rec["floor"]["wall"].append(fw)
        rec["floor"]["cpu"].append(fc)
    return rec, info, first


def med(x):
    return float(np.median(x)) if len(x) else float("nan")


def print_frames(rec, info, first, n_curves):
    fw, fc = med(rec["floor"]["wall"]), med(rec["floor"]["cpu"])
    spread = np.percentile(rec["floor"]["wall"], [10, 90]) if rec["floor"]["wall"] else (0, 0)
    print(f"\n  rigid floor (render groom, 2 threads): {fw:6.1f} ms wall (10-90 %: "
          f"{spread[0]:.1f}-{spread[1]:.1f}), {fc:6.1f} ms CPU   [median of "
          f"{len(rec['floor']['wall'])} frames]")
    print(f"  {'stage':<11}{'wall ms':>9}{'ratio':>8}{'CPU ms':>9}{'ratio':>8}"
          f"{'first':>9}   target")
    out = {}
    for k in STAGES:
        w, c = med(rec[k]["wall"]), med(rec[k]["cpu"])
        tgt = TARGETS.get(k)
        rw, rc = w / fw, c / fc
        verdict = "" if tgt is None else f"<= {tgt:g}x  {'PASS' if rw <= tgt else 'MISS'}"
        print(f"  {k:<11}{w:9.1f}{rw:8.2f}{c:9.1f}{rc:8.2f}{first.get(k, 0):9.1f}   {verdict}")
        out[k] = (w, rw, c, rc)
    print(f"  (guides colliding per frame: median {int(med(info['colliding']))}; render curves "
          f"fixed by the clearance pass: median {int(med(info['fixed']))} of {n_curves:,})")
    return out


# ------------------------------------------------------------------ scaling + memory
def measure_stage(fn, repeat):
    """(median wall ms, median CPU ms) of ``fn`` over ``repeat`` calls after a warm-up."""
    fn()
    ws, cs = [], []
    for _ in range(repeat):
        with Clock() as c:
            fn()
        ws.append(c.wall)
        cs.append(c.cpu)
    return med(ws), med(cs)


def peak_mb(fn):
    """Peak numpy/Python memory of one call (tracemalloc), MB above the start."""
    tracemalloc.start()
    tracemalloc.reset_peak()
    base = tracemalloc.get_traced_memory()[0]
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return (peak - base) / 2**20


def stage_calls(sc, f):
    """The four pipeline stages of frame ``f`` as closures (inputs prepared, untimed)."""
    Vn = sc.advance(f)
    g_out = np.asarray(sc.res.points, np.float64)
    r_att = stage_attach(sc, Vn)
    g_fin = stage_motion(sc, g_out, f)
    r_now = stage_groom(sc, g_fin, r_att)
    return {
        "attach": lambda: stage_attach(sc, Vn),
        "motion": lambda: stage_motion(sc, g_out, f),
        "groom": lambda: stage_groom(sc, g_fin, r_att),
        "clearance": lambda: stage_clearance(sc, r_now),
    }


def scaling(args):
    sizes = [int(s) for s in args.sizes.split(",")]
    rows = {}
    for n in sizes:
        sc = Scene(n, tris=args.tris, frames=48, threads=args.threads,
                   log=lambda m: print("  " + m.strip()))
        calls = stage_calls(sc, args.scaling_frame)
        rows[n] = {}
        for k, fn in calls.items():
            w, c = measure_stage(fn, args.repeat)
            rows[n][k] = (w, c, peak_mb(fn))
        del sc, calls
    print(f"\n  linear scaling (CPU ms per 10k render curves; guides = 15 %; median of "
          f"{args.repeat}) and peak memory (tracemalloc MB):")
    head = "".join(f"{n // 1000:>9}k" for n in sizes)
    print(f"  {'stage':<11}{head}   slope  (1 = linear)   peak MB {head}")
    for k in ("attach", "motion", "groom", "clearance"):
        per = [rows[n][k][1] / (n / 10_000) for n in sizes]
        x = np.log([float(n) for n in sizes])
        y = np.log([max(rows[n][k][1], 1e-3) for n in sizes])
        slope = float(np.polyfit(x, y, 1)[0]) if len(sizes) > 1 else float("nan")
        mem = "".join(f"{rows[n][k][2]:10.0f}" for n in sizes)
        print(f"  {k:<11}" + "".join(f"{v:10.2f}" for v in per) + f"   {slope:5.2f}"
              + " " * 19 + mem)
    return rows


# ------------------------------------------------------------------ main
def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--curves", type=int, default=50_000, help="render curves (default 50,000)")
    ap.add_argument("--tris", type=int, default=130_000, help="shell triangles (approx.)")
    ap.add_argument("--frames", type=int, default=12, help="timed frames (after the first)")
    ap.add_argument("--first-frame", type=int, default=6,
                    help="first timed frame of the 48-frame shot (the shell is on the hair)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--sizes", default="10000,50000,100000,250000,500000",
                    help="render curve counts of the scaling check")
    ap.add_argument("--scaling-frame", type=int, default=8)
    ap.add_argument("--repeat", type=int, default=3, help="repeats per size (scaling)")
    ap.add_argument("--no-scaling", action="store_true")
    ap.add_argument("--no-frames", action="store_true")
    ap.add_argument("--no-blender", action="store_true",
                    help="skip the Blender end-to-end figure (bench_pipeline_blender.py)")
    ap.add_argument("--blender-frames", type=int, default=24)
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: 10,000 curves, 4 frames, scaling 5k..20k")
    a = ap.parse_args(argv)
    if a.quick:
        a.curves, a.frames, a.tris = 10_000, 4, 40_000
        a.sizes, a.repeat = "5000,10000,20000", 1
    return a


def main(argv=None):
    args = parse_args(argv)
    BLAS.set(1)
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    print("FurCollide pipeline benchmark (issue 11)")
    print(f"  {len(cpus) or os.cpu_count()} CPUs, numpy {np.__version__}, OpenBLAS threads "
          f"{BLAS.get() if BLAS.available else 'n/a'}")
    pool = floor.PinnedPool(args.threads)
    if not args.no_frames:
        sc = Scene(args.curves, tris=args.tris, threads=args.threads)
        rec, info, first = run_frames(sc, args, pool)
        print_frames(rec, info, first, args.curves)
        del sc
    if not args.no_scaling:
        scaling(args)
    pool.shutdown()
    if not args.no_blender:
        import subprocess

        print("\n  Blender end-to-end (the demo's pipeline through the operators, bpy wheel):",
              flush=True)
        cmd = [sys.executable, str(HERE / "bench_pipeline_blender.py"), "--curves",
               str(args.curves), "--frames", str(args.blender_frames)]
        try:
            subprocess.run(cmd, check=False, timeout=1800)
        except subprocess.TimeoutExpired:
            print("  (timed out)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
