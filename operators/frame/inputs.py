"""A frame's inputs: the evaluated source read into numpy.

:func:`read_inputs` reads the evaluated source (world positions, offsets, per-curve
enable mask, parameter maps; moved by Fur Attach when it is on) into a
:class:`FrameInputs`; :func:`prepare_input` records the roots for jiggle and applies the
motion that runs before collision. The colliders are added when the frame is solved
(:func:`.colliders.read_for_solve`). What a cached frame was solved from is its
record (:mod:`.record`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...core import framecache
from ...core.pipeline.frame import before_collision
from ..blender import bridge
from ..settings import maps, motion
from .attach import attach_input
from .clock import clock


@dataclass
class FrameInputs:
    """One frame's input to :func:`solve.solve_frame`.

    Read from the evaluated scene by :func:`read_inputs`, or given by a script
    (``points``, ``offsets``, ``colliders`` and ``frame`` are enough).
    """

    points: np.ndarray  # world (P, 3) float32, after the motion before collision
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
    #: How the source draws its curves (``output.SourceSplines``; read by
    #: ``output.source_splines``). None: not read (a script: Catmull-Rom).
    splines: object = None

    def __post_init__(self):
        if self.raw is None:
            self.raw = self.points
        if self.key is None:
            self.key = framecache.topology_key(self.offsets)


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
                  warning=warning, maps=mapped)
    if s.use_fur_attach:  # the input stage: curves follow the evaluated growth surface
        att = attach_input(ob, depsgraph, offs, s.core_threads)
        world = np.asarray(att.points(), np.float32) if attach else None
        return FrameInputs(world, attached=att, **common)
    # Equal up to float noise: setting matrix_basis recomposes it from loc/rot/scale.
    local = P if np.allclose(M, M_out, rtol=1e-6, atol=1e-7) else None
    return FrameInputs(bridge.transform(P, M), local=local, **common)


def prepare_input(setup, inp) -> None:
    """Record the roots for jiggle and apply the motion that runs before collision
    (:func:`core.pipeline.frame.before_collision`)."""
    m, f, rt = motion.values(setup.motion), inp.frame, setup.rt
    if m.needs_history and f >= setup.s.frame_start:
        # (before the start frame the hair counts as at rest: frames viewed there
        # must not change a bake, which starts at the start frame)
        rt.history.record(f, inp.points[inp.offsets[:-1]])
    with clock.timing("motion"):
        moved = before_collision(m, inp.points, inp.offsets, f, setup.fps, rt.history,
                                 setup.s.core_threads)
    if moved is not None:
        inp.points = moved
        inp.local = None


def shown(obj, depsgraph) -> bool:
    """Is ``obj`` evaluated in ``depsgraph`` (not hidden from it)?"""
    return obj is not None and obj.evaluated_get(depsgraph).is_evaluated
