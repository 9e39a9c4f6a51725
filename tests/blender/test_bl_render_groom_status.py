"""The render groom as the guides' output: ``furcollide_status`` and colours, stats that
count its unresolved and invalid curves, no crossing left unmarked (oracle), curves
it cannot solve set aside at Bind Groom, edits of the groom reported, and a groom that
keeps following the skin while the guides' frame fails (issue 17)."""

from functools import partial

import bpy
import numpy as np
import pytest
from helpers import (
    PIPELINE_FRAMES,
    RESOLVED,
    UNRESOLVED,
    activate,
    crossing_unmarked,
    draw_enabled,
    groom_scene,
    mesh_object,
    move_skin,
    offsets_of,
    pipeline_frame,
    pipeline_scene,
    play,
    play_pipeline,
    positions,
    reopen,
    roots_off_surface,
    same_pipeline_frame,
    save_in,
    seg_lengths,
    status_of,
    world,
)

pytestmark = pytest.mark.blender

INVALID = 6  # core Status.INVALID


def _bound(fc, **kw):
    guides, groom, box, out = groom_scene(fc)
    for k, v in kw.items():
        setattr(guides.furcollide.groom, k, v)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    return guides, groom, box, out, guides.furcollide.groom.output


def _colours(ob):
    a = ob.data.attributes["furcollide_color"]
    assert (a.domain, a.data_type) == ("POINT", "FLOAT_COLOR")
    c = np.empty(len(a.data) * 4, np.float32)
    a.data.foreach_get("color", c)
    return c.reshape(-1, 4)


def test_groom_output_has_status_colours_and_counts(fc):
    scene = bpy.context.scene
    guides, groom, box, out, gout = _bound(fc)
    g = guides.furcollide.groom
    seen_colliding = 0
    for f in range(1, 8):
        scene.frame_set(f)
        st = status_of(gout)
        assert len(st) == len(offsets_of(gout)) - 1
        np.testing.assert_array_equal(
            _colours(gout),
            np.repeat(fc.blender.bridge.STATUS_COLORS[st], np.diff(offsets_of(gout)), 0))
        assert g.stat_unresolved == int((st == UNRESOLVED).sum())
        assert g.stat_invalid == int((st == INVALID).sum()) == 0
        assert g.stat_fixed == guides.furcollide.stat_groom_fixed
        seen_colliding = max(seen_colliding, int((st == 1).sum()))
        assert len(crossing_unmarked(gout, [(box, True)])) == 0, f
    assert seen_colliding > 0
    # the status and colours follow the frame shown (cached frames too)
    scene.frame_set(1)
    assert (status_of(gout) == 0).all() and g.stat_fixed == 0


def test_a_curve_the_clearance_pass_cannot_free_is_unresolved_and_red(fc):
    """A double-sided cage around a few roots: no rotation frees the curves grown in it.
    They are UNRESOLVED (red, counted), never shown as resolved while crossing."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    h = 0.12
    verts = [(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-0.05, 2 * h - 0.05)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4),
             (1, 5, 7, 3)]
    cage = mesh_object("Cage", verts, faces=faces)
    cage.location = (0.45, 0.45, 0.0)
    activate(guides, cage)
    assert bpy.ops.furcollide.collider_add() == {"FINISHED"}
    guides.furcollide.colliders[-1].double_sided = True
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    play(scene, range(1, 5))
    st = status_of(gout)
    caged = np.flatnonzero(st == UNRESOLVED)
    assert len(caged) >= 2
    assert guides.furcollide.groom.stat_unresolved == len(caged)
    red = fc.blender.bridge.STATUS_COLORS[UNRESOLVED]
    offs = offsets_of(gout)
    assert (_colours(gout)[offs[caged[0]]] == red).all()
    assert len(crossing_unmarked(gout, [(box, True), (cage, False)])) == 0


def _groom_with(fc, edit):
    """The groom scene whose Render Groom's curves were edited by ``edit(P, offs)``."""
    guides, groom, box, out = groom_scene(fc)
    P = positions(groom).copy()
    edit(P, offsets_of(groom))
    groom.data.position_data.foreach_set("vector", P.ravel())
    groom.data.update_tag()
    return guides, groom, box, out


