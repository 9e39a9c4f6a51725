"""More artist / TD flows: a setting changed on a baked setup, a sub-range bake,
moving a .blend with (and without) its bake, a source whose curve count changes
mid-play, two setups sharing a deforming collider, a Subdivision Surface collider,
a mirrored (negative scale) collider, and an animation render with a frame step."""

import os
import shutil

import bpy
import numpy as np
import pytest
from conftest import activate as _activate
from conftest import bake_crashing_at, make_box, make_hair, render_camera
from test_bl_stages import offsets_of, segments_in_box, world

from core import Status

pytestmark = pytest.mark.blender

PINCHED, UNRESOLVED = Status.PINCHED, Status.UNRESOLVED


# ------------------------------------------------------------------ helpers
def _status(out):
    st = np.zeros(len(out.data.curves), np.int8)
    out.data.attributes["furcollide_status"].data.foreach_get("value", st)
    return st


def _save(tmp_path, name="shot.blend"):
    path = str(tmp_path / name)
    bpy.ops.wm.save_as_mainfile(filepath=path)
    return path


def _reopen(path):
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    bpy.ops.wm.open_mainfile(filepath=path)


class _Layout:
    """Records what a panel draws, with the effective ``enabled`` state of every
    property (panels cannot be drawn headless)."""

    def __init__(self, log, parent=None):
        self.log = log
        self.parent = parent
        self.enabled = True
        self.active = True
        self.alert = False
        self.use_property_split = self.use_property_decorate = None

    def _on(self):
        return self.enabled and (self.parent is None or self.parent._on())

    def _child(self, *args, **kw):
        return _Layout(self.log, self)

    box = row = column = _child

    def prop(self, data, name, **kw):
        assert hasattr(data, name), name
        self.log.append(("prop", name, self._on()))

    def operator(self, idname, **kw):
        self.log.append(("operator", idname, self._on()))
        return type("Props", (), {})()

    def label(self, **kw):
        self.log.append(("label", kw.get("text"), self._on()))

    def separator(self, **kw):
        pass


def _draw(panel):
    log = []
    fake = type("P", (), {"layout": _Layout(log), "prepare": getattr(panel, "prepare", None),
                          "settings": getattr(panel, "settings", None)})()
    panel.draw(fake, bpy.context)
    return log


def _small_scene(fc, frames=(1, 8), nx=4, ny=4):
    hair, box = fc.make_scene(frames=frames, nx=nx, ny=ny)
    out = fc.setup(hair, [box])
    return hair, box, out


