"""Hunt 7: what hunt 6 left untried, on the demo's scene (scripts/demo_scene.py) driven
frame by frame with ``scene.frame_set`` through the real ``bpy`` wheel: animation
renders with motion blur (subframes fire the frame handler again), Soft's warm start
against its full search, the grass setup (Grass Trampling) baked with Bake All and baked
again after a change, and Shrink. Every frame is checked against invariants (no resolved
curve crosses a collider: the brute-force oracle of tests/core/oracle.py; roots never
move; lengths as the mode says) or against the same frame reached another way, bit for
bit. The report is docs/hunt7-report.md."""

import copy
import sys
from pathlib import Path

import bpy
import numpy as np
import pytest
from helpers import (
    ADDON,
    RESOLVED,
    activate,
    offsets_of,
    oracle,
    pipeline_state,
    positions,
    save_in,
    seg_lengths,
    status_of,
    tris_world,
    world,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
import demo_scene as ds  # noqa: E402

pytestmark = pytest.mark.blender

#: The demo's "fur" settings (scripts/demo.py SETTINGS["fur"]).
FUR = dict(
    mode="bend",
    rotation_precision=0.5,
    collision_offset=0.008,
    recovery_rate=0.3,
    pinch_resolution="growth_surface",
)
#: The Grass Trampling preset (ui/preset_files/Grass_Trampling.py).
GRASS = dict(
    mode="bend",
    rotation_precision=0.5,
    max_angle=170.0,
    collision_offset=0.01,
    recovery_rate=0.05,
    plasticity=0.6,
    pinch_resolution="stop",
)
CLOTH_NOTE = "Colliders: no pinch detection for 'Cloth': open mesh (112 open edges)"
QUIET = ("", CLOTH_NOTE)


# ------------------------------------------------------------------ the scene
def demo_fur(n_fur, last, mode="bend", grass=50, **settings):
    """The demo with a FurCollide setup on its body fur (pusher and cloth), the demo's
    settings, Frame Range 1..``last``. Returns (demo, fur, out)."""
    demo = ds.build(fur_count=n_fur, grass_count=grass)
    activate(demo.fur, demo.pusher, demo.cloth)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    s = demo.fur.furcollide
    for k, v in dict(FUR, mode=mode, **settings).items():
        setattr(s, k, v)
    s.frame_start, s.frame_end = 1, last
    demo.scene.frame_start, demo.scene.frame_end = 1, last
    demo.scene.frame_set(1)
    return demo, demo.fur, s.output


def crossing(P, offs, meshes, st=None, keep=RESOLVED):
    """Curves whose status is in ``keep`` (all when ``st`` is None) that surely cross
    one of ``meshes`` ((V, F) in world space): ``oracle.curves_crossing``."""
    return oracle.curves_crossing(P, offs, meshes, None if st is None else np.isin(st, keep))


def test_crossing_agrees_with_the_oracle():
    """The culled crossing test gives the plain oracle's answer."""
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
    np.testing.assert_array_equal(crossing(P, offs, [(V, F)]), want)


def meshes(objects, depsgraph=None):
    return [tris_world(o, depsgraph) for o in objects]


def frame_of(out):
    return positions(out).copy(), status_of(out).copy()


def same(a, b, what=""):
    np.testing.assert_array_equal(a[0], b[0], err_msg=f"{what}: positions")
    np.testing.assert_array_equal(a[1], b[1], err_msg=f"{what}: status")


def play(scene, hair, out, frames, check=None):
    """frame_set every frame ({frame: (positions, statuses)}); the setup says nothing
    but the cloth's note; ``check(frame)`` after each."""
    rec = {}
    for f in frames:
        scene.frame_set(f)
        assert hair.furcollide.status_message in QUIET, (f, hair.furcollide.status_message)
        assert not hair.furcollide.is_outdated, f
        if check is not None:
            check(f)
        rec[f] = frame_of(out)
    return rec


def reset(hair):
    activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}


