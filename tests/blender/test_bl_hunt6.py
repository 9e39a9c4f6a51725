"""Hunt 6: the demo's scene (scripts/demo_scene.py) at a size where a step solves its
phases in two halves on two threads (core.tolerances.SPLIT_MIN_CURVES curves of work),
driven frame by frame with ``scene.frame_set`` as an artist plays, scrubs, jumps,
changes settings (Mode, Rotation Precision, Recovery Rate, Plasticity, Threads) mid-shot,
saves and reopens, bakes, and re-runs Fur Sampler. Every frame is checked against
invariants, not snapshots: no resolved curve crosses a collider (brute-force oracle,
tests/core/oracle.py), roots never move, lengths are kept, the groomed source is never
modified, and the same frame reached by two paths is bit-identical where the README says
so. The report is docs/hunt6-report.md."""

import sys
from pathlib import Path

import bpy
import numpy as np
import pytest
from helpers import (
    ADDON,
    PINCHED,
    RESOLVED,
    activate,
    offsets_of,
    oracle,
    pipeline_state,
    positions,
    reopen,
    save_in,
    seg_lengths,
    status_of,
    tris_world,
    world,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "pipeline"))
import demo_scene as ds  # noqa: E402
import pipe_oracle  # noqa: E402

pytestmark = pytest.mark.blender

INVALID = 6  # core Status.INVALID
#: Curves of fur on the demo's body: enough that the cloth and the pusher put more than
#: SPLIT_MIN_CURVES (4096) curves into a phase (checked by every test that needs it).
N_FUR = 20000
#: The shot: the pusher reaches the fur at ~8, the cloth lands at 16, the pinch from 19.
LAST = 24
FRAMES = range(1, LAST + 1)
#: The demo's "fur" settings (scripts/demo.py SETTINGS["fur"]).
FUR_SETTINGS = dict(mode="bend", rotation_precision=0.5, collision_offset=0.008,
                    recovery_rate=0.3, pinch_resolution="growth_surface")
CLOTH_NOTE = "Colliders: no pinch detection for 'Cloth': open mesh (112 open edges)"


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


def demo_fur(mode="bend", threads=0, n_fur=N_FUR, **settings):
    """The demo scene with a FurCollide setup on its body fur (pusher and cloth), with the
    demo's settings, Frame Range 1..LAST. Returns (demo, fur, out)."""
    demo = ds.build(fur_count=n_fur, grass_count=50)
    activate(demo.fur, demo.pusher, demo.cloth)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    s = demo.fur.furcollide
    for k, v in dict(FUR_SETTINGS, mode=mode, threads=threads, **settings).items():
        setattr(s, k, v)
    s.frame_start, s.frame_end = 1, LAST
    demo.scene.frame_end = LAST + 4
    demo.scene.frame_set(1)
    return demo, demo.fur, s.output


def colliders_of(demo):
    return [demo.pusher, demo.cloth]


def crossing(P, offs, colliders, st=None, keep=RESOLVED):
    """Curves whose status is in ``keep`` (all when ``st`` is None) that surely cross one
    of ``colliders`` (the brute-force oracle, float32 margin: ``oracle.curves_crossing``
    on their evaluated world meshes)."""
    meshes = [tris_world(ob) for ob in colliders]
    return oracle.curves_crossing(P, offs, meshes, None if st is None else np.isin(st, keep))


def test_crossing_agrees_with_the_oracle():
    """The culled crossing test above gives the oracle's answer (random segments
    through random triangles on a unit sphere)."""
    rng = np.random.default_rng(5)
    V = rng.normal(size=(300, 3))
    V /= np.linalg.norm(V, axis=1, keepdims=True)
    F = rng.integers(0, 300, size=(600, 3))
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    P = rng.uniform(-1.3, 1.3, size=(400 * 4, 3))
    offs = np.arange(0, len(P) + 1, 4)
    want = np.flatnonzero(oracle.segments_hit_mesh(
        P, offs, V, F, abs_eps=oracle.float32_margin(P, V)))
    import helpers
    real = helpers.tris_world
    globals()["tris_world"] = lambda ob: (V, F)
    try:
        got = crossing(P, offs, [None])
    finally:
        globals()["tris_world"] = real
    assert len(want) > 20
    np.testing.assert_array_equal(got, want)


