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
groom, its binding and clearance settings (:func:`groom.settings_key`).
"""

from __future__ import annotations

import os

import bpy

from ...core import framecache
from ..frame import groom
from ..frame.record import VALUES_PART, fixed_change
from ..frame.setup import Setup
from ..settings.fingerprints import read_settings
from . import registry, report

#: What a baked setup whose settings are not the bake's says (:func:`message`).
MESSAGE = "baked with other settings"
_ADVICE = "Free Bake and bake again"


def message(what="") -> str:
    """"baked with other settings (Recovery Rate changed at frame 12): Free Bake and
    bake again"."""
    return f"{MESSAGE}{f' ({what})' if what else ''}: {_ADVICE}"


_records: dict = {}  # (file, mtime) -> (inputs record or None, groom key or None)


def _bake_file(ob, scene):
    """(directory, frame) of the setup's bake frame for the scene's current frame
    (Frame Start before it, Frame End after it; the first baked frame when that one
    is missing), or None."""
    s = ob.furcollide
    directory = bpy.path.abspath(s.bake_path)
    f = min(max(scene.frame_current, s.frame_start), s.frame_end)
    if os.path.exists(framecache.frame_path(directory, f)):
        return directory, f
    frames = framecache.list_frames(directory)
    return (directory, frames[0]) if frames else None


def _baked_with(directory, f):
    """(frame-inputs record, render groom key) a bake frame was made with (None:
    unknown, or no render groom in it)."""
    path = framecache.frame_path(directory, f)
    try:
        key = (path, os.path.getmtime(path))
    except OSError:
        return None, None
    got = _records.get(key)
    if got is None:
        try:
            record = framecache.read_inputs(directory, f)
            part = framecache.read_extra(directory, f, groom.BAKE_PART, ("key",))
        except (OSError, ValueError, KeyError):
            record, part = None, None
        got = (record, None if part is None else part["key"].tobytes().decode())
        if len(_records) > 64:
            _records.clear()
        _records[key] = got
    return got


def settings_change(ob, scene=None, directory=None, f=None, record=None, read=None) -> str:
    """What of the setup's settings is other than what its bake's frame ``f`` was made
    with, in words ('' when nothing, or when the bake does not say: files of older
    versions). Default: the baked frame the scene's current frame shows.

    A frame's record holds what every frame shares and the keyable values at that
    frame (:func:`..frame.record.fixed_change` compares them, at ``f`` without going
    there); a bake made before values were recorded holds one digest of the settings,
    the same for every frame. ``read``: the settings as read once at the frame shown
    (:func:`..settings.fingerprints.read_settings`, read now when not given)."""
    scene = scene or bpy.context.scene
    if directory is None:
        where = _bake_file(ob, scene)
        if where is None:
            return ""
        directory, f = where
    record_read, groom_key = _baked_with(directory, f)
    record = record_read if record is None else record
    if record is not None:
        read = read_settings(ob, scene) if read is None else read
        if VALUES_PART in record:
            setup = Setup(ob, scene, None, registry.get_runtime(ob, create=False))
            why = fixed_change(setup, record, read, f)
            if why:
                return why
        elif record.get("settings") not in (None, framecache.text_digest(
                read.signature_record)):
            return "the settings changed"
    g = ob.furcollide.groom
    if (groom_key is not None and g.output is not None and g.bind_id != ""
            and groom_key != groom.settings_key(ob)):
        return "the render groom's settings changed"
    return ""


def settings_differ(ob, scene=None, directory=None, f=None) -> bool:
    """Are the setup's settings other than those its bake was made with
    (:func:`settings_change`)?"""
    return bool(settings_change(ob, scene, directory, f))


def check(ob, scene=None) -> bool:
    """Mark the baked setup on ``ob`` outdated (with :func:`message`) when its settings
    are not those of the baked frame shown, or clear that mark when they are again;
    True when they differ. Does nothing for a setup that is not baked."""
    if not ob.furcollide.is_baked:
        return False
    # A disabled setup shows its source (nothing baked is shown): nothing to disagree with.
    what = settings_change(ob, scene) if ob.furcollide.enabled else ""
    rt = registry.get_runtime(ob)
    if rt is None:
        return bool(what)
    if what:
        report.mark_outdated(rt)
        report.set_status(ob, "WARNING",
                          f"This setup was {message(what)} (the frames shown are the bake's)")
    elif MESSAGE in rt.report.status[1]:
        report.mark_outdated(rt, False)
        report.set_status(ob, "INFO", "")
    return bool(what)
