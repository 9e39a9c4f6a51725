"""Stiff and Bend (paper 3.2.1), Shrink (3.2.2), Recovery and Plasticity (3.2.3-4).

A Stiff or Bend curve carries one angle about one axis (kept in the curve's
local frame from its first hit until it has recovered); these functions
update that angle for all curves of a step at once.
"""

from __future__ import annotations

import numpy as np

from . import rotations as rot
from . import tolerances as tol
from .search import gallop_bisect
from .status import Status

#: Probes per curve per search round. Each probe of a Stiff/Bend curve casts
#: all its segments: after the first (estimate-spread) round two probes per
#: round cast fewest rays for the same main-thread time.
_WIDTH = 2

#: Probes per block when building ray batches (working arrays stay in cache).
_BLOCK = 1024


def solve(ctx, idx, status):
    """Stiff and Bend: one angle per curve about its kept axis."""
    angle = ctx.angle
    near = idx[ctx.cand_any[idx]]
    far = idx[~ctx.cand_any[idx]]
    act = near[ctx.active[near]]  # rotated curves near a collider
    new = near[~ctx.active[near]]  # unrotated: their segments are the input's
    # 1. Unrotated curves near a collider: tested at their input shape.
    hit_new, seg_hit = ctx.input_hits(new)
    cn = new[hit_new]
    if len(cn):  # first hit: choose the axis (kept until recovered)
        seg_hit = seg_hit[np.repeat(hit_new, ctx.sv_._nseg[new])]  # (the same rays)
        o, d, _, rep, starts = ctx.input_rays(cn)
        ctx.axis[cn] = ctx.new_axes(cn, o, d, rep, starts, seg_hit)
        ctx.active[cn] = True
    # One batch for the rotated curves (items 0..len(act)-1) and the new
    # colliding ones, so that every search below is one ray query per round.
    batch = RigidBatch(ctx, np.concatenate([act, cn]))
    # 2. Rotated curves near a collider: their recovery step is tested first
    #    (one ray query); only those it would make collide are tested at their
    #    current angle, to tell a blocked recovery from a new collision.
    th0 = angle[act].copy()
    th1 = recovery_step(ctx, act)
    moving = th1 < th0
    hit_step = batch.hits(np.arange(len(act)), np.where(moving, th1, th0))
    hit_act = hit_step & ~moving  # colliding at the current angle
    again = np.flatnonzero(moving & hit_step)
    hit_act[again] = batch.hits(again, th0[again])
    blocked = moving & hit_step & ~hit_act

    # 3. Collision: the smallest clearing angle above the current one.
    cc = act[hit_act]
    if len(cc):  # first probe: lift the current shape above the tangent plane
        o, d, _, rep, starts = ctx.deform(cc, angle=angle[cc], axis=ctx.axis[cc])
        k, point, push = ctx.first_hit_details(cc, o, d, rep, starts)
        g = ctx._plane_guess(cc, o + d, rep, starts, point, push, ctx.axis[cc])
        ctx.guess[cc] = np.where(k >= 0, g, ctx.guess[cc])
    colliding = np.concatenate([np.flatnonzero(hit_act), len(act) + np.arange(len(cn))])
    # 4. Recovery toward the (plasticity) target, stopping before contact:
    #    blocked steps are bisected in the same search rounds as the collisions.
    items = np.flatnonzero(~hit_act)
    b = np.flatnonzero(blocked[items])
    p = ctx.prec
    lo_th, hi_th = th1[items[b]], th0[items[b]]
    K = np.maximum(np.ceil((hi_th - lo_th) / p - 1e-9), 1).astype(np.int64)
    k_rec = collide(ctx, batch, colliding, status, (items[b], lo_th, hi_th, K))
    recover(ctx, act[items], th0[items], th1[items], b, k_rec, status)
    rec = far[ctx.active[far]]  # far from every collider: nothing to check
    recover(ctx, rec, angle[rec].copy(), recovery_step(ctx, rec), None, None, status)
    release(ctx, idx)


