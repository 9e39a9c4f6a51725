"""Packaging: build the linux-x64 zip with Blender's own CLI, check it, install it.

The zip is built once per session with ``scripts/package.py`` for linux-x64 and
the Python running the tests (cp311 in the 4.2, 4.5 and 5.0 lanes, cp313 in the 5.2
lane: ``make test-matrix``), so each zip is installed into a Blender that uses it; the
wheel is downloaded once into ``./wheels/`` and reused. The
install runs in a fresh subprocess with ``BLENDER_USER_RESOURCES`` set to a
temporary folder *before* ``bpy`` is imported, so it never touches the
developer's Blender nor the in-process dev-extension tests.
"""

import json
import os
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

from scripts import package as pkg

pytestmark = pytest.mark.blender

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
PY = f"{sys.version_info.major}.{sys.version_info.minor}"  # the lane's Python: 3.11 or 3.13
CP = f"cp{sys.version_info.major}{sys.version_info.minor}"
LINUX_WHEEL = f"embreex-4.4.0.post1-{CP}-{CP}-manylinux_2_27_x86_64.manylinux_2_28_x86_64.whl"


@pytest.fixture(scope="module")
def linux_zip(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    try:
        results = pkg.build(platforms=["linux-x64"], pythons=[PY], output_dir=out)
    except pkg.PackageError as err:
        pytest.fail(f"packaging failed: {err}")
    assert len(results) == 1
    return Path(results[0]["zip"])


def run_check(user: Path, work: Path, *args: str) -> dict:
    """Run ``_install_check.py`` in a fresh interpreter; return its JSON report."""
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(user))
    env.pop("PYTHONPATH", None)  # only the installed copy may be importable
    proc = subprocess.run(
        [sys.executable, str(HERE / "_install_check.py"), *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=str(work),
        timeout=120,
    )
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, (
        f"install subprocess failed (exit {proc.returncode}):\n{proc.stdout[-3000:]}\n"
        f"{proc.stderr[-3000:]}"
    )
    report = json.loads(lines[-1][len("RESULT ") :])
    report["_user"] = str(user)
    report["_log"] = proc.stdout[-4000:] + proc.stderr[-4000:]
    return report


@pytest.fixture(scope="module")
def install_dirs(tmp_path_factory):
    return tmp_path_factory.mktemp("blender_user"), tmp_path_factory.mktemp("work")


@pytest.fixture(scope="module")
def installed(linux_zip, install_dirs):
    """Install the zip into an isolated user folder and drive it (one session)."""
    user, work = install_dirs
    return run_check(user, work, str(linux_zip), str(work))


@pytest.fixture(scope="module")
def next_session(installed, install_dirs):
    """A second, later session on the same isolated user folder."""
    user, work = install_dirs
    return run_check(user, work, "--next-session", str(work))


# ----------------------------------------------------------------- manifest


def test_manifest_lists_all_platforms_and_pythons():
    manifest = pkg.read_manifest()
    wheels = pkg.manifest_wheels(manifest)
    got = {(w.platform, w.python) for w in wheels}
    want = {
        (p, v)
        for p in ("linux-x64", "windows-x64", "macos-arm64", "macos-x64")
        for v in ("3.11", "3.13")
    }
    assert got == want
    assert set(manifest["platforms"]) == {p for p, _ in want}
    assert all(w.dist == "embreex" and w.version == "4.4.0.post1" for w in wheels)


def test_numpy_wheel_is_refused():
    with pytest.raises(pkg.PackageError, match="never bundle numpy"):
        pkg.manifest_wheels({"wheels": ["./wheels/numpy-1.26.4-cp311-cp311-win_amd64.whl"]})


def test_validate_rejects_a_bad_manifest(tmp_path):
    """The CLI validation is real: a tagline ending in '.' fails."""
    src = pkg.stage(ROOT, [], ["linux-x64"], ROOT / "wheels", tmp_path)
    pkg.validate(src)  # the real manifest passes
    m = src / pkg.MANIFEST
    text = m.read_text()
    tagline = tomllib.loads(text)["tagline"]
    m.write_text(text.replace(f'"{tagline}"', '"Hair collision."'))
    with pytest.raises(pkg.PackageError, match="punctuation"):
        pkg.validate(src)


def test_no_download_fails_clearly(tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "scripts" / "package.py"),
            "--no-download",
            "--platform",
            "windows-x64",
            "--wheels-dir",
            str(tmp_path / "none"),
            "--output-dir",
            str(tmp_path / "dist"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 1
    assert "--no-download given" in proc.stderr and "win_amd64" in proc.stderr


# ----------------------------------------------------------------- the zip


def test_zip_contents(linux_zip):
    assert linux_zip.name == "furcollide-0.1.0-linux_x64.zip"
    with zipfile.ZipFile(linux_zip) as zf:
        names = zf.namelist()
        manifest = tomllib.loads(zf.read("blender_manifest.toml").decode())
    tops = {n.split("/", 1)[0] for n in names}
    for forbidden in (
        "tests",
        "bench",
        "scripts",
        "docs",
        "out",
        "dist",
        ".git",
        ".venv",
        "Makefile",
        "pyproject.toml",
        "requirements-dev.txt",
    ):
        assert forbidden not in tops, f"{forbidden} must not be in the zip"
    assert {"__init__.py", "blender_manifest.toml", "core", "operators", "ui"} <= tops
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]
    wheels = [n for n in names if n.endswith(".whl")]
    assert wheels == [f"wheels/{LINUX_WHEEL}"]  # only this Python's wheel
    assert not [n for n in names if "numpy" in n.lower()]
    assert manifest["build"]["generated"]["platforms"] == ["linux-x64"]
    assert manifest["platforms"] == ["linux-x64"]
    assert manifest["id"] == "furcollide"


def test_stage_holds_only_the_addon(tmp_path):
    """A checkout that has run ``make mutate`` (git-ignored ``mutants/``) or holds
    other files stages only the add-on: those never reach a zip."""
    root = tmp_path / "checkout"
    root.mkdir()
    for name in pkg.ADDON_TOP:
        src = ROOT / name
        if src.is_dir():
            (root / name).mkdir()
            (root / name / "__init__.py").write_text("# part of the add-on\n")
            (root / name / "__pycache__").mkdir()
            (root / name / "__pycache__" / "x.cpython-311.pyc").write_bytes(b"")
        else:
            (root / name).write_bytes(src.read_bytes())
    junk = ["mutants/core/rigid.py", "mutants.log", "requirements/bpy-4.2.txt", "shot.blend",
            "tests/test_x.py", "notes.txt"]
    for rel in junk:
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text("not the add-on\n")
    src = pkg.stage(root, [], ["linux-x64"], tmp_path / "wheels", tmp_path / "stage")
    staged = sorted(str(p.relative_to(src)) for p in src.rglob("*"))
    expected = sorted([*pkg.ADDON_TOP, "wheels", "core/__init__.py", "operators/__init__.py",
                       "ui/__init__.py"])
    assert staged == expected


def test_check_zip_refuses_a_name_that_is_not_the_addon(linux_zip, tmp_path):
    bad = tmp_path / linux_zip.name
    with zipfile.ZipFile(linux_zip) as zf, zipfile.ZipFile(bad, "w") as out:
        for item in zf.infolist():
            out.writestr(item, zf.read(item))
        out.writestr("mutants/core/rigid.py", "# a mutated copy\n")
    wheels = pkg.select_wheels(pkg.manifest_wheels(pkg.read_manifest(ROOT)), ["linux-x64"], [PY])
    with pytest.raises(pkg.PackageError, match="'mutants'"):
        pkg.check_zip(bad, "linux-x64", wheels)


def test_zip_validates(linux_zip):
    pkg.validate(linux_zip)


# ----------------------------------------------------------------- installed add-on


def test_install_enables_the_addon(installed):
    assert installed.get("enabled") is True, installed["_log"]
    # The installed copy, not the repository checkout, is what got enabled.
    user = Path(installed["_user"]).resolve()
    assert Path(installed["module_file"]).resolve().is_relative_to(user / "extensions")
    # The bundled wheel (and nothing else) was unpacked into the isolated
    # user folder's .local site-packages.
    site = user / "extensions" / ".local" / "lib" / f"python{PY}" / "site-packages"
    assert (site / "embreex" / "__init__.py").is_file()
    assert not list(site.glob("numpy*"))
    assert "embreex_file" in installed, installed.get("embreex_error")
    assert not installed.get("errors"), "\n".join(installed["errors"])


def test_next_session_uses_the_bundled_wheel(next_session):
    """Preferences were not saved: re-enable; the bundled embreex now wins."""
    assert not next_session.get("errors"), "\n".join(next_session["errors"])
    assert next_session["enabled"] is True
    user = Path(next_session["_user"]).resolve()
    assert Path(next_session["module_file"]).resolve().is_relative_to(user / "extensions")
    # In a fresh session the .local site-packages precedes the venv's.
    assert Path(next_session["embreex_file"]).resolve().is_relative_to(user), next_session[
        "embreex_file"
    ]


def test_installed_core_solves(installed):
    assert installed.get("enabled") is True
    assert "core_file" in installed, installed.get("errors")
    assert installed.get("core_has_solver_api"), (
        f"the installed core does not export {installed.get('core_missing')}")
    step = installed["core_step"]
    assert step["finite"] and step["shape_ok"]
    assert step["moved_curve0"] > 1e-3, "the curve crossing the box must be moved"
    assert step["moved_curve1"] == 0.0, "the free curve must stay exactly in place"
    assert step["status"][1] == 0  # FREE


def test_installed_operators(installed):
    assert installed.get("enabled") is True
    ops = installed.get("operators", [])
    assert "add" in ops, f"furcollide.add is not registered (operators: {ops})"
    assert not installed.get("errors"), "\n".join(installed["errors"])
    assert installed["op_add"] == ["FINISHED"]
    assert installed["op_bake_all"] == ["FINISHED"]
    assert installed["source_untouched"], "the source hair must never be modified"
    assert installed["output_objects"], "furcollide.add must create an output hair object"
    # Same topology as the source; the curve through the box moved, the other did not.
    assert "op_moved_curve0" in installed, "the output's point count differs from the source"
    assert installed["op_moved_curve0"] > 1e-3
    assert installed["op_moved_curve1"] == 0.0


# ----------------------------------------------------------------- failure paths


def test_embreex_missing_gives_a_clear_message(linux_zip, tmp_path):
    """Where embreex cannot load, the add-on enables and says why, no traceback."""
    user, work = tmp_path / "user", tmp_path / "work"
    user.mkdir()
    work.mkdir()
    rep = run_check(user, work, "--no-embree", str(linux_zip), str(work))
    assert rep.get("enabled") is True, rep["_log"]
    assert not rep.get("errors"), "\n".join(rep["errors"])
    assert rep["embree_available"] is False
    assert "embreex" in rep["embree_error"] and "Supported" in rep["embree_error"]
    # The set-up operator refuses with that message (its poll), nothing obscure.
    assert "op_add" not in rep
    assert "embreex" in rep["op_add_error"], rep["op_add_error"]


def test_wrong_platform_zip_is_refused_though_operator_says_finished(tmp_path):
    """package_install_files returns FINISHED even when it refuses the package."""
    stage_dir, dist = tmp_path / "stage", tmp_path / "dist"
    stage_dir.mkdir()
    dist.mkdir()
    src = pkg.stage(ROOT, [], ["windows-x64"], ROOT / "wheels", stage_dir)
    pkg.run_cli("build", "--source-dir", str(src), "--output-dir", str(dist))
    (zip_path,) = dist.glob("*.zip")
    user, work = tmp_path / "user", tmp_path / "work"
    user.mkdir()
    work.mkdir()
    rep = run_check(user, work, str(zip_path), str(work))
    assert rep["install_return"] == ["FINISHED"]  # the pitfall
    assert rep["enabled"] is False
    assert "windows-x64" in rep["_log"]


def test_blender_version_min_is_the_lowest_tested_version():
    """``blender_version_min`` is true: the oldest bpy any test lane pins (make test)."""
    pins = []
    for req in [ROOT / "requirements-dev.txt", *sorted((ROOT / "requirements").glob("bpy-*.txt"))]:
        for line in req.read_text().splitlines():
            if line.startswith("bpy=="):
                pins.append(tuple(int(x) for x in line[5:].split(".")[:2]))
    assert len(pins) == 4, pins  # 4.2, 4.5, 5.0, 5.2
    low = ".".join(map(str, min(pins)))
    assert pkg.read_manifest()["blender_version_min"] == f"{low}.0"
