"""Rigs, simulations and time: a collider skinned by an animated bone (the arm
that presses into the fur, pinching roots), a Cloth-simulated collider played,
baked and rendered, shape-key and parent-animated (non-uniformly scaled)
colliders, hair parented to a moving body, negative frames, frame step, time
remapping, fps changes, a one-frame range, unit scale 0.01, a set far from the
origin, scrubbing back and jumping past the cache, and a ragged groom.

Invariants checked throughout: no output segment of a curve whose status says
resolved (free, colliding, recovering) surely crosses a collider (the
independent float64 oracle of ``tests/core``), roots never move, bend keeps the
segment lengths, the same input gives bit-identical output (play, bake, render,
scrubbing), nothing the artist made is changed, errors are one-line messages."""

import importlib.util
import os
from pathlib import Path

import bmesh
import bpy
import numpy as np
import pytest
from conftest import make_box, make_hair, make_surface, render_camera
from test_bl_flows2 import _render_spy, _status
from test_bl_flows3 import ragged_groom
from test_bl_stages import offsets_of, world

from core import Status

pytestmark = pytest.mark.blender

_spec = importlib.util.spec_from_file_location(
    "fc5_oracle", Path(__file__).resolve().parents[1] / "core" / "oracle.py"
)
oracle = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(oracle)

FREE, COLLIDING, RECOVERING, PINCHED, UNRESOLVED = (
    Status.FREE, Status.COLLIDING, Status.RECOVERING, Status.PINCHED, Status.UNRESOLVED)
RESOLVED = (FREE, COLLIDING, RECOVERING)


# ------------------------------------------------------------------ helpers
def _fcurves(id_):
    """Every F-curve of ``id_``'s action (layered actions of Blender 4.4+ too)."""
    ad = getattr(id_, "animation_data", None)
    act = ad.action if ad else None
    if act is None:
        return []
    if hasattr(act, "fcurves"):
        return list(act.fcurves)
    out = []
    for layer in act.layers:
        for strip in layer.strips:
            for bag in strip.channelbags:
                out.extend(bag.fcurves)
    return out


def _linear(*ids):
    for id_ in ids:
        for fcu in _fcurves(id_):
            for k in fcu.keyframe_points:
                k.interpolation = "LINEAR"


def _mesh_box(name, lo, hi, cuts=0):
    """A closed box mesh from ``lo`` to ``hi`` (object at the origin), its edges
    cut ``cuts`` times (so a skinned box can bend)."""
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=1.0)
    if cuts:
        bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=cuts, use_grid_fill=True)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    for v in bm.verts:
        v.co = (np.array(v.co) + 0.5) * (hi - lo) + lo
    bm.to_mesh(me)
    bm.free()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def _arm_rig(keys, name="Arm", cuts=2, length=1.8):
    """An arm: a closed box skinned (Armature modifier, one vertex group) to the
    bone 'Upper' of the armature 'Rig', whose shoulder is at (-1.2, 0, 0.9); the
    bone's X rotation is keyed (``keys``: (frame, radians); negative lowers the
    arm into the fur)."""
    scene = bpy.context.scene
    arm = _mesh_box(name, (-1.2, -0.15, 0.75), (-1.2 + length, 0.15, 1.05), cuts)
    rig = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
    scene.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    b = rig.data.edit_bones.new("Upper")
    b.head, b.tail = (-1.2, 0, 0.9), (-1.2 + length, 0, 0.9)
    bpy.ops.object.mode_set(mode="OBJECT")
    vg = arm.vertex_groups.new(name="Upper")
    vg.add(list(range(len(arm.data.vertices))), 1.0, "REPLACE")
    arm.modifiers.new("Armature", "ARMATURE").object = rig
    pb = rig.pose.bones["Upper"]
    pb.rotation_mode = "XYZ"
    for f, a in keys:
        pb.rotation_euler = (a, 0.0, 0.0)
        pb.keyframe_insert("rotation_euler", frame=f)
    _linear(rig)
    scene.frame_set(scene.frame_current)
    return rig, arm


def _sweep_box(name="Box", x=(-1.2, 1.2), frames=(1, 8), size=0.5, z=0.6, y=0.0):
    box = make_box(name, size=size, location=(x[0], y, z))
    box.keyframe_insert("location", frame=frames[0])
    box.location = (x[1], y, z)
    box.keyframe_insert("location", frame=frames[1])
    _linear(box)
    return box


def _tris_world(ob, depsgraph=None):
    """World vertices (float64) and triangles of ``ob``'s evaluated mesh."""
    dg = depsgraph or bpy.context.evaluated_depsgraph_get()
    e = ob.evaluated_get(dg)
    me = e.data
    V = np.empty(len(me.vertices) * 3, np.float32)
    me.vertices.foreach_get("co", V)
    me.calc_loop_triangles()
    F = np.empty(len(me.loop_triangles) * 3, np.int32)
    me.loop_triangles.foreach_get("vertices", F)
    return oracle.transform(V.reshape(-1, 3), np.array(e.matrix_world)), F.reshape(-1, 3)


