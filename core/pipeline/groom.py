"""The render groom follows the collided guides (paper section 2, after O'Hagan et al. 2015).

:func:`bind_groom` picks, at the reference pose, the ``k`` nearest guide
roots of every render curve and their inverse-distance weights;
:func:`deform_groom` makes every render curve follow the rotation and bend
of its guides, blended per CV along the normalized arc length;
:func:`clearance_pass` runs FurCollide once on the result so that render
curves that still pass through a collider (between the guides) are
resolved, and counts them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import rotations as rot
from .. import tolerances as tol
from ..collider import Collider
from ..errors import InputError
from ..proximity import knn
from ..settings import Settings
from ..solver import Solver
from ..status import Status
from ._curves import as_points, check_curves, layout, segmented_cumsum, uniform_size

#: Above this share of reaching curves the clearance pass solves them all (no gather).
_CLEARANCE_ALL = 0.7
#: Neighbouring guide roots used to find each guide's root rotation.
_FRAME_NEIGHBORS = 4


@dataclass
class GroomWeights:
    """Guides of every render curve (result of :func:`bind_groom`). Arrays only.

    Attributes
    ----------
    index : (R, k) int64
        Guide curve indices, nearest first.
    weight : (R, k) float64
        Inverse-distance weights, each row sums to 1.
    """

    index: np.ndarray
    weight: np.ndarray
    #: The :class:`GroomDeformer` of the last :func:`deform_groom` call (a cache).
    _deformer: object = field(default=None, init=False, repr=False, compare=False)

    def arrays(self) -> dict:
        return {"index": self.index, "weight": self.weight}

    @classmethod
    def from_arrays(cls, d) -> GroomWeights:
        return cls(np.asarray(d["index"], np.int64), np.asarray(d["weight"], np.float64))


def bind_groom(render_roots_ref, guide_roots_ref, k=4, power=1.0) -> GroomWeights:
    """Weights of the ``k`` nearest guides of every render curve, at the reference pose.

    Parameters
    ----------
    render_roots_ref : (R, 3) array_like of float
    guide_roots_ref : (G, 3) array_like of float
    k : int, default 4
        Guides per render curve (at most G).
    power : float, default 1
        Weights are ``1 / distance ** power``, normalized; a render root on a
        guide root follows that guide only.

    Returns
    -------
    GroomWeights
    """
    Rr = as_points(render_roots_ref, "render_roots_ref")
    Gr = as_points(guide_roots_ref, "guide_roots_ref")
    for name, a in (("render_roots_ref", Rr), ("guide_roots_ref", Gr)):
        bad = ~np.isfinite(a).all(axis=1)
        if bad.any():
            raise InputError(f"{name}: curve {int(np.argmax(bad))} has a non-finite root")
    if len(Gr) == 0:
        raise InputError("bind_groom needs at least one guide")
    if isinstance(k, bool) or int(k) != k or k < 1:
        raise InputError(f"k must be a positive integer, got {k!r}")
    power = float(power)
    if not (np.isfinite(power) and power >= 0):
        raise InputError(f"power must be >= 0, got {power}")
    idx, d = knn(Rr, Gr, int(k))
    scale = float(np.linalg.norm(Gr.max(0) - Gr.min(0))) or 1.0
    zero = d <= 1e-12 * scale
    with np.errstate(divide="ignore"):
        w = np.where(zero, 0.0, 1.0 / np.where(zero, 1.0, d) ** power)
    on = zero.any(1)
    w[on] = zero[on].astype(np.float64)  # exactly on a guide root
    w /= w.sum(1, keepdims=True)
    return GroomWeights(idx, w)


# ---------------------------------------------------------------- deform
class GroomDeformer:
    """:func:`deform_groom` for one bound groom, with its bind-time work done once.

    Everything that depends only on the reference poses, the curve layouts
    and the weights is computed here: each guide's root neighbourhood, the
    rest tangents of its segments, and for every (render segment, guide)
    pair the two guide segments to interpolate and the interpolation
    parameter. :meth:`deform` then only finds the guides' rotations and
    blends them onto the render segments, in cache-sized blocks of
    component arrays. :func:`deform_groom` keeps one on its ``weights`` and
    reuses it while its inputs are equal, so callers get this for free.

    Parameters
    ----------
    render_ref_points, render_offsets, guides_ref_points, guide_offsets, weights
        As in :func:`deform_groom` (copied: later changes to the arrays do
        not affect the deformer).

    Raises
    ------
    InputError
        As :func:`deform_groom`.
    """

    #: Render segments per block of the blend (component arrays of
    #: (4, block, k) floats stay in the CPU caches).
    BLOCK = 8192

    def __init__(self, render_ref_points, render_offsets, guides_ref_points, guide_offsets,
                 weights):
        rp, roff = check_curves(render_ref_points, render_offsets, "render_ref_points")
        gr, goff = check_curves(guides_ref_points, guide_offsets, "guides_ref_points")
        if not isinstance(weights, GroomWeights):
            raise InputError(f"weights must be a GroomWeights, got {type(weights).__name__}")
        Rn, G = len(roff) - 1, len(goff) - 1
        index = np.asarray(weights.index)
        weight = np.asarray(weights.weight, np.float64)
        if index.shape[0] != Rn or weight.shape != index.shape:
            raise InputError(f"weights are for {index.shape[0]} render curves, the groom has {Rn}")
        if (index < 0).any() or (index >= G).any():
            raise InputError(f"weights index guides out of range (there are {G} guides)")
        self.rp, self.roff, self.gr, self.goff = rp, roff, gr, goff
        self.index = index.astype(np.int64)
        self.weight = weight.copy()
        self._bind_guides()
        self._bind_render()

    def _bind_guides(self):
        gr, goff = self.gr, self.goff
        G = len(goff) - 1
        curve, gidx, gs0 = layout(goff)
        self.gs0 = gs0
        # root neighbourhoods (reference pose): see _root_rotations
        roots_r = gr[goff[:-1]]
        self.nb = None
        if G > 1:
            nb, _ = knn(roots_r, roots_r, min(G, _FRAME_NEIGHBORS + 1))
            self.nb = nb[:, 1:]
            self.nb_dir = rot.normalize(roots_r[self.nb] - roots_r[:, None])
        self.t_r = rot.normalize(gr[gs0 + 1] - gr[gs0])
        seg_curve, seg_j = curve[gs0], gidx[gs0]
        self.by_index = []  # parallel transport: segment j of every guide at once
        for j in range(int(seg_j.max()) + 1 if len(gs0) else 0):
            s = np.flatnonzero(seg_j == j)
            self.by_index.append((s, seg_curve[s]))
        # normalized arc positions of the guides' segment midpoints
        glen = np.linalg.norm(gr[gs0 + 1] - gr[gs0], axis=1)
        nseg = np.diff(goff) - 1
        gcurve = np.repeat(np.arange(G), nseg)
        gtot = np.bincount(gcurve, glen, minlength=G)
        gcum = np.cumsum(glen) - np.repeat(np.cumsum(gtot) - gtot, nseg)
        self.gmid = np.where(gtot[gcurve] > 0,
                             (gcum - 0.5 * glen) / np.where(gtot > 0, gtot, 1)[gcurve],
                             (gidx[gs0] + 0.5) / nseg[gcurve])
        self.gkey = gcurve + self.gmid  # sorted: guide by guide, increasing along each
        self.gfirst = np.cumsum(nseg) - nseg
        self.nseg = nseg

    def _bind_render(self):
        rp, roff = self.rp, self.roff
        Rn = len(roff) - 1
        rcurve, ridx, rs0 = layout(roff)
        v = rp[rs0 + 1] - rp[rs0]
        rlen = np.linalg.norm(v, axis=1)
        sc = rcurve[rs0]
        rtot = np.bincount(sc, rlen, minlength=Rn)
        rn = np.diff(roff) - 1
        rcum = np.cumsum(rlen) - np.repeat(np.cumsum(rtot) - rtot, rn)
        s = np.where(rtot[sc] > 0, (rcum - 0.5 * rlen) / np.where(rtot > 0, rtot, 1)[sc],
                     (ridx[rs0] + 0.5) / rn[sc])
        itype = np.int32 if len(self.gs0) < 2**31 - 1 else np.int64
        self.i0 = np.empty(self.index[sc].shape, itype)
        self.t = np.empty(self.i0.shape)
        gf, nseg, gmid = self.gfirst, self.nseg, self.gmid
        for a in range(0, len(rs0), 1 << 18):  # bounded temporaries
            g = self.index[sc[a:a + (1 << 18)]]
            sa = s[a:a + (1 << 18), None]
            pos = np.searchsorted(self.gkey, g + sa, "right") - 1 - gf[g]
            j0 = np.clip(pos, 0, nseg[g] - 1)
            j1 = np.minimum(j0 + 1, nseg[g] - 1)
            m0, m1 = gmid[gf[g] + j0], gmid[gf[g] + j1]
            self.t[a:a + (1 << 18)] = np.where(
                j1 > j0, np.clip((sa - m0) / np.where(j1 > j0, m1 - m0, 1), 0, 1), 0)
            # where t > 0 the second segment is the next one (j1 = j0 + 1); where
            # t = 0 it does not count, so it is never stored
            self.i0[a:a + (1 << 18)] = gf[g] + j0
        self.sc = sc
        # (guide, segment) layout for the blend: contiguous rows per guide slot
        self.i0k = np.ascontiguousarray(self.i0.T)
        self.tk = np.ascontiguousarray(self.t.T)
        del self.i0, self.t
        self.weight_t = np.ascontiguousarray(self.weight.T)
        self.vT = np.ascontiguousarray(v.T)  # (3, S) render segments at rest
        sizes = np.diff(roff)
        self.uniform = int(sizes[0]) if len(sizes) and (sizes == sizes[0]).all() else 0
        self.rs0 = rs0
        groot_r = self.gr[self.goff[:-1]]
        self.rel = rp[roff[:-1]][:, None] - groot_r[self.index]  # (R, k, 3)

    def matches(self, render_ref_points, render_offsets, guides_ref_points, guide_offsets,
                weights) -> bool:
        """Were these the arguments of the constructor (equal values)?"""
        try:
            return (
                isinstance(weights, GroomWeights)
                and np.array_equal(np.asarray(render_offsets), self.roff)
                and np.array_equal(np.asarray(guide_offsets), self.goff)
                and np.array_equal(np.asarray(weights.index), self.index)
                and np.array_equal(np.asarray(weights.weight), self.weight)
                and np.array_equal(np.asarray(guides_ref_points), self.gr)
                and np.array_equal(np.asarray(render_ref_points), self.rp)
            )
        except Exception:  # noqa: BLE001 - unconvertible input: the constructor reports it
            return False

    # ----------------------------------------------------------- per frame
    def _root_rotations(self, gn):
        """Rotation of every guide at its root (G, 4): best fit of its root neighbourhood.

        Kabsch fit of the unit vectors to the nearest guide roots, so that it
        is the identity when the roots do not move (wind, collisions) and the
        exact rotation under a rigid motion. Where the neighbourhood does not
        fix a rotation (fewer than 3 guides, collinear roots) the guide's own
        strand is added; where even that fails (a lone straight guide), the
        minimal rotation of the first segment.
        """
        ref, off = self.gr, self.goff
        roots_r, roots_n = ref[off[:-1]], gn[off[:-1]]
        G = len(roots_r)
        H = np.zeros((G, 3, 3))
        if self.nb is not None:
            b = rot.normalize(roots_n[self.nb] - roots_n[:, None])
            H += np.einsum("gki,gkj->gij", self.nb_dir, b)
        R, S = rot.kabsch(H)
        q = rot.quat_from_matrix(R)
        weak = S[:, 1] <= 1e-9 * np.maximum(S[:, 0], 1e-300)
        if weak.any():
            # add the strand: its direction and the vectors from the root to its CVs
            curve, _, _ = layout(off)
            rel_r = rot.normalize(ref - roots_r[curve])
            rel_n = rot.normalize(gn - roots_n[curve])
            Hs = H + np.stack([np.bincount(curve, rel_r[:, i] * rel_n[:, j], minlength=G)
                               for i in range(3) for j in range(3)], 1).reshape(G, 3, 3)
            R2, S2 = rot.kabsch(Hs[weak])
            q[weak] = rot.quat_from_matrix(R2)
            still = S2[:, 1] <= 1e-9 * np.maximum(S2[:, 0], 1e-300)
            if still.any():
                w = np.flatnonzero(weak)[still]
                t_r = rot.normalize(ref[off[w] + 1] - roots_r[w])
                t_n = rot.normalize(gn[off[w] + 1] - roots_n[w])
                q[w] = rot.quat_swing(t_r, t_n)
        return q

    def _segment_rotations(self, gn, q_root):
        """Per-segment rotations (S, 4) of every guide, parallel-transported from the root."""
        gs0 = self.gs0
        n = uniform_size(self.goff)
        if n:
            return self._segment_rotations_uniform(gn, q_root, n)
        t_n = rot.normalize(gn[gs0 + 1] - gn[gs0])
        q = np.empty((len(gs0), 4))
        prev = q_root.copy()
        for s, c in self.by_index:  # over the CV index, vectorized over guides
            p = prev[c]
            qj = rot.quat_mul(rot.quat_swing(rot.normalize(rot.quat_rotate(p, self.t_r[s])),
                                             t_n[s]), p)
            q[s] = qj
            prev[c] = qj
        return q

    def _segment_rotations_uniform(self, gn, q_root, n):
        """:meth:`_segment_rotations` for guides of ``n`` CVs each, on component arrays
        (4, G): the formulas of rotations.quat_rotate, normalize, quat_swing, quat_mul."""
        G = len(q_root)
        g3 = gn.reshape(G, n, 3)
        tr3 = self.t_r.reshape(G, n - 1, 3)
        p = np.ascontiguousarray(q_root.T)  # (4, G)
        out = np.empty((G, n - 1, 4))
        for j in range(n - 1):
            tn = (g3[:, j + 1] - g3[:, j]).T  # (3, G)
            tn = rot._unit3(tn)
            v = rot.quat_rotate_soa(p, np.ascontiguousarray(tr3[:, j].T))
            v = rot._unit3(v)
            # quat_swing(v, tn): minimal rotation taking v to tn
            c = rot._dot3(v, tn)
            sw = np.empty((4, G))
            sw[0] = 1.0 + c
            sw[1:] = rot._cross3(v, tn)
            anti = c < -1 + 1e-12
            if anti.any():
                sw[:, anti] = rot.quat_swing(v[:, anti].T, tn[:, anti].T).T
            sw /= np.sqrt(sw[0] * sw[0] + rot._dot3(sw[1:], sw[1:]))
            # quat_mul(sw, p)
            q = np.empty((4, G))
            q[0] = sw[0] * p[0] - rot._dot3(sw[1:], p[1:])
            q[1:] = sw[0] * p[1:] + p[0] * sw[1:] + rot._cross3(sw[1:], p[1:])
            out[:, j] = q.T
            p = q
        return out.reshape(-1, 4)

    def _blend_block(self, Qt, flip, a, b, out):
        """Rotated render segments ``a:b`` into ``out`` (3, S): per guide, the rotation
        interpolated along it (sign-aligned nlerp), then the weighted sign-aligned
        average over the guides, applied to the rest segment.

        ``flip`` (GS,) is true where a guide segment's rotation and the next one's
        have a negative dot product: the nlerp then takes the next one negated.
        Arrays are (component, guide, segment): every pass runs over contiguous
        rows of the block's segments.
        """
        i0, t = self.i0k[:, a:b], self.tk[:, a:b]  # (k, n)
        q0 = np.empty((4,) + i0.shape)
        q1 = np.empty_like(q0)
        i1 = i0 + (t > 0)
        for c in range(4):
            np.take(Qt[c], i0, out=q0[c])
            np.take(Qt[c], i1, out=q1[c])
        t1 = np.where(flip.take(i0), -t, t)  # (-q1) t = q1 (-t)
        qs = q0 * (1 - t)
        q1 *= t1
        qs += q1
        n = qs[0] * qs[0]
        for c in (1, 2, 3):
            n += qs[c] * qs[c]
        np.sqrt(n, out=n)
        # sign-aligned with the first guide's, weighted; the nlerp's normalization
        # folded into the weights
        d = qs[0] * qs[0, :1]
        for c in (1, 2, 3):
            d += qs[c] * qs[c, :1]
        sw = self.weight_t[:, self.sc[a:b]]
        sw /= n
        np.negative(sw, out=sw, where=d < 0)
        m = qs[:, 0] * sw[0]
        for k in range(1, len(sw)):
            m += qs[:, k] * sw[k]
        n = m[0] * m[0]
        for c in (1, 2, 3):
            n += m[c] * m[c]
        m /= np.sqrt(n)
        out[:, a:b] = rot.quat_rotate_soa(m, self.vT[:, a:b])

    def deform(self, guides_now_points, render_roots_now=None) -> np.ndarray:
        """The render groom following ``guides_now_points`` (see :func:`deform_groom`).

        Returns
        -------
        (P, 3) ndarray of float64
        """
        gn, _ = check_curves(guides_now_points, self.goff, "guides_now_points")
        roff = self.roff
        Rn = len(roff) - 1
        if render_roots_now is not None:
            new_roots = as_points(render_roots_now, "render_roots_now")
            if new_roots.shape != (Rn, 3):
                raise InputError(f"render_roots_now must have shape ({Rn}, 3)")
        q_root = self._root_rotations(gn)
        Qt = np.ascontiguousarray(self._segment_rotations(gn, q_root).T)  # (4, GS)
        d = Qt[0, :-1] * Qt[0, 1:]
        for c in (1, 2, 3):
            d += Qt[c, :-1] * Qt[c, 1:]
        flip = np.append(d < 0, False)  # (the next of a guide's last: never used)
        S = len(self.rs0)
        seg = np.empty((3, S))
        for a in range(0, S, self.BLOCK):
            self._blend_block(Qt, flip, a, min(S, a + self.BLOCK), seg)
        if render_roots_now is None:  # blended guide root frames
            gi = self.index
            groot_n = gn[self.goff[:-1]]
            qT = np.ascontiguousarray(q_root.T)[:, gi]  # (4, R, k)
            cand = rot.quat_rotate_soa(qT, np.moveaxis(self.rel, -1, 0))
            cand += np.moveaxis(groot_n[gi], -1, 0)
            new_roots = np.einsum("rk,irk->ri", self.weight, cand)
        if self.uniform:
            n = self.uniform
            out = np.empty((Rn, n, 3))
            out[:, 0] = new_roots
            for i in range(3):
                out[:, 1:, i] = seg[i].reshape(Rn, n - 1)
            for j in range(1, n):  # the sums of np.cumsum(axis=1), one CV column a pass
                out[:, j] += out[:, j - 1]
            return out.reshape(-1, 3)
        step = np.empty_like(self.rp)
        step[self.rs0 + 1] = seg.T
        step[roff[:-1]] = new_roots
        return segmented_cumsum(step, roff)


def deform_groom(render_ref_points, render_offsets, guides_ref_points, guides_now_points,
                 guide_offsets, weights, render_roots_now=None):
    """Every render curve follows the rotation and bend of its guides.

    For each guide, the rotation of every segment from the reference to
    the current pose is found (parallel transport from a root rotation
    fitted to the guide and its neighbouring guide roots). A render
    curve's segment at normalized arc length ``s`` takes, from each of its
    guides, the rotation interpolated at ``s`` along the guide, blends them
    with the weights (quaternion averaging), and the curve is re-chained
    from its root, which follows the guides' root frames.

    Everything that depends only on the reference poses and the weights is
    computed on the first call and kept on ``weights`` (a
    :class:`GroomDeformer`), reused while the reference arrays, offsets and
    weights are equal (checked every call); per frame only the guides'
    rotations and the blend remain.

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
    if not isinstance(weights, GroomWeights):
        raise InputError(f"weights must be a GroomWeights, got {type(weights).__name__}")
    deformer = weights._deformer
    if deformer is None or not deformer.matches(render_ref_points, render_offsets,
                                                guides_ref_points, guide_offsets, weights):
        weights._deformer = None  # never keep a stale one behind an error
        deformer = GroomDeformer(render_ref_points, render_offsets, guides_ref_points,
                                 guide_offsets, weights)
        weights._deformer = deformer
    return deformer.deform(guides_now_points, render_roots_now)