def collide(ctx, batch, items, status, bisect=None):
    """Resolve colliding curves ``batch.curves[items]`` (paper 3.2.1).

    ``bisect`` (batch items, low angle, high angle, steps): recovery steps to
    bisect in the same search rounds (see :func:`search_angles`); their
    results are returned.
    """
    p, angle = ctx.prec, ctx.angle
    c = batch.curves[items]
    th0 = angle[c]
    k, k_rec = search_angles(ctx, batch, items, th0, ctx.guess[c], bisect)
    if len(items) == 0:
        return k_rec
    if ctx.s.mode == "bend":
        # Bending turns the root segment by only 1/n of the angle: curves
        # hit near the root that bending cannot clear turn at the root (as
        # Stiff) instead, until they have recovered.
        retry = np.flatnonzero((k < 0) & ~ctx.sv_._stiff[c])
        if len(retry):
            cr = c[retry]
            ctx.sv_._stiff[cr] = True
            # seed: the Stiff estimate, plus about the mean bend already taken
            seed = ctx.guess_stiff[cr] + 0.5 * th0[retry]
            k2, _ = search_angles(
                ctx, RigidBatch(ctx, cr), np.arange(len(cr)), np.zeros(len(cr)), seed
            )
            ctx.sv_._stiff[cr[k2 < 0]] = False
            ok2 = k2 >= 0
            k[retry[ok2]] = k2[ok2]
            th0[retry[ok2]] = 0.0
    ok = k >= 0
    res = c[ok]
    angle[res] = np.minimum(th0[ok] + k[ok] * p, ctx.max_angle)
    ctx.angle_max[res] = np.maximum(ctx.angle_max[res], angle[res])
    status[res] = Status.COLLIDING
    bad = c[~ok]
    status[bad] = Status.UNRESOLVED
    # Fallback: the state of the previous frame (last collision-free).
    angle[bad] = th0[~ok]
    fresh = bad[ctx.sv_._angle[bad] == 0]
    ctx.active[fresh] = ctx.sv_._active[fresh]
    return k_rec


def recovery_step(ctx, rec):
    """This frame's recovery angle of curves ``rec`` (paper 3.2.3-4).

    The angle moves toward the target ``plasticity * largest angle`` (or
    stays, for curves held after a pinch) by ``recovery_rate`` of the
    remaining difference; within half a precision step it lands on the
    target, and below half a step on exactly zero.
    """
    p = ctx.prec
    th0 = ctx.angle[rec]
    frac = ctx.target_fraction(rec)
    target = np.where(np.isnan(frac), th0, np.nan_to_num(frac) * ctx.angle_max[rec])
    target = np.minimum(target, th0)
    th1 = th0 - ctx.s.recovery_rate * (th0 - target)
    th1 = np.where(th1 - target < tol.SNAP_FRACTION * p, target, th1)
    return np.where(th1 < tol.SNAP_FRACTION * p, 0.0, th1)


def recover(ctx, rec, th0, th1, b, k, status):
    """Turn clear curves ``rec`` from ``th0`` to their recovery step ``th1``.

    Where the step would collide (``rec[b]``) the largest safe step, ``k``
    precision steps above ``th1`` (bisected by :func:`collide`), is taken
    instead: recovery stops where the curve would collide again.
    """
    if len(rec) == 0:
        return
    p = ctx.prec
    th1 = th1.copy()
    if b is None:
        b = np.zeros(0, np.int64)
    if len(b):
        th1[b] = np.minimum(th1[b] + k * p, th0[b])
    ctx.angle[rec] = th1
    # Back at exactly the input shape counts as FREE, not RECOVERING.
    st = np.where((th1 < th0) & (th1 > 0), Status.RECOVERING, Status.FREE)
    if len(b):
        st[b] = Status.COLLIDING
    status[rec] = np.maximum(status[rec], st)


