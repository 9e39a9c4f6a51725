"""FurCollide in the real Blender application, with its UI (the app lane).

One session of Debian's Blender 4.3.2 (Python 3.13, numpy 2.x, its own system Embree)
runs under Xvfb in the chroot of ``scripts/blender_chroot.sh``. ``blender_driver.py``
drives it from ``bpy.app.timers``; this module builds the cp313 zip, runs the session
once (module fixture, ~2 minutes) and asserts on what it reported, on its exit code,
on the absence of a crash log, and on the screenshots it left in ``out/app/shots/``.
"""


import pytest
from app_session import ROOT, assert_ran_to_the_end, run_session

WORK = ROOT / "out" / "app"
CHECK_FRAMES = ("6", "12", "18", "24")


@pytest.fixture(scope="module")
def session():
    """Build (or reuse) the chroot and the cp313 zip, run one Blender UI session."""
    return run_session(WORK, "blender_driver.py", timeout=1200,
                       env_vars="FC_APP_CURVES=50000")


def test_blender_exits_cleanly_without_a_crash(session):
    r = assert_ran_to_the_end(session, WORK, tail=6000)
    assert r["blender"].startswith("4.3") and r["python"].startswith("3.13")
    assert r["numpy"].startswith("2.")


def test_the_cp313_zip_installs_and_enables(session):
    r = session["result"]
    assert r["install_return"] == ["FINISHED"] and r["enabled"] is True
    assert r["module_file"].startswith("/work/user/extensions/user_default/furcollide/")
    # the bundled cp313 embreex wheel, not anything of the system, is what loaded
    assert "/extensions/.local/lib/python3.13/site-packages/embreex/" in r["embreex_file"]
    assert r["embree_available"] is True, r["embree_error"]


def test_paper_scale_setup(session):
    r = session["result"]
    assert (r["curves"], r["points"]) == (50000, 400000)
    assert r["collider_triangles"] >= 130000
    assert r["add_return"] == ["FINISHED"] and r["colliders"] == ["Ball", "Blob"]
    assert r["sidebar_tab"] == "FurCollide" and r["panel_registered"]


def test_no_crossings_on_baked_frames_rigid_and_deforming(session):
    """Frames 6 and 12: the rigid Ball moves in; 18 and 24: the Blob deforms in."""
    r = session["result"]
    assert r["baked"] is True
    for f, c in r["baked_crossings"].items():
        assert c["segments_near"] > 1000, (f, c)  # the colliders are in the fur
        assert c["crossing_curves"] == 0, (f, c)
    assert sorted(r["baked_crossings"]) == sorted(CHECK_FRAMES)
    assert r["source_untouched"] is True


def test_modal_bake_shows_progress_and_esc_cancels(session):
    r = session["result"]
    assert r["bake_invoke_return"] == ["RUNNING_MODAL"]
    done, total = r["progress_before_esc"]
    assert 0 < done < total == 24
    assert r["xdotool_rc"] == 0, r["xdotool_err"]
    # Esc (a real X key event) cancelled it: not running, not baked, finished frames kept
    assert r["running_after_esc"] is False and r["baked_after_esc"] is False
    kept = r["files_after_esc"]
    assert done <= len(kept) < total and kept[0] == "frame_000001.npz"
    # the second bake resumed and finished
    assert r["resume_return"] == ["RUNNING_MODAL"] and r["baked"] is True
    assert len(r["files_done"]) == 24


def test_playback_steps_every_frame(session):
    """Playing fires a depsgraph update with the animated colliders when it starts:
    it is not an edit, so every frame is solved and cached (it used to drop the cache,
    and every frame after the first said 'not cached')."""
    r = session["result"]
    assert r["played_to"] == 24
    bad = {f: s for f, s in r["statuses"].items() if s and s[0] != "INFO"}
    assert not bad, bad
    assert r["cached_after_play"] == list(range(1, 25))
    for f, c in r["crossings"].items():
        assert c["crossing_curves"] == 0, (f, c)


def test_arrow_keys_show_cached_frames(session):
    """The arrow keys fire a depsgraph update of the new frame before its frame
    handlers: the frames come from the cache, nothing is dropped."""
    scrub = session["result"]["scrub"]
    assert [s["frame"] for s in scrub] == [23, 22, 21, 22], scrub
    for s in scrub:
        assert s["source"] == "cache" and s["cached"] == 24 and s["status"][0] == "INFO", s


def test_children_from_guides_says_why_without_hair_assets(session):
    """Debian's Blender ships no hair node assets (removed from the +dfsg source)."""
    c = session["result"]["children"]
    if c["assets"]:
        assert c.get("return") == ["FINISHED"], c
    else:
        assert "hair node assets" in c["error"] and "were not found" in c["error"], c


def test_screenshots_of_the_sidebar_panel(session):
    shots = sorted((WORK / "shots").glob("*.png"))
    names = [p.name for p in shots]
    assert names == ["1_panel_after_add.png", "2_panel_after_playback.png",
                     "3_panel_baking_progress.png", "4_panel_after_esc.png",
                     "5_panel_baked.png"], names
    for p in shots:
        assert p.stat().st_size > 50_000, p  # a real 1600x900 screen, not a black frame
