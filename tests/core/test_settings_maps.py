"""Parameter maps: ``Settings`` fields given one value per curve.

``max_angle``, ``scale_minimum``, ``recovery_rate``, ``plasticity``,
``collision_offset`` and ``clearance_margin`` take a number or a ``(C,)``
array. These tests hold that

* a uniform map gives the bits of the plain number (every field, every mode,
  with Shrink and Attract to Growth Surface, uniform and mixed CV counts),
* a curve's result depends only on its own values (curves permuted with their
  values give the same curves),
* per-curve values take effect curve by curve (plasticity, recovery rate, Max
  Angle, Scale Minimum; offsets and margins keep each curve's own clearance,
  measured with the independent oracle), also past ``tolerances.OFFSET_LEVELS``
  distinct distances (rounded up, never down),
* bad maps are refused with a ``SettingsError`` naming the field (and the curve
  or the lengths), and
* settings with maps compare, hash, copy and round-trip by value.
"""

from __future__ import annotations

import geom
import numpy as np
import oracle
import pytest
import scenes
from geom import EXCLUDED

from core import Collider, Settings, SettingsError, Solver, Status
from core import tolerances as tol
from core.collider import clearance_levels

#: A value of each mapped field away from its default (so that it matters).
VALUES = {"max_angle": 100.0, "scale_minimum": 0.6, "recovery_rate": 0.3, "plasticity": 0.4,
          "collision_offset": 0.03, "clearance_margin": 0.02}
FIELDS = tuple(VALUES)
MODES = ("stiff", "bend", "soft")

R_BALL = 0.32


def _fur(uniform, n=40, seed=5):
    rng = np.random.default_rng(seed)
    cvs = (6, 6) if uniform else (3, 9)
    return scenes.fur_on_plane(rng, n_curves=n, curly=0.2, extent=0.55, n_cvs=cvs,
                               length=(0.6, 1.0))


def _ball_path(n_frames):
    """A ball that comes in over the fur, presses into it and leaves (recovery and
    plasticity then matter), one world matrix per frame."""
    xs = np.linspace(-0.9, 0.9, n_frames)
    return [scenes.affine(t=[x, 0.05, 0.62], s=R_BALL) for x in xs]


def _run(pts, offs, settings, n_frames=7, growth=True, cols=None):
    """(points, status) of every frame, and the final state."""
    V, F = scenes.uv_sphere([0, 0, 0], 1.0, 24, 12)
    col = Collider(V, F) if cols is None else None
    Vg, Fg = scenes.grid(size=4.0, n=4, z=0.0)
    g = Collider(Vg, Fg) if growth else None
    solver = Solver(offs, settings)
    out = []
    for M in _ball_path(n_frames):
        if col is not None:
            col.matrix = M
        res = solver.step(pts, [col] if cols is None else cols, growth=g)
        out.append((res.points.copy(), np.asarray(res.status).copy()))
    return out, solver.state


def _assert_same_runs(a, b, what):
    (fa, sa), (fb, sb) = a, b
    for f, ((pa, ta), (pb, tb)) in enumerate(zip(fa, fb, strict=True)):
        assert np.array_equal(ta, tb), f"{what}: status differs at frame {f}"
        assert pa.tobytes() == pb.tobytes(), f"{what}: points differ at frame {f}"
    assert sa.keys() == sb.keys()
    for k in sa:
        assert sa[k].tobytes() == sb[k].tobytes(), f"{what}: state[{k!r}] differs"


# ----------------------------------------------------------- same bits
@pytest.mark.parametrize("uniform", [True, False], ids=["uniform_cvs", "mixed_cvs"])
@pytest.mark.parametrize("mode", MODES)
def test_uniform_map_gives_the_bits_of_the_number(mode, uniform):
    """Every mapped field, one at a time and all at once: a (C,) array of one value
    steps exactly as that value (Shrink and Attract on, a ball passing)."""
    pts, offs = _fur(uniform)
    C = len(offs) - 1
    plain = Settings(mode=mode, shrink=True, attract_to_growth_surface=True, scale_angle=40.0,
                     **VALUES)
    ref = _run(pts, offs, plain)
    statuses = np.concatenate([s for _, s in ref[0]])
    assert (statuses == Status.COLLIDING).sum() >= 20  # (in play)
    assert (statuses == Status.RECOVERING).sum() >= 5
    for name in (*FIELDS, "all"):
        names = FIELDS if name == "all" else (name,)
        mapped = plain.replace(**{n: np.full(C, VALUES[n]) for n in names})
        assert mapped.mapped == names
        _assert_same_runs(_run(pts, offs, mapped), ref, f"{mode}: uniform {name}")