def clearance_pass(render_points, render_offsets, colliders, settings=None, growth=None):
    """Final clearance: FurCollide once on the render curves, counting those it moved.

    Render curves that still pass through a collider after
    :func:`deform_groom` (between the guides) are resolved by the core's
    solver with a fresh state (Stiff mode by default: minimal rotation at
    the root, shape kept). Only the curves whose bounding box meets a
    collider's bounds go to the solver: the others can neither cross a
    collider nor have their root inside one, so the solver would return them
    unchanged and FREE (a curve's result never depends on the other curves
    solved with it: the same output as solving them all).

    Parameters
    ----------
    render_points : (P, 3) array_like of float
    render_offsets : (R+1,) array_like of int
    colliders : sequence of Collider
    settings : Settings, optional
        Default ``Settings(mode="stiff")``.
    growth : Collider, optional
        Growth surface (for the settings that need it).

    Returns
    -------
    points : (P, 3) ndarray of float64
    status : (R,) int8 ndarray
        :class:`core.Status` per render curve.
    n_fixed : int
        Number of render curves the pass had to move.
    """
    pts, off = check_curves(render_points, render_offsets, "render_points")
    if isinstance(colliders, Collider):
        colliders = [colliders]
    colliders = list(colliders)
    settings = Settings(mode="stiff") if settings is None else settings
    R = len(off) - 1
    reach = _reaching(pts, off, colliders, settings)
    if R and not reach.any():
        reach[0] = True  # (one curve, unchanged: the solver still checks its other inputs)
    if R == 0 or reach.mean() > _CLEARANCE_ALL:  # (gathering would cost more than it saves)
        res = Solver(off, settings).step(pts, colliders, growth=growth)
        out = np.asarray(res.points, np.float64)
        changed = np.any(out != pts, axis=1)
        curve = np.repeat(np.arange(R), np.diff(off))
        return out, res.status, int(np.count_nonzero(np.bincount(curve, changed, minlength=R)))
    out = pts.copy()
    status = np.zeros(R, np.int8)
    status[_degenerate(pts, off, ~reach)] = Status.INVALID  # as the solver marks them
    idx = np.flatnonzero(reach)
    sizes = np.diff(off)[idx]
    rows = np.repeat(off[idx] - (np.cumsum(sizes) - sizes), sizes) + np.arange(int(sizes.sum()))
    sub_off = np.concatenate([[0], np.cumsum(sizes)])
    res = Solver(sub_off, settings).step(pts[rows], colliders, growth=growth)
    sub = np.asarray(res.points, np.float64)
    out[rows] = sub
    status[idx] = res.status
    changed = np.any(sub != pts[rows], axis=1)
    curve = np.repeat(np.arange(len(idx)), sizes)
    n_fixed = int(np.count_nonzero(np.bincount(curve, changed, minlength=len(idx))))
    return out, status, n_fixed


