"""Colliders driven by rigs and simulations: an armature-skinned arm that presses into
the fur and pinches roots, a cloth simulation, shape keys, parents with non-uniform
scale, a Build modifier, animators editing the rig mid-session.

Invariants: no curve whose status says resolved surely crosses a collider (the
independent float64 oracle of ``tests/core``), roots never move, Bend keeps segment
lengths, play, bake and render agree bit for bit."""

import os

import bmesh
import bpy
import numpy as np
import pytest
from helpers import (
    COLLIDING,
    FREE,
    PINCHED,
    UNRESOLVED,
    assert_same_frames,
    bake_files_of,
    bake_setup,
    check_frame,
    fcurves,
    linear,
    make_box,
    make_hair,
    make_surface,
    offsets_of,
    poly,
    positions,
    ragged_groom,
    record,
    render_camera,
    render_spy,
    save_in,
    status_of,
    tris_world,
    world,
)

pytestmark = pytest.mark.blender




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
    linear(rig)
    scene.frame_set(scene.frame_current)
    return rig, arm


def _rig_key(rig, frame):
    """The keyframe point of the bone's X rotation at ``frame``."""
    for fcu in fcurves(rig):
        if fcu.data_path.endswith("rotation_euler") and fcu.array_index == 0:
            for k in fcu.keyframe_points:
                if k.co[0] == frame:
                    return fcu, k
    raise AssertionError("no key")


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
    rt = fc.store.registry.get_runtime(hair)
    seen, builds = np.zeros(6, int), []
    for f in range(1, 9):
        scene.frame_set(f)
        st = check_frame(hair, out, [arm])
        seen += np.bincount(st, minlength=6)
        (entry,) = rt.colliders.entries.values()
        builds.append(entry.collider.build_count)
    assert seen[COLLIDING] > 0 and seen[PINCHED] > 0, seen
    assert hair.furcollide.stat_pinched > 0
    assert entry.deforming and entry.collider.closed
    # Skinned wholly to one bone, the box only moves rigidly: its rest shape's BVH is
    # placed by the fitted motion, never built again once placed (issue 32).
    assert builds[1:] == [builds[1]] * 7 and builds[1] <= 2, builds
    played = record(scene, out, range(1, 9))  # (all cached now)
    save_in(tmp_path)
    bake_setup(hair)
    assert len(bake_files_of(hair)) == 8
    assert_same_frames(played, scene, out, what="baked")
    # the artist's rig, mesh and groom are untouched
    assert [m.type for m in arm.modifiers] == ["ARMATURE"] and arm.modifiers[0].object == rig
    assert len(arm.data.vertices) == n_verts and not arm.data.shape_keys