def _crossing(out, colliders, status=None):
    """Curves whose status says resolved but that surely cross a collider."""
    P, offs = world(out), offsets_of(out)
    st = _status(out) if status is None else status
    bad = np.zeros(len(offs) - 1, bool)
    for ob in colliders:
        V, F = _tris_world(ob)
        margin = oracle.float32_margin(P, V)
        bad |= oracle.segments_hit_mesh(P, offs, V, F, abs_eps=margin)
    return np.flatnonzero(bad & np.isin(st, RESOLVED))


def _seg_lengths(P, offs):
    d = np.linalg.norm(np.diff(np.asarray(P, np.float64), axis=0), axis=1)
    keep = np.ones(len(d), bool)
    keep[offs[1:-1] - 1] = False
    return d[keep]


def _check_frame(hair, out, colliders, exact_roots=True, lengths=True):
    """The per-frame invariants; returns the status codes."""
    s = hair.furcollide
    assert s.status_message == "", s.status_message
    offs = offsets_of(out)
    st = _status(out)
    assert len(_crossing(out, colliders, st)) == 0, _crossing(out, colliders, st)
    src, res = oracle.transform(fc_positions(hair), None), fc_positions(out)
    if exact_roots:
        np.testing.assert_array_equal(res[offs[:-1]], fc_positions(hair)[offs[:-1]])
    else:
        np.testing.assert_allclose(world(out)[offs[:-1]], world(hair)[offs[:-1]], atol=2e-5)
    if lengths:
        np.testing.assert_allclose(_seg_lengths(res, offs), _seg_lengths(src, offs),
                                   rtol=2e-4, atol=1e-6)
    return st


def fc_positions(ob):
    d = ob.data
    P = np.empty(len(d.points) * 3, np.float32)
    d.position_data.foreach_get("vector", P)
    return P.reshape(-1, 3)


def _save(tmp_path, name="shot.blend"):
    path = str(tmp_path / name)
    bpy.ops.wm.save_as_mainfile(filepath=path)
    return path


def _bake(hair):
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert hair.furcollide.is_baked


def _files(hair):
    d = bpy.path.abspath(hair.furcollide.bake_path)
    return sorted(f for f in os.listdir(d) if f.startswith("frame_")) if os.path.isdir(d) else []


def _play(scene, out, frames):
    rec = {}
    for f in frames:
        scene.frame_set(f)
        rec[f] = (fc_positions(out).copy(), _status(out).copy())
    return rec


def _assert_same(rec, scene, out, frames=None, what=""):
    for f in frames or sorted(rec):
        scene.frame_set(f)
        np.testing.assert_array_equal(fc_positions(out), rec[f][0], err_msg=f"{what} frame {f}")
        np.testing.assert_array_equal(_status(out), rec[f][1], err_msg=f"{what} frame {f}")


def _render_local_spy(fc, tmp_path, hair, out, tag):
    """Render the animation; {frame: (output local points, status, status message)}
    as the RENDER depsgraph's frame changes left them. (Local: the originals'
    matrix_world is the viewport's, not the rendered frame's.)"""
    scene = bpy.context.scene
    scene.render.filepath = str(tmp_path / f"{tag}_####")
    seen = {}

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            seen[sc.frame_current] = (fc_positions(out).copy(), _status(out).copy(),
                                      fc.registry.status_for(hair))

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    return seen


# ============================================ 1. the arm presses into the fur
def test_armature_arm_presses_into_fur_played_then_baked(fc, tmp_path):
    """A skinned arm swings down through the fur until its tip traps roots: every
    frame is collision free where resolved, roots stay, some roots are pinched; the
    bake equals the played frames bit for bit."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    hair = make_hair(nx=6, ny=3)
    rig, arm = _arm_rig([(1, 0.0), (8, -0.8)])
    n_verts = len(arm.data.vertices)
    out = fc.setup(hair, [arm])
    rt = fc.registry.get_runtime(hair)
    seen = np.zeros(6, int)
    for f in range(1, 9):
        scene.frame_set(f)
        st = _check_frame(hair, out, [arm])
        seen += np.bincount(st, minlength=6)
    assert seen[COLLIDING] > 0 and seen[PINCHED] > 0, seen
    assert hair.furcollide.stat_pinched > 0
    (entry,) = rt.colliders.values()
    assert entry.deforming and entry.collider.closed
    assert entry.collider.build_count > 1  # the skinned arm really deformed
    played = _play(scene, out, range(1, 9))  # (all cached now)
    _save(tmp_path)
    _bake(hair)
    assert len(_files(hair)) == 8
    _assert_same(played, scene, out, what="baked")
    # the artist's rig, mesh and groom are untouched
    assert [m.type for m in arm.modifiers] == ["ARMATURE"] and arm.modifiers[0].object == rig
    assert len(arm.data.vertices) == n_verts and not arm.data.shape_keys


@pytest.mark.parametrize("resolution", ["stop", "growth_surface"])
def test_pinched_roots_recover_when_the_arm_lifts(fc, resolution):
    """The arm presses down onto the roots and lifts again: pinched curves are
    handled (Stop Solving / Put to Growth Surface) and, once free, recover to the
    groom exactly (plasticity 0, recovery rate 1)."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 12
    scene.frame_set(1)
    hair = make_hair(nx=6, ny=3)
    skin = make_surface("Skin", half=1.5, n=4)
    hair.data.surface = skin
    rig, arm = _arm_rig([(1, 0.45), (5, -0.8), (9, 0.45)])  # raised: clear of the tips
    out = fc.setup(hair, [arm])
    s = hair.furcollide
    s.pinch_resolution = resolution
    s.recovery_rate = 1.0
    s.plasticity = 0.0
    s.recover_pinched = True
    pinched_at = {}
    prev = None
    for f in range(1, 13):
        scene.frame_set(f)
        st = _check_frame(hair, out, [arm], lengths=resolution == "stop")
        pinched_at[f] = np.flatnonzero(st == PINCHED)
        P = fc_positions(out).copy()
        if resolution == "stop" and prev is not None:
            # Stop Solving: a pinched curve keeps the local rotation it had (the
            # input is static, so it keeps its shape of the frame before)
            offs = offsets_of(out)
            pts = np.repeat(st == PINCHED, np.diff(offs))
            np.testing.assert_array_equal(P[pts], prev[pts], err_msg=f"frame {f}")
        prev = P
    assert len(pinched_at[5]) > 0 and len(pinched_at[1]) == 0
    if resolution == "growth_surface":
        # laid down: the tips of the pinched curves lie on the skin's plane (z = 0)
        scene.frame_set(5)
        P, offs = fc_positions(out), offsets_of(out)
        tips = P[offs[1:][pinched_at[5]] - 1]
        assert np.abs(tips[:, 2]).max() < 0.05, tips
        scene.frame_set(12)
    # the arm is back where it started: everything recovered, bit for bit
    assert not _status(out).any()
    np.testing.assert_array_equal(fc_positions(out), fc_positions(hair))
    assert s.status_message == ""