def check_frame(demo, hair, out, what="", lengths=True):
    """README's per-frame promises for a plain setup: no resolved curve crosses a
    collider, roots exactly the source's, lengths kept (no Shrink). Returns the statuses."""
    offs = offsets_of(out)
    st = status_of(out)
    bad = crossing(world(out), offs, colliders_of(demo), st)
    assert len(bad) == 0, (what, len(bad), bad[:10], st[bad[:10]])
    src, res = positions(hair), positions(out)
    np.testing.assert_array_equal(res[offs[:-1]], src[offs[:-1]], err_msg=f"{what}: roots")
    if lengths:
        ok = np.repeat(st != INVALID, np.diff(offs) - 1)
        np.testing.assert_allclose(seg_lengths(res, offs)[ok], seg_lengths(src, offs)[ok],
                                   rtol=2e-4, atol=1e-6, err_msg=f"{what}: lengths")
    return st


def frame_of(out):
    return positions(out).copy(), status_of(out).copy()


def same(a, b, what=""):
    np.testing.assert_array_equal(a[0], b[0], err_msg=f"{what}: positions")
    np.testing.assert_array_equal(a[1], b[1], err_msg=f"{what}: status")


def play(demo, hair, out, frames=FRAMES, check=False, status=True):
    """frame_set every frame: {frame: (positions, statuses)}; ``check``: the invariants
    of every frame; ``status``: the setup says nothing but the cloth's note."""
    rec = {}
    s = hair.furcollide
    for f in frames:
        bpy.context.scene.frame_set(f)
        if status:
            assert s.status_message in ("", CLOTH_NOTE), (f, s.status_message)
            assert not s.is_outdated, f
        if check:
            check_frame(demo, hair, out, what=f"frame {f}")
        rec[f] = frame_of(out)
    return rec


def snapshot(ob):
    """What the artist groomed: positions, layout and every attribute's values."""
    d = ob.data
    attrs = {}
    for a in d.attributes:
        if a.name.startswith("."):
            continue
        n = len(a.data)
        key = ("vector" if a.data_type in ("FLOAT_VECTOR", "FLOAT2") else
               "color" if a.data_type in ("FLOAT_COLOR", "BYTE_COLOR") else "value")
        width = {"FLOAT_VECTOR": 3, "FLOAT2": 2, "FLOAT_COLOR": 4, "BYTE_COLOR": 4}.get(
            a.data_type, 1)
        buf = np.empty(n * width, np.float64 if key != "value" or a.data_type == "FLOAT"
                       else np.int64)
        if a.data_type == "BOOLEAN":
            buf = np.empty(n, bool)
        a.data.foreach_get(key, buf)
        attrs[(a.name, a.domain, a.data_type)] = buf
    return positions(ob).copy(), offsets_of(ob).copy(), attrs, np.array(ob.matrix_world)


def assert_unchanged(ob, snap, what=""):
    now = snapshot(ob)
    np.testing.assert_array_equal(now[0], snap[0], err_msg=f"{ob.name} positions {what}")
    np.testing.assert_array_equal(now[1], snap[1], err_msg=f"{ob.name} layout {what}")
    assert now[2].keys() == snap[2].keys(), (what, now[2].keys() ^ snap[2].keys())
    for k in snap[2]:
        np.testing.assert_array_equal(now[2][k], snap[2][k], err_msg=f"{ob.name} {k} {what}")
    np.testing.assert_array_equal(now[3], snap[3], err_msg=f"{ob.name} matrix {what}")


def reset(hair):
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}


# --------------------------------------------------------- played, scrubbed, jumped
def test_demo_played_scrubbed_and_jumped(fc, split_spy):
    """The demo's fur (20,000 curves, Bend) played 1..24: every frame holds the README's
    promises and both phases of a step ran in two halves; scrubbed back, the same
    frames bit for bit; after Reset Cache a jump ahead holds the newest cached frame and
    says so; played from the start again, the first play bit for bit. The groom is
    never touched."""
    demo, hair, out = demo_fur()
    groomed = snapshot(hair)
    scene = demo.scene
    first = play(demo, hair, out, check=True)
    assert split_phases(split_spy) == {"_new_contacts", "_search"}, sorted(
        {(n, w) for n, w, _ in split_spy if w > 3000})
    counts = np.bincount(first[LAST][1], minlength=7)
    assert counts[1] > 1000 and counts[PINCHED] > 0, counts
    for f in (20, 5, 24, 13, 1, 17, 24, 2):
        scene.frame_set(f)
        same(frame_of(out), first[f], f"scrubbed to {f}")
    reset(hair)
    scene.frame_set(1)
    scene.frame_set(12)  # a jump ahead: frame 1 is held, outdated
    s = hair.furcollide
    assert s.is_outdated and "not cached" in s.status_message, s.status_message
    same(frame_of(out), first[1], "jump: the newest cached frame held")
    again = play(demo, hair, out)
    for f in FRAMES:
        same(again[f], first[f], f"replayed frame {f}")
    assert_unchanged(hair, groomed)


