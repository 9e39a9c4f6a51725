"""Hunt 3: wrong pictures, lost work and broken promises of the Blender add-on.

Each ``xfail(strict=True)`` test fails today because of the bug its reason names
(``docs/hunt3-report.md``); it turns red (XPASS) when the bug is fixed. Run:

    .venv/bin/python -m pytest -q -p no:cacheprovider tests/blender/test_bl_hunt3.py
    .venv/bin/python -m pytest -q -p no:cacheprovider --runxfail tests/blender/test_bl_hunt3.py
"""

from __future__ import annotations

import os

import bpy
import numpy as np
import pytest
from helpers import (
    bake_crashing_at,
    bake_files,
    render_camera,
    render_watching,
    save_in,
    world,
)


# ------------------------------------------------------------ 1. bake directory
def test_a_new_cache_directory_after_a_failed_bake_is_used(fc, tmp_path):
    """The Cache Directory points at a file (a typo, an unmounted share): Bake fails at
    frame 1. The artist fixes the Directory (Cache panel, still editable) and presses
    Bake again: it must bake there, not fail again on the old path."""
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    blocker = tmp_path / "cache_is_a_file"
    blocker.write_text("not a directory")
    hair.furcollide.cache_directory = str(blocker) + os.sep
    save_in(tmp_path)
    with pytest.raises(RuntimeError, match="Not a directory"):
        bpy.ops.furcollide.bake()
    good = tmp_path / "good cache"
    hair.furcollide.cache_directory = str(good) + os.sep
    bpy.ops.furcollide.bake()  # raises today: the same NotADirectoryError
    assert hair.furcollide.is_baked
    assert os.path.abspath(bpy.path.abspath(hair.furcollide.bake_path)).startswith(str(good))


def test_a_partial_bake_resumed_after_a_directory_change_goes_to_the_new_directory(
        fc, tmp_path, monkeypatch):
    """A bake crashes at frame 4 (frames 1-3 on disk, next to the .blend). The artist
    then points Directory at the farm share and presses Bake: every frame must end up
    on the share (the render nodes read only it)."""
    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    save_in(tmp_path)
    bake_crashing_at(fc, monkeypatch, 4)
    share = tmp_path / "farm share"
    hair.furcollide.cache_directory = str(share) + os.sep
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    assert os.path.abspath(d).startswith(str(share)), d
    assert len(bake_files(d)) == 12


