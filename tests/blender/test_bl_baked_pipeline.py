"""A baked pipeline setup (Fur Attach, wind, jiggle, Region of Influence, the collider
distance, a render groom) against its bake (issue 17 point 1, issue 11 point 4):
every setting greyed in every panel, a change from Python marks it outdated at once
with a status naming what to press, the frames shown never silently disagree with
the settings, and the render groom is read from the bake (never computed again)."""

import bpy
import numpy as np
import pytest
from helpers import (
    COLLIDER_CHANGES,
    KEEPS_COLLIDING,
    PIPELINE_FRAMES,
    EnabledLayout,
    activate,
    draw_enabled,
    groom_scene,
    move_skin,
    pipeline_frame,
    pipeline_scene,
    play,
    play_pipeline,
    reopen,
    same_pipeline_frame,
    save_in,
    status_of,
    toggle_collider,
    wall_collider,
    world,
)

pytestmark = pytest.mark.blender

FRAMES = range(1, 7)


def _counted(monkeypatch, cls, name):
    """The calls of method ``cls.name`` from now on (a list, one entry per call)."""
    calls = []
    method = getattr(cls, name)
    monkeypatch.setattr(cls, name, lambda self, *a, **k: calls.append(1) or method(self, *a, **k))
    return calls


def _baked_pipeline(fc, tmp_path):
    """The groom scene with Fur Attach on an animated Surface, wind and jiggle after
    collision held by the Region of Influence, the collider distance attribute and a
    render groom, baked over frames 1-6; returns (guides, out, gout, baked frames)."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    surf = guides.data.surface
    move_skin(surf, (0.1, 0.0, 0.05), 6)
    s = guides.furcollide
    s.frame_end = 6
    scene.frame_end = 6
    m = s.motion
    m.use_wind, m.wind_strength = True, 0.2
    m.use_jiggle = True
    m.write_collider_distance, m.distance_max = True, 0.3
    activate(guides)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    gout = s.groom.output
    save_in(tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert s.is_baked and s.groom.is_baked_with
    baked = {}
    for f in FRAMES:
        scene.frame_set(f)
        assert s.status_message == "" and not s.is_outdated, (f, s.status_message)
        baked[f] = (world(out).copy(), world(gout).copy(), status_of(gout).copy())
    return guides, out, gout, baked


def _shows_the_bake(fc, guides, out, gout, baked, frames, outdated):
    s = guides.furcollide
    for f in frames:
        bpy.context.scene.frame_set(f)
        np.testing.assert_array_equal(world(out), baked[f][0], err_msg=f"frame {f}")
        np.testing.assert_array_equal(world(gout), baked[f][1], err_msg=f"frame {f}")
        np.testing.assert_array_equal(status_of(gout), baked[f][2])
        assert s.is_outdated == outdated, (f, s.status_message)
        if outdated:
            assert "baked with other settings (" in s.status_message, s.status_message
            assert "changed): Free Bake and bake again" in s.status_message, s.status_message
        else:
            assert s.status_message == "", s.status_message


CHANGES = [  # (group, property, new value, what the status names)
    ("motion", "wind_strength", 0.5, "Wind Strength"),
    ("motion", "use_wind", False, "Wind"),
    ("motion", "use_jiggle", False, "Jiggle"),
    ("motion", "jiggle_amount", 2.0, "Jiggle Amount"),
    ("motion", "use_region_of_influence", False, "Region of Influence"),
    ("motion", "roi_margin", 0.5, "Region of Influence Margin"),
    ("motion", "distance_max", 0.0, "Max Distance"),
    ("", "use_fur_attach", False, "Fur Attach"),
    ("", "collision_offset", 0.02, "Offset"),  # (its name in the panel)
    ("groom", "use_clearance", False, "Clearance Pass"),
]


@pytest.mark.parametrize("part,name,value,label", CHANGES, ids=[c[1] for c in CHANGES])
def test_a_setting_changed_on_a_baked_setup_marks_it_outdated(fc, tmp_path, part, name,
                                                               value, label):
    """Changed from Python (greyed in the panel): at once outdated, with the status;
    every frame still shows the bake (guides and render groom), marked outdated; set
    back, the setup is current again."""
    guides, out, gout, baked = _baked_pipeline(fc, tmp_path)
    s = guides.furcollide
    data = getattr(s, part) if part else s
    before = getattr(data, name)
    setattr(data, name, value)
    assert s.is_outdated  # at once, before any frame change
    assert s.status_message == (f"This setup was baked with other settings ({label} "
                                "changed): Free Bake and bake again (the frames shown are "
                                "the bake's)")
    _shows_the_bake(fc, guides, out, gout, baked, (3, 6, 1), outdated=True)
    setattr(data, name, before)
    assert not s.is_outdated and s.status_message == ""
    _shows_the_bake(fc, guides, out, gout, baked, (2, 5), outdated=False)


def test_an_outdated_bake_says_so_after_reopening_the_file(fc, tmp_path):
    guides, out, gout, baked = _baked_pipeline(fc, tmp_path)
    guides.furcollide.motion.wind_strength = 0.7
    path = tmp_path / "changed.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    reopen(str(path))
    guides = bpy.data.objects["Guides"]
    out, gout = guides.furcollide.output, guides.furcollide.groom.output
    _shows_the_bake(fc, guides, out, gout, baked, (4, 2), outdated=True)


def test_disabling_a_baked_setup_is_not_a_settings_change(fc, tmp_path):
    guides, out, gout, baked = _baked_pipeline(fc, tmp_path)
    s = guides.furcollide
    s.enabled = False
    assert not s.is_outdated and "other settings" not in s.status_message
    bpy.context.scene.frame_set(3)
    assert s.status_message == "Disabled"
    s.enabled = True
    _shows_the_bake(fc, guides, out, gout, baked, (3,), outdated=False)


class _DataLayout(EnabledLayout):
    """Records (owner type, property, enabled) for every property drawn."""

    def _child(self, *args, **kw):
        return _DataLayout(self.log, self)

    box = row = column = split = _child

    def prop(self, data, name, **kw):
        assert hasattr(data, name), name
        self.log.append((type(data).__name__, name, self._on()))

    def prop_search(self, data, name, *args, **kw):
        self.prop(data, name)


def _pipeline_panel():
    log = []
    bpy.types.FURCOLLIDE_PT_pipeline.draw(
        type("P", (), {"layout": _DataLayout(log)})(), bpy.context)
    return log


def test_every_pipeline_setting_of_a_baked_setup_is_greyed(fc, tmp_path):
    """Fur Attach, Wind & Jiggle, Region of Influence, the collider distance and the
    render groom baked with the setup: greyed. The scene's operator options (Fur
    Sampler, Children from Guides) are not the setup's: they stay editable."""
    guides, out, gout, baked = _baked_pipeline(fc, tmp_path)
    activate(guides)
    log = _pipeline_panel()
    setup_props = [e for e in log if e[0] in ("FurCollideSettings", "FurCollideMotion",
                                              "FurCollideGroom")]
    names = {e[1] for e in setup_props}
    assert {"use_fur_attach", "use_wind", "wind_strength", "use_jiggle",
            "use_region_of_influence", "roi_margin", "write_collider_distance",
            "distance_max", "groom", "guides", "use_clearance"} <= names, names
    assert not [e for e in setup_props if e[2]], [e for e in setup_props if e[2]]
    assert [e for e in log if e[0] == "FURCOLLIDE_PG_pipeline" and e[2]]
    assert ("operator", "furcollide.groom_bind", False) in [
        e for e in draw_enabled(bpy.types.FURCOLLIDE_PT_pipeline) if e[0] == "operator"]
    with pytest.raises(RuntimeError, match="free the bake"):
        bpy.ops.furcollide.groom_bind()
    activate(guides)
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    log = _pipeline_panel()
    assert all(e[2] for e in log if e[0] in ("FurCollideMotion", "FurCollideGroom"))