# ------------------------- 1. a setting changed on a baked setup, free, re-bake
def test_setting_change_on_a_bake_then_free_and_bake_again(fc, tmp_path):
    scene = bpy.context.scene
    hair, box, out = _small_scene(fc)
    s = hair.furcollide
    _save(tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(s.bake_path)
    old = {f: fc.cache.read_frame(d, f)[0] for f in range(1, 9)}

    # README: "A baked setup only reads. Its settings are greyed out until Free Bake."
    _activate(hair)
    log = _draw(bpy.types.FURCOLLIDE_PT_resolution)
    assert ("prop", "mode", False) in log and ("prop", "rotation_precision", False) in log
    s.mode = "stiff"  # a script can still change it
    s.rotation_precision = 2.0
    # the bake still shows its own frames, bit for bit, never a re-solve, but
    # marked outdated: they were baked with other settings (issue 14)
    for f in (3, 8, 1, 5, 6):
        scene.frame_set(f)
        np.testing.assert_array_equal(fc.positions(out), old[f], err_msg=f"frame {f}")
        assert s.stat_frame == f and s.is_outdated
        assert "settings" in s.status_message and "Free Bake" in s.status_message
    assert ("label", "Outdated bake: Free Bake, then Bake", True) in _draw(
        bpy.types.FURCOLLIDE_PT_cache)
    with pytest.raises(RuntimeError, match="Free Bake first"):
        bpy.ops.furcollide.bake()

    # Free Bake at frame 5: nothing new is solved there yet. Whatever the output
    # shows while the new result is unknown is flagged outdated (never silently old).
    scene.frame_set(5)
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    log = _draw(bpy.types.FURCOLLIDE_PT_resolution)
    assert ("prop", "mode", True) in log  # editable again
    for f in (6, 7):
        scene.frame_set(f)
        assert s.is_outdated and fc.registry.status_for(hair)[0] == "WARNING"
        assert "not cached" in s.status_message
    assert ("label", "Outdated: play from the start frame or bake", True) in _draw(
        bpy.types.FURCOLLIDE_PT_cache)

    # play from the start: the new settings' result
    live = {}
    for f in range(1, 9):
        scene.frame_set(f)
        assert s.status_message == "" and not s.is_outdated, (f, s.status_message)
        live[f] = fc.positions(out).copy()
    assert any(not np.array_equal(live[f], old[f]) for f in live), "the change changed nothing"

    # bake again: the files and the playback are the new result on every frame
    scene.frame_set(3)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert fc.cache.list_frames(d) == list(range(1, 9))
    for f in range(1, 9):
        np.testing.assert_array_equal(fc.cache.read_frame(d, f)[0], live[f], err_msg=f"{f}")
    for f in (8, 2, 5, 1, 7):
        scene.frame_set(f)
        np.testing.assert_array_equal(fc.positions(out), live[f], err_msg=f"frame {f}")
        assert s.status_message == ""


def test_interrupted_bake_does_not_resume_over_an_edited_collider(fc, tmp_path, monkeypatch):
    """README: the next Bake resumes after the last frame whose files match the
    current settings and colliders; editing a collider invalidates."""
    hair, box, out = _small_scene(fc)
    _save(tmp_path)
    bake_crashing_at(fc, monkeypatch, 5)
    d = fc.bake.bake_directory(hair)
    assert fc.cache.list_frames(d) == [1, 2, 3, 4]
    for v in box.data.vertices:  # the artist makes the collider bigger
        v.co *= 1.5
    box.data.update()
    bpy.context.view_layer.update()
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    resumed = {f: fc.cache.read_frame(d, f)[0] for f in range(1, 9)}
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    assert bpy.ops.furcollide.bake() == {"FINISHED"}  # a clean bake of the edited scene
    for f in range(1, 9):
        np.testing.assert_array_equal(resumed[f], fc.cache.read_frame(d, f)[0],
                                      err_msg=f"frame {f}")


# -------------------------------------------------------- 2. a sub-range bake
def test_sub_range_bake_before_inside_after(fc, tmp_path):
    scene = bpy.context.scene
    hair, box, out = _small_scene(fc, frames=(1, 10))
    s = hair.furcollide
    s.frame_start, s.frame_end = 4, 7
    source = fc.positions(hair).copy()
    # live play over the whole scene: frame 4 solves from the groomed shape
    live = {}
    for f in range(1, 11):
        scene.frame_set(f)
        live[f] = fc.positions(out).copy()
        assert fc.registry.status_for(hair)[0] == "INFO", (f, s.status_message)
        assert not s.is_outdated, f
    for f in (1, 2, 3):
        np.testing.assert_array_equal(live[f], source, err_msg=f"frame {f}")
    for f in (8, 9, 10):  # README: after Frame End, Frame End is held
        np.testing.assert_array_equal(live[f], live[7], err_msg=f"frame {f}")
    assert any(not np.array_equal(live[f], source) for f in range(4, 8))
    _save(tmp_path)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(s.bake_path)
    assert fc.cache.list_frames(d) == [4, 5, 6, 7]
    baked = {f: fc.cache.read_frame(d, f)[0] for f in range(4, 8)}
    for f in range(4, 8):
        np.testing.assert_array_equal(baked[f], live[f], err_msg=f"frame {f}")
    for f in (1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 9, 2, 6, 10, 4, 3):
        scene.frame_set(f)
        P = fc.positions(out)
        level, msg = fc.registry.status_for(hair)
        assert level == "INFO", (f, msg)
        if f < 4:  # README: before Frame Start the output follows the source
            np.testing.assert_array_equal(P, source, err_msg=f"frame {f}")
            assert not np.any(_status(out)), f
        elif f <= 7:  # baked frames, bit for bit
            np.testing.assert_array_equal(P, baked[f], err_msg=f"frame {f}")
            assert s.stat_frame == f
        else:  # README: after Frame End, Frame End is held
            np.testing.assert_array_equal(P, baked[7], err_msg=f"frame {f}")
            assert s.stat_frame == 7 and msg == ""
        assert not s.is_outdated


# ------------------------------------------- 3. moving the .blend and its bake
def test_moved_blend_with_its_bake_and_without(fc, tmp_path, capsys):
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    a.mkdir()
    c.mkdir()
    hair, box, out = _small_scene(fc, frames=(1, 6))
    path = _save(a)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    s = hair.furcollide
    assert s.bake_path.startswith("//")  # relative: it moves with the file
    d = bpy.path.abspath(s.bake_path)
    baked = {f: fc.cache.read_frame(d, f)[0] for f in range(1, 7)}
    bpy.context.scene.frame_set(1)
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    shutil.move(str(a), str(b))  # the .blend and furcollide_cache/ together
    _reopen(str(b / os.path.basename(path)))
    hair = bpy.data.objects["Fur"]
    out, s = hair.furcollide.output, hair.furcollide
    assert s.is_baked
    for f in (4, 1, 6, 2, 5, 3):
        bpy.context.scene.frame_set(f)
        np.testing.assert_array_equal(fc.positions(out), baked[f], err_msg=f"frame {f}")
        assert s.status_message == ""

    # now only the .blend moves: the bake is left behind in b/
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    shutil.move(str(b / "shot.blend"), str(c / "shot.blend"))
    capsys.readouterr()
    _reopen(str(c / "shot.blend"))
    hair = bpy.data.objects["Fur"]
    s = hair.furcollide
    for f in (3, 4):
        bpy.context.scene.frame_set(f)
        level, msg = fc.registry.status_for(hair)
        assert level == "ERROR" and "missing" in msg, msg
        assert str(c / "furcollide_cache") in msg  # where they were looked for
        assert s.is_outdated
    err = capsys.readouterr()
    assert "Traceback" not in err.err + err.out
    _activate(hair)
    labels = [e[1] for e in _draw(bpy.types.FURCOLLIDE_PT_cache) if e[0] == "label"]
    assert "0 of 6 frames baked" in labels
    # Free Bake (nothing left to delete here) and play: the same frames, solved again
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    out = s.output
    for f in range(1, 7):
        bpy.context.scene.frame_set(f)
        assert s.status_message == "", (f, s.status_message)
        np.testing.assert_array_equal(fc.positions(out), baked[f], err_msg=f"frame {f}")
    assert os.path.isdir(b / "furcollide_cache")  # the other copy's bake is untouched


# ------------------------------------- 4. the source's curve count changes mid-play
def test_source_data_swapped_for_more_curves_mid_play(fc, capsys):
    scene = bpy.context.scene
    hair, box, out = _small_scene(fc, frames=(1, 8))
    for f in range(1, 5):
        scene.frame_set(f)
    shown = fc.positions(out).copy()
    more = make_hair(name="More", nx=5, ny=5)
    data = more.data
    bpy.data.objects.remove(more)
    hair.data = data  # a new hair data block with 25 curves instead of 16
    for f in (5, 6, 2):
        scene.frame_set(f)
        level, msg = fc.registry.status_for(hair)
        assert level == "ERROR" and "16" in msg and "25" in msg and "Reset" in msg, msg
        np.testing.assert_array_equal(fc.positions(out), shown)  # keeps its last result
        assert len(out.data.curves) == 16
    assert "Traceback" not in capsys.readouterr().err
    scene.frame_set(4)
    _activate(hair)
    assert bpy.ops.furcollide.reset() == {"FINISHED"}  # "Reset Cache"
    assert len(out.data.curves) == 25
    rec = {}
    hits = 0
    for f in range(1, 9):
        scene.frame_set(f)
        assert hair.furcollide.status_message == "", (f, hair.furcollide.status_message)
        assert len(out.data.curves) == 25
        rec[f] = fc.positions(out).copy()
        hits += hair.furcollide.stat_colliding
    assert hits > 0
    # and the same as a fresh play of the new curves
    assert bpy.ops.furcollide.reset() == {"FINISHED"}
    for f in range(1, 9):
        scene.frame_set(f)
        np.testing.assert_array_equal(fc.positions(out), rec[f], err_msg=f"frame {f}")


# -------------------------- 5. two setups sharing one (deforming) collider
def _growing_box(frames=(1, 6)):
    """A box of edge 0.3 at (0, 0, 0.6) whose animated shape key doubles it."""
    box = make_box("Blob", size=0.3, location=(0, 0, 0.6))
    box.shape_key_add(name="Basis")
    grow = box.shape_key_add(name="Grow")
    for i, v in enumerate(box.data.vertices):
        grow.data[i].co = v.co * 2.0
    grow.value = 0.0
    grow.keyframe_insert("value", frame=frames[0])
    grow.value = 1.0
    grow.keyframe_insert("value", frame=frames[1])
    return box


def _world_bounds(ob):
    dg = bpy.context.evaluated_depsgraph_get()
    e = ob.evaluated_get(dg)
    V = np.array([v.co[:] for v in e.data.vertices], np.float64)
    M = np.array(e.matrix_world)
    W = V @ M[:3, :3].T + M[:3, 3]
    return W.min(0), W.max(0)


def _free_curves_in_box(out, lo, hi):
    P, offs = world(out), offsets_of(out)
    bad = segments_in_box(P, offs, (lo + hi) / 2, (hi - lo) / 2)
    free = np.flatnonzero(~np.isin(_status(out), (PINCHED, UNRESOLVED)))
    return np.intersect1d(bad, free)


def test_two_setups_share_a_deforming_collider(fc):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    scene.frame_set(1)
    hair_a = make_hair("FurA", nx=4, ny=4)
    hair_b = make_hair("FurB", nx=3, ny=3, spacing=0.25)
    blob = _growing_box()
    scene.frame_set(1)  # the key's value at frame 1 (0), not the value keyed last
    wall = make_box("Wall", size=0.5, location=(0.0, 0.45, 0.6))  # rigid, B only
    out_a = fc.setup(hair_a, [blob])
    out_b = fc.setup(hair_b, [blob, wall])
    rt_a, rt_b = fc.registry.get_runtime(hair_a), fc.registry.get_runtime(hair_b)
    contact = {hair_a.name: 0, hair_b.name: 0}
    alone = {}
    for f in range(1, 7):
        scene.frame_set(f)
        lo, hi = _world_bounds(blob)
        for hair, out in ((hair_a, out_a), (hair_b, out_b)):
            s = hair.furcollide
            assert s.status_message == "", (hair.name, f, s.status_message)
            assert len(_free_curves_in_box(out, lo, hi)) == 0, (hair.name, f)
            contact[hair.name] += s.stat_colliding
        wl, wh = _world_bounds(wall)
        assert len(_free_curves_in_box(out_b, wl, wh)) == 0, f
        alone[f] = fc.positions(out_a).copy()
    assert all(contact.values()), contact
    assert hi[0] - lo[0] == pytest.approx(0.6, abs=1e-5)  # the key really animated
    flags_a = {e.collider.name: e.collider.deforming for e in rt_a.colliders.values()}
    flags_b = {e.collider.name: e.collider.deforming for e in rt_b.colliders.values()}
    assert flags_a == {"Blob": True} and flags_b == {"Blob": True, "Wall": False}
    assert fc.colliders.is_deforming(blob, scene) and not fc.colliders.is_deforming(wall, scene)
    # each setup owns its core collider; A's result does not depend on B
    assert rt_a.colliders[blob.session_uid].collider is not \
        rt_b.colliders[blob.session_uid].collider
    hair_b.furcollide.enabled = False
    _activate(hair_a)
    scene.frame_set(1)
    bpy.ops.furcollide.reset()
    for f in range(1, 7):
        scene.frame_set(f)
        np.testing.assert_array_equal(fc.positions(out_a), alone[f], err_msg=f"frame {f}")


# -------------------------------------- 6. a Subdivision Surface collider
def _densify(P, offs, n=16):
    """n points along every segment of the curves, and their curve index."""
    t = np.linspace(0, 1, n)[:, None, None]
    sizes = np.diff(offs)
    curve = np.repeat(np.arange(len(sizes)), sizes - 1)
    s0 = np.arange(len(curve)) + curve
    pts = P[s0][None] * (1 - t) + P[s0 + 1][None] * t  # (n, segments, 3)
    return pts.reshape(-1, 3), np.tile(curve, n)


def _curves_inside_convex(out, ob, eps=1e-4):
    """Curves of ``out`` with a point strictly inside the convex evaluated mesh of
    ``ob`` (translated only)."""
    dg = bpy.context.evaluated_depsgraph_get()
    me = ob.evaluated_get(dg).data
    t = np.array(ob.matrix_world.translation)
    C = np.array([p.center[:] for p in me.polygons]) + t
    N = np.array([p.normal[:] for p in me.polygons])
    pts, curve = _densify(world(out), offsets_of(out))
    inside = (np.einsum("pk,fk->pf", pts, N) - np.einsum("fk,fk->f", C, N) < -eps).all(1)
    return np.unique(curve[inside])


def _hair_at(name, xy, npts=5, length=1.0):
    hc = bpy.data.hair_curves.new(name)
    hc.add_curves([npts] * len(xy))
    t = np.linspace(0, length, npts)
    P = np.array([(x, y, z) for x, y in xy for z in t], np.float32)
    hc.position_data.foreach_set("vector", P.ravel())
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def test_subdivision_surface_collider_collides_as_evaluated(fc):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 3
    scene.frame_set(1)
    # x = 0.23 crosses the cage (|x| <= 0.25) but not the subdivided shape (|x| <= 0.21)
    hair = _hair_at("Fur", [(0.23, 0.0), (0.0, 0.0), (0.7, 0.0)])
    box = make_box(location=(0, 0, 0.6))
    sub = box.modifiers.new("Subdivision", "SUBSURF")
    sub.levels = sub.render_levels = 2
    lo, hi = _world_bounds(box)
    assert hi[0] < 0.215  # the evaluated mesh is the subdivided one
    out = fc.setup(hair, [box])
    src = fc.positions(hair).copy()
    scene.frame_set(2)
    scene.frame_set(1)
    st = _status(out)
    P = fc.positions(out)
    assert st[1] != 0 and st[0] == 0 and st[2] == 0, st
    np.testing.assert_array_equal(P[0:5], src[0:5])  # passes beside the rounded shape
    assert np.abs(P[5:10] - src[5:10]).max() > 0.05
    assert len(_curves_inside_convex(out, box)) == 0
    assert list(_curves_inside_convex(hair, box)) == [1]  # the input crosses it
    # the same collider without its modifier: the cage collides, x = 0.23 too
    sub.show_viewport = False
    bpy.context.view_layer.update()
    scene.frame_set(2)
    scene.frame_set(1)
    st = _status(out)
    assert st[0] != 0 and st[1] != 0 and st[2] == 0, st
    assert np.abs(fc.positions(out)[0:5] - src[0:5]).max() > 0.01
    assert len(_free_curves_in_box(out, *_world_bounds(box))) == 0
    assert list(_curves_inside_convex(hair, box)) == [0, 1]


# ------------------------------------------ 7. a mirrored (negative scale) collider
def _mirrored_box(location, scale=(-1.0, 1.0, 1.0)):
    box = make_box(location=location)
    box.scale = scale
    bpy.context.view_layer.update()
    det = np.linalg.det(np.array(box.matrix_world)[:3, :3])
    assert (det < 0) == (np.prod(scale) < 0)
    return box


@pytest.mark.parametrize("scale", [(-1.0, 1.0, 1.0), (1.0, 1.0, -1.0), (-1.0, -1.0, -1.0)])
def test_mirrored_collider_pushes_out_and_pinches(fc, scale):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 3
    scene.frame_set(1)
    hair = make_hair(nx=4, ny=4)  # x, y in {-0.3, -0.1, 0.1, 0.3}
    box = _mirrored_box((0, 0, 0.6), scale)
    assert np.linalg.det(np.array(box.matrix_world)[:3, :3]) < 0
    out = fc.setup(hair, [box])
    scene.frame_set(1)
    st = _status(out)
    assert hair.furcollide.status_message == ""
    assert np.count_nonzero(st == Status.COLLIDING) >= 4, st
    assert not np.isin(st, (PINCHED, UNRESOLVED)).any(), st
    assert len(segments_in_box(world(out), offsets_of(out), box.location)) == 0
    # pinch: the box swallows the roots of the 4 central curves only
    box.location = (0, 0, 0)
    bpy.context.view_layer.update()
    scene.frame_set(2)
    scene.frame_set(1)
    roots = fc.positions(hair)[offsets_of(hair)[:-1]]
    inside = (np.abs(roots[:, :2]) < 0.25).all(axis=1)
    assert inside.sum() == 4
    st = _status(out)
    assert (st[inside] == PINCHED).all() and not (st[~inside] == PINCHED).any(), st
    assert hair.furcollide.stat_pinched == 4


@pytest.mark.parametrize("mirrored", [False, True])
def test_mirrored_collider_keeps_the_collision_offset(fc, mirrored):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 3
    scene.frame_set(1)
    hair = make_hair(nx=4, ny=4)
    box = _mirrored_box((0, 0, 0.6), (-1.0, 1.0, 1.0) if mirrored else (1.0, 1.0, 1.0))
    out = fc.setup(hair, [box])
    hair.furcollide.collision_offset = 0.05
    scene.frame_set(2)
    scene.frame_set(1)
    assert hair.furcollide.status_message == ""
    assert hair.furcollide.stat_colliding >= 4
    lo, hi = np.array(box.location) - 0.25, np.array(box.location) + 0.25
    assert len(_free_curves_in_box(out, lo, hi)) == 0
    # and at least most of the offset is kept (grown box, a little slack)
    assert len(_free_curves_in_box(out, lo - 0.04, hi + 0.04)) == 0


# ------------------------------- 8. an animation render with a frame step of 2
def _render_spy(fc, tmp_path, hair, out, tag):
    """Render the animation; {frame: (world points, status, outdated)} as the
    RENDER depsgraph's frame changes left them (after FurCollide's handler)."""
    scene = bpy.context.scene
    scene.render.filepath = str(tmp_path / f"{tag}_####")
    seen = {}

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            seen[sc.frame_current] = (world(out).copy(), fc.registry.status_for(hair),
                                      hair.furcollide.is_outdated)

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    return seen


def _step_scene(fc):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 7), nx=4, ny=4)
    out = fc.setup(hair, [box])
    render_camera(scene)
    box.hide_render = True
    scene.frame_step = 2
    scene.frame_set(1)
    return scene, hair, out