# -------------------------------------------------------- renders with motion blur
def cycles_motion_blur(scene, tmp_path, position="CENTER"):
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.device = "CPU"
    scene.render.resolution_x = scene.render.resolution_y = 16
    scene.render.use_lock_interface = True
    scene.render.use_motion_blur = True
    scene.render.motion_blur_position = position
    scene.render.filepath = str(tmp_path / "mb_####")


def render_recording(hair, record):
    """Render the animation; [((frame, subframe), record(depsgraph), status message,
    outdated)] for every RENDER-depsgraph frame change, after FurCollide's handler."""
    seen = []

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            s = hair.furcollide
            seen.append(
                (
                    (sc.frame_current, round(sc.frame_subframe, 3)),
                    record(depsgraph),
                    s.status_message,
                    s.is_outdated,
                )
            )

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    return seen


#: The fur (6,000 curves: the pusher reaches it at frame 8, the cloth comes down from 1).
R_FUR, R_LAST = 6000, 12


#: Motion blur centred on the frame runs in every lane; the other shutter positions
#: (the same frame rules, other orders of the motion steps) in the main lane only.
OTHER_POSITIONS = pytest.mark.slow


@pytest.mark.parametrize("position", [
    "CENTER", pytest.param("START", marks=OTHER_POSITIONS),
    pytest.param("END", marks=OTHER_POSITIONS)])
def test_motion_blur_render_of_a_played_setup(fc, tmp_path, position):
    """README "Time": a subframe "never steps ... the output keeps the whole frame";
    "Animation renders show the solved ... result on every frame". An animation render
    with motion blur (Cycles' motion steps fire the frame handler at subframes) of a
    setup nobody played: every whole frame rendered is a fresh viewport play's frame
    bit for bit, every subframe shows the whole frame being rendered, nothing is said,
    and afterwards the playback cache holds the whole frames only, as played."""
    demo, hair, out = demo_fur(R_FUR, R_LAST)
    scene = demo.scene
    ref = play(scene, hair, out, range(1, R_LAST + 1))
    assert (ref[R_LAST][1] == 1).sum() > 20  # the pusher and the cloth reached the fur
    reset(hair)
    scene.frame_set(1)
    cycles_motion_blur(scene, tmp_path, position)
    seen = render_recording(hair, lambda dg: frame_of(out))
    assert any(sub for (_, sub), *_ in seen), "no motion step was rendered"
    last_whole = None
    for (f, sub), got, msg, outdated in seen:
        assert msg in QUIET and not outdated, (f, sub, msg)
        if sub == 0.0:
            same(got, ref[f], f"{position}: rendered frame {f}")
            last_whole = f
        else:  # the whole frame being rendered, evaluated just before
            same(got, ref[last_whole], f"{position}: subframe {f}+{sub}")
    rt = fc.registry.get_runtime(hair)
    assert sorted(rt.memory.frames) == list(range(1, R_LAST + 1))
    for f in (R_LAST, 3, 9):
        scene.frame_set(f)
        same(frame_of(out), ref[f], f"after the render, frame {f}")
    scene.frame_set(R_LAST + 1)  # after the end: the end frame held
    same(frame_of(out), ref[R_LAST], "after the end")


