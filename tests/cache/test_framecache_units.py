"""The frame cache's building blocks, one by one (``core.framecache``): layout keys, point
masks, bit-exact row comparison, the digests bakes keep, frame-inputs records, the
sparse solver state, the memory cache's bookkeeping and the bake files' names.

Written against the module's documented behaviour; ``make mutate`` found each of these
gaps (a mutant of the function survived the other tests)."""

from __future__ import annotations

import os
import zlib

import numpy as np
import pytest

from core import framecache as fc

RAGGED = np.array([0, 3, 5, 9, 11], np.int32)  # curves of 3, 2, 4, 2 points


# ----------------------------------------------------------------- layout helpers
def test_topology_key_is_counts_and_the_crc_of_int32_offsets_whatever_their_dtype():
    key = fc.topology_key(RAGGED)
    assert key == (4, 11, zlib.crc32(RAGGED.astype(np.int32).tobytes()))
    for dtype in (np.int64, np.int16, np.uint32):
        assert fc.topology_key(RAGGED.astype(dtype)) == key, dtype
    assert fc.topology_key(RAGGED[::-1][::-1]) == key  # a view, not contiguous-owned
    assert fc.topology_key(np.array([0], np.int32)) == (0, 0, zlib.crc32(np.int32(0)))


def test_curve_point_mask_lists_the_points_of_the_curves_in_order():
    assert fc.curve_point_mask(RAGGED, np.array([1, 3])).tolist() == [3, 4, 9, 10]
    assert fc.curve_point_mask(RAGGED, np.array([0, 2])).tolist() == [0, 1, 2, 5, 6, 7, 8]
    assert fc.curve_point_mask(RAGGED, np.arange(4)).tolist() == list(range(11))
    empty = fc.curve_point_mask(RAGGED, np.zeros(0, np.int64))
    assert empty.shape == (0,) and empty.dtype == np.int64


def _brute_any(flags, offsets):
    return np.array([flags[offsets[c]:offsets[c + 1]].any() for c in range(len(offsets) - 1)])


@pytest.mark.parametrize("offsets", [RAGGED, np.arange(0, 25, 5, dtype=np.int32),
                                     np.array([0, 2], np.int32),
                                     np.array([0, 4, 8, 12], np.int64)])
def test_curves_with_any_equals_brute_force(offsets):
    rng = np.random.default_rng(1)
    P = int(offsets[-1])
    for flags in (np.zeros(P, bool), np.ones(P, bool), rng.random(P) < 0.2,
                  np.eye(1, P, P - 1, dtype=bool)[0], np.eye(1, P, 0, dtype=bool)[0]):
        got = fc.curves_with_any(flags, offsets)
        assert got.dtype == bool and got.shape == (len(offsets) - 1,)
        np.testing.assert_array_equal(got, _brute_any(flags, offsets))


def test_rows_differ_on_any_layout_and_dtype():
    rng = np.random.default_rng(2)
    for shape in ((7, 3), (7, 4), (7, 9), (7, 3, 3), (7,), (7, 2, 5)):
        a = rng.random(shape)
        b = a.copy()
        rows = [1, 5]
        b[rows] += 1.0
        want = np.isin(np.arange(7), rows)
        for x, y in ((a, b), (a.astype(np.float32), b.astype(np.float32)),
                     (np.round(a * 100).astype(np.int32),  # other dtypes: values compared
                      np.round(b * 100).astype(np.int64)),
                     (np.repeat(a, 2, axis=0)[::2], np.repeat(b, 2, axis=0)[::2])):
            got = fc.rows_differ(x, y)
            assert got.dtype == bool and got.shape == (7,), shape
            np.testing.assert_array_equal(got, want, err_msg=str(shape))
    c = np.zeros((4, 3), np.float32)
    d = c.copy()
    d[2, 1] = -0.0  # bits differ, values equal
    assert fc.rows_differ(c, d).tolist() == [False, False, True, False]
    e = np.full((3, 2), np.nan)
    assert not fc.rows_differ(e, e.copy()).any()  # the same NaN is no change
    i = np.arange(12, dtype=np.int64).reshape(6, 2)
    assert fc.rows_differ(i[:, ::-1], i[:, ::-1].copy()).tolist() == [False] * 6  # strided
    j = i.copy()
    j[0, 1] = 99
    assert fc.rows_differ(i, j).tolist() == [True] + [False] * 5


