"""The pipeline's fast paths agree with the straightforward implementations.

The references (tests/pipeline/slow_reference.py) are the code of
``core.pipeline`` before its per-frame stages were made fast (issue 11). The
fast paths compute the same formulas in another order (bind-time caches,
blocked component arrays): they must agree within
``tolerances.PIPELINE_REORDER_REL`` times the scene's size, on
hypothesis-drawn inputs.
"""

from __future__ import annotations

import numpy as np
import pipe_oracle as po
import pytest
import slow_reference as ref
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core import tolerances as tol
from core.errors import InputError
from core.pipeline import GroomDeformer, bind_groom, deform_groom, wind

PROP = settings(max_examples=examples(25))


def _close(a, b, *scenes):
    size = max(float(np.abs(np.concatenate([np.ravel(s) for s in scenes])).max()), 1.0)
    np.testing.assert_allclose(a, b, rtol=0, atol=tol.PIPELINE_REORDER_REL * size)


def _groom(seed, n_guides, n_render, uniform):
    rng = np.random.default_rng(seed)
    V, F = po.icosphere((0.2, -0.1, 0.3), 1.0, 2)
    if uniform:
        gp, go = po.fur_on_mesh(rng, V, F, n_guides, int(rng.integers(2, 9)), 0.4)
    else:
        gp, go = po.pack([po.fur_on_mesh(rng, V, F, 1, int(rng.integers(2, 9)), 0.4)[0]
                          for _ in range(n_guides)])
    if uniform:
        rp, ro = po.fur_on_mesh(rng, V, F, n_render, int(rng.integers(2, 9)), 0.4)
    else:  # every curve its own CV count
        parts = [po.fur_on_mesh(rng, V, F, 1, int(rng.integers(2, 9)), 0.4)[0]
                 for _ in range(n_render)]
        rp, ro = po.pack(parts)
    return rng, gp, go, rp, ro


@PROP
@given(seed=st.integers(0, 10_000), n_guides=st.integers(1, 30), n_render=st.integers(1, 120),
       k=st.integers(1, 6), uniform=st.booleans(), own_roots=st.booleans(),
       strength=st.floats(0.0, 1.5), angle=st.floats(-3.1, 3.1))
def test_deform_groom_matches_the_reference(seed, n_guides, n_render, k, uniform, own_roots,
                                            strength, angle):
    rng, gp, go, rp, ro = _groom(seed, n_guides, n_render, uniform)
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], k)
    R = po.rotation(rng.normal(size=3), angle)
    gn = wind(gp, go, seed % 97, strength=strength, turbulence=1.0, seed=seed) @ R.T + 0.3
    roots = rp[ro[:-1]] @ R.T + 0.3 if own_roots else None
    want = ref.deform_groom_v0(rp, ro, gp, gn, go, w, render_roots_now=roots)
    got = deform_groom(rp, ro, gp, gn, go, w, render_roots_now=roots)
    _close(got, want, rp, gn)
    # a second call and an explicit deformer give the same
    again = deform_groom(rp, ro, gp, gn, go, w, render_roots_now=roots)
    np.testing.assert_array_equal(again, got)
    d = GroomDeformer(rp, ro, gp, go, w)
    np.testing.assert_array_equal(d.deform(gn, roots), got)


def test_deform_groom_follows_its_inputs():
    """A changed reference (in place or a new array) or new weights change the result:
    nothing of an earlier call is kept (a per-frame caller keeps a GroomDeformer)."""
    _, gp, go, rp, ro = _groom(3, 20, 60, True)
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 4)
    gn = wind(gp, go, 3, strength=0.5, turbulence=1.0)
    deform_groom(rp, ro, gp, gn, go, w)
    rp[5] += 0.01  # in place
    _close(deform_groom(rp, ro, gp, gn, go, w), ref.deform_groom_v0(rp, ro, gp, gn, go, w),
           rp, gn)
    gp2 = gp.copy()
    gp2[go[1]] += 0.01
    _close(deform_groom(rp, ro, gp2, gn, go, w), ref.deform_groom_v0(rp, ro, gp2, gn, go, w),
           rp, gn)
    w.weight[:] = w.weight[:, ::-1]
    _close(deform_groom(rp, ro, gp2, gn, go, w), ref.deform_groom_v0(rp, ro, gp2, gn, go, w),
           rp, gn)
    # the same values in new arrays give the same bits
    np.testing.assert_array_equal(deform_groom(rp.copy(), ro.copy(), gp2.copy(), gn, go.copy(),
                                               w), deform_groom(rp, ro, gp2, gn, go, w))


