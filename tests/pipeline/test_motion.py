"""Wind and jiggle: deterministic per frame, roots fixed, falloff, lengths kept."""

from __future__ import annotations

import numpy as np
import pipe_oracle as po
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core.errors import InputError
from core.pipeline import jiggle, wind, wind_noise

PROP = settings(max_examples=examples(15))


def _fur(seed=0, n=25, cvs=6):
    return po.fur_on_plane(np.random.default_rng(seed), n, cvs, 0.6)


def _seg_len(p, off):
    A, B, _ = po.segments(p, off)
    return np.linalg.norm(B - A, axis=1)


@PROP
@given(frame=st.floats(-100, 1000), seed=st.integers(0, 99), turb=st.floats(0, 2),
       falloff=st.floats(0, 4))
def test_wind_deterministic_roots_fixed_lengths_kept(frame, seed, turb, falloff):
    pts, off = _fur(seed)
    kw = dict(direction=(1, 0.5, 0), strength=0.3, turbulence=turb, falloff=falloff, seed=seed)
    a = wind(pts, off, frame, **kw)
    b = wind(pts.copy(), off, frame, **kw)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a[off[:-1]], pts[off[:-1]])
    np.testing.assert_allclose(_seg_len(a, off), _seg_len(pts, off), rtol=1e-12)


def test_zero_wind_is_identity():
    pts, off = _fur()
    np.testing.assert_array_equal(wind(pts, off, 12, strength=0.0), pts)


@PROP
@given(frame=st.floats(0, 500), falloff=st.floats(0.1, 4))
def test_falloff_monotone_root_to_tip(frame, falloff):
    pts, off = _fur(3)
    out = wind(pts, off, frame, strength=0.4, falloff=falloff, preserve_length=False)
    m = np.linalg.norm(out - pts, axis=1)
    for i in range(len(off) - 1):
        c = m[off[i]:off[i + 1]]
        assert c[0] == 0
        assert (np.diff(c) >= -1e-15).all()


def test_wind_blows_along_direction_and_changes_over_time():
    pts, off = _fur(4)
    tips = off[1:] - 1
    out = wind(pts, off, 10, direction=(0, 1, 0), strength=0.3, turbulence=0.0,
               preserve_length=False)
    np.testing.assert_allclose((out - pts)[tips], np.tile([0, 0.3, 0], (len(tips), 1)),
                               atol=1e-12)
    a = wind(pts, off, 10, strength=0.3, turbulence=1.0)
    b = wind(pts, off, 10.5, strength=0.3, turbulence=1.0)
    c = wind(pts, off, 40, strength=0.3, turbulence=1.0)
    small = np.abs(a - b).max()
    assert 0 < small < np.abs(a - c).max()  # coherent in time: half a frame moves little


def test_noise_is_coherent_in_space():
    rng = np.random.default_rng(0)
    x = rng.uniform(-2, 2, (2000, 3))
    n0 = wind_noise(x, 1.0)
    n1 = wind_noise(x + 0.01, 1.0)
    n2 = wind_noise(x + 1.7, 1.0)
    assert abs(n0.std() - 1) < 0.35
    assert np.abs(n0 - n1).mean() < 0.1 * np.abs(n0 - n2).mean()


def _history(C, f, pos):
    """(N, C, 3) root history: the roots of curve i at frames f[k] are pos(f[k]) + i."""
    return np.stack([np.tile(pos(t), (C, 1)) + np.arange(C)[:, None] * [1, 0, 0] for t in f])


def test_jiggle_zero_for_uniform_motion():
    pts, off = _fur(5)
    C = len(off) - 1
    f = np.arange(30.0)
    hist = _history(C, f, lambda t: np.array([0.1 * t, -0.05 * t, 0.02 * t]))
    out = jiggle(pts, off, hist, stiffness=1.5, damping=0.2)
    np.testing.assert_allclose(out, pts, atol=1e-10)


def test_jiggle_lags_behind_acceleration_and_overshoots():
    pts, off = _fur(6)
    C = len(off) - 1
    tips = off[1:] - 1

    def pos(t):  # at rest until frame 20, then constant velocity +x (a velocity step)
        return np.array([max(t - 20.0, 0.0) * 0.05, 0, 0])

    disp = []
    for frame in (22, 26, 30, 34, 38):
        f = np.arange(frame - 40, frame + 1, dtype=float)
        out = jiggle(pts, off, _history(C, f, pos), stiffness=1.0, damping=0.2,
                     preserve_length=False)
        np.testing.assert_array_equal(out[off[:-1]], pts[off[:-1]])
        disp.append((out - pts)[tips, 0].mean())
    assert disp[0] < 0  # the tips lag behind the acceleration
    assert max(disp) > 0  # and overshoot later
    assert np.abs(disp).max() > 1e-3


def test_jiggle_callable_equals_history_and_scrubbing():
    pts, off = _fur(7)
    C = len(off) - 1

    def roots(t):
        return np.tile([np.sin(t * 0.3), 0, 0.1 * np.cos(t * 0.2)], (C, 1))

    for frame in (50, 13, 50):  # scrub back and forth: pure function of the frame
        hist = np.stack([roots(frame - k) for k in range(24, -1, -1)])
        a = jiggle(pts, off, roots, frame=frame, window=24)
        b = jiggle(pts, off, hist)
        np.testing.assert_array_equal(a, b)
        assert np.abs(a - pts).max() > 1e-4
        np.testing.assert_allclose(_seg_len(a, off), _seg_len(pts, off), rtol=1e-12)


