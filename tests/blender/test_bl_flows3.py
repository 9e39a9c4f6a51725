"""Odd and bad input an artist may produce in the fur pipeline: Fur Sampler and
Children from Guides on unusual grooms and Surfaces, Fur Attach on empty,
degenerate, far or edited Surfaces, presets (round trip and broken files), every
Before/After Collision combination of wind and jiggle baked then rendered, jiggle
bakes started mid-range, the Collider Distance attribute with Max Distance 0 and
with a collider of 0 faces, and the render groom with ragged or foreign grooms.

Every case must end in ``{'FINISHED'}``, a clear report (``RuntimeError`` from
``bpy.ops`` for an ERROR report) or a clear status message: never a traceback."""

import itertools
import os

import bmesh
import bpy
import numpy as np
import pytest
from conftest import activate, bake_crashing_at, make_box, make_hair, make_surface, render_camera
from test_bl_stages import groom_scene, offsets_of, segments_in_box, world

pytestmark = pytest.mark.blender

PRESETS = "FURCOLLIDE_MT_presets"


# ------------------------------------------------------------------ helpers
def hair_from_sizes(name, sizes, spacing=0.1):
    """A hair object with one vertical curve of ``sizes[i]`` points per entry."""
    hc = bpy.data.hair_curves.new(name)
    if len(sizes):
        hc.add_curves(list(sizes))
        P = [(spacing * i - 0.3, 0.05 * i - 0.2, 0.1 * j)
             for i, n in enumerate(sizes) for j in range(n)]
        hc.position_data.foreach_set("vector", np.array(P, np.float32).ravel())
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def mesh_object(name, verts, edges=(), faces=()):
    me = bpy.data.meshes.new(name)
    me.from_pydata(list(verts), list(edges), list(faces))
    me.update()
    ob = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def no_faces(name="Wire"):
    """A mesh with vertices and an edge but no face."""
    return mesh_object(name, [(0, 0, 0.5), (1, 0, 0.5)], [(0, 1)])


def ragged_groom(name, surf=None, n=60, seed=1, one_point=None):
    """A groom whose curves have 2 to 8 points each (ragged), roots on z = 0."""
    rng = np.random.default_rng(seed)
    sizes = rng.integers(2, 9, n)
    if one_point is not None:
        sizes[one_point] = 1
    hc = bpy.data.hair_curves.new(name)
    hc.add_curves(sizes.tolist())
    roots = np.c_[rng.uniform(-0.6, 0.6, (n, 2)), np.zeros(n)]
    lengths = rng.uniform(0.6, 1.2, n)
    P = [r + np.linspace(0, L, k)[:, None] * [0, 0, 1.0]
         for r, k, L in zip(roots, sizes, lengths, strict=True)]
    hc.position_data.foreach_set("vector", np.concatenate(P).astype(np.float32).ravel())
    hc.surface = surf
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def attribute(ob, name):
    a = ob.data.attributes[name]
    d = np.empty(len(a.data), np.float32)
    a.data.foreach_get("value", d)
    return d


def play(scene, frames):
    for f in frames:
        scene.frame_set(f)


def seg_lengths(P, offs):
    """Per-curve segment lengths (no segment between two curves)."""
    d = np.linalg.norm(np.diff(P, axis=0), axis=1)
    keep = np.ones(len(d), bool)
    keep[offs[1:-1] - 1] = False
    return d[keep]


def _linear(ob):
    ad = ob.animation_data
    for fcu in getattr(ad.action, "fcurves", []) if ad and ad.action else []:
        for k in fcu.keyframe_points:
            k.interpolation = "LINEAR"


def _save(tmp_path, name="shot.blend"):
    path = str(tmp_path / name)
    bpy.ops.wm.save_as_mainfile(filepath=path)
    return path


