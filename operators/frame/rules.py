"""The frame rules: what a setup's frame shows, and why. A decision that writes nothing.

Frame rules (``frame_change_post``; see README "Using it in Blender"):

* subframes (motion blur) never step: the output keeps the whole frame (a bake
  blends its two neighbouring baked frames);
* ``f == frame_start``: reset the solver and solve;
* ``f`` cached (memory, or disk when baked) and its inputs still hold: show it, bit
  for bit; its inputs changed: solve it again at the start frame; solve it again from
  ``f - 1`` when only objects the depsgraph reported while an earlier frame held
  changed (a key moved ahead: :func:`_key_moved_ahead`); else mark the setup outdated
  and drop the playback cache;
* ``f - 1`` cached with today's settings and colliders: restore its solver state if
  needed and step (other settings: the playback cache is dropped, as any change does);
* otherwise (jump ahead, a dropped cache): hold the newest cached frame, mark outdated;
* ``f < frame_start``: the output follows the source; ``f > frame_end``:
  the end frame is held.

Each rule is a function of the frame as read once (:class:`.inputs.FrameRead`) and of
what the session holds (the playback cache, the solver's frame), and returns a
:class:`Decision`: what the output shows, the status and why, the cached frames to
drop, whether to solve and from where. The spine (:mod:`.spine`) applies it: drops,
solve, one write of the output, one status. A drop can change what the rules see (a
frame no longer cached): the spine then asks them again (:attr:`Decision.then`).
"""

from __future__ import annotations

import enum
import os
from dataclasses import dataclass

import bpy
import numpy as np

from ...core import framecache
from ...core.pipeline.frame import frame_stats
from ..blender import bridge
from ..settings import keyed
from ..settings.fingerprints import structure_change
from ..store import baked
from . import topology
from .colliders import collider_note, surface_as_collider
from .inputs import FrameInputs, shown, source_splines
from .output import Shown
from .record import (
    baked_frame_change,
    cached_frame_change,
    changed_objects,
    first_changed_frame,
    fixed_change,
)


class Outcome(enum.Enum):
    """What a frame of a setup did (:func:`.spine.evaluate`)."""

    RESET = "reset"  #: the start frame, solved from the groomed shape
    STEP = "step"  #: solved one step from the previous frame's state
    CACHE = "cache"  #: a memory-cached frame shown
    BAKE = "bake"  #: a baked frame shown (or the newest one before it, when missing)
    HOLD = "hold"  #: after the end frame: the end frame held
    OUTDATED = "outdated"  #: not solvable (jump ahead, changed inputs): a frame held
    PASSTHROUGH = "passthrough"  #: disabled or before the start: the output follows
    SUBFRAME = "subframe"  #: a motion-blur subframe (never steps; a bake blends)
    TOPOLOGY = "topology"  #: the source's curves changed: nothing written
    BAKING = "baking"  #: this setup's bake is running (it writes the frames)
    HIDDEN = "hidden"  #: no output of the setup is in this depsgraph


#: :attr:`Decision.status` of a frame whose status is its note: the input warning, or
#: what the frame shown says (INVALID curves, the colliders): :func:`frame_note`.
NOTE = "note"


@dataclass(frozen=True)
class Drop:
    """Cached frames a decision drops (applied through the runtime's drop methods).

    ``kind``: ``"cache"`` (every frame, as Blender's point cache on a change), ``"from"``
    (the frames from ``frame`` on), ``"after"`` (the frames after ``frame``),
    ``"restart"`` (the start frame ``frame`` is solved again: the cache starts over).
    ``why``: the change, seen at the frame evaluated; ``since``: how the status names
    it afterwards (the frames that are not cached say it); ``colliders``: the core
    Colliders are forgotten too (which objects collide changed)."""

    kind: str
    frame: int = 0
    why: str = ""
    since: str = ""
    colliders: bool = False


