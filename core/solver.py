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
until the curve has recovered (no pops when hit normals change). At the
first hit the curve turns away along the collider's normal (paper 3.2.1),
toward the growth surface (Attract to Growth Surface) or, with Follow
Collider Motion, along the collider's motion at the contact.

Parameter maps: Max Angle, Scale Minimum, Recovery Rate, Plasticity,
Collision Offset and Clearance Margin may be given per curve (``Settings``);
each curve uses its own values (per-curve clearances test each collider as
a few offset shells, ``Collider.clearance_groups``).

Where things are
----------------
:mod:`.curves` (``CurveLayout``: where each curve's points and segments
are; the rule for the curves the solver leaves as they are, INVALID),
:mod:`.state` (``SolverState``: what one step hands the next),
:mod:`.step` (a step's shared machinery: candidates, local frames,
deformation, batched ray queries, first hits, Put to Growth Surface),
:mod:`.rigid` (Stiff, Bend, the warm-start search, Shrink, Recovery,
Plasticity), :mod:`.soft` (Soft, Affected Connected CVs, CV FallOff): each
returns its curves' rotations, which ``StepContext.apply`` takes,
:mod:`.search` (Rotation Precision: the batched gallop-and-bisect and the
scan for Soft), :mod:`.collider` (the Collider facade and its parts: mesh,
pose, occupancy grid, offset shells and hits, inside test),
:mod:`.meshfix` (welded seams, duplicated faces, outward windings),
:mod:`.rays` (the embree adapter); :mod:`.pipeline.frame` runs a frame's
stages around the step (``Shot``).
"""

from __future__ import annotations

import time

import numpy as np

from . import curves
from .collider import Collider
from .curves import CurveLayout
from .errors import InputError, SettingsError
from .rays import beside
from .settings import Settings
from .state import STATE_VERSION, SolverState
from .status import Status, StepResult
from .step import StepContext

__all__ = ["Solver", "Status", "StepResult"]


def _ms_since(t0: float) -> float:
    """Milliseconds since ``t0`` (a ``time.perf_counter()`` reading): every
    phase of ``res.timings``."""
    return (time.perf_counter() - t0) * 1e3


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

    #: Stiff/Bend: start each step's angle search from the curves' memory of
    #: the last step (rigid.Plan; Soft: its blocked recoveries). False: the
    #: full search from the current angle (the reference the warm start is
    #: tested against). Both give the same result.
    warm_start = True

    def __init__(self, offsets, settings: Settings | None = None):
        self.layout = CurveLayout(offsets)
        self._settings = Settings() if settings is None else self._check_settings(settings)
        self._groups = {}  # per-curve clearance groups of the settings (see _clearances)
        self.reset()

    @property
    def n_curves(self) -> int:
        return self.layout.n_curves

    @property
    def n_points(self) -> int:
        return self.layout.n_points

    # ------------------------------------------------------------ settings
    def _check_settings(self, s):
        if not isinstance(s, Settings):
            raise SettingsError(f"settings must be a core.Settings, got {type(s).__name__}")
        s.check_curve_count(self.n_curves)
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
        self._groups = {}
        if mode_changed:
            self.reset()

    # --------------------------------------------------------------- state
    def reset(self):
        """Forget every curve's history (the next step starts afresh)."""
        self._state = SolverState.fresh(self.n_curves, self.layout.n_segments)

    @property
    def state(self) -> dict:
        """Snapshot (copies) of all per-curve state as numpy arrays.

        Restoring it with ``solver.state = snapshot`` makes the next step
        bit-identical to what it was after the snapshot. Only numpy arrays:
        it can be written with ``np.savez`` and read without pickle. The
        per-segment ``quat`` arrays are only present in Soft mode. See
        :class:`core.state.SolverState` for what each holds.
        """
        mode = ("stiff", "bend", "soft").index(self._settings.mode)
        st = self._state
        out = {k: getattr(st, k).copy() for k in SolverState.SHAPES
               if mode == 2 or k not in SolverState.SOFT}
        out["meta"] = np.array([STATE_VERSION, self.n_curves, self.n_points, mode], np.int64)
        return out

    @state.setter
    def state(self, s):
        if not isinstance(s, dict) and not hasattr(s, "keys"):
            raise InputError("state must be a dict of numpy arrays (from Solver.state)")
        if "meta" not in s.keys():
            raise InputError("state is missing ['meta'] (not a Solver.state snapshot)")
        meta = np.asarray(s["meta"])
        if meta.shape != (4,) or not np.issubdtype(meta.dtype, np.integer):
            raise InputError("state['meta'] must be 4 integers (from Solver.state)")
        if (
            int(meta[0]) != STATE_VERSION
            or int(meta[1]) != self.n_curves
            or int(meta[2]) != self.n_points
        ):
            raise InputError("state was saved for other curves (curve/point count differs)")
        if int(meta[3]) != ("stiff", "bend", "soft").index(self._settings.mode):
            raise InputError("state was saved with another mode")
        soft = self._settings.mode == "soft"
        keys = {k: v for k, v in SolverState.SHAPES.items() if soft or k not in SolverState.SOFT}
        missing = set(keys) - set(s.keys()) - set(SolverState.OPTIONAL)
        if missing:
            raise InputError(f"state is missing {sorted(missing)}")
        dims = {"C": self.n_curves, "S": self.layout.n_segments}
        arrs = {}
        for k, shape in keys.items():
            if k not in s.keys():
                continue
            a = np.asarray(s[k])
            want = tuple(dims.get(d, d) for d in shape)
            if a.shape != want:
                raise InputError(f"state['{k}'] has shape {a.shape}, expected {want}")
            if not (np.issubdtype(a.dtype, np.number) or a.dtype == bool):
                raise InputError(f"state['{k}'] must be numeric, got dtype {a.dtype}")
            if not np.isfinite(a).all():
                raise InputError(f"state['{k}'] has non-finite values")
            arrs[k] = a
        self._state = SolverState.from_arrays(arrs, self.n_curves, self.layout.n_segments)

    # --------------------------------------------------------------- input
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

    def _clearances(self, colliders):
        """``(cols, groups)`` for the step: one ``(collider, distance)`` entry
        per offset shell the curves are tested against and, per entry, the
        curves kept at that distance ((C,) bool, None: all). Plain settings
        give one entry per collider, as ever; per-curve offsets or margins
        several (:meth:`Collider.clearance_groups`), computed once per
        settings and collider offset."""
        s = self._settings
        cols, groups = [], []
        for c in colliders:
            key = c.offset
            g = self._groups.get(key)
            if g is None:
                g = c.clearance_groups(s.collision_offset, s.clearance_margin,
                                       s.clearance_rounding(c))
                if len(self._groups) >= 16:  # (colliders' own offsets keyed over a shot)
                    self._groups.clear()
                self._groups[key] = g
            for dist, mask in g:
                cols.append((c, dist))
                groups.append(mask)
        return cols, groups

    # ------------------------------------------------------------ the step
    def step(self, points, colliders=(), growth=None, enabled=None) -> StepResult:
        """Solve one frame.

        Parameters
        ----------
        points : (P, 3) ndarray of float32 or float64
            This frame's input curves, world space.
        colliders : sequence of Collider
            Meshes the curves must not pass through (world transforms in
            their ``matrix``). Empty colliders are ignored. With
            ``Settings.follow_collider_motion``, a collider's motion since
            its previous placement (:attr:`Collider.previous`, e.g. updated
            once per frame with :meth:`Collider.place`) steers the curves it
            starts to push.
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
        s = self._check_settings(self._settings)
        points = curves.check_points(points, self.n_points)
        enabled = self._check_enabled(enabled)
        # Curves the solver cannot work with (a non-finite point, a zero-length
        # segment: core.curves) are left as they are (INVALID) and every other
        # curve is solved: the step works on stand-ins for them.
        given = points
        off = self.layout.offsets
        invalid, why = curves.non_finite(points, off)
        reasons = [(int(np.argmax(invalid)), why)] if invalid.any() else []
        if invalid.any():
            points = curves.stand_ins(given, off, invalid)
        if colliders is None:
            colliders = ()
        elif isinstance(colliders, Collider):
            colliders = [colliders]
        cols = []
        for i, c in enumerate(colliders):
            if not isinstance(c, Collider):
                raise InputError(f"colliders[{i}] is a {type(c).__name__}, not a core.Collider")
            if not c.empty:
                cols.append(c)
        cols, groups = self._clearances(cols)
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

        layout, state = self.layout, self._state
        warm = bool(self.warm_start)
        waits = []  # background work of this step: never left running on error
        try:
            ctx = StepContext(layout, state, s, points, cols, growth, warm, groups)
            waits += ctx.builds
            if ctx.degenerate.any():
                reasons.append((int(np.argmax(ctx.degenerate)), ctx.degenerate_reason))
                invalid = invalid | ctx.degenerate
                points = curves.stand_ins(given, off, invalid)
                ctx = StepContext(layout, state, s, points, cols, growth, warm, groups)
                waits += ctx.builds
            enabled = enabled & ~invalid
            problems = curves.invalid_report(invalid, reasons)
            seg_invalid = np.repeat(invalid, layout.nseg)
            kept = state.rows(invalid, seg_invalid) if invalid.any() else None
            timings = ctx.timings
            timings["setup"] = _ms_since(t_start)

            C = self.n_curves
            status = np.zeros(C, np.int8)
            status[~enabled] = Status.DISABLED

            # Pinch detection (paper 3.1): roots inside closed single-sided
            # colliders, on a ray thread while the main thread builds the local
            # frames of every curve that carries state (independent work).
            def pinch():
                t0 = time.perf_counter()
                pinched = np.zeros(C, bool)
                for k in range(len(cols)):
                    pinched |= ctx.roots_inside(k, enabled)
                timings["pinch"] = _ms_since(t0)
                return pinched

            pinch_result = beside(pinch, ctx.threads if cols else 1)
            waits.append(pinch_result)
            t0 = time.perf_counter()
            ctx.load_state()
            timings["frames"] = _ms_since(t0)
            pinched = pinch_result()
            for b in waits:  # wait for the builds (and re-raise their errors)
                b()
        except BaseException:
            for b in waits:
                try:
                    b()
                except BaseException:  # the first error is the one to report
                    pass
            raise

        t0 = time.perf_counter()
        was_pinched = state.pinched
        out_of_pinch = was_pinched & ~pinched & enabled
        if not s.recover_pinched:
            state.hold |= out_of_pinch & state.active
        pin = np.flatnonzero(pinched)
        status[pin] = Status.PINCHED
        if len(pin) and s.pinch_resolution == "growth_surface":
            ctx.put_to_growth_surface(pin)
        state.pinched = pinched & enabled | (was_pinched & ~enabled)

        solve = enabled & ~pinched & (ctx.cand_any | state.active)
        idx = np.flatnonzero(solve)
        if len(idx):
            ctx.solve(idx, status)
        ctx.remember(status, enabled)
        timings["solve"] = _ms_since(t0)

        t0 = time.perf_counter()
        # Independent: the next step's state on a ray thread, the output here.
        # Output only gathers and rotates arrays already checked, so it cannot
        # fail on input; should it fail otherwise (out of memory), the state
        # has advanced all the same: restore a snapshot (solver.state) or
        # reset() before solving that frame again.
        stored = beside(ctx.store_state, ctx.threads)
        try:
            out = ctx.output()
        finally:
            stored()
        if invalid.any():
            rows, own = curves.given_rows(given, off, invalid)
            out[rows] = own
            status[invalid] = Status.INVALID
            state.put_rows(invalid, seg_invalid, kept)  # their state: as before this step
        timings["output"] = _ms_since(t0)
        timings["total"] = _ms_since(t_start)
        timings["rays"] = ctx.n_rays
        return StepResult(out, status, timings, problems)