# ================================================ 1. Fur Sampler, Children
def test_sampler_on_odd_grooms(fc):
    scene = bpy.context.scene
    surf = make_surface(uv=False)

    # 0 curves: refused, nothing created
    empty = hair_from_sizes("Empty", [])
    empty.data.surface = surf
    activate(empty)
    n_objects = len(bpy.data.objects)
    with pytest.raises(RuntimeError, match="'Empty' has no curves to sample"):
        bpy.ops.furcollide.fur_sampler()
    assert len(bpy.data.objects) == n_objects

    # 1 curve: the guide is that curve
    one = hair_from_sizes("One", [5])
    one.data.surface = surf
    activate(one)
    assert bpy.ops.furcollide.fur_sampler() == {"FINISHED"}
    g = bpy.context.view_layer.objects.active
    assert g.name == "One Guides" and len(g.data.curves) == 1
    np.testing.assert_array_equal(fc.positions(g), fc.positions(one))

    # curves of 1 point: sampled (roots only count), but a setup on them is refused
    dots = hair_from_sizes("Dots", [1, 1, 1, 1])
    dots.data.surface = surf
    activate(dots)
    assert bpy.ops.furcollide.fur_sampler(fraction=0.5) == {"FINISHED"}
    g = bpy.context.view_layer.objects.active
    assert len(g.data.curves) == 2 and len(g.data.points) == 2
    activate(g, make_box())
    with pytest.raises(RuntimeError, match="has curves with fewer than 2 points"):
        bpy.ops.furcollide.add()
    assert not g.furcollide.is_setup

    # a fraction that rounds to 0 guides still gives one guide (never an empty object)
    grid = make_hair("Grid", nx=6, ny=6)
    grid.data.surface = surf  # no UV map on this Surface: not needed
    activate(grid)
    assert bpy.ops.furcollide.fur_sampler(fraction=0.001) == {"FINISHED"}
    g = bpy.context.view_layer.objects.active
    assert len(g.data.curves) == 1
    assert g.data.surface == surf and "surface_uv_coordinate" not in g.data.attributes
    activate(grid)
    assert bpy.ops.furcollide.fur_sampler(fraction=0.5, seed=3) == {"FINISHED"}
    assert len(bpy.context.view_layer.objects.active.data.curves) == 18

    # a Surface that is not a mesh (Blender accepts any object there): refused
    for other in (bpy.data.objects.new("Ctrl", None),
                  bpy.data.objects.new("Path", bpy.data.curves.new("Path", "CURVE"))):
        scene.collection.objects.link(other)
        grid.data.surface = other
        activate(grid)
        n_objects = len(bpy.data.objects)
        assert not bpy.ops.furcollide.fur_sampler.poll()
        with pytest.raises(RuntimeError, match="must be a hair Curves object with a Surface"):
            bpy.ops.furcollide.fur_sampler()
        assert len(bpy.data.objects) == n_objects


def test_children_from_guides_on_odd_setups(fc):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 4
    box = make_box(location=(0, 0, 0.6))
    # a hair with 0 curves cannot even become a setup
    empty = hair_from_sizes("Empty", [])
    activate(empty, box)
    with pytest.raises(RuntimeError, match="has no curves to collide"):
        bpy.ops.furcollide.add()

    # 1 curve, on a Surface without a UV map: children grow, the handler is fine
    one = hair_from_sizes("One", [5])
    surf = make_surface(uv=False)
    one.data.surface = surf
    out = fc.setup(one, [box])
    activate(one)
    assert bpy.ops.furcollide.children_from_guides(density=50.0) == {"FINISHED"}
    dg = bpy.context.evaluated_depsgraph_get()
    assert len(out.evaluated_get(dg).data.curves) > 10
    play(scene, range(1, 4))
    assert fc.registry.status_for(one) == ("INFO", "")

    # a Surface that is not a mesh: refused with the reason, nothing changed
    ctrl = bpy.data.objects.new("Ctrl", None)
    scene.collection.objects.link(ctrl)
    grid = make_hair("Grid", nx=3, ny=3)
    out2 = fc.setup(grid, [box])
    grid.data.surface = ctrl
    activate(grid)
    with pytest.raises(RuntimeError, match="no Surface mesh"):
        bpy.ops.furcollide.children_from_guides()
    assert "FurCollide Children" not in out2.modifiers


def test_children_from_guides_refuses_a_surface_without_faces(fc):
    hair, box = fc.make_scene(animate=False, nx=3, ny=3)
    out = fc.setup(hair, [box])
    hair.data.surface = no_faces()
    activate(hair)
    with pytest.raises(RuntimeError, match="no faces"):
        bpy.ops.furcollide.children_from_guides()
    assert "FurCollide Children" not in out.modifiers


# =========================================================== 2. Fur Attach
def _attach_scene(fc, nx=3, ny=3):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 6
    scene.frame_set(1)
    hair = make_hair(nx=nx, ny=ny)
    out = fc.setup(hair, [make_box(location=(5, 5, 5))])
    return scene, hair, out