# --------------------------------------------------------------- threads, warm start
@pytest.mark.slow
@pytest.mark.parametrize("mode", ["stiff", "bend", "soft", "soft+attract"])
def test_threads_give_the_same_frames(fc, split_spy, mode):
    """README: "the same inputs give bit-identical outputs whatever the thread count".
    Played with Threads 2 (the split on), then 1, then switched from 2 to 1 mid-shot
    (Threads does not invalidate the cache): the same frames bit for bit."""
    mode, _, attract = mode.partition("+")
    demo, hair, out = demo_fur(mode, threads=2, attract_to_growth_surface=bool(attract))
    s = hair.furcollide
    # the crossing oracle on every frame once for Soft (with Attract, which runs the same
    # solve and then pulls); Stiff and Bend: test_demo_played_scrubbed_and_jumped
    ref = play(demo, hair, out, check=bool(attract))
    assert split_phases(split_spy), mode
    reset(hair)
    s.threads = 1
    for f, got in play(demo, hair, out).items():
        same(got, ref[f], f"{mode}: Threads 1, frame {f}")
    reset(hair)
    s.threads = 2
    play(demo, hair, out, range(1, 13))
    s.threads = 1
    for f, got in play(demo, hair, out, range(13, LAST + 1)).items():
        same(got, ref[f], f"{mode}: Threads 2 -> 1 at 13, frame {f}")


WARM_DIFFERS = ("A known limit (README 'Known limitations of the core', precision where "
                "clearance is not monotone): on the demo's frame 22 (the pusher pinching, the "
                "cloth on the fur) the full search's first probe (1.3 times the tangent-plane "
                "estimate) lands in a blocked band above a 38-degree-wide clear window and "
                "skips it: 4 curves turn 25-50 degrees further, then start again as new "
                "contacts; the warm start finds the window")


@pytest.mark.slow
@pytest.mark.parametrize("mode", [
    pytest.param("stiff", marks=pytest.mark.xfail(strict=True, reason=WARM_DIFFERS))])
def test_warm_start_equals_the_full_search(fc, monkeypatch, mode):
    """README "Warm start": "The result is bit-identical to the full search
    (Solver.warm_start = False) from the same state". The demo's fur played 1..22 with
    the warm start (the add-on's default), then with the full search. (Bend: hunt 7's
    test_bend_warm_start_equals_the_full_search_to_frame_24_and_differs_at_25.)"""
    demo, hair, out = demo_fur(mode, threads=2)
    frames = range(1, 23)
    ref = play(demo, hair, out, frames)
    solver = sys.modules[ADDON + ".core.solver"]
    monkeypatch.setattr(solver.Solver, "warm_start", False)
    reset(hair)
    for f, got in play(demo, hair, out, frames).items():
        same(got, ref[f], f"{mode}: full search, frame {f}")


# ------------------------------------------------------------ a setting mid-shot
MID_SHOT = [("mode", "stiff"), ("mode", "soft"), ("rotation_precision", 0.25),
            ("recovery_rate", 0.8), ("plasticity", 0.6)]


def test_a_setting_changed_mid_shot_drops_the_playback_cache(fc):
    """README "Time" > Invalidation: a changed setting drops the whole playback cache,
    as Blender's point cache does: played to 6, Recovery Rate changed, frame 7 is not
    stepped from frame 6 (solved with the old setting); the output keeps frame 6 and
    says why. (Hunt 6, finding 2: the README said only the frames after the current
    one were dropped.) Threads changes no result and drops nothing."""
    demo, hair, out = demo_fur(n_fur=3000)
    first = play(demo, hair, out, range(1, 7))
    hair.furcollide.threads = 1
    demo.scene.frame_set(7)
    assert not hair.furcollide.is_outdated, hair.furcollide.status_message
    demo.scene.frame_set(6)
    hair.furcollide.recovery_rate = 0.8
    demo.scene.frame_set(7)
    s = hair.furcollide
    assert s.is_outdated and "Recovery Rate changed" in s.status_message, s.status_message
    same(frame_of(out), first[6], "frame 7 after the change: the output held")


