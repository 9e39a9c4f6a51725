"""A frame's inputs: the evaluated source read into numpy.

:func:`read_inputs` reads the evaluated source (world positions, offsets, per-curve
enable mask, parameter maps; moved by Fur Attach when it is on) into a
:class:`FrameInputs`; :func:`prepare_input` records the roots for jiggle and applies the
motion that runs before collision. The colliders are added when the frame is solved
(:func:`.colliders.read_for_solve`). What a cached frame was solved from is its
record (:mod:`.record`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ...core import framecache, splines
from ...core.pipeline.frame import Motion, before_collision
from ..blender import bridge
from ..settings import maps, motion
from ..settings.fingerprints import SettingsRead, read_settings
from . import solve
from .attach import attach_input
from .clock import clock


@dataclass
class FrameInputs:
    """One frame's input to :func:`solve.solve_frame`.

    Read from the evaluated scene by :func:`read_inputs`, or given by a script
    (``points``, ``offsets``, ``colliders`` and ``frame`` are enough).
    """

    #: World (P, 3) float32, after the motion before collision; None when read with
    #: ``attach=False`` under Fur Attach, or not yet computed from ``source_local`` and
    #: ``source_matrix`` (:meth:`world` computes it: a cached frame shown never needs it).
    points: np.ndarray | None
    offsets: np.ndarray  # (C+1,) int32
    enabled: np.ndarray | None = None  # (C,) bool per-curve enable mask (None: all)
    frame: int = 0
    colliders: list = field(default_factory=list)  # core Colliders (read when solved)
    growth: object = None  # core Collider of the growth surface, when the solve reads it
    #: The source's curve layout (``framecache.topology_key``; computed when not given).
    key: tuple | None = None
    #: The input before motion (the caches store the result relative to it, so a
    #: cached frame never needs the motion again); ``points`` when there is none.
    raw: np.ndarray | None = None
    m_out_inv: np.ndarray | None = None  # world -> output's local space
    warning: str = ""  # the enable attribute cannot be used (the status says why)
    #: The source's own local positions when the output has the same world matrix
    #: (the usual case): unchanged points are written back from here, untouched.
    local: np.ndarray | None = None
    #: Fur Attach's input (``attach.AttachInput``) when it is on: ``points`` are
    #: its attached points (None when read with ``attach=False``: a baked frame shown).
    attached: object = None
    #: Parameter maps at this frame: setting name -> (C,) values (:func:`maps.read_maps`).
    maps: dict = field(default_factory=dict)
    #: How the source draws its curves (:class:`SourceSplines`, read with the source).
    #: None: not read (a script: Catmull-Rom).
    splines: object = None
    #: The source's own positions (P, 3) float32 and world matrix (4, 4) they were read
    #: with (without Fur Attach): the world input is ``bridge.transform`` of them, and
    #: the frame-inputs record digests them (part ``source local``).
    source_local: np.ndarray | None = None
    source_matrix: np.ndarray | None = None
    #: The setup's :class:`InputState`: the world positions last computed, reused while
    #: the source's own positions and matrix stay the same (None: always computed).
    state: object = None
    #: What is made of the source on first use (its digest, its world positions),
    #: shared by the copies of these inputs (``dataclasses.replace`` passes it on).
    _made: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        if self.raw is None and self.points is not None:
            self.raw = self.points
        if self.key is None:
            self.key = framecache.topology_key(self.offsets)

    @property
    def has_points(self) -> bool:
        """Were the world positions read (or can they be made: :meth:`world`)?"""
        return self.points is not None or self.source_local is not None

    def source_digest(self) -> int:
        """64-bit digest of the source's own positions, offsets and world matrix (what
        the world input is made of; computed once)."""
        made = self._made
        if "digest" not in made:
            made["digest"] = framecache.digest(self.source_local, self.offsets,
                                               self.source_matrix)
        return made["digest"]

    def _source_world(self) -> np.ndarray:
        """The source's world positions (before any motion), made once for these inputs
        and their copies: a copy of the last ones the setup made when the source's own
        positions and matrix are the same (a static groom, grass: the same bits, a copy
        being cheaper than the product), else transformed."""
        made = self._made
        if "world" not in made:
            # (at the origin the world positions are the source's own: nothing to keep)
            keep = self.state is not None and not bridge.is_identity(self.source_matrix)
            last = self.state.world if keep else None
            if last is not None and last[0] == self.source_digest():
                made["world"] = last[1].copy()  # (a copy: whoever gets it may write in it)
            else:
                made["world"] = bridge.transform(self.source_local, self.source_matrix)
                if keep:
                    self.state.world = (self.source_digest(), made["world"].copy())
        return made["world"]

    def world(self) -> np.ndarray:
        """The world positions ``points``, made from the source's own positions on
        first use (a frame that only shows a cached one never transforms them)."""
        if self.points is None and self.source_local is not None:
            self.points = self._source_world()
        return self.points

    def before_motion(self) -> np.ndarray:
        """The world positions before the motion before collision (``raw``)."""
        if self.raw is None:
            self.raw = self._source_world() if self.source_local is not None else self.points
        return self.raw


@dataclass(slots=True)
class InputState:
    """The part of a setup's runtime owned here: the source's world positions last
    computed, as ``(FrameInputs.source_digest, (P, 3) float32)`` (None: none yet)."""

    world: tuple | None = None


@dataclass
class SourceSplines:
    """How the evaluated source draws its curves, as one frame reads it.

    Attributes
    ----------
    world : core.splines.Splines
        Types, NURBS data and Bezier handles, the handles in world space.
    points : (P, 3) float32 ndarray or None
        The source's world polygon the handles go with (Bezier only); the frame's
        input when neither Fur Attach nor motion moved it.
    left_local, right_local : (P, 3) float32 ndarrays or None
        The source's own handles (local space): written back as they are where the
        output sits on the source and a curve was not moved.
    """

    world: splines.Splines
    points: np.ndarray | None = None
    left_local: np.ndarray | None = None
    right_local: np.ndarray | None = None

    @property
    def has_handles(self) -> bool:
        return self.points is not None

    def at(self, points, offsets) -> splines.Splines:
        """The splines with the handles moved onto the polygon ``points`` (world)."""
        sp = self.world
        if not self.has_handles or points is self.points or np.array_equal(points, self.points):
            return sp
        return sp.with_handles(*splines.moved_handles(self.points, points, offsets,
                                                      sp.handle_left, sp.handle_right))


def source_splines(src, local=None) -> SourceSplines:
    """How the evaluated source ``src`` draws its curves (read once per frame).

    ``local``: its local positions (P, 3), when read already."""
    data = src.data
    sp = bridge.read_splines(data)
    out = SourceSplines(sp)
    if sp.has(splines.BEZIER) and sp.handle_left is not None and sp.handle_right is not None:
        M = bridge.matrix(src)
        local = local if local is not None else bridge.get_positions(data)
        # (as read_inputs transforms them: bit for bit ``inputs.raw`` without Fur Attach)
        out.points = bridge.transform(local, M)
        out.left_local, out.right_local = sp.handle_left, sp.handle_right
        sp.handle_left = bridge.transform(sp.handle_left, M).astype(np.float64)
        sp.handle_right = bridge.transform(sp.handle_right, M).astype(np.float64)
    return out



def read_inputs(setup, attach=True) -> FrameInputs:
    """Evaluated source positions (world), offsets, enable mask.

    With Fur Attach on, ``attach=False`` checks the binding and reads the Surface
    (``FrameInputs.attached``) but leaves ``points`` None: the frame-inputs record
    needs only the Surface (:func:`frame_inputs`), so a baked frame shown, or an edit
    check, never moves the curves.
    """
    ob, depsgraph = setup.ob, setup.depsgraph
    s = ob.furcollide
    src = ob.evaluated_get(depsgraph)
    if not src.is_evaluated:
        raise RuntimeError("the source is not evaluated in this depsgraph")
    data = src.data
    offs = bridge.curve_offsets(data)
    key = framecache.topology_key(offs)
    P = bridge.get_positions(data)
    M = bridge.matrix(src)
    out = s.output.evaluated_get(depsgraph)
    M_out = bridge.matrix(out)
    mask, warning = bridge.read_curve_mask(data, s.enable_attribute, len(offs) - 1)
    mapped, map_warnings = maps.read_maps(data, s, offs)
    warning = "; ".join(w for w in (warning, *map_warnings) if w)
    M_out_inv = bridge.matrix(out, inverted=True)
    common = dict(offsets=offs, enabled=mask, frame=setup.frame, key=key, m_out_inv=M_out_inv,
                  warning=warning, maps=mapped, splines=source_splines(src, P))
    if s.use_fur_attach:  # the input stage: curves follow the evaluated growth surface
        att = attach_input(ob, depsgraph, offs, s.core_threads)
        world = np.asarray(att.points(), np.float32) if attach else None
        return FrameInputs(world, attached=att, **common)
    # Equal up to float noise: setting matrix_basis recomposes it from loc/rot/scale.
    local = P if np.allclose(M, M_out, rtol=1e-6, atol=1e-7) else None
    # (world positions on first use: a cached frame shown needs none, see FrameInputs.world)
    return FrameInputs(None, local=local, source_local=P, source_matrix=M,
                       state=setup.rt.inputs, **common)


def prepare_input(setup, inp, m) -> FrameInputs:
    """``inp`` after the motion that runs before collision
    (:func:`core.pipeline.frame.before_collision`, ``m``: the motion settings as
    :func:`..settings.motion.values` reads them), the roots recorded for jiggle first."""
    if not m.active:  # (nothing moves the curves nor needs their roots)
        return inp
    f = inp.frame
    if m.needs_history and f >= setup.s.frame_start:
        # (before the start frame the hair counts as at rest: frames viewed there
        # must not change a bake, which starts at the start frame)
        solve.record_roots(setup.rt, f, inp.world()[inp.offsets[:-1]])
    with clock.timing("motion"):
        moved = before_collision(m, inp.world(), inp.offsets, f, setup.fps, setup.history,
                                 setup.s.core_threads)
    return inp if moved is None else replace(inp, points=moved, local=None)


@dataclass(frozen=True)
class FrameRead:
    """What one evaluation of a setup's frame reads, once (:func:`read_frame`): the
    evaluated source (``inputs``), the settings (``settings``: colliders listed, keyable
    values, fingerprints) and the motion settings as plain values (``motion``)."""

    inputs: FrameInputs
    settings: SettingsRead
    motion: Motion


def read_frame(setup, attach=True) -> FrameRead:
    """Read the frame of ``setup`` once (:func:`read_inputs`, ``attach`` as there)."""
    return FrameRead(read_inputs(setup, attach), read_settings(setup.ob, setup.scene),
                     motion.values(setup.motion))


def shown(obj, depsgraph) -> bool:
    """Is ``obj`` evaluated in ``depsgraph`` (not hidden from it)?"""
    return obj is not None and obj.evaluated_get(depsgraph).is_evaluated