def test_attach_bind_refuses_surfaces_it_cannot_use(fc):
    scene, hair, out = _attach_scene(fc)
    s = hair.furcollide
    wire = no_faces()
    flat = mesh_object("Flat", [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)],
                       faces=[(0, 1, 2), (1, 2, 3)])  # every face has zero area
    for surf, why in ((wire, "The Surface 'Wire' has no faces"),
                      (flat, "every face is degenerate")):
        hair.data.surface = surf
        activate(hair)
        with pytest.raises(RuntimeError, match=why):
            bpy.ops.furcollide.fur_attach_bind()
        assert not s.use_fur_attach and not fc.fur_attach.has_binding(hair)
    play(scene, range(1, 4))  # the setup still solves its source's own curves
    assert fc.registry.status_for(hair) == ("INFO", "")
    np.testing.assert_allclose(world(out), world(hair), atol=1e-6)
    # not a mesh: the operator is not even offered
    ctrl = bpy.data.objects.new("Ctrl", None)
    scene.collection.objects.link(ctrl)
    hair.data.surface = ctrl
    activate(hair)
    assert not bpy.ops.furcollide.fur_attach_bind.poll()
    with pytest.raises(RuntimeError, match="no Surface mesh"):
        bpy.ops.furcollide.fur_attach_bind()


def test_attach_bind_far_from_the_surface_snaps_with_a_warning(fc, capsys):
    scene, hair, out = _attach_scene(fc)
    surf = make_surface(n=4, uv=False, z=-50.0)
    hair.data.surface = surf
    activate(hair)
    capsys.readouterr()
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    log = capsys.readouterr().out
    assert "9 roots were not on the Surface at frame 1 (up to 50 away)" in log, log
    assert "Traceback" not in log
    play(scene, range(1, 4))
    assert fc.registry.status_for(hair) == ("INFO", "")
    P, offs = world(out), offsets_of(out)
    np.testing.assert_allclose(P[offs[:-1], 2], -50.0, atol=1e-5)  # roots on the Surface
    # the curves were translated whole: same shape
    np.testing.assert_allclose(P - P[np.repeat(offs[:-1], np.diff(offs))],
                               world(hair) - world(hair)[np.repeat(offs[:-1], np.diff(offs))],
                               atol=1e-5)


def _attach_bound(fc):
    """The attach scene, its hair bound to a fresh 4 x 4 Surface (no UV map)."""
    scene, hair, out = _attach_scene(fc)
    surf = make_surface(n=4, uv=False)
    hair.data.surface = surf
    activate(hair)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    return scene, hair, out, surf


@pytest.mark.parametrize("edit", ["add_vertex", "subdivide"])
def test_attach_surface_edited_after_bind(fc, capsys, edit):
    scene, hair, out, surf = _attach_bound(fc)
    play(scene, range(1, 3))
    held = fc.positions(out).copy()
    me = surf.data
    if edit == "add_vertex":
        me.vertices.add(1)
        want = "(26 vertices / 16 faces, bound: 25 / 16)"
    else:
        bm = bmesh.new()
        bm.from_mesh(me)
        bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=1, use_grid_fill=True)
        bm.to_mesh(me)
        bm.free()
        want = "(81 vertices / 64 faces, bound: 25 / 16)"
    me.update()
    capsys.readouterr()
    for f in (3, 4, 1):
        scene.frame_set(f)
        level, msg = fc.registry.status_for(hair)
        assert level == "ERROR", (f, msg)
        assert "Surface 'Skin' changed topology since binding" in msg and want in msg, msg
        assert "press Bind again" in msg
        np.testing.assert_array_equal(fc.positions(out), held)  # keeps its last result
    log = capsys.readouterr()
    assert "Traceback" not in log.out + log.err
    # Bind again on the edited Surface: solved again
    scene.frame_set(1)
    activate(hair)
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    play(scene, range(1, 4))
    assert fc.registry.status_for(hair) == ("INFO", "")


