"""The frame cache without Blender (``core.framecache``): the memory cache's footprint,
budget and exactness, the bake files, and the frame-inputs digests and records."""

from __future__ import annotations

import os

import numpy as np
import pytest

from core import Settings, Solver, Status
from core import framecache as fcache

C, N = 50_000, 8


# ------------------------------------------------------------------ memory
def _frames(touched=0.1, n_frames=12, seed=0):
    """Paper-scale frames (50,000 curves x 8 CVs) with ``touched`` of the curves moved."""
    rng = np.random.default_rng(seed)
    offsets = np.arange(0, (C + 1) * N, N, dtype=np.int32)
    solver = Solver(offsets, Settings(mode="bend"))
    base = solver.state
    inp = rng.random((C * N, 3), dtype=np.float32)
    for f in range(1, n_frames + 1):
        hit = np.sort(rng.choice(C, int(C * touched), replace=False))
        out = inp.copy()
        pts = fcache.curve_point_mask(offsets, hit)
        out[pts] += 0.01
        st = {k: v.copy() for k, v in base.items()}
        st["angle"][hit] = 0.3
        st["angle_max"][hit] = 0.4
        st["axis"][hit] = (0, 0, 1)
        st["frame"][hit] = np.eye(3)
        st["active"][hit] = True
        status = np.zeros(C, np.int8)
        status[hit] = Status.COLLIDING
        yield f, inp, out, status, offsets, st, base


def test_paper_scale_footprint_and_exactness():
    mem = fcache.MemoryCache(limit_mb=512)
    per_frame = []
    kept = {}
    for f, inp, out, status, offsets, st, base in _frames():
        if mem.sparse is None:
            mem.sparse = fcache.SparseState(base)
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


def test_budget_evicts_states_then_frames():
    mem = fcache.MemoryCache(limit_mb=8)
    for f, inp, out, status, offsets, st, base in _frames(n_frames=14):
        if mem.sparse is None:
            mem.sparse = fcache.SparseState(base)
            mem.start = 1
        mem.put(f, inp, out, status, offsets, st, {})
        assert mem.nbytes <= mem.limit or len(mem) <= 2
    assert 14 in mem and mem.state(14) is not None  # the newest frame can be stepped from
    assert mem.nbytes <= mem.limit


def _small(n_curves=6, npts=4, seed=1):
    rng = np.random.default_rng(seed)
    offsets = np.arange(0, (n_curves + 1) * npts, npts, dtype=np.int32)
    inp = rng.random((n_curves * npts, 3), dtype=np.float32)
    return offsets, inp


def test_memory_frames_keep_attributes_records_and_drop_after():
    offsets, inp = _small()
    mem = fcache.MemoryCache()
    for f in range(1, 6):
        out = inp.copy()
        out[4 * f: 4 * f + 4] += f
        status = np.zeros(6, np.int8)
        status[f] = Status.RECOVERING
        dist = np.full(len(inp), float(f), np.float32)
        mem.put(f, inp, out, status, offsets, None, {"frame": f},
                attributes={"d": dist}, inputs={"source": f})
    assert len(mem) == 5 and mem.newest_before(4) == 3 and mem.newest_before(1) is None
    out, status, stats = mem.get(3, inp, offsets)
    assert stats == {"frame": 3} and status.tolist() == [0, 0, 0, 2, 0, 0]
    assert np.array_equal(out[12:16], inp[12:16] + 3) and np.array_equal(out[:12], inp[:12])
    assert mem.attributes(3)["d"][0] == 3.0 and mem.inputs(3) == {"source": 3}
    assert mem.state(3) is None  # stored without a solver state: cannot be stepped from
    assert mem.drop_after(3) == 2 and sorted(mem.frames) == [1, 2, 3]
    assert mem.inputs(5) is None and mem.attributes(5) == {}


def test_rows_differ_compares_bits():
    a = np.zeros((5, 3), np.float32)
    b = a.copy()
    b[1, 2] = -0.0  # equal as a number, not as stored bits
    b[3, 0] = 1.0
    assert fcache.rows_differ(a, b).tolist() == [False, True, False, True, False]
    q = np.zeros((4, 4))
    r = q.copy()
    r[2, 3] = 5.0
    assert fcache.rows_differ(q, r).tolist() == [False, False, True, False]
    f = np.zeros((3, 3, 3))
    g = f.copy()
    g[0, 2, 2] = 1.0
    assert fcache.rows_differ(f, g).tolist() == [True, False, False]


