"""The render groom follows the collided guides (paper section 2, after O'Hagan et al. 2015).

:func:`bind_groom` picks, at the reference pose, the ``k`` nearest guide
roots of every render curve and their inverse-distance weights;
:func:`deform_groom` makes every render curve follow the rotation and bend
of its guides, blended per CV along the normalized arc length;
:func:`clearance_pass` runs FurCollide once on the result so that render
curves that still pass through a collider (between the guides) are
resolved, and counts them. :class:`GroomBinding` is a whole bound groom
(curves set aside, roots on the surface) with its own deformer, as the
Blender glue saves it on the groom output and deforms it every frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import rotations as rot
from .. import tolerances as tol
from ..collider import Collider
from ..curves import (
    as_given,
    as_points,
    check_curves,
    degenerate,
    invalid_curves,
    layout,
    segmented_cumsum,
    subset,
    uniform_size,
)
from ..errors import InputError
from ..proximity import knn
from ..rays import in_two, thread_count
from ..settings import MAX_DISTANCE, Settings
from ..solver import Solver
from ..splines import DrawnMargin
from ..status import Status
from .attach import Binding, bind
from .distance import LowerBoundField

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
    component arrays. Build one per bound groom and call :meth:`deform` every
    frame (:class:`GroomBinding` owns one); :func:`deform_groom` builds one per
    call.

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
            # (3, G, k) component arrays: the per-frame fit sums over k in rows
            self.nb_dir = np.ascontiguousarray(
                np.moveaxis(rot.normalize(roots_r[self.nb] - roots_r[:, None]), -1, 0))
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

    # ----------------------------------------------------------- per frame
    def _root_rotations(self, gn):
        """Rotation of every guide at its root (G, 4): best fit of its root neighbourhood.

        Kabsch fit of the unit vectors to the nearest guide roots, so that it
        is the identity when the roots do not move (wind, collisions) and the
        exact rotation under a rigid motion. Where the neighbourhood does not
        fix a rotation (fewer than 3 guides, collinear roots) the guide's own
        strand is added; where even that fails (a lone straight guide), the
        minimal rotation of the first segment.

        The fit is :func:`rotations.quat_fit` (no SVD, five times faster);
        where it is not trusted (``tol.QUAT_FIT_GAP``: about 1 % of guides,
        and every neighbourhood that does not fix a rotation) the SVD's
        :func:`rotations.kabsch`, whose singular values decide as before
        which guides add their strand.
        """
        ref, off = self.gr, self.goff
        roots_r, roots_n = ref[off[:-1]], gn[off[:-1]]
        G = len(roots_r)
        h = np.zeros((3, 3, G))  # H[g, i, j] = h[i, j, g]: sum over neighbours of a_i b_j
        H = h.transpose(2, 0, 1)
        if self.nb is not None:
            # on one thread: ~30 short numpy passes over the guides, which two threads
            # only interleave (measured at 7,500 guides: 2.3 ms on one, 2.7 ms on two)
            rn = np.ascontiguousarray(roots_n.T)  # (3, G)
            d = rn[:, self.nb]  # (3, G, k): unit vectors to the neighbouring roots
            d -= rn[:, :, None]
            n = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            np.divide(d, n, out=d, where=n > 0)
            for i in range(3):
                for j in range(3):
                    np.einsum("gk,gk->g", self.nb_dir[i], d[j], out=h[i, j])
        q, ok = rot.quat_fit(H)
        # a trusted fit's top eigenvalue stands clear of the next one, so its second
        # singular value is far above the 1e-9 below: only the SVD's can be weak
        svd = np.flatnonzero(~ok)
        weak = np.zeros(G, bool)
        if len(svd):
            R, S = rot.kabsch(H[svd])
            q[svd] = rot.quat_from_matrix(R)
            weak[svd] = S[:, 1] <= 1e-9 * np.maximum(S[:, 0], 1e-300)
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
            tn = rot.unit3(tn)
            v = rot.quat_rotate_soa(p, np.ascontiguousarray(tr3[:, j].T))
            v = rot.unit3(v)
            # quat_swing(v, tn): minimal rotation taking v to tn
            c = rot.dot3(v, tn)
            sw = np.empty((4, G))
            sw[0] = 1.0 + c
            sw[1:] = rot.cross3(v, tn)
            anti = c < -1 + 1e-12
            if anti.any():
                sw[:, anti] = rot.quat_swing(v[:, anti].T, tn[:, anti].T).T
            sw /= np.sqrt(sw[0] * sw[0] + rot.dot3(sw[1:], sw[1:]))
            # quat_mul(sw, p)
            q = np.empty((4, G))
            q[0] = sw[0] * p[0] - rot.dot3(sw[1:], p[1:])
            q[1:] = sw[0] * p[1:] + p[0] * sw[1:] + rot.cross3(sw[1:], p[1:])
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

    def deform(self, guides_now_points, render_roots_now=None, threads=None) -> np.ndarray:
        """The render groom following ``guides_now_points`` (see :func:`deform_groom`).

        Returns
        -------
        (P, 3) ndarray of float64
        """
        threads = thread_count(threads)
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

        def blend(a, b):  # render segments a:b (per segment: any cut gives the same bits)
            for s in range(a, b, self.BLOCK):
                self._blend_block(Qt, flip, s, min(b, s + self.BLOCK), seg)

        def roots(c0, c1):  # render curves c0:c1
            if render_roots_now is not None:
                return new_roots[c0:c1]
            gi = self.index[c0:c1]  # blended guide root frames
            qT = np.ascontiguousarray(q_root.T)[:, gi]  # (4, r, k)
            cand = rot.quat_rotate_soa(qT, np.moveaxis(self.rel[c0:c1], -1, 0))
            cand += np.moveaxis(gn[self.goff[:-1]][gi], -1, 0)
            return np.einsum("rk,irk->ri", self.weight[c0:c1], cand)

        if self.uniform:
            n = self.uniform
            out = np.empty((Rn, n, 3))

            def chain(c0, c1):  # render curves c0:c1, whole: blend, roots, re-chain
                blend(c0 * (n - 1), c1 * (n - 1))
                o = out[c0:c1]
                o[:, 0] = roots(c0, c1)
                for i in range(3):
                    o[:, 1:, i] = seg[i, c0 * (n - 1):c1 * (n - 1)].reshape(c1 - c0, n - 1)
                for j in range(1, n):  # the sums of np.cumsum(axis=1), one CV column a pass
                    o[:, j] += o[:, j - 1]

            in_two(chain, Rn, threads, tol.SPLIT_MIN_ITEMS)
            return out.reshape(-1, 3)
        in_two(blend, S, threads, tol.SPLIT_MIN_ITEMS)
        step = np.empty_like(self.rp)
        step[self.rs0 + 1] = seg.T
        step[roff[:-1]] = roots(0, Rn)
        return segmented_cumsum(step, roff)


def deform_groom(render_ref_points, render_offsets, guides_ref_points, guides_now_points,
                 guide_offsets, weights, render_roots_now=None, threads=None):
    """Every render curve follows the rotation and bend of its guides.

    For each guide, the rotation of every segment from the reference to
    the current pose is found (parallel transport from a root rotation
    fitted to the guide and its neighbouring guide roots). A render
    curve's segment at normalized arc length ``s`` takes, from each of its
    guides, the rotation interpolated at ``s`` along the guide, blends them
    with the weights (quaternion averaging), and the curve is re-chained
    from its root, which follows the guides' root frames.

    Everything that depends only on the reference poses and the weights (a
    :class:`GroomDeformer`) is computed by every call: frame after frame, build
    the deformer once and call its :meth:`GroomDeformer.deform` (or use a
    :class:`GroomBinding`), so that only the guides' rotations and the blend
    remain per frame.

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
    threads : int or None, default None
        Threads to use (None: every CPU). From ``tolerances.SPLIT_MIN_ITEMS`` guides or
        render curves the work runs in parts, one per thread; the result
        is the same bit for bit.

    Returns
    -------
    (P, 3) ndarray of float64
        Identity when the guides do not move; a rigid motion of all guides
        moves the groom rigidly. Segment lengths are kept.
    """
    deformer = GroomDeformer(render_ref_points, render_offsets, guides_ref_points,
                             guide_offsets, weights)
    return deformer.deform(guides_now_points, render_roots_now, threads)


# ---------------------------------------------------------------- binding
class GroomBinding:
    """A render groom bound to guides: the reference poses, each render curve's guides
    and weights (:func:`bind_groom`) and, optionally, the render roots bound to the
    growth surface (Fur Attach); every frame :meth:`deform` makes the groom follow the
    guides with the binding's own :class:`GroomDeformer` (its bind-time work, made on
    the first :meth:`deform` and kept with the binding).

    Render curves the solver cannot work with (:func:`core.curves.invalid_curves`) are
    set aside (``invalid``): they are shown as they are (moved rigidly with their
    surface triangle when the roots are bound to it), ``Status.INVALID``. So are
    guides: the render curves follow the others.

    Parameters
    ----------
    arrays : dict of ndarray
        What :meth:`build` returns (saved and loaded as they are, e.g. ``np.savez``).

    Attributes
    ----------
    render_ref, render_offsets, guides_ref, guide_offsets
        The reference poses (world) and layouts.
    invalid : (R,) bool
        Render curves set aside.
    guides_used : (G,) bool
        Guides the render curves follow.
    weights : GroomWeights
        Of the valid render curves, over the used guides.
    roots, fixed : Binding or None
        The valid render curves' roots, and the invalid curves, bound to the surface.
    surface_key : tuple of int or None
        The caller's key of the surface's topology at bind time.
    guides_k : int
        Guides per render curve asked for.
    note : str
        What :meth:`build` set aside, or ''.
    groom_name, groom_digest, groom_counts
        What the caller recorded to recognise the bound groom later (``record`` of
        :meth:`build`): '' / None / (0, 0) when not recorded.
    """

    def __init__(self, arrays: dict):
        self.render_ref = np.asarray(arrays["render_ref"], np.float64)
        self.render_offsets = np.asarray(arrays["render_offsets"], np.int64)
        self.guides_ref = np.asarray(arrays["guides_ref"], np.float64)
        self.guide_offsets = np.asarray(arrays["guide_offsets"], np.int64)
        R, G = len(self.render_offsets) - 1, len(self.guide_offsets) - 1
        self.invalid = np.asarray(arrays.get("invalid", np.zeros(R, bool)), bool)
        self.guides_used = np.asarray(arrays.get("guides_used", np.ones(G, bool)), bool)
        self.weights = GroomWeights.from_arrays(
            {"index": arrays["weights_index"], "weight": arrays["weights_weight"]}
        )
        self.roots = None
        self.fixed = None
        self.surface_key = None
        if "root_face" in arrays:
            self.roots = Binding.from_arrays(
                {k[5:]: arrays[k] for k in arrays if k.startswith("root_")}
            )
            self.surface_key = tuple(int(k) for k in arrays["surface_key"])
        if "fixed_face" in arrays:
            self.fixed = Binding.from_arrays(
                {k[6:]: arrays[k] for k in arrays if k.startswith("fixed_")}
            )
        self.groom_name = str(arrays["groom_name"]) if "groom_name" in arrays else ""
        self.groom_digest = (int(np.asarray(arrays["groom_digest"]).view(np.uint64)[0])
                             if "groom_digest" in arrays else None)
        self.groom_counts = tuple(int(k) for k in arrays.get("groom_counts", (0, 0)))
        self.guides_k = int(arrays["guides_k"]) if "guides_k" in arrays else 0
        self.note = str(arrays["note"]) if "note" in arrays else ""
        self._rows_v, self._off_v = self.subset(~self.invalid)
        self._rows_i, _ = self.subset(self.invalid)
        self._g_rows, self._g_off = subset(self.guide_offsets, self.guides_used)
        #: This binding's GroomDeformer (made by the first :meth:`deform`).
        self.deformer = None

    def subset(self, which):
        """(rows (k,), offsets) of the render curves ``which`` (bool (R,))."""
        return subset(self.render_offsets, which)

    @staticmethod
    def build(render_ref, render_offsets, guides_ref, guide_offsets, k, surface=None,
              name="the render groom", record=None):
        """Bind (all world space, reference pose).

        Parameters
        ----------
        render_ref : (P, 3) float array
        render_offsets : (R+1,) int array
        guides_ref : (Q, 3) float array
        guide_offsets : (G+1,) int array
        k : int
            Guides per render curve.
        surface : (V, F, key) or None
            The surface (world) the render roots stay on, and the caller's key of
            its topology (kept as ``surface_key``).
        name : str
            The render groom in messages ("No curve of {name} can be used").
        record : dict, optional
            ``groom_name``, ``groom_digest`` (an int), ``groom_counts`` (curves,
            points): what the caller needs to recognise the bound groom later.

        Returns
        -------
        arrays : dict
            What :class:`GroomBinding` is made of (save it as it is).
        notes : list of str
            The curves set aside (invalid render curves, guides), naming the first.

        Raises
        ------
        InputError
            No render curve (or no guide) can be used.
        """
        render_offsets = np.asarray(render_offsets, np.int64)
        guide_offsets = np.asarray(guide_offsets, np.int64)
        bad_r, why_r = invalid_curves(render_ref, render_offsets)
        bad_g, why_g = invalid_curves(guides_ref, guide_offsets)
        if bad_r.all():
            raise InputError(f"No curve of {name} can be used: {why_r}")
        if bad_g.all():
            raise InputError(f"No guide can be followed: {why_g}")
        render_ref = as_given(render_ref, render_offsets, bad_r)
        guides_ref = as_given(guides_ref, guide_offsets, bad_g)
        rows_v, off_v = subset(render_offsets, ~bad_r)
        g_rows, g_off = subset(guide_offsets, ~bad_g)
        weights = bind_groom(render_ref[rows_v][off_v[:-1]], guides_ref[g_rows][g_off[:-1]],
                             k=min(int(k), len(g_off) - 1))
        arrays = {
            "render_ref": render_ref, "render_offsets": render_offsets,
            "guides_ref": guides_ref, "guide_offsets": guide_offsets,
            "weights_index": weights.index, "weights_weight": weights.weight,
            "invalid": bad_r, "guides_used": ~bad_g, "guides_k": np.int64(k),
        }
        if surface is not None:
            V, F, key = surface
            b = bind(render_ref[rows_v], off_v, V, F, drop_degenerate=True)
            arrays.update({"root_" + n: v for n, v in b.arrays().items()})
            if bad_r.any():
                rows_i, off_i = subset(render_offsets, bad_r)
                b = bind(render_ref[rows_i], off_i, V, F, drop_degenerate=True)
                arrays.update({"fixed_" + n: v for n, v in b.arrays().items()})
            arrays["surface_key"] = np.asarray(key, np.int64)
        if record is not None:
            arrays["groom_name"] = np.array(record["groom_name"])
            arrays["groom_digest"] = np.array([record["groom_digest"]], np.uint64).view(
                np.int64)
            arrays["groom_counts"] = np.asarray(record["groom_counts"], np.int64)
        notes = []
        if bad_r.any():
            n = int(bad_r.sum())
            notes.append(
                f"{n} curve{'s' if n > 1 else ''} of {name} cannot be solved ({why_r}): "
                f"{'they are' if n > 1 else 'it is'} shown as {'they are' if n > 1 else 'it is'},"
                " in yellow (Invalid). Fix the groom's curves and press Bind Groom again")
        if bad_g.any():
            n = int(bad_g.sum())
            notes.append(f"{n} guide{'s' if n > 1 else ''} cannot be followed ({why_g}): "
                         "the render curves follow the others")
        if notes:
            arrays["note"] = np.array("Render groom: " + "; ".join(notes))
        return arrays, notes

    def deform(self, guides_now, surface_V=None, threads=None):
        """The render curves following ``guides_now`` (world), on ``threads``
        threads (None: all CPUs; the same result for any count).

        Parameters
        ----------
        guides_now : (Q, 3) array_like
            The guides now (e.g. the solver's output), the bound layout.
        surface_V : (n, 3) array_like, optional
            The surface's world vertices now (the roots follow it when bound).

        Returns
        -------
        points : (P, 3) float64 ndarray
        status : (R,) int8 ndarray
            ``Status.INVALID`` for the curves set aside (and any the guides made
            non-finite this frame: they are shown at their reference shape), else FREE.
        """
        roots = None
        if self.roots is not None and surface_V is not None:
            roots = self.roots.roots(surface_V)
        if self.deformer is None:
            self.deformer = GroomDeformer(
                self.render_ref[self._rows_v], self._off_v, self.guides_ref[self._g_rows],
                self._g_off, self.weights)
        gn = np.asarray(guides_now, np.float64)[self._g_rows]
        moved = self.deformer.deform(gn, roots, threads)
        status = np.where(self.invalid, Status.INVALID, Status.FREE).astype(np.int8)
        if len(self._rows_i):
            points = self.render_ref.copy()
            points[self._rows_v] = moved
            if self.fixed is not None and surface_V is not None:
                points[self._rows_i] = self.fixed.apply(surface_V, threads)
        else:  # (every curve is valid: the deformer's result as it is)
            points = np.asarray(moved, np.float64)
        if not np.isfinite(points.sum()):  # (a guide degenerated this frame: never NaN)
            finite = np.isfinite(points).all(axis=1)
            R = len(self.render_offsets) - 1
            curve = np.repeat(np.arange(R), np.diff(self.render_offsets))
            bad = np.zeros(R, bool)
            bad[curve[~finite]] = True
            rows, _ = self.subset(bad)
            points[rows] = self.render_ref[rows]
            status[bad] = Status.INVALID
        return points, status


class ClearanceMargins:
    """The drawn margins of one clearance pass, kept between frames: a
    :class:`core.splines.DrawnMargin` for its settings and one for its fallback's
    (each keeps its last margin and what it was computed from: a groom that does not
    move is not measured again). One per pass that runs every frame (a setup's render
    groom, its children).
    """

    def __init__(self):
        self.settings = DrawnMargin()
        self.fallback = DrawnMargin()


def drawn_settings(settings, splines, points, offsets, drawn=None) -> Settings:
    """``settings`` with their clearance widened so that the curves Blender draws
    through ``points`` as ``splines`` clear the colliders wherever their polygons keep
    the widened clearance, through any solve of ``settings``.

    The widening is the largest drawn margin of the curves
    (:func:`core.splines.clearance_margin`, rounded up as ``DrawnMargin`` does), added
    to ``Settings.clearance_margin`` for every curve: one offset shell per collider,
    as :func:`core.pipeline.frame.drawn_clearance`; one value for all curves also
    keeps each curve's result independent of the others solved with it. The same
    ``settings`` object when nothing is widened (``splines`` None, every curve Poly,
    or straight curves): a pass on polygons is exactly the pass without splines.

    Parameters
    ----------
    settings : Settings
    splines : core.splines.Splines or None
        Bezier handles in the space of ``points``.
    points : (P, 3) ndarray
    offsets : (C+1,) ndarray
    drawn : core.splines.DrawnMargin, optional
        Keeps the last margin; a new one when not given.
    """
    if splines is None or splines.drawn_as_polygon:
        return settings
    widen = (DrawnMargin() if drawn is None else drawn).largest(splines, points, offsets,
                                                                 settings)
    if widen <= 0.0:
        return settings
    have = settings.clearance_margin
    if isinstance(have, np.ndarray):
        return settings.replace(clearance_margin=np.minimum(have + widen, MAX_DISTANCE))
    return settings.replace(clearance_margin=min(float(have) + widen, MAX_DISTANCE))


def clearance_pass(render_points, render_offsets, colliders, settings=None, growth=None,
                   fallback=None, splines=None, margins=None):
    """Final clearance: FurCollide once on the render curves, counting those it moved.

    Render curves that still pass through a collider after
    :func:`deform_groom` (between the guides) are resolved by the core's
    solver with a fresh state (Stiff mode by default: minimal rotation at
    the root, shape kept). Only the curves that may touch a collider go to
    the solver; every other curve is one the solver would return unchanged
    and FREE (or PINCHED: its root inside a closed collider, unchanged), so
    it is marked so without solving it. A curve may touch a collider when
    its bounding box meets the collider's (offset) bounds, its bounding
    ball comes near the collider's surface (``Collider.near_surface``) and,
    for a collider whose shape has not changed since the last pass, one of
    its segments comes near the surface (a lower-bound distance field of
    the collider, built once per shape: :class:`_ClearanceField`). A curve's
    result never depends on the other curves solved with it, nor on the
    previous frames: the output is that of solving every curve.

    Curves the solver cannot work with (a zero-length segment, a non-finite
    point) are left as they are and marked ``Status.INVALID``, as the solver
    marks them; the output never holds NaN.

    Parameters
    ----------
    render_points : (P, 3) array_like of float
    render_offsets : (R+1,) array_like of int
    colliders : sequence of Collider
    settings : Settings, optional
        Default ``Settings(mode="stiff")``. A parameter map (``Settings.mapped``)
        has one value per render curve (``R``); so has ``fallback``'s.
    growth : Collider, optional
        Growth surface (for the settings that need it).
    fallback : Settings, optional
        Curves ``settings`` leave ``UNRESOLVED`` (no rotation within Max Angle
        clears them) are solved again, from their input, with these settings
        (e.g. Bend: a bent curve clears where a rigidly turned one cannot); the
        second result is kept where it resolves the curve. Curves still
        unresolved keep the status ``UNRESOLVED``.
    splines : core.splines.Splines, optional
        How Blender draws the render curves (their curve types; Bezier handles in the
        space of ``render_points``): each solve (the settings' and the fallback's)
        widens its clearance by the curves' drawn margin for its own settings
        (:func:`drawn_settings`), so that the drawn curve clears the colliders, not
        only its control polygon. None, or every curve Poly: the polygons, exactly
        as without.
    margins : ClearanceMargins, optional
        Keeps the last drawn margins (one per pass that runs every frame); new ones
        when not given.

    Returns
    -------
    points : (P, 3) ndarray of float64
    status : (R,) int8 ndarray
        :class:`core.Status` per render curve.
    n_fixed : int
        Number of render curves the pass had to move.

    Raises
    ------
    InputError
        Malformed curves, or ``splines`` of another number of curves.
    SettingsError
        A parameter map of ``settings`` or ``fallback`` without one value per curve.
    """
    pts, off = check_curves(render_points, render_offsets, "render_points", finite=False)
    if isinstance(colliders, Collider):
        colliders = [colliders]
    colliders = list(colliders)
    settings = Settings(mode="stiff") if settings is None else settings
    R = len(off) - 1
    for s in (settings, fallback):  # (a map of another length: named, before any work)
        if isinstance(s, Settings):
            s.check_curve_count(R)
    if splines is not None:
        if len(splines.types) != R:
            raise InputError(f"splines describe {len(splines.types)} curves, "
                             f"render_offsets {R}")
        margins = ClearanceMargins() if margins is None else margins
        settings = drawn_settings(settings, splines, pts, off, margins.settings)
    nonfinite = np.zeros(R, bool)
    finite = None  # (None: every point is finite, the usual case)
    if not np.isfinite(pts.reshape(-1)).all():
        finite = np.isfinite(pts).all(axis=1)
        nonfinite[np.repeat(np.arange(R), np.diff(off))[~finite]] = True
    clean = pts if finite is None else np.where(finite[:, None], pts, 0.0)
    solve = _to_solve(clean, off, colliders, settings, nonfinite)
    solve |= nonfinite  # the solver sets them aside (INVALID, never NaN)
    if R and not solve.any():
        solve[0] = True  # (one curve, unchanged: the solver still checks its other inputs)
    status = np.zeros(R, np.int8)
    n = uniform_size(off)
    if R == 0 or solve.mean() > tol.CLEARANCE_SOLVE_ALL:  # (gathering would cost more)
        res = Solver(off, settings).step(pts, colliders, growth=growth)
        out = np.asarray(res.points, np.float64)
        status = res.status
        idx = np.arange(R)
    else:
        out = pts.copy()
        status[_degenerate(pts, off, np.flatnonzero(~solve), n)] = Status.INVALID  # (as the
        idx = np.flatnonzero(solve)  # solver marks them)
        sub, sub_off = _take(pts, off, idx, n)
        res = Solver(sub_off, settings.take(idx)).step(sub, colliders, growth=growth)
        _put(out, off, idx, n, res.points)
        status[idx] = res.status
    if fallback is not None and R:
        again = np.flatnonzero(status == Status.UNRESOLVED)
        if len(again):
            if splines is not None:  # (measured only when the fallback runs: most frames
                # free every curve with the settings; the widening is still every curve's)
                fallback = drawn_settings(fallback, splines, pts, off, margins.fallback)
            sub, sub_off = _take(pts, off, again, n)
            res = Solver(sub_off, fallback.take(again)).step(sub, colliders, growth=growth)
            took = res.status != Status.UNRESOLVED
            if took.any():
                keep = again[took]
                _put(out, off, keep, n, _take(np.asarray(res.points, np.float64), sub_off,
                                              np.flatnonzero(took), n)[0])
                status[keep] = res.status[took]
    # only the solved curves can have moved (a non-finite one is INVALID)
    with np.errstate(invalid="ignore"):
        if n:
            moved = _rows_any(out.reshape(R, -1)[idx] != pts.reshape(R, -1)[idx])
        else:
            moved = (_take(out, off, idx, 0)[0] != _take(pts, off, idx, 0)[0]).any(axis=1)
            sizes = np.diff(off)[idx]
            moved = (np.logical_or.reduceat(moved, np.cumsum(sizes) - sizes) if len(idx)
                     else np.zeros(0, bool))
    return out, status, int(np.count_nonzero(moved & (status[idx] != Status.INVALID)))


def _take(pts, off, idx, n):
    """Points and offsets of the curves ``idx`` as a curve set of their own
    (``n``: the common point count, 0 if none)."""
    if n:
        return (pts.reshape(-1, n, 3)[idx].reshape(-1, 3),
                np.arange(len(idx) + 1, dtype=np.int64) * n)
    rows, sub_off = _gather(off, idx)
    return pts[rows], sub_off


def _rows_any(B):
    """``B.any(axis=1)`` of a (k, m) bool array, a few words per row at a time
    (numpy's reductions over short rows are slow)."""
    B = np.ascontiguousarray(B)
    k, m = B.shape
    if m % 8 == 0:
        W = B.view(np.uint64)
    else:
        W = B.view(np.uint8)
    acc = W[:, 0].copy()
    for j in range(1, W.shape[1]):
        acc |= W[:, j]
    return acc != 0


def _put(out, off, idx, n, values):
    """``out``'s rows of the curves ``idx`` set to ``values`` (their points in order)."""
    if n:
        out.reshape(-1, n, 3)[idx] = np.asarray(values).reshape(-1, n, 3)
    else:
        out[_gather(off, idx)[0]] = values

def _gather(off, idx):
    """Rows of the curves ``idx`` and their offsets as a curve set of their own."""
    sizes = np.diff(off)[idx]
    rows = np.repeat(off[idx] - (np.cumsum(sizes) - sizes), sizes) + np.arange(int(sizes.sum()))
    return rows, np.concatenate([[0], np.cumsum(sizes)])


def _degenerate(pts, off, idx, n):
    """The solver's rule on lengths (:func:`core.curves.degenerate`) on the curves
    ``idx``: curves the pass does not solve are INVALID as they would be in the
    solver. Returns the offending curves of ``idx``."""
    if len(idx) == 0:
        return idx
    sub, sub_off = _take(pts, off, idx, n)
    if n:  # column by column (reductions over 8 CVs are slow)
        Q = sub.reshape(-1, n, 3)
        d = Q[:, 1:] - Q[:, :-1]
        L2 = np.einsum("ijk,ijk->ij", d, d)
        lo2, hi2 = L2[:, 0].copy(), L2[:, 0].copy()
        for j in range(1, n - 1):
            np.minimum(lo2, L2[:, j], out=lo2)
            np.maximum(hi2, L2[:, j], out=hi2)
        # the rule can only fail where the shortest segment is below
        # ZERO_SEGMENT_REL * (n - 1) times the longest: the rule itself on those
        maybe = np.flatnonzero(~(lo2 > (tol.ZERO_SEGMENT_REL * (n - 1)) ** 2 * hi2 * (1 + 1e-6)))
        L = np.sqrt(L2[maybe])
        total, short = L[:, 0].copy(), L[:, 0].copy()
        for j in range(1, n - 1):
            total += L[:, j]
            np.minimum(short, L[:, j], out=short)
        return idx[maybe[degenerate(short, total)]]
    else:
        d = np.diff(sub, axis=0)
        L = np.sqrt(np.einsum("ij,ij->i", d, d))[layout(sub_off)[2]]
        nseg = np.diff(sub_off) - 1
        first = np.cumsum(nseg) - nseg
        total = np.add.reduceat(L, first)
        short = np.minimum.reduceat(L, first)
    return idx[degenerate(short, total)]


def _boxes(pts, off):
    """Bounding boxes ``(lo, hi)`` (R, 3) of the curves."""
    R = len(off) - 1
    n = uniform_size(off)
    if n:
        P3 = pts.reshape(R, n, 3)
        return _halving(np.minimum, P3), _halving(np.maximum, P3)
    if R == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.minimum.reduceat(pts, off[:-1], axis=0), np.maximum.reduceat(pts, off[:-1], axis=0)


def _halving(ufunc, X):
    """``ufunc.reduce(X, axis=1)`` of ``X`` (k, n, 3) for min and max (exact, so any
    order gives the same values; a zero's sign may differ), by halving the columns:
    log2(n) passes over whole blocks (numpy's reductions over short rows are slow, and
    a pass a column reads every row n times)."""
    while X.shape[1] > 1:
        h = X.shape[1] // 2
        Y = ufunc(X[:, :h], X[:, h:2 * h])
        X = np.concatenate([Y, X[:, 2 * h:]], axis=1) if X.shape[1] % 2 else Y
    return X[:, 0]


def _shape_seen(c) -> bool:
    """Has an earlier pass seen collider ``c`` with its current shape? (A rigid
    collider: from its second frame on; a deforming one: never.) Decides only
    whether the pass builds a :class:`_ClearanceField` for it, never a result."""
    first = []
    c.derived("clearance_shape", c.version, lambda: first.append(True))
    return not first


def _to_solve(pts, off, colliders, settings, skip):
    """(R,) bool: the curves the clearance pass hands to the solver.

    Every other curve is certain to come back from the solver unchanged and
    FREE (or INVALID, see :func:`_degenerate`): with a fresh state the solver
    moves a curve only when one of its (input) segments hits a collider, and
    marks it otherwise only when its root is inside a closed collider (a
    pinch). A curve is left out when, for every collider, its box misses the
    collider's (offset) bounds, or its bounding ball is not near the surface
    (``Collider.near_surface``, the solver's own test), or every one of its
    segments is provably farther from the mesh than the offset shell reaches
    (:class:`_ClearanceField`, colliders whose shape an earlier pass saw);
    and its root is outside every closed collider (``Collider.contains``
    where all colliders keep their shape, else: outside their bounds). The
    margins (``pad``, relative 1e-4) are far above the solver's ray
    extension (``tolerances.RAY_EXTEND_ULPS`` float32 ulps).

    ``skip`` (R,) bool: curves to hand over whatever they are (non-finite).
    """
    R = len(off) - 1
    lo, hi = _boxes(pts, off)
    reach = np.zeros(R, bool)  # box meets a collider's bounds (the solver may look at it)
    touch = np.zeros(R, bool)  # may touch a collider
    pinch_box = np.zeros(R, bool)  # root within a closed collider's bounds
    cols = [c for c in colliders if isinstance(c, Collider) and not c.empty]
    # (the solver reports a wrong type)
    seen = [_shape_seen(c) for c in cols]
    static = all(seen)
    roots = pts[off[:-1]]
    for c, known in zip(cols, seen, strict=True):
        offset = _largest_offset(c, settings)
        blo, bhi = c.bounds_world(offset)
        pad = 1e-4 * (float(np.linalg.norm(bhi - blo)) + float(np.abs(np.r_[blo, bhi]).max()))
        r = ((lo <= bhi + pad) & (hi >= blo - pad)).all(1)
        reach |= r
        w = np.flatnonzero(r & ~touch & ~skip)
        if len(w):
            centre = 0.5 * (lo[w] + hi[w])
            radius = 0.5 * np.sqrt(((hi[w] - lo[w]) ** 2).sum(1)) * (1 + 1e-6) + pad
            w = w[c.near_surface(centre, radius, offset)]
        if len(w) and known:
            # the offset shell lies within OFFSET_MAX_STRETCH offsets of the mesh, the
            # clearance margin within a few margins (own units)
            need = (offset * tol.OFFSET_MAX_STRETCH * 1.01
                    + 16.0 * c.margin * rot.norm_bound(c.matrix[:3, :3]) + pad)
            mag = max(float(np.abs(lo[w]).max()), float(np.abs(hi[w]).max()))
            w = w[~_ClearanceField.of(c).clear(pts, off, w, c.matrix, need, mag)]
        touch[w] = True
        if c.detects_pinch:
            pinch_box |= ((roots >= blo - pad) & (roots <= bhi + pad)).all(1)
    clear = reach & ~touch & ~skip
    maybe = np.flatnonzero(clear & pinch_box)
    if len(maybe):
        if static:  # (contains caches its answers per shape: cheap for these)
            inside = np.zeros(len(maybe), bool)
            for c in cols:
                if c.detects_pinch:
                    inside |= c.contains(roots[maybe], _largest_offset(c, settings))
            maybe = maybe[inside]
        clear[maybe] = False
    return reach & ~clear


def _largest_offset(c, settings):
    """The largest distance ``settings`` keep curves from collider ``c`` (its own
    offset or Collision Offset, plus Clearance Margin; the largest value of a
    per-curve map): the conservative reach of :func:`_to_solve`'s tests."""
    return max(d for d, _ in c.clearance_groups(settings.collision_offset,
                                                 settings.clearance_margin))


class _ClearanceField:
    """A lower bound of the distance to a collider's mesh (its own space).

    The windowed lower-bound distance field of the mesh's cells
    (``distance.LowerBoundField``: 128 cells along the mesh's box, distances
    up to 8 cells): a point in a cell is at least the cell's value from every
    triangle. Built once per collider shape (about 0.1 s for 130,000
    triangles) and kept on the collider (``Collider.derived``).
    """

    DIMS = 128
    WINDOW = 8

    def __init__(self, c):
        V = np.asarray(c.vertices, np.float64)
        T = V[np.asarray(c.faces, np.int64)]
        f = LowerBoundField(T, 0.0, dims=self.DIMS, window=self.WINDOW)
        self.glo, self.h, self.dims = f.glo, float(f.h), f.dims
        self.D = np.ascontiguousarray(f.D, np.float32).reshape(-1)

    @classmethod
    def of(cls, c):
        return c.derived("clearance_field", c.version, lambda: cls(c))

    def clear(self, pts, off, w, M, need, mag):
        """(len(w),) bool: is every segment of curves ``w`` farther than ``need``
        (world units) from the mesh, the collider's world matrix being ``M``?
        ``mag``: the largest absolute coordinate of their points.

        A segment of midpoint ``m`` and length ``L`` is at least ``lb(m) - L / 2``
        from the mesh, ``lb`` the field's value at ``m``. Computed in float32 in
        cell units: a margin of 1e-3 cells plus 2e-6 (about 30 float32 ulps) of
        the largest cell coordinate covers the rounding.
        """
        Minv = rot.inv_affine(M)
        M3 = M[:3, :3]
        # smallest singular value of M3, from below (Weyl): world distances are at
        # least s times the distances in the collider's space
        G = np.einsum("ki,kj->ij", M3, M3)
        g = float(np.trace(G)) / 3.0
        s2 = g - float(np.sqrt(((G - g * np.eye(3)) ** 2).sum()))
        if not s2 > 0 or len(w) == 0:
            return np.zeros(len(w), bool)
        s = float(np.sqrt(s2)) * (1 - 1e-6)
        n = uniform_size(off)
        if n:
            Q = pts.reshape(-1, n, 3)[w]  # (k, n, 3)
            xyz = [Q[..., i] for i in range(3)]
        else:
            rows, sub = _gather(off, w)
            xyz = [pts[rows, i] for i in range(3)]
        # cell coordinates (float32) of the points: x_cell = (Minv x - glo) / h
        A = Minv[:3, :3] / self.h
        b = (Minv[:3, 3] - self.glo) / self.h
        c = []
        for i in range(3):
            y = np.multiply(xyz[0], A[i, 0], dtype=np.float32)
            y += np.multiply(xyz[1], A[i, 1], dtype=np.float32)
            y += np.multiply(xyz[2], A[i, 2], dtype=np.float32)
            y += np.float32(b[i])
            c.append(y)
        if n:
            a, e = [y[:, :-1] for y in c], [y[:, 1:] for y in c]
        else:
            _, _, s0 = layout(sub)
            a, e = [y[s0] for y in c], [y[s0 + 1] for y in c]
        half2 = None  # (L / 2)^2 and the cell of the midpoint, in cell units
        gap2 = None
        cell = None
        for i in range(3):
            m = a[i] + e[i]
            m *= 0.5
            d = e[i] - a[i]
            d *= d
            half2 = d if half2 is None else np.add(half2, d, out=half2)
            # a midpoint outside the grid: its projection q' onto the grid's box is in
            # a border cell, and |m - x|^2 >= |m - q'|^2 + |q' - x|^2 for x in the box
            g = np.maximum(-m, m - np.float32(self.dims[i]))
            np.maximum(g, 0, out=g)
            g *= g
            gap2 = g if gap2 is None else np.add(gap2, g, out=gap2)
            np.clip(m, 0, self.dims[i] - 1, out=m)
            k = m.astype(np.int32)  # (floor: m >= 0)
            cell = k if cell is None else np.add(cell * np.int32(self.dims[i]), k, out=k)
        lb = self.D.take(cell)
        lb *= lb
        lb += gap2
        np.sqrt(lb, out=lb)
        half2 *= 0.25
        lb -= np.sqrt(half2, out=half2)
        big = float(np.abs(A).sum(1).max()) * mag + float(np.abs(b).max()) + float(self.dims.max())
        ok = lb > np.float32(need / (s * self.h) + 1e-3 + 2e-6 * big)
        if n:
            return ok.all(axis=1)
        nseg = np.diff(sub) - 1
        return np.logical_and.reduceat(ok.reshape(-1), np.cumsum(nseg) - nseg)