def test_attach_surface_vertex_order_change_is_reported(fc):
    scene, hair, out, surf = _attach_bound(fc)
    play(scene, range(1, 3))
    before = fc.positions(out).copy()
    me = surf.data
    V = np.array([v.co[:] for v in me.vertices])
    F = [tuple(p.vertices) for p in me.polygons]
    perm = np.random.default_rng(0).permutation(len(V))
    inv = np.argsort(perm)
    me.clear_geometry()
    me.from_pydata(V[perm].tolist(), [], [tuple(int(inv[i]) for i in f) for f in F])
    me.update()
    scene.frame_set(3)
    level, msg = fc.registry.status_for(hair)
    # either the change is reported, or the hair stays where the (same) surface is
    assert level == "ERROR" or np.abs(fc.positions(out) - before).max() < 1e-5, msg


def test_attach_bind_again_then_reopen_keeps_the_binding(fc, tmp_path):
    scene, hair, out, surf = _attach_bound(fc)
    surf.data.vertices.add(1)  # README: the topology changed, press Bind again
    surf.data.update()
    assert bpy.ops.furcollide.fur_attach_bind() == {"FINISHED"}
    play(bpy.context.scene, range(1, 3))
    assert fc.registry.status_for(hair) == ("INFO", "")
    path = _save(tmp_path)
    bpy.ops.wm.open_mainfile(filepath=path)
    hair = bpy.data.objects["Fur"]
    play(bpy.context.scene, range(1, 3))
    assert fc.registry.status_for(hair) == ("INFO", "")


# ============================================================== 3. Presets
def _preset_folder():
    return bpy.utils.user_resource("SCRIPTS", path="presets/furcollide")


def _load(path):
    return bpy.ops.script.execute_preset(filepath=path, menu_idname=PRESETS)


PRESET_HEAD = (
    "import bpy\n"
    "fc = bpy.context.object.furcollide\n"
    "settings = fc.source.furcollide if fc.is_output and fc.source else fc\n"
)


def test_preset_round_trip_restores_every_setting_exactly(fc):
    hair, box = fc.make_scene(frames=(1, 4))
    out = fc.setup(hair, [box])
    s = hair.furcollide
    names = fc.package.operators.properties.SOLVER_PROPERTIES
    look = dict(
        mode="soft", rotation_precision=0.7, max_angle=77.7, affected_connected_cvs=4,
        cv_falloff=0.33, attract_to_growth_surface=True, shrink=True, scale_minimum=0.42,
        scale_angle=33.3, recovery_rate=0.123, plasticity=0.37,
        pinch_resolution="growth_surface", recover_pinched=False, collision_offset=0.0123,
    )
    assert set(look) == set(names)
    for k, v in look.items():
        setattr(s, k, v)
    saved = {k: getattr(s, k) for k in names}
    others = dict(threads=s.threads, frame_end=s.frame_end, wind=s.motion.wind_strength,
                  colliders=len(s.colliders))
    activate(out)  # saved from the output: it stores its source's settings
    assert bpy.ops.furcollide.preset_add(name="Round Trip 3") == {"FINISHED"}
    path = os.path.join(_preset_folder(), "Round_Trip_3.py")
    try:
        assert os.path.isfile(path)
        activate(hair)
        assert _load(os.path.join(_preset_folder(), "Short_Fur_(Stiff).py")) == {"FINISHED"}
        s.cv_falloff, s.attract_to_growth_surface, s.pinch_resolution = 0.9, False, "stop"
        s.recover_pinched, s.affected_connected_cvs, s.shrink = True, 1, False
        assert all(getattr(s, k) != saved[k] for k in names)
        assert _load(path) == {"FINISHED"}
        for k in names:
            assert getattr(s, k) == saved[k], k  # bit for bit
        assert others == dict(threads=s.threads, frame_end=s.frame_end,
                              wind=s.motion.wind_strength, colliders=len(s.colliders))
    finally:
        if os.path.exists(path):
            os.remove(path)