def test_a_fresh_baseline_is_one_row_and_the_state_round_trips_bit_for_bit():
    """The baseline of a fresh Soft solver (zeros, identity quaternions) is kept as one
    row per array (at 200,000 curves x 8 CVs its full copy took 114 MB), and rows that
    differ from it only in their bits (-0.0, a NaN) still round-trip exactly."""
    C, N = 300, 5
    offsets = np.arange(0, (C + 1) * N, N, dtype=np.int32)
    solver = Solver(offsets, Settings(mode="soft"))
    sparse = fcache.SparseState(solver.state)
    assert all(b.strides[0] == 0 for k, b in sparse.baseline.items() if k != "meta")
    state = solver.state
    state["angle"][7] = -0.0
    state["delta"][9] = np.nan
    state["quat"][[0, 33]] = [0.0, 1.0, 0.0, 0.0]
    state["frame"][250] = np.eye(3)
    state["active"][[7, 250]] = True
    enc = sparse.encode(state)
    assert enc["idx:angle"].tolist() == [7] and enc["idx:delta"].tolist() == [9]
    assert enc["idx:quat"].tolist() == [0, 33] and enc["idx:frame"].tolist() == [250]
    back = sparse.decode(enc)
    for k, a in state.items():
        assert back[k].flags.writeable and back[k].shape == a.shape, k
        assert fcache.rows_differ(back[k], a).sum() == 0, k
    # a baseline that is not one row repeated is kept as it is
    assert fcache.SparseState({"x": np.arange(100.0)}).baseline["x"].strides[0] == 8


def test_topology_key_and_point_masks():
    offsets = np.array([0, 3, 5, 9], np.int32)
    assert fcache.topology_key(offsets)[:2] == (3, 9)
    assert fcache.topology_key(offsets) != fcache.topology_key(np.array([0, 4, 5, 9]))
    assert fcache.curve_point_mask(offsets, np.array([0, 2])).tolist() == [0, 1, 2, 5, 6, 7, 8]
    flags = np.zeros(9, bool)
    flags[6] = True
    assert fcache.curves_with_any(flags, offsets).tolist() == [False, False, True]


# -------------------------------------------------------------------- disk
def test_bake_file_round_trip_with_a_sparse_state(tmp_path):
    offsets = np.arange(0, 65 * 4, 4, dtype=np.int32)
    solver = Solver(offsets, Settings(mode="bend"))
    sparse = fcache.SparseState(solver.state)
    state = solver.state
    state["angle"][[3, 40]] = 0.25
    points = np.random.default_rng(2).random((64 * 4, 3), dtype=np.float32)
    status = np.zeros(64, np.int8)
    status[3] = Status.PINCHED
    d = str(tmp_path / "bake")
    path = fcache.write_frame(d, -4, points, status, offsets, state, sparse,
                              {"d": np.arange(len(points), dtype=np.float32)},
                              inputs={"source": (1 << 64) - 1})
    assert os.path.basename(path) == "frame_-00004.npz"  # a pre-roll frame keeps its sign
    assert fcache.list_frames(d) == [-4] and not os.path.exists(path + ".tmp")
    p, st, offs, stored = fcache.read_frame(d, -4)
    assert np.array_equal(p, points) and np.array_equal(st, status)
    assert np.array_equal(offs, offsets)
    full = fcache.decode_state(stored, sparse)
    for k in state:
        assert np.array_equal(full[k], state[k]), k
    assert fcache.read_attributes(d, -4)["d"][5] == 5.0
    assert fcache.read_inputs(d, -4) == {"source": (1 << 64) - 1}
    assert fcache.read_extra(d, -4, "groom") is None


