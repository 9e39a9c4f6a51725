"""CPU accounting helpers for the benchmark (Linux; harmless no-ops elsewhere).

* :func:`task_cpu` reads every thread's CPU time from ``/proc/self/task``, so
  a frame's CPU can be split between the main thread, the core's Python
  worker threads and native threads (OpenBLAS's workers, embree's own).
* :class:`OpenBlas` gets/sets the thread count of numpy's bundled OpenBLAS
  through ctypes (what threadpoolctl does). numpy's OpenBLAS starts one
  worker per extra CPU, and after every large matmul those workers spin for a
  while, taking a CPU from the ray threads on a 2-CPU machine.
"""

from __future__ import annotations

import ctypes
import glob
import os

import numpy as np

_HZ = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def task_cpu() -> dict[int, float]:
    """CPU seconds (user + system) of every thread of this process, by TID."""
    out = {}
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return out
    for t in tids:
        try:
            with open(f"/proc/self/task/{t}/stat") as fh:
                s = fh.read()
        except OSError:
            continue
        f = s[s.rindex(")") + 2 :].split()
        out[int(t)] = (int(f[11]) + int(f[12])) / _HZ
    return out


class OpenBlas:
    """numpy's OpenBLAS thread count, or ``available = False``."""

    def __init__(self):
        self._get = self._set = None
        pats = [
            os.path.join(os.path.dirname(np.__file__) + ".libs", "libopenblas*.so*"),
            os.path.join(os.path.dirname(np.__file__), ".dylibs", "libopenblas*.dylib"),
        ]
        for pat in pats:
            for path in glob.glob(pat):
                try:
                    lib = ctypes.CDLL(path)
                except OSError:
                    continue
                for suffix in ("64_", ""):
                    g = getattr(lib, f"openblas_get_num_threads{suffix}", None)
                    s = getattr(lib, f"openblas_set_num_threads{suffix}", None)
                    if g is not None and s is not None:
                        self._get, self._set = g, s
                        s.argtypes = [ctypes.c_int]
                        return

    @property
    def available(self) -> bool:
        return self._get is not None

    def get(self) -> int | None:
        return int(self._get()) if self._get else None

    def set(self, n: int) -> None:
        if self._set:
            self._set(int(n))


_BLAS = OpenBlas()


class single_blas:
    """Context manager: OpenBLAS on one thread inside (the floor uses it so that
    its single small matmul does not leave BLAS workers spinning against the
    ray threads), the previous count restored on exit."""

    def __enter__(self):
        self._n = _BLAS.get()
        if self._n not in (None, 1):
            _BLAS.set(1)
        return self

    def __exit__(self, *exc):
        if self._n not in (None, 1):
            _BLAS.set(self._n)
        return False
