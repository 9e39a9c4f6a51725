"""Colliders as artists make them: weld seams, drop duplicated faces, wind outward.

Meshes reach FurCollide with the usual accidents of modelling and import:
faces wound inward (a flipped normal, an import from another handedness),
mixed windings, a few duplicated faces, and seams whose vertices were never
merged (split normals, UV seams, an OBJ without "merge vertices"). Each of them
used to switch pinch detection off silently, or (inward winding with a Collision
Offset) build the offset shell inside the mesh. :func:`tidy` fixes the
*topology* the collider works with; the positions are never moved:

1. **Weld**: vertices closer than ``tol.WELD_REL`` of the mesh's size become one
   (the faces point at the first of them; the duplicates stay, unused).
2. **Duplicated faces** (the same three welded corners, either winding) count
   once.
3. **Winding**: made consistent across every edge two faces share, per connected
   part; a closed part is then wound outward (positive signed volume), an open
   one keeps the winding most of its faces had.

The result says what it changed, for the artist's status line.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from . import tolerances as tol


@dataclass(frozen=True)
class Tidy:
    """What :func:`tidy` made of a mesh.

    Attributes
    ----------
    faces : (m', 3) int32
        The faces to use: welded corners, no duplicates, outward windings.
    welded : int
        Vertices merged into another one at the same place.
    duplicates : int
        Faces dropped as duplicates of another face.
    collapsed : int
        Faces dropped because welding merged two of their corners.
    flipped : int
        Faces whose winding was reversed.
    open_edges : int
        Edges with one face only (0 with ``closed``).
    closed : bool
        Every edge shared by exactly two faces, wound consistently.
    """

    faces: np.ndarray
    welded: int = 0
    duplicates: int = 0
    collapsed: int = 0
    flipped: int = 0
    open_edges: int = 0
    closed: bool = False

    def describe(self) -> str:
        """A short account of the repairs ('' when nothing was changed)."""
        parts = []
        if self.welded:
            parts.append(f"{self.welded} vertices welded")
        if self.duplicates:
            parts.append(f"{self.duplicates} duplicated faces ignored")
        if self.collapsed:
            parts.append(f"{self.collapsed} faces collapsed by welding ignored")
        if self.flipped:
            parts.append(f"{self.flipped} faces turned outward")
        return ", ".join(parts)


def weld_map(V, tol_rel=tol.WELD_REL) -> np.ndarray:
    """(n,) index of the vertex each vertex is welded to (itself if none):
    vertices in the same cell of a grid of ``tol_rel`` times the mesh's size."""
    V = np.asarray(V, np.float64)
    n = len(V)
    if n == 0:
        return np.zeros(0, np.int64)
    lo, hi = V.min(axis=0), V.max(axis=0)
    h = max(float(np.linalg.norm(hi - lo)) * tol_rel, 1e-300)
    key = np.floor((V - lo) / h).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return first[inverse.reshape(-1)]


def tidy(V, F) -> Tidy:
    """Weld, drop duplicated faces and orient the windings of ``(V, F)``.

    Parameters
    ----------
    V : (n, 3) array_like of float
    F : (m, 3) array_like of int
        Non-degenerate triangles (indices into ``V``).
    """
    F = np.asarray(F, np.int64).reshape(-1, 3)
    n = len(V)
    rep = weld_map(V)
    welded = int(np.count_nonzero(rep != np.arange(n)))
    Fw = rep[F]
    ok = (Fw[:, 0] != Fw[:, 1]) & (Fw[:, 1] != Fw[:, 2]) & (Fw[:, 0] != Fw[:, 2])
    collapsed = int(np.count_nonzero(~ok))
    Fw = Fw[ok]
    # duplicated faces: the same corners in any order
    _, keep = np.unique(np.sort(Fw, axis=1), axis=0, return_index=True)
    keep = np.sort(keep)
    duplicates = len(Fw) - len(keep)
    Fw = Fw[keep]
    flip, open_edges, closed = _orient(np.asarray(V, np.float64), Fw, n)
    Fw[flip] = Fw[flip][:, ::-1]
    return Tidy(Fw.astype(np.int32), welded, duplicates, collapsed,
                int(np.count_nonzero(flip)), open_edges, closed)


def _edges(F, n):
    """Undirected edge of every face corner: (key (3m,), sign (3m,), face (3m,)).
    ``sign`` is +1 where the corner runs from the lower to the higher vertex."""
    a = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
    b = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    face = np.tile(np.arange(len(F)), 3)
    return lo * n + hi, np.where(a < b, 1, -1), face


def _orient(V, F, n):
    """Faces to flip so that windings agree across shared edges, closed parts
    outward, open parts as most of their faces were. Returns (flip (m,) bool,
    number of open edges, closed)."""
    m = len(F)
    flip = np.zeros(m, bool)
    if m == 0:
        return flip, 0, False
    key, sign, face = _edges(F, n)
    order = np.argsort(key, kind="stable")
    key, sign, face = key[order], sign[order], face[order]
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    count = np.diff(np.r_[start, len(key)])
    open_edges = int(np.count_nonzero(count == 1))
    # face pairs across manifold edges (exactly two faces)
    two = start[count == 2]
    f1, f2 = face[two], face[two + 1]
    agree = sign[two] != sign[two + 1]  # consistent: the edge runs both ways
    labels = _components(f1, f2, m)
    if not agree.all():
        flip = _propagate(f1, f2, agree, m)
        # re-count consistency with the flips
        s = np.where(flip[face], -sign, sign)
        agree = s[two] != s[two + 1]
    closed_part = np.ones(labels.max() + 1, bool)
    bad = np.zeros(m, bool)
    bad[face[np.repeat(count != 2, count)]] = True  # a face on an open or non-manifold edge
    bad[f1[~agree]] = True
    bad[f2[~agree]] = True
    closed_part[labels[bad]] = False
    # signed volume of each closed part (with the flips), outward = positive
    G = np.where(flip[:, None], F[:, ::-1], F)
    p0, p1, p2 = V[G[:, 0]], V[G[:, 1]], V[G[:, 2]]
    c = V.mean(axis=0)  # about the mesh's centre: better conditioned
    vol = np.einsum("ij,ij->i", p0 - c, np.cross(p1 - c, p2 - c))
    part_vol = np.bincount(labels, weights=vol, minlength=len(closed_part))
    turned = np.bincount(labels, weights=flip.astype(float), minlength=len(closed_part))
    size = np.bincount(labels, minlength=len(closed_part))
    inward = np.where(closed_part, part_vol < 0, turned * 2 > size)
    flip ^= inward[labels]
    closed = bool(closed_part.all() and open_edges == 0 and (count == 2).all())
    return flip, open_edges, closed


def _components(f1, f2, m):
    """Connected parts of the faces (linked across shared edges), (m,) labels
    0..k-1: pointer jumping, O(log m) vectorized rounds."""
    parent = np.arange(m)
    for _ in range(64):  # bounded: each round at least halves the tree height
        p1, p2 = parent[f1], parent[f2]
        lo, hi = np.minimum(p1, p2), np.maximum(p1, p2)
        moved = lo != hi
        if not moved.any():
            break
        np.minimum.at(parent, hi[moved], lo[moved])
        for _ in range(64):
            pp = parent[parent]
            if np.array_equal(pp, parent):
                break
            parent = pp
    _, labels = np.unique(parent, return_inverse=True)
    return labels.reshape(-1)


def _propagate(f1, f2, agree, m):
    """Flip bits making every face pair agree, found by a breadth-first walk
    over the faces (only for meshes whose windings disagree somewhere; a part
    that cannot be made consistent, a Moebius strip, keeps the first walk's
    choice)."""
    nbr = np.concatenate([f2, f1])
    own = np.concatenate([f1, f2])
    same = np.concatenate([agree, agree])
    order = np.argsort(own, kind="stable")
    nbr, own, same = nbr[order], own[order], same[order]
    first = np.searchsorted(own, np.arange(m + 1))
    nbr_l, same_l, first_l = nbr.tolist(), same.tolist(), first.tolist()
    flip = [False] * m
    seen = [False] * m
    for s in range(m):
        if seen[s]:
            continue
        seen[s] = True
        todo = deque([s])
        while todo:
            f = todo.popleft()
            for e in range(first_l[f], first_l[f + 1]):
                g = nbr_l[e]
                if not seen[g]:
                    seen[g] = True
                    # agree (before flips): g keeps f's flip; disagree: the opposite
                    flip[g] = flip[f] if same_l[e] else not flip[f]
                    todo.append(g)
    return np.array(flip, bool)