def test_extra_parts_are_stored_with_the_frame_and_read_alone(tmp_path):
    """A later stage's arrays (the render groom) live in the frame's file, apart from
    the guides' own arrays and attributes; ``names`` reads only some of them."""
    offsets = np.arange(0, 9 * 4, 4, dtype=np.int32)
    points = np.random.default_rng(3).random((32, 3), dtype=np.float32)
    groom = {"points": np.arange(30, dtype=np.float32).reshape(10, 3),
             "status": np.array([0, 6], np.int8), "key": np.frombuffer(b"k|1", np.uint8)}
    d = str(tmp_path / "bake")
    fcache.write_frame(d, 3, points, np.zeros(8, np.int8), offsets, None,
                       attributes={"a": np.ones(32, np.float32)}, extra={"groom": groom})
    got = fcache.read_extra(d, 3, "groom")
    assert sorted(got) == ["key", "points", "status"]
    for k, v in groom.items():
        assert np.array_equal(got[k], v) and got[k].dtype == v.dtype
    assert list(fcache.read_extra(d, 3, "groom", ("key",))) == ["key"]
    assert fcache.read_extra(d, 3, "other") is None
    assert list(fcache.read_attributes(d, 3)) == ["a"]
    assert np.array_equal(fcache.read_frame(d, 3)[0], points)


def _loaded_names(monkeypatch):
    """The names of the arrays read from any bake file from now on."""
    names = []
    get = np.lib.npyio.NpzFile.__getitem__

    def spy(self, key):
        names.append(key)
        return get(self, key)

    monkeypatch.setattr(np.lib.npyio.NpzFile, "__getitem__", spy)
    return names


def test_a_shown_frame_is_everything_but_the_state_in_one_read(tmp_path, monkeypatch):
    """``read_shown`` (a baked frame shown) gives what the separate readers give, opens
    the file once, and never loads the solver state (a few MB per frame at scale)."""
    offsets = np.arange(0, 9 * 4, 4, dtype=np.int32)
    state = Solver(offsets, Settings(mode="bend")).state
    sparse = fcache.SparseState(state)
    state["angle"][[1, 5]] = 0.5
    points = np.random.default_rng(4).random((32, 3), dtype=np.float32)
    status = np.array([0, 1, 2, 3, 4, 5, 6, 0], np.int8)
    groom = {"points": np.arange(30, dtype=np.float32).reshape(10, 3),
             "status": np.array([0, 6], np.int8)}
    d = str(tmp_path / "bake")
    fcache.write_frame(d, 7, points, status, offsets, state, sparse,
                       attributes={"a": np.ones(32, np.float32), "b": np.zeros(32)},
                       inputs={"settings": 12},
                       extra={"groom": groom, "more": {"x__y__z": [1]}})  # (a name may have __)
    fcache.write_frame(d, 8, points, status, offsets, None)  # nothing else stored
    opens = []
    load = np.load
    monkeypatch.setattr(np, "load", lambda *a, **k: opens.append(a[0]) or load(*a, **k))
    names = _loaded_names(monkeypatch)
    shown = fcache.read_shown(d, 7)
    assert opens == [fcache.frame_path(d, 7)]
    assert not [n for n in names if n.startswith("state__")], names
    assert np.array_equal(shown.points, points) and shown.points.dtype == np.float32
    assert np.array_equal(shown.status, status) and np.array_equal(shown.offsets, offsets)
    assert sorted(shown.attributes) == ["a", "b"]
    for k, v in fcache.read_attributes(d, 7).items():
        assert np.array_equal(shown.attributes[k], v) and shown.attributes[k].dtype == v.dtype
    assert shown.inputs == fcache.read_inputs(d, 7) == {"settings": 12}
    assert sorted(shown.extra) == ["groom", "more"]
    assert list(shown.extra["more"]) == ["x__y__z"]
    for part in shown.extra:
        got = fcache.read_extra(d, 7, part)
        assert sorted(shown.extra[part]) == sorted(got)
        assert all(np.array_equal(shown.extra[part][k], got[k]) for k in got)
    bare = fcache.read_shown(d, 8)
    assert (bare.attributes, bare.inputs, bare.extra) == ({}, None, {})
    assert np.array_equal(bare.points, points)


def test_the_state_is_read_only_when_asked_for(tmp_path, monkeypatch):
    """A subframe blends two baked frames' points: ``read_frame(state=False)`` leaves the
    solver state unread; by default it is read (resuming a bake)."""
    offsets = np.arange(0, 9 * 4, 4, dtype=np.int32)
    state = Solver(offsets, Settings(mode="bend")).state
    state["angle"][2] = 0.25
    points = np.zeros((32, 3), np.float32)
    d = str(tmp_path / "bake")
    fcache.write_frame(d, 1, points, np.zeros(8, np.int8), offsets, state)
    names = _loaded_names(monkeypatch)
    p, st, offs, stored = fcache.read_frame(d, 1, state=False)
    assert stored == {} and not [n for n in names if n.startswith("state__")]
    assert np.array_equal(offs, offsets) and p.shape == (32, 3) and len(st) == 8
    stored = fcache.read_frame(d, 1)[3]
    assert stored["angle"][2] == 0.25


