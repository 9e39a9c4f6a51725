"""What the real application's viewport evaluates from the output of spline hair (app lane).

``curves_driver.py`` runs in one session of Debian's Blender 4.3 with its UI under Xvfb
(the chroot of ``scripts/blender_chroot.sh``, as ``test_real_blender.py``): a groom of
Catmull-Rom and Bezier hairs pressed by a ball, a Resample Curve modifier (and Trim Hair
Curves where the hair assets ship) on the output, played in the viewport and stepped
with the arrow keys' operator. The bpy lanes have no viewport playback (``screen.animation_play``).
"""


import pytest
from app_session import ROOT, assert_ran_to_the_end, run_session

WORK = ROOT / "out" / "app_curves"


@pytest.fixture(scope="module")
def session():
    return run_session(WORK, "curves_driver.py", timeout=900)


def test_session_ran_to_the_end_without_a_crash(session):
    r = assert_ran_to_the_end(session, WORK)
    # (after the add-on's own; Debian's Blender ships no hair assets: Trim Hair Curves
    # only where it does)
    assert "Resample" in r["modifiers"]


def test_the_viewport_evaluates_each_frame_solved(session):
    """After playback and at every arrow-key step: the output's Resample and Trim give
    what they give on a fresh copy of its curves (no shape of an earlier frame)."""
    checks = session["result"]["checks"]
    assert [c["how"] for c in checks][:1] == ["played"] and len(checks) == 5
    for c in checks:
        assert c["same_layout"] and c["max_difference"] <= 1e-6, c


def test_the_drawn_curves_clear_the_ball(session):
    checks = session["result"]["checks"]
    assert max(c["colliding"] for c in checks) > 20  # the ball is in the fur
    for c in checks:
        assert c["crossing_curves"] == 0, c
