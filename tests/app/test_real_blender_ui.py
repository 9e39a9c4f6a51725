"""The sidebar drawn by the real Blender application in every state, and undo (app lane).

``ui_driver.py`` runs in one session of Debian's Blender 4.3 with its UI under Xvfb (the
chroot of ``scripts/blender_chroot.sh``, as ``test_real_blender.py``): it re-registers the
add-on's panels open, counts every ``draw`` Blender itself calls per state (no setup, a
fresh setup, played, an error, outdated, the scene's warnings (Lock Interface off,
Sync dropping frames: a label and its button on one line, measured with Blender's font
at the real sidebar's width), Lock Interface on, baked, an outdated bake, no output)
and keeps any exception raised while drawing; then it undoes and redoes Add
FurCollide and a setting change, playing frames after each. The headless ``bpy`` lanes
cannot do either: panels are not drawn there and undo needs a window
(``tests/blender/test_bl_panels.py`` draws them into an RNA-checking recorder instead).
"""


import pytest
from app_session import ROOT, assert_ran_to_the_end, run_session

WORK = ROOT / "out" / "app_ui"
STATES = ("no_setup", "setup", "played", "error", "outdated", "scene_warnings",
          "lock_interface_on", "baked", "baked_outdated", "no_output")
#: Panels drawn once a setup exists (their poll needs one).
SETUP_PANELS = ("FURCOLLIDE_PT_colliders", "FURCOLLIDE_PT_resolution", "FURCOLLIDE_PT_shrink",
                "FURCOLLIDE_PT_recovery", "FURCOLLIDE_PT_pinch", "FURCOLLIDE_PT_enable",
                "FURCOLLIDE_PT_cache", "FURCOLLIDE_PT_stats")


@pytest.fixture(scope="module")
def session():
    return run_session(WORK, "ui_driver.py", timeout=600)


def test_session_ran_to_the_end_without_a_crash(session):
    assert_ran_to_the_end(session, WORK)


def test_every_panel_draws_in_every_state_without_an_error(session):
    r = session["result"]
    assert r["draw_errors"] == [], "\n".join(r["draw_errors"])[:4000]
    # Blender prints an exception raised in a draw() with its traceback
    assert "Traceback" not in session["log"], session["log"][-4000:]
    drawn = {}
    for key, n in r["draws"].items():
        state, what = key.split("|")
        if n > 0:
            drawn.setdefault(state, set()).add(what)
    for state in STATES:
        assert "FURCOLLIDE_PT_main.draw" in drawn.get(state, ()), (state, sorted(drawn))
    assert "FURCOLLIDE_PT_pipeline.draw" in drawn["no_setup"]
    for state in ("setup", "played", "error", "outdated", "baked", "baked_outdated"):
        for panel in SETUP_PANELS:
            assert f"{panel}.draw" in drawn[state], (state, panel)
        assert "FURCOLLIDE_UL_colliders.draw_item" in drawn[state], state
        assert "FURCOLLIDE_PT_shrink.draw_header" in drawn[state], state
        assert "FURCOLLIDE_PT_main.draw_header_preset" in drawn[state], state
    every = set().union(*drawn.values())
    for name in r["ui_classes"]:  # (the presets popover draws only when clicked)
        if name.startswith(("FURCOLLIDE_PT_", "FURCOLLIDE_UL_")) and "presets" not in name:
            assert any(w.startswith(name + ".") for w in every), name


def test_the_states_were_what_they_claim(session):
    r = session["result"]
    assert r["error_status"][0] == "ERROR" and "Surface" in r["error_status"][1]
    assert r["outdated"] is True
    assert r["baked"] is True and r["baked_outdated"] is True


def test_undo_and_redo_of_add_and_of_a_setting(session):
    """README "Limits": undo restores the output's data, not the playback cache (press
    Reset Cache). Undoing Add FurCollide removes the setup and its output; redoing
    brings both back and, after Reset Cache, playing solves again; a setting change
    undone is back to its old value; no handler error and no draw error on the way."""
    r = session["result"]
    assert r["undo_added"] == {"is_setup": True, "output": True}
    assert r["undo_undone"]["is_setup"] is False and r["undo_undone"]["output"] is False
    assert r["undo_undone"]["hidden"] is False  # the source is shown again
    red = r["undo_redone"]
    assert red["is_setup"] is True and red["output"] is True and red["reset"] == ["FINISHED"]
    assert red["moved"] > 0.01, red  # the box pushed the hair: it was solved again
    assert red["status"][0] == "INFO", red
    assert r["undo_mode_after"] == "BEND"
    assert r["undo_final_status"][0] == "INFO", r["undo_final_status"]
    assert r["undo_handler_errors"] == [] and r["undo_draw_errors"] == []
