"""The whole fur pipeline through the core, as a pipeline script would run it.

groom -> Fur Sampler -> Fur Attach -> wind -> FurCollide -> Collider Distance /
Region of Influence (extreme wind after collision) -> guide deform of the render
groom -> clearance pass. Checked with brute-force segment/triangle tests.
"""

from __future__ import annotations

import numpy as np
import pipe_oracle as po

from core import Collider, Settings, Solver
from core.pipeline import (
    bind,
    bind_groom,
    clearance_pass,
    collider_distance,
    deform_groom,
    region_of_influence,
    sample_guides,
    wind,
)

PINCHED, UNRESOLVED = 3, 4


def _surface(V, frame):
    """The growth surface at a frame: a rigid motion plus a gentle wave."""
    R = po.rotation([0.2, 1.0, 0.1], 0.05 * frame)
    W = V.copy()
    W[:, 2] += 0.03 * np.sin(2.0 * V[:, 0] + 0.5 * frame)
    return W @ R.T + [0.02 * frame, 0.0, 0.01 * frame], R


def _penetrating(points, offsets, col):
    V = col.vertices.astype(np.float64)
    M = col.matrix
    Vw = V @ M[:3, :3].T + M[:3, 3]
    A, B, cid = po.segments(points, offsets)
    return np.unique(cid[po.segments_cross_mesh(A, B, Vw, col.faces, eps=-1e-6)])


def test_whole_pipeline():
    rng = np.random.default_rng(7)
    Vs, Fs = po.grid(2.4, 12)
    render, roff = po.fur_on_mesh(rng, Vs, Fs, 600, 5, 0.6, noise=0.1)
    rroots = render[roff[:-1]]

    # Fur Sampler: 15 % of the groom as guides
    gidx = sample_guides(rroots, Vs, Fs, 0.15, seed=1)
    assert len(gidx) == 90
    guides, goff = po.pack([render[roff[i]:roff[i + 1]] for i in gidx])

    # Fur Attach: guides and render groom bound at the reference pose
    gbind = bind(guides, goff, Vs, Fs)
    rbind = bind(render, roff, Vs, Fs)
    weights = bind_groom(rroots, guides[goff[:-1]], 4)

    Vc, Fc = po.icosphere((0.0, 0.0, 0.0), 0.45, 2)
    col = Collider(Vc, Fc)
    solver = Solver(goff, Settings(mode="bend"))
    for frame in range(8):
        V_now, R = _surface(Vs, frame)
        g_in = gbind.apply(V_now)
        g_in = wind(g_in, goff, frame, strength=0.08, turbulence=0.5)  # before FurCollide
        M = np.eye(4)
        M[:3, :3] = R
        M[:3, 3] = R @ [0.2, 0.1, 1.17 - 0.07 * frame] + [0.02 * frame, 0, 0.01 * frame]
        col.matrix = M
        res = solver.step(g_in, [col])
    g_out = res.points
    ok = ~np.isin(res.status, [PINCHED, UNRESOLVED])
    assert ok.mean() > 0.95
    assert (res.status == 1).sum() >= 5  # the sphere really pressed into the guides
    assert not np.isin(_penetrating(g_out, goff, col), np.flatnonzero(ok)).any()

    # Collider Distance + Region of Influence: extreme wind after collision
    dist = collider_distance(g_out, goff, [col])
    blown = wind(g_out, goff, frame, direction=(-1, -0.5, -0.3), strength=1.5, turbulence=1.0)
    assert len(_penetrating(blown, goff, col)) > 0
    g_final = region_of_influence(g_out, goff, blown, dist)
    assert not np.isin(_penetrating(g_final, goff, col), np.flatnonzero(ok)).any()
    assert np.abs(g_final - g_out).max() > 0.05  # it did move

    # render groom follows the guides, roots from its own Fur Attach
    r_att = rbind.apply(V_now)
    r_now = deform_groom(render, roff, guides, g_final, goff, weights,
                         render_roots_now=r_att[roff[:-1]])
    np.testing.assert_array_equal(r_now[roff[:-1]], r_att[roff[:-1]])
    out, status, n_fixed = clearance_pass(r_now, roff, [col])
    before = _penetrating(r_now, roff, col)
    after = _penetrating(out, roff, col)
    rok = ~np.isin(status, [PINCHED, UNRESOLVED])
    assert not np.isin(after, np.flatnonzero(rok)).any()
    assert n_fixed >= len(np.intersect1d(before, np.flatnonzero(rok)))
    np.testing.assert_array_equal(out[roff[:-1]], r_att[roff[:-1]])  # roots on the surface
