"""Per-curve outcome codes and the result of a solver step."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np


class Status(IntEnum):
    """Per-curve outcome of a step (``StepResult.status`` values)."""

    FREE = 0  #: not in contact, shape unchanged this frame
    COLLIDING = 1  #: in contact: rotated to clear, or recovery blocked
    RECOVERING = 2  #: clear, rotating back toward its input shape
    PINCHED = 3  #: root inside a closed collider (not solved, see pinch_resolution)
    UNRESOLVED = 4  #: not clearable within max_angle: keeps the previous frame's local state
    DISABLED = 5  #: switched off by ``enabled``: prior local state kept
    INVALID = 6  #: a zero-length segment or a non-finite point: left as its input, not solved


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
    problems : list of str
        What is wrong with the curves marked ``INVALID`` this step: the first
        such curve by index with its reason, and how many there are (empty
        when every curve is fine).
    """

    points: np.ndarray
    status: np.ndarray
    timings: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)

    def count(self, status: Status) -> int:
        """Number of curves with ``status``."""
        return int(np.count_nonzero(self.status == status))
