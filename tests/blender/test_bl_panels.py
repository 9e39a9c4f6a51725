"""Every panel, sub-panel, menu and list of the sidebar drawn in every state of a setup.

Panels cannot be drawn headless, so each is drawn into ``helpers.RnaLayout``: a recording
layout that checks every call against Blender's own RNA (``UILayout``'s functions, their
parameters and enum values, and every property name against the RNA of the object it is
given). A misspelled property, an icon Blender does not have, a keyword the real layout
refuses or an exception in ``draw()`` fails here as it would show an error in the real
sidebar. The states: no setup, a fresh setup, played, an error, outdated, a partial bake,
baked, an outdated bake, no output, the output active, a collider out of the scene, an
empty collider slot, the ray tracer missing, a bake in progress, Lock Interface off and
on. The real application draws them too (``tests/app/test_real_blender_ui.py``).
"""

from __future__ import annotations

import sys

import bpy
import numpy as np
import pytest
from helpers import (
    ADDON,
    DRAWN,
    activate,
    bake_crashing_at,
    draw_rna,
    make_surface,
    play,
    save_in,
    small_setup,
)

pytestmark = pytest.mark.blender

#: Panels whose settings a baked setup only shows (greyed out until Free Bake).
SETTINGS_PANELS = ("FURCOLLIDE_PT_colliders", "FURCOLLIDE_PT_resolution",
                   "FURCOLLIDE_PT_shrink", "FURCOLLIDE_PT_recovery", "FURCOLLIDE_PT_pinch",
                   "FURCOLLIDE_PT_enable")
LOCK_WARNING = "Enable Render > Lock Interface"


def _ui_classes():
    ui = sys.modules[ADDON + ".ui"]
    panels = [c for c in ui.classes if issubclass(c, bpy.types.Panel)]
    menus = [c for c in ui.classes if issubclass(c, bpy.types.Menu)]
    lists = [c for c in ui.classes if issubclass(c, bpy.types.UIList)]
    return panels, menus, lists


def draw_everything(context=None):
    """{panel name: its log, or None when its poll refuses} for every panel of the
    add-on, drawn as Blender would draw the sidebar for the active object; menus are
    drawn too (the presets menu)."""
    panels, menus, _ = _ui_classes()
    out = {}
    parents_ok = {}
    for cls in panels:
        parent = getattr(cls, "bl_parent_id", "")
        if parent and not parents_ok.get(parent, True):
            out[cls.__name__] = None  # a closed parent hides its children
            continue
        if getattr(cls, "bl_region_type", "") == "HEADER":  # a popover (presets)
            log = draw_rna(cls, context, header=False)
        else:
            log = draw_rna(cls, context)
        out[cls.__name__] = log
        parents_ok[cls.__name__] = log is not None
    for cls in menus:
        out[cls.__name__] = draw_rna(cls, context, header=False)
    return out


def labels(log):
    return [e["text"] for e in log if e["kind"] == "label"]


def entries(log, kind, name=None):
    return [e for e in log if e["kind"] == kind and (name is None or e.get("name") == name)]


def _drawn(logs):
    return {k for k, v in logs.items() if v is not None}


def _settings_props(logs):
    return [e for p in SETTINGS_PANELS for e in (logs[p] or []) if e["kind"] == "prop"]


# -------------------------------------------------------------------- states
def test_no_setup_offers_add_and_hides_the_sub_panels(fc):
    hair, box = fc.make_scene()
    activate(hair, box)
    logs = draw_everything()
    main = logs["FURCOLLIDE_PT_main"]
    assert [e["name"] for e in entries(main, "operator")] == ["furcollide.add"]
    assert "Select the colliders," in labels(main)
    assert "then Shift-click the hair last" in labels(main)
    setup_panels = {"FURCOLLIDE_PT_colliders", "FURCOLLIDE_PT_resolution",
                    "FURCOLLIDE_PT_cache", "FURCOLLIDE_PT_stats", *SETTINGS_PANELS}
    assert not (setup_panels & _drawn(logs)), _drawn(logs)
    pipe = logs["FURCOLLIDE_PT_pipeline"]  # the Fur Sampler works without a setup
    assert entries(pipe, "operator", "furcollide.fur_sampler")
    assert "Needs a FurCollide setup" in labels(pipe)
    # a mesh (not hair) active: no FurCollide panel at all
    activate(box)
    assert draw_everything()["FURCOLLIDE_PT_main"] is None