def test_the_baked_render_groom_is_read_not_computed(fc, tmp_path, monkeypatch):
    """Issue 11: the bake holds the render groom's positions and statuses; a baked
    frame shows them (bit for bit the frame baked) without deforming or clearing the
    groom; freed, the groom is computed again, the same."""
    guides, out, gout, baked = _baked_pipeline(fc, tmp_path)
    calls = _counted(monkeypatch, fc.frame.groom.GroomBinding, "deform")
    _shows_the_bake(fc, guides, out, gout, baked, (5, 1, 3, 6), outdated=False)
    assert calls == []
    assert any((baked[f][2] == 1).any() for f in FRAMES)  # the clearance pass was baked
    stats = fc.store.report.stats_for(guides)
    assert stats["groom_ms"] == 0.0 and stats["clearance_ms"] == 0.0
    activate(guides)
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    # (freed, the current frame is held, not cached: the groom follows the guides shown)
    calls.clear()
    play(bpy.context.scene, FRAMES)
    assert len(calls) == len(FRAMES)
    np.testing.assert_array_equal(world(gout), baked[6][1])


def test_a_baked_frame_shown_reads_its_file_once_and_not_the_state(fc, tmp_path,
                                                                    monkeypatch):
    """Issue 11 point 4: a baked frame is shown as fast as its file reads, so the file
    is opened once (the guides, their attributes, the inputs record and the render
    groom: ``framecache.read_shown``) and the solver state in it (read only to resume
    a bake) is never loaded."""
    guides, out, gout, baked = _baked_pipeline(fc, tmp_path)
    d = bpy.path.abspath(guides.furcollide.bake_path)
    opened, names = [], []
    load, get = np.load, np.lib.npyio.NpzFile.__getitem__
    monkeypatch.setattr(np, "load", lambda *a, **k: opened.append(str(a[0])) or load(*a, **k))
    monkeypatch.setattr(np.lib.npyio.NpzFile, "__getitem__",
                        lambda self, key: names.append(key) or get(self, key))
    for f in (5, 1, 3, 6):
        opened.clear()
        bpy.context.scene.frame_set(f)
        assert opened == [fc.cache.frame_path(d, f)], (f, opened)
        np.testing.assert_array_equal(world(gout), baked[f][1], err_msg=f"frame {f}")
    assert names and not [n for n in names if n.startswith("state__")], names