def test_rows_differ_on_fortran_ordered_rows():
    a = np.asfortranarray(np.zeros((7, 4)))
    b = a.copy(order="F")
    b[2, 3] = 1.0
    assert fc.rows_differ(a, b).tolist() == [False, False, True] + [False] * 4


# ------------------------------------------------------------------------ digests
def test_digests_are_stable_across_sessions():
    """Bakes keep their records: the same bytes must give the same digest in every
    session, version and platform (a changed digest would report every old bake as
    outdated). Pinned values."""
    a = np.arange(12, dtype=np.float32).reshape(4, 3)
    big = np.arange(3000 * 3, dtype=np.float32).reshape(-1, 3) * np.float32(0.5)
    assert fc.digest(a) == 6002031957010796291
    assert fc.digest(big) == 14762855775881825934
    assert fc.digest(a, big) == 4441843421768434335
    assert fc.digest(np.eye(4)) == 14605458869067404733
    assert fc.digest(np.arange(1001, dtype=np.int8)) == 538610193805778229
    assert fc.digest(np.arange(4097, dtype=np.uint8)) == 2161780671468864723
    assert fc.text_digest("settings") == 16048056643289807056
    assert fc.text_digest("") == 13020603013274838756


def test_digest_weights_are_odd_and_keep_their_prefix():
    w = fc._digest_weights(10).copy()
    assert (w & np.uint64(1)).all() and len(set(w.tolist())) == 10
    longer = fc._digest_weights(50_000)
    np.testing.assert_array_equal(longer[:10], w)
    assert len(longer) == 50_000 and (longer & np.uint64(1)).all()
    assert len(set(longer.tolist())) == 50_000


def test_digest_sees_dtype_shape_tail_and_order():
    big = np.arange(2001, dtype=np.float64)  # 16,008 bytes: hashed by weights
    d = fc.digest(big)
    assert fc.digest(big.astype(np.float32)) != d
    assert fc.digest(big.reshape(-1)[:-1]) != d
    assert fc.digest(big[::-1]) != d
    assert fc.digest(big.reshape(1, -1)) == d  # the bytes, not the shape, are what count
    odd = np.arange(4099, dtype=np.uint8)  # a 3-byte tail after the 8-byte words
    t = odd.copy()
    t[-1] ^= 1
    assert fc.digest(t) != fc.digest(odd)
    assert fc.digest(np.zeros(5000, np.uint8)) != fc.digest(np.zeros(5001, np.uint8))
    assert fc.digest() != fc.digest(np.zeros(0))


def test_inputs_records_encode_decode_and_reject_junk():
    rec = {"settings": 1, "source": (1 << 64) - 1, "collider 0 matrix": 0}
    enc = fc.encode_inputs(rec)
    assert enc.dtype == np.uint8 and enc.ndim == 1
    assert fc.decode_inputs(enc) == rec
    assert list(fc.decode_inputs(enc)) == list(rec)  # the order is kept (first_change)
    for junk in (b"\xff\xfe", b"not json", b"[1, 2]", b"3", b""):
        assert fc.decode_inputs(np.frombuffer(junk, np.uint8)) is None, junk
    assert fc.first_change({"a": 1, "b": 2}, {"b": 3, "a": 1}) == "b"
    assert fc.first_change({"a": 1, "b": 2}, {"a": 1}) == "b"  # gone from the new one
    assert fc.first_change({}, {}) is None