def test_bind_groom_sets_bad_curves_aside_and_keeps_updating(fc, capsys):
    """A zero-length segment and a NaN point: Bind Groom names the first, binds the
    others, and every frame shows those two as they are, in yellow (Invalid); the
    rest follows the guides, no NaN is ever written."""
    scene = bpy.context.scene

    def edit(P, offs):
        P[offs[5] + 2] = P[offs[5] + 1]
        P[offs[9] + 3] = np.nan

    guides, groom, box, out = _groom_with(fc, edit)
    capsys.readouterr()
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    said = capsys.readouterr().out
    assert "2 curves of 'Groom' cannot be solved (curve 5 has a zero-length segment" in said
    gout = guides.furcollide.groom.output
    g = guides.furcollide.groom
    first = world(gout).copy()
    moved = set()
    for f in range(1, 8):
        scene.frame_set(f)
        P, st = world(gout), status_of(gout)
        assert np.isfinite(P).all()
        assert np.flatnonzero(st == INVALID).tolist() == [5, 9]
        assert g.stat_invalid == 2
        assert "Render groom: 2 curves of 'Groom' cannot be solved" in \
            guides.furcollide.status_message
        moved |= set(np.flatnonzero(np.abs(P - first).max(1) > 0.01).tolist())
        assert len(crossing_unmarked(gout, [(box, True)])) == 0
    offs = offsets_of(gout)
    yellow = fc.blender.bridge.STATUS_COLORS[INVALID]
    assert (_colours(gout)[offs[5]:offs[6]] == yellow).all()
    assert len(moved) > 10  # the others follow the guides


def test_a_groom_with_only_bad_curves_is_refused(fc):
    guides, groom, box, out = _groom_with(fc, lambda P, offs: P.__setitem__(
        slice(None), np.nan))
    with pytest.raises(RuntimeError, match="No curve of 'Groom' can be used"):
        bpy.ops.furcollide.groom_bind()
    assert guides.furcollide.groom.output is None


@pytest.mark.parametrize("edit", ["comb", "remove", "add", "other_groom"])
def test_editing_the_render_groom_after_bind_is_reported(fc, edit):
    """Issue 17: combing, removing or adding curves, or choosing another groom after Bind
    Groom: the groom output keeps the bound curves and the status says what changed and
    to press Bind Groom again; binding again clears it."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = _bound(fc)
    play(scene, range(1, 4))
    before = world(gout).copy()
    if edit == "comb":
        P = positions(groom).copy()
        P[:, 0] += 0.05 * (P[:, 2] ** 2)
        groom.data.position_data.foreach_set("vector", P.ravel())
        groom.data.update_tag()
        want = "'Groom' was edited since Bind Groom"
    elif edit in ("remove", "add"):
        n = len(groom.data.curves)
        sizes = np.diff(offsets_of(groom))
        keep = n - 40 if edit == "remove" else n + 3
        hc = bpy.data.hair_curves.new("Edited")
        sizes = np.resize(sizes, keep)
        hc.add_curves(sizes.tolist())
        P = np.resize(positions(groom), (int(sizes.sum()), 3))
        hc.position_data.foreach_set("vector", P.ravel())
        hc.surface = groom.data.surface
        groom.data = hc
        want = f"'Groom' now has {keep} curves / {int(sizes.sum())} points but was bound " \
               f"with {n} / {n * 5}"
    else:
        other = fc.make_scene.__globals__["make_hair"]("Other", nx=3, ny=3)
        guides.furcollide.groom.groom = other
        want = "the Render Groom is now 'Other' but 'Groom' is bound: press Bind Groom"
    scene.frame_set(3)
    level, msg = fc.store.report.status_for(guides)
    assert level == "WARNING" and want in msg, msg
    assert "press Bind Groom" in msg and "Render groom: Render groom" not in msg
    np.testing.assert_array_equal(world(gout), before)  # the bound groom, still following
    scene.frame_set(1)
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    scene.frame_set(2)
    assert fc.store.report.status_for(guides) == ("INFO", "")


@pytest.mark.parametrize("edit", ["comb", "none_chosen"])
def test_advice_on_a_baked_setup_works_when_followed(fc, tmp_path, edit):
    """The render groom of a baked setup is combed (or unchosen from a script): Bind
    Groom and the groom's settings are greyed while the bake holds it, so the status
    says Free Bake first; following the advice (Free Bake, then Bind Groom) works and
    clears it."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = _bound(fc)
    save_in(tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    if edit == "comb":
        P = positions(groom).copy()
        P[:, 0] += 0.05 * (P[:, 2] ** 2)
        groom.data.position_data.foreach_set("vector", P.ravel())
        groom.data.update_tag()
    else:
        guides.furcollide.groom.groom = None
    scene.frame_set(3)
    level, msg = fc.store.report.status_for(guides)
    assert level == "WARNING", msg
    if edit == "comb":
        assert "was edited since Bind Groom" in msg, msg
        assert "press Free Bake, then Bind Groom again" in msg, msg
        assert "press Bind Groom again" not in msg.replace("then Bind Groom again", ""), msg
    else:
        assert "Press Free Bake and choose it again" in msg, msg
    activate(guides)
    assert not bpy.ops.furcollide.groom_bind.poll()  # (greyed: the advice says why)
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    if edit == "none_chosen":
        guides.furcollide.groom.groom = groom
    scene.frame_set(1)
    assert bpy.ops.furcollide.groom_bind.poll()
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    scene.frame_set(2)
    assert fc.store.report.status_for(guides) == ("INFO", "")



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

def test_guides_changed_since_bind_are_named_once(fc):
    """The guides' curves changed (and were solved again after Reset): the groom says it
    with one prefix and keeps following the last guides it could use."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = _bound(fc)
    play(scene, range(1, 4))
    hc = bpy.data.hair_curves.new("Fewer")
    hc.add_curves([5] * 24)
    hc.position_data.foreach_set("vector", positions(guides)[:120].ravel())
    hc.surface = guides.data.surface
    guides.data = hc
    scene.frame_set(1)
    activate(guides)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    scene.frame_set(1)
    scene.frame_set(2)
    msg = guides.furcollide.status_message
    assert msg.count("Render groom:") == 1, msg
    assert "the guides now have 120 points but were bound with 125: press Bind Groom again" \
        in msg
    assert np.isfinite(world(gout)).all()


def test_error_state_groom_follows_the_last_guides_on_the_current_skin(fc):
    """Issue 17: the guides' frame fails (their Fur Attach binding no longer matches the
    source) while the skin moves and the box sweeps on: the render groom keeps its roots
    on the skin and the clearance pass keeps it out of the box."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    surf = guides.data.surface
    move_skin(surf, (0.3, 0.0, 0.25), 8)  # (bind at the animated pose of frame 1)
    activate(guides)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    ref = world(groom)
    roff = offsets_of(gout)
    play(scene, range(1, 4))
    hc = bpy.data.hair_curves.new("Fewer")  # the bound source loses a curve
    hc.add_curves([5] * 24)
    hc.position_data.foreach_set("vector", positions(guides)[:120].ravel())
    hc.surface = surf
    guides.data = hc
    for f in range(4, 9):
        scene.frame_set(f)
        level, msg = fc.store.report.status_for(guides)
        assert level == "ERROR" and "press Bind again" in msg, msg
        P = world(gout)
        lift = np.array(surf.matrix_world.translation)
        np.testing.assert_allclose(P[roff[:-1]], ref[roff[:-1]] + lift, atol=1e-5)
        np.testing.assert_allclose(seg_lengths(P, roff), seg_lengths(ref, roff), atol=1e-4)
        assert len(crossing_unmarked(gout, [(box, True)])) == 0, f