def test_a_fresh_setup_draws_every_section_from_source_and_output(fc):
    hair, box, out = small_setup(fc)
    for ob in (hair, out):  # the output shows the same setup
        activate(ob)
        logs = draw_everything()
        main = logs["FURCOLLIDE_PT_main"]
        props = [(e["name"], e["enabled"]) for e in entries(main, "prop")]
        assert ("enabled", True) in props and ("show_result", True) in props
        assert ("output", False) in props  # shown, never edited
        assert entries(main, "operator", "furcollide.remove")
        for name in SETTINGS_PANELS + ("FURCOLLIDE_PT_cache", "FURCOLLIDE_PT_stats",
                                       "FURCOLLIDE_PT_pipeline"):
            assert logs[name] is not None, name
        assert all(e["enabled"] for e in _settings_props(logs))  # not baked: editable
        cols = logs["FURCOLLIDE_PT_colliders"]
        (tl,) = entries(cols, "template_list")
        assert tl["items"] == 1
        item = [e for e in cols if e["kind"] == "prop" and e["list_item"] == 0
                and e["name"] == "object"]
        assert item and item[0]["icon"] == "MESH_DATA" and not item[0]["alert"]
        cache = logs["FURCOLLIDE_PT_cache"]
        assert "1 of 8 frames cached" in labels(cache), labels(cache)
        assert entries(cache, "operator", "furcollide.bake")
        assert not entries(cache, "operator", "furcollide.free_bake")
        resolution = {e["name"] for e in entries(logs["FURCOLLIDE_PT_resolution"], "prop")}
        assert {"mode", "rotation_precision", "max_angle", "affected_connected_cvs",
                "cv_falloff", "attract_to_growth_surface", "collision_offset",
                "threads"} <= resolution


def test_last_frame_shows_the_statistics_of_the_frame_shown(fc):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    play(scene, range(1, 5))
    s = hair.furcollide
    assert s.stat_colliding > 0
    activate(hair)
    stats = labels(draw_everything()["FURCOLLIDE_PT_stats"])
    assert stats[:6] == ["Frame 4", f"Colliding: {s.stat_colliding}",
                         f"Recovering: {s.stat_recovering}", f"Pinched: {s.stat_pinched}",
                         f"Unresolved: {s.stat_unresolved}", f"Disabled: {s.stat_disabled}"]
    assert f"Solve: {s.stat_solve_ms:.1f} ms" in stats  # (then the time of each stage)
    assert "4 of 8 frames cached" in labels(draw_everything()["FURCOLLIDE_PT_cache"])


def test_an_error_is_shown_in_the_main_panel(fc):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    hair.furcollide.attract_to_growth_surface = True  # needs the hair's Surface: none
    play(scene, range(1, 3))
    level, message = fc.store.report.status_for(hair)
    assert level == "ERROR" and "Surface" in message
    activate(hair)
    main = draw_everything()["FURCOLLIDE_PT_main"]
    shown = [e for e in main if e["kind"] == "label" and e["icon"] == "ERROR"]
    assert shown and message.startswith(shown[0]["text"]), (shown, message)
    # the whole message is shown, wrapped
    box = [e["text"] for e in main if e["kind"] == "label" and e["icon"] in ("ERROR", "BLANK1")]
    assert " ".join(box).replace(LOCK_WARNING, "").split() [:len(message.split())] \
        == message.split()


def test_outdated_playback_cache_is_shown(fc):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    play(scene, range(1, 6))
    box.rotation_euler.z += 0.3  # turned without a key: the cached frames no longer hold
    scene.frame_set(3)
    assert hair.furcollide.is_outdated
    activate(hair)
    logs = draw_everything()
    cache = logs["FURCOLLIDE_PT_cache"]
    assert "Outdated: play from the start frame or bake" in labels(cache), labels(cache)
    main = logs["FURCOLLIDE_PT_main"]
    assert any("outdated" in (t or "") for t in labels(main)), labels(main)


def test_partial_bake_offers_free_partial(fc, tmp_path, monkeypatch):
    hair, box, out = small_setup(fc)
    save_in(tmp_path)
    activate(hair)
    bake_crashing_at(fc, monkeypatch, 4)
    logs = draw_everything()
    cache = logs["FURCOLLIDE_PT_cache"]
    assert "3 of 8 frames on disk (partial bake)" in labels(cache), labels(cache)
    ops = [(e["name"], e["text"]) for e in entries(cache, "operator")]
    assert ("furcollide.bake", None) in ops and ("furcollide.free_bake", "Free Partial") in ops
    assert all(e["enabled"] for e in _settings_props(logs))


def test_a_baked_setup_only_reads(fc, tmp_path):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    save_in(tmp_path)
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    logs = draw_everything()
    settings = _settings_props(logs)
    assert settings and not any(e["enabled"] for e in settings), \
        [e["name"] for e in settings if e["enabled"]]
    preset = [e for e in logs["FURCOLLIDE_PT_main"] if e["kind"] == "popover"]
    assert preset and not preset[0]["enabled"]  # presets would change settings too
    cache = logs["FURCOLLIDE_PT_cache"]
    assert "8 of 8 frames baked" in labels(cache)
    assert entries(cache, "operator", "furcollide.free_bake")
    assert not entries(cache, "operator", "furcollide.bake")
    frame_props = [e for e in entries(cache, "prop") if e["name"] in ("frame_start", "frame_end",
                                                                       "cache_directory")]
    assert len(frame_props) == 3 and not any(e["enabled"] for e in frame_props)
    # an outdated bake says so (a collider moved since the bake)
    box.rotation_euler.z += 0.3
    scene.frame_set(4)
    assert hair.furcollide.is_outdated
    cache = draw_everything()["FURCOLLIDE_PT_cache"]
    assert "Outdated bake: Free Bake, then Bake" in labels(cache), labels(cache)


