"""Collision meshes: :class:`Collider`, a thin facade over parts that each own their data.

* :mod:`.mesh` (``ColliderMesh``): validation and repair of the triangles
  (:mod:`core.meshfix`), their topology, the shape (vertices, version, centre,
  bounds) and its normals;
* :mod:`.pose` (``Pose``, ``Placement``): where the collider is (its matrix),
  where it was (its previous placement) and the velocity of its surface;
* :mod:`.grid` (``Occupancy``): the vertex occupancy grid, "can this ball
  touch the mesh";
* :mod:`.shells` (``Shells``): the offset shells per clearance level, their
  BVHs, segment hits and the normals at hits;
* :mod:`.inside` (``Inside``, ``Closest``): the inside test (pinches) and
  closest points.

A collider keeps its triangles in its own (object) space. Rigid motion only
changes :attr:`Collider.matrix`: rays are moved into the collider's space, the
BVH is never rebuilt. Deformation sets :attr:`Collider.vertices`, which
rebuilds the BVH lazily, and only when the vertices really changed and, for a
collider given its rest shape, did not only move rigidly from it (a hat skinned
to one bone: :mod:`.pose` fits the motion and places the rest shape's BVH).
:meth:`Collider.place` does both as one update and remembers the placement
before it (:attr:`Collider.previous`): the surface's velocity at a point
(:meth:`Collider.velocities`, Follow Collider Motion).

Naming: ``_wo`` is world space, ``_lo`` the collider's local space (its own
space shifted to the centre of its bounds, where the float32 BVH lives).
"""

from __future__ import annotations

import numpy as np

from .. import tolerances as tol
from ..errors import ColliderError
from .grid import Occupancy
from .inside import Closest, Inside
from .mesh import ColliderMesh
from .pose import Placement, Pose
from .shells import Reach, ShellFaces, Shells

__all__ = ["Collider", "Placement", "ShellFaces", "clearance_levels"]


def clearance_levels(dist):
    """Per-curve distances ``dist`` (C,) grouped into at most
    ``tol.OFFSET_LEVELS`` levels (one offset shell each).

    Up to ``OFFSET_LEVELS`` distinct values are their own levels (exact).
    More: the range ``[min, max]`` is cut into ``OFFSET_LEVELS`` equal bins
    and each bin's level is the largest distance in it, so every curve is
    kept at least as far as it asked, and at most one bin width farther. The
    levels depend on the set of values only, never on the curves' order.

    Returns
    -------
    levels : (L,) float64, increasing
    group : (C,) int64
        Each curve's level.
    """
    u, inv = np.unique(dist, return_inverse=True)
    inv = inv.reshape(-1)
    L = tol.OFFSET_LEVELS
    if len(u) <= L:
        return u, inv
    lo, hi = float(u[0]), float(u[-1])
    b = np.minimum(np.floor((u - lo) / (hi - lo) * L), L - 1).astype(np.int64)
    # u is sorted: a bin's largest value is its last; bins only increase
    last = np.flatnonzero(np.r_[b[1:] != b[:-1], True])
    bins = np.cumsum(np.r_[0, (b[1:] != b[:-1]).astype(np.int64)])  # value -> level
    return u[last], bins[inv]


def _check_offset(offset, name):
    try:
        offset = float(offset)
    except (TypeError, ValueError):
        raise ColliderError(f"collider '{name}': offset must be a number") from None
    if not (np.isfinite(offset) and 0 <= offset <= 1e6):
        raise ColliderError(
            f"collider '{name}': offset must be between 0 and 1e6, got {offset}"
        )
    return offset


