"""Slow references: the pipeline's implementations before issue 11, kept to test the fast paths.

Each function is the code of ``core.pipeline`` as it was (numpy, straightforward,
no caching): the fast paths must agree with them within the tolerances of
``core.tolerances`` (see tests/pipeline/test_fast_paths.py).
"""

from __future__ import annotations

import numpy as np

from core.curves import as_points, check_curves, layout, segmented_cumsum
from core.errors import InputError
from core.pipeline.groom import knn

_FRAME_NEIGHBORS = 4


# ---------------------------------------------------------------- deform_groom
def _qmul(p, q):
    pw, pv = p[..., :1], p[..., 1:]
    qw, qv = q[..., :1], q[..., 1:]
    return np.concatenate([pw * qw - np.sum(pv * qv, -1, keepdims=True),
                           pw * qv + qw * pv + np.cross(pv, qv)], -1)


def _qrot(q, v):
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def _qswing(a, b):
    """Minimal rotation (quaternions) taking unit rows ``a`` to unit rows ``b``."""
    c = np.sum(a * b, -1)
    q = np.concatenate([(1.0 + c)[..., None], np.cross(a, b)], -1)
    anti = c < -1 + 1e-12
    if anti.any():  # half turn about any perpendicular axis
        aa = a[anti]
        e = np.zeros_like(aa)
        e[np.arange(len(aa)), np.argmin(np.abs(aa), -1)] = 1.0
        ax = np.cross(aa, e)
        q[anti] = np.concatenate([np.zeros((len(aa), 1)), ax], -1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _qfrom_matrix(R):
    """Unit quaternions (w, x, y, z) of rotation matrices (k, 3, 3) (Shepperd)."""
    m = R
    t = np.stack([m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2],
                  m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], 1)
    case = np.argmax(t, 1)
    q = np.empty((len(R), 4))
    for c in range(4):
        s = case == c
        if not s.any():
            continue
        r = m[s]
        if c == 0:
            w = np.sqrt(1 + r[:, 0, 0] + r[:, 1, 1] + r[:, 2, 2]) * 2
            q[s] = np.stack([0.25 * w, (r[:, 2, 1] - r[:, 1, 2]) / w,
                             (r[:, 0, 2] - r[:, 2, 0]) / w, (r[:, 1, 0] - r[:, 0, 1]) / w], 1)
        else:
            i = c - 1
            j, k = (i + 1) % 3, (i + 2) % 3
            w = np.sqrt(1 + r[:, i, i] - r[:, j, j] - r[:, k, k]) * 2
            out = np.empty((s.sum(), 4))
            out[:, 0] = (r[:, k, j] - r[:, j, k]) / w
            out[:, 1 + i] = 0.25 * w
            out[:, 1 + j] = (r[:, j, i] + r[:, i, j]) / w
            out[:, 1 + k] = (r[:, k, i] + r[:, i, k]) / w
            q[s] = out
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _unit(v):
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def _kabsch(H):
    """Rotations R (g, 3, 3) maximizing ``sum b . R a`` for ``H = sum a b^T``; and S."""
    U, S, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("gji,gkj->gik", Vt, U)))  # det(V U^T)
    d[d == 0] = 1.0
    D = np.ones((len(H), 3))
    D[:, 2] = d
    return np.einsum("gji,gj,gkj->gik", Vt, D, U), S  # V D U^T


def _root_rotations(ref, now, off):
    """Rotation of every guide at its root (G, 4): best fit of its root neighbourhood.

    Kabsch fit of the unit vectors to the nearest guide roots, so that it
    is the identity when the roots do not move (wind, collisions) and the
    exact rotation under a rigid motion. Where the neighbourhood does not
    fix a rotation (fewer than 3 guides, collinear roots) the guide's own
    strand is added; where even that fails (a lone straight guide), the
    minimal rotation of the first segment.
    """
    roots_r, roots_n = ref[off[:-1]], now[off[:-1]]
    G = len(roots_r)
    H = np.zeros((G, 3, 3))
    if G > 1:
        nb, _ = knn(roots_r, roots_r, min(G, _FRAME_NEIGHBORS + 1))
        nb = nb[:, 1:]
        a = _unit(roots_r[nb] - roots_r[:, None])
        b = _unit(roots_n[nb] - roots_n[:, None])
        H += np.einsum("gki,gkj->gij", a, b)
    R, S = _kabsch(H)
    q = _qfrom_matrix(R)
    weak = S[:, 1] <= 1e-9 * np.maximum(S[:, 0], 1e-300)
    if weak.any():
        # add the strand: its direction and the vectors from the root to its CVs
        curve, _, _ = layout(off)
        rel_r = _unit(ref - roots_r[curve])
        rel_n = _unit(now - roots_n[curve])
        Hs = H + np.stack([np.bincount(curve, rel_r[:, i] * rel_n[:, j], minlength=G)
                           for i in range(3) for j in range(3)], 1).reshape(G, 3, 3)
        R2, S2 = _kabsch(Hs[weak])
        q[weak] = _qfrom_matrix(R2)
        still = S2[:, 1] <= 1e-9 * np.maximum(S2[:, 0], 1e-300)
        if still.any():
            w = np.flatnonzero(weak)[still]
            t_r = _unit(ref[off[w] + 1] - roots_r[w])
            t_n = _unit(now[off[w] + 1] - roots_n[w])
            q[w] = _qswing(t_r, t_n)
    return q


