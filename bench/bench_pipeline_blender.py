"""Blender end-to-end figure of the fur pipeline (run by ``bench_pipeline.py --blender``).

The demo's pipeline (``scripts/demo.py``: Fur Sampler -> FurCollide on the
guides with Fur Attach -> wind after collision, Region of Influence and the
collider distance attribute -> render groom with its clearance pass), its
render groom scaled to ``--curves`` curves, set up through the add-on's
operators with the ``bpy`` wheel and played frame by frame
(``scene.frame_set``: the add-on's frame handler runs every stage).

The per-stage times are the add-on's own: the *Last Frame* statistics of the
setup (``operators/frame/clock.py``; ``attach_ms`` ... ``write_ms``), what the panel
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

Then the children figure (:func:`children_figure`): a turning head wearing a closed hat,
about 300 guides from Blender's Generate Hair Curves, and Blender's Interpolate, Clump and
Frizz Hair Curves on the output (``--children-density`` children per unit area), played
with the children cleared live and with Clear Children off (the output renders its own
stack, as before the children stage). It counts how often the output's stack runs in a
played frame, and on what: each evaluation of the output is seen where it ends (the
first pass of the frame change by a ``frame_change_post`` handler run before
FurCollide's, ``Depsgraph.update`` by ``depsgraph_update_post``, the second pass by the
next frame's ``frame_change_pre``), with the number of curves it made and the
Interpolate modifier's own ``execution_time``; the depsgraph's evaluation log
(``bpy.app.debug_depsgraph_eval``) counts the output's data updates independently.

Wall-clock milliseconds (the handler is single-threaded glue around the core's
threads), median over the frames after the first.

    .venv/bin/python bench/bench_pipeline_blender.py [--curves 50000] [--frames 24]
        [--children-density 1500] [--children-only]

With ``--vs CHECKOUT [--pairs 3]`` it compares this checkout with another one (e.g.
``git worktree add ../before <commit>``, with its ``.venv``): each side's played frame,
run in turn, each run a process of its own, with the other options given to both; per
stage the medians and their ratio (how issue 32's pipeline target is measured).
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
STAGES = ("attach", "collide", "motion", "groom", "children", "clearance", "write")


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


def played_row(text):
    """The played table's medians {stage: ms} in a run's printed ``text`` (None when it
    has none): this script's output, of this checkout or of an earlier one."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if "frames played (ms per frame" in line and i + 2 < len(lines):
            names, values = lines[i + 1].split(), lines[i + 2].split()
            if len(names) == len(values):
                try:
                    return dict(zip(names, map(float, values), strict=True))
                except ValueError:
                    return None
    return None


def side_by_side(other, pairs, flags):
    """This checkout's played pipeline frame beside ``other``'s (another checkout of the
    repository: a worktree of an earlier commit), run in turn ``pairs`` times, each run a
    process of its own (A B A B ...: a comparison that holds while the machine's speed
    drifts). Prints per stage the median of each side's medians and their ratio, and the
    total's ratio pair by pair."""
    import subprocess

    other = Path(other).resolve()
    script = other / "bench" / "bench_pipeline_blender.py"
    if not script.is_file():
        print(f"  --vs {other}: no bench/bench_pipeline_blender.py there (a checkout of "
              "this repository is needed)")
        return 2
    py = other / ".venv" / "bin" / "python"
    sides = {"this": [sys.executable, str(Path(__file__).resolve())],
             "other": [str(py) if py.exists() else sys.executable, str(script)]}
    rows = {"this": [], "other": []}
    for i in range(pairs):
        for side in ("other", "this"):
            done = subprocess.run(sides[side] + flags, capture_output=True, text=True,
                                  cwd=str(other if side == "other" else ROOT))
            row = played_row(done.stdout)
            if row is None:
                print(f"  run {i + 1} of {side} gave no played table (exit {done.returncode}):"
                      f"\n{done.stderr[-2000:]}")
                return 1
            rows[side].append(row)
            print(f"  pair {i + 1}, {side}: {row['total']:.1f} ms a played frame", flush=True)
    keys = [k for k in rows["this"][0] if all(k in r for r in rows["other"])]
    print(f"\n  side by side, {pairs} pairs: this checkout ({ROOT}) / {other}, ms per played "
          "frame (median of the runs' medians)")
    print(f"  {'stage':>10}{'this':>10}{'other':>10}{'ratio':>8}")
    for k in keys:
        a = float(np.median([r[k] for r in rows["this"]]))
        b = float(np.median([r[k] for r in rows["other"]]))
        ratio = f"{a / b:8.2f}" if b > 0 else f"{'':>8}"
        print(f"  {k:>10}{a:10.1f}{b:10.1f}{ratio}")
    per_pair = [a["total"] / b["total"] for a, b in zip(rows["this"], rows["other"],
                                                         strict=True)]
    print(f"  total, pair by pair: {', '.join(f'{r:.2f}' for r in per_pair)}")
    return 0


