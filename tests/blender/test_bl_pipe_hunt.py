"""Hunt 5: the fur pipeline as an artist and a TD use it (README "The fur pipeline"):
Fur Attach guides on a deforming Surface, wind after collision held by the Region of
Influence, the collider distance attribute and a render groom with its clearance pass,
played frame by frame with settings, colliders, the Surface and the file changed
mid-shot. Every frame is checked against the brute-force oracle (tests/core/oracle.py):
no render curve crossing a collider unless its status says so, roots on the Surface,
lengths kept, and a frame shown twice (scrub, cache, bake) is bit-identical."""

import sys
from pathlib import Path

import bpy
import numpy as np
import pytest
from helpers import (
    UNRESOLVED,
    activate,
    groom_scene,
    offsets_of,
    oracle,
    play,
    positions,
    reopen,
    resolved_crossing,
    save_in,
    seg_lengths,
    status_of,
    tris_world,
    world,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "pipeline"))
import pipe_oracle  # noqa: E402

pytestmark = pytest.mark.blender

INVALID = 6  # core Status.INVALID
FRAMES = range(1, 7)


def pipeline_scene(fc, skin="move"):
    """The groom scene as the README's pipeline: Fur Attach guides on a Surface that
    moves (``skin``: 'move' keyed location, 'shape' a shape key, 'armature' a bone),
    strong wind after collision held by the Region of Influence, the collider distance
    attribute, a render groom bound with its clearance pass. Returns
    (guides, groom, box, out, gout)."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    surf = guides.data.surface
    if skin == "move":
        surf.location = (0, 0, 0)
        surf.keyframe_insert("location", frame=1)
        surf.location = (0.1, 0.0, 0.05)
        surf.keyframe_insert("location", frame=6)
    elif skin == "shape":
        surf.shape_key_add(name="Basis")
        k = surf.shape_key_add(name="Bulge")
        co = np.empty(len(k.data) * 3, np.float32)
        k.data.foreach_get("co", co)
        co = co.reshape(-1, 3)
        co[:, 2] += 0.15 * np.exp(-(co[:, 0] ** 2 + co[:, 1] ** 2))
        k.data.foreach_set("co", co.ravel())
        k.value = 0.0
        k.keyframe_insert("value", frame=1)
        k.value = 1.0
        k.keyframe_insert("value", frame=6)
    elif skin == "armature":
        arm = bpy.data.objects.new("Rig", bpy.data.armatures.new("Rig"))
        scene.collection.objects.link(arm)
        activate(arm)
        bpy.ops.object.mode_set(mode="EDIT")
        b = arm.data.edit_bones.new("Bone")
        b.head, b.tail = (0, 0, 0), (0, 0, 0.5)
        bpy.ops.object.mode_set(mode="OBJECT")
        vg = surf.vertex_groups.new(name="Bone")
        vg.add(list(range(len(surf.data.vertices))), 1.0, "REPLACE")
        mod = surf.modifiers.new("Armature", "ARMATURE")
        mod.object = arm
        pb = arm.pose.bones["Bone"]
        pb.rotation_mode = "XYZ"
        pb.rotation_euler = (0, 0, 0)
        pb.keyframe_insert("rotation_euler", frame=1)
        pb.rotation_euler = (0.15, 0, 0.3)
        pb.keyframe_insert("rotation_euler", frame=6)
    scene.frame_set(1)
    s = guides.furcollide
    m = s.motion
    m.use_wind, m.wind_strength, m.wind_turbulence = True, 0.3, 1.0
    m.write_collider_distance, m.distance_max = True, 0.3
    activate(guides)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    return guides, groom, box, out, s.groom.output


def crossing_unmarked(gout, colliders):
    """Render curves crossing a collider (oracle) whose root is outside every closed
    collider and whose status does not say so (unresolved, invalid)."""
    P, offs = world(gout), offsets_of(gout)
    st = status_of(gout)
    crossing = np.zeros(len(offs) - 1, bool)
    inside = np.zeros(len(offs) - 1, bool)
    for ob in colliders:
        V, F = tris_world(ob)
        crossing |= oracle.segments_hit_mesh(P, offs, V, F, abs_eps=oracle.float32_margin(P, V))
        inside |= oracle.points_inside_closed_mesh(P[offs[:-1]], V, F)
    return np.flatnonzero(crossing & ~inside & ~np.isin(st, (UNRESOLVED, INVALID)))


def roots_off_surface(ob, surf, tol=1e-4):
    """Curves of hair object ``ob`` whose root is farther than ``tol`` from ``surf``'s
    evaluated mesh (world space)."""
    P, offs = world(ob), offsets_of(ob)
    V, F = tris_world(surf)
    d = pipe_oracle.point_mesh_distance(P[offs[:-1]].astype(np.float64), V, F)
    return np.flatnonzero(d > tol)


def check_pipeline_frame(guides, groom, box, colliders=None, what="", guides_clear=True,
                         groom_clear=True):
    """The README's per-frame promises for the whole pipeline. ``guides_clear``: the
    Region of Influence is on (off, wind after collision may push guides into a
    collider); ``groom_clear``: the Clearance Pass is on."""
    s = guides.furcollide
    colliders = [box] if colliders is None else colliders
    out, gout = s.output, s.groom.output
    surf = guides.data.surface
    if s.status_message == "":  # (a held frame says so: the guides are the last result)
        if guides_clear:
            assert len(resolved_crossing(out, colliders)) == 0, what
        assert len(roots_off_surface(out, surf)) == 0, what
    if groom_clear:
        bad = crossing_unmarked(gout, colliders)
        assert len(bad) == 0, (what, bad)
    assert len(roots_off_surface(gout, surf)) == 0, (what, roots_off_surface(gout, surf))
    ok = ~np.isin(status_of(gout), (INVALID,))
    goffs = offsets_of(gout)
    ref = seg_lengths(positions(groom), goffs)
    got = seg_lengths(positions(gout), goffs)
    per_seg_ok = np.repeat(ok, np.diff(goffs) - 1)
    np.testing.assert_allclose(got[per_seg_ok], ref[per_seg_ok], rtol=1e-3, atol=1e-5,
                               err_msg=what)


def frame_state(guides):
    s = guides.furcollide
    return (world(s.output).copy(), status_of(s.output).copy(),
            world(s.groom.output).copy(), status_of(s.groom.output).copy())


def same_state(a, b, what=""):
    for x, y, name in zip(a, b, ("guides", "guide status", "groom", "groom status"),
                          strict=True):
        np.testing.assert_array_equal(x, y, err_msg=f"{what} {name}")


def play_record(guides, groom, box, frames=FRAMES, colliders=None, check=True, **kw):
    scene = bpy.context.scene
    rec = {}
    for f in frames:
        scene.frame_set(f)
        if check:
            check_pipeline_frame(guides, groom, box, colliders, what=f"frame {f}", **kw)
        rec[f] = frame_state(guides)
    return rec


# ------------------------------------------------------------------------ the shot
@pytest.mark.parametrize("skin", ["move", "shape", "armature"])
def test_pipeline_played_scrubbed_and_replayed(fc, skin):
    scene = bpy.context.scene
    guides, groom, box, out, gout = pipeline_scene(fc, skin)
    rec = play_record(guides, groom, box)
    assert guides.furcollide.status_message == "", guides.furcollide.status_message
    for f in (4, 2, 6, 1, 5, 3):
        scene.frame_set(f)
        same_state(frame_state(guides), rec[f], f"scrub {f}")



# ------------------------------------------------------------- settings mid-shot
def _replayed_equal(guides, groom, box, rec_mid, frames, what):
    """Played again from the start frame, the frames equal those shown mid-shot, and a
    fresh play equals scrubbing."""
    scene = bpy.context.scene
    again = play_record(guides, groom, box)
    for f in frames:
        same_state(rec_mid[f], again[f], f"{what}: frame {f} shown mid-shot vs replayed")
    for f in (5, 2, 6, 3):
        scene.frame_set(f)
        same_state(frame_state(guides), again[f], f"{what}: scrub {f}")


CHANGES = [
    ("motion", "wind_strength", 0.6),
    ("motion", "use_region_of_influence", False),
    ("motion", "wind_stage", "INPUT"),
    ("groom", "use_clearance", False),
    ("", "collision_offset", 0.05),
]


@pytest.mark.parametrize("part,name,value", CHANGES, ids=[c[1] for c in CHANGES])
def test_a_setting_changed_mid_shot(fc, part, name, value):
    scene = bpy.context.scene
    guides, groom, box, out, gout = pipeline_scene(fc)
    s = guides.furcollide
    first = play_record(guides, groom, box)
    scene.frame_set(3)
    data = getattr(s, part) if part else s
    before = getattr(data, name)
    setattr(data, name, value)
    kw = {"guides_clear": name != "use_region_of_influence",
          "groom_clear": name != "use_clearance"}
    for f in range(3, 7):  # (held and outdated, as the README says: the groom still holds)
        scene.frame_set(f)
        check_pipeline_frame(guides, groom, box, what=f"{name} held frame {f}", **kw)
    assert s.is_outdated or part == "groom"  # (the groom is computed live from the guides)
    # the advice: play from the start frame; every frame holds, scrub == play
    again = play_record(guides, groom, box, **kw)
    assert s.status_message == "" and not s.is_outdated, s.status_message
    for f in (5, 2, 6, 3):
        scene.frame_set(f)
        same_state(frame_state(guides), again[f], f"{name}: scrub {f}")
    # set back and played again: the first session's frames, bit for bit
    setattr(data, name, before)
    scene.frame_set(1)
    for f in FRAMES:
        scene.frame_set(f)
        same_state(frame_state(guides), first[f], f"{name} set back: frame {f}")


# ------------------------------------------------------------- colliders mid-shot
def _wall(name="Wall"):
    """A thin wall (a closed box) across the render curves between guides only: at
    x = 0.05 (the guides are at multiples of 0.3, the render curves of 0.1 + 0.05)."""
    from helpers import make_box
    w = make_box(name, size=1.0, location=(0.0, 0.0, 0.0))
    w.scale = (0.02, 0.6, 0.6)
    w.location = (0.05, 0.0, 0.7)
    return w


COLLIDER_CHANGES = ["hide_viewport", "hide_set", "exclude", "modifier_off", "disabled"]


def _toggle(kind, ob, guides, off):
    """Switch collider ``ob`` off (``off``) or on again, as an artist does."""
    scene = bpy.context.scene
    if kind == "hide_viewport":
        ob.hide_viewport = off
    elif kind == "hide_set":
        ob.hide_set(off)
    elif kind == "exclude":
        lc = bpy.context.view_layer.layer_collection.children[ob.users_collection[0].name]
        lc.exclude = off
    elif kind == "modifier_off":
        ob.modifiers["Push"].show_viewport = not off
    elif kind == "disabled":
        for c in guides.furcollide.colliders:
            if c.object == ob:
                c.enabled = not off
    scene.frame_set(scene.frame_current)


@pytest.mark.parametrize("kind", COLLIDER_CHANGES)
def test_a_collider_switched_off_and_on_mid_shot(fc, kind):
    """A second collider that the render curves cross (between guides) switched off and
    on mid-shot: every frame shown has no unmarked crossing with the colliders that are
    on, and on again the frames are those of a shot where it never went off."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = pipeline_scene(fc)
    coll = bpy.data.collections.new("Props")
    scene.collection.children.link(coll)
    wall = _wall()
    coll.objects.link(wall)
    scene.collection.objects.unlink(wall)
    mod = wall.modifiers.new("Push", "DISPLACE")
    mod.strength = 0.0 if kind != "modifier_off" else 0.02
    activate(guides, wall)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    both = [box, wall]
    first = play_record(guides, groom, box, colliders=both)
    assert guides.furcollide.stat_groom_fixed > 0 or any(
        (st[3] == 1).any() for st in first.values())
    scene.frame_set(3)
    _toggle(kind, wall, guides, True)
    for f in range(3, 7):
        scene.frame_set(f)
        check_pipeline_frame(guides, groom, box, colliders=[box], what=f"{kind} off, {f}")
    scene.frame_set(4)
    _toggle(kind, wall, guides, False)
    for f in range(4, 7):
        scene.frame_set(f)
        check_pipeline_frame(guides, groom, box, colliders=both, what=f"{kind} on, {f}")
    again = play_record(guides, groom, box, colliders=both)
    for f in FRAMES:
        same_state(again[f], first[f], f"{kind} on again, replayed: frame {f}")
