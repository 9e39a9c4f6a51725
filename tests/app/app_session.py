"""One session of the real Blender application for the app lane's test modules.

``run_session`` builds (or reuses) the chroot of ``scripts/blender_chroot.sh`` and the
cp313 zip, copies a driver script next to it and runs Debian's Blender 4.3 with its UI
under Xvfb on a saved empty start file; the driver reports into ``result.json``.
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
from scripts import package as pkg  # noqa: E402

CHROOT = ROOT / "scripts" / "blender_chroot.sh"


def run_session(work: Path, driver: str, timeout: int, env_vars: str = "") -> dict:
    """Run ``tests/app/<driver>`` in one Blender session with its output in ``work``.

    Returns {"rc", "log" (stdout, then stderr), "result" (the driver's result.json),
    "zip"}. A missing piece (no root, a chroot or zip that cannot be built, a session
    that does not end) is a test failure naming it.
    """
    if os.geteuid() != 0:
        pytest.fail("the real-Blender lane needs root (debootstrap, chroot, mount)")
    built = subprocess.run([str(CHROOT), "build"], capture_output=True, text=True,
                           timeout=3000)
    if built.returncode != 0:
        pytest.fail(f"the Blender chroot could not be prepared:\n{built.stderr[-3000:]}")
    shutil.rmtree(work, ignore_errors=True)
    (work / "tmp").mkdir(parents=True)
    try:
        (res,) = pkg.build(platforms=["linux-x64"], pythons=["3.13"], output_dir=work)
    except pkg.PackageError as err:
        pytest.fail(f"packaging the cp313 zip failed: {err}")
    zip_path = Path(res["zip"])
    for name in (driver, "driver_session.py"):  # the driver and what it imports
        shutil.copy2(Path(__file__).with_name(name), work / name)
    inner = (
        "cd /work && blender -b --factory-startup --python-expr "
        "'import bpy; bpy.ops.wm.save_as_mainfile(filepath=\"/work/start.blend\")' >/dev/null"
        f" && env TMPDIR=/work/tmp BLENDER_USER_RESOURCES=/work/user {env_vars}"
        " xvfb-run -a -s '-screen 0 1600x900x24 +extension GLX'"
        # (--python-exit-code: a driver that fails before its timers start, e.g. on an
        # import, ends the session at once instead of leaving Blender's UI up)
        f" blender /work/start.blend -p 0 0 1600 900 --python-exit-code 1"
        f" --python /work/{driver}"
        f" -- /work/{zip_path.name} /work"
    )
    env = dict(os.environ, FURCOLLIDE_CHROOT_BIND=str(work))
    try:
        proc = subprocess.run([str(CHROOT), "run", "sh", "-c", inner], capture_output=True,
                              text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"the Blender session did not finish in {timeout // 60} minutes: {exc}")
    log = proc.stdout + "\n--- stderr ---\n" + proc.stderr
    (work / "blender.log").write_text(log)
    result_file = work / "result.json"
    result = json.loads(result_file.read_text()) if result_file.is_file() else {}
    return {"rc": proc.returncode, "log": log, "result": result, "zip": zip_path}


def assert_ran_to_the_end(session, work, tail=4000) -> dict:
    """The session's Blender exited with 0, left no crash report, and its driver
    finished without an error after installing the zip and finding the add-on enabled
    (``driver_session.install``); returns the driver's result."""
    assert session["rc"] == 0, session["log"][-tail:]
    crash = list((work / "tmp").glob("*.crash.txt")) + list(work.glob("*.crash.txt"))
    assert not crash, (crash, crash and crash[0].read_text()[-3000:])
    r = session["result"]
    assert r.get("finished") and not r.get("errors"), r.get("errors") or session["log"][-tail:]
    assert r["install_return"] == ["FINISHED"] and r["enabled"] is True, r["install_return"]
    return r
