"""Colliders as artists and importers make them, in Blender (issue 15, the glue side).

The core repairs a collider when it builds it (welded seams, duplicated faces ignored,
windings made consistent and closed parts outward, ``core/meshfix.py``). Here, with real
Blender meshes and the real operators:

* what was repaired is said once, as info: in the status of the frame it was built on,
  in one console line, and in the Colliders panel for the selected collider;
* a single-sided collider that really is open says "no pinch detection for <object>:
  open mesh" in the status (on every frame it is a collider) and the panel;
* a closed mesh made every way an importer makes it detects exactly the pinched roots
  (the roots inside it by the brute-force parity oracle of ``tests/core``), and no
  resolved curve crosses it (the segment/triangle oracle), Collision Offset included.
"""

import bpy
import numpy as np
import oracle  # (tests/core: on the path, conftest imports helpers first)
import pytest
import scenes
from helpers import (
    PINCHED,
    UNRESOLVED,
    activate,
    check_frame,
    make_hair,
    offsets_of,
    poly,
    status_of,
    tris_world,
    world,
)

pytestmark = pytest.mark.blender

CENTER = (0.05, 0.0, 0.12)  # sunk into the fur: some roots (z = 0) are inside


def sphere():
    V, F = scenes.uv_sphere(CENTER, 0.35, 24, 12)
    return np.asarray(V, float), np.asarray(F)


def flipped(V, F):
    return V, F[:, ::-1]


def duplicated(V, F):
    return V, np.concatenate([F, F[::7], F[1::11, ::-1]])


def split_seam(V, F):
    """Faces with y > 0 use copies of their vertices (a seam an import did not merge)."""
    right = V[F].mean(axis=1)[:, 1] > 0
    F2 = F.copy()
    F2[right] += len(V)
    return np.concatenate([V, V]), F2


def flat_export(V, F):
    """Every face its own three vertices (a flat-shaded export), half of them flipped."""
    F2 = np.arange(3 * len(F)).reshape(-1, 3)
    F2[::2] = F2[::2, ::-1]
    return V[F].reshape(-1, 3), F2


def mesh(name, V, F, location=(0.0, 0.0, 0.0)):
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in V], [], [tuple(int(i) for i in f) for f in F])
    me.update()  # (not validated: duplicated faces stay, as an import leaves them)
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    bpy.context.scene.collection.objects.link(ob)
    return ob


def scene_with(fc, ob, frames=(1, 3)):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    scene.frame_set(frames[0])
    # (Poly: the pinches are the roots in the mesh itself, no spline margin around it)
    hair = poly(make_hair(nx=12, ny=12, npts=5, length=0.6, spacing=0.07))
    out = fc.setup(hair, [ob])
    return scene, hair, out


def pinched_by_the_oracle(hair, V, F):
    """Curves whose root is inside the (original, un-repaired) closed sphere."""
    P = np.empty(len(hair.data.points) * 3, np.float32)
    hair.data.position_data.foreach_get("vector", P)
    offs = np.empty(len(hair.data.curves) + 1, np.int32)
    hair.data.curve_offset_data.foreach_get("value", offs)
    return oracle.points_inside_closed_mesh(P.reshape(-1, 3)[offs[:-1]], V, F)


@pytest.mark.parametrize("make, said", [
    (flipped, ["faces turned outward"]),
    (duplicated, ["duplicated faces ignored"]),
    (split_seam, ["vertices welded"]),
    (flat_export, ["vertices welded", "faces turned outward"]),
], ids=["flipped", "duplicated", "split-seam", "flat-export"])
def test_a_closed_mesh_made_by_an_importer_detects_pinches_and_says_what_was_repaired(
        fc, capsys, make, said):
    V0, F0 = sphere()
    ball = mesh("Ball", *make(V0, F0))
    scene, hair, out = scene_with(fc, ball)
    s = hair.furcollide
    # frame 1, where the collider was built: the repairs, said once, as info
    level, msg = fc.store.report.status_for(hair)
    assert level == "INFO" and msg.startswith("Colliders: 'Ball': "), msg
    for words in said:
        assert words in msg, msg
    assert "no pinch detection" not in msg
    inside = pinched_by_the_oracle(hair, V0, F0)
    assert inside.sum() >= 5
    np.testing.assert_array_equal(status_of(out) == PINCHED, inside)
    rt = fc.store.registry.get_runtime(hair)
    lines = fc.frame.colliders.collider_lines(rt, ball)
    assert lines == ["Repaired " + msg[len("Colliders: "):]], lines
    for f in (2, 3, 2):
        scene.frame_set(f)
        check_frame(hair, out, [ball])  # status "" (said once), no resolved crossing
        np.testing.assert_array_equal(status_of(out) == PINCHED, inside)
    assert s.stat_pinched == inside.sum()
    assert capsys.readouterr().out.count("collider 'Ball': ") == 1


def test_a_clean_mesh_says_nothing(fc):
    ball = mesh("Ball", *sphere())
    scene, hair, out = scene_with(fc, ball)
    assert fc.store.report.status_for(hair) == ("INFO", "")
    assert fc.frame.colliders.collider_lines(fc.store.registry.get_runtime(hair), ball) == []


