"""Zero-copy triangle geometry for embreex scenes (Linux only; a safe fallback elsewhere).

Why: embreex's ``TriangleMesh`` copies vertices and triangles into Embree one
element at a time through Python indexing (about 90 ms for 130k triangles on
top of the ~35 ms BVH build). A deforming collider pays that every frame. Here
the same Embree library embreex loaded is called through :mod:`ctypes`: the
geometry *shares* our numpy buffers (``rtcSetSharedGeometryBuffer``, no copy)
and is attached to an ordinary ``embreex.rtcore_scene.EmbreeScene``, so the
queries still run in embreex's own loop (``EmbreeScene.run``, GIL released).
Same build quality as embreex: the BVH, and therefore every hit, is the same.

Safety: the Embree scene handle is read from the ``EmbreeScene`` object only
after its memory layout is proven (object sizes, a sentinel written through
its public ``is_committed`` field, and the address of the device object we
passed in), and only when the library found is the very file already mapped
into this process by embreex. Anything unexpected raises
:class:`NativeUnavailable` and the caller falls back to ``TriangleMesh``.
``FURCOLLIDE_EMBREE_NATIVE=0`` switches this module off.
"""

from __future__ import annotations

import ctypes
import glob
import os
import sys
import threading

import numpy as np

# Embree 4 constants (rtcore_common.h / rtcore_geometry.h / rtcore_buffer.h).
_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX = 0
_BUFFER_TYPE_VERTEX = 1
_FORMAT_UINT3 = 0x5003
_FORMAT_FLOAT3 = 0x9003
_ERROR_NONE = 0
_BUILD_QUALITY_LOW = 0
_SCENE_FLAG_DYNAMIC = 1
#: A sentinel written into ``EmbreeScene.is_committed`` to find its offset.
_SENTINEL = 0x5A17C0DE

_lock = threading.Lock()
_lib = None
_lib_error = ""


class NativeUnavailable(RuntimeError):
    """The zero-copy path cannot be used here (the reason is the message)."""


def _mapped_library() -> str:
    """Path of the Embree 4 library embreex loaded into this process."""
    import embreex

    root = os.path.dirname(os.path.abspath(embreex.__file__))
    candidates = glob.glob(os.path.join(root, "..", "embreex.libs", "libembree4*.so*"))
    candidates = [os.path.realpath(p) for p in candidates]
    if len(candidates) != 1:
        raise NativeUnavailable(f"expected one bundled libembree4, found {len(candidates)}")
    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as fh:
            mapped = {line.split(None, 5)[-1].strip() for line in fh if "/" in line}
    except OSError as exc:
        raise NativeUnavailable(f"cannot read /proc/self/maps: {exc}") from None
    if candidates[0] not in {os.path.realpath(p) for p in mapped}:
        raise NativeUnavailable("the bundled libembree4 is not the one loaded")
    return candidates[0]


def _load():
    global _lib, _lib_error
    with _lock:
        if _lib is not None or _lib_error:
            return _lib
        try:
            if os.environ.get("FURCOLLIDE_EMBREE_NATIVE", "1") == "0":
                raise NativeUnavailable("switched off by FURCOLLIDE_EMBREE_NATIVE=0")
            if not sys.platform.startswith("linux") or ctypes.sizeof(ctypes.c_void_p) != 8:
                raise NativeUnavailable("only on 64-bit Linux")
            from embreex import rtcore_scene  # noqa: F401 - loads the library first

            lib = ctypes.CDLL(_mapped_library())
            vp, uint, size = ctypes.c_void_p, ctypes.c_uint, ctypes.c_size_t
            sig = {
                "rtcNewGeometry": (vp, [vp, ctypes.c_int]),
                "rtcSetSharedGeometryBuffer": (
                    None, [vp, ctypes.c_int, uint, ctypes.c_int, vp, size, size, size]),
                "rtcCommitGeometry": (None, [vp]),
                "rtcAttachGeometry": (uint, [vp, vp]),
                "rtcReleaseGeometry": (None, [vp]),
                "rtcCommitScene": (None, [vp]),
                "rtcGetDeviceError": (ctypes.c_int, [vp]),
                "rtcSetSceneBuildQuality": (None, [vp, ctypes.c_int]),
                "rtcSetSceneFlags": (None, [vp, ctypes.c_int]),
                "rtcSetGeometryBuildQuality": (None, [vp, ctypes.c_int]),
            }
            for name, (res, args) in sig.items():
                fn = getattr(lib, name)
                fn.restype, fn.argtypes = res, args
            _lib = lib
        except Exception as exc:  # noqa: BLE001 - any failure means: use the fallback
            _lib_error = f"{type(exc).__name__}: {exc}"
        return _lib