def main(argv=None):
    ap = argparse.ArgumentParser(add_help=False)
    ap.add_argument("--vs")
    ap.add_argument("--pairs", type=int, default=3)
    known, rest = ap.parse_known_args(argv if argv is not None else sys.argv[1:])
    if known.vs:
        return side_by_side(known.vs, max(1, known.pairs), rest)
    user = tempfile.mkdtemp(prefix="furcollide_bench_user_")
    try:
        return run(user, rest)
    finally:
        shutil.rmtree(user, ignore_errors=True)  # (the bake files too)


def run(user, argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--curves", type=int, default=50_000, help="render groom curves")
    ap.add_argument("--frames", type=int, default=24, help="frames played (from the start)")
    ap.add_argument("--children-density", type=float, default=1500.0,
                    help="children per unit area of the children figure (0: skip it)")
    ap.add_argument("--children-only", action="store_true",
                    help="only the children figure")
    ap.add_argument("--vs", metavar="CHECKOUT",
                    help="another checkout of the repository (a worktree of an earlier "
                         "commit): its played frame and this one's, in turn, each run a "
                         "process of its own; the other options go to both")
    ap.add_argument("--pairs", type=int, default=3, help="runs of each side with --vs")
    args = ap.parse_args(argv)
    os.environ["BLENDER_USER_RESOURCES"] = user
    sys.path.insert(0, str(SCRIPTS))
    import bpy
    import demo
    import demo_scene as ds

    demo.log = lambda msg: print(f"  {msg}", flush=True)
    if args.children_only:
        mod = demo.enable_addon(bpy, user)
        if mod is None:
            return 1
        children_figure(bpy, mod.__name__, args.children_density)
        return 0
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

    report = sys.modules[pkg + ".operators.store.report"]
    framecache = sys.modules[pkg + ".core.framecache"]
    guides = pipe.guides
    scene = scn.scene
    start = scene.frame_start
    frames = list(range(start, start + args.frames))
    table(f"Blender end-to-end, {args.frames} frames played",
          play(bpy, scene, frames, lambda: report.stats_for(guides)))

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
                                              lambda: report.stats_for(guides)))
    directory = bpy.path.abspath(s.bake_path)
    reads = []
    for f in frames[1:]:
        t0 = time.perf_counter()
        framecache.read_shown(directory, f)  # what a frame shown reads, all but the state
        reads.append(1e3 * (time.perf_counter() - t0))
    print(f"  reading a baked frame's file alone (guides, attributes, inputs record, render "
          f"groom): {np.median(reads):.1f} ms; shown: {med['total']:.1f} ms")
    if args.children_density > 0:
        children_figure(bpy, pkg, args.children_density)
    return 0


# ------------------------------------------------------------------ children
def _hair_modifier(bpy, compat, ob, group, path, at=None, **inputs):
    """Blender's bundled hair node group ``group`` as a modifier of ``ob``, its inputs
    set by name (``Surface`` also on the hair data: Blender 5.2 reads it there)."""
    ng = next((g for g in bpy.data.node_groups if g.get("bench_asset") == group), None)
    if ng is None:
        with bpy.data.libraries.load(path, link=False) as (_src, dst):
            dst.node_groups = [group]
        ng = dst.node_groups[0]
        ng["bench_asset"] = group
    mod = ob.modifiers.new(group, "NODES")
    mod.node_group = ng
    ids = {name: ident for (name, _t), ident in compat.group_inputs(ng).items()
           if _t != "NodeSocketGeometry"}
    for name, value in inputs.items():
        if name == "Surface":
            ob.data.surface = value
        if name in ids:
            compat.set_modifier_input(mod, ids[name], value)
    if at is not None:
        compat.move_modifier(ob, mod, at)
    return mod


