"""QA probes (hunt), Blender side: what an artist or TD sees on the real ``bpy`` wheel.

Colliders made the usual ways (Solidify, objects joined with Ctrl-J), the render groom
(determinism between play, scrub, bake and reopen; the groom's own invariants), the
playback cache's messages and advice.
"""

import bpy
import numpy as np
import oracle  # (tests/core: on the path, conftest imports helpers first)
import pytest
import scenes
from helpers import (
    PINCHED,
    RESOLVED,
    activate,
    groom_scene,
    make_hair,
    offsets_of,
    play,
    positions,
    reopen,
    save_in,
    status_of,
    tris_world,
    world,
)

pytestmark = pytest.mark.blender

INVALID = 6  # core Status.INVALID


def mesh(name, V, F, location=(0.0, 0.0, 0.0)):
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, v)) for v in V], [],
                   [tuple(int(i) for i in f) for f in F])
    me.update()
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    bpy.context.scene.collection.objects.link(ob)
    return ob


def hair_setup(fc, colliders, nx=10, ny=10, spacing=0.06, length=0.3, frames=(1, 3)):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    scene.frame_set(frames[0])
    hair = make_hair(nx=nx, ny=ny, npts=5, length=length, spacing=spacing)
    out = fc.setup(hair, colliders)
    return scene, hair, out


def roots_world(ob):
    return world(ob)[offsets_of(ob)[:-1]]


# ------------------------------------------------------------------ colliders
def test_fur_inside_a_solidified_helmet_is_not_pinched(fc):
    """A helmet made the usual way (a ball with a Solidify modifier) over fur: the fur
    grows inside the cavity, outside the helmet's solid. No root is pinched, nothing
    says the helmet was repaired."""
    V, F = scenes.icosphere((0.0, 0.0, 0.0), 0.6, subdivisions=3)
    helmet = mesh("Helmet", V, F, location=(0.0, 0.0, 0.05))
    sol = helmet.modifiers.new("Solidify", "SOLIDIFY")
    sol.thickness = 0.08
    sol.offset = 1.0  # (outward: the cavity keeps the ball's radius)
    scene, hair, out = hair_setup(fc, [helmet])
    Vw, Fw = tris_world(helmet)
    inside = oracle.points_inside_closed_mesh(roots_world(hair), Vw, Fw)
    assert not inside.any()  # the oracle: every root in the cavity, none in the solid
    msg = hair.furcollide.status_message
    assert (status_of(out) != PINCHED).all(), (np.bincount(status_of(out)), msg)
    assert "turned outward" not in msg, msg


def test_two_joined_crates_touching_still_detect_pinches(fc):
    """Two closed boxes joined into one object (Ctrl-J), side by side, sunk into the
    fur: roots inside either are pinched, and the status does not call the mesh open."""
    # (sides off the roots' grid lines: a root exactly on a face is neither in nor out)
    Va, Fa = scenes.box([-0.3, -0.155, -0.1], [0.0, 0.155, 0.2])
    Vb, Fb = scenes.box([0.0, -0.155, -0.1], [0.3, 0.155, 0.2])
    crates = mesh("Crates", np.concatenate([Va, Vb]), np.concatenate([Fa, Fb + len(Va)]))
    scene, hair, out = hair_setup(fc, [crates], nx=12, ny=12, spacing=0.06)
    Vw, Fw = tris_world(crates)
    inside = oracle.points_inside_closed_mesh(roots_world(hair), Vw, Fw)
    assert inside.sum() >= 10
    msg = hair.furcollide.status_message
    assert "open mesh" not in msg, msg
    np.testing.assert_array_equal(status_of(out) == PINCHED, inside)


# --------------------------------------------------------------- render groom
def _groom_crossing_unmarked(gout, colliders):
    """Render curves crossing a collider (oracle) with a root outside every closed one,
    whose status says resolved."""
    P, offs = world(gout), offsets_of(gout)
    st = status_of(gout)
    bad = np.zeros(len(offs) - 1, bool)
    inside = np.zeros(len(offs) - 1, bool)
    for ob, closed in colliders:
        V, F = tris_world(ob)
        bad |= oracle.segments_hit_mesh(P, offs, V, F, abs_eps=oracle.float32_margin(P, V))
        if closed:
            inside |= oracle.points_inside_closed_mesh(P[offs[:-1]], V, F)
    return np.flatnonzero(bad & ~inside & np.isin(st, RESOLVED))


def _groom_frames(scene, gout, frames):
    rec = {}
    for f in frames:
        scene.frame_set(f)
        rec[f] = (world(gout).copy(), status_of(gout).copy())
    return rec


def _same(rec, scene, gout, frames, what):
    for f in frames:
        scene.frame_set(f)
        np.testing.assert_array_equal(world(gout), rec[f][0], err_msg=f"{what}: frame {f}")
        np.testing.assert_array_equal(status_of(gout), rec[f][1], err_msg=f"{what}: frame {f}")


