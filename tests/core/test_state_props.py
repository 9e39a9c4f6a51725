"""Property tests of the solver's state, threading and collider history.

What recent changes could break: the solver builds collider BVHs on a ray
thread during its set-up (``Collider.prefetch``), stores its state on a pool
thread beside the output, and colliders default to ``deforming=None`` (their
build quality switches once ``col.vertices`` changes). Over random animated
scenes (moving and deforming colliders, closed and open, single and double
sided, collision offsets, changing ``enabled`` masks) these check that

* a snapshot/restore into a fresh solver continues bit for bit,
* the thread count never changes a bit,
* with an explicit ``deforming`` flag a collider's history never matters,
* float64 input keeps the invariants (oracle-checked), and
* a collider far from the curves on some frames is never built needlessly.

Existing tests cover the rigid-only versions of the first two
(``test_invariants.py``); these add deformation, offsets, masks and 3 threads.
"""

from __future__ import annotations

import io

import geom
import numpy as np
import scenes
from geom import FAST
from hypothesis import given, settings
from hypothesis import strategies as st

from core import Collider, Settings, Solver, Status

MODES = ("stiff", "bend", "soft")
#: Small meshes only (the torus and UV sphere are ~600-800 triangles).
KINDS = ("icosphere", "box", "plane", "plane2", "bumpy", "sphere")
#: How a collider is animated.
MOTIONS = ("static", "rigid", "deform", "both")


# ---------------------------------------------------------------- scenes
def _deformed(V0, rng, n_frames, hold):
    """Local vertices per frame: a breathing, wobbling mesh (same topology).
    ``hold[f]``: frame f repeats frame f-1's vertices exactly."""
    center = V0.mean(axis=0)
    ext = float(np.abs(V0 - center).max()) or 1.0
    noise = rng.normal(size=V0.shape) * 0.03 * ext
    phase = rng.uniform(0, 2 * np.pi)
    out = []
    for f in range(n_frames):
        if f and hold[f]:
            out.append(out[-1].copy())
            continue
        s = 1.0 + 0.15 * np.sin(0.9 * f + phase)
        out.append(center + (V0 - center) * s + noise * np.cos(1.3 * f + phase))
    return out


def _matrices(M0, rng, n_frames, hold):
    """World matrices per frame: translation, rotation and (for some
    colliders) a scale pulse, uniform or not (a new offset shell each frame)."""
    vel = rng.normal(size=3) * 0.12
    axis = rng.normal(size=3)
    w = rng.uniform(-0.3, 0.3)
    pulse = rng.choice([0.0, 0.0, 0.1]) * (rng.uniform(0.5, 1.5, 3) if rng.random() < 0.5
                                           else np.ones(3))
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


def make_scene(seed, n_frames, n_cols=None, dtype=np.float64, masks=True):
    """A random animated scene, fully precomputed (so every run replays it).

    Returns a dict: ``offs``, ``points[f]``, ``enabled[f]`` and ``cols``, a
    list of collider specs with per-frame ``V[f]`` (local) and ``M[f]``.
    """
    rng = np.random.default_rng(seed)
    n_curves = int(rng.integers(20, 41))
    ragged = rng.random() < 0.5
    n_cvs = (3, 8) if ragged else (int(rng.integers(3, 8)),) * 2
    pts0, offs = scenes.fur_on_plane(rng, n_curves=n_curves, n_cvs=n_cvs, extent=0.8,
                                     curly=0.2, dtype=np.float64)
    C = len(offs) - 1
    sway_axis = rng.normal(size=3)
    sway_axis[2] = 0.0
    points = []
    for f in range(n_frames):
        ang = 0.06 * np.sin(0.7 * f)
        curves = [geom.rotate_curve(c, sway_axis, ang) for c in scenes.unpack(pts0, offs)]
        p = scenes.pack(curves, dtype)[0]
        p[offs[:-1]] = pts0[offs[:-1]].astype(dtype)
        points.append(p)
    enabled = []
    for _ in range(n_frames):
        if not masks or rng.random() < 0.3:
            enabled.append(None)
        else:
            enabled.append(rng.random(C) < rng.uniform(0.4, 0.95))
    if n_cols is None:
        n_cols = int(rng.integers(1, 4))
    cols = []
    for i in range(n_cols):
        kind = KINDS[int(rng.integers(len(KINDS)))]
        spec = scenes.random_collider(rng, kind)
        motion = MOTIONS[int(rng.integers(len(MOTIONS)))]
        hold = rng.random(n_frames) < 0.25
        V0 = np.asarray(spec["V"], float)
        M0 = np.asarray(spec["matrix"], float)
        Vs = (_deformed(V0, rng, n_frames, hold) if motion in ("deform", "both")
              else [V0] * n_frames)
        Ms = (_matrices(M0, rng, n_frames, hold) if motion in ("rigid", "both")
              else [M0] * n_frames)
        cols.append(dict(
            name=f"{kind}{i}", F=spec["F"], V=Vs, M=Ms, motion=motion,
            double_sided=bool(spec["double_sided"]),
            offset=(None if rng.random() < 0.6 else float(rng.choice([0.0, 0.01, 0.03]))),
            deforming=[None, True, False][int(rng.integers(3))],
        ))
    return dict(offs=offs, points=points, enabled=enabled, cols=cols, C=C)


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


