"""core.pipeline imports and runs without Blender."""

from __future__ import annotations

import pathlib
import subprocess
import sys
import textwrap

ROOT = pathlib.Path(__file__).resolve().parents[2]

SCRIPT = textwrap.dedent(
    """
    import importlib.abc, sys

    BLOCKED = {"bpy", "mathutils", "bmesh", "bpy_extras", "gpu", "aud", "bgl",
               "operators", "ui", "scipy"}

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"blocked for the test: {name}")
            return None

    sys.meta_path.insert(0, Block())
    import numpy as np
    from core.pipeline import collider_distance, wind

    pts = np.array([[0, 0, 0], [0, 0, .4], [0.05, 0, .8]], float)
    V = np.array([[-1, -1, 1], [1, -1, 1], [1, 1, 1]], float)
    d = collider_distance(pts, [0, 3], [(V, np.array([[0, 1, 2]]))])
    assert np.isfinite(d).all()
    assert np.isfinite(wind(pts, [0, 3], 1.0)).all()
    print("OK")
    """
)


def test_pipeline_imports_without_blender():
    proc = subprocess.run(
        [sys.executable, "-I", "-c", f"import sys; sys.path.insert(0, {str(ROOT)!r})\n" + SCRIPT],
        capture_output=True, text=True, timeout=120, cwd=str(ROOT),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert proc.stdout.strip().endswith("OK")
