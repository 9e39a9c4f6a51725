"""The user guide against the registered add-on (real ``bpy``, the add-on enabled).

* every name the user guide writes in bold is a setting, a choice or a button of the
  registered add-on (their RNA names, or the text a panel draws them with), or one of the
  few words the guide stresses that are no setting (``NOT_SETTINGS``);
* every operator a page names (``furcollide.<name>``) is registered;
* every setting and button the panels draw, in the states a setup goes through, is named
  in bold in the user guide. The panels are drawn headless into ``helpers.RnaLayout``
  (``tests/blender/helpers.py``), which records each ``prop`` and ``operator`` call.
"""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
GUIDE = ROOT / "docs" / "user-guide.md"
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BLENDER_TESTS = ROOT / "tests" / "blender"


def _blender_conftest():
    """tests/blender/conftest.py (the add-on registered from the checkout): the module
    pytest loaded, or loaded here when only tests/docs runs."""
    path = (BLENDER_TESTS / "conftest.py").resolve()
    for mod in list(sys.modules.values()):
        f = getattr(mod, "__file__", None)
        if f and Path(f).resolve() == path:
            return mod
    if str(BLENDER_TESTS) not in sys.path:
        sys.path.insert(0, str(BLENDER_TESTS))
    spec = importlib.util.spec_from_file_location("furcollide_blender_conftest", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


_conftest = _blender_conftest()  # (skips this module where bpy is missing)
furcollide_addon = _conftest.furcollide_addon  # module-scoped, autouse: the add-on enabled
clean_scene = _conftest.clean_scene  # autouse: every test from an empty scene
fc = _conftest.fc

import bpy  # noqa: E402
from helpers import ADDON, activate, draw_rna, make_hair, small_setup  # noqa: E402

pytestmark = pytest.mark.blender

#: Words the user guide writes in bold that are not a setting, a choice or a button.
NOT_SETTINGS = {
    "source", "output", "recover", "pinched", "outdated", "unresolved",
    "children output", "Shift-click the hair last", "Play Every Frame",
    "Bake before rendering", "Turn on Render › Lock Interface",
    "Colliders that render otherwise than the viewport",
    "A source with other curves in renders", "A hat with thickness",
    "A hat or hood made of one sheet", "Which Mode.", "Collision Offset.",
    "Collide the guides, make the children on the output",
    "Make the children on the source.", "curve count changes every frame",
    "What drops the cache.", "Messages.", "Saving", "The source's curve count changed",
    "A baked setup only reads.", "Undo", "Save As", "Memory.", "Placeholder.",
    "Short Fur (Stiff)", "Long Fur (Bend)", "Tight Cloth Contact (Soft)", "Grass Trampling",
    "+", "FurCollide Inputs",
}
_BOLD = re.compile(r"\*\*(.+?)\*\*", re.S)
_OPERATOR = re.compile(r"(?<![\w.])(?:bpy\.ops\.)?furcollide\.([a-z_]+)\b(?!\.)")


def bold_names(text: str) -> set[str]:
    """The bold spans of ``text`` (code blocks left out), whitespace normalized."""
    text = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    return {" ".join(m.split()) for m in _BOLD.findall(text)}


def guide_bold() -> set[str]:
    return bold_names(GUIDE.read_text(encoding="utf-8"))


def _ui_panels():
    ui = sys.modules[ADDON + ".ui"]
    return [c for c in ui.classes
            if issubclass(c, bpy.types.Panel) and getattr(c, "bl_region_type", "") == "UI"]


def drawn_names(logs) -> dict[str, str]:
    """{label: what} of every setting and button in the panels' draw logs: the text it
    is drawn with, else its RNA name (a setting's, or an operator's label)."""
    out = {}
    for log in logs:
        for e in log or []:
            if e["kind"] in ("prop", "prop_search"):
                rna = e["data"].bl_rna.properties[e["name"]]
                label = e["text"] or rna.name
                out[label] = f"{e['data'].bl_rna.identifier}.{e['name']}"
            elif e["kind"] == "operator":
                mod, _, op = e["name"].partition(".")
                label = e["text"] or getattr(getattr(bpy.ops, mod), op).get_rna_type().name
                out[label] = e["name"]
    return out


def draw_all():
    """Every FurCollide panel of the sidebar drawn for the active object (None: its poll
    refuses)."""
    return [draw_rna(cls) for cls in _ui_panels()]


def property_groups():
    """The RNA of the add-on's property groups: ``Object.furcollide``,
    ``Scene.furcollide_pipeline`` and the groups they hold (colliders, motion, render
    groom, children)."""
    todo = [bpy.types.Object.bl_rna.properties["furcollide"].fixed_type,
            bpy.types.Scene.bl_rna.properties["furcollide_pipeline"].fixed_type]
    seen = {}
    while todo:
        rna = todo.pop()
        if rna.identifier in seen:
            continue
        seen[rna.identifier] = rna
        for p in rna.properties:
            t = getattr(p, "fixed_type", None)
            if p.type in ("POINTER", "COLLECTION") and t is not None and (
                    t.identifier.lower().startswith("furcollide")):
                todo.append(t)
    assert {"FurCollideSettings", "FurCollideCollider", "FurCollideMotion", "FurCollideGroom",
            "FurCollideChildren", "FURCOLLIDE_PG_pipeline"} <= set(seen), sorted(seen)
    return list(seen.values())


def registered_names(logs) -> set[str]:
    """Every name of the registered add-on a user can meet in the panels: its settings'
    RNA names and choices, its operators' labels, and the text the panels draw them with."""
    names = set(drawn_names(logs))
    names |= {e["text"] for log in logs for e in log or [] if e["kind"] == "label"}  # boxes
    for rna in property_groups():
        for p in rna.properties:
            names.add(p.name)
            if p.type == "ENUM":
                names |= {item.name for item in p.enum_items}
    for op in dir(bpy.ops.furcollide):
        names.add(getattr(bpy.ops.furcollide, op).get_rna_type().name)
    names.add(bpy.types.RenderSettings.bl_rna.properties["use_lock_interface"].name)
    return names


def _states(fc):
    """Draw logs of the panels in the states a setup goes through: no setup; a setup
    with a collider selected in the list; a partial bake; Soft mode with Shrink, wind and
    jiggle; a render groom chosen and the output carrying a modifier (the children
    box), the scene rendering unlocked and dropping frames (its warnings)."""
    logs = []
    hair, box = fc.make_scene()
    activate(hair, box)
    logs += draw_all()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    hair, box, out = small_setup(fc)
    s = hair.furcollide
    s.collider_index = 0
    logs += draw_all()
    s.bake_path = "//furcollide_cache/partial/"  # a partial bake: Free Partial
    logs += draw_all()
    s.bake_path = ""
    s.mode, s.shrink = "SOFT", True
    s.motion.use_wind = s.motion.use_jiggle = True
    s.motion.wind_stage = "OUTPUT"
    logs += draw_all()
    s.groom.groom = make_hair("Groom", nx=3, ny=3)
    out.modifiers.new("Noise", "NODES")
    scene = bpy.context.scene  # (the scene's warnings and their buttons)
    scene.render.use_lock_interface, scene.sync_mode = False, "AUDIO_SYNC"
    activate(hair)
    logs += draw_all()
    return logs


def test_every_operator_a_page_names_is_registered():
    registered = set(dir(bpy.ops.furcollide))
    for page in PAGES:
        for name in _OPERATOR.findall(page.read_text(encoding="utf-8")):
            assert name in registered, f"{page.name}: furcollide.{name} is not an operator"


def test_every_name_the_user_guide_stresses_is_a_setting_choice_or_button(fc):
    known = registered_names(_states(fc))
    unknown = sorted(n for n in guide_bold() if n not in known and n not in NOT_SETTINGS)
    assert not unknown, (
        "bold in docs/user-guide.md but no setting, choice or button of the add-on "
        f"(rename it, or add a word that is no setting to NOT_SETTINGS): {unknown}")


def test_every_setting_and_button_the_panels_draw_is_in_the_user_guide(fc):
    drawn = drawn_names(_states(fc))
    bold = guide_bold()
    missing = sorted(f"{label} ({what})" for label, what in drawn.items() if label not in bold)
    assert not missing, f"drawn in a panel, not named in bold in docs/user-guide.md: {missing}"


def test_the_states_draw_what_the_guide_documents(fc):
    """The drawn states reach the settings that only some states show (a collider's own
    options, the children box, the render groom box)."""
    drawn = drawn_names(_states(fc))
    for label in ("Own Offset", "Clear Children", "Clear in Viewport", "Guides per Curve",
                  "Add FurCollide", "Fur Sampler", "Min Scale", "Lock Interface"):
        assert label in drawn, label