def test_without_its_output_the_setup_still_draws(fc):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    bpy.data.objects.remove(out)
    play(scene, range(1, 3))
    activate(hair)
    logs = draw_everything()
    main = logs["FURCOLLIDE_PT_main"]
    output = entries(main, "prop", "output")
    assert output and output[0]["data"].output is None
    assert entries(main, "operator", "furcollide.remove")
    assert logs["FURCOLLIDE_PT_cache"] is not None


def test_collider_list_marks_a_collider_out_of_the_scene_and_an_empty_slot(fc):
    hair, box, out = small_setup(fc)
    bpy.context.scene.collection.objects.unlink(box)  # alive in the file, not in the scene
    hair.furcollide.colliders.add()  # an empty slot
    activate(hair)
    cols = draw_everything()["FURCOLLIDE_PT_colliders"]
    in_list = [e for e in cols if e["kind"] == "prop" and e["list_item"] is not None]
    items = [e for e in in_list if e["name"] == "object"]
    assert len(items) == 2 and [e["list_item"] for e in items] == [0, 1]
    assert items[0]["alert"] and items[0]["icon"] == "ERROR"
    assert not items[1]["alert"] and items[1]["icon"] == "MESH_DATA"
    assert [(e["name"], e["icon"]) for e in in_list if e["name"] != "object"] == [
        ("double_sided", "MOD_SOLIDIFY"), ("enabled", "CHECKBOX_HLT"),
        ("double_sided", "MOD_SOLIDIFY"), ("enabled", "CHECKBOX_HLT")]


def test_lock_interface_warning_only_while_it_is_off(fc):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    activate(hair)
    scene.render.use_lock_interface = False
    main = draw_everything()["FURCOLLIDE_PT_main"]
    assert LOCK_WARNING in labels(main)
    toggle = entries(main, "prop", "use_lock_interface")
    assert toggle and toggle[0]["data"] == scene.render
    scene.render.use_lock_interface = True
    main = draw_everything()["FURCOLLIDE_PT_main"]
    assert LOCK_WARNING not in labels(main) and not entries(main, "prop", "use_lock_interface")


def test_missing_ray_tracer_is_explained_in_the_panel(fc, monkeypatch):
    panel_module = sys.modules[ADDON + ".ui.panel"]
    monkeypatch.setattr(panel_module, "backend_message",
                        lambda: "FurCollide needs the embreex ray tracer: no wheel for this "
                                "platform (simulated)")
    hair, box = fc.make_scene()
    activate(hair)
    main = draw_everything()["FURCOLLIDE_PT_main"]
    text = labels(main)
    assert "Ray tracer unavailable" in text
    assert "platform (simulated)" in " ".join(t for t in text if t)


def test_a_running_bake_shows_its_progress(fc):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    activate(hair)
    progress = sys.modules[ADDON + ".operators.ops.bake"].PROGRESS
    progress[scene.name] = (3, 8)
    try:
        cache = draw_everything()["FURCOLLIDE_PT_cache"]
    finally:
        progress.pop(scene.name, None)
    (bar,) = entries(cache, "progress")
    assert bar["text"] == "Baking 3 / 8 (Esc)"


def test_pipeline_panel_draws_with_a_surface_and_every_stage(fc):
    hair, box, out = small_setup(fc)
    surf = make_surface()
    hair.data.surface = surf
    surf.vertex_groups.new(name="Area")
    m = hair.furcollide.motion
    m.use_wind = m.use_jiggle = True
    m.wind_stage = "OUTPUT"
    activate(hair)
    pipe = draw_everything()["FURCOLLIDE_PT_pipeline"]
    assert entries(pipe, "prop_search", "area")  # the surface's vertex groups
    for idname in ("furcollide.fur_sampler", "furcollide.fur_attach_bind",
                   "furcollide.collider_distance", "furcollide.children_from_guides",
                   "furcollide.groom_bind"):
        assert entries(pipe, "operator", idname), idname


def test_every_panel_menu_and_list_is_drawn(fc, tmp_path):
    """Draws the states above once more in one session and checks that each panel,
    menu and list class of the add-on was drawn at least once (a new panel must be
    added to the states here)."""
    scene = bpy.context.scene
    DRAWN.clear()
    hair, box = fc.make_scene()
    activate(hair)
    draw_everything()
    hair2, box2, out = small_setup(fc)
    hair.hide_set(True)
    activate(hair2)
    draw_everything()
    play(scene, range(1, 4))
    draw_everything()
    save_in(tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    draw_everything()
    panels, menus, lists = _ui_classes()
    want = {c.__name__ for c in panels + menus + lists}
    assert want - DRAWN == set(), want - DRAWN
    assert np.all([isinstance(n, str) for n in DRAWN])
