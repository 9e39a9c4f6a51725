"""Frame caches: a bounded in-memory cache and an atomic on-disk bake.

Pure numpy and the standard library (no Blender): the add-on's frame rules
(``operators/``) keep one :class:`MemoryCache` per setup and bake through
:func:`write_frame` / :func:`read_frame`; pipeline scripts may use both directly.

Memory cache (interactive playback)
-----------------------------------
A frame stores only what differs from that frame's *input* (the evaluated
source, which Blender re-evaluates on demand):

* the exact float32 world positions of the curves the solver changed
  (curve indices + their points; unchanged curves are the input itself),
* the non-zero per-curve status codes,
* the solver state as rows that differ from the freshly reset state.

Everything is stored losslessly, so scrubbing back shows bit-identical
results. The footprint grows with the number of *touched* curves, not with
the groom: at paper scale (50,000 curves x 8 CVs, 250 frames) with 10 % of
the curves in contact a frame costs about 0.6 MB (positions 0.5 MB, state
rows) - 150 MB for 250 frames. A per-setup budget (``memory_limit`` MB)
caps the worst case: past it, solver states are dropped from all but every
``KEY_EVERY``-th frame (those frames still display, they just cannot be
stepped from), then the oldest frames are dropped entirely.

Disk cache (bake)
-----------------
One ``frame_NNNNNN.npz`` per frame in the setup's bake directory, written
to a temporary file and moved into place with :func:`os.replace`, so a
crash never leaves a half-written frame. Each file holds full world
positions (self-contained: it does not need the input), the status codes,
the curve offsets (topology check) and the full solver state (resume).
Files are read with ``allow_pickle=False``.

Frame inputs
------------
Every cached frame (memory or bake) keeps a *frame-inputs record*: a few
64-bit digests of what it was solved from (settings, source curves, each
collider's matrix and shape, the growth surface), see :func:`digest`. A
cached frame is shown only while the record of the current inputs equals it
(:func:`first_change` names the part that differs).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import zipfile
import zlib
from dataclasses import dataclass, field

import numpy as np

#: Frames whose solver state survives a memory-budget eviction.
KEY_EVERY = 10
#: Default per-setup memory budget, megabytes.
DEFAULT_MEMORY_LIMIT_MB = 512

FRAME_FILE = "frame_{:06d}.npz"
#: Frame files: the name :data:`FRAME_FILE` gives (``frame_-00004.npz`` for a
#: negative pre-roll frame: the sign takes one of the six places).
_FRAME_RE = re.compile(r"^frame_(-?\d+)\.npz$")


def _frame_of(name: str) -> int | None:
    """The frame of a bake file name, None for anything else."""
    m = _FRAME_RE.match(name)
    if m is None or FRAME_FILE.format(int(m.group(1))) != name:
        return None
    return int(m.group(1))


#: What reading a frame file that is not a finished frame raises (cut short, empty,
#: not a zip, an older format): such a file holds no frame.
UNREADABLE = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile)

_STATE_PREFIX = "state__"
_ATTRIBUTE_PREFIX = "attr__"
_INPUTS_KEY = "inputs"
_EXTRA_PREFIX = "extra__"
_FORMAT_VERSION = 1


def topology_key(offsets: np.ndarray) -> tuple[int, int, int]:
    """(curves, points, crc32 of the offsets): identifies a curve layout."""
    offsets = np.ascontiguousarray(offsets, np.int32)
    return (len(offsets) - 1, int(offsets[-1]) if len(offsets) else 0, zlib.crc32(offsets))


def curve_point_mask(offsets: np.ndarray, curves: np.ndarray) -> np.ndarray:
    """Point indices of ``curves`` (sorted curve indices) for ``offsets``."""
    starts = offsets[curves]
    sizes = offsets[curves + 1] - starts
    if not len(sizes):
        return np.zeros(0, np.int64)
    base = np.repeat(starts - np.concatenate([[0], np.cumsum(sizes)[:-1]]), sizes)
    return base + np.arange(int(sizes.sum()))


_UINT = {1: np.uint8, 2: np.uint16, 4: np.uint32, 8: np.uint64}


def rows_differ(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Bool per row (first axis): does any element of ``a`` differ from ``b``?

    Compares bit patterns (``-0.0`` differs from ``0.0``, a NaN equals
    itself), so what is stored as "unchanged" really is identical.
    """
    n = len(a)
    size = a.dtype.itemsize
    if a.dtype == b.dtype and size in _UINT:  # (a same-size view takes any strides)
        d = a.view(_UINT[size]) != b.view(_UINT[size])
    else:
        d = a != b
    d = d.reshape(n, -1)
    if d.shape[1] in _UINT:  # a row of 1/2/4/8 flags is one integer
        d = np.ascontiguousarray(d)  # (the view needs C-ordered rows: Fortran input)
        return d.view(_UINT[d.shape[1]]).reshape(n) != 0
    m = d[:, 0].copy()
    for j in range(1, d.shape[1]):
        m |= d[:, j]
    return m


