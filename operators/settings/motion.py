"""Wind, jiggle, the Region of Influence and the collider distance of a setup: its
settings read into the core's plain values.

The stages are the core's (:mod:`..core.pipeline.frame`: ``before_collision`` once a
frame's input is read, ``solve`` for the solver and the stages after it, and the
``RootHistory`` jiggle reads); here only the setup's ``furcollide.motion`` property
group is read into a :class:`core.pipeline.frame.Motion` (:func:`values`), and the
scene's frame rate (:func:`fps`: wind and jiggle run on seconds).
"""

from __future__ import annotations

from ...core.pipeline.frame import Motion


def fps(scene) -> float:
    """Frames per second of ``scene``."""
    return scene.render.fps / (scene.render.fps_base or 1.0)


def values(m) -> Motion:
    """The motion settings ``m`` (a setup's ``furcollide.motion``) as plain values."""
    return Motion.of(m)