def test_broken_preset_files_report_clearly(fc, capsys):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 4))
    fc.setup(hair, [box])
    s = hair.furcollide
    activate(hair)
    folder = _preset_folder()
    written = []

    def preset(name, body):
        path = os.path.join(folder, f"Broken_{name}.py")
        with open(path, "w") as fh:
            fh.write(PRESET_HEAD + body)
        written.append(path)
        return path

    try:
        # a bad enum value: a clear error naming the value and the valid ones
        p = preset("enum", "settings.mode = 'warp'\n")
        with pytest.raises(RuntimeError, match=r"Failed to execute the preset.*warp.*stiff"):
            _load(p)
        assert s.mode == "bend"
        # a value of the wrong type
        p = preset("type", "settings.affected_connected_cvs = 'three'\n")
        with pytest.raises(RuntimeError, match="Failed to execute the preset.*expected an int"):
            _load(p)
        assert s.affected_connected_cvs == 2
        # a syntax error
        p = preset("syntax", "settings.max_angle = = 3\n")
        with pytest.raises(RuntimeError, match="Failed to execute the preset.*SyntaxError"):
            _load(p)
        # an unknown key (a newer or older version's setting) is ignored, the rest applies
        p = preset("unknown", "settings.wobble = 3\nsettings.plasticity = 0.25\n")
        assert _load(p) == {"FINISHED"}
        assert s.plasticity == pytest.approx(0.25)
        assert "wobble" not in s.keys()  # nothing stored in the file
        # out of range values are clamped to the property's limits
        p = preset("range", "settings.max_angle = 1e9\nsettings.rotation_precision = -5.0\n")
        assert _load(p) == {"FINISHED"}
        assert s.max_angle == pytest.approx(360.0)
        assert s.rotation_precision == pytest.approx(0.001)
        # a non-finite value the properties accept: a clear status when solving, no crash
        p = preset("nan", "settings.max_angle = float('nan')\n")
        assert _load(p) == {"FINISHED"}
        play(scene, range(1, 3))
        level, msg = fc.registry.status_for(hair)
        assert level == "ERROR" and "max_angle must be finite" in msg, msg
        # a good preset fixes it: the setup solves again from the start frame
        assert _load(os.path.join(folder, "Long_Fur_(Bend).py")) == {"FINISHED"}
        play(scene, range(1, 4))
        assert fc.registry.status_for(hair) == ("INFO", "")
        # no active object: a clear error, not a crash
        bpy.context.view_layer.objects.active = None
        with pytest.raises(RuntimeError, match="Failed to execute the preset.*NoneType"):
            _load(p)
    finally:
        for path in written:
            os.remove(path)
    log = capsys.readouterr()
    assert "Traceback" not in log.out + log.err