# ------------------------------------------------- 2. motion blur at Frame End
def test_motion_blur_steps_of_the_last_baked_frame(fc, tmp_path):
    """Cycles renders a motion-blurred frame F as F, F-0.25, F+0.25, F (its frame
    handler calls; see the report). Baked, F-0.25 is a blend of F-1 and F; at Frame End,
    F+0.25 has no next baked frame and must show Frame End (held after it, README
    "Time"), not keep the F-0.25 blend: the hair would be at F-0.25 at both ends of
    the shutter."""
    hair, box = fc.make_scene(frames=(1, 4), nx=5, ny=5)
    out = fc.setup(hair, [box])
    scene = bpy.context.scene
    save_in(tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    scene.frame_set(3)
    p3 = world(out).copy()
    scene.frame_set(4)
    p4 = world(out).copy()
    assert not np.array_equal(p3, p4)
    # an inner frame: both motion steps are blends of their baked neighbours
    scene.frame_set(3, subframe=0.25)
    assert not np.array_equal(world(out), p3)
    # the last frame, in Cycles' order
    scene.frame_set(4)
    scene.frame_set(3, subframe=0.75)
    before = world(out).copy()
    np.testing.assert_allclose(before, p3 + (p4 - p3) * 0.75, atol=1e-6)
    scene.frame_set(4, subframe=0.25)
    np.testing.assert_array_equal(world(out), p4)


# ----------------------------------- 3. the source's other data never reach the output
def _radius_modifier(ob, value):
    """A geometry-nodes modifier on ``ob`` setting every curve's radius (what the
    artist uses for the render width); returns its Set Curve Radius node."""
    ng = bpy.data.node_groups.new("Width", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gi, go = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    sr = ng.nodes.new("GeometryNodeSetCurveRadius")
    sr.inputs["Radius"].default_value = value
    ng.links.new(gi.outputs[0], sr.inputs["Curve"])
    ng.links.new(sr.outputs[0], go.inputs[0])
    ob.modifiers.new("Width", "NODES").node_group = ng
    return sr


def _radii(ob):
    d = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    r = np.empty(len(d.points), np.float32)
    d.attributes["radius"].data.foreach_get("value", r)
    return r


def test_the_output_follows_the_evaluated_sources_radius(fc):
    """README: each frame FurCollide reads the *evaluated* source (after its modifiers)
    and the output has its curves. The artist widens the fur after Add (the source's
    Set Curve Radius modifier: 0.01 -> 0.05) and plays: the output, which is what
    renders (the source is hidden from render), must get the new width. Today it keeps
    0.01 forever, through Reset Cache too; only Remove + Add (which deletes the output
    and the artist's modifiers on it) picks it up."""
    hair, box = fc.make_scene()
    sr = _radius_modifier(hair, 0.01)
    out = fc.setup(hair, [box])
    np.testing.assert_allclose(_radii(out), 0.01)
    sr.inputs["Radius"].default_value = 0.05
    scene = bpy.context.scene
    for f in range(1, 5):
        scene.frame_set(f)
    np.testing.assert_allclose(_radii(hair), 0.05)
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    scene.frame_set(1)
    np.testing.assert_allclose(_radii(out), 0.05)


# ------------------------- 4. and 5. objects that Blender evaluates otherwise in renders
#: The status (an INFO note) of a setup whose collider has a Subdivision Surface at
#: Blender's defaults: renders show the frames solved against the viewport's shape.
SUBDIVIDED = ("Colliders: 'Box' renders with other geometry than the viewport "
              "('Subdivision' at level 1 in the viewport, 2 in renders): the playback cache "
              "and the bake are solved against its viewport shape, and renders show them "
              "as they are")
def _played_with_a_subdivided_box(fc, frames=(1, 6)):
    """The sweeping box with a Subdivision Surface modifier at Blender's defaults
    (Levels Viewport 1, Render 2), hidden from render, a setup on the hair grid."""
    hair, box = fc.make_scene(frames=frames)
    mod = box.modifiers.new("Subdivision", "SUBSURF")
    assert (mod.levels, mod.render_levels) == (1, 2)  # what Ctrl-1 / Add Modifier give
    out = fc.setup(hair, [box])
    scene = bpy.context.scene
    render_camera(scene)
    box.hide_render = True
    return scene, hair, box, out


def test_f12_with_a_subdivided_collider_keeps_the_playback_cache(fc, tmp_path):
    """Play the shot, stop at frame 5, press F12. Nobody changed the box; today the
    render reads its render-level mesh, the frame's record no longer holds, the whole
    playback cache is dropped and the status says "'Box' changed shape since it was
    cached" (so does the render's console). The control (no modifier) keeps it."""
    scene, hair, box, out = _played_with_a_subdivided_box(fc)
    for f in range(1, 7):
        scene.frame_set(f)
    scene.frame_set(5)
    rt = fc.registry.get_runtime(hair, create=False)
    assert len(rt.memory) == 6
    scene.render.filepath = str(tmp_path / "still.png")
    bpy.ops.render.render(write_still=True)
    assert "changed shape" not in hair.furcollide.status_message
    assert len(rt.memory) == 6, hair.furcollide.status_message


def test_render_of_a_bake_with_a_subdivided_collider_is_not_outdated(fc, tmp_path):
    """Baked, then rendered (the README's way): every rendered frame says "Frame N of
    the bake is outdated: 'Box' changed shape since it was baked ... press Free Bake,
    then Bake", and following the advice gives the same bake and the same warnings."""
    scene, hair, box, out = _played_with_a_subdivided_box(fc, frames=(1, 4))
    save_in(tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    seen, statuses = render_watching(tmp_path, "baked", [out], hair)
    assert [s for s in statuses if s[1] != SUBDIVIDED] == []


def test_frames_solved_in_a_render_of_a_subdivided_collider_are_shown_in_the_viewport(
        fc, tmp_path):
    """Played to frame 3, then the animation rendered: frames 4-6 are solved in the
    render (against the box at render levels) and cached. Back in the viewport they are
    shown as they are: the box's other render evaluation is not an edit either way."""
    scene, hair, box, out = _played_with_a_subdivided_box(fc)
    for f in range(1, 4):
        scene.frame_set(f)
    rt = fc.registry.get_runtime(hair, create=False)
    seen, statuses = render_watching(tmp_path, "anim", [out], hair)
    assert [s for s in statuses if s[1] != SUBDIVIDED] == []
    assert len(rt.memory) == 6
    for f in (4, 5, 6, 3):
        scene.frame_set(f)
        assert hair.furcollide.status_message == SUBDIVIDED
        assert not hair.furcollide.is_outdated
        np.testing.assert_array_equal(world(out), seen[(f, 0.0)][-1][out.name])
    assert len(rt.memory) == 6


def _render_only_subdivision():
    """A geometry-nodes group that subdivides the curves in renders only (``Is
    Viewport``), as Blender's own *Interpolate Hair Curves* does with its *Viewport
    Amount* below 1."""
    ng = bpy.data.node_groups.new("Render Detail", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gi, go = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    sub = ng.nodes.new("GeometryNodeSubdivideCurve")
    viewport = ng.nodes.new("GeometryNodeIsViewport")
    switch = ng.nodes.new("GeometryNodeSwitch")
    switch.input_type = "GEOMETRY"
    ng.links.new(gi.outputs[0], sub.inputs["Curve"])
    ng.links.new(viewport.outputs[0], switch.inputs["Switch"])
    ng.links.new(sub.outputs[0], switch.inputs["False"])
    ng.links.new(gi.outputs[0], switch.inputs["True"])
    ng.links.new(switch.outputs[0], go.inputs[0])
    return ng


@pytest.mark.xfail(strict=True, reason="a limit (README Rendering): the cache and the bake "
                   "hold the viewport's curves; the render shows them, with a message saying why")
def test_a_source_denser_in_renders_renders_its_render_curves(fc, tmp_path):
    """The source's modifier gives more points in renders than in the viewport. The
    animation render must show the render curves collided; today every rendered frame
    says "Source hair changed from 36 curves / 180 points to 36 / 324 ... Press Reset"
    (Reset changes nothing: the viewport is right) and the output keeps the viewport's
    180 points."""
    hair, box = fc.make_scene(frames=(1, 3))
    hair.modifiers.new("Render Detail", "NODES").node_group = _render_only_subdivision()
    out = fc.setup(hair, [box])
    scene = bpy.context.scene
    render_camera(scene)
    box.hide_render = True
    seen, statuses = render_watching(tmp_path, "dense", [out], hair)
    assert [s for s in statuses if s[1]] == []


def test_a_source_denser_in_renders_says_why_the_render_shows_the_viewport_curves(
        fc, tmp_path):
    """The limit the test above names: each rendered frame says that the source has
    other curves in the render than in the viewport and what to do, not "press Reset"
    (which changes nothing); the viewport afterwards is as it was."""
    hair, box = fc.make_scene(frames=(1, 3))
    hair.modifiers.new("Render Detail", "NODES").node_group = _render_only_subdivision()
    out = fc.setup(hair, [box])
    scene = bpy.context.scene
    render_camera(scene)
    for f in (1, 2, 3):
        scene.frame_set(f)
    before = world(out).copy()
    seen, statuses = render_watching(tmp_path, "dense_msg", [out], hair)
    said = [m for _k, m in statuses if m]
    assert said and all("other curves in this render" in m and "Reset" not in m
                        for m in said), said
    scene.frame_set(3)
    np.testing.assert_array_equal(world(out), before)
    assert "other curves" not in hair.furcollide.status_message


# ------------------------------------------- 6. the Cache Directory's "//" on 5.0
def test_a_relative_cache_directory_set_from_a_script_does_not_warn(fc):
    """README: the Directory defaults to ``//furcollide_cache/`` ('//' = next to the
    .blend). A TD's script setting another relative folder the same way gets, on
    Blender 5.0, a RuntimeWarning "FurCollideSettings.cache_directory: does not support
    blend relative "//" prefix" (the value is stored all the same), and the property is
    not marked as supporting relative paths (the file browser's Relative Path option)."""
    import warnings

    hair, box = fc.make_scene()
    fc.setup(hair, [box])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        hair.furcollide.cache_directory = "//shot cache/"
    assert hair.furcollide.cache_directory == "//shot cache/"
    assert [str(w.message) for w in caught] == []