def test_reopened_held_frame_groom_follows_the_guides_shown_on_the_current_skin(fc, tmp_path):
    """Saved mid-playback (unbaked), reopened, frames held (the playback cache is not
    saved): the render groom follows the guides as their output shows them, its roots
    on this frame's skin, and the clearance pass runs against this frame's box; the
    frame that was saved is the same as played, bit for bit."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    surf = guides.data.surface
    move_skin(surf, (0.3, 0.0, 0.25), 8)
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    ref, roff = world(groom), offsets_of(gout)
    play(scene, range(1, 6))
    played5 = world(gout).copy()
    path = save_in(tmp_path)
    reopen(path)
    scene = bpy.context.scene
    guides = bpy.data.objects["Guides"]
    surf, box = guides.data.surface, bpy.data.objects["Box"]
    gout = guides.furcollide.groom.output
    guides_shown = world(guides.furcollide.output).copy()
    for f in (7, 8, 3, 5):
        scene.frame_set(f)
        assert guides.furcollide.is_outdated, f
        np.testing.assert_array_equal(world(guides.furcollide.output), guides_shown)
        P = world(gout)
        lift = np.array(surf.matrix_world.translation)
        np.testing.assert_allclose(P[roff[:-1]], ref[roff[:-1]] + lift, atol=1e-5)
        np.testing.assert_allclose(seg_lengths(P, roff), seg_lengths(ref, roff), atol=1e-4)
        assert len(crossing_unmarked(gout, [(box, True)])) == 0, f
        if f == 7:
            assert (status_of(gout) == 1).any()  # the box reached it: cleared this frame
    np.testing.assert_array_equal(world(gout), played5)



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
    bad = crossing_unmarked(gout, [(bpy.data.objects["Box"], True)], unmarked=RESOLVED)
    assert len(bad) == 0, (len(bad), np.bincount(status_of(gout)[bad]))

def test_stage_times_and_skipped_stages(fc, monkeypatch):
    """Per-stage milliseconds are in the setup's stats; the groom is not computed again
    while its inputs (guides, Surface, colliders, settings) are unchanged."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = _bound(fc)
    play(scene, range(1, 5))
    stats = fc.store.report.stats_for(guides)
    for k in ("attach", "collide", "motion", "groom", "clearance", "write"):
        assert f"{k}_ms" in stats
    assert stats["collide_ms"] > 0 and stats["groom_ms"] > 0 and stats["write_ms"] > 0
    # the Last Frame panel shows them, and the render groom's counts
    activate(guides)
    labels = [e[1] for e in draw_enabled(bpy.types.FURCOLLIDE_PT_stats) if e[0] == "label"]
    assert f"Groom: {stats['groom_ms']:.1f}" in labels and "Milliseconds per stage:" in labels
    g = guides.furcollide.groom
    assert f"Render groom: {g.stat_fixed} fixed" in labels
    assert f"Unresolved (red): {g.stat_unresolved}" in labels
    calls = []
    deform = fc.frame.groom.GroomBinding.deform

    def counted(self, *a, **kw):
        calls.append(1)
        return deform(self, *a, **kw)

    monkeypatch.setattr(fc.frame.groom.GroomBinding, "deform", counted)
    shown = world(gout).copy()
    scene.frame_set(4)  # the same frame again
    scene.frame_set(3)  # a cached frame: its guides differ
    scene.frame_set(3)
    assert len(calls) == 1
    assert fc.store.report.stats_for(guides)["groom_ms"] == 0.0  # (skipped this time)
    scene.frame_set(4)
    np.testing.assert_array_equal(world(gout), shown)
    box.scale = (1.1, 1.1, 1.1)  # a collider changed: computed again
    scene.frame_set(4)
    assert len(calls) == 3