def _output_evaluations(bpy, out, play):
    """Play (``play()``) watching every evaluation of ``out``: [(where, curves made,
    Interpolate's execution_time in ms)] and the output's data updates counted in the
    depsgraph's evaluation log."""
    seen = []

    def spy(where):
        def handler(*args):
            dg = args[1] if len(args) > 1 and args[1] is not None else \
                bpy.context.evaluated_depsgraph_get()
            oe = out.evaluated_get(dg)
            mod = oe.modifiers.get("Interpolate Hair Curves")
            ms = 1e3 * float(getattr(mod, "execution_time", 0.0) or 0.0)
            if where == "second pass" and (not seen or seen[-1][2] == ms):
                return  # (before the first frame watched, or not evaluated again)
            seen.append((where, len(oe.data.curves), ms))
        return handler

    first, update, second = spy("first pass"), spy("update"), spy("second pass")
    handlers = bpy.app.handlers
    handlers.frame_change_post.insert(0, first)  # (before FurCollide's handler)
    handlers.depsgraph_update_post.append(update)
    handlers.frame_change_pre.insert(0, second)  # (the last frame's second pass)
    log = tempfile.TemporaryFile(mode="w+")
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(log.fileno(), 1)
    try:
        play()
        second(None)  # (the last frame's second pass)
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)
        handlers.frame_change_post.remove(first)
        handlers.depsgraph_update_post.remove(update)
        handlers.frame_change_pre.remove(second)
    log.seek(0)
    updates = sum(1 for line in log if "BKE_object_handle_data_update on OB" + out.name
                  + " (" in line)
    return seen, updates


def children_figure(bpy, pkg, density, frames=8):
    """The children stack's evaluations per played frame (module docstring)."""
    compat = sys.modules[pkg + ".operators.blender.compat"]
    path = compat.find_datafile(compat.hair_asset_candidates())
    if not path:
        print("\n  no hair node assets in this Blender: no children figure")
        return
    bpy.app.debug_depsgraph_eval = True  # (the new scene's depsgraph logs its evaluations)
    bpy.ops.scene.new(type="EMPTY")
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, frames + 1
    bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=1.0)
    head = bpy.context.object
    bpy.ops.mesh.primitive_cylinder_add(vertices=24, radius=0.55, depth=0.25,
                                        location=(0.0, 0.0, 1.3))
    hat = bpy.context.object
    hat.parent = head
    head.keyframe_insert("rotation_euler", frame=1)
    head.rotation_euler = (0.4, 0.0, 0.8)
    head.keyframe_insert("rotation_euler", frame=frames + 1)
    bpy.context.view_layer.objects.active = head
    bpy.ops.object.curves_empty_hair_add()
    hair = bpy.context.object
    _hair_modifier(bpy, compat, hair, "Generate Hair Curves", path, at=0, Surface=head,
                   Density=25.0, **{"Hair Length": 0.45, "Control Points": 6})
    scene.frame_set(1)
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    hat.select_set(True)
    hair.select_set(True)
    bpy.context.view_layer.objects.active = hair
    bpy.ops.furcollide.add()
    out = hair.furcollide.output
    _hair_modifier(bpy, compat, out, "Interpolate Hair Curves", path, Surface=head,
                   Density=float(density))
    _hair_modifier(bpy, compat, out, "Clump Hair Curves", path, Factor=0.8)
    _hair_modifier(bpy, compat, out, "Frizz Hair Curves", path)
    report = sys.modules[pkg + ".operators.store.report"]
    for cleared in (True, False):
        hair.furcollide.children.use_children = cleared
        scene.frame_set(1)
        scene.frame_set(2)
        walls = []

        def play(walls=walls):
            for f in range(3, frames + 2):
                t0 = time.perf_counter()
                scene.frame_set(f)
                walls.append(1e3 * (time.perf_counter() - t0))

        seen, updates = _output_evaluations(bpy, out, play)
        n = frames - 1
        on = [ms for _w, c, ms in seen if c]
        off = [ms for _w, c, ms in seen if not c]
        stats = report.stats_for(hair)
        what = (f"children cleared live ({stats.get('children', 0):,} children, "
                f"{stats.get('children_fixed', 0)} fixed on the last frame)" if cleared
                else "Clear Children off (the output renders its own stack)")
        print(f"\n  Children stack on the output, {what}, {n} frames played:")
        print(f"    the output's stack ran {len(on) / n:.1f} times per frame on the guides "
              f"(Interpolate {np.median(on) if on else 0:.1f} ms each) and "
              f"{len(off) / n:.1f} times on no guides ({np.median(off) if off else 0:.1f} ms);"
              f" depsgraph data updates of the output: {updates / n:.1f} per frame")
        firsts = [i for i, e in enumerate(seen) if e[0] == "first pass"]
        one = seen[firsts[-2]:firsts[-1]]  # (a frame: from one first pass to the next)
        print("    in a frame: " + ", ".join(f"{w} ({'guides' if c else 'no guides'})"
                                             for w, c, _ms in one))
        med = {k: float(stats.get(f"{k}_ms", 0.0)) for k in STAGES}
        print(f"    frame {np.median(walls):.0f} ms (median); last frame's stages: "
              + ", ".join(f"{k} {v:.0f}" for k, v in med.items() if v))
    bpy.app.debug_depsgraph_eval = False


if __name__ == "__main__":
    sys.exit(main())
