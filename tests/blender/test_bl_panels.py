"""Every panel, sub-panel, menu and list of the sidebar drawn in every state of a setup.

Panels cannot be drawn headless, so each is drawn into ``helpers.RnaLayout``: a recording
layout that checks every call against Blender's own RNA (``UILayout``'s functions, their
parameters and enum values, and every property name against the RNA of the object it is
given). A misspelled property, an icon Blender does not have, a keyword the real layout
refuses or an exception in ``draw()`` fails here as it would show an error in the real
sidebar. The states: no setup, a fresh setup, played, an error, outdated, a partial bake,
baked, an outdated bake, no output, the output active, a collider out of the scene, an
empty collider slot, the ray tracer missing, a bake in progress, Lock Interface off and
on, Playback Sync dropping frames. The real application draws them too
(``tests/app/test_real_blender_ui.py``).

Then the panel as Blender users expect it: the hint followed as written sets the hair up;
every name, hint and status fits the sidebar at its default width (measured with
Blender's font, ``ui/text.py``); every keyable setting shows its keyframe decorator;
Recovery & Plasticity opens with the sections a setup needs; Remove asks first; the
Object menu's FurCollide entry comes and goes with the add-on; a scene that drops frames
or renders unlocked gets a one-line warning with the button that fixes it.
"""

from __future__ import annotations

import sys

import bpy
import numpy as np
import pytest
from helpers import (
    ADDON,
    DRAWN,
    Bound,
    RnaLayout,
    activate,
    bake_crashing_at,
    draw_rna,
    make_box,
    make_hair,
    make_surface,
    play,
    property_groups,
    save_in,
    small_setup,
)

pytestmark = pytest.mark.blender

#: Panels whose settings a baked setup only shows (greyed out until Free Bake).
SETTINGS_PANELS = ("FURCOLLIDE_PT_colliders", "FURCOLLIDE_PT_resolution",
                   "FURCOLLIDE_PT_shrink", "FURCOLLIDE_PT_recovery", "FURCOLLIDE_PT_pinch",
                   "FURCOLLIDE_PT_enable")


def _panel_module():
    return sys.modules[ADDON + ".ui.panel"]


def _text():
    return sys.modules[ADDON + ".ui.text"]


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
    assert " ".join(labels(main)) == "Select the colliders, then Shift-click the hair last"
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
    box = [e["text"] for e in main if e["kind"] == "label" and e["boxes"] == 1]
    assert " ".join(box).split() == message.split()


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
    assert _panel_module().OUTDATED in labels(cache), labels(cache)
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


def _warning_rows(log):
    """(label, operator idname, button text) of each one-line warning a panel drew."""
    rows = {}
    for e in log:
        if e.get("in_split") and e["kind"] in ("label", "operator"):
            rows.setdefault(e["layout"], []).append(e)
    return [(row[0]["text"], row[1]["name"], row[1]["text"]) for row in rows.values()]


def test_lock_interface_off_is_one_line_with_its_fix(fc):
    """Add FurCollide turns Render > Lock Interface on (renders from the UI could crash
    while the handler writes hair): a fresh setup draws no warning. Turned off, one line
    says so beside the button that turns it on again."""
    scene = bpy.context.scene
    scene.render.use_lock_interface = False
    hair, box, out = small_setup(fc)
    assert scene.render.use_lock_interface
    activate(hair)
    main = draw_everything()["FURCOLLIDE_PT_main"]
    assert _warning_rows(main) == [] and not entries(main, "prop", "use_lock_interface")
    scene.render.use_lock_interface = False
    main = draw_everything()["FURCOLLIDE_PT_main"]
    pm = _panel_module()
    assert _warning_rows(main) == [(pm.LOCK_WARNING, "furcollide.lock_interface",
                                    "Lock Interface")]
    assert bpy.ops.furcollide.lock_interface() == {"FINISHED"}
    assert scene.render.use_lock_interface
    assert _warning_rows(draw_everything()["FURCOLLIDE_PT_main"]) == []


def test_playback_sync_other_than_every_frame_is_one_line_with_its_fix(fc):
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    activate(hair)
    pm = _panel_module()
    for sync in ("AUDIO_SYNC", "FRAME_DROP"):
        scene.sync_mode = sync
        main = draw_everything()["FURCOLLIDE_PT_main"]
        assert _warning_rows(main) == [(pm.SYNC_WARNING, "furcollide.play_every_frame",
                                        "Play Every Frame")], sync
    # the button beside the warning, pressed: Sync is Play Every Frame and playback
    # solves every frame again
    ((_, idname, _),) = _warning_rows(main)
    mod, _, op = idname.partition(".")
    assert getattr(getattr(bpy.ops, mod), op)() == {"FINISHED"}
    assert scene.sync_mode == "NONE"
    assert _warning_rows(draw_everything()["FURCOLLIDE_PT_main"]) == []
    with pytest.raises(RuntimeError, match="already"):  # (nothing to fix: greyed)
        bpy.ops.furcollide.lock_interface()