def test_an_open_mesh_says_it_detects_no_pinch_until_double_sided(fc, capsys):
    """A bowl (the sphere without its top cap): really open, even after welding.
    Single-sided, the status says so on every frame and the panel for it; no root
    is pinched; Double Sided (what a thin sheet should be) silences it."""
    V, F = sphere()
    top = V[F].mean(axis=1)[:, 2] > CENTER[2] + 0.3
    bowl = mesh("Bowl", V, F[~top])
    scene, hair, out = scene_with(fc, bowl)
    s = hair.furcollide
    rt = fc.store.registry.get_runtime(hair)
    n_open = int(rt.colliders.entries[bowl.session_uid].collider.repairs.open_edges)
    assert n_open == 24
    note = f"Colliders: no pinch detection for 'Bowl': open mesh ({n_open} open edges)"
    for f in (1, 2, 3, 1):
        scene.frame_set(f)
        assert fc.store.report.status_for(hair) == ("INFO", note), f
        check_frame(hair, out, [bowl], status=note)
    assert s.stat_pinched == 0
    assert fc.frame.colliders.collider_lines(rt, bowl) == [
        f"No pinch detection for 'Bowl': open mesh ({n_open} open edges)"]
    assert capsys.readouterr().out.count("no pinch detection for 'Bowl'") == 1
    s.colliders[0].double_sided = True
    scene.frame_set(1)
    assert fc.store.report.status_for(hair) == ("INFO", "")
    assert fc.frame.colliders.collider_lines(rt, bowl) == []


def test_a_warning_comes_before_the_collider_note(fc):
    """The status has one line: a warning (here: the enable attribute on the wrong
    domain) is said first; the open mesh note comes back once it is fixed."""
    V, F = sphere()
    top = V[F].mean(axis=1)[:, 2] > CENTER[2] + 0.3
    bowl = mesh("Bowl", V, F[~top])
    scene, hair, out = scene_with(fc, bowl)
    hair.data.attributes.new("furcollide_enable", "BOOLEAN", "POINT")
    scene.frame_set(2)
    level, msg = fc.store.report.status_for(hair)
    assert level == "WARNING" and "furcollide_enable" in msg, msg
    hair.data.attributes.remove(hair.data.attributes["furcollide_enable"])
    scene.frame_set(3)
    assert fc.store.report.status_for(hair)[1].startswith("Colliders: no pinch detection")


@pytest.mark.parametrize("make", [flipped, flat_export], ids=["flipped", "flat-export"])
def test_collision_offset_shell_is_outside_an_inward_wound_ball(fc, make):
    """The issue's first case in Blender: a ball wound inward (or exported flat and
    half flipped) with a Collision Offset of 0.05 lowered onto the fur: no resolved
    curve crosses the real surface (oracle), and the points keep about the offset."""
    V0, F0 = scenes.uv_sphere((0.0, 0.0, 0.0), 0.3, 24, 12)
    V0, F0 = np.asarray(V0, float), np.asarray(F0)
    ball = mesh("Ball", *make(V0, F0), location=(0.02, 0.0, 1.1))
    ball.keyframe_insert("location", frame=1)
    ball.location.z = 0.55
    ball.keyframe_insert("location", frame=6)
    scene, hair, out = scene_with(fc, ball, frames=(1, 6))
    hair.furcollide.collision_offset = 0.05
    for f in range(1, 7):
        scene.frame_set(f)
        st = check_frame(hair, out, [ball], status=None)
    assert (st != 0).sum() >= 5
    P = np.empty(len(out.data.points) * 3, np.float32)
    out.data.position_data.foreach_get("vector", P)
    offs = np.empty(len(out.data.curves) + 1, np.int32)
    out.data.curve_offset_data.foreach_get("value", offs)
    d = oracle.curve_distance_to_sphere_center(P.reshape(-1, 3).astype(float), offs,
                                               (0.02, 0.0, 0.55))
    keep = ~np.isin(st, (PINCHED, UNRESOLVED))
    assert (d[keep] >= 0.3 + 0.045).all(), d[keep].min()


def test_the_colliders_panel_shows_the_lines(fc):
    """The Colliders sub-panel draws the selected collider's lines (a stand-in layout:
    panels cannot be drawn headless)."""
    V, F = sphere()
    ball = mesh("Ball", *flipped(V, F))
    scene, hair, out = scene_with(fc, ball)
    activate(hair)
    labels = []

    class Layout:
        use_property_split = use_property_decorate = enabled = active = None

        def __getattr__(self, name):
            return lambda *a, **k: self

        def label(self, text="", icon="NONE", **_k):
            labels.append((text, icon))

    panel = bpy.types.FURCOLLIDE_PT_colliders
    panel.draw(type("P", (), {"layout": Layout(), "prepare": lambda self, c: (
        Layout(), hair.furcollide)})(), bpy.context)
    # (a line wraps at the sidebar's width: its first label carries the icon)
    text = " ".join(t for t, _ in labels)
    first = next((i for i, (t, _) in enumerate(labels) if t.startswith("Repaired 'Ball': ")),
                 None)
    assert first is not None and labels[first][1] == "INFO", labels
    assert "faces turned outward" in text, labels


# ------------------------------------------ closed colliders made the usual ways
def hair_setup(fc, colliders, nx=10, ny=10, spacing=0.06, length=0.3, frames=(1, 3)):
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = frames
    scene.frame_set(frames[0])
    hair = make_hair(nx=nx, ny=ny, npts=5, length=length, spacing=spacing)
    out = fc.setup(hair, colliders)
    return scene, hair, out


def roots_world(ob):
    return world(ob)[offsets_of(ob)[:-1]]


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
