"""The sidebar drawn by the real Blender application in every state, and undo (app lane).

``ui_driver.py`` runs in one session of Debian's Blender 4.3 with its UI under Xvfb (the
chroot of ``scripts/blender_chroot.sh``, as ``test_real_blender.py``): it re-registers the
add-on's panels open, counts every ``draw`` Blender itself calls per state (no setup, a
fresh setup, played, an error, outdated, Lock Interface on, baked, an outdated bake, no
output) and keeps any exception raised while drawing; then it undoes and redoes Add
FurCollide and a setting change, playing frames after each. The headless ``bpy`` lanes
cannot do either: panels are not drawn there and undo needs a window
(``tests/blender/test_bl_panels.py`` draws them into an RNA-checking recorder instead).
"""

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
from scripts import package as pkg  # noqa: E402

WORK = ROOT / "out" / "app_ui"
CHROOT = ROOT / "scripts" / "blender_chroot.sh"
STATES = ("no_setup", "setup", "played", "error", "outdated", "lock_interface_on", "baked",
          "baked_outdated", "no_output")
#: Panels drawn once a setup exists (their poll needs one).
SETUP_PANELS = ("FURCOLLIDE_PT_colliders", "FURCOLLIDE_PT_resolution", "FURCOLLIDE_PT_shrink",
                "FURCOLLIDE_PT_recovery", "FURCOLLIDE_PT_pinch", "FURCOLLIDE_PT_enable",
                "FURCOLLIDE_PT_cache", "FURCOLLIDE_PT_stats")


@pytest.fixture(scope="module")
def session():
    if os.geteuid() != 0:
        pytest.fail("the real-Blender lane needs root (debootstrap, chroot, mount)")
    built = subprocess.run([str(CHROOT), "build"], capture_output=True, text=True, timeout=3000)
    if built.returncode != 0:
        pytest.fail(f"the Blender chroot could not be prepared:\n{built.stderr[-3000:]}")
    shutil.rmtree(WORK, ignore_errors=True)
    (WORK / "tmp").mkdir(parents=True)
    try:
        (res,) = pkg.build(platforms=["linux-x64"], pythons=["3.13"], output_dir=WORK)
    except pkg.PackageError as err:
        pytest.fail(f"packaging the cp313 zip failed: {err}")
    zip_path = Path(res["zip"])
    shutil.copy2(Path(__file__).with_name("ui_driver.py"), WORK / "ui_driver.py")
    inner = (
        "cd /work && blender -b --factory-startup --python-expr "
        "'import bpy; bpy.ops.wm.save_as_mainfile(filepath=\"/work/start.blend\")' >/dev/null"
        " && env TMPDIR=/work/tmp BLENDER_USER_RESOURCES=/work/user"
        " xvfb-run -a -s '-screen 0 1600x900x24 +extension GLX'"
        " blender /work/start.blend -p 0 0 1600 900 --python /work/ui_driver.py"
        f" -- /work/{zip_path.name} /work"
    )
    env = dict(os.environ, FURCOLLIDE_CHROOT_BIND=str(WORK))
    try:
        proc = subprocess.run([str(CHROOT), "run", "sh", "-c", inner], capture_output=True,
                              text=True, timeout=600, env=env)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"the Blender session did not finish in 10 minutes: {exc}")
    log = proc.stdout + "\n--- stderr ---\n" + proc.stderr
    (WORK / "blender.log").write_text(log)
    result_file = WORK / "result.json"
    result = json.loads(result_file.read_text()) if result_file.is_file() else {}
    return {"rc": proc.returncode, "log": log, "result": result}


def test_session_ran_to_the_end_without_a_crash(session):
    assert session["rc"] == 0, session["log"][-4000:]
    assert not list((WORK / "tmp").glob("*.crash.txt"))
    r = session["result"]
    assert r.get("finished") and not r.get("errors"), r.get("errors") or session["log"][-4000:]
    assert r["install_return"] == ["FINISHED"] and r["enabled"] is True


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
    assert r["undo_mode_after"] == "bend"
    assert r["undo_final_status"][0] == "INFO", r["undo_final_status"]
    assert r["undo_handler_errors"] == [] and r["undo_draw_errors"] == []
