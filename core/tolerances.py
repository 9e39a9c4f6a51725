"""Every numerical tolerance of the core, in one place.

Distances relative to a scene are multiplied by that scene's size (the
diagonal of the collider's bounding box, or the curve's length), so the core
behaves the same in millimetres and in kilometres.
"""

#: Segment-triangle tests are done in float32 (embree). A hit at ray
#: parameter ``t`` in ``[0, 1 + T_SLACK]`` counts, so a segment that ends
#: *exactly* on a surface is a contact, not a miss.
T_SLACK = 1e-6

#: Re-cast offset (relative to the collider's size) used when counting every
#: crossing of a parity ray: the next cast starts this far past the last hit.
PARITY_STEP_REL = 1e-5

#: At most this many crossings are followed along one parity ray.
PARITY_MAX_HITS = 64

#: A triangle whose area is below ``DEGENERATE_AREA_REL * diag**2`` (``diag``
#: the collider's bounding box diagonal) is degenerate.
DEGENERATE_AREA_REL = 1e-14

#: A segment shorter than ``ZERO_SEGMENT_REL`` times its curve's length (or of
#: absolute length 0) is a zero-length segment and is rejected.
ZERO_SEGMENT_REL = 1e-9

#: Rotations below half a Rotation Precision step snap to exactly zero, so a
#: recovering curve reaches its input shape bit for bit.
SNAP_FRACTION = 0.5

#: A Stiff/Bend contact starts again from the input shape (new axis) when its
#: kept axis would turn it further by more than its whole angle plus this many
#: Rotation Precision steps (a collider pushing it back the other way, see
#: ``rigid.restart_contacts``), and only if the new contact moves its CVs less
#: than ``RESTART_GAIN`` times what turning further would.
RESTART_MIN_STEPS = 2
RESTART_GAIN = 0.9

#: A hit whose largest barycentric coordinate is within this of 1 lands on that
#: vertex: it pushes along the vertex's angle-weighted normal, not the normal of
#: whichever of the faces around it the rounding picked (``Collider.segment_hit_details``).
VERTEX_HIT_BARY = 1e-5

#: Below this |cross| (unit vectors) two directions count as parallel and a
#: fallback rotation axis is used.
PARALLEL_EPS = 1e-6

#: The curve's shape perpendicular (tip minus root, orthogonal to the root
#: segment) is trusted for the local frame when its length exceeds
#: ``FRAME_SHAPE_LO`` of the curve length, fully from ``FRAME_SHAPE_HI`` on;
#: in between the frame blends with the time-transported one (no pops).
FRAME_SHAPE_LO = 0.01
FRAME_SHAPE_HI = 0.05

#: Every tested segment is extended by this many float32 ulps of the scene's
#: coordinate magnitude: forward always, backward except the root segment.
#: A CV resting within rounding distance of a surface then counts as a
#: contact, so a curve reported clear is clear by a margin any float32 or
#: float64 segment test resolves (embree tests in float32).
RAY_EXTEND_ULPS = 32

#: Cells along the longest side of a collider's vertex occupancy grid (the
#: tight "can this curve touch the mesh" test).
OCCUPANCY_CELLS = 64

#: The inside test's per-cell answers use the occupancy grid's cells split
#: this many times per axis: a root in a cell no triangle touches takes its
#: cell's answer (computed once per collider shape), finer cells leave fewer
#: roots near a surface to trace.
INSIDE_SUBDIV = 2

#: Collision offset shells move each vertex so that every face around it
#: moves by the full offset (a vertex where faces meet at a sharp angle moves
#: farther than the offset), at most this many times the offset.
OFFSET_MAX_STRETCH = 4.0

#: Per-curve clearances (``Settings.collision_offset`` and
#: ``Settings.clearance_margin`` as parameter maps): each distinct distance a
#: collider must keep is one offset shell, i.e. one BVH built (every frame for
#: a deforming collider) and kept in memory. Up to this many distinct distances
#: are exact; more are rounded UP to at most this many levels (equal bins from
#: the smallest to the largest distance, each bin kept at the largest distance
#: asked in it: never less clearance than asked, at most an eighth of the
#: spread more). Eight bounds the builds and the BVH memory to what a few
#: colliders with their own offsets cost already, while a painted map's
#: gradient still comes out in steps no coarser than 1/8 of its range.
OFFSET_LEVELS = 8

