"""How the probes' rays use the ray-tracing threads (``Settings.threads``).

The answers never depend on the thread count (``test_state_props.py``:
``test_thread_count_never_changes_a_bit``); these tests hold how the threads are
used, which only a benchmark would otherwise see: a probe batch of a few curves is
traced on all of the step's threads, a large one is built and traced in two halves
by two threads, each half tracing on its own thread (not both halves on both
threads: four tracers on two cores).
"""

from __future__ import annotations

import sys

import numpy as np
import scenes

from core import Collider, Settings, Solver


def _probe_tracing(monkeypatch):
    """Record (first probe a, stop b, thread count) of every ray query made by a
    probe batch (a > 0: a second half)."""
    seen = []
    segment_hits_local = Collider.segment_hits_local

    def spy(self, o, d, offset_wo=0.0, threads=1):
        caller = sys._getframe(1)
        if caller.f_code.co_name == "part":  # rigid.RigidBatch's probe batches
            seen.append((caller.f_locals["a"], caller.f_locals["b"], threads))
        return segment_hits_local(self, o, d, offset_wo, threads)

    monkeypatch.setattr(Collider, "segment_hits_local", spy)
    return seen


def _pressed_grid(n):
    g = (np.arange(n) + 0.5) / n * 2 - 1
    X, Y = np.meshgrid(g, g, indexing="ij")
    curves = [scenes.straight_curve([x, y, 0.0], [0.0, 0.0, 1.0], 0.8, 6)
              for x, y in zip(X.ravel(), Y.ravel(), strict=True)]
    pts, offs = scenes.pack(curves, np.float32)
    V, F = scenes.grid(size=3.0, n=12, z=0.5)
    return pts, offs, Collider(V, F)


def test_a_few_probes_are_traced_on_all_threads(monkeypatch):
    seen = _probe_tracing(monkeypatch)
    pts, offs, col = _pressed_grid(4)
    Solver(offs, Settings(mode="bend", threads=2)).step(pts, [col])
    assert seen and {(t, a > 0) for a, _, t in seen} == {(2, False)}, seen


def test_a_large_probe_batch_is_traced_in_two_halves_one_thread_each(monkeypatch):
    seen = _probe_tracing(monkeypatch)
    pts, offs, col = _pressed_grid(50)  # 2,500 curves under a sheet: rounds of > 2,048
    res = Solver(offs, Settings(mode="bend", threads=2)).step(pts, [col])
    assert (res.status > 0).sum() > 2048
    halves = [t for a, _, t in seen if a > 0]
    assert halves and set(halves) == {1}, seen  # a second half: on its own thread
    assert any(a == 0 and t == 1 for a, _, t in seen)  # (and its first half)


def test_a_batch_of_exactly_two_blocks_is_traced_in_two_halves(monkeypatch):
    """The split starts at two blocks of probes (``rigid._BLOCK``): a batch of exactly
    that many is built and traced in two halves of one block each."""
    from core import rigid

    sizes = []
    hits_uniform = rigid.RigidBatch._hits_uniform

    def count(self, items, theta, hit):
        sizes.append(len(items))
        return hits_uniform(self, items, theta, hit)

    monkeypatch.setattr(rigid.RigidBatch, "_hits_uniform", count)
    pts, offs, col = _pressed_grid(6)
    Solver(offs, Settings(mode="bend", threads=2)).step(pts, [col])
    k = max(s for s in sizes if s % 2 == 0 and s >= 4)
    monkeypatch.setattr(rigid, "_BLOCK", k // 2)
    parts = _probe_tracing(monkeypatch)
    Solver(offs, Settings(mode="bend", threads=2)).step(pts, [col])
    assert (k // 2, k, 1) in parts and (0, k // 2, 1) in parts, (k, parts)
    assert (0, k, 2) not in parts
