"""FurCollide core benchmark (``make bench``): paper-scale scenes, timed.

The paper (SIGGRAPH 2017 talk, section 5): 50,000 curves x 8 CVs against a
~130,000-triangle collider at about 4 frames/s on 16 CPUs. This command builds
two such scenes procedurally and deterministically (see ``bench/scene.py``):

* **brief contact**: an ellipsoid orbiting through the fur (contact passes:
  about 1,200 curves start a contact every frame, 8,000 recover in its wake);
* **sustained contact**: a hat resting on the fur and swinging (contact
  lasts: about 10,000 curves colliding every frame, 4.5 % of the roots
  inside the hat's wall).

Each is solved for 48 frames with a rigid collider (``col.matrix``), the same
rigid motion handed over as vertices (``col.vertices = V @ M`` in float32, a
*skinned* accessory: a hat or buckle on an Armature modifier, given its rest shape,
``Collider(rest=V)``, issue 32) and a
deforming one (``col.vertices``), in Bend and in Soft, and printed side by side:
per-frame times, rays per frame, ms per phase, contact counts, an untimed
check that no resolved curve still crosses the collider, and the ratio to
the *floor* measured in the same run (``bench/floor.py``: one embree ray per
segment on the same threads plus the numpy set-up of those rays).

Every rigid run also steps a twin solver whose settings give each per-curve
field (Max Angle, Scale Minimum, Recovery Rate, Plasticity, Collision Offset,
Clearance Margin) as a uniform parameter map, a (C,) array of the plain value:
the same frames, each stepped right before or after the plain one (alternating),
timed apart and compared bit for bit (issue 30: maps cost nothing measurable).

Then the *large-collider* case (``bench/large_collider.py``): chest fur under an
open, deforming shirt about ten times larger than the fur's reach, against the
shirt's reachable part alone and the shirt built whole every frame (issue 32).

It prints the targets of issues 10 and 32 with PASS/MISS; it never asserts them.

    .venv/bin/python bench/bench_core.py            # everything (~3-5 min)
    .venv/bin/python bench/bench_core.py --quick    # small smoke run (~10 s)
    .venv/bin/python bench/bench_core.py --scenes sustained --modes bend --only rigid
    .venv/bin/python bench/bench_core.py --profile  # + cProfile of one run
    .venv/bin/python bench/bench_core.py --threads 8 --scaling  # each phase, 1 vs 8 threads
    make bench ARGS="--threads 8 --scaling"
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import io
import json
import os
import platform
import pstats
import sys
import threading
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
for p in (str(ROOT), str(HERE)):
    if p not in sys.path:
        sys.path.insert(0, p)

import floor  # noqa: E402
import large_collider  # noqa: E402
import scene  # noqa: E402
from cpu import OpenBlas, single_blas, task_cpu  # noqa: E402

BLAS = OpenBlas()

# Issue 10's targets (ratios measured in the same run)
TARGET_SUSTAINED_RATIO = 3.0  # sustained contact, rigid: within 3x its floor
TARGET_BRIEF_RATIO = 2.0  # brief contact, rigid: within 2x its floor
TARGET_DEFORM_VS_RIGID = 1.3  # deforming within 1.3x the rigid time (same scene)
TARGET_SOFT_UNRESOLVED = 0.01  # Soft, sustained: at most 1 % unresolved
TARGET_SOFT_VS_BEND = 2.0  # Soft at most 2x Bend's time per frame
TARGET_FPS = 30.0  # the long-run goal, paper scale on 2 cores
# Issue 32's target (same run): rigid motion as vertices within 1.1x the same motion as a matrix
TARGET_SKINNED_VS_RIGID = 1.1

# Collider kinds: the motion as a matrix, the same rigid motion as vertices, a deformation
KINDS = ("rigid", "skinned", "deforming")

# res.timings entries that are counts, not milliseconds
COUNT_KEYS = {"rays"}

# Status values of the core (IntEnum); overwritten from core.Status when present.
STATUS = {"FREE": 0, "COLLIDING": 1, "RECOVERING": 2, "PINCHED": 3, "UNRESOLVED": 4, "DISABLED": 5}


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--curves", type=int, default=50_000)
    ap.add_argument("--cvs", type=int, default=8, help="CVs per curve (default 8)")
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--tris", type=int, default=130_000, help="collider triangles (approx.)")
    ap.add_argument("--threads", type=int, default=None,
                    help="ray-tracing threads (core + floor; default 2); given, each phase's"
                    " speed-up over one thread is printed too (--scaling)")
    ap.add_argument("--scenes", default="brief,sustained",
                    help="comma-separated: brief, sustained (default both)")
    ap.add_argument("--modes", default="bend,soft",
                    help="comma-separated: stiff, bend, soft (default bend,soft)")
    ap.add_argument("--mode", help="one mode (same as --modes MODE)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument(
        "--quick", action="store_true", help="small smoke scenes: 5,000 curves, 12 frames, 20k tris"
    )
    ap.add_argument("--profile", action="store_true",
                    help="cProfile top 25 of one extra run (the first scene/mode; --only kind)")
    ap.add_argument(
        "--profile-cpu",
        action="store_true",
        help="like --profile but timing the main thread's CPU time (robust on a busy machine;"
        " waits for worker threads then count ~0)",
    )
    ap.add_argument("--only", help="comma-separated collider kinds: rigid, skinned, deforming"
                    " (default all three)")
    ap.add_argument("--full-search", action="store_true",
                    help="Stiff/Bend: the full angle search (Solver.warm_start = False)")
    ap.add_argument("--floor-only", action="store_true", help="scenes + floors, no core")
    ap.add_argument("--no-pin", action="store_true", help="don't pin worker threads to CPUs")
    ap.add_argument(
        "--wait-idle",
        type=float,
        default=0.0,
        metavar="S",
        help="before each run, wait up to S seconds for other processes to leave the CPUs"
        " (< 10%% busy over 2 s)",
    )
    ap.add_argument(
        "--blas-threads",
        type=int,
        metavar="N",
        help="numpy's OpenBLAS thread count for the whole run (default 1: the core uses no"
        " BLAS, and the untimed input generation's BLAS workers would otherwise spin"
        " into the timed frames)",
    )
    ap.add_argument("--scaling", action="store_true",
                    help="also step every frame on one thread (right after, the same"
                    " collider) and print each phase's speed-up (on with --threads N > 1)")
    ap.add_argument("--no-check", action="store_true", help="skip the untimed crossing check")
    ap.add_argument("--no-maps", action="store_true",
                    help="no twin run with uniform parameter maps beside the rigid runs")
    ap.add_argument("--no-large", action="store_true",
                    help="skip the large-collider case (a shirt ten times the fur's reach)")
    ap.add_argument("--verbose", action="store_true", help="print every run in full too")
    ap.add_argument("--json", metavar="PATH", help="also write the figures as JSON")
    a = ap.parse_args(argv)
    if a.mode:
        a.modes = a.mode
    a.scenes = [x for x in a.scenes.split(",") if x]
    a.modes = [x for x in a.modes.split(",") if x]
    for x in a.scenes:
        if x not in ("brief", "sustained"):
            ap.error(f"unknown scene {x!r}")
    for x in a.modes:
        if x not in ("stiff", "bend", "soft"):
            ap.error(f"unknown mode {x!r}")
    if a.threads is not None and a.threads > 1:
        a.scaling = True  # make bench --threads N: how each phase scales
    a.threads = 2 if a.threads is None else a.threads
    a.only = [x for x in (a.only or "rigid,skinned,deforming").split(",") if x]
    for x in a.only:
        if x not in KINDS:
            ap.error(f"unknown collider kind {x!r}")
    if a.quick:
        a.curves, a.frames, a.tris = min(a.curves, 5_000), min(a.frames, 12), min(a.tris, 20_000)
    return a


# ----------------------------------------------------------------------------- helpers


def ms_stats(x):
    x = np.asarray(x, dtype=float)
    return {"median": float(np.median(x)), "worst": float(np.max(x)), "mean": float(np.mean(x))}


def pin_foreign_threads(skip: set[int]) -> int:
    """Pin every live non-main Python thread not in ``skip`` (thread idents)
    round-robin to the allowed CPUs, like the floor's pool. Returns how many.
    A no-op off Linux. Used for the core's worker threads, which the
    benchmark cannot create itself."""
    if not hasattr(os, "sched_setaffinity"):
        return 0
    cpus = sorted(os.sched_getaffinity(0))
    n = 0
    for t in threading.enumerate():
        if t is threading.main_thread() or t.ident in skip or t.native_id is None:
            continue
        try:
            os.sched_setaffinity(t.native_id, {cpus[n % len(cpus)]})
            n += 1
        except OSError:
            pass
    return n


def _cpu_snapshot():
    """(busy CPU seconds of the whole machine, CPU seconds of this process,
    wall time), for the foreign-load estimate; None off Linux."""
    try:
        with open("/proc/stat") as fh:
            v = [int(x) for x in fh.readline().split()[1:]]
    except OSError:
        return None
    hz = os.sysconf("SC_CLK_TCK")
    busy = (sum(v[:8]) - v[3] - v[4]) / hz  # all but idle and iowait
    t = os.times()
    return busy, t.user + t.system, time.perf_counter()


def foreign_load(a, b):
    """Share of the CPUs used by *other* processes between two snapshots."""
    if a is None or b is None:
        return None
    ncpu = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    wall = b[2] - a[2]
    other = (b[0] - a[0]) - (b[1] - a[1])
    return max(0.0, other / (wall * ncpu)) if wall > 0 else None


def wait_idle(limit_s: float) -> float | None:
    """Wait (up to ``limit_s``) until the machine is < 10% busy over 2 s.
    Returns the last busy share seen (None off Linux)."""
    share, t_end = None, time.perf_counter() + limit_s
    while True:
        a = _cpu_snapshot()
        time.sleep(2.0)
        share = foreign_load(a, _cpu_snapshot())
        if share is None or share < 0.10 or time.perf_counter() >= t_end:
            return share


def crossing_curves(scn, points, seg0, curves, inv=None):
    """Curves with at least one segment crossing the collider (untimed check)."""
    org, d, dist = floor.setup_rays(points, seg0, inv)
    prim = floor.trace(scn, org, d, dist, CHECK_POOL)
    return (prim.reshape(curves, -1) >= 0).any(axis=1)


CHECK_POOL = None


def fmt_ms(x):
    return f"{x:8.1f} ms"


def verdict(ok):
    return "PASS" if ok else "MISS"


# ----------------------------------------------------------------------------- runs


def skinned(V, M):
    """What an Armature modifier hands over for a part skinned rigidly to one bone:
    the float32 vertices moved by the float32 matrix (world space, float32)."""
    M32 = np.asarray(M, np.float32)
    return np.ascontiguousarray(V.astype(np.float32) @ M32[:3, :3].T + M32[:3, 3])


def uniform_maps(Settings, settings, C):
    """``settings`` with every per-curve field a (C,) array of its value."""
    names = ("max_angle", "scale_minimum", "recovery_rate", "plasticity", "collision_offset",
             "clearance_margin")
    return settings.replace(**{n: np.full(C, getattr(settings, n), np.float64) for n in names
                               if hasattr(settings, n)})


def run_solver(shot, kind, mode, args, core, pool_idents, profile=False, twin=False):
    """Solve all frames of one run. Returns a dict of figures. ``twin``: also step
    a solver with uniform parameter maps on the same frames (timed apart)."""
    fur, V, F = shot.fur, shot.V, shot.F
    Collider, Settings, Solver = core.Collider, core.Settings, core.Solver
    frames = args.frames
    seg0 = floor.segment_index(fur.offsets)

    if kind == "rigid":
        t0 = time.perf_counter()
        col = Collider(V, F, double_sided=False, matrix=shot.matrix(0, frames))
        setup_ms = 1000 * (time.perf_counter() - t0)
        check_scene = floor.build_scene(V, F)
        floor.trace(check_scene, *floor.setup_rays(fur.rest, seg0, None), CHECK_POOL)  # commit
    else:
        Vw0 = (skinned(V, shot.matrix(0, frames)) if kind == "skinned"
               else shot.vertices(V, 0, frames))
        t0 = time.perf_counter()
        # (skinned: given its rest shape, the hat's own vertices, as an Armature
        # modifier's object has them)
        col = Collider(Vw0, F, double_sided=False, matrix=None,
                       rest=V if kind == "skinned" else None)
        setup_ms = 1000 * (time.perf_counter() - t0)
        check_scene = None
        if kind == "skinned":  # its floor: the same motion as a matrix
            rigid_scene = floor.build_scene(V, F)
            floor.trace(rigid_scene, *floor.setup_rays(fur.rest, seg0, None), CHECK_POOL)

    plain = Settings(mode=mode, threads=args.threads)
    solver = Solver(fur.offsets, plain)
    solver.warm_start = not args.full_search
    maps = None
    if twin:
        maps = Solver(fur.offsets, uniform_maps(Settings, plain, fur.curves))
        maps.warm_start = solver.warm_start
    maps_ms, maps_same = [], True
    # A skinned run steps the same motion as a matrix beside it, interleaved (each
    # frame before or after the skinned step, alternating): its ratio under the same
    # load, which a busy machine makes the only fair one.
    matrix_col = matrix_solver = None
    if kind == "skinned":
        matrix_col = Collider(V, F, double_sided=False, matrix=shot.matrix(0, frames))
        matrix_solver = Solver(fur.offsets, plain)
        matrix_solver.warm_start = solver.warm_start
    matrix_ms = []
    # --scaling: the same frames on one thread, right after each timed step
    single = None
    if args.scaling and args.threads > 1:
        single = Solver(fur.offsets, plain.replace(threads=1))
        single.warm_start = solver.warm_start
    single_ms, single_timings = [], []

    def step_matrix(pts, M):
        t0 = time.perf_counter()
        matrix_col.matrix = M
        matrix_solver.step(pts, [matrix_col], growth=None)
        matrix_ms.append(1000 * (time.perf_counter() - t0))

    def step_maps(pts):
        t0 = time.perf_counter()
        r = maps.step(pts, [col], growth=None)
        maps_ms.append(1000 * (time.perf_counter() - t0))
        return r

    frame_ms, floor_ms, counts, timings, crossing, pinned_threads = [], [], [], [], [], 0
    offenders = []  # (frame, curve, status) of curves still crossing (first 10)
    cpu_ms, main_ms = [], []  # CPU time of the process (all threads) / of the main thread
    by_thread = {}  # CPU ms summed over frames 2..N: main / python workers / native threads
    if profile == "cpu":  # main-thread CPU time: immune to other processes' load
        prof = cProfile.Profile(time.thread_time)
    else:
        prof = cProfile.Profile() if profile else None
    gc.collect()
    snap0 = _cpu_snapshot()
    for f in range(frames):
        # --- inputs of the frame (untimed: a DCC hands them to us) ---
        pts = shot.points(f, frames)
        if kind == "rigid":
            M = shot.matrix(f, frames)
        elif kind == "skinned":
            M = shot.matrix(f, frames)
            Vw = skinned(V, M)
        else:
            Vw = shot.vertices(V, f, frames)
        # --- the twin with uniform maps first on odd frames (after on even ones) ---
        twin_res = None
        if matrix_solver is not None and f % 2 == 1:
            step_matrix(pts, M)
        if maps is not None and f % 2 == 1:
            col.matrix = M
            twin_res = step_maps(pts)
        # --- the timed frame: update the collider + one step ---
        if prof is not None and f > 0:
            prof.enable()
        tc0 = task_cpu()
        c0, m0 = time.process_time(), time.thread_time()
        t0 = time.perf_counter()
        if kind == "rigid":
            col.matrix = M
        else:
            col.vertices = Vw
        res = solver.step(pts, [col], growth=None)
        t1 = time.perf_counter()
        c1, m1 = time.process_time(), time.thread_time()
        tc1 = task_cpu()
        if prof is not None:
            prof.disable()
        if f > 0:
            py = {t.native_id for t in threading.enumerate()}
            main_tid = threading.main_thread().native_id
            for tid, v in tc1.items():
                dv = 1000 * (v - tc0.get(tid, 0.0))
                k = "main" if tid == main_tid else "python" if tid in py else "native"
                by_thread[k] = by_thread.get(k, 0.0) + dv
        frame_ms.append(1000 * (t1 - t0))
        cpu_ms.append(1000 * (c1 - c0))
        main_ms.append(1000 * (m1 - m0))
        if matrix_solver is not None and f % 2 == 0:
            step_matrix(pts, M)
        if single is not None:
            t0 = time.perf_counter()
            r1 = single.step(pts, [col], growth=None)
            single_ms.append(1000 * (time.perf_counter() - t0))
            tm1 = getattr(r1, "timings", None)
            if isinstance(tm1, dict) and f > 0:
                single_timings.append({k: float(v) for k, v in tm1.items()})
        if maps is not None:
            if twin_res is None:
                twin_res = step_maps(pts)
            maps_same &= (twin_res.points.tobytes() == res.points.tobytes()
                          and np.array_equal(twin_res.status, res.status))

        if f < 2 and not args.no_pin:
            pinned_threads = max(pinned_threads, pin_foreign_threads(pool_idents))

        st = np.asarray(res.status)
        c = np.bincount(st.astype(np.int64), minlength=6)
        counts.append(
            {
                "contact": int(c[STATUS["COLLIDING"]] + c[STATUS["RECOVERING"]]),
                "colliding": int(c[STATUS["COLLIDING"]]),
                "recovering": int(c[STATUS["RECOVERING"]]),
                "pinched": int(c[STATUS["PINCHED"]]),
                "unresolved": int(c[STATUS["UNRESOLVED"]]),
            }
        )
        tm = getattr(res, "timings", None)
        if isinstance(tm, dict) and f > 0:
            timings.append({k: float(v) for k, v in tm.items()})

        # --- the floor of this very frame, interleaved (same machine load) ---
        with single_blas():
            t0 = time.perf_counter()
            if kind == "rigid":
                inv = np.linalg.inv(M)
            elif kind == "skinned":  # the floor of the same motion as a matrix
                floor.trace(rigid_scene, *floor.setup_rays(pts, seg0, np.linalg.inv(M)),
                            CHECK_POOL)
            else:
                check_scene = floor.build_scene(Vw, F)
                inv = None
            if kind != "skinned":
                floor.trace(check_scene, *floor.setup_rays(pts, seg0, inv), CHECK_POOL)
            floor_ms.append(1000 * (time.perf_counter() - t0))
        if kind == "skinned" and not args.no_check:  # untimed: the true (given) vertices
            check_scene, inv = floor.build_scene(Vw, F), None

        if not args.no_check:  # untimed: no resolved curve may still cross
            out = np.asarray(res.points, dtype=np.float32)
            cross = crossing_curves(check_scene, out, seg0, fur.curves, inv)
            excused = np.isin(st, [STATUS["PINCHED"], STATUS["UNRESOLVED"], STATUS["DISABLED"]])
            bad = np.flatnonzero(cross & ~excused)
            crossing.append(len(bad))
            offenders.extend((f, int(i), int(st[i])) for i in bad[: max(0, 10 - len(offenders))])

    load = foreign_load(snap0, _cpu_snapshot())
    steady = frame_ms[1:] if len(frame_ms) > 1 else frame_ms
    out = {
        "foreign_cpu_share": load,
        "scene": shot.name,
        "mode": mode,
        "kind": kind,
        "collider_setup_ms": setup_ms,
        "first_frame_ms": frame_ms[0],
        "frame_ms": ms_stats(steady),
        "fps": 1000.0 / float(np.median(steady)),
        "frame_ms_all": frame_ms,
        "cpu_ms": float(np.median(cpu_ms[1:] if len(cpu_ms) > 1 else cpu_ms)),
        "main_thread_cpu_ms": float(np.median(main_ms[1:] if len(main_ms) > 1 else main_ms)),
        "cpu_ms_by_thread": {k: v / max(1, frames - 1) for k, v in by_thread.items()},
        "floor_ms": float(np.median(floor_ms[1:] if len(floor_ms) > 1 else floor_ms)),
        "floor_ms_all": floor_ms,
        "counts": counts,
        "pinned_core_threads": pinned_threads,
        "timings": timings,
        "crossing_after_solve": crossing,
        "crossing_offenders": offenders,
        "builds": int(col.build_count),
    }
    if maps is not None:
        steady_maps = maps_ms[1:] if len(maps_ms) > 1 else maps_ms
        out["maps"] = {"frame_ms": ms_stats(steady_maps), "frame_ms_all": maps_ms,
                       "same_bits": bool(maps_same)}
    if single_ms:
        out["one_thread"] = {"frame_ms": ms_stats(single_ms[1:] if len(single_ms) > 1
                                                  else single_ms),
                             "timings": single_timings}
    if matrix_ms:
        out["as_matrix_ms"] = ms_stats(matrix_ms[1:] if len(matrix_ms) > 1 else matrix_ms)
    if prof is not None:
        out["profile"] = prof
    return out


def print_run(r, fl, curves):
    fm = r["frame_ms"]
    print(f"  collider construction : {fmt_ms(r['collider_setup_ms'])}")
    print(f"  first frame           : {fmt_ms(r['first_frame_ms'])}")
    print(f"  median frame          : {fmt_ms(fm['median'])}   ({r['fps']:.1f} frames/s)")
    print(f"  worst frame           : {fmt_ms(fm['worst'])}   (mean {fm['mean']:.1f} ms)")
    print(
        f"  CPU time per frame    : {fmt_ms(r['cpu_ms'])}   all threads; main thread"
        f" {r['main_thread_cpu_ms']:.1f} ms (medians; not inflated by other processes)"
    )
    bt = r["cpu_ms_by_thread"]
    if bt:
        print(
            f"  CPU by thread (mean)  : main {bt.get('main', 0):.1f} ms, Python workers (the"
            f" core's ray pool) {bt.get('python', 0):.1f} ms, native threads (OpenBLAS/embree)"
            f" {bt.get('native', 0):.1f} ms"
        )
    print(
        f"  floor, per frame      : {fmt_ms(r['floor_ms'])}   (median, measured right after each"
        " solved frame on the same inputs)"
    )
    print(f"  floor, before the run : {fmt_ms(fl['total'])}   " + floor_detail(fl))
    print(f"  ratio median / floor  : {fm['median'] / r['floor_ms']:8.2f}")
    keys = ("contact", "colliding", "recovering", "pinched", "unresolved")
    print(f"  curves per frame      :    median        max   (of {curves})")
    for k in keys:
        v = [c[k] for c in r["counts"]]
        label = "contact (COLL+RECOV)" if k == "contact" else k
        print(
            f"    {label:<20}: {int(np.median(v)):9d} {max(v):10d}"
            f"   ({100 * np.median(v) / curves:.1f}% / {100 * max(v) / curves:.1f}%)"
        )
    if r["crossing_after_solve"]:
        cr = r["crossing_after_solve"]
        print(
            f"  check (untimed)       : curves still crossing the collider, not pinched/"
            f"unresolved: max {max(cr)} per frame, total {sum(cr)}"
        )
        if r["crossing_offenders"]:
            print("    (frame, curve, status):", r["crossing_offenders"])
    if r["foreign_cpu_share"] is not None:
        share = r["foreign_cpu_share"]
        warn = "  << other processes were busy: timings are inflated" if share > 0.1 else ""
        print(f"  other processes' CPU  : {100 * share:5.1f}% of the CPUs during this run{warn}")
    if r["pinned_core_threads"]:
        print(f"  pinned {r['pinned_core_threads']} core worker thread(s) to CPUs")
    if r["timings"]:
        phases = sorted({k for t in r["timings"] for k in t})
        counts = [k for k in phases if k in COUNT_KEYS or k.startswith("n_")]
        print("  per-phase (res.timings, median over frames 2..N):")
        med_total = fm["median"]
        for k in phases:
            v = float(np.median([t.get(k, 0.0) for t in r["timings"]]))
            if k in counts:
                print(f"    {k:<24}{v:10.0f}     (count, not ms)")
            else:
                print(f"    {k:<24}{v:8.2f} ms   ({100 * v / med_total:4.0f}% of the median frame)")


def floor_detail(fl):
    parts = [f"{k} {v:.1f}" for k, v in fl.items() if k not in ("total", "hit_segments")]
    return "(" + ", ".join(parts) + ")"


def print_profile(prof, n=25, title="cProfile of the rigid solve"):
    for key in ("tottime", "cumulative"):
        s = io.StringIO()
        ps = pstats.Stats(prof, stream=s).strip_dirs().sort_stats(key)
        ps.print_stats(n)
        text = s.getvalue()
        start = text.find("   ncalls")
        print(f"\n--- {title} (frames 2..N), top {n} by {key} ---")
        print(text[start:].rstrip() if start >= 0 else text)


# ----------------------------------------------------------------------------- main


def run_label(r):
    return f"{r['scene']} {r['kind']} {r['mode']}"


def median_phase(r, key):
    return float(np.median([t.get(key, 0.0) for t in r["timings"]])) if r["timings"] else 0.0


def print_side_by_side(results, curves):
    """One column per run: the figures an artist or a TD compares."""
    runs = list(results.values())
    if not runs:
        return
    cols = [f"{r['scene'][:9]}/{r['kind'][:5]}/{r['mode']}" for r in runs]
    w = max(17, max(len(c) for c in cols) + 1)

    def row(label, vals):
        print(f"  {label:<26}" + "".join(f"{v:>{w}}" for v in vals))

    print("\nSide by side (medians over frames 2..N; floor = same run, same frames)")
    row("", cols)
    row("ms / frame", [f"{r['frame_ms']['median']:.1f}" for r in runs])
    row("  with uniform maps", [f"{r['maps']['frame_ms']['median']:.1f}" if "maps" in r else "-"
                                for r in runs])
    row("  maps: same bits", [("yes" if r["maps"]["same_bits"] else "NO") if "maps" in r
                              else "-" for r in runs])
    row("frames / s", [f"{r['fps']:.1f}" for r in runs])
    row("floor ms", [f"{r['floor_ms']:.1f}" for r in runs])
    row("ratio to floor", [f"{r['frame_ms']['median'] / r['floor_ms']:.2f}" for r in runs])

    def to_rigid(r):
        rr = results.get((r["scene"], "rigid", r["mode"]))
        return f"{r['frame_ms']['median'] / rr['frame_ms']['median']:.2f}" if rr else "-"

    row("ratio to rigid (same run)", [to_rigid(r) for r in runs])
    row("  to matrix, interleaved", [
        f"{r['frame_ms']['median'] / r['as_matrix_ms']['median']:.2f}" if "as_matrix_ms" in r
        else "-" for r in runs])
    row("CPU ms (all threads)", [f"{r['cpu_ms']:.1f}" for r in runs])
    row("rays / frame", [f"{median_phase(r, 'rays'):,.0f}" for r in runs])
    for k in ("setup", "pinch", "frames", "solve", "output"):
        row(f"  {k} ms", [f"{median_phase(r, k):.1f}" for r in runs])
    for k in ("colliding", "recovering", "pinched", "unresolved"):
        row(f"curves {k}", [f"{int(np.median([c[k] for c in r['counts']])):,}" for r in runs])
    row("BVH builds", [f"{r.get('builds', 0)}" for r in runs])
    row("crossing after solve", [
        f"{max(r['crossing_after_solve'])} max" if r["crossing_after_solve"] else "-"
        for r in runs])


def print_scaling(results, threads):
    """--scaling: each phase on one thread against ``threads`` (same frames, same
    run: the speed-up, 1 thread / N threads)."""
    runs = [r for r in results.values() if "one_thread" in r]
    if not runs:
        return
    print(f"\nScaling (--scaling: medians over frames 2..N; speed-up = 1 thread / {threads}"
          " threads, the same frames stepped right after each other)")
    for r in runs:
        one = r["one_thread"]
        print(f"  {run_label(r)}:")
        print(f"    {'phase':<12}{'1 thread':>12}{f'{threads} threads':>12}{'speed-up':>10}")
        a, b = one["frame_ms"]["median"], r["frame_ms"]["median"]
        print(f"    {'frame':<12}{a:10.1f} ms{b:10.1f} ms{a / b:9.2f}x")
        for k in ("setup", "pinch", "frames", "solve", "output"):
            a = float(np.median([t.get(k, 0.0) for t in one["timings"]])) if one["timings"] \
                else 0.0
            b = median_phase(r, k)
            ratio = f"{a / b:9.2f}x" if b > 0 else "        -"
            print(f"    {k:<12}{a:10.1f} ms{b:10.1f} ms{ratio}")


def print_large_collider(core, args):
    """The large-collider case (``large_collider``): figures and issue 32's target."""
    frames = min(args.frames, 24)
    if args.wait_idle > 0:
        wait_idle(args.wait_idle)
    runs, same = large_collider.run(core, args.curves, args.cvs, args.tris, frames,
                                    args.threads, args.seed)
    part = runs["reachable part alone"]
    print(f"\nLarge collider: chest fur ({args.curves:,} curves x {args.cvs} CVs) under an"
          f" open deforming shirt of {runs['shirt']['triangles']:,} triangles, Bend,"
          f" {frames} frames (median of frames 2..{frames})")
    print(f"  {'run':<24} {'ms / frame':>10} {'triangles':>10} {'shell built':>12}"
          f" {'to the part':>12} {'colliding':>10} {'builds':>7}")
    for name, r in runs.items():
        print(f"  {name:<24} {r['ms']:10.1f} {r['triangles']:10,} {r['shell']:12,}"
              f" {r['ms'] / part['ms']:12.2f} {r['colliding']:10,} {r['builds']:7}")
    print(f"  shirt and shirt built whole give the same bits: {'yes' if same else 'NO'}")
    ratio = runs["shirt"]["ms"] / part["ms"]
    print(f"  target (issue 32): the shirt no slower than its reachable part alone:"
          f" {ratio:.2f}  {verdict(ratio <= 1.0)}")