def test_a_skinned_box_that_really_bends_is_built_each_frame(fc):
    """The same arm with its outer half skinned to a second bone that stays: the box
    bends (no rigid fit of the whole), so it is built again every frame, and every
    frame is collision free where resolved."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    scene.frame_set(1)
    hair = make_hair(nx=6, ny=3)
    rig, arm = _arm_rig([(1, 0.0), (6, -0.6)])
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    b = rig.data.edit_bones.new("Still")
    b.head, b.tail = (-0.3, 0, 0.9), (0.6, 0, 0.9)
    bpy.ops.object.mode_set(mode="OBJECT")
    outer = [v.index for v in arm.data.vertices if v.co.x > -0.3]
    arm.vertex_groups["Upper"].remove(outer)
    arm.vertex_groups.new(name="Still").add(outer, 1.0, "REPLACE")
    out = fc.setup(hair, [arm])
    rt = fc.store.registry.get_runtime(hair)
    builds = []
    for f in range(1, 7):
        scene.frame_set(f)
        check_frame(hair, out, [arm])
        (entry,) = rt.colliders.entries.values()
        builds.append(entry.collider.build_count)
    assert np.all(np.diff(builds[1:]) >= 1), builds


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
    s.pinch_resolution = resolution.upper()
    s.recovery_rate = 1.0
    s.plasticity = 0.0
    s.recover_pinched = True
    pinched_at = {}
    prev = None
    for f in range(1, 13):
        scene.frame_set(f)
        st = check_frame(hair, out, [arm], lengths=resolution == "stop")
        pinched_at[f] = np.flatnonzero(st == PINCHED)
        P = positions(out).copy()
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
        P, offs = positions(out), offsets_of(out)
        tips = P[offs[1:][pinched_at[5]] - 1]
        assert np.abs(tips[:, 2]).max() < 0.05, tips
        scene.frame_set(12)
    # the arm is back where it started: everything recovered, bit for bit
    assert not status_of(out).any()
    np.testing.assert_array_equal(positions(out), positions(hair))
    assert s.status_message == ""


def test_scrub_back_change_a_setting_then_play_on_with_a_skinned_arm(fc):
    """Scrubbing back through cached frames of a deforming collider, then changing a
    setting: the playback cache is dropped (frame 5 is outdated, not stepped from the
    old state), and playing from the start frame as the status says gives exactly what
    a fresh play with the new setting gives (the solver state restore and the rebuilt
    BVH do not depend on history)."""
    def shot():
        scene = bpy.context.scene
        scene.frame_start, scene.frame_end = 1, 9
        scene.frame_set(1)
        hair = make_hair(nx=6, ny=3)
        _rig, arm = _arm_rig([(1, 0.1), (9, -0.7)])
        return scene, hair, fc.setup(hair, [arm])

    scene, hair, out = shot()
    s = hair.furcollide
    record(scene, out, range(1, 10))
    for f in (7, 2, 9, 4):  # scrubbing back and forth over cached frames
        scene.frame_set(f)
    s.recovery_rate = 0.6
    assert len(fc.store.registry.get_runtime(hair).cache.memory) == 0
    scene.frame_set(5)
    assert s.is_outdated and "Play from frame 1" in s.status_message, s.status_message
    rec = record(scene, out, range(1, 10))  # the advice
    assert not s.is_outdated and s.status_message == ""
    assert all((rec[f][1] != FREE).any() for f in range(5, 10))  # the arm is in the fur
    # fresh: a new file, the same shot played once with the new setting
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene, hair, out = shot()
    hair.furcollide.recovery_rate = 0.6
    assert_same_frames(rec, scene, out, what="fresh")


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
    record(scene, out, range(1, 5))
    rest = np.array([v.co[:] for v in arm.data.vertices])
    bpy.data.objects.remove(rig)
    assert arm.modifiers[0].object is None
    for f in range(5, 9):
        scene.frame_set(f)
        check_frame(hair, out, [arm], exact_roots=False)
        assert hair.furcollide.stat_colliding > 0
        np.testing.assert_allclose(tris_world(arm)[0], rest, atol=1e-6)  # rest shape
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
    hair.furcollide.mode = mode.upper()
    scene.frame_set(1)
    counts = np.zeros(6, int)
    played = {}
    for f in range(1, 8):
        scene.frame_set(f)
        st = check_frame(hair, out, [arm])
        counts += np.bincount(st, minlength=6)
        played[f] = (positions(out).copy(), st.copy())
    assert counts[COLLIDING] > 0, counts
    assert np.array_equal(offsets_of(out), offsets_of(hair))
    save_in(tmp_path)
    bake_setup(hair)
    assert_same_frames(played, scene, out, what="baked")


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
    rt = fc.store.registry.get_runtime(hair)
    z = {}
    played = {}
    for f in range(1, 9):
        scene.frame_set(f)
        check_frame(hair, out, [sheet])
        z[f] = tris_world(sheet)[0][:, 2].max()
        played[f] = (positions(out).copy(), status_of(out).copy())
    assert z[8] < 0.8 < z[1], z  # the cloth really fell into the fur
    assert played[8][1].any() and (played[8][1] == COLLIDING).sum() > 3
    (entry,) = rt.colliders.entries.values()
    assert entry.deforming
    save_in(tmp_path)
    bake_setup(hair)
    assert_same_frames(played, scene, out, what="baked")
    # render (Workbench, tiny): every rendered frame is the baked one
    render_camera(scene, px=16)
    scene.frame_set(1)
    seen = render_spy(fc, tmp_path, hair, out, "cloth")
    assert sorted(seen) == list(range(1, 9))
    want = {}
    for f in range(1, 9):
        scene.frame_set(f)
        want[f] = world(out).copy()
    for f, (P, (level, msg), outdated) in seen.items():
        np.testing.assert_array_equal(P, want[f], err_msg=f"render frame {f}")
        assert (level, msg, outdated) == ("INFO", "", False), (f, level, msg)
    assert os.path.exists(tmp_path / "cloth_0008.png")


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
    linear(blob.data.shape_keys)
    scene.frame_set(1)
    out = fc.setup(hair, [blob])
    s = hair.furcollide
    clean = {}
    for f in range(1, 13):
        scene.frame_set(f)
        check_frame(hair, out, [blob])
        clean[f] = (positions(out).copy(), status_of(out).copy())
    assert any((clean[f][1] == COLLIDING).any() for f in clean)
    assert fc.frame.colliders.is_deforming(blob, scene)
    # start over and play a little, then scrub and jump around
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    record(scene, out, range(1, 6))
    for f in (3, 1, 4):
        assert_same_frames(clean, scene, out, [f], "scrubbed")
        assert not s.is_outdated
    scene.frame_set(10)  # past the cache
    assert s.is_outdated
    assert "Frame 10 is not cached" in s.status_message and "holding frame 5" in s.status_message
    np.testing.assert_array_equal(positions(out), clean[5][0])
    scene.frame_set(2)  # back into the cache
    np.testing.assert_array_equal(positions(out), clean[2][0])
    assert_same_frames(clean, scene, out, range(6, 13), "played on")
    assert not s.is_outdated and s.status_message == ""
    scene.frame_set(20)
    np.testing.assert_array_equal(positions(out), clean[12][0])
    assert s.status_message == "After the end frame: holding frame 12" and not s.is_outdated
    assert [k.name for k in blob.data.shape_keys.key_blocks] == ["Basis", "Press"]


@pytest.mark.parametrize("offset", [0.0, 0.06])
def test_collider_parented_to_an_animated_non_uniformly_scaled_empty(fc, offset):
    """A box under an empty whose location and non-uniform scale are animated: a
    rigid collider (no deform flag). Without an offset its BVH is built once; with
    its own offset, resolved curves keep that distance from the scaled box."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    hair = poly(make_hair(nx=6, ny=4))  # (Poly: no spline margin, offset 0 is 0)
    ctrl = bpy.data.objects.new("Ctrl", None)
    scene.collection.objects.link(ctrl)
    box = make_box("Box", size=0.4, location=(0.0, 0.0, 0.6))
    box.parent = ctrl
    for f, x, sc in ((1, -1.4, (1.8, 0.6, 1.0)), (8, 1.4, (1.1, 1.0, 0.8))):
        ctrl.location = (x, 0.0, 0.0)
        ctrl.scale = sc
        ctrl.keyframe_insert("location", frame=f)
        ctrl.keyframe_insert("scale", frame=f)
    linear(ctrl)
    scene.frame_set(1)
    out = fc.setup(hair, [box])
    s = hair.furcollide
    if offset:
        s.colliders[0].use_offset = True
        s.colliders[0].collision_offset = offset
    scene.frame_set(1)
    rt = fc.store.registry.get_runtime(hair)
    hits = 0
    for f in range(1, 9):
        scene.frame_set(f)
        st = check_frame(hair, out, [box])
        hits += int((st == COLLIDING).sum())
        assert not (st == PINCHED).any() and not (st == UNRESOLVED).any(), st
        if offset:
            V, _F = tris_world(box)
            lo, hi = V.min(0), V.max(0)
            P, offs = world(out), offsets_of(out)
            t = np.linspace(0, 1, 9)[:, None, None]
            a = np.delete(P, offs[1:] - 1, axis=0)
            b = np.delete(P, offs[:-1], axis=0)
            pts = (a[None] * (1 - t) + b[None] * t).reshape(-1, 3)
            d = np.linalg.norm(np.maximum(np.maximum(lo - pts, pts - hi), 0.0), axis=1)
            assert d.min() > 0.9 * offset, (f, d.min())
    assert hits > 0
    (entry,) = rt.colliders.entries.values()
    assert not entry.deforming and not fc.frame.colliders.is_deforming(box, scene)
    if not offset:
        assert entry.collider.build_count == 1  # moved and stretched, never rebuilt


