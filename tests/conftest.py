"""Shared by every test folder: the hypothesis profiles (``hypothesis_profiles.py``:
``ci`` by default, ``thorough`` with ``--hypothesis-profile=thorough``)."""

import hypothesis_profiles  # noqa: F401  (registers and loads the profiles)
