"""Fur Attach and the render groom on two threads (``threads``, issue 11).

From ``core.tolerances.SPLIT_MIN_ITEMS`` curves :meth:`Binding.apply`
and :func:`deform_groom` (its blend; the guides' root fits stay on one thread) run
in two halves, one on
a ray-pool thread, one on the caller's. Curves are independent, so the result
must be the same bit for bit as on one thread, and each half must really run
on its own thread. On N threads they run in N parts, one per thread, with the
same bits (N = 2, 3, 4, 8). The tests lower the threshold to 1 so that small
grooms split too.
"""

from __future__ import annotations

import threading

import numpy as np
import pipe_oracle as po
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core import rays, tolerances
from core.errors import InputError
from core.pipeline import bind, bind_groom, deform_groom, wind

PROP = settings(max_examples=examples(25), deadline=None)


def _groom(seed, n_guides, n_render, uniform):
    rng = np.random.default_rng(seed)
    V, F = po.icosphere((0.2, -0.1, 0.3), 1.0, 2)

    def fur(n):
        if uniform:
            return po.fur_on_mesh(rng, V, F, n, int(rng.integers(2, 9)), 0.4)
        return po.pack([po.fur_on_mesh(rng, V, F, 1, int(rng.integers(2, 9)), 0.4)[0]
                        for _ in range(n)])

    (gp, go), (rp, ro) = fur(n_guides), fur(n_render)
    return rng, V, F, gp, go, rp, ro


class _Halves:
    """Records the threads :func:`core.rays.in_two`'s halves run on."""

    def __init__(self, mp):
        self.calls = []  # (items, threads, {thread ident of each half})
        real = rays.in_two

        def spy(fn, n, threads, min_n):
            idents = set()

            def half(a, b):
                idents.add(threading.get_ident())
                fn(a, b)

            real(half, n, threads, min_n)
            self.calls.append((n, threads, idents))

        for mod in ("core.pipeline.groom", "core.pipeline.attach", "core.pipeline.motion"):
            mp.setattr(f"{mod}.in_two", spy)


@PROP
@given(seed=st.integers(0, 10_000), n_guides=st.integers(2, 30),
       n_render=st.integers(2, 120), uniform=st.booleans(), own_roots=st.booleans(),
       collapse=st.booleans())
def test_two_threads_give_the_bits_of_one(seed, n_guides, n_render, uniform, own_roots,
                                          collapse):
    """Binding.apply, deform_groom and wind, split in two halves on two threads, give
    the same bits as on one thread (a collapsed root triangle and curves of many CV
    counts included), and the halves ran on two threads."""
    rng, V, F, gp, go, rp, ro = _groom(seed, n_guides, n_render, uniform)
    b = bind(rp, ro, V, F)
    V2 = V + 0.2 * rng.normal(size=V.shape) + 1.0
    if collapse:  # its curves keep their reference orientation, in either half
        f = F[b.face[-1]]
        V2[f[1]] = V2[f[2]] = V2[f[0]]
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 3)
    gn = wind(gp, go, seed % 97, strength=0.6, turbulence=1.0, seed=seed) + 0.25
    roots = b.apply(V2, threads=1)[ro[:-1]] if own_roots else None
    blow = dict(frame=seed % 31 + 0.25, direction=(1.0, 0.2, -0.3), strength=0.3,
                turbulence=0.8, preserve_length=bool(seed % 2))
    one = (b.apply(V2, threads=1), deform_groom(rp, ro, gp, gn, go, w, roots, threads=1),
           wind(rp, ro, threads=1, **blow))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tolerances, "SPLIT_MIN_ITEMS", 1)
        halves = _Halves(mp)
        two = (b.apply(V2, threads=2), deform_groom(rp, ro, gp, gn, go, w, roots, threads=2),
               wind(rp, ro, threads=2, **blow))
    for a, c in zip(two, one, strict=True):
        np.testing.assert_array_equal(a, c)
    assert halves.calls[-1][0] == len(ro) - 1  # (wind: its curves)
    assert all(len(ids) == 2 for *_, ids in halves.calls), halves.calls


