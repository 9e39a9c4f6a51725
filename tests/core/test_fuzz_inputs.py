"""Fuzzed inputs: the core either rejects them with a FurCollide ValueError
or returns a finite, well-shaped result. Never another exception, never NaN."""

from __future__ import annotations

import re

import numpy as np
import pytest
import scenes
import strategies as strat
from geom import FAST
from hypothesis import given
from hypothesis import strategies as st

from core import Collider, Settings, Solver, Status
from core.errors import ColliderError, FurCollideError, InputError

CORRUPTIONS = [
    "none", "nan_point", "inf_point", "dup_point", "swap_offsets", "short_offsets",
    "long_offsets", "nan_vertex", "bad_face", "neg_face", "degenerate_face", "empty_mesh",
    "huge_coords", "tiny_curve", "enabled_len", "float32", "single_point_curve",
]


#: The corruptions that must be refused, and the typed error each raises.
REFUSED = {"short_offsets": InputError, "long_offsets": InputError,
           "nan_vertex": ColliderError, "bad_face": ColliderError,
           "neg_face": ColliderError, "degenerate_face": ColliderError,
           "enabled_len": InputError, "single_point_curve": InputError,
           "swap_offsets": InputError}
#: The corruptions after which every curve is still valid input.
VALID = ("none", "empty_mesh", "huge_coords", "tiny_curve", "float32")


@pytest.mark.parametrize("kind", CORRUPTIONS)
@FAST
@given(fur=st.lists(strat.curves(extent=0.5, n_cvs=(2, 8)), min_size=1, max_size=7),
       where=st.floats(0.0, 1.0, exclude_max=True), axis=st.integers(0, 2),
       mode=st.sampled_from(["stiff", "bend", "soft"]))
def test_fuzzed_input_is_rejected_cleanly_or_solved(fur, where, axis, kind, mode):
    """Every corruption of a drawn groom and collider is either refused with the typed
    error naming the culprit, or solved: valid input has no INVALID curve, and a bad
    curve (NaN, infinite or duplicated point) is exactly the INVALID one, left as its
    input, while every other curve is solved exactly as with that curve disabled."""
    pts, offs = scenes.pack(fur)
    V, F = scenes.uv_sphere([0, 0, 0.8], 0.35, 12, 6)
    enabled = None
    i = int(where * len(pts))  # the point (or vertex, or face) the corruption picks
    owner = np.searchsorted(offs, np.arange(len(pts)), "right") - 1
    expect_invalid = np.zeros(len(offs) - 1, bool)
    if kind == "nan_point":
        pts[i, axis] = np.nan
        expect_invalid[owner[i]] = True
    elif kind == "inf_point":
        pts[i, axis] = np.inf
        expect_invalid[owner[i]] = True
    elif kind == "dup_point" and i + 1 < len(pts):
        pts[i + 1] = pts[i]
        expect_invalid[owner[i]] = owner[i] == owner[i + 1]  # a zero-length segment
    elif kind == "swap_offsets" and len(offs) > 2:
        offs = offs.copy()
        offs[1], offs[2] = offs[2], offs[1]
    elif kind == "short_offsets":
        offs = offs.copy()
        offs[-1] -= 1
    elif kind == "long_offsets":
        offs = offs.copy()
        offs[-1] += 1
    elif kind == "nan_vertex":
        V = V.copy()
        V[int(where * len(V))] = np.nan
    elif kind == "bad_face":
        F = F.copy()
        F[int(where * len(F)), axis] = len(V) + axis
    elif kind == "neg_face":
        F = F.copy()
        F[int(where * len(F)), axis] = -1
    elif kind == "degenerate_face":
        F = F.copy()
        j = int(where * len(F))
        F[j, 1] = F[j, 0]
    elif kind == "empty_mesh":
        V, F = np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    elif kind == "huge_coords":
        pts = pts * 1e6
        V = V * 1e6
    elif kind == "tiny_curve":
        pts = pts * 1e-9
        V = V * 1e-9
    elif kind == "enabled_len":
        enabled = np.ones(len(offs) - 1 + axis + 1, bool)
    elif kind == "float32":
        pts = pts.astype(np.float32)
    elif kind == "single_point_curve":
        pts = np.vstack([pts, pts[-1:] + 1.0])
        offs = np.append(offs, len(pts))
    must_fail = kind in REFUSED and not (kind == "swap_offsets" and len(offs) <= 2)
    if must_fail:
        with pytest.raises(FurCollideError) as ei:
            Solver(offs, Settings(mode=mode)).step(pts, [Collider(V, F)], enabled=enabled)
        assert type(ei.value) is REFUSED[kind], (kind, type(ei.value))
        msg = str(ei.value)
        if kind in ("bad_face", "neg_face", "degenerate_face"):
            assert re.search(rf"\bface {int(where * len(F))}\b", msg), msg
        if kind == "nan_vertex":
            assert re.search(rf"\b{int(where * len(V))}\b", msg), msg
        if kind == "single_point_curve":
            assert re.search(rf"\b{len(offs) - 2}\b", msg), msg
        return
    # everything else is solved (a bad curve is marked INVALID, never raised)
    col = Collider(V, F)
    res = Solver(offs, Settings(mode=mode)).step(pts, [col], enabled=enabled)
    assert res.points.shape == pts.shape
    assert res.points.dtype == pts.dtype
    assert np.all(np.isfinite(res.points))
    status = np.asarray(res.status)
    assert status.shape == (len(offs) - 1,)
    if kind in VALID or not expect_invalid.any():
        assert not (status == Status.INVALID).any(), (kind, status)
        assert not res.problems, res.problems
    np.testing.assert_array_equal(status == Status.INVALID, expect_invalid)
    if kind in ("nan_point", "inf_point"):
        assert res.problems and "not finite" in res.problems[0]
    if kind == "dup_point" and expect_invalid.any():
        assert res.problems and "zero-length" in res.problems[0]
    ok = ~expect_invalid
    assert np.array_equal(res.points[offs[:-1]][ok], pts[offs[:-1]][ok])
    # the invalid curves are their input where it was finite
    bad_rows = ~np.isfinite(pts).all(axis=1)
    keep = np.isin(owner, np.flatnonzero(expect_invalid)) & ~bad_rows
    assert np.array_equal(res.points[keep], pts[keep])
    if expect_invalid.any():  # the others: as if the bad curve were switched off
        ref = Solver(offs, Settings(mode=mode)).step(np.where(np.isfinite(pts), pts, 0.0),
                                                     [Collider(V, F)], enabled=ok)
        rows = np.isin(owner, np.flatnonzero(ok))
        np.testing.assert_array_equal(res.points[rows], ref.points[rows])
        np.testing.assert_array_equal(status[ok], np.asarray(ref.status)[ok])
