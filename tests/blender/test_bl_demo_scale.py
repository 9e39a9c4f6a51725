"""The demo's scene (scripts/demo_scene.py) at real size: 20,000 curves of fur, where a
step solves its phases in two halves on two threads (core.tolerances.SPLIT_MIN_CURVES curves
of work), driven frame by frame with ``scene.frame_set`` as an artist plays, scrubs and
jumps, with Threads changed, with the demo's pipeline (saved, reopened and baked; Fur
Sampler run again on it), and
with Shrink at the demo's size. Every frame is checked against invariants, not
snapshots: no resolved curve crosses a collider (brute-force oracle,
tests/core/oracle.py), roots never move, lengths are kept (or shrink as Shrink says),
the groomed source is never modified, and the same frame reached by two paths is
bit-identical where the README says so."""

import sys

import bpy
import numpy as np
import pytest
from helpers import (
    ADDON,
    PINCHED,
    REAL_FRAMES,
    REAL_LAST,
    activate,
    assert_groom_unchanged,
    curves_crossing,
    demo_checks,
    demo_fur,
    frame_of,
    groom_snapshot,
    no_traceback,
    offsets_of,
    oracle,
    pipe_oracle,
    pipeline_state,
    play_demo,
    positions,
    real_size_fur,
    real_size_pipeline,
    reopen,
    reset_cache,
    same_frame,
    same_pipeline_frame,
    save_in,
    seg_lengths,
    status_of,
    tris_world,
    world,
    world_meshes,
)

pytestmark = pytest.mark.blender


# ------------------------------------------------------------------ the scene
@pytest.fixture
def split_spy(monkeypatch):
    """Records (phase, curves of work, threads) of every StepContext.in_halves call."""
    step = sys.modules[ADDON + ".core.step"]
    calls = []
    real = step.StepContext.in_halves

    def spy(self, fn, work, *parts, **kw):
        calls.append((fn.__name__, int(work), int(self.threads)))
        return real(self, fn, work, *parts, **kw)

    monkeypatch.setattr(step.StepContext, "in_halves", spy)
    return calls


def split_phases(calls):
    """The phases that ran in two halves."""
    tolerances = sys.modules[ADDON + ".core.tolerances"]
    return {name for name, work, threads in calls
            if work >= tolerances.SPLIT_MIN_CURVES and threads >= 2}


def test_crossing_agrees_with_the_oracle():
    """The culled crossing test of these checks (helpers.curves_crossing) gives the
    plain oracle's answer (random segments through random triangles on a unit sphere)."""
    rng = np.random.default_rng(5)
    V = rng.normal(size=(300, 3))
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    F = rng.integers(0, 300, size=(600, 3))
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    P = rng.uniform(-1.3, 1.3, size=(1600, 3))
    offs = np.arange(0, len(P) + 1, 4)
    want = np.flatnonzero(
        oracle.segments_hit_mesh(P, offs, V, F, abs_eps=oracle.float32_margin(P, V))
    )
    assert len(want) > 20
    np.testing.assert_array_equal(curves_crossing(P, offs, [(V, F)]), want)


# --------------------------------------------------------- played, scrubbed, jumped
@pytest.mark.slow
def test_demo_played_scrubbed_and_jumped(fc, split_spy):
    """The demo's fur (20,000 curves, Bend) played 1..24: every frame holds the README's
    promises and both phases of a step ran in two halves; scrubbed back, the same
    frames bit for bit; after Reset Cache a jump ahead holds the newest cached frame and
    says so; played from the start again, the first play bit for bit. The groom is
    never touched."""
    demo, hair, out = real_size_fur()
    groomed = groom_snapshot(hair)
    scene = demo.scene
    first = play_demo(demo.scene, hair, out, check=demo_checks(demo, hair, out))
    assert split_phases(split_spy) == {"_new_contacts", "_search"}, sorted(
        {(n, w) for n, w, _ in split_spy if w > 3000})
    counts = np.bincount(first[REAL_LAST][1], minlength=7)
    assert counts[1] > 1000 and counts[PINCHED] > 0, counts
    for f in (20, 5, 24, 13, 1, 17, 24, 2):
        scene.frame_set(f)
        same_frame(frame_of(out), first[f], f"scrubbed to {f}")
    reset_cache(hair)
    scene.frame_set(1)
    scene.frame_set(12)  # a jump ahead: frame 1 is held, outdated
    s = hair.furcollide
    assert s.is_outdated and "not cached" in s.status_message, s.status_message
    same_frame(frame_of(out), first[1], "jump: the newest cached frame held")
    again = play_demo(demo.scene, hair, out)
    for f in REAL_FRAMES:
        same_frame(again[f], first[f], f"replayed frame {f}")
    assert_groom_unchanged(hair, groomed)


