"""Hypothesis profiles for every property test, registered by ``tests/conftest.py``
(README "Tests and CI", property tests).

* ``ci`` (the default): reproducible (``derandomize``: the same examples on every run and
  machine, so CI never turns red by chance), no example database, the numbers of
  examples each test asks for.
* ``thorough``: ten times the examples, fresh random ones on every run, failures kept in
  ``.hypothesis/`` and replayed first next time. Run it with
  ``.venv/bin/python -m pytest tests/core tests/pipeline --hypothesis-profile=thorough``
  (or ``HYPOTHESIS_PROFILE=thorough``); pin what it finds as an explicit test.

Health checks are on in both. Tests scale their own example counts by the profile's
``max_examples`` (100 in ``ci``) through :func:`examples`.
"""

from __future__ import annotations

import os

from hypothesis import settings

settings.register_profile("ci", max_examples=100, deadline=None, derandomize=True,
                          database=None, print_blob=True)
settings.register_profile("thorough", max_examples=1000, deadline=None, derandomize=False,
                          print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def examples(n: int) -> int:
    """``n`` examples in the ``ci`` profile, scaled by the loaded profile's size."""
    return max(1, round(n * settings.default.max_examples / 100))
