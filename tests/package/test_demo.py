"""Smoke test of the README's demo command (``scripts/demo.py``), scaled down.

Runs in a subprocess (the demo sets its own ``BLENDER_USER_RESOURCES`` and
registers the add-on from this checkout as a development extension). A few
hundred curves, 8 frames, no Cycles render except a tiny one: a few seconds.
"""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parent.parent.parent
DEMO = ROOT / "scripts" / "demo.py"


def run_demo(out: Path, *extra: str) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env.pop("BLENDER_USER_RESOURCES", None)
    return subprocess.run(
        [
            sys.executable,
            str(DEMO),
            "--out",
            str(out),
            "--fur",
            "300",
            "--grass",
            "200",
            "--frames",
            "8",
            *extra,
        ],
        capture_output=True,
        text=True,
        timeout=240,
        env=env,
        cwd=str(ROOT),
    )


def stat_rows(stdout: str) -> list[int]:
    return [int(m.group(1)) for m in re.finditer(r"^demo:\s+(\d+)\s+\d+/\d+/\d+/\d+", stdout, re.M)]


@pytest.mark.parametrize("engine", ["auto", "core"])
def test_demo_bakes_and_saves(tmp_path, engine):
    proc = run_demo(tmp_path, "--no-render", "--engine", engine)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert (tmp_path / "demo.blend").is_file()
    assert stat_rows(proc.stdout) == list(range(1, 9)), proc.stdout[-2000:]
    assert "engine: " in proc.stdout
    if engine == "auto":  # the whole fur pipeline ran, and its crossing check passed
        assert re.search(r"^demo: pipeline check, frame 8: .*: ok$", proc.stdout, re.M), (
            proc.stdout[-3000:]
        )
        assert re.search(r"^demo: pipeline\s+8\s+\d+/\d+/\d+/\d+", proc.stdout, re.M)


def test_demo_renders_stills(tmp_path):
    proc = run_demo(tmp_path, "--resolution", "96x54", "--samples", "1", "--engine", "core")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    for name in ("before", "after", "before_closeup", "after_closeup", "compare"):
        png = tmp_path / f"{name}.png"
        assert png.is_file() and png.stat().st_size > 1000, name


def test_demo_bad_arguments_exit_nonzero(tmp_path):
    proc = run_demo(tmp_path, "--resolution", "wide")
    assert proc.returncode == 2
