"""Fur Attach, the optional input stage: the binding's storage and the attached curves.

``furcollide.fur_attach_bind`` (:mod:`..ops.attach`) ties every curve of the source to the
Surface triangle under its root at the reference frame (:func:`core.pipeline.bind`). The
binding is saved on the source object (:data:`ATTACH_PROPERTY`) and cached in the setup's
runtime; each frame :func:`attach_input` reads the evaluated Surface and
:meth:`AttachInput.points` moves the curves rigidly with it (only when the points are
needed: a baked frame shown checks its record with :attr:`AttachInput.digest`).
"""

from __future__ import annotations

import io

import numpy as np

from ...core import framecache
from ...core.pipeline import Binding
from ..blender import bridge
from ..store.registry import get_runtime
from .clock import clock

#: Custom property (bytes of an ``np.savez`` file) on the source object holding the
#: Fur Attach binding (``core.pipeline.Binding.arrays()`` plus the surface topology
#: key). Saved with the .blend file; the leading underscore hides it in the UI.
ATTACH_PROPERTY = "_furcollide_attach"


def store_binding(ob, binding, topology_key, attach_id) -> None:
    """Persist ``binding`` on the source ``ob`` and keep it in its runtime."""
    buf = io.BytesIO()
    np.savez(buf, topology_key=np.asarray(topology_key, np.int64), **binding.arrays())
    if ATTACH_PROPERTY in ob.keys():
        # Blender truncates bytes assigned over an existing bytes property at
        # their first NUL byte: a second Bind would corrupt the binding.
        del ob[ATTACH_PROPERTY]
    ob[ATTACH_PROPERTY] = buf.getvalue()
    rt = get_runtime(ob)
    if rt is not None:
        rt.attach = (attach_id, binding, tuple(int(k) for k in topology_key))


def has_binding(ob) -> bool:
    """Does the source ``ob`` hold a Fur Attach binding?"""
    try:
        return ATTACH_PROPERTY in ob.keys()
    except (TypeError, AttributeError):
        return False


def clear_binding(ob) -> None:
    """Forget the Fur Attach binding of the source ``ob``."""
    if has_binding(ob):
        del ob[ATTACH_PROPERTY]
    rt = get_runtime(ob, create=False)
    if rt is not None:
        rt.attach = None


def load_binding(ob):
    """(Binding, surface topology key) of the source ``ob`` (cached in its runtime).

    Raises ValueError when the setup has no binding.
    """
    s = ob.furcollide
    rt = get_runtime(ob)
    if rt.attach is not None and rt.attach[0] == s.attach_id:
        return rt.attach[1], rt.attach[2]
    if not has_binding(ob):
        raise ValueError(
            "Fur Attach is on but the curves are not bound to the Surface: "
            "press Bind (Fur Pipeline > Fur Attach)"
        )
    raw = ob[ATTACH_PROPERTY]
    if not isinstance(raw, bytes):
        raw = bytes(raw)
    with np.load(io.BytesIO(raw), allow_pickle=False) as d:
        binding = Binding.from_arrays(d)
        key = tuple(int(k) for k in d["topology_key"])
    rt.attach = (s.attach_id, binding, key)
    return binding, key


def _bind_again(ob) -> str:
    """Advice that works when followed: Bind is refused on a baked setup
    ('free the bake before binding'), so there it says Free Bake first."""
    if ob.furcollide.is_baked:
        return "press Free Bake, then Bind again (Fur Pipeline > Fur Attach)"
    return "press Bind again"


def attached_points(ob, depsgraph, offsets) -> np.ndarray:
    """Fur Attach input stage: the bound curves moved rigidly with the evaluated
    Surface of the source ``ob`` (world space, (P, 3) float64)."""
    return attach_input(ob, depsgraph, offsets, ob.furcollide.core_threads).points()


class AttachInput:
    """One frame's Fur Attach input: the binding and the evaluated Surface's world
    vertices, checked (:func:`attach_input`). The attached points are a function of
    the binding (the settings' ``attach_id``) and the bound triangles' vertices alone,
    so :attr:`digest` stands for them in a frame-inputs record and a baked frame
    shown never attaches."""

    def __init__(self, binding, V_world, offsets, threads=None):
        self.binding, self.V_world, self.offsets = binding, V_world, offsets
        self.threads = threads  # (the setup's Threads; None: all CPUs)
        self._points = None

    @property
    def digest(self) -> int:
        """Digest of what :meth:`points` depends on besides the binding: the world
        positions of the Surface vertices it reads (``Binding.used_vertices``: an
        edit elsewhere on the Surface, away from the roots, is not a change) and
        the curve layout."""
        return framecache.digest(self.V_world[self.binding.used_vertices], self.offsets)

    def points(self) -> np.ndarray:
        """The attached curves, world space (P, 3) float64 (computed once)."""
        if self._points is None:
            with clock.timing("attach"):
                self._points = self.binding.apply(self.V_world, self.threads)
        return self._points


def attach_input(ob, depsgraph, offsets, threads=None) -> AttachInput:
    """The Fur Attach input of the source ``ob`` at this frame: the binding checked
    against the source's curves and the evaluated Surface's topology (ValueError
    naming what to press otherwise), and that Surface's world vertices. ``threads``:
    the setup's Threads for moving the curves (None: all CPUs)."""
    with clock.timing("attach"):
        return _attach_input(ob, depsgraph, offsets, threads)


def _attach_input(ob, depsgraph, offsets, threads) -> AttachInput:
    binding, key = load_binding(ob)
    surf = ob.data.surface
    if surf is None or surf.type != "MESH":
        raise ValueError(
            "Fur Attach needs the hair's Surface mesh (Object Data > Surface)"
        )
    if not np.array_equal(binding.offsets, offsets):
        C, P = len(binding.offsets) - 1, int(binding.offsets[-1])
        raise ValueError(
            f"Fur Attach: the source hair has {len(offsets) - 1} curves / {int(offsets[-1])} "
            f"points but was bound with {C} / {P}: {_bind_again(ob)}"
        )
    se = surf.evaluated_get(depsgraph)
    me = se.data
    now = bridge.mesh_topology_key(me)
    if not bridge.same_topology(now, key):
        what = (
            f"{now[0]} vertices / {now[1]} faces, bound: {key[0]} / {key[1]}"
            if tuple(now[:2]) != tuple(key[:2])
            else "its vertices or faces were reordered"
        )
        raise ValueError(
            f"Fur Attach: the Surface '{surf.name}' changed topology since binding "
            f"({what}): {_bind_again(ob)}"
        )
    V = bridge.mesh_vertices(me).astype(np.float64)
    M = bridge.matrix(se)
    return AttachInput(binding, V @ M[:3, :3].T + M[:3, 3], offsets, threads)