def test_scrub_back_change_a_setting_then_play_on_with_a_skinned_arm(fc):
    """Scrubbing back through cached frames of a deforming collider, changing a
    setting and playing on gives exactly what a fresh play of the same sequence
    gives (the solver state restore and the rebuilt BVH do not depend on history)."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 9
    scene.frame_set(1)
    hair = make_hair(nx=6, ny=3)
    _rig, arm = _arm_rig([(1, 0.1), (9, -0.7)])
    out = fc.setup(hair, [arm])
    s = hair.furcollide
    _play(scene, out, range(1, 10))
    for f in (7, 2, 9, 4):  # scrubbing back and forth over cached frames
        scene.frame_set(f)
    s.recovery_rate = 0.6
    assert sorted(fc.registry.get_runtime(hair).memory.frames) == [1, 2, 3, 4]
    rec = _play(scene, out, range(5, 10))
    assert not s.is_outdated and s.status_message == ""
    # fresh: the same sequence from the start frame
    s.recovery_rate = 0.2
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    _play(scene, out, range(1, 5))
    s.recovery_rate = 0.6
    assert all((rec[f][1] != FREE).any() for f in rec)  # the arm is in the fur
    _assert_same(rec, scene, out, what="fresh")


def test_rig_deleted_mid_play_never_raises(fc, capsys):
    """Deleting the armature mid-play leaves the arm at its rest shape: the next
    frames collide with that shape, without an error or a traceback."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    hair = make_hair(nx=6, ny=3)
    hair.location.z = 0.5  # hair from z 0.5 to 1.5: the arm crosses it, raised or not
    rig, arm = _arm_rig([(1, 0.5), (8, 0.0)])
    out = fc.setup(hair, [arm])
    _play(scene, out, range(1, 5))
    rest = np.array([v.co[:] for v in arm.data.vertices])
    bpy.data.objects.remove(rig)
    assert arm.modifiers[0].object is None
    for f in range(5, 9):
        scene.frame_set(f)
        _check_frame(hair, out, [arm], exact_roots=False)
        assert hair.furcollide.stat_colliding > 0
        np.testing.assert_allclose(_tris_world(arm)[0], rest, atol=1e-6)  # rest shape
    cap = capsys.readouterr()
    assert "Traceback" not in cap.out + cap.err


