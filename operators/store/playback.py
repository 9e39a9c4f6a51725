"""The playback cache of a setup: the frames solved in this session, and what was dropped.

Each setup's runtime (:class:`.registry.Runtime`) holds one :class:`PlaybackCache`,
changed only by the functions here, as Blender's point cache: a frame solved is kept
(:func:`keep`) with its inputs record; an edit, a key moved or a change seen by the
frame rules drops frames (:func:`drop_cache`, :func:`drop_from`, :func:`drop_after`),
and until the start frame is solved again (:func:`restart`) the frames that are not
cached say why. A drop also forgets what was derived from the frames dropped: the
solver's state of them (:func:`..frame.solve.forget_after`) and the structure seen
(:func:`..frame.record.forget_structure`: the new settings are accepted without a
second drop).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ...core import framecache
from ..frame import record, solve

#: Why the playback cache is empty after a file saved with one was opened (the reason
#: the frames that are not cached give, as ``PlaybackCache.dropped``, until the start
#: frame is solved again).
NOT_SAVED = "the playback cache is not saved with the file: bake to keep the frames"


@dataclass(slots=True)
class PlaybackCache:
    """The part of a setup's runtime with its cached frames."""

    memory: framecache.MemoryCache = field(default_factory=framecache.MemoryCache)
    hold: tuple | None = None  # (frame, world positions, status) of newest frame
    #: Why the playback cache is empty (until the start frame is solved again): the
    #: reason the frames that are not cached give, e.g. "'Box' moved: the playback
    #: cache was dropped".
    dropped: str = ""
    dropped_why: str = ""  # the change itself ("'Box' moved")...
    dropped_at: int | None = None  # ...and the frame it was seen at...
    dropped_from: int = 0  # ...and the first frame dropped
    #: Objects the depsgraph reported updated while the current frame's inputs held (the
    #: animation evaluated again, or a key moved on another frame), since the playback
    #: cache was last dropped; and the cached frames known to hold since: the frame it
    #: was seen at, the frames solved after. A cached frame whose inputs changed only
    #: in those objects is solved again from a verified previous frame (a key moved
    #: ahead of it); any other change drops the playback cache (see frame.rules).
    trusted: set = field(default_factory=set)
    verified: set = field(default_factory=set)


def new(limit_mb: float) -> PlaybackCache:
    """An empty playback cache with the Memory Limit ``limit_mb``."""
    return PlaybackCache(memory=framecache.MemoryCache(limit_mb))


def keep(rt, f, inputs, result, inputs_record) -> None:
    """Keep frame ``f`` just solved (``result``, from ``inputs``, with its inputs
    ``inputs_record`` and the solver's state), known to hold; it is held after the end and on a
    jump ahead when it is the newest."""
    c = rt.cache
    c.verified.add(f)
    c.verified &= c.memory.frames.keys() | {f}  # (frames the budget dropped go)
    c.memory.put(
        f, inputs.before_motion(), result.points, result.status, inputs.offsets,
        rt.solve.solver.state, result.stats, result.changed, result.attributes, inputs_record,
    )
    if c.hold is None or f >= c.hold[0]:
        c.hold = (f, result.points, result.status)


def hold(rt, f, points, status) -> None:
    """Frame ``f``, shown as ``points`` and ``status``, is the one held after the end
    and on a jump ahead."""
    rt.cache.hold = (f, points, status)


def forget_hold(rt) -> None:
    """No frame is held (it was one of other curves)."""
    rt.cache.hold = None


def sparse(rt, state) -> None:
    """The solver's state encoder for the cached frames (a solver was built: its
    ``state`` gives the arrays)."""
    rt.cache.memory.sparse = framecache.SparseState(state)


def restart(rt, start: int, limit_mb: float) -> None:
    """The start frame ``start`` is solved again: the playback cache starts over (with
    the Memory Limit ``limit_mb``), nothing dropped before is said any more."""
    c = rt.cache
    c.memory.clear()
    c.verified.clear()
    c.trusted.clear()
    c.dropped = ""
    c.memory.start = start
    c.memory.limit = int(limit_mb * 1024 * 1024)


def drop_after(rt, f: int, start: int) -> None:
    """Forget the cached frames after ``f`` (every one when ``f`` is before the start
    frame ``start``), and what was derived from them."""
    c = rt.cache
    c.verified = {k for k in c.verified if k <= f}
    if f < start:
        c.memory.clear()
        c.hold = None
    else:
        c.memory.drop_after(f)
        if c.hold is not None and c.hold[0] > f:
            c.hold = None
    solve.forget_after(rt, f)
    record.forget_structure(rt)  # accept the new settings without a second drop


def drop_from(rt, first: int, why: str, start: int, frame: int | None = None) -> bool:
    """Drop the cached frames from ``first`` on (every one when ``first`` is the start
    frame ``start`` or before it: :func:`drop_cache`): ``why`` (a change seen at
    ``frame``) made them other than they were solved. True when frames were dropped."""
    if first <= start:
        return drop_cache(rt, why, start, frame)
    c, solved = rt.cache, rt.solve.frame
    had = any(k >= first for k in c.memory.frames) or (solved is not None and solved >= first)
    drop_after(rt, first - 1, start)
    c.trusted.clear()
    if had and why:
        c.dropped = f"{why}: the frames from {first} on were dropped"
        c.dropped_why, c.dropped_at, c.dropped_from = why, frame, first
    return had


def drop_cache(rt, why: str, start: int, frame: int | None = None, since: str = "") -> bool:
    """Drop the whole playback cache, as Blender's point cache does on a change: the
    frames shown next are solved again from the start frame ``start`` on, and until
    then the frames that are not cached say ``why`` (the change, seen at ``frame``;
    ``since``: how the status names it there, default ``why``). True when frames (or
    a solver state) were dropped."""
    c = rt.cache
    had = len(c.memory) > 0 or rt.solve.frame is not None
    drop_after(rt, start - 1, start)
    solve.forget_frame(rt)
    c.verified.clear()
    c.trusted.clear()
    if had and why:
        c.dropped = f"{why}: the playback cache was dropped"
        c.dropped_why, c.dropped_at, c.dropped_from = why, frame, start
    if since:
        c.dropped_why = since
    return had


def trust(rt, objects, frame) -> None:
    """The depsgraph reported ``objects`` updated while frame ``frame``'s inputs held
    (the animation evaluated again, or a key moved on another frame): only ``frame`` is
    known to hold now."""
    c = rt.cache
    c.trusted |= objects
    c.verified &= {frame}


def not_saved(rt) -> None:
    """The file was saved with a playback cache, which is not in it: the frames that
    are not cached say so until the start frame is solved again."""
    rt.cache.dropped = NOT_SAVED


def forget(rt) -> None:
    """Forget every cached frame (the setup was baked: it reads its bake now)."""
    rt.cache.memory.clear()
    rt.cache.hold = None


def set_limit(rt, limit_mb: float) -> None:
    """The Memory Limit changed."""
    rt.cache.memory.limit = int(limit_mb * 1024 * 1024)
