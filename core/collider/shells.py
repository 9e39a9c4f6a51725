"""A collider's offset shells, their BVHs and segment hits.

Curves are tested against a *shell* of the collider: the mesh moved out along
its vertex normals by the clearance margin (``Collider.margin``) plus, when
there is one, a Collision Offset (a per-curve clearance gives a few offset
levels, each a shell). :class:`Shells` owns the BVH of each shell in use
(a few kept, newest last, built on a ray thread ahead of need:
:meth:`Shells.prefetch`), answers segment queries and gives the normal at a
hit. A shell depends on the shape and, with an offset, on the matrix's
stretch: rigid motion never rebuilds it.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import partial

import numpy as np

from .. import tolerances as tol
from ..closest import barycentric
from ..rays import beside, make_backend, make_parts_backend, triangle_rows
from ..rotations import apply, det3
from ..rotations import dot as rot_dot
from .mesh import PerShape, angle_weighted, unit


@dataclass(frozen=True)
class ShellFaces:
    """Which face of the collider each triangle of a built shell is.

    ``real`` (k,) int: the collider face; ``flip`` (k,) bool: the triangle
    faces the other way (the inner shell of an open or double-sided mesh).
    ``single``: the shell is the mesh's own faces, once each (a closed
    single-sided collider). ``cover``: for a reachable part (``Shells.reach``),
    the local box ``(lo, hi)`` every triangle of the shell that meets it is in;
    None for the whole shell.
    """

    real: np.ndarray
    flip: np.ndarray
    single: bool = False
    cover: tuple | None = None


@dataclass(frozen=True)
class Reach:
    """What the curves of a solver step can reach, in the collider's local space,
    rounded out to a grid (``tol.REACH_GRID``): ``key`` (the grid cells, part of
    the shell's key) and the box ``lo``, ``hi`` (3,) they make."""

    key: tuple
    lo: np.ndarray
    hi: np.ndarray


@dataclass(frozen=True)
class Chunks:
    """A shell layout's triangles cut into runs (``tol.REACH_CHUNK_FACES`` each),
    each ready to be built alone: ``order`` (k,) the shell's triangles in run order
    and ``starts`` (r+1,) where each run starts in it; per run its vertices
    ``verts`` (indices into the layout's vertices), its faces on them ``faces`` and
    their :func:`core.rays.triangle_rows` ``rows`` (None with the numpy backend);
    ``vstarts`` (r+1,) where each run's vertices start in ``allverts``, the
    concatenation of ``verts`` (the runs' boxes in one pass)."""

    order: np.ndarray
    starts: np.ndarray
    verts: list
    faces: list
    rows: list
    allverts: np.ndarray
    vstarts: np.ndarray


#: Check the segments of solver steps against the reach they set too (and raise when
#: one leaves it): the tests turn it on; off, they are trusted (see ``Shells.for_rays``).
AUDIT = False


def spatial_rank(V, F) -> np.ndarray:
    """(m,) int64: each face's place in a Z-order (Morton) walk over the centroids of
    ``V`` (n, 3), ``F`` (m, 3), 10 bits per axis of their bounds: faces near in the
    ranking are near in space (ties keep the faces' order)."""
    c = np.asarray(V, np.float64)[F].mean(axis=1)
    lo, hi = c.min(axis=0), c.max(axis=0)
    q = ((c - lo) / np.where(hi > lo, hi - lo, 1.0) * 1023.0).astype(np.uint64)
    code = np.zeros(len(F), np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    rank = np.empty(len(F), np.int64)
    rank[np.argsort(code, kind="stable")] = np.arange(len(F))
    return rank


class Shells:
    """The BVHs of a collider's shells (see the module docstring).

    Parameters
    ----------
    mesh : ColliderMesh
    pose : Pose
    double_sided : bool
        A thin two-sided shell: shells on both sides (as an open mesh gets).
    backend : {None, 'embree', 'numpy'}
        Ray tracer (None: embree).
    """

    def __init__(self, mesh, pose, double_sided=False, backend=None):
        self.mesh, self.pose = mesh, pose
        self.double_sided = double_sided
        self.backend_name = backend
        self.built = []  # [(key, backend, ShellFaces)], newest last
        # Builds may run on a ray thread (see prefetch).
        self.lock = threading.Lock()
        self._prefetching = None  # shell key of the last prefetch started
        self._key_memo = (None, -1, {})  # (matrix, version, offset -> key): shell_key
        self._rows = {}  # shell layout -> prepared triangles (see rows)
        self._chunks = {}  # shell layout -> Chunks (reachable parts)
        #: What the curves of the current solver step can reach (:class:`Reach`), set
        #: by ``Collider.set_reach`` for a collider that builds reachable parts;
        #: None: shells are built whole.
        self.reach = None
        self._offset_dirs = PerShape()
        self._own_dirs = PerShape()  # offset directions in own units, per shape
        #: BVHs built so far (every shell, every shape).
        self.build_count = 0

    def shell_key(self, offset_wo):
        """What a shell depends on: the vertices, a fitted placement's allowance
        (``Pose.allowance``), the offset and, for an offset, the matrix's
        rotation-invariant stretch ``M^T M`` (quantized, so float32 jitter of a
        rigid transform never triggers a rebuild)."""
        version = self.mesh.version
        allowance = self.pose.allowance
        if allowance:
            version = (version, allowance)
        if offset_wo <= 0:
            return (version, 0.0)
        # Every ray query asks: remembered per matrix (assigning one replaces the
        # array, never writes into it) and shape.
        M = self.pose.M
        memo = self._key_memo
        if memo[0] is not M or memo[1] != version:  # (a fitted placement: a new M)
            memo = self._key_memo = (M, version, {})
        key = memo[2].get(offset_wo)
        if key is None:
            S = M[:3, :3]
            G = np.einsum("ki,kj->ij", S, S)
            g = float(np.trace(G)) / 3.0
            q = tuple(np.round(G / g, 6).ravel()) + (float(f"{g:.6g}"),)
            key = memo[2][offset_wo] = (version, float(f"{offset_wo:.9g}"), q)
        return key

    def backend(self, offset_wo: float, whole: bool = False, reach=None):
        """``(ray backend, ShellFaces)`` of the shell at ``offset_wo`` (built when
        missing): of its part within :attr:`reach` when one is set and leaves out
        enough triangles (``tol.REACH_MIN_SAVING``), else (or ``whole``) of all of
        it; ``reach`` instead of :attr:`reach` (the one a solver step set, whatever
        another set since). A few shells are kept (several solvers may share one
        collider with different offsets, per-curve clearances use up to
        ``tol.OFFSET_LEVELS``), newest last."""
        with self.lock:
            return self._backend_locked(offset_wo, whole, reach)

    def for_rays(self, offset_wo, o_lo, d_lo, tmax, reach=None):
        """:meth:`backend` for the segments ``o_lo + t d_lo``, ``t`` in [0, ``tmax``]
        (local space): the whole shell when one leaves a reachable part's cover (a
        query the reach did not foresee: the same answers, more work).

        ``reach``: the :class:`Reach` the solver step asking set (its segments are
        its curves', within it by construction): that part, unchecked (the check
        costs about what the rays do); checked, and an escape raised, under
        :data:`AUDIT` (the tests)."""
        be, faces = self.backend(offset_wo, reach=reach)
        if faces.cover is None or not len(o_lo) or (reach is not None and not AUDIT):
            return be, faces
        lo, hi = faces.cover
        end = o_lo + tmax * d_lo
        inside = (np.minimum(o_lo, end).min(axis=0) >= lo).all() and (
            np.maximum(o_lo, end).max(axis=0) <= hi).all()
        if not inside and reach is not None:
            raise AssertionError("a solver step's segment left the reach it set")
        return (be, faces) if inside else self.backend(offset_wo, whole=True)

    def prefetch(self, offset_wo: float, threads: int):
        """Start building the BVH that queries at ``offset_wo`` need on a ray
        thread, when the vertices or the offset changed (see ``Collider.prefetch``).
        Returns a callable that waits for it, or None when nothing was started."""
        if threads <= 1 or len(self.mesh.F) == 0:
            return None
        key = self.part_key(offset_wo, self.reach)
        if key == self._prefetching or any(b[0] == key for b in self.built):
            return None
        self._prefetching = key
        return beside(partial(self.backend, offset_wo), threads)

    def part_key(self, offset_wo, reach):
        """:meth:`shell_key`, with the cells of ``reach`` (:class:`Reach`; None: the
        whole shell)."""
        key = self.shell_key(offset_wo)
        return key if reach is None else key + (reach.key,)

    def _backend_locked(self, offset_wo: float, whole: bool = False, reach=None):
        # (read once: a solver may set another)
        reach = None if whole else (self.reach if reach is None else reach)
        key = self.part_key(offset_wo, reach)
        for k, be, faces in self.built:
            if k == key:
                return be, faces
        mesh = self.mesh
        V = mesh.local_vertices()
        F = mesh.F
        m, n = len(F), len(mesh.V)
        # Every shell keeps the clearance margin (see Collider.margin), plus the
        # Collision Offset when there is one.
        disp = mesh.margin * mesh.margin_directions()
        if offset_wo > 0:
            disp = disp + offset_wo * self.offset_directions()
        if self.pose.allowance:
            # A fitted placement (Pose.allowance): every face moves out by the
            # fit's allowance too, as an offset in the collider's own units.
            disp = disp + self.pose.allowance * self._own_dirs.get(
                mesh.version, lambda: self.offset_directions_of(np.eye(3), np.eye(3)))
        # Face blocks: [outer shell, (inner shell, surface)]. A closed
        # single-sided solid is only kept at a distance from outside (inside
        # is a pinch). Anything else (open sheets, double-sided meshes) gets
        # shells on both sides, the inner one facing inward, and keeps its
        # real surface too, so a curve slipping in between the shells from a
        # rim still collides: all of it with an offset, its rim faces only
        # for the bare margin (a curve can only slip in within it of a rim).
        blocks_V, blocks_F = [V + disp], [F]
        real, flip = [np.arange(m)], [np.zeros(m, bool)]
        if self.double_sided or not mesh.closed:
            keep = np.arange(m) if offset_wo > 0 else mesh.rim_faces()
            blocks_V += [V - disp, V]
            blocks_F += [F[:, ::-1] + n, F[keep] + 2 * n]
            real += [np.arange(m), keep]
            flip += [np.ones(m, bool), np.zeros(len(keep), bool)]
        V = np.concatenate(blocks_V)
        F = np.concatenate(blocks_F)
        real, flip = np.concatenate(real), np.concatenate(flip)
        single = len(blocks_F) == 1
        part = None if reach is None else self._part(V, F, real, reach)
        aliases = []
        if part is None:
            if reach is not None:  # (the part would be about all of it: the whole shell,
                # shared with every other reach that finds the same)
                aliases, key = [key], self.part_key(offset_wo, None)
                for k, be, faces in self.built:
                    if k == key:
                        self.built.append((aliases[0], be, faces))
                        self.built = self.built[-(tol.OFFSET_LEVELS + 3):]
                        return be, faces
            faces = ShellFaces(real, flip, single)
            backend = make_backend(self.backend_name, V, F, rows=self.rows(F))
        else:
            chunks, runs, cover = part
            tri = np.concatenate([chunks.order[chunks.starts[r]:chunks.starts[r + 1]]
                                  for r in runs])
            faces = ShellFaces(real[tri], flip[tri], single, cover=cover)
            backend = make_parts_backend(self.backend_name, [
                (V[chunks.verts[r]], chunks.faces[r], chunks.rows[r]) for r in runs])
        self.build_count += 1
        # (room for every level of per-curve clearances, tol.OFFSET_LEVELS,
        # beside a few other offsets: several solvers may share a collider; a
        # fitted placement's shells beside the plain ones)
        # (aliases: a reach whose part would be about all of it shares the whole shell)
        self.built = [b for b in self.built
                      if self._version_of(b[0]) == mesh.version][-(tol.OFFSET_LEVELS + 3):]
        self.built += [(k, backend, faces) for k in [key, *aliases]]
        return backend, faces

    def _part(self, V, F, real, reach):
        """``(Chunks, runs, cover)``: the runs of the shell ``V``, ``F`` whose box meets
        ``reach`` (:class:`Reach`), and the box every triangle meeting it is among
        them (the reach's, unbounded on the sides where it holds the whole shell); or
        None when they would leave out too little of it (``tol.REACH_MIN_SAVING``:
        then the whole shell is built)."""
        chunks = self.chunks(F, real)
        Vc = V[chunks.allverts]
        lo = np.minimum.reduceat(Vc, chunks.vstarts[:-1], axis=0)
        hi = np.maximum.reduceat(Vc, chunks.vstarts[:-1], axis=0)
        meets = (lo <= reach.hi).all(axis=1) & (hi >= reach.lo).all(axis=1)
        runs = np.flatnonzero(meets)
        size = np.diff(chunks.starts)
        if size[runs].sum() > (1.0 - tol.REACH_MIN_SAVING) * len(F) or not len(runs):
            # (no run at all: nothing there to hit, but a query may still come: whole)
            return None
        # (a triangle's box is within the shell's: on a side where the reach holds
        # the shell, a segment beyond it meets no triangle the part lacks)
        cover = (np.where(reach.lo <= lo.min(axis=0), -np.inf, reach.lo),
                 np.where(reach.hi >= hi.max(axis=0), np.inf, reach.hi))
        return chunks, runs, cover

    def chunks(self, F, real):
        """The :class:`Chunks` of the shell faces ``F`` (``real``: the collider face
        of each; a topology property: cut once per layout, reused by every build of
        a reachable part).

        The runs follow the faces' order in space on the rest shape when the
        collider has one (:func:`spatial_rank`: compact patches whatever the
        mesh's face order), else the mesh's own face order (modelled meshes keep
        neighbours near in it). Either is fixed by the collider as made, never by
        the shapes seen since: what a frame builds depends on that frame only."""
        key = len(F)
        if key not in self._chunks:
            n = tol.REACH_CHUNK_FACES
            if self.pose.rest is not None:
                rank = spatial_rank(self.pose.rest, self.mesh.F)
                order = np.argsort(rank[real], kind="stable")
            else:
                order = np.arange(len(F))
            starts = np.unique(np.r_[np.arange(0, len(F), n), len(F)]).astype(np.int64)
            verts, faces, rows = [], [], []
            for a, b in zip(starts[:-1], starts[1:], strict=True):
                ids, local = np.unique(F[order[a:b]], return_inverse=True)
                local = local.reshape(-1, 3).astype(np.int64)
                verts.append(ids)
                faces.append(local)
                rows.append(None if self.backend_name == "numpy" else triangle_rows(local))
            vstarts = np.cumsum([0] + [len(v) for v in verts]).astype(np.int64)
            self._chunks[key] = Chunks(order, starts, verts, faces, rows,
                                       np.concatenate(verts), vstarts)
        return self._chunks[key]

    @staticmethod
    def _version_of(key):
        """The shape version of a :meth:`shell_key`."""
        v = key[0]
        return v[0] if isinstance(v, tuple) else v

    def rows(self, F):
        """:func:`core.rays.triangle_rows` of the shell faces ``F`` (a topology
        property: prepared once per layout, reused by every rebuild)."""
        if self.backend_name == "numpy":
            return None
        key = len(F)  # the layout: 1 to 3 blocks of this collider's faces
        if key not in self._rows:
            self._rows[key] = triangle_rows(F)
        return self._rows[key]

    def offset_directions(self):
        """:meth:`offset_directions_of` the current shape and matrix, kept for the
        shells of other offsets (per-curve clearance levels) of the same."""
        pose = self.pose
        key = (self.mesh.version, pose.M[:3, :3].tobytes())
        return self._offset_dirs.get(
            key, lambda: self.offset_directions_of(pose.M[:3, :3], pose.Minv[:3, :3]))

    def offset_directions_of(self, S, Sinv):
        """Local displacement of each vertex for a world offset of 1, (n, 3), for
        the linear part ``S`` (3, 3) of the world matrix (its inverse ``Sinv``;
        the identity: an offset in the collider's own units).

        Computed in world metric (the matrix's scale and shear included), so
        the shell keeps the offset in world units whatever the matrix. Each
        vertex moves along its angle-weighted normal (each face's normal
        weighted by its corner angle at the vertex: the same direction however
        the faces are triangulated), lengthened so that every face around it
        moves by the full offset: a box keeps the offset on its faces, not
        offset / sqrt(3), nor twice it at a corner split into two triangles.
        The lengthening is capped at ``tol.OFFSET_MAX_STRETCH`` (needle-sharp
        vertices).
        """
        mesh = self.mesh
        Vw = apply(S, mesh.local_vertices())
        F = mesh.F
        fa = np.cross(Vw[F[:, 1]] - Vw[F[:, 0]], Vw[F[:, 2]] - Vw[F[:, 0]])
        if det3(S) < 0:  # a mirroring matrix flips the winding: keep normals outward
            fa = -fa
        fn = unit(fa, np.linalg.norm(fa, axis=1, keepdims=True))
        n = len(mesh.V)
        vn = angle_weighted(Vw, F, fn)
        # smallest cos(vertex normal, face normal) over the faces around each vertex
        cos = np.concatenate([rot_dot(vn[F[:, k]], fn) for k in range(3)])
        order, _, first, verts = mesh.corners()
        lowest = np.ones(n)
        lowest[verts] = np.minimum.reduceat(cos[order], first)
        stretch = 1.0 / np.clip(lowest, 1.0 / tol.OFFSET_MAX_STRETCH, 1.0)
        return apply(Sinv, vn * stretch[:, None])

    # ------------------------------------------------------------- queries
    def hits_local(self, o_lo, d_lo, offset_wo=0.0, threads=1, reach=None) -> np.ndarray:
        """Which segments ``o + t d``, ``t`` in [0, 1], already in the local space,
        hit the shell at ``offset_wo``: (k,) bool (``reach``: see :meth:`for_rays`)."""
        be, _ = self.for_rays(offset_wo, o_lo, d_lo, 1.0 + tol.T_SLACK, reach)
        return be.any_hit(o_lo, d_lo, 1.0 + tol.T_SLACK, threads)

    def hit_details(self, o_wo, d_wo, offset_wo=0.0, faces=False, reach=None):
        """First hit of each segment: ``(hit, t, n_wo[, face])``, see
        ``Collider.segment_hit_details`` (segments given in world space; ``reach``:
        see :meth:`for_rays`)."""
        k = len(o_wo)
        o_lo, d_lo = self.pose.to_local(o_wo, d_wo)
        be, shell = self.for_rays(offset_wo, o_lo, d_lo, 1.0 + tol.T_SLACK, reach)
        prim, t = be.hit_details(o_lo, d_lo, 1.0 + tol.T_SLACK)
        hit = prim >= 0
        t = np.where(hit, np.minimum(t, 1.0), np.inf)  # (a hit in the slack: at the end)
        n_wo = np.zeros((k, 3))
        if hit.any():
            n_wo[hit] = self.normals_world(prim[hit], shell)
            if shell.single:  # the mesh's own faces (a closed single-sided collider)
                self.vertex_pushes(n_wo, hit, prim, o_lo, d_lo, t)
        if not faces:
            return hit, t, n_wo
        face = np.full(k, -1, np.int64)
        face[hit] = shell.real[prim[hit]]
        return hit, t, n_wo, face

    def normals_world(self, prim, faces):
        """Unit world normals of shell triangles ``prim`` (:class:`ShellFaces`
        ``faces``), oriented as their shell (the inner one faces inward)."""
        idx, flip = faces.real[prim], faces.flip[prim]
        n_lo = self.mesh.face_normals(idx) * np.where(flip, -1.0, 1.0)[:, None]
        n_wo = apply(self.pose.Minv[:3, :3].T, n_lo)  # inverse-transpose for normals
        return unit(n_wo, np.linalg.norm(n_wo, axis=1, keepdims=True))

    def vertex_pushes(self, n_wo, hit, prim, o_lo, d_lo, t):
        """Hits that land on a vertex (``tol.VERTEX_HIT_BARY``) push along the vertex's
        angle-weighted normal: the faces around a vertex all contain the hit, and which
        one the tracer reports is decided by rounding (a curve through a UV sphere's
        pole would take its rotation axis from it). ``n_wo`` is updated in place."""
        mesh = self.mesh
        w = np.flatnonzero(hit)
        tri = mesh.V[mesh.F[prim[w]]] - mesh.center  # (h, 3, 3), as local_vertices
        p = o_lo[w] + t[w, None] * d_lo[w]
        bary = barycentric(p, tri[:, 0], tri[:, 1], tri[:, 2])  # (0 rows: degenerate)
        corner = np.argmax(bary, axis=1)
        at = bary[np.arange(len(w)), corner] > 1.0 - tol.VERTEX_HIT_BARY
        if not at.any():
            return
        vn = apply(self.pose.Minv[:3, :3].T,
                   mesh.vertex_normals()[mesh.F[prim[w[at]], corner[at]]])
        vn = unit(vn, np.linalg.norm(vn, axis=1, keepdims=True))
        good = vn.any(axis=1)  # (a vertex whose face normals cancel keeps its face's)
        n_wo[w[at][good]] = vn[good]