def available() -> bool:
    """Can :func:`triangle_scene` be used in this process?"""
    return _load() is not None


def unavailable_reason() -> str:
    _load()
    return _lib_error


def _slot(obj, i: int) -> int:
    """The i-th pointer-sized field after the object header (CPython, 64-bit)."""
    return ctypes.c_uint64.from_address(id(obj) + 16 + 8 * i).value


def _handles(scene, device):
    """(RTCScene, RTCDevice) of an embreex scene created with ``device``, layout proven."""
    ts, td = type(scene), type(device)
    if ts.__basicsize__ != 40 or td.__basicsize__ != 24:
        raise NativeUnavailable("unexpected embreex object layout")
    old = scene.is_committed
    scene.is_committed = _SENTINEL
    try:
        ok = (_slot(scene, 1) & 0xFFFFFFFF) == _SENTINEL and _slot(scene, 2) == id(device)
    finally:
        scene.is_committed = old
    sc, dev = _slot(scene, 0), _slot(device, 0)
    if not ok or not sc or not dev:
        raise NativeUnavailable("unexpected embreex object layout")
    return sc, dev


def triangle_scene(V, F, fast_build=False):
    """An embreex scene holding the triangle mesh ``(V, F)``, committed.

    Parameters
    ----------
    V : (n, 3) array_like of float
        Vertices (converted to float32, as embreex does).
    F : (m, 3) array_like of int
        Triangles (indices in ``[0, n)``; checked by the caller).
    fast_build : bool
        Embree's low-quality build for dynamic scenes: about 4x faster to build
        (about 10 ms for 130k triangles), about 15 % slower to query; for meshes
        rebuilt every frame. The BVH depends only on ``(V, F, fast_build)``.

    Returns
    -------
    scene : embreex.rtcore_scene.EmbreeScene
        Query it with ``scene.run`` as usual.
    keep : tuple
        The shared buffers: keep them alive as long as ``scene``.

    Raises
    ------
    NativeUnavailable
        The path cannot be used (use ``TriangleMesh``).
    """
    lib = _load()
    if lib is None:
        raise NativeUnavailable(_lib_error)
    from embreex import rtcore as _rc
    from embreex import rtcore_scene as _rs

    device = _rc.EmbreeDevice()
    scene = _rs.EmbreeScene(device)
    sc, dev = _handles(scene, device)
    if fast_build:
        lib.rtcSetSceneFlags(sc, _SCENE_FLAG_DYNAMIC)
        lib.rtcSetSceneBuildQuality(sc, _BUILD_QUALITY_LOW)
    V = np.asarray(V)
    # Embree reads vertices with 16-byte loads: a stride of 16 and one padding row.
    vb = np.zeros((len(V) + 1, 4), np.float32)
    vb[:-1, :3] = V
    ib = np.ascontiguousarray(F, dtype=np.uint32)
    geom = lib.rtcNewGeometry(dev, _GEOMETRY_TYPE_TRIANGLE)
    if not geom:
        raise NativeUnavailable(f"rtcNewGeometry failed (error {lib.rtcGetDeviceError(dev)})")
    try:
        lib.rtcSetSharedGeometryBuffer(
            geom, _BUFFER_TYPE_INDEX, 0, _FORMAT_UINT3, ib.ctypes.data, 0, 12, len(ib))
        lib.rtcSetSharedGeometryBuffer(
            geom, _BUFFER_TYPE_VERTEX, 0, _FORMAT_FLOAT3, vb.ctypes.data, 0, 16, len(V))
        if fast_build:
            lib.rtcSetGeometryBuildQuality(geom, _BUILD_QUALITY_LOW)
        lib.rtcCommitGeometry(geom)
        lib.rtcAttachGeometry(sc, geom)
    finally:
        lib.rtcReleaseGeometry(geom)  # the scene holds its own reference
    lib.rtcCommitScene(sc)
    err = lib.rtcGetDeviceError(dev)
    if err != _ERROR_NONE:
        raise NativeUnavailable(f"Embree error {err} while building the scene")
    scene.is_committed = 1  # committed here: embreex must not commit again
    return scene, (vb, ib, device)
