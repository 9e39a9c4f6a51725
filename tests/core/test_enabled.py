"""The enabled mask (paper 5): disabled curves keep their prior local state."""

from __future__ import annotations

import geom
import numpy as np
import scenes
import strategies as strat
from geom import FAST
from hypothesis import given
from hypothesis import strategies as st

from core import Collider, Settings, Solver, Status


def _scene():
    rng = np.random.default_rng(21)
    pts, offs = scenes.fur_on_plane(rng, n_curves=20, curly=0.2, extent=0.5, n_cvs=(3, 8))
    V, F = scenes.uv_sphere([0.0, 0.0, 0.9], 0.4, 24, 12)
    return pts, offs, V, F


def _curve(p, offs, c):
    return p[offs[c]:offs[c + 1]]


def test_disabled_without_state_is_input():
    pts, offs, V, F = _scene()
    C = len(offs) - 1
    enabled = np.arange(C) % 2 == 0
    for mode in ("stiff", "bend", "soft"):
        res = Solver(offs, Settings(mode=mode)).step(pts, [Collider(V, F)], enabled=enabled)
        status = np.asarray(res.status)
        assert np.all(status[~enabled] == Status.DISABLED)
        assert not np.any(status[enabled] == Status.DISABLED)
        for c in np.nonzero(~enabled)[0]:
            assert np.array_equal(_curve(res.points, offs, c), _curve(pts, offs, c))
        # enabled ones are solved as without a mask (to rounding: the core
        # chains segments with one cumulative sum over the whole batch)
        full = Solver(offs, Settings(mode=mode)).step(pts, [Collider(V, F)])
        assert np.array_equal(status[enabled], np.asarray(full.status)[enabled])
        for c in np.nonzero(enabled)[0]:
            np.testing.assert_allclose(_curve(res.points, offs, c), _curve(full.points, offs, c),
                                       rtol=0, atol=1e-12)
        geom.assert_no_intersection(res.points, offs, status, [(V, F)])


def test_disabled_keeps_prior_state_then_resumes():
    pts, offs, V, F = _scene()
    C = len(offs) - 1
    for mode in ("stiff", "bend", "soft"):
        solver = Solver(offs, Settings(mode=mode, recovery_rate=1.0))
        r1 = solver.step(pts, [Collider(V, F)])
        hit = np.asarray(r1.status) == Status.COLLIDING
        assert hit.sum() >= 3
        off = np.ones(C, bool)
        off[np.nonzero(hit)[0][:2]] = False
        # frame 2: collider gone; disabled curves hold the frame-1 pose,
        # the others recover (rate 1) to the input
        r2 = solver.step(pts, [], enabled=off)
        for c in range(C):
            want = _curve(r1.points if not off[c] else pts, offs, c)
            np.testing.assert_allclose(_curve(r2.points, offs, c), want, atol=1e-12,
                                       err_msg=f"{mode} curve {c}")
        # frame 3: re-enabled, they recover now
        r3 = solver.step(pts, [], enabled=np.ones(C, bool))
        assert np.array_equal(r3.points, pts)


def test_disabled_state_follows_input_animation():
    """The held state is local: when the input curve moves rigidly (growth
    surface animation), the held deformation moves with it."""
    pts, offs, V, F = _scene()
    solver = Solver(offs, Settings(mode="bend"))
    r1 = solver.step(pts, [Collider(V, F)])
    C = len(offs) - 1
    shift = np.array([0.3, -0.2, 0.1])
    r2 = solver.step(pts + shift, [], enabled=np.zeros(C, bool))
    assert np.all(np.asarray(r2.status) == Status.DISABLED)
    np.testing.assert_allclose(r2.points, r1.points + shift, atol=1e-9)


def test_enabled_all_true_equals_no_mask():
    pts, offs, V, F = _scene()
    C = len(offs) - 1
    a = Solver(offs, Settings()).step(pts, [Collider(V, F)], enabled=np.ones(C, bool))
    b = Solver(offs, Settings()).step(pts, [Collider(V, F)])
    assert np.array_equal(a.points, b.points)
    assert np.array_equal(np.asarray(a.status), np.asarray(b.status))


@FAST
@given(fur=st.lists(strat.curves(extent=0.5, n_cvs=(3, 8)), min_size=1, max_size=20),
       mode=st.sampled_from(["stiff", "bend", "soft"]), n_frames=st.integers(2, 6),
       rate=st.floats(0.0, 1.0), data=st.data())
def test_random_masks_over_frames(fur, mode, n_frames, rate, data):
    """Static input, a moving ball, a random enabled mask per frame: a
    disabled curve shows exactly its previous frame's output; every enabled
    curve keeps the invariants."""
    pts, offs = scenes.pack(fur)
    V, F = scenes.uv_sphere([0, 0, 0], 0.35, 24, 12)
    col = Collider(V, F)
    C = len(offs) - 1
    solver = Solver(offs, Settings(mode=mode, recovery_rate=rate))
    prev = pts.copy()
    for f in range(n_frames):
        M = scenes.translation([0.15 * f - 0.3, 0.0, 0.9])
        col.matrix = M
        enabled = np.array(data.draw(st.lists(st.booleans(), min_size=C, max_size=C),
                                     label=f"enabled {f}"))
        r = solver.step(pts, [col], enabled=enabled)
        status = np.asarray(r.status)
        assert np.all((status == Status.DISABLED) == ~enabled)
        for c in np.nonzero(~enabled)[0]:
            np.testing.assert_allclose(_curve(r.points, offs, c), _curve(prev, offs, c),
                                       atol=1e-12, err_msg=f"frame {f} curve {c}")
        geom.assert_no_intersection(r.points, offs, status, [(scenes.world_vertices(
            dict(V=V, matrix=M)), F)])
        geom.assert_roots_exact(pts, r.points, offs)
        prev = r.points