@dataclass(frozen=True)
class Decision:
    """What a setup's frame does (:func:`decide`).

    Attributes
    ----------
    outcome : Outcome
    show : str or None
        What the output shows: ``"source"`` (the frame's input), ``"memory"`` (cached
        frame :attr:`frame`), ``"hold"`` (the newest frame held), ``"baked"`` (the baked
        frame in :attr:`baked`), ``"shown"`` (:attr:`shown`, made here), ``"solve"`` (the
        frame solved), or None: the output keeps what it shows.
    frame : int or None
        The frame shown (``"memory"``, ``"hold"``, ``"baked"``).
    status : (str, str) or str or None
        ``(level, message)``, :data:`NOTE`, or None: the status stays as it is.
    outdated : bool or None
        Whether the frame shown is outdated (None: unchanged).
    drops : tuple of Drop
    then : str or None
        The drops change what the rules see: once they are applied, ``"decide"``
        again (:func:`decide`), or ``"hold"`` (:func:`hold`).
    start : str or None
        How a frame to solve starts: ``"reset"`` (from the groomed shape) or ``"step"``
        (from frame ``f - 1``'s state).
    keep_hold : bool
        What is shown becomes the frame held after the end and on a jump ahead.
    stats : dict or None
        The statistics of the frame shown (None: unchanged).
    record : dict or None
        The frame's inputs record, when the rules made it (the frame handler's seen).
    baked : framecache.ShownFrame or None
    shown : output.Shown or None
    inputs : inputs.FrameInputs or None
        What ``shown`` is written with, when not the frame's own input.
    """

    outcome: Outcome
    show: str | None = None
    frame: int | None = None
    status: tuple | str | None = None
    outdated: bool | None = None
    drops: tuple = ()
    then: str | None = None
    start: str | None = None
    keep_hold: bool = False
    stats: dict | None = None
    record: dict | None = None
    baked: object = None
    shown: object = None
    inputs: object = None


# ------------------------------------------------------------ before reading
def not_evaluated(setup) -> Decision | None:
    """The decision when the frame is not evaluated at all (a bake runs, the outputs
    are hidden from this depsgraph, a subframe), else None. Raises ValueError when the
    output must not be written (:func:`check_output`)."""
    s = setup.s
    check_output(setup.ob)
    if setup.rt.baking:
        return Decision(Outcome.BAKING)
    if not shown(s.output, setup.depsgraph) and not shown(s.groom.output, setup.depsgraph):
        # Nothing of this setup is in this depsgraph (its outputs are hidden from
        # it, e.g. from the render): nothing to show, so nothing to compute or to
        # report (its source is usually hidden too).
        return Decision(Outcome.HIDDEN)
    if setup.subframe != 0.0:
        # Never step on subframes (motion blur). A bake is blended between its
        # whole frames; otherwise the output keeps the whole frame.
        if s.is_baked and s.enabled:
            return _baked_subframe(setup)
        return Decision(Outcome.SUBFRAME)
    return None


def check_output(ob) -> None:
    """Raise ValueError when FurCollide must not write into the setup's output."""
    s = ob.furcollide
    if s.output is None:
        raise ValueError("the output hair object is missing: remove the setup and add it again")
    if s.output == ob or not s.output.furcollide.is_output:
        raise ValueError(
            f"'{s.output.name}' is not a FurCollide output: FurCollide only writes into "
            "the output object it created (remove the setup and add it again)"
        )
    if s.output.furcollide.source != ob:
        raise ValueError(
            f"this object is a copy of the setup on '{_owner_name(s.output)}': "
            "use Add FurCollide to give it its own output"
        )
    if problem := bridge.write_refusal(s.output, "output"):
        raise ValueError(problem)


def passes_through(setup) -> bool:
    """Does the frame show the source as it is (the setup disabled, or before its
    Frame Start)? The first of the frame rules: a bake is shown only after it."""
    s = setup.s
    return not s.enabled or setup.frame < s.frame_start


def starts_here(setup, animation=None) -> bool:
    """Does the frame solve from the groomed shape: the start frame, or the first frame
    after frames where the setup's Enabled (keyed) was off? (Disabled frames show the
    source; the fur starts again from its groom when it is turned on.) ``animation``:
    the setup's :class:`keyed.Animation`, when made already."""
    f, s = setup.frame, setup.s
    if f == s.frame_start:
        return True
    if f < s.frame_start:
        return False
    if animation is None:
        return keyed.setup_value(setup.ob, "enabled", f - 1) is False
    return animation.value(s, "furcollide", "enabled", None, f - 1) is False


