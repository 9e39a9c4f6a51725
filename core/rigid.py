"""Stiff and Bend (paper 3.2.1), Shrink (3.2.2), Recovery and Plasticity (3.2.3-4).

A Stiff or Bend curve carries one angle about one axis (kept in the curve's
local frame from its first hit until it has recovered); :func:`solve` finds
that angle for all curves of a step at once and returns every curve's
rotation as it leaves it (:class:`Turns`, the mode's own while it solves),
which the step applies (``StepContext.apply``). The step lends its machinery
(deformation, ray queries, first hits); these functions never write into it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from . import rotations as rot
from . import tolerances as tol
from .rays import run_parts
from .search import NONE, gallop_bisect
from .status import Status

#: Probes per curve per search round. Each probe of a Stiff/Bend curve builds
#: all its segments, and one that clears traces them all: one probe per round
#: casts fewest rays (sustained contact: 401,000 rays a frame instead of
#: 451,000 with two), which outweighs the rounds it adds.
_WIDTH = 1

#: A search from scratch (:func:`search_angles` with ``use_guess``) first probes
#: this multiple of its tangent-plane estimate, then gallops on from there with a
#: stride of the estimate over ``_GUESS_STRIDE``, or bisects below a clearing probe.
#: The estimate is low: the answers measured 1.0-1.6 times it (median 1.1 under
#: the orbiting ball of ``make bench``, 1.3-1.4 under the hat and in the render
#: groom's clearance pass). One probe at 1.3 times it takes fewer probes there than
#: four spread around it (0.8, 1, 1.25, 1.6, before): the clearance pass 6.8 -> 4.7 probes
#: per curve, 8 % less CPU; the same answers wherever clearance is monotone.
_GUESS_FACTOR = 1.3
_GUESS_STRIDE = 4

#: Probes per block when building ray batches (working arrays stay in cache).
_BLOCK = 1024


@dataclass
class Turns:
    """Stiff/Bend's answer for one step: every curve's rotation as the mode leaves it.

    :func:`solve` makes it from the step's rotations (its own copies: the rows
    of the curves it solves change) and returns it; ``StepContext.apply`` takes
    it. The halves of a step (``StepContext.in_halves``) share it, each writing
    only its own curves.

    Attributes
    ----------
    angle, angle_max : (C,) float64
        The rotation (radians) and the largest of the contact.
    axis : (C, 3) float64
        The rotation axis, world.
    active : (C,) bool
        Has a non-identity state.
    stiff : (C,) bool
        A Bend curve solved as Stiff (bending could not clear it).
    restyled : (C,) bool
        Started again this step (a new axis) or fallen back to Stiff: the next
        step's search keeps no memory of its change.
    status : (C,) int8
        The outcome of each curve solved (``Status``; FREE elsewhere).
    guess, guess_stiff : (C,) float64
        The searches' first probes: tangent-plane estimates of the angle
        (``StepContext.plane_guess``), as the mode turns and as Stiff.
    """

    angle: np.ndarray
    angle_max: np.ndarray
    axis: np.ndarray
    active: np.ndarray
    stiff: np.ndarray
    restyled: np.ndarray
    status: np.ndarray
    guess: np.ndarray
    guess_stiff: np.ndarray

    @classmethod
    def of(cls, ctx) -> Turns:
        """The step's rotations as they are before the solve (copies)."""
        C = ctx.layout.n_curves
        return cls(ctx.angle.copy(), ctx.angle_max.copy(), ctx.axis.copy(), ctx.active.copy(),
                   ctx.stiff.copy(), np.zeros(C, bool), np.zeros(C, np.int8), np.zeros(C),
                   np.zeros(C))


def solve(ctx, idx) -> Turns:
    """Stiff and Bend: one angle per curve about its kept axis, for curves ``idx``."""
    t = Turns.of(ctx)
    near = idx[ctx.cand_any[idx]]
    far = idx[~ctx.cand_any[idx]]
    act = near[t.active[near]]  # rotated curves near a collider
    new = near[~t.active[near]]  # unrotated: their segments are the input's
    # 1. Unrotated curves near a collider: tested at their input shape; 2. the
    # searches. Each in parts, one per thread, when there are many.
    ctx.in_halves(_new_contacts, len(new), new, turns=t)
    cn = new[t.active[new]]
    ctx.in_halves(_search, len(act) + len(cn), act, cn, turns=t)
    rec = far[t.active[far]]  # far from every collider: nothing to check
    th_far = t.angle[rec].copy()
    recover(t, rec, th_far, recovery_step(ctx, t, rec), np.zeros(len(rec), bool))
    release(t, idx)
    return t