@pytest.mark.slow
@pytest.mark.parametrize("name,value", MID_SHOT, ids=[f"{n}={v}" for n, v in MID_SHOT])
def test_a_setting_changed_mid_shot(fc, name, value):
    """Played to 14 (Bend), a setting changed: the frames after it are held and say why
    (finding 2), scrubbed back a frame cached with the old setting is not shown (the
    output keeps what it showed). Played from the start: every frame holds the promises
    (checked every sixth frame), and equals a fresh solve (Reset Cache) with the new
    setting. Set back and played again: the first session's frames bit for bit.
    (The crossing oracle runs on frames 2, 8, 14 and 20: before the pusher, entering,
    pinching, with the cloth on the fur; every frame in test_demo_played_scrubbed_and_jumped.)"""
    demo, hair, out = demo_fur()
    s = hair.furcollide
    scene = demo.scene
    first = play(demo, hair, out, range(1, 15))
    before = getattr(s, name)
    setattr(s, name, value)
    for f in (15, 16, 8, 3):
        scene.frame_set(f)
        said = f"{s.bl_rna.properties[name].name} changed"
        assert s.is_outdated and said in s.status_message, (
            f, s.status_message)
        same(frame_of(out), first[14], f"frame {f} after the change: the output held")
    new = {}
    for f in FRAMES:
        new.update(play(demo, hair, out, [f]))
        if f % 6 == 2:
            check_frame(demo, hair, out, what=f"{name}={value}, frame {f}")
    reset(hair)
    for f, got in play(demo, hair, out).items():
        same(got, new[f], f"{name}={value}: replayed vs fresh, frame {f}")
    setattr(s, name, before)
    for f, got in play(demo, hair, out, range(1, 15)).items():
        same(got, first[f], f"{name} set back, frame {f}")


# -------------------------------------------------------------- file and bake
@pytest.mark.slow
def test_saved_mid_playback_reopened_and_baked(fc, tmp_path):
    """Played to 14 with Threads 2, saved, reopened: the saved frame shown and held on a
    jump, said so; played from the start with Threads 1: the first session bit for bit.
    Baked (Threads 1) and the baked frames played and scrubbed: the first session bit
    for bit, nothing said. The groom never changes."""
    demo, hair, out = demo_fur(threads=2)
    groomed = snapshot(hair)
    first = play(demo, hair, out)
    demo.scene.frame_set(14)
    path = save_in(tmp_path)
    reopen(path)
    scene = bpy.context.scene
    hair = bpy.data.objects["Fur"]
    out = hair.furcollide.output
    s = hair.furcollide
    assert scene.frame_current == 14
    same(frame_of(out), first[14], "reopened")
    scene.frame_set(16)
    assert "not saved with the file" in s.status_message, s.status_message
    same(frame_of(out), first[14], "reopened, frame 16 held")
    s.threads = 1
    for f, got in play(demo, hair, out).items():
        same(got, first[f], f"reopened and replayed, frame {f}")
    scene.frame_set(1)
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert s.is_baked
    s.threads = 2
    for f in list(FRAMES) + [20, 3, 24, 11]:
        scene.frame_set(f)
        assert s.status_message in ("", CLOTH_NOTE) and not s.is_outdated, (f, s.status_message)
        same(frame_of(out), first[f], f"baked frame {f}")
    assert_unchanged(hair, groomed)


# ------------------------------------------------------------------ the pipeline
def pipeline(n_fur=N_FUR, fraction=0.25):
    """The demo's pipeline (scripts/demo.py pipeline_setup) on ``n_fur`` curves: Fur
    Sampler, FurCollide on the guides (the demo's settings, collider offsets), Fur Attach,
    wind after collision with the Region of Influence and the collider distance, the fur
    bound as the render groom with the clearance pass. Returns (demo, guides, out, gout)."""
    demo = ds.build(fur_count=n_fur, grass_count=50)
    scene = demo.scene
    scene.frame_set(1)
    activate(demo.fur)
    assert bpy.ops.furcollide.fur_sampler(fraction=fraction, seed=3) == {"FINISHED"}
    guides = bpy.context.view_layer.objects.active
    activate(guides, demo.pusher, demo.cloth)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    s = guides.furcollide
    for k, v in FUR_SETTINGS.items():
        setattr(s, k, v)
    s.frame_start, s.frame_end = 1, LAST
    for c in s.colliders:
        c.use_offset, c.collision_offset = True, FUR_SETTINGS["collision_offset"]
    activate(guides)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    m = s.motion
    for k, v in dict(use_wind=True, wind_stage="OUTPUT", wind_strength=0.04,
                     wind_direction=(1.0, 0.4, 0.0), wind_turbulence=0.8, wind_frequency=0.7,
                     wind_scale=0.4, use_region_of_influence=True,
                     write_collider_distance=True, distance_max=0.1).items():
        setattr(m, k, v)
    s.groom.groom = demo.fur
    s.groom.use_clearance = True
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    return demo, guides, s.output, s.groom.output