@pytest.mark.parametrize("position", ["CENTER", pytest.param("END", marks=OTHER_POSITIONS)])
def test_motion_blur_render_of_a_baked_setup(fc, tmp_path, position):
    """README "Time": at a subframe "a baked setup blends its two neighbouring baked
    frames (from Frame End on it shows Frame End)". Every subframe of the render is
    exactly ``a + (b - a) * subframe`` of the two bake files (the start frame's motion
    step before it keeps the start frame), every whole frame the bake, nothing said,
    and the viewport afterwards the bake."""
    demo, hair, out = demo_fur(R_FUR, R_LAST)
    scene = demo.scene
    save_in(tmp_path)
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    baked = {f: fc.cache.read_frame(d, f, state=False)[0] for f in range(1, R_LAST + 1)}
    cycles_motion_blur(scene, tmp_path, position)
    seen = render_recording(hair, lambda dg: world(out).astype(np.float32))
    blended = 0
    for (f, sub), got, msg, outdated in seen:
        assert msg in QUIET and not outdated, (f, sub, msg)
        if sub == 0.0:
            np.testing.assert_array_equal(got, baked[f], err_msg=f"whole frame {f}")
            last_whole = f
        elif f < 1:
            np.testing.assert_array_equal(got, baked[last_whole], err_msg="before the start")
        else:
            a, b = (f, f + 1) if f < R_LAST else (R_LAST, R_LAST)
            want = baked[a] + (baked[b] - baked[a]) * np.float32(sub)
            np.testing.assert_allclose(got, want, atol=1e-6, err_msg=f"subframe {f}+{sub}")
            blended += not np.array_equal(baked[a], baked[b])
    assert blended > 5
    for f in (R_LAST, 4):
        scene.frame_set(f)
        np.testing.assert_array_equal(world(out).astype(np.float32), baked[f])
        assert hair.furcollide.status_message in QUIET


def test_f12_with_motion_blur_in_the_middle_of_playback(fc, tmp_path):
    """An F12 still with motion blur at frame 8 while playing (frames 1-10 cached):
    the still sees frame 8, the subframes change no cached frame, and playing on from
    frame 10 gives what an uninterrupted play gives, bit for bit."""
    demo, hair, out = demo_fur(R_FUR, R_LAST)
    scene = demo.scene
    ref = play(scene, hair, out, range(1, R_LAST + 1))
    reset(hair)
    play(scene, hair, out, range(1, 11))
    scene.frame_set(8)
    cycles_motion_blur(scene, tmp_path)
    seen = []

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            seen.append(((sc.frame_current, round(sc.frame_subframe, 3)), frame_of(out)))

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render()
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    assert {k for k, _ in seen} >= {(8, 0.0), (7, 0.75), (8, 0.25)}, [k for k, _ in seen]
    for key, got in seen:
        same(got, ref[8], f"F12 at {key}")
    assert sorted(fc.registry.get_runtime(hair).memory.frames) == list(range(1, 11))
    for f, got in play(scene, hair, out, [9, 10, 11, 12, 2]).items():
        same(got, ref[f], f"after F12, frame {f}")


def pipeline(n_fur, last):
    """The demo's pipeline (scripts/demo.py pipeline_setup): Fur Sampler 25 %, FurCollide
    on the guides with Fur Attach and wind after collision (Region of Influence), the
    fur bound as the render groom with the clearance pass. (demo, guides, out, gout)."""
    demo = ds.build(fur_count=n_fur, grass_count=50)
    scene = demo.scene
    scene.frame_start, scene.frame_end = 1, last
    scene.frame_set(1)
    activate(demo.fur)
    assert bpy.ops.furcollide.fur_sampler(fraction=0.25, seed=3) == {"FINISHED"}
    guides = bpy.context.view_layer.objects.active
    activate(guides, demo.pusher, demo.cloth)
    assert bpy.ops.furcollide.add() == {"FINISHED"}
    s = guides.furcollide
    for k, v in FUR.items():
        setattr(s, k, v)
    s.frame_start, s.frame_end = 1, last
    activate(guides)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    m = s.motion
    m.use_wind, m.wind_stage, m.wind_strength = True, "OUTPUT", 0.04
    m.use_region_of_influence = True
    s.groom.groom = demo.fur
    s.groom.use_clearance = True
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    return demo, guides, s.output, s.groom.output


def baked_pipeline(tmp_path, last, n_fur=4000):
    """:func:`pipeline`, saved in ``tmp_path`` and baked with its render groom."""
    demo, guides, out, gout = pipeline(n_fur, last)
    save_in(tmp_path)
    activate(guides)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert guides.furcollide.groom.is_baked_with
    return demo, guides, out, gout


