"""The runnable examples of docs/api.md run and behave as the text says; the paper's
parameters are named where artists and developers look for them (no Blender needed)."""

import pathlib
import re

import numpy as np

DOCS = pathlib.Path(__file__).resolve().parents[2] / "docs"
PAPER_NAMES = ["Stiff", "Bend", "Soft", "Rotation Precision", "Affected Connected CVs",
               "CV Falloff", "Scale Minimum", "Scale Angle", "Recovery Rate", "Plasticity",
               "Stop Solving", "Put to Growth Surface", "Recover Pinched Fur",
               "Attract to Growth Surface"]


def test_core_example_runs_and_resolves_the_collision():
    text = (DOCS / "api.md").read_text(encoding="utf-8")
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    example = next(b for b in blocks if "Solver(offsets" in b)
    scope = {}
    exec(compile(example, "docs/api.md", "exec"), scope)
    res, points = scope["res"], scope["points"]
    # curve 0 passes through the box and is moved; curve 1 is free and untouched
    assert res.status.tolist()[1] == 0
    assert not np.array_equal(res.points[:4], points[:4])
    assert np.array_equal(res.points[4:], points[4:])
    assert np.array_equal(res.points[[0, 4]], points[[0, 4]])  # roots never move


def test_every_paper_parameter_is_documented():
    for page in ("user-guide.md", "api.md"):
        text = (DOCS / page).read_text(encoding="utf-8")
        for name in PAPER_NAMES:
            assert name in text, (page, name)
