"""The render groom's root fit without an SVD (:func:`rotations.quat_fit`, issue 11).

``quat_fit`` gives the rotation maximizing ``sum b . R a`` for ``H = sum a b^T``
(Horn's quaternion: the top eigenvector of a 4x4 matrix, found by Newton on
its characteristic polynomial and the adjugate). Where it says ``ok`` it must
be :func:`rotations.kabsch`'s rotation (the SVD) to ``FIT_ATOL``; elsewhere
the groom uses the SVD. The groom relies on one more promise: an ``ok`` fit
is never one the SVD would call weak (second singular value below 1e-9 of the
first), so only the SVD's fits need that test.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core import rotations as rot

#: Measured: at most ~3e-14 between the two fits on 10^5 random, near-planar,
#: reflected and integer H (tol.QUAT_FIT_GAP's comment); the SVD itself is
#: good to ~5e-14 against an eigensolver of the 4x4 matrix.
FIT_ATOL = 2e-13

PROP = settings(max_examples=examples(60), deadline=None)


def _same_rotation(q, p):
    """Largest component difference of unit quaternions, up to sign (k,)."""
    return np.minimum(np.abs(q - p).max(1), np.abs(q + p).max(1))


def _svd_fit(H):
    R, S = rot.kabsch(H)
    return rot.quat_from_matrix(R), S


def _check_against_svd(H):
    q, ok = rot.quat_fit(H)
    assert q.shape == (len(H), 4) and ok.shape == (len(H),)
    assert np.isfinite(q).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, rtol=0, atol=1e-14)
    assert (q[:, 0] >= 0).all()
    if ok.any():
        want, S = _svd_fit(H[ok])
        err = _same_rotation(q[ok], want)
        assert err.max() <= FIT_ATOL, (err.max(), np.flatnonzero(ok)[np.argmax(err)])
        # never a fit the SVD would call weak: far from it
        assert (S[:, 1] > 1e-3 * S[:, 0]).all()
    return q, ok


def _rotations(rng, n):
    return rot.quat_canonical(rot.normalize(rng.normal(size=(n, 4))))


@PROP
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 6), flat=st.floats(0.0, 1.0),
       noise=st.floats(0.0, 0.5), scale=st.sampled_from([1e-150, 1e-8, 1.0, 1e6, 1e150]))
def test_the_fit_is_the_svds_rotation_wherever_it_is_trusted(seed, k, flat, noise, scale):
    """Neighbourhoods as the groom has them (unit vectors to k neighbours, from nearly
    planar to spread out), moved by a rotation plus noise, at any scale."""
    rng = np.random.default_rng(seed)
    n = 400
    a = rng.normal(size=(n, k, 3))
    a[..., 2] *= flat
    a = rot.normalize(a)
    q0 = _rotations(rng, n)
    b = rot.quat_rotate(np.repeat(q0, k, 0), a.reshape(-1, 3)).reshape(a.shape)
    b = rot.normalize(b + noise * rng.normal(size=b.shape))
    H = scale * np.einsum("gki,gkj->gij", a, b)
    q, ok = _check_against_svd(H)
    if k >= 3 and flat > 0.2 and noise == 0.0:
        # an exact rigid motion of well spread vectors: that very rotation, trusted
        assert ok.mean() > 0.9
        assert _same_rotation(q[ok], q0[ok]).max() <= FIT_ATOL


@PROP
@given(seed=st.integers(0, 2**32 - 1), kind=st.sampled_from(["normal", "ints", "reflect"]))
def test_any_matrix_is_the_svds_rotation_or_not_trusted(seed, kind):
    """Random H (reflections: det < 0, where the SVD's rule flips the third axis) and
    small integer H (exact ties between singular values)."""
    rng = np.random.default_rng(seed)
    if kind == "ints":
        H = rng.integers(-2, 3, size=(500, 3, 3)).astype(np.float64)
    else:
        H = rng.normal(size=(500, 3, 3))
        if kind == "reflect":
            H[np.linalg.det(H) > 0] *= -1.0
    q, ok = _check_against_svd(H)
    assert ok.mean() > 0.8  # the fast fit does the bulk of the work


def test_what_fixes_no_rotation_is_left_to_the_svd():
    """Zero, rank-1 (one neighbour, collinear neighbours), non-finite and exactly
    degenerate H are never trusted; their quaternion is finite all the same."""
    rng = np.random.default_rng(3)
    u = rot.normalize(rng.normal(size=(50, 3)))
    v = rot.normalize(rng.normal(size=(50, 3)))
    cases = {
        "zero": np.zeros((5, 3, 3)),
        "rank 1": np.einsum("gi,gj->gij", u, v),
        "rank 1, same": np.einsum("gi,gj->gij", u, u),
        "collinear": np.einsum("gi,gj->gij", u, v) * 3 - np.einsum("gi,gj->gij", -u, -v),
        "nan": np.full((3, 3, 3), np.nan),
        "inf": np.full((3, 3, 3), np.inf),
    }
    for name, H in cases.items():
        q, ok = rot.quat_fit(H)
        assert not ok.any(), name
        assert np.isfinite(q).all(), name


def test_the_identity_and_a_half_turn():
    a = rot.normalize(np.random.default_rng(4).normal(size=(30, 4, 3)))
    H = np.einsum("gki,gkj->gij", a, a)
    q, ok = rot.quat_fit(H)
    assert ok.all()
    np.testing.assert_allclose(q, np.tile([1.0, 0, 0, 0], (30, 1)), rtol=0, atol=1e-15)
    half = np.array([[0.0, 0.0, 0.0, 1.0]])  # 180 degrees about z
    b = rot.quat_rotate(np.repeat(half, 30 * 4, 0), a.reshape(-1, 3)).reshape(a.shape)
    q, ok = rot.quat_fit(np.einsum("gki,gkj->gij", a, b))
    assert ok.all()
    assert _same_rotation(q, np.repeat(half, 30, 0)).max() <= FIT_ATOL