def test_motion_blur_render_of_a_baked_render_groom(fc, tmp_path):
    """The demo's pipeline baked with its render groom, rendered with motion blur, the
    guides and the groom hidden from render (only the groom output renders): every whole
    frame is the bake (guides and render groom) bit for bit; at a subframe the guides
    and the render groom are the blends of their two baked frames (README *Time*: "A
    baked setup blends its two neighbouring baked frames"; nothing is computed, so the
    groom moves over the shutter with its guides instead of being solved again at each
    motion step, which made single curves jump 10-25 cm in a quarter frame); nothing
    said."""
    last = 14
    demo, guides, out, gout = baked_pipeline(tmp_path, last)
    scene = demo.scene
    first = {}
    for f in range(1, last + 1):
        scene.frame_set(f)
        first[f] = pipeline_state(guides)
    for o in (guides, out, demo.fur, demo.grass):
        o.hide_render = True
    cycles_motion_blur(scene, tmp_path)
    seen = render_recording(guides, lambda dg: pipeline_state(guides))
    d = bpy.path.abspath(guides.furcollide.bake_path)
    fixed = 0
    for (f, sub), state, msg, outdated in seen:
        assert msg in QUIET and not outdated, (f, sub, msg)
        if sub == 0.0:
            for x, y in zip(state, first[f], strict=True):
                np.testing.assert_array_equal(x, y, err_msg=f"whole frame {f}")
            continue
        if 1 <= f < last:
            a, b = (fc.cache.read_frame(d, k, state=False)[0] for k in (f, f + 1))
            np.testing.assert_allclose(state[0], a + (b - a) * np.float32(sub), atol=1e-6)
            ga, gb = (fc.cache.read_extra(d, k, "groom")["points"] for k in (f, f + 1))
            np.testing.assert_allclose(state[2], ga + (gb - ga) * np.float32(sub), atol=1e-6)
            np.testing.assert_array_equal(state[3], first[f][3])
        fixed += int((state[2] != first[max(f, 1)][2]).any())
    assert fixed > 5
    for f in (last, 5):
        scene.frame_set(f)
        for x, y in zip(pipeline_state(guides), first[f], strict=True):
            np.testing.assert_array_equal(x, y, err_msg=f"after the render, frame {f}")


# ------------------------------------------------------------ warm start, full search
N_FUR = 20000  # the real-size demo of hunt 6


@pytest.mark.slow
def test_soft_warm_start_equals_its_full_search_over_the_whole_shot(fc, monkeypatch):
    """README "Warm start": Soft's blocked recoveries start from the fraction they took
    last step, "the same level as the full search wherever clearance is monotone along
    the recovery arc". The demo's fur (20,000 curves, Soft) over the whole shot, 1..48
    (the pusher in, the pinch, the pusher backing out at 28-38 with the cloth on the fur:
    hundreds of curves recovering under it), played with the warm start and again with
    ``Solver.warm_start = False``: the same frames, bit for bit."""
    demo, hair, out = demo_fur(N_FUR, 48, mode="soft")
    scene = demo.scene
    ref = play(scene, hair, out, range(1, 49))
    assert (ref[36][1] == 2).sum() > 200  # recovering (465)
    solver = sys.modules[ADDON + ".core.solver"]
    monkeypatch.setattr(solver.Solver, "warm_start", False)
    reset(hair)
    for f, got in play(scene, hair, out, range(1, 49)).items():
        same(got, ref[f], f"Soft, full search, frame {f}")


