"""An open sheet's rims: a segment that slips in between the two clearance-margin
shells past a rim and crosses the real surface there is still a hit.

Every shell of an open (or double-sided) collider lies the clearance margin
(``Collider.margin``, a few float32 ulps) out on both sides of the surface. A segment
that enters from beyond a rim, nearly in the sheet's plane, passes under the outer
shell's rim and over the inner one's: only the real surface's rim faces, kept
between the shells, see it cross (README "Collision Offset", open sheets).
"""

from __future__ import annotations

import numpy as np
import oracle
import pytest
import scenes

from core import Collider


def _slipping_segments(col):
    """Segments entering the sheet (z = 0, |x|, |y| <= 1) past each of its four
    rims, half a margin from its plane at the rim, crossing it 0.05 inside (away
    from the rim cells' corners), from above and from below.

    Returns (o, d, where): starts, vectors (end - start) and the crossing points.
    """
    m = col.margin
    slope = 0.5 * m / 0.05  # |z| = m / 2 at the rim, 0 at 0.05 inside it
    o, d, where = [], [], []
    for side in range(4):
        for along in (-0.25, 0.25, 0.75):
            for sign in (1.0, -1.0):
                # in the rim's own frame: u across the rim (out > 1), w along it
                u0, u1 = 1.3, 0.9
                z0, z1 = sign * slope * (u0 - 0.95), sign * slope * (u1 - 0.95)
                a = np.array([u0, along, z0])
                b = np.array([u1, along, z1])
                c = np.array([0.95, along, 0.0])
                rot = [(0, 1), (1, 0), (0, 1), (1, 0)][side]
                flip = [1, 1, -1, -1][side]

                def to_world(p, rot=rot, flip=flip):
                    q = np.empty(3)
                    q[rot[0]] = flip * p[0]
                    q[rot[1]] = flip * p[1]
                    q[2] = p[2]
                    return q

                a, b, c = to_world(a), to_world(b), to_world(c)
                o.append(a)
                d.append(b - a)
                where.append(c)
    return np.array(o), np.array(d), np.array(where)


@pytest.mark.parametrize("double_sided", [False, True])
def test_a_segment_slipping_between_the_margin_shells_past_a_rim_is_a_hit(double_sided):
    V, F = scenes.grid(size=2.0, n=4, z=0.0)
    col = Collider(V, F, double_sided=double_sided)
    assert not col.closed
    o, d, where = _slipping_segments(col)
    m = col.margin
    # the set-up: each segment crosses the sheet (independent oracle) ...
    pts = np.stack([o, o + d], axis=1).reshape(-1, 3)
    offs = np.arange(0, len(pts) + 1, 2)
    assert oracle.segments_hit_mesh(pts, offs, V, F).all()
    # ... where the margin shells cannot see it: within half a margin of the
    # sheet's plane wherever it is over the sheet (|x|, |y| <= 1)
    t = np.linspace(0.0, 1.0, 2001)[:, None, None]
    p = o + t * d
    over = (np.abs(p[..., 0]) <= 1.0) & (np.abs(p[..., 1]) <= 1.0)
    assert over.any() and (np.abs(p[..., 2])[over] <= 0.5 * m * (1 + 1e-9)).all()
    assert np.allclose(np.abs(where).max(axis=1), 0.95)
    np.testing.assert_array_equal(col.segment_hits(o, d), np.ones(len(o), bool))
    hit, t_hit, n = col.segment_hit_details(o, d)
    assert hit.all()
    # the first hit is the real surface's crossing point (a rim face), whose
    # normal is the sheet's
    np.testing.assert_allclose(o + t_hit[:, None] * d, where, atol=1e-4)
    np.testing.assert_allclose(np.abs(n), [[0.0, 0.0, 1.0]] * len(n), atol=1e-6)
    # the same segments shifted out of the sheet by two margins miss (they pass
    # over the outer shell's rim): the hits above are the real surface's
    for s in (1.0, -1.0):
        o2 = o + np.array([0.0, 0.0, s * 4.0 * m])
        clear = ~col.segment_hits(o2, d)
        assert clear[np.sign(d[:, 2]) == -s].all()
