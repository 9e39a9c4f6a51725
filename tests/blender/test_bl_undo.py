"""What the add-on does around an undo, on the ``bpy`` wheel. The undo itself needs a
window: it is tested in the real application (``tests/app/test_real_blender_undo.py``);
here the handlers Blender calls around it are called as Blender calls them."""

import sys

import bpy
import pytest
from helpers import ADDON, bake_files_of, build_setup, save_in

pytestmark = pytest.mark.blender


def handlers():
    return sys.modules[ADDON + ".operators.frame.handlers"]


def test_undo_pre_stops_a_running_bake_and_keeps_its_frames(fc, tmp_path):
    """An undo replaces the objects a running modal bake holds: ``undo_pre`` stops it
    first, as Esc does (frames kept, not baked, the setup no longer 'baking'), and the
    frame handler evaluates the setup again. (Without it every later step of the bake
    raised ReferenceError and the setup stayed 'baking': never shown again.)"""
    ops_bake = sys.modules[ADDON + ".operators.ops.bake"]
    hair, _box, _out = build_setup(fc, "")
    save_in(tmp_path)
    scene = bpy.context.scene
    job = fc.store.bake.BakeJob(scene, [hair])
    job.step()
    job.step()
    ops_bake.RUNNING.add(job)  # (what invoke does)
    try:
        handlers().on_undo_pre(scene)
    finally:
        ops_bake.RUNNING.discard(job)
    assert job.stopped == ops_bake.STOPPED_BY_UNDO
    assert not fc.store.registry.get_runtime(hair).baking
    assert not hair.furcollide.is_baked
    assert bake_files_of(hair) == ["frame_000001.npz", "frame_000002.npz"]
    # stopped once: the operator's own end (its next event) finishes nothing again
    job.stop("again")
    assert job.stopped == ops_bake.STOPPED_BY_UNDO
    scene.frame_set(1)  # the frame handler solves the start frame again
    assert 1 in fc.store.registry.get_runtime(hair).cache.memory
    depsgraph = bpy.context.evaluated_depsgraph_get()
    assert fc.frame.spine.evaluate(fc.Setup(hair, scene, depsgraph)) is (
        fc.frame.rules.Outcome.CACHE)


def test_undo_pre_without_a_bake_does_nothing(fc):
    hair, _box, _out = build_setup(fc, "")
    handlers().on_undo_pre(bpy.context.scene)
    handlers().on_undo_post(bpy.context.scene)  # (headless: no refresh timer)
    bpy.context.scene.frame_set(1)
    assert fc.store.report.status_for(hair) == ("INFO", "")