@pytest.mark.parametrize("mode", ["stiff", "soft"])
def test_ragged_groom_with_an_armature_collider(fc, tmp_path, mode):
    """Curves of 2 to 8 points under the pressing arm: invariants per curve, and
    the bake equals the play."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 7
    scene.frame_set(1)
    hair = ragged_groom("Ragged", n=40)
    sizes = np.diff(offsets_of(hair))
    assert sizes.min() == 2 and len(set(sizes.tolist())) > 4
    _rig, arm = _arm_rig([(1, 0.2), (7, -0.75)])
    out = fc.setup(hair, [arm])
    hair.furcollide.mode = mode
    scene.frame_set(1)
    counts = np.zeros(6, int)
    played = {}
    for f in range(1, 8):
        scene.frame_set(f)
        st = _check_frame(hair, out, [arm])
        counts += np.bincount(st, minlength=6)
        played[f] = (fc_positions(out).copy(), st.copy())
    assert counts[COLLIDING] > 0, counts
    assert np.array_equal(offsets_of(out), offsets_of(hair))
    _save(tmp_path)
    _bake(hair)
    _assert_same(played, scene, out, what="baked")


# ======================================================= 2. a cloth collider
def test_cloth_collider_played_from_start_then_baked_then_rendered(fc, tmp_path):
    """A Cloth sheet falls onto the fur (its point cache simulated by playing from
    the start): resolved curves never cross the cloth, the bake equals the play and
    the rendered frames show the baked result."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.gravity = (0.0, 0.0, -40.0)
    scene.frame_set(1)
    hair = make_hair(nx=5, ny=5)
    sheet = make_surface("Cloth", half=0.7, n=6, z=1.15, uv=False)
    cloth = sheet.modifiers.new("Cloth", "CLOTH")
    cloth.point_cache.frame_end = 8
    out = fc.setup(hair, [sheet])
    hair.furcollide.colliders[0].double_sided = True
    rt = fc.registry.get_runtime(hair)
    z = {}
    played = {}
    for f in range(1, 9):
        scene.frame_set(f)
        _check_frame(hair, out, [sheet])
        z[f] = _tris_world(sheet)[0][:, 2].max()
        played[f] = (fc_positions(out).copy(), _status(out).copy())
    assert z[8] < 0.8 < z[1], z  # the cloth really fell into the fur
    assert played[8][1].any() and (played[8][1] == COLLIDING).sum() > 3
    (entry,) = rt.colliders.values()
    assert entry.deforming
    _save(tmp_path)
    _bake(hair)
    _assert_same(played, scene, out, what="baked")
    # render (Workbench, tiny): every rendered frame is the baked one
    render_camera(scene, px=16)
    scene.frame_set(1)
    seen = _render_spy(fc, tmp_path, hair, out, "cloth")
    assert sorted(seen) == list(range(1, 9))
    want = {}
    for f in range(1, 9):
        scene.frame_set(f)
        want[f] = world(out).copy()
    for f, (P, (level, msg), outdated) in seen.items():
        np.testing.assert_array_equal(P, want[f], err_msg=f"render frame {f}")
        assert (level, msg, outdated) == ("INFO", "", False), (f, level, msg)
    assert os.path.exists(tmp_path / "cloth_0008.png")


# ================================ 3. shape keys, parents with non-uniform scale
def test_shape_key_collider_scrub_back_jump_ahead_then_play_on(fc):
    """A shape key pushes a box's bottom down into the fur. Scrubbing back is exact,
    a jump past the cache holds and warns, and playing on from the newest cached
    frame gives exactly the frames of a clean play from the start."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 12
    scene.frame_set(1)
    hair = make_hair(nx=6, ny=6)
    blob = _mesh_box("Blob", (-0.35, -0.35, 1.2), (0.35, 0.35, 1.5), cuts=1)
    blob.shape_key_add(name="Basis")
    press = blob.shape_key_add(name="Press")
    for i, v in enumerate(blob.data.vertices):
        if v.co.z < 1.3:
            press.data[i].co.z = 0.45
    for f, val in ((1, 0.0), (7, 1.0), (12, 0.3)):
        press.value = val
        press.keyframe_insert("value", frame=f)
    _linear(blob.data.shape_keys)
    scene.frame_set(1)
    out = fc.setup(hair, [blob])
    s = hair.furcollide
    clean = {}
    for f in range(1, 13):
        scene.frame_set(f)
        _check_frame(hair, out, [blob])
        clean[f] = (fc_positions(out).copy(), _status(out).copy())
    assert any((clean[f][1] == COLLIDING).any() for f in clean)
    assert fc.colliders.is_deforming(blob, scene)
    # start over and play a little, then scrub and jump around
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    _play(scene, out, range(1, 6))
    for f in (3, 1, 4):
        _assert_same(clean, scene, out, [f], "scrubbed")
        assert not s.is_outdated
    scene.frame_set(10)  # past the cache
    assert s.is_outdated
    assert "Frame 10 is not cached" in s.status_message and "holding frame 5" in s.status_message
    np.testing.assert_array_equal(fc_positions(out), clean[5][0])
    scene.frame_set(2)  # back into the cache
    np.testing.assert_array_equal(fc_positions(out), clean[2][0])
    _assert_same(clean, scene, out, range(6, 13), "played on")
    assert not s.is_outdated and s.status_message == ""
    scene.frame_set(20)
    np.testing.assert_array_equal(fc_positions(out), clean[12][0])
    assert s.status_message == "After the end frame: holding frame 12" and not s.is_outdated
    assert [k.name for k in blob.data.shape_keys.key_blocks] == ["Basis", "Press"]


def test_jump_past_an_uncached_end_frame_holds_the_newest_cached_frame(fc):
    """Cached 1..5 of 1..12, then a jump to frame 20 (after the end): like any jump
    past the cache the newest cached frame (5) is held and the setup is outdated,
    whichever frame was on screen before the jump."""
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 12), nx=5, ny=5)
    out = fc.setup(hair, [box])
    s = hair.furcollide
    rec = _play(scene, out, range(1, 6))
    assert not np.array_equal(rec[5][0], rec[2][0])
    shown = {}
    for before in (2, 5):
        scene.frame_set(before)
        scene.frame_set(20)
        assert s.is_outdated and "not cached" in s.status_message, s.status_message
        shown[before] = fc_positions(out).copy()
    np.testing.assert_array_equal(shown[5], rec[5][0])
    np.testing.assert_array_equal(shown[2], shown[5], err_msg="depends on the frame shown before")


@pytest.mark.parametrize("offset", [0.0, 0.06])
def test_collider_parented_to_an_animated_non_uniformly_scaled_empty(fc, offset):
    """A box under an empty whose location and non-uniform scale are animated: a
    rigid collider (no deform flag). Without an offset its BVH is built once; with
    its own offset, resolved curves keep that distance from the scaled box."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    hair = make_hair(nx=6, ny=4)
    ctrl = bpy.data.objects.new("Ctrl", None)
    scene.collection.objects.link(ctrl)
    box = make_box("Box", size=0.4, location=(0.0, 0.0, 0.6))
    box.parent = ctrl
    for f, x, sc in ((1, -1.4, (1.8, 0.6, 1.0)), (8, 1.4, (1.1, 1.0, 0.8))):
        ctrl.location = (x, 0.0, 0.0)
        ctrl.scale = sc
        ctrl.keyframe_insert("location", frame=f)
        ctrl.keyframe_insert("scale", frame=f)
    _linear(ctrl)
    scene.frame_set(1)
    out = fc.setup(hair, [box])
    s = hair.furcollide
    if offset:
        s.colliders[0].use_offset = True
        s.colliders[0].collision_offset = offset
    scene.frame_set(1)
    rt = fc.registry.get_runtime(hair)
    hits = 0
    for f in range(1, 9):
        scene.frame_set(f)
        st = _check_frame(hair, out, [box])
        hits += int((st == COLLIDING).sum())
        assert not (st == PINCHED).any() and not (st == UNRESOLVED).any(), st
        if offset:
            V, _F = _tris_world(box)
            lo, hi = V.min(0), V.max(0)
            P, offs = world(out), offsets_of(out)
            t = np.linspace(0, 1, 9)[:, None, None]
            a = np.delete(P, offs[1:] - 1, axis=0)
            b = np.delete(P, offs[:-1], axis=0)
            pts = (a[None] * (1 - t) + b[None] * t).reshape(-1, 3)
            d = np.linalg.norm(np.maximum(np.maximum(lo - pts, pts - hi), 0.0), axis=1)
            assert d.min() > 0.9 * offset, (f, d.min())
    assert hits > 0
    (entry,) = rt.colliders.values()
    assert not entry.deforming and not fc.colliders.is_deforming(box, scene)
    if not offset:
        assert entry.collider.build_count == 1  # moved and stretched, never rebuilt


