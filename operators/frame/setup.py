"""A setup as one evaluation sees it (:class:`Setup`).

A FurCollide *setup* lives on its source hair object (``ob.furcollide``, see
:mod:`..settings.properties`) and writes into its output hair object. Every step of a
frame takes one :class:`Setup`: the source, its session state
(:class:`..store.registry.Runtime`), the scene being evaluated and its depsgraph.
"""

from __future__ import annotations

from ... import core
from ...core import framecache
from ...core.pipeline.frame import RootHistory
from ..settings import motion
from ..settings.fingerprints import core_settings, signature, structure, time_key
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
    baked : framecache.ShownFrame or None
        The baked frame this evaluation shows, as read from its file (the render groom
        stage takes its part from it instead of reading the file again).
    """

    __slots__ = ("ob", "rt", "scene", "depsgraph", "baked")

    def __init__(self, ob, scene, depsgraph, rt=None):
        self.ob = ob
        self.scene = scene
        self.depsgraph = depsgraph
        self.rt = registry.get_runtime(ob) if rt is None else rt
        self.baked = None

    @property
    def s(self):
        """The setup's properties (``ob.furcollide``)."""
        return self.ob.furcollide

    @property
    def frame(self) -> int:
        return self.scene.frame_current

    @property
    def subframe(self) -> float:
        return self.scene.frame_subframe

    @property
    def solver(self):
        """The core Solver (:meth:`ensure_solver` builds it)."""
        return self.rt.solver

    @property
    def history(self) -> RootHistory:
        """The roots of the frames seen (jiggle)."""
        return self.rt.history

    @property
    def motion(self):
        """The motion settings (wind, jiggle, Region of Influence, distance attribute)."""
        return self.ob.furcollide.motion

    @property
    def fps(self) -> float:
        return motion.fps(self.scene)

    def settings(self, maps=None):
        """core.Settings for the setup's properties (raises SettingsError), with the
        frame's parameter ``maps`` (setting name -> (C,) values) in."""
        return core_settings(self.ob, maps)

    def signature(self, identities=True) -> str:
        """:func:`signature` in the scene being evaluated."""
        return signature(self.ob, scene=self.scene, identities=identities)

    def structure(self, identities=True) -> str:
        """:func:`structure` in the scene being evaluated."""
        return structure(self.ob, scene=self.scene, identities=identities)

    def time_key(self):
        """:func:`time_key` in the scene being evaluated."""
        return time_key(self.ob, self.scene)

    def ensure_solver(self, inputs):
        """The core Solver for the curves of ``inputs`` and the current settings.

        Built for the runtime's topology (a new curve layout forgets the solver:
        :meth:`registry.Runtime.adopt_topology`); a settings change is applied to it
        (a mode change resets it: its state is unknown then).
        """
        rt = self.rt
        settings = self.settings(inputs.maps)
        if rt.solver is None:
            rt.solver = core.Solver(inputs.offsets, settings)
            rt.solver_frame = None
            rt.memory.sparse = framecache.SparseState(rt.solver.state)
        elif rt.solver.settings != settings:
            if rt.solver.settings.mode != settings.mode:
                rt.solver_frame = None  # the solver resets on a mode change
            rt.solver.settings = settings
        return rt.solver

    def set_status(self, level: str, message: str) -> None:
        registry.set_status(self.ob, level, message)