def test_following_the_hint_as_written_sets_up_the_hair_with_its_colliders(fc):
    """"Select the colliders, then Shift-click the hair last": clicked as a user does
    (each click selects and makes active; Shift adds), the hair is active, the panel
    offers Add FurCollide, and Add takes both colliders (not the hair) in the list."""
    hair, box = fc.make_scene()
    box2 = make_box("Box2", location=(0.5, 0.5, 0.6))
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    vl = bpy.context.view_layer
    for ob in (box, box2, hair):  # click, Shift-click, Shift-click
        ob.select_set(True)
        vl.objects.active = ob
    main = draw_everything()["FURCOLLIDE_PT_main"]
    assert " ".join(labels(main)) == _panel_module().HINT
    assert entries(main, "operator", "furcollide.add")
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    s = hair.furcollide
    assert s.is_setup and [c.object for c in s.colliders] == [box, box2]
    # the other way round (the hair first) the active object is a collider: no tab
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    hair, box = fc.make_scene()
    vl = bpy.context.view_layer
    for ob in (hair, box):
        ob.select_set(True)
        vl.objects.active = ob
    assert draw_everything()["FURCOLLIDE_PT_main"] is None


def _all_states(fc, tmp_path):
    """Yields the draw logs of every panel in the states a setup goes through (no setup; fresh,
    with a collider selected; an error; Soft with Shrink; wind, jiggle and the Region of
    Influence off; a render groom and the output's modifier; a partial bake; baked;
    outdated; the scene's warnings), each checked before the next state: a new file
    removes the data a log holds)."""
    scene = bpy.context.scene
    hair, box = fc.make_scene()
    activate(hair, box)
    yield draw_everything()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    hair, box, out = small_setup(fc)
    s = hair.furcollide
    play(scene, range(1, 4))
    yield draw_everything()
    s.attract_to_growth_surface = True  # an error: no Surface
    scene.frame_set(4)
    yield draw_everything()
    s.attract_to_growth_surface = False
    s.mode, s.shrink = "SOFT", True
    m = s.motion
    m.use_wind = m.use_jiggle = m.write_collider_distance = True
    m.use_region_of_influence = False
    s.groom.groom = make_hair("Groom", nx=3, ny=3)
    out.modifiers.new("Noise", "NODES")
    scene.render.use_lock_interface = False
    scene.sync_mode = "AUDIO_SYNC"
    activate(hair)
    yield draw_everything()
    scene.render.use_lock_interface, scene.sync_mode = True, "NONE"
    s.mode, s.shrink = "BEND", False
    m.use_wind = m.use_jiggle = m.write_collider_distance = False
    out.modifiers.clear()
    save_in(tmp_path)
    s.bake_path = "//furcollide_cache/partial/"
    yield draw_everything()
    s.bake_path = ""
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    box.rotation_euler.z += 0.3
    scene.frame_set(4)
    yield draw_everything()


def test_every_name_and_line_fits_the_sidebar_at_its_default_width(fc, tmp_path):
    """Measured with Blender's UI font at UI scale 1 in a sidebar of the default width
    (``ui/text.py``; its limits were read off Blender 4.3's screenshots, which
    ``tests/app`` takes): a setting's name beside its field, a checkbox's text, every
    choice of a menu button, every label line, every button's text; a one-line warning
    and its button side by side."""
    t = _text()
    ctx = bpy.context
    assert t.ui_scale(ctx) == 1.0 and t.region_width(ctx) == t.SIDEBAR_WIDTH
    width = t.text_width
    row_width = t.line_width(ctx, icon=False)
    too_wide = []

    def check(what, text, limit):
        if text and width(ctx, text) > limit:
            too_wide.append(f"{what}: {text!r} {width(ctx, text):.0f} > {limit:.0f} px")

    for logs in _all_states(fc, tmp_path):
        for panel, log in logs.items():
            if log is None or "_MT_" in panel or panel == "FURCOLLIDE_PT_presets":
                continue  # (a menu is as wide as its entries)
            buttons = {}
            for e in log:
                if e.get("list_item") is not None:
                    continue  # (the colliders list: names of the user's objects)
                if e["kind"] in ("prop", "prop_search"):
                    prop = e["data"].bl_rna.properties[e["name"]]
                    text = prop.name if e["text"] is None else e["text"]
                    if prop.type == "ENUM" and not getattr(prop, "is_enum_flag", False):
                        for item in prop.enum_items:
                            check(f"{panel} {e['name']} choice", item.name, t.MENU_TEXT)
                    if not e["split"]:
                        check(f"{panel} {e['name']}", text,
                              t.line_width(ctx, box=e["boxes"] > 0, icon=True))
                    elif prop.type == "BOOLEAN":
                        check(f"{panel} {e['name']} (checkbox)", text, t.CHECKBOX_TEXT)
                    else:
                        check(f"{panel} {e['name']}", text,
                              t.SPLIT_LABEL_BOX if e["boxes"] else t.SPLIT_LABEL)
                elif e["kind"] == "label" and not e["in_split"]:
                    check(f"{panel} label", e["text"],
                          t.line_width(ctx, box=e["boxes"] > 0, icon=e["icon"] not in (
                              None, "NONE")))
                elif e["kind"] == "operator" and not e["in_split"]:
                    buttons.setdefault(e["layout"], []).append(e)
            for row in buttons.values():
                share = t.line_width(ctx, box=row[0]["boxes"] > 0, icon=False) / len(row)
                for e in row:
                    mod, _, op = e["name"].partition(".")
                    text = (e["text"] if e["text"] is not None else
                            getattr(getattr(bpy.ops, mod), op).get_rna_type().name)
                    icon = t.ICON if e["icon"] else 0
                    check(f"{panel} {e['name']} (button)", text,
                          share - icon - t.BUTTON_PADDING)
            for label, _op, button in _warning_rows(log):
                need = (width(ctx, label) + t.ICON + 8 + width(ctx, button)
                        + t.BUTTON_PADDING)
                if need > row_width:
                    too_wide.append(f"{panel} warning {label!r} [{button}]: {need:.0f} px")
    assert not too_wide, "\n".join(sorted(set(too_wide)))