def random_settings(draw_mode, rng_seed):
    rng = np.random.default_rng(rng_seed + 7)
    return Settings(
        mode=draw_mode,
        recovery_rate=float(rng.choice([0.2, 0.5, 1.0])),
        plasticity=float(rng.choice([0.0, 0.3])),
        collision_offset=float(rng.choice([0.0, 0.0, 0.02])),
        rotation_precision=float(rng.choice([0.25, 1.0])),
    )


def savez_roundtrip(state):
    """The documented use: np.savez, loaded back without pickle."""
    buf = io.BytesIO()
    np.savez(buf, **state)
    buf.seek(0)
    with np.load(buf, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


seeds = st.integers(0, 2**31 - 1)
modes = st.sampled_from(MODES)
dtypes = st.sampled_from([np.float32, np.float64])


# ---------------------------------------------------------------- 1. snapshot / restore
@FAST
@given(seed=seeds, mode=modes, n_frames=st.integers(3, 6), data=st.data(),
       threads=st.sampled_from([1, 2]), dtype=dtypes)
def test_restore_into_a_fresh_solver_continues_bit_for_bit(seed, mode, n_frames, data, threads,
                                                           dtype):
    """0..N in one go == 0..k, snapshot, a fresh Solver restored, k+1..N (the
    same colliders, in the same state). Re-stepping k+1 from the restored
    state twice gives the same result both times."""
    k = data.draw(st.integers(0, n_frames - 2), label="k")
    scene = make_scene(seed, n_frames, dtype=dtype)
    s = random_settings(mode, seed).replace(threads=threads)
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
@FAST
@given(seed=seeds, mode=modes, n_frames=st.integers(2, 5), dtype=dtypes)
def test_thread_count_never_changes_a_bit(seed, mode, n_frames, dtype):
    scene = make_scene(seed, n_frames, dtype=dtype)
    s = random_settings(mode, seed)
    runs = {t: run(scene, s.replace(threads=t), range(n_frames))[:2] for t in (1, 2, 3)}
    for t in (2, 3):
        for f in range(n_frames):
            assert_same(runs[t][0][f], runs[1][0][f], f"threads={t} frame {f}")
        assert_same_state(runs[t][1].state, runs[1][1].state, f"threads={t} final state")


@settings(FAST, max_examples=max(1, FAST.max_examples // 3))
@given(seed=seeds, mode=modes, offset=st.sampled_from([0.0, 0.01]),
       dtype=dtypes, masked=st.booleans())
def test_thread_count_never_changes_a_bit_on_split_batches(seed, mode, offset, dtype, masked):
    """Enough curves (> 2 x 4096 rays per query) that the ray batches are
    really split over the pool, with a deforming sheet built on a ray thread
    and the state stored beside the output."""
    rng = np.random.default_rng(seed)
    pts, offs = scenes.fur_on_plane(rng, n_curves=2500, n_cvs=(6, 6), extent=1.0,
                                    curly=0.2, dtype=dtype)
    V, F = scenes.grid(size=3.0, n=12, z=0.0)
    phase = rng.uniform(0, 6.28, 2)
    shapes = []
    for f in range(3):
        W = V.copy()
        W[:, 2] = 0.5 + 0.1 * np.sin(3 * W[:, 0] + f + phase[0]) * np.cos(2 * W[:, 1] + phase[1])
        shapes.append(W)
    masks = [rng.random(len(offs) - 1) < 0.8 if masked else None for _ in range(3)]
    double = bool(rng.random() < 0.5)
    runs = {}
    for t in (1, 2, 3):
        col = Collider(V, F, double_sided=double)
        solver = Solver(offs, Settings(mode=mode, threads=t, collision_offset=offset))
        out = []
        for f in range(3):
            col.vertices = shapes[f]
            r = solver.step(pts, [col], enabled=masks[f])
            out.append((r.points.copy(), np.asarray(r.status).copy()))
        runs[t] = (out, solver.state)
    assert (runs[1][0][0][1] == Status.COLLIDING).sum() > 500  # in play
    for t in (2, 3):
        for f in range(3):
            assert_same(runs[t][0][f], runs[1][0][f], f"threads={t} frame {f}")
        assert_same_state(runs[t][1], runs[1][1], f"threads={t} final state")


# ---------------------------------------------------------------- 3. collider history
@FAST
@given(seed=seeds, mode=modes, n_frames=st.integers(2, 5),
       threads=st.sampled_from([1, 2]), dtype=dtypes)
def test_explicit_deforming_flag_makes_history_irrelevant(seed, mode, n_frames, threads, dtype):
    """Every frame: colliders animated frame by frame (history) and colliders
    built fresh at that frame (same explicit flag) give the same result from
    the same solver state."""
    scene = make_scene(seed, n_frames, dtype=dtype)
    s = random_settings(mode, seed).replace(threads=threads)
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
@given(seed=seeds, mode=modes, n_frames=st.integers(2, 5))
def test_deforming_true_history_irrelevant_for_deformed_colliders(seed, mode, n_frames):
    """Every collider deforms, all with deforming=True: one built fresh at
    frame k's vertices (and matrix) equals the one deformed frame by frame
    up to k."""
    scene = make_scene(seed, n_frames)
    for c in scene["cols"]:
        if c["motion"] == "static":
            c["motion"] = "deform"
        if c["motion"] == "rigid":
            c["motion"] = "both"
    s = random_settings(mode, seed)
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
@given(seed=seeds, mode=modes, n_frames=st.integers(2, 5))
def test_float64_in_float64_out_and_invariants(seed, mode, n_frames):
    scene = make_scene(seed, n_frames, dtype=np.float64)
    s = random_settings(mode, seed)
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
@given(seed=seeds, mode=modes, n_frames=st.integers(3, 7), data=st.data())
def test_far_collider_builds_only_for_vertex_sets_it_meets(seed, mode, n_frames, data):
    """One collider jumps between far (50 units away) and near frames while
    it deforms (on some frames it keeps its vertices). Its build count never
    exceeds the number of distinct shapes (vertex set, and with an offset the
    matrix's metric) on frames where its bounds are within the curves' reach,
    whatever the thread count, and results equal the single-threaded run's."""
    scene = make_scene(seed, n_frames, n_cols=1)
    near = data.draw(st.lists(st.booleans(), min_size=n_frames, max_size=n_frames),
                     label="near")
    spec = scene["cols"][0]
    spec["motion"] = "deform"
    rng = np.random.default_rng(seed + 1)
    hold = rng.random(n_frames) < 0.3
    spec["V"] = _deformed(np.asarray(spec["V"][0], float), rng, n_frames, hold)
    spec["M"] = [M.copy() for M in spec["M"]]
    for f in range(n_frames):
        if not near[f]:
            spec["M"][f][:3, 3] += [50.0, 0.0, 0.0]
    s = random_settings(mode, seed)
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
