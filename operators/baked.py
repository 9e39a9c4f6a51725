"""A baked setup against its bake: are the settings shown the ones it was baked with?

A baked setup only reads its files (its settings are greyed out in every panel), but a
script, a driver or undo can still change a setting. Such a change must never leave
frames on screen that silently disagree with the settings shown: :func:`check` marks
the setup outdated with :data:`MESSAGE` (the update callbacks call it at once, from
Python too) and clears it when the settings are the bake's again.

What is compared: the *settings* part of the bake's frame-inputs record (the setup's
signature without the objects' identities: every solver setting, the colliders'
options, Fur Attach, wind, jiggle, Region of Influence, the collider distance
attribute; renaming an object never counts), and, when the bake holds the render
groom, its binding and clearance settings (:func:`groom_stage.settings_key`).
"""

from __future__ import annotations

import os

import bpy

from ..core import framecache
from . import groom_stage, registry
from .setup import signature

#: What a baked setup whose settings are not the bake's says.
MESSAGE = "baked with other settings: Free Bake and bake again"

_records: dict = {}  # (file, mtime) -> (settings digest or None, groom key or None)


def _bake_file(ob):
    """(directory, frame) of the first frame of the setup's bake, or None."""
    s = ob.furcollide
    directory = bpy.path.abspath(s.bake_path)
    if os.path.exists(framecache.frame_path(directory, s.frame_start)):
        return directory, s.frame_start
    frames = framecache.list_frames(directory)
    return (directory, frames[0]) if frames else None


def _baked_with(directory, f):
    """(settings digest, render groom key) a bake frame was made with (None: unknown,
    or no render groom in it)."""
    path = framecache.frame_path(directory, f)
    try:
        key = (path, os.path.getmtime(path))
    except OSError:
        return None, None
    got = _records.get(key)
    if got is None:
        try:
            record = framecache.read_inputs(directory, f)
            groom = framecache.read_extra(directory, f, groom_stage.BAKE_PART, ("key",))
        except (OSError, ValueError, KeyError):
            record, groom = None, None
        got = (None if record is None else record.get("settings"),
               None if groom is None else groom["key"].tobytes().decode())
        if len(_records) > 64:
            _records.clear()
        _records[key] = got
    return got


def settings_differ(ob, scene=None, directory=None, f=None) -> bool:
    """Are the setup's settings other than those its bake (frame ``f``, default the
    first) was made with? False when the bake does not say (files of older versions).

    Every frame of a bake has the same settings (a bake resumes only with them), so the
    first frame's record, read once per file version, answers for every frame shown."""
    if directory is None:
        where = _bake_file(ob)
        if where is None:
            return False
        directory, f = where
    settings, groom_key = _baked_with(directory, f)
    scene = scene or bpy.context.scene
    if settings is not None and settings != framecache.text_digest(
        signature(ob, scene=scene, identities=False)
    ):
        return True
    g = ob.furcollide.groom
    return (groom_key is not None and g.output is not None and g.bind_id != ""
            and groom_key != groom_stage.settings_key(ob))


def check(ob, scene=None) -> bool:
    """Mark the baked setup on ``ob`` outdated (with :data:`MESSAGE`) when its settings
    are not the bake's, or clear that mark when they are again; True when they differ.
    Does nothing for a setup that is not baked."""
    if not ob.furcollide.is_baked:
        return False
    # A disabled setup shows its source (nothing baked is shown): nothing to disagree with.
    differs = ob.furcollide.enabled and settings_differ(ob, scene)
    rt = registry.get_runtime(ob)
    if rt is None:
        return differs
    if differs:
        rt.outdated = True
        registry.set_status(ob, "WARNING",
                            f"This setup was {MESSAGE} (the frames shown are the bake's)")
    elif MESSAGE in rt.status[1]:
        rt.outdated = False
        registry.set_status(ob, "INFO", "")
    return differs