def test_render_groom_is_the_same_played_scrubbed_baked_and_reopened(fc, tmp_path):
    """The render groom (deform + clearance pass) of each frame is bit for bit the same
    played, scrubbed back and forth, baked, and read from the bake after reopening the
    file; on every frame no resolved render curve crosses the box, no NaN, the groom
    itself never changes."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    groom_before = positions(groom).copy()
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    frames = range(1, 9)
    played = _groom_frames(scene, gout, frames)
    for f in frames:
        scene.frame_set(f)
        assert np.isfinite(world(gout)).all()
        assert len(_groom_crossing_unmarked(gout, [(box, True)])) == 0, f
    assert any((played[f][1] == 1).any() for f in frames)  # the clearance pass worked
    _same(played, scene, gout, (5, 2, 7, 7, 1, 8, 3), "scrubbed")
    path = save_in(tmp_path)
    activate(guides)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    _same(played, scene, gout, frames, "baked")
    bpy.ops.wm.save_mainfile()
    reopen(path)
    guides = bpy.data.objects["Guides"]
    gout = guides.furcollide.groom.output
    _same(played, bpy.context.scene, gout, (4, 8, 1, 6), "reopened")
    assert guides.furcollide.status_message == "", guides.furcollide.status_message
    np.testing.assert_array_equal(positions(bpy.data.objects["Groom"]), groom_before)


def test_reopened_unbaked_render_groom_replays_the_same(fc, tmp_path):
    """Saved mid-playback with a render groom, reopened, played from frame 1 (the
    advice): the groom output is the first session's, bit for bit."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    played = _groom_frames(scene, gout, range(1, 9))
    scene.frame_set(5)
    path = save_in(tmp_path)
    reopen(path)
    scene = bpy.context.scene
    guides = bpy.data.objects["Guides"]
    gout = guides.furcollide.groom.output
    np.testing.assert_array_equal(world(gout), played[5][0])  # what was saved
    scene.frame_set(7)
    msg = guides.furcollide.status_message
    assert "not saved with the file" in msg and "Play from frame 1" in msg, msg
    _same(played, scene, gout, range(1, 9), "replayed")
    assert guides.furcollide.status_message == ""


def test_reopened_held_frame_render_groom_does_not_cross_the_moved_box(fc, tmp_path):
    """README: when the guides' frame fails (an outdated frame), the groom follows the
    last good guides and the clearance pass still runs against this frame's colliders.
    Saved at frame 5, reopened, frame 7 shown (held: the cache is not saved): the box
    has moved on, and no render curve may be left in it while marked resolved."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    play(scene, range(1, 6))
    path = save_in(tmp_path)
    reopen(path)
    guides = bpy.data.objects["Guides"]
    gout = guides.furcollide.groom.output
    bpy.context.scene.frame_set(7)
    assert guides.furcollide.is_outdated
    bad = _groom_crossing_unmarked(gout, [(bpy.data.objects["Box"], True)])
    assert len(bad) == 0, (len(bad), np.bincount(status_of(gout)[bad]))


def test_advice_after_combing_the_groom_of_a_baked_setup_works(fc, tmp_path):
    """The artist combs the Render Groom after baking (the groom object is not greyed).
    The status names what to press; pressing it must work."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    save_in(tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    P = positions(groom).copy()
    P[:, 0] += 0.05 * P[:, 2] ** 2
    groom.data.position_data.foreach_set("vector", P.ravel())
    groom.data.update_tag()
    scene.frame_set(3)
    msg = guides.furcollide.status_message
    assert "was edited since Bind Groom" in msg, msg
    if "Free Bake" not in msg:  # the advice given is Bind Groom alone: follow it
        assert "press Bind Groom again" in msg, msg
        activate(guides)
        assert bpy.ops.furcollide.groom_bind.poll(), "Bind Groom greyed"
        assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}


def test_an_imported_ball_with_a_not_quite_bit_identical_seam_detects_pinches(fc):
    V, F = scenes.uv_sphere([0.1, 0.2, 0.3], 0.5, 32, 16)
    V = (V * 2.0924042).astype(np.float32)
    right = V[F].mean(axis=1)[:, 1] > 0.2 * 2.0924042
    V2 = np.concatenate([V, np.nextafter(V, np.float32(4))])
    F2 = F.copy()
    F2[right] += len(V)
    ball = mesh("Ball", V2, F2, location=(0.0, 0.0, -0.4))
    scene, hair, out = hair_setup(fc, [ball], nx=12, ny=12, spacing=0.1)
    Vw, Fw = tris_world(ball)
    inside = oracle.points_inside_closed_mesh(roots_world(hair), Vw, Fw)
    assert inside.sum() >= 10
    msg = hair.furcollide.status_message
    assert "open mesh" not in msg, msg
    np.testing.assert_array_equal(status_of(out) == PINCHED, inside)