def _new_contacts(ctx, new, turns):
    """Test unrotated curves ``new`` at their input shape; the ones that hit
    become active with the axis of their first hit (kept until recovered)."""
    hit_new, seg_hit = ctx.input_hits(new)
    cn = new[hit_new]
    if len(cn):
        seg_hit = seg_hit[np.repeat(hit_new, ctx.layout.nseg[new])]  # (the same rays)
        o, d, _, rep, starts = ctx.input_rays(cn)
        axis, guess, guess_stiff = ctx.new_axes(cn, o, d, rep, starts, turns.stiff[cn], seg_hit)
        turns.axis[cn] = axis
        turns.guess[cn] = guess
        turns.guess_stiff[cn] = guess_stiff
        turns.active[cn] = True


def _search(ctx, act, cn, turns):
    """Angles of the rotated curves ``act`` near a collider and of the new
    contacts ``cn`` (their axes set): collisions, recoveries, restarts and
    Bend's fall back to Stiff. Each curve's answer is its own."""
    t = turns
    angle = t.angle
    # One batch for the rotated curves (items 0..len(act)-1) and the new
    # colliding ones, so that every search below is one ray query per round.
    curves = np.concatenate([act, cn])
    batch = RigidBatch(ctx, curves, t.axis[curves], t.stiff[curves])
    th0 = angle[act].copy()
    th1 = recovery_step(ctx, t, act)
    plan = Plan(ctx, act, th0, th1)
    if ctx.warm_start:
        plan.first_round_warm(batch)
    else:
        plan.first_round_full(batch)
    # Collisions without a bracket yet: a first probe that lifts the
    # current shape above the tangent plane at the first hit.
    cc = plan.collisions_to_guess()
    if len(cc):
        c = act[cc]
        o, d, _, rep, starts = ctx.deform(c, angle=angle[c], axis=t.axis[c], stiff=t.stiff[c])
        k, point, push = ctx.first_hit_details(c, o, d, rep, starts)
        g, g_stiff = ctx.plane_guess(c, o + d, rep, starts, point, push, t.axis[c], t.stiff[c])
        t.guess[c] = np.where(k >= 0, g, t.guess[c])
        t.guess_stiff[c] = g_stiff
    # Every search left, collisions (new and old) and blocked recoveries,
    # in the same rounds (one ray query per round).
    col_items, col_lo, col_hi, col_stride, col_guess = plan.collision_searches()
    new_lo, new_hi, new_stride, new_guess = fresh_searches(len(cn))
    items = np.concatenate([col_items, len(act) + np.arange(len(cn))])
    lo = np.concatenate([col_lo, new_lo])
    hi = np.concatenate([col_hi, new_hi])
    stride = np.concatenate([col_stride, new_stride])
    use_guess = np.concatenate([col_guess, new_guess])
    k_col, k_rec = search_angles(ctx, batch, items, angle[batch.curves[items]], lo, hi, stride,
                                 use_guess, plan.recovery_searches(),
                                 guess=t.guess[batch.curves[items]])
    plan.recovery_found(k_rec)
    # Contacts pushed back the other way: a turn further by more than their
    # whole angle; then, after Bend's fall back to Stiff, those still unresolved.
    again = np.zeros(len(items), bool)
    further = k_col != NONE
    again[further] = restart_contacts(ctx, t, batch, items[further], k_col[further])
    left = items[~again]
    resolve_collisions(ctx, t, batch, left, k_col[~again])
    left = left[t.status[batch.curves[left]] == Status.UNRESOLVED]
    restart_contacts(ctx, t, batch, left, np.full_like(left, NONE))
    rec = plan.recovered_items()
    recover(t, act[rec], th0[rec], plan.recovered_angle(rec), plan.blocked(rec))


def fresh_searches(n):
    """(lo, hi, stride, use_guess) of ``n`` collision searches from scratch, as
    :func:`search_angles` takes them: step 0 (the current angle) blocked, no
    clearing step known, a first gallop stride of 1, from the tangent-plane guess."""
    return np.zeros(n, np.int64), np.full(n, NONE, np.int64), np.ones(n, np.int64), np.ones(n, bool)


