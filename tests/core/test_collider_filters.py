"""The collider's conservative shortcuts agree with brute force.

``Collider.near_surface`` may only say False where a ball certainly misses
the mesh, and ``Collider.contains`` (cell-cached for points far from the
surface) must equal the plain three-vote ray parity everywhere.
"""

import numpy as np
import strategies as strat
from geom import FAST
from hypothesis import assume, given
from hypothesis import strategies as st

from core import Collider
from core.closest import closest_on_triangles


def ellipsoid(n=24, m=12, axes=(0.6, 0.4, 0.3)):
    u = np.linspace(0, np.pi, m + 1)[1:-1]
    v = np.linspace(0, 2 * np.pi, n, endpoint=False)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    ring = np.stack([np.sin(uu) * np.cos(vv), np.sin(uu) * np.sin(vv), np.cos(uu)], -1)
    V = np.concatenate([[[0, 0, 1]], ring.reshape(-1, 3), [[0, 0, -1]]]) * axes
    F = []
    top, bot = 0, len(V) - 1
    idx = 1 + np.arange(len(u) * n).reshape(len(u), n)
    for j in range(n):
        F.append([top, idx[0, j], idx[0, (j + 1) % n]])
        F.append([bot, idx[-1, (j + 1) % n], idx[-1, j]])
        for i in range(len(u) - 1):
            a, b = idx[i, j], idx[i, (j + 1) % n]
            c, d = idx[i + 1, j], idx[i + 1, (j + 1) % n]
            F += [[a, c, d], [a, d, b]]
    return V, np.array(F)


def brute_distance(V_wo, F, p):
    tri = V_wo[F]
    out = np.empty(len(p))
    for i, q in enumerate(p):
        qq = np.repeat(q[None], len(F), 0)
        c = closest_on_triangles(qq, tri[:, 0], tri[:, 1], tri[:, 2])
        out[i] = np.linalg.norm(c - qq, axis=1).min()
    return out


@st.composite
def matrices(draw):
    """A drawn similarity: axis (two angles), angle, scale and translation."""
    a = draw(strat.directions())
    t = draw(strat.floats(0.0, np.pi))
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    R = np.eye(3) + np.sin(t) * K + (1 - np.cos(t)) * K @ K
    M = np.eye(4)
    M[:3, :3] = R * draw(strat.floats(0.2, 3.0))
    M[:3, 3] = [draw(strat.floats(-6.0, 6.0)) for _ in range(3)]
    return M


axes = st.tuples(strat.floats(0.1, 0.8), strat.floats(0.1, 0.8), strat.floats(0.1, 0.8))
#: The query points are a sample, not the scene: a drawn seed picks them (the
#: collider, its shape and placement, are what hypothesis draws and shrinks).
clouds = st.integers(0, 2**31 - 1)


@FAST
@given(M=matrices(), ax=axes, cloud=clouds)
def test_near_surface_is_conservative(M, ax, cloud):
    rng = np.random.default_rng(cloud)
    V, F = ellipsoid(axes=ax)
    col = Collider(V, F, matrix=M)
    V_wo = V @ M[:3, :3].T + M[:3, 3]
    p = V_wo.mean(0) + rng.normal(size=(200, 3)) * 2.0
    r = rng.uniform(0.01, 0.8, 200)
    near = col.near_surface(p, r)
    dist = brute_distance(V_wo, F, p)
    assert not np.any(~near & (dist <= r)), "a ball touching the mesh was filtered out"
    assert near[dist <= r].all()
    assert (~near).any(), "the filter never filters: useless"