# ---------------------------------------------------------------- sparse state
def test_sparse_state_round_trip_and_what_it_stores():
    base = {"angle": np.zeros(200), "axis": np.zeros((200, 3)), "few": np.zeros(10),
            "scalar": np.array(3.0), "mask": np.zeros(100, bool)}
    sp = fc.SparseState(base)
    state = {k: v.copy() for k, v in base.items()}
    state["angle"][[3, 150]] = 1.5
    state["axis"][7] = (0, 0, 1)
    state["few"][2] = 4.0
    state["mask"][99] = True
    state["new"] = np.arange(5)  # not in the baseline
    state["other_shape"] = np.zeros((200, 2))
    enc = sp.encode(state)
    assert enc["idx:angle"].tolist() == [3, 150] and enc["val:angle"].tolist() == [1.5, 1.5]
    assert enc["idx:axis"].tolist() == [7] and enc["idx:mask"].tolist() == [99]
    assert enc["idx:angle"].dtype == np.int32
    for k in ("few", "scalar", "new"):  # short, 0-d or new: stored whole
        assert "full:" + k in enc and "idx:" + k not in enc, k
    dec = sp.decode(enc)
    assert sorted(dec) == sorted(state)
    for k in state:
        assert np.array_equal(dec[k], state[k]) and dec[k].dtype == state[k].dtype, k
    state["angle"][3] = 9.0  # the encoding is a copy
    assert sp.decode(enc)["angle"][3] == 1.5
    dec["axis"][0] = 5.0  # and decoding does not touch the baseline
    assert not sp.baseline["axis"].any()


