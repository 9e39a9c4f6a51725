"""Shared by every test folder: the hypothesis profiles (``hypothesis_profiles.py``:
``ci`` by default, ``thorough`` with ``--hypothesis-profile=thorough``), and the test
order of ``make mutate``."""

import json
import os

import hypothesis_profiles  # noqa: F401  (registers and loads the profiles)


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
