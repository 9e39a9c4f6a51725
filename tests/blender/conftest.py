"""Blender-side test set-up (real ``bpy`` wheel, no mocks).

* ``BLENDER_USER_RESOURCES`` points to a temporary folder *before* ``bpy`` is
  imported, so no installed extension (or its wheels) can shadow the venv.
* The repository is registered as an extension from a temporary "dev"
  repository whose folder contains a symlink ``furcollide -> <repo root>``
  (CI may clone the repository under another name).
* Every test starts from an empty factory scene (``read_homefile``), which
  keeps the add-on enabled.
* ``fc`` gives a test the add-on's modules; the scene builders the tests share are in
  ``helpers.py``.
"""

from __future__ import annotations

import atexit
import os
import shutil
import sys
import tempfile
import types
from pathlib import Path

import pytest

_USER = tempfile.mkdtemp(prefix="furcollide_user_")
os.environ["BLENDER_USER_RESOURCES"] = _USER

bpy = pytest.importorskip("bpy")
import addon_utils  # noqa: E402  (needs bpy first)
import helpers  # noqa: E402  (scene builders shared by the tests)

REPO = Path(__file__).resolve().parents[2]
DEV_DIR = Path(tempfile.mkdtemp(prefix="furcollide_dev_"))
(DEV_DIR / "furcollide").symlink_to(REPO, target_is_directory=True)
ADDON = helpers.ADDON


@atexit.register
def _cleanup():
    link = DEV_DIR / "furcollide"
    if link.is_symlink():
        link.unlink()  # the link only, never the repository behind it
    shutil.rmtree(DEV_DIR, ignore_errors=True)
    shutil.rmtree(_USER, ignore_errors=True)


@pytest.fixture(scope="module", autouse=True)
def furcollide_addon():
    """Enable the add-on from the dev repository for each test module (and disable it
    afterwards, so register/unregister run repeatedly and nothing leaks into other
    test directories)."""
    repos = bpy.context.preferences.extensions.repos
    if "fcdev" not in {r.module for r in repos}:
        repos.new(name="fcdev", module="fcdev", custom_directory=str(DEV_DIR), source="USER")
    mod = addon_utils.enable(ADDON, default_set=True, handle_error=None)
    assert mod is not None, "FurCollide add-on failed to enable"
    yield mod
    addon_utils.disable(ADDON, default_set=True)


@pytest.fixture(autouse=True)
def clean_scene(furcollide_addon):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    yield


#: The rooms of the add-on's glue (``operators/<room>/``) the tests reach as ``fc.<room>``:
#: ``fc.frame.rules``, ``fc.store.registry``, ``fc.settings.keyed``, ``fc.ops.cli``,
#: ``fc.blender.bridge``.
_ROOMS = ("frame", "settings", "ops", "store", "blender")


@pytest.fixture
def fc():
    """The add-on's glue by room (``fc.store.registry``, ``fc.frame.rules`` ...), the
    core (``fc.core``, ``fc.cache``: its frame cache), ``fc.Setup`` and scene helpers."""
    pkg = ADDON
    ns = types.SimpleNamespace(
        cache=sys.modules[pkg + ".core.framecache"],
        core=sys.modules[pkg + ".core"],
        package=sys.modules[pkg],
        Setup=sys.modules[pkg + ".operators.frame.setup"].Setup,
        make_scene=helpers.make_scene,
        positions=helpers.positions,
        setup=helpers.setup,
        **{room: sys.modules[f"{pkg}.operators.{room}"] for room in _ROOMS},
    )
    return ns
