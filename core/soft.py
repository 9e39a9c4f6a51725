"""Soft mode (paper 3.2.1): per-segment rotations with Affected Connected CVs and CV FallOff.

:func:`solve` finds the rotations of a step's curves and returns them (:class:`Turns`:
every segment's quaternion as the mode leaves it, the mode's own while it solves),
which the step applies (``StepContext.apply``); it never writes into the step.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import rotations as rot
from . import tolerances as tol
from .search import gallop_bisect, scan_bisect
from .status import Status


@dataclass
class Turns:
    """Soft's answer for one step: every segment's rotation as the mode leaves it.

    :func:`solve` makes it from the step's rotations (its own copies: the rows of
    the curves it solves change) and returns it; ``StepContext.apply`` takes it.
    The halves of a step (``StepContext.in_halves``) share it, each writing only
    its own curves.

    Attributes
    ----------
    quat : (S, 4) float64
        Each segment's rotation (world).
    quat_max : list of (rows (k,), quaternions (k, 4), grow)
        The changes of the largest rotations, in order: with ``grow`` each row
        takes its quaternion where that turns further than its largest so far,
        else it is set (back to the identity).
    active : (C,) bool
    soft_level : (C,) float64
        The fraction of the recovery step a blocked curve took.
    status : (C,) int8
        The outcome of each curve solved (``Status``; FREE elsewhere).
    """

    quat: np.ndarray
    active: np.ndarray
    soft_level: np.ndarray
    status: np.ndarray
    quat_max: list = field(default_factory=list)

    @classmethod
    def of(cls, ctx) -> Turns:
        """The step's rotations as they are before the solve (copies)."""
        C = ctx.layout.n_curves
        return cls(ctx.quat.copy(), ctx.active.copy(), np.zeros(C), np.zeros(C, np.int8))


def solve(ctx, idx) -> Turns:
    """Soft on curves ``idx`` (in parts, one per thread, when there are many)."""
    t = Turns.of(ctx)
    ctx.in_halves(_solve, len(idx), idx, turns=t)
    return t


def _solve(ctx, idx, turns):
    """Soft on curves ``idx``: :meth:`StepContext.in_halves`'s ``fn``."""
    SoftSolve(ctx, turns).run(idx)


