"""Shared by every test folder: the hypothesis profiles (``hypothesis_profiles.py``:
``ci`` by default, ``thorough`` with ``--hypothesis-profile=thorough``), the test
order of ``make mutate``, and the reach audit of the core's solver steps."""

import json
import os

import hypothesis_profiles  # noqa: F401  (registers and loads the profiles)
import pytest


@pytest.fixture(autouse=True)
def _solver_segments_stay_within_their_reach(monkeypatch):
    """Every segment a solver step traces against a reachable part is checked to lie
    within the reach the step set (``core.collider.shells.AUDIT``; unchecked in use,
    where the check would cost what the rays do): a step that leaves it fails."""
    try:
        from core.collider import shells
    except ImportError:  # (a lane without the core on its path)
        return
    monkeypatch.setattr(shells, "AUDIT", True)


def pytest_collection_modifyitems(config, items):
    """Under ``make mutate`` (mutmut runs the tests of one mutant with ``-x``), the
    fastest tests first, by the durations mutmut recorded: a mutant is usually killed
    by a quick test, so the slow ones only run for the mutants that survive them."""
    if "__mutmut_" not in os.environ.get("MUTANT_UNDER_TEST", ""):
        return
    try:
        with open("mutmut-stats.json") as fh:  # mutmut runs the tests from mutants/
            took = json.load(fh)["duration_by_test"]
    except (OSError, ValueError, KeyError):
        return
    items.sort(key=lambda item: took.get(item.nodeid, float("inf")))
