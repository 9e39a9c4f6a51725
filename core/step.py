"""One solver step's working state and the machinery all modes share.

:class:`StepContext` holds a frame's inputs and the per-curve state in
world space while the step runs: candidate selection, local frames,
deformation, batched ray queries, first hits and push directions, Put to
Growth Surface, and writing the output. The modes live in :mod:`.rigid`
(Stiff, Bend) and :mod:`.soft`: each returns its curves' rotations
(``rigid.Turns``, ``soft.Turns``) and :meth:`StepContext.apply` takes them,
the one place a solve changes the step's per-curve state.
"""

from __future__ import annotations

import copy
from functools import partial

import numpy as np

from . import curves, rigid, soft
from . import rotations as rot
from . import tolerances as tol
from .rays import default_threads, run_parts, split_count
from .status import Status


class StepContext:
    """Everything one step needs; methods are the phases of the step."""

    def __init__(self, layout, state, settings, points, cols, growth, warm_start=True,
                 groups=None):
        """``layout`` (:class:`core.curves.CurveLayout`) and ``state``
        (:class:`core.state.SolverState`) are the solver's: the step reads the
        state in :meth:`load_state` and writes the next one in
        :meth:`store_state`. ``cols``: ``(collider, offset)`` entries, one per
        offset shell; ``groups``: per entry, the curves tested against it
        ((C,) bool, None: all; see ``Solver._clearances``)."""
        self.layout = layout
        self.state = state
        self.s = s = settings
        self.points = points  # the input, its own dtype (never modified)
        out_dtype = points.dtype
        self.cols = cols
        self.groups = [None] * len(cols) if groups is None else list(groups)
        self.growth = growth
        self.threads = s.threads or default_threads()
        self.prec = np.deg2rad(s.rotation_precision)
        # Max Angle in radians: a number, or (C,) per curve (max_angle_of)
        self.max_angle = np.deg2rad(s.max_angle)
        self.out_dtype = out_dtype
        self.timings = {}
        self.n_rays = 0
        self.builds = []  # BVH builds started early (see _candidates)
        # Input segment vectors in the input dtype: (S, 3) segment-major, or
        # for a uniform CV count ``ns`` a (C, ns, 3) view of one flat
        # difference of all points (no per-curve gathers or copies).
        ns = layout.ns
        if ns:
            Df = np.empty_like(points)
            flat = points.reshape(-1)
            np.subtract(flat[3:], flat[:-3], out=Df.reshape(-1)[:-3])
            Df[-1] = 0
            self._Dflat = Df  # row c (ns + 1) + j: segment j of curve c
            self.D3 = Df.reshape(-1, ns + 1, 3)[:, :ns]
            self.Dseg = None
            sq = Df[:, 0] * Df[:, 0]  # = einsum("ij,ij->i"), as separate passes
            sq += Df[:, 1] * Df[:, 1]
            sq += Df[:, 2] * Df[:, 2]
            L = np.sqrt(sq, out=sq).reshape(-1, ns + 1)[:, :ns]
            # Column passes: numpy's reductions are slow on short rows. Below
            # 8 terms numpy sums a row sequentially, as this loop does.
            shortest = L[:, 0].copy()
            for j in range(1, ns):
                np.minimum(shortest, L[:, j], out=shortest)
            if ns < 8:
                self.curve_len = L[:, 0].astype(np.float64)
                for j in range(1, ns):
                    self.curve_len += L[:, j]
            else:
                self.curve_len = L.sum(axis=1, dtype=np.float64)
        else:
            self.Dseg = np.diff(points, axis=0)[layout.seg_start]
            L = np.sqrt(np.einsum("ij,ij->i", self.Dseg, self.Dseg))
            self.curve_len = np.add.reduceat(L, layout.soff[:-1], dtype=np.float64)
            shortest = np.minimum.reduceat(L, layout.soff[:-1])
        # Curves the step cannot work with (core.curves.degenerate: Solver.step
        # marks them INVALID and steps again with stand-ins for them): a
        # zero-length segment, or a length that overflows. (Non-finite points
        # never get here.)
        self.degenerate = curves.degenerate(shortest, self.curve_len)
        self.degenerate_reason = ""
        if self.degenerate.any():
            c = int(np.argmax(self.degenerate))
            a, b = int(layout.soff[c]), int(layout.soff[c + 1])
            k = int(layout.seg_start[a + int(np.argmin(L[c] if ns else L[a:b]))])
            self.degenerate_reason = curves.degenerate_reason(c, self.curve_len[c], k)
            return  # (the caller steps again without them)
        if ns:
            self.roots = points.reshape(-1, ns + 1, 3)[:, 0].astype(np.float64)
        else:
            self.roots = points[layout.offsets[:-1]].astype(np.float64)
        # Ray growth (tol.RAY_EXTEND_ULPS): float32 ulps at the size of the
        # largest collider (where embree works, centred), plus the output
        # dtype's rounding at the colliders' distance from the origin. It
        # depends on the colliders only, so a curve's result does not depend
        # on which other curves are solved with it.
        size = mag = 0.0
        for c, _ in cols:
            lo, hi = c.bounds_world()
            size = max(size, float(np.linalg.norm(hi - lo)))
            mag = max(mag, float(np.abs(lo).max()), float(np.abs(hi).max()))
        self.eps_abs = tol.RAY_EXTEND_ULPS * (
            float(np.finfo(np.float32).eps) * size + float(np.finfo(points.dtype).eps) * mag
        )
        # What the curves can reach (each root grown by its curve's length): a
        # deforming collider builds only its triangles near it (Collider.set_reach),
        # set before any build of this step starts.
        # (every collider: one that builds no part this step forgets the last reach)
        self.reaches = {}  # id(collider) -> the Reach set (its own queries pass it)
        reach = (None, None)
        if any(c.builds_reach for c, _ in cols):
            r = self.roots.T
            reach = (r - self.curve_len).min(axis=1), (r + self.curve_len).max(axis=1)
        for c, _ in cols:
            self.reaches[id(c)] = c.set_reach(*reach)
        # Candidate curves per collider: the ball a curve can sweep about its
        # root (any rotation, scale <= 1) meets the collider's bounds, then
        # comes near one of its vertices (Collider.near_surface).
        # Roots are handled as components (3, C) here (long contiguous passes).
        self.cand = []
        self._near_roots = []  # per collider: (roots in its box, their grid coords)
        rootsT = np.ascontiguousarray(self.roots.T)
        try:
            seen = set()
            for (c, off), group in zip(cols, self.groups, strict=True):
                self._candidates(c, off, rootsT, group, first=id(c) not in seen)
                seen.add(id(c))
        except BaseException:
            for b in self.builds:  # never leave a build running behind an error
                try:
                    b()
                except BaseException:
                    pass
            raise
        if self.cand:
            self.cand_any = np.logical_or.reduce(self.cand)
        else:
            self.cand_any = np.zeros(layout.n_curves, bool)
        self.soft = s.mode == "soft"
        self.warm_start = bool(warm_start) and not self.soft
        self.warm_soft = bool(warm_start) and self.soft

    def _candidates(self, c, off, rootsT, group=None, first=True):
        """Candidate curves of collider ``c`` at offset ``off`` (appended to
        ``self.cand``), among the curves ``group`` ((C,) bool, None: all) that
        this shell is for. ``first``: the first shell of ``c`` this step."""
        lo, hi = c.bounds_world(off)
        in_box = None
        for i in range(3):
            g = np.maximum(lo[i] - rootsT[i], 0)
            g += np.maximum(rootsT[i] - hi[i], 0)
            in_box = g == 0 if in_box is None else in_box & (g == 0)
            if i == 0:
                gg = g * g
            else:
                gg += g * g
        cand = gg <= self.curve_len**2
        if group is not None:
            cand &= group
            in_box &= group
        w = np.flatnonzero(cand)
        # A changed collider (deforming: every frame) that the step will query
        # gets its BVH built on a ray thread while the set-up goes on. Started
        # before the grid test (to overlap it) only for a collider queried
        # last step too, so a collider whose box holds the curves but whose
        # surface is out of their reach (a ring, a room) is not built every
        # frame; otherwise started once the grid test says it is needed.
        # Only timing depends on this, never a result.
        early = len(w) and c.queried
        if early:
            self._prefetch(c, off)
        q = c.grid_coords(rootsT.take(w, axis=1))  # (take: contiguous rows)
        cand[w] = c.near_surface_grid(q, self.curve_len[w], off)
        needed = bool(cand.any() or (c.detects_pinch and in_box.any()))
        c.queried = needed if first else (c.queried or needed)
        if needed and not early:
            self._prefetch(c, off)
        self.cand.append(cand)
        self._near_roots.append((w, q, in_box))

    def _prefetch(self, c, off):
        b = c.prefetch(off, self.threads)  # None: built, under way, or one thread
        if b is not None:
            self.builds.append(b)

    def roots_inside(self, k, enabled):
        """Enabled curves whose root is inside collider ``k`` (paper 3.1: pinch)."""
        c, off = self.cols[k]
        inside = np.zeros(self.layout.n_curves, bool)
        if not c.detects_pinch:
            return inside
        w, q, in_box = self._near_roots[k]
        # roots in the box have a gap of 0: they are among w
        sel = np.flatnonzero((enabled & in_box)[w])
        if len(sel):
            r = w[sel]
            inside[r[c.contains_grid(self.roots[r], q.take(sel, axis=1), off)]] = True
        return inside

    # ------------------------------------------------------------ frames
    def load_state(self):
        # A Max Angle lowered mid-shot: a curve turned further than it now starts
        # from it (the full and the warm search alike), and is UNRESOLVED where
        # that shape collides.
        self.angle = np.minimum(self.state.angle, self.max_angle)
        self.angle_max = np.minimum(self.state.angle_max, self.max_angle)
        self.stiff = self.state.stiff.copy()  # Bend curves solved as Stiff
        self.axis = np.zeros((self.layout.n_curves, 3))
        if self.soft:
            self.quat = self.state.quat.copy()
            self.quat_max = self.state.quat_max.copy()
        self.active = self.state.active.copy()
        self.restyled = np.zeros(self.layout.n_curves, bool)  # Bend curves switched to Stiff
        self.soft_level = np.zeros(self.layout.n_curves)  # Soft: recovery fraction (blocked)
        idx = np.flatnonzero(self.active)
        self.B = np.zeros((self.layout.n_curves, 3, 3))  # this step's frames (rows in use only)
        self.ref = None
        if len(idx):
            B, self.ref, rows = self._frames(idx, self.state.frame[idx])
            self.B[idx] = B
            self.axis[idx] = self._from_frame(rows, self.state.axis[idx])
            if self.soft:
                for q in (self.quat, self.quat_max):
                    self._quats_to(idx, B, q, q, to_world=True)

    def _quats_to(self, idx, B, src, dst, to_world):
        """Move the quaternions of every segment of curves ``idx`` between
        world and their curve's local frame ``B`` (n, 3, 3): ``dst[seg] =
        _quat_to(B[rep], src[seg], to_world)``. Uniform curves work on
        (n, ns) blocks, frame by frame (no per-segment copy of ``B``); both
        layouts add the same terms in the same order."""
        ns = self.layout.ns
        if not ns:
            seg, rep, _ = self.segments(idx)
            dst[seg] = self._quat_to(B[rep], src[seg], to_world)
            return
        q = src.reshape(-1, ns, 4)[idx]  # (n, ns, 4) copy
        v = q[..., 1:].copy()
        for i in range(3):
            # to world: sum_j B[j, i] v_j; to local: sum_j B[i, j] v_j
            b = B[:, :, i] if to_world else B[:, i, :]
            out = b[:, 0, None] * v[..., 0]
            out += b[:, 1, None] * v[..., 1]
            out += b[:, 2, None] * v[..., 2]
            q[..., 1 + i] = out
        dst.reshape(-1, ns, 4)[idx] = q

    @staticmethod
    def _quat_to(B, q, to_world):
        """Quaternions ``q`` (k, 4) with their vector part moved by frames
        ``B`` (k, 3, 3): to world ``B^T v``, to local ``B v`` (the arithmetic
        of :meth:`_quats_to`, term by term)."""
        out = q.copy()
        v = q[:, 1:]
        for i in range(3):
            b = B[:, :, i] if to_world else B[:, i, :]
            o = b[:, 0] * v[:, 0]
            o += b[:, 1] * v[:, 1]
            o += b[:, 2] * v[:, 2]
            out[:, 1 + i] = o
        return out

    def _frames(self, idx, prev):
        """Local frames of curves ``idx`` (:func:`rot.curve_frames`), computed
        on component arrays; also returns their rows as components (3, 3, n)."""
        ns = self.layout.ns
        if ns:  # root segments and tips straight from the (C, ns + 1, 3) blocks
            seg0 = self.D3[idx, 0]
            last = self.points.reshape(-1, ns + 1, 3)[idx, ns]
        else:
            seg0 = self.Dseg[self.layout.soff[idx]]
            last = self.points[self.layout.offsets[idx + 1] - 1]
        t = rot.unit3(np.ascontiguousarray(seg0.T, dtype=np.float64))
        rootT = self.roots[idx].T
        chord = np.empty((3, len(idx)))
        for i in range(3):
            np.subtract(last[:, i], rootT[i], out=chord[i])
        u = chord - rot.dot3(chord, t) * t
        ratio = rot.norm3(u) / self.curve_len[idx]
        B, ref, e1 = rot.curve_frames(t, u, ratio, prev)
        return B, ref, (t, e1, rot.cross3(t, e1))

    @staticmethod
    def _from_frame(rows, a):
        """World vectors of local ``a`` (n, 3) in frames given as row
        components (= einsum("kji,kj->ki", B, a)), (n, 3)."""
        e0, e1, e2 = rows
        out = e0 * a[:, 0]
        out += e1 * a[:, 1]
        out += e2 * a[:, 2]
        return out.T

    def remember(self, status, enabled):
        """The memory the next step's search starts from (``Solver`` state
        ``contact``, ``delta``): curves COLLIDING now, and their angle change
        (Soft: the fraction of the recovery step a blocked curve took).
        Disabled curves keep theirs (as their whole local state)."""
        contact = status == Status.COLLIDING
        if self.soft:  # the fraction of the recovery step a blocked curve took
            delta = np.where(contact, self.soft_level, 0.0)
        else:
            delta = np.where(contact & ~self.restyled, self.angle - self.state.angle, 0.0)
        self.contact_next = np.where(enabled, contact, self.state.contact)
        self.delta_next = np.where(enabled, delta, self.state.delta)

    def store_state(self):
        self.state.contact, self.state.delta = self.contact_next, self.delta_next
        idx = np.flatnonzero(self.active)
        frame = self.state.frame  # the transported references (see rot.curve_frames)
        old = np.flatnonzero(self.state.active)
        if len(old):
            frame[old] = self.ref
        dropped = old[~self.active[old]]
        frame[dropped] = 0.0
        fresh = idx[~self.state.active[idx]]
        if len(fresh):
            self.B[fresh], frame[fresh], _ = self._frames(fresh, None)
        B = self.B
        self.state.angle = self.angle
        self.state.angle_max = self.angle_max
        self.state.stiff = self.stiff
        self.state.active = self.active
        axis_lo = np.zeros_like(self.axis)
        if len(idx):
            Bi, ax = B[idx], self.axis[idx]  # = einsum("kij,kj->ki", Bi, ax)
            for i in range(3):
                a = Bi[:, i, 0] * ax[:, 0]
                a += Bi[:, i, 1] * ax[:, 1]
                a += Bi[:, i, 2] * ax[:, 2]
                axis_lo[idx, i] = a
        self.state.axis = axis_lo
        self.state.hold &= self.active
        if self.soft:
            # Rows of curves without state are the identity in any frame: only
            # the active curves' rows move back to their local frames (into
            # copies: the output reads the world rows meanwhile).
            q, qm = self.quat.copy(), self.quat_max.copy()
            if len(idx):
                Bi = B[idx]
                self._quats_to(idx, Bi, self.quat, q, to_world=False)
                self._quats_to(idx, Bi, self.quat_max, qm, to_world=False)
            self.state.quat, self.state.quat_max = q, qm

    # ----------------------------------------------------------- geometry
    def segments(self, idx):
        """Segments of curves ``idx``: (seg ids, owner position in idx, starts)."""
        return self.layout.segments(idx)

    def rigid_rotations(self, idx, angle, axis, seg, rep, stiff):
        """Per-segment (angle, axis) of stiff/bend curves ``idx`` (``stiff`` (n,):
        Bend curves turned as Stiff)."""
        if self.s.mode == "bend":
            w = np.where(stiff[rep], 1.0, self.layout.w_bend[seg])
        else:
            w = 1.0
        return angle[rep] * w, axis[rep]

    def deform(self, idx, angle=None, axis=None, quat=None, stiff=None):
        """Deformed segments of curves ``idx``: turned by ``angle`` (n,) about
        ``axis`` (n, 3), Bend curves ``stiff`` (n,) bool as Stiff (default: the
        step's), or by per-segment quaternions ``quat`` (Soft).

        Returns
        -------
        o, d : (k, 3) segment starts and vectors, world space
        seg, rep, starts : see :meth:`segments`
        """
        if quat is None and stiff is None:
            stiff = self.stiff[idx]
        if self.layout.ns:
            return self._deform_uniform(idx, angle, axis, quat, stiff)
        seg, rep, starts = self.segments(idx)
        v = self.seg_in(seg)
        if quat is not None:
            v = rot.quat_rotate(quat, v)
        else:
            a_seg, ax_seg = self.rigid_rotations(idx, angle, axis, seg, rep, stiff)
            v = rot.rotate(v, ax_seg, a_seg)
            scale = self.shrink_scale(a_seg, idx[rep])
            if scale is not None:
                v = v * scale[:, None]
        cs = rot.cumsum_owned(v, rep, starts)
        # Round to the output dtype so the segments tested are exactly the
        # segments written out (float32 rounding must not re-open a contact).
        end = (cs + self.roots[idx][rep]).astype(self.out_dtype).astype(np.float64)
        o = np.empty_like(end)
        o[1:] = end[:-1]
        o[starts] = self.roots[idx]
        return o, end - o, seg, rep, starts

    def _deform_uniform(self, idx, angle, axis, quat, stiff):
        """:meth:`deform` for curves that all have ``ns`` segments (blocks).

        Stiff/Bend work on component arrays (3, ns, n) (see
        :func:`rot.rotate_soa`); the arithmetic is that of :meth:`deform`.
        """
        ns, n = self.layout.ns, len(idx)
        root = self.roots[idx]
        if quat is not None:
            end = self._ends_quat_soa(idx, quat).astype(np.float64)
        else:
            end = self._ends_soa(idx, angle, axis, stiff).astype(np.float64)
        o = np.empty_like(end)
        o[:, 0] = root.T
        o[:, 1:] = end[:, :-1]
        d = rot.aos(np.subtract(end, o, out=end))
        o = rot.aos(o)
        seg = (idx[:, None] * ns + np.arange(ns)).ravel()
        rep = np.repeat(np.arange(n), ns)
        return o.reshape(-1, 3), d.reshape(-1, 3), seg, rep, np.arange(n) * ns

    def _ends_soa(self, idx, angle, axis, stiff):
        """Segment ends of the Stiff/Bend deformed uniform curves ``idx``,
        (3, ns, n) components in the output dtype (as :meth:`deform`)."""
        a = self.bend_weights(stiff) * angle
        v = rot.rotate_soa(self.seg_soa(idx), axis, a)
        scale = self.shrink_scale(a, idx)
        if scale is not None:
            v *= scale
        end = rot.cumsum_soa(v)
        end += self.roots[idx].T[:, None, :]
        return end.astype(self.out_dtype)

    def _ends_quat_soa(self, idx, quat):
        """Segment ends of uniform curves ``idx`` whose segments turn by the
        quaternions ``quat`` (rows, n * ns), (3, ns, n) in the output dtype."""
        ns, n = self.layout.ns, len(idx)
        q3 = np.asarray(quat).reshape(n, ns, 4)
        q = np.empty((4, ns, n))
        for i in range(4):
            q[i] = q3[..., i].T
        end = rot.cumsum_soa(rot.quat_rotate_soa(q, self.seg_soa(idx)))
        end += self.roots[idx].T[:, None, :]
        return end.astype(self.out_dtype)

    def bend_weights(self, stiff):
        """(ns, n) fraction of a curve's angle turning each segment (uniform
        curves; ``stiff`` (n,): those solved as Stiff): Bend ``(j + 1) / ns`` (1
        for curves solved as Stiff), Stiff 1."""
        ns = self.layout.ns
        if self.s.mode == "bend":
            return np.where(stiff, 1.0, ((np.arange(ns) + 1.0) / ns)[:, None])
        return np.ones((ns, 1))

    def shrink_scale(self, a, curves):
        """Shrink (paper 3.2.2): segment scale for segment rotation angles ``a``
        (radians) of curves ``curves`` (an index array broadcasting with
        ``a``: one per row, or (n,) for (ns, n) blocks), linear from 1 at 0
        to ``scale_minimum`` at ``scale_angle``, clamped beyond; None when
        Shrink is off."""
        if not self.s.shrink:
            return None
        ramp = np.minimum(a / np.deg2rad(self.s.scale_angle), 1.0)
        return 1.0 - (1.0 - self.s.per_curve("scale_minimum", curves)) * ramp

    def ray_growth(self, length, root):
        """Fractions ``(back, grow)`` by which segments of ``length`` are grown.

        A tested segment ``o + t d`` becomes ``(o - back d) + t (grow d)``:
        a few float32 ulps at each end (``tol.RAY_EXTEND_ULPS``), except
        backward for root segments (``root``): roots never move, so a root
        resting on a collider is a pinch, not a contact.
        """
        e = self.eps_abs / np.maximum(length, 1e-300)
        back = np.where(root, 0.0, e)
        return back, 1.0 + back + e

    def extend(self, o, d, root):
        """Segments grown as :meth:`ray_growth` says."""
        back, grow = self.ray_growth(np.sqrt(np.einsum("ij,ij->i", d, d)), root)
        return o - back[:, None] * d, d * grow[:, None]

    def hits(self, idx, o, d, rep, root):
        """Per segment: does it hit any collider (segments of curves ``idx``).

        Parameters
        ----------
        rep : (k,) int  owner of each segment (position in ``idx``)
        root : (k,) bool  which segments are root segments
        """
        o, d = self.extend(o, d, root)
        hit = np.zeros(len(o), bool)
        for (c, off), cand in zip(self.cols, self.cand, strict=True):
            m = cand[idx][rep]
            if m.all():
                hit |= c.segment_hits(o, d, off, self.threads)
                self.n_rays += len(o)
            elif m.any():
                w = np.flatnonzero(m)
                hit[w] |= c.segment_hits(o[w], d[w], off, self.threads)
                self.n_rays += len(w)
        return hit

    def curve_hits(self, idx, **deformation):
        if len(idx) == 0:
            return np.zeros(0, bool)
        o, d, seg, rep, starts = self.deform(idx, **deformation)
        root = self.root_mask(len(o), starts)
        return np.logical_or.reduceat(self.hits(idx, o, d, rep, root), starts)

    def quat_curve_hits(self, idx, q):
        """:meth:`curve_hits` of uniform curves ``idx`` with segment rotations
        given as component quaternions ``q`` (4, ns, n) (Soft's probes).

        The arithmetic of :meth:`deform` (quat) then :meth:`hits`, on
        component arrays: long contiguous passes instead of rows of 3 and 4.
        """
        ns, n = self.layout.ns, len(idx)
        hit = np.zeros(n, bool)
        if n == 0:
            return hit
        v = rot.quat_rotate_soa(q, self.seg_soa(idx))
        end = rot.cumsum_soa(v)
        end += self.roots[idx].T[:, None, :]
        end = end.astype(self.out_dtype).astype(np.float64)
        o = np.empty_like(end)
        o[:, 0] = self.roots[idx].T
        o[:, 1:] = end[:, :-1]
        d = np.subtract(end, o, out=end)
        sq = d[0] * d[0]
        sq += d[1] * d[1]
        sq += d[2] * d[2]
        back, grow = self.ray_growth(np.sqrt(sq, out=sq), (np.arange(ns) == 0)[:, None])
        o -= back * d
        d *= grow
        for (c, off), cand in zip(self.cols, self.cand, strict=True):
            w = np.flatnonzero(cand[idx])
            if len(w) == 0:
                continue
            A, b = c.local_map()
            ow = o[:, :, w] if len(w) < n else o
            dw = d[:, :, w] if len(w) < n else d
            o_lo = rot.apply_soa(A, ow)
            for i in range(3):
                o_lo[i] += b[i]
            d_lo = rot.apply_soa(A, dw)
            h = c.segment_hits_local(rot.rows32(o_lo), rot.rows32(d_lo), off, self.threads,
                                     self.reaches.get(id(c)))
            self.n_rays += h.size
            hit[w] |= h.reshape(ns, len(w)).any(axis=0)
        return hit

    @staticmethod
    def root_mask(k, starts):
        m = np.zeros(k, bool)
        m[starts] = True
        return m

    def first_hit_details(self, idx, o, d, rep, starts, hit=None, motion=False):
        """First hit (root to tip) of each curve: segment, point, push direction.

        ``hit``: which segments hit, when already known (:meth:`input_hits`).

        Returns
        -------
        k : (n,) int  index into o/d of the first hitting segment (-1: none)
        point : (n, 3)  hit point
        push : (n, 3)  unit direction away from the collider (paper 3.2.1)
        velocity : (n, 3)
            Only with ``motion=True``: the hit collider's velocity at the hit
            point (:meth:`Collider.velocities`, world units per step; zero
            without a hit).
        """
        n = len(idx)
        root = self.root_mask(len(o), starts)
        if hit is None:
            hit = self.hits(idx, o, d, rep, root)
        k = np.full(n, -1, np.int64)
        w = np.flatnonzero(hit)
        if len(w):
            owners, first = np.unique(rep[w], return_index=True)
            k[owners] = w[first]
        point = np.zeros((n, 3))
        push = np.zeros((n, 3))
        vel = np.zeros((n, 3))
        has = np.flatnonzero(k >= 0)
        if len(has) == 0:
            return (k, point, push, vel) if motion else (k, point, push)
        ks = k[has]
        o, d = self.extend(o[ks], d[ks], root[ks])
        best_t = np.full(len(has), np.inf)
        best_n = np.zeros((len(has), 3))
        double = np.zeros(len(has), bool)
        best_e = np.full(len(has), -1)  # (motion) entry of self.cols hit, and its face
        best_f = np.full(len(has), -1, np.int64)
        for e, ((c, off), cand) in enumerate(zip(self.cols, self.cand, strict=True)):
            m = np.flatnonzero(cand[idx[has]])
            if len(m) == 0:
                continue
            if motion:
                h, t, nrm, face = c.segment_hit_details(o[m], d[m], off, faces=True,
                                                        reach=self.reaches.get(id(c)))
            else:
                h, t, nrm = c.segment_hit_details(o[m], d[m], off,
                                                  reach=self.reaches.get(id(c)))
            better = h & (t < best_t[m])
            mm = m[better]
            best_t[mm] = t[better]
            best_n[mm] = nrm[better]
            double[mm] = c.double_sided
            if motion:
                best_e[mm] = e
                best_f[mm] = face[better]
        best_t = np.where(np.isfinite(best_t), best_t, 0.0)
        pt = o + d * best_t[:, None]
        if motion:
            for e in np.unique(best_e[best_e >= 0]):
                w = np.flatnonzero(best_e == e)
                vel[has[w]] = self.cols[e][0].velocities(pt[w], faces=best_f[w])
        # Single-sided: along the normal, or its inverse when a back face is
        # crossed. Double-sided: toward the side the root is on.
        side = -np.sign(rot.dot(d, best_n))
        root_side = np.sign(rot.dot(self.roots[idx[has]] - pt, best_n))
        side = np.where(double & (root_side != 0), root_side, side)
        side = np.where(side == 0, 1.0, side)
        point[has] = pt
        push[has] = best_n * side[:, None]
        return (k, point, push, vel) if motion else (k, point, push)

    def follow_directions(self, idx, seg, vel, ref):
        """Follow Collider Motion (``Settings.follow_collider_motion``): which
        way curves ``idx`` turn at their first hit, given their hit segments
        ``seg`` (n, 3), the collider's velocity there ``vel`` (n, 3) and the
        vector ``ref`` (n, 3) the axis will be made perpendicular to.

        The direction is the velocity made perpendicular to the hit segment,
        unit. It is used (``ok``) where that velocity exceeds
        ``tol.FOLLOW_SPEED_REL`` times the curve's length and
        ``tol.FOLLOW_SPEED_ULPS`` float32 ulps of the curve's coordinates, and
        is not parallel to ``ref`` (no axis); elsewhere the caller keeps the
        paper's direction.

        Returns
        -------
        direction : (n, 3) float64 (rows where ``ok``; zero elsewhere)
        ok : (n,) bool
        """
        sq = rot.dot(seg, seg)
        along = rot.dot(vel, seg) / np.where(sq > 0, sq, 1.0)
        v = vel - along[:, None] * seg
        speed = np.sqrt(rot.dot(v, v))
        mag = np.abs(self.roots[idx]).max(axis=1) + self.curve_len[idx]
        floor = np.maximum(tol.FOLLOW_SPEED_REL * self.curve_len[idx],
                           tol.FOLLOW_SPEED_ULPS * float(np.finfo(np.float32).eps) * mag)
        side = np.cross(ref, v)
        sideways = np.sqrt(rot.dot(side, side))
        ok = (speed > floor) & (sq > 0)
        ok &= sideways > tol.PARALLEL_EPS * np.sqrt(rot.dot(ref, ref)) * speed
        return np.where(ok[:, None], v / np.where(ok, speed, 1.0)[:, None], 0.0), ok

    # ----------------------------------------------------------- solving
    def target_fraction(self, idx):
        """Recovery target as a fraction of the maximum rotation (plasticity)."""
        return np.where(self.state.hold[idx], np.nan, self.s.per_curve("plasticity", idx))

    def max_angle_of(self, curves):
        """Max Angle (radians) of ``curves``: the number, or their values of
        a per-curve map (broadcasts as ``curves`` does)."""
        if np.ndim(self.max_angle):
            return self.max_angle[curves]
        return self.max_angle

    def solve(self, idx, status):
        """Solve curves ``idx`` in this step's mode (their status into ``status``)."""
        self.apply(soft.solve(self, idx) if self.soft else rigid.solve(self, idx), idx, status)

    def apply(self, turns, idx, status):
        """Take a mode's answer for curves ``idx`` (``rigid.Turns`` or ``soft.Turns``:
        every curve's rotation as the mode left it) and their statuses: the one
        place a solve changes the step's per-curve state."""
        if self.soft:
            self.quat = turns.quat
            for rows, q, grow in turns.quat_max:
                if grow:
                    self._grow_quat_max(rows, q)
                else:
                    self.quat_max[rows] = q
            self.active, self.soft_level = turns.active, turns.soft_level
        else:
            self.angle, self.angle_max, self.axis = turns.angle, turns.angle_max, turns.axis
            self.active, self.stiff, self.restyled = turns.active, turns.stiff, turns.restyled
        status[idx] = turns.status[idx]

    def _grow_quat_max(self, rows, q):
        """Segments ``rows`` turned by ``q`` (k, 4): each keeps the larger of it and
        its largest rotation so far (Plasticity's reference)."""
        grow = rot.quat_angle(q) > rot.quat_angle(self.quat_max[rows])
        self.quat_max[rows[grow]] = q[grow]

    def in_halves(self, fn, work, *parts, **kw):
        """``fn(self, *parts, **kw)``; with ``work`` of at least
        :data:`tolerances.SPLIT_MIN_CURVES` curves and two threads or more, as
        :func:`core.rays.split_count` calls (two halves on two threads, one call
        per thread on more), each on its own thread, call ``i`` of ``p`` with
        every ``p``-th curve of each of ``parts`` (curve index arrays) from the
        ``i``-th, and a shallow copy of this context: the per-curve arrays are
        shared (the calls write disjoint curves in place), the ray count and the
        thread count (one each: the calls are the parallelism) their own. ``fn``
        must give each curve what it gives it in the whole, so the result has
        the same bits for any thread count."""
        p = split_count(work, self.threads, tol.SPLIT_MIN_CURVES)
        if p == 1:
            fn(self, *parts, **kw)
            return
        shares = [copy.copy(self) for _ in range(p)]
        for h in shares:
            h.threads, h.n_rays = 1, 0
        # Interleaved, so that every call gets as much contact wherever the
        # groom's curve order puts it.
        run_parts([partial(fn, shares[i], *(x[i::p] for x in parts), **kw) for i in range(p)],
                  self.threads)
        self.n_rays += sum(h.n_rays for h in shares)

    def new_axes(self, idx, o, d, rep, starts, stiff, hit=None):
        """Rotation axes for curves starting a contact (paper 3.2.1).

        The paper's: turning the hit point away along the push direction, or
        toward the growth surface (Attract to Growth Surface); with Follow
        Collider Motion, where the collider moves at the hit
        (:meth:`follow_directions`), turning the tip along that motion.
        ``stiff`` (n,): Bend curves turned as Stiff. ``hit``: see
        :meth:`first_hit_details`.

        Returns
        -------
        axis : (n, 3)
        guess, guess_stiff : (n,)
            The rotation that lifts every CV above the collider's tangent plane
            at the hit (a first probe for the angle search, nothing more), as the
            mode turns and as Stiff (:meth:`plane_guess`).
        """
        follow = self.s.follow_collider_motion
        if follow:
            k, point, push, vel = self.first_hit_details(idx, o, d, rep, starts, hit, motion=True)
        else:
            k, point, push = self.first_hit_details(idx, o, d, rep, starts, hit)
        c = point - self.roots[idx]
        normal = push
        if self.s.attract_to_growth_surface:
            mid = self.midpoints(idx, o, d, starts)
            cp, _ = self.growth.closest_points(mid)
            toward = cp - mid
            a = np.cross(c, toward)
            ok = np.linalg.norm(a, axis=1) > tol.PARALLEL_EPS * np.maximum(
                np.linalg.norm(c, axis=1) * np.linalg.norm(toward, axis=1), 1e-300
            )
            push = np.where(ok[:, None], rot.normalize(toward), push)
        axis = rot.rotation_axis(c, push)
        if follow:
            # Where the collider moves at the hit: the tip moves along that
            # motion (made perpendicular to the hit segment), i.e. the axis is
            # perpendicular to it and to the chord root -> tip.
            last = starts + self.layout.nseg[idx] - 1
            chord = o[last] + d[last] - self.roots[idx]
            way, ok = self.follow_directions(idx, d[np.maximum(k, 0)], vel, chord)
            if ok.any():
                axis[ok] = rot.rotation_axis(chord[ok], way[ok])
        guess, guess_stiff = self.plane_guess(idx, o + d, rep, starts, point, normal, axis,
                                              stiff)
        return axis, guess, guess_stiff

    def plane_guess(self, idx, ends, rep, starts, point, normal, axis, stiff):
        """Angles lifting each curve's CVs above the plane (point, normal): as the
        mode turns the curves ``idx`` (``stiff`` (n,): Bend curves turned as
        Stiff), and as Stiff (turned at the root: Bend's fall back to Stiff).
        Returns ``(guess (n,), guess_stiff (n,))``."""
        depth = -rot.dot(ends - point[rep], normal[rep])
        v = ends - self.roots[idx][rep]
        ax = axis[rep]
        radius = np.linalg.norm(v - ax * rot.dot(v, ax)[:, None], axis=1)
        lift = np.arcsin(np.clip(depth / np.maximum(radius, 1e-300), 0.0, 1.0))
        if len(lift) == 0:
            return lift, lift
        as_stiff = np.maximum.reduceat(lift, starts)
        if self.s.mode == "bend":  # a CV turns by about the mean weight up to it
            j = np.arange(len(rep)) - starts[rep]
            n = self.layout.nseg[idx][rep]
            w = np.where(stiff[rep], 1.0, (j + 2) / (2.0 * n))
            lift = lift / w
        return np.maximum.reduceat(lift, starts), as_stiff

    def midpoints(self, idx, o, d, starts):
        nseg = self.layout.nseg[idx]
        j = starts + nseg // 2
        return o[j] + np.where((nseg % 2 == 1)[:, None], 0.5 * d[j], 0.0)

    def input_rays(self, idx):
        """Segments of the *input* curves ``idx`` (float64), like :meth:`deform`."""
        seg, rep, starts = self.segments(idx)
        ss = self.layout.seg_start[seg]
        return self.points[ss].astype(np.float64), self.seg_in(seg), seg, rep, starts

    def input_hits(self, idx):
        """Does the *input* curve ``idx`` hit a collider?

        The same rays as :meth:`hits` on :meth:`input_rays`; for uniform CV
        counts built as (3, ns, n) components straight in each collider's
        space, and only for curves whose input points come near its surface
        (a ball about their bounding box, :meth:`Collider.near_surface`:
        curves it leaves out cannot touch the mesh).

        Returns
        -------
        (n,) bool per curve, and per segment (in the order of
        :meth:`input_rays`, as :meth:`hits` would give them).
        """
        ns, n = self.layout.ns, len(idx)
        if not ns or n == 0:
            if n == 0:
                return np.zeros(0, bool), np.zeros(0, bool)
            o, d, seg, rep, starts = self.input_rays(idx)
            seg_hit = self.hits(idx, o, d, rep, self.root_mask(len(o), starts))
            return np.logical_or.reduceat(seg_hit, starts), seg_hit
        P = self.points.reshape(-1, ns + 1, 3)[idx]  # (n, ns + 1, 3), input dtype
        p = np.empty((3, ns + 1, n))
        for i in range(3):
            p[i] = P[..., i].T
        # bounding balls of the input curves (world)
        lo, hi = p.min(axis=1), p.max(axis=1)
        centre = 0.5 * (lo + hi)
        half = hi - lo
        radius = 0.5 * np.sqrt(half[0] ** 2 + half[1] ** 2 + half[2] ** 2)
        radius = radius * (1.0 + 1e-6) + 2.0 * self.eps_abs
        seg_hit = np.zeros((ns, n), bool)
        root = (np.arange(ns) == 0)[:, None]
        for (c, off), cand in zip(self.cols, self.cand, strict=True):
            w = np.flatnonzero(cand[idx])
            if len(w) == 0:
                continue
            q = c.grid_coords(centre.take(w, axis=1))
            w = w[c.near_surface_grid(q, radius[w], off)]
            self.n_rays += len(w) * ns
            if len(w) == 0:
                continue
            # the rays of :meth:`input_rays` grown by :meth:`extend`
            d = self.seg_soa(idx[w])  # the input dtype's differences, as in seg_in
            sq = d[0] * d[0]
            sq += d[1] * d[1]
            sq += d[2] * d[2]
            back, grow = self.ray_growth(np.sqrt(sq, out=sq), root)
            o = p.take(w, axis=2)[:, :ns]  # (a copy with contiguous rows)
            o -= back * d
            d *= grow
            A, b = c.local_map()
            o_lo = rot.apply_soa(A, o)
            for i in range(3):
                o_lo[i] += b[i]
            d_lo = rot.apply_soa(A, d)
            h = c.segment_hits_local(rot.rows32(o_lo), rot.rows32(d_lo), off, self.threads,
                                     self.reaches.get(id(c)))
            seg_hit[:, w] |= h.reshape(ns, len(w))
        return seg_hit.any(axis=0), seg_hit.T.ravel()

    def put_to_growth_surface(self, pin):
        """Rotate pinched curves down onto the growth surface (paper 3.2.5)."""
        _, n_g = self.growth.closest_points(self.roots[pin])
        chord = self.points[self.layout.offsets[pin + 1] - 1] - self.roots[pin]
        down = -n_g
        axis = rot.rotation_axis(chord, down)
        # Elevation of the deformed chord over the tangent plane, bisected on
        # the angle so the same works for every mode's deformation.
        lo = np.zeros(len(pin))
        hi = np.full(len(pin), np.pi)
        for _ in range(24):
            mid = 0.5 * (lo + hi)
            o, d, seg, rep, starts = self._deform_mode(pin, mid, axis)
            tip = o[starts + self.layout.nseg[pin] - 1] + d[starts + self.layout.nseg[pin] - 1]
            above = rot.dot(tip - self.roots[pin], n_g) > 0
            lo = np.where(above, mid, lo)
            hi = np.where(above, hi, mid)
        ang = np.where(rot.dot(chord, n_g) > 0, hi, 0.0)
        self._set_uniform(pin, ang, axis)

    def _deform_mode(self, idx, angle, axis):
        if self.soft:
            seg, rep, _ = self.segments(idx)
            q = rot.quat_from_axis_angle(axis[rep], angle[rep])
            return self.deform(idx, quat=q)
        return self.deform(idx, angle=angle, axis=axis)

    def _set_uniform(self, idx, angle, axis):
        if self.soft:
            seg, rep, _ = self.segments(idx)
            q = rot.quat_from_axis_angle(axis[rep], angle[rep])
            self.quat[seg] = q
            self._grow_quat_max(seg, q)
        else:
            self.angle[idx] = angle
            self.axis[idx] = axis
            self.angle_max[idx] = np.maximum(self.angle_max[idx], angle)
        self.active[idx] = angle > 0

    # ------------------------------------------------------------ output
    def output(self):
        out = self.points.copy()
        idx = np.flatnonzero(self.active)
        ns = self.layout.ns
        if len(idx) and ns and self.out_dtype == np.float32:
            # The points written are the deformed segments' float32 ends
            # (what ``o + d`` of :meth:`deform` rounds back to).
            out3 = out.reshape(-1, ns + 1, 3)
            if self.soft:
                end = self._ends_quat_soa(idx, self.quat.reshape(-1, ns, 4)[idx])
            else:
                end = self._ends_soa(idx, self.angle[idx], self.axis[idx], self.stiff[idx])
            out3[idx, 1:] = rot.aos(end)
        elif len(idx):
            if self.soft:
                seg, _, _ = self.segments(idx)
                o, d, seg, rep, starts = self.deform(idx, quat=self.quat[seg])
            else:
                o, d, seg, rep, starts = self.deform(
                    idx, angle=self.angle[idx], axis=self.axis[idx]
                )
            if ns:  # uniform CV count: write whole curves as blocks
                out.reshape(-1, ns + 1, 3)[idx, 1:] = (o + d).reshape(-1, ns, 3)
            else:
                out[self.layout.seg_start[seg] + 1] = o + d
        return out

    def seg_soa(self, idx):
        """Input segment vectors of uniform curves ``idx`` as float64
        components, shape (3, ns, n): elementwise work on them runs over long
        contiguous rows instead of rows of 3."""
        ns = self.layout.ns
        g = self.D3[idx]
        out = np.empty((3, ns, len(idx)))
        for i in range(3):
            out[i] = g[..., i].T
        return out

    def seg_in(self, seg):
        """Input segment vectors (float64) of segment ids ``seg``."""
        if self.Dseg is None:
            ns = self.layout.ns
            return self._Dflat[seg + seg // ns].astype(np.float64)
        return self.Dseg[seg].astype(np.float64)

