"""How the probes' rays use the ray-tracing threads (``Settings.threads``).

The answers never depend on the thread count (``test_state_props.py``:
``test_thread_count_never_changes_a_bit``); these tests hold how the threads are
used, which only a benchmark would otherwise see: a probe batch of a few curves is
traced on all of the step's threads, a large one is built and traced in two halves
by two threads, each half tracing on its own thread (not both halves on both
threads: four tracers on two cores). A step with many curves of work is solved in
two halves, one per thread (``core.step.SPLIT_MIN_CURVES``).
"""

from __future__ import annotations

import sys
import threading

import numpy as np
import pytest
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


# ------------------------------------------------------------ a step in two halves
def _solves(monkeypatch, split_from):
    """Record (thread, curves, ctx.threads) of every mode solve of a step, the
    split threshold set to ``split_from`` curves of work."""
    from core import rigid, step

    monkeypatch.setattr(step, "SPLIT_MIN_CURVES", split_from)
    seen = []
    for name, fn in (("rigid", rigid.solve), ("soft", step._solve_soft)):
        def spy(ctx, idx, status, fn=fn):
            seen.append((threading.get_ident(), np.array(idx), ctx.threads))
            return fn(ctx, idx, status)

        if name == "rigid":
            monkeypatch.setattr(rigid, "solve", spy)
        else:
            monkeypatch.setattr(step, "_solve_soft", spy)
    return seen


def _two_steps(mode, threads):
    pts, offs, col = _pressed_grid(20)  # 400 curves under a sheet
    solver = Solver(offs, Settings(mode=mode, threads=threads))
    first = solver.step(pts, [col])
    second = solver.step(pts, [col])
    return first, second


@pytest.mark.parametrize("mode", ["bend", "soft"])
def test_a_step_with_much_work_is_solved_in_two_halves_one_thread_each(monkeypatch, mode):
    """Stiff/Bend count the rotated curves near a collider (the ones searched: none
    on the first step of a groom), Soft every curve solved. The halves interleave
    the curves, each solved on its own thread with one ray thread, and together
    give what one thread gives, rays counted once."""
    ref = _two_steps(mode, 1)
    seen = _solves(monkeypatch, 100)
    got = _two_steps(mode, 2)
    per_step = [seen[:1], seen[1:]] if mode == "bend" else [seen[:2], seen[2:]]
    if mode == "bend":
        assert len(seen[0][1]) == 400 and seen[0][2] == 2  # nothing rotated yet: whole
    for calls in per_step[1 if mode == "bend" else 0:]:
        assert len(calls) == 2, [(len(i), t) for _, i, t in calls]
        # (in whichever order the two threads started)
        (ta, ia, na), (tb, ib, nb) = sorted(calls, key=lambda c: c[1][0])
        assert ta != tb and na == nb == 1
        whole = np.sort(np.concatenate([ia, ib]))
        assert len(whole) == len(ia) + len(ib) and abs(len(ia) - len(ib)) <= 1
        assert np.array_equal(ia, whole[0::2]) and np.array_equal(ib, whole[1::2])
    for a, b in zip(got, ref, strict=True):
        assert np.array_equal(a.points, b.points) and np.array_equal(a.status, b.status)
        assert a.timings["rays"] == b.timings["rays"]
    assert (got[1].status == 1).sum() > 100  # (COLLIDING: the sheet presses the grid)


@pytest.mark.parametrize("threads, split_from", [(2, 10_000), (1, 1)])
def test_a_step_with_little_work_or_one_thread_is_solved_whole(monkeypatch, threads, split_from):
    seen = _solves(monkeypatch, split_from)
    _two_steps("bend", threads)
    assert [len(i) for _, i, _ in seen] == [400, 400]
    assert {t for _, _, t in seen} == {threads}
    assert {tid for tid, _, _ in seen} == {threading.get_ident()}


def test_an_error_in_the_other_half_reaches_the_caller(monkeypatch):
    """The half on the pool thread fails: the step raises its error (after the
    caller's own half has finished; no half is left running)."""
    from core import rigid, step

    monkeypatch.setattr(step, "SPLIT_MIN_CURVES", 100)
    pts, offs, col = _pressed_grid(20)
    solver = Solver(offs, Settings(mode="bend", threads=2))
    solver.step(pts, [col])
    main = threading.get_ident()
    solve = rigid.solve
    finished = []

    def spy(ctx, idx, status):
        if threading.get_ident() != main:
            raise MemoryError("the pool thread's half")
        solve(ctx, idx, status)
        finished.append(len(idx))

    monkeypatch.setattr(rigid, "solve", spy)
    with pytest.raises(MemoryError, match="pool thread"):
        solver.step(pts, [col])
    assert finished  # the caller's half ran to its end before the error was raised
