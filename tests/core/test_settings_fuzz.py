"""Random settings x random scenes x several frames: the invariants hold for
every combination (no crash, no NaN, no intersection, roots fixed, lengths
kept or only shrunk where Shrink applies)."""

from __future__ import annotations

import geom
import numpy as np
import scenes
import strategies as strat
from geom import EXCLUDED, MEDIUM
from hypothesis import given
from hypothesis import strategies as st

from core import Collider, Settings, Solver, Status

settings_st = st.builds(
    Settings,
    mode=st.sampled_from(["stiff", "bend", "soft"]),
    rotation_precision=st.sampled_from([0.25, 1.0, 5.0]),
    max_angle=st.sampled_from([30.0, 90.0, 180.0, 360.0]),
    affected_connected_cvs=st.integers(0, 5),
    cv_falloff=st.sampled_from([0.0, 0.3, 1.0]),
    attract_to_growth_surface=st.booleans(),
    shrink=st.booleans(),
    scale_minimum=st.sampled_from([0.2, 0.7, 1.0]),
    scale_angle=st.sampled_from([10.0, 90.0]),
    recovery_rate=st.sampled_from([0.0, 0.3, 1.0]),
    plasticity=st.sampled_from([0.0, 0.5, 1.0]),
    pinch_resolution=st.sampled_from(["stop", "growth_surface"]),
    recover_pinched=st.booleans(),
    collision_offset=st.sampled_from([0.0, 0.0, 0.05]),
    threads=st.sampled_from([None, 1, 2]),
)


@MEDIUM
@given(scene=strat.fur_scenes(max_curves=15), s=settings_st, data=st.data())
def test_any_settings_keep_invariants(scene, s, data):
    pts, offs, specs = scene
    f32 = pts.dtype == np.float32
    cols = [Collider(sp["V"], sp["F"], double_sided=sp["double_sided"], matrix=sp["matrix"])
            for sp in specs]
    Vg, Fg = scenes.grid(size=6.0, n=6, z=0.0)
    growth = Collider(Vg, Fg)
    vel = data.draw(strat.rigid_motions(len(specs)), label="velocities")
    solver = Solver(offs, s)
    C = len(offs) - 1
    mask = np.array(data.draw(st.lists(st.booleans(), min_size=C, max_size=C), label="mask"))
    for f in range(4):
        meshes = []
        for sp, col, v in zip(specs, cols, vel, strict=True):
            M = sp["matrix"].copy()
            M[:3, 3] += v * f
            col.matrix = M
            meshes.append((scenes.world_vertices(dict(sp, matrix=M)), sp["F"]))
        enabled = None if f != 2 else mask
        cur = cols if f != 3 else []  # last frame: colliders gone
        res = solver.step(pts, cur, growth=growth, enabled=enabled)
        status = np.asarray(res.status)
        assert res.points.dtype == pts.dtype and res.points.shape == pts.shape
        assert np.all(np.isfinite(res.points))
        geom.assert_roots_exact(pts, res.points, offs)
        if cur:
            geom.assert_no_intersection(res.points, offs, status, meshes)
        if enabled is not None:
            assert np.all((status == Status.DISABLED) == ~enabled)
        Li = scenes.segment_lengths(pts, offs)
        Lo = scenes.segment_lengths(res.points, offs)
        rtol = 2e-5 if f32 else 1e-9
        for c in range(C):
            if s.shrink and s.mode != "soft" and status[c] not in EXCLUDED:
                # shrunk at most to scale_minimum, never stretched
                assert np.all(Lo[c] <= Li[c] * (1 + rtol))
                assert np.all(Lo[c] >= Li[c] * s.scale_minimum * (1 - rtol))
            elif not s.shrink or s.mode == "soft":
                np.testing.assert_allclose(Lo[c], Li[c], rtol=rtol, err_msg=f"curve {c}")
