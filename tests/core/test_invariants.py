"""Property tests of the solver's invariants on random scenes (oracle-checked).

Scenes are drawn from their parameters (``strategies.fur_scenes``: every curve and
collider, shrinkable) and each has at least one curve whose input crosses a collider.
"""

from __future__ import annotations

import geom
import numpy as np
import oracle
import scenes
from geom import EXCLUDED, FAST, MEDIUM
from hypothesis import given
from hypothesis import strategies as st
from strategies import fur_scenes, rigid_motions

from core import Collider, Settings, Solver, Status

MODES = ("stiff", "bend", "soft")
VALID_STATUS = {int(s) for s in Status}


def _colliders(specs, backend=None):
    return [Collider(s["V"], s["F"], double_sided=s["double_sided"], matrix=s["matrix"],
                     backend=backend) for s in specs]


def _meshes(specs):
    return [(scenes.world_vertices(s), s["F"]) for s in specs]


def _check_frame(pts, offs, res, specs, lengths=True, cols=None):
    out = res.points
    status = np.asarray(res.status)
    C = len(offs) - 1
    assert out.shape == pts.shape
    assert out.dtype == pts.dtype
    assert status.shape == (C,)
    assert status.dtype == np.int8
    assert set(np.unique(status).tolist()) <= VALID_STATUS
    assert np.all(np.isfinite(out))
    geom.assert_roots_exact(pts, out, offs)
    geom.assert_no_intersection(out, offs, status, _meshes(specs))
    if lengths:
        rtol = 2e-5 if pts.dtype == np.float32 else 1e-9
        geom.assert_lengths_kept(pts, out, offs, rtol=rtol)
    if cols is not None:
        # self-consistency: the colliders' own query agrees that resolved
        # curves are clear (of the clearance margin's shell, too)
        keep = ~np.isin(status, EXCLUDED)
        A, B, cid, _ = oracle.curve_segments(out, offs)
        for k, col in enumerate(cols):
            hit = np.asarray(col.segment_hits(A, B - A)) & keep[cid]
            assert not hit.any(), f"collider #{k} hits curves {np.unique(cid[hit]).tolist()}"


modes = st.sampled_from(MODES)


@MEDIUM
@given(scene=fur_scenes(max_curves=25), mode=modes)
def test_single_frame_invariants(scene, mode):
    pts, offs, specs = scene
    solver = Solver(offs, Settings(mode=mode))
    pts_before = pts.copy()
    cols = _colliders(specs)
    res = solver.step(pts, cols)
    assert np.array_equal(pts, pts_before), "step() modified its input"
    _check_frame(pts, offs, res, specs, cols=cols)
    status = np.asarray(res.status)
    # first frame: no prior state, so a curve whose input is clear is FREE and
    # comes back bit-identical; a curve reported FREE really was clear
    maybe = np.zeros(len(offs) - 1, bool)
    sure = np.zeros(len(offs) - 1, bool)
    for V, F in _meshes(specs):
        maybe |= oracle.segments_hit_mesh(pts, offs, V, F, eps=oracle.MAYBE)
        sure |= oracle.segments_hit_mesh(pts, offs, V, F, eps=oracle.SURE)
    assert not np.any(sure & (status == Status.FREE)), "colliding input reported FREE"
    assert not np.any(status == Status.RECOVERING), "RECOVERING on the very first frame"
    assert not np.any(status == Status.DISABLED)
    for c in np.nonzero(status == Status.FREE)[0]:
        s, e = offs[c], offs[c + 1]
        assert np.array_equal(res.points[s:e], pts[s:e]), f"FREE curve {c} changed"
    for c in np.nonzero(~maybe)[0]:
        assert status[c] in (Status.FREE, Status.PINCHED), f"clear curve {c}: {status[c]}"


@FAST
@given(scene=fur_scenes(), mode=modes, n_frames=st.integers(2, 6), data=st.data(),
       rate=st.floats(0.1, 1.0))