def test_every_keyable_setting_shows_its_keyframe_decorator(fc, tmp_path):
    """A setting that can be keyed, drawn as a setting (its name in the label column),
    has the keyframe dot beside it; one drawn with its whole name (a box's title
    checkbox) has its own decorator."""
    missing = []
    for logs in _all_states(fc, tmp_path):
        for panel, log in logs.items():
            own = {(id(e["data"]), e["name"]) for e in log or [] if e["kind"] ==
                   "prop_decorator"}
            for e in log or []:
                if e["kind"] != "prop" or e.get("list_item") is not None:
                    continue
                if not e["data"].bl_rna.identifier.lower().startswith("furcollide"):
                    continue
                prop = e["data"].bl_rna.properties[e["name"]]
                if not prop.is_animatable or prop.is_readonly or prop.type in (
                        "STRING", "POINTER", "COLLECTION"):
                    continue
                if e["text"] == "" and not e["split"]:
                    continue  # (a header's checkbox: Shrink, as Blender's own headers)
                shown = (e["split"] and e["decorate"]) or (id(e["data"]), e["name"]) in own
                if not shown:
                    missing.append(f"{panel}: {e['name']}")
    assert not missing, sorted(set(missing))


def test_sections_open_as_registered(fc):
    """The main panel, Colliders, Resolution, Recovery & Plasticity (the paper's
    signature control) and Cache open; Shrink, Pinch, Per-Curve Enable, Last Frame and
    Fur Pipeline closed; no sub-panel is titled like a setting."""
    panels, _, _ = _ui_classes()
    sidebar = [c for c in panels if getattr(c, "bl_region_type", "") == "UI"]
    closed = {c.__name__ for c in sidebar if "DEFAULT_CLOSED" in getattr(c, "bl_options", ())}
    assert closed == {"FURCOLLIDE_PT_shrink", "FURCOLLIDE_PT_pinch", "FURCOLLIDE_PT_enable",
                      "FURCOLLIDE_PT_stats", "FURCOLLIDE_PT_pipeline"}, closed
    titles = {c.bl_label for c in sidebar}
    names = {p.name for rna in property_groups() for p in rna.properties}
    # (Colliders lists the colliders and Shrink's header is the Shrink checkbox: the same
    # thing; "Resolution" titled a section and labelled the pinch setting)
    assert titles & names == {"Colliders", "Shrink"}, titles & names


def test_remove_asks_first(fc):
    """From a button or a menu (invoke), Remove shows Blender's confirmation; only
    confirming runs it (a script's call runs at once)."""
    hair, box, out = small_setup(fc)
    activate(hair)
    asked = []

    class WM:
        def invoke_confirm(self, op, event, **kw):
            asked.append(kw)
            return {"RUNNING_MODAL"}

    class Ctx:
        window_manager = WM()
        object = hair
        scene = bpy.context.scene

    op_cls = bpy.types.FURCOLLIDE_OT_remove
    got = op_cls.invoke(Bound(op_cls, None), Ctx(), None)
    assert got == {"RUNNING_MODAL"} and hair.furcollide.is_setup  # nothing removed yet
    (kw,) = asked
    assert kw["title"] == op_cls.CONFIRM and kw["confirm_text"] == "Remove"
    assert out.name in kw["message"] and kw["icon"] == "WARNING"
    # the keywords and the icon are those Blender's own invoke_confirm takes
    params = bpy.types.WindowManager.bl_rna.functions["invoke_confirm"].parameters
    assert set(kw) <= set(params.keys()), set(kw) - set(params.keys())
    assert kw["icon"] in params["icon"].enum_items.keys()


