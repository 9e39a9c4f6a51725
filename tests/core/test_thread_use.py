"""How the probes' rays use the ray-tracing threads (``Settings.threads``).

The answers never depend on the thread count (``test_state_props.py``:
``test_thread_count_never_changes_a_bit``); these tests hold how the threads are
used, which only a benchmark would otherwise see: a probe batch of a few curves is
traced on all of the step's threads, a large one is built and traced in two halves
by two threads, each half tracing on its own thread (not both halves on both
threads: four tracers on two cores). A step with many curves of work is solved in
two halves, one per thread (``core.tolerances.SPLIT_MIN_CURVES``). On N threads
both are N-way, one part per thread, with the bits of one thread (N = 2, 3, 4, 8).
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

    def spy(self, o, d, offset_wo=0.0, threads=1, reach=None):
        caller = sys._getframe(1)
        if caller.f_code.co_name == "part":  # rigid.RigidBatch's probe batches
            seen.append((caller.f_locals["a"], caller.f_locals["b"], threads))
        return segment_hits_local(self, o, d, offset_wo, threads, reach)

    monkeypatch.setattr(Collider, "segment_hits_local", spy)
    return seen


def _batch_sizes(monkeypatch):
    """The sizes of the probe batches the steps build, as they come."""
    from core import rigid

    sizes = []
    hits_uniform = rigid.RigidBatch._hits_uniform

    def count(self, items, theta, hit):
        sizes.append(len(items))
        return hits_uniform(self, items, theta, hit)

    monkeypatch.setattr(rigid.RigidBatch, "_hits_uniform", count)
    return sizes


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

    sizes = _batch_sizes(monkeypatch)
    pts, offs, col = _pressed_grid(6)
    Solver(offs, Settings(mode="bend", threads=2)).step(pts, [col])
    k = max(s for s in sizes if s % 2 == 0 and s >= 4)
    monkeypatch.setattr(rigid, "_BLOCK", k // 2)
    parts = _probe_tracing(monkeypatch)
    Solver(offs, Settings(mode="bend", threads=2)).step(pts, [col])
    assert (k // 2, k, 1) in parts and (0, k // 2, 1) in parts, (k, parts)
    assert (0, k, 2) not in parts


# ------------------------------------------------------------ a step in two halves
#: The phases a step may run in two halves: (module, function).
_PHASES = (("rigid", "_new_contacts"), ("rigid", "_search"), ("soft", "_solve"))


def _phases(monkeypatch, split_from):
    """Record (phase, thread, curve arrays, ctx.threads) of every call of the
    phases a step may split, the threshold set to ``split_from`` curves of work."""
    from core import rigid, soft, tolerances

    monkeypatch.setattr(tolerances, "SPLIT_MIN_CURVES", split_from)
    seen = []
    for mod_name, name in _PHASES:
        mod = rigid if mod_name == "rigid" else soft
        fn = getattr(mod, name)

        def spy(ctx, *parts, fn=fn, name=name, **kw):
            seen.append((name, threading.get_ident(), [np.array(p) for p in parts], ctx.threads))
            return fn(ctx, *parts, **kw)

        monkeypatch.setattr(mod, name, spy)
    return seen


def _two_steps(mode, threads):
    pts, offs, col = _pressed_grid(20)  # 400 curves under a sheet
    solver = Solver(offs, Settings(mode=mode, threads=threads))
    first = solver.step(pts, [col])
    second = solver.step(pts, [col])
    return first, second


def _assert_halves(calls):
    """Two calls on two threads, one ray thread each, every other curve of each array."""
    assert len(calls) == 2, [(n, [len(p) for p in parts]) for n, _, parts, _ in calls]
    (_, ta, pa, na), (_, tb, pb, nb) = calls
    assert ta != tb and na == nb == 1
    # (the steps' curve arrays are sorted; the two halves start in either order)
    wholes = [np.sort(np.concatenate([a, b])) for a, b in zip(pa, pb, strict=True)]

    def even_odd(x, y):
        return all(np.array_equal(a, w[0::2]) and np.array_equal(b, w[1::2])
                   for a, b, w in zip(x, y, wholes, strict=True))

    assert even_odd(pa, pb) or even_odd(pb, pa)


@pytest.mark.parametrize("mode", ["bend", "soft"])
def test_a_step_with_much_work_is_solved_in_two_halves_one_thread_each(monkeypatch, mode):
    """Stiff/Bend split the input test of the unrotated curves near a collider and
    the searches (rotated curves near a collider and new contacts), each by its own
    count; Soft every curve solved. The halves interleave the curves, each on its own
    thread with one ray thread, and together give what one thread gives, rays
    counted once."""
    ref = _two_steps(mode, 1)
    seen = _phases(monkeypatch, 100)
    pts, offs, col = _pressed_grid(20)
    solver = Solver(offs, Settings(mode=mode, threads=2))
    names = ["_new_contacts", "_search"] if mode == "bend" else ["_solve"]
    got, split = [], set()
    for _ in range(2):
        seen.clear()
        got.append(solver.step(pts, [col]))
        assert {n for n, *_ in seen} == set(names)
        for name in names:
            calls = [c for c in seen if c[0] == name]
            if len(calls) == 1:  # whole: under the threshold (the second step's input test)
                assert sum(len(p) for p in calls[0][2]) < 100 and calls[0][3] == 2
            else:
                _assert_halves(calls)
                split.add(name)
    assert split == set(names)
    for a, b in zip(got, ref, strict=True):
        assert np.array_equal(a.points, b.points) and np.array_equal(a.status, b.status)
        assert a.timings["rays"] == b.timings["rays"]
    assert (got[1].status == 1).sum() > 100  # (COLLIDING: the sheet presses the grid)


@pytest.mark.parametrize("mode", ["bend", "soft"])
@pytest.mark.parametrize("threads, split_from", [(2, 10_000), (1, 1)])
def test_a_step_with_little_work_or_one_thread_is_solved_whole(monkeypatch, mode, threads,
                                                              split_from):
    seen = _phases(monkeypatch, split_from)
    _two_steps(mode, threads)
    assert seen and {t for *_, t in seen} == {threads}
    assert {tid for _, tid, _, _ in seen} == {threading.get_ident()}
    if mode == "soft":
        assert [len(parts[0]) for *_, parts, _ in seen] == [400, 400]


def test_an_error_in_the_other_half_reaches_the_caller(monkeypatch):
    """The half on the pool thread fails: the step raises its error (after the
    caller's own half has finished; no half is left running)."""
    from core import rigid, tolerances

    monkeypatch.setattr(tolerances, "SPLIT_MIN_CURVES", 100)
    pts, offs, col = _pressed_grid(20)
    solver = Solver(offs, Settings(mode="bend", threads=2))
    solver.step(pts, [col])
    main = threading.get_ident()
    search = rigid._search
    finished = []

    def spy(ctx, act, cn, turns):
        if threading.get_ident() != main:
            raise MemoryError("the pool thread's half")
        search(ctx, act, cn, turns)
        finished.append(len(act))

    monkeypatch.setattr(rigid, "_search", spy)
    with pytest.raises(MemoryError, match="pool thread"):
        solver.step(pts, [col])
    assert finished  # the caller's half ran to its end before the error was raised


# ------------------------------------------------------------ N threads
def test_the_split_count_is_one_part_per_thread_of_at_least_half_the_threshold():
    from core.rays import split_count

    assert [split_count(n, 8, 100) for n in (99, 100, 149, 150, 250, 400, 10**6)] == \
        [1, 2, 2, 3, 5, 8, 8]
    assert split_count(10**6, 1, 100) == 1
    assert split_count(10**6, 3, 100) == 3
    assert split_count(3, 8, 1) == 3  # never more parts than items


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
@pytest.mark.parametrize("threads", [2, 3, 4, 8])
def test_a_step_split_n_ways_gives_the_bits_of_one_thread(monkeypatch, mode, threads):
    """Forced to split (the threshold at 100 curves of work, 400 curves pressed),
    a step on N threads solves its phases in N parts, each with every N-th curve
    and one ray thread, and gives the bits and the ray count of one thread."""
    ref = _two_steps(mode, 1)
    seen = _phases(monkeypatch, 100)
    got = _two_steps(mode, threads)
    for a, b in zip(got, ref, strict=True):
        assert np.array_equal(a.points, b.points) and np.array_equal(a.status, b.status)
        assert a.timings["rays"] == b.timings["rays"]
    split = [c for c in seen if c[3] == 1]
    assert split, seen
    for name in {n for n, *_ in split}:
        calls = [c for c in split if c[0] == name]
        assert len(calls) % threads == 0, (name, len(calls))
        first = calls[:threads]
        assert len({tid for _, tid, _, _ in first}) >= 2
        # each curve array of the phase: call k of N has every N-th curve from the k-th
        for arrays in zip(*(c[2] for c in first), strict=True):
            whole = np.sort(np.concatenate(arrays))
            by_start = sorted(arrays, key=lambda p: int(p[0]) if len(p) else 1 << 60)
            for k, p in enumerate(by_start):
                assert np.array_equal(p, whole[k::threads]), (name, k)


@pytest.mark.parametrize("threads", [3, 4, 8])
def test_a_batch_of_n_blocks_is_traced_in_n_parts(monkeypatch, threads):
    """On N threads a probe batch of N blocks or more (``rigid._BLOCK``) is built
    and traced in N parts of whole blocks, one ray thread each, with the bits of
    one thread."""
    from core import rigid

    sizes = _batch_sizes(monkeypatch)
    pts, offs, col = _pressed_grid(8)
    ref = Solver(offs, Settings(mode="bend", threads=1)).step(pts, [col])
    k = max(sizes)
    B = k // threads
    monkeypatch.setattr(rigid, "_BLOCK", B)
    parts = _probe_tracing(monkeypatch)
    res = Solver(offs, Settings(mode="bend", threads=threads)).step(pts, [col])
    # N parts of whole blocks, about equal, the last one to the batch's end
    cut = [i * (k // B) // threads * B for i in range(threads)] + [k]
    for a, b in zip(cut[:-1], cut[1:], strict=True):
        assert (a, b, 1) in parts, (k, B, cut, sorted(set(parts)))
    assert np.array_equal(res.points, ref.points) and np.array_equal(res.status, ref.status)