def test_moving_colliders_invariants(scene, mode, n_frames, data, rate):
    """Colliders sweep through the fur (rigid motion via matrix) while the
    fur itself sways: every frame keeps every invariant."""
    pts0, offs, specs = scene
    dtype = pts0.dtype
    vel = data.draw(rigid_motions(len(specs)), label="velocities")
    solver = Solver(offs, Settings(mode=mode, recovery_rate=rate))
    cols = _colliders(specs)
    for f in range(n_frames):
        # sway the input curves rigidly about their roots (input animation)
        ang = 0.05 * np.sin(f)
        curves = [geom.rotate_curve(c, [1, 0.3, 0], ang)
                  for c in scenes.unpack(pts0.astype(np.float64), offs)]
        pts = scenes.pack(curves, dtype)[0]
        pts[offs[:-1]] = pts0[offs[:-1]]
        for s, c, v in zip(specs, cols, vel, strict=True):
            M = s["matrix"].copy()
            M[:3, 3] += v * f
            c.matrix = M
            s["matrix_now"] = M
        now = [dict(s, matrix=s["matrix_now"]) for s in specs]
        res = solver.step(pts, cols)
        _check_frame(pts, offs, res, now, cols=cols)
    for c in cols:
        assert c.build_count <= 1


@FAST
@given(scene=fur_scenes(dtype=np.float64), mode=modes)
def test_deterministic_and_thread_independent(scene, mode):
    pts, offs, specs = scene
    runs = []
    for threads in (1, 2, 1, None):
        solver = Solver(offs, Settings(mode=mode, threads=threads))
        cols = _colliders(specs)
        frames = []
        for f in range(3):
            for s, c in zip(specs, cols, strict=True):
                M = s["matrix"].copy()
                M[:3, 3] += [0.1 * f, 0.05 * f, -0.05 * f]
                c.matrix = M
            r = solver.step(pts, cols)
            frames.append((r.points.copy(), np.asarray(r.status).copy()))
        runs.append(frames)
    for other in runs[1:]:
        for (p0, s0), (p1, s1) in zip(runs[0], other, strict=True):
            assert np.array_equal(p0, p1)
            assert np.array_equal(s0, s1)


@FAST
@given(scene=fur_scenes(dtype=np.float64), mode=modes, k=st.integers(1, 4))
def test_state_snapshot_restore(scene, mode, k):
    pts, offs, specs = scene
    settings = Settings(mode=mode, recovery_rate=0.3, plasticity=0.2)
    solver = Solver(offs, settings)
    cols = _colliders(specs)

    def move(f):
        for s, c in zip(specs, cols, strict=True):
            M = s["matrix"].copy()
            M[:3, 3] += [0.12 * f, 0.0, 0.04 * f]
            c.matrix = M

    for f in range(k):
        move(f)
        solver.step(pts, cols)
    snap = solver.state
    assert isinstance(snap, dict)
    assert all(isinstance(v, np.ndarray) for v in snap.values())
    frozen = {key: v.copy() for key, v in snap.items()}
    move(k)
    a = solver.step(pts, cols)
    # the snapshot is a copy: stepping did not modify it
    for key, v in frozen.items():
        assert np.array_equal(snap[key], v, equal_nan=True), f"state[{key!r}] aliased"
    move(k + 1)
    a2 = solver.step(pts, cols)
    # restore into the same solver
    solver.state = snap
    move(k)
    b = solver.step(pts, cols)
    move(k + 1)
    b2 = solver.step(pts, cols)
    # and into a brand-new solver
    fresh = Solver(offs, settings)
    fresh.state = frozen
    move(k)
    c = fresh.step(pts, cols)
    for x, y in ((a, b), (a, c), (a2, b2)):
        assert np.array_equal(x.points, y.points)
        assert np.array_equal(np.asarray(x.status), np.asarray(y.status))


@FAST
@given(scene=fur_scenes(dtype=np.float64), mode=modes)
def test_reset_forgets_history(scene, mode):
    pts, offs, specs = scene
    cols = _colliders(specs)
    solver = Solver(offs, Settings(mode=mode))
    first = solver.step(pts, cols)
    solver.step(pts, cols)
    solver.reset()
    again = solver.step(pts, cols)
    assert np.array_equal(first.points, again.points)
    assert np.array_equal(np.asarray(first.status), np.asarray(again.status))
    # with no colliders after a reset, output is the input
    solver.reset()
    r = solver.step(pts, [])
    assert np.array_equal(r.points, pts)
    assert np.all(np.asarray(r.status) == Status.FREE)


