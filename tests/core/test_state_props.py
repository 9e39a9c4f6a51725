"""Property tests of the solver's state, threading and collider history.

What recent changes could break: the solver builds collider BVHs on a ray
thread during its set-up (``Collider.prefetch``), stores its state on a pool
thread beside the output, and colliders default to ``deforming=None`` (their
build quality switches once ``col.vertices`` changes). Over random animated
scenes (moving and deforming colliders, closed and open, single and double
sided, collision offsets, changing ``enabled`` masks) these check that

* a snapshot/restore into a fresh solver continues bit for bit,
* the thread count never changes a bit, nor does a step solved in two halves
  on two threads (``core.tolerances.SPLIT_MIN_CURVES``, forced down to a few curves),
* with an explicit ``deforming`` flag a collider's history never matters,
* float64 input keeps the invariants (oracle-checked), and
* a collider far from the curves on some frames is never built needlessly.

Existing tests cover the rigid-only versions of the first two
(``test_invariants.py``); these add deformation, offsets, masks and 3 threads.
"""

from __future__ import annotations

import contextlib
import io

import geom
import numpy as np
import scenes
import strategies as strat
from geom import FAST
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import core.step
from core import Collider, Settings, Solver, Status

MODES = ("stiff", "bend", "soft")
#: Small meshes only (the torus and UV sphere are ~600-800 triangles).
KINDS = ("icosphere", "box", "plane", "plane2", "bumpy", "sphere")
#: How a collider is animated.
MOTIONS = ("static", "rigid", "deform", "both")
modes = st.sampled_from(MODES)
dtypes = st.sampled_from([np.float32, np.float64])


# ---------------------------------------------------------------- scenes
def _deformed(V0, wave, n_frames, hold):
    """Local vertices per frame: a breathing, wobbling mesh (same topology).
    ``wave``: (amplitude, phase, k (3,)) drawn; ``hold[f]``: frame f repeats frame
    f-1's vertices exactly."""
    amp, phase, k = wave
    center = V0.mean(axis=0)
    ext = float(np.abs(V0 - center).max()) or 1.0
    noise = amp * ext * np.sin((V0 - center) @ k + phase)[:, None] * np.array([1, -0.5, 0.7])
    out = []
    for f in range(n_frames):
        if f and hold[f]:
            out.append(out[-1].copy())
            continue
        s = 1.0 + 0.15 * np.sin(0.9 * f + phase)
        out.append(center + (V0 - center) * s + noise * np.cos(1.3 * f + phase))
    return out


def _matrices(M0, motion, n_frames, hold):
    """World matrices per frame: translation, rotation and (for some colliders) a
    scale pulse, uniform or not (a new offset shell each frame); ``motion`` drawn."""
    vel, axis, w, pulse = motion
    out = []
    for f in range(n_frames):
        if f and hold[f]:
            out.append(out[-1].copy())
            continue
        M = M0.copy()
        S = np.diag(1.0 + pulse * np.sin(1.1 * f))
        M[:3, :3] = scenes.rotation_matrix(axis, w * f) @ M0[:3, :3] @ S
        M[:3, 3] = M0[:3, 3] + vel * f
        out.append(M)
    return out


@st.composite
def waves(draw):
    return (draw(strat.floats(0.0, 0.03)), draw(strat.floats(0.0, 2 * np.pi)),
            np.array([draw(strat.floats(-4.0, 4.0)) for _ in range(3)]))


@st.composite
def rigid(draw):
    vel = np.array([draw(strat.floats(-0.3, 0.3)) for _ in range(3)])
    pulse = draw(st.sampled_from([0.0, 0.1]))
    aniso = (np.array([draw(strat.floats(0.5, 1.5)) for _ in range(3)]) if draw(st.booleans())
             else np.ones(3))
    return vel, draw(strat.directions()), draw(strat.floats(-0.3, 0.3)), pulse * aniso


