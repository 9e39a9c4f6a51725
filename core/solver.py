"""The FurCollide solver (paper sections 3.1-3.2 and 5).

One :meth:`Solver.step` is one frame: it takes that frame's *input* curves
(already moving with the growth surface) and the colliders, and returns
curves that no longer pass through the colliders.

How a curve is deformed
-----------------------
Every output curve is its input curve with each segment rotated (and, with
Shrink, scaled) and the segments re-chained from the root::

    out[0] = in[0]
    out[j + 1] = out[j] + scale_j * R_j @ (in[j + 1] - in[j])

so roots never move and lengths are kept unless Shrink says otherwise.

* Stiff: ``R_j = R(axis, theta)`` for every segment.
* Bend: ``R_j = R(axis, theta * (j + 1) / n)`` (uniform bend root to tip).
* Soft: one quaternion per segment, built up from the colliding segments'
  own rotations (each dragging ``affected_connected_cvs`` following
  segments with ``cv_falloff``).

The per-curve state (``theta``, its axis, soft quaternions) is stored in a
*local frame* carried along with the input curve, so it follows the
animated growth surface; the axis is chosen at the first hit and kept
until the curve has recovered (no pops when hit normals change).

Searching the angle
-------------------
The smallest clearing rotation on the Rotation Precision grid is found by
galloping (1, 2, 4, ... steps) then bisecting, for all colliding curves at
once: every probe round is a single batched ray query. Where clearance is
monotone in the angle (the usual case) this is exactly what stepping by
Rotation Precision gives; otherwise it is a clearing angle within one step
of a transition.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from . import rotations as rot
from . import tolerances as tol
from .collider import Collider
from .errors import InputError, SettingsError
from .rays import default_threads
from .settings import Settings

_STATE_VERSION = 1


class Status(IntEnum):
    """Per-curve outcome of a step (``StepResult.status`` values)."""

    FREE = 0  #: not in contact, shape unchanged this frame
    COLLIDING = 1  #: in contact: rotated to clear, or recovery blocked
    RECOVERING = 2  #: clear, rotating back toward its input shape
    PINCHED = 3  #: root inside a closed collider (not solved, see pinch_resolution)
    UNRESOLVED = 4  #: could not be cleared within max_angle: last collision-free state kept
    DISABLED = 5  #: switched off by ``enabled``: prior local state kept


@dataclass
class StepResult:
    """What :meth:`Solver.step` returns.

    Attributes
    ----------
    points : (P, 3) ndarray
        Resolved positions, world space, the input's dtype.
    status : (C,) int8 ndarray
        :class:`Status` code per curve.
    timings : dict
        Milliseconds per phase (for benchmarks and the panel's stats).
    """

    points: np.ndarray
    status: np.ndarray
    timings: dict = field(default_factory=dict)

    def count(self, status: Status) -> int:
        """Number of curves with ``status``."""
        return int(np.count_nonzero(self.status == status))


def _check_offsets(offsets) -> np.ndarray:
    try:
        off = np.asarray(offsets)
    except Exception as exc:
        raise InputError(f"offsets must be a 1-D integer array: {exc}") from None
    if off.ndim != 1 or len(off) < 2:
        raise InputError(f"offsets must be a 1-D array of C+1 >= 2 integers, got shape {off.shape}")
    if not np.issubdtype(off.dtype, np.integer):
        raise InputError(f"offsets must be integers, got dtype {off.dtype}")
    off = off.astype(np.int64)
    if off[0] != 0:
        raise InputError(f"offsets must start at 0, got {int(off[0])}")
    sizes = np.diff(off)
    if (sizes < 2).any():
        i = int(np.argmax(sizes < 2))
        if sizes[i] <= 0:
            raise InputError(f"offsets must increase: curve {i} has {int(sizes[i])} points")
        raise InputError(f"curve {i} has only 1 point; every curve needs at least 2")
    return off


def _gallop_bisect(n, test, k_max, lo=None, hi=None, width=4, stride=None):
    """Smallest integer ``k`` in ``(lo, k_max]`` with ``test`` true, per item.

    A ``width``-ary gallop-then-bisect: each round probes ``width`` values
    per unsettled item (galloping: ``lo + stride * 1, 2, 4, ...``; once a good
    probe is known: evenly inside the bracket) and calls ``test`` once for all
    of them, i.e. one batched ray query per round. Where ``test`` is monotone
    the result is exactly the first good ``k``; otherwise it is a good ``k``
    right after a bad one.

    Parameters
    ----------
    n : int
        Number of items.
    test : callable(items (m,) int, ks (m,) int) -> (m,) bool
        ``items`` may repeat (several probes of one item).
    k_max : (n,) int
        Largest admissible ``k``.
    lo : (n,) int, optional
        Known bad ``k`` (default 0).
    hi : (n,) int, optional
        Known good ``k`` (-1 = unknown: gallop first).
    width : int
        Probes per item per round.
    stride : (n,) int, optional
        First gallop stride (default 1).

    Returns
    -------
    (n,) int
        The good ``k`` found, -1 where none up to ``k_max``.
    """
    lo = np.zeros(n, np.int64) if lo is None else np.asarray(lo, np.int64).copy()
    hi = np.full(n, -1, np.int64) if hi is None else np.asarray(hi, np.int64).copy()
    stride = np.ones(n, np.int64) if stride is None else np.maximum(stride, 1).astype(np.int64)
    k_max = np.broadcast_to(np.asarray(k_max, np.int64), (n,))
    ladder = 2 ** np.arange(width)
    frac = np.arange(1, width + 1) / (width + 1)
    for _ in range(128):  # bounded: each round multiplies the stride or divides the bracket
        gallop = (hi < 0) & (lo < k_max)
        bisect = (hi >= 0) & (hi - lo > 1)
        items = np.flatnonzero(gallop | bisect)
        if len(items) == 0:
            break
        g = gallop[items][:, None]
        l, h = lo[items][:, None], hi[items][:, None]
        probes = np.where(
            g,
            np.minimum(l + stride[items][:, None] * ladder, k_max[items][:, None]),
            np.clip(l + np.ceil((h - l) * frac).astype(np.int64), l + 1, h),
        )
        good = test(np.repeat(items, width), probes.ravel()).reshape(len(items), width)
        anyg = good.any(axis=1)
        first = np.argmax(good, axis=1)
        rows = np.arange(len(items))
        k_first = probes[rows, first]
        k_before = np.where(first > 0, probes[rows, np.maximum(first - 1, 0)], lo[items])
        hit_i = items[anyg]
        hi[hit_i] = k_first[anyg]
        lo[hit_i] = k_before[anyg]
        miss_i = items[~anyg]
        lo[miss_i] = probes[~anyg, -1]
        stride[miss_i] *= 2**width
    return hi


class Solver:
    """Frame-by-frame FurCollide solver for one set of curves.

    Parameters
    ----------
    offsets : (C+1,) array_like of int
        Curve ``i`` is ``points[offsets[i]:offsets[i + 1]]`` (Blender's
        layout). Every curve needs at least 2 points.
    settings : Settings, optional
        Default ``Settings()``.

    Examples
    --------
    >>> solver = Solver(offsets, Settings(mode="bend"))
    >>> res = solver.step(points, [Collider(V, F)])
    >>> res.points, res.status
    """

    def __init__(self, offsets, settings: Settings | None = None):
        off = _check_offsets(offsets)
        self._off = off
        self.n_curves = C = len(off) - 1
        self.n_points = int(off[-1])
        nseg = np.diff(off) - 1
        self._nseg = nseg
        self._soff = np.concatenate([[0], np.cumsum(nseg)])
        is_last = np.zeros(self.n_points, bool)
        is_last[off[1:] - 1] = True
        self._seg_start = np.flatnonzero(~is_last)
        self._curve_end = off[1:-1] - 1  # point-difference rows that span two curves
        self._seg_curve = np.repeat(np.arange(C), nseg)
        seg_j = np.arange(len(self._seg_start)) - self._soff[self._seg_curve]
        self._w_bend = (seg_j + 1) / nseg[self._seg_curve]
        self._seg_j = seg_j
        self._settings = Settings() if settings is None else self._check_settings(settings)
        self.reset()

    # ------------------------------------------------------------ settings
    @staticmethod
    def _check_settings(s):
        if not isinstance(s, Settings):
            raise SettingsError(f"settings must be a core.Settings, got {type(s).__name__}")
        return s

    @property
    def settings(self) -> Settings:
        """The :class:`Settings` in use. Assigning new ones keeps the state,
        except that a change of ``mode`` resets the solver."""
        return self._settings

    @settings.setter
    def settings(self, s):
        s = self._check_settings(s)
        mode_changed = s.mode != self._settings.mode
        self._settings = s
        if mode_changed:
            self.reset()

    # --------------------------------------------------------------- state
    def reset(self):
        """Forget every curve's history (the next step starts afresh)."""
        C, S = self.n_curves, len(self._seg_start)
        self._angle = np.zeros(C)  # radians (stiff/bend)
        self._angle_max = np.zeros(C)
        self._push = np.zeros(C)  # last frame's collision increment (search prediction)
        self._axis_lo = np.zeros((C, 3))
        self._frame = np.zeros((C, 3, 3))
        self._active = np.zeros(C, bool)  # has a non-identity local state
        self._hold = np.zeros(C, bool)  # no recovery (out of a pinch, recover_pinched off)
        self._pinched = np.zeros(C, bool)
        self._stiff = np.zeros(C, bool)  # Bend curves solved as Stiff (bending could not clear)
        self._quat = np.tile([1.0, 0.0, 0.0, 0.0], (S, 1))  # soft, local frame
        self._quat_max = self._quat.copy()
        self._steps = 0

    _STATE_KEYS = {
        "angle": ("C",), "angle_max": ("C",), "push": ("C",), "axis": ("C", 3),
        "frame": ("C", 3, 3),
        "active": ("C",), "hold": ("C",), "pinched": ("C",), "stiff": ("C",), "quat": ("S", 4),
        "quat_max": ("S", 4), "meta": (4,),
    }

    @property
    def state(self) -> dict:
        """Snapshot (copies) of all per-curve state as numpy arrays.

        Restoring it with ``solver.state = snapshot`` makes the next step
        bit-identical to what it was after the snapshot. Only numpy arrays:
        it can be written with ``np.savez`` and read without pickle.
        """
        mode = ("stiff", "bend", "soft").index(self._settings.mode)
        return {
            "angle": self._angle.copy(), "angle_max": self._angle_max.copy(),
            "push": self._push.copy(),
            "axis": self._axis_lo.copy(), "frame": self._frame.copy(),
            "active": self._active.copy(), "hold": self._hold.copy(),
            "pinched": self._pinched.copy(), "stiff": self._stiff.copy(),
            "quat": self._quat.copy(),
            "quat_max": self._quat_max.copy(),
            "meta": np.array([_STATE_VERSION, self.n_curves, self.n_points, mode], np.int64),
        }

    @state.setter
    def state(self, s):
        if not isinstance(s, dict) and not hasattr(s, "keys"):
            raise InputError("state must be a dict of numpy arrays (from Solver.state)")
        missing = set(self._STATE_KEYS) - set(s.keys())
        if missing:
            raise InputError(f"state is missing {sorted(missing)}")
        dims = {"C": self.n_curves, "S": len(self._seg_start)}
        arrs = {}
        for k, shape in self._STATE_KEYS.items():
            a = np.asarray(s[k])
            want = tuple(dims.get(d, d) for d in shape)
            if a.shape != want:
                raise InputError(f"state['{k}'] has shape {a.shape}, expected {want}")
            arrs[k] = a
        meta = arrs["meta"]
        if int(meta[0]) != _STATE_VERSION or int(meta[1]) != self.n_curves or int(
            meta[2]
        ) != self.n_points:
            raise InputError("state was saved for other curves (curve/point count differs)")
        if int(meta[3]) != ("stiff", "bend", "soft").index(self._settings.mode):
            raise InputError("state was saved with another mode")
        self._angle = arrs["angle"].astype(np.float64).copy()
        self._angle_max = arrs["angle_max"].astype(np.float64).copy()
        self._push = arrs["push"].astype(np.float64).copy()
        self._axis_lo = arrs["axis"].astype(np.float64).copy()
        self._frame = arrs["frame"].astype(np.float64).copy()
        self._active = arrs["active"].astype(bool).copy()
        self._hold = arrs["hold"].astype(bool).copy()
        self._pinched = arrs["pinched"].astype(bool).copy()
        self._stiff = arrs["stiff"].astype(bool).copy()
        self._quat = arrs["quat"].astype(np.float64).copy()
        self._quat_max = arrs["quat_max"].astype(np.float64).copy()

    # --------------------------------------------------------------- input
    def _check_points(self, points):
        if not isinstance(points, np.ndarray):
            try:
                points = np.asarray(points)
            except Exception as exc:
                raise InputError(f"points must be a (P, 3) float array: {exc}") from None
        if points.ndim != 2 or points.shape[1] != 3:
            raise InputError(f"points must have shape (P, 3), got {points.shape}")
        if points.dtype not in (np.float32, np.float64):
            raise InputError(f"points must be float32 or float64, got {points.dtype}")
        if len(points) != self.n_points:
            raise InputError(
                f"points has {len(points)} rows but offsets describe {self.n_points} points"
            )
        if not np.isfinite(points).all():
            i = int(np.argmax(~np.isfinite(points).all(axis=1)))
            c = int(np.searchsorted(self._off, i, "right") - 1)
            raise InputError(f"point {i} (curve {c}) is not finite: {points[i].tolist()}")
        return np.ascontiguousarray(points)

    def _check_enabled(self, enabled):
        if enabled is None:
            return np.ones(self.n_curves, bool)
        e = np.asarray(enabled)
        if e.shape != (self.n_curves,):
            raise InputError(f"enabled must have shape ({self.n_curves},), got {e.shape}")
        if e.dtype != bool:
            if not (np.issubdtype(e.dtype, np.integer) or np.issubdtype(e.dtype, np.floating)):
                raise InputError(f"enabled must be booleans, got dtype {e.dtype}")
            if not np.isfinite(e).all():
                raise InputError("enabled has non-finite values")
            e = e != 0
        return e

    # ------------------------------------------------------------ the step
    def step(self, points, colliders=(), growth=None, enabled=None) -> StepResult:
        """Solve one frame.

        Parameters
        ----------
        points : (P, 3) ndarray of float32 or float64
            This frame's input curves, world space.
        colliders : sequence of Collider
            Meshes the curves must not pass through (world transforms in
            their ``matrix``). Empty colliders are ignored.
        growth : Collider, optional
            The growth surface (for Attract to Growth Surface and Put to
            Growth Surface). Never collided with.
        enabled : (C,) array_like of bool, optional
            Curves to solve; disabled curves keep their prior local state.

        Returns
        -------
        StepResult

        Raises
        ------
        InputError
            Malformed points, mask or collider list (the message names the
            curve or point at fault).
        """
        t_start = time.perf_counter()
        s = self._settings
        points = self._check_points(points)
        enabled = self._check_enabled(enabled)
        if isinstance(colliders, Collider):
            colliders = [colliders]
        cols = []
        for i, c in enumerate(colliders):
            if not isinstance(c, Collider):
                raise InputError(f"colliders[{i}] is a {type(c).__name__}, not a core.Collider")
            if not c.empty:
                cols.append((c, c.effective_offset(s.collision_offset)))
        if growth is not None and not isinstance(growth, Collider):
            raise InputError(f"growth must be a core.Collider, got {type(growth).__name__}")
        if growth is not None and growth.empty:
            growth = None
        if s.attract_to_growth_surface and growth is None:
            raise InputError(
                "attract_to_growth_surface needs the growth surface (step(growth=...))"
            )
        if s.pinch_resolution == "growth_surface" and growth is None:
            raise InputError(
                "pinch_resolution='growth_surface' needs the growth surface (step(growth=...))"
            )

        ctx = _StepContext(self, points, cols, growth)
        timings = ctx.timings
        timings["setup"] = (time.perf_counter() - t_start) * 1e3

        C = self.n_curves
        status = np.zeros(C, np.int8)
        status[~enabled] = Status.DISABLED

        # Local frames of every curve that carries state, and its axes in world.
        t0 = time.perf_counter()
        ctx.load_state()
        timings["frames"] = (time.perf_counter() - t0) * 1e3

        # Pinch detection (paper 3.1): roots inside closed single-sided colliders.
        t0 = time.perf_counter()
        pinched = np.zeros(C, bool)
        for (c, off), box in zip(cols, ctx.boxes, strict=True):
            if c.detects_pinch:
                q = np.flatnonzero(enabled & ctx.root_in_box(box))
                if len(q):
                    pinched[q[c.contains(ctx.roots[q], off)]] = True
        timings["pinch"] = (time.perf_counter() - t0) * 1e3

        t0 = time.perf_counter()
        was_pinched = self._pinched
        out_of_pinch = was_pinched & ~pinched & enabled
        if not s.recover_pinched:
            self._hold |= out_of_pinch & self._active
        pin = np.flatnonzero(pinched)
        status[pin] = Status.PINCHED
        if len(pin) and s.pinch_resolution == "growth_surface":
            ctx.put_to_growth_surface(pin)
        self._pinched = pinched & enabled | (was_pinched & ~enabled)

        solve = enabled & ~pinched & (ctx.cand_any | self._active)
        idx = np.flatnonzero(solve)
        if len(idx):
            ctx.solve(idx, status)
        timings["solve"] = (time.perf_counter() - t0) * 1e3

        t0 = time.perf_counter()
        out = ctx.output()
        ctx.store_state()
        self._steps += 1
        timings["output"] = (time.perf_counter() - t0) * 1e3
        timings["total"] = (time.perf_counter() - t_start) * 1e3
        timings["rays"] = ctx.n_rays
        return StepResult(out, status, timings)


class _StepContext:
    """Everything one step needs; methods are the phases of the step."""

    def __init__(self, solver: Solver, points, cols, growth):
        self.sv_ = solver
        self.s = s = solver.settings
        self.points = points  # the input, its own dtype (never modified)
        out_dtype = points.dtype
        self.cols = cols
        self.growth = growth
        self.threads = s.threads or default_threads()
        self.prec = np.deg2rad(s.rotation_precision)
        self.max_angle = np.deg2rad(s.max_angle)
        self.out_dtype = out_dtype
        self.timings = {}
        self.n_rays = 0
        # Point differences in the input dtype: contiguous and cheap. Entry i is
        # the segment starting at point i (entries at curve ends are unused).
        self.D = np.diff(points, axis=0)
        L = np.sqrt(np.einsum("ij,ij->i", self.D, self.D))
        L[solver._curve_end] = 0
        self.curve_len = np.add.reduceat(L, solver._off[:-1]).astype(np.float64)
        L[solver._curve_end] = np.inf
        shortest = np.minimum.reduceat(L, solver._off[:-1])
        bad = shortest <= tol.ZERO_SEGMENT_REL * self.curve_len
        if bad.any():
            c = int(np.argmax(bad))
            a, b = int(solver._off[c]), int(solver._off[c + 1])
            k = a + int(np.argmin(L[a : b - 1]))
            raise InputError(
                f"curve {c} has a zero-length segment between points {k} and {k + 1}"
            )
        self.roots = points[solver._off[:-1]].astype(np.float64)
        # Ray growth (tol.RAY_EXTEND_ULPS): float32 ulps at the size of the
        # largest collider (where embree works, centred), plus the output
        # dtype's rounding at the colliders' distance from the origin. It
        # depends on the colliders only, so a curve's result does not depend
        # on which other curves are solved with it.
        size = mag = 0.0
        for c, _ in cols:
            lo, hi = c.bounds_world()
            size = max(size, float(np.linalg.norm(hi - lo)))
            mag = max(mag, float(np.abs(lo).max()), float(np.abs(hi).max()))
        self.eps_abs = tol.RAY_EXTEND_ULPS * (
            float(np.finfo(np.float32).eps) * size + float(np.finfo(points.dtype).eps) * mag
        )
        # Candidate curves per collider: the ball a curve can sweep about its
        # root (any rotation, scale <= 1) meets the collider's bounds, then
        # comes near one of its vertices (Collider.near_surface).
        self.cand = []
        self.boxes = []
        for c, off in cols:
            lo, hi = c.bounds_world(off)
            self.boxes.append((lo, hi))
            gap = np.maximum(lo - self.roots, 0) + np.maximum(self.roots - hi, 0)
            cand = np.einsum("ij,ij->i", gap, gap) <= self.curve_len**2
            w = np.flatnonzero(cand)
            cand[w] = c.near_surface(self.roots[w], self.curve_len[w], off)
            self.cand.append(cand)
        if self.cand:
            self.cand_any = np.logical_or.reduce(self.cand)
        else:
            self.cand_any = np.zeros(solver.n_curves, bool)
        self.soft = s.mode == "soft"

    def root_in_box(self, box):
        lo, hi = box
        return np.all((self.roots >= lo) & (self.roots <= hi), axis=1)

    # ------------------------------------------------------------ frames
    def load_state(self):
        sv = self.sv_
        self.angle = sv._angle.copy()
        self.angle_max = sv._angle_max.copy()
        self.push = np.zeros(sv.n_curves)
        self.guess = sv._push.copy()
        self.axis = np.zeros((sv.n_curves, 3))
        if self.soft:
            self.quat = sv._quat.copy()
            self.quat_max = sv._quat_max.copy()
        self.active = sv._active.copy()
        idx = np.flatnonzero(self.active)
        self.B = np.zeros((sv.n_curves, 3, 3))  # this step's frames (rows in use only)
        self.ref = None
        if len(idx):
            B, self.ref = self._frames(idx, sv._frame[idx])
            self.B[idx] = B
            self.axis[idx] = np.einsum("kji,kj->ki", B, sv._axis_lo[idx])
            if self.soft:
                seg, rep, _ = self.segments(idx)
                self.quat[seg] = self._quat_to(B[rep], self.quat[seg], to_world=True)
                self.quat_max[seg] = self._quat_to(B[rep], self.quat_max[seg], to_world=True)

    @staticmethod
    def _quat_to(B, q, to_world):
        v = q[:, 1:]
        v = np.einsum("kji,kj->ki", B, v) if to_world else np.einsum("kij,kj->ki", B, v)
        return np.concatenate([q[:, :1], v], axis=1)

    def _frames(self, idx, prev):
        sv = self.sv_
        first = sv._soff[idx]
        t = rot.normalize(self.seg_in(first))
        chord = self.points[sv._off[idx + 1] - 1] - self.roots[idx]
        u = chord - rot.dot(chord, t)[:, None] * t
        ratio = np.linalg.norm(u, axis=1) / self.curve_len[idx]
        return rot.curve_frames(t, u, ratio, prev)

    def store_state(self):
        sv = self.sv_
        idx = np.flatnonzero(self.active)
        frame = sv._frame  # the transported references (see rot.curve_frames)
        old = np.flatnonzero(sv._active)
        if len(old):
            frame[old] = self.ref
        dropped = old[~self.active[old]]
        frame[dropped] = 0.0
        fresh = idx[~sv._active[idx]]
        if len(fresh):
            self.B[fresh], frame[fresh] = self._frames(fresh, None)
        B = self.B
        sv._angle = self.angle
        sv._angle_max = self.angle_max
        sv._push = self.push
        sv._active = self.active
        axis_lo = np.zeros_like(self.axis)
        if len(idx):
            axis_lo[idx] = np.einsum("kij,kj->ki", B[idx], self.axis[idx])
        sv._axis_lo = axis_lo
        sv._hold &= self.active
        if self.soft:
            q = np.tile([1.0, 0.0, 0.0, 0.0], (len(self.quat), 1))
            qm = q.copy()
            if len(idx):
                seg, rep, _ = self.segments(idx)
                q[seg] = self._quat_to(B[idx][rep], self.quat[seg], to_world=False)
                qm[seg] = self._quat_to(B[idx][rep], self.quat_max[seg], to_world=False)
            sv._quat, sv._quat_max = q, qm

    # ----------------------------------------------------------- geometry
    def segments(self, idx):
        """Segments of curves ``idx``: (seg ids, owner position in idx, starts)."""
        sv = self.sv_
        cnt = sv._nseg[idx]
        starts = np.cumsum(cnt) - cnt
        rep = np.repeat(np.arange(len(idx)), cnt)
        seg = sv._soff[idx][rep] + (np.arange(int(cnt.sum())) - starts[rep])
        return seg, rep, starts

    def rigid_rotations(self, idx, angle, axis, seg, rep):
        """Per-segment (angle, axis) of stiff/bend curves ``idx``."""
        if self.s.mode == "bend":
            w = np.where(self.sv_._stiff[idx][rep], 1.0, self.sv_._w_bend[seg])
        else:
            w = 1.0
        return angle[rep] * w, axis[rep]

    def deform(self, idx, angle=None, axis=None, quat=None):
        """Deformed segments of curves ``idx``.

        Returns
        -------
        o, d : (k, 3) segment starts and vectors, world space
        seg, rep, starts : see :meth:`segments`
        """
        seg, rep, starts = self.segments(idx)
        v = self.seg_in(seg)
        if quat is not None:
            v = rot.quat_rotate(quat, v)
        else:
            a_seg, ax_seg = self.rigid_rotations(idx, angle, axis, seg, rep)
            v = rot.rotate(v, ax_seg, a_seg)
            if self.s.shrink:
                ramp = np.minimum(a_seg / np.deg2rad(self.s.scale_angle), 1.0)
                v = v * (1.0 - (1.0 - self.s.scale_minimum) * ramp)[:, None]
        cs = np.cumsum(v, axis=0)
        base = self.roots[idx] - (cs[starts] - v[starts])
        # Round to the output dtype so the segments tested are exactly the
        # segments written out (float32 rounding must not re-open a contact).
        end = (cs + base[rep]).astype(self.out_dtype).astype(np.float64)
        o = np.empty_like(end)
        o[1:] = end[:-1]
        o[starts] = self.roots[idx]
        return o, end - o, seg, rep, starts

    def extend(self, o, d, root):
        """Segments grown by a few float32 ulps (see ``tol.RAY_EXTEND_ULPS``).

        ``root`` marks root segments, which are not grown backward: roots
        never move, so a root resting on a collider is a pinch, not a contact.
        """
        L = np.sqrt(np.einsum("ij,ij->i", d, d))
        e = self.eps_abs / np.maximum(L, 1e-300)
        back = np.where(root, 0.0, e)
        return o - back[:, None] * d, d * (1.0 + back + e)[:, None]

    def hits(self, idx, o, d, rep, root):
        """Per segment: does it hit any collider (segments of curves ``idx``).

        Parameters
        ----------
        rep : (k,) int  owner of each segment (position in ``idx``)
        root : (k,) bool  which segments are root segments
        """
        o, d = self.extend(o, d, root)
        hit = np.zeros(len(o), bool)
        for (c, off), cand in zip(self.cols, self.cand, strict=True):
            m = cand[idx][rep]
            if m.all():
                hit |= c.segment_hits(o, d, off, self.threads)
                self.n_rays += len(o)
            elif m.any():
                w = np.flatnonzero(m)
                hit[w] |= c.segment_hits(o[w], d[w], off, self.threads)
                self.n_rays += len(w)
        return hit

    def current_hits(self, idx):
        """Per-curve hits of curves ``idx`` in their current state.

        Curves without a local rotation are the input itself: their rays come
        straight from the input points, with no deformation to compute.
        """
        hit = np.zeros(len(idx), bool)
        act = self.active[idx]
        a = idx[act]
        if len(a):
            if self.soft:
                seg, _, _ = self.segments(a)
                hit[act] = self.curve_hits(a, quat=self.quat[seg])
            else:
                hit[act] = self.curve_hits(a, angle=self.angle[a], axis=self.axis[a])
        b = idx[~act]
        if len(b):
            seg, rep, starts = self.segments(b)
            ss = self.sv_._seg_start[seg]
            h = self.hits(b, self.points[ss], self.D[ss], rep, self.root_mask(len(seg), starts))
            hit[~act] = np.logical_or.reduceat(h, starts)
        return hit

    def curve_hits(self, idx, **deformation):
        if len(idx) == 0:
            return np.zeros(0, bool)
        o, d, seg, rep, starts = self.deform(idx, **deformation)
        root = self.root_mask(len(o), starts)
        return np.logical_or.reduceat(self.hits(idx, o, d, rep, root), starts)

    @staticmethod
    def root_mask(k, starts):
        m = np.zeros(k, bool)
        m[starts] = True
        return m

    def first_hit_details(self, idx, o, d, rep, starts):
        """First hit (root to tip) of each curve: segment, point, push direction.

        Returns
        -------
        k : (n,) int  index into o/d of the first hitting segment (-1: none)
        point : (n, 3)  hit point
        push : (n, 3)  unit direction away from the collider (paper 3.2.1)
        """
        n = len(idx)
        root = self.root_mask(len(o), starts)
        hit = self.hits(idx, o, d, rep, root)
        k = np.full(n, -1, np.int64)
        w = np.flatnonzero(hit)
        if len(w):
            owners, first = np.unique(rep[w], return_index=True)
            k[owners] = w[first]
        point = np.zeros((n, 3))
        push = np.zeros((n, 3))
        has = np.flatnonzero(k >= 0)
        if len(has) == 0:
            return k, point, push
        ks = k[has]
        o, d = self.extend(o[ks], d[ks], root[ks])
        best_t = np.full(len(has), np.inf)
        best_n = np.zeros((len(has), 3))
        double = np.zeros(len(has), bool)
        for (c, off), cand in zip(self.cols, self.cand, strict=True):
            m = np.flatnonzero(cand[idx[has]])
            if len(m) == 0:
                continue
            h, t, nrm = c.segment_hit_details(o[m], d[m], off)
            better = h & (t < best_t[m])
            mm = m[better]
            best_t[mm] = t[better]
            best_n[mm] = nrm[better]
            double[mm] = c.double_sided
        best_t = np.where(np.isfinite(best_t), best_t, 0.0)
        pt = o + d * best_t[:, None]
        # Single-sided: along the normal, or its inverse when a back face is
        # crossed. Double-sided: toward the side the root is on.
        side = -np.sign(rot.dot(d, best_n))
        root_side = np.sign(rot.dot(self.roots[idx[has]] - pt, best_n))
        side = np.where(double & (root_side != 0), root_side, side)
        side = np.where(side == 0, 1.0, side)
        point[has] = pt
        push[has] = best_n * side[:, None]
        return k, point, push

    # ----------------------------------------------------------- solving
    def target_fraction(self, idx):
        """Recovery target as a fraction of the maximum rotation (plasticity)."""
        return np.where(self.sv_._hold[idx], np.nan, self.s.plasticity)

    def solve(self, idx, status):
        if self.soft:
            _SoftSolve(self).run(idx, status)
        else:
            self.solve_rigid(idx, status)

    def new_axes(self, idx, o, d, rep, starts):
        """Rotation axes for curves starting a contact (paper 3.2.1).

        Also sets ``self.guess`` for them: the rotation that lifts every CV
        above the collider's tangent plane at the hit (a first probe for the
        angle search, nothing more).
        """
        k, point, push = self.first_hit_details(idx, o, d, rep, starts)
        c = point - self.roots[idx]
        normal = push
        if self.s.attract_to_growth_surface:
            mid = self._midpoints(idx, o, d, starts)
            cp, _ = self.growth.closest_points(mid)
            toward = cp - mid
            a = np.cross(c, toward)
            ok = np.linalg.norm(a, axis=1) > tol.PARALLEL_EPS * np.maximum(
                np.linalg.norm(c, axis=1) * np.linalg.norm(toward, axis=1), 1e-300
            )
            push = np.where(ok[:, None], rot.normalize(toward), push)
        axis = rot.rotation_axis(c, push)
        self.guess[idx] = self._plane_guess(idx, o + d, rep, starts, point, normal, axis)
        return axis

    def _plane_guess(self, idx, ends, rep, starts, point, normal, axis):
        """Angle lifting each curve's CVs above the plane (point, normal)."""
        depth = -rot.dot(ends - point[rep], normal[rep])
        v = ends - self.roots[idx][rep]
        ax = axis[rep]
        radius = np.linalg.norm(v - ax * rot.dot(v, ax)[:, None], axis=1)
        lift = np.arcsin(np.clip(depth / np.maximum(radius, 1e-300), 0.0, 1.0))
        if self.s.mode == "bend":  # a CV turns by about the mean weight up to it
            j = np.arange(len(rep)) - starts[rep]
            n = self.sv_._nseg[idx][rep]
            w = np.where(self.sv_._stiff[idx][rep], 1.0, (j + 2) / (2.0 * n))
            lift = lift / w
        return np.maximum.reduceat(lift, starts) if len(lift) else lift

    def _midpoints(self, idx, o, d, starts):
        nseg = self.sv_._nseg[idx]
        j = starts + nseg // 2
        return o[j] + np.where((nseg % 2 == 1)[:, None], 0.5 * d[j], 0.0)

    def input_rays(self, idx):
        """Segments of the *input* curves ``idx`` (float64), like :meth:`deform`."""
        seg, rep, starts = self.segments(idx)
        ss = self.sv_._seg_start[seg]
        return self.points[ss].astype(np.float64), self.seg_in(seg), seg, rep, starts

    def solve_rigid(self, idx, status):
        """Stiff and Bend: one angle per curve about its kept axis."""
        angle = self.angle
        near = idx[self.cand_any[idx]]
        far = idx[~self.cand_any[idx]]
        act = near[self.active[near]]  # rotated curves near a collider
        new = near[~self.active[near]]  # unrotated: their segments are the input's
        # 1. Every near curve in its current state: one ray query each.
        batch = _RigidBatch(self, act)
        hit_act = batch.hits(np.arange(len(act)), angle[act])
        hit_new = np.zeros(len(new), bool)
        if len(new):
            o, d, seg, rep, starts = self.input_rays(new)
            hit_new = np.logical_or.reduceat(
                self.hits(new, o, d, rep, self.root_mask(len(o), starts)), starts
            )
        cn = new[hit_new]
        if len(cn):  # first hit: choose the axis (kept until recovered)
            self.axis[cn] = self.new_axes(cn, *self.input_rays(cn)[:2],
                                          *self.segments(cn)[1:])
            self.active[cn] = True

        # 2. Collision: the smallest clearing angle above the current one.
        cc = act[hit_act]
        if len(cc):  # first probe: lift the current shape above the tangent plane
            o, d, _, rep, starts = self.deform(cc, angle=angle[cc], axis=self.axis[cc])
            k, point, push = self.first_hit_details(cc, o, d, rep, starts)
            g = self._plane_guess(cc, o + d, rep, starts, point, push, self.axis[cc])
            self.guess[cc] = np.where(k >= 0, g, self.guess[cc])
        self.collide(batch, np.flatnonzero(hit_act), status)
        if len(cn):
            self.collide(_RigidBatch(self, cn), np.arange(len(cn)), status)

        # 3. Recovery toward the (plasticity) target, stopping before contact.
        items = np.flatnonzero(~hit_act)
        self.recover_rigid(act[items], status, batch, items)
        self.recover_rigid(far[self.active[far]], status, None, None)
        self._release(idx)

    def collide(self, batch, items, status):
        """Resolve colliding curves ``batch.curves[items]`` (paper 3.2.1)."""
        if len(items) == 0:
            return
        p, angle = self.prec, self.angle
        c = batch.curves[items]
        th0 = angle[c]
        k = self.search_angles(batch, items, th0, self.guess[c])
        if self.s.mode == "bend":
            # Bending turns the root segment by only 1/n of the angle: curves
            # hit near the root that bending cannot clear turn at the root (as
            # Stiff) instead, until they have recovered.
            retry = np.flatnonzero((k < 0) & ~self.sv_._stiff[c])
            if len(retry):
                cr = c[retry]
                self.sv_._stiff[cr] = True
                k2 = self.search_angles(_RigidBatch(self, cr), np.arange(len(cr)),
                                        np.zeros(len(cr)))
                self.sv_._stiff[cr[k2 < 0]] = False
                ok2 = k2 >= 0
                k[retry[ok2]] = k2[ok2]
                th0[retry[ok2]] = 0.0
        ok = k >= 0
        res = c[ok]
        angle[res] = np.minimum(th0[ok] + k[ok] * p, self.max_angle)
        self.push[res] = angle[res] - th0[ok]
        self.angle_max[res] = np.maximum(self.angle_max[res], angle[res])
        status[res] = Status.COLLIDING
        bad = c[~ok]
        status[bad] = Status.UNRESOLVED
        # Fallback: the state of the previous frame (last collision-free).
        angle[bad] = th0[~ok]
        fresh = bad[self.sv_._angle[bad] == 0]
        self.active[fresh] = self.sv_._active[fresh]

    def recover_rigid(self, rec, status, batch, items):
        """Turn clear curves ``rec`` back toward their target (paper 3.2.3-4).

        ``batch.curves[items]`` are ``rec`` when they are near a collider (the
        step is checked and, if it would collide, bisected back); ``batch`` is
        None for curves far from every collider.
        """
        if len(rec) == 0:
            return
        p = self.prec
        th0 = self.angle[rec]
        frac = self.target_fraction(rec)
        target = np.where(np.isnan(frac), th0, np.nan_to_num(frac) * self.angle_max[rec])
        target = np.minimum(target, th0)
        th1 = th0 - self.s.recovery_rate * (th0 - target)
        th1 = np.where(th1 - target < tol.SNAP_FRACTION * p, target, th1)
        th1 = np.where(th1 < tol.SNAP_FRACTION * p, 0.0, th1)
        blocked = np.zeros(len(rec), bool)
        if batch is not None:
            check = np.flatnonzero(th1 < th0)
            blocked[check] = batch.hits(items[check], th1[check])
            b = np.flatnonzero(blocked)
            if len(b):
                lo_th, hi_th = th1[b], th0[b]
                K = np.maximum(np.ceil((hi_th - lo_th) / p - 1e-9), 1).astype(np.int64)

                def test(it, ks):
                    return ~batch.hits(items[b[it]], np.minimum(lo_th[it] + ks * p, hi_th[it]))

                k = _gallop_bisect(len(b), test, K, lo=np.zeros(len(b)), hi=K)
                th1[b] = np.minimum(lo_th + k * p, hi_th)
        self.angle[rec] = th1
        # Back at exactly the input shape counts as FREE, not RECOVERING.
        st = np.where(blocked, Status.COLLIDING,
                      np.where((th1 < th0) & (th1 > 0), Status.RECOVERING, Status.FREE))
        status[rec] = np.maximum(status[rec], st)

    def search_angles(self, batch, items, th0, guess=None):
        """Smallest clearing rotation above ``th0`` of ``batch.curves[items]``.

        ``guess`` (radians, per item) is last frame's increment: colliders move
        smoothly, so the steps ``k - 1`` and ``k`` around it are probed first
        (one round); the search continues from whatever bracket that gives.

        Returns
        -------
        (n,) int
            Steps ``k`` (angle ``min(th0 + k p, max_angle)``), -1 where no
            angle up to ``max_angle`` clears the curve.
        """
        p = self.prec
        n = len(items)
        kmax = np.maximum(np.ceil((self.max_angle - th0) / p - 1e-9), 0).astype(np.int64)

        def test(it, ks):
            return ~batch.hits(items[it], np.minimum(th0[it] + ks * p, self.max_angle))

        lo = np.zeros(n, np.int64)
        hi = np.full(n, -1, np.int64)
        stride = None
        if guess is not None:
            # One round of probes spread around the guess; it leaves a bracket
            # to bisect, or a floor to gallop on from with a guess-sized stride.
            kg = np.clip(np.rint(guess / p).astype(np.int64), 1, np.maximum(kmax, 1))
            it = np.flatnonzero(kmax >= 1)
            spread = np.array([0.8, 1.0, 1.25, 1.6])
            probes = np.clip(np.rint(kg[it][:, None] * spread).astype(np.int64), 1,
                             kmax[it][:, None])
            probes = np.maximum.accumulate(probes, axis=1)
            good = test(np.repeat(it, len(spread)), probes.ravel()).reshape(probes.shape)
            anyg = good.any(axis=1)
            first = np.argmax(good, axis=1)
            rows = np.arange(len(it))
            hi[it[anyg]] = probes[rows, first][anyg]
            lo[it[anyg]] = np.where(first > 0, probes[rows, np.maximum(first - 1, 0)], 0)[anyg]
            lo[it[~anyg]] = probes[~anyg, -1]
            stride = np.maximum(kg // 2, 1)
        return _gallop_bisect(n, test, kmax, lo=lo, hi=hi, stride=stride)

    def _release(self, idx):
        """Curves back at exactly their input shape drop their local state."""
        if self.soft:
            return
        done = idx[self.active[idx] & (self.angle[idx] == 0)]
        self.active[done] = False
        self.sv_._stiff[done] = False
        self.axis[done] = 0.0
        self.angle_max[done] = 0.0

    # ------------------------------------------------------------ pinch
    def put_to_growth_surface(self, pin):
        """Rotate pinched curves down onto the growth surface (paper 3.2.5)."""
        _, n_g = self.growth.closest_points(self.roots[pin])
        chord = self.points[self.sv_._off[pin + 1] - 1] - self.roots[pin]
        down = -n_g
        axis = rot.rotation_axis(chord, down)
        # Elevation of the deformed chord over the tangent plane, bisected on
        # the angle so the same works for every mode's deformation.
        lo = np.zeros(len(pin))
        hi = np.full(len(pin), np.pi)
        for _ in range(24):
            mid = 0.5 * (lo + hi)
            o, d, seg, rep, starts = self._deform_mode(pin, mid, axis)
            tip = o[starts + self.sv_._nseg[pin] - 1] + d[starts + self.sv_._nseg[pin] - 1]
            above = rot.dot(tip - self.roots[pin], n_g) > 0
            lo = np.where(above, mid, lo)
            hi = np.where(above, hi, mid)
        ang = np.where(rot.dot(chord, n_g) > 0, hi, 0.0)
        self._set_uniform(pin, ang, axis)

    def _deform_mode(self, idx, angle, axis):
        if self.soft:
            seg, rep, _ = self.segments(idx)
            q = rot.quat_from_axis_angle(axis[rep], angle[rep])
            return self.deform(idx, quat=q)
        return self.deform(idx, angle=angle, axis=axis)

    def _set_uniform(self, idx, angle, axis):
        if self.soft:
            seg, rep, _ = self.segments(idx)
            q = rot.quat_from_axis_angle(axis[rep], angle[rep])
            self.quat[seg] = q
            grow = rot.quat_angle(q) > rot.quat_angle(self.quat_max[seg])
            self.quat_max[seg[grow]] = q[grow]
        else:
            self.angle[idx] = angle
            self.axis[idx] = axis
            self.angle_max[idx] = np.maximum(self.angle_max[idx], angle)
        self.active[idx] = angle > 0

    # ------------------------------------------------------------ output
    def output(self):
        out = self.points.copy()
        idx = np.flatnonzero(self.active)
        if len(idx):
            if self.soft:
                seg, _, _ = self.segments(idx)
                o, d, seg, rep, starts = self.deform(idx, quat=self.quat[seg])
            else:
                o, d, seg, rep, starts = self.deform(
                    idx, angle=self.angle[idx], axis=self.axis[idx]
                )
            out[self.sv_._seg_start[seg] + 1] = o + d
        return out

    def seg_in(self, seg):
        """Input segment vectors (float64) of segment ids ``seg``."""
        return self.D[self.sv_._seg_start[seg]].astype(np.float64)


class _RigidBatch:
    """Stiff/Bend curves under search, with all angle-independent work done once.

    Rodrigues' rotation of a segment ``v`` about the curve's axis ``a`` is
    ``Y + V0 cos(t) + X sin(t)`` with ``Y = a (a.v)``, ``V0 = v - Y`` and
    ``X = a x v``; the map into a collider's space is affine, so ``Y``, ``V0``,
    ``X`` and the roots are moved into each collider's space once. A probe
    round then costs a gather, a cos/sin, a cumulative sum and the ray query.
    Rays are grown by ``tol.RAY_EXTEND_ULPS`` as in :meth:`_StepContext.hits`.
    """

    def __init__(self, ctx: _StepContext, curves):
        self.ctx = ctx
        self.curves = curves
        sv = ctx.sv_
        seg, rep, starts = ctx.segments(curves)
        self.cnt = sv._nseg[curves]
        self.starts = starts
        v = ctx.seg_in(seg)
        ax = ctx.axis[curves][rep]
        Y = ax * rot.dot(ax, v)[:, None]
        X = np.cross(ax, v)
        V0 = v - Y
        if ctx.s.mode == "bend":
            self.w = np.where(sv._stiff[curves][rep], 1.0, sv._w_bend[seg])
        else:
            self.w = np.ones(len(seg))
        self.length = np.sqrt(rot.dot(v, v))
        self.root = ctx.root_mask(len(seg), starts)
        # Uniform CV counts (the usual groom): keep (curves, segments, 3) blocks.
        ns = int(self.cnt[0]) if len(curves) else 0
        self.ns = ns if len(curves) and (self.cnt == ns).all() else 0
        self.per_col = []
        for (c, off), cand in zip(ctx.cols, ctx.cand, strict=True):
            m = cand[curves]
            if not m.any():
                continue
            A, b = c.local_map()
            terms = [rot.apply(A, x) for x in (Y, V0, X)]
            if self.ns:
                terms = [x.reshape(-1, self.ns, 3) for x in terms]
            self.per_col.append((c, off, m, rot.apply(A, ctx.roots[curves]) + b, *terms))
        if self.ns:
            self.w = self.w.reshape(-1, self.ns)
            self.length = self.length.reshape(-1, self.ns)

    def hits(self, items, theta):
        """Does curve ``curves[items[i]]`` turned by ``theta[i]`` hit a collider.

        ``items`` may repeat (several angles of one curve in one query).
        """
        n = len(items)
        hit = np.zeros(n, bool)
        if n == 0:
            return hit
        if self.ns:
            return self._hits_uniform(items, theta, hit)
        ctx = self.ctx
        cnt = self.cnt[items]
        first = np.cumsum(cnt) - cnt
        rep = np.repeat(np.arange(n), cnt)
        sel = self.starts[items][rep] + (np.arange(len(rep)) - first[rep])
        a = theta[rep] * self.w[sel]
        cos, sin = np.cos(a)[:, None], np.sin(a)[:, None]
        scale = None
        if ctx.s.shrink:
            ramp = np.minimum(a / np.deg2rad(ctx.s.scale_angle), 1.0)
            scale = 1.0 - (1.0 - ctx.s.scale_minimum) * ramp
        length = self.length[sel] if scale is None else self.length[sel] * scale
        ext = ctx.eps_abs / np.maximum(length, 1e-300)
        grow = (1.0 + np.where(self.root[sel], 0.0, ext) + ext)[:, None]
        back = np.where(self.root[sel], 0.0, ext)[:, None]
        for c, off, m, root_lo, Y, V0, X in self.per_col:
            mi = m[items]
            if not mi.any():
                continue
            d = Y[sel] + V0[sel] * cos + X[sel] * sin
            if scale is not None:
                d *= scale[:, None]
            cs = np.cumsum(d, axis=0)
            o = cs - d + (root_lo[items] - (cs[first] - d[first]))[rep]
            rays = mi[rep]
            if rays.all():
                h = c.segment_hits_local(o - back * d, d * grow, off, ctx.threads)
            else:
                w = np.flatnonzero(rays)
                h = np.zeros(len(rep), bool)
                h[w] = c.segment_hits_local(o[w] - back[w] * d[w], d[w] * grow[w], off,
                                            ctx.threads)
            ctx.n_rays += int(rays.sum())
            hit |= np.logical_or.reduceat(h, first)
        return hit

    def _hits_uniform(self, items, theta, hit):
        """:meth:`hits` for curves that all have ``self.ns`` segments."""
        ctx = self.ctx
        ns = self.ns
        a = theta[:, None] * self.w[items]  # (n, ns)
        cos, sin = np.cos(a)[..., None], np.sin(a)[..., None]
        length = self.length[items]
        scale = None
        if ctx.s.shrink:
            scale = 1.0 - (1.0 - ctx.s.scale_minimum) * np.minimum(
                a / np.deg2rad(ctx.s.scale_angle), 1.0)
            length = length * scale
        ext = ctx.eps_abs / np.maximum(length, 1e-300)
        back = ext.copy()
        back[:, 0] = 0.0  # roots never move: the root segment is not grown backward
        grow = (1.0 + back + ext)[..., None]
        back = back[..., None]
        for c, off, m, root_lo, Y, V0, X in self.per_col:
            mi = m[items]
            if not mi.any():
                continue
            it = items if mi.all() else items[mi]
            sub = slice(None) if mi.all() else mi
            d = Y[it] + V0[it] * cos[sub] + X[it] * sin[sub]
            if scale is not None:
                d *= scale[sub][..., None]
            o = np.cumsum(d, axis=1)
            o -= d
            o += root_lo[it][:, None, :]
            o -= back[sub] * d
            d *= grow[sub]
            h = c.segment_hits_local(o.reshape(-1, 3), d.reshape(-1, 3), off, ctx.threads)
            ctx.n_rays += len(h)
            hit[sub] |= h.reshape(-1, ns).any(axis=1)
        return hit


class _SoftSolve:
    """Soft mode (paper 3.2.1): per-segment rotations, prefix by prefix.

    The first colliding segment of each curve turns about its own axis (away
    from the collider) by the smallest clearing angle; the next
    ``affected_connected_cvs`` segments turn with it scaled by
    ``(1 - cv_falloff) ** i``; segment lengths are kept because output
    curves are re-chained from rotated input segments (length correction).
    Segments before the one being solved never move, so each round clears
    one more prefix of the curve and the loop ends after at most one round
    per segment.
    """

    def __init__(self, ctx: _StepContext):
        self.ctx = ctx
        s = ctx.s
        A = s.affected_connected_cvs
        self.weights = (1.0 - s.cv_falloff) ** np.arange(1, A + 1) if A else np.zeros(0)

    def run(self, idx, status):
        ctx, p = self.ctx, self.ctx.prec
        sv = ctx.sv_
        near = idx[ctx.cand_any[idx]]
        far = idx[~ctx.cand_any[idx]]
        q0 = ctx.quat.copy()  # world, state at the start of the step
        unresolved = np.zeros(sv.n_curves, bool)
        touched = np.zeros(sv.n_curves, bool)
        todo = near
        for _ in range(int(sv._nseg.max(initial=0)) + 1):
            if len(todo) == 0:
                break
            seg, rep, starts = ctx.segments(todo)
            o, d, _, rep, starts = ctx.deform(todo, quat=ctx.quat[seg])
            k, point, push = ctx.first_hit_details(todo, o, d, rep, starts)
            hit = k >= 0
            todo, k, push = todo[hit], k[hit], push[hit]
            if len(todo) == 0:
                break
            touched[todo] = True
            ctx.active[todo] = True
            seg_hit = seg[k]  # global segment id of the first hitting segment
            if ctx.s.attract_to_growth_surface:
                mid = ctx._midpoints(todo, o, d, starts[hit])
                cp, _ = ctx.growth.closest_points(mid)
                pull = rot.normalize(cp - mid)
                ok = np.linalg.norm(np.cross(d[k], pull), axis=1) > tol.PARALLEL_EPS
                push = np.where(ok[:, None], pull, push)
            axis = rot.rotation_axis(d[k], push)
            last = sv._soff[todo + 1]  # one past the curve's last segment

            def test(items, ks, seg_hit=seg_hit, axis=axis, todo=todo, last=last):
                c = todo[items]  # may repeat: several angles of one curve
                owner, sel, q = self._rotated(seg_hit[items], last[items], axis[items], ks * p)
                # Only the solved segment needs testing: segments before it
                # did not move, segments after it are the next rounds' job.
                sseg, srep, sst = ctx.segments(c)
                qq = ctx.quat[sseg]
                qq[sst[owner] + (sel - sv._soff[c][owner])] = q
                o2, d2, _, r2, st2 = ctx.deform(c, quat=qq)
                j = st2 + (seg_hit[items] - sv._soff[c])
                root = seg_hit[items] == sv._soff[c]
                return ~ctx.hits(c, o2[j], d2[j], np.arange(len(c)), root)

            kmax = np.full(len(todo), int(np.ceil(ctx.max_angle / p - 1e-9)))
            kk = _gallop_bisect(len(todo), test, kmax)
            ok = kk >= 0
            if ok.any():
                w = np.flatnonzero(ok)
                _, sel, q = self._rotated(seg_hit[w], last[w], axis[w], kk[w] * p)
                ctx.quat[sel] = q
                grow = rot.quat_angle(q) > rot.quat_angle(ctx.quat_max[sel])
                ctx.quat_max[sel[grow]] = q[grow]
            unresolved[todo[~ok]] = True
            todo = todo[ok]
        # Unresolvable curves fall back to their state at the start of the step.
        bad = np.flatnonzero(unresolved)
        if len(bad):
            seg, _, _ = ctx.segments(bad)
            ctx.quat[seg] = q0[seg]
            ctx.active[bad] = self.ctx.sv_._active[bad]
            status[bad] = Status.UNRESOLVED
        status[touched & ~unresolved] = Status.COLLIDING
        rec = np.sort(np.concatenate([near, far]))
        rec = rec[~touched[rec] & ctx.active[rec]]
        if len(rec):
            self.recover(rec, status)

    def _rotated(self, seg_hit, last, axis, phi):
        """(owner, segment ids, composed quaternions) after turning ``seg_hit`` by ``phi``."""
        ctx = self.ctx
        n = len(seg_hit)
        span = np.minimum(len(self.weights) + 1, last - seg_hit)  # segments affected
        rep = np.repeat(np.arange(n), span)
        first = np.concatenate([[0], np.cumsum(span)[:-1]])
        i = np.arange(int(span.sum())) - first[rep]
        sel = seg_hit[rep] + i
        w = np.concatenate([[1.0], self.weights])[i]
        r = rot.quat_from_axis_angle(axis[rep], phi[rep] * w)
        return rep, sel, rot.quat_canonical(rot.quat_mul(r, ctx.quat[sel]))

    def recover(self, rec, status):
        """Slerp every segment toward its target; stop before contact."""
        ctx, s, p = self.ctx, self.ctx.s, self.ctx.prec
        seg, rep, starts = ctx.segments(rec)
        q0 = ctx.quat[seg]
        ident = np.zeros_like(q0)
        ident[:, 0] = 1.0
        frac = ctx.target_fraction(rec)
        hold = np.isnan(frac)
        qt = rot.quat_slerp(ident, ctx.quat_max[seg], np.nan_to_num(frac)[rep])
        qt = np.where(hold[rep][:, None], q0, qt)

        q1 = rot.quat_slerp(q0, qt, np.full(len(q0), s.recovery_rate))
        # Within half a precision step of the target (every segment): land on it.
        conj = qt * np.array([1.0, -1.0, -1.0, -1.0])
        near_t = rot.quat_angle(rot.quat_mul(q1, conj)) < tol.SNAP_FRACTION * p
        snap = np.logical_and.reduceat(near_t, starts)
        q1 = np.where(snap[rep][:, None], qt, q1)
        moving = ~np.all(q1 == q0, axis=1)
        moving_c = np.logical_or.reduceat(moving, starts)
        is_near = ctx.cand_any[rec]
        chk = np.flatnonzero(moving_c & is_near)
        blocked = np.zeros(len(rec), bool)
        if len(chk):
            sseg, srep, _ = ctx.segments(rec[chk])
            pos = np.searchsorted(seg, sseg)
            blocked[chk] = ctx.curve_hits(rec[chk], quat=q1[pos])
        if blocked.any():
            b = np.flatnonzero(blocked)
            # Bisect the recovery fraction on 16 levels (finer than precision
            # for any recovery step a frame can take).
            levels = 16

            def test(items, ks):
                c = rec[b[items]]
                sseg, srep, _ = ctx.segments(c)
                pos = np.searchsorted(seg, sseg)
                lamk = (ks / levels * s.recovery_rate)[srep]
                q = rot.quat_slerp(q0[pos], qt[pos], lamk)
                return ~ctx.curve_hits(c, quat=q)

            # The largest safe fraction is the smallest good k of the reversed
            # grid (fraction levels - k): k = levels (fraction 0) is known good.
            def test_rev(items, ks):
                return test(items, levels - ks)

            kr = _gallop_bisect(len(b), test_rev, np.full(len(b), levels),
                                lo=np.zeros(len(b)), hi=np.full(len(b), levels))
            sseg, srep, _ = ctx.segments(rec[b])
            pos = np.searchsorted(seg, sseg)
            lamk = ((levels - kr) / levels * s.recovery_rate)[srep]
            q1[pos] = rot.quat_slerp(q0[pos], qt[pos], lamk)
        ctx.quat[seg] = q1
        changed = np.logical_or.reduceat(~np.all(q1 == q0, axis=1), starts)
        identity = np.logical_and.reduceat(np.all(q1 == ident, axis=1), starts)
        st = np.where(blocked, Status.COLLIDING,
                      np.where(changed & ~identity, Status.RECOVERING, Status.FREE))
        status[rec] = np.maximum(status[rec], st)
        # Back exactly at the input shape: drop the state.
        done = rec[identity]
        ctx.active[done] = False
        dseg, _, _ = ctx.segments(done)
        ctx.quat_max[dseg] = ident[: len(dseg)]