def test_a_failed_call_leaves_nothing_behind():
    _, gp, go, rp, ro = _groom(4, 10, 30, True)
    w = bind_groom(rp[ro[:-1]], gp[go[:-1]], 3)
    deform_groom(rp, ro, gp, gp, go, w)
    bad = rp.copy()
    bad[2] = np.nan
    with pytest.raises(InputError, match="not finite"):
        deform_groom(bad, ro, gp, gp, go, w)
    assert vars(w).keys() == {"index", "weight"}  # (weights are arrays only)
    np.testing.assert_allclose(deform_groom(rp, ro, gp, gp, go, w), rp, atol=1e-9, rtol=0)


@PROP
@given(seed=st.integers(0, 10_000), radius=st.floats(0.1, 0.9), offset=st.floats(0.0, 0.05),
       mode=st.sampled_from(["stiff", "bend"]), two=st.booleans())
def test_clearance_pass_matches_solving_every_curve(seed, radius, offset, mode, two):
    """Culled curves (their box misses every collider's bounds) come back unchanged and
    FREE, exactly as the solver run on all curves returns them."""
    from core import Collider, Settings
    from core.pipeline import clearance_pass

    rng = np.random.default_rng(seed)
    V, F = po.grid(4.0, 8)
    pts, off = po.fur_on_mesh(rng, V, F, 150, int(rng.integers(2, 8)), 0.6, noise=0.2)
    cols = [Collider(*po.icosphere(rng.uniform(-1.5, 1.5, 3) * [1, 1, 0] + [0, 0, 0.3],
                                   radius, 2))]
    if two:
        cols.append(Collider(*po.icosphere((1.2, -1.2, 0.5), 0.3, 1), double_sided=True))
    s = Settings(mode=mode, collision_offset=offset)
    want = ref.clearance_pass_v0(pts, off, cols, settings=s)
    got = clearance_pass(pts, off, cols, settings=s)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert got[2] == want[2]


def test_clearance_pass_marks_bad_curves_like_the_solver():
    """A culled curve with a zero-length segment is INVALID, as the solver marks
    it (issue 15/17: a bad render curve never stops the groom); errors in the
    other inputs still raise as the solver's do."""
    from core import Collider, Status
    from core.pipeline import clearance_pass

    rng = np.random.default_rng(2)
    V, F = po.grid(4.0, 4)
    pts, off = po.fur_on_mesh(rng, V, F, 30, 4, 0.5)
    far = Collider(*po.icosphere((1.8, 1.8, 0.2), 0.1, 1))  # touches almost nothing
    pts[off[20] + 2] = pts[off[20] + 1]  # a zero-length segment in a culled curve
    out, st, _ = clearance_pass(pts, off, [far])
    out0, st0, _ = ref.clearance_pass_v0(pts, off, [far])
    assert st[20] == Status.INVALID == st0[20]
    np.testing.assert_array_equal(st, st0)
    np.testing.assert_array_equal(out, out0)
    pts[off[20] + 2] += 0.01
    with pytest.raises(InputError, match="not a core.Collider"):
        clearance_pass(pts, off, [far, "mesh"])


@PROP
@given(seed=st.integers(0, 10_000), uniform=st.booleans(), amp=st.floats(0.0, 0.4),
       collapse=st.booleans())
def test_binding_apply_matches_the_reference(seed, uniform, amp, collapse):
    from core.pipeline import bind

    rng = np.random.default_rng(seed)
    V, F = po.icosphere((0.3, -0.2, 0.1), 1.0, 2)
    if uniform:
        pts, off = po.fur_on_mesh(rng, V, F, 60, int(rng.integers(2, 9)), 0.4)
    else:
        pts, off = po.pack([po.fur_on_mesh(rng, V, F, 1, int(rng.integers(2, 9)), 0.4)[0]
                            for _ in range(60)])
    b = bind(pts, off, V, F)
    V2 = V + amp * rng.normal(size=V.shape) + 2.0
    if collapse:  # a triangle collapses: its curves keep their reference orientation
        f = F[b.face[0]]
        V2[f[1]] = V2[f[0]]
        V2[f[2]] = V2[f[0]]
    _close(b.apply(V2), ref.binding_apply_v0(b, V2), V2, pts)