# =============================================== 4. hair on a moving body
@pytest.mark.parametrize("how", ["played", "baked"])
def test_hair_parented_to_a_moving_body_against_a_static_collider(fc, tmp_path, how):
    """The body (and the hair parented to it) moves and turns into a static box:
    the output follows the body, its roots stay on the source's roots, it is
    collision free, and the render (from the memory cache, or from the bake) equals
    the play."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    body = make_surface("Body", half=0.7, n=4)
    for f, x, rz in ((1, -1.0, 0.0), (8, 0.4, 0.6)):
        body.location = (x, 0.0, 0.0)
        body.rotation_euler = (0.0, 0.0, rz)
        body.keyframe_insert("location", frame=f)
        body.keyframe_insert("rotation_euler", frame=f)
    _linear(body)
    hair = make_hair(nx=5, ny=5)
    hair.parent = body
    box = make_box("Post", size=0.4, location=(0.4, 0.0, 0.6))
    scene.frame_set(1)
    out = fc.setup(hair, [box])
    assert out.parent == body
    src_local = fc_positions(hair).copy()
    played = {}
    hits = 0
    for f in range(1, 9):
        scene.frame_set(f)
        np.testing.assert_allclose(np.array(out.matrix_world), np.array(hair.matrix_world))
        st = _check_frame(hair, out, [box], exact_roots=False)
        hits += int((st == COLLIDING).sum())
        # curves the solver left alone are the source's own local positions, exactly
        offs = offsets_of(out)
        free = np.repeat(st == FREE, np.diff(offs))
        untouched = free & (fc_positions(out) == src_local).all(1)
        assert untouched.sum() > 0
        played[f] = (fc_positions(out).copy(), st.copy())
    assert hits > 0
    np.testing.assert_array_equal(fc_positions(hair), src_local)  # the groom is untouched
    if how == "baked":
        _save(tmp_path)
        _bake(hair)
        _assert_same(played, scene, out, what="baked")
    render_camera(scene, px=16)
    scene.frame_set(1)
    seen = _render_local_spy(fc, tmp_path, hair, out, "body")
    assert sorted(seen) == list(range(1, 9))
    for f, (P, st, (level, msg)) in seen.items():
        np.testing.assert_array_equal(P, played[f][0], err_msg=f"render frame {f}")
        np.testing.assert_array_equal(st, played[f][1], err_msg=f"render frame {f}")
        assert (level, msg) == ("INFO", ""), (f, level, msg)


# ========================================================== 5. time
def _preroll_scene(fc):
    """A shot of frames 0..3 whose setup starts at frame -4 (a pre-roll so the fur
    has settled when the shot starts; Blender's scene range cannot go below 0, the
    setup's Frame Start can). The box sweeps from frame -4 to 3."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 0, 3
    hair = make_hair(nx=5, ny=5)
    box = _sweep_box(frames=(-4, 3))
    scene.frame_set(0)
    out = fc.setup(hair, [box])
    s = hair.furcollide
    s.frame_start = -4
    assert (s.frame_start, s.frame_end) == (-4, 3)
    return scene, hair, box, out


def test_negative_start_frame_plays_scrubs_and_holds(fc):
    """A setup starting at frame -4: before it the output is the source, frames
    from -4 on are solved, scrubbing back over negative frames is exact."""
    scene, hair, box, out = _preroll_scene(fc)
    s = hair.furcollide
    scene.frame_set(-6)
    assert s.status_message == "Before the start frame"
    np.testing.assert_array_equal(fc_positions(out), fc_positions(hair))
    rec = {}
    for f in range(-4, 4):
        scene.frame_set(f)
        _check_frame(hair, out, [box])
        rec[f] = (fc_positions(out).copy(), _status(out).copy())
    assert any(rec[f][1].any() for f in rec)
    assert sorted(fc.registry.get_runtime(hair).memory.frames) == list(range(-4, 4))
    _assert_same(rec, scene, out, [0, -3, 2, -4, 3], "scrubbed")
    scene.frame_set(5)
    np.testing.assert_array_equal(fc_positions(out), rec[3][0])
    assert "holding frame 3" in s.status_message


def test_negative_start_frame_bake_and_free(fc, tmp_path):
    """Baking a setup that starts at frame -4 marks it baked, writes one file per
    frame, reads back the played frames, and Free Bake removes every file."""
    scene, hair, _box, out = _preroll_scene(fc)
    played = _play(scene, out, range(-4, 4))
    _save(tmp_path)
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    directory = bpy.path.abspath(hair.furcollide.bake_path)
    assert len(os.listdir(directory)) == 8
    assert hair.furcollide.is_baked, "the bake of frames -4..3 was not marked baked"
    _assert_same(played, scene, out, what="baked")
    bpy.context.view_layer.objects.active = hair
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    assert not os.path.exists(directory), os.listdir(directory)


def test_bake_with_a_frame_step_solves_every_frame(fc, tmp_path):
    """Scene › Frame Step 3 only changes what playback and render show: the bake
    still solves every frame of the range, equal to a play of every frame."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 7
    scene.frame_set(1)
    hair = make_hair(nx=5, ny=5)
    box = _sweep_box(frames=(1, 7))
    scene.frame_set(1)
    out = fc.setup(hair, [box])
    played = _play(scene, out, range(1, 8))
    scene.frame_step = 3
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    _save(tmp_path)
    _bake(hair)
    assert scene.frame_step == 3 and scene.frame_current == 1
    assert _files(hair) == [f"frame_{f:06d}.npz" for f in range(1, 8)]
    _assert_same(played, scene, out, what="baked")


def test_time_remapping_play_bake_and_render_agree(fc, tmp_path):
    """Time remapping (Old 100 -> New 50: the animation runs twice as fast): the
    collider is read at the remapped time, and play, bake and render agree."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    scene.frame_set(1)
    hair = make_hair(nx=5, ny=5)
    box = _sweep_box(frames=(1, 11), x=(-1.2, 1.2))
    scene.render.frame_map_old, scene.render.frame_map_new = 100, 50
    scene.frame_set(1)
    out = fc.setup(hair, [box])
    played = {}
    for f in range(1, 7):
        scene.frame_set(f)
        assert scene.frame_subframe == 0.0
        # the box is where the un-remapped animation has it at frame 2f - 1 ... 2f
        want = min(1.2, -1.2 + 0.24 * (2 * f - 1))  # (keyed at frames 1 and 11)
        assert box.matrix_world.translation.x == pytest.approx(want, abs=1e-5)
        _check_frame(hair, out, [box])
        played[f] = (fc_positions(out).copy(), _status(out).copy())
    assert any(played[f][1].any() for f in played)
    _save(tmp_path)
    _bake(hair)
    _assert_same(played, scene, out, what="baked")
    render_camera(scene, px=16)
    box.hide_render = True
    scene.frame_set(1)
    seen = _render_spy(fc, tmp_path, hair, out, "remap")
    assert sorted(seen) == list(range(1, 7))
    for f, (P, (level, msg), outdated) in seen.items():
        scene.frame_set(f)
        np.testing.assert_array_equal(P, world(out), err_msg=f"render frame {f}")
        assert (level, msg, outdated) == ("INFO", "", False), (f, level, msg)


def test_fps_change_mid_session_keeps_a_plain_setup_exact(fc):
    """Without motion stages nothing depends on the fps: changing it mid-play keeps
    the cache, and playing on equals a clean play."""
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 10), nx=5, ny=5)
    out = fc.setup(hair, [box])
    clean = _play(scene, out, range(1, 11))
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    _play(scene, out, range(1, 5))
    scene.render.fps = 30
    scene.render.fps_base = 1.001
    _assert_same(clean, scene, out, range(5, 11), "after the fps change")
    assert hair.furcollide.status_message == ""