def test_a_baked_frame_shown_does_not_attach_and_still_sees_the_surface_move(
        fc, tmp_path, monkeypatch):
    """Issue 11 point 4: the bake's inputs record digests Fur Attach's input (the
    Surface's world vertices; the binding is in the settings), so a baked frame is
    checked without moving the curves; the Surface moved after baking still makes the
    frame outdated, the status naming it."""
    guides, out, gout, baked = _baked_pipeline(fc, tmp_path)
    calls = _counted(monkeypatch, fc.frame.attach.Binding, "apply")  # (Fur Attach)
    _shows_the_bake(fc, guides, out, gout, baked, (5, 1, 3, 6), outdated=False)
    assert calls == []
    surf = guides.data.surface
    z = surf.rotation_euler.z
    surf.rotation_euler.z = z + 0.2  # (its location is keyed)
    bpy.context.scene.frame_set(4)
    np.testing.assert_array_equal(world(out), baked[4][0])  # still shown, outdated
    s = guides.furcollide
    assert s.is_outdated, s.status_message
    assert (f"Frame 4 of the bake is outdated: the Surface '{surf.name}' the curves are "
            "attached to (Fur Attach) moved or changed shape since it was baked"
            in s.status_message), s.status_message
    surf.rotation_euler.z = z
    _shows_the_bake(fc, guides, out, gout, baked, (2, 4), outdated=False)
    assert calls == []
    # a vertex no bound triangle uses (away from the roots) cannot move the curves:
    # not a change; one of a bound triangle is
    used = fc.frame.attach.load_binding(guides)[0].used_vertices
    free = np.setdiff1d(np.arange(len(surf.data.vertices)), used)
    assert len(free)
    surf.data.vertices[int(free[0])].co.z += 0.3
    surf.data.update()
    _shows_the_bake(fc, guides, out, gout, baked, (2, 4), outdated=False)
    surf.data.vertices[int(used[0])].co.z += 0.3
    surf.data.update()
    bpy.context.scene.frame_set(5)
    assert s.is_outdated and f"the Surface '{surf.name}'" in s.status_message
    assert calls == []


def _old_style_records(fc, guides, directory, wrong=()):
    """Rewrite the bake's inputs records as FurCollide wrote them before the
    ``attached`` part: ``source``, the digest of the attached points (float32) and the
    offsets, in its place (``wrong``: frames given a wrong digest)."""
    scene = bpy.context.scene
    key = fc.cache._INPUTS_KEY
    for f in FRAMES:
        scene.frame_set(f)
        path = fc.cache.frame_path(directory, f)
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        offs = arrays["offsets"]
        pts = np.asarray(fc.frame.attach.attached_points(
            guides, bpy.context.evaluated_depsgraph_get(), offs), np.float32)
        record = fc.cache.decode_inputs(arrays[key])
        assert "source" not in record
        d = fc.cache.digest(pts, offs) + (1 if f in wrong else 0)
        arrays[key] = fc.cache.encode_inputs(
            {("source" if k == "attached" else k): (d if k == "attached" else v)
             for k, v in record.items()})
        np.savez(path, **arrays)


