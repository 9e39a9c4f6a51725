"""Render groom follows the guides: identity, rigid motion, roots; the clearance pass."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pipe_oracle as po
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core import Collider, Settings, Solver, Status
from core.errors import InputError
from core.pipeline import (
    GroomBinding,
    GroomWeights,
    bind,
    bind_groom,
    clearance_pass,
    deform_groom,
    knn,
    wind,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "core"))
import scenes  # noqa: E402  (the core tests' scene builders)

PROP = settings(max_examples=examples(10))
FREE, COLLIDING, RECOVERING, PINCHED, UNRESOLVED, DISABLED = range(6)


def _groom(seed, n_guides=40, n_render=250):
    rng = np.random.default_rng(seed)
    V, F = po.icosphere((0, 0, 0), 1.0, 2)
    gp, go = po.fur_on_mesh(rng, V, F, n_guides, 6, 0.4)
    rp, ro = po.fur_on_mesh(rng, V, F, n_render, int(rng.integers(3, 9)), 0.4)
    return rng, gp, go, rp, ro


def _seg_len(p, off):
    A, B, _ = po.segments(p, off)
    return np.linalg.norm(B - A, axis=1)


def test_knn_and_weights_against_brute_force():
    rng = np.random.default_rng(0)
    Q, X = rng.normal(size=(200, 3)), rng.normal(size=(50, 3))
    idx, d = knn(Q, X, 4)
    D = np.linalg.norm(Q[:, None] - X[None], axis=-1)
    np.testing.assert_array_equal(idx, np.argsort(D, 1, kind="stable")[:, :4])
    np.testing.assert_allclose(d, np.sort(D, 1)[:, :4], atol=1e-12)
    # large enough for the grid path (points near a surface, some far queries)
    Xs = rng.normal(size=(3000, 3)) * [1, 1, 0.02]
    Qs = np.vstack([rng.normal(size=(2500, 3)) * [1, 1, 0.02], rng.normal(size=(50, 3)) * 5])
    idx, d = knn(Qs, Xs, 5)
    D = np.linalg.norm(Qs[:, None] - Xs[None], axis=-1)
    np.testing.assert_array_equal(idx, np.argsort(D, 1, kind="stable")[:, :5])
    np.testing.assert_allclose(d, np.sort(D, 1)[:, :5], atol=1e-12)
    w = bind_groom(Q, X, 4)
    np.testing.assert_allclose(w.weight.sum(1), 1)
    assert (np.diff(w.weight, axis=1) <= 1e-15).all()  # nearer guides weigh more
    w = bind_groom(X[:3] + 0.0, X, 4)  # render roots on guide roots
    np.testing.assert_array_equal(w.weight[:, 0], 1.0)


@PROP
@given(seed=st.integers(0, 10_000))
def test_identity_when_guides_do_not_move(seed):
    _, gp, go, rp, ro = _groom(seed)
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 4)
    np.testing.assert_allclose(deform_groom(rp, ro, gp, gp.copy(), go, w), rp, atol=1e-9, rtol=0)


@PROP
@given(seed=st.integers(0, 10_000), angle=st.floats(-3.1, 3.1),
       axis=st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda a: np.linalg.norm(a) > 0.1),
       t=st.tuples(*[st.floats(-3, 3)] * 3))
def test_rigid_guide_motion_moves_the_groom_rigidly(seed, angle, axis, t):
    _, gp, go, rp, ro = _groom(seed)
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 4)
    R = po.rotation(axis, angle)
    out = deform_groom(rp, ro, gp, gp @ R.T + np.asarray(t), go, w)
    np.testing.assert_allclose(out, rp @ R.T + np.asarray(t), atol=1e-9, rtol=0)


@PROP
@given(seed=st.integers(0, 10_000), frame=st.floats(0, 200))
def test_render_curve_on_a_guide_follows_it_exactly(seed, frame):
    rng, gp, go, rp, ro = _groom(seed)
    gn = wind(gp, go, frame, strength=0.3, turbulence=1.0, seed=seed)  # bends, keeps lengths
    w = bind_groom(gp[go[:-1]], gp[go[:-1]], 4)  # the guides themselves as render curves
    out = deform_groom(gp, go, gp, gn, go, w)
    np.testing.assert_allclose(out, gn, atol=1e-9, rtol=0)
    # and a real groom: lengths kept, roots follow the guide roots (they do not move here)
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 4)
    out = deform_groom(rp, ro, gp, gn, go, w)
    np.testing.assert_allclose(_seg_len(out, ro), _seg_len(rp, ro), rtol=1e-9)
    np.testing.assert_allclose(out[ro[:-1]], rp[ro[:-1]], atol=1e-9)
    assert np.abs(out - rp).max() > 1e-3


def test_roots_follow_the_guides_and_explicit_roots():
    _, gp, go, rp, ro = _groom(5)
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 4)
    shift = np.array([0.0, 0.0, 0.5])
    out = deform_groom(rp, ro, gp, gp + shift, go, w)
    np.testing.assert_allclose(out[ro[:-1]], rp[ro[:-1]] + shift, atol=1e-12)
    roots = rp[ro[:-1]] + 1.0
    out = deform_groom(rp, ro, gp, gp, go, w, render_roots_now=roots)
    np.testing.assert_array_equal(out[ro[:-1]], roots)


def test_a_binding_deforms_as_deform_groom_with_its_own_deformer(monkeypatch):
    """GroomBinding: the arrays it is built from (saved and loaded as they are) give a
    binding whose groom follows the guides as deform_groom does, its roots on the
    surface when bound to it; its GroomDeformer is made once, by the first frame."""
    _, gp, go, rp, ro = _groom(8)
    V, F = po.icosphere((0, 0, 0), 1.0, 2)
    arrays, notes = GroomBinding.build(rp, ro, gp, go, 4, surface=(V, F, (len(V), len(F))))
    assert notes == []
    binding = GroomBinding(dict(arrays))
    assert binding.deformer is None and binding.surface_key == (len(V), len(F))
    made = []
    from core.pipeline import groom as groom_mod

    real = groom_mod.GroomDeformer

    def counted(*a, **k):
        made.append(1)
        return real(*a, **k)

    monkeypatch.setattr(groom_mod, "GroomDeformer", counted)
    w = GroomWeights(arrays["weights_index"], arrays["weights_weight"])
    V2 = V * 1.1
    for f in range(3):
        gn = wind(gp, go, f, strength=0.3, turbulence=1.0) * 1.1
        points, status = binding.deform(gn, V2, threads=1)
        roots = bind(rp, ro, V, F, drop_degenerate=True).roots(V2)
        np.testing.assert_array_equal(points, real(rp, ro, gp, go, w).deform(gn, roots, 1))
        assert (status == Status.FREE).all()
    assert made == [1]


def test_a_binding_sets_invalid_curves_aside():
    _, gp, go, rp, ro = _groom(9)
    bad = rp.copy()
    bad[ro[3] + 1] = bad[ro[3]]  # a zero-length segment
    bad[ro[7] + 1] = np.nan
    gbad = gp.copy()
    gbad[go[2] + 1] = np.inf
    arrays, notes = GroomBinding.build(bad, ro, gbad, go, 4, name="'Groom'")
    assert notes[0].startswith("2 curves of 'Groom' cannot be solved (curve 3 has a zero")
    assert notes[1].startswith("1 guide cannot be followed (curve 2: point")
    binding = GroomBinding(arrays)
    assert np.flatnonzero(binding.invalid).tolist() == [3, 7]
    assert not binding.guides_used[2] and binding.note.startswith("Render groom: 2 curves")
    points, status = binding.deform(gbad, threads=1)
    assert np.flatnonzero(status == Status.INVALID).tolist() == [3, 7]
    assert np.isfinite(points).all()  # (never NaN: set aside as the solver outputs them)
    rows, _ = binding.subset(binding.invalid)
    np.testing.assert_array_equal(points[rows], binding.render_ref[rows])
    with pytest.raises(InputError, match="No guide can be followed"):
        GroomBinding.build(rp, ro, np.full_like(gp, np.nan), go, 4)


def _oracle_hits(points, offsets, V, F):
    A, B, cid = po.segments(points, offsets)
    hit = po.segments_cross_mesh(A, B, V, F, eps=-1e-6)
    return np.unique(cid[hit])


def test_clearance_pass_after_guide_deform():
    rng = np.random.default_rng(11)
    Vg, Fg = po.grid(2.4, 6)
    gp, go = po.fur_on_mesh(rng, Vg, Fg, 30, 6, 0.8, noise=0.05)
    rp, ro = po.fur_on_mesh(rng, Vg, Fg, 300, 6, 0.8, noise=0.05)
    # the guides lean over and FurCollide solves them against a sphere
    R = po.rotation([0, 1, 0], 0.8)
    lean = np.concatenate([
        (gp[go[i]:go[i + 1]] - gp[go[i]]) @ R.T + gp[go[i]] for i in range(len(go) - 1)])
    Vs, Fs = po.icosphere((0.4, 0.0, 0.35), 0.28, 2)
    col = Collider(Vs, Fs)
    gn = Solver(go, Settings(mode="bend")).step(lean, [col]).points
    V32 = Vs.astype(np.float32).astype(np.float64)
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 4)
    render = deform_groom(rp, ro, gp, gn, go, w)
    before = _oracle_hits(render, ro, V32, Fs)
    assert len(before) > 0, "the scene must make render curves pass through the sphere"
    out, status, n_fixed = clearance_pass(render, ro, [col])
    after = _oracle_hits(out, ro, V32, Fs)
    excluded = np.isin(status, [PINCHED, UNRESOLVED])
    assert not np.isin(after, np.flatnonzero(~excluded)).any()
    assert excluded.sum() <= 0.02 * len(status)
    moved = [not np.array_equal(out[ro[i]:ro[i + 1]], render[ro[i]:ro[i + 1]])
             for i in range(len(ro) - 1)]
    assert n_fixed == sum(moved) >= len(before) - excluded.sum()
    np.testing.assert_array_equal(out[ro[:-1]], render[ro[:-1]])  # stiff: roots stay


def test_bad_input():
    _, gp, go, rp, ro = _groom(6)
    with pytest.raises(InputError, match="at least one guide"):
        bind_groom(rp[ro[:-1]], np.zeros((0, 3)))
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 4)
    with pytest.raises(InputError, match="render curves"):
        deform_groom(rp, ro, gp, gp, go, GroomWeights(w.index[:-1], w.weight[:-1]))
    with pytest.raises(InputError, match="guides_now_points"):
        deform_groom(rp, ro, gp, gp[:-1], go, w)
    with pytest.raises(InputError, match="out of range"):
        deform_groom(rp, ro, gp[:go[2]], gp[:go[2]], go[:3], w)


@pytest.mark.parametrize("n_guides", [1, 2])
def test_few_guides_rigid_motion(n_guides):
    _, gp, go, rp, ro = _groom(8)
    gp, go = gp[:go[n_guides]], go[:n_guides + 1]
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 4)
    R = po.rotation([0.3, -1, 0.2], 2.0)
    out = deform_groom(rp, ro, gp, gp @ R.T + 1.0, go, w)
    np.testing.assert_allclose(out, rp @ R.T + 1.0, atol=1e-9, rtol=0)


def _bend(pts, offs, angle):
    """Each curve bent about x at its root by ``angle`` (radians) times its arc fraction."""
    out = pts.copy()
    for c in range(len(offs) - 1):
        s, e = offs[c], offs[c + 1]
        n = e - s - 1
        p = pts[s]
        for j in range(n):
            R = scenes.rotation_matrix([1, 0, 0], angle * (j + 1) / n)
            out[s + j + 1] = p + (pts[s + j + 1] - pts[s + j]) @ R.T
            p = out[s + j + 1]
    return out


@pytest.mark.parametrize("move", ["still", "rigid", "bent"])
def test_render_curves_lying_on_ragged_guides_follow_them(move):
    """README: a render curve lying on a guide follows it exactly (and a still guide set
    leaves the groom unchanged, a rigid motion moves it rigidly), with guides and render
    curves of mixed CV counts."""
    rng = np.random.default_rng(3)
    g_pts, g_off = scenes.fur_on_plane(rng, n_curves=12, curly=0.0, lean=0.2, extent=1.0,
                                       n_cvs=(2, 9))
    roots = g_pts[g_off[:-1]]
    w = bind_groom(roots, roots, k=1)
    if move == "still":
        now = g_pts.copy()
    elif move == "rigid":
        R = scenes.rotation_matrix([0.2, 1, 0.4], 0.7)
        now = g_pts @ R.T + [0.3, -0.2, 0.1]
    else:
        now = _bend(g_pts, g_off, 0.6)
    out = deform_groom(g_pts, g_off, g_pts, now, g_off, w)
    assert np.isfinite(out).all()
    np.testing.assert_allclose(out, now, atol=1e-9)
