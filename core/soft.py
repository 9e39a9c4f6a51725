"""Soft mode (paper 3.2.1): per-segment rotations with Affected Connected CVs and CV FallOff."""

from __future__ import annotations

import numpy as np

from . import rotations as rot
from . import tolerances as tol
from .search import gallop_bisect, scan_bisect
from .status import Status


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

    def __init__(self, ctx):
        self.ctx = ctx
        s = ctx.s
        A = s.affected_connected_cvs
        self.weights = (1.0 - s.cv_falloff) ** np.arange(1, A + 1) if A else np.zeros(0)

    def run(self, idx, status):
        ctx, p = self.ctx, self.ctx.prec
        sv = ctx.sv_
        near = idx[ctx.cand_any[idx]]
        far = idx[~ctx.cand_any[idx]]
        q0 = ctx.quat.copy()  # world, state at the start of the step
        unresolved = np.zeros(sv.n_curves, bool)
        touched = np.zeros(sv.n_curves, bool)
        todo = near
        for _ in range(int(sv._nseg.max(initial=0)) + 1):
            if len(todo) == 0:
                break
            seg, rep, starts = ctx.segments(todo)
            o, d, _, rep, starts = ctx.deform(todo, quat=ctx.quat[seg])
            k, point, push = ctx.first_hit_details(todo, o, d, rep, starts)
            hit = k >= 0
            todo, k, push = todo[hit], k[hit], push[hit]
            if len(todo) == 0:
                break
            touched[todo] = True
            ctx.active[todo] = True
            seg_hit = seg[k]  # global segment id of the first hitting segment
            if ctx.s.attract_to_growth_surface:
                mid = ctx._midpoints(todo, o, d, starts[hit])
                cp, _ = ctx.growth.closest_points(mid)
                pull = rot.normalize(cp - mid)
                ok = np.linalg.norm(np.cross(rot.normalize(d[k]), pull), axis=1) > tol.PARALLEL_EPS
                push = np.where(ok[:, None], pull, push)
            axis = rot.rotation_axis(d[k], push)
            last = sv._soff[todo + 1]  # one past the curve's last segment

            # Only the solved segment needs testing: segments before it do not
            # move (so neither does its start), segments after it are the next
            # rounds' job; its direction is its current one turned by phi.
            o_k, d_k = o[k], d[k]
            root_k = k == starts[hit]

            def test(items, ks, o_k=o_k, d_k=d_k, axis=axis, root_k=root_k, todo=todo):
                dd = rot.rotate(d_k[items], axis[items], ks * p)
                n = len(items)
                return ~ctx.hits(todo[items], o_k[items], dd, np.arange(n), root_k[items])

            kmax = np.full(len(todo), int(np.ceil(ctx.max_angle / p - 1e-9)))
            kk = scan_bisect(len(todo), test, kmax)
            ok = kk >= 0
            if ok.any():
                w = np.flatnonzero(ok)
                _, sel, q = self._rotated(seg_hit[w], last[w], axis[w], kk[w] * p)
                ctx.quat[sel] = q
                grow = rot.quat_angle(q) > rot.quat_angle(ctx.quat_max[sel])
                ctx.quat_max[sel[grow]] = q[grow]
            unresolved[todo[~ok]] = True
            todo = todo[ok]
        # Unresolvable curves fall back to their state at the start of the step.
        bad = np.flatnonzero(unresolved)
        if len(bad):
            seg, _, _ = ctx.segments(bad)
            ctx.quat[seg] = q0[seg]
            ctx.active[bad] = self.ctx.sv_._active[bad]
            status[bad] = Status.UNRESOLVED
        status[touched & ~unresolved] = Status.COLLIDING
        rec = np.sort(np.concatenate([near, far]))
        rec = rec[~touched[rec] & ctx.active[rec]]
        if len(rec):
            self.recover(rec, status)

    def _rotated(self, seg_hit, last, axis, phi):
        """(owner, segment ids, composed quaternions) after turning ``seg_hit`` by ``phi``."""
        ctx = self.ctx
        n = len(seg_hit)
        span = np.minimum(len(self.weights) + 1, last - seg_hit)  # segments affected
        rep = np.repeat(np.arange(n), span)
        first = np.concatenate([[0], np.cumsum(span)[:-1]])
        i = np.arange(int(span.sum())) - first[rep]
        sel = seg_hit[rep] + i
        w = np.concatenate([[1.0], self.weights])[i]
        r = rot.quat_from_axis_angle(axis[rep], phi[rep] * w)
        return rep, sel, rot.quat_canonical(rot.quat_mul(r, ctx.quat[sel]))

    def recover(self, rec, status):
        """Slerp every segment toward its target; stop before contact."""
        ctx, s, p = self.ctx, self.ctx.s, self.ctx.prec
        seg, rep, starts = ctx.segments(rec)
        q0 = ctx.quat[seg]
        ident = np.zeros_like(q0)
        ident[:, 0] = 1.0
        frac = ctx.target_fraction(rec)
        hold = np.isnan(frac)
        qt = rot.quat_slerp(ident, ctx.quat_max[seg], np.nan_to_num(frac)[rep])
        qt = np.where(hold[rep][:, None], q0, qt)

        q1 = rot.quat_slerp(q0, qt, np.full(len(q0), s.recovery_rate))
        # Within half a precision step of the target (every segment): land on it.
        conj = qt * np.array([1.0, -1.0, -1.0, -1.0])
        near_t = rot.quat_angle(rot.quat_mul(q1, conj)) < tol.SNAP_FRACTION * p
        snap = np.logical_and.reduceat(near_t, starts)
        q1 = np.where(snap[rep][:, None], qt, q1)
        moving = ~np.all(q1 == q0, axis=1)
        moving_c = np.logical_or.reduceat(moving, starts)
        is_near = ctx.cand_any[rec]
        chk = np.flatnonzero(moving_c & is_near)
        blocked = np.zeros(len(rec), bool)
        if len(chk):
            sseg, srep, _ = ctx.segments(rec[chk])
            pos = np.searchsorted(seg, sseg)
            blocked[chk] = ctx.curve_hits(rec[chk], quat=q1[pos])
        if blocked.any():
            b = np.flatnonzero(blocked)
            # Bisect the recovery fraction on 16 levels (finer than precision
            # for any recovery step a frame can take).
            levels = 16

            def test(items, ks):
                c = rec[b[items]]
                sseg, srep, _ = ctx.segments(c)
                pos = np.searchsorted(seg, sseg)
                lamk = (ks / levels * s.recovery_rate)[srep]
                q = rot.quat_slerp(q0[pos], qt[pos], lamk)
                return ~ctx.curve_hits(c, quat=q)

            # The largest safe fraction is the smallest good k of the reversed
            # grid (fraction levels - k): k = levels (fraction 0) is known good.
            def test_rev(items, ks):
                return test(items, levels - ks)

            kr = gallop_bisect(
                len(b),
                test_rev,
                np.full(len(b), levels),
                lo=np.zeros(len(b)),
                hi=np.full(len(b), levels),
            )
            sseg, srep, _ = ctx.segments(rec[b])
            pos = np.searchsorted(seg, sseg)
            lamk = ((levels - kr) / levels * s.recovery_rate)[srep]
            q1[pos] = rot.quat_slerp(q0[pos], qt[pos], lamk)
        ctx.quat[seg] = q1
        changed = np.logical_or.reduceat(~np.all(q1 == q0, axis=1), starts)
        identity = np.logical_and.reduceat(np.all(q1 == ident, axis=1), starts)
        st = np.where(
            blocked, Status.COLLIDING, np.where(changed & ~identity, Status.RECOVERING, Status.FREE)
        )
        status[rec] = np.maximum(status[rec], st)
        # Back exactly at the input shape: drop the state.
        done = rec[identity]
        ctx.active[done] = False
        dseg, _, _ = ctx.segments(done)
        ctx.quat_max[dseg] = ident[: len(dseg)]
