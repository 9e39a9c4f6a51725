"""``bench/bench_pipeline_blender.py --vs``: the side by side reads each run's played
table as the script prints it (this checkout's and an earlier one's alike)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location(
        "bench_pipeline_blender", ROOT / "bench" / "bench_pipeline_blender.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)  # (numpy only at import: bpy is imported by a run)
    return mod


def test_the_played_table_printed_is_read_back(bench, capsys):
    rows = [{k: 10.0 * (i + 1) + j for j, k in enumerate(bench.STAGES)} for i in range(4)]
    for r in rows:
        r["total"] = sum(r[k] for k in bench.STAGES) + 5.0
        r["rest"] = 5.0
    med = bench.table("Blender end-to-end, 4 frames played", rows)
    bench.table("Baked frames played", rows[:2])  # (a second table: not the played one)
    row = bench.played_row("  some set-up line\n" + capsys.readouterr().out)
    assert row == {k: pytest.approx(med[k], abs=0.05) for k in med}


def test_a_run_without_a_played_table_gives_none(bench):
    assert bench.played_row("the add-on is not available: no Blender figure") is None
    assert bench.played_row("frames played (ms per frame)\n a b\n 1.0") is None


def test_vs_a_folder_without_the_bench_says_so(bench, tmp_path, capsys):
    assert bench.main(["--vs", str(tmp_path), "--pairs", "1"]) == 2
    assert "no bench/bench_pipeline_blender.py there" in capsys.readouterr().out
