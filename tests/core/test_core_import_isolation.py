"""The core must import and solve without Blender (bpy, mathutils, bmesh)."""

from __future__ import annotations

import pathlib
import subprocess
import sys
import textwrap

ROOT = pathlib.Path(__file__).resolve().parents[2]

SCRIPT = textwrap.dedent(
    """
    import importlib.abc, sys

    BLOCKED = {"bpy", "mathutils", "bmesh", "bpy_extras", "gpu", "aud", "bgl"}

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"blocked for the test: {name}")
            return None

    sys.meta_path.insert(0, Block())
    for m in list(sys.modules):
        if m.split(".")[0] in BLOCKED:
            del sys.modules[m]

    import numpy as np
    import core
    from core import Collider, Settings, Solver, Status

    V = np.array([[-1, -1, .5], [1, -1, .5], [1, 1, .5], [-1, 1, .5]], float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    pts = np.array([[0, 0, 0], [0, 0, .4], [0.05, 0, .8], [0.1, 0, 1.2]], float)
    res = Solver(np.array([0, 4]), Settings(mode="stiff")).step(pts, [Collider(V, F)])
    assert res.status[0] == Status.COLLIDING, res.status
    assert np.all(np.isfinite(res.points))
    leaked = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
    assert not leaked, leaked
    print("OK")
    """
)


def test_core_imports_and_solves_without_blender():
    proc = subprocess.run(
        [sys.executable, "-I", "-c", f"import sys; sys.path.insert(0, {str(ROOT)!r})\n" + SCRIPT],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=str(ROOT),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("OK")


def test_core_does_not_import_the_addon_package():
    """core must not pull in the Blender glue (operators / ui)."""
    code = (
        f"import sys; sys.path.insert(0, {str(ROOT)!r})\n"
        "import core\n"
        "bad = [m for m in sys.modules if m.split('.')[0] in ('operators', 'ui')]\n"
        "assert not bad, bad\n"
        "print('OK')\n"
    )
    proc = subprocess.run([sys.executable, "-I", "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=str(ROOT))
    assert proc.returncode == 0, proc.stderr[-3000:]
