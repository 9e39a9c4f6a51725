"""One frame of a shot from plain arrays: the stages around the solver (paper section 4).

A frame runs, in this order::

    attach          the curves follow the growth surface (optional: a Fur Attach Binding)
    motion before   wind and jiggle on the input curves (Stage = Before Collision)
    collide         Solver.step
    motion after    wind and jiggle on the collided curves, limited per point by the
                    Region of Influence; the collider distance attribute
    statistics      curves per Status, the frame, the solve time

:class:`Shot` runs the whole sequence for a script or a farm job: it owns the solver,
the root history jiggle reads and the motion settings, and takes each frame's arrays
(curves or the deformed surface, colliders). The Blender glue runs the same stages
one by one (:func:`before_collision` once the frame's input is read,
:func:`solve` for the rest), so playback, bakes and scripts give the same bits.

Motion settings are :class:`Motion` (plain values, the names of the setup's
``furcollide.motion`` properties). Jiggle reads the roots of earlier frames: a
:class:`RootHistory` records them as the frames play.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field, fields

import numpy as np

from .. import framecache
from .. import splines as splines_module
from ..settings import MAX_DISTANCE, Settings
from ..solver import Solver
from ..status import Status
from . import distance as _distance
from .influence import region_of_influence
from .motion import jiggle, wind

#: Per-point attribute with the Fur Collider Distance the frame writes.
DISTANCE_ATTRIBUTE = "furcollide_collider_distance"
#: Frames of root history kept for jiggle (its window is at most 240).
HISTORY_FRAMES = 480
#: The stages motion runs at.
STAGES = ("INPUT", "OUTPUT")


@dataclass(frozen=True)
class Motion:
    """Wind, jiggle, the Region of Influence and the collider distance attribute of a
    shot (plain values; the Blender setup's ``furcollide.motion`` has the same names).

    ``wind_stage`` and ``jiggle_stage``: ``'INPUT'`` (before collision: FurCollide
    resolves the moved curves) or ``'OUTPUT'`` (after it, limited by the Region of
    Influence when ``use_region_of_influence``). See :func:`core.pipeline.wind`,
    :func:`core.pipeline.jiggle`, :func:`core.pipeline.region_of_influence` and
    :func:`core.pipeline.collider_distance` for the values.
    """

    use_wind: bool = False
    wind_stage: str = "OUTPUT"
    wind_direction: tuple = (1.0, 0.0, 0.0)
    wind_strength: float = 0.05
    wind_frequency: float = 0.5
    wind_turbulence: float = 0.5
    wind_falloff: float = 1.5
    wind_scale: float = 1.0
    wind_seed: int = 0
    use_jiggle: bool = False
    jiggle_stage: str = "OUTPUT"
    jiggle_stiffness: float = 2.0
    jiggle_damping: float = 0.3
    jiggle_amount: float = 1.0
    jiggle_falloff: float = 1.0
    use_region_of_influence: bool = True
    roi_margin: float = 0.99
    write_collider_distance: bool = False
    distance_max: float = 0.0

    @classmethod
    def of(cls, values) -> Motion:
        """The motion settings read from ``values`` (any object with these attribute
        names, e.g. a Blender property group)."""
        kw = {f.name: getattr(values, f.name) for f in fields(cls)}
        kw["wind_direction"] = tuple(float(x) for x in kw["wind_direction"])
        return cls(**kw)

    @property
    def active(self) -> bool:
        """Does any stage change the curves or write the attribute?"""
        return bool(self.use_wind or self.use_jiggle or self.write_collider_distance)

    @property
    def needs_history(self) -> bool:
        """Does the result depend on the roots of earlier frames (jiggle)?"""
        return bool(self.use_jiggle)


# ------------------------------------------------------------- root history
class RootHistory:
    """Curve roots (world) per whole frame, recorded as the frames play, for jiggle.
    It belongs to one curve layout: clear it when the layout changes."""

    def __init__(self):
        self.frames: dict[int, np.ndarray] = {}

    def record(self, f: int, roots: np.ndarray) -> None:
        self.frames[int(f)] = np.asarray(roots, np.float32).copy()
        if len(self.frames) > HISTORY_FRAMES:  # forget the frames farthest from f
            far = sorted(self.frames, key=lambda k: (abs(k - f), k))[HISTORY_FRAMES:]
            for k in far:
                del self.frames[k]

    def clear(self) -> None:
        self.frames.clear()

    def drop_after(self, f: int) -> None:
        for k in [k for k in self.frames if k > f]:
            del self.frames[k]

    def lookup(self, f: int) -> np.ndarray:
        """Roots at frame ``f``: recorded, else those of the nearest later recorded
        frame (frames never seen: the hair at rest before the start frame)."""
        got = self.frames.get(int(round(f)))
        if got is not None:
            return got
        later = [k for k in self.frames if k > f]
        k = min(later) if later else max(self.frames)
        return self.frames[k]


# ------------------------------------------------------------------ stages
def apply_motion(m, stage, points, offsets, f, fps, history, threads=None):
    """Wind then jiggle of the motion settings ``m`` (:class:`Motion`) that run at
    ``stage`` ('INPUT' or 'OUTPUT'); None when none does. ``points`` (P, 3) world;
    returns float64. ``threads``: None for all CPUs (the same result for any count)."""
    out = None
    if m.use_wind and m.wind_stage == stage and m.wind_strength > 0:
        out = wind(
            points if out is None else out, offsets, f, direction=m.wind_direction,
            strength=m.wind_strength, frequency=m.wind_frequency,
            turbulence=m.wind_turbulence, falloff=m.wind_falloff, seed=m.wind_seed,
            scale=m.wind_scale, fps=fps, threads=threads,
        )
    if m.use_jiggle and m.jiggle_stage == stage and m.jiggle_amount > 0 and history.frames:
        out = jiggle(
            points if out is None else out, offsets, history.lookup, frame=f, fps=fps,
            stiffness=m.jiggle_stiffness, damping=m.jiggle_damping, amount=m.jiggle_amount,
            falloff=m.jiggle_falloff,
        )
    return out


def before_collision(m, points, offsets, f, fps, history, threads=None):
    """Motion before collision: the input curves ``points`` (P, 3) moved by the wind
    and jiggle of ``m`` that run before collision, as float32 (what the solver
    takes), or None when none does."""
    moved = apply_motion(m, "INPUT", points, offsets, f, fps, history, threads)
    return None if moved is None else np.asarray(moved, np.float32)


def after_collision(m, points, offsets, f, fps, history, colliders, threads=None):
    """Motion after collision with its Region of Influence, and the collider distance.

    Parameters
    ----------
    m : Motion
    points : (P, 3) float32 ndarray
        The solver's collided curves (world).
    offsets : (C+1,) int ndarray
    f : float
        Frame.
    fps : float
        Frames per second (wind and jiggle run on seconds).
    history : RootHistory
    colliders : list of core.Collider
        This frame's colliders.
    threads : int or None
        None: all CPUs.

    Returns
    -------
    points : (P, 3) float32 ndarray
        Final curves (``points`` itself when nothing moved them).
    attributes : dict
        ``{DISTANCE_ATTRIBUTE: (P,) float32}`` when ``m.write_collider_distance``.
    """
    moved = apply_motion(m, "OUTPUT", points, offsets, f, fps, history, threads)
    return _limit(m, points, offsets, moved, colliders)


def _limit(m, points, offsets, moved, colliders):
    """The collider distance (the attribute and the Region of Influence's limit), once
    per frame with the larger of the two caps, then the Region of Influence."""
    attributes = {}
    want_attr = bool(m.write_collider_distance)
    want_roi = moved is not None and bool(m.use_region_of_influence) and bool(colliders)
    if want_attr or want_roi:
        attr_cap = float(m.distance_max) if m.distance_max > 0 else None
        caps = [attr_cap] if want_attr else []
        if want_roi:
            # RoI only clamps displacements longer than the distance: capped at the
            # longest displacement, the distance gives the same result, faster.
            caps.append(float(np.sqrt(((moved - points) ** 2).sum(1).max()))
                        if len(points) else 0.0)
        cap = None if None in caps else max(caps)
        distance = collider_distance(points, offsets, colliders, cap)
        if want_attr:  # nothing within the cap (no collider either): the cap
            shown = distance if attr_cap is None else np.minimum(distance, attr_cap)
            attributes[DISTANCE_ATTRIBUTE] = np.asarray(shown, np.float32)
    if moved is None:
        return points, attributes
    if want_roi:
        moved = region_of_influence(points, offsets, moved, distance, margin=m.roi_margin)
    return np.asarray(moved, np.float32), attributes


def collider_distance(points, offsets, colliders, cap):
    """Fur Collider Distance of every point (``inf`` without a collider), at most
    ``cap`` (None: no cap)."""
    if not colliders:
        return np.full(len(points), np.inf)
    return _distance.collider_distance(points, offsets, colliders, max_distance=cap)


# ------------------------------------------------------------------- frame
@dataclass
class FrameResult:
    """One frame's result (:func:`solve`, :meth:`Shot.frame`).

    Attributes
    ----------
    points : (P, 3) float32 ndarray
        The frame's final curves (world), after the stages.
    status : (C,) int8 ndarray
        ``Status`` code per curve.
    attributes : dict
        Per-point attributes for the output (name -> (P,) array).
    changed : (P,) bool ndarray
        The points that differ from the input before motion (``raw``).
    stats : dict
        Statistics (:func:`frame_stats`).
    problems : list of str
        What is wrong with the curves the solver marked INVALID (``StepResult.problems``).
    timings : dict
        Milliseconds of the stages this call ran: ``collide`` (the solver's total),
        ``motion`` (the stages after collision, when they ran).
    """

    points: np.ndarray
    status: np.ndarray
    attributes: dict = field(default_factory=dict)
    changed: np.ndarray | None = None
    stats: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)


def solve(solver, points, offsets, frame, colliders=(), growth=None, enabled=None,
          motion=None, fps=24.0, history=None, threads=None, raw=None, splines=None,
          drawn=None) -> FrameResult:
    """Collide and the stages after it: one frame's solve from its (prepared) input.

    Parameters
    ----------
    solver : Solver
        Holds the previous frame's state (or was reset for the first frame).
    points : (P, 3) float32 ndarray
        The frame's input curves, world, after the motion before collision.
    offsets : (C+1,) int ndarray
    frame : float
    colliders : list of Collider
    growth : Collider, optional
    enabled : (C,) bool, optional
    motion : Motion, optional
        None: no stage after collision.
    fps : float
        Frames per second (the motion's time base).
    history : RootHistory, optional
        Jiggle's roots (needed with jiggle after collision).
    threads : int or None
        Threads of the stages (None: all CPUs).
    raw : (P, 3) ndarray, optional
        The input before motion (``FrameResult.changed`` is relative to it;
        default ``points``).
    splines : core.splines.Splines, optional
        How the curves are drawn (Blender's curve types, handles, NURBS): the
        solve widens their clearance so the drawn curve clears the colliders, not
        only its polygon (:func:`drawn_clearance`). None: drawn as polygons.
    drawn : core.splines.DrawnMargin, optional
        Keeps the last margin (one per shot); a new one when not given.

    Raises
    ------
    Exception
        Any error of the solver or a stage (the solver's state is then unknown).
    """
    with drawn_clearance(solver, points, offsets, enabled, splines, drawn):
        res = solver.step(points, colliders, growth=growth, enabled=enabled)
    timings = {"collide": res.timings.get("total", 0.0)}
    if motion is None or not motion.active:
        out, attributes = res.points, {}
    else:
        t0 = time.perf_counter()
        out, attributes = after_collision(motion, res.points, offsets, frame, fps,
                                          RootHistory() if history is None else history,
                                          colliders, threads)
        timings["motion"] = 1e3 * (time.perf_counter() - t0)
    stats = frame_stats(res.status, frame, res.timings.get("total", 0.0))
    changed = framecache.rows_differ(out, points if raw is None else raw)
    return FrameResult(out, res.status, attributes, changed, stats, list(res.problems),
                       timings)


@contextmanager
def drawn_clearance(solver, points, offsets, enabled, sp, drawn=None):
    """Widen the clearance of ``solver``'s step by the curves' drawn margin
    (:class:`core.splines.DrawnMargin` of splines ``sp``; nothing for None or Poly
    curves); its settings are restored afterwards.

    Every curve is widened by the largest margin of the frame, as
    ``Settings.clearance_margin`` (added to whatever offset applies to each collider,
    its own or the setting's): one shell per collider. Per-curve margins would make
    each collider one shell per level of margin, each level a ray query per search
    round (a BVH build per frame for a deforming collider); the frame's largest margin
    is a few thousandths of the hair's length.
    """
    if sp is None or sp.drawn_as_polygon:
        yield
        return
    settings = solver.settings
    widen = (drawn or splines_module.DrawnMargin()).largest(sp, points, offsets, settings,
                                                            enabled)
    if widen <= 0.0:
        yield
        return
    solver.settings = settings.replace(clearance_margin=min(widen, MAX_DISTANCE))
    try:
        yield
    finally:
        solver.settings = settings


def frame_stats(status, frame, solve_ms=0.0, source="solved") -> dict:
    """Statistics: the number of curves per ``Status`` (named in lower case; free
    curves are not counted), the frame, the solve time and where it came from."""
    counts = np.bincount(status.astype(np.intp, copy=False), minlength=len(Status))
    stats = {s.name.lower(): int(counts[s]) for s in Status if s != Status.FREE}
    stats.update(frame=int(frame), solve_ms=float(solve_ms), source=source)
    return stats


# -------------------------------------------------------------------- shot
class Shot:
    """A shot solved frame by frame from plain arrays (scripts, farm jobs).

    Parameters
    ----------
    offsets : (C+1,) array_like of int
        The curves' layout.
    settings : Settings, optional
        The solver's (default ``Settings()``).
    motion : Motion, optional
        Wind, jiggle, Region of Influence, collider distance (None: none).
    fps : float
        Frames per second (the motion's time base).
    binding : core.pipeline.Binding, optional
        Fur Attach: each frame's curves are the bound curves moved with the
        surface's vertices given to :meth:`frame`.
    frame_start : int, optional
        Jiggle's history starts here (frames before it count as the hair at rest).
    threads : int or None
        Threads of the stages (None: all CPUs; the solver's are ``settings.threads``).
    splines : core.splines.Splines, optional
        How the curves are drawn (None: as polygons). Hair Blender draws with its
        default Catmull-Rom type: ``Splines.catmull_rom(C)``; the solve then keeps
        the drawn curves clear, not only their polygons (:func:`drawn_clearance`).

    Examples
    --------
    >>> shot = Shot(offsets, Settings(mode="bend"), Motion(use_wind=True))
    >>> for f in frames:
    ...     res = shot.frame(f, points_at(f), colliders_at(f))
    ...     res.points, res.status, res.stats
    """

    def __init__(self, offsets, settings=None, motion=None, fps=24.0, binding=None,
                 frame_start=None, threads=None, splines=None):
        self.solver = Solver(offsets, settings if settings is not None else Settings())
        self.offsets = self.solver.layout.offsets
        self.motion = motion
        self.fps = float(fps)
        self.binding = binding
        self.frame_start = frame_start
        self.threads = threads
        self.history = RootHistory()
        self.splines = splines
        self.drawn = splines_module.DrawnMargin()

    def attach(self, surface):
        """The bound curves on the surface's vertices ``surface`` (n, 3) world,
        float32 (:class:`Binding` needed)."""
        return np.asarray(self.binding.apply(surface, self.threads), np.float32)

    def frame(self, frame, points=None, colliders=(), growth=None, enabled=None,
              surface=None) -> FrameResult:
        """Solve ``frame`` (frames in order: each step starts from the previous one's
        state; :meth:`Solver.reset` on ``self.solver`` starts afresh).

        Parameters
        ----------
        frame : float
        points : (P, 3) array_like, optional
            The frame's input curves, world (float32 or float64); with a binding,
            None: the bound curves on ``surface``.
        colliders : list of Collider
            Placed at this frame (``Collider.place``).
        growth : Collider, optional
        enabled : (C,) bool, optional
        surface : (n, 3) array_like, optional
            The growth surface's world vertices (with a binding).
        """
        t0 = time.perf_counter()
        raw = self.attach(surface) if points is None else points
        attach_ms = 1e3 * (time.perf_counter() - t0) if points is None else 0.0
        points = raw
        m = self.motion
        motion_ms = 0.0
        if m is not None and m.active:
            t0 = time.perf_counter()
            if m.needs_history and (self.frame_start is None or frame >= self.frame_start):
                self.history.record(frame, np.asarray(raw)[self.offsets[:-1]])
            moved = before_collision(m, raw, self.offsets, frame, self.fps, self.history,
                                     self.threads)
            if moved is not None:
                points = moved
            motion_ms = 1e3 * (time.perf_counter() - t0)
        result = solve(self.solver, points, self.offsets, frame, colliders, growth, enabled,
                       m, self.fps, self.history, self.threads, raw=raw,
                       splines=self.splines, drawn=self.drawn)
        result.timings["attach"] = attach_ms
        result.timings["motion"] = result.timings.get("motion", 0.0) + motion_ms
        return result
