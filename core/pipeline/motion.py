"""Procedural wind and simple secondary motion (paper section 4).

Both are pure functions of their inputs and the frame: no hidden state, so
scrubbing the timeline gives the same motion. Either can run before
FurCollide (on its input curves) or after it, through
:func:`~core.pipeline.region_of_influence`.
"""

from __future__ import annotations

import math

import numpy as np

from .. import tolerances as tol
from ..curves import arc_length, check_curves, layout, rechain
from ..errors import InputError
from ..rays import in_two, thread_count

#: Sinusoids summed per noise channel.
_WAVES = 4


def _number(name, v, lo=None, lo_open=False):
    if isinstance(v, bool):
        raise InputError(f"{name} must be a number, got {v!r}")
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {v!r}") from None
    if not math.isfinite(v):
        raise InputError(f"{name} must be finite, got {v!r}")
    if lo is not None and (v < lo or (lo_open and v == lo)):
        raise InputError(f"{name} must be {'>' if lo_open else '>='} {lo}, got {v!r}")
    return v


def _weights(points, off, falloff):
    """Root-to-tip weight ``s ** falloff`` per point (0 at roots, 1 at tips)."""
    s, _ = arc_length(points, off)
    w = s**falloff
    w[off[:-1]] = 0.0
    return w


def _displace(points, off, disp, preserve_length):
    moved = points + disp
    moved[off[:-1]] = points[off[:-1]]
    if preserve_length:
        return rechain(points, off, moved)
    return moved


def wind_noise(x, t, seed=0, scale=1.0, frequency=1.0, channels=4):
    """Coherent noise in space and time: a sum of seeded travelling sinusoids.

    Parameters
    ----------
    x : (k, 3) ndarray of float64
        Positions.
    t : float
        Time, seconds.
    seed : int
    scale : float
        Spatial wavelength of the patterns (world units).
    frequency : float
        Temporal frequency (Hz) of the patterns.
    channels : int
        Independent noise channels.

    Returns
    -------
    (k, channels) ndarray of float64
        Zero-mean, unit-variance (over space and time), smooth in both.
    """
    rng = np.random.default_rng([int(seed), 0x57494E44])
    n = channels * _WAVES
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    k = dirs * (2 * np.pi / scale) * rng.uniform(0.5, 1.5, n)[:, None]
    f = 2 * np.pi * frequency * rng.uniform(0.5, 1.5, n)
    phase = rng.uniform(0, 2 * np.pi, n)
    # one contiguous row per wave (long passes), summed wave by wave per channel
    xt = np.ascontiguousarray(np.asarray(x, np.float64).T)
    arg = np.empty((n, len(x)))
    for i in range(n):
        a = arg[i]
        np.multiply(xt[0], k[i, 0], out=a)
        a += xt[1] * k[i, 1]
        a += xt[2] * k[i, 2]
        a += f[i] * t + phase[i]
    np.sin(arg, out=arg)
    out = np.empty((len(x), channels))
    for c in range(channels):
        w = arg[c * _WAVES:(c + 1) * _WAVES]
        acc = w[0] + w[1]
        for j in range(2, _WAVES):
            acc += w[j]
        out[:, c] = acc
    return out * math.sqrt(2.0 / _WAVES)