class Plan:
    """Where each rotated curve near a collider stands during a step.

    Every curve ends in one of two regimes (paper 3.2.1, 3.2.3):

    * collision: blocked at its current angle ``th0``; it turns further, to
      the smallest clearing angle ``th0 + k p`` (``k >= 1``);
    * recovery: clear at ``th0``; it turns back to the recovery step ``th1``
      or, where that step collides, to the smallest clearing angle
      ``min(th1 + k p, th0)`` (``0 <= k <= K``): recovery stops before
      contact.

    A search keeps per curve a known blocked step ``lo`` and a known
    clearing step ``hi`` (``search.NONE``: none yet) on its regime's grid; the answer is
    the clearing step right above a blocked one (the first clearing step
    wherever clearance is monotone in the angle).

    The first round (:meth:`first_round_warm`) uses each curve's memory of
    the last step (``Solver`` state ``contact``, ``delta``): a curve in
    contact probes where last step's answer and change put it now, plus the
    step below, so a lasting contact is confirmed in one round of two or
    three probes instead of searched for from its current angle. The full
    search (:meth:`first_round_full`, ``Solver.warm_start = False``) probes
    the recovery step, then the current angle, as the reference.
    """

    def __init__(self, ctx, act, th0, th1):
        self.ctx, self.act, self.th0, self.th1 = ctx, act, th0, th1
        p = ctx.prec
        self.moving = th1 < th0
        # recovery grid th1 + k p, k in [0, K] (K: th0 itself, the cap)
        self.K = np.where(
            self.moving, np.maximum(np.ceil((th0 - th1) / p - 1e-9), 1), 0
        ).astype(np.int64)
        self.kmax = collision_steps(ctx, th0, act)  # collision grid th0 + k p, k in [1, kmax]
        # per curve (the dtype of the curve indices, int64): regime (0 unknown,
        # 1 collision, 2 recovery) and bracket
        self.regime = np.zeros_like(act)
        self.lo = np.full_like(act, NONE)
        self.hi = np.full_like(act, NONE)
        self.stride = np.ones_like(act)
        self.k = np.full_like(act, -2)  # recovery answers (-2: not a recovery)

    # ---------------------------------------------------------- probing
    def _theta(self, i, k, collision):
        """Angle of step ``k`` of curves ``i`` on the collision or recovery grid."""
        if collision:
            return np.minimum(self.th0[i] + k * self.ctx.prec,
                              self.ctx.max_angle_of(self.act[i]))
        return np.minimum(self.th1[i] + k * self.ctx.prec, self.th0[i])

    def _probe(self, batch, probes):
        """One ray query for ``probes``: a list of (curves i, steps k (one per curve,
        or one for all), collision grid?) groups. Returns the clear flags, one array
        per group."""
        items = [i for i, _, _ in probes]
        theta = [self._theta(i, k, c) for i, k, c in probes]
        clear = ~batch.hits(np.concatenate(items), np.concatenate(theta))
        out, a = [], 0
        for i in items:
            out.append(clear[a:a + len(i)])
            a += len(i)
        return out

    def _regime_test(self, batch, i, lo_rec):
        """Probe ``th0`` of curves ``i`` (recovery step ``lo_rec`` known blocked):
        clear starts a recovery search, blocked a collision search."""
        if len(i) == 0:
            return
        (clear,) = self._probe(batch, [(i, 0, True)])
        r, c = i[clear], i[~clear]
        self.regime[r] = 2
        self.lo[r], self.hi[r] = lo_rec[clear], self.K[r]
        self.regime[c] = 1
        self.lo[c] = 0

    def first_round_full(self, batch):
        """Reference search: the recovery step, then (if it is blocked) the
        current angle, then a collision or recovery search."""
        n = len(self.act)
        i = np.arange(n)
        k = np.where(self.moving, 0, self.K)
        # step 0 of the recovery grid is th1 (or th0 when not moving)
        (clear,) = self._probe(batch, [(i, k, False)])
        r = i[clear]
        self.regime[r] = 2
        self.k[r] = k[clear]  # clear at the recovery step: recovered (no search)
        b = i[~clear]
        m = self.moving[b]
        self._regime_test(batch, b[m], np.zeros_like(b[m]))
        c = b[~m]  # not moving and blocked at th0: a collision
        self.regime[c] = 1
        self.lo[c] = 0

    def first_round_warm(self, batch):
        """First round from the curves' memory (see the class docstring)."""
        ctx, p = self.ctx, self.ctx.prec
        n = len(self.act)
        i = np.arange(n)
        contact = ctx.state.contact[self.act]
        delta = ctx.state.delta[self.act]
        # a contact that was turning further: it likely turns as much again
        pred_col = contact & (delta > 0) & (self.kmax >= 1)
        kc = np.clip(np.rint(delta / p), 1, self.kmax).astype(np.int64)  # (used: kmax >= 1)
        # a contact that held or gave way: the same change on the recovery grid
        pred_rec = contact & ~pred_col & self.moving
        kr = np.clip(np.ceil((self.th0 + np.minimum(delta, 0) - self.th1) / p - 1e-9),
                     0, self.K).astype(np.int64)
        rest = ~pred_col & ~pred_rec
        ic, ir, io = i[pred_col], i[pred_rec], i[rest]
        kc, kr = kc[pred_col], kr[pred_rec]
        ko = np.where(self.moving[io], 0, self.K[io])  # as the full search
        kc2 = kc - 1  # (probed only where kc > 1: step 0 is th0 itself)
        two = kc > 1
        kr1 = kr >= 2  # (step kr - 1 = 0, the recovery step, is probed for all of mv below)
        # The recovery step too, where it moves: clear there, a curve
        # recovers to it, as in the full search (whatever the rest says).
        mv = np.concatenate([ic, ir])
        mv = mv[self.moving[mv]]
        clear = self._probe(batch, [
            (io, ko, False),
            (ic, 0, True),
            (ic[two], kc2[two], True),
            (ic, kc, True),
            (ir, kr, False),
            (ir[kr1], kr[kr1] - 1, False),
            (mv, 0, False),
        ])
        c_o, c_c0, c_c2, c_c, c_r, c_r1, c_mv = clear
        # the rest: as the full search
        r = io[c_o]
        self.regime[r] = 2
        self.k[r] = ko[c_o]  # recovered (no search)
        b = io[~c_o]
        m = self.moving[b]
        pend_i, pend_lo = [b[m]], [np.zeros_like(b[m])]
        c = b[~m]
        self.regime[c] = 1
        self.lo[c] = 0
        # predicted collisions
        rec = ic[c_c0]  # clear at th0 after all: a recovery, th0 clear
        self.regime[rec] = 2
        self.lo[rec], self.hi[rec] = NONE, self.K[rec]
        blk = ~c_c0
        col = ic[blk]
        self.regime[col] = 1
        lo = np.zeros_like(ic)
        hi = np.full_like(ic, NONE)
        mid = np.full(len(ic), True)  # kc - 1 clear (or untested)
        mid[np.flatnonzero(two)] = c_c2
        lo = np.where(two & ~mid, kc2, lo)
        hi = np.where(c_c, kc, hi)
        hi = np.where(two & mid, kc2, hi)
        self.lo[col], self.hi[col] = lo[blk], hi[blk]
        self.stride[col] = np.maximum(kc[blk] // 2, 1)
        # predicted recoveries (th0 is clear wherever step kr is)
        ok = c_r.copy()
        below = np.full(len(ir), False)  # step kr - 1 clear
        below[np.flatnonzero(kr1)] = c_r1
        r = ir[ok]
        self.regime[r] = 2
        self.hi[r] = kr[ok]
        self.lo[r] = np.where(below[ok], NONE, kr[ok] - 1)
        self.hi[r] = np.where(below[ok], kr[ok] - 1, kr[ok])
        nb = ~ok  # blocked at step kr: th0 decides the regime
        full = nb & (kr == self.K[ir])  # step K is th0: a collision
        c = ir[full]
        self.regime[c] = 1
        self.lo[c] = 0
        pend_i.append(ir[nb & ~full])
        pend_lo.append(kr[nb & ~full])
        pend = np.concatenate(pend_i)
        pend_k = np.concatenate(pend_lo)
        # clear at the recovery step: recovered (as the full search decides first)
        rec0 = mv[c_mv]
        self.regime[rec0] = 2
        self.k[rec0] = 0
        keep = ~np.isin(pend, rec0)
        self._regime_test(batch, pend[keep], pend_k[keep])
        # (a recovery whose bracket is closed goes to the search all the same:
        # gallop_bisect returns a settled bracket's top without a probe)

    # --------------------------------------------------------- searches
    def _nothing_known(self, c):
        """Which collisions ``c`` know nothing above ``th0`` (they take the guess)."""
        return (self.hi[c] == NONE) & (self.lo[c] == 0) & (self.stride[c] == 1)

    def collisions_to_guess(self):
        """Collisions with nothing known above ``th0``: they get the tangent-plane guess."""
        c = np.flatnonzero(self.regime == 1)
        return c[self._nothing_known(c)]

    def collision_searches(self):
        """(items, lo, hi, stride, use the guess) of the collision searches."""
        c = np.flatnonzero(self.regime == 1)
        return c, self.lo[c], self.hi[c], self.stride[c], self._nothing_known(c)

    def recovery_searches(self):
        """(items, base th1, cap th0, K, lo, hi) of the recoveries still searched."""
        r = np.flatnonzero((self.regime == 2) & (self.k == -2))
        self._searched = r
        return r, self.th1[r], self.th0[r], self.K[r], self.lo[r], self.hi[r]

    def recovery_found(self, k):
        self.k[self._searched] = k

    def recovered_items(self):
        return np.flatnonzero(self.regime == 2)

    def recovered_angle(self, r):
        return self._theta(r, self.k[r], False)

    def blocked(self, r):
        """Recoveries stopped before contact (answer above the recovery step)."""
        return (self.k[r] > 0) & self.moving[r]


def restart_contacts(ctx, turns, batch, items, k):
    """Contacts pushed back the other way start again from the input shape.

    A curve keeps the axis of its first hit until it has recovered (paper
    3.2.1), and a collision only turns it further about it. A collider that
    arrives from the other side of a curve still turned (recovering, or held
    at its Plasticity imprint) would then whip it the long way round, under
    that collider. Where the search's answer ``k`` turns curve
    ``batch.curves[items]`` further by more than its whole angle (``k = NONE``:
    no angle, e.g. still unresolved after Bend's fall back to Stiff), the
    curve is also solved as a new contact: its input shape, an axis from the
    input's first hit, the smallest clearing angle from zero (or zero itself
    where the input is clear). The new contact is kept where it moves the
    curve's CVs (from their place at the current angle) less than
    ``tol.RESTART_GAIN`` times what turning further would, or where turning
    further finds no angle. Everything here depends only on ``k`` and the
    curve, so the warm start still equals the full search.

    Returns
    -------
    (len(items),) bool
        The items started again (their angle, axis and status are set in ``turns``).
    """
    t = turns
    again = np.zeros(len(items), bool)
    if len(items) == 0:
        return again
    p = ctx.prec
    c = batch.curves[items]
    th0 = t.angle[c]
    turn = np.where(k != NONE, k * p, np.inf)
    sel = np.flatnonzero((th0 > 0) & (turn > th0 + tol.RESTART_MIN_STEPS * p))
    if len(sel) == 0:
        return again
    cs = c[sel]
    axis0 = t.axis[cs]
    stiff0 = t.stiff[cs]
    # The current shape, and the one turning further would give (the kept axis).
    now = _ends(ctx, cs, th0[sel], axis0, stiff0)
    ok = np.isfinite(turn[sel])
    further = _moved(ctx, cs, now,
                     _ends(ctx, cs, th0[sel] + np.where(ok, turn[sel], 0.0), axis0, stiff0))
    further[~ok] = np.inf
    # The new contact: a fresh solve of the input shape, as Bend (not Stiff), about
    # the axis of the input's first hit.
    bend = np.zeros(len(cs), bool)
    phi = np.zeros(len(cs))
    axis1 = axis0.copy()
    found = np.ones(len(cs), bool)
    hit0, seg_hit = ctx.input_hits(cs)
    hb = np.flatnonzero(hit0)
    if len(hb):
        cb = cs[hb]
        seg_hit = seg_hit[np.repeat(hit0, ctx.layout.nseg[cs])]
        o, d, _, rep, starts = ctx.input_rays(cb)
        axis1[hb], t.guess[cb], t.guess_stiff[cb] = ctx.new_axes(cb, o, d, rep, starts,
                                                                 bend[hb], seg_hit)
        n = len(cb)
        kb, _ = search_angles(ctx, RigidBatch(ctx, cb, axis1[hb], bend[hb]), np.arange(n),
                              np.zeros(n), *fresh_searches(n), guess=t.guess[cb])
        found[hb] = kb != NONE
        phi[hb] = np.where(found[hb], np.minimum(kb * p, ctx.max_angle_of(cb)), 0.0)
    anew = _moved(ctx, cs, now, _ends(ctx, cs, phi, axis1, bend))
    take = found & (anew < tol.RESTART_GAIN * further)
    cr = cs[take]
    if len(cr):
        t.stiff[cr] = False
        t.restyled[cr] = True  # a new grid: no memory of the last change
        t.axis[cr] = axis1[take]
        t.angle[cr] = phi[take]
        t.angle_max[cr] = phi[take]
        t.status[cr] = np.where(phi[take] > 0, Status.COLLIDING, Status.FREE)
        again[sel[take]] = True
    return again


def _ends(ctx, idx, angle, axis, stiff):
    """(k, 3) segment ends of curves ``idx`` turned by ``angle`` (n,) about
    ``axis`` (n, 3) (``stiff`` (n,): Bend curves turned as Stiff), in the rows of
    :meth:`StepContext.deform`."""
    o, d, _, _, _ = ctx.deform(idx, angle=np.asarray(angle, np.float64), axis=axis,
                               stiff=stiff)
    return o + d


def _moved(ctx, idx, a, b):
    """Largest CV displacement of each curve ``idx`` between segment ends ``a``
    and ``b`` (rows as :meth:`StepContext.deform` gives them)."""
    starts = np.concatenate([[0], np.cumsum(ctx.layout.nseg[idx])[:-1]])
    dist = np.sqrt(rot.dot(a - b, a - b))
    return np.maximum.reduceat(dist, starts)


def resolve_collisions(ctx, turns, batch, items, k):
    """Apply the collision searches' answers ``k`` to ``batch.curves[items]``
    (paper 3.2.1), with Bend's fall back to Stiff and the unresolved fallback."""
    t = turns
    p, angle = ctx.prec, t.angle
    c = batch.curves[items]
    if len(items) == 0:
        return
    th0 = angle[c].copy()
    if ctx.s.mode == "bend":
        # Bending turns the root segment by only 1/n of the angle: curves
        # hit near the root that bending cannot clear turn at the root (as
        # Stiff) instead, until they have recovered.
        retry = np.flatnonzero((k == NONE) & ~t.stiff[c])
        if len(retry):
            cr = c[retry]
            # seed: the Stiff estimate at the current shape (the tangent plane
            # at its first hit, whatever path the search took), plus about
            # the mean bend already taken
            bend = t.stiff[cr]
            o, d, _, rep, starts = ctx.deform(cr, angle=angle[cr], axis=t.axis[cr], stiff=bend)
            kh, point, push = ctx.first_hit_details(cr, o, d, rep, starts)
            _, t.guess_stiff[cr] = ctx.plane_guess(cr, o + d, rep, starts, point, push,
                                                   t.axis[cr], bend)
            t.stiff[cr] = True
            t.restyled[cr] = True
            seed = t.guess_stiff[cr] + 0.5 * th0[retry]
            n = len(cr)
            k2, _ = search_angles(ctx, RigidBatch(ctx, cr, t.axis[cr], t.stiff[cr]),
                                  np.arange(n), np.zeros(n), *fresh_searches(n), guess=seed)
            # (still restyled: they end UNRESOLVED, which the next step does
            # not remember as a contact either way)
            ok2 = k2 != NONE
            t.stiff[cr[~ok2]] = False
            k[retry[ok2]] = k2[ok2]
            th0[retry[ok2]] = 0.0
    ok = k != NONE
    res = c[ok]
    angle[res] = np.minimum(th0[ok] + k[ok] * p, ctx.max_angle_of(res))
    t.angle_max[res] = np.maximum(t.angle_max[res], angle[res])
    t.status[res] = Status.COLLIDING
    bad = c[~ok]
    t.status[bad] = Status.UNRESOLVED
    # Fallback: the state of the previous frame (last collision-free).
    angle[bad] = th0[~ok]  # (a new contact left at 0 is released by release())


def recovery_step(ctx, turns, rec):
    """This frame's recovery angle of curves ``rec`` (paper 3.2.3-4).

    The angle moves toward the target ``plasticity * largest angle`` (or
    stays, for curves held after a pinch) by ``recovery_rate`` of the
    remaining difference; within half a precision step it lands on the
    target, and below half a step on exactly zero.
    """
    p = ctx.prec
    th0 = turns.angle[rec]
    frac = ctx.target_fraction(rec)
    target = np.where(np.isnan(frac), th0, np.nan_to_num(frac) * turns.angle_max[rec])
    target = np.minimum(target, th0)
    th1 = th0 - ctx.s.per_curve("recovery_rate", rec) * (th0 - target)
    th1 = np.where(th1 - target < tol.SNAP_FRACTION * p, target, th1)
    return np.where(th1 < tol.SNAP_FRACTION * p, 0.0, th1)


def recover(turns, rec, th0, th1, blocked):
    """Turn clear curves ``rec`` from ``th0`` to ``th1`` (their recovery step,
    or where that step collides, ``blocked``, the smallest clearing angle
    above it found by the search: recovery stops before contact)."""
    if len(rec) == 0:
        return
    turns.angle[rec] = th1
    # Back at exactly the input shape counts as FREE, not RECOVERING.
    st = np.where((th1 < th0) & (th1 > 0), Status.RECOVERING, Status.FREE)
    st[blocked] = Status.COLLIDING
    turns.status[rec] = np.maximum(turns.status[rec], st)


def collision_steps(ctx, th0, curves):
    """(n,) int64: the last step ``k`` of the collision grid ``th0 + k p`` of curves
    ``curves`` (n,) at angles ``th0`` (n,), the one that reaches their Max Angle (0
    for a curve already there)."""
    return np.maximum(np.ceil((ctx.max_angle_of(curves) - th0) / ctx.prec - 1e-9),
                      0).astype(np.int64)


def search_angles(ctx, batch, items, th0, lo, hi, stride, use_guess, bisect=None, guess=None):
    """Smallest clearing rotation above ``th0`` of ``batch.curves[items]``.

    Steps ``k`` count from ``th0`` (angle ``min(th0 + k p, max_angle)``);
    ``lo`` is a known blocked step, ``hi`` a known clearing one (``NONE``:
    none yet), ``stride`` the first gallop stride (:func:`fresh_searches`:
    searches from scratch). Items with ``use_guess`` (and nothing known)
    start from an estimate of the increment, ``guess`` (n,) (needed when any
    item uses it: e.g. the tangent-plane estimate of
    :meth:`StepContext.plane_guess`, ``Turns.guess``): one round probes ``_GUESS_FACTOR`` times
    it (1.3), and the search continues from the bracket that gives
    (bisection) or from its top (gallop, stride ``estimate / _GUESS_STRIDE``).

    ``bisect`` (items ``bi``, base ``lo_th``, cap ``hi_th``, ``K``, ``lo``,
    ``hi``): recovery searches for the smallest clearing ``min(lo_th + k p,
    hi_th)``, ``k`` in ``(lo, K]``, of ``batch.curves[bi]``, run in the same
    rounds (one ray query per round for both).

    Returns
    -------
    k : (n,) int
        Steps of the collision searches, ``NONE`` where no angle up to
        ``max_angle`` clears the curve.
    k_bisect : (m,) int
        The recovery searches' steps (empty without ``bisect``).
    """
    p = ctx.prec
    n = len(items)
    curves = batch.curves[items]
    kmax = collision_steps(ctx, th0, curves)
    base = th0
    cap = np.empty(n)
    cap[:] = ctx.max_angle_of(curves)
    lo = lo.copy()
    hi = hi.copy()
    stride = stride.copy()

    def test(it, ks):
        return ~batch.hits(all_items[it], np.minimum(base[it] + ks * p, cap[it]))

    all_items = items
    it = np.flatnonzero(use_guess & (kmax >= 1))
    if len(it):
        # One probe at the guess (scaled: it is low); it leaves a bracket to
        # bisect, or a floor to gallop on from with a guess-sized stride.
        g = guess[it]
        kg = np.clip(np.rint(g / p).astype(np.int64), 1, kmax[it])
        kp = np.clip(np.rint(kg * _GUESS_FACTOR).astype(np.int64), 1, kmax[it])
        good = test(it, kp)
        hi[it[good]] = kp[good]
        lo[it[good]] = 0  # (nothing known below the probe)
        lo[it[~good]] = kp[~good]
        stride[it] = np.maximum(kg // _GUESS_STRIDE, 1)
    m = 0
    if bisect is not None and len(bisect[0]):
        bi, lo_th, hi_th, K, blo, bhi = bisect
        m = len(bi)
        all_items = np.concatenate([items, bi])
        base = np.concatenate([th0, lo_th])
        cap = np.concatenate([cap, hi_th])
        kmax = np.concatenate([kmax, K])
        lo = np.concatenate([lo, blo])
        hi = np.concatenate([hi, bhi])
        stride = np.concatenate([stride, np.ones_like(bi)])
    k = gallop_bisect(len(all_items), test, kmax, lo=lo, hi=hi, stride=stride, width=_WIDTH)
    return k[:n], k[n:n + m]


def release(turns, idx):
    """Curves back at exactly their input shape drop their local state."""
    t = turns
    done = idx[t.active[idx] & (t.angle[idx] == 0)]
    t.active[done] = False
    t.stiff[done] = False
    t.axis[done] = 0.0
    t.angle_max[done] = 0.0


def _stages(ns):
    """Segment ranges (first, stop) a probe's rays are traced in, in turn.

    A probe that collides usually collides at its tip (the outer segments turn
    the most), so the tip segment goes first, then the next one, then the rest
    of the outer half, then the inner half; each range only for the probes the
    ones before left clear. The answer does not depend on the order; a probe
    that collides costs about 1.5 rays instead of the 4 of an outer-half-first
    order (sustained contact at paper scale: 345,000 rays per frame instead of
    414,000).
    """
    t = ns // 2
    if ns - t >= 3:
        return ((ns - 1, ns), (ns - 2, ns - 1), (t, ns - 2), (0, t))
    return ((t, ns), (0, t)) if t else ((0, ns),)


class RigidBatch:
    """Stiff/Bend curves under search, with all angle-independent work done once.

    Rodrigues' rotation of a segment ``v`` about the curve's axis ``a`` is
    ``Y + V0 cos(t) + X sin(t)`` with ``Y = a (a.v)``, ``V0 = v - Y`` and
    ``X = a x v``; the map into a collider's space is affine, so ``Y``, ``V0``,
    ``X`` and the roots are moved into each collider's space once. A probe
    round then costs a gather, a cos/sin, a cumulative sum and the ray query.
    Rays are grown by ``tol.RAY_EXTEND_ULPS`` as in :meth:`core.step.StepContext.hits`.
    """

    def __init__(self, ctx, curves, axis, stiff):
        """``axis`` (n, 3): each curve's rotation axis (world); ``stiff`` (n,) bool:
        Bend curves turned as Stiff."""
        self.ctx = ctx
        self.curves = curves
        self.cnt = ctx.layout.nseg[curves]
        # Uniform CV counts (the usual groom): component arrays (3, ns, n),
        # see :meth:`_hits_uniform`.
        self.ns = ctx.layout.ns if len(curves) else 0
        if self.ns:
            self._init_uniform(ctx, curves, axis, stiff)
            return
        seg, rep, starts = ctx.segments(curves)
        self.starts = starts
        v = ctx.seg_in(seg)
        ax = axis[rep]
        Y = ax * rot.dot(ax, v)[:, None]
        X = np.cross(ax, v)
        V0 = v - Y
        if ctx.s.mode == "bend":
            self.w = np.where(stiff[rep], 1.0, ctx.layout.w_bend[seg])
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

    def _init_uniform(self, ctx, curves, axis, stiff):
        """The terms as (3, ns, n) component arrays (same arithmetic as the
        rows of 3 of the general case, so the same rays bit for bit)."""
        v = ctx.seg_soa(curves)
        ax = np.ascontiguousarray(axis.T)  # components as contiguous rows
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
        self.w = np.broadcast_to(ctx.bend_weights(stiff), (self.ns, len(curves)))
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
        scale = ctx.shrink_scale(a, self.curves[items][rep])
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
            o = rot.cumsum_owned(d, rep, first)
            o -= d
            o += root_lo[items][rep]
            rays = mi[rep]
            if rays.all():
                h = c.segment_hits_local(o - back * d, d * grow, off, ctx.threads,
                                         ctx.reaches.get(id(c)))
            else:
                w = np.flatnonzero(rays)
                h = np.zeros_like(rays)
                h[w] = c.segment_hits_local(o[w] - back[w] * d[w], d[w] * grow[w], off,
                                            ctx.threads, ctx.reaches.get(id(c)))
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
            terms = (root_lo, Y, V0, X)

            def part(a, b, threads, c=c, off=off, it=it, th=th, terms=terms):
                o32 = np.empty((ns, b - a, 3), np.float32)
                d32 = np.empty((ns, b - a, 3), np.float32)
                for lo in range(a, b, _BLOCK):
                    blk = slice(lo, min(lo + _BLOCK, b))
                    w = slice(lo - a, min(lo + _BLOCK, b) - a)
                    self._rays(it[blk], th[blk], *terms, o32[:, w], d32[:, w])
                # Segment ranges in turn (:func:`_stages`), each only for the
                # probes the ones before left clear: the answer is the same.
                h = np.zeros(b - a, bool)
                rest = np.arange(b - a)
                n_rays = 0
                for s0, s1 in _stages(ns):
                    if len(rest) == 0:
                        break
                    if len(rest) == b - a:
                        oo, dd = o32[s0:s1], d32[s0:s1]
                    else:
                        oo, dd = o32[s0:s1, rest], d32[s0:s1, rest]
                    hi = c.segment_hits_local(oo.reshape(-1, 3), dd.reshape(-1, 3), off,
                                              threads, ctx.reaches.get(id(c))).reshape(
                                                  s1 - s0, len(rest)).any(axis=0)
                    n_rays += (s1 - s0) * len(rest)
                    h[rest[hi]] = True
                    rest = rest[~hi]
                return h, n_rays

            if ctx.threads > 1 and k >= 2 * _BLOCK:
                # One part per thread (of at least a block each), each built and
                # traced by its thread: numpy and embree release the GIL, so the
                # parts' work overlaps. Cut at block boundaries: the blocks, and
                # so their arithmetic, are those of one thread.
                p = min(ctx.threads, k // _BLOCK)
                cut = (np.linspace(0, k // _BLOCK, p + 1).astype(np.int64) * _BLOCK).tolist()
                cut[-1] = k
                got = run_parts([partial(part, a, b, 1) for a, b in zip(cut[:-1], cut[1:],
                                                                         strict=True)],
                                ctx.threads)
                h = np.concatenate([g[0] for g in got])
                n_rays = sum(g[1] for g in got)
            else:
                h, n_rays = part(0, k, ctx.threads)
            ctx.n_rays += n_rays
            hit[sub] |= h
        return hit

    def _rays(self, it, theta, root_lo, Y, V0, X, o32, d32):
        """Rays (collider space, grown) of curves ``it`` turned by ``theta``,
        written into ``o32``, ``d32`` (ns, n, 3)."""
        ctx = self.ctx
        ns = self.ns
        a = self.w.take(it, axis=1) * theta  # (ns, n); take keeps rows contiguous
        scale = ctx.shrink_scale(a, self.curves[it])
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