def test_a_part_name_with_a_double_underscore_is_refused(tmp_path):
    """Parts are stored as ``extra__<part>__<name>``: a ``__`` in a part's name would
    read back as another part."""
    offsets = np.arange(0, 9 * 4, 4, dtype=np.int32)
    d = str(tmp_path / "bake")
    with pytest.raises(ValueError, match="a__b"):
        fcache.write_frame(d, 1, np.zeros((32, 3)), np.zeros(8, np.int8), offsets, None,
                           extra={"a__b": {"x": [1]}})
    assert fcache.list_frames(d) == []


def test_free_removes_only_the_bake_files(tmp_path):
    d = tmp_path / "bake"
    offsets = np.array([0, 2], np.int32)
    for f in (1, 2):
        fcache.write_frame(str(d), f, np.zeros((2, 3), np.float32), np.zeros(1, np.int8),
                           offsets, None)
    (d / "frame_000003.npz.tmp").write_bytes(b"half")  # a crashed write
    (d / "notes.txt").write_text("mine")
    (d / "frame_3.npz").write_bytes(b"not ours")  # not a name FurCollide writes
    assert fcache.list_frames(str(d)) == [1, 2]
    assert fcache.read_inputs(str(d), 1) is None  # written without a record: not checked
    assert fcache.remove_frames(str(d)) == 3
    assert sorted(os.listdir(d)) == ["frame_3.npz", "notes.txt"]
    for name in os.listdir(d):
        os.remove(d / name)
    assert fcache.remove_frames(str(d)) == 0 and not d.exists()  # empty: removed


# ------------------------------------------------------------ frame inputs
def test_digest_sees_any_change_and_any_reordering():
    """One flipped bit, a swap of two points, another dtype, a change in the tail bytes
    (not a whole 8-byte word) and another length all count."""
    digest = fcache.digest
    rng = np.random.default_rng(3)
    P = rng.random((40_001, 3), dtype=np.float32)  # 480,012 bytes: a 4-byte tail
    d = digest(P)
    assert digest(P.copy()) == d
    for i in rng.integers(0, P.size, 50):
        a = P.copy().reshape(-1)
        a.view(np.uint32)[i] ^= np.uint32(1)  # one ulp
        assert digest(a.reshape(-1, 3)) != d, i
    for i, j in rng.integers(0, len(P), (50, 2)):
        if i != j:
            a = P.copy()
            a[[i, j]] = a[[j, i]]
            assert digest(a) != d, (i, j)
    a = P.copy()
    a[-1, 2] = -a[-1, 2]
    assert digest(a) != d
    assert digest(P[:-1]) != d and digest(P.view(np.int32)) != d
    assert digest(np.zeros(3, np.float32)) != digest(np.zeros(3, np.int32))
    assert digest(np.eye(4)) != digest(np.eye(4) * (1 + 1e-16 * 4))


def test_records_compare_in_order_and_survive_a_bake_file():
    c = fcache
    old = {"colliders": 1, "settings": 2, "source": 3, "collider 0 matrix": 4}
    assert c.first_change(old, dict(old)) is None
    assert c.first_change(old, {**old, "source": 9, "collider 0 matrix": 9}) == "source"
    assert c.first_change(old, {k: v for k, v in old.items() if k != "source"}) == "source"
    assert c.first_change(old, {**old, "surface matrix": 5}) == "surface matrix"
    big = {**old, "source": (1 << 64) - 1}
    assert c.decode_inputs(c.encode_inputs(big)) == big
    assert c.decode_inputs(np.frombuffer(b"\xff\x00", np.uint8)) is None


@pytest.mark.parametrize("text", ["settings", ""])
def test_text_digest_is_stable(text):
    assert fcache.text_digest(text) == fcache.text_digest(str(text))
    assert fcache.text_digest(text) != fcache.text_digest(text + " ")


