"""Fur Attach (paper section 2): curves rigidly follow an animated growth surface.

At the reference pose each curve's root is bound to its closest surface
triangle (face index, barycentric coordinates) and its CVs are stored in
an orthonormal frame of that triangle. Every frame, the curve is moved
rigidly with the frame of the same triangle on the deformed surface. No UV
map is needed; only the vertex positions may change (deforming, skinned,
shape-keyed surfaces), not the topology.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .. import rotations as rot
from .. import tolerances as tol
from ..closest import barycentric, closest_faces
from ..curves import check_curves, uniform_size
from ..errors import ColliderError, InputError
from ..mesh import check_surface, degenerate_faces
from ..rays import in_two, thread_count


def _frames(V, F, face):
    """Origin-free frames of triangles ``face``: (k, 3, 3), columns (edge, bitangent, normal).

    Returns
    -------
    R : (k, 3, 3) ndarray
    ok : (k,) bool
        False where the triangle is degenerate (R is then garbage).
    """
    return _frames_of(V[F[face]])


def _frames_of(T, rows=False):
    """:func:`_frames` of triangles given by their corners ``T`` (k, 3, 3); with
    ``rows``, the transposed frames (rows edge, bitangent, normal)."""
    axes, ok = _frame_axes(T)
    out = np.empty((len(T), 3, 3))
    for k, v in enumerate(axes):
        if rows:
            out[:, k, :] = v.T
        else:
            out[:, :, k] = v.T
    return out, ok


def _frame_axes(T):
    """The frame axes (edge, bitangent, normal) of triangles ``T`` (k, 3, 3) as
    component arrays, each (3, k), and ``ok`` (k,) (False where the triangle is
    degenerate: its axes are then garbage).

    Computed on component arrays (the products of ``np.cross`` and the sums of
    ``np.linalg.norm``, in long passes).
    """
    Tc = np.moveaxis(T, -1, 0)  # (3, k, 3): component, triangle, corner
    a, b, c = Tc[:, :, 0], Tc[:, :, 1], Tc[:, :, 2]
    e = b - a
    ca = c - a
    n = rot.cross3(e, ca)
    le = np.sqrt(rot.dot3(e, e))
    ln = np.sqrt(rot.dot3(n, n))
    scale = np.maximum(np.sqrt(rot.dot3(ca, ca)), le)
    ok = (le > 0) & (ln > tol.ATTACH_FRAME_MIN_SIN * scale**2)
    e /= np.where(ok, le, 1.0)
    n /= np.where(ok, ln, 1.0)
    t = rot.cross3(n, e)
    return (e, t, n), ok


def _barycentric(p, a, b, c):
    """Barycentric coordinates (k, 3) of points p (closest points) in triangles (a, b, c)."""
    bary = barycentric(p, a, b, c)
    # the closest point is on the triangle: clamp rounding and renormalize
    bary = np.clip(bary, 0.0, 1.0)
    return bary / bary.sum(1, keepdims=True)


def surface_values(V, F, values, points):
    """Per-vertex ``values`` interpolated at the closest surface point of each point.

    Used to read a vertex group or attribute of the growth surface at the
    hair roots (e.g. the Fur Sampler's area of interest).

    Parameters
    ----------
    V : (n, 3) float
        Surface vertices.
    F : (m, 3) int
        Surface triangles.
    values : (n,) float
        One value per vertex.
    points : (k, 3) float
        Query points (same space as ``V``).

    Returns
    -------
    (k,) float64
        Barycentric interpolation on each point's closest triangle.
    """
    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    values = np.asarray(values, np.float64)
    if values.shape != (len(V),):
        raise InputError(f"values must have one entry per vertex ({len(V)}), got {values.shape}")
    P, face = closest_faces(V, F, np.asarray(points, np.float64))
    tri = F[face]
    bary = _barycentric(P, V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]])
    return np.einsum("ij,ij->i", bary, values[tri])


@dataclass
class Binding:
    """Curves bound to a growth surface (result of :func:`bind`). Arrays only.

    Attributes
    ----------
    face : (C,) int64
        Surface triangle of each root.
    bary : (C, 3) float64
        Barycentric coordinates of each root's surface point in its triangle.
    local : (P, 3) float64
        Every CV in its triangle's frame (edge, bitangent, normal), relative
        to the root's surface point (roots are 0 when snapped).
    offsets : (C+1,) int64
    faces : (m, 3) int64
        The surface's triangles.
    n_vertices : int
        The surface's vertex count (``apply`` checks it).
    frame_ref : (C, 3, 3) float64
        Reference frames, used where a triangle collapses later.
    root_distance : (C,) float64
        Distance of each root to the surface at bind time (snapped away
        when ``snap_roots``).

    Save with ``np.savez(path, **binding.arrays())`` and load with
    ``Binding.from_arrays(np.load(path))``.
    """

    face: np.ndarray
    bary: np.ndarray
    local: np.ndarray
    offsets: np.ndarray
    faces: np.ndarray
    n_vertices: int
    frame_ref: np.ndarray
    root_distance: np.ndarray

    def arrays(self) -> dict:
        """The binding as a dict of numpy arrays (for ``np.savez``)."""
        return {
            "face": self.face, "bary": self.bary, "local": self.local,
            "offsets": self.offsets, "faces": self.faces,
            "n_vertices": np.array(self.n_vertices), "frame_ref": self.frame_ref,
            "root_distance": self.root_distance,
        }

    @classmethod
    def from_arrays(cls, d) -> Binding:
        """Inverse of :meth:`arrays` (accepts an ``np.load`` result)."""
        try:
            return cls(
                face=np.asarray(d["face"], np.int64), bary=np.asarray(d["bary"], np.float64),
                local=np.asarray(d["local"], np.float64),
                offsets=np.asarray(d["offsets"], np.int64),
                faces=np.asarray(d["faces"], np.int64), n_vertices=int(d["n_vertices"]),
                frame_ref=np.asarray(d["frame_ref"], np.float64),
                root_distance=np.asarray(d["root_distance"], np.float64),
            )
        except KeyError as exc:
            raise InputError(f"binding arrays lack {exc}") from None

    @cached_property
    def used_vertices(self) -> np.ndarray:
        """(k,) int64, sorted: the surface vertices :meth:`apply` reads (those of the
        bound triangles). The attached curves are a function of these alone: a
        change elsewhere on the surface cannot move them."""
        return np.unique(self.faces[self.face])

    def roots(self, V_now) -> np.ndarray:
        """(C, 3) root surface points on the surface ``V_now`` (barycentric)."""
        V = self._check(V_now)
        T = V[self.faces[self.face]]  # (C, 3, 3)
        return np.einsum("ck,cki->ci", self.bary, T)

    def _check(self, V_now):
        try:
            V = np.asarray(V_now, np.float64)
        except Exception as exc:
            raise ColliderError(f"surface vertices must be an (n, 3) array: {exc}") from None
        if V.shape != (self.n_vertices, 3):
            raise ColliderError(
                f"surface vertices have shape {V.shape}, the binding expects "
                f"({self.n_vertices}, 3) (same topology as at bind time)"
            )
        if np.isfinite(V).all():  # (one pass over the surface; vertices only on error)
            return V
        used = self.faces[self.face].ravel()
        bad = ~np.isfinite(V[used]).all(axis=1)
        if bad.any():
            raise ColliderError(f"surface vertex {int(used[np.argmax(bad)])} is not finite")
        return V

    def apply(self, V_now, threads=None) -> np.ndarray:
        """Move every curve rigidly with its triangle's frame on the surface ``V_now``.

        Parameters
        ----------
        V_now : (n, 3) array_like of float
            The deformed growth surface (same topology as at bind time).
        threads : int or None, default None
            Threads to use (None: every CPU). From ``tolerances.SPLIT_MIN_ITEMS``
            curves of one CV count the curves are moved in parts, one per
            thread; the result is the same bit for bit.

        Returns
        -------
        (P, 3) ndarray of float64
            Roots (when snapped) are exactly the barycentric points of their
            triangles. A triangle collapsed to zero area keeps its reference
            orientation (its curves only translate).
        """
        threads = thread_count(threads)
        V = self._check(V_now)
        n = uniform_size(self.offsets)
        if not n:
            T = V[self.faces[self.face]]  # (C, 3, 3)
            O = np.einsum("ck,cki->ci", self.bary, T)
            Rt, ok = _frames_of(T, rows=True)  # R transposed
            if not ok.all():
                Rt[~ok] = self.frame_ref[~ok].transpose(0, 2, 1)
            sizes = np.diff(self.offsets)
            curve = np.repeat(np.arange(len(sizes)), sizes)
            return O[curve] + np.einsum("pji,pj->pi", Rt[curve], self.local)
        # Every curve n CVs: a CV is O + l0 e + l1 t + l2 n (its frame
        # coordinates l on the triangle's axes), on component arrays (k, n) per
        # coordinate: long passes, no per-CV gathers. (np.matmul would hand each
        # small product to BLAS, whose calls from two threads wait on each
        # other, and whose kernel, and so the last bit, depends on the CPU.)
        C = len(self.face)
        out = np.empty((C, n, 3))
        local = self._local_components  # (3, C, n)

        def move(a, b):  # curves a:b
            T = V[self.faces[self.face[a:b]]]  # (k, 3, 3)
            axes, ok = _frame_axes(T)
            if not ok.all():  # a collapsed triangle keeps its reference frame
                for k, v in enumerate(axes):
                    v[:, ~ok] = self.frame_ref[a:b][~ok][:, :, k].T
            O = np.einsum("ck,cki->ci", self.bary[a:b], T)  # as roots(): the same bits
            oc = np.empty((3, b - a, n))
            for i in range(3):
                o = np.multiply(local[0, a:b], axes[0][i, :, None], out=oc[i])
                o += local[1, a:b] * axes[1][i, :, None]
                o += local[2, a:b] * axes[2][i, :, None]
                o += O[:, i, None]
            out[a:b] = oc.transpose(1, 2, 0)

        in_two(move, C, threads, tol.SPLIT_MIN_ITEMS)
        return out.reshape(-1, 3)

    @cached_property
    def _local_components(self) -> np.ndarray:
        """(3, C, n) :attr:`local` by coordinate, for curves of one CV count ``n``."""
        n = uniform_size(self.offsets)
        return np.ascontiguousarray(self.local.reshape(-1, n, 3).transpose(2, 0, 1))


def bind(points, offsets, V_ref, F, snap_roots=True, drop_degenerate=False) -> Binding:
    """Fur Attach: bind curves to their closest growth-surface triangles.

    Parameters
    ----------
    points : (P, 3) array_like of float
        Curves at the reference pose, same space as ``V_ref``.
    offsets : (C+1,) array_like of int
    V_ref : (n, 3) array_like of float
        Growth surface vertices at the reference pose.
    F : (m, 3) array_like of int
        Its triangles.
    snap_roots : bool, default True
        Translate each curve so its root lies exactly on the surface (the
        identity at the reference pose is then exact only for roots that
        are on the surface, as Blender's are).
    drop_degenerate : bool, default False
        Ignore zero-area triangles instead of raising.

    Returns
    -------
    Binding

    Raises
    ------
    InputError
        Malformed curves.
    ColliderError
        Empty surface, indices out of range, or a degenerate triangle (the
        message names the face) unless ``drop_degenerate``.
    """
    pts, off = check_curves(points, offsets)
    V, F = check_surface(V_ref, F, "growth surface")
    # degenerate by the colliders' rule, or too thin to give its curves an orientation
    bad = degenerate_faces(V, F) | ~_frames(V, F, np.arange(len(F)))[1]
    if bad.any() and not drop_degenerate:
        i = int(np.argmax(bad))
        raise ColliderError(
            f"growth surface: face {i} {F[i].tolist()} is degenerate (zero area); "
            f"{int(bad.sum())} such faces (use drop_degenerate=True to ignore them)"
        )
    valid = np.flatnonzero(~bad)
    if len(valid) == 0:
        raise ColliderError("growth surface: every face is degenerate")
    roots = pts[off[:-1]]
    S, fi = closest_faces(V, F[valid], roots)
    face = valid[fi]
    T = V[F[face]]
    bary = _barycentric(S, T[:, 0], T[:, 1], T[:, 2])
    O = np.einsum("ck,cki->ci", bary, T)
    R, _ = _frames(V, F, face)
    sizes = np.diff(off)
    curve = np.repeat(np.arange(len(sizes)), sizes)
    origin = roots[curve] if snap_roots else O[curve]
    local = np.einsum("pji,pj->pi", R[curve], pts - origin)  # R^T (x - origin)
    if snap_roots:
        local[off[:-1]] = 0.0
    return Binding(face=face.astype(np.int64), bary=bary, local=local, offsets=off,
                   faces=F, n_vertices=len(V), frame_ref=R,
                   root_distance=np.linalg.norm(roots - S, axis=1))