@st.composite
def animated_scenes(draw, n_frames, n_cols=(1, 3), dtype=None, masks=True, contact=True):
    """A drawn animated scene, fully precomputed (so every run replays it): curves that
    sway, 1-3 colliders (static, rigid, deforming or both; held on some frames),
    per-frame enable masks. Everything is a drawn parameter (shrinkable); with
    ``contact`` some curve crosses a collider at frame 0.

    Returns a dict: ``offs``, ``points[f]``, ``enabled[f]`` and ``cols``, a list of
    collider specs with per-frame ``V[f]`` (local) and ``M[f]``."""
    if dtype is None:
        dtype = draw(dtypes)
    ragged = draw(st.booleans())
    if ragged:
        cs = draw(st.lists(strat.curves(extent=0.8, n_cvs=(3, 8)), min_size=1, max_size=40))
    else:
        n = draw(st.integers(3, 7))
        cs = draw(st.lists(strat.curves(extent=0.8, n_cvs=(n, n)), min_size=1, max_size=40))
    pts0, offs = scenes.pack(cs, np.float64)
    C = len(offs) - 1
    sway_axis = draw(strat.directions()) * [1.0, 1.0, 0.0] + [1e-3, 0.0, 0.0]
    points = []
    for f in range(n_frames):
        ang = 0.06 * np.sin(0.7 * f)
        curves = [geom.rotate_curve(c, sway_axis, ang) for c in scenes.unpack(pts0, offs)]
        p = scenes.pack(curves, dtype)[0]
        p[offs[:-1]] = pts0[offs[:-1]].astype(dtype)
        points.append(p)
    enabled = []
    for _ in range(n_frames):  # a drawn fraction of the curves, in a drawn stripe pattern
        if not masks or draw(st.booleans()):
            enabled.append(None)
        else:
            frac, k = draw(strat.floats(0.4, 0.95)), draw(st.integers(1, 7))
            enabled.append(((np.arange(C) * k * 0.618034) % 1.0) < frac)
    cols = []
    for i in range(draw(st.integers(*n_cols))):
        spec = draw(strat.collider_specs(cs, KINDS))
        motion = draw(st.sampled_from(MOTIONS))
        hold = draw(st.lists(st.booleans(), min_size=n_frames, max_size=n_frames))
        V0 = np.asarray(spec["V"], float)
        M0 = np.asarray(spec["matrix"], float)
        Vs = (_deformed(V0, draw(waves()), n_frames, hold) if motion in ("deform", "both")
              else [V0] * n_frames)
        Ms = (_matrices(M0, draw(rigid()), n_frames, hold) if motion in ("rigid", "both")
              else [M0] * n_frames)
        cols.append(dict(
            name=f"{spec['kind']}{i}", F=spec["F"], V=Vs, M=Ms, motion=motion,
            double_sided=bool(spec["double_sided"]),
            offset=draw(st.sampled_from([None, None, 0.0, 0.01, 0.03])),
            deforming=draw(st.sampled_from([None, True, False])),
        ))
    scene = dict(offs=offs, points=points, enabled=enabled, cols=cols, C=C)
    if contact:
        assume(strat.colliding(points[0], offs, [dict(V=c["V"][0], F=c["F"], matrix=c["M"][0])
                                                  for c in cols]).any())
    return scene


def build_colliders(scene, frame=0, deforming="spec"):
    """Fresh Colliders at ``frame``'s vertices and matrices.

    ``deforming``: "spec" (the scene's random flag), "explicit" (True for
    deformed colliders, False for the others) or a value for all."""
    out = []
    for c in scene["cols"]:
        if deforming == "spec":
            flag = c["deforming"]
        elif deforming == "explicit":
            flag = c["motion"] in ("deform", "both")
        else:
            flag = deforming
        out.append(Collider(c["V"][frame], c["F"], double_sided=c["double_sided"],
                            matrix=c["M"][frame], offset=c["offset"], name=c["name"],
                            deforming=flag))
    return out


