"""Wind, jiggle and the Region of Influence around the solver (paper section 4).

Thin glue, no Blender data: every computation is a :mod:`..core.pipeline` call, driven
by a setup's motion settings ``m`` (its ``furcollide.motion`` property group, or any
object with the same attributes).

* **Motion before collision** (``Stage = Before Collision``): wind and/or jiggle
  move the input curves; FurCollide resolves the moved curves
  (:func:`frame_inputs.prepare_input`).
* **Motion after collision** (``Stage = After Collision``): wind and/or jiggle
  move the collided curves, restricted per point by the **Region of Influence**
  (:func:`core.pipeline.region_of_influence`) to less than its **Fur Collider
  Distance**, so the result stays collision free (:func:`output_stage`).
* **Collider distance attribute**: ``furcollide_collider_distance`` on the
  output, the distance of every point's segments to the colliders.

Jiggle needs the roots of the last frames: the frame rules record them
(:class:`RootHistory`) while they play; frames never seen take the roots of the
nearest later frame seen (hair at rest before the start frame).
"""

from __future__ import annotations

import numpy as np

from ..core import pipeline
from .clock import clock

#: Per-point attribute with the Fur Collider Distance on the output.
DISTANCE_ATTRIBUTE = "furcollide_collider_distance"
#: Frames of root history kept per setup for jiggle (its window is at most 240).
HISTORY_FRAMES = 480


def fps(scene) -> float:
    """Frames per second of ``scene``."""
    return scene.render.fps / (scene.render.fps_base or 1.0)


# ------------------------------------------------------------- root history
class RootHistory:
    """Curve roots (world) per whole frame, recorded by the frame rules for jiggle. It
    belongs to one curve layout: the runtime clears it when the layout changes."""

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
        """Roots at frame ``f``: recorded, else those of the nearest later recorded frame."""
        got = self.frames.get(int(round(f)))
        if got is not None:
            return got
        later = [k for k in self.frames if k > f]
        k = min(later) if later else max(self.frames)
        return self.frames[k]


# -------------------------------------------------------------------- motion
def _wind(m, points, offsets, f, fps, threads):
    return pipeline.wind(
        points, offsets, f, direction=tuple(m.wind_direction), strength=m.wind_strength,
        frequency=m.wind_frequency, turbulence=m.wind_turbulence, falloff=m.wind_falloff,
        seed=m.wind_seed, scale=m.wind_scale, fps=fps, threads=threads,
    )


def _jiggle(m, points, offsets, f, fps, history):
    return pipeline.jiggle(
        points, offsets, history.lookup, frame=f, fps=fps,
        stiffness=m.jiggle_stiffness, damping=m.jiggle_damping, amount=m.jiggle_amount,
        falloff=m.jiggle_falloff,
    )


def apply_motion(m, stage, points, offsets, f, fps, history,
                 threads=None) -> np.ndarray | None:
    """Wind then jiggle of the motion settings ``m`` that run at ``stage`` ('INPUT' or
    'OUTPUT'); None when none does. ``points`` (P, 3) world; returns float64. ``threads``:
    the setup's Threads (None: all CPUs; the same result for any count)."""
    with clock.timing("motion"):
        return _apply_motion(m, stage, points, offsets, f, fps, history, threads)


def _apply_motion(m, stage, points, offsets, f, fps, history, threads):
    out = None
    if m.use_wind and m.wind_stage == stage and m.wind_strength > 0:
        out = _wind(m, points if out is None else out, offsets, f, fps, threads)
    if m.use_jiggle and m.jiggle_stage == stage and m.jiggle_amount > 0 and history.frames:
        out = _jiggle(m, points if out is None else out, offsets, f, fps, history)
    return out


def needs_history(m) -> bool:
    """Does the motion settings ``m``'s result depend on the roots of earlier frames?"""
    return bool(m.use_jiggle)


def output_stage(m, points, offsets, f, fps, history, colliders, threads=None):
    """Motion after collision with its Region of Influence, and the collider distance.

    Parameters
    ----------
    m : the setup's motion settings.
    points : (P, 3) float32 ndarray
        The solver's collided curves (world).
    offsets : (C+1,) int ndarray
    f : int
        Frame.
    fps : float
        The scene's frames per second (wind and jiggle run on seconds).
    history : RootHistory
    colliders : list of core.Collider
        This frame's colliders.
    threads : int or None
        The setup's Threads (None: all CPUs).

    Returns
    -------
    points : (P, 3) float32 ndarray
        Final curves (``points`` itself when nothing moved them).
    attributes : dict
        ``{DISTANCE_ATTRIBUTE: (P,) float32}`` when the attribute is on.
    """
    moved = apply_motion(m, "OUTPUT", points, offsets, f, fps, history, threads)
    with clock.timing("motion"):
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
        distance = _distance(points, offsets, colliders, cap)
        if want_attr:  # nothing within the cap (no collider either): the cap
            shown = distance if attr_cap is None else np.minimum(distance, attr_cap)
            attributes[DISTANCE_ATTRIBUTE] = np.asarray(shown, np.float32)
    if moved is None:
        return points, attributes
    if want_roi:
        moved = pipeline.region_of_influence(points, offsets, moved, distance,
                                             margin=m.roi_margin)
    return np.asarray(moved, np.float32), attributes


def _distance(points, offsets, colliders, cap):
    if not colliders:
        return np.full(len(points), np.inf)
    return pipeline.collider_distance(points, offsets, colliders, max_distance=cap)