def syncs(setup, outcome) -> bool:
    """Does the output's curve layout follow the source's before the frame is shown?
    Always, but when a baked setup shows anything else than its bake or its source."""
    return not setup.s.is_baked or outcome in (Outcome.PASSTHROUGH, Outcome.BAKE)


# ------------------------------------------------------------ since last seen
@dataclass(frozen=True)
class Changes:
    """What changed without an update callback since the frame handler last saw the
    setup (:func:`since_seen`): the drops to apply before the frame's motion
    (``before``) and after it (``after``), and the topology decision (None: the curves
    are the ones the cache belongs to, or are adopted: ``adopt``)."""

    before: tuple = ()
    adopt: tuple | None = None
    topology: Decision | None = None
    after: tuple = ()


def since_seen(setup, read) -> Changes:
    """The changes made without an update callback (undo, a driver, a deleted
    collider) that drop cached frames, and the source's curve layout checked.

    Fur Attach toggled or rebound, or the frame rate changed (wind and jiggle run on
    seconds): every cached frame's input changed. What every frame shares changed
    (``structure``: a collider deleted, undo): like any such change, it drops the
    playback cache (the keyable values are inputs of each frame: their records say
    when they hold). A baked setup's bake is never dropped here."""
    s, rt = setup.s, setup.rt
    inp, sr = read.inputs, read.settings
    before = []
    if not s.is_baked:
        att = (bool(s.use_fur_attach), s.attach_id if s.use_fur_attach else "")
        if rt.seen.attach is not None and att != rt.seen.attach:
            before.append(Drop("cache", why="Fur Attach changed"))
        tk = sr.time_key
        if None not in (tk, rt.seen.time) and tk != rt.seen.time:
            before.append(Drop("cache", why="the frame rate changed"))
    adopt, decision = _topology(setup, inp)
    after = []
    signature = None if before else rt.seen.structure  # (a drop accepts the new structure)
    if signature is not None and sr.structure != signature and not s.is_baked:
        after.append(Drop("cache", why=structure_change(signature, sr.structure),
                          colliders=True))
    return Changes(tuple(before), adopt, decision, tuple(after))


def _topology(setup, inp):
    """(the curve layout to adopt or None, the TOPOLOGY decision or None): the source's
    curves against those the cached frames, the solver and the jiggle history belong
    to. Other curves with nothing cached are adopted (the held frame forgotten);
    otherwise the status says what changed and what to press, and the output follows
    the source (a bake's frame stays)."""
    rt, s = setup.rt, setup.s
    if rt.solve.topology is None or rt.solve.topology == inp.key:
        return inp.key, None
    if len(rt.cache.memory) == 0 and not s.is_baked:
        return inp.key, None
    old, new = rt.solve.topology, inp.key
    if bridge.is_render(setup.depsgraph):
        # The viewport still has the curves the frames were solved for: a modifier
        # evaluates the source otherwise for renders. Reset would change nothing.
        status = ("ERROR",
                  f"'{setup.ob.name}' has other curves in this render ({new[0]} curves / "
                  f"{new[1]} points) than in the viewport ({old[0]} / {old[1]}): a modifier "
                  "evaluates it otherwise for renders (e.g. Interpolate Hair Curves' "
                  "Viewport Amount, an Is Viewport switch). The render shows the viewport's "
                  "curves: make the source the same in both, or collide the dense hair as "
                  "a Render Groom.")
        return None, Decision(Outcome.TOPOLOGY, status=status)
    what = "bake" if s.is_baked else "cached frames"
    status = ("ERROR", topology.topology_message(setup.ob, old, new, what, s.frame_start))
    # Never left frozen while marked current: the output is outdated and, playing,
    # follows the source (its roots on the skin), not collided (a bake's frame stays).
    source = not s.is_baked and inp.has_points
    return None, Decision(Outcome.TOPOLOGY, show="source" if source else None, status=status,
                          outdated=True)


