"""Fuzzed inputs: the core either rejects them with a FurCollide ValueError
or returns a finite, well-shaped result. Never another exception, never NaN."""

from __future__ import annotations

import numpy as np
import pytest
import scenes
from geom import FAST
from hypothesis import given
from hypothesis import strategies as st

from core import Collider, Settings, Solver, Status
from core.errors import FurCollideError

CORRUPTIONS = [
    "none", "nan_point", "inf_point", "dup_point", "swap_offsets", "short_offsets",
    "long_offsets", "nan_vertex", "bad_face", "neg_face", "degenerate_face", "empty_mesh",
    "huge_coords", "tiny_curve", "enabled_len", "float32", "single_point_curve",
]


@pytest.mark.parametrize("kind", CORRUPTIONS)
@FAST
@given(seed=st.integers(0, 2**31 - 1), mode=st.sampled_from(["stiff", "bend", "soft"]))
def test_fuzzed_input_is_rejected_cleanly_or_solved(seed, kind, mode):
    rng = np.random.default_rng(seed)
    pts, offs = scenes.fur_on_plane(rng, n_curves=int(rng.integers(1, 8)), extent=0.5)
    V, F = scenes.uv_sphere([0, 0, 0.8], 0.35, 12, 6)
    enabled = None
    i = int(rng.integers(len(pts)))
    if kind == "nan_point":
        pts[i, int(rng.integers(3))] = np.nan
    elif kind == "inf_point":
        pts[i, int(rng.integers(3))] = np.inf
    elif kind == "dup_point" and i + 1 < len(pts):
        pts[i + 1] = pts[i]
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
        V[int(rng.integers(len(V)))] = np.nan
    elif kind == "bad_face":
        F = F.copy()
        F[int(rng.integers(len(F))), int(rng.integers(3))] = len(V) + int(rng.integers(5))
    elif kind == "neg_face":
        F = F.copy()
        F[int(rng.integers(len(F))), int(rng.integers(3))] = -1
    elif kind == "degenerate_face":
        F = F.copy()
        j = int(rng.integers(len(F)))
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
        enabled = np.ones(len(offs) - 1 + int(rng.integers(1, 3)), bool)
    elif kind == "float32":
        pts = pts.astype(np.float32)
    elif kind == "single_point_curve":
        pts = np.vstack([pts, pts[-1:] + 1.0])
        offs = np.append(offs, len(pts))
    must_fail = kind in ("short_offsets", "long_offsets", "nan_vertex", "bad_face", "neg_face",
                         "degenerate_face", "enabled_len", "single_point_curve") or (
        kind == "swap_offsets" and len(offs) > 2)
    if must_fail:
        with pytest.raises(FurCollideError) as ei:
            Solver(offs, Settings(mode=mode)).step(pts, [Collider(V, F)], enabled=enabled)
        assert str(ei.value)  # a message for the user
        return
    # everything else is solved (a bad curve is marked INVALID, never raised)
    res = Solver(offs, Settings(mode=mode)).step(pts, [Collider(V, F)], enabled=enabled)
    assert res.points.shape == pts.shape
    assert res.points.dtype == pts.dtype
    assert np.all(np.isfinite(res.points))
    status = np.asarray(res.status)
    assert status.shape == (len(offs) - 1,)
    owner = np.searchsorted(offs, np.arange(len(pts)), "right") - 1
    bad_rows = ~np.isfinite(pts).all(axis=1)
    bad = np.zeros(len(offs) - 1, bool)
    bad[owner[bad_rows]] = True
    if kind in ("nan_point", "inf_point"):
        assert bad.any() and (status[bad] == Status.INVALID).all()
        assert res.problems and "not finite" in res.problems[0]
    if kind == "dup_point" and (status == Status.INVALID).any():
        assert "zero-length" in res.problems[0]
    ok = status != Status.INVALID
    assert np.array_equal(res.points[offs[:-1]][ok], pts[offs[:-1]][ok])
    # the invalid curves are their input where it was finite
    keep = np.isin(owner, np.flatnonzero(~ok)) & ~bad_rows
    assert np.array_equal(res.points[keep], pts[keep])