def pose(scene, cols, f):
    """Put the Colliders ``cols`` in frame ``f``'s state (as a host would)."""
    for spec, col in zip(scene["cols"], cols, strict=True):
        col.vertices = spec["V"][f]
        col.matrix = spec["M"][f]


def world_meshes(scene, f):
    return [(scenes.world_vertices(dict(V=c["V"][f], matrix=c["M"][f])), c["F"])
            for c in scene["cols"]]


def step(solver, scene, cols, f):
    pose(scene, cols, f)
    r = solver.step(scene["points"][f], cols, enabled=scene["enabled"][f])
    return r.points.copy(), np.asarray(r.status).copy()


def run(scene, settings, frames, cols=None, solver=None):
    cols = build_colliders(scene) if cols is None else cols
    solver = Solver(scene["offs"], settings) if solver is None else solver
    return [step(solver, scene, cols, f) for f in frames], solver, cols


def assert_same(a, b, what):
    (pa, sa), (pb, sb) = a, b
    assert pa.dtype == pb.dtype, what
    assert np.array_equal(sa, sb), f"{what}: status differs at curves " \
        f"{np.flatnonzero(sa != sb)[:10].tolist()}"
    if not np.array_equal(pa, pb):
        bad = np.flatnonzero((pa != pb).any(axis=1))
        raise AssertionError(f"{what}: points differ at rows {bad[:10].tolist()} "
                             f"(max |diff| {np.abs(pa - pb).max():.3g})")


def assert_same_state(a, b, what):
    assert sorted(a) == sorted(b), what
    for key in a:
        assert a[key].dtype == b[key].dtype, f"{what}: state[{key!r}] dtype"
        assert np.array_equal(a[key], b[key]), f"{what}: state[{key!r}] differs"


@st.composite
def solver_settings(draw, mode=None):
    return Settings(
        mode=draw(modes) if mode is None else mode,
        recovery_rate=draw(st.sampled_from([0.2, 0.5, 1.0])),
        plasticity=draw(st.sampled_from([0.0, 0.3])),
        collision_offset=draw(st.sampled_from([0.0, 0.0, 0.02])),
        rotation_precision=draw(st.sampled_from([0.25, 1.0])),
    )


def savez_roundtrip(state):
    """The documented use: np.savez, loaded back without pickle."""
    buf = io.BytesIO()
    np.savez(buf, **state)
    buf.seek(0)
    with np.load(buf, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}




# ---------------------------------------------------------------- 1. snapshot / restore
@FAST
@given(n_frames=st.integers(3, 6), data=st.data(), threads=st.sampled_from([1, 2]))
def test_restore_into_a_fresh_solver_continues_bit_for_bit(n_frames, data, threads):
    """0..N in one go == 0..k, snapshot, a fresh Solver restored, k+1..N (the
    same colliders, in the same state). Re-stepping k+1 from the restored
    state twice gives the same result both times."""
    k = data.draw(st.integers(0, n_frames - 2), label="k")
    scene = data.draw(animated_scenes(n_frames), label="scene")
    s = data.draw(solver_settings(), label="settings").replace(threads=threads)
    ref, solver_a, _ = run(scene, s, range(n_frames))

    first, solver_b, cols_b = run(scene, s, range(k + 1))
    for f in range(k + 1):
        assert_same(first[f], ref[f], f"frame {f} (replay)")
    snap = savez_roundtrip(solver_b.state)
    fresh = Solver(scene["offs"], s)
    fresh.state = snap
    assert_same_state(fresh.state, snap, "state read back after restore")
    again = step(fresh, scene, cols_b, k + 1)
    fresh.state = snap
    twice = step(fresh, scene, cols_b, k + 1)
    assert_same(again, twice, f"frame {k + 1} stepped twice from the snapshot")
    assert_same(again, ref[k + 1], f"frame {k + 1} after restore")
    for f in range(k + 2, n_frames):
        assert_same(step(fresh, scene, cols_b, f), ref[f], f"frame {f} after restore")
    assert_same_state(fresh.state, solver_a.state, "final state after restore")


