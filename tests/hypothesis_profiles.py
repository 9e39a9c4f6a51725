"""Hypothesis profiles for every property test, registered by ``tests/conftest.py``
(README "Tests and CI", property tests).

* ``ci`` (the default): reproducible (``derandomize``: the same examples on every run and
  machine, so CI never turns red by chance), no example database, the numbers of
  examples each test asks for.
* ``thorough``: ten times the examples, fresh random ones on every run, failures kept in
  ``.hypothesis/`` and replayed first next time. Run it with
  ``.venv/bin/python -m pytest tests/core tests/pipeline --hypothesis-profile=thorough``
  (or ``HYPOTHESIS_PROFILE=thorough``); pin what it finds as an explicit test.
* ``brief``: 40 % of the examples, reproducible, with shrinking: the property tests'
  second run in ``make test`` (the bpy-free suites on the 5.2 lane's Python 3.13 and numpy
  2, ``scripts/test_lanes.py``); the main lane runs the full ``ci`` search.
* ``mutation``: what ``make mutate`` runs for each mutant (``scripts/mutate.py``): 40 % of
  the examples, reproducible, and no shrinking (one failing example kills a mutant).

Health checks are on in all four. Tests scale their own example counts by the profile's
``max_examples`` (100 in ``ci``) through :func:`examples`.
"""

from __future__ import annotations

import os

from hypothesis import Phase, settings

settings.register_profile("ci", max_examples=100, deadline=None, derandomize=True,
                          database=None, print_blob=True)
settings.register_profile("thorough", max_examples=1000, deadline=None, derandomize=False,
                          print_blob=True)
settings.register_profile("brief", max_examples=40, deadline=None, derandomize=True,
                          database=None, print_blob=True)
# make mutate (scripts/mutate.py) runs the tests once per mutant: 40 % of the examples,
# and no shrinking (a failing example is enough to kill a mutant)
settings.register_profile("mutation", max_examples=40, deadline=None, derandomize=True,
                          database=None, phases=(Phase.explicit, Phase.reuse, Phase.generate))
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def examples(n: int) -> int:
    """``n`` examples in the ``ci`` profile, scaled by the loaded profile's size."""
    return max(1, round(n * settings.default.max_examples / 100))
