"""Milliseconds per pipeline stage of the frame being evaluated.

The stages of a frame (attach, collide, motion, groom, children, clearance, write) add
their time to :data:`clock`; the frame rules start it for each setup's frame and put its
figures into the setup's statistics (``attach_ms`` ...), which the Fur Pipeline panel
shows and ``make bench-pipeline`` prints. Frames are evaluated one setup at a time, so
one clock serves them all.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

#: The stages, in the order a frame runs them.
#: (children: evaluating the output's children stack and reading its result.)
STAGES = ("attach", "collide", "motion", "groom", "children", "clearance", "write")


class StageClock:
    """Accumulated milliseconds per stage since :meth:`start`."""

    def __init__(self):
        self.ms: dict = {}

    def start(self) -> None:
        self.ms = {}

    def add(self, stage: str, ms: float) -> None:
        self.ms[stage] = self.ms.get(stage, 0.0) + float(ms)

    @contextmanager
    def timing(self, stage: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.add(stage, 1e3 * (time.perf_counter() - t0))

    def stats(self) -> dict:
        """``{"attach_ms": ..., ...}``: every stage, 0 when it did not run."""
        return {f"{s}_ms": float(self.ms.get(s, 0.0)) for s in STAGES}


clock = StageClock()