def wind(points, offsets, frame, direction=(1.0, 0.0, 0.0), strength=0.1, frequency=0.5,
         turbulence=0.5, falloff=1.5, seed=0, scale=1.0, fps=24.0, preserve_length=True,
         threads=None):
    """Procedural wind: gusts and turbulence from coherent noise, growing root to tip.

    Each curve is pushed by ``strength * (d * (1 + turbulence * g) +
    turbulence * n)``, where ``d`` is the unit wind direction, ``g`` (gusts)
    and ``n`` (a 3-vector of turbulence) are coherent noise evaluated at the
    curve's root and time ``frame / fps``; CV ``j`` gets that push times
    ``s_j ** falloff`` (``s`` the normalized arc length: 0 at the root, 1 at
    the tip). Deterministic: the same frame gives the same result.

    Parameters
    ----------
    points : (P, 3) array_like of float
    offsets : (C+1,) array_like of int
    frame : float
        Scene frame (fractional frames allowed: motion blur, subframes).
    direction : (3,) array_like
        Wind direction (normalized here; zero means turbulence only).
    strength : float
        Push at the tip, world units (0 = no wind: the input is returned).
    frequency : float
        Gust frequency, Hz.
    turbulence : float
        Relative amount of gusts and side-to-side turbulence (0 = steady push).
    falloff : float
        Exponent of the root-to-tip ramp (>= 0; 1 = linear, larger = only
        the tips move).
    seed : int
        Noise seed.
    scale : float
        Size of the gust patterns (world units, > 0).
    fps : float
        Frames per second.
    preserve_length : bool
        Re-chain the moved curve keeping every segment's length (the curve
        bends instead of stretching).
    threads : int or None, default None
        Threads to use (None: every CPU). From ``tolerances.SPLIT_MIN_ITEMS``
        curves the work runs in parts, one per thread; the result is the
        same bit for bit (every curve's wind is its own).

    Returns
    -------
    (P, 3) ndarray of float64
        Roots are unchanged.
    """
    pts, off = check_curves(points, offsets)
    frame = _number("frame", frame)
    strength = _number("strength", strength, 0)
    frequency = _number("frequency", frequency, 0)
    turbulence = _number("turbulence", turbulence, 0)
    falloff = _number("falloff", falloff, 0)
    scale = _number("scale", scale, 0, lo_open=True)
    fps = _number("fps", fps, 0, lo_open=True)
    d = np.asarray(direction, np.float64)
    if d.shape != (3,) or not np.isfinite(d).all():
        raise InputError(f"direction must be 3 finite numbers, got {direction!r}")
    threads = thread_count(threads)
    if strength == 0:
        return pts.copy()
    nd = np.linalg.norm(d)
    d = d / nd if nd > 0 else d
    out = np.empty_like(pts)

    def blow(c0, c1):  # curves c0:c1
        a, b = off[c0], off[c1]
        p, o = pts[a:b], off[c0:c1 + 1] - a
        g = wind_noise(p[o[:-1]], frame / fps, seed, scale, frequency)
        push = strength * (d[None] * (1 + turbulence * g[:, :1]) + turbulence * g[:, 1:])
        curve, _, _ = layout(o)
        disp = _weights(p, o, falloff)[:, None] * push[curve]
        out[a:b] = _displace(p, o, disp, preserve_length)

    in_two(blow, len(off) - 1, threads, tol.SPLIT_MIN_ITEMS)
    return out


def spring_impulse_response(tau, stiffness, damping):
    """Unit-impulse response of ``y'' + 2 z w y' + w^2 y = delta`` at times ``tau``.

    ``w = 2 pi stiffness`` (Hz -> rad/s), ``z = damping``.
    """
    w = 2 * np.pi * stiffness
    z = damping
    tau = np.asarray(tau, np.float64)
    if z < 1:
        wd = w * math.sqrt(1 - z * z)
        return np.exp(-z * w * tau) * np.sin(wd * tau) / wd
    if z == 1:
        return tau * np.exp(-w * tau)
    r = math.sqrt(z * z - 1)
    s1, s2 = -w * (z - r), -w * (z + r)
    return (np.exp(s1 * tau) - np.exp(s2 * tau)) / (s1 - s2)