@FAST
@given(scene=fur_scenes(), mode=modes)
def test_recovery_rate_one_returns_exact_input(scene, mode):
    pts, offs, specs = scene
    solver = Solver(offs, Settings(mode=mode, recovery_rate=1.0, plasticity=0.0))
    solver.step(pts, _colliders(specs))
    res = solver.step(pts, [])
    assert np.array_equal(res.points, pts)


@FAST
@given(scene=fur_scenes(dtype=np.float64), mode=modes)
def test_status_free_once_back_at_input(scene, mode):
    """Documented: with recovery_rate=1 the next step returns the input AND
    status FREE; likewise, any curve whose output is its input is FREE."""
    pts, offs, specs = scene
    for rate in (1.0, 0.5):
        solver = Solver(offs, Settings(mode=mode, recovery_rate=rate, plasticity=0.0))
        solver.step(pts, _colliders(specs))
        for _ in range(60):
            res = solver.step(pts, [])
            st_ = np.asarray(res.status)
            same = np.array([np.array_equal(res.points[offs[c]:offs[c + 1]],
                                            pts[offs[c]:offs[c + 1]])
                             for c in range(len(offs) - 1)])
            assert np.all(st_[same] == Status.FREE), (rate, st_[same])
            assert np.all(st_[~same] == Status.RECOVERING), (rate, st_[~same])
            if same.all():
                break


@FAST
@given(scene=fur_scenes(max_curves=15, dtype=np.float64), mode=modes,
       rate=st.sampled_from([0.2, 0.5, 0.8]))
def test_recovery_monotone_then_exact(scene, mode, rate):
    pts, offs, specs = scene
    solver = Solver(offs, Settings(mode=mode, recovery_rate=rate, plasticity=0.0))
    r0 = solver.step(pts, _colliders(specs))
    excluded = np.isin(np.asarray(r0.status), EXCLUDED)
    ok = ~excluded
    prev = geom.curve_max_displacement(r0.points, pts, offs)
    frames = np.zeros(len(offs) - 1, int)
    for _ in range(200):
        r = solver.step(pts, [])
        dev = geom.curve_max_displacement(r.points, pts, offs)
        assert np.all(dev[ok] <= prev[ok] * (1 + 1e-9) + 1e-12), "deviation grew"
        frames += dev > 0
        prev = dev
        if np.all(dev[ok] == 0):
            break
    assert np.all(prev[ok] == 0), "recovery never snapped back to the exact input"
    geom.assert_roots_exact(pts, r.points, offs)
    # gradual: a curve deviating by more than a few precision steps takes
    # more than one frame to come back when rate < 1
    L = np.array([x.sum() for x in scenes.segment_lengths(pts, offs)])
    big = ok & (geom.curve_max_displacement(r0.points, pts, offs) > 0.2 * L)
    if rate <= 0.5:
        assert np.all(frames[big] >= 2), (frames[big], rate)


def test_threads_bit_identical_on_a_large_batch():
    """Big enough (>32k rays per query) that the ray batches really are split
    over threads."""
    rng = np.random.default_rng(0)
    pts, offs = scenes.fur_on_plane(rng, n_curves=6000, n_cvs=(6, 10), extent=1.0, curly=0.2)
    V, F = scenes.grid(size=3.0, n=20, z=0.0)
    V[:, 2] = 0.55 + 0.1 * np.sin(3 * V[:, 0]) * np.cos(2 * V[:, 1])
    for mode in MODES:
        runs = []
        for threads in (1, 2):
            solver = Solver(offs, Settings(mode=mode, threads=threads))
            col = Collider(V, F, double_sided=True)
            frames = []
            for f in range(3):
                col.matrix = scenes.translation([0.05 * f, 0, 0.05 * f])
                r = solver.step(pts, [col])
                frames.append((r.points, np.asarray(r.status)))
            runs.append(frames)
        assert np.count_nonzero(runs[0][0][1] == Status.COLLIDING) > 1000
        for (p1, s1), (p2, s2) in zip(*runs, strict=True):
            assert np.array_equal(p1, p2) and np.array_equal(s1, s2), mode