# ---------------------------------------------------------------- 2. thread count
@contextlib.contextmanager
def split_from(n):
    """Steps solve their curves in two halves from ``n`` curves of work (the
    benchmark's scenes reach the real threshold; these scenes have a few dozen)."""
    old = core.tolerances.SPLIT_MIN_CURVES
    core.tolerances.SPLIT_MIN_CURVES = n
    try:
        yield
    finally:
        core.tolerances.SPLIT_MIN_CURVES = old


@FAST
@given(n_frames=st.integers(2, 5), split=st.sampled_from([1, 5, None]), data=st.data())
def test_thread_count_never_changes_a_bit(n_frames, split, data):
    """Nor does a step split in two halves (``split``: from that many curves of
    work; None: the real threshold), which only runs on two threads or more."""
    scene = data.draw(animated_scenes(n_frames), label="scene")
    s = data.draw(solver_settings(), label="settings")
    runs = {1: run(scene, s.replace(threads=1), range(n_frames))[:2]}
    with split_from(core.tolerances.SPLIT_MIN_CURVES if split is None else split):
        for t in (2, 3):
            runs[t] = run(scene, s.replace(threads=t), range(n_frames))[:2]
    for t in (2, 3):
        for f in range(n_frames):
            assert_same(runs[t][0][f], runs[1][0][f], f"threads={t} frame {f}")
        assert_same_state(runs[t][1].state, runs[1][1].state, f"threads={t} final state")