@pytest.mark.slow
def test_bend_warm_start_equals_the_full_search_to_frame_24_and_differs_at_25(fc, monkeypatch):
    """README "Warm start": the demo's fur in Bend (Threads 2: each phase in two halves),
    played 1..25 with the warm start and again with the full search
    (``Solver.warm_start = False``). Frames 1..24 are the same bit for bit; at frame 25
    (the pusher deep in the fur, the cloth on it) a few curves differ: the full search's
    first probe at 1.3 times the tangent-plane estimate lands in a blocked band above a
    wide clear window (core/rigid.py search_angles, core/step.py plane_guess), the known
    limit of *Known limitations of the core*. Why each differing curve may differ, and
    that both are collision-free: the next test. (This replaces hunt 6's Bend case to
    frame 22 and hunt 7's strict xfail to frame 25, which played the same frames.)"""
    demo, hair, out = demo_fur(N_FUR, 25, threads=2)
    scene = demo.scene
    ref = play(scene, hair, out, range(1, 26))
    solver = sys.modules[ADDON + ".core.solver"]
    monkeypatch.setattr(solver.Solver, "warm_start", False)
    reset(hair)
    got = play(scene, hair, out, range(1, 26))
    for f in range(1, 25):
        same(got[f], ref[f], f"Bend, full search, frame {f}")
    pos_w, pos_f = ref[25][0].reshape(-1, 3), got[25][0].reshape(-1, 3)
    moved = np.abs(pos_w - pos_f).max(1)
    offs = offsets_of(hair)
    per_curve = np.maximum.reduceat(moved, offs[:-1])
    assert 0 < (per_curve > 0).sum() < 50, (per_curve > 0).sum()  # (5 on this machine)


@pytest.mark.slow
def test_bend_warm_start_differs_only_where_clearance_is_not_monotone(fc, monkeypatch):
    """README "Warm start": "Wherever clearance is monotone along a curve's turn the
    result is bit-identical to the full search from the same state". Frame 25 of the
    demo's fur (Bend) stepped from frame 24's state both ways in the core: every curve
    that differs has, along its kept axis from its current angle, a clear step below a
    blocked one on the precision grid (both answers a clear step right after a colliding
    one), and neither result leaves a resolved curve crossing the pusher or the cloth."""
    demo, hair, out = demo_fur(N_FUR, 25)
    solver_mod = sys.modules[ADDON + ".core.solver"]
    rigid = sys.modules[ADDON + ".core.rigid"]
    cap = {}
    real_step = solver_mod.Solver.step

    def capture(self, points, colliders=(), growth=None, enabled=None):
        if bpy.context.scene.frame_current == 25:
            cap.update(
                args=(np.array(points), list(colliders), growth, enabled),
                state=copy.deepcopy(self.state),
                settings=self.settings,
            )
        return real_step(self, points, colliders, growth, enabled)

    monkeypatch.setattr(solver_mod.Solver, "step", capture)
    play(demo.scene, hair, out, range(1, 26))
    ms = meshes((demo.pusher, demo.cloth))
    offs = offsets_of(hair)
    searches, batches = [], []
    real_search, real_init = rigid._search, rigid.RigidBatch.__init__

    def init(self, ctx, curves, axis, stiff):
        real_init(self, ctx, curves, axis, stiff)
        batches.append(self)

    def search(ctx, act, cn, turns):
        th0, n = turns.angle[act].copy(), len(batches)
        real_search(ctx, act, cn, turns)
        main = next(b for b in batches[n:] if np.array_equal(b.curves[: len(act)], act))
        searches.append((act.copy(), th0, main, ctx))

    monkeypatch.setattr(rigid, "_search", search)
    monkeypatch.setattr(rigid.RigidBatch, "__init__", init)
    results = {}
    for warm in (True, False):
        s = solver_mod.Solver(offs, cap["settings"].replace(threads=1))  # (no halves)
        s.state = copy.deepcopy(cap["state"])
        s.warm_start = warm
        searches.clear()
        res = real_step(s, *cap["args"])
        results[warm] = (res, list(searches))
        bad = crossing(res.points, offs, ms, res.status)
        assert len(bad) == 0, (warm, bad[:5])
    pw, pf = results[True][0].points, results[False][0].points
    moved = np.zeros(len(offs) - 1)
    np.maximum.at(moved, np.repeat(np.arange(len(offs) - 1), np.diff(offs)), np.abs(pw - pf).max(1))
    differ = np.flatnonzero(moved > 0)
    assert 0 < len(differ) < 50, len(differ)  # (5 on this machine; 0 would be fine too)
    prec = np.deg2rad(cap["settings"].rotation_precision)
    top = np.deg2rad(cap["settings"].max_angle)
    for c in differ:
        act, th0, batch, _ = next(x for x in results[True][1] if c in x[0])
        it = int(np.flatnonzero(act == c)[0])
        k = np.arange(int(np.ceil((top - th0[it]) / prec)) + 1)
        clear = ~batch.hits(np.full(len(k), it), np.minimum(th0[it] + k * prec, top))
        first_clear = int(np.argmax(clear))
        assert clear.any() and not clear[first_clear:].all(), (
            f"curve {c} differs (by {moved[c]:.4f}) though its clearance is monotone: "
            + "".join("o" if x else "x" for x in clear)
        )