def _wind_setup(fc):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 6), nx=4, ny=4)
    out = fc.setup(hair, [box])
    m = hair.furcollide.motion
    m.use_wind = True
    m.wind_stage = "OUTPUT"
    m.wind_strength = 0.1
    m.wind_frequency = 2.0
    m.wind_turbulence = 1.0
    scene.frame_set(1)
    return scene, hair, out


def test_fps_change_with_wind_replays_like_a_clean_solve(fc):
    """Wind after collision depends on time (frame / fps). After the artist changes
    the fps, playing again from the start frame must show the new wind, the same as
    a clean solve (Reset Cache) or a bake would."""
    scene, hair, out = _wind_setup(fc)
    _play(scene, out, range(1, 7))
    scene.render.fps = 12
    replay = _play(scene, out, range(1, 7))
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    clean = _play(scene, out, range(1, 7))
    assert any(not np.array_equal(clean[f][0], clean[1][0]) for f in clean)
    for f in range(2, 7):
        np.testing.assert_array_equal(replay[f][0], clean[f][0], err_msg=f"frame {f}")


def test_one_frame_range_plays_bakes_and_renders(fc, tmp_path):
    """Frame Start = Frame End = 5: before it the source, at it the solve, after it
    the held frame 5; the bake is one file; a render shows it."""
    scene = bpy.context.scene
    scene.frame_start = scene.frame_end = 5
    scene.frame_set(5)
    hair = make_hair(nx=5, ny=5)
    box = make_box(location=(0.1, 0.0, 0.6))
    out = fc.setup(hair, [box])
    s = hair.furcollide
    assert (s.frame_start, s.frame_end) == (5, 5)
    st = _check_frame(hair, out, [box])
    solved = fc_positions(out).copy()
    assert (st == COLLIDING).sum() > 0
    scene.frame_set(4)
    np.testing.assert_array_equal(fc_positions(out), fc_positions(hair))
    scene.frame_set(9)
    np.testing.assert_array_equal(fc_positions(out), solved)
    assert s.status_message == "After the end frame: holding frame 5" and not s.is_outdated
    _save(tmp_path)
    _bake(hair)
    assert _files(hair) == ["frame_000005.npz"]
    for f, want in ((5, solved), (8, solved), (4, fc_positions(hair))):
        scene.frame_set(f)
        np.testing.assert_array_equal(fc_positions(out), want, err_msg=f"frame {f}")
    render_camera(scene, px=16)
    box.hide_render = True
    scene.frame_set(5)
    seen = _render_spy(fc, tmp_path, hair, out, "one")
    assert sorted(seen) == [5]
    scene.frame_set(5)
    np.testing.assert_array_equal(seen[5][0], world(out))