def test_collider_distance_computed_once_per_frame(fc, monkeypatch):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 5))
    fc.setup(hair, [box])
    m = hair.furcollide.motion
    m.use_wind, m.wind_strength = True, 0.3
    m.write_collider_distance = True
    m.distance_max = 0.05
    calls = []
    core = fc.core.pipeline.distance  # (the core's frame sequence calls it there)
    real = core.collider_distance

    def counted(*a, **kw):
        calls.append(kw.get("max_distance"))
        return real(*a, **kw)

    monkeypatch.setattr(core, "collider_distance", counted)
    play(scene, range(1, 4))
    assert len(calls) == 3
    assert all(c is None or c >= 0.05 for c in calls)
    a = hair.furcollide.output.data.attributes["furcollide_collider_distance"]
    v = np.empty(len(a.data), np.float32)
    a.data.foreach_get("value", v)
    assert (v <= np.float32(0.05)).all()
    tip = type(m).bl_rna.properties["distance_max"].description
    assert "(0 = no cap)" in tip and "exact" not in tip


def test_a_groom_stage_error_is_prefixed_once(fc):
    """Issue 17 point 7: an error of the groom stage (here its output's curves were
    edited) says "Render groom:" once, and an error raised with the prefix is not
    prefixed again."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = _bound(fc)
    play(scene, range(1, 3))
    hc = bpy.data.hair_curves.new("Edited output")
    hc.add_curves([5] * 3)
    gout.data = hc
    scene.frame_set(3)
    level, msg = fc.store.report.status_for(guides)
    assert level == "WARNING" and msg.startswith(
        "Render groom: The groom output 'Groom FurCollide' has other curves than the bound "
        "groom (edited?): press Bind Groom again"), msg
    assert msg.count("Render groom:") == 1
    said = fc.frame.groom.error_message(ValueError("Render groom: the guides now have 3"))
    assert said == "Render groom: the guides now have 3"


# ---------------------------------------- the render groom's source in a shot
def _set_groom_points(groom, edit):
    P = positions(groom).copy()
    edit(P, offsets_of(groom))
    groom.data.position_data.foreach_set("vector", P.ravel())
    groom.data.update_tag()


def _break_curve_7(bad, P, offs):
    """Render curve 7 made bad in place: a NaN CV, or a zero-length segment."""
    P[offs[7] + 2] = np.nan if bad == "nan" else P[offs[7] + 1]


@pytest.mark.parametrize("bad", ["nan", "zero_length"])
def test_a_bad_curve_in_the_groom_after_bind(fc, bad):
    """One render curve of the groom goes bad after Bind Groom (a NaN, a zero-length
    segment): the status says the groom was edited, the output keeps following the
    guides with the bound curves: no NaN out, every promise held."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = pipeline_scene(fc)
    play_pipeline(guides, groom, box, range(1, 4))

    _set_groom_points(groom, partial(_break_curve_7, bad))
    for f in range(3, 7):
        scene.frame_set(f)
        level, msg = fc.store.report.status_for(guides)
        assert level == "WARNING" and "'Groom' was edited since Bind Groom" in msg, msg
        assert np.isfinite(world(gout)).all()
        # (the bound curves are the reference: the lengths are the bound ones)
        assert len(crossing_unmarked(gout, [box])) == 0, f
        assert len(roots_off_surface(gout, guides.data.surface)) == 0, f


