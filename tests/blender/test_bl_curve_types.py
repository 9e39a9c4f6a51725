"""The output draws what was solved, whatever the hair's curve type: Poly, Catmull-Rom,
Bezier (AUTO, ALIGN, FREE, VECTOR handles) and NURBS. Crossings are measured on the
curves Blender *evaluates* (``helpers.evaluated_curves``) against the colliders'
evaluated meshes; handles move with their point; NURBS order, knots mode and weights
are carried over; and anything evaluated from the output (its own Resample Curve and
Trim Hair Curves modifiers) sees the solved positions of the frame they were written."""

import bpy
import numpy as np
import pytest
from helpers import (
    evaluated_crossing,
    evaluated_curves,
    offsets_of,
    play,
    positions,
    render_camera,
    set_curve_type,
    setup,
    world,
)

pytestmark = pytest.mark.blender

FRAMES = (1, 6)
TYPES = ("CATMULL_ROM", "POLY", "BEZIER", "NURBS")
FREE, AUTO, VECTOR, ALIGN = 0, 1, 2, 3


# ------------------------------------------------------------------ scenes
def curved_groom(name="Fur", n=10, npts=7, length=0.9, spacing=0.09, seed=0):
    """An n x n grid of arched hairs (roots on z = 0) leaning every way: their
    Catmull-Rom / Bezier / NURBS curves differ from their control polygons."""
    rng = np.random.default_rng(seed)
    xs = (np.arange(n) - (n - 1) / 2) * spacing
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    C = n * n
    lean = rng.uniform(0, 2 * np.pi, C)
    bend = rng.uniform(0.8, 1.6, C)  # total turn along the hair, radians
    t = np.linspace(0, 1, npts)
    pts = []
    for c in range(C):
        ang = bend[c] * t  # arc: the tangent turns from vertical toward ``lean``
        seg = np.diff(t)[0] * length
        d = np.stack([np.sin(ang) * np.cos(lean[c]), np.sin(ang) * np.sin(lean[c]),
                      np.cos(ang)], 1)[:-1] * seg
        pts.append(np.vstack([[X.ravel()[c], Y.ravel()[c], 0.0],
                              [X.ravel()[c], Y.ravel()[c], 0.0] + np.cumsum(d, 0)]))
    P = np.vstack(pts).astype(np.float32)
    hc = bpy.data.hair_curves.new(name)
    hc.add_curves([npts] * C)
    hc.position_data.foreach_set("vector", P.ravel())
    ob = bpy.data.objects.new(name, hc)
    bpy.context.scene.collection.objects.link(ob)
    return ob


def ball(name="Ball", radius=0.35, frames=FRAMES, z0=1.5, z1=0.55):
    """A UV sphere pressing down into the fur over ``frames``."""
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, segments=24, ring_count=12,
                                         location=(0.05, -0.03, z0))
    ob = bpy.context.active_object
    ob.name = name
    ob.keyframe_insert("location", frame=frames[0])
    ob.location.z = z1
    ob.keyframe_insert("location", frame=frames[1])
    return ob


def set_type(hair, kind, handles=AUTO, order=4, knots_mode=0):
    """Give every curve of ``hair`` the type ``kind``: Bezier with ``handles`` (a
    handle type code, or 'MIXED': AUTO, ALIGN, FREE and VECTOR curves), NURBS of
    ``order`` and ``knots_mode``."""
    hc = hair.data
    C, P = len(hc.curves), len(hc.points)
    if kind != "CATMULL_ROM":
        set_curve_type(hair, kind)
    if kind == "BEZIER":
        X = positions(hair).astype(np.float64)
        offs = offsets_of(hair)
        kinds = (np.array([AUTO, ALIGN, FREE, VECTOR])[np.arange(C) % 4]
                 if handles == "MIXED" else np.full(C, handles))
        per_point = np.repeat(kinds, np.diff(offs))
        hl, hr = _auto_handles(X, offs)
        rng = np.random.default_rng(1)
        align = per_point == ALIGN  # aligned, not the AUTO lengths
        s = rng.uniform(0.4, 1.4, (P, 1))
        hl[align] = X[align] + (hl[align] - X[align]) * s[align]
        free = per_point == FREE  # anywhere near
        hl[free] = X[free] + rng.normal(size=(free.sum(), 3)) * 0.02
        hr[free] = X[free] + rng.normal(size=(free.sum(), 3)) * 0.02
        _attr(hc, "handle_left", "FLOAT_VECTOR", "vector", hl)
        _attr(hc, "handle_right", "FLOAT_VECTOR", "vector", hr)
        _attr(hc, "handle_type_left", "INT8", "value", per_point)
        _attr(hc, "handle_type_right", "INT8", "value", per_point)
    if kind == "NURBS":
        if order != 4:  # (Blender's default; 4.2 cannot create nurbs_order from Python)
            _attr(hc, "nurbs_order", "INT8", "value", np.full(C, order), "CURVE")
        _attr(hc, "knots_mode", "INT8", "value", np.full(C, knots_mode), "CURVE")
        w = np.random.default_rng(2).uniform(0.5, 2.0, P)
        _attr(hc, "nurbs_weight", "FLOAT", "value", w)
    hc.update_tag()