# ------------------------------------------------------------------------ threads
@pytest.mark.slow
@pytest.mark.parametrize("mode", ["bend", "soft+attract"])
def test_threads_give_the_same_frames(fc, split_spy, mode):
    """README: "the same inputs give bit-identical outputs whatever the thread count".
    Played with Threads 2 (the split on), then 1, then switched from 2 to 1 mid-shot
    (Threads does not invalidate the cache): the same frames bit for bit. (Every mode's
    solve, thread count against thread count: tests/core/test_state_props.py; here the
    setting through Blender's frame, at real size.)"""
    mode, _, attract = mode.partition("+")
    demo, hair, out = real_size_fur(mode, threads=2, attract_to_growth_surface=bool(attract))
    s = hair.furcollide
    # the crossing oracle on every frame once for Soft (with Attract, which runs the same
    # solve and then pulls); Stiff and Bend: test_demo_played_scrubbed_and_jumped
    ref = play_demo(demo.scene, hair, out,
                    check=demo_checks(demo, hair, out) if attract else None)
    assert split_phases(split_spy), mode
    reset_cache(hair)
    s.threads = 1
    for f, got in play_demo(demo.scene, hair, out).items():
        same_frame(got, ref[f], f"{mode}: Threads 1, frame {f}")
    reset_cache(hair)
    s.threads = 2
    play_demo(demo.scene, hair, out, range(1, 13))
    s.threads = 1
    for f, got in play_demo(demo.scene, hair, out, range(13, REAL_LAST + 1)).items():
        same_frame(got, ref[f], f"{mode}: Threads 2 -> 1 at 13, frame {f}")


@pytest.mark.slow
def test_threads_one_is_one_thread_for_the_whole_frame(fc, split_spy):
    """The Threads tooltip: "Threads a frame uses (0 = all CPUs)". With
    Threads 1 (a farm running one Blender per core), no step of the frame, the render
    groom's clearance pass included, runs on more than one thread."""
    demo, guides, out, gout = real_size_pipeline()
    guides.furcollide.threads = 1
    split_spy.clear()  # (what building the pipeline solved, with the default Threads)
    for f in range(1, 17):
        demo.scene.frame_set(f)
    tolerances = sys.modules[ADDON + ".core.tolerances"]
    assert max(w for _, w, _ in split_spy) >= tolerances.SPLIT_MIN_CURVES  # (the pass's work)
    assert {t for _, _, t in split_spy} == {1}, sorted(
        {(n, w, t) for n, w, t in split_spy if t > 1})[:5]


