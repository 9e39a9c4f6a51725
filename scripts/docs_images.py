"""``make docs-images``: the documentation's screenshots, made by the real Blender.

Builds (or reuses) the application lane's chroot (``scripts/blender_chroot.sh``: Debian
trixie with Debian's Blender 4.3, Xvfb and ImageMagick; needs root), builds the cp313
Linux zip, then runs one session of Blender with its UI under Xvfb driven by
``tests/app/docs_driver.py``: the README's quick start on the demo scene
(``scripts/demo_scene.py``). The driver crops each screenshot to a region Blender reports;
this script copies the pictures into ``docs/img/`` and lists them.

    python scripts/docs_images.py [--work DIR] [--keep-going] [--max-kb 150]

Exit status 0 when every picture was made and is at most ``--max-kb`` KB, 1 otherwise
(the reason is printed), 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
from scripts import package as pkg  # noqa: E402

CHROOT = ROOT / "scripts" / "blender_chroot.sh"
DRIVER = ROOT / "tests" / "app" / "docs_driver.py"
#: What the driver needs next to it.
BESIDE = (ROOT / "tests" / "app" / "driver_session.py", ROOT / "scripts" / "demo_scene.py")
IMG = ROOT / "docs" / "img"
#: The Blender window and the X screen (tall: the Fur Pipeline panel opened whole).
SCREEN = (1600, 1800)
#: The pictures the driver makes (docs/img/<name>.png).
PICTURES = (
    "sidebar-no-setup", "sidebar-setup", "sidebar-played", "sidebar-baked",
    "panel-main", "panel-colliders", "panel-resolution", "panel-shrink", "panel-recovery",
    "panel-pinch", "panel-enable", "panel-cache", "panel-last-frame", "panel-pipeline",
    "outliner", "viewport-status",
)


def fail(msg: str) -> int:
    print(f"docs-images: {msg}", file=sys.stderr, flush=True)
    return 1


def session(work: Path, timeout: int) -> tuple[int, dict]:
    """Run the driver in one Blender session; (exit code, its result.json)."""
    shutil.rmtree(work, ignore_errors=True)
    (work / "tmp").mkdir(parents=True)
    (res,) = pkg.build(platforms=["linux-x64"], pythons=["3.13"], output_dir=work)
    zip_path = Path(res["zip"])
    for f in (DRIVER, *BESIDE):
        shutil.copy2(f, work / f.name)
    w, h = SCREEN
    inner = (
        "cd /work && blender -b --factory-startup --python-expr "
        "'import bpy; bpy.ops.wm.save_as_mainfile(filepath=\"/work/start.blend\")' >/dev/null"
        " && env TMPDIR=/work/tmp BLENDER_USER_RESOURCES=/work/user"
        f" xvfb-run -a -s '-screen 0 {w}x{h}x24 +extension GLX'"
        f" blender /work/start.blend -p 0 0 {w} {h} --python /work/{DRIVER.name}"
        f" -- /work/{zip_path.name} /work"
    )
    env = dict(os.environ, FURCOLLIDE_CHROOT_BIND=str(work))
    proc = subprocess.run([str(CHROOT), "run", "sh", "-c", inner], capture_output=True,
                          text=True, timeout=timeout, env=env)
    (work / "blender.log").write_text(proc.stdout + "\n--- stderr ---\n" + proc.stderr)
    result_file = work / "result.json"
    result = json.loads(result_file.read_text()) if result_file.is_file() else {}
    return proc.returncode, result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "docs_images",
                    help="working folder (default out/docs_images, git-ignored)")
    ap.add_argument("--max-kb", type=int, default=150, help="largest picture allowed")
    ap.add_argument("--timeout", type=int, default=1200, help="seconds for the session")
    args = ap.parse_args(argv)
    if os.geteuid() != 0:
        return fail("needs root: the Blender chroot uses debootstrap, chroot and mount "
                    "(run as root, e.g. sudo make docs-images)")
    built = subprocess.run([str(CHROOT), "build"], capture_output=True, text=True,
                           timeout=3600)
    if built.returncode != 0:
        return fail(f"the Blender chroot could not be prepared:\n{built.stderr[-3000:]}")
    try:
        rc, result = session(args.work, args.timeout)
    except pkg.PackageError as err:
        return fail(f"packaging the cp313 zip failed: {err}")
    except subprocess.TimeoutExpired:
        return fail(f"the Blender session did not end in {args.timeout} s "
                    f"(log: {args.work / 'blender.log'})")
    if rc != 0 or not result.get("finished") or result.get("errors"):
        errors = "\n".join(result.get("errors", [])) or f"exit code {rc}"
        return fail(f"the Blender session failed ({args.work / 'blender.log'}):\n{errors}")
    made = result.get("images", {})
    missing = [p for p in PICTURES if p not in made]
    if missing:
        return fail(f"not made: {', '.join(missing)}")
    IMG.mkdir(parents=True, exist_ok=True)
    big = []
    for name in PICTURES:
        src = args.work / "img" / f"{name}.png"
        dst = IMG / f"{name}.png"
        shutil.copyfile(src, dst)
        kb = dst.stat().st_size / 1024
        w, h = made[name]["box"][2:]
        print(f"  docs/img/{name}.png  {kb:6.1f} KB  (cropped {w}x{h})  "
              f"{made[name]['caption']}")
        if kb > args.max_kb:
            big.append(f"{name}.png ({kb:.0f} KB)")
    print(f"docs-images: {len(PICTURES)} pictures from Blender {result.get('blender')}")
    if big:
        return fail(f"larger than {args.max_kb} KB: {', '.join(big)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