def jiggle(points, offsets, roots, frame=None, fps=24.0, stiffness=2.0, damping=0.3,
           amount=1.0, falloff=1.0, window=None, preserve_length=True):
    """Simple secondary motion: curves lag and overshoot when their roots accelerate.

    The tip offset ``y`` of each curve is the response of a damped spring
    to its root's acceleration ``a``: ``y'' + 2 z w y' + w^2 y = -a``,
    computed as a finite impulse response over the last ``window`` frames
    of root motion, so the result at frame ``f`` is a pure function of the
    roots at frames ``f - window .. f`` (scrubbing gives the same motion).
    CV ``j`` moves by ``amount * s_j ** falloff * y``. Uniform motion
    (constant velocity) gives no jiggle.

    Parameters
    ----------
    points : (P, 3) array_like of float
        This frame's curves (e.g. after Fur Attach).
    offsets : (C+1,) array_like of int
    roots : (N, C, 3) array_like, or callable
        Root positions over the window, oldest first, the last row being
        this frame (N >= 3); or ``roots(frame) -> (C, 3)`` evaluated at
        frames ``frame - window .. frame``.
    frame : float, optional
        Current frame; needed when ``roots`` is callable.
    fps : float
        Frames per second.
    stiffness : float
        Natural frequency of the spring, Hz (> 0). Higher = stiffer, faster.
    damping : float
        Damping ratio (>= 0): 0 oscillates forever (within the window), 1
        is critically damped (no overshoot).
    amount : float
        Multiplier of the offset (0 = no jiggle).
    falloff : float
        Exponent of the root-to-tip ramp (>= 0).
    window : int, optional
        Frames of history with a callable ``roots`` (default: until the
        response has decayed to 0.1 %, at most 240).
    preserve_length : bool
        Keep every segment's length (re-chain).

    Returns
    -------
    (P, 3) ndarray of float64
    """
    pts, off = check_curves(points, offsets)
    fps = _number("fps", fps, 0, lo_open=True)
    stiffness = _number("stiffness", stiffness, 0, lo_open=True)
    damping = _number("damping", damping, 0)
    amount = _number("amount", amount)
    falloff = _number("falloff", falloff, 0)
    C = len(off) - 1
    if callable(roots):
        if frame is None:
            raise InputError("jiggle: frame is needed when roots is a callable")
        frame = _number("frame", frame)
        if window is None:
            decay = damping * 2 * np.pi * stiffness / fps
            window = 240 if decay <= 0 else min(240, max(3, math.ceil(math.log(1000) / decay)))
        if isinstance(window, bool) or int(window) != window or window < 2:
            raise InputError(f"window must be an integer >= 2, got {window!r}")
        N = int(window) + 1

        def row(j):  # frame j of the window, oldest first
            return roots(frame - (N - 1 - j))
    else:
        hist = np.asarray(roots, np.float64)
        if hist.ndim != 3 or hist.shape[1:] != (C, 3) or len(hist) < 3:
            raise InputError(f"roots history must have shape (N >= 3, {C}, 3), got {hist.shape}")
        if not np.isfinite(hist).all():  # bad input raises even with amount 0
            i = int(np.argmax(~np.isfinite(hist).all(axis=(0, 2))))
            raise InputError(f"roots history of curve {i} is not finite")
        N = len(hist)

        def row(j):
            return hist[j]
    if amount == 0:
        return pts.copy()
    dt = 1.0 / fps
    # y = -sum_j h_j a_j over the central second differences a_j = (r_{j+1} - 2 r_j +
    # r_{j-1}) / dt^2 at j = 1 .. N-2 equals -sum_j c_j r_j / dt^2 with c the second
    # difference of h (h = 0 outside): the frames are summed one at a time, so memory
    # stays (C, 3) whatever the window.
    lag = (N - 2 - np.arange(N - 2)) * dt  # frame j lags N-1-j frames, j = 1..N-2
    h = np.zeros(N + 2)
    h[2:N] = spring_impulse_response(lag, stiffness, damping) * dt  # h[j + 1] = h_j
    c = h[:-2] - 2 * h[1:-1] + h[2:]  # (N,)
    # c sums to 0: positions relative to the current roots give the same y without
    # cancelling large coordinates.
    y = np.zeros((C, 3))
    ref = None
    for j in range(N - 1, -1, -1):
        r = np.asarray(row(j), np.float64)
        if r.shape != (C, 3):
            raise InputError(f"roots history must have shape (N >= 3, {C}, 3), got a frame "
                             f"of shape {r.shape}")
        if not np.isfinite(r).all():
            i = int(np.argmax(~np.isfinite(r).all(axis=1)))
            raise InputError(f"roots history of curve {i} is not finite")
        if ref is None:
            ref = r
        elif c[j] != 0:
            y -= c[j] * (r - ref)
    y /= dt**2
    curve, _, _ = layout(off)
    disp = (amount * _weights(pts, off, falloff))[:, None] * y[curve]
    return _displace(pts, off, disp, preserve_length)