def test_bad_input():
    pts, off = _fur(8)
    with pytest.raises(InputError, match="strength"):
        wind(pts, off, 1, strength=-1)
    with pytest.raises(InputError, match="direction"):
        wind(pts, off, 1, direction=(1, 0))
    with pytest.raises(InputError, match="roots history"):
        jiggle(pts, off, np.zeros((5, 3, 3)))
    C = len(off) - 1
    hist = np.zeros((5, C, 3))
    hist[2, 1, 0] = np.nan
    with pytest.raises(InputError, match="curve 1 is not finite"):
        jiggle(pts, off, hist, amount=0)
    with pytest.raises(InputError, match="frame"):
        jiggle(pts, off, lambda f: 0)


def _spring_rk4(acc, t0, t1, stiffness, damping, substeps=4, dt=None):
    """The README's spring written out, nothing from core: integrate
    ``y'' + 2 z w y' + w^2 y = -a(t)`` (``w = 2 pi stiffness``, ``z = damping``) from rest
    at ``t0`` to ``t1`` with classical Runge-Kutta; ``acc(t) -> (C, 3)``."""
    w, z = 2 * np.pi * stiffness, damping
    n = int(round((t1 - t0) / dt)) * substeps
    h = (t1 - t0) / n
    y = np.zeros_like(acc(t0))
    v = np.zeros_like(y)

    def f(t, y, v):
        return v, -acc(t) - 2 * z * w * v - w * w * y

    t = t0
    for _ in range(n):
        k1y, k1v = f(t, y, v)
        k2y, k2v = f(t + h / 2, y + h / 2 * k1y, v + h / 2 * k1v)
        k3y, k3v = f(t + h / 2, y + h / 2 * k2y, v + h / 2 * k2v)
        k4y, k4v = f(t + h, y + h * k3y, v + h * k3v)
        y = y + h / 6 * (k1y + 2 * k2y + 2 * k3y + k4y)
        v = v + h / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)
        t += h
    return y


@pytest.mark.parametrize("damping", [0.0, 0.2, 1.0, 2.5])
@pytest.mark.parametrize("stiffness", [0.7, 2.0])
def test_jiggle_is_the_damped_spring_of_the_readme(stiffness, damping):
    """README "Wind and secondary motion": the tip offset follows the damped spring
    ``y'' + 2 z w y' + w^2 y = -a`` driven by the root's acceleration, and CV ``j`` moves
    by ``amount * s_j ** falloff * y``. The oracle integrates that equation (Runge-Kutta,
    the roots' acceleration known exactly) for roots that start from rest and swing
    differently per curve and axis; sampled at 480 fps, jiggle's finite impulse
    response must agree to 0.5 % of the largest offset (all damping regimes)."""
    pts, off = _fur(11, n=4, cvs=5)
    C = len(off) - 1
    fps, t0 = 480.0, 0.0
    amp = np.random.default_rng(5).normal(0, 20.0, (C, 3))  # roots move about 0.1
    T = 0.15

    def root(t):  # rest until t0, then r = amp (t - t0)^3 exp(-(t - t0) / T): C2 at t0
        u = np.maximum(np.asarray(t, float) - t0, 0.0)
        return amp * (u**3 * np.exp(-u / T))

    def acc(t):
        u = max(t - t0, 0.0)
        e = np.exp(-u / T)
        return amp * (6 * u - 6 * u * u / T + u**3 / T**2) * e

    n = int(1.2 * fps)  # 1.2 s of history: the response has not decayed at damping 0
    frames = np.arange(n + 3) - 2  # two frames at rest before t0
    t_end = frames[-1] / fps
    hist = np.stack([np.tile(root(f / fps)[None], (1, 1, 1))[0] for f in frames])
    hist = hist + pts[off[:-1]]
    falloff, amount = 1.7, 0.8
    out = jiggle(pts, off, hist, fps=fps, stiffness=stiffness, damping=damping,
                 amount=amount, falloff=falloff, preserve_length=False)
    y = _spring_rk4(acc, t0, t_end, stiffness, damping, dt=1 / fps)
    assert np.abs(y).max() > 1e-4  # the roots really accelerated
    disp = out - pts
    tol = 5e-3 * np.abs(y).max()
    for c in range(C):
        P = pts[off[c]:off[c + 1]]
        L = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
        s_j = L / L[-1]
        want = amount * s_j[:, None] ** falloff * y[c]
        np.testing.assert_allclose(disp[off[c]:off[c + 1]], want, atol=tol * amount,
                                   err_msg=f"curve {c}")
    # constant velocity gives no jiggle, whatever the speed
    moving = pts[off[:-1]][None] + (frames / fps)[:, None, None] * amp[None]
    still = jiggle(pts, off, moving, fps=fps, stiffness=stiffness, damping=damping,
                   preserve_length=False)
    np.testing.assert_allclose(still, pts, atol=1e-9)


def test_jiggle_ignores_far_translations():
    """Moving everything 1e6 units away changes nothing but the position."""
    pts, off = _fur(9)
    C = len(off) - 1
    rng = np.random.default_rng(3)
    hist = np.cumsum(rng.normal(scale=0.01, size=(30, C, 3)), axis=0)
    fps, k, z = 24.0, 1.3, 0.25
    out = jiggle(pts, off, hist, fps=fps, stiffness=k, damping=z, preserve_length=False)
    assert np.abs(out - pts).max() > 1e-4
    far = np.array([1e6, -1e6, 1e6])
    moved = jiggle(pts + far, off, hist + far, fps=fps, stiffness=k, damping=z,
                   preserve_length=False)
    np.testing.assert_allclose(moved - far, out, atol=1e-6)