# ===================================================== 6. units and distance
def _unit_run(fc, scale_length):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = scale_length
    if scale_length != 1.0:
        scene.unit_settings.length_unit = "CENTIMETERS"
    hair, box = fc.make_scene(frames=(1, 8), nx=5, ny=5)
    out = fc.setup(hair, [box])
    hair.furcollide.collision_offset = 0.03
    scene.frame_set(1)
    return _play(scene, out, range(1, 9)), hair


def test_unit_scale_does_not_change_the_result(fc):
    """Scene › Units › Unit Scale 0.01 (a centimetre scene) only changes how values
    are displayed: the solve (with a collision offset) is bit-identical."""
    ref, _hair = _unit_run(fc, 1.0)
    got, hair = _unit_run(fc, 0.01)
    assert bpy.context.scene.unit_settings.scale_length == pytest.approx(0.01)
    assert hair.furcollide.collision_offset == pytest.approx(0.03)
    assert any(ref[f][1].any() for f in ref)
    for f in ref:
        np.testing.assert_array_equal(got[f][0], ref[f][0], err_msg=f"frame {f}")
        np.testing.assert_array_equal(got[f][1], ref[f][1], err_msg=f"frame {f}")


def test_set_far_from_the_origin(fc):
    """Hair and an animated box 10,000 units from the origin (a big set): collisions
    are found and resolved as near the origin, no false pinch, the roots stay on the
    source's roots (2e-5 in world space) and segment lengths within float32 rounding."""
    def run(far):
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        hair, box = fc.make_scene(frames=(1, 8), nx=5, ny=5)
        off = np.array([1e4, -1e4, 0.0]) if far else np.zeros(3)
        hair.location = off
        box.animation_data_clear()
        for f, x in ((1, -1.2), (8, 1.2)):
            box.location = off + (x, 0.0, 0.6)
            box.keyframe_insert("location", frame=f)
        _linear(box)
        scene.frame_set(1)
        out = fc.setup(hair, [box])
        counts = []
        for f in range(1, 9):
            scene.frame_set(f)
            st = _check_frame(hair, out, [box], exact_roots=not far, lengths=False)
            offs = offsets_of(out)
            L0 = _seg_lengths(world(hair), offs)
            np.testing.assert_allclose(_seg_lengths(world(out), offs), L0, atol=4e-3)
            counts.append(np.bincount(st, minlength=6))
        return np.array(counts)

    near, far = run(False), run(True)
    assert far[:, COLLIDING].sum() > 0
    assert far[:, PINCHED].sum() == 0 and far[:, UNRESOLVED].sum() == 0
    # as many curves are touched (colliding or recovering) frame by frame as near the
    # origin; which of the two a curve at the box's trailing edge is may differ
    touched = slice(COLLIDING, RECOVERING + 1)
    np.testing.assert_array_equal(far[:, touched].sum(1), near[:, touched].sum(1))


