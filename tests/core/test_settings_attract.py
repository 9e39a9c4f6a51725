"""attract_to_growth_surface (paper 3.2.1): curves are patted down toward the
growth surface instead of being pushed along the collider's normal."""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes

from core import Collider, Settings, Solver, Status


def _scene():
    """Fur leaning +x; a ball comes in from the +x side at mid height."""
    rng = np.random.default_rng(11)
    curves = []
    for _ in range(30):
        root = [rng.uniform(-0.4, 0.2), rng.uniform(-0.3, 0.3), 0.0]
        curves.append(scenes.curly_curve(root, [0.5, 0.05 * rng.normal(), 1.0], 1.0, 7,
                                         amplitude=0.05, phase=rng.uniform(0, 6)))
    pts, offs = scenes.pack(curves)
    Vg, Fg = scenes.grid(size=8.0, n=8, z=0.0)
    V, F = scenes.uv_sphere([0.75, 0.0, 0.6], 0.4, 24, 12)
    return pts, offs, Collider(Vg, Fg), (V, F)


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_attract_brings_curves_closer_to_growth_surface(mode):
    pts, offs, growth, (V, F) = _scene()
    out = {}
    for attract in (False, True):
        s = Settings(mode=mode, attract_to_growth_surface=attract)
        res = Solver(offs, s).step(pts, [Collider(V, F)], growth=growth)
        geom.assert_no_intersection(res.points, offs, res.status, [(V, F)])
        geom.assert_roots_exact(pts, res.points, offs)
        out[attract] = res
    both = ((np.asarray(out[False].status) == Status.COLLIDING)
            & (np.asarray(out[True].status) == Status.COLLIDING))
    assert both.sum() >= 5
    sel = np.concatenate([np.arange(offs[c], offs[c + 1]) for c in np.nonzero(both)[0]])

    def height(p):
        return oracle.distance_to_plane(p[sel], [0, 0, 0], [0, 0, 1]).mean()

    assert height(out[True].points) < 0.8 * height(out[False].points), (
        height(out[True].points), height(out[False].points))
    # without attract, the ball pushes the fur back (-x, up): mean height grows
    assert height(out[False].points) > height(pts) - 1e-9
    # with it the fur is patted down: lower than its input
    assert height(out[True].points) < height(pts)


def test_attract_only_changes_colliding_curves():
    pts, offs, growth, (V, F) = _scene()
    s = Settings(mode="bend", attract_to_growth_surface=True)
    res = Solver(offs, s).step(pts, [Collider(V, F)], growth=growth)
    for c in np.nonzero(np.asarray(res.status) == Status.FREE)[0]:
        assert np.array_equal(res.points[offs[c]:offs[c + 1]], pts[offs[c]:offs[c + 1]])
