#!/usr/bin/env python
"""FurCollide demo (``make demo``): build, collide, bake, save and render.

Runs headless with the ``bpy`` wheel (``.venv/bin/python scripts/demo.py``)
and writes everything to ``out/demo/``:

* ``demo.blend``: the demo scene with its FurCollide setups (and, with the
  add-on's operators, the bake cache next to it);
* ``before.png`` / ``after.png``: Cycles (CPU) stills of the same frame
  without and with FurCollide, and ``compare.png``, the two side by side;
* one line of statistics per frame on stdout.

The scene (see ``demo_scene.py``): fur on a body, pushed and pinched by a
sphere and covered by a thin single-sided cloth; grass with a rolling ball.

FurCollide is set up the way an artist or a farm script would: select the
collider meshes, make the hair object active, ``bpy.ops.furcollide.add()``,
then ``bpy.ops.furcollide.bake_all()``. If the add-on's operators cannot be
registered (``--engine core``, or while they are being developed) the demo
drives the collision core directly and writes an output copy of the hair.

Exit status: 0 on success, 1 on any failure (the reason is printed).
"""

from __future__ import annotations

import argparse
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
    # Grass trampling: bend, recover slowly, keep part of the imprint.
    "grass": dict(
        mode="bend",
        rotation_precision=0.5,
        collision_offset=0.004,
        recovery_rate=0.06,
        plasticity=0.5,
    ),
}

STATUS_NAMES = ("free", "colliding", "recovering", "pinched", "unresolved", "disabled")


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
        "--docs-img",
        type=Path,
        default=None,
        help="also write a small JPEG of compare.png here (for the README)",
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


def apply_addon_settings(ob, values: dict) -> list[str]:
    """Set the add-on's per-object settings that exist; return what was set."""
    group = getattr(ob, "furcollide", None)
    done = []
    if group is None:
        return done
    for key, value in values.items():
        if not hasattr(group, key):
            continue
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
            c = "/".join(str(counts.get(k, 0)) for k in (1, 2, 3, 4))
            t = f"{ms:6.1f}" if ms is not None else "     -"
            cells.append(f"{c:>19s} {t}")
        print(f"demo: {frame:5d}  " + "  ".join(f"{c:>26s}" for c in cells), flush=True)

    def summary(self):
        for i, name in enumerate(self.names):
            peak = {
                k: max((r[1][i][0].get(k, 0) for r in self.rows), default=0) for k in (1, 2, 3, 4)
            }
            ms = [r[1][i][1] for r in self.rows if r[1][i][1] is not None]
            tail = f", solve {sum(ms) / len(ms):.1f} ms/frame mean" if ms else ""
            log(
                f"{name}: peak "
                + ", ".join(f"{STATUS_NAMES[k]} {v}" for k, v in peak.items())
                + tail
            )


def counts_of(status):
    import numpy as np

    vals, n = np.unique(np.asarray(status), return_counts=True)
    return {int(v): int(c) for v, c in zip(vals, n, strict=True)}


def collide_with_core(bpy, demo, frame_end):
    """Run the core solver frame by frame; return (outputs, per-frame points)."""
    import demo_scene as ds
    import numpy as np

    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from core import Collider, Settings, Solver

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
        settings = Settings(**SETTINGS[kind])
        solver = Solver(ds.curve_offsets(hair), settings)
        setups.append((hair, out, colliders, cols, growth, solver))

    stats = Stats([hair.name for hair, *_ in setups])
    stats.header()
    frames = {}
    for f in range(scene.frame_start, frame_end + 1):
        scene.frame_set(f)
        row, pts_f = [], []
        for hair, _out, colliders, cols, growth, solver in setups:
            for ob, col in zip(colliders, cols, strict=True):
                col.matrix = np.array(ob.matrix_world)  # rigid motion: no BVH rebuild
            if growth is not None:
                growth.matrix = np.array(hair.data.surface.matrix_world)
            t0 = time.perf_counter()
            res = solver.step(ds.hair_points(hair), cols, growth=growth)
            ms = (time.perf_counter() - t0) * 1e3
            row.append((counts_of(res.status), ms))
            pts_f.append(res.points)
        frames[f] = pts_f
        stats.add(f, row)
    stats.summary()
    outputs = [s[1] for s in setups]
    return outputs, frames