# ------------------------------------------------------------------- the grass
def grass_and_fur(n_grass, n_fur, last):
    """The demo's grass (the Grass Trampling preset, Ball) and fur (the demo's fur
    settings, Pusher and Cloth; its range ends 8 frames earlier) setups. Returns
    (demo, [grass output, fur output])."""
    demo = ds.build(fur_count=n_fur, grass_count=n_grass)
    scene = demo.scene
    scene.frame_start, scene.frame_end = 1, last
    for hair, cols, values, end in (
        (demo.grass, [demo.ball], GRASS, last),
        (demo.fur, [demo.pusher, demo.cloth], FUR, last - 8),
    ):
        activate(hair, *cols)
        assert bpy.ops.furcollide.add() == {"FINISHED"}
        for k, v in values.items():
            setattr(hair.furcollide, k, v)
        hair.furcollide.frame_start, hair.furcollide.frame_end = 1, end
    scene.frame_set(1)
    return demo, [demo.grass.furcollide.output, demo.fur.furcollide.output]


def shown(scene, outs, frames, check=None):
    rec = {}
    for f in frames:
        scene.frame_set(f)
        if check is not None:
            check(f)
        rec[f] = [frame_of(o) for o in outs]
    return rec


def same_shots(got, want, what):
    for f in got:
        for k, (a, b) in enumerate(zip(got[f], want[f], strict=True)):
            same(a, b, f"{what}, frame {f}, setup {k}")


@pytest.mark.slow
def test_grass_bake_all_played_back_freed_and_baked_again(fc, tmp_path):
    """README "Bake (disk cache)" on the demo's two setups at the demo's size (2,500
    blades of Grass Trampling under the rolling ball, 40 frames; the fur besides, with a
    shorter range): played with checks (no resolved blade crosses the ball, roots and
    lengths kept); Bake All; the baked frames played and scrubbed are the played frames
    bit for bit, nothing said; Free All Bakes, Plasticity and the fur's Recovery Rate
    changed, Bake All again: the new bake is what playing the shot with the new settings
    gives, bit for bit, and the change shows (the trail is another)."""
    last = 40
    demo, outs = grass_and_fur(2500, 500, last)
    scene, grass = demo.scene, demo.grass
    g = grass.furcollide
    offs, src = offsets_of(grass), positions(grass)

    def check(f):
        assert g.status_message == "" and not g.is_outdated, (f, g.status_message)
        if f % 4:
            return
        st = status_of(g.output)
        bad = crossing(world(g.output), offs, meshes([demo.ball]), st)
        assert len(bad) == 0, (f, bad[:5])
        P = positions(g.output)
        np.testing.assert_array_equal(P[offs[:-1]], src[offs[:-1]])
        np.testing.assert_allclose(
            seg_lengths(P, offs), seg_lengths(src, offs), rtol=2e-4, atol=1e-6
        )

    played = shown(scene, outs, range(1, last + 1), check)
    trail = played[last][0][1]
    assert (trail == 2).sum() > 200, np.bincount(trail)  # trampled blades recovering
    save_in(tmp_path)
    scene.frame_set(1)
    assert bpy.ops.furcollide.bake_all() == {"FINISHED"}
    assert g.is_baked and demo.fur.furcollide.is_baked
    same_shots(shown(scene, outs, range(1, last + 1), check), played, "baked")
    same_shots(shown(scene, outs, [30, 5, last, 17, 1, 29]), played, "baked, scrubbed")
    activate(grass)
    assert bpy.ops.furcollide.free_bake_all() == {"FINISHED"}
    assert not g.is_baked and not demo.fur.furcollide.is_baked
    g.plasticity = 0.3
    demo.fur.furcollide.recovery_rate = 0.5
    scene.frame_set(1)
    assert bpy.ops.furcollide.bake_all() == {"FINISHED"}
    rebaked = shown(scene, outs, range(1, last + 1), check)
    activate(grass)
    assert bpy.ops.furcollide.free_bake_all() == {"FINISHED"}
    scene.frame_set(1)
    same_shots(shown(scene, outs, range(1, last + 1), check), rebaked, "played after")
    assert not np.array_equal(rebaked[last][0][0], played[last][0][0])