def search_angles(ctx, batch, items, th0, guess=None, bisect=None):
    """Smallest clearing rotation above ``th0`` of ``batch.curves[items]``.

    ``guess`` (radians, per item) is an estimate of the increment (the
    tangent-plane estimate of :meth:`StepContext._plane_guess`): the first
    round probes 0.8, 1, 1.25 and 1.6 times it, and the search continues
    from the bracket that gives (bisection) or from its top (gallop).

    ``bisect`` (items ``bi``, angles ``lo``, ``hi``, steps ``K``): largest
    clear angle ``min(lo + k p, hi)``, ``k`` in ``[0, K]``, of
    ``batch.curves[bi]`` (``lo`` colliding, ``hi`` clear): a bisection run
    in the same rounds (one ray query per round for both).

    Returns
    -------
    k : (n,) int
        Steps ``k`` (angle ``min(th0 + k p, max_angle)``), -1 where no
        angle up to ``max_angle`` clears the curve.
    k_bisect : (m,) int
        The bisected steps (empty without ``bisect``).
    """
    p = ctx.prec
    n = len(items)
    kmax = np.maximum(np.ceil((ctx.max_angle - th0) / p - 1e-9), 0).astype(np.int64)
    base, cap = th0, np.full(n, ctx.max_angle)

    def test(it, ks):
        return ~batch.hits(all_items[it], np.minimum(base[it] + ks * p, cap[it]))

    all_items = items
    lo = np.zeros(n, np.int64)
    hi = np.full(n, -1, np.int64)
    stride = None
    if guess is not None and n:
        # One round of probes spread around the guess; it leaves a bracket
        # to bisect, or a floor to gallop on from with a guess-sized stride.
        kg = np.clip(np.rint(guess / p).astype(np.int64), 1, np.maximum(kmax, 1))
        it = np.flatnonzero(kmax >= 1)
        spread = np.array([0.8, 1.0, 1.25, 1.6])
        probes = np.clip(np.rint(kg[it][:, None] * spread).astype(np.int64), 1, kmax[it][:, None])
        probes = np.maximum.accumulate(probes, axis=1)
        good = test(np.repeat(it, len(spread)), probes.ravel()).reshape(probes.shape)
        anyg = good.any(axis=1)
        first = np.argmax(good, axis=1)
        rows = np.arange(len(it))
        hi[it[anyg]] = probes[rows, first][anyg]
        lo[it[anyg]] = np.where(first > 0, probes[rows, np.maximum(first - 1, 0)], 0)[anyg]
        lo[it[~anyg]] = probes[~anyg, -1]
        stride = np.maximum(kg // 2, 1)
    if bisect is not None and len(bisect[0]):
        bi, lo_th, hi_th, K = bisect
        m = len(bi)
        all_items = np.concatenate([items, bi])
        base = np.concatenate([th0, lo_th])
        cap = np.concatenate([cap, hi_th])
        kmax = np.concatenate([kmax, K])
        lo = np.concatenate([lo, np.zeros(m, np.int64)])
        hi = np.concatenate([hi, K])
        stride = np.concatenate([np.ones(n, np.int64) if stride is None else stride,
                                 np.ones(m, np.int64)])
    k = gallop_bisect(len(all_items), test, kmax, lo=lo, hi=hi, stride=stride, width=_WIDTH)
    return k[:n], k[n:]


def release(ctx, idx):
    """Curves back at exactly their input shape drop their local state."""
    if ctx.soft:
        return
    done = idx[ctx.active[idx] & (ctx.angle[idx] == 0)]
    ctx.active[done] = False
    ctx.sv_._stiff[done] = False
    ctx.axis[done] = 0.0
    ctx.angle_max[done] = 0.0


class RigidBatch:
    """Stiff/Bend curves under search, with all angle-independent work done once.

    Rodrigues' rotation of a segment ``v`` about the curve's axis ``a`` is
    ``Y + V0 cos(t) + X sin(t)`` with ``Y = a (a.v)``, ``V0 = v - Y`` and
    ``X = a x v``; the map into a collider's space is affine, so ``Y``, ``V0``,
    ``X`` and the roots are moved into each collider's space once. A probe
    round then costs a gather, a cos/sin, a cumulative sum and the ray query.
    Rays are grown by ``tol.RAY_EXTEND_ULPS`` as in :meth:`core.step.StepContext.hits`.
    """

    def __init__(self, ctx, curves):
        self.ctx = ctx
        self.curves = curves
        sv = ctx.sv_
        self.cnt = sv._nseg[curves]
        # Uniform CV counts (the usual groom): component arrays (3, ns, n),
        # see :meth:`_hits_uniform`.
        self.ns = ctx.sv_._ns if len(curves) else 0
        if self.ns:
            self._init_uniform(ctx, curves)
            return
        seg, rep, starts = ctx.segments(curves)
        self.starts = starts
        v = ctx.seg_in(seg)
        ax = ctx.axis[curves][rep]
        Y = ax * rot.dot(ax, v)[:, None]
        X = np.cross(ax, v)
        V0 = v - Y
        if ctx.s.mode == "bend":
            self.w = np.where(sv._stiff[curves][rep], 1.0, sv._w_bend[seg])
        else:
            self.w = np.ones(len(seg))
        self.length = np.sqrt(rot.dot(v, v))
        self.root = ctx.root_mask(len(seg), starts)
        self.per_col = []
        for (c, off), cand in zip(ctx.cols, ctx.cand, strict=True):
            m = cand[curves]
            if not m.any():
                continue
            A, b = c.local_map()
            terms = [rot.apply(A, x) for x in (Y, V0, X)]
            self.per_col.append((c, off, m, rot.apply(A, ctx.roots[curves]) + b, *terms))

    def _init_uniform(self, ctx, curves):
        """The terms as (3, ns, n) component arrays (same arithmetic as the
        rows of 3 of the general case, so the same rays bit for bit)."""
        v = ctx.seg_soa(curves)
        ax = np.ascontiguousarray(ctx.axis[curves].T)  # components as contiguous rows
        a0, a1, a2 = ax
        along = v[0] * a0
        along += v[1] * a1
        along += v[2] * a2
        Y = np.empty_like(v)
        X = np.empty_like(v)
        for i, (p, q, r) in enumerate(((a1, 2, (a2, 1)), (a2, 0, (a0, 2)), (a0, 1, (a1, 0)))):
            np.multiply(ax[i], along, out=Y[i])
            np.multiply(p, v[q], out=X[i])
            X[i] -= r[0] * v[r[1]]
        V0 = np.subtract(v, Y)
        self.w = np.broadcast_to(ctx.bend_weights(curves), (self.ns, len(curves)))
        sq = v[0] * v[0]
        sq += v[1] * v[1]
        sq += v[2] * v[2]
        self.length = np.sqrt(sq, out=sq)
        # Without Shrink the ray growth does not depend on the angle.
        self.growth = None
        if not ctx.s.shrink:
            self.growth = ctx.ray_growth(self.length, (np.arange(self.ns) == 0)[:, None])
        self.per_col = []
        for (c, off), cand in zip(ctx.cols, ctx.cand, strict=True):
            m = cand[curves]
            if not m.any():
                continue
            A, b = c.local_map()
            terms = [rot.apply_soa(A, x) for x in (Y, V0, X)]
            root_lo = np.ascontiguousarray((rot.apply(A, ctx.roots[curves]) + b).T)
            self.per_col.append((c, off, m, root_lo, *terms))

    def hits(self, items, theta):
        """Does curve ``curves[items[i]]`` turned by ``theta[i]`` hit a collider.

        ``items`` may repeat (several angles of one curve in one query).
        """
        n = len(items)
        hit = np.zeros(n, bool)
        if n == 0:
            return hit
        if self.ns:
            return self._hits_uniform(items, theta, hit)
        ctx = self.ctx
        cnt = self.cnt[items]
        first = np.cumsum(cnt) - cnt
        rep = np.repeat(np.arange(n), cnt)
        sel = self.starts[items][rep] + (np.arange(len(rep)) - first[rep])
        a = theta[rep] * self.w[sel]
        cos, sin = np.cos(a)[:, None], np.sin(a)[:, None]
        scale = ctx.shrink_scale(a)
        length = self.length[sel] if scale is None else self.length[sel] * scale
        back, grow = ctx.ray_growth(length, self.root[sel])
        back, grow = back[:, None], grow[:, None]
        for c, off, m, root_lo, Y, V0, X in self.per_col:
            mi = m[items]
            if not mi.any():
                continue
            d = Y[sel] + V0[sel] * cos + X[sel] * sin
            if scale is not None:
                d *= scale[:, None]
            cs = np.cumsum(d, axis=0)
            o = cs - d + (root_lo[items] - (cs[first] - d[first]))[rep]
            rays = mi[rep]
            if rays.all():
                h = c.segment_hits_local(o - back * d, d * grow, off, ctx.threads)
            else:
                w = np.flatnonzero(rays)
                h = np.zeros(len(rep), bool)
                h[w] = c.segment_hits_local(o[w] - back[w] * d[w], d[w] * grow[w], off, ctx.threads)
            ctx.n_rays += int(rays.sum())
            hit |= np.logical_or.reduceat(h, first)
        return hit

    def _hits_uniform(self, items, theta, hit):
        """:meth:`hits` for curves that all have ``self.ns`` segments.

        Works on (3, ns, n) component arrays (long contiguous rows, no rows
        of 3) with the arithmetic of :meth:`hits`, in blocks of probes small
        enough to stay in the CPU cache; the rays go to the tracer
        segment-major (a ray's result does not depend on its batch).
        """
        ctx = self.ctx
        ns = self.ns
        for c, off, m, root_lo, Y, V0, X in self.per_col:
            mi = m[items]
            if not mi.any():
                continue
            sub = slice(None) if mi.all() else mi
            it = items[sub]
            th = theta[sub]
            k = len(it)
            o32 = np.empty((ns, k, 3), np.float32)
            d32 = np.empty((ns, k, 3), np.float32)
            for lo in range(0, k, _BLOCK):
                blk = slice(lo, lo + _BLOCK)
                self._rays(it[blk], th[blk], root_lo, Y, V0, X, o32[:, blk], d32[:, blk])
            h = c.segment_hits_local(o32.reshape(-1, 3), d32.reshape(-1, 3), off, ctx.threads)
            ctx.n_rays += len(h)
            hit[sub] |= h.reshape(ns, k).any(axis=0)
        return hit

    def _rays(self, it, theta, root_lo, Y, V0, X, o32, d32):
        """Rays (collider space, grown) of curves ``it`` turned by ``theta``,
        written into ``o32``, ``d32`` (ns, n, 3)."""
        ctx = self.ctx
        ns = self.ns
        a = self.w.take(it, axis=1) * theta  # (ns, n); take keeps rows contiguous
        scale = ctx.shrink_scale(a)
        if scale is None:
            back, grow = (g.take(it, axis=1) for g in self.growth)
        else:
            length = self.length.take(it, axis=1) * scale
            back, grow = ctx.ray_growth(length, (np.arange(ns) == 0)[:, None])
        d = Y.take(it, axis=2)
        t = V0.take(it, axis=2)
        t *= np.cos(a)
        d += t
        X.take(it, axis=2, out=t)
        t *= np.sin(a)
        d += t
        if scale is not None:
            d *= scale
        o = rot.cumsum_soa(d)
        o -= d
        o += root_lo.take(it, axis=1)[:, None, :]
        np.multiply(back, d, out=t)
        o -= t
        d *= grow
        for i in range(3):
            o32[..., i] = o[i]
            d32[..., i] = d[i]

