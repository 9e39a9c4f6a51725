"""Memory-cache footprint at paper scale (50,000 curves x 8 CVs) and its budget."""

import numpy as np
import pytest

pytestmark = pytest.mark.blender

C, N = 50_000, 8


def _frames(fc, touched=0.1, n_frames=12, seed=0):
    rng = np.random.default_rng(seed)
    offsets = np.arange(0, (C + 1) * N, N, dtype=np.int32)
    solver = fc.core.Solver(offsets, fc.core.Settings(mode="bend"))
    base = solver.state
    inp = rng.random((C * N, 3), dtype=np.float32)
    for f in range(1, n_frames + 1):
        hit = np.sort(rng.choice(C, int(C * touched), replace=False))
        out = inp.copy()
        pts = fc.cache.curve_point_mask(offsets, hit)
        out[pts] += 0.01
        st = {k: v.copy() for k, v in base.items()}
        st["angle"][hit] = 0.3
        st["angle_max"][hit] = 0.4
        st["axis"][hit] = (0, 0, 1)
        st["frame"][hit] = np.eye(3)
        st["active"][hit] = True
        status = np.zeros(C, np.int8)
        status[hit] = 1
        yield f, inp, out, status, offsets, st, base


def test_paper_scale_footprint_and_exactness(fc):
    mem = fc.cache.MemoryCache(limit_mb=512)
    per_frame = []
    kept = {}
    for f, inp, out, status, offsets, st, base in _frames(fc):
        if mem.sparse is None:
            mem.sparse = fc.cache.SparseState(base)
        before = mem.nbytes
        mem.put(f, inp, out, status, offsets, st, {})
        per_frame.append(mem.nbytes - before)
        if f in (1, 7):
            kept[f] = (out.copy(), status.copy(), st)
        the_input = inp
    mb = np.median(per_frame) / 2**20
    # 10 % of the curves touched: ~1 MB per frame -> 250 frames well under 512 MB
    print(f"memory cache: {mb:.2f} MB per frame")
    assert mb < 1.3, mb
    assert 250 * mb < 400
    for f, (out, status, st) in kept.items():
        got, got_status, _ = mem.get(f, the_input, offsets)
        assert np.array_equal(got, out) and np.array_equal(got_status, status)
        state = mem.state(f)
        for k in st:
            assert np.array_equal(state[k], st[k]), k


def test_budget_evicts_states_then_frames(fc):
    mem = fc.cache.MemoryCache(limit_mb=8)
    for f, inp, out, status, offsets, st, base in _frames(fc, n_frames=14):
        if mem.sparse is None:
            mem.sparse = fc.cache.SparseState(base)
            mem.start = 1
        mem.put(f, inp, out, status, offsets, st, {})
        assert mem.nbytes <= mem.limit or len(mem) <= 2
    assert 14 in mem and mem.state(14) is not None  # the newest frame can be stepped from
    assert mem.nbytes <= mem.limit
