"""A setup as one evaluation sees it (:class:`Setup`).

A FurCollide *setup* lives on its source hair object (``ob.furcollide``, see
:mod:`..settings.properties`) and writes into its output hair object. Every step of a
frame takes one :class:`Setup`: the source, its session state
(:class:`..store.registry.Runtime`), the scene being evaluated and its depsgraph.
"""

from __future__ import annotations

from ...core.pipeline.frame import RootHistory
from ..settings import motion
from ..store import registry


class Setup:
    """One setup (source object ``ob``) as one evaluation of ``scene`` sees it.

    Parameters
    ----------
    ob : bpy.types.Object
        The source hair object.
    scene : bpy.types.Scene
        The scene being evaluated (its ``frame_current`` / ``frame_subframe``).
    depsgraph : bpy.types.Depsgraph
        Its evaluated depsgraph (viewport or render) the inputs are read from.
    rt : registry.Runtime, optional
        The setup's session state (default: the registry's, created on first use).

    Attributes
    ----------
    s : FurCollideSettings
        The setup's properties (``ob.furcollide``).
    frame : int
        The frame evaluated (``scene.frame_current`` when the setup was made).
    subframe : float
        Its subframe (``scene.frame_subframe``).

    Nothing else is kept on it: the steps of a frame pass what they made on.
    """

    __slots__ = ("ob", "rt", "scene", "depsgraph", "s", "frame", "subframe")

    def __init__(self, ob, scene, depsgraph, rt=None):
        self.ob = ob
        self.scene = scene
        self.depsgraph = depsgraph
        self.rt = registry.get_runtime(ob) if rt is None else rt
        self.s = ob.furcollide
        self.frame = scene.frame_current
        self.subframe = scene.frame_subframe

    @property
    def solver(self):
        """The core Solver (:func:`.solve.ensure_solver` builds it)."""
        return self.rt.solve.solver

    @property
    def history(self) -> RootHistory:
        """The roots of the frames seen (jiggle)."""
        return self.rt.solve.history

    @property
    def motion(self):
        """The motion settings (wind, jiggle, Region of Influence, distance attribute)."""
        return self.ob.furcollide.motion

    @property
    def fps(self) -> float:
        return motion.fps(self.scene)