def test_uniform_map_on_a_collider_with_its_own_offset():
    """A collider's own offset replaces the (mapped) setting; a uniform margin on top
    of it is that margin as a number."""
    pts, offs = _fur(True)
    C = len(offs) - 1
    V, F = scenes.uv_sphere([0, 0, 0], 1.0, 24, 12)
    for mode in MODES:
        runs = []
        for s in (Settings(mode=mode, collision_offset=0.2, clearance_margin=0.01),
                  Settings(mode=mode, collision_offset=np.linspace(0, 0.3, C),
                           clearance_margin=np.full(C, 0.01))):
            col = Collider(V, F, offset=0.02)
            solver = Solver(offs, s)
            frames = []
            for M in _ball_path(5):
                col.matrix = M
                r = solver.step(pts, [col])
                frames.append((r.points.copy(), np.asarray(r.status).copy()))
            runs.append((frames, solver.state))
        _assert_same_runs(runs[1], runs[0], mode)


# ------------------------------------------------- depends on its own value only
@pytest.mark.parametrize("mode", MODES)
def test_curves_permuted_with_their_values_give_the_same_curves(mode):
    """Random values of every map (more distinct offsets than OFFSET_LEVELS): curve
    ``i`` solved among others in another order, with its own values, ends the same,
    frame by frame, bit for bit."""
    rng = np.random.default_rng(21)
    pts, offs = _fur(False, n=48, seed=9)
    C = len(offs) - 1
    maps = {"max_angle": rng.uniform(20, 180, C), "scale_minimum": rng.uniform(0.3, 1.0, C),
            "recovery_rate": rng.uniform(0.0, 1.0, C), "plasticity": rng.uniform(0.0, 1.0, C),
            "collision_offset": rng.uniform(0.0, 0.08, C),
            "clearance_margin": rng.uniform(0.0, 0.02, C)}
    s = Settings(mode=mode, shrink=mode != "soft", scale_angle=45.0, **maps)
    perm = rng.permutation(C)
    curves = scenes.unpack(pts, offs)
    pts_p, offs_p = scenes.pack([curves[i] for i in perm])
    s_p = s.replace(**{k: v[perm] for k, v in maps.items()})
    (fa, _), (fb, _) = _run(pts, offs, s, growth=False), _run(pts_p, offs_p, s_p, growth=False)
    hits = 0
    for (pa, ta), (pb, tb) in zip(fa, fb, strict=True):
        assert np.array_equal(ta[perm], tb)
        hits += int((ta == Status.COLLIDING).sum())
        a, b = scenes.unpack(pa, offs), scenes.unpack(pb, offs_p)
        for j, i in enumerate(perm):
            assert a[i].tobytes() == b[j].tobytes(), f"curve {i} (moved to {j})"
    assert hits >= 20


@pytest.mark.parametrize("mode", MODES)
def test_state_snapshot_with_maps_continues_bit_for_bit(mode):
    """``Solver.state`` saved mid-shot under per-curve settings, restored into a
    fresh solver: the next frames are those of the uninterrupted run."""
    rng = np.random.default_rng(3)
    pts, offs = _fur(True, n=30)
    C = len(offs) - 1
    s = Settings(mode=mode, plasticity=rng.uniform(0, 1, C), recovery_rate=rng.uniform(0, 1, C),
                 max_angle=rng.uniform(30, 180, C), collision_offset=rng.uniform(0, 0.05, C))
    V, F = scenes.uv_sphere([0, 0, 0], 1.0, 24, 12)
    path = _ball_path(7)
    col = Collider(V, F)
    a = Solver(offs, s)
    ref = []
    for f, M in enumerate(path):
        col.matrix = M
        ref.append(a.step(pts, [col]).points.copy())
        if f == 3:
            snap = {k: v.copy() for k, v in a.state.items()}
    b = Solver(offs, s)
    b.state = snap
    for f in range(4, 7):
        col.matrix = path[f]
        assert b.step(pts, [col]).points.tobytes() == ref[f].tobytes(), f"frame {f}"


