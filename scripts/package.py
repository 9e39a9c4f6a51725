#!/usr/bin/env python
"""Build the FurCollide extension zips (``make package``).

Steps
-----
1. Download the embreex wheels that ``blender_manifest.toml`` lists into
   ``./wheels/`` with ``pip download --no-deps --only-binary=:all:`` (one
   call per Python version and platform; wheels already present are kept).
   The file pip returns must have exactly the name the manifest lists.
   numpy is never downloaded or bundled: Blender ships its own.
2. Stage the add-on source in a temporary folder together with *only* the
   wheels of the platforms being built (Blender copies unlisted wheels into
   every split zip, so the real ``./wheels/`` folder is never built from).
3. Run Blender's own extension CLI (``blender_ext.py``, shipped inside the
   ``bpy`` wheel): ``validate --valid-tags`` on the staged source, then
   ``build --split-platforms``, then ``validate`` on every zip.
4. Check each zip (only the add-on, only that platform's wheels, no numpy)
   and print the zips with their sizes.

Usage::

    python scripts/package.py                       # every platform -> dist/
    python scripts/package.py --platform linux-x64  # one platform
    python scripts/package.py --platform linux-x64 --python 3.11 --no-download
    python scripts/package.py --check-only          # validate the manifest only

Exit status: 0 on success, 1 on any failure (with a one-line reason on
stderr), 2 on bad arguments.

This module never imports ``bpy``; it only locates the ``bpy`` package to
run the CLI script inside it with the current interpreter.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
import zipfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MANIFEST = "blender_manifest.toml"
WHEELS_DIR = ROOT / "wheels"
DIST_DIR = ROOT / "dist"

#: What the add-on is: the only top-level names of the repository a zip holds
#: (the stage adds ``wheels``). An allow-list, so that nothing else a checkout
#: holds reaches a zip: git-ignored tool output (``make mutate``'s ``mutants/``,
#: 34 MB of mutated copies of ``core``), ``requirements/``, a test's leftovers,
#: an artist's .blend.
ADDON_TOP = ("__init__.py", "blender_manifest.toml", "README.md", "core", "operators", "ui")

#: Top-level names a built zip must never contain.
FORBIDDEN_TOP = (
    "tests",
    "bench",
    "scripts",
    "docs",
    "out",
    "dist",
    "wheels_src",
    ".git",
    ".venv",
    "Makefile",
    "pyproject.toml",
    "requirements-dev.txt",
)

#: wheel platform tag fragment -> Blender platform name.
PLATFORM_OF_TAG = (
    ("manylinux", "x86_64", "linux-x64"),
    ("win_amd64", "", "windows-x64"),
    ("macosx", "arm64", "macos-arm64"),
    ("macosx", "x86_64", "macos-x64"),
)


class PackageError(RuntimeError):
    """A packaging step failed; the message says which and why."""


@dataclass(frozen=True)
class Wheel:
    """One wheel the manifest lists."""

    manifest_path: str  # as written in the manifest, e.g. "./wheels/x.whl"
    filename: str
    dist: str  # "embreex"
    version: str  # "4.4.0.post1"
    python: str  # "3.11"
    platform: str  # Blender platform, e.g. "linux-x64"
    pip_platform: str  # the tag handed to ``pip download --platform``


def log(msg: str) -> None:
    print(f"package: {msg}", flush=True)


# --------------------------------------------------------------------------- manifest


def read_manifest(root: Path = ROOT) -> dict:
    path = root / MANIFEST
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise PackageError(f"{path} not found") from None
    except tomllib.TOMLDecodeError as err:
        raise PackageError(f"{path} is not valid TOML: {err}") from None


def parse_wheel(manifest_path: str) -> Wheel:
    """Parse a manifest wheel entry into :class:`Wheel` (PEP 427 file name)."""
    filename = manifest_path.rsplit("/", 1)[-1]
    m = re.fullmatch(
        r"(?P<dist>[A-Za-z0-9_.]+)-(?P<ver>[^-]+)-(?P<py>cp\d+)-(?P<abi>[^-]+)-(?P<plat>[^-]+)\.whl",
        filename,
    )
    if not m:
        raise PackageError(f"manifest wheel {manifest_path!r} is not a CPython wheel file name")
    py = m["py"][2:]
    python = f"{py[0]}.{py[1:]}"
    tags = m["plat"].split(".")
    platform = None
    for frag, arch, name in PLATFORM_OF_TAG:
        if all(frag in t and arch in t for t in tags):
            platform = name
            break
    if platform is None:
        raise PackageError(f"manifest wheel {filename!r}: unknown platform tag {m['plat']!r}")
    return Wheel(manifest_path, filename, m["dist"], m["ver"], python, platform, tags[-1])


def manifest_wheels(manifest: dict) -> list[Wheel]:
    wheels = [parse_wheel(p) for p in manifest.get("wheels", [])]
    for w in wheels:
        if w.dist.lower().replace("_", "-") == "numpy":
            raise PackageError(
                f"the manifest lists {w.filename}: never bundle numpy, Blender ships its own"
            )
        if not w.manifest_path.startswith("./wheels/"):
            raise PackageError(f"manifest wheel {w.manifest_path!r} must live in ./wheels/")
    return wheels


def select_wheels(wheels, platforms, pythons) -> list[Wheel]:
    return [
        w
        for w in wheels
        if (not platforms or w.platform in platforms) and (not pythons or w.python in pythons)
    ]


# --------------------------------------------------------------------------- download


def wheel_ok(path: Path) -> bool:
    """True if ``path`` is a complete wheel (a readable zip with a RECORD)."""
    try:
        with zipfile.ZipFile(path) as zf:
            return any(n.endswith(".dist-info/RECORD") for n in zf.namelist())
    except (OSError, zipfile.BadZipFile):
        return False


def download_wheels(wheels: list[Wheel], wheels_dir: Path, allow_download: bool = True) -> None:
    """Make every wheel of ``wheels`` present (and complete) in ``wheels_dir``."""
    wheels_dir.mkdir(parents=True, exist_ok=True)
    missing = []
    for w in wheels:
        path = wheels_dir / w.filename
        if path.exists() and wheel_ok(path):
            log(f"have      {w.filename}")
            continue
        if path.exists():
            log(f"corrupt   {w.filename} (re-downloading)")
            path.unlink()
        missing.append(w)
    if not missing:
        return
    if not allow_download:
        names = ", ".join(w.filename for w in missing)
        raise PackageError(
            f"--no-download given but {len(missing)} wheel(s) are missing from "
            f"{wheels_dir}: {names}. Run `python scripts/package.py` once with network access."
        )
    for w in missing:
        log(f"download  {w.filename}")
        with tempfile.TemporaryDirectory(prefix="furcollide_pip_") as tmp:
            cmd = [
                sys.executable,
                "-m",
                "pip",
                "download",
                "--disable-pip-version-check",
                "--no-deps",
                "--only-binary=:all:",
                "--implementation",
                "cp",
                "--python-version",
                w.python,
                "--platform",
                w.pip_platform,
                "--dest",
                tmp,
                f"{w.dist}=={w.version}",
            ]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0:
                tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
                raise PackageError(
                    f"pip download of {w.filename} failed (exit {proc.returncode}): "
                    + " | ".join(tail)
                )
            got = sorted(os.listdir(tmp))
            if any(g.lower().startswith("numpy") for g in got):
                raise PackageError(f"pip downloaded numpy ({got}); refusing to bundle it")
            if got != [w.filename]:
                raise PackageError(
                    f"pip returned {got} for Python {w.python} / {w.pip_platform}, "
                    f"but the manifest lists {w.filename!r}; update blender_manifest.toml"
                )
            if not wheel_ok(Path(tmp) / w.filename):
                raise PackageError(f"downloaded {w.filename} is not a valid wheel")
            # Into place by a rename: test lanes running at once may fetch the same wheel,
            # and none may see a half-copied file.
            part = wheels_dir / f".{w.filename}.{os.getpid()}.part"
            shutil.move(os.path.join(tmp, w.filename), part)
            os.replace(part, wheels_dir / w.filename)


# --------------------------------------------------------------------------- Blender CLI


def bpy_dir() -> Path:
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise PackageError(
            "the bpy wheel is not installed in this Python; "
            "run `make venv` and use .venv/bin/python"
        )
    return Path(list(spec.submodule_search_locations)[0])


def blender_cli() -> tuple[Path, Path]:
    """Paths of ``blender_ext.py`` and Blender's valid-tags file in the bpy wheel."""
    base = bpy_dir()
    clis = sorted(base.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    tags = sorted(base.glob("*/scripts/modules/_bpy_internal/extensions/tags.py"))
    if not clis or not tags:
        raise PackageError(f"Blender's extension CLI was not found under {base}")
    return clis[-1], tags[-1]


def run_cli(*args: str) -> str:
    cli, _ = blender_cli()
    proc = subprocess.run([sys.executable, str(cli), *args], capture_output=True, text=True)
    out = (proc.stdout + proc.stderr).strip()
    if proc.returncode != 0:
        raise PackageError(f"blender_ext {args[0]} failed (exit {proc.returncode}):\n{out}")
    return out


def validate(path: Path) -> str:
    _, tags = blender_cli()
    return run_cli("validate", "--valid-tags", str(tags), str(path))


# --------------------------------------------------------------------------- staging


def _replace_array(text: str, key: str, values: list[str]) -> str:
    """Replace the TOML array ``key = [...]`` (possibly multi-line) at top level."""
    body = "".join(f'\n  "{v}",' for v in values)
    new = f"{key} = [{body}\n]" if values else f"{key} = []"
    # A TOML array ends at the first "]" outside a string; platform names and
    # wheel paths contain no "]", so this match is exact for these two keys.
    pattern = re.compile(rf"^{key}\s*=\s*\[[^\]]*\]", re.M)
    text2, n = pattern.subn(lambda _m: new, text, count=1)
    if n != 1:
        raise PackageError(f"could not find `{key} = [...]` in {MANIFEST}")
    return text2


def stage(
    root: Path, wheels: list[Wheel], platforms: list[str], wheels_dir: Path, dest: Path
) -> Path:
    """Copy the add-on into ``dest/furcollide`` with only ``wheels``; return it."""
    src = dest / "furcollide"
    src.mkdir(parents=True)

    def ignore(_d, names):
        return {n for n in names if n == "__pycache__" or n.endswith((".pyc", ".zip", ".blend1"))}

    for name in ADDON_TOP:
        path = root / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=ignore, symlinks=False)
        elif path.is_file():
            shutil.copy2(path, src / name)
    text = (root / MANIFEST).read_text(encoding="utf-8")
    text = _replace_array(text, "platforms", platforms)
    text = _replace_array(text, "wheels", [w.manifest_path for w in wheels])
    (src / MANIFEST).write_text(text, encoding="utf-8")
    (src / "wheels").mkdir()
    for w in wheels:
        target = src / "wheels" / w.filename
        try:
            os.link(wheels_dir / w.filename, target)
        except OSError:
            shutil.copy2(wheels_dir / w.filename, target)
    return src