def _attr(hc, name, kind, key, values, domain="POINT"):
    a = hc.attributes.get(name) or hc.attributes.new(name, kind, domain)
    dtype = np.float32 if kind.startswith("FLOAT") else np.int32
    a.data.foreach_set(key, np.ascontiguousarray(values, dtype).ravel())


def _auto_handles(X, offs):
    """Blender's AUTO handles (``bezier::calculate_auto_handles``) of open curves."""
    hl, hr = np.empty_like(X), np.empty_like(X)
    for a, b in zip(offs[:-1], offs[1:], strict=True):
        Q = X[a:b]
        prev = np.vstack([2 * Q[:1] - Q[1:2], Q[:-1]])
        nxt = np.vstack([Q[1:], 2 * Q[-1:] - Q[-2:-1]])
        pd, nd = Q - prev, nxt - Q
        pl, nl = np.linalg.norm(pd, axis=1), np.linalg.norm(nd, axis=1)
        d = nd / nl[:, None] + pd / pl[:, None]
        ln = np.linalg.norm(d, axis=1) * 2.5614
        hl[a:b] = Q - d * (np.minimum(pl, 5 * nl) / ln)[:, None]
        hr[a:b] = Q + d * (np.minimum(nl, 5 * pl) / ln)[:, None]
    return hl, hr