def print_targets(results):
    """Issue 10's targets (printed, never asserted)."""
    print("\nTargets (issues 10 and 32, 2 cores; PASS/MISS, never asserted):")

    def get(scene_, kind, mode):
        return results.get((scene_, kind, mode))

    def ratio(r):
        return r["frame_ms"]["median"] / r["floor_ms"]

    lines = []
    for mode in ("bend", "stiff", "soft"):
        r = get("sustained", "rigid", mode)
        if r:
            lines.append((f"sustained rigid {mode} <= {TARGET_SUSTAINED_RATIO:.0f}x floor",
                          f"{ratio(r):.2f}", ratio(r) <= TARGET_SUSTAINED_RATIO))
        r = get("brief", "rigid", mode)
        if r:
            lines.append((f"brief rigid {mode} <= {TARGET_BRIEF_RATIO:.0f}x floor",
                          f"{ratio(r):.2f}", ratio(r) <= TARGET_BRIEF_RATIO))
        for sc in ("sustained", "brief"):
            rs = get(sc, "skinned", mode)
            if rs and "as_matrix_ms" in rs:  # interleaved: the fair ratio on a busy machine
                q = rs["frame_ms"]["median"] / rs["as_matrix_ms"]["median"]
                lines.append((f"{sc} skinned {mode} <= {TARGET_SKINNED_VS_RIGID}x as matrix",
                              f"{q:.2f}", q <= TARGET_SKINNED_VS_RIGID))
            rr, rd = get(sc, "rigid", mode), get(sc, "deforming", mode)
            if rr and rd:
                q = rd["frame_ms"]["median"] / rr["frame_ms"]["median"]
                lines.append((f"{sc} deforming {mode} <= {TARGET_DEFORM_VS_RIGID}x rigid",
                              f"{q:.2f}", q <= TARGET_DEFORM_VS_RIGID))
    for kind in ("rigid", "deforming"):
        rs, rb = get("sustained", kind, "soft"), get("sustained", kind, "bend")
        if rs:
            u = max(c["unresolved"] for c in rs["counts"]) / rs["curves"]
            lines.append((f"sustained {kind} soft unresolved <= 1 %", f"{100 * u:.2f} %",
                          u <= TARGET_SOFT_UNRESOLVED))
        if rs and rb:
            q = rs["frame_ms"]["median"] / rb["frame_ms"]["median"]
            lines.append((f"sustained {kind} soft <= {TARGET_SOFT_VS_BEND:.0f}x bend time",
                          f"{q:.2f}", q <= TARGET_SOFT_VS_BEND))
    for r in results.values():
        if r["crossing_after_solve"]:
            total = sum(r["crossing_after_solve"])
            lines.append((f"{run_label(r)}: 0 crossing curves", f"{total}", total == 0))
    best = [r for r in results.values() if r["kind"] == "rigid" and r["mode"] == "bend"]
    for r in best:
        lines.append((f"{r['scene']} rigid bend >= {TARGET_FPS:.0f} frames/s (long run)",
                      f"{r['fps']:.1f}", r["fps"] >= TARGET_FPS))
    for label, val, ok in lines:
        print(f"  {label:<48}: {val:>9}   {verdict(ok)}")
    print("  (paper: ~4 frames/s on 16 CPUs at this scale)")