class SoftSolve:
    """Soft mode (paper 3.2.1): per-segment rotations, prefix by prefix.

    The first colliding segment of each curve turns about its own axis (away
    from the collider) by the smallest clearing angle; the next
    ``affected_connected_cvs`` segments turn with it scaled by
    ``(1 - cv_falloff) ** i``; segment lengths are kept because output
    curves are re-chained from rotated input segments (length correction).
    Segments before the one being solved never move, so each round clears
    one more prefix of the curve and the loop ends after at most one round
    per segment.
    """

    def __init__(self, ctx, turns):
        self.ctx, self.t = ctx, turns
        s = ctx.s
        A = s.affected_connected_cvs
        self.weights = (1.0 - s.cv_falloff) ** np.arange(1, A + 1)  # (A,): empty for 0

    def run(self, idx):
        ctx, t, p = self.ctx, self.t, self.ctx.prec
        near = idx[ctx.cand_any[idx]]
        far = idx[~ctx.cand_any[idx]]
        # (ctx.quat: the rotations at the start of the step, world)
        unresolved = np.zeros(ctx.layout.n_curves, bool)
        touched = np.zeros(ctx.layout.n_curves, bool)
        todo = near
        if ctx.layout.ns and len(todo):
            # Most curves near a collider are clear in their current state:
            # find the ones that are not on component arrays first (the first
            # round's details need rows).
            q = t.quat.reshape(-1, ctx.layout.ns, 4)[todo]
            qs = np.empty((4, ctx.layout.ns, len(todo)))
            for i in range(4):
                qs[i] = q[..., i].T
            todo = todo[ctx.quat_curve_hits(todo, qs)]
        for _ in range(int(ctx.layout.nseg.max()) + 1):  # (run: curves to solve)
            if len(todo) == 0:
                break
            seg, rep, starts = ctx.segments(todo)
            o, d, _, rep, starts = ctx.deform(todo, quat=t.quat[seg])
            follow = ctx.s.follow_collider_motion
            if follow:
                k, point, push, vel = ctx.first_hit_details(todo, o, d, rep, starts, motion=True)
            else:
                k, point, push = ctx.first_hit_details(todo, o, d, rep, starts)
            hit = k >= 0
            todo, k, push = todo[hit], k[hit], push[hit]
            if len(todo) == 0:
                break
            touched[todo] = True
            t.active[todo] = True
            seg_hit = seg[k]  # global segment id of the first hitting segment
            if ctx.s.attract_to_growth_surface:
                mid = ctx.midpoints(todo, o, d, starts[hit])
                cp, _ = ctx.growth.closest_points(mid)
                pull = rot.normalize(cp - mid)
                ok = np.linalg.norm(np.cross(rot.normalize(d[k]), pull), axis=1) > tol.PARALLEL_EPS
                push = np.where(ok[:, None], pull, push)
            axis = rot.rotation_axis(d[k], push)
            if follow:  # where the collider moves at the hit: the segment follows it
                way, ok = ctx.follow_directions(todo, d[k], vel[hit], d[k])
                if ok.any():
                    axis[ok] = rot.rotation_axis(d[k][ok], way[ok])
            last = ctx.layout.soff[todo + 1]  # one past the curve's last segment

            # Only the solved segment needs testing: segments before it do not
            # move (so neither does its start), segments after it are the next
            # rounds' job; its direction is its current one turned by phi.
            o_k, d_k = o[k], d[k]
            root_k = k == starts[hit]

            turn = _SegmentTurn(ctx, todo, o_k, d_k, axis, root_k)
            kmax = np.ceil(ctx.max_angle_of(todo) / p - 1e-9).astype(np.int64)
            kk = scan_bisect(len(todo), lambda items, ks, t=turn: t.clear(items, ks * p), kmax)
            ok = kk >= 0
            if ok.any():
                w = np.flatnonzero(ok)
                _, sel, q = self._rotated(seg_hit[w], last[w], axis[w], kk[w] * p)
                t.quat[sel] = q
                t.quat_max.append((sel, q, True))
            unresolved[todo[~ok]] = True
            todo = todo[ok]
        # Unresolvable curves fall back to their state at the start of the step.
        bad = np.flatnonzero(unresolved)
        if len(bad):
            seg, _, _ = ctx.segments(bad)
            t.quat[seg] = ctx.quat[seg]
            t.active[bad] = ctx.state.active[bad]
            t.status[bad] = Status.UNRESOLVED
        t.status[touched & ~unresolved] = Status.COLLIDING
        rec = np.sort(np.concatenate([near, far]))
        rec = rec[~touched[rec] & t.active[rec]]
        if len(rec):
            self.recover(rec)

    def _rotated(self, seg_hit, last, axis, phi):
        """(owner, segment ids, composed quaternions) after turning ``seg_hit`` by ``phi``."""
        n = len(seg_hit)
        span = np.minimum(len(self.weights) + 1, last - seg_hit)  # segments affected
        rep = np.repeat(np.arange(n), span)
        first = np.concatenate([[0], np.cumsum(span)[:-1]])
        i = np.arange(int(span.sum())) - first[rep]
        sel = seg_hit[rep] + i
        w = np.concatenate([[1.0], self.weights])[i]
        r = rot.quat_from_axis_angle(axis[rep], phi[rep] * w)
        return rep, sel, rot.quat_canonical(rot.quat_mul(r, self.t.quat[sel]))

    def recover(self, rec):
        """Slerp every segment toward its target; stop before contact.

        The step is ``recovery_rate`` of the way to the target; where it
        would collide, the largest safe fraction ``k / levels`` of it (16
        levels, finer than the precision for any step a frame can take).
        Curves that were blocked last step start from the level they took
        then (``Solver`` state ``delta``: that fraction), testing it and the
        level above: a lasting contact is confirmed with two probes instead
        of bisected. Where clearance is monotone in the fraction both give
        the same level.
        """
        ctx, t, p = self.ctx, self.t, self.ctx.prec
        levels = _LEVELS
        rate = ctx.s.per_curve("recovery_rate", rec)  # a number, or per curve of rec
        seg, rep, starts = ctx.segments(rec)
        q0 = t.quat[seg]
        ident = np.zeros_like(q0)
        ident[:, 0] = 1.0
        frac = ctx.target_fraction(rec)
        hold = np.isnan(frac)
        qt = rot.quat_slerp(ident, ctx.quat_max[seg], np.nan_to_num(frac)[rep])
        qt = np.where(hold[rep][:, None], q0, qt)
        path = _Slerp(q0, qt)  # the arc every probe of this step samples

        q1 = path(np.full(len(q0), rate) if np.ndim(rate) == 0 else rate[rep])
        # Within half a precision step of the target (every segment): land on it.
        conj = qt * np.array([1.0, -1.0, -1.0, -1.0])
        near_t = rot.quat_angle(rot.quat_mul(q1, conj)) < tol.SNAP_FRACTION * p
        snap = np.logical_and.reduceat(near_t, starts)
        q1 = np.where(snap[rep][:, None], qt, q1)
        moving = ~np.all(q1 == q0, axis=1)
        moving_c = np.logical_or.reduceat(moving, starts)
        chk = np.flatnonzero(moving_c & ctx.cand_any[rec])
        q1_soa = np.ascontiguousarray(q1.T)

        ns = ctx.layout.ns

        def clear(items, ks):
            """Is curve ``rec[chk[items]]`` clear at level ``ks`` (``levels``:
            the full, possibly snapped, step)?"""
            c = rec[chk[items]]
            sseg, srep, _ = ctx.segments(c)
            pos = np.searchsorted(seg, sseg)
            full = (ks == levels)[srep]
            r = rate if np.ndim(rate) == 0 else rate[chk[items]]
            q = path.soa((ks / levels * r)[srep], pos)
            q = np.where(full, q1_soa.take(pos, axis=1), q)
            if ns:  # component arrays (4, ns, n)
                return ~ctx.quat_curve_hits(c, q.reshape(4, len(c), ns).transpose(0, 2, 1))
            return ~ctx.curve_hits(c, quat=np.ascontiguousarray(q.T))

        # Per checked curve: the lowest level known blocked and the highest
        # known clear (0: the current state is clear). Every curve probes the
        # full step (``levels``) first: where it is clear, hi is ``levels`` and
        # lo no longer matters.
        n = len(chk)
        lo = np.full(n, levels, np.int64)
        hi = np.zeros_like(lo)
        mem = ctx.state.contact[rec[chk]] & ctx.warm_soft
        m = np.clip(np.rint(ctx.state.delta[rec[chk]] * levels), 0, levels - 1).astype(np.int64)
        warm = np.flatnonzero(mem)
        above = warm[m[warm] > 0]
        below_full = warm[m[warm] + 1 < levels]
        # every curve probes the full step, as the full search decides first;
        # a remembered one also the level it took and the one above
        items = np.concatenate([np.arange(n), below_full, above])
        ks = np.concatenate([np.full(n, levels), m[below_full] + 1, m[above]])
        ok = clear(items, ks) if len(items) else np.zeros(0, bool)
        np.minimum.at(lo, items[~ok], ks[~ok])
        np.maximum.at(hi, items[ok], ks[ok])
        # A blocked level below a clear one (not monotone): what it says of the
        # levels above is void; the full step, probed by all and blocked unless
        # hi == levels, is the lowest level still known blocked.
        lo = np.where(lo <= hi, levels, lo)
        # The rest: the largest clear level in [hi, lo), bisected (the
        # smallest good k of the reversed grid).
        todo = np.flatnonzero((hi < levels) & (lo - hi > 1))
        if len(todo):
            def test_rev(items, kk):
                return clear(todo[items], levels - kk)

            kr = gallop_bisect(len(todo), test_rev, levels - hi[todo],
                               lo=levels - lo[todo], hi=levels - hi[todo])
            hi[todo] = levels - kr
        level = np.full(len(rec), levels, np.int64)
        level[chk] = hi
        blocked = level < levels
        b = np.flatnonzero(blocked)
        if len(b):
            sseg, _, _ = ctx.segments(rec[b])
            pos = np.searchsorted(seg, sseg)
            r = rate if np.ndim(rate) == 0 else rate[b]
            lam = np.repeat(level[b] / levels * r, ctx.layout.nseg[rec[b]])
            q1[pos] = path(lam, pos)
        t.quat[seg] = q1
        t.soft_level[rec[b]] = level[b] / levels
        changed = np.logical_or.reduceat(~np.all(q1 == q0, axis=1), starts)
        identity = np.logical_and.reduceat(np.all(q1 == ident, axis=1), starts)
        st = np.where(
            blocked, Status.COLLIDING, np.where(changed & ~identity, Status.RECOVERING, Status.FREE)
        )
        t.status[rec] = np.maximum(t.status[rec], st)
        # Back exactly at the input shape: drop the state.
        done = rec[identity]
        t.active[rec] &= ~identity
        dseg, _, _ = ctx.segments(done)
        t.quat_max.append((dseg, ident[: len(dseg)], False))