# ------------------------------------------------------------------ decide
def decide(setup, read, record=None) -> Decision:
    """The frame rules (module docstring) for the frame of ``setup`` read as ``read``
    (:class:`.inputs.FrameRead`, motion before collision applied). ``record``: the
    frame's inputs record, when an earlier decision of this frame made it."""
    s, rt, f = setup.s, setup.rt, setup.frame
    inp = read.inputs
    note = input_warning(setup, inp)
    if passes_through(setup):
        level, msg = note
        return Decision(Outcome.PASSTHROUGH, show="source", outdated=False,
                        status=(level, msg or ("Disabled" if not s.enabled
                                               else "Before the start frame")))
    if s.is_baked:
        return _baked(setup, read, note)
    if f > s.frame_end:
        return _after_the_end(setup, read, note)
    if f in rt.cache.memory:
        d = _cached(setup, read, note)
        if d is not None:
            return d
    start = "reset" if starts_here(setup, read.settings.animation) else "step"
    if start == "step":
        if (f - 1) not in rt.cache.memory:
            return hold(setup)
        # Frame f - 1 cannot be evaluated again from here: at least its settings
        # (what every frame shares, and the keyable values at f - 1) must be what it
        # was solved with.
        if fixed_change(setup, rt.cache.memory.inputs(f - 1), read.settings, f - 1):
            return Decision(Outcome.OUTDATED, drops=_changed(setup, read), then="hold")
    drops = ()
    if f == s.frame_start:
        drops = (Drop("restart", f),)
    elif start == "reset":  # enabled again after disabled frames: from the groom
        drops = (Drop("after", f - 1),)
    return Decision(Outcome.RESET if f == s.frame_start else Outcome.STEP, show="solve",
                    start=start, drops=drops, outdated=False, status=NOTE, record=record)


def input_warning(setup, inp) -> tuple[str, str]:
    """(level, message) the status shows when the frame is fine: a warning about the
    enable attribute or a Surface listed as a collider, else ("INFO", "")."""
    if inp.warning:
        return "WARNING", inp.warning
    if warn := surface_as_collider(setup.ob):
        return "WARNING", warn
    return "INFO", ""


def _after_the_end(setup, read, note):
    """After the end frame: hold the end frame (or, not cached, the newest cached one)."""
    rt, end = setup.rt, setup.s.frame_end
    if rt.cache.hold is not None and rt.cache.hold[0] == end:
        level, msg = note
        return Decision(Outcome.HOLD, show="hold", frame=end, outdated=False,
                        status=(level, msg or f"After the end frame: holding frame {end}"))
    return hold(setup, reason=f"after the end frame, and frame {end} is not")


def _cached(setup, read, note):
    """A memory-cached frame: shown while its inputs still hold; else the setup is
    outdated (or, at the start frame, None: it is solved again, which drops every
    cached frame)."""
    rt, f, start = setup.rt, setup.frame, setup.s.frame_start
    why, record = cached_frame_change(setup, read.inputs, f, read.settings)
    if not why:
        newest = rt.cache.hold is None and f == max(rt.cache.memory.frames)
        return Decision(Outcome.CACHE, show="memory", frame=f, keep_hold=newest,
                        outdated=False, status=NOTE, record=record)
    if f == start:
        return None  # solved again (which drops every cached frame)
    changed = first_changed_frame(setup, rt.cache.memory.frames, read.settings)
    if changed is not None and changed[0] <= f:
        # A setting's value changed at a cached frame (a key edited): the frames
        # before it hold; f is solved again from f - 1 when that is one of them.
        drops = (Drop("from", changed[0], why=changed[1]),)
        then = "decide" if changed[0] == f and (f - 1) in rt.cache.memory else "hold"
        return Decision(Outcome.OUTDATED, drops=drops, then=then, record=record)
    if changed is None and _key_moved_ahead(setup, read, record):
        # Only the frames from f on were solved from other inputs (a key moved after
        # f - 1): solve f again from f - 1.
        return Decision(Outcome.OUTDATED, drops=(Drop("after", f - 1),), then="decide",
                        record=record)
    # (a change at a later cached frame too: every frame goes all the same)
    since = f"{why} since it was cached"
    return Decision(Outcome.OUTDATED, drops=(Drop("cache", why=why, since=since),),
                    outdated=True, record=record,
                    status=("WARNING", dropped_message(f, since, start)))