def test_collider_with_a_build_modifier_changes_topology_every_frame(fc, tmp_path):
    """A Build modifier adds the faces of a wall frame by frame (0 faces at the
    start): the collider's topology changes on every frame. Nothing raises, the
    invariants hold and the bake equals the play. While it is built the wall is an
    open mesh: the status says it detects no pinch."""
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
    notes = {}
    for f in range(1, 9):
        scene.frame_set(f)
        st = check_frame(hair, out, [wall], status=None)
        notes[f] = hair.furcollide.status_message
        faces[f] = len(tris_world(wall)[1])
        played[f] = (positions(out).copy(), st.copy())
    assert faces[1] == 0 and faces[1] < faces[4] < faces[8], faces
    assert notes[1] == "" and notes[8] == "", notes  # no faces; then closed
    for f in range(2, 8):
        assert notes[f].startswith("Colliders: no pinch detection for 'Wall': open mesh ("), f
    assert (played[8][1] != FREE).any()
    save_in(tmp_path)
    bake_setup(hair)
    assert_same_frames(played, scene, out, what="baked")


@pytest.mark.parametrize("how", ["key", "empty"])
def test_animator_edits_the_rig_mid_session(fc, how):
    """Standing at frame 4, the animator changes what drives the collider after it:
    the rig's key at frame 8 ('key'), or the collider's parent empty's offset key
    ('empty'). Frame 4 still holds, so nothing is dropped at once (the depsgraph
    reports the collider as it does for the animation evaluated again); playing on,
    frames 5..8 no longer match their records and are solved again from frame 4, and
    give what a clean play of the new animation gives (frames 1..4 are unchanged by
    the edit)."""
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
        linear(ctrl)
        rig, colliders = ctrl, [box]
    scene.frame_set(1)
    out = fc.setup(hair, colliders)
    rt = fc.store.registry.get_runtime(hair)
    record(scene, out, range(1, 9))
    scene.frame_set(4)
    if how == "key":
        fcu, k = _rig_key(rig, 8)
        k.co[1] = -0.9
    else:
        fcu = next(c for c in fcurves(rig) if c.data_path == "location" and c.array_index == 0)
        k = next(k for k in fcu.keyframe_points if k.co[0] == 8)
        k.co[0], k.co[1] = 8, 0.2
    k.handle_left[1] = k.handle_right[1] = k.co[1]
    fcu.update()
    bpy.context.view_layer.update()
    assert sorted(rt.cache.memory.frames) == list(range(1, 9)), sorted(rt.cache.memory.frames)
    assert rt.cache.trusted and rt.cache.verified == {4}
    edited = {}
    for f in range(5, 9):
        scene.frame_set(f)
        assert rt.report.stats["source"] == "solved" and not hair.furcollide.is_outdated, f
        edited[f] = (positions(out).copy(), status_of(out).copy())
    scene.frame_set(1)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    clean = record(scene, out, range(1, 9))
    for f in range(5, 9):
        np.testing.assert_array_equal(edited[f][0], clean[f][0], err_msg=f"frame {f}")


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
            st = check_frame(hair, out, [arm], exact_roots=not far, lengths=False)
            counts.append(np.bincount(st, minlength=6))
        assert np.abs(tris_world(arm)[0].min(0) - off).max() < 1.5  # really out there
        assert arm.matrix_world.translation.length == 0.0
        return np.array(counts)

    near, far = run(False), run(True)
    assert near[:, COLLIDING].sum() > 0 and near[:, PINCHED].sum() > 0
    # Float32 resolves about 1 mm 10,000 units away, and every collider keeps a
    # clearance margin of a few float32 ulps of its coordinates (Collider.margin):
    # a curve at the very edge of a contact may be counted on the other side.
    assert np.abs(far - near).max() <= 1, (far, near)