def curves_with_any(point_flags: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Bool per curve: is any of its points flagged? (``offsets`` with C >= 1)"""
    C = len(offsets) - 1
    n = int(offsets[-1]) // C
    if n * C == offsets[-1] and np.array_equal(offsets, np.arange(C + 1) * n):
        rows = point_flags.reshape(C, n)  # every curve has n points: a fast row-wise "any"
        return rows_differ(rows, np.zeros_like(rows[:1]))
    return np.maximum.reduceat(point_flags.view(np.uint8), offsets[:-1]).astype(bool)


# ------------------------------------------------------------ frame inputs
_MASK64 = (1 << 64) - 1
_SMALL = 4096  # bytes: smaller arrays are hashed as they are
_weights = np.zeros(0, np.uint64)  # grows on demand; a prefix never changes


def _digest_weights(n: int) -> np.ndarray:
    """(n,) uint64 pseudo-random odd weights (splitmix64 of the index)."""
    global _weights
    if len(_weights) < n:
        with np.errstate(over="ignore"):
            z = np.arange(max(n, 2 * len(_weights)), dtype=np.uint64)
            z = z * np.uint64(0x9E3779B97F4A7C15) + np.uint64(0x632BE59BD9B4E019)
            z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
            z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
            z ^= z >> np.uint64(31)
        _weights = z | np.uint64(1)
    return _weights[:n]


def digest(*arrays) -> int:
    """64-bit digest of the bytes of ``arrays`` (each as stored: dtype, order).

    A weighted sum, modulo 2**64, of the data read as uint64 words with
    pseudo-random odd weights: one pass, no copy for contiguous arrays (about
    0.2 ms for 400,000 float32 points, where SHA-1 takes 5 ms). Any change of
    a single word always changes it (an odd weight is invertible modulo
    2**64); so does moving a word elsewhere, unless weights collide by chance
    (2**-64). It guards against edits, not against an adversary. Stable across
    sessions and platforms (little-endian words), so bakes keep it.
    """
    h = hashlib.blake2b(digest_size=8)
    for a in arrays:
        a = np.ascontiguousarray(a)
        b = a.reshape(-1).view(np.uint8)
        h.update(a.dtype.str.encode() + len(b).to_bytes(8, "little"))
        if len(b) <= _SMALL:  # a matrix, a key: the bytes themselves
            h.update(b)
            continue
        n = len(b) // 8
        acc = int(np.dot(b[: n * 8].view("<u8"), _digest_weights(n))) & _MASK64
        h.update(acc.to_bytes(8, "little") + bytes(b[n * 8:]))
    return int.from_bytes(h.digest(), "little")


def text_digest(text: str) -> int:
    """64-bit digest of a string (settings signatures)."""
    return int.from_bytes(hashlib.blake2b(text.encode(), digest_size=8).digest(), "little")


def first_change(old: dict, new: dict) -> str | None:
    """The first part (in ``new``'s order) whose digest differs between two
    frame-inputs records (name -> int), or None when they are equal. A part
    only one of them has counts as changed."""
    for key, value in new.items():
        if old.get(key) != value:
            return key
    for key in old:
        if key not in new:
            return key
    return None


def encode_inputs(record: dict) -> np.ndarray:
    """A frame-inputs record as a uint8 array (JSON) for a bake file."""
    return np.frombuffer(json.dumps(record).encode(), np.uint8).copy()


def decode_inputs(array) -> dict | None:
    """The record :func:`encode_inputs` stored (None if it cannot be read)."""
    try:
        record = json.loads(np.asarray(array, np.uint8).tobytes().decode())
    except (ValueError, UnicodeDecodeError):
        return None
    return record if isinstance(record, dict) else None


# ------------------------------------------------------------------- memory
@dataclass
class Frame:
    """One memory-cached frame (sparse, lossless)."""

    curves: np.ndarray  # (k,) int32 changed curves
    points: np.ndarray  # (n, 3) float32 world positions of those curves
    status_idx: np.ndarray  # (s,) int32 curves with a non-zero status
    status_val: np.ndarray  # (s,) int8
    state: dict | None  # sparse state (see SparseState) or None when evicted
    stats: dict = field(default_factory=dict)
    attributes: dict = field(default_factory=dict)  # name -> (P,) per-point values
    inputs: dict | None = None  # frame-inputs record it was solved from
    #: (n,) bool: which of ``points`` differ from the input (the rest are the input's)
    moved: np.ndarray | None = None

    @property
    def nbytes(self) -> int:
        n = self.curves.nbytes + self.points.nbytes + self.status_idx.nbytes
        n += self.moved.nbytes if self.moved is not None else 0
        n += self.status_val.nbytes + sum(a.nbytes for a in self.attributes.values())
        if self.state:
            n += sum(a.nbytes for a in self.state.values())
        return n


class SparseState:
    """Encode a solver state as the rows that differ from a baseline state.

    The baseline is a fresh solver's state: every row of each array is the same
    (zeros, identity quaternions), so it is kept as that one row broadcast to the
    array's shape (at 200,000 curves x 8 CVs a full copy of a Soft state would
    take 114 MB, and nothing else).
    """

    def __init__(self, baseline: dict):
        self.baseline = {k: _one_row(np.asarray(v)) for k, v in baseline.items()}

    def encode(self, state: dict) -> dict:
        out = {}
        for k, a in state.items():
            a = np.asarray(a)
            b = self.baseline.get(k)
            if b is None or b.shape != a.shape or a.ndim == 0 or len(a) < 64:
                out["full:" + k] = a.copy()
                continue
            idx = np.flatnonzero(rows_differ(a, b)).astype(np.int32)
            out["idx:" + k] = idx
            out["val:" + k] = a[idx].copy()
        return out

    def decode(self, sparse: dict) -> dict:
        out = {}
        for key, a in sparse.items():
            kind, name = key.split(":", 1)
            if kind == "full":
                out[name] = a.copy()
            elif kind == "idx":
                full = self.baseline[name].copy()
                full[a] = sparse["val:" + name]
                out[name] = full
        return out


def _one_row(a: np.ndarray) -> np.ndarray:
    """``a``, as its first row broadcast (read-only) when every row has its bits."""
    if a.ndim == 0 or len(a) < 2 or rows_differ(a, np.broadcast_to(a[:1], a.shape)).any():
        return a
    return np.broadcast_to(a[:1].copy(), a.shape)


class MemoryCache:
    """Sparse, lossless frame cache with a memory budget (see module doc)."""

    def __init__(self, limit_mb: float = DEFAULT_MEMORY_LIMIT_MB):
        self.frames: dict[int, Frame] = {}
        self.limit = int(limit_mb * 1024 * 1024)
        self.start: int | None = None
        self.sparse: SparseState | None = None

    def __contains__(self, f: int) -> bool:
        return f in self.frames

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def nbytes(self) -> int:
        return sum(fr.nbytes for fr in self.frames.values())

    def newest_before(self, f: int) -> int | None:
        """Newest cached frame strictly before ``f`` (None if none)."""
        keys = [k for k in self.frames if k < f]
        return max(keys) if keys else None

    def clear(self) -> None:
        self.frames.clear()

    def drop_after(self, f: int) -> int:
        """Drop every frame after ``f``; returns how many were dropped."""
        gone = [k for k in self.frames if k > f]
        for k in gone:
            del self.frames[k]
        return len(gone)

    def put(self, f, inp, out, status, offsets, state, stats, changed=None,
            attributes=None, inputs=None) -> None:
        """Store frame ``f`` (lossless, sparse).

        Parameters
        ----------
        f : int
            Frame number.
        inp, out : (P, 3) float32 ndarray
            That frame's input and solved world positions.
        status : (C,) int8 ndarray
            Core status codes.
        offsets : (C+1,) int32 ndarray
            Curve offsets.
        state : dict or None
            ``Solver.state`` after the frame (encoded against ``self.sparse``).
        stats : dict
            Panel statistics kept with the frame.
        changed : (P,) bool ndarray, optional
            ``rows_differ(out, inp)`` when the caller has it already.
        attributes : dict, optional
            Per-point attributes of the output (name -> (P,) array), kept as is.
        inputs : dict, optional
            The frame-inputs record the frame was solved from (:meth:`inputs`).
        """
        C = len(offsets) - 1
        P = len(inp)
        if out.shape != inp.shape:
            raise ValueError("cache: output and input positions differ in shape")
        if P and C:
            if changed is None:
                changed = rows_differ(out, inp)
            curve_changed = curves_with_any(changed, offsets)
        else:
            curve_changed = np.zeros(C, bool)
        curves = np.flatnonzero(curve_changed).astype(np.int32)
        rows = curve_point_mask(offsets, curves)
        pts = out[rows].astype(np.float32, copy=True)
        moved = changed[rows] if len(rows) else np.zeros(0, bool)
        nz = np.flatnonzero(status).astype(np.int32)
        enc = self.sparse.encode(state) if (self.sparse is not None and state is not None) else None
        attrs = {k: np.array(v, copy=True) for k, v in (attributes or {}).items()}
        self.frames[f] = Frame(curves, pts, nz, status[nz].astype(np.int8), enc, dict(stats),
                               attrs, dict(inputs) if inputs is not None else None, moved)
        self._enforce_budget(keep=f)

    def get(self, f, inp, offsets):
        """Rebuild frame ``f`` bit for bit.

        Parameters
        ----------
        f : int
            A cached frame.
        inp : (P, 3) float32 ndarray
            That frame's input world positions (re-evaluated by Blender).
        offsets : (C+1,) int32 ndarray

        Returns
        -------
        points : (P, 3) float32 ndarray
        status : (C,) int8 ndarray
        stats : dict
        """
        rows, points, status, stats = self.get_moved(f, offsets)
        out = inp.astype(np.float32, copy=True)
        out[rows] = points  # (the curves' other points are the input's bits)
        return out, status, stats

    def get_moved(self, f, offsets):
        """Frame ``f`` as the rows that differ from its input, without the input
        (:meth:`get` is the input with these rows set, bit for bit).

        Returns
        -------
        rows : (k,) int64 ndarray
            Increasing point indices: exactly the rows where the frame's output
            differs from its input (``rows_differ``).
        points : (k, 3) float32 ndarray
            Their world positions.
        status : (C,) int8 ndarray
        stats : dict
        """
        fr = self.frames[f]
        rows = curve_point_mask(offsets, fr.curves)
        status = np.zeros(len(offsets) - 1, np.int8)
        status[fr.status_idx] = fr.status_val
        return rows[fr.moved], fr.points[fr.moved], status, fr.stats

    def attributes(self, f) -> dict:
        """Per-point attributes stored with frame ``f`` (empty when none)."""
        fr = self.frames.get(f)
        return dict(fr.attributes) if fr is not None else {}

    def inputs(self, f) -> dict | None:
        """The frame-inputs record frame ``f`` was solved from (None if unknown)."""
        fr = self.frames.get(f)
        return fr.inputs if fr is not None else None

    def state(self, f) -> dict | None:
        """Full solver state after frame ``f`` (None if unknown/evicted)."""
        fr = self.frames.get(f)
        if fr is None or fr.state is None or self.sparse is None:
            return None
        return self.sparse.decode(fr.state)

    def _enforce_budget(self, keep: int) -> None:
        total = self.nbytes
        if total <= self.limit:
            return
        start = self.start if self.start is not None else min(self.frames)
        for k in sorted(self.frames):
            if total <= self.limit:
                return
            fr = self.frames[k]
            if k != keep and fr.state is not None and (k - start) % KEY_EVERY:
                total -= sum(a.nbytes for a in fr.state.values())
                fr.state = None
        for k in sorted(self.frames):
            if total <= self.limit:
                return
            if k not in (keep, start):
                total -= self.frames[k].nbytes
                del self.frames[k]


# --------------------------------------------------------------------- disk
def subframe_pair(f: int, start: int, end: int) -> tuple[int, int] | None:
    """The two baked frames ``(a, b)`` a motion-blur subframe after whole frame ``f``
    blends (``a + (b - a) * subframe``), or None outside the bake's range ``start``
    to ``end``. From the end frame on it is ``(end, end)``: the end frame held, as
    whole frames after it are."""
    a, b = f, f + 1
    if a >= end:
        a = b = end
    if not (start <= a and b <= end):
        return None
    return a, b


def subframe_blend(a: np.ndarray, b: np.ndarray, subframe: float) -> np.ndarray:
    """``a + (b - a) * subframe`` in the baked points' float32: what a subframe shows
    between the baked frames :func:`subframe_pair` names (the guides and the render
    groom alike, so they move over the shutter together)."""
    return a + (b - a) * np.float32(subframe)


def frame_path(directory: str, f: int) -> str:
    """Path of frame ``f``'s bake file in ``directory``."""
    return os.path.join(directory, FRAME_FILE.format(f))


def list_frames(directory: str) -> list[int]:
    """Frames that have a finished bake file in ``directory`` (sorted)."""
    if not directory or not os.path.isdir(directory):
        return []
    frames = []
    for name in os.listdir(directory):
        f = _frame_of(name)
        if f is not None:
            frames.append(f)
    return sorted(frames)


def write_frame(directory, f, points, status, offsets, state, sparse=None,
                attributes=None, inputs=None, extra=None) -> str:
    """Atomically write frame ``f`` (temp file + :func:`os.replace`).

    With ``sparse`` (a :class:`SparseState`), the solver state is stored as
    the rows that differ from the freshly reset state (lossless; a few MB
    instead of ~25 MB per frame at paper scale). ``attributes`` (name -> (P,)
    array) are per-point attributes of the output (:func:`read_attributes`).
    ``inputs`` is the frame-inputs record the frame was solved from
    (:func:`read_inputs`). ``extra`` (part name -> dict of arrays, or None) stores
    what later stages derived from the frame, e.g. the render groom
    (:func:`read_extra`; a part's name has no ``__``).
    """
    if sparse is not None and state is not None:
        state = {k.replace(":", "__", 1): v for k, v in sparse.encode(state).items()}
    os.makedirs(directory, exist_ok=True)
    path = frame_path(directory, f)
    tmp = path + ".tmp"
    arrays = {
        "format": np.array([_FORMAT_VERSION, f], np.int64),
        "points": np.ascontiguousarray(points, np.float32),
        "status": np.ascontiguousarray(status, np.int8),
        "offsets": np.ascontiguousarray(offsets, np.int32),
    }
    for k, v in (state or {}).items():
        arrays[_STATE_PREFIX + k] = np.asarray(v)
    for k, v in (attributes or {}).items():
        arrays[_ATTRIBUTE_PREFIX + k] = np.asarray(v)
    if inputs is not None:
        arrays[_INPUTS_KEY] = encode_inputs(inputs)
    for part, items in (extra or {}).items():
        if "__" in part:
            raise ValueError(f"write_frame: a part's name has no '__' ({part!r})")
        for k, v in (items or {}).items():
            arrays[f"{_EXTRA_PREFIX}{part}__{k}"] = np.asarray(v)
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    return path


def decode_state(stored: dict, sparse: SparseState) -> dict:
    """Full solver state from what :func:`read_frame` returned."""
    if not any("__" in k for k in stored):
        return dict(stored)
    return sparse.decode({k.replace("__", ":", 1): v for k, v in stored.items()})


def read_frame(directory, f, state=True):
    """Read frame ``f``: (points, status, offsets, state). Never unpickles.

    ``state`` is as stored (sparse keys ``idx__name``/``val__name``/``full__name``
    when written with ``sparse``; see :func:`decode_state`); with ``state=False`` it
    is not read (an empty dict): only resuming a bake needs it.
    """
    with np.load(frame_path(directory, f), allow_pickle=False) as z:
        stored = _prefixed(z, _STATE_PREFIX) if state else {}
        return z["points"], z["status"], z["offsets"], stored


@dataclass
class ShownFrame:
    """What showing a baked frame reads from its file (:func:`read_shown`)."""

    points: np.ndarray  #: (P, 3) float32, the output's points
    status: np.ndarray  #: (C,) int8
    offsets: np.ndarray  #: (C + 1,) int32
    attributes: dict  #: as :func:`read_attributes`
    inputs: dict | None  #: as :func:`read_inputs`
    extra: dict  #: part -> {name: array}, as :func:`read_extra` (no key for a part not stored)


def read_shown(directory, f) -> ShownFrame:
    """Frame ``f`` as a baked frame is shown: everything :func:`write_frame` stored but
    the solver state (only resuming a bake needs it), in one open of the file (the other
    ``read_*`` functions each open it again)."""
    with np.load(frame_path(directory, f), allow_pickle=False) as z:
        extra = {}
        for k, v in _prefixed(z, _EXTRA_PREFIX).items():
            part, name = k.split("__", 1)
            extra.setdefault(part, {})[name] = v
        return ShownFrame(z["points"], z["status"], z["offsets"],
                          _prefixed(z, _ATTRIBUTE_PREFIX), _inputs(z), extra)


def _prefixed(z, prefix, names=None) -> dict:
    """{name: array} of the arrays of open bake file ``z`` named ``prefix + name``
    (only ``names``, when given: the others are not loaded)."""
    n = len(prefix)
    return {k[n:]: z[k] for k in z.files
            if k.startswith(prefix) and (names is None or k[n:] in names)}


def _inputs(z) -> dict | None:
    return decode_inputs(z[_INPUTS_KEY]) if _INPUTS_KEY in z.files else None


def read_inputs(directory, f) -> dict | None:
    """The frame-inputs record stored with frame ``f`` (None for files written
    before FurCollide stored it, or unreadable)."""
    try:
        with np.load(frame_path(directory, f), allow_pickle=False) as z:
            return _inputs(z)
    except UNREADABLE:
        return None


def read_extra(directory, f, part, names=None) -> dict | None:
    """The arrays of ``part`` stored with frame ``f`` (:func:`write_frame`'s
    ``extra``), or None when the frame has none. ``names`` (optional) reads only
    those arrays (the others are not loaded)."""
    with np.load(frame_path(directory, f), allow_pickle=False) as z:
        return _prefixed(z, f"{_EXTRA_PREFIX}{part}__", names) or None


def read_attributes(directory, f) -> dict:
    """Per-point attributes stored with frame ``f`` (name -> array; empty when none)."""
    with np.load(frame_path(directory, f), allow_pickle=False) as z:
        return _prefixed(z, _ATTRIBUTE_PREFIX)


def remove_frames(directory: str) -> int:
    """Delete the bake files FurCollide wrote in ``directory`` (and nothing else).

    The directory itself is removed only when it is empty afterwards.
    Returns the number of files removed.
    """
    if not directory or not os.path.isdir(directory):
        return 0
    n = 0
    for name in os.listdir(directory):
        if _frame_of(name) is not None or (
            name.startswith("frame_") and name.endswith(".npz.tmp")
        ):
            os.remove(os.path.join(directory, name))
            n += 1
    try:
        os.rmdir(directory)
    except OSError:
        pass
    return n