def _key_moved_ahead(setup, read, record) -> bool:
    """Did frame ``f``'s inputs change only in objects the depsgraph reported while the
    frame it was seen at still held (``PlaybackCache.trusted``), and is ``f - 1`` a frame
    known to hold since (``PlaybackCache.verified``), with its solver state and today's
    settings? Then f is solved again from f - 1 (an animator moved a key ahead of the
    frame shown); anything else drops the playback cache. ``record``: f's inputs
    record now."""
    rt, f = setup.rt, setup.frame
    fr = rt.cache.memory.frames.get(f - 1)
    if fr is None or (f - 1) not in rt.cache.verified or not rt.cache.trusted:
        return False
    if fr.state is None and rt.solve.frame != f - 1:
        return False
    if fixed_change(setup, fr.inputs, read.settings, f - 1):
        return False
    objects = changed_objects(setup, rt.cache.memory.inputs(f), record, read.settings.refs)
    return objects is not None and objects <= rt.cache.trusted


def _changed(setup, read) -> tuple:
    """The drop of the cached frames from the first one whose settings record no
    longer holds (:func:`.record.first_changed_frame`: a key edited, a setting
    changed), or () when every cached frame holds."""
    changed = first_changed_frame(setup, setup.rt.cache.memory.frames, read.settings)
    return () if changed is None else (Drop("from", changed[0], why=changed[1]),)


def hold(setup, reason="") -> Decision:
    """Jump ahead past the cache (or its solver state unknown, ``reason``): hold the
    newest cached frame, mark outdated."""
    rt, f = setup.rt, setup.frame
    here = not reason and rt.cache.dropped and rt.cache.dropped_at == f  # the change was seen here
    reason = reason or rt.cache.dropped
    k = rt.cache.memory.newest_before(f)
    if rt.cache.hold is not None and rt.cache.hold[0] == k:
        show, held = "hold", f"holding frame {k}"
    elif k is not None and k in rt.cache.memory:  # (whatever frame was shown before the jump)
        show, held = "memory", f"holding frame {k}"
    else:
        show, held = None, "showing the last result"
    d = dict(show=show, frame=k, keep_hold=show == "memory", outdated=True)
    start = setup.s.frame_start
    if rt.report.error:
        return Decision(Outcome.OUTDATED, status=(
            "ERROR", f"{rt.report.error} (frame {f} not solved: fix it, then go back to frame "
            f"{start})"), **d)
    if here:
        # Only the frames from the change on were dropped: playing on from the newest
        # one kept (its state known) solves the rest.
        resume = k if rt.cache.dropped_from > start and k is not None and (
            rt.cache.memory.frames[k].state is not None) else None
        return Decision(Outcome.OUTDATED, status=(
            "WARNING", dropped_message(f, rt.cache.dropped_why, start, resume)), **d)
    why = f" ({reason})" if reason else ""
    return Decision(Outcome.OUTDATED, status=(
        "WARNING", f"Frame {f} is not cached{why}: {held}. Play from frame {start} or bake."),
        **d)


def dropped_message(f, why, start, resume=None) -> str:
    """The status of frame ``f`` when ``why`` (a change seen there) dropped cached
    frames: every one, or those after ``resume``, the frame to play on from."""
    if resume is None or resume < start:
        return (f"Frame {f} is outdated: {why}. The playback cache is dropped: go to frame "
                f"{start} and play, or press Bake.")
    return (f"Frame {f} is outdated: {why}. The frames after {resume} are dropped: go to "
            f"frame {resume} and play, or press Bake.")


# ------------------------------------------------------------------ notes
def invalid_note(problems):
    """The status for curves the core left as they are (INVALID), or None."""
    if not problems:
        return None
    return ("WARNING", f"Source hair: {problems[0]}. They are shown in yellow; the other "
            "curves are solved. Fix the source curves (merge or delete the points)")


def frame_note(setup, read, stats, fresh=()) -> tuple[str, str]:
    """The status of a frame shown whose status is its :data:`NOTE`: the input warning
    (:func:`input_warning`), unless the frame shown (``stats``) holds INVALID curves:
    then what the last solve said about them (or how many there are, for a frame
    solved in another session). Without either, what there is to say about the
    colliders (an open mesh detects no pinch; what was repaired in one just built,
    ``fresh``, once): :func:`.colliders.collider_note`."""
    note = input_warning(setup, read.inputs)
    n = stats.get("invalid", 0)
    if not n:
        if note[1]:
            return note
        about = collider_note(setup.rt, setup.scene, read.settings.refs, fresh)
        return ("INFO", about) if about else note
    return setup.rt.report.invalid_note or (
        "WARNING", f"Source hair: {n} curves have a zero-length segment or a non-finite "
        "point. They are shown as they are, in yellow; the other curves are solved")