def _degenerate(pts, off, which):
    """The solver's zero-length segment rule (``tolerances.ZERO_SEGMENT_REL``) on
    the curves ``which`` (bool (R,)): culled curves are INVALID as they would be
    in the solver. Returns (R,) bool."""
    d = np.diff(pts, axis=0)
    L = np.sqrt(np.einsum("ij,ij->i", d, d))
    _, _, s0 = layout(off)
    L = L[s0]
    nseg = np.diff(off) - 1
    first = np.cumsum(nseg) - nseg
    total = np.add.reduceat(L, first) if len(L) else np.zeros(0)
    short = np.minimum.reduceat(L, first) if len(L) else np.zeros(0)
    return which & ~(short > tol.ZERO_SEGMENT_REL * total)


def _reaching(pts, off, colliders, settings):
    """(R,) bool: curves whose bounding box meets the (offset) bounds of a collider.

    The box is grown by a relative margin far above the solver's ray
    extension (``tolerances.RAY_EXTEND_ULPS`` float32 ulps), so every curve
    the solver could touch is kept.
    """
    R = len(off) - 1
    n = uniform_size(off)
    if n:  # column by column: reductions over 8 CVs are slow
        P3 = pts.reshape(R, n, 3)
        lo, hi = P3[:, 0].copy(), P3[:, 0].copy()
        for j in range(1, n):
            np.minimum(lo, P3[:, j], out=lo)
            np.maximum(hi, P3[:, j], out=hi)
    else:
        lo = np.minimum.reduceat(pts, off[:-1], axis=0)
        hi = np.maximum.reduceat(pts, off[:-1], axis=0)
    reach = np.zeros(R, bool)
    for c in colliders:
        if not isinstance(c, Collider) or c.empty:
            continue  # (the solver reports a wrong type)
        blo, bhi = c.bounds_world(c.effective_offset(settings.collision_offset))
        pad = 1e-4 * (float(np.linalg.norm(bhi - blo)) + float(np.abs(np.r_[blo, bhi]).max()))
        reach |= ((lo <= bhi + pad) & (hi >= blo - pad)).all(1)
    return reach