#: Follow Collider Motion: a collider moves at a contact when its velocity
#: there, perpendicular to the hit segment, exceeds ``FOLLOW_SPEED_REL`` times
#: the curve's length per step (scale-free: the same in millimetres and
#: kilometres). Slower, it would take a thousand steps (40 s at 24 fps) to
#: move by one curve length: no visible motion to follow, and its direction is
#: then no more than the rounding of animated float32 transforms; the curve
#: takes the paper's direction instead.
FOLLOW_SPEED_REL = 1e-3

#: ... and exceeds this many float32 ulps of the contact point's coordinates:
#: Blender hands matrices and vertices over in float32, so a collider keyed to
#: stay put can still move by a few ulps from frame to frame (tiny curves far
#: from the origin would otherwise follow that noise).
FOLLOW_SPEED_ULPS = 64

#: Every collider keeps curves at least this many float32 ulps of its own
#: coordinates away (``Collider.margin``: the tested shell lies that far out
#: along the vertex normals, plus any Collision Offset). Embree tests in
#: float32 and the output is rounded to float32: a segment passing within
#: rounding distance of a sharp edge must not be clear for the solver and
#: crossing for a float64 test.
CLEARANCE_ULPS = 4

#: Rigid parts handed over as vertices (a hat skinned to one bone:
#: ``core.collider.pose``). New vertices that are, every used one to within this
#: many float32 ulps of the coordinates (of the largest of the collider's extent
#: and its largest coordinate, at rest and as placed, rounded up to a power of two,
#: as ``CLEARANCE_ULPS``), the collider's rest shape moved by one rigid transform
#: keep the rest shape's structures, placed by the fitted transform: no rebuild.
#: The shells are then built this much farther out (every face by it, as a
#: Collision Offset moves faces), so the fitted placement never lets a curve closer
#: to the true vertices than the clearance margin. They are grown by the fit's
#: residual rounded up to a power of two ulps, not by this tolerance: float32
#: skinning (a bone's float32 matrix times float32 vertices) leaves residuals under
#: one ulp (measured on make bench's hat, near the origin and 10,000 units away),
#: so the allowance is one ulp every frame and its shells are built once; growing
#: them by the whole tolerance (16 ulps, 3 cm 10,000 units away) kept curves
#: visibly farther than the rebuilt path. 16 leaves room for a chain of float32
#: bone matrices, while a deformation that moves a vertex by more than 4e-6 of the
#: largest coordinate (2e-5 is tested) is rebuilt. 0: no fit (every new shape is
#: built).
RIGID_FIT_ULPS = 16

#: The rigid fit's rotation is fitted to this many vertices spread over the
#: mesh (then checked on every vertex): a deforming collider is turned down by
#: the sample alone, for about a tenth of a millisecond.
RIGID_FIT_SAMPLE = 256

#: Collider vertices closer than this fraction of the mesh's bounding-box
#: diagonal are one vertex for its topology (closedness, windings): seams an
#: import left unwelded still close the mesh (``core.meshfix``).
WELD_REL = 1e-6

#: The fur pipeline's per-frame stages (``core.pipeline``) are computed with
#: bind-time caches and blocked component arrays: the same formulas in
#: another order of floating-point operations. Their results agree with the
#: straightforward implementations (kept in tests/pipeline/slow_reference.py)
#: to within ``PIPELINE_REORDER_REL`` times the scene's size (the largest
#: absolute coordinate plus the longest curve), i.e. a few float64 ulps.
PIPELINE_REORDER_REL = 1e-12

#: Fur Collider Distance (``core.pipeline.collider_distance``) is, by default,
#: a lower bound from a node field of each collider: exact distances at the
#: grid nodes within one cell of the mesh, a Euclidean transform beyond, and
#: 1-Lipschitz bounds between nodes. It is never above the true distance and
#: at most ``DISTANCE_FIELD_CELLS`` cells ``h`` below it (the field's cell: the
#: collider's median triangle size, halved until at most half the curves'
#: median segment length): 2 (sqrt(3) / 2 + 1) = 3.73 cells for a piece of a
#: segment (at most 2 cells long) from the nearest node, plus sqrt(3) cells
#: beyond the exact band. Measured: 1.3 cells below on average, 2.6 at most.
DISTANCE_FIELD_CELLS = 5.5