# ------------------------------------------------------- values take effect
def _row(n, z=0.0, x0=-0.5, x1=0.5, length=1.0, cvs=6):
    """``n`` straight vertical blades in a row along x."""
    xs = np.linspace(x0, x1, n)
    return scenes.pack([scenes.straight_curve([x, 0.0, z], [0, 0, 1], length, cvs)
                        for x in xs])


def _press_and_leave(pts, offs, settings, n_after=4):
    """A tilted plate presses the row down (frames 0-1), then is gone: the
    results after it left, and the statuses while it pressed."""
    V, F = scenes.grid(size=3.0, n=6, z=0.0)
    col = Collider(V, F)
    solver = Solver(offs, settings)
    pressed = []
    for z in (0.7, 0.5):
        col.matrix = scenes.affine(R=scenes.rotation_matrix([0, 1, 0], 0.2), t=[0.0, 0.0, z])
        pressed.append(np.asarray(solver.step(pts, [col]).status).copy())
    out = []
    for _ in range(n_after):
        out.append(solver.step(pts, []))
    return pressed, out


def test_plasticity_map_imprints_only_its_curves():
    pts, offs = _row(12)
    C = len(offs) - 1
    plast = np.where(np.arange(C) % 2 == 0, 0.0, 1.0)
    pressed, after = _press_and_leave(pts, offs, Settings(mode="bend", recovery_rate=1.0,
                                                          plasticity=plast))
    assert (pressed[-1] == Status.COLLIDING).all()
    last = scenes.unpack(after[-1].points, offs)
    inp = scenes.unpack(pts, offs)
    for c in range(C):
        moved = not np.array_equal(last[c], inp[c])
        assert moved == (plast[c] == 1.0), f"curve {c} plasticity {plast[c]}"


def test_recovery_rate_map_recovers_only_its_curves():
    pts, offs = _row(12)
    C = len(offs) - 1
    rate = np.where(np.arange(C) % 3 == 0, 1.0, 0.0)
    pressed, after = _press_and_leave(pts, offs, Settings(mode="stiff", recovery_rate=rate))
    assert (pressed[-1] == Status.COLLIDING).all()
    inp = scenes.unpack(pts, offs)
    first = scenes.unpack(after[0].points, offs)
    for c in range(C):
        assert np.array_equal(first[c], inp[c]) == (rate[c] == 1.0), f"curve {c}"
    last = scenes.unpack(after[-1].points, offs)
    for c in range(C):  # (rate 0: held where the plate left it)
        assert np.array_equal(last[c], first[c]), f"curve {c}"


def test_max_angle_map_leaves_its_small_curves_unresolved():
    """A plate pressed down to a third of the blades' height: clearing it needs
    ~70 degrees; curves allowed 30 are UNRESOLVED, those allowed 180 resolve."""
    pts, offs = _row(10)
    C = len(offs) - 1
    ma = np.where(np.arange(C) < 5, 30.0, 180.0)
    V, F = scenes.grid(size=3.0, n=6, z=0.33)
    res = Solver(offs, Settings(mode="stiff", max_angle=ma)).step(pts, [Collider(V, F)])
    st = np.asarray(res.status)
    assert (st[ma == 30.0] == Status.UNRESOLVED).all(), st
    assert (st[ma == 180.0] == Status.COLLIDING).all(), st
    geom.assert_no_intersection(res.points, offs, st, [(V, F)])


def test_scale_minimum_map_shrinks_only_its_curves():
    pts, offs = _row(10)
    C = len(offs) - 1
    smin = np.where(np.arange(C) % 2 == 0, 1.0, 0.3)
    V, F = scenes.grid(size=3.0, n=6, z=0.5)
    s = Settings(mode="stiff", shrink=True, scale_angle=30.0, scale_minimum=smin)
    res = Solver(offs, s).step(pts, [Collider(V, F)])
    st = np.asarray(res.status)
    assert (st == Status.COLLIDING).all()
    length = np.array([np.linalg.norm(np.diff(c, axis=0), axis=1).sum()
                       for c in scenes.unpack(res.points, offs)])
    np.testing.assert_allclose(length[smin == 1.0], 1.0, rtol=1e-6)
    assert (length[smin == 0.3] < 0.95).all(), length
    geom.assert_no_intersection(res.points, offs, st, [(V, F)])


def _inradius_factor(V, F):
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return float(np.abs(np.einsum("ij,ij->i", n, a)).min())