@FAST
@given(M=matrices(), M2=matrices(), ax=axes, cloud=clouds, offset=st.sampled_from([0.0, 0.05, 0.3]))
def test_cached_inside_test_equals_parity(M, M2, ax, cloud, offset):
    rng = np.random.default_rng(cloud)
    V, F = ellipsoid(axes=ax)
    col = Collider(V, F, matrix=M)
    V_wo = V @ M[:3, :3].T + M[:3, 3]
    for _ in range(3):  # repeated calls hit the per-cell cache
        p = V_wo.mean(0) + rng.normal(size=(300, 3)) * 0.8
        assert np.array_equal(col.contains(p, offset), col.inside.parity(p, offset))
    col.matrix = M2  # rigid motion keeps the (local) cache valid
    p = rng.normal(size=(300, 3)) * 3
    assert np.array_equal(col.contains(p, offset), col.inside.parity(p, offset))
    col.vertices = V * 1.1  # deformation invalidates it
    assert np.array_equal(col.contains(p, offset), col.inside.parity(p, offset))


@FAST
@given(M=matrices(), ax=axes, cloud=clouds, offset=st.sampled_from([0.0, 0.05, 0.3]))
def test_input_curve_filter_equals_all_rays(M, ax, cloud, offset):
    """Unrotated curves are only traced when their bounding ball comes near
    the mesh (StepContext.input_hits): the same answers, per segment, as
    tracing every segment of every candidate."""
    from core import Settings, Solver
    from core.step import StepContext

    rng = np.random.default_rng(cloud)
    V, F = ellipsoid(axes=ax)
    col = Collider(V, F, matrix=M, offset=offset)
    V_wo = V @ M[:3, :3].T + M[:3, 3]
    C, cvs = 400, 5
    size = np.ptp(V_wo, axis=0).max()  # curves at the collider's own scale
    roots = V_wo.mean(0) + rng.normal(size=(C, 1, 3)) * 1.2 * size
    steps = rng.normal(size=(C, cvs - 1, 3)) * 0.15 * size
    pts = np.concatenate([roots, roots + np.cumsum(steps, axis=1)], axis=1)
    pts = pts.reshape(-1, 3).astype(np.float32)
    solver = Solver(np.arange(0, C * cvs + 1, cvs), Settings())
    ctx = StepContext(solver.layout, solver._state, solver.settings, pts,
                      [(col, col.effective_offset(0.0))], None)
    idx = np.flatnonzero(ctx.cand_any)
    fast, fast_seg = ctx.input_hits(idx)
    o, d, _, rep, starts = ctx.input_rays(idx)
    every_seg = ctx.hits(idx, o, d, rep, ctx.root_mask(len(o), starts))
    every = np.logical_or.reduceat(every_seg, starts)
    assert np.array_equal(fast_seg, every_seg)
    assert np.array_equal(fast, every)
    assume(every.any() and (~every).any())  # an example where the filter has work


def test_cached_inside_test_next_to_an_offset_shell_under_a_scaling_matrix():
    """The per-cell answers of the inside test trace every cell the *offset shell*
    touches: the shell lies ``offset * (matrix's largest inverse stretch)`` out in the
    collider's own units (here 4x the world offset: a collider scaled by 0.25).
    Points in a band around the shell, inside the grid (the bounds' corners), on the
    second call (the cached path) must get the answer of plain ray parity."""
    V, F = ellipsoid(32, 16, axes=(1.0, 1.0, 1.0))
    a = np.array([1.0, 2.0, 0.5]) / np.linalg.norm([1.0, 2.0, 0.5])
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    M = np.eye(4)
    M[:3, :3] = (np.eye(3) + np.sin(0.7) * K + (1 - np.cos(0.7)) * K @ K) * 0.25
    M[:3, 3] = [1.0, -2.0, 0.5]
    col = Collider(V, F, matrix=M)
    offset = 0.05  # world: 0.2 in the collider's units
    rng = np.random.default_rng(6)
    u = rng.normal(size=(20000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    p_lo = u * rng.uniform(1.05, 1.35, (len(u), 1))
    p_lo = p_lo[(np.abs(p_lo) < 0.98).all(axis=1)][:1500]  # on the grid
    assert len(p_lo) > 500
    p = p_lo @ M[:3, :3].T + M[:3, 3]
    want = col.inside.parity(p, offset)
    assert want.any() and (~want).any()  # the band straddles the shell
    for _ in range(2):  # the second call is the cached (static) path
        np.testing.assert_array_equal(col.contains(p, offset), want)