def test_a_bake_from_before_the_attached_part_is_checked_as_before(fc, tmp_path,
                                                                    monkeypatch):
    """Older bakes' records digest the attached points (``source``): a baked frame of
    one attaches the curves to check it, and is current exactly when they are the
    points baked from (a wrong digest: outdated, naming the source)."""
    guides, out, gout, baked = _baked_pipeline(fc, tmp_path)
    directory = bpy.path.abspath(guides.furcollide.bake_path)
    _old_style_records(fc, guides, directory, wrong=(3,))
    calls = _counted(monkeypatch, fc.frame.attach.Binding, "apply")  # (Fur Attach)
    _shows_the_bake(fc, guides, out, gout, baked, (5, 1, 6), outdated=False)
    assert len(calls) == 3
    bpy.context.scene.frame_set(3)
    np.testing.assert_array_equal(world(out), baked[3][0])
    s = guides.furcollide
    assert s.is_outdated and (f"the source hair '{guides.name}' changed"
                              in s.status_message), s.status_message


# ------------------------------------------- changes after the bake, in a shot
GROOM_CHANGES = [
    ("groom", "use_clearance", False),
    ("", "collision_offset", 0.05),
    ("motion", "wind_strength", 0.6),
    ("groom", "guides", 2),
]


@pytest.mark.parametrize("part,name,value", GROOM_CHANGES, ids=[c[1] for c in GROOM_CHANGES])
def test_baked_with_the_render_groom_then_a_setting_changed(fc, tmp_path, part, name, value):
    """A setting changed after baking with the render groom: outdated at once and on
    every frame (never a stale frame shown as current); set back, the bake again."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = pipeline_scene(fc)
    s = guides.furcollide
    save_in(tmp_path)
    played = play_pipeline(guides, groom, box)
    activate(guides)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert s.groom.is_baked_with
    baked = play_pipeline(guides, groom, box)
    for f in PIPELINE_FRAMES:
        same_pipeline_frame(baked[f], played[f], f"baked vs played frame {f}")
    data = getattr(s, part) if part else s
    before = getattr(data, name)
    setattr(data, name, value)
    for f in (4, 2, 6):
        scene.frame_set(f)
        assert s.is_outdated or name == "guides", (name, f)  # (the bound groom: a note)
        assert s.status_message != "", (name, f)
        assert "baked with other settings" in s.status_message or "Bind Groom" in (
            s.status_message), s.status_message
    setattr(data, name, before)
    for f in PIPELINE_FRAMES:
        scene.frame_set(f)
        assert not s.is_outdated and s.status_message == "", (f, s.status_message)
        same_pipeline_frame(pipeline_frame(guides), baked[f], f"set back, frame {f}")


@pytest.mark.parametrize("kind", COLLIDER_CHANGES)
def test_a_collider_switched_off_on_a_baked_pipeline(fc, tmp_path, kind):
    """Baked with the render groom, then a collider switched off: never a frame shown
    as current that was solved with it (hidden or excluded, it still collides: the
    bake holds); switched on again, the bake."""
    scene = bpy.context.scene
    guides, groom, box, out, gout = pipeline_scene(fc)
    s = guides.furcollide
    wall = wall_collider(guides, 0.02)
    save_in(tmp_path)
    activate(guides)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    baked = play_pipeline(guides, groom, box, colliders=[box, wall])
    scene.frame_set(3)
    toggle_collider(kind, wall, guides, True)
    for f in (3, 4, 6):
        scene.frame_set(f)
        if kind in KEEPS_COLLIDING:
            assert not s.is_outdated and s.status_message == "", (kind, f, s.status_message)
            same_pipeline_frame(pipeline_frame(guides), baked[f], f"{kind}: the bake, {f}")
        else:
            assert s.is_outdated and s.status_message, (kind, f)
    toggle_collider(kind, wall, guides, False)
    for f in PIPELINE_FRAMES:
        scene.frame_set(f)
        assert not s.is_outdated and s.status_message == "", (kind, f, s.status_message)
        same_pipeline_frame(pipeline_frame(guides), baked[f], f"{kind} on again, frame {f}")