def _ring(n=36, r_ring=0.3):
    """Blades on a ring around the ball's foot, leaning in: every one hits it."""
    curves = []
    for a in np.linspace(0, 2 * np.pi, n, endpoint=False):
        root = np.array([np.cos(a), np.sin(a), 0.0]) * r_ring
        curves.append(scenes.straight_curve(root, [-np.cos(a) * 0.3, -np.sin(a) * 0.3, 1.0],
                                            1.0, 7))
    return scenes.pack(curves)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("what", ["offset", "margin", "own_plus_margin", "many"])
def test_per_curve_clearance_is_kept_curve_by_curve(mode, what):
    """Each curve keeps its own distance from the ball (the oracle's distance from
    its centre), and only that much: curves asked little come closer than curves
    asked much. ``many``: more distinct distances than tol.OFFSET_LEVELS (rounded
    up: never closer than asked), at most OFFSET_LEVELS shells built."""
    pts, offs = _ring()
    C = len(offs) - 1
    V, F = scenes.uv_sphere([0, 0, 0], 1.0, 32, 16)
    c, r = np.array([0.0, 0.0, 0.75]), 0.35
    own = None
    if what == "offset":
        want = np.where(np.arange(C) % 2 == 0, 0.02, 0.15)
        s = Settings(mode=mode, collision_offset=want)
    elif what == "margin":
        margin = np.where(np.arange(C) % 3 == 0, 0.12, 0.0)
        s = Settings(mode=mode, collision_offset=0.03, clearance_margin=margin)
        want = 0.03 + margin
    elif what == "own_plus_margin":
        own = 0.05
        margin = np.where(np.arange(C) % 2 == 0, 0.0, 0.1)
        s = Settings(mode=mode, collision_offset=np.full(C, 0.4), clearance_margin=margin)
        want = own + margin  # (the collider's own offset replaces the setting)
    else:
        want = np.linspace(0.0, 0.16, C)  # C distinct distances
        s = Settings(mode=mode, collision_offset=want)
    col = Collider(V, F, matrix=scenes.affine(t=c, s=r), offset=own)
    res = Solver(offs, s).step(pts, [col])
    st = np.asarray(res.status)
    keep = ~np.isin(st, EXCLUDED)
    assert keep.sum() >= 0.8 * C
    assert (st[keep] == Status.COLLIDING).all()
    dist = oracle.curve_distance_to_sphere_center(res.points, offs, c)
    # the inflated tessellated sphere's face planes, minus 10 % of the offset
    k = _inradius_factor(V, F)
    floor = k * (r + want) - 0.1 * want - 1e-6
    assert np.all(dist[keep] >= floor[keep]), (dist - floor)[keep].min()
    geom.assert_no_intersection(res.points, offs, st, [(oracle.transform(V, col.matrix), F)])
    # each curve rests near its own shell (not at the largest distance asked)
    near = dist[keep] - k * (r + want[keep])
    if what == "many":
        assert col.build_count <= tol.OFFSET_LEVELS
        # rounded up by at most one bin width (plus the search's precision)
        assert np.median(near) < (want.max() - want.min()) / tol.OFFSET_LEVELS + 0.05
    else:
        small = want[keep] == want.min()
        assert np.median(near[small]) < 0.05, near[small]
        assert np.median(dist[keep][small]) < np.median(dist[keep][~small]) - 0.05


@pytest.mark.parametrize("mode", MODES)
def test_per_curve_offset_decides_each_pinch(mode):
    """Roots 0.05 outside a closed ball: inside the offset shell of the curves kept
    0.1 away (pinched), outside that of the curves kept 0.01 away (solved)."""
    V, F = scenes.uv_sphere([0, 0, 0], 1.0, 32, 16)
    c, r = np.array([0.0, 0.0, 0.0]), 0.5
    curves = []
    for a in np.linspace(0, 2 * np.pi, 16, endpoint=False):
        n = np.array([np.cos(a), np.sin(a), 0.3])
        n /= np.linalg.norm(n)
        t = np.cross(n, [0.0, 0.0, 1.0])
        curves.append(scenes.straight_curve(c + (r + 0.05) * n, t + 0.2 * n, 0.4, 5))
    pts, offs = scenes.pack(curves)
    C = len(offs) - 1
    want = np.where(np.arange(C) % 2 == 0, 0.1, 0.01)
    col = Collider(V, F, matrix=scenes.affine(t=c, s=r))
    st = np.asarray(Solver(offs, Settings(mode=mode, collision_offset=want)).step(
        pts, [col]).status)
    assert np.array_equal(st == Status.PINCHED, want == 0.1), st


