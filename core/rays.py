"""Ray adapter: the only module that talks to a ray tracer.

Two backends share one small API (as trimesh's ``ray/`` does):

* :class:`EmbreeBackend` - embreex (Embree 4) BVH, float32, multi-threaded
  (embreex releases the GIL, so ray batches are split over a thread pool).
* :class:`NumpyBackend` - brute-force Moller-Trumbore in float64. Slow; it is
  the reference the embree path is tested against, and a fallback.

Rays are *segments*: origin ``o`` and unnormalized direction ``d`` with a hit
counted for ray parameter ``t`` in ``[0, tmax]``. Because ``d`` is not
normalized, ``t`` is invariant under affine maps, which is what lets a rigid
collider keep its BVH in its own space and move the rays instead.
"""

from __future__ import annotations

import numbers
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import numpy as np

from . import tolerances as tol
from .errors import BackendUnavailable, InputError

try:  # embreex wheels exist for linux-x64, windows-x64, macOS 13+ (arm64/x64) only
    from embreex import mesh_construction as _mc
    from embreex import rtcore_scene as _rs

    _EMBREE_ERROR = None
except Exception as exc:  # pragma: no cover - depends on the platform
    _mc = _rs = None
    _EMBREE_ERROR = exc

_pool: ThreadPoolExecutor | None = None
_pool_size = 0
_pool_lock = threading.Lock()
_local = threading.local()  # in_pool: set on the pool's own threads


def _mark_pool_thread():
    _local.in_pool = True


def embree_available() -> bool:
    """True when embreex imported on this platform."""
    return _EMBREE_ERROR is None


def embree_error() -> str:
    """Human-readable reason why embreex is unavailable ('' if it is)."""
    if _EMBREE_ERROR is None:
        return ""
    return (
        f"FurCollide needs the embreex ray tracer, which could not be loaded on this "
        f"platform ({type(_EMBREE_ERROR).__name__}: {_EMBREE_ERROR}). Supported: Linux x64, "
        f"Windows x64, macOS 13+ (Apple Silicon and Intel)."
    )