# ---------------------------------------------------------------------- Shrink
@pytest.mark.slow
@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
def test_shrink_on_the_demo(fc, mode):
    """README Settings: Shrink (Stiff/Bend) "segments shrink as they rotate", linearly
    from 1 at 0 degrees to Scale Minimum at Scale Angle; "roots never move, lengths are
    exact unless shrinking". The demo's fur (8,000 curves) with Shrink on, Scale Minimum
    0.5 and Scale Angle 20 (so that it bites), frames 1..24 (pusher, cloth, pinch): no
    resolved curve crosses a collider, roots are the source's, every segment keeps
    between 0.5 and 1 of its length, free curves all of it; Stiff shrinks a curve's
    segments alike, Bend less toward the root (its segments turn less there); Soft
    ignores Shrink (lengths exact)."""
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
            bad = crossing(world(out), offs, meshes(cols), st)
            assert len(bad) == 0, (f, bad[:5], st[bad[:5]])
        r = seg_lengths(P, offs).reshape(-1, ns) / L0
        smallest = min(smallest, r.min())
        if mode == "soft":
            np.testing.assert_allclose(r, 1.0, rtol=2e-5, err_msg=f"Soft lengths, {f}")
            return
        assert r.min() >= 0.5 - 2e-5 and r.max() <= 1 + 2e-5, (f, r.min(), r.max())
        np.testing.assert_allclose(r[st == 0], 1.0, rtol=2e-5, err_msg=f"free, {f}")
        if mode == "stiff":
            assert (r.max(1) - r.min(1)).max() < 1e-4, f
        else:
            assert np.diff(r, axis=1).max() < 1e-4, f

    rec = play(demo.scene, hair, out, range(1, 25), check)
    counts = np.bincount(rec[24][1], minlength=7)
    assert counts[1] > 300 and counts[3] > 50, counts
    if mode != "soft":
        assert smallest < 0.5 + 1e-4, smallest  # Scale Minimum reached




def test_motion_blur_of_frame_end_holds_the_baked_render_groom(fc, tmp_path):
    """README "Time": at a subframe a baked setup blends its neighbouring baked frames,
    "from Frame End on it shows Frame End, held as whole frames are"; README "Render
    Groom": a bake made after Bind Groom holds the render groom. So the motion step after
    Frame End shows Frame End's baked render groom, as its guides."""
    last = 14
    demo, guides, out, gout = baked_pipeline(tmp_path, last)
    scene = demo.scene
    scene.frame_set(last)
    end = pipeline_state(guides)
    scene.frame_start = last - 1
    for o in (guides, out, demo.fur, demo.grass):
        o.hide_render = True
    cycles_motion_blur(scene, tmp_path)
    seen = render_recording(guides, lambda dg: pipeline_state(guides))
    steps = [(k, st) for k, st, *_ in seen if k[0] == last and k[1] > 0]
    assert steps, [k for k, *_ in seen]
    for key, st in steps:
        np.testing.assert_array_equal(st[0], end[0], err_msg=f"guides at {key}")
        np.testing.assert_array_equal(st[2], end[2], err_msg=f"render groom at {key}")