# ======================================================= 4. wind and jiggle
def _motion_scene(fc, frames=(1, 6)):
    """A 4 x 4 hair grid accelerating along +x (Bezier) through a static box."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    scene.frame_set(frames[0])
    hair = make_hair(nx=4, ny=4)
    hair.location = (0, 0, 0)
    hair.keyframe_insert("location", frame=frames[0])
    hair.location = (1.5, 0, 0)
    hair.keyframe_insert("location", frame=frames[1])
    box = make_box(location=(0.9, 0, 0.6))
    scene.frame_set(frames[0])
    out = fc.setup(hair, [box])
    hair.furcollide.frame_start, hair.furcollide.frame_end = frames
    return scene, hair, box, out


STAGES = list(itertools.product(["INPUT", "OUTPUT"], repeat=2))


@pytest.mark.parametrize("wind_stage,jiggle_stage", STAGES,
                         ids=[f"wind_{w}-jiggle_{j}" for w, j in STAGES])
def test_motion_stages_bake_then_render_match_the_viewport(fc, tmp_path, capsys, wind_stage,
                                                           jiggle_stage):
    scene, hair, box, out = _motion_scene(fc)
    still = {}  # no motion
    for f in range(1, 7):
        scene.frame_set(f)
        still[f] = world(out).copy()
    m = hair.furcollide.motion
    m.use_wind, m.wind_stage, m.wind_strength = True, wind_stage, 0.3
    m.use_jiggle, m.jiggle_stage = True, jiggle_stage
    m.jiggle_stiffness, m.jiggle_damping = 1.0, 0.2
    live = {}
    for f in range(1, 7):
        scene.frame_set(f)
        assert fc.registry.status_for(hair) == ("INFO", ""), f
        live[f] = world(out).copy()
    assert max(np.abs(live[f] - still[f]).max() for f in range(2, 7)) > 0.02
    _save(tmp_path)
    activate(hair)
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    assert hair.furcollide.is_baked
    viewport = {}
    for f in range(1, 7):
        scene.frame_set(f)
        viewport[f] = world(out).copy()
        np.testing.assert_allclose(viewport[f], live[f], atol=1e-5, err_msg=f"frame {f}")
    # render frames 3..5 (only the output visible)
    for o in (hair, box):
        o.hide_render = True
    render_camera(scene)
    scene.frame_start, scene.frame_end = 3, 5
    scene.render.filepath = str(tmp_path / "motion_####")
    seen = {}

    def spy(sc, depsgraph):
        if depsgraph is not None and depsgraph.mode == "RENDER":
            seen[sc.frame_current] = (world(out).copy(), fc.registry.status_for(hair))

    scene.frame_set(1)
    capsys.readouterr()
    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    log = capsys.readouterr()
    assert "Traceback" not in log.out + log.err
    assert sorted(seen) == [3, 4, 5]
    for f, (P, status) in seen.items():
        assert status == ("INFO", ""), (f, status)
        np.testing.assert_array_equal(P, viewport[f], err_msg=f"frame {f}")
    for f in (3, 4, 5):  # and the viewport afterwards still shows the same frames
        scene.frame_set(f)
        np.testing.assert_array_equal(world(out), viewport[f])


def _jiggle_scene(fc, start=1):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 8
    scene.frame_set(1)
    hair = make_hair(nx=3, ny=3)
    hair.location = (0, 0, 0)
    hair.keyframe_insert("location", frame=1)
    hair.location = (2.0, 0, 0)
    hair.keyframe_insert("location", frame=8)
    scene.frame_set(1)
    out = fc.setup(hair, [make_box(location=(5, 5, 5))])
    s = hair.furcollide
    s.frame_start, s.frame_end = start, 8
    m = s.motion
    m.use_jiggle, m.jiggle_stage = True, "OUTPUT"
    m.jiggle_stiffness, m.jiggle_damping = 1.0, 0.2
    return scene, hair, out


def test_jiggle_bake_started_mid_range_starts_over_at_the_start_frame(fc, tmp_path, capsys,
                                                                      monkeypatch):
    """README: "A bake with jiggle always starts over at the start frame instead of
    resuming" -- pressed mid-range, or after an interrupted bake."""
    scene, hair, out = _jiggle_scene(fc)
    _save(tmp_path)
    scene.frame_set(5)  # mid-range, never played
    activate(hair)
    capsys.readouterr()
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    log = capsys.readouterr().out
    assert "frame 1 (1/8)" in log and "(8 frames solved)" in log, log
    assert scene.frame_current == 5  # the frame is restored
    d = bpy.path.abspath(hair.furcollide.bake_path)
    baked = {f: fc.cache.read_frame(d, f)[0] for f in range(1, 9)}
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    # the bake equals a play from the start frame
    for f in range(1, 9):
        scene.frame_set(f)
        np.testing.assert_allclose(world(out), baked[f], atol=1e-5, err_msg=f"frame {f}")
    assert np.abs(baked[5] - baked[1]).max() > 0.1

    # interrupted at frame 5, then Bake again: jiggle starts over, it never resumes
    scene.frame_set(3)
    bake_crashing_at(fc, monkeypatch, 5, match="frame 5: .*simulated crash.*bake again to resume")
    assert fc.cache.list_frames(d) == [1, 2, 3, 4] and not hair.furcollide.is_baked
    capsys.readouterr()
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    log = capsys.readouterr().out
    assert "resuming" not in log and "(8 frames solved)" in log, log
    for f in range(1, 9):
        np.testing.assert_array_equal(fc.cache.read_frame(d, f)[0], baked[f], err_msg=f"{f}")


def test_jiggle_bake_does_not_depend_on_frames_viewed_before_the_start(fc, tmp_path):
    scene, hair, out = _jiggle_scene(fc, start=4)  # the hair already moves at 1..3
    _save(tmp_path)
    activate(hair)
    scene.frame_set(4)
    fc.registry.clear_runtime(hair)  # a fresh session
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    d = bpy.path.abspath(hair.furcollide.bake_path)
    fresh = {f: fc.cache.read_frame(d, f)[0] for f in range(4, 9)}
    assert bpy.ops.furcollide.free_bake() == {"FINISHED"}
    play(scene, (1, 2, 3))  # the artist looked at the frames before the start
    assert bpy.ops.furcollide.bake() == {"FINISHED"}
    for f in range(4, 9):
        np.testing.assert_allclose(fc.cache.read_frame(d, f)[0], fresh[f], atol=1e-5,
                                   err_msg=f"frame {f}")