# ---------------------------------------------------------------- memory cache
def _frame(P=12, C=4, changed=(1,), value=1.0):
    offsets = np.arange(0, P + 1, P // C, dtype=np.int32)
    inp = np.zeros((P, 3), np.float32)
    out = inp.copy()
    for c in changed:
        out[offsets[c]:offsets[c + 1]] = value
    status = np.zeros(C, np.int8)
    status[list(changed)] = 1
    return inp, out, status, offsets


def test_memory_cache_bookkeeping():
    mem = fc.MemoryCache(limit_mb=1)
    assert mem.limit == 1024 * 1024 and len(mem) == 0 and mem.nbytes == 0
    assert 3 not in mem and mem.newest_before(10) is None and mem.state(3) is None
    inp, out, status, offsets = _frame()
    stats = {"colliding": 1}
    attrs = {"d": np.arange(12, dtype=np.float32)}
    rec = {"source": 7}
    for f in (2, 3, 5):
        mem.put(f, inp, out, status, offsets, None, stats, attributes=attrs, inputs=rec)
    stats["colliding"] = 99  # later changes of the caller's objects do not leak in
    attrs["d"][0] = -1
    rec["source"] = 8
    assert len(mem) == 3 and 3 in mem and 4 not in mem
    assert mem.newest_before(5) == 3 and mem.newest_before(3) == 2 and mem.newest_before(2) is None
    assert mem.get(3, inp, offsets)[2] == {"colliding": 1}
    assert mem.attributes(3)["d"][0] == 0 and mem.inputs(3) == {"source": 7}
    assert mem.frames[3].curves.tolist() == [1] and mem.frames[3].points.shape == (3, 3)
    assert mem.nbytes == sum(fr.nbytes for fr in mem.frames.values()) > 0
    assert mem.drop_after(2) == 2 and sorted(mem.frames) == [2]
    assert mem.drop_after(2) == 0
    mem.clear()
    assert len(mem) == 0


def test_memory_cache_rebuilds_changed_curves_only_and_checks_shapes():
    mem = fc.MemoryCache()
    inp, out, status, offsets = _frame(changed=(0, 3), value=2.0)
    mem.put(1, inp, out, status, offsets, None, {})
    got, got_status, _ = mem.get(1, inp, offsets)
    np.testing.assert_array_equal(got, out)
    np.testing.assert_array_equal(got_status, status)
    assert got.dtype == np.float32
    nothing = inp.copy()
    mem.put(2, inp, nothing, np.zeros(4, np.int8), offsets, None, {})
    assert len(mem.frames[2].curves) == 0 and len(mem.frames[2].status_idx) == 0
    np.testing.assert_array_equal(mem.get(2, inp, offsets)[0], inp)
    with pytest.raises(ValueError, match="shape"):
        mem.put(3, inp, out[:-1], status, offsets, None, {})
    empty = np.zeros((0, 3), np.float32)
    mem.put(4, empty, empty, np.zeros(0, np.int8), np.array([0], np.int32), None, {})
    assert mem.get(4, empty, np.array([0], np.int32))[0].shape == (0, 3)


def test_a_frame_exactly_at_the_limit_stays_and_one_byte_more_evicts():
    inp, out, status, offsets = _frame(P=400, C=100, changed=range(100))
    probe = fc.MemoryCache(limit_mb=100)
    probe.put(1, inp, out, status, offsets, None, {})
    size = probe.frames[1].nbytes
    for limit, kept in ((2 * size, [1, 2]), (2 * size - 1, [2])):
        mem = fc.MemoryCache(limit_mb=limit / 2**20)
        mem.start = 0
        for f in (1, 2):
            mem.put(f, inp, out, status, offsets, None, {})
        assert sorted(mem.frames) == kept, (limit, size)


# --------------------------------------------------------------------- bake files
def test_frame_file_names_and_listing(tmp_path):
    d = str(tmp_path)
    assert fc.frame_path(d, 7) == os.path.join(d, "frame_000007.npz")
    assert fc.frame_path(d, -4) == os.path.join(d, "frame_-00004.npz")
    for name in ("frame_000001.npz", "frame_-00004.npz", "frame_000010.npz",
                 "frame_000002.npz.tmp", "frame_2.npz", "frame_0000003.npz", "Frame_000005.npz",
                 "frame_00000a.npz", "notes.txt"):
        (tmp_path / name).write_bytes(b"x")
    assert fc.list_frames(d) == [-4, 1, 10]
    assert fc.list_frames(str(tmp_path / "missing")) == [] and fc.list_frames("") == []
    assert fc.remove_frames(str(tmp_path / "missing")) == 0 and fc.remove_frames("") == 0


def test_bake_file_without_a_sparse_state_or_a_record(tmp_path):
    d = str(tmp_path / "b")
    offsets = np.array([0, 2, 4], np.int32)
    pts = np.arange(12, dtype=np.float64).reshape(4, 3)  # stored as float32
    state = {"angle": np.array([0.5, 0.0]), "frame": np.eye(3)[None].repeat(2, 0)}
    fc.write_frame(d, 3, pts, np.array([1, 0]), offsets, state)
    p, st, offs, stored = fc.read_frame(d, 3)
    assert p.dtype == np.float32 and st.dtype == np.int8 and offs.dtype == np.int32
    np.testing.assert_array_equal(p, pts.astype(np.float32))
    assert fc.decode_state(stored, None) == stored  # no sparse keys: as stored
    np.testing.assert_array_equal(stored["frame"], state["frame"])
    assert fc.read_inputs(d, 3) is None and fc.read_attributes(d, 3) == {}
    assert fc.read_inputs(d, 4) is None  # no file
    with np.load(fc.frame_path(d, 3), allow_pickle=False) as z:
        assert z["format"].tolist() == [1, 3]




@pytest.mark.parametrize("data", [b"", b"abc", b"PK\x03\x04 cut short"])
def test_an_unreadable_frame_file_has_no_record(tmp_path, data):
    """read_inputs: None for files that cannot be read (its docstring), never an
    exception: the bake's resume and the frame rules call it on any file."""
    (tmp_path / "frame_000005.npz").write_bytes(data)
    assert fc.read_inputs(str(tmp_path), 5) is None


# ------------------------------------------- gaps make mutate found (second run)
def test_topology_key_of_no_offsets_at_all():
    """An empty offsets array (no layout yet) has a key too, with 0 points."""
    assert fc.topology_key(np.zeros(0, np.int32)) == (-1, 0, zlib.crc32(b""))


def test_curves_with_any_on_a_ragged_layout_of_uniform_size():
    """Curves of 1, 3 and 2 points: 6 points = 3 curves x 2, but not 2 points each, so
    the row-wise shortcut for uniform layouts must not be taken."""
    offsets = np.array([0, 1, 4, 6], np.int32)
    for p in range(6):
        flags = np.eye(1, 6, p, dtype=bool)[0]
        np.testing.assert_array_equal(fc.curves_with_any(flags, offsets),
                                      _brute_any(flags, offsets), err_msg=str(p))


def test_digest_of_exactly_the_small_size_is_pinned():
    """4,096 bytes is the last size hashed as plain bytes (pinned, like the others:
    a bake's records must not change)."""
    assert fc._SMALL == 4096
    assert fc.digest(np.arange(4096, dtype=np.uint8)) == 18102430450357302631
    assert fc.digest(np.arange(1024, dtype=np.float32)) == 17651677044420214483
    assert fc.digest(np.arange(4095, dtype=np.uint8)) == 15523956259463418600


_UNPICKLED = []


def _unpickled_marker():
    _UNPICKLED.append(True)
    return "unpickled"


class _Marker:
    def __reduce__(self):
        return (_unpickled_marker, ())


def test_bake_files_are_never_unpickled(tmp_path):
    """Module doc: "Files are read with allow_pickle=False". A frame file with object
    arrays (a pickle that would run code) is refused by every reader; nothing runs."""
    d = str(tmp_path)
    evil = np.array([_Marker()], dtype=object)
    offsets = np.array([0, 2], np.int32)
    with open(fc.frame_path(d, 1), "wb") as fh:
        np.savez(fh, format=np.array([1, 1]), points=np.zeros((2, 3), np.float32),
                 status=np.zeros(1, np.int8), offsets=offsets, state__angle=evil,
                 attr__d=evil, inputs=evil, extra__groom__points=evil)
    for read in (fc.read_frame, fc.read_attributes, fc.read_shown,
                 lambda d, f: fc.read_extra(d, f, "groom")):
        with pytest.raises(ValueError, match="allow_pickle"):
            read(d, 1)
    assert fc.read_inputs(d, 1) is None
    assert _UNPICKLED == []


def test_a_bake_file_stores_the_sparse_state_and_int32_offsets(tmp_path):
    """write_frame with a SparseState stores the rows that differ (read_frame's keys
    idx__/val__/full__), decode_state gives the state back exactly, names with double
    underscores included; without a state nothing is stored; offsets are int32
    whatever they were given as."""
    d = str(tmp_path)
    base = {"angle": np.zeros(100), "x__y": np.zeros((100, 3)), "meta": np.zeros(3)}
    sp = fc.SparseState(base)
    state = {k: v.copy() for k, v in base.items()}
    state["angle"][5] = 2.0
    state["x__y"][7] = 1.0
    state["meta"][0] = 9.0
    offsets = np.array([0, 2, 4], np.int64)
    fc.write_frame(d, 1, np.zeros((4, 3)), np.zeros(2), offsets, state, sparse=sp)
    _, _, offs, stored = fc.read_frame(d, 1)
    assert offs.dtype == np.int32 and offs.tolist() == [0, 2, 4]
    assert sorted(stored) == ["full__meta", "idx__angle", "idx__x__y", "val__angle",
                              "val__x__y"], sorted(stored)
    assert stored["idx__angle"].tolist() == [5] and stored["idx__x__y"].tolist() == [7]
    back = fc.decode_state(stored, sp)
    assert sorted(back) == sorted(state)
    for k in state:
        np.testing.assert_array_equal(back[k], state[k], err_msg=k)
    fc.write_frame(d, 2, np.zeros((4, 3)), np.zeros(2), offsets, None, sparse=sp)
    assert fc.read_frame(d, 2)[3] == {}


def test_sparse_state_names_may_hold_colons():
    """In memory, any state name comes back (the kind is split off at the first ':')."""
    base = {"a:b": np.zeros(100), "c": np.zeros(100)}
    sp = fc.SparseState(base)
    state = {"a:b": np.arange(100.0), "c": np.zeros(100), "d:e:f": np.ones(3)}
    back = sp.decode(sp.encode(state))
    assert sorted(back) == sorted(state)
    for k in state:
        np.testing.assert_array_equal(back[k], state[k], err_msg=k)


def test_a_state_name_with_a_colon_survives_a_bake_file(tmp_path):
    sp = fc.SparseState({"a:b": np.zeros(100)})
    fc.write_frame(str(tmp_path), 1, np.zeros((2, 3)), np.zeros(1), np.array([0, 2]),
                   {"a:b": np.ones(100)}, sparse=sp)
    back = fc.decode_state(fc.read_frame(str(tmp_path), 1)[3], sp)
    np.testing.assert_array_equal(back["a:b"], np.ones(100))


def test_memory_cache_put_and_get_keep_their_documented_types():
    """put: the exact message for a shape mismatch; a state without a SparseState
    baseline, or no state, is not kept (state() None), never an error; what a frame
    stores and get returns: int32 curves, float32 points, int8 status."""
    mem = fc.MemoryCache()
    inp, out, status, offsets = _frame(changed=(0, 2), value=3.0)
    with pytest.raises(ValueError, match=r"^cache: output and input positions differ in "
                       r"shape$"):
        mem.put(1, inp, out[:-1], status, offsets, None, {})
    state = {"angle": np.ones(4)}
    mem.put(1, inp, out, status, offsets, state, {})  # no baseline yet
    assert mem.frames[1].state is None and mem.state(1) is None
    mem.sparse = fc.SparseState({"angle": np.zeros(4)})
    mem.put(2, inp, out, status, offsets, None, {})  # a baseline, no state
    assert mem.frames[2].state is None and mem.state(2) is None
    mem.put(3, inp, out, status, offsets, state, {})
    np.testing.assert_array_equal(mem.state(3)["angle"], state["angle"])
    fr = mem.frames[3]
    assert fr.curves.dtype == np.int32 and fr.points.dtype == np.float32
    assert fr.status_idx.dtype == np.int32 and fr.status_val.dtype == np.int8
    assert fr.moved.dtype == bool and len(fr.moved) == len(fr.points)
    assert fr.nbytes == 2 * 4 + 6 * 12 + 6 * 1 + 2 * 4 + 2 * 1 + sum(
        a.nbytes for a in fr.state.values())
    got, got_status, _ = mem.get(3, inp, offsets)
    assert got_status.dtype == np.int8 and got_status.tolist() == status.tolist()
    rows, pts, moved_status, _ = mem.get_moved(3, offsets)
    assert rows.dtype == np.int64 and pts.dtype == np.float32
    assert moved_status.tolist() == status.tolist()


def test_a_frame_as_its_moved_rows_is_the_frame_bit_for_bit():
    """get_moved: exactly the rows where the frame differs from its input (bitwise:
    a point of a changed curve left where it was is not among them, nor is -0.0 for
    0.0 the same row), and the input with those rows set is get's frame, bit for bit."""
    rng = np.random.default_rng(4)
    offsets = np.array([0, 3, 7, 8, 12, 15], np.int32)  # curves of 3, 4, 1, 4, 3 points
    inp = rng.normal(size=(15, 3)).astype(np.float32)
    out = inp.copy()
    out[[1, 2, 9]] += np.float32(0.25)  # curves 0 and 3 moved, their roots did not
    out[13, 0] = -out[13, 0] if out[13, 0] == 0 else out[13, 0]  # (unchanged bits)
    inp[14, 1], out[14, 1] = 0.0, -0.0  # curve 4: a sign bit only
    mem = fc.MemoryCache()
    mem.put(5, inp, out, np.zeros(5, np.int8), offsets, None, {})
    rows, pts, _, _ = mem.get_moved(5, offsets)
    assert rows.tolist() == [1, 2, 9, 14]
    rebuilt = inp.copy()
    rebuilt[rows] = pts
    got, _, _ = mem.get(5, inp, offsets)
    assert rebuilt.tobytes() == got.tobytes() == out.tobytes()


def test_an_evicted_state_reads_as_none():
    """state(f) of a frame whose state the budget dropped is None (it still displays)."""
    frames = [_frame(P=400, C=100, changed=range(100), value=float(f)) for f in range(3)]
    base = {"angle": np.zeros(5000)}
    probe = fc.MemoryCache(limit_mb=100)
    probe.sparse = fc.SparseState(base)
    inp, out, status, offsets = frames[0]
    probe.put(0, inp, out, status, offsets, {"angle": np.ones(5000)}, {})
    size = probe.frames[0].nbytes
    mem = fc.MemoryCache(limit_mb=(3 * size - 1) / 2**20)
    mem.sparse = fc.SparseState(base)
    mem.start = 0
    for f, (inp, out, status, offsets) in enumerate(frames):
        mem.put(f, inp, out, status, offsets, {"angle": np.full(5000, f + 1.0)}, {})
    assert sorted(mem.frames) == [0, 1, 2] and mem.frames[1].state is None
    assert mem.state(1) is None and mem.state(2)["angle"][0] == 3.0
    np.testing.assert_array_equal(mem.get(1, inp, offsets)[0], frames[1][1])


def test_budget_without_a_start_frame_counts_from_the_oldest_frame():
    """MemoryCache.start unset (a pipeline script's cache): every 10th frame from the
    oldest cached one keeps its state."""
    base = {"angle": np.zeros(2000)}
    inp, out, status, offsets = _frame(P=40, C=10, changed=range(10))
    probe = fc.MemoryCache(limit_mb=100)
    probe.sparse = fc.SparseState(base)
    probe.put(0, inp, out, status, offsets, {"angle": np.ones(2000)}, {})
    state = sum(a.nbytes for a in probe.frames[0].state.values())
    frame = probe.frames[0].nbytes - state
    mem = fc.MemoryCache(limit_mb=(25 * frame + 4 * state) / 2**20)
    mem.sparse = fc.SparseState(base)
    assert mem.start is None
    for f in range(3, 28):
        mem.put(f, inp, out, status, offsets, {"angle": np.full(2000, float(f))}, {})
    assert sorted(mem.frames) == list(range(3, 28))
    assert sorted(k for k in mem.frames if mem.frames[k].state is not None) == [3, 13, 23, 27]


@pytest.mark.parametrize("what", ["state", "frame"])
def test_budget_stops_dropping_exactly_at_the_limit(what):
    """Dropping stops as soon as the total is at most the limit: a limit that one
    dropped state (or one dropped frame) meets exactly loses that one and no more."""
    base = {"angle": np.zeros(2000)}
    inp, out, status, offsets = _frame(P=40, C=10, changed=range(10))
    probe = fc.MemoryCache(limit_mb=100)
    probe.sparse = fc.SparseState(base)
    probe.put(0, inp, out, status, offsets, {"angle": np.ones(2000)}, {})
    state = sum(a.nbytes for a in probe.frames[0].state.values())
    full = probe.frames[0].nbytes
    assert state < full < 2 * state  # the arithmetic below needs it
    if what == "state":  # all five fit without the states of frames 1 and 2 (exactly)
        frames, limit = (0, 1, 2, 3, 4), 5 * full - 2 * state
    else:  # states alone do not suffice: frame 1 goes, and frame 2 (stateless) stays
        frames, limit = (0, 1, 2, 3), 2 * full + (full - state)
    mem = fc.MemoryCache(limit_mb=limit / 2**20)
    mem.sparse = fc.SparseState(base)
    mem.start = 0
    for f in frames:
        mem.put(f, inp, out, status, offsets, {"angle": np.full(2000, f + 1.0)}, {})
    with_state = sorted(k for k in mem.frames if mem.frames[k].state is not None)
    if what == "state":  # 0 is the start frame, 4 the newest; 3 keeps its state
        assert sorted(mem.frames) == [0, 1, 2, 3, 4] and with_state == [0, 3, 4]
    else:
        assert sorted(mem.frames) == [0, 2, 3] and with_state == [0, 3]
    assert mem.nbytes == limit


@pytest.mark.parametrize(("f", "want"), [
    (1, (1, 2)), (5, (5, 6)), (9, (9, 10)),  # between two baked frames
    (10, (10, 10)), (12, (10, 10)),  # from the end frame on: the end frame held
    (0, None), (-3, None),  # before the start: nothing baked to blend
])
def test_subframe_pair_blends_neighbours_and_holds_the_end(f, want):
    """The baked frames a motion-blur subframe after frame ``f`` blends (the guides and
    the render groom alike), for a bake of frames 1-10."""
    assert fc.subframe_pair(f, 1, 10) == want


def test_subframe_pair_of_a_one_frame_bake_holds_it():
    assert fc.subframe_pair(4, 4, 4) == (4, 4)
    assert fc.subframe_pair(3, 4, 4) is None


def test_subframe_blend_is_float32_and_ends_at_the_baked_frames():
    a = np.array([[0.0, 1.0, 2.0]], np.float32)
    b = np.array([[1.0, 1.0, -2.0]], np.float32)
    got = fc.subframe_blend(a, b, 0.25)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, [[0.25, 1.0, 1.0]])
    np.testing.assert_array_equal(fc.subframe_blend(a, b, 0.0), a)
    np.testing.assert_array_equal(fc.subframe_blend(a, b, 1.0), b)