def test_object_menu_entry_comes_and_goes_with_the_add_on(fc):
    hair, box, out = small_setup(fc)
    activate(hair)
    menu_module = sys.modules[ADDON + ".ui.menu"]
    funcs = bpy.types.VIEW3D_MT_object.draw._draw_funcs
    assert menu_module.draw_object_menu in funcs
    log = []
    menu_module.draw_object_menu(Bound(bpy.types.VIEW3D_MT_object,
                                       RnaLayout(log, bpy.context)), bpy.context)
    assert [e["name"] for e in log if e["kind"] == "menu"] == ["FURCOLLIDE_MT_object"]
    sub = draw_rna(bpy.types.FURCOLLIDE_MT_object, header=False)
    assert [e["name"] for e in sub if e["kind"] == "operator"] == [
        "furcollide.add", "furcollide.bake", "furcollide.free_bake", "furcollide.remove"]
    assert bpy.ops.preferences.addon_disable(module=ADDON) == {"FINISHED"}
    try:
        assert menu_module.draw_object_menu not in bpy.types.VIEW3D_MT_object.draw._draw_funcs
        assert not hasattr(bpy.types, "FURCOLLIDE_MT_object")
    finally:
        assert bpy.ops.preferences.addon_enable(module=ADDON) == {"FINISHED"}
    menu_module = sys.modules[ADDON + ".ui.menu"]
    assert menu_module.draw_object_menu in bpy.types.VIEW3D_MT_object.draw._draw_funcs


def test_object_menu_entries_run_on_the_active_hair(fc, tmp_path):
    """Object > FurCollide, each entry pressed in turn as a user would (the hair active,
    its collider selected): Add sets it up, Bake bakes, Free Bake frees, Remove (once
    confirmed) removes the setup and its output."""
    hair, box = fc.make_scene(frames=(1, 6), nx=4, ny=4)
    activate(hair, box)
    save_in(tmp_path)
    sub = draw_rna(bpy.types.FURCOLLIDE_MT_object, header=False)
    add, bake, free, remove = (e["name"] for e in sub if e["kind"] == "operator")

    def press(idname, **kw):
        mod, _, op = idname.partition(".")
        return getattr(getattr(bpy.ops, mod), op)("EXEC_DEFAULT", **kw)

    assert press(add) == {"FINISHED"}
    s = hair.furcollide
    out_name = s.output.name
    assert s.is_setup and [c.object for c in s.colliders] == [box]
    assert press(bake) == {"FINISHED"} and s.is_baked
    assert press(free) == {"FINISHED"} and not s.is_baked
    assert press(remove) == {"FINISHED"}  # (a click confirms first: test_remove_asks_first)
    assert not s.is_setup and out_name not in bpy.data.objects


def _meaning(prop_id):
    """A setting's meaning: its identifier, without the owner it sits under (Wind's and
    Jiggle's Falloff, Stage and Seed are the same setting of each motion; the Collider
    Collection's Double Sided is a collider's); each setting's Map (the line under it)
    is one meaning: the parameter map of the setting above."""
    if prop_id.endswith("_map"):
        return "map"
    for owner in ("wind_", "jiggle_", "collection_"):
        if prop_id.startswith(owner):
            return prop_id[len(owner):]
    return prop_id


def test_every_drawn_name_means_one_thing(fc, tmp_path):
    """In every state, a name drawn for a setting names one setting (the same setting of
    another owner, e.g. a collider's own Offset, is the same meaning), and no setting is
    named like a section ("Resolution" was both the section and Pinch's method)."""
    panels, _, _ = _ui_classes()
    titles = {c.bl_label for c in panels}
    meanings = {}
    for logs in _all_states(fc, tmp_path):
        for log in logs.values():
            for e in log or []:
                if e["kind"] not in ("prop", "prop_search") or e.get("list_item") is not None:
                    continue
                prop = e["data"].bl_rna.properties[e["name"]]
                text = prop.name if e["text"] is None else e["text"]
                if text:
                    meanings.setdefault(text, set()).add(_meaning(e["name"]))
    shared = {k: v for k, v in meanings.items() if len(v) > 1}
    assert not shared, shared
    # (Colliders lists the colliders; Shrink's header is the Shrink checkbox)
    assert set(meanings) & titles <= {"Colliders", "Shrink"}, set(meanings) & titles


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