def test_framecache_imports_without_blender():
    import subprocess
    import sys
    import textwrap
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    code = textwrap.dedent(f"""
        import importlib.abc, sys
        class Block(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in ("bpy", "mathutils", "bmesh"):
                    raise ImportError(name)
        sys.meta_path.insert(0, Block())
        sys.path.insert(0, {str(root)!r})
        from core import framecache
        assert not [m for m in sys.modules if m.split(".")[0] in ("bpy", "operators", "ui")]
        print("OK")
    """)
    proc = subprocess.run([sys.executable, "-I", "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "OK", proc.stderr[-2000:]


# ------------------------------------------------- the budget's eviction order
def _budget_frames(n_frames, n_curves=200, state_rows=2000):
    """Small frames whose solver state is much larger than their positions: every
    frame moves every curve and changes every state row (so nothing is shared)."""
    offsets = np.arange(0, 2 * n_curves + 1, 2, dtype=np.int32)
    inp = np.zeros((2 * n_curves, 3), np.float32)
    base = {"angle": np.zeros(state_rows), "axis": np.zeros((state_rows, 3))}
    for f in range(1, n_frames + 1):
        out = inp + np.float32(f)
        status = np.full(n_curves, Status.COLLIDING, np.int8)
        st = {"angle": np.full(state_rows, float(f)), "axis": np.full((state_rows, 3), -f, float)}
        yield f, inp, out, status, offsets, st, base


def _check_budget_invariants(mem, put, start):
    """README "Memory used by the playback cache": past the limit, solver states are
    dropped except on every 10th frame; if that is not enough, the oldest frames go.
    ``put``: the frames put so far, in order."""
    kept = sorted(mem.frames)
    newest = put[-1]
    stateless = [k for k in kept if mem.frames[k].state is None]
    keyed = [k for k in kept if (k - start) % fcache.KEY_EVERY == 0]
    assert newest in kept and mem.state(newest) is not None  # it can be stepped from
    # every 10th frame keeps its state as long as the frame is kept at all
    assert all(mem.frames[k].state is not None for k in keyed), (keyed, stateless)
    # states go oldest first: no frame keeps a droppable state older than one that lost it
    droppable = [k for k in kept if k not in keyed and k != newest]
    with_state = [k for k in droppable if mem.frames[k].state is not None]
    if stateless and with_state:
        assert max(stateless) < min(with_state), (stateless, with_state)
    dropped = [k for k in put if k not in mem.frames]
    if dropped:
        # frames go only once no droppable state is left, and the oldest go first:
        # what is kept is the start frame and the newest frames, without a gap
        assert with_state == [], with_state
        rest = [k for k in kept if k != start]
        assert rest == put[len(put) - len(rest):], (kept, dropped)
        assert start in kept
    assert mem.nbytes <= mem.limit or len(mem) <= 2


def test_budget_drops_states_but_every_10th_then_the_oldest_frames():
    frames = list(_budget_frames(45))
    # measure one frame (positions + status) and one state, then allow 20 frames'
    # positions and 5 states: states must go from about frame 8 and frames from
    # about frame 25
    probe = fcache.MemoryCache(limit_mb=1e6)
    probe.sparse = fcache.SparseState(frames[0][6])
    f, inp, out, status, offsets, st, _ = frames[0]
    probe.put(f, inp, out, status, offsets, st, {})
    full = probe.frames[f].nbytes
    state = sum(a.nbytes for a in probe.frames[f].state.values())
    assert state > 3 * (full - state)  # the scenario needs heavy states
    mem = fcache.MemoryCache(limit_mb=(20 * (full - state) + 5 * state) / 2**20)
    mem.sparse = fcache.SparseState(frames[0][6])
    mem.start = 1
    put = []
    first_state_drop = first_frame_drop = None
    for f, inp, out, status, offsets, st, _ in frames:
        mem.put(f, inp, out, status, offsets, st, {"f": f})
        put.append(f)
        _check_budget_invariants(mem, put, start=1)
        if first_state_drop is None and any(fr.state is None for fr in mem.frames.values()):
            first_state_drop = f
        if first_frame_drop is None and len(mem) < len(put):
            first_frame_drop = f
    assert first_state_drop is not None and first_frame_drop is not None
    assert first_state_drop < first_frame_drop, (first_state_drop, first_frame_drop)
    kept = sorted(mem.frames)
    assert sorted(k for k in kept if mem.frames[k].state is not None) == \
        [k for k in kept if (k - 1) % 10 == 0 or k == 45]
    assert kept[0] == 1 and kept[1] > 2 and kept[-1] == 45 and 41 in kept
    # a frame without its state still displays bit for bit
    for k in mem.frames:
        got, got_status, stats = mem.get(k, frames[0][1], frames[0][4])
        assert np.array_equal(got, frames[k - 1][2]) and stats == {"f": k}
        assert np.array_equal(got_status, frames[k - 1][3])
    # and a kept state is exact
    assert np.array_equal(mem.state(41)["angle"], frames[40][5]["angle"])


def test_budget_counts_from_the_setups_start_frame():
    """The states kept are those of every 10th frame from Frame Start (a pre-roll
    starting at -4 keeps -4, 6, 16 ...), not of frames divisible by 10."""
    frames = list(_budget_frames(30))
    mem = fcache.MemoryCache(limit_mb=0.6)  # 30 frames' positions and 4 or 5 states
    mem.sparse = fcache.SparseState(frames[0][6])
    mem.start = -4
    for f, inp, out, status, offsets, st, _ in frames:
        mem.put(f - 5, inp, out, status, offsets, st, {})
    keyed = sorted(k for k in mem.frames if mem.frames[k].state is not None)
    assert len(mem) == 30 and [k for k in keyed if k < 20] == [-4, 6, 16], keyed


# ---------------------------------------------------------- atomic bake writes
def _partial_savez(fail_after=0.5):
    """A stand-in for ``np.savez`` that writes the first part of a real npz into the
    open file, then fails as a full disk or a killed process would."""
    real = np.savez

    def savez(fh, **arrays):
        import io

        buf = io.BytesIO()
        real(buf, **arrays)
        data = buf.getvalue()
        fh.write(data[: int(len(data) * fail_after)])
        fh.flush()
        raise OSError(28, "No space left on device (simulated, in the middle of a frame)")

    return savez


def _frame(f, n=64):
    offsets = np.arange(0, (n + 1) * 2, 2, dtype=np.int32)
    pts = np.full((2 * n, 3), float(f), np.float32)
    return pts, np.full(n, f % 5, np.int8), offsets


@pytest.mark.parametrize("fail_after", [0.0, 0.02, 0.5, 0.999])
def test_a_write_failing_midway_keeps_the_previous_file(tmp_path, monkeypatch, fail_after):
    """README "Bake": files are written to a temporary file, then moved into place,
    so a crash never leaves a half-written frame. Re-baking frame 3 fails in the
    middle: frame 3's previous file is intact; a new frame 4 that fails does not
    exist at all (list_frames never offers a partial frame to resume from)."""
    d = str(tmp_path / "bake")
    for f in (1, 2, 3):
        fcache.write_frame(d, f, *_frame(f), None, inputs={"source": f})
    before = (tmp_path / "bake" / "frame_000003.npz").read_bytes()
    with monkeypatch.context() as m:
        m.setattr(fcache.np, "savez", _partial_savez(fail_after))
        for f in (3, 4):
            with pytest.raises(OSError, match="simulated"):
                fcache.write_frame(d, f, *_frame(f + 100), None, inputs={"source": 0})
    assert (tmp_path / "bake" / "frame_000003.npz").read_bytes() == before
    p, st, offs, _ = fcache.read_frame(d, 3)
    assert np.array_equal(p, _frame(3)[0]) and fcache.read_inputs(d, 3) == {"source": 3}
    assert fcache.list_frames(d) == [1, 2, 3]
    assert not (tmp_path / "bake" / "frame_000004.npz").exists()
    # Free Bake removes the leftovers of the failed writes too
    leftovers = len(os.listdir(d))
    assert fcache.remove_frames(d) == leftovers
    assert not (tmp_path / "bake").exists()


def test_a_frame_file_is_synced_before_it_is_moved_into_place(tmp_path, monkeypatch):
    """The finished temporary file is flushed to disk (fsync) and only then renamed
    over the frame's name with os.replace (atomic on POSIX and Windows)."""
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        return real_fsync(fd)

    def replace(src, dst):
        events.append(("replace", os.fspath(src), os.fspath(dst)))
        return real_replace(src, dst)

    monkeypatch.setattr(fcache.os, "fsync", fsync)
    monkeypatch.setattr(fcache.os, "replace", replace)
    d = str(tmp_path / "bake")
    path = fcache.write_frame(d, 7, *_frame(7), None)
    tmp = [e for e in events if e[0] == "replace"][0][1]
    assert tmp != path and os.path.dirname(tmp) == os.path.dirname(path)
    assert events == [("fsync", os.path.realpath(tmp)), ("replace", tmp, path)], events