class _SegmentTurn:
    """One segment per curve turned about its own axis (a Soft search round).

    Only that segment moves (its start is fixed, the segments after it are
    the next round's), so a probe is one ray. Rodrigues' terms of the turn
    (``Y = a (a.d)``, ``V0 = d - Y``, ``X = a x d``) and the segment's start
    are moved into each collider's space once; a probe at angle ``t`` is
    then ``Y + V0 cos t + X sin t`` there, grown as
    :meth:`~core.step.StepContext.extend` grows it (its length never
    changes), on component arrays.
    """

    def __init__(self, ctx, curves, o, d, axis, root):
        self.ctx = ctx
        ax = np.ascontiguousarray(axis.T)
        v = np.ascontiguousarray(d.T)
        along = rot.dot3(ax, v)
        Y = ax * along
        V0 = v - Y
        X = rot.cross3(ax, v)
        length = rot.norm3(v)
        self.back, self.grow = ctx.ray_growth(length, root)
        o = np.ascontiguousarray(o.T)
        self.per_col = []
        for (c, off), cand in zip(ctx.cols, ctx.cand, strict=True):
            m = cand[curves]
            if not m.any():
                continue
            A, b = c.local_map()
            o_lo = rot.apply_soa(A, o)
            for i in range(3):
                o_lo[i] += b[i]
            terms = [rot.apply_soa(A, x) for x in (Y, V0, X)]
            self.per_col.append((c, off, m, o_lo, *terms))

    def clear(self, items, theta):
        """Is segment ``items`` turned by ``theta`` clear of every collider."""
        ctx = self.ctx
        hit = np.zeros(len(items), bool)
        cos, sin = np.cos(theta), np.sin(theta)
        back, grow = self.back[items], self.grow[items]
        for c, off, m, o_lo, Y, V0, X in self.per_col:
            w = np.flatnonzero(m[items])
            if len(w) == 0:
                continue
            it = items[w]
            d = Y.take(it, axis=1)
            d += V0.take(it, axis=1) * cos[w]
            d += X.take(it, axis=1) * sin[w]
            o = o_lo.take(it, axis=1)
            o -= back[w] * d
            d *= grow[w]
            hit[w] |= c.segment_hits_local(rot.rows32(o), rot.rows32(d), off, ctx.threads,
                                           ctx.reaches.get(id(c)))
            ctx.n_rays += len(w)
        return ~hit