def test_collider_with_a_build_modifier_changes_topology_every_frame(fc, tmp_path):
    """A Build modifier adds the faces of a wall frame by frame (0 faces at the
    start): the collider's topology changes on every frame. Nothing raises, the
    invariants hold and the bake equals the play."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    hair = make_hair(nx=5, ny=5)
    wall = _mesh_box("Wall", (-0.6, -0.6, 0.45), (0.6, 0.6, 0.6), cuts=3)
    build = wall.modifiers.new("Build", "BUILD")
    build.frame_start, build.frame_duration = 1, 7
    build.use_random_order = True
    scene.frame_set(1)
    out = fc.setup(hair, [wall])
    faces = {}
    played = {}
    for f in range(1, 9):
        scene.frame_set(f)
        st = _check_frame(hair, out, [wall])
        faces[f] = len(_tris_world(wall)[1])
        played[f] = (fc_positions(out).copy(), st.copy())
    assert faces[1] == 0 and faces[1] < faces[4] < faces[8], faces
    assert (played[8][1] != FREE).any()
    _save(tmp_path)
    _bake(hair)
    _assert_same(played, scene, out, what="baked")


def _rig_key(rig, frame):
    """The keyframe point of the bone's X rotation at ``frame``."""
    for fcu in _fcurves(rig):
        if fcu.data_path.endswith("rotation_euler") and fcu.array_index == 0:
            for k in fcu.keyframe_points:
                if k.co[0] == frame:
                    return fcu, k
    raise AssertionError("no key")


@pytest.mark.parametrize("how", ["key", "empty"])
def test_animator_edits_the_rig_mid_session(fc, how):
    """Standing at frame 4, the animator changes what drives the collider after it:
    the rig's key at frame 8 ('key'), or the collider's parent empty's offset key
    ('empty'). The frames after 4 are dropped and playing on gives what a clean play
    of the new animation gives (frames 1..4 are unchanged by the edit)."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    hair = make_hair(nx=6, ny=3)
    if how == "key":
        rig, arm = _arm_rig([(1, 0.3), (4, 0.3), (8, -0.6)])
        colliders = [arm]
    else:
        ctrl = bpy.data.objects.new("Ctrl", None)
        scene.collection.objects.link(ctrl)
        box = make_box("Box", size=0.4, location=(0.0, 0.0, 0.6))
        box.parent = ctrl
        for f, x in ((1, -1.4), (4, -1.4), (8, 0.6)):
            ctrl.location = (x, 0.0, 0.0)
            ctrl.keyframe_insert("location", frame=f)
        _linear(ctrl)
        rig, colliders = ctrl, [box]
    scene.frame_set(1)
    out = fc.setup(hair, colliders)
    rt = fc.registry.get_runtime(hair)
    _play(scene, out, range(1, 9))
    scene.frame_set(4)
    if how == "key":
        fcu, k = _rig_key(rig, 8)
        k.co[1] = -0.9
    else:
        fcu = next(c for c in _fcurves(rig) if c.data_path == "location" and c.array_index == 0)
        k = next(k for k in fcu.keyframe_points if k.co[0] == 8)
        k.co[0], k.co[1] = 8, 0.2
    k.handle_left[1] = k.handle_right[1] = k.co[1]
    fcu.update()
    bpy.context.view_layer.update()
    assert sorted(rt.memory.frames) == [1, 2, 3, 4], sorted(rt.memory.frames)
    edited = _play(scene, out, range(5, 9))
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    clean = _play(scene, out, range(1, 9))
    for f in range(5, 9):
        np.testing.assert_array_equal(edited[f][0], clean[f][0], err_msg=f"frame {f}")


def _add_root(rig):
    """Give the rig a master bone 'Root' (pointing along +Y: its pose location is a
    world offset) parenting 'Upper'."""
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    root = rig.data.edit_bones.new("Root")
    root.head, root.tail = (0, 0, 0), (0, 1, 0)
    rig.data.edit_bones["Upper"].parent = root
    bpy.ops.object.mode_set(mode="OBJECT")
    return rig.pose.bones["Root"]


def test_skinned_arm_placed_far_away_by_its_master_bone(fc):
    """The character (an arm skinned to a rig whose master bone sits 10,000 units
    away; the mesh object stays at the origin, so its deformed vertices are far in
    its own space) presses into hair placed there: the same curves collide and are
    pinched frame by frame as at the origin, and resolved curves never cross."""
    def run(far):
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.frame_start, scene.frame_end = 1, 8
        scene.frame_set(1)
        hair = make_hair(nx=6, ny=3)
        off = np.array([1e4, -1e4, 0.0]) if far else np.zeros(3)
        hair.location = off
        rig, arm = _arm_rig([(1, 0.45), (8, -0.8)])
        _add_root(rig).location = off  # the master control places the character
        scene.frame_set(1)
        out = fc.setup(hair, [arm])
        counts = []
        for f in range(1, 9):
            scene.frame_set(f)
            st = _check_frame(hair, out, [arm], exact_roots=not far, lengths=False)
            counts.append(np.bincount(st, minlength=6))
        assert np.abs(_tris_world(arm)[0].min(0) - off).max() < 1.5  # really out there
        assert arm.matrix_world.translation.length == 0.0
        return np.array(counts)

    near, far = run(False), run(True)
    assert near[:, COLLIDING].sum() > 0 and near[:, PINCHED].sum() > 0
    # Float32 resolves about 1 mm 10,000 units away, and every collider keeps a
    # clearance margin of a few float32 ulps of its coordinates (Collider.margin):
    # a curve at the very edge of a contact may be counted on the other side.
    assert np.abs(far - near).max() <= 1, (far, near)