@pytest.mark.parametrize("bad", ["nan", "zero_length"])
def test_a_bad_curve_at_bind_follows_the_skin(fc, bad):
    """A render curve that cannot be solved at Bind Groom is set aside (INVALID, yellow)
    and moves with its Surface triangle: its root stays on the moving skin, no NaN
    out, and the other curves hold every promise."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)

    _set_groom_points(groom, partial(_break_curve_7, bad))
    surf = guides.data.surface
    surf.location = (0, 0, 0)
    surf.keyframe_insert("location", frame=1)
    surf.location = (0.1, 0.0, 0.05)
    surf.keyframe_insert("location", frame=6)
    scene.frame_set(1)
    activate(guides)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = guides.furcollide.groom.output
    for f in PIPELINE_FRAMES:
        scene.frame_set(f)
        st = status_of(gout)
        assert np.flatnonzero(st == INVALID).tolist() == [7], f
        P = world(gout)
        offs = offsets_of(gout)
        good = np.ones(len(P), bool)
        good[offs[7]:offs[8]] = False
        assert np.isfinite(P[good]).all()
        assert len(crossing_unmarked(gout, [box])) == 0, f
        assert len(roots_off_surface(gout, surf)) == 0, f


def _delete_curves_modifier(ob, below):
    """A Geometry Nodes modifier deleting the curves of index < ``below``."""
    ng = bpy.data.node_groups.new("Cull", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gi = ng.nodes.new("NodeGroupInput")
    go = ng.nodes.new("NodeGroupOutput")
    dl = ng.nodes.new("GeometryNodeDeleteGeometry")
    dl.domain = "CURVE"
    idx = ng.nodes.new("GeometryNodeInputIndex")
    cmp = ng.nodes.new("FunctionNodeCompare")
    cmp.data_type, cmp.operation = "INT", "LESS_THAN"
    # (by type: the node's socket list differs across Blender versions; 5.1+ builds it
    # for the data type)
    a, b = [sock for sock in cmp.inputs if sock.type == "INT"][:2]
    ng.links.new(idx.outputs[0], a)
    b.default_value = below
    ng.links.new(cmp.outputs[0], dl.inputs["Selection"])
    ng.links.new(gi.outputs[0], dl.inputs["Geometry"])
    ng.links.new(dl.outputs[0], go.inputs[0])
    mod = ob.modifiers.new("Cull", "NODES")
    mod.node_group = ng
    return mod


def test_groom_with_fewer_curves_than_bound_from_a_modifier(fc):
    """A modifier on the render groom gives fewer curves than when bound (mid-shot):
    the status names the counts and what to press; the output keeps the bound curves,
    following the guides; the modifier off again, nothing is said."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = pipeline_scene(fc)
    first = play_pipeline(guides, groom, box)
    scene.frame_set(3)
    mod = _delete_curves_modifier(groom, 10)
    for f in range(3, 7):
        scene.frame_set(f)
        level, msg = fc.store.report.status_for(guides)
        assert level == "WARNING" and "'Groom' now gives 134 curves" in msg, msg
        assert "press Bind Groom again" in msg
        same_pipeline_frame(pipeline_frame(guides), first[f], f"bound curves shown, frame {f}")
    mod.show_viewport = False
    scene.frame_set(5)
    scene.frame_set(6)
    assert fc.store.report.status_for(guides) == ("INFO", "")
    same_pipeline_frame(pipeline_frame(guides), first[6], "modifier off")


def test_clearance_pass_off_marks_nothing(fc):
    """With the Clearance Pass off, render curves between guides cross the box and
    their status is FREE (grey): nothing marks them (README: Render Groom)."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = pipeline_scene(fc)
    guides.furcollide.groom.use_clearance = False
    crossing = 0
    for f in PIPELINE_FRAMES:
        scene.frame_set(f)
        assert (status_of(gout) == 0).all()
        crossing += len(crossing_unmarked(gout, [box]))
    assert crossing > 0