def test_a_subset_taken_from_the_settings_solves_as_the_whole():
    """``Settings.take``: a solver of some of the curves, with more distinct
    distances than OFFSET_LEVELS (rounded to the whole set's levels, not the
    subset's own), ends them exactly as a solver of all curves does."""
    pts, offs = _ring()
    C = len(offs) - 1
    V, F = scenes.uv_sphere([0, 0, 0], 1.0, 32, 16)
    rng = np.random.default_rng(4)
    s = Settings(mode="bend", collision_offset=rng.uniform(0.0, 0.1, C),
                 clearance_margin=rng.uniform(0.0, 0.05, C), plasticity=rng.uniform(0, 1, C))
    M = scenes.affine(t=[0.0, 0.0, 0.75], s=0.35)
    full = Solver(offs, s).step(pts, [Collider(V, F, matrix=M)])
    assert (np.asarray(full.status) == Status.COLLIDING).sum() >= 20
    idx = np.arange(3, C, 4)  # (its values span less than the whole set's)
    sub_pts, sub_offs = scenes.pack([scenes.unpack(pts, offs)[i] for i in idx])
    t = s.take(idx)
    assert t == Settings(mode="bend", collision_offset=s.collision_offset[idx],
                         clearance_margin=s.clearance_margin[idx],
                         plasticity=s.plasticity[idx])
    sub = Solver(sub_offs, t).step(sub_pts, [Collider(V, F, matrix=M)])
    assert np.array_equal(np.asarray(sub.status), np.asarray(full.status)[idx])
    whole = scenes.unpack(full.points, offs)
    for j, i in enumerate(scenes.unpack(sub.points, sub_offs)):
        assert i.tobytes() == whole[idx[j]].tobytes(), f"curve {idx[j]}"


def test_clearance_levels_exact_then_rounded_up():
    few = np.array([0.3, 0.1, 0.1, 0.0, 0.25, 0.3])
    levels, group = clearance_levels(few)
    assert np.array_equal(levels, [0.0, 0.1, 0.25, 0.3])
    assert np.array_equal(levels[group], few)
    rng = np.random.default_rng(2)
    many = rng.uniform(0.01, 0.5, 1000)
    levels, group = clearance_levels(many)
    assert len(levels) <= tol.OFFSET_LEVELS
    assert np.all(levels[group] >= many)  # never less clearance than asked
    width = (many.max() - many.min()) / tol.OFFSET_LEVELS
    assert np.all(levels[group] - many <= width * (1 + 1e-12))
    assert levels[-1] == many.max()
    perm = rng.permutation(len(many))  # the set of values decides, not their order
    lp, gp = clearance_levels(many[perm])
    assert np.array_equal(lp, levels) and np.array_equal(levels[group][perm], lp[gp])


def test_clearance_groups_of_plain_and_uniform_settings_are_one_shell():
    V, F = scenes.box()
    col = Collider(V, F)
    assert col.clearance_groups(0.1, 0.02) == [(0.1 + 0.02, None)]
    assert col.clearance_groups(np.full(5, 0.1), np.full(5, 0.02)) == [(0.1 + 0.02, None)]
    assert Collider(V, F, offset=0.3).clearance_groups(np.arange(5.0), 0.0) == [(0.3, None)]
    g = col.clearance_groups(np.array([0.0, 0.1, 0.0]), 0.0)
    assert [d for d, _ in g] == [0.0, 0.1]
    assert [m.tolist() for _, m in g] == [[True, False, True], [False, True, False]]


# ------------------------------------------------------------- bad maps
BAD = [
    ("plasticity", np.array([0.0, 1.5, 0.2]), "curve 1"),
    ("plasticity", np.array([0.0, -0.1, 0.2]), "curve 1"),
    ("recovery_rate", np.array([0.2, 0.2, np.nan]), "curve 2"),
    ("recovery_rate", np.array([np.inf, 0.2, 0.2]), "curve 0"),
    ("collision_offset", np.array([0.0, -1e-3, 0.0]), "curve 1"),
    ("clearance_margin", np.array([0.0, 0.0, -0.5]), "curve 2"),
    ("max_angle", np.array([90.0, 0.0, 90.0]), "curve 1"),
    ("max_angle", np.array([90.0, 400.0, 90.0]), "curve 1"),
    ("max_angle", np.array([90.0, 90.0, 0.1]), "curve 2"),  # below rotation_precision
    ("scale_minimum", np.array([0.5, 0.0, 0.5]), "curve 1"),
    ("scale_minimum", np.array([1.2, 0.5, 0.5]), "curve 0"),
    ("plasticity", np.array([True, False, True]), "dtype"),
    ("plasticity", np.array(["a", "b", "c"]), "dtype"),
    ("plasticity", np.array([1j, 0, 0]), "dtype"),
    ("plasticity", np.array([None, 0.1, 0.2], dtype=object), "dtype"),
    ("recovery_rate", np.zeros((3, 1)), "shape"),
    ("recovery_rate", np.array(0.5), "shape"),
    ("collision_offset", [[0.1, 0.2], [0.3]], "collision_offset"),
]