def same_pipeline(a, b, what=""):
    for x, y, n in zip(a, b, ("guides", "guide status", "groom", "groom status"), strict=True):
        np.testing.assert_array_equal(x, y, err_msg=f"{what} {n}")


def check_pipeline(demo, guides, what=""):
    """No resolved guide and no render curve not marked crosses a collider; the render
    roots (a sample of 400) on the evaluated body."""
    s = guides.furcollide
    cols = colliders_of(demo)
    out, gout = s.output, s.groom.output
    if not s.is_outdated:
        bad = crossing(world(out), offsets_of(out), cols, status_of(out))
        assert len(bad) == 0, (what, "guides", bad[:10])
    st = status_of(gout)
    bad = crossing(world(gout), offsets_of(gout), cols, st,
                   keep=(0, 1, 2))  # not PINCHED, UNRESOLVED, INVALID
    assert len(bad) == 0, (what, "render groom", len(bad), bad[:10], st[bad[:10]])
    P, offs = world(gout), offsets_of(gout)
    roots = P[offs[:-1]][:: max(1, (len(offs) - 1) // 400)]
    V, F = tris_world(demo.body)
    d = pipe_oracle.point_mesh_distance(roots.astype(np.float64), V, F)
    assert d.max() < 1e-4, (what, d.max())


@pytest.mark.slow
def test_pipeline_at_real_size(fc, split_spy, monkeypatch):
    """The demo's pipeline with 20,000 render curves and 5,000 guides: played with
    checks, the clearance pass split in two halves; played again with the core on one
    thread (no split anywhere): bit for bit. Then Fur Sampler run again with another
    Fraction on the groom, and on the guides that have the setup: new objects only; the
    setup's frames, its source and the groom unchanged."""
    demo, guides, out, gout = pipeline()
    scene = demo.scene
    fur = demo.fur
    groomed, guide_src = snapshot(fur), snapshot(guides)
    first = {}
    for f in FRAMES:
        scene.frame_set(f)
        if f % 4 == 0:
            check_pipeline(demo, guides, f"frame {f}")
        first[f] = pipeline_state(guides)
    assert split_phases(split_spy), sorted({(n, w) for n, w, _ in split_spy if w > 2000})
    step = sys.modules[ADDON + ".core.step"]
    with monkeypatch.context() as m:
        m.setattr(step, "default_threads", lambda: 1)
        guides.furcollide.threads = 1
        reset(guides)
        split_spy.clear()
        for f in FRAMES:
            scene.frame_set(f)
            same_pipeline(pipeline_state(guides), first[f], f"one thread, frame {f}")
        assert not split_phases(split_spy)
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
            same_pipeline(pipeline_state(guides), first[f], f"after Fur Sampler, frame {f}")
    assert_unchanged(fur, groomed, "the render groom")
    assert_unchanged(guides, guide_src, "the guides")


def test_threads_one_is_one_thread_for_the_whole_frame(fc, split_spy):
    """The Threads tooltip: "Threads a frame uses (0 = all CPUs)". With
    Threads 1 (a farm running one Blender per core), no step of the frame, the render
    groom's clearance pass included, runs on more than one thread. (Hunt 6, finding 3:
    the clearance pass took every CPU and two halves whatever Threads said.)"""
    demo, guides, out, gout = pipeline()
    guides.furcollide.threads = 1
    split_spy.clear()  # (what building the pipeline solved, with the default Threads)
    for f in range(1, 17):
        demo.scene.frame_set(f)
    tolerances = sys.modules[ADDON + ".core.tolerances"]
    assert max(w for _, w, _ in split_spy) >= tolerances.SPLIT_MIN_CURVES  # (the pass's work)
    assert {t for _, _, t in split_spy} == {1}, sorted(
        {(n, w, t) for n, w, t in split_spy if t > 1})[:5]


# ------------------------------------------------------------ resume, memory limit
@pytest.mark.slow
@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_a_bake_resumed_after_a_crash_gives_the_played_frames(fc, tmp_path, monkeypatch,
                                                              mode):
    """A bake that crashed at frame 21 (the pinch, where the warm start's memory
    matters: finding 1), resumed with Threads 1: every baked frame equals the played
    one bit for bit (README: "The next Bake resumes after the last frame whose files
    match"; each file holds "the full solver state")."""
    from helpers import bake_crashing_at
    demo, hair, out = demo_fur(mode, threads=2)
    first = play(demo, hair, out)
    save_in(tmp_path)
    demo.scene.frame_set(1)
    activate(hair)
    bake_crashing_at(fc, monkeypatch, 21)
    hair.furcollide.threads = 1
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    for f in FRAMES:
        demo.scene.frame_set(f)
        assert not hair.furcollide.is_outdated, hair.furcollide.status_message
        same(frame_of(out), first[f], f"{mode}: resumed bake, frame {f}")


@pytest.mark.slow
def test_memory_limit_at_real_size(fc):
    """The Memory Limit at its minimum (16 MB) with 20,000 curves and wind after
    collision (every point cached): the frames it keeps are shown bit for bit, a frame
    whose state was dropped holds the next one and says so, and playing from the start
    gives the same frames again."""
    demo, hair, out = demo_fur()
    s = hair.furcollide
    m = s.motion
    m.use_wind, m.wind_stage, m.wind_strength = True, "OUTPUT", 0.04
    first = play(demo, hair, out)
    s.memory_limit = 16
    reset(hair)
    play(demo, hair, out)
    rt = fc.registry.get_runtime(hair, create=False)
    kept = sorted(rt.memory.frames)
    with_state = [f for f in kept if rt.memory.state(f) is not None]
    assert len(kept) < LAST or len(with_state) < len(kept), (kept, with_state)
    for f in kept[::-1]:
        demo.scene.frame_set(f)
        assert not s.is_outdated, (f, s.status_message)
        same(frame_of(out), first[f], f"memory-limited cache, frame {f}")
    gone = [f for f in FRAMES if f not in kept and f - 1 not in kept]
    assert gone
    demo.scene.frame_set(gone[0])  # evicted: a jump ahead holds a cached frame
    assert s.is_outdated and "not cached" in s.status_message, s.status_message
    assert any(np.array_equal(positions(out), first[g][0]) for g in kept)
    for f, got in play(demo, hair, out).items():
        same(got, first[f], f"played again, frame {f}")


@pytest.mark.slow
def test_pipeline_baked_at_real_size(fc, tmp_path, capsys):
    """The real-size pipeline played (Threads 2), saved at frame 10 and reopened, then
    baked with Threads 1 (the render groom baked with it): every baked frame, guides and
    render groom, equals the first session's bit for bit; no traceback anywhere."""
    from helpers import no_traceback
    demo, guides, out, gout = pipeline()
    scene = demo.scene
    first = {}
    for f in FRAMES:
        scene.frame_set(f)
        first[f] = pipeline_state(guides)
    scene.frame_set(10)
    name = guides.name
    path = save_in(tmp_path)
    reopen(path)
    scene = bpy.context.scene
    guides = bpy.data.objects[name]
    same_pipeline(pipeline_state(guides), first[10], "reopened at frame 10")
    guides.furcollide.threads = 1
    scene.frame_set(1)
    activate(guides)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert guides.furcollide.groom.is_baked_with
    for f in list(FRAMES) + [7, 22, 1]:
        scene.frame_set(f)
        assert not guides.furcollide.is_outdated, guides.furcollide.status_message
        same_pipeline(pipeline_state(guides), first[f], f"baked frame {f}")
    no_traceback(capsys)


def test_fur_sampler_gives_the_same_guides_at_any_frame(fc):
    """README: "The same Seed always gives the same guides". Run again later in the shot
    (the demo's body, the groom's Surface, has turned by frame 12): the same curves."""
    demo = ds.build(fur_count=3000, grass_count=50)
    got = []
    for f in (1, 12, 1):
        demo.scene.frame_set(f)
        activate(demo.fur)
        assert bpy.ops.furcollide.fur_sampler(fraction=0.15, seed=3) == {"FINISHED"}
        g = bpy.context.view_layer.objects.active
        got.append(world(g))
    assert len(got[0]) == 450 * 8
    for g in got[1:]:
        np.testing.assert_array_equal(g, got[0])

