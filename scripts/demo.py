#!/usr/bin/env python
"""FurCollide demo (``make demo``): build, collide, bake, save and render.

Runs headless with the ``bpy`` wheel (``.venv/bin/python scripts/demo.py``)
and writes everything to ``out/demo/``:

* ``demo.blend``: the demo scene with its FurCollide setups (and, with the
  add-on's operators, the bake cache next to it);
* ``before.png`` / ``after.png``: Cycles (CPU) stills of the same frame
  without and with FurCollide, and ``compare.png``, the two side by side;
* ``pipeline-1-groom.png`` ... ``pipeline-6-render-groom.png`` and
  ``pipeline.png`` (the six as a 3x2 sheet): the fur pipeline, step by step
  (groom, Fur Sampler, Fur Attach, FurCollide + wind, collider distance,
  render groom);
* one line of statistics per frame on stdout (and one per frame for the
  pipeline: guide status counts, min collider distance, clearance count).

The scene (see ``demo_scene.py``): fur on a body, pushed and pinched by a
sphere and covered by a thin single-sided cloth; grass with a rolling ball.

FurCollide is set up the way an artist or a farm script would: select the
collider meshes, make the hair object active, ``bpy.ops.furcollide.add()``,
then ``bpy.ops.furcollide.bake_all()``. If the add-on's operators cannot be
registered (``--engine core``, or while they are being developed) the demo
drives the collision core directly and writes an output copy of the hair.

With the operators, the demo also runs the whole fur pipeline (paper
sections 2 and 4) on the body fur, headless: the dense fur is the render
groom; ``furcollide.fur_sampler`` picks 15 % of it as guides; FurCollide is
set up on the guides (``furcollide.add``); ``furcollide.fur_attach_bind``
makes them follow the turning body; wind after collision with the Region of
Influence and the per-frame collider distance attribute; and
``furcollide.groom_bind`` makes the dense fur follow the collided guides,
with the clearance pass. After the bake, the render groom is checked at the
still frame: no curve (pinched ones aside) may cross the pusher or the
cloth, or go deeper than a strand's thickness into the body (exit 1).

Exit status: 0 on success, 1 on any failure (the reason is printed).
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = Path(__file__).resolve().parent
ADDON = "bl_ext.furcollide_demo.furcollide"
if str(ROOT) not in sys.path:  # the collision core, imported as ``core`` (no Blender needed)
    sys.path.insert(0, str(ROOT))

from core import Status  # noqa: E402  (the per-curve codes: their only definition)

# Settings per setup, in the core's names (Settings fields). The same values
# are applied to the add-on's per-object settings when it has them.
SETTINGS = {
    # Long-ish fur: bend away from the pusher and the cloth, keep a small gap,
    # lay pinched hair onto the skin, recover quickly once free.
    "fur": dict(
        mode="bend",
        rotation_precision=0.5,
        collision_offset=0.008,
        recovery_rate=0.3,
        pinch_resolution="growth_surface",
    ),
    # Grass trampling: bend, recover slowly, keep part of the imprint (more of it along
    # the painted path: MAPS), laid along the ball's roll.
    "grass": dict(
        mode="bend",
        rotation_precision=0.5,
        collision_offset=0.004,
        recovery_rate=0.06,
        plasticity=0.8,
        follow_collider_motion=True,
    ),
}
#: Parameter maps per setup: setting -> the hair's float attribute that scales it per
#: curve (the add-on's ``<setting>_map``; the core path multiplies them in itself).
MAPS = {"grass": {"plasticity": "trampled_path"}}

#: The statistics' columns: col/rec/pin/unres.
COUNTED = (Status.COLLIDING, Status.RECOVERING, Status.PINCHED, Status.UNRESOLVED)


def log(msg: str) -> None:
    print(f"demo: {msg}", flush=True)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description="FurCollide demo: build, bake, save, render.")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "demo", help="output folder")
    ap.add_argument(
        "--frames",
        type=int,
        default=None,
        help="last frame to solve (default: the scene's end, 48)",
    )
    ap.add_argument("--fur", type=int, default=3500, help="fur guide curves (8 CVs each)")
    ap.add_argument("--grass", type=int, default=2500, help="grass blades (8 CVs each)")
    ap.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel")
    ap.add_argument("--resolution", default="480x270", help="render size WxH")
    ap.add_argument("--no-render", action="store_true", help="skip the Cycles stills")
    ap.add_argument(
        "--engine",
        choices=("auto", "operators", "core"),
        default="auto",
        help="operators: the add-on's bpy.ops.furcollide.*; core: the solver "
        "directly; auto: operators if they register, else core",
    )
    ap.add_argument(
        "--no-pipeline",
        action="store_true",
        help="skip the fur pipeline (Fur Sampler, Fur Attach, wind, render groom)",
    )
    ap.add_argument(
        "--docs-img",
        type=Path,
        default=None,
        help="also write a small JPEG of compare.png here, and of the pipeline "
        "pictures (pipeline*.jpg) next to it (for the README)",
    )
    args = ap.parse_args(argv)
    try:
        w, h = (int(v) for v in args.resolution.lower().split("x"))
    except ValueError:
        ap.error(f"--resolution must look like 480x270, got {args.resolution!r}")
    args.size = (w, h)
    return args


# ----------------------------------------------------------------- add-on


def enable_addon(bpy, base_dir):
    """Register the add-on from this checkout as a development extension.

    A temporary repository folder holds a ``furcollide`` symlink to the repo
    root (Blender's "development repository" set-up), so the add-on is
    imported as ``bl_ext.furcollide_demo.furcollide`` exactly as installed.
    Returns the module or None (with the reason printed).
    """
    import addon_utils

    repo_dir = os.path.join(base_dir, "dev_repo")
    os.makedirs(repo_dir, exist_ok=True)
    try:
        os.symlink(ROOT, os.path.join(repo_dir, "furcollide"))
    except OSError as err:  # e.g. Windows without the symlink privilege
        log(f"could not link the checkout into a development repository ({err})")
        return None
    repos = bpy.context.preferences.extensions.repos
    if "furcollide_demo" not in {r.module for r in repos}:
        repos.new(
            name="furcollide_demo",
            module="furcollide_demo",
            custom_directory=repo_dir,
            source="USER",
        )
    try:
        mod = addon_utils.enable(ADDON, default_set=True, handle_error=None)
    except Exception as err:  # the add-on is under development: report, fall back
        log(f"could not enable the add-on ({type(err).__name__}: {err})")
        return None
    if mod is None or ADDON not in bpy.context.preferences.addons:
        log("could not enable the add-on (see the messages above)")
        return None
    return mod


def has_operators(bpy) -> bool:
    names = set(dir(bpy.ops.furcollide))
    return {"add", "bake_all"} <= names


def mapped(hair, settings: dict, maps: dict) -> dict:
    """``settings`` with each mapped one times its map (the hair's per-curve float
    attribute), as the add-on applies a parameter map (clamped to 0..1: the maps here are
    Plasticity's and Recovery Rate's)."""
    import numpy as np

    out = dict(settings)
    for name, attr in maps.items():
        a = hair.data.attributes[attr]
        values = np.empty(len(a.data), np.float32)
        a.data.foreach_get("value", values)
        out[name] = np.clip(settings[name] * values.astype(np.float64), 0.0, 1.0)
    return out


def apply_addon_settings(ob, values: dict) -> list[str]:
    """Set the add-on's per-object settings that exist; return what was set."""
    group = getattr(ob, "furcollide", None)
    done = []
    if group is None:
        return done
    for key, value in values.items():
        if not hasattr(group, key):
            continue
        if group.bl_rna.properties[key].subtype == "ANGLE":  # (Blender angles: radians)
            value = math.radians(value)
        candidates = [value]
        if isinstance(value, str):
            candidates += [value.upper(), value.title()]
        for v in candidates:
            try:
                setattr(group, key, v)
                done.append(f"{key}={v}")
                break
            except (TypeError, ValueError, AttributeError):
                continue
    return done


# ----------------------------------------------------------------- collide


class Stats:
    """Per-frame status counts and solve times, printed as a table."""

    def __init__(self, names):
        self.names = names
        self.rows = []

    def header(self):
        cols = "  ".join(f"{n:>26s}" for n in self.names)
        print(f"demo: {'frame':>5s}  {cols}   [col/rec/pin/unres, ms]", flush=True)

    def add(self, frame, per_setup):
        self.rows.append((frame, per_setup))
        cells = []
        for counts, ms in per_setup:
            c = "/".join(str(counts.get(k, 0)) for k in COUNTED)
            t = f"{ms:6.1f}" if ms is not None else "     -"
            cells.append(f"{c:>19s} {t}")
        print(f"demo: {frame:5d}  " + "  ".join(f"{c:>26s}" for c in cells), flush=True)

    def summary(self):
        for i, name in enumerate(self.names):
            peak = {
                k: max((r[1][i][0].get(k, 0) for r in self.rows), default=0) for k in COUNTED
            }
            ms = [r[1][i][1] for r in self.rows if r[1][i][1] is not None]
            tail = f", solve {sum(ms) / len(ms):.1f} ms/frame mean" if ms else ""
            log(
                f"{name}: peak "
                + ", ".join(f"{k.name.lower()} {v}" for k, v in peak.items())
                + tail
            )


def counts_of(status):
    import numpy as np

    vals, n = np.unique(np.asarray(status), return_counts=True)
    return {int(v): int(c) for v, c in zip(vals, n, strict=True)}


def collide_with_core(bpy, demo, frame_end):
    """Solve frame by frame with the core's frame sequence (``core.pipeline.Shot``: the
    stages playback and bakes run, from plain arrays), without the add-on's operators
    or frame handler; return (outputs, per-frame points)."""
    import demo_scene as ds
    import numpy as np

    from core import Collider, Settings
    from core.pipeline import Shot
    from core.splines import Splines

    scene = demo.scene
    setups = []
    for hair, colliders, kind in demo.setups:
        out = hair.copy()
        out.data = hair.data.copy()
        out.name = out.data.name = f"{hair.name} (FurCollide)"
        scene.collection.objects.link(out)
        cols = []
        for ob in colliders:
            V, F = ds.mesh_world(ob)
            cols.append(
                Collider(V, F, double_sided=False, matrix=np.array(ob.matrix_world), name=ob.name)
            )
        surf = hair.data.surface
        growth = None
        if surf is not None:
            V, F = ds.mesh_world(surf)
            growth = Collider(V, F, matrix=np.array(surf.matrix_world), name=surf.name)
        offsets = ds.curve_offsets(hair)
        # (the hair draws as Catmull-Rom, Blender's default: the drawn curves are kept clear)
        shot = Shot(offsets, Settings(**mapped(hair, SETTINGS[kind], MAPS.get(kind, {}))),
                    splines=Splines.catmull_rom(len(offsets) - 1))
        setups.append((hair, out, colliders, cols, growth, shot))

    stats = Stats([hair.name for hair, *_ in setups])
    stats.header()
    frames = {}
    for f in range(scene.frame_start, frame_end + 1):
        scene.frame_set(f)
        row, pts_f = [], []
        for hair, _out, colliders, cols, growth, shot in setups:
            for ob, col in zip(colliders, cols, strict=True):
                col.matrix = np.array(ob.matrix_world)  # rigid motion: no BVH rebuild
            if growth is not None:
                growth.matrix = np.array(hair.data.surface.matrix_world)
            t0 = time.perf_counter()
            res = shot.frame(f, ds.hair_points(hair), cols, growth=growth)
            ms = (time.perf_counter() - t0) * 1e3
            row.append((counts_of(res.status), ms))
            pts_f.append(res.points)
        frames[f] = pts_f
        stats.add(f, row)
    stats.summary()
    outputs = [s[1] for s in setups]
    return outputs, frames


def collide_with_operators(bpy, demo, frame_end, blend_path, pipeline=False):
    """Set FurCollide up through its operators, bake, return the outputs.

    With ``pipeline``, the fur pipeline (:func:`pipeline_setup`) is set up
    before the bake and returned too (else None).
    """
    import numpy as np

    scene = demo.scene
    scene.frame_end = frame_end
    outputs = []
    for hair, colliders, kind in demo.setups:
        out = add_setup(bpy, scene, hair, colliders, kind)
        outputs.append(out)

    pipe = pipeline_setup(bpy, demo) if pipeline else None

    # The bake cache lives next to the saved .blend.
    bpy.ops.wm.save_as_mainfile(filepath=str(blend_path))
    log("furcollide.bake_all() ...")
    t0 = time.perf_counter()
    ret = bpy.ops.furcollide.bake_all()
    dt = time.perf_counter() - t0
    if ret != {"FINISHED"}:
        raise RuntimeError(f"bpy.ops.furcollide.bake_all() returned {ret}")
    log(f"baked frames {scene.frame_start}-{frame_end} in {dt:.1f} s")

    stats = Stats([h.name for h, *_ in demo.setups])
    stats.header()
    t0 = time.perf_counter()
    for f in range(scene.frame_start, frame_end + 1):
        scene.frame_set(f)
        row = []
        for out in outputs:
            attr = out.data.attributes.get("furcollide_status")
            if attr is None:
                row.append(({}, None))
                continue
            st = np.empty(len(attr.data), np.int32)
            attr.data.foreach_get("value", st)
            row.append((counts_of(st), None))
        stats.add(f, row)
        if pipe is not None:
            pipe.record(f)
    stats.summary()
    if pipe is not None:
        log(
            f"played the bake back in {time.perf_counter() - t0:.1f} s "
            "(the render groom is deformed and cleared on every frame)"
        )
        pipe.print_table()
    return outputs, pipe


def add_setup(bpy, scene, hair, colliders, kind):
    """``bpy.ops.furcollide.add()`` on ``hair`` with ``colliders``; its SETTINGS; the output."""
    select(bpy, scene, colliders, hair)
    before = set(bpy.data.objects)
    ret = bpy.ops.furcollide.add()
    if ret != {"FINISHED"}:
        raise RuntimeError(f"bpy.ops.furcollide.add() on {hair.name!r} returned {ret}")
    new = [o for o in bpy.data.objects if o not in before and o.type == "CURVES"]
    if len(new) != 1:
        raise RuntimeError(f"furcollide.add on {hair.name!r} made {len(new)} hair outputs")
    set_ = apply_addon_settings(hair, SETTINGS[kind])
    set_ += apply_addon_settings(
        hair, {f"{k}_map": v for k, v in MAPS.get(kind, {}).items()})
    missed = sorted(set(SETTINGS[kind]) - {x.split("=")[0] for x in set_})
    if missed:
        log(f"warning: the add-on has no setting(s) {missed}; its defaults are used")
    log(
        f"furcollide.add: {hair.name} + {[o.name for o in colliders]} -> {new[0].name}"
        + (f" ({', '.join(set_)})" if set_ else "")
    )
    return new[0]


def select(bpy, scene, selected, active):
    """Select exactly ``selected`` and ``active``; make ``active`` the active object."""
    for ob in scene.objects:
        ob.select_set(False)
    for ob in selected:
        ob.select_set(True)
    active.select_set(True)
    bpy.context.view_layer.objects.active = active


def run_op(name, **kwargs):
    """``bpy.ops.furcollide.<name>(**kwargs)``; RuntimeError unless it finished."""
    import bpy

    ret = getattr(bpy.ops.furcollide, name)(**kwargs)
    if ret != {"FINISHED"}:
        raise RuntimeError(f"bpy.ops.furcollide.{name}() returned {ret}")


# ----------------------------------------------------------------- pipeline

# The fur pipeline (paper sections 2 and 4) on the body fur, all through the
# add-on's operators: the dense "Fur" is the render groom, FurCollide runs on
# guides sampled from it, and the groom follows the collided guides.
PIPELINE = dict(
    fraction=0.15,  # Fur Sampler: share of the groom's curves kept as guides
    seed=3,
    # Wind after collision (Region of Influence keeps it collision free).
    motion=dict(
        use_wind=True,
        wind_stage="OUTPUT",
        wind_strength=0.04,
        wind_direction=(1.0, 0.4, 0.0),
        wind_turbulence=0.8,
        wind_frequency=0.7,
        wind_scale=0.4,
        use_region_of_influence=True,
        write_collider_distance=True,
        distance_max=0.1,
    ),
)
#: How deep (world units) render curves pressed onto the skin may dip into the
#: body, the growth surface (not a collider): about a strand's thickness.
BODY_DEPTH_TOLERANCE = 0.015
PIPELINE_OPERATORS = {"fur_sampler", "fur_attach_bind", "groom_bind"}


def has_pipeline_operators(bpy) -> bool:
    return PIPELINE_OPERATORS <= set(dir(bpy.ops.furcollide))


class Pipeline:
    """The fur pipeline's objects, its per-frame statistics and its checks."""

    def __init__(self, demo, guides, output, groom_out):
        self.demo = demo
        self.guides = guides  # Fur Sampler result: the FurCollide source
        self.output = output  # collided guides (+ wind), the setup's output
        self.groom_out = groom_out  # the render groom following the guides
        self.rows = []

    @property
    def objects(self):
        return [self.guides, self.output, self.groom_out]

    def record(self, f):
        """Statistics of frame ``f`` (call right after ``scene.frame_set(f)``)."""
        import numpy as np

        data = self.output.data
        counts, st = {}, None
        attr = data.attributes.get("furcollide_status")
        if attr is not None:
            st = np.empty(len(attr.data), np.int32)
            attr.data.foreach_get("value", st)
            counts = counts_of(st)
        dist = None
        attr = data.attributes.get("furcollide_collider_distance")
        if attr is not None and len(attr.data):
            d = np.empty(len(attr.data), np.float32)
            attr.data.foreach_get("value", d)
            if st is not None:  # pinched curves touch the pusher: leave them out
                offs = np.empty(len(data.curves) + 1, np.int32)
                data.curve_offset_data.foreach_get("value", offs)
                d = d[np.repeat(st != Status.PINCHED, np.diff(offs))]
            dist = float(d.min()) if len(d) else None
        s = self.guides.furcollide
        self.rows.append((f, counts, dist, int(s.stat_groom_fixed)))

    def print_table(self):
        g = self.guides
        log(
            f"pipeline: {len(g.data.curves)} guides ({g.name}) -> {self.output.name}; "
            f"render groom {len(self.groom_out.data.curves)} curves -> {self.groom_out.name}"
        )
        log("pipeline  frame  guides col/rec/pin/unres  min collider dist* clearance fixed")
        for f, counts, dist, fixed in self.rows:
            c = "/".join(str(counts.get(k, 0)) for k in COUNTED)
            d = f"{dist:17.4f}" if dist is not None else f"{'-':>17s}"
            log(f"pipeline  {f:5d}  {c:>23s}  {d}  {fixed:15d}")
        log("pipeline  (* of the guides' CVs, pinched guides left out, capped at "
            f"{PIPELINE['motion']['distance_max']})")
        fixed = [r[3] for r in self.rows]
        if fixed:
            peak = max(self.rows, key=lambda r: r[3])
            log(
                f"pipeline: clearance pass fixed {sum(fixed)} render curves over "
                f"{len(fixed)} frames (peak {peak[3]} at frame {peak[0]})"
            )

    def follows_pinched_guide(self):
        """(R,) bool: render curves with a pinched guide among their nearest guides."""
        import demo_scene as ds
        import numpy as np

        g = self.guides
        attr = self.output.data.attributes.get("furcollide_status")
        if attr is None:
            return np.zeros(len(self.groom_out.data.curves), bool)
        st = np.empty(len(attr.data), np.int32)
        attr.data.foreach_get("value", st)
        # Roots at the reference pose: the groom's and the guides' own data.
        r = ds.hair_points(self.demo.fur)[ds.curve_offsets(self.demo.fur)[:-1]]
        q = ds.hair_points(g)[ds.curve_offsets(g)[:-1]]
        k = min(int(g.furcollide.groom.guides), len(q))
        d2 = ((r[:, None, :] - q[None, :, :]) ** 2).sum(-1)
        near = np.argpartition(d2, k - 1, axis=1)[:, :k]
        return (st[near] == Status.PINCHED).any(1)

    def check_crossings(self, frame):
        """Render groom curves that cross the pusher, the cloth or the body at ``frame``.

        Pinched curves are left out: those with the root inside the pusher,
        and those that follow a pinched guide (one of the ``groom.guides``
        guides nearest to its root at the reference pose), which lie on the
        skin with it. The pusher and the cloth are the setup's colliders: no
        render curve may cross them (the clearance pass sees to it). The body
        is the growth surface, not a collider: curves pressed onto the skin
        may dip into it a little; deeper than BODY_DEPTH_TOLERANCE is an
        error. Returns a list of failures (empty when all is well), printed.
        """
        import demo_scene as ds
        import numpy as np

        from core import Collider

        demo = self.demo
        P = ds.hair_points(self.groom_out).astype(np.float64)
        offs = ds.curve_offsets(self.groom_out)
        C = len(offs) - 1

        def collider(ob):
            V, F = ds.mesh_world(ob)
            return Collider(V, F, matrix=np.array(ob.matrix_world), name=ob.name)

        pusher = collider(demo.pusher)
        pinched = pusher.contains(P[offs[:-1]]) | self.follows_pinched_guide()
        # Segments of every curve; the first one starts a hair's breadth off
        # the skin (roots sit exactly on the body).
        seg_curve = np.repeat(np.arange(C), np.diff(offs) - 1)
        last = np.zeros(len(P), bool)
        last[offs[1:] - 1] = True
        o = P[~last]
        d = P[1:][~last[:-1]] - o
        first = np.zeros(len(o), bool)
        first[offs[:-1] - np.arange(C)] = True
        o = o + np.where(first[:, None], 0.02 * d, 0.0)
        d = d * np.where(first[:, None], 0.98, 1.0)

        def crossing(col):
            hit = col.segment_hits(o, d)
            return (np.bincount(seg_curve[hit], minlength=C) > 0) & ~pinched

        failures, parts = [], []
        for ob, col in ((demo.pusher, pusher), (demo.cloth, collider(demo.cloth))):
            n = int(crossing(col).sum())
            parts.append(f"{ob.name} {n}")
            if n:
                failures.append(f"{n} render groom curves cross {ob.name}")
        body = collider(demo.body)
        cross = crossing(body)
        depth = 0.0
        if cross.any():
            pts_curve = np.repeat(np.arange(C), np.diff(offs))
            idx = np.flatnonzero(cross[pts_curve])
            inside = idx[body.contains(P[idx])]
            if len(inside):
                q, _n = body.closest_points(P[inside])
                depth = float(np.linalg.norm(P[inside] - q, axis=1).max())
        deep = depth > BODY_DEPTH_TOLERANCE
        parts.append(
            f"{demo.body.name} {int(cross.sum())} (deepest point {depth * 1000:.1f} mm inside, "
            f"tolerance {BODY_DEPTH_TOLERANCE * 1000:.0f} mm)"
        )
        if deep:
            failures.append(
                f"render groom curves go {depth * 1000:.1f} mm into {demo.body.name}"
            )
        log(
            f"pipeline check, frame {frame}: render groom curves crossing: "
            + ", ".join(parts)
            + f"; of {C} curves, {int(pinched.sum())} pinched ones left out: "
            + ("FAILED" if failures else "ok")
        )
        return failures


def pipeline_setup(bpy, demo):
    """Fur Sampler -> FurCollide on the guides -> Fur Attach -> wind -> render groom."""
    scene = demo.scene
    fur = demo.fur
    colliders = demo.setups[0][1]  # the pusher and the cloth, like the plain setup
    scene.frame_set(scene.frame_start)  # the reference pose
    t0 = time.perf_counter()

    # 1. Fur Sampler: guides from the dense fur (the render groom).
    select(bpy, scene, [], fur)
    before = set(bpy.data.objects)
    run_op("fur_sampler", fraction=PIPELINE["fraction"], seed=PIPELINE["seed"])
    new = [o for o in bpy.data.objects if o not in before]
    if len(new) != 1 or bpy.context.view_layer.objects.active != new[0]:
        raise RuntimeError(f"furcollide.fur_sampler made {[o.name for o in new]}")
    guides = new[0]
    log(
        f"pipeline: fur_sampler(fraction={PIPELINE['fraction']}) on {fur.name}: "
        f"{len(guides.data.curves)} of {len(fur.data.curves)} curves -> {guides.name}"
    )

    # 2. FurCollide on the guides, with the fur's settings.
    output = add_setup(bpy, scene, guides, colliders, "fur")
    s = guides.furcollide
    s.frame_start, s.frame_end = scene.frame_start, scene.frame_end
    # The offset also per collider: the render groom's clearance pass uses the
    # setup's colliders (with their own offsets) but not the setup's Collision
    # Offset, and thick render strands would show through the thin cloth.
    offset = SETTINGS["fur"]["collision_offset"]
    for c in s.colliders:
        c.use_offset, c.collision_offset = True, offset
    log(f"pipeline: collider offsets {offset} on {[c.object.name for c in s.colliders]}")

    # 3. Fur Attach: the guides follow the (turning) body from the first frame.
    s.attach_reference_frame = scene.frame_start
    run_op("fur_attach_bind")
    log(f"pipeline: fur_attach_bind at frame {s.attach_reference_frame} (use_fur_attach="
        f"{s.use_fur_attach})")

    # 4. Wind after collision, Region of Influence, collider distance attribute.
    m = s.motion
    for key, value in PIPELINE["motion"].items():
        setattr(m, key, value)
    log("pipeline: motion " + ", ".join(
        f"{k}={tuple(round(x, 3) for x in v) if isinstance(v, tuple) else v}"
        for k, v in PIPELINE["motion"].items()
    ))

    # 5. Render groom: the fur follows the collided guides, then the clearance pass.
    s.groom.groom = fur
    s.groom.use_clearance = True
    select(bpy, scene, [], guides)
    run_op("groom_bind")
    groom_out = s.groom.output
    if groom_out is None:
        raise RuntimeError("furcollide.groom_bind made no groom output")
    log(
        f"pipeline: groom_bind {fur.name} -> {groom_out.name} "
        f"({s.groom.guides} guides per curve, clearance pass on); "
        f"set up in {time.perf_counter() - t0:.1f} s"
    )
    return Pipeline(demo, guides, output, groom_out)


def set_object_material(ob, mat):
    """Object-level material (the hair data stays the add-on's own)."""
    if not ob.material_slots:
        ob.data.materials.append(None)
    ob.material_slots[0].link = "OBJECT"
    ob.material_slots[0].material = mat


#: (file stem, label, frame key, shown objects, their material keys) of each
#: panel. Frames: "ref" the reference pose (first frame), "still" the still
#: frame, "late" the last frame (the body has turned most).
PIPELINE_PANELS = (
    ("pipeline-1-groom", "1 groom, frame {ref}: {groom} curves", "ref", ("fur",),
     ("fur_before",)),
    ("pipeline-2-guides", "2 Fur Sampler: {guides} guides", "ref", ("guides",),
     ("guides",)),
    ("pipeline-3-attach", "3 Fur Attach, frame {late}: guides turn with body", "late",
     ("attached", "band", "band_ref"), ("guides", "band", "band_ref")),
    ("pipeline-4-collided", "4 FurCollide + wind, frame {still}", "still", ("output",),
     ("status",)),
    ("pipeline-5-distance", "5 Collider Distance (Region of Influence)", "still",
     ("output",), ("distance",)),
    ("pipeline-6-render-groom", "6 render groom follows, cleared", "still", ("groom_out",),
     ("render_groom",)),
)
PIPELINE_COLUMNS = 3


#: Fur Attach panel: a band of guides (this wide, in degrees about the body's
#: vertical axis) is marked, blue at the reference pose and magenta where Fur
#: Attach has carried it; it starts half the body's turn before the camera.
ATTACH_BAND_DEG = 30.0


def attached_guides(bpy, demo, pipe):
    """Plain hair objects with the guides as FurCollide receives them at the
    current frame: moved with the body by Fur Attach (the add-on's own input
    stage), before any collision. The setup's source itself keeps the
    reference pose (Fur Attach runs inside the frame handler).

    Returns {"attached": the other guides, "band": a band of guides facing
    the camera, "band_ref": the same band at the reference pose}.
    """
    import importlib
    import math

    import demo_scene as ds
    import numpy as np

    fur_attach = importlib.import_module(ADDON + ".operators.frame.attach")
    g = pipe.guides
    offs = ds.curve_offsets(g)
    pts = fur_attach.attached_points(g, bpy.context.evaluated_depsgraph_get(), offs)
    ref = ds.hair_points(g)
    rad = None
    src = g.data.attributes.get("radius")
    if src is not None:
        rad = np.empty(len(src.data), np.float32)
        src.data.foreach_get("value", rad)

    # The band: reference roots within ATTACH_BAND_DEG / 2 of the azimuth that
    # the body's turn carries to the camera's azimuth in half the turn.
    c = np.array(ds.BODY_CENTER)
    roots = ref[offs[:-1]] - c
    cam = np.array(demo.furcam.location) - c
    az = np.degrees(np.arctan2(roots[:, 1], roots[:, 0]) - math.atan2(cam[1], cam[0]))
    az = (az + 0.5 * ds.BODY_TURN[2] + 180.0) % 360.0 - 180.0
    band = np.abs(az) <= 0.5 * ATTACH_BAND_DEG
    sizes = np.diff(offs)
    on = np.repeat(band, sizes)

    def plain_hair(name, p, keep):
        hc = bpy.data.hair_curves.new(name)
        hc.add_curves(sizes[keep[offs[:-1]]].tolist())
        hc.position_data.foreach_set("vector", p[keep].astype(np.float32).ravel())
        if rad is not None:
            attr = hc.attributes.get("radius") or hc.attributes.new("radius", "FLOAT", "POINT")
            attr.data.foreach_set("value", rad[keep])
        ob = bpy.data.objects.new(name, hc)  # world positions, identity matrix
        demo.scene.collection.objects.link(ob)
        return ob

    return {
        "attached": plain_hair("Fur Guides (Fur Attach input)", pts, ~on),
        "band": plain_hair("Fur Guides band (Fur Attach input)", pts, on),
        "band_ref": plain_hair("Fur Guides band (reference pose)", ref, on),
    }


def render_pipeline(bpy, demo, pipe, still, out_dir, size, set_frame):
    """The labelled panels of the pipeline (Camera Fur) and a 3x2 sheet pipeline.png."""
    import demo_scene as ds

    scene = demo.scene
    cam = demo.furcam
    frames = {"ref": scene.frame_start, "still": still, "late": scene.frame_end}
    set_frame(frames["late"])
    attached = attached_guides(bpy, demo, pipe)
    shown = {"fur": demo.fur, "guides": pipe.guides, "output": pipe.output,
             "groom_out": pipe.groom_out, **attached}
    mats = dict(demo.materials)
    mats["band"] = ds._material("Guides band (Fur Attach)", (0.95, 0.1, 0.75), 0.45, True)
    mats["band_ref"] = ds._material("Guides band (reference pose)", (0.1, 0.25, 0.9), 0.6, True)
    mats["distance"] = ds.distance_material(
        "Guides by collider distance", PIPELINE["motion"]["distance_max"]
    )
    hairs = list(shown.values()) + [h for h, *_ in demo.setups]
    hairs += [o for o in scene.objects if o.type == "CURVES" and o not in hairs]
    away = [demo.grass, demo.ground, demo.ball]
    colliders = [demo.pusher, demo.cloth]  # not shown with the Fur Attach input
    saved = {o: o.hide_render for o in hairs + away + colliders}
    for o in away:
        o.hide_render = True
    colors = {"ref": (1.0, 0.85, 0.4), "late": (0.8, 0.7, 1.0), "still": (0.55, 0.95, 0.8)}
    # Diagnostic colours: the plain sRGB view, no filmic tone mapping.
    view = scene.view_settings
    saved_view = (view.view_transform, view.look)
    view.view_transform, view.look = "Standard", "None"
    labels = []
    paths = {}
    scene.camera = cam
    try:
        for stem, text, when, keys, mat_keys in PIPELINE_PANELS:
            obs = [shown[k] for k in keys]
            for ob, m in zip(obs, mat_keys, strict=True):
                set_object_material(ob, mats[m])
            text = text.format(
                ref=frames["ref"], still=still, late=frames["late"],
                groom=len(demo.fur.data.curves), guides=len(pipe.guides.data.curves),
            )
            lab = add_label(bpy, cam, text, colors[when])
            labels.append(lab)
            for o in hairs:
                o.hide_render = o not in obs
            for o in colliders:
                o.hide_render = stem == "pipeline-3-attach"
            for o in labels:
                o.hide_render = o is not lab
            frame = frames[when]
            set_frame(frame)
            path = out_dir / f"{stem}.png"
            scene.render.filepath = str(path)
            t0 = time.perf_counter()
            bpy.ops.render.render(write_still=True)
            if not path.exists():
                raise RuntimeError(f"Cycles did not write {path}")
            log(f"rendered {_rel(path)} (frame {frame}) in {time.perf_counter() - t0:.1f} s")
            paths[stem] = path
    finally:
        scene.camera = demo.camera
        view.view_transform, view.look = saved_view
        for o, h in saved.items():
            o.hide_render = h
        for lab in labels:
            lab.hide_render = lab.hide_viewport = True
        set_object_material(pipe.output, mats["status"])  # demo.blend: by status
        for ob in attached.values():
            hc = ob.data
            bpy.data.objects.remove(ob)
            bpy.data.hair_curves.remove(hc)
    sheet = tile_images(bpy, [paths[p[0]] for p in PIPELINE_PANELS], size, "pipeline",
                        columns=PIPELINE_COLUMNS)
    path = out_dir / "pipeline.png"
    sheet.filepath_raw = str(path)
    sheet.file_format = "PNG"
    sheet.save()
    paths["pipeline"] = path
    return paths, sheet


def tile_images(bpy, paths, size, name, columns=2, gap=4):
    """A new Blender image with the PNGs ``paths`` (all ``size``) in a grid, row by row."""
    import numpy as np

    w, h = size
    rows = (len(paths) + columns - 1) // columns
    buf = np.ones((rows * h + (rows - 1) * gap, columns * w + (columns - 1) * gap, 4),
                  np.float32)
    for i, p in enumerate(paths):
        row, col = divmod(i, columns)
        im = bpy.data.images.load(str(p))
        px = np.empty(w * h * 4, np.float32)
        im.pixels.foreach_get(px)
        y0 = (rows - 1 - row) * (h + gap)  # Blender images start at the bottom row
        x0 = col * (w + gap)
        buf[y0 : y0 + h, x0 : x0 + w] = px.reshape(h, w, 4)
        bpy.data.images.remove(im)
    img = bpy.data.images.new(name, buf.shape[1], buf.shape[0], alpha=False)
    img.pixels.foreach_set(buf.ravel())
    return img


# ----------------------------------------------------------------- render


def add_label(bpy, camera, text, color):
    """A small text object in the top-left corner of the camera's view."""
    cu = bpy.data.curves.new(f"Label {text}", "FONT")
    cu.body = text
    cu.size = 0.032
    ob = bpy.data.objects.new(cu.name, cu)
    bpy.context.scene.collection.objects.link(ob)
    ob.parent = camera
    cam = camera.data
    half_w = 0.5 * cam.sensor_width / cam.lens
    half_h = half_w * 9 / 16
    ob.location = (-half_w + 0.025, half_h - 0.055, -1.0)
    mat = bpy.data.materials.new(f"Label {text}")
    if mat.node_tree is None:  # Blender < 5.0; 5.0 deprecates use_nodes
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = (*color, 1)
    bsdf.inputs["Emission Color"].default_value = (*color, 1)
    bsdf.inputs["Emission Strength"].default_value = 1.5
    cu.materials.append(mat)
    return ob


def render_stills(bpy, demo, outputs, frame, out_dir, size, samples, set_frame):
    """Render before/after stills of ``frame`` (wide and close-up) and a 2x2 compare."""
    scene = demo.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = True
    scene.cycles.use_denoising = True
    scene.cycles_curves.shape = "THICK"  # hair rendered as round curves
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.film_transparent = False

    sources = [h for h, *_ in demo.setups]
    after_mats = [demo.materials["fur_after"], demo.materials["grass_after"]]
    for out, mat in zip(outputs, after_mats, strict=True):
        set_object_material(out, mat)
    labels = {}
    for cam in (demo.camera, demo.closeup):
        labels[cam.name, "before"] = add_label(bpy, cam, "without collision", (1.0, 0.55, 0.25))
        labels[cam.name, "after"] = add_label(bpy, cam, "FurCollide", (0.35, 0.8, 1.0))

    paths = {}
    shots = (("", demo.camera), ("_closeup", demo.closeup))
    for suffix, cam in shots:
        scene.camera = cam
        for which in ("before", "after"):
            show_src = which == "before"
            for ob in sources:
                ob.hide_render = not show_src
            for ob in outputs:
                ob.hide_render = show_src
            for key, lab in labels.items():
                lab.hide_render = key != (cam.name, which)
            set_frame(frame)
            path = out_dir / f"{which}{suffix}.png"
            scene.render.filepath = str(path)
            t0 = time.perf_counter()
            bpy.ops.render.render(write_still=True)
            if not path.exists():
                raise RuntimeError(f"Cycles did not write {path}")
            log(
                f"rendered {_rel(path)} (frame {frame}, {size[0]}x{size[1]}, {samples} spp) "
                f"in {time.perf_counter() - t0:.1f} s"
            )
            paths[which + suffix] = path
    scene.camera = demo.camera

    # Leave the saved scene showing the result.
    for ob in sources:
        ob.hide_render = True
    for ob in outputs:
        ob.hide_render = False
    for lab in labels.values():
        lab.hide_render = True
        lab.hide_viewport = True

    # compare.png: before | after, wide shot on top, close-up below.
    keys = ("before", "after", "before_closeup", "after_closeup")
    cmp_img = tile_images(bpy, [paths[k] for k in keys], size, "compare")
    cmp_path = out_dir / "compare.png"
    cmp_img.filepath_raw = str(cmp_path)
    cmp_img.file_format = "PNG"
    cmp_img.save()
    paths["compare"] = cmp_path
    return paths, cmp_img


def _rel(p: Path):
    return p.relative_to(ROOT) if p.is_relative_to(ROOT) else p


def save_docs_image(img, path: Path, quality=88):
    """Save a Blender image as a JPEG for the README."""
    path.parent.mkdir(parents=True, exist_ok=True)
    img.filepath_raw = str(path)
    img.file_format = "JPEG"
    img.save(quality=quality)
    log(f"wrote {_rel(path)} ({path.stat().st_size // 1024} KiB)")


# ----------------------------------------------------------------- main


def main(argv=None) -> int:
    args = parse_args(argv)
    t_all = time.perf_counter()
    out_dir = args.out.resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    # A private Blender user folder: the demo never touches your preferences,
    # and an installed copy of the extension cannot shadow this checkout.
    user = tempfile.mkdtemp(prefix="furcollide_demo_user_")
    os.environ["BLENDER_USER_RESOURCES"] = user
    sys.path.insert(0, str(SCRIPTS))
    try:
        import bpy
        import demo_scene as ds

        log(f"Blender {bpy.app.version_string}, output {out_dir}")
        bpy.context.preferences.filepaths.save_version = 0  # no demo.blend1
        t0 = time.perf_counter()
        demo = ds.build(fur_count=args.fur, grass_count=args.grass)
        log(
            f"scene built in {time.perf_counter() - t0:.2f} s: "
            f"{len(demo.fur.data.curves)} fur curves, {len(demo.grass.data.curves)} grass "
            f"blades, {len(demo.fur.data.points) + len(demo.grass.data.points)} points"
        )
        frame_end = min(args.frames or ds.FRAME_END, ds.FRAME_END)
        still = min(ds.STILL_FRAME, frame_end)
        blend = out_dir / "demo.blend"

        engine = args.engine
        if engine in ("auto", "operators"):
            mod = enable_addon(bpy, user)
            ok = mod is not None and has_operators(bpy)
            if not ok and engine == "operators":
                log("error: bpy.ops.furcollide.add / bake_all are not available")
                return 1
            if not ok:
                log("the add-on's operators are not available: driving the core directly")
            engine = "operators" if ok else "core"
        log(f"engine: {engine}")

        pipeline = not args.no_pipeline
        if pipeline and engine != "operators":
            log("pipeline: skipped (the fur pipeline runs through the add-on's operators)")
            pipeline = False
        elif pipeline and not has_pipeline_operators(bpy):
            missing = sorted(PIPELINE_OPERATORS - set(dir(bpy.ops.furcollide)))
            log(f"pipeline: skipped (the add-on has no bpy.ops.furcollide.{missing})")
            pipeline = False

        pipe = None
        if engine == "operators":
            outputs, pipe = collide_with_operators(bpy, demo, frame_end, blend, pipeline)

            def set_frame(f):
                demo.scene.frame_set(f)  # the add-on's handler loads the baked frame
        else:
            outputs, frames = collide_with_core(bpy, demo, frame_end)

            def set_frame(f):
                demo.scene.frame_set(f)
                for out, pts in zip(outputs, frames[f], strict=True):
                    ds.set_hair_points_world(out, pts)

        failures = []
        if pipe is not None:
            set_frame(still)
            failures += pipe.check_crossings(still)
            for ob in pipe.objects:  # the before/after stills show the plain setups
                ob.hide_render = True

        if not args.no_render:
            paths, cmp_img = render_stills(
                bpy, demo, outputs, still, out_dir, args.size, args.samples, set_frame
            )
            if args.docs_img:
                save_docs_image(cmp_img, args.docs_img)
            if pipe is not None:
                more, sheet = render_pipeline(
                    bpy, demo, pipe, still, out_dir, args.size, set_frame
                )
                paths.update(more)
                if args.docs_img:
                    docs = args.docs_img.parent
                    save_docs_image(sheet, docs / "pipeline.jpg", quality=82)
                    for stem, *_ in PIPELINE_PANELS:
                        img = tile_images(bpy, [more[stem]], args.size, stem, columns=1)
                        save_docs_image(img, docs / f"{stem}.jpg")
        else:
            paths = {}
            for ob in (h for h, *_ in demo.setups):
                ob.hide_render = True
        set_frame(still)
        if pipe is not None:
            # demo.blend shows the plain setups; the pipeline is there, hidden.
            for ob in pipe.objects:
                ob.hide_render = True
                ob.hide_set(True)
            log(
                "demo.blend: the pipeline's objects ("
                + ", ".join(repr(o.name) for o in pipe.objects)
                + ") are hidden; unhide them to play the pipeline"
            )
        bpy.ops.wm.save_as_mainfile(filepath=str(blend))
        paths["blend"] = blend
        log("wrote " + ", ".join(str(_rel(p)) for p in paths.values()))
        log(f"done in {time.perf_counter() - t_all:.1f} s")
        if failures:
            log("error: " + "; ".join(failures))
            return 1
        return 0
    except Exception as err:
        traceback.print_exc()
        log(f"error: {type(err).__name__}: {err}")
        return 1
    finally:
        shutil.rmtree(user, ignore_errors=True)


if __name__ == "__main__":
    # Inside a Blender binary (``blender -b --python scripts/demo.py -- --no-render``)
    # only the arguments after ``--`` are the demo's.
    code = main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else None)
    bpy = sys.modules.get("bpy")
    if bpy is not None and bpy.app.version < (4, 5, 0) and not bpy.app.binary_path:
        # bpy 4.2 (the module) segfaults at exit after enabling an extension (README, Tests)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code or 0)
    sys.exit(code)
