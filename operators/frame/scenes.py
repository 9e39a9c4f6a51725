"""A setup in the scenes its hair is in: solved in the one it belongs to, shown as groomed
in the others.

A hair object can be in several scenes (a character collection linked into several
shots) while its setup — settings, colliders, playback cache, bake and output object —
is one. The setup belongs to one scene (:func:`registry.owner`, recorded by Add
FurCollide; an older file's setup is adopted by the scene that holds its colliders, or
the first that evaluates or bakes it). :func:`evaluate` runs a frame of a setup in a
scene:

* in its own scene, the frame's spine (:func:`.spine.evaluate`) as always;
* in another scene, :func:`show_source`: the output shows the source as groomed (Fur
  Attach applied, nothing collides, no motion), the render groom follows it without
  the clearance pass, and nothing of the setup's cache, bake or status is read or
  changed. Its status there says where it belongs (:func:`registry.foreign_message`),
  and the operators that touch the cache or the bake refuse (``ops.common``).

Showing a scene (switching the window to it) runs the frame handler for it, so the
output follows the scene shown: the setup's own scene shows its cached or baked frame
again without anyone pressing anything.
"""

from __future__ import annotations

import numpy as np

from ..store import registry, report
from . import groom, output, rules, spine
from .inputs import read_inputs, shown
from .output import Shown
from .setup import Setup

#: What has been said in the console about a setup shown in another scene (one line
#: per distinct problem): setup key -> message.
_said: dict = {}


def evaluate(ob, scene, depsgraph):
    """Evaluate the frame of setup ``ob`` in ``scene``: the frame's spine where it
    belongs (recording that scene, :func:`registry.adopt`), else :func:`show_source`.
    Returns the frame's ``Outcome`` (None in another scene). Raises what the spine
    raises; never raises for another scene's setup."""
    if registry.belongs(ob, scene):
        registry.adopt(ob, scene)
        return spine.evaluate(Setup(ob, scene, depsgraph))
    try:
        show_source(ob, scene, depsgraph)
    except Exception as exc:  # noqa: BLE001 - the setup is not this scene's: only say it
        text = report.describe(exc)
        if _said.get(ob.name) != text:
            _said[ob.name] = text
            print(f"FurCollide '{ob.name}' in scene '{scene.name}': the source hair could "
                  f"not be shown: {text}", flush=True)
    return None


def show_source(ob, scene, depsgraph) -> bool:
    """Write the source of setup ``ob`` as groomed into its output, for ``scene``, a
    scene the setup does not belong to; True when written.

    The source as ``depsgraph`` evaluates it (with Fur Attach when it is on), every
    curve FREE; the render groom follows it without the clearance pass. Subframes keep
    the whole frame (as everywhere). Uses the setup's runtime for this scene
    (:func:`registry.foreign_runtime`); the setup's own runtime only forgets what it
    wrote into the outputs, so its scene writes them in full when shown again.
    """
    s = ob.furcollide
    if scene.frame_subframe != 0.0:
        return False
    rules.check_output(ob)
    if not shown(s.output, depsgraph) and not shown(s.groom.output, depsgraph):
        return False
    rt = registry.foreign_runtime(ob, scene)
    setup = Setup(ob, scene, depsgraph, rt)
    inp = read_inputs(setup)
    own = registry.get_runtime(ob, create=False)
    for r in (rt, own):  # both write into the same output data
        if r is not None:
            output.forget_written(r)
            groom.forget_written(r)
    written = output.show(setup, inp, Shown(inp.world(), np.zeros(len(inp.offsets) - 1, np.int8)),
                          sync=True)
    if s.groom.output is not None:
        groom.follow_unsolved(setup, written)
    _said.pop(ob.name, None)
    return True