# ===================================================== 5. Collider Distance
def test_distance_attribute_max_distance_zero_is_exact_and_a_cap_clamps(fc):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 4))
    out = fc.setup(hair, [box])
    m = hair.furcollide.motion
    m.write_collider_distance = True
    assert m.distance_max == 0.0  # the default: exact everywhere
    exact = {}
    for f in range(1, 5):
        scene.frame_set(f)
        assert fc.registry.status_for(hair) == ("INFO", "")
        d = attribute(out, "furcollide_collider_distance")
        me = box.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
        V = np.array([box.matrix_world @ v.co for v in me.vertices])
        me.calc_loop_triangles()
        F = np.array([t.vertices[:] for t in me.loop_triangles])
        ref = fc.core.pipeline.collider_distance(world(out), offsets_of(out), [(V, F)])
        assert np.isfinite(d).all() and (d >= 0).all()
        np.testing.assert_allclose(d, ref, rtol=1e-5, atol=1e-6)
        exact[f] = d
    assert max(d.max() for d in exact.values()) > 0.3
    cap = 0.1
    m.distance_max = cap
    for f in range(1, 5):
        scene.frame_set(f)
        d = attribute(out, "furcollide_collider_distance")
        assert (d <= np.float32(cap)).all()
        near = exact[f] < 0.5 * cap
        assert near.any() or f < 3
        np.testing.assert_allclose(d[near], exact[f][near], rtol=1e-5, atol=1e-6)
        np.testing.assert_array_equal(d[exact[f] >= cap], np.float32(cap))
    # a negative Max Distance cannot be entered
    m.distance_max = -1.0
    assert m.distance_max == 0.0


def test_collider_of_zero_faces(fc, capsys):
    scene = bpy.context.scene
    hair, box = fc.make_scene(frames=(1, 6))
    wire = no_faces()
    out = fc.setup(hair, [wire])
    activate(hair)
    # Collider Distance Now: nothing to measure to
    with pytest.raises(RuntimeError, match="The setup of 'Fur' has no enabled collider"):
        bpy.ops.furcollide.collider_distance()
    assert "furcollide_collider_distance" not in out.data.attributes
    # every frame: the setup solves (nothing collides), the attribute is inf (README:
    # inf without colliders) with Max Distance 0 and the cap with a Max Distance
    m = hair.furcollide.motion
    m.write_collider_distance = True
    play(scene, range(1, 4))
    assert fc.registry.status_for(hair) == ("INFO", "")
    np.testing.assert_allclose(world(out), world(hair), atol=1e-6)
    assert np.isposinf(attribute(out, "furcollide_collider_distance")).all()
    m.distance_max = 0.2
    play(scene, range(1, 4))
    np.testing.assert_array_equal(attribute(out, "furcollide_collider_distance"),
                                  np.float32(0.2))
    # with a real collider next to it, the empty one changes nothing
    s = hair.furcollide
    item = s.colliders.add()
    item.object = box
    m.distance_max = 0.0
    play(scene, range(1, 4))
    assert fc.registry.status_for(hair) == ("INFO", "")
    with_wire = attribute(out, "furcollide_collider_distance")
    assert np.isfinite(with_wire).all()
    assert bpy.ops.furcollide.collider_distance() == {"FINISHED"}  # Now: the box counts
    np.testing.assert_allclose(attribute(out, "furcollide_collider_distance"), with_wire,
                               rtol=1e-5, atol=1e-6)
    log = capsys.readouterr()
    assert "Traceback" not in log.out + log.err


def test_distance_attribute_without_an_enabled_collider_honours_max_distance(fc):
    hair, box = fc.make_scene(frames=(1, 6))
    out = fc.setup(hair, [box])
    m = hair.furcollide.motion
    m.write_collider_distance, m.distance_max = True, 0.1
    hair.furcollide.colliders[0].enabled = False
    play(bpy.context.scene, range(1, 3))
    assert fc.registry.status_for(hair) == ("INFO", "")
    np.testing.assert_array_equal(attribute(out, "furcollide_collider_distance"),
                                  np.float32(0.1))


