"""The one closest-point search (core.closest): exact, ties to the lowest face.

Used by Fur Attach (bind, surface values) and the growth surface
(``Collider.closest_points``). Checked against testing every triangle.
"""

from __future__ import annotations

import numpy as np
import pipe_oracle as po
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis_profiles import examples

from core import Collider
from core.closest import closest_on_triangles, closest_points_on_mesh
from core.pipeline import closest_faces

PROP = settings(max_examples=examples(20))


def _brute(V, F, Q):
    T = V[F]
    m = len(F)
    qi = np.repeat(np.arange(len(Q)), m)
    ti = np.tile(np.arange(m), len(Q))
    p = closest_on_triangles(Q[qi], T[ti, 0], T[ti, 1], T[ti, 2])
    d = np.linalg.norm(p - Q[qi], axis=1).reshape(len(Q), m)
    face = np.argmin(d, 1)  # the first of equal distances: the lowest face
    return p.reshape(len(Q), m, 3)[np.arange(len(Q)), face], face


@PROP
@given(seed=st.integers(0, 10_000), kind=st.sampled_from(["sphere", "grid", "ground"]),
       near=st.floats(0.0, 0.5), far=st.integers(0, 8))
def test_matches_every_triangle(seed, kind, near, far):
    rng = np.random.default_rng(seed)
    if kind == "sphere":
        V, F = po.icosphere(rng.uniform(-1, 1, 3), rng.uniform(0.2, 2.0), 2)
        V = V * (1 + 0.1 * rng.normal(size=(len(V), 1)))
    elif kind == "grid":
        V, F = po.grid(3.0, 12)
        V[:, 2] = 0.2 * np.sin(3 * V[:, 0])
    else:  # two huge triangles next to a fine sphere
        _, _, V, F = po.sphere_and_ground(seed)
    T = V[F]
    i = rng.integers(0, len(F), 60)
    on = np.einsum("ck,cki->ci", rng.dirichlet([1, 1, 1], 60), T[i])
    Q = np.vstack([on, on + rng.normal(0, near + 1e-9, on.shape),
                   rng.normal(0, 10, (far, 3)), V[:5]])  # on, near, far, on vertices (ties)
    P, face, grid = closest_points_on_mesh(V, F, Q)
    Pb, fb = _brute(V, F, Q)
    np.testing.assert_array_equal(face, fb)
    np.testing.assert_array_equal(P, Pb)
    # the structures passed back give the same answers
    P2, f2, _ = closest_points_on_mesh(V, F, Q[::-1], grid)
    np.testing.assert_array_equal(f2, fb[::-1])
    P3, f3 = closest_faces(V, F, Q)
    np.testing.assert_array_equal(f3, fb)


def test_collider_closest_points_uses_it():
    V, F = po.icosphere((0.5, 0, 0), 1.0, 2)
    M = np.eye(4)
    M[:3, :3] = po.rotation([1, 2, 0], 0.8)
    M[:3, 3] = [0.1, 2.0, -1.0]
    col = Collider(V, F, matrix=M)
    rng = np.random.default_rng(3)
    q = rng.normal(0, 2, (40, 3)) + M[:3, 3]
    p, n = col.closest_points(q)
    Vw = V.astype(np.float32).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
    Pb, fb = _brute(Vw, F, q)
    np.testing.assert_allclose(p, Pb, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