def _segment_rotations(ref, now, off, q_root):
    """Per-segment rotations of every guide, parallel-transported from the root.

    Returns
    -------
    (S, 4) ndarray: the rotation of each segment (in segment order).
    """
    curve, index, s0 = layout(off)
    t_r = _unit(ref[s0 + 1] - ref[s0])
    t_n = _unit(now[s0 + 1] - now[s0])
    seg_curve = curve[s0]
    seg_j = index[s0]
    q = np.empty((len(s0), 4))
    prev = q_root.copy()
    for j in range(int(seg_j.max()) + 1):  # over the CV index, vectorized over guides
        s = np.flatnonzero(seg_j == j)
        c = seg_curve[s]
        p = prev[c]
        qj = _qmul(_qswing(_unit(_qrot(p, t_r[s])), t_n[s]), p)
        q[s] = qj
        prev[c] = qj
    return q


def _blend(q, w):
    """Weighted quaternion average (k, n, 4), weights (k, n): sign-aligned nlerp."""
    sign = np.where(np.sum(q * q[:, :1], -1) < 0, -1.0, 1.0)
    m = np.sum(q * (w * sign)[..., None], 1)
    return m / np.linalg.norm(m, axis=-1, keepdims=True)


def deform_groom_v0(render_ref_points, render_offsets, guides_ref_points, guides_now_points,
                 guide_offsets, weights, render_roots_now=None):
    """Every render curve follows the rotation and bend of its guides.

    For each guide, the rotation of every segment from the reference to
    the current pose is found (parallel transport from a root rotation
    fitted to the guide and its neighbouring guide roots). A render
    curve's segment at normalized arc length ``s`` takes, from each of its
    guides, the rotation interpolated at ``s`` along the guide, blends them
    with the weights (quaternion averaging), and the curve is re-chained
    from its root, which follows the guides' root frames.

    Parameters
    ----------
    render_ref_points : (P, 3) array_like of float
        Render groom at the reference pose.
    render_offsets : (R+1,) array_like of int
    guides_ref_points, guides_now_points : (Q, 3) array_like of float
        Guides at the reference pose and now (e.g. FurCollide's output).
    guide_offsets : (G+1,) array_like of int
    weights : GroomWeights
        From :func:`bind_groom` (reference pose).
    render_roots_now : (R, 3) array_like, optional
        Roots to use instead of the guide-driven ones (e.g. the render
        groom's own Fur Attach roots, which stay exactly on the surface).

    Returns
    -------
    (P, 3) ndarray of float64
        Identity when the guides do not move; a rigid motion of all guides
        moves the groom rigidly. Segment lengths are kept.
    """
    rp, roff = check_curves(render_ref_points, render_offsets, "render_ref_points")
    gr, goff = check_curves(guides_ref_points, guide_offsets, "guides_ref_points")
    gn, _ = check_curves(guides_now_points, guide_offsets, "guides_now_points")
    Rn, G = len(roff) - 1, len(goff) - 1
    if weights.index.shape[0] != Rn or weights.weight.shape != weights.index.shape:
        raise InputError(
            f"weights are for {weights.index.shape[0]} render curves, the groom has {Rn}"
        )
    if (weights.index < 0).any() or (weights.index >= G).any():
        raise InputError(f"weights index guides out of range (there are {G} guides)")
    q_root = _root_rotations(gr, gn, goff)
    q_seg = _segment_rotations(gr, gn, goff, q_root)
    # normalized arc positions of the guides' segment midpoints
    _, gidx, gs0 = layout(goff)
    glen = np.linalg.norm(gr[gs0 + 1] - gr[gs0], axis=1)
    gcurve = np.repeat(np.arange(G), np.diff(goff) - 1)
    gtot = np.bincount(gcurve, glen, minlength=G)
    gcum = np.cumsum(glen) - np.repeat(np.cumsum(gtot) - gtot, np.diff(goff) - 1)
    nseg = np.diff(goff) - 1
    gmid = np.where(gtot[gcurve] > 0, (gcum - 0.5 * glen) / np.where(gtot > 0, gtot, 1)[gcurve],
                    (gidx[gs0] + 0.5) / nseg[gcurve])
    gkey = gcurve + gmid  # sorted: guide by guide, increasing along each
    gfirst = np.cumsum(nseg) - nseg
    # the render segments
    rcurve, _, rs0 = layout(roff)
    v = rp[rs0 + 1] - rp[rs0]
    rlen = np.linalg.norm(v, axis=1)
    sc = rcurve[rs0]
    rtot = np.bincount(sc, rlen, minlength=Rn)
    rn = np.diff(roff) - 1
    rcum = np.cumsum(rlen) - np.repeat(np.cumsum(rtot) - rtot, rn)
    _, ridx, _ = layout(roff)
    s = np.where(rtot[sc] > 0, (rcum - 0.5 * rlen) / np.where(rtot > 0, rtot, 1)[sc],
                 (ridx[rs0] + 0.5) / rn[sc])
    g = weights.index[sc]  # (S, k)
    w = weights.weight[sc]
    pos = np.searchsorted(gkey, g + s[:, None], "right") - 1 - gfirst[g]
    j0 = np.clip(pos, 0, nseg[g] - 1)
    j1 = np.minimum(j0 + 1, nseg[g] - 1)
    m0 = gmid[gfirst[g] + j0]
    m1 = gmid[gfirst[g] + j1]
    t = np.where(j1 > j0, np.clip((s[:, None] - m0) / np.where(j1 > j0, m1 - m0, 1), 0, 1), 0)
    q0 = q_seg[gfirst[g] + j0]
    q1 = q_seg[gfirst[g] + j1]
    q1 = np.where(np.sum(q0 * q1, -1, keepdims=True) < 0, -q1, q1)
    qs = q0 * (1 - t)[..., None] + q1 * t[..., None]
    qs /= np.linalg.norm(qs, axis=-1, keepdims=True)
    qb = _blend(qs, w)  # (S, 4)
    # roots: blended guide root frames
    rroots = rp[roff[:-1]]
    if render_roots_now is None:
        gi, wi = weights.index, weights.weight
        groot_r, groot_n = gr[goff[:-1]], gn[goff[:-1]]
        cand = groot_n[gi] + _qrot(q_root[gi], rroots[:, None] - groot_r[gi])
        new_roots = np.einsum("rk,rki->ri", wi, cand)
    else:
        new_roots = as_points(render_roots_now, "render_roots_now")
        if new_roots.shape != (Rn, 3):
            raise InputError(f"render_roots_now must have shape ({Rn}, 3)")
    step = np.zeros_like(rp)
    step[rs0 + 1] = _qrot(qb, v)
    step[roff[:-1]] = new_roots
    return segmented_cumsum(step, roff)