@pytest.mark.parametrize(("field", "value", "where"), BAD,
                         ids=[f"{f}-{i}" for i, (f, _, _) in enumerate(BAD)])
def test_bad_map_names_field(field, value, where):
    with pytest.raises(SettingsError) as ei:
        Settings(**{field: value})
    msg = str(ei.value)
    assert f"Settings.{field}" in msg and where in msg, msg
    with pytest.raises(SettingsError):
        Settings().replace(**{field: value})


@pytest.mark.parametrize("field", (*FIELDS,))
def test_map_of_wrong_length_is_refused_by_the_solver(field):
    pts, offs = _row(4)
    s = Settings(**{field: np.full(5, VALUES[field])})
    with pytest.raises(SettingsError) as ei:
        Solver(offs, s)
    msg = str(ei.value)
    assert f"Settings.{field}" in msg and "5 values" in msg and "4 curves" in msg, msg
    solver = Solver(offs)
    with pytest.raises(SettingsError, match=f"Settings.{field} has 5 values"):
        solver.settings = s
    assert solver.settings == Settings()  # (refused: unchanged)
    solver.settings = Settings(**{field: np.full(4, VALUES[field])})
    solver.step(pts, [])


def test_map_lists_are_accepted_and_copied():
    src = np.array([0.1, 0.2, 0.3])
    s = Settings(plasticity=src, recovery_rate=[0.5, 0.5, 1])
    src[0] = 0.9  # the caller's array is not the settings'
    assert s.plasticity.tolist() == [0.1, 0.2, 0.3]
    assert s.recovery_rate.dtype == np.float64
    assert not s.plasticity.flags.writeable
    with pytest.raises(ValueError):
        s.plasticity[0] = 0.5
    assert np.array_equal(Settings(plasticity=np.array([0, 1], np.int32)).plasticity, [0.0, 1.0])


# ----------------------------------------------------- compare, hash, copy
def test_settings_with_maps_compare_and_hash_by_value():
    a = Settings(plasticity=np.array([0.0, 0.5]), collision_offset=0.1)
    b = Settings(plasticity=[0.0, 0.5], collision_offset=0.1)
    assert a == b and hash(a) == hash(b)
    assert a != Settings(plasticity=[0.0, 0.6], collision_offset=0.1)
    assert a != Settings(plasticity=0.5, collision_offset=0.1)  # a map is not its number
    assert Settings(plasticity=np.full(2, 0.5)) != Settings(plasticity=0.5)
    assert a != Settings(plasticity=[0.0, 0.5, 0.5], collision_offset=0.1)
    assert Settings(plasticity=[-0.0, 0.5]) == Settings(plasticity=[0.0, 0.5])
    assert hash(Settings(plasticity=[-0.0, 0.5])) == hash(Settings(plasticity=[0.0, 0.5]))
    assert len({a, b, Settings()}) == 2
    assert a != "settings"
    assert Settings(**a.to_dict()) == a
    assert a.replace(mode="soft").plasticity.tolist() == [0.0, 0.5]
    assert a.replace(plasticity=0.2).mapped == ()
    assert a.mapped == ("plasticity",)
    assert a.per_curve("plasticity", np.array([1])).tolist() == [0.5]
    assert a.per_curve("collision_offset", np.array([1])) == 0.1


def test_take_selects_the_curves_of_every_map():
    s = Settings(plasticity=[0.0, 0.5, 1.0], max_angle=[10.0, 20.0, 30.0], shrink=True)
    t = s.take(np.array([2, 0]))
    assert t.plasticity.tolist() == [1.0, 0.0] and t.max_angle.tolist() == [30.0, 10.0]
    assert t.shrink and t.recovery_rate == s.recovery_rate
    assert Settings().take([0]) == Settings()