# ============================================================ 6. Render groom
def test_render_groom_ragged_groom(fc, capsys):
    scene = bpy.context.scene
    guides, _groom, box, out = groom_scene(fc)
    rg = ragged_groom("Ragged", surf=guides.data.surface)
    ref = world(rg)
    roff = offsets_of(rg)
    assert len(set(np.diff(roff).tolist())) > 3  # really ragged
    guides.furcollide.groom.groom = rg
    activate(guides)
    capsys.readouterr()
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    assert "60 curves of 'Ragged' follow 25 guides" in capsys.readouterr().out
    gout = guides.furcollide.groom.output
    np.testing.assert_array_equal(offsets_of(gout), roff)
    np.testing.assert_allclose(world(gout), ref, atol=1e-5)  # identity at the reference
    moved = 0.0
    for f in range(1, 8):
        scene.frame_set(f)
        assert fc.registry.status_for(guides) == ("INFO", ""), f
        P = world(gout)
        np.testing.assert_allclose(P[roff[:-1]], ref[roff[:-1]], atol=1e-5)  # roots stay
        np.testing.assert_allclose(seg_lengths(P, roff), seg_lengths(ref, roff), atol=1e-4)
        assert len(segments_in_box(P, roff, box.matrix_world.translation)) == 0, f
        moved = max(moved, float(np.abs(P - ref).max()))
    assert moved > 0.05 and guides.furcollide.stat_groom_fixed >= 0
    np.testing.assert_array_equal(world(rg), ref)  # the groom itself is untouched


def test_render_groom_with_a_one_point_curve_is_refused(fc):
    guides, _groom, box, out = groom_scene(fc)
    bad = ragged_groom("Stubby", surf=guides.data.surface, one_point=3)
    guides.furcollide.groom.groom = bad
    activate(guides)
    n = len(bpy.data.objects)
    with pytest.raises(RuntimeError, match="'Stubby': curve 3 has fewer than 2 points"):
        bpy.ops.furcollide.groom_bind()
    assert len(bpy.data.objects) == n and guides.furcollide.groom.output is None
    assert not bad.hide_render


def test_render_groom_on_another_surface_follows_the_guides(fc, capsys):
    scene = bpy.context.scene
    guides, _groom, box, out = groom_scene(fc)
    other = make_surface("Other", half=1.0, n=3, uv=False)
    rg = ragged_groom("Foreign", surf=other, seed=4)
    ref = world(rg)
    roff = offsets_of(rg)
    guides.furcollide.groom.groom = rg
    activate(guides)
    capsys.readouterr()
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    assert "(roots following the guides)" in capsys.readouterr().out
    gout = guides.furcollide.groom.output
    np.testing.assert_allclose(world(gout), ref, atol=1e-5)
    for f in range(1, 8):
        scene.frame_set(f)
        assert fc.registry.status_for(guides) == ("INFO", ""), f
        assert len(segments_in_box(world(gout), roff, box.matrix_world.translation)) == 0
    assert np.abs(world(gout) - ref).max() > 0.05
    # the other Surface moving does not move the roots (they follow the guides' roots)
    other.location = (0, 0, 1.0)
    scene.frame_set(1)
    np.testing.assert_allclose(world(gout)[roff[:-1]], ref[roff[:-1]], atol=1e-5)


def test_guides_per_curve_changed_after_binding_keeps_the_old_binding(fc):
    """README: "Bind again after changing Guides per Curve": until then the groom
    keeps its binding (no error, no silent re-bind)."""
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    g = guides.furcollide.groom
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    play(scene, range(1, 5))
    before = world(g.output).copy()
    rt = fc.registry.get_runtime(guides)
    assert fc.groom_stage.groom_binding(guides, rt).weights.index.shape[1] == 4
    g.guides = 1
    scene.frame_set(3)
    scene.frame_set(4)
    assert fc.registry.status_for(guides) == ("INFO", "")
    assert fc.groom_stage.groom_binding(guides, rt).weights.index.shape[1] == 4
    np.testing.assert_array_equal(world(g.output), before)


def test_bind_groom_again_after_changing_guides_per_curve(fc):
    scene = bpy.context.scene
    guides, groom, box, out = groom_scene(fc)
    g = guides.furcollide.groom
    activate(guides)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    play(scene, range(1, 4))
    g.guides = 1
    scene.frame_set(1)
    assert bpy.ops.furcollide.groom_bind() == {"FINISHED"}
    play(scene, range(1, 6))
    assert fc.registry.status_for(guides) == ("INFO", ""), fc.registry.status_for(guides)
    rt = fc.registry.get_runtime(guides)
    assert fc.groom_stage.groom_binding(guides, rt).weights.index.shape[1] == 1