# --------------------------------------------------------------------------- zip checks


def zip_platform_suffix(platform: str) -> str:
    return platform.replace("-", "_")


def check_zip(zip_path: Path, platform: str, wheels: list[Wheel]) -> dict:
    """Check one split zip; raise :class:`PackageError` or return a summary."""
    with zipfile.ZipFile(zip_path) as zf:
        names = zf.namelist()
        bad = zf.testzip()
        if bad is not None:
            raise PackageError(f"{zip_path.name}: corrupt member {bad}")
        manifest = tomllib.loads(zf.read(MANIFEST).decode("utf-8"))
    tops = {n.split("/", 1)[0] for n in names}
    extra = sorted(tops - set(ADDON_TOP) - {"wheels"})
    for f in [*FORBIDDEN_TOP, *extra]:
        if f in tops:
            raise PackageError(f"{zip_path.name} contains {f!r}, which is not part of the add-on")
    if "__init__.py" not in names:
        raise PackageError(f"{zip_path.name} has no top-level __init__.py")
    if any("__pycache__/" in n or n.endswith(".pyc") for n in names):
        raise PackageError(f"{zip_path.name} contains compiled Python files")
    whl = sorted(n for n in names if n.endswith(".whl"))
    if any(Path(n).name.lower().startswith("numpy") for n in whl):
        raise PackageError(f"{zip_path.name} bundles numpy; Blender ships its own")
    expected = sorted(w.manifest_path[2:] for w in wheels if w.platform == platform)
    if whl != expected:
        raise PackageError(f"{zip_path.name}: wheels {whl}, expected {expected}")
    generated = manifest.get("build", {}).get("generated", {})
    plats = generated.get("platforms", manifest.get("platforms"))
    if plats != [platform]:
        raise PackageError(f"{zip_path.name}: manifest platforms {plats}, expected [{platform!r}]")
    return {
        "zip": zip_path,
        "platform": platform,
        "wheels": whl,
        "size": zip_path.stat().st_size,
        "files": len(names),
    }