# ------------------------------------------------------------------ the pipeline
def check_demo_pipeline(demo, guides, what=""):
    """No resolved guide and no render curve not marked crosses a collider; the render
    roots (a sample of 400) on the evaluated body."""
    s = guides.furcollide
    cols = world_meshes([demo.pusher, demo.cloth])
    out, gout = s.output, s.groom.output
    if not s.is_outdated:
        bad = curves_crossing(world(out), offsets_of(out), cols, status_of(out))
        assert len(bad) == 0, (what, "guides", bad[:10])
    st = status_of(gout)
    bad = curves_crossing(world(gout), offsets_of(gout), cols, st,
                          keep=(0, 1, 2))  # not PINCHED, UNRESOLVED, INVALID
    assert len(bad) == 0, (what, "render groom", len(bad), bad[:10], st[bad[:10]])
    P, offs = world(gout), offsets_of(gout)
    roots = P[offs[:-1]][:: max(1, (len(offs) - 1) // 400)]
    V, F = tris_world(demo.body)
    d = pipe_oracle.point_mesh_distance(roots.astype(np.float64), V, F)
    assert d.max() < 1e-4, (what, d.max())


@pytest.mark.slow
def test_pipeline_at_real_size(fc, split_spy, monkeypatch, tmp_path, capsys):
    """The demo's pipeline with 20,000 render curves and 5,000 guides: played with
    checks, the clearance pass split in two halves; saved at frame 10 and reopened; baked
    with the core on one thread (no split anywhere; the render groom baked with it):
    every baked frame, guides and render groom, equals the played one bit for bit. Then
    Fur Sampler run again with another Fraction on the groom, and on the guides that have
    the setup: new objects only; the setup's frames, its source and the groom unchanged;
    no traceback anywhere."""
    demo, guides, out, gout = real_size_pipeline()
    scene = demo.scene
    groomed, guide_src = groom_snapshot(demo.fur), groom_snapshot(guides)
    first = {}
    for f in REAL_FRAMES:
        scene.frame_set(f)
        if f % 4 == 0:
            check_demo_pipeline(demo, guides, f"frame {f}")
        first[f] = pipeline_state(guides)
    assert split_phases(split_spy), sorted({(n, w) for n, w, _ in split_spy if w > 2000})
    scene.frame_set(10)
    names = (guides.name, demo.fur.name, out.name, gout.name)
    reopen(save_in(tmp_path))
    scene = bpy.context.scene
    guides, fur, out, gout = (bpy.data.objects[n] for n in names)
    same_pipeline_frame(pipeline_state(guides), first[10], "reopened at frame 10")
    step = sys.modules[ADDON + ".core.step"]
    with monkeypatch.context() as m:
        m.setattr(step, "default_threads", lambda: 1)
        guides.furcollide.threads = 1
        split_spy.clear()
        scene.frame_set(1)
        activate(guides)
        assert bpy.ops.furcollide.bake() == {"FINISHED"}
        assert not split_phases(split_spy)
    assert guides.furcollide.groom.is_baked_with
    for f in [*REAL_FRAMES, 7, 22, 1]:
        scene.frame_set(f)
        assert not guides.furcollide.is_outdated, guides.furcollide.status_message
        same_pipeline_frame(pipeline_state(guides), first[f], f"baked frame {f}")
    scene.frame_set(12)
    n_objects = len(bpy.data.objects)
    for src, fraction in ((fur, 0.3), (guides, 0.5)):
        activate(src)
        assert bpy.ops.furcollide.fur_sampler(fraction=fraction, seed=1) == {"FINISHED"}
        new = bpy.context.view_layer.objects.active
        assert new not in (fur, guides) and new.furcollide.output is None
        assert len(bpy.data.objects) == n_objects + 1
        n_objects += 1
        assert guides.furcollide.output == out and guides.furcollide.groom.output == gout
        for f in (12, 5, 20):
            scene.frame_set(f)
            assert not guides.furcollide.is_outdated, guides.furcollide.status_message
            same_pipeline_frame(pipeline_state(guides), first[f], f"after Fur Sampler, frame {f}")
    assert_groom_unchanged(fur, groomed, "the render groom")
    assert_groom_unchanged(guides, guide_src, "the guides")
    no_traceback(capsys)


# ---------------------------------------------------------------------- Shrink
@pytest.mark.slow
@pytest.mark.parametrize("mode", ["stiff", "bend"])
def test_shrink_on_the_demo(fc, mode):
    """README Settings: Shrink (Stiff/Bend) "segments shrink as they rotate", linearly
    from 1 at 0 degrees to Scale Minimum at Scale Angle; "roots never move, lengths are
    exact unless shrinking". The demo's fur (8,000 curves) with Shrink on, Scale Minimum
    0.5 and Scale Angle 20 (so that it bites), frames 1..24 (pusher, cloth, pinch): no
    resolved curve crosses a collider, roots are the source's, every segment keeps
    between 0.5 and 1 of its length, free curves all of it; Stiff shrinks a curve's
    segments alike, Bend less toward the root (its segments turn less there). (Soft
    ignores Shrink: tests/core/test_settings_fuzz.py.)"""
    demo, hair, out = demo_fur(
        8000, 24, mode=mode, shrink=True, scale_minimum=0.5, scale_angle=20.0
    )
    offs, src = offsets_of(hair), positions(hair)
    ns = int(np.diff(offs)[0]) - 1
    assert (np.diff(offs) == ns + 1).all()
    L0 = seg_lengths(src, offs).reshape(-1, ns)
    cols = (demo.pusher, demo.cloth)
    smallest = 1.0

    def check(f):
        nonlocal smallest
        P, st = positions(out), status_of(out)
        np.testing.assert_array_equal(P[offs[:-1]], src[offs[:-1]], err_msg=f"roots {f}")
        if f % 2 == 0 or f == 24:
            bad = curves_crossing(world(out), offs, world_meshes(cols), st)
            assert len(bad) == 0, (f, bad[:5], st[bad[:5]])
        r = seg_lengths(P, offs).reshape(-1, ns) / L0
        smallest = min(smallest, r.min())
        assert r.min() >= 0.5 - 2e-5 and r.max() <= 1 + 2e-5, (f, r.min(), r.max())
        np.testing.assert_allclose(r[st == 0], 1.0, rtol=2e-5, err_msg=f"free, {f}")
        if mode == "stiff":
            assert (r.max(1) - r.min(1)).max() < 1e-4, f
        else:
            assert np.diff(r, axis=1).max() < 1e-4, f

    rec = play_demo(demo.scene, hair, out, range(1, 25), check)
    counts = np.bincount(rec[24][1], minlength=7)
    assert counts[1] > 300 and counts[3] > 50, counts
    assert smallest < 0.5 + 1e-4, smallest  # Scale Minimum reached