def collide_with_operators(bpy, demo, frame_end, blend_path):
    """Set FurCollide up through its operators, bake, return the outputs."""
    import numpy as np

    scene = demo.scene
    scene.frame_end = frame_end
    outputs = []
    for hair, colliders, kind in demo.setups:
        for ob in scene.objects:
            ob.select_set(False)
        for ob in colliders:
            ob.select_set(True)
        hair.select_set(True)
        bpy.context.view_layer.objects.active = hair
        before = set(bpy.data.objects)
        ret = bpy.ops.furcollide.add()
        if ret != {"FINISHED"}:
            raise RuntimeError(f"bpy.ops.furcollide.add() on {hair.name!r} returned {ret}")
        new = [o for o in bpy.data.objects if o not in before and o.type == "CURVES"]
        if len(new) != 1:
            raise RuntimeError(f"furcollide.add on {hair.name!r} made {len(new)} hair outputs")
        set_ = apply_addon_settings(hair, SETTINGS[kind])
        missed = sorted(set(SETTINGS[kind]) - {x.split("=")[0] for x in set_})
        if missed:
            log(f"warning: the add-on has no setting(s) {missed}; its defaults are used")
        log(
            f"furcollide.add: {hair.name} + {[o.name for o in colliders]} -> {new[0].name}"
            + (f" ({', '.join(set_)})" if set_ else "")
        )
        outputs.append(new[0])

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
    stats.summary()
    return outputs


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
    import numpy as np

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
        # Object-level material: the output's data stays FurCollide's own.
        if not out.material_slots:
            out.data.materials.append(None)
        out.material_slots[0].link = "OBJECT"
        out.material_slots[0].material = mat
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
    grid_keys = [("before", "after"), ("before_closeup", "after_closeup")]
    w, h = size
    gap = 4
    buf = np.ones((2 * h + gap, 2 * w + gap, 4), np.float32)
    for row, keys in enumerate(grid_keys):
        for col, key in enumerate(keys):
            im = bpy.data.images.load(str(paths[key]))
            px = np.empty(w * h * 4, np.float32)
            im.pixels.foreach_get(px)
            y0 = (1 - row) * (h + gap)  # Blender images start at the bottom row
            x0 = col * (w + gap)
            buf[y0 : y0 + h, x0 : x0 + w] = px.reshape(h, w, 4)
            bpy.data.images.remove(im)
    cmp_img = bpy.data.images.new("compare", buf.shape[1], buf.shape[0], alpha=False)
    cmp_img.pixels.foreach_set(buf.ravel())
    cmp_path = out_dir / "compare.png"
    cmp_img.filepath_raw = str(cmp_path)
    cmp_img.file_format = "PNG"
    cmp_img.save()
    paths["compare"] = cmp_path
    return paths, cmp_img


def _rel(p: Path):
    return p.relative_to(ROOT) if p.is_relative_to(ROOT) else p


def save_docs_image(cmp_img, path: Path):
    path.parent.mkdir(parents=True, exist_ok=True)
    cmp_img.filepath_raw = str(path)
    cmp_img.file_format = "JPEG"
    cmp_img.save(quality=88)
    log(f"wrote {path} ({path.stat().st_size // 1024} KiB)")


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

        if engine == "operators":
            outputs = collide_with_operators(bpy, demo, frame_end, blend)

            def set_frame(f):
                demo.scene.frame_set(f)  # the add-on's handler loads the baked frame
        else:
            outputs, frames = collide_with_core(bpy, demo, frame_end)

            def set_frame(f):
                demo.scene.frame_set(f)
                for out, pts in zip(outputs, frames[f], strict=True):
                    ds.set_hair_points_world(out, pts)

        if not args.no_render:
            paths, cmp_img = render_stills(
                bpy, demo, outputs, still, out_dir, args.size, args.samples, set_frame
            )
            if args.docs_img:
                save_docs_image(cmp_img, args.docs_img)
        else:
            paths = {}
            for ob in (h for h, *_ in demo.setups):
                ob.hide_render = True
        set_frame(still)
        bpy.ops.wm.save_as_mainfile(filepath=str(blend))
        paths["blend"] = blend
        log("wrote " + ", ".join(str(_rel(p)) for p in paths.values()))
        log(f"done in {time.perf_counter() - t_all:.1f} s")
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
    sys.exit(main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else None))