# --------------------------------------------------------------------------- main entry


def build(
    platforms: list[str] | None = None,
    pythons: list[str] | None = None,
    output_dir: Path = DIST_DIR,
    wheels_dir: Path = WHEELS_DIR,
    allow_download: bool = True,
    root: Path = ROOT,
) -> list[dict]:
    """Download, stage, validate, build and check; return one summary per zip."""
    manifest = read_manifest(root)
    all_plats = list(manifest.get("platforms", []))
    if not all_plats:
        raise PackageError(f"{MANIFEST} has no `platforms`; --split-platforms needs it")
    platforms = list(platforms or all_plats)
    unknown = sorted(set(platforms) - set(all_plats))
    if unknown:
        raise PackageError(f"platform(s) {unknown} are not in the manifest's {all_plats}")
    wheels = select_wheels(manifest_wheels(manifest), platforms, pythons)
    for p in platforms:
        if not any(w.platform == p for w in wheels):
            raise PackageError(f"no manifest wheel for platform {p} / Python {pythons or 'any'}")
    download_wheels(wheels, wheels_dir, allow_download)

    output_dir = Path(output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    ident, version = manifest["id"], manifest["version"]
    with tempfile.TemporaryDirectory(prefix="furcollide_stage_") as tmp:
        src = stage(root, wheels, platforms, wheels_dir, Path(tmp))
        log("validate  source manifest")
        validate(src)
        log(f"build     --split-platforms {' '.join(platforms)}")
        t0 = time.perf_counter()
        _, tags = blender_cli()
        run_cli(
            "build",
            "--source-dir",
            str(src),
            "--output-dir",
            str(output_dir),
            "--valid-tags",
            str(tags),
            "--split-platforms",
        )
        dt = time.perf_counter() - t0
    results = []
    for p in platforms:
        zp = output_dir / f"{ident}-{version}-{zip_platform_suffix(p)}.zip"
        if not zp.exists():
            raise PackageError(f"the build did not produce {zp}")
        validate(zp)
        results.append(check_zip(zp, p, wheels))
    log(f"built {len(results)} zip(s) in {dt:.1f} s, validated and checked:")
    for r in results:
        z = Path(r["zip"]).resolve()
        rel = z.relative_to(Path.cwd()) if z.is_relative_to(Path.cwd()) else z
        whl = ", ".join(Path(n).name.split("-")[2] for n in r["wheels"])
        print(f"  {str(rel):48s} {r['size'] / 2**20:7.1f} MiB  ({r['files']} files; wheels: {whl})")
    return results


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--platform",
        action="append",
        dest="platforms",
        metavar="PLATFORM",
        help="build only this Blender platform (repeatable): linux-x64, "
        "windows-x64, macos-arm64, macos-x64. Default: all in the manifest",
    )
    ap.add_argument(
        "--python",
        action="append",
        dest="pythons",
        metavar="X.Y",
        help="bundle only wheels for this Python (repeatable): 3.11 = Blender "
        "4.2-5.0, 3.13 = Blender 5.1+. Default: all in the manifest",
    )
    ap.add_argument(
        "--no-download",
        action="store_true",
        help="never call pip; fail if a needed wheel is not in ./wheels/",
    )
    ap.add_argument(
        "--output-dir", type=Path, default=DIST_DIR, help="where the zips go (default: dist/)"
    )
    ap.add_argument(
        "--wheels-dir", type=Path, default=WHEELS_DIR, help="wheel cache (default: wheels/)"
    )
    ap.add_argument(
        "--check-only",
        action="store_true",
        help="only parse and validate the manifest (no download, no build)",
    )
    args = ap.parse_args(argv)
    try:
        if args.check_only:
            manifest = read_manifest()
            wheels = manifest_wheels(manifest)
            with tempfile.TemporaryDirectory(prefix="furcollide_stage_") as tmp:
                # Validation needs no wheel files: stage without them.
                src = stage(ROOT, [], manifest.get("platforms", []), args.wheels_dir, Path(tmp))
                validate(src)
            log(f"manifest OK: {manifest['id']} {manifest['version']}, {len(wheels)} wheels listed")
            return 0
        build(
            args.platforms,
            args.pythons,
            args.output_dir,
            args.wheels_dir,
            allow_download=not args.no_download,
        )
    except PackageError as err:
        print(f"package: error: {err}", file=sys.stderr, flush=True)
        return 1
    except KeyboardInterrupt:
        print("package: interrupted", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