# ------------------------------------------------------------------ baked
def _baked(setup, read, note):
    """A baked setup: show the baked frame (the newest one before it when missing)."""
    s, f = setup.s, setup.frame
    inp = read.inputs
    directory = bpy.path.abspath(s.bake_path)
    fe = min(f, s.frame_end)
    outdated = None
    if not os.path.exists(framecache.frame_path(directory, fe)):
        frames = [k for k in framecache.list_frames(directory) if k < fe]
        outdated = True
        if frames:
            fe = frames[-1]
        else:
            return Decision(Outcome.OUTDATED, outdated=True, status=(
                "ERROR", f"Bake files are missing in {directory} (undo does not bring back "
                "files Free Bake deleted): press Free Bake, then Bake"))
    try:
        frame = framecache.read_shown(directory, fe)
    except framecache.UNREADABLE as exc:  # damaged (or not readable) since the bake
        return Decision(Outcome.OUTDATED, outdated=True, status=(
            "ERROR", f"Frame {fe} of the bake cannot be read: "
            f"{framecache.frame_path(directory, fe)} ({type(exc).__name__}: {exc}). The "
            "output keeps its last result. A damaged file: press Free Bake, then Bake"))
    if not np.array_equal(frame.offsets, inp.offsets):
        return Decision(Outcome.TOPOLOGY, outdated=outdated, status=(
            "ERROR", "The bake was made for other curves (the source changed): output keeps "
            "its last result. Free Bake to simulate the new curves."))
    stats = frame_stats(frame.status, fe, source="bake")
    d = dict(show="baked", frame=fe, baked=frame, stats=stats)
    why = baked_frame_change(setup, inp, frame.inputs, read.settings) if fe == f else ""
    other = baked.settings_change(setup.ob, setup.scene, directory, fe, frame.inputs,
                                  read.settings)
    if other:
        return Decision(Outcome.BAKE, outdated=True, status=(
            "WARNING", f"Frame {fe} was {baked.message(other)} (the baked frame is still "
            "shown)"), **d)
    if why:  # still shown (it is what renders), never as if current
        return Decision(Outcome.BAKE, outdated=True, status=(
            "WARNING", f"Frame {f} of the bake is outdated: {why} since it was baked. The "
            "baked frame is still shown: press Free Bake, then Bake."), **d)
    if fe == min(f, s.frame_end):
        return Decision(Outcome.BAKE, outdated=False, status=NOTE, **d)
    return Decision(Outcome.BAKE, outdated=outdated, status=(
        "WARNING", f"Frame {f} is missing from the bake: holding frame {fe}"), **d)


def _owner_name(out) -> str:
    src = out.furcollide.source
    return src.name if src is not None else "?"


def _baked_subframe(setup) -> Decision:
    """Blend the two baked frames around a subframe into the output (nothing written
    when they are not both baked). From Frame End on, Frame End itself (held after the
    end, as whole frames are): the second motion step of Frame End's motion blur."""
    s = setup.s
    none = Decision(Outcome.SUBFRAME)
    directory = bpy.path.abspath(s.bake_path)
    pair = framecache.subframe_pair(setup.frame, s.frame_start, s.frame_end)
    if pair is None:
        return none
    a, b = pair
    if not (os.path.exists(framecache.frame_path(directory, a)) and os.path.exists(
        framecache.frame_path(directory, b)
    )):
        return none
    pa, status, offs, _ = framecache.read_frame(directory, a, state=False)
    pb = framecache.read_frame(directory, b, state=False)[0]
    data = s.output.data
    if pa.shape != pb.shape or len(data.points) != len(pa):
        return none
    points = framecache.subframe_blend(pa, pb, setup.subframe)
    m_out_inv = bridge.matrix(s.output.evaluated_get(setup.depsgraph), inverted=True)
    src = setup.ob.evaluated_get(setup.depsgraph)
    inp = FrameInputs(points, offs, m_out_inv=m_out_inv, splines=source_splines(src))
    return Decision(Outcome.SUBFRAME, show="shown", shown=Shown(points, status), inputs=inp)