@pytest.mark.parametrize("threads", [2, 3, 4, 8])
def test_n_threads_give_the_bits_of_one(monkeypatch, threads):
    """On N threads Binding.apply, deform_groom and wind run in N parts (consecutive
    ranges of about equal size, on more than one thread) and give the bits of one."""
    rng, V, F, gp, go, rp, ro = _groom(7, 12, 90, False)
    b = bind(rp, ro, V, F)
    V2 = V + 0.2 * rng.normal(size=V.shape) + 1.0
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 3)
    gn = wind(gp, go, 5, strength=0.6, turbulence=1.0, seed=7) + 0.25
    blow = dict(frame=3.25, direction=(1.0, 0.2, -0.3), strength=0.3, turbulence=0.8)
    one = (b.apply(V2, threads=1), deform_groom(rp, ro, gp, gn, go, w, threads=1),
           wind(rp, ro, threads=1, **blow))
    monkeypatch.setattr(tolerances, "SPLIT_MIN_ITEMS", 1)
    ranges = []
    real = rays.in_two

    def spy(fn, n, nthreads, min_n):
        seen, idents = [], set()

        def part(a, b):
            seen.append((a, b))
            idents.add(threading.get_ident())
            fn(a, b)

        real(part, n, nthreads, min_n)
        ranges.append((n, sorted(seen), idents))

    for mod in ("core.pipeline.groom", "core.pipeline.attach", "core.pipeline.motion"):
        monkeypatch.setattr(f"{mod}.in_two", spy)
    many = (b.apply(V2, threads=threads), deform_groom(rp, ro, gp, gn, go, w, threads=threads),
            wind(rp, ro, threads=threads, **blow))
    for a, c in zip(many, one, strict=True):
        np.testing.assert_array_equal(a, c)
    assert ranges
    for n, seen, idents in ranges:
        assert len(seen) == min(threads, n) and len(idents) >= 2, (n, seen)
        assert [a for a, _ in seen][1:] == [b for _, b in seen][:-1]  # consecutive
        assert seen[0][0] == 0 and seen[-1][1] == n
        sizes = [b - a for a, b in seen]
        assert max(sizes) - min(sizes) <= 1


def test_one_thread_or_few_curves_run_whole_on_the_caller(monkeypatch):
    """Threads 1 (a farm running one Blender per core) never hands work to another
    thread; nor does a stage with fewer curves than the threshold."""
    _, V, F, gp, go, rp, ro = _groom(1, 20, 300, True)
    b = bind(rp, ro, V, F)
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 3)
    halves = _Halves(monkeypatch)
    me = {threading.get_ident()}
    monkeypatch.setattr(tolerances, "SPLIT_MIN_ITEMS", 1)
    b.apply(V, threads=1)
    deform_groom(rp, ro, gp, gp, go, w, threads=1)
    wind(rp, ro, 3, threads=1)
    monkeypatch.setattr(tolerances, "SPLIT_MIN_ITEMS", 301)
    b.apply(V, threads=2)
    deform_groom(rp, ro, gp, gp, go, w, threads=2)
    wind(rp, ro, 3, threads=2)
    assert len(halves.calls) == 6  # apply, the blend and wind, twice
    assert all(ids == me for *_, ids in halves.calls), halves.calls


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_threads_must_be_a_positive_count(bad):
    _, V, F, gp, go, rp, ro = _groom(2, 5, 10, True)
    b = bind(rp, ro, V, F)
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 3)
    with pytest.raises(InputError, match="threads must be a positive integer or None"):
        b.apply(V, threads=bad)
    with pytest.raises(InputError, match="threads must be a positive integer or None"):
        deform_groom(rp, ro, gp, gp, go, w, threads=bad)
    with pytest.raises(InputError, match="threads must be a positive integer or None"):
        wind(rp, ro, 1, threads=bad)


def test_both_waits_for_both_and_reports_the_first_error():
    """:func:`core.rays.both`: the caller's own error is raised after the other call
    has ended; the other call's error is raised when the caller's call succeeds."""
    ended = threading.Event()

    def slow_ok():
        ended.wait(0.05)
        ended.set()
        return 1

    def fails():
        raise ValueError("the caller's half")

    with pytest.raises(ValueError, match="caller's half"):
        rays.both(slow_ok, fails, 2)
    assert ended.is_set()

    def other_fails():
        raise KeyError("the pool's half")

    with pytest.raises(KeyError, match="pool's half"):
        rays.both(other_fails, lambda: 2, 2)
    assert rays.both(lambda: 1, lambda: 2, 2) == (1, 2)
    assert rays.both(lambda: 1, lambda: 2, 1) == (1, 2)
