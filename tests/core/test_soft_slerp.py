"""Soft's recovery arc (``soft._Slerp``): the arc of :func:`rotations.quat_slerp`,
set up once per step and sampled at many fractions. Its docstring promises
quat_slerp's arithmetic: the shortest way between the two rotations, the ends
exact (``t = 0`` is ``p``, ``t = 1`` is ``q`` as given, bit for bit)."""

from __future__ import annotations

import numpy as np

from core import rotations as rot
from core.soft import _Slerp


def _pairs(rng, k=400):
    p = rot.quat_canonical(rot.normalize(rng.normal(size=(k, 4))))
    q = rot.normalize(rng.normal(size=(k, 4)))  # any sign: half of them flip
    q[:20] = p[:20]  # equal rotations (theta = 0)
    q[20:40] = -p[20:40]  # the same rotation, opposite sign
    q[40:60] = rot.normalize(p[40:60] + 1e-12 * rng.normal(size=(20, 4)))  # nearly equal
    return p, q


def test_the_recovery_arc_is_quat_slerp_the_shortest_way():
    rng = np.random.default_rng(16)
    p, q = _pairs(rng)
    path = _Slerp(p, q)
    flipped = rot.dot(p, q) < 0
    assert 100 < flipped.sum() < len(p) - 100
    for t in (0.0, 1e-3, 0.25, 0.5, 0.7, 1.0 - 1e-9, 1.0):
        tt = np.full(len(p), t)
        got = path(tt)
        want = rot.quat_slerp(p, q, tt)
        if t == 1.0:  # q as given (quat_slerp returns the sign it took the short way with)
            np.testing.assert_array_equal(got, q)
            np.testing.assert_array_equal(np.where(flipped[:, None], -got, got), want)
            continue
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
        if t == 0.0:
            np.testing.assert_array_equal(got, p)
        # the shortest way: never further from p than the whole arc's angle
        ang = rot.quat_angle(rot.quat_mul(got, p * np.array([1.0, -1.0, -1.0, -1.0])))
        whole = rot.quat_angle(rot.quat_mul(q, p * np.array([1.0, -1.0, -1.0, -1.0])))
        assert (ang <= whole * t + 1e-9).all()
    # rows picked out: the same values as the whole
    rows = rng.permutation(len(p))[:50]
    t = rng.random(50)
    full_t = np.zeros(len(p))
    full_t[rows] = t
    np.testing.assert_array_equal(path(t, rows), path(full_t)[rows])
    np.testing.assert_array_equal(path.soa(t, rows), path(t, rows).T)
