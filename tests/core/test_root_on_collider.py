"""A root resting on a collider (a floor, just outside its clearance margin) never
counts as a contact of its own: roots never move, so only the segments' far ends
and sides are tested there (README "Pinch": a root inside is a pinch). A one-segment
curve that must turn away from a ball turns alike in Stiff, Bend and Soft (one
segment: the same smallest clearing angle), however close its root is to the floor."""

from __future__ import annotations

import numpy as np
import oracle
import pytest
import scenes

from core import Collider, Settings, Solver, Status


@pytest.mark.parametrize("margins", [2.0, 3.0, 40.0])
def test_a_one_segment_curve_rooted_on_a_floor_turns_alike_in_every_mode(margins):
    Vb, Fb = scenes.box([-1, -1, -1], [1, 1, 0])  # the floor: its top face at z = 0
    floor = Collider(Vb, Fb)
    root = np.array([0.0, 0.0, margins * floor.margin])
    pts, offs = scenes.pack([scenes.straight_curve(root, [0.6, 0, 0.8], 1.0, 2)])
    Vs, Fs = scenes.uv_sphere([0.45, 0.05, 0.6], 0.2, 24, 12)
    assert oracle.segments_hit_mesh(pts, offs, Vs, Fs)[0]
    out = {}
    for mode in ("stiff", "bend", "soft"):
        res = Solver(offs, Settings(mode=mode)).step(pts, [floor, Collider(Vs, Fs)])
        assert np.asarray(res.status)[0] == Status.COLLIDING, mode
        np.testing.assert_array_equal(res.points[0], pts[0])
        for V, F in ((Vs, Fs), (Vb, Fb)):
            assert not oracle.segments_hit_mesh(res.points, offs, V, F)[0], mode
        out[mode] = res.points
    np.testing.assert_allclose(out["soft"], out["stiff"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(out["bend"], out["stiff"], rtol=0, atol=1e-12)


@pytest.mark.parametrize("mode", ["stiff", "bend"])
@pytest.mark.parametrize("margins", [1.05, 1.5, 4.0])
def test_a_root_on_a_floor_is_no_contact_with_shrink(mode, margins):
    """With Shrink each probe's rays are grown from its shrunk segments: the root
    segment still is not grown backward (into the floor under its root, just outside
    the clearance margin), so a curve rooted on the floor that must turn away from a
    ball turns and clears. (Growing the second segment's start instead of the root's
    leaves the curve unresolved at 1.05 and 1.5 margins: a mutant of ``_rays``.)"""
    Vb, Fb = scenes.box([-1, -1, -1], [1, 1, 0])
    floor = Collider(Vb, Fb)
    root = np.array([0.0, 0.0, margins * floor.margin])
    pts, offs = scenes.pack([scenes.straight_curve(root, [0.6, 0, 0.8], 1.0, 4)])
    Vs, Fs = scenes.uv_sphere([0.45, 0.05, 0.6], 0.2, 24, 12)
    assert oracle.segments_hit_mesh(pts, offs, Vs, Fs)[0]
    res = Solver(offs, Settings(mode=mode, shrink=True)).step(pts, [floor, Collider(Vs, Fs)])
    assert np.asarray(res.status)[0] == Status.COLLIDING
    np.testing.assert_array_equal(res.points[0], pts[0])
    for V, F in ((Vs, Fs), (Vb, Fb)):
        assert not oracle.segments_hit_mesh(res.points, offs, V, F)[0]