def default_threads() -> int:
    """Number of CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def thread_count(threads) -> int:
    """Threads a stage may use: ``threads`` (a positive integer), or every CPU
    for None (as :attr:`core.settings.Settings.threads`)."""
    if threads is None:
        return default_threads()
    if isinstance(threads, (bool, np.bool_)) or not isinstance(threads, numbers.Integral) \
            or threads < 1:
        raise InputError(f"threads must be a positive integer or None, got {threads!r}")
    return int(threads)


def _executor(n: int) -> ThreadPoolExecutor:
    global _pool, _pool_size
    with _pool_lock:
        if _pool is None or _pool_size < n:
            if _pool is not None:
                _pool.shutdown(wait=False)
            _pool = ThreadPoolExecutor(
                max_workers=n, thread_name_prefix="furcollide-rays", initializer=_mark_pool_thread
            )
            _pool_size = n
        return _pool


def beside(fn, threads: int):
    """Run ``fn()`` on a ray-pool thread while the caller goes on (when
    ``threads > 1``; inline otherwise). Returns a callable that waits for and
    returns ``fn``'s result (or raises its exception).

    For independent phases: numpy's loops and the tracer release the GIL, so
    the two overlap. Work that ``fn`` or the caller hands to the pool never
    waits for ``fn``, so it completes on the pool's other threads.
    """
    if threads <= 1:
        result = fn()
        return lambda: result
    return _executor(threads).submit(fn).result


def both(first, second, threads: int):
    """``(first(), second())``; with ``threads > 1`` the first on a ray-pool
    thread while the caller runs the second (:func:`beside`).

    Both have ended when this returns or raises. An error of the caller's
    own call is the one raised (the other call's is then dropped), else the
    other call's.
    """
    done = beside(first, threads)
    try:
        b = second()
    except BaseException:
        try:
            done()
        except BaseException:  # the first error is the one to report
            pass
        raise
    return done(), b


def split_count(n: int, threads: int, min_n: int) -> int:
    """How many parts :func:`in_two` cuts ``n`` items into: 1 with one thread or
    fewer than ``min_n`` items, else one per thread, each of at least
    ``min_n / 2`` items (two from ``min_n`` on, as the halves always were) and
    of one at least."""
    if threads <= 1 or n < min_n or n < 2:
        return 1
    return int(min(threads, n, max(2, (2 * n) // max(min_n, 1))))


def run_parts(calls, threads: int) -> list:
    """``[c() for c in calls]``, each call on its own thread: all but the last on
    ray-pool threads while the caller runs the last (one call, or on a pool
    thread: inline, in order; waiting there for the pool could deadlock).

    Every call has ended when this returns or raises. An error of the caller's
    own call is the one raised, else the first of the others' (in order).
    """
    if len(calls) <= 1 or threads <= 1 or getattr(_local, "in_pool", False):
        return [c() for c in calls]
    pool = _executor(max(threads, len(calls)))
    futs = [pool.submit(c) for c in calls[:-1]]
    try:
        last = calls[-1]()
    except BaseException:
        for f in futs:  # never leave a part running; this error is the one raised
            f.exception()
        raise
    out, error = [], None
    for f in futs:
        exc = f.exception()
        if exc is not None and error is None:
            error = exc
        out.append(None if exc is not None else f.result())
    if error is not None:
        raise error
    return out + [last]


def in_two(fn, n: int, threads: int, min_n: int) -> None:
    """``fn(0, n)``; with ``threads > 1`` and ``n >= min_n``, ``fn(a, b)`` over
    :func:`split_count` consecutive ranges of about equal size, each on its own
    thread (:func:`run_parts`; two halves on two threads, one part per thread on
    more).

    For per-item work whose items are independent (curves, guides, segments)
    and which writes disjoint slices of its outputs: each part computes what
    the whole would, bit for bit, whatever the number of parts, and numpy's
    long loops release the GIL, so the parts overlap.
    """
    p = split_count(n, threads, min_n)
    if p == 1:
        fn(0, n)
        return
    bounds = np.linspace(0, n, p + 1).astype(np.int64)
    run_parts([partial(fn, int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:],
                                                             strict=True)], threads)


def triangle_rows(F) -> np.ndarray:
    """Triangles prepared for a fast :class:`EmbreeBackend` build, (m,) object.

    embreex's ``TriangleMesh`` copies its input into Embree one element at a
    time with Python indexing (``indices[i][0]``): on an ``(m, 3)`` integer
    array each ``indices[i]`` makes a new array view, the bulk of the ~50 ms a
    130k-triangle mesh takes. Handing it a 1-D object array of row tuples
    instead makes each lookup a plain tuple access (about 3x faster), with
    exactly the same values. Building the tuples costs about as much as one
    slow build, so a collider prepares them once per topology and reuses them
    for every rebuild (deformation).

    Parameters
    ----------
    F : (m, 3) array_like of int
        Triangles.
    """
    F = np.asarray(F, dtype=np.int64)
    rows = np.empty(len(F), dtype=object)
    rows[:] = list(map(tuple, F.tolist()))
    return rows


class EmbreeBackend:
    """Embree BVH over one triangle mesh (in the mesh's own space).

    Built only through embreex's public API (``EmbreeScene`` +
    ``TriangleMesh``): never through the Embree library directly, which in a
    Blender that links its own Embree can be another library than the one
    that made embreex's device (a crash of the application).

    Parameters
    ----------
    V : (n, 3) array_like of float
        Vertices.
    F : (m, 3) array_like of int
        Triangles, ``m >= 1``.
    rows : (m,) object ndarray, optional
        :func:`triangle_rows` of ``F``, prepared once per topology: the fast
        path (same BVH, same hits; see there).
    """

    name = "embree"

    def __init__(self, V, F, rows=None, parts=None):
        if _EMBREE_ERROR is not None:
            raise BackendUnavailable(embree_error())
        self._starts = None  # first triangle of each geometry (parts only)
        if parts is not None:
            self._build_parts(parts)
        else:
            V = np.ascontiguousarray(V, dtype=np.float32)
            self._scene = _rs.EmbreeScene()
            if rows is None or len(rows) != len(F) or not self._build_fast(V, F, rows):
                _mc.TriangleMesh(self._scene, V, np.ascontiguousarray(F, dtype=np.int32))
        # Commit now (Embree commits lazily on the first query) so that the
        # threads of a split batch never race to commit the same scene.
        one = np.zeros((1, 3), np.float32)
        self._scene.run(one, one + np.float32(1.0), dists=np.ones(1, np.float32))

    def _build_parts(self, parts):
        """One Embree geometry per part ``(V, F, rows)`` (see :func:`make_parts_backend`):
        each the fast way (:func:`triangle_rows`), else every part from plain arrays."""
        self._starts = np.cumsum([0] + [len(F) for _, F, _ in parts[:-1]]).astype(np.int64)
        self._scene = _rs.EmbreeScene()
        try:
            for V, _, rows in parts:
                _mc.TriangleMesh(self._scene, np.asarray(V, np.float32).astype(object), rows)
            fast = self._probe(np.asarray(parts[0][0], np.float32), parts[0][1])
        except Exception:  # noqa: BLE001 - a refusal only means: build the slow way
            fast = False
        if not fast:
            self._scene = _rs.EmbreeScene()
            for V, F, _ in parts:
                _mc.TriangleMesh(self._scene, np.ascontiguousarray(V, dtype=np.float32),
                                 np.ascontiguousarray(F, dtype=np.int32))

    def _build_fast(self, V, F, rows) -> bool:
        """``TriangleMesh`` fed Python objects (see :func:`triangle_rows`).

        The float32 vertices become Python floats, which convert back to the
        same float32 values. Should an embreex release refuse these inputs,
        or build something else from them (checked with one ray through the
        middle of the first and last triangle), the scene is made again from
        plain arrays: the fast path can cost time, never a result.
        """
        try:
            _mc.TriangleMesh(self._scene, V.astype(object), rows)
        except Exception:  # noqa: BLE001 - a refusal only means: build the slow way
            self._scene = _rs.EmbreeScene()
            return False
        if not self._probe(V, F):
            self._scene = _rs.EmbreeScene()
            return False
        return True

    def _probe(self, V, F) -> bool:
        """Do rays through the centroids of the first and last triangle hit a
        triangle at the centroid? (non-degenerate ones only)"""
        F = np.asarray(F)
        pick = np.unique([0, len(F) - 1])
        tri = V[F[pick]].astype(np.float64)  # (k, 3, 3)
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        ln = np.linalg.norm(n, axis=1)
        ok = ln > 0
        if not ok.any():
            return True
        c = tri[ok].mean(axis=1)
        # a short ray across the plane (nothing else is likely that close)
        size = 0.05 * np.sqrt(ln[ok])[:, None] * n[ok] / ln[ok][:, None]
        o = (c + size).astype(np.float32)
        d = (-2.0 * size).astype(np.float32)
        r = self._scene.run(o, d, dists=np.ones(len(o), np.float32), query="INTERSECT", output=1)
        t = np.asarray(r["tfar"], np.float64)
        return bool(((np.asarray(r["primID"]) >= 0) & (np.abs(t - 0.5) < 0.25)).all())

    def _run(self, o, d, tmax, query="INTERSECT"):
        return self._scene.run(o, d, dists=tmax, query=query)

    def any_hit(self, o, d, tmax, threads: int = 1):
        """Does each ray hit any triangle within ``tmax`` (k,) bool.

        Embree's occlusion query: it stops at the first triangle found, about
        12 % faster than :meth:`first_hit` on rays near a surface, with the
        same answer (the same watertight triangle test).
        """
        return self.first_hit(o, d, tmax, threads, query="OCCLUDED") == 0

    def first_hit(self, o, d, tmax, threads: int = 1, query="INTERSECT"):
        """Index of the first triangle hit by each ray, -1 for none.

        Parameters
        ----------
        o, d : (k, 3) ndarray
            Ray origins and unnormalized directions.
        tmax : (k,) ndarray or float
            Largest ray parameter that counts.
        threads : int
            Split the batch over this many threads (the result does not depend
            on it).

        Returns
        -------
        (k,) ndarray of int32
        """
        if self._starts is not None and query == "INTERSECT":  # (parts: indices mapped)
            return self.hit_details(o, d, tmax)[0]
        o = np.ascontiguousarray(o, dtype=np.float32)
        d = np.ascontiguousarray(d, dtype=np.float32)
        k = len(o)
        tmax = np.ascontiguousarray(np.broadcast_to(tmax, (k,)), dtype=np.float32)
        if k == 0:
            return np.empty(0, np.int32)
        n = int(min(threads, max(1, k // tol.MIN_RAYS_PER_THREAD)))
        if n <= 1 or getattr(_local, "in_pool", False):
            # (on a pool thread: waiting for the pool's other threads could deadlock)
            return np.asarray(self._run(o, d, tmax, query), dtype=np.int32)
        bounds = np.linspace(0, k, n + 1).astype(np.int64)
        # The caller traces the last chunk itself rather than idling on a lock.
        futs = [
            _executor(n).submit(self._run, o[a:b], d[a:b], tmax[a:b], query)
            for a, b in zip(bounds[:-2], bounds[1:-1], strict=True)
        ]
        a = bounds[-2]
        try:
            last = np.asarray(self._run(o[a:], d[a:], tmax[a:], query), dtype=np.int32)
        except BaseException:
            for f in futs:  # never leave chunks running; this error is the one raised
                f.exception()
            raise
        return np.concatenate([np.asarray(f.result(), dtype=np.int32) for f in futs] + [last])

    def hit_details(self, o, d, tmax, normals=False):
        """First hit with its ray parameter.

        Returns
        -------
        prim : (k,) int32
            Triangle index, -1 for none.
        t : (k,) float64
            Ray parameter of the hit (``inf`` for none).
        Ng : (k, 3) float32
            With ``normals``: the hit triangle's unnormalized geometric
            normal ``(v1 - v0) x (v2 - v0)`` (its winding's side).
        """
        o = np.ascontiguousarray(o, dtype=np.float32)
        d = np.ascontiguousarray(d, dtype=np.float32)
        k = len(o)
        if k == 0:
            empty = (np.empty(0, np.int32), np.empty(0))
            return empty + (np.empty((0, 3), np.float32),) if normals else empty
        tmax = np.ascontiguousarray(np.broadcast_to(tmax, (k,)), dtype=np.float32)
        r = self._scene.run(o, d, dists=tmax, query="INTERSECT", output=1)
        prim = np.asarray(r["primID"], dtype=np.int32)
        if self._starts is not None:  # (parts: the index in the parts' order)
            hit = prim >= 0
            prim[hit] += self._starts[np.asarray(r["geomID"])[hit]].astype(np.int32)
        t = np.where(prim >= 0, np.asarray(r["tfar"], dtype=np.float64), np.inf)
        if normals:
            return prim, t, np.asarray(r["Ng"])
        return prim, t


class NumpyBackend:
    """Brute-force reference with the same API as :class:`EmbreeBackend`.

    Moller-Trumbore in float64, chunked so memory stays bounded. Two-sided
    (like Embree's default): both front and back faces are hit.
    """

    name = "numpy"

    def __init__(self, V, F):
        V = np.asarray(V, dtype=np.float64)
        F = np.asarray(F, dtype=np.int64)
        self._v0 = V[F[:, 0]]
        self._e1 = V[F[:, 1]] - self._v0
        self._e2 = V[F[:, 2]] - self._v0

    def crossings(self, o, d):
        """(k,) number of triangles each ray ``o + t d`` (t >= 0, no end) crosses."""
        o = np.asarray(o, dtype=np.float64)
        d = np.asarray(d, dtype=np.float64)
        out = np.zeros(len(o), np.int64)
        step = max(1, 2_000_000 // max(1, len(self._v0)))
        for a in range(0, len(o), step):
            out[a : a + step] = np.isfinite(self._all_t(o[a : a + step], d[a : a + step])).sum(1)
        return out

    def _all_t(self, o, d):
        """(k, m) ray parameter of every ray-triangle hit (inf where none)."""
        p = np.cross(d[:, None, :], self._e2[None])
        det = np.einsum("kmi,mi->km", p, self._e1)
        ok = np.abs(det) > 1e-300
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o[:, None, :] - self._v0[None]
        u = np.einsum("kmi,kmi->km", s, p) * inv
        q = np.cross(s, self._e1[None])
        v = np.einsum("ki,kmi->km", d, q) * inv
        t = np.einsum("mi,kmi->km", self._e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0)
        return np.where(hit, t, np.inf)

    def hit_details(self, o, d, tmax, normals=False):
        o = np.asarray(o, dtype=np.float64)
        d = np.asarray(d, dtype=np.float64)
        k = len(o)
        tmax = np.broadcast_to(np.asarray(tmax, dtype=np.float64), (k,))
        prim = np.full(k, -1, np.int32)
        tt = np.full(k, np.inf)
        m = max(1, len(self._v0))
        step = max(1, 2_000_000 // m)
        for a in range(0, k, step):
            t = self._all_t(o[a : a + step], d[a : a + step])
            j = np.argmin(t, axis=1)
            tj = t[np.arange(len(t)), j]
            hit = tj <= tmax[a : a + step]
            prim[a : a + step][hit] = j[hit]
            tt[a : a + step][hit] = tj[hit]
        if normals:
            ng = np.cross(self._e1, self._e2)[np.maximum(prim, 0)]
            return prim, tt, np.where((prim >= 0)[:, None], ng, 0.0)
        return prim, tt

    def first_hit(self, o, d, tmax, threads: int = 1):
        return self.hit_details(o, d, tmax)[0]

    def any_hit(self, o, d, tmax, threads: int = 1):
        return self.first_hit(o, d, tmax) >= 0


def make_parts_backend(name: str | None, parts):
    """A backend over the triangles of several ``parts`` (a non-empty list of ``(V,
    F, rows)``: each its own vertices (k, 3), triangles indexing them and their
    :func:`triangle_rows`), answering as one mesh of them in that order: triangle
    ``i`` of part ``j`` is triangle ``sum(len(F) of the parts before j) + i``.

    With embree each part is one geometry built from its prepared rows, so a mesh
    cut into parts once can have any subset of them built without preparing rows
    again (``Shells``' reachable parts).
    """
    if name in (None, "embree"):
        return EmbreeBackend(None, None, parts=parts)
    if name == "numpy":
        base = np.cumsum([0] + [len(V) for V, _, _ in parts[:-1]])
        V = np.concatenate([np.asarray(V, np.float64) for V, _, _ in parts])
        F = np.concatenate([np.asarray(F, np.int64) + b for (_, F, _), b in zip(parts, base,
                                                                              strict=True)])
        return NumpyBackend(V, F)
    raise ValueError(f"unknown ray backend {name!r}; use 'embree' or 'numpy'")


def make_backend(name: str | None, V, F, rows=None):
    """Build the backend called ``name`` ('embree', 'numpy'; None = embree).

    ``rows``: :func:`triangle_rows` of ``F`` (embree only: a faster build).
    """
    if name in (None, "embree"):
        return EmbreeBackend(V, F, rows)
    if name == "numpy":
        return NumpyBackend(V, F)
    raise ValueError(f"unknown ray backend {name!r}; use 'embree' or 'numpy'")