def pressed(kind, mode="bend", **type_args):
    """A curved groom of ``kind`` pressed by a ball, set up; (hair, ball, output)."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = FRAMES
    scene.frame_set(FRAMES[0])
    hair = curved_groom()
    set_type(hair, kind, **type_args)
    b = ball()
    scene.frame_set(FRAMES[0])
    out = setup(hair, [b])
    hair.furcollide.mode = mode.upper()
    return hair, b, out


def _handles(ob):
    hc = ob.data
    P = len(hc.points)
    out = []
    for name in ("handle_left", "handle_right"):
        v = np.empty(P * 3, np.float32)
        hc.attributes[name].data.foreach_get("vector", v)
        out.append(v.reshape(-1, 3))
    for name in ("handle_type_left", "handle_type_right"):
        v = np.empty(P, np.int32)
        hc.attributes[name].data.foreach_get("value", v)
        out.append(v)
    return out


# ------------------------------------------------------------------- tests
@pytest.mark.parametrize("kind", TYPES)
def test_the_drawn_curves_clear_the_ball(fc, kind):
    """0 crossings of the evaluated output for resolved curves, every frame."""
    hair, b, out = pressed(kind, handles="MIXED")
    touched = 0
    for f in range(FRAMES[0], FRAMES[1] + 1):
        bpy.context.scene.frame_set(f)
        assert hair.furcollide.status_message == "", hair.furcollide.status_message
        bad = evaluated_crossing(out, [b])
        assert len(bad) == 0, (f, bad)
        touched = max(touched, hair.furcollide.stat_colliding)
    assert touched > 10  # the ball did press into the fur


@pytest.mark.parametrize("kind", TYPES)
def test_where_nothing_collides_the_output_draws_the_source(fc, kind):
    """Same evaluated curves as the source (NURBS tips no longer fall short, Bezier
    handles and types, NURBS order, knots mode and weights carried over)."""
    for knots_mode in ((0, 1) if kind == "NURBS" else (0,)):
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        hair, b, out = pressed(kind, handles="MIXED", knots_mode=knots_mode)
        b.animation_data_clear()
        b.location = (5.0, 0.0, 0.5)  # far from the fur
        play(bpy.context.scene, range(1, 4))
        assert hair.furcollide.stat_colliding == 0
        P_out, o_out = evaluated_curves(out)
        P_src, o_src = evaluated_curves(hair)
        np.testing.assert_array_equal(o_out, o_src)
        np.testing.assert_allclose(P_out, P_src, atol=1e-6, err_msg=f"knots mode {knots_mode}")


def _rigid_fit(A, B):
    """Rotation R (Kabsch) with B - B[0] = (A - A[0]) R^T."""
    H = (A - A[0]).T @ (B - B[0])
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def test_bezier_handles_turn_with_their_point(fc):
    """Stiff turns a curve rigidly: its handles turn with it exactly (AUTO become
    ALIGN, VECTOR stay on their segment); Bend keeps every handle's length, the end
    handles' angle to their segment, and aligned pairs aligned."""
    for mode in ("stiff", "bend"):
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        hair, b, out = pressed("BEZIER", mode=mode, handles="MIXED")
        play(bpy.context.scene, range(1, 5))
        offs = offsets_of(out)
        src_P, out_P = world(hair), world(out)
        src_l, src_r, src_tl, src_tr = _handles(hair)
        out_l, out_r, out_tl, out_tr = _handles(out)
        kinds = src_tl[offs[:-1]]
        assert np.array_equal(out_tl[src_tl == AUTO], np.full((src_tl == AUTO).sum(), ALIGN))
        for t in (FREE, ALIGN, VECTOR):
            assert np.all(out_tl[src_tl == t] == t) and np.all(out_tr[src_tr == t] == t)
        moved = [c for c in range(len(offs) - 1)
                 if not np.array_equal(out_P[offs[c]:offs[c + 1]], src_P[offs[c]:offs[c + 1]])]
        assert len(moved) > 10
        for c in moved:
            sl = slice(offs[c], offs[c + 1])
            A, B = src_P[sl], out_P[sl]
            ha = [src_l[sl] - A, src_r[sl] - A]
            hb = [out_l[sl] - B, out_r[sl] - B]
            if kinds[c] == VECTOR:  # a third of the way to the neighbour
                np.testing.assert_allclose(hb[1][:-1], (B[1:] - B[:-1]) / 3, atol=1e-5)
                np.testing.assert_allclose(hb[0][1:], (B[:-1] - B[1:]) / 3, atol=1e-5)
                continue
            if mode == "stiff":
                R = _rigid_fit(A, B)
                for a, b_ in zip(ha, hb, strict=True):
                    np.testing.assert_allclose(b_, a @ R.T, atol=2e-5, err_msg=f"curve {c}")
            for a, b_ in zip(ha, hb, strict=True):  # lengths kept (no Shrink)
                np.testing.assert_allclose(np.linalg.norm(b_, axis=1),
                                           np.linalg.norm(a, axis=1), rtol=1e-4, atol=1e-6)
            # the end handles keep their angle to their segment
            d0, d1 = A[1] - A[0], B[1] - B[0]
            assert _angle(ha[1][0], d0) == pytest.approx(_angle(hb[1][0], d1), abs=1e-3)
            d0, d1 = A[-2] - A[-1], B[-2] - B[-1]
            assert _angle(ha[0][-1], d0) == pytest.approx(_angle(hb[0][-1], d1), abs=1e-3)
            if kinds[c] in (AUTO, ALIGN):  # aligned pairs stay aligned
                cos = np.einsum("ij,ij->i", _unit(hb[0]), _unit(hb[1]))
                np.testing.assert_allclose(cos, -1.0, atol=1e-5)