#: Soft recovery: fractions of the recovery step tested when it collides.
_LEVELS = 16


class _Slerp:
    """Spherical interpolation from ``p`` to ``q`` (k, 4), its arc set up once
    (:func:`rotations.quat_slerp`'s arithmetic, bit for bit): each call only
    evaluates two sines. Kept as component arrays (4, k): long contiguous
    passes instead of rows of 4."""

    def __init__(self, p, q):
        d = rot.dot(p, q)
        flip = d < 0
        self.p = np.ascontiguousarray(p.T)
        self.q = np.ascontiguousarray(np.where(flip[:, None], -q, q).T)
        self.q_raw = np.ascontiguousarray(q.T)
        d = np.abs(d)
        self.theta = np.arccos(np.minimum(d, 1.0))  # (d >= 0 here)
        s = np.sin(self.theta)
        self.small = s < 1e-9
        self.s = np.where(self.small, 1.0, s)

    def soa(self, t, rows=None):
        """Rows ``rows`` (all if None) at fractions ``t`` (len(rows),), as
        component quaternions (4, len(rows))."""
        take = (lambda x: x) if rows is None else (lambda x: x.take(rows, axis=-1))
        p, q, theta, s = take(self.p), take(self.q), take(self.theta), take(self.s)
        t = np.broadcast_to(np.asarray(t, np.float64), theta.shape)
        a = np.sin((1.0 - t) * theta)
        a /= s
        b = np.sin(t * theta)
        b /= s
        small = take(self.small)
        if small.any():
            a = np.where(small, 1.0 - t, a)
            b = np.where(small, t, b)
        out = p * a
        out += q * b
        sq = out[0] * out[0]  # = norm(axis=1) of the rows: the same sums
        for i in range(1, 4):
            sq += out[i] * out[i]
        out /= np.sqrt(sq)
        ends = (t == 0) | (t == 1)
        if ends.any():  # exact at the ends: t = 0 is p and t = 1 is q, bit for bit
            out = np.where(t == 0, p, out)
            out = np.where(t == 1, take(self.q_raw), out)
        return out

    def __call__(self, t, rows=None):
        """:meth:`soa` as rows (len(rows), 4)."""
        return np.ascontiguousarray(self.soa(t, rows).T)