class Collider:
    """A triangle mesh that curves must not pass through.

    Parameters
    ----------
    V : (n, 3) array_like of float
        Vertices in the collider's own space.
    F : (m, 3) array_like of int
        Triangles (indices into ``V``). ``m == 0`` is allowed: an empty
        collider never collides (a documented no-op).
    double_sided : bool
        Treat the mesh as a thin two-sided shell: curves are pushed back to
        the side their root is on, offsets apply on both sides, and it never
        reports pinches. Single-sided meshes push along the hit normal (or
        its inverse when a back face is crossed) and, when closed, detect
        pinched roots (roots inside the volume).
    matrix : (4, 4) array_like, optional
        Affine world transform (None = identity).
    offset : float, optional
        Collision offset of this collider (world units), overriding
        ``Settings.collision_offset`` (a number for every curve;
        ``Settings.clearance_margin`` is still added).
    drop_degenerate : bool
        Silently drop zero-area triangles instead of raising. The number
        dropped is in :attr:`dropped_faces`.
    backend : {'embree', 'numpy'}, optional
        Ray tracer; default embree. 'numpy' is the brute-force reference.
    name : str
        Used in error messages (e.g. the Blender object's name).
    deforming : bool or None
        A hint that the vertices change every frame (skinning, shape keys,
        cloth). It changes no result (the BVH is a function of the vertices
        and, with an offset, of the shell alone, so results never depend on
        the frames played before), only work: the inside test of a deforming
        collider never builds its fine per-shape grid (see
        :meth:`contains_grid`), which a second query of the same frame (the
        render groom's clearance pass after the guides) would otherwise build
        every frame for one use.
    rest : (n, 3) array_like of float, optional
        The rest shape (the undeformed mesh, e.g. a skinned object's own
        vertices; same topology as ``V``, which is then placed on it). Vertices
        that only moved rigidly from it (a hat, belt or buckle skinned to one
        bone), ``V`` included, reuse its BVH placed by the fitted motion instead
        of a new build (``tol.RIGID_FIT_ULPS``, :mod:`.pose`); the topology and
        repairs are made of it. Results then depend on ``rest`` and each frame's
        placement only (whatever frame the collider was constructed at), within
        one Rotation Precision step of a collider without it, and as safe. None:
        every new shape is built.

    Attributes
    ----------
    mesh : ColliderMesh
    pose : Pose
    grid : Occupancy
    shells : Shells
    inside : Inside
    closest : Closest
        The parts (see the module docstring).
    queried : bool
        Did the last solver step that saw this collider query it? (It then
        starts the next rebuild early: timing only, never a result.)

    Raises
    ------
    ColliderError
        Malformed vertices, faces or matrix; the message names the vertex
        or face at fault.
    """

    def __init__(
        self,
        V,
        F,
        double_sided=False,
        matrix=None,
        offset=None,
        drop_degenerate=False,
        backend=None,
        name="collider",
        deforming=None,
        rest=None,
    ):
        self.name = str(name)
        if backend not in (None, "embree", "numpy"):
            raise ColliderError(f"collider '{self.name}': unknown backend {backend!r}")
        self.offset = None if offset is None else _check_offset(offset, self.name)
        # With a rest shape the mesh is made of it (topology, repairs): the same
        # whatever frame the collider is constructed at; V is then placed on it.
        self.mesh = ColliderMesh(V if rest is None else rest, F, self.name, drop_degenerate)
        self.closest = Closest(self.mesh)
        self.pose = Pose(self.mesh, matrix, self.closest.nearest_faces,
                         fit_rest=rest is not None)
        if rest is not None:
            self.pose.start(V)
        self.grid = Occupancy(self.mesh, self.pose)
        self.shells = Shells(self.mesh, self.pose, bool(double_sided), backend)
        self.inside = Inside(self.mesh, self.pose, self.grid, self.shells,
                             None if deforming is None else bool(deforming))
        self.queried = False
        self._derived = {}  # name -> (key, value), see derived()

    # ------------------------------------------------------------ the mesh
    @property
    def double_sided(self) -> bool:
        """A thin two-sided shell (see the parameter)."""
        return self.shells.double_sided

    @double_sided.setter
    def double_sided(self, value):
        self.shells.double_sided = bool(value)

    @property
    def deforming(self) -> bool | None:
        """The hint that the vertices change every frame (see the parameter)."""
        return self.inside.deforming

    @deforming.setter
    def deforming(self, value):
        self.inside.deforming = None if value is None else bool(value)

    @property
    def faces(self) -> np.ndarray:
        """(m, 3) int32 triangles (after dropping degenerate ones)."""
        return self.mesh.F

    @property
    def empty(self) -> bool:
        """True when the collider has no triangle (it never collides)."""
        return len(self.mesh.F) == 0

    @property
    def repairs(self):
        """What :mod:`core.meshfix` repaired (``meshfix.Tidy``)."""
        return self.mesh.repairs

    @property
    def closed(self) -> bool:
        """Is the (repaired) mesh closed (it has an inside)?"""
        return self.mesh.closed

    @property
    def dropped_faces(self) -> int:
        """Degenerate faces dropped (``drop_degenerate=True``)."""
        return self.mesh.dropped_faces

    @property
    def vertices(self) -> np.ndarray:
        """(n, 3) float32 vertices in the collider's own space, as last given
        (read-only view)."""
        v = self.pose.vertices.view()
        v.flags.writeable = False
        return v

    @vertices.setter
    def vertices(self, V2):
        self.pose.set_vertices(V2)

    @property
    def version(self) -> int:
        """Shape version: 0 at construction, +1 each time :attr:`vertices`
        changes. Derived data keyed on it stays valid while the collider only
        moves (see :meth:`derived`)."""
        return self.pose.user_version

    def derived(self, name: str, key, build):
        """Data derived from this collider, kept with it under ``name``.

        Returns the kept value when it was made for ``key`` (hashable, e.g.
        ``(col.version, ...)``), else ``build()``, which is kept. For callers
        that index a collider their own way (distance fields, closest-point
        structures) without reaching into its parts.
        """
        hit = self._derived.get(name)
        if hit is not None and hit[0] == key:
            return hit[1]
        value = build()
        self._derived[name] = (key, value)
        return value

    @property
    def margin(self) -> float:
        """The clearance margin, in the collider's own units: every shell the
        curves are tested against lies this far out along the vertex
        normals, even with no Collision Offset.

        ``tol.CLEARANCE_ULPS`` float32 ulps of the collider's own coordinates
        (the largest of its size and its vertices' distance from its origin,
        rounded up to a power of two). A function of the vertices alone:
        moving, turning or scaling a collider never changes it, so its BVH
        is never rebuilt for motion.

        Embree tests in float32 and a curve's output is rounded to float32:
        without a margin a segment passing within rounding distance of a
        sharp edge can be clear for the solver and crossing for another
        (float64, or differently rounded) test of the same output.
        """
        return self.mesh.margin

    @property
    def detects_pinch(self) -> bool:
        """Only closed, single-sided colliders have an inside."""
        return self.mesh.closed and not self.shells.double_sided

    # ----------------------------------------------------------- placement
    @property
    def matrix(self) -> np.ndarray:
        """(4, 4) float64 world transform, as last given (a copy)."""
        return self.pose.user_M.copy()

    @matrix.setter
    def matrix(self, M):
        self.pose.set_matrix(M)

    def place(self, matrix=None, vertices=None):
        """Move the collider to this frame's placement: one update.

        The whole placement it had (matrix and vertices) becomes
        :attr:`previous`, then ``matrix`` and ``vertices`` (None: unchanged)
        are applied as assigning :attr:`matrix` and :attr:`vertices` would.
        Call it once per frame (step) with both parts: a part left unchanged
        then did not move since the previous frame.
        """
        self.pose.place(matrix, vertices)

    @property
    def previous(self) -> Placement | None:
        """The placement the collider had before its last update, or None when
        none is known (a new collider, or after :meth:`forget_previous`).

        An update is :meth:`place` (both parts at once), or an assignment of
        :attr:`matrix` or :attr:`vertices` (that part only: assigning the
        same value again is an update in which it did not move). Follow
        Collider Motion takes each contact's velocity from it
        (:meth:`velocities`): update both parts once per frame, e.g. with
        :meth:`place`; a glue that resumes from a cached frame sets the
        previous frame's placement with :meth:`set_previous` to get the bits
        of playback.
        """
        return self.pose.previous

    def set_previous(self, matrix=None, vertices=None):
        """Set :attr:`previous` explicitly: ``matrix`` (4, 4) and ``vertices``
        (n, 3) (same topology), each None for "where it is now" (that part
        did not move)."""
        self.pose.set_previous(matrix, vertices)

    def forget_previous(self):
        """Forget the previous placement: the collider has no known motion
        (:meth:`velocities` are zero) until its next update."""
        self.pose.forget_previous()

    def velocities(self, p_wo, faces=None) -> np.ndarray:
        """Velocity of the collider's surface at points ``p_wo`` (world units
        per update: from :attr:`previous` to now).

        Parameters
        ----------
        p_wo : (k, 3) array_like
            Points on (or near: an offset shell) the collider, world space,
            current placement.
        faces : (k,) array_like of int, optional
            The face of each point (indices into :attr:`faces`, e.g. a hit's
            face). Needed to follow a deformation (the point moves with its
            face's vertices, barycentric weights of its projection onto the
            face); without it the nearest face is looked up, only when the
            vertices moved.

        Returns
        -------
        (k, 3) float64
            Zero where nothing is known (no previous placement) and,
            exactly, where the collider did not move at all.
        """
        return self.pose.velocities(p_wo, faces)

    def local_map(self) -> tuple[np.ndarray, np.ndarray]:
        """``(A, b)`` with ``x_lo = A @ x_wo + b`` (vectors: ``A @ v``).

        The local space is the collider's own space shifted to the centre of
        its bounds (where the float32 BVH lives).
        """
        return self.pose.local_map()

    def bounds_world(self, offset_wo: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """World-space axis-aligned bounds (lo, hi), grown by the offset."""
        return self.pose.bounds_world(offset_wo)

    # ----------------------------------------------------------- clearance
    def effective_offset(self, default: float) -> float:
        """This collider's offset in world units (its own, else ``default``)."""
        return self.offset if self.offset is not None else float(default)

    def clearance_groups(self, offset=0.0, margin=0.0, levels=None) -> list:
        """The offset shells the curves are tested against, and which curves.

        Parameters
        ----------
        offset : float or (C,) ndarray
            ``Settings.collision_offset`` (a number or one per curve); this
            collider's own :attr:`offset`, when it has one, replaces it.
        margin : float or (C,) ndarray
            ``Settings.clearance_margin``, added to the offset that applies.
        levels : (L,) ndarray, optional
            Increasing distances to round every curve's distance up to (the
            levels of a larger set of curves these are taken from, see
            ``Settings.take``), instead of this set's own.

        Returns
        -------
        list of (float, (C,) bool ndarray or None)
            ``(distance, curves)``: the curves (None: all of them) kept at
            ``distance`` from this collider. One distance for every curve is
            one group of all curves (``distance`` as the plain numbers give
            it, bit for bit); otherwise see :func:`clearance_levels` (at most
            ``tol.OFFSET_LEVELS`` groups, never less than a curve's own
            distance).
        """
        dist = self.clearance_distances(offset, margin)
        if not isinstance(dist, np.ndarray):
            return [(dist, None)]
        if len(dist) == 0:
            return [(0.0, None)]
        if levels is not None:  # the smallest level at least each distance
            j = np.searchsorted(levels, dist)
            used = np.unique(j)
            if len(used) == 1:
                return [(float(levels[used[0]]), None)]
            return [(float(levels[u]), j == u) for u in used]
        lo, hi = dist.min(), dist.max()
        if lo == hi:  # a uniform map: the plain number's shell
            return [(float(dist[0]), None)]
        levels, group = clearance_levels(dist)
        return [(float(levels[j]), group == j) for j in range(len(levels))]

    def clearance_distances(self, offset=0.0, margin=0.0):
        """The distance each curve asks to be kept from this collider (before
        any rounding): a float, or (C,) float64 when a map is involved."""
        base = self.offset if self.offset is not None else offset
        if not isinstance(base, np.ndarray) and not isinstance(margin, np.ndarray):
            return float(base) + float(margin)
        return np.asarray(base, np.float64) + margin

    # ------------------------------------------------------------- queries
    @property
    def build_count(self) -> int:
        """BVHs built so far (every shell, every shape)."""
        return self.shells.build_count

    @property
    def builds_reach(self) -> bool:
        """Does this collider build only what the curves can reach
        (:meth:`set_reach`)? A deforming one (the ``deforming`` hint) without an
        inside test (open, or double-sided), not placed by a rigid fit (its rest
        shape's shells are built once, whole)."""
        return bool(self.deforming) and not self.detects_pinch and not self.pose.allowance

    def set_reach(self, lo_wo=None, hi_wo=None):
        """What the curves of a solver step can reach: the world box ``lo_wo``,
        ``hi_wo`` (3,) (the roots grown by their curves' lengths), or None.

        A collider that :attr:`builds_reach` then builds, for the shape it has, only
        the runs of its shell's triangles (``tol.REACH_CHUNK_FACES`` each, cut once:
        ``Shells.chunks``) whose box meets that box, rounded out to cubes of
        ``1 / tol.REACH_GRID`` of the collider's largest side (``tol.REACH_GROW_REL``
        grown first): a shirt or a body
        much larger than the fur on it builds about the part near the fur. Every
        triangle that meets the box is in that part, so a segment inside it gets
        the answers of the whole mesh; one leaving it is traced against the whole
        shell (built then). What is built is a function of the shape and the box,
        never of the frames before: the same input gives the same bits. The only
        difference from the whole shell: which of two triangles a segment meets at
        exactly the same point is reported may differ (another BVH).
        The solver sets it at the start of each step and passes what this returns
        with its own segments (``reach=``: theirs by construction, so unchecked);
        other queries use the last one set, checked.

        Returns
        -------
        Reach or None
            What was set (None: shells are built whole).
        """
        shells = self.shells
        if lo_wo is None or not self.builds_reach or self.empty:
            shells.reach = None
            return None
        A, b = self.local_map()
        lo_wo, hi_wo = np.asarray(lo_wo, np.float64), np.asarray(hi_wo, np.float64)
        c = A @ (0.5 * (lo_wo + hi_wo)) + b
        h = np.abs(A) @ (0.5 * (hi_wo - lo_wo))
        h = h + tol.REACH_GROW_REL * float(np.linalg.norm(h)) + 1e-9
        lo, hi = self.mesh.bounds()
        base = lo - self.mesh.center
        size = hi - lo
        cell = (float(size.max()) or 1.0) / tol.REACH_GRID  # (cubes: a thin sheet too)
        # (never clamped to the mesh: an offset shell stands out of it, and a reach
        # that holds the whole shell on a side leaves that side open anyway)
        i_lo = np.floor((c - h - base) / cell).astype(np.int64)
        i_hi = np.ceil((c + h - base) / cell).astype(np.int64)
        key = ("reach", *i_lo.tolist(), *i_hi.tolist())
        # (always the box of this shape's grid: the same cells of another shape are
        # another box; a build is keyed by the shape's version as well)
        shells.reach = Reach(key, base + i_lo * cell, base + i_hi * cell)
        return shells.reach

    def prefetch(self, offset_wo: float, threads: int):
        """Start building the BVH that queries at ``offset_wo`` need on a ray
        thread, when the vertices or the offset changed.

        Embree builds without the GIL, so the build overlaps the caller's own
        work (the solver's set-up). Queries made meanwhile wait for it. The
        result never depends on it: only when the work is done.

        Returns
        -------
        callable or None
            Waits for the work (re-raising its error); None when nothing was
            started (nothing to do, one thread, or already under way).
        """
        return self.shells.prefetch(offset_wo, threads)

    def near_surface(self, p_wo, radius_wo, offset_wo=0.0) -> np.ndarray:
        """Conservative test: can a ball (``p_wo``, ``radius_wo``) touch the mesh?

        Parameters
        ----------
        p_wo : (k, 3) ndarray
            Ball centres, world space.
        radius_wo : (k,) ndarray or float
            Radii, world units.

        Returns
        -------
        (k,) bool
            False only where the ball certainly misses the (offset) mesh.
        """
        k = len(p_wo)
        if self.empty or k == 0:
            return np.zeros(k, bool)
        q = self.grid_coords(np.asarray(p_wo, np.float64).T)
        return self.near_surface_grid(q, radius_wo, offset_wo)

    def grid_coords(self, p_wo):
        """World points given as components (3, k) in the occupancy grid's
        frame (local space minus the grid's corner), as components (3, k)."""
        return self.grid.grid_coords(p_wo)

    def near_surface_grid(self, q, radius_wo, offset_wo=0.0) -> np.ndarray:
        """:meth:`near_surface` for centres given by :meth:`grid_coords`."""
        k = q.shape[1]
        if self.empty or k == 0:
            return np.zeros(k, bool)
        return self.grid.near_surface_grid(q, radius_wo, offset_wo)

    def segment_hits(self, o_wo, d_wo, offset_wo=0.0, threads=1) -> np.ndarray:
        """Which segments ``o + t d, t in [0, 1]`` hit the collider.

        Parameters
        ----------
        o_wo, d_wo : (k, 3) ndarray
            Segment starts and vectors (end minus start), world space.

        Returns
        -------
        (k,) bool
        """
        if self.empty or len(o_wo) == 0:
            return np.zeros(len(o_wo), bool)
        return self.segment_hits_local(*self.pose.to_local(o_wo, d_wo), offset_wo, threads)

    def segment_hits_local(self, o_lo, d_lo, offset_wo=0.0, threads=1,
                           reach=None) -> np.ndarray:
        """:meth:`segment_hits` for segments already in the collider's space
        (``reach``: the reach a solver step set, for its own segments: see
        :meth:`set_reach`)."""
        if self.empty or len(o_lo) == 0:
            return np.zeros(len(o_lo), bool)
        return self.shells.hits_local(o_lo, d_lo, offset_wo, threads, reach)

    def segment_hit_details(self, o_wo, d_wo, offset_wo=0.0, faces=False, reach=None):
        """First hit of each segment: parameter, point and unit normal.

        Returns
        -------
        hit : (k,) bool
        t : (k,) float64
            Segment parameter of the hit in [0, 1] (inf for none).
        n_wo : (k, 3) float64
            Unit face normal (world), oriented as the shell that was hit.
        face : (k,) int64
            Only with ``faces=True``: the face hit (index into :attr:`faces`;
            for an offset shell, the face the shell's triangle is made of), -1
            for none.
        """
        k = len(o_wo)
        if self.empty or k == 0:
            out = np.zeros(k, bool), np.full(k, np.inf), np.zeros((k, 3))
            return (*out, np.full(k, -1, np.int64)) if faces else out
        return self.shells.hit_details(o_wo, d_wo, offset_wo, faces, reach)

    def contains(self, p_wo, offset_wo=0.0) -> np.ndarray:
        """Parity inside test (paper 3.1): more back faces than front faces.

        Three fixed directions vote, so a ray that grazes an edge cannot flip
        the answer. Always False for open or double-sided colliders.

        Parameters
        ----------
        p_wo : (k, 3) ndarray
            Points, world space.

        Returns
        -------
        (k,) bool
        """
        k = len(p_wo)
        if not self.detects_pinch or k == 0:
            return np.zeros(k, bool)
        p_wo = np.asarray(p_wo, np.float64)
        return self.contains_grid(p_wo, self.grid_coords(p_wo.T), offset_wo)

    def contains_grid(self, p_wo, q, offset_wo=0.0) -> np.ndarray:
        """:meth:`contains` with the points' :meth:`grid_coords` ``q`` given.

        Points in a grid cell no triangle of the tested shell touches share
        the answer of the cell's centre (the segment between them stays in
        the cell, so crosses nothing), computed once per cell and shape of
        the collider; the rest are traced. A collider whose shape stays
        (rigid: any motion) uses a fine grid whose touched cells are found
        from the triangles once per shape, so only roots right next to the
        surface are traced. A collider deformed since the last call at that
        offset, or made with ``deforming=True``, uses the coarse occupancy grid (no
        per-triangle work every frame): points near a vertex are traced. Both
        give the answer of tracing every point.
        """
        k = len(p_wo)
        if not self.detects_pinch or k == 0:
            return np.zeros(k, bool)
        return self.inside.contains_grid(p_wo, q, offset_wo)

    def closest_points(self, q_wo):
        """Closest point on the (un-inflated) mesh to each query and its normal.

        Parameters
        ----------
        q_wo : (k, 3) ndarray
            Query points, world space.

        Returns
        -------
        p_wo : (k, 3) float64
        n_wo : (k, 3) float64
            Unit face normal at the closest point.
        """
        k = len(q_wo)
        if self.empty or k == 0:
            return np.array(q_wo, np.float64), np.zeros((k, 3))
        return self.closest.closest_points(q_wo, self.pose, self.shells.normals_world)
