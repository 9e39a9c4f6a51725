"""A curve's result never depends on the other curves solved with it.

Curves of different lengths are batched as one ragged array; a sum over that
array (one global cumsum minus each curve's offset) once carried the rounding
of the curves before a curve into its points and rays, so removing a curve
earlier in the groom changed later curves in the last bits (and could flip a
contact decided within an ulp). Every curve's sums are its own now
(``rotations.cumsum_owned``).
"""

from __future__ import annotations

import numpy as np
import pytest
import scenes

from core import Collider, Settings, Solver, Status


def _sweep(f, x0):
    """The ball's matrix at frame ``f``: turning and sweeping through the fur from ``x0``."""
    return scenes.affine(scenes.rotation_matrix([0, 1, 0.3], 0.15 * f),
                         t=[x0 + 0.25 * f, 0.05 * f, 0.55 - 0.04 * f])


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_removing_earlier_curves_leaves_the_others_bit_for_bit(mode, seed):
    rng = np.random.default_rng(seed)
    pts, offs = scenes.fur_on_plane(rng, n_curves=80, curly=0.3, lean=0.3, extent=1.0,
                                    n_cvs=(3, 9))
    V, F = scenes.uv_sphere([0, 0, 0], 0.45, 24, 12)
    drop = 17  # the groom without its first curves
    pts2 = pts[offs[drop]:]
    offs2 = offs[drop:] - offs[drop]
    a_sol = Solver(offs, Settings(mode=mode))
    b_sol = Solver(offs2, Settings(mode=mode))
    col = Collider(V, F)
    for f in range(6):
        col.matrix = _sweep(f, -0.6)
        a = a_sol.step(pts, [col])
        b = b_sol.step(pts2, [col])
        np.testing.assert_array_equal(a.status[drop:], b.status)
        np.testing.assert_array_equal(a.points[offs[drop]:], b.points)
    assert (a.status != 0).any()  # the sphere met the fur


@pytest.mark.parametrize("shrink", [False, True])
@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_a_uniform_groom_equals_the_same_curves_in_a_ragged_one(mode, shrink):
    """Curves of one CV count are solved on component arrays (``RigidBatch._init_uniform``,
    ``StepContext._deform_uniform``), a groom of mixed counts row by row: one far-away
    curve of another count added to a uniform groom leaves every other curve's search
    (statuses, angles) exactly as it was, Shrink included, and its points to the last
    float64 bits (the two paths sum a segment's terms in another order)."""
    rng = np.random.default_rng(7)
    pts, offs = scenes.fur_on_plane(rng, n_curves=60, curly=0.3, lean=0.3, extent=1.0,
                                    n_cvs=(6, 6))
    extra, eo = scenes.pack([scenes.straight_curve([9.0, 9.0, 0.0], [0, 0, 1], 0.5, 3)])
    pts2 = np.concatenate([pts, extra])
    offs2 = np.concatenate([offs, offs[-1] + eo[1:]])
    V, F = scenes.uv_sphere([0, 0, 0], 0.45, 24, 12)
    s = Settings(mode=mode, shrink=shrink, scale_minimum=0.6, scale_angle=60.0)
    a_sol, b_sol = Solver(offs, s), Solver(offs2, s)
    col = Collider(V, F)
    for f in range(5):
        col.matrix = _sweep(f, -0.5)
        a = a_sol.step(pts, [col])
        b = b_sol.step(pts2, [col])
        np.testing.assert_array_equal(a.status, b.status[:-1])
        sa, sb = a_sol.state, b_sol.state
        np.testing.assert_array_equal(sa["angle"], sb["angle"][:-1])
        if mode == "soft":  # per-segment rotations, to the last bits
            np.testing.assert_allclose(sa["quat"], sb["quat"][:len(sa["quat"])], atol=1e-14)
        np.testing.assert_allclose(a.points, b.points[:len(pts)], rtol=0, atol=1e-14)
    assert (a.status != 0).any()


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_curves_keep_their_own_state_frame_after_frame_in_any_batch(mode):
    """A uniform groom (every curve 5 CVs: Soft's component-array path) under a
    ball coming down over 8 frames, curves keeping their rotations (recovery rate
    0): solved as one groom or as two halves, every frame's output is the same bit
    for bit (no curve's state is read for another)."""
    rng = np.random.default_rng(4)
    pts, offs = scenes.fur_on_plane(rng, n_curves=80, n_cvs=(5, 5), extent=0.6)
    C = len(offs) - 1
    cut = offs[C // 2]
    parts = [(pts[:cut], offs[: C // 2 + 1]), (pts[cut:], offs[C // 2:] - cut)]
    s = Settings(mode=mode, recovery_rate=0.0)
    whole = Solver(offs, s)
    halves = [Solver(o, s) for _, o in parts]
    colliding = 0
    for f in range(8):
        V, F = scenes.uv_sphere([0.1 * np.sin(f), 0.0, 1.2 - 0.05 * f], 0.4, 24, 12)
        a = whole.step(pts, [Collider(V, F)])
        b = [h.step(p, [Collider(V, F)]) for h, (p, _) in zip(halves, parts, strict=True)]
        np.testing.assert_array_equal(a.points, np.vstack([r.points for r in b]))
        np.testing.assert_array_equal(a.status, np.concatenate([r.status for r in b]))
        colliding += int((np.asarray(a.status) == 1).sum())
    assert colliding > 20


@pytest.mark.parametrize("bad", ["nan", "duplicated_point", "inf_root"])
@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_one_bad_curve_changes_no_other_curve(mode, bad):
    """A ragged groom with one broken curve (a NaN CV, a duplicated CV, an infinite
    root): every other curve is solved bit for bit as in the groom without the break,
    on every frame of a sweep; the broken one is INVALID, never NaN, and its root stays."""
    rng = np.random.default_rng(7)
    pts, offs = scenes.fur_on_plane(rng, n_curves=60, curly=0.3, extent=0.9, n_cvs=(2, 9),
                                    length=(0.5, 1.0))
    pts = pts.astype(np.float32)
    k = 23
    assert offs[k + 1] - offs[k] >= 3
    broken = pts.copy()
    if bad == "nan":
        broken[offs[k] + 1] = np.nan
    elif bad == "duplicated_point":
        broken[offs[k] + 2] = broken[offs[k] + 1]
    else:
        broken[offs[k]] = np.inf
    V, F = scenes.uv_sphere([0, 0, 0], 0.4, 24, 12)
    col = Collider(V, F)
    a, b = Solver(offs, Settings(mode=mode)), Solver(offs, Settings(mode=mode))
    others = np.ones(len(offs) - 1, bool)
    others[k] = False
    rows = np.repeat(others, np.diff(offs))
    touched = 0
    for f in range(6):
        col.matrix = scenes.turning_sweep(f)
        ra = a.step(pts, [col])
        rb = b.step(broken, [col])
        assert np.isfinite(rb.points).all()
        assert rb.status[k] == Status.INVALID
        assert rb.problems and f"curve {k}" in rb.problems[0], rb.problems
        np.testing.assert_array_equal(rb.status[others], ra.status[others], err_msg=f"{f}")
        np.testing.assert_array_equal(rb.points[rows], ra.points[rows], err_msg=f"{f}")
        touched += int((ra.status != 0).sum())
        if bad != "inf_root":
            assert np.array_equal(rb.points[offs[k]], broken[offs[k]])
    assert touched > 10