def main(argv=None):
    global CHECK_POOL
    args = parse_args(argv)
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    try:
        import embreex

        emb_ver = getattr(embreex, "__version__", "?")
    except Exception:  # pragma: no cover
        emb_ver = "?"
    print("FurCollide core benchmark")
    print(
        f"  machine: {platform.machine()} {platform.processor() or ''} "
        f"{len(cpus) or os.cpu_count()} CPUs, Python {platform.python_version()}, "
        f"numpy {np.__version__}, embreex {emb_ver}"
    )

    BLAS.set(1 if args.blas_threads is None else args.blas_threads)
    print(
        f"  OpenBLAS threads: {BLAS.get() if BLAS.available else 'n/a'}"
        + (" (set by --blas-threads)" if args.blas_threads is not None else
           " (default: the core uses no BLAS)")
    )
    makers = {"brief": scene.brief_contact, "sustained": scene.sustained_contact}
    t0 = time.perf_counter()
    shots = [makers[n](args.curves, args.cvs, args.tris, seed=args.seed) for n in args.scenes]
    search = "full search" if args.full_search else "warm-start search"
    for sh in shots:
        print(
            f"  scene {sh.name:<9}: {sh.title}; {sh.fur.curves:,} curves x {sh.fur.cvs} CVs"
            f" ({sh.fur.segments:,} segments), collider {len(sh.F):,} triangles"
        )
    print(f"  {args.frames} frames per run, modes {', '.join(args.modes)} ({search}),"
          f" {args.threads} thread(s), pin {'off' if args.no_pin else 'on'}"
          f" [scenes built in {time.perf_counter() - t0:.1f} s]")

    pool = floor.PinnedPool(args.threads, pin=not args.no_pin)
    CHECK_POOL = pool
    pool_idents = {t.ident for t in pool.pool._threads}

    mid = args.frames // 2
    floors = {}
    with single_blas():
        for sh in shots:
            pts_mid = sh.points(mid, args.frames)
            floors[(sh.name, "rigid")] = floor.measure_rigid(
                pts_mid, sh.fur.offsets, sh.V, sh.F, sh.matrix(mid, args.frames), pool)
            floors[(sh.name, "skinned")] = floors[(sh.name, "rigid")]
            floors[(sh.name, "deforming")] = floor.measure_deforming(
                pts_mid, sh.fur.offsets, sh.vertices(sh.V, mid, args.frames), sh.F, pool)

    core = None
    if not args.floor_only:
        try:
            import core as core_mod
            from core import Collider, Settings, Solver, Status  # noqa: F401  (the public API)

            for k in STATUS:
                STATUS[k] = int(getattr(Status, k))
            core = core_mod
        except Exception as e:  # the core is not importable yet
            print(f"\n  core not usable ({type(e).__name__}: {e}); measuring the floor only")

    results = {}
    kinds = args.only
    if core is not None:
        for sh in shots:
            for mode in args.modes:
                for kind in kinds:
                    if args.wait_idle > 0:
                        share = wait_idle(args.wait_idle)
                        if share is not None:
                            print(f"\n  (waited for a quiet machine: {100 * share:.0f}% busy)")
                    r = run_solver(sh, kind, mode, args, core, pool_idents,
                                   twin=kind == "rigid" and not args.no_maps)
                    r["curves"] = sh.fur.curves
                    results[(sh.name, kind, mode)] = r
                    fm = r["frame_ms"]
                    cr = r["crossing_after_solve"]
                    print(f"  [{run_label(r):<26}] median {fm['median']:7.1f} ms"
                          f"  floor {r['floor_ms']:5.1f} ms  ratio"
                          f" {fm['median'] / r['floor_ms']:5.2f}  rays"
                          f" {median_phase(r, 'rays'):9,.0f}  crossing"
                          f" {sum(cr) if cr else '-'}",
                          flush=True)
                    if "as_matrix_ms" in r:
                        am = r["as_matrix_ms"]["median"]
                        print(f"  [{run_label(r) + ' as matrix':<26}] median {am:7.1f} ms"
                              f"  (the same motion as a matrix, interleaved; skinned / matrix"
                              f" {fm['median'] / am:.2f})", flush=True)
                    if "maps" in r:
                        mp = r["maps"]
                        print(f"  [{run_label(r) + ' maps':<26}] median"
                              f" {mp['frame_ms']['median']:7.1f} ms  (uniform parameter maps,"
                              f" same frames; plain {fm['median']:.1f} ms; same bits:"
                              f" {'yes' if mp['same_bits'] else 'NO'})", flush=True)
                    if args.verbose:
                        how = {"rigid": "moved by col.matrix",
                               "skinned": "moved rigidly via col.vertices"}.get(
                                   kind, "deformed via col.vertices")
                        print(f"\n[{run_label(r)}] collider {how}")
                        print_run(r, floors[(sh.name, kind)], sh.fur.curves)
    else:
        for key, fl in floors.items():
            print(f"\n[{' '.join(key)}] floor : {fmt_ms(fl['total'])}   {floor_detail(fl)}")

    print_side_by_side(results, args.curves)
    print_scaling(results, args.threads)
    if results:
        print_targets(results)
    if core is not None and not args.no_large:
        print_large_collider(core, args)

    if (args.profile or args.profile_cpu) and core is not None:
        how = "cpu" if args.profile_cpu else "wall"
        kind = args.only[0]
        r = run_solver(shots[0], kind, args.modes[0], args, core, pool_idents, profile=how)
        note = (
            "timer: main-thread CPU time (waits on worker threads count ~0)"
            if how == "cpu"
            else "timer: wall clock; worker-thread time shows up as waiting in the main thread"
        )
        print(
            f"\n(profiled {run_label(r)}: median {r['frame_ms']['median']:.1f} ms/frame under"
            f" cProfile; {note})"
        )
        print_profile(r["profile"], title=f"cProfile ({how}) of {run_label(r)}")

    if args.json:
        out = {
            "args": vars(args),
            "floor": {" ".join(k): v for k, v in floors.items()},
            "runs": {
                " ".join(k): {kk: vv for kk, vv in v.items() if kk != "profile"}
                for k, v in results.items()
            },
        }
        Path(args.json).write_text(json.dumps(out, indent=1))
    pool.shutdown()
    return 0 if core is not None or args.floor_only else 2


if __name__ == "__main__":
    sys.exit(main())