def _unit(v):
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _angle(a, b):
    return float(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


def _resample_group(count=16):
    ng = bpy.data.node_groups.new("Resample", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gi, go = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    r = ng.nodes.new("GeometryNodeResampleCurve")
    r.inputs["Count"].default_value = count
    ng.links.new(gi.outputs[0], r.inputs["Curve"])
    ng.links.new(r.outputs[0], go.inputs[0])
    return ng


def _trim_group(fc):
    path = fc.package.operators.ops.pipeline.hair_assets_path()
    with bpy.data.libraries.load(path, link=False) as (_src, dst):
        dst.node_groups = ["Trim Hair Curves"]
    return dst.node_groups[0]


def _stack(fc, ob, groups):
    """Resample Curve, then Trim Hair Curves to 0.6 long, on ``ob``."""
    compat = fc.package.operators.blender.compat
    for ng in groups:
        mod = ob.modifiers.new(ng.name, "NODES")
        mod.node_group = ng
        if ng.name.startswith("Trim"):
            ids = compat.group_inputs(ng)
            compat.set_modifier_input(mod, ids[("Length", "NodeSocketFloat")], 0.6)


def _evaluated_data(ob):
    e = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    P = np.empty(len(e.points) * 3, np.float32)
    e.position_data.foreach_get("vector", P)
    offs = np.zeros(len(e.curves) + 1, np.int32)
    e.curve_offset_data.foreach_get("value", offs)
    return P.reshape(-1, 3), offs


def _fresh(fc, out, groups):
    """A new object with a copy of the output's curves built from scratch (no cache
    of Blender's shared with the output's) and the same modifiers."""
    hc = bpy.data.hair_curves.new("Fresh")
    fc.blender.bridge.copy_topology(out.data, hc)
    ob = bpy.data.objects.new("Fresh", hc)
    bpy.context.scene.collection.objects.link(ob)
    ob.matrix_world = out.matrix_world
    _stack(fc, ob, groups)
    return ob


@pytest.mark.parametrize("kind", ["CATMULL_ROM", "BEZIER", "NURBS"])
def test_modifiers_on_the_output_see_each_frame_solved(fc, kind):
    """A Resample Curve and a Trim Hair Curves modifier on the output give, on every
    frame played (and scrubbed back to), what the same stack gives on a fresh copy of
    the output's curves."""
    hair, b, out = pressed(kind, handles="MIXED")
    groups = [_resample_group(), _trim_group(fc)]
    _stack(fc, out, groups)
    scene = bpy.context.scene
    for f in (*range(FRAMES[0], FRAMES[1] + 1), 3, 2, 6):
        scene.frame_set(f)
        got, offs = _evaluated_data(out)
        ref = _fresh(fc, out, groups)
        want, offs_want = _evaluated_data(ref)
        np.testing.assert_array_equal(offs, offs_want)
        np.testing.assert_allclose(got, want, atol=1e-6, err_msg=f"frame {f}")
        bpy.data.objects.remove(ref)
    assert hair.furcollide.stat_colliding > 10


def test_a_render_sees_each_frame_solved_through_the_output_modifiers(fc, tmp_path):
    """An animation render: the render's own evaluation of the output's Resample Curve
    modifier gives each frame's solved shape (what a fresh copy gives)."""
    hair, b, out = pressed("CATMULL_ROM")
    groups = [_resample_group()]
    _stack(fc, out, groups)
    scene = bpy.context.scene
    render_camera(scene, px=16)
    scene.render.filepath = str(tmp_path / "f_####")
    seen = {}

    def spy(sc, depsgraph):  # (after FurCollide's own frame handler)
        if depsgraph is not None and depsgraph.mode == "RENDER":
            depsgraph.update()  # the render's evaluation of what the handler wrote
            e = out.evaluated_get(depsgraph).data
            P = np.empty(len(e.points) * 3, np.float32)
            e.position_data.foreach_get("vector", P)
            seen[sc.frame_current] = P.reshape(-1, 3)

    bpy.app.handlers.frame_change_post.append(spy)
    try:
        bpy.ops.render.render(animation=True)
    finally:
        bpy.app.handlers.frame_change_post.remove(spy)
    assert sorted(seen) == list(range(FRAMES[0], FRAMES[1] + 1))
    for f, got in seen.items():
        scene.frame_set(f)
        ref = _fresh(fc, out, groups)
        np.testing.assert_allclose(got, _evaluated_data(ref)[0], atol=1e-6, err_msg=f"frame {f}")
        bpy.data.objects.remove(ref)