# ---------------------------------------------------------------- clearance_pass
def clearance_pass_v0(render_points, render_offsets, colliders, settings=None, growth=None):
    """The clearance pass before issue 11: the solver on every render curve."""
    from core import Collider, Settings, Solver

    pts, off = check_curves(render_points, render_offsets, "render_points")
    if isinstance(colliders, Collider):
        colliders = [colliders]
    solver = Solver(off, Settings(mode="stiff") if settings is None else settings)
    res = solver.step(pts, list(colliders), growth=growth)
    out = np.asarray(res.points, np.float64)
    changed = np.any(out != pts, axis=1)
    curve = np.repeat(np.arange(len(off) - 1), np.diff(off))
    n_fixed = int(np.count_nonzero(np.bincount(curve, changed, minlength=len(off) - 1)))
    return out, res.status, n_fixed


# ---------------------------------------------------------------- Binding.apply
def binding_apply_v0(binding, V_now):
    """``Binding.apply`` before issue 11: per-CV gathers of the frames."""
    from core.pipeline.attach import _frames

    O = binding.roots(V_now)
    V = np.asarray(V_now, np.float64)
    R, ok = _frames(V, binding.faces, binding.face)
    R = np.where(ok[:, None, None], R, binding.frame_ref)
    sizes = np.diff(binding.offsets)
    curve = np.repeat(np.arange(len(sizes)), sizes)
    return O[curve] + np.einsum("pij,pj->pi", R[curve], binding.local)