def test_render_with_frame_step_holds_and_warns(fc, tmp_path, capsys):
    """Unbaked and not played: every rendered frame after the first is a jump ahead
    (README: hold the newest cached frame, mark outdated, one console line)."""
    scene, hair, out = _step_scene(fc)
    first = world(out).copy()
    capsys.readouterr()
    seen = _render_spy(fc, tmp_path, hair, out, "step")
    console = capsys.readouterr()
    assert sorted(seen) == [1, 3, 5, 7]
    for f in (1, 3, 5, 7):
        assert os.path.exists(tmp_path / f"step_{f:04d}.png")
    P, (level, msg), outdated = seen[1]
    np.testing.assert_array_equal(P, first)
    assert level == "INFO" and msg == "" and not outdated
    for f in (3, 5, 7):  # a jump ahead: hold the newest cached frame, mark outdated
        P, (level, msg), outdated = seen[f]
        np.testing.assert_array_equal(P, first, err_msg=f"frame {f}")
        assert level == "WARNING" and outdated, (f, level, msg)
        assert f"Frame {f} is not cached" in msg and "holding frame 1" in msg, msg
    assert "Traceback" not in console.err + console.out
    assert "Error" not in console.err
    lines = [ln for ln in console.out.splitlines() if ln.startswith("FurCollide 'Fur'")]
    assert len(lines) == 1 and "not cached" in lines[0], lines  # one console line


@pytest.mark.parametrize("how", ["played", "baked"])
def test_render_with_frame_step_after_play_or_bake(fc, tmp_path, capsys, how):
    """Played every frame first (memory cache) or baked: the rendered frames are the
    solved ones, with no warning."""
    scene, hair, out = _step_scene(fc)
    want = {}
    for f in range(1, 8):
        scene.frame_set(f)
        want[f] = world(out).copy()
    if how == "baked":
        _save(tmp_path)
        assert bpy.ops.furcollide.bake() == {"FINISHED"}
        bpy.context.view_layer.objects.active = hair
    scene.frame_set(1)
    capsys.readouterr()
    seen = _render_spy(fc, tmp_path, hair, out, how)
    console = capsys.readouterr()
    assert sorted(seen) == [1, 3, 5, 7]
    for f, (P, (level, msg), outdated) in seen.items():
        np.testing.assert_array_equal(P, want[f], err_msg=f"frame {f}")
        assert (level, msg, outdated) == ("INFO", "", False), (f, level, msg)
    assert any(not np.array_equal(want[f], want[1]) for f in (3, 5, 7))
    assert "Traceback" not in console.err + console.out