#: Fur Attach orients each curve by its triangle's frame (edge, normal). The
#: frame is undefined when the normal is shorter than ``ATTACH_FRAME_MIN_SIN``
#: times the triangle's longest edge squared (the sine of its smallest angle,
#: roughly, below 1e-12: float64 cannot tell the normal's direction): such a
#: face cannot be bound (with ``DEGENERATE_AREA_REL``'s faces, the only
#: degenerate-face rule), and a bound triangle that collapses below it later
#: keeps its reference frame.
ATTACH_FRAME_MIN_SIN = 1e-12

#: The render groom's root fits (``rotations.quat_fit``: Horn's quaternion, the
#: top eigenvector of a 4x4 matrix from the adjugate at its top eigenvalue)
#: are used where the adjugate's largest diagonal entry is at least
#: ``QUAT_FIT_GAP`` times the cube of the eigenvalue bound, i.e. where the top
#: eigenvalue stands clear of the others. There they agree with the SVD
#: (Kabsch) fit to within ~3e-14 (measured on 100,000 random and near-planar
#: neighbourhoods; 1e-12 at a tenth of this gap, 1e-11 at a hundredth); the
#: other ~1 % of fits (nearly collinear neighbourhoods, fits that do not fix
#: a rotation) use the SVD.
QUAT_FIT_GAP = 3e-2

#: Newton steps on the characteristic polynomial at most; a fit that has
#: not converged by then uses the SVD.
QUAT_FIT_ITERS = 64

#: A root fit is used only if ``|N q - lambda q|`` is at most this times the
#: eigenvalue bound (correct fits: ~1e-15); otherwise the SVD.
QUAT_FIT_RESIDUAL = 1e-12

#: Spline margins (``splines.clearance_margin``) below this fraction of a curve's
#: longest segment are float noise of a straight curve (float32 points give second
#: differences of ~1e-7 of a segment), not curvature: they count as 0, so straight
#: Catmull-Rom hair solved Stiff keeps the plain (offset 0) collider path.
SPLINE_MARGIN_NOISE = 1e-5

#: Spline margins are rounded UP onto a geometric grid of this many steps per
#: decade (``splines.quantized``: at most 10^(1/16) - 1 = 15 % above the bound). A
#: margin follows the frame's curves; on the grid, an animated groom whose bound
#: moves by a few ulps keeps its value, so the offset shells it selects are not
#: rebuilt every frame.
SPLINE_MARGIN_STEPS = 16

#: Relative widening of a spline margin's cheap upper bound (``splines._hermite_upper``)
#: over the float rounding of it and of the exact bound (both ~1e-15 relative).
SPLINE_BOUND_SLACK = 1e-9

# ------------------------------------------------------------------------------
# Thresholds of work. Each decides between two ways of computing the same thing
# (two threads or one, one structure or another): only the time depends on them,
# never a result (the tests force each way and compare the bits).

#: A step solves its curves in parts, one per thread (two halves on two
#: threads; on more, parts of at least half this many curves: ``core.rays.
#: split_count``), from this many curves of work (``StepContext.in_halves``):
#: in Soft every curve solved; in Stiff/Bend, by phase, the unrotated curves
#: near a collider (tested at their input shape) and the curves searched
#: (rotated ones near a collider, new contacts). Curves are independent, so
#: each part gives the curves what the whole would, bit for bit; the parts'
#: numpy passes and ray queries overlap (both release the GIL). Below it the
#: per-call overhead of twice the numpy calls costs more than the overlap
#: gains. Measured A/B in one process (``make bench``, 24 frames): Bend under
#: the orbiting ellipsoid (7,300 tested, 3,000 searched: only the test split)
#: 39.5 ms, 38-39 split at this threshold, 46 with every phase split; under the
#: hat (15,000 searched) 83-89 -> 79-84 ms; Soft 87-93 -> 75-78 and 201-210 ->
#: 140-155 ms; the render groom's clearance pass (a fresh solver: all new
#: contacts) 72 -> 65 ms.
SPLIT_MIN_CURVES = 4096