@settings(FAST, max_examples=max(1, FAST.max_examples // 3))
@given(mode=modes, offset=st.sampled_from([0.0, 0.01]), dtype=dtypes, masked=st.booleans(),
       phase=st.tuples(strat.floats(0, 6.28), strat.floats(0, 6.28)),
       double=st.booleans(), lean=strat.floats(0.0, 0.4), split=st.sampled_from([500, None]))
def test_thread_count_never_changes_a_bit_on_split_batches(mode, offset, dtype, masked, phase,
                                                          double, lean, split):
    """Enough curves (> 2 x 4096 rays per query) that the ray batches are
    really split over the pool, with a deforming sheet built on a ray thread
    and the state stored beside the output; ``split`` 500: the steps also solve
    their curves in two halves (each tracing its rays on its own thread alone).
    (The 2,500 curves are a fixed grid
    leaning by a drawn amount: drawing each would be data, not a scene.)"""
    g = (np.arange(50) + 0.5) / 50 * 2 - 1
    X, Y = np.meshgrid(g, g, indexing="ij")
    curves = [scenes.straight_curve([x, y, 0], [lean * np.sin(7 * x), lean * np.cos(5 * y), 1],
                                    0.5 + 0.4 * abs(np.sin(3 * x * y)), 6)
              for x, y in zip(X.ravel(), Y.ravel(), strict=True)]
    pts, offs = scenes.pack(curves, dtype)
    V, F = scenes.grid(size=3.0, n=12, z=0.0)
    shapes = []
    for f in range(3):
        W = V.copy()
        W[:, 2] = 0.5 + 0.1 * np.sin(3 * W[:, 0] + f + phase[0]) * np.cos(2 * W[:, 1] + phase[1])
        shapes.append(W)
    C = len(offs) - 1
    masks = [((np.arange(C) * 0.618034 + 0.3 * f) % 1.0) < 0.8 if masked else None
             for f in range(3)]
    runs, rays = {}, {}
    for t in (1, 2, 3):
        col = Collider(V, F, double_sided=double)
        solver = Solver(offs, Settings(mode=mode, threads=t, collision_offset=offset))
        out = []
        with split_from(core.tolerances.SPLIT_MIN_CURVES if split is None else split):
            for f in range(3):
                col.vertices = shapes[f]
                r = solver.step(pts, [col], enabled=masks[f])
                out.append((r.points.copy(), np.asarray(r.status).copy()))
                rays.setdefault(t, []).append(r.timings["rays"])
        runs[t] = (out, solver.state)
    assert (runs[1][0][0][1] == Status.COLLIDING).sum() > 500  # in play
    for t in (2, 3):
        for f in range(3):
            assert_same(runs[t][0][f], runs[1][0][f], f"threads={t} frame {f}")
        assert_same_state(runs[t][1], runs[1][1], f"threads={t} final state")
        assert rays[t] == rays[1]  # the same rays traced, counted once each


# ---------------------------------------------------------------- 3. collider history
@FAST
@given(n_frames=st.integers(2, 5), threads=st.sampled_from([1, 2]), data=st.data())
def test_explicit_deforming_flag_makes_history_irrelevant(n_frames, threads, data):
    """Every frame: colliders animated frame by frame (history) and colliders
    built fresh at that frame (same explicit flag) give the same result from
    the same solver state."""
    scene = data.draw(animated_scenes(n_frames), label="scene")
    s = data.draw(solver_settings(), label="settings").replace(threads=threads)
    solver = Solver(scene["offs"], s)
    cols = build_colliders(scene, 0, "explicit")
    for f in range(n_frames):
        snap = solver.state
        got = step(solver, scene, cols, f)
        other = Solver(scene["offs"], s)
        other.state = snap
        fresh = build_colliders(scene, f, "explicit")
        assert_same(step(other, scene, fresh, f), got, f"frame {f}: fresh colliders")
        assert_same_state(other.state, solver.state, f"frame {f}: state, fresh colliders")


@FAST
@given(n_frames=st.integers(2, 5), data=st.data())
def test_deforming_true_history_irrelevant_for_deformed_colliders(n_frames, data):
    """Every collider deforms, all with deforming=True: one built fresh at
    frame k's vertices (and matrix) equals the one deformed frame by frame
    up to k."""
    scene = data.draw(animated_scenes(n_frames), label="scene")
    for c in scene["cols"]:
        if c["motion"] == "static":
            c["motion"] = "deform"
        if c["motion"] == "rigid":
            c["motion"] = "both"
    s = data.draw(solver_settings(), label="settings")
    solver = Solver(scene["offs"], s)
    cols = build_colliders(scene, 0, True)
    for f in range(n_frames):
        snap = solver.state
        got = step(solver, scene, cols, f)
        other = Solver(scene["offs"], s)
        other.state = snap
        assert_same(step(other, scene, build_colliders(scene, f, True), f), got,
                    f"frame {f}: fresh deforming=True colliders")


# ---------------------------------------------------------------- 4. float64
@FAST
@given(n_frames=st.integers(2, 5), data=st.data())
def test_float64_in_float64_out_and_invariants(n_frames, data):
    scene = data.draw(animated_scenes(n_frames, dtype=np.float64), label="scene")
    s = data.draw(solver_settings(), label="settings")
    solver = Solver(scene["offs"], s)
    cols = build_colliders(scene)
    offs = scene["offs"]
    for f in range(n_frames):
        pts = scene["points"][f]
        before = pts.copy()
        pose(scene, cols, f)
        r = solver.step(pts, cols, enabled=scene["enabled"][f])
        status = np.asarray(r.status)
        assert r.points.dtype == np.float64
        assert r.points.shape == pts.shape
        assert np.isfinite(r.points).all()
        assert np.array_equal(pts, before), "step() modified its input"
        en = scene["enabled"][f]
        if en is not None:
            assert np.array_equal(status == Status.DISABLED, ~en)
        geom.assert_roots_exact(pts, r.points, offs)
        geom.assert_lengths_kept(pts, r.points, offs, rtol=1e-9)
        geom.assert_no_intersection(r.points, offs, status, world_meshes(scene, f))


# ---------------------------------------------------------------- 5. far and near
def _reach_meets_box(scene, f, k, offset):
    """The solver's first candidate test: some curve's reach (a ball of its
    length about its root) meets the collider's world bounds (its public
    ``bounds_world``: the local box's corners transformed, grown by the
    offset), with a little slack."""
    c = scene["cols"][k]
    lo, hi = Collider(c["V"][f], c["F"], matrix=c["M"][f]).bounds_world(offset)
    lo, hi = lo - 1e-6, hi + 1e-6
    pts, offs = scene["points"][f], scene["offs"]
    roots = pts[offs[:-1]].astype(float)
    L = np.array([x.sum() for x in scenes.segment_lengths(pts, offs)])
    gap = np.linalg.norm(np.maximum(lo - roots, 0) + np.maximum(roots - hi, 0), axis=1)
    return bool((gap <= L * (1 + 1e-6)).any())


@FAST
@given(n_frames=st.integers(3, 7), data=st.data())
def test_far_collider_builds_only_for_vertex_sets_it_meets(n_frames, data):
    """One collider jumps between far (50 units away) and near frames while
    it deforms (on some frames it keeps its vertices). Its build count never
    exceeds the number of distinct shapes (vertex set, and with an offset the
    matrix's metric) on frames where its bounds are within the curves' reach,
    whatever the thread count, and results equal the single-threaded run's."""
    scene = data.draw(animated_scenes(n_frames, n_cols=(1, 1)), label="scene")
    near = data.draw(st.lists(st.booleans(), min_size=n_frames, max_size=n_frames),
                     label="near")
    spec = scene["cols"][0]
    spec["motion"] = "deform"
    hold = data.draw(st.lists(st.booleans(), min_size=n_frames, max_size=n_frames),
                     label="hold")
    spec["V"] = _deformed(np.asarray(spec["V"][0], float), data.draw(waves(), label="wave"),
                          n_frames, hold)
    spec["M"] = [M.copy() for M in spec["M"]]
    for f in range(n_frames):
        if not near[f]:
            spec["M"][f][:3, 3] += [50.0, 0.0, 0.0]
    s = data.draw(solver_settings(), label="settings")
    off = spec["offset"] if spec["offset"] is not None else s.collision_offset
    meets = [_reach_meets_box(scene, f, 0, off) for f in range(n_frames)]

    def shape(f):
        # what a BVH depends on: the vertices and, with an offset, the shell's
        # world metric M^T M (a scale pulse of the matrix makes a new shell;
        # exact here, so never fewer keys than the collider's quantized ones)
        S = spec["M"][f][:3, :3]
        return (spec["V"][f].astype(np.float32).tobytes(),
                (S.T @ S).tobytes() if off > 0 else b"")

    distinct = {shape(f) for f in range(n_frames) if meets[f]}
    results = {}
    for t in (1, 2, 3):
        for flag in (None, True):
            cols = build_colliders(scene, 0, flag)
            solver = Solver(scene["offs"], s.replace(threads=t))
            out = []
            for f in range(n_frames):
                before = cols[0].build_count
                out.append(step(solver, scene, cols, f))
                if not meets[f]:
                    assert cols[0].build_count == before, (
                        f"threads={t} deforming={flag}: built on frame {f}, out of reach")
                seen = {shape(g) for g in range(f + 1) if meets[g]}
                assert cols[0].build_count <= len(seen), (
                    f"threads={t} deforming={flag}: {cols[0].build_count} builds after "
                    f"frame {f}, {len(seen)} distinct vertex sets within reach ({meets})")
            assert cols[0].build_count <= len(distinct)
            results[t, flag] = out
    for key, out in results.items():
        ref = results[1, key[1]]
        for f in range(n_frames):
            assert_same(out[f], ref[f], f"{key} frame {f}")