#: Per-frame stages of the fur pipeline (Fur Attach, the render groom's
#: deformation, wind) run in parts, one per thread (two halves on two threads,
#: parts of at least half this many items on more: ``core.rays.in_two``) from
#: this many items (curves, guides). The items are independent, so the
#: halves give what the whole gives, bit for bit; their long numpy passes
#: release the GIL and overlap. Below it the halves' own overhead (a hand-over
#: to the ray pool, twice the numpy calls) is more than they save. Measured (2
#: cores, 50,000 render curves, 7,500 guides): the groom's blend 35 -> 21 ms,
#: Fur Attach 9.8 -> 5.7 ms. (The guides' root fits, 2.3 ms of short passes,
#: stay on one thread: two only interleave them.)
SPLIT_MIN_ITEMS = 2048

#: Below this many rays per thread a ray batch is not split over threads
#: (``core.rays``: the hand-over costs more than the rays).
MIN_RAYS_PER_THREAD = 4096

#: The render groom's clearance pass gathers the curves that may touch a
#: collider into a curve set of their own; above this share of all curves it
#: solves them all instead (gathering would cost more than it saves).
CLEARANCE_SOLVE_ALL = 0.7

#: Fur Collider Distance: segments whose search box spans more grid cells than
#: this take the lower-bound path (they are far from the collider compared to
#: the cells).
DISTANCE_MAX_CELLS = 512

#: Fur Collider Distance: node fields (the default, fast path) have at most
#: this many nodes; a collider that would need more (huge next to the curves)
#: takes the exact search.
DISTANCE_NODE_MAX = 1 << 23

#: Closest points on a mesh: a query whose search box grows past this many
#: cells continues on a coarser grid.
CLOSEST_MAX_CELLS = 512

#: Triangle grids (``core.proximity``): triangles spanning more grid cells than
#: this are tested by every search instead of being listed in their cells.
GRID_BIG_CELLS = 4096

#: Triangle grids with at most this many cells get a dense cell -> triangles
#: lookup (a sorted search above it).
GRID_DENSE_CELLS = 1 << 23

#: ``splines.largest_margin`` measures in full this many curves of the largest upper
#: bounds first (their largest margin is the bar every other curve's bound must pass to
#: be measured); grooms of at most four times as many curves are measured whole.
SPLINE_MARGIN_SEEDS = 64

# ------------------------------------------------------------------------------
# Tolerances of the fur pipeline and the mesh repairs.

#: Fur Collider Distance: a collider matrix whose singular values agree to this
#: (relative) is a rotation and uniform scale (float32 rounding of a Blender
#: matrix included): distances in the collider's space scale to world units.
SIMILARITY_REL = 1e-5

#: Above this many closed parts (a scatter of pebbles) ``core.meshfix`` does not
#: look for parts nested in others: every closed part faces outward.
NEST_MAX_PARTS = 64

#: Reachable-part builds (``Collider.set_reach``): a deforming collider without an
#: inside test (open, or double-sided) builds, every frame, only the triangles near what
#: the curves can reach. Its shell's triangles are cut, once per topology, into runs of
#: this many triangles (along a walk in space over its rest shape, else in face order:
#: ``Shells.chunks``; one Embree geometry each, prepared once); a frame builds the runs
#: whose box meets the reach.
REACH_CHUNK_FACES = 1024
#: A reachable part is built only when it leaves out at least this fraction of the
#: shell's triangles (else the whole shell is, as for any collider).
REACH_MIN_SAVING = 0.25
#: The reach (the curves' roots grown by their lengths) is rounded out to a grid of
#: cubes ``1 / REACH_GRID`` of the collider's largest side, so the solvers of one frame
#: (guides, render groom) mostly ask for the same part and share its build.
REACH_GRID = 16
#: The reach is grown by this fraction of its size before rounding (room for the
#: rays' own slack; a ray leaving the reach is traced against the whole shell).
REACH_GROW_REL = 0.02
