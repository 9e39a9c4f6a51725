"""Colliders as artists make them: weld seams, drop duplicated faces, wind outward.

Meshes reach FurCollide with the usual accidents of modelling and import:
faces wound inward (a flipped normal, an import from another handedness),
mixed windings, a few duplicated faces, and seams whose vertices were never
merged (split normals, UV seams, an OBJ without "merge vertices"). Each of them
used to switch pinch detection off silently, or (inward winding with a Collision
Offset) build the offset shell inside the mesh. :func:`tidy` fixes the
*topology* the collider works with; the positions are never moved:

1. **Weld**: vertices within ``tol.WELD_REL`` of the mesh's size of each other
   (transitively) become one (the faces point at the first of them; the
   duplicates stay, unused).
2. **Duplicated faces** (the same three welded corners): copies with the same
   winding count once. Two copies wound opposite ways whose edges every other
   face leaves shared by two more faces are the wall between two closed parts
   touching face to face (two crates joined): both go, leaving the union closed.
3. **Winding**: made consistent across every edge two faces share, per connected
   part, keeping the winding most of its faces had. A closed part (each of its
   edges shared by two of its faces, wound opposite ways) is then turned so that
   the mesh means what its artist meant: a closed part inside no other one faces
   outward (positive signed volume); a closed part lying wholly inside another
   keeps its winding *relative to* that one (wound against it, it is the wall of
   a cavity: the inner shell of a Solidify helmet faces the cavity; wound with
   it, a solid within the solid). An open part keeps its majority winding.

The result says what it changed, for the artist's status line.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from . import tolerances as tol
from .rays import NumpyBackend


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
    shared : int
        Faces dropped in pairs as the wall between two closed parts that touch
        face to face.
    flipped : int
        Faces whose winding was reversed.
    open_edges : int
        Edges with one face only (0 with ``closed``).
    closed : bool
        Every part closed: each of its edges shared by two of its faces, wound
        opposite ways.
    parts : int
        Connected parts (faces linked across edges two faces share).
    """

    faces: np.ndarray
    welded: int = 0
    duplicates: int = 0
    collapsed: int = 0
    shared: int = 0
    flipped: int = 0
    open_edges: int = 0
    closed: bool = False
    parts: int = 0

    def describe(self) -> str:
        """A short account of the repairs ('' when nothing was changed)."""
        parts = []
        if self.welded:
            parts.append(f"{self.welded} vertices welded")
        if self.duplicates:
            parts.append(f"{self.duplicates} duplicated faces ignored")
        if self.collapsed:
            parts.append(f"{self.collapsed} faces collapsed by welding ignored")
        if self.shared:
            parts.append(f"{self.shared} faces between touching parts ignored")
        if self.flipped:
            parts.append(f"{self.flipped} faces turned outward")
        return ", ".join(parts)


def weld_map(V, tol_rel=tol.WELD_REL) -> np.ndarray:
    """(n,) index of the vertex each vertex is welded to (itself if none).

    Vertices within ``h = tol_rel`` times the mesh's size of each other are
    one vertex, transitively; each maps to the lowest index of its group.
    Found on a grid of cell ``h``: a pair that close lies in the same or a
    neighbouring cell, so copies straddling a cell boundary (a seam whose
    copies differ by an ulp) are welded too.
    """
    V = np.asarray(V, np.float64)
    n = len(V)
    if n == 0:
        return np.zeros(0, np.int64)
    lo, hi = V.min(axis=0), V.max(axis=0)
    h = max(float(np.linalg.norm(hi - lo)) * tol_rel, 1e-300)
    key = np.floor((V - lo) / h).astype(np.int64) + 1  # (>= 1: neighbours stay >= 0)
    dims = key.max(axis=0) + 2
    lin = (key[:, 0] * dims[1] + key[:, 1]) * dims[2] + key[:, 2]
    order = np.argsort(lin, kind="stable")
    sl = lin[order]
    at = np.empty(n, np.int64)
    at[order] = np.arange(n)  # each vertex's place in the sorted order
    ia, ib = [], []
    # the cell itself (the vertices after each one in its cell's run) and the
    # 13 neighbours "after" it: each pair of vertices once
    for dx, dy, dz in [(0, 0, 0)] + [(x, y, z) for x in (0, 1) for y in (-1, 0, 1)
                                     for z in (-1, 0, 1) if (x, y, z) > (0, 0, 0)]:
        t = lin + (dx * dims[1] + dy) * dims[2] + dz
        if (dx, dy, dz) == (0, 0, 0):
            a = at + 1
            cnt = np.searchsorted(sl, t, "right") - a
        else:
            a = np.searchsorted(sl, t, "left")
            cnt = np.searchsorted(sl, t, "right") - a
        has = np.flatnonzero(cnt > 0)
        if len(has) == 0:
            continue
        c = cnt[has]
        k = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        ia.append(np.repeat(has, c))
        ib.append(order[np.repeat(a[has], c) + k])
    rep = np.arange(n)
    if ia:
        i, j = np.concatenate(ia), np.concatenate(ib)
        d = V[i] - V[j]
        near = np.einsum("ij,ij->i", d, d) <= h * h
        i, j = i[near], j[near]
        if len(i):
            labels = _components(i, j, n)
            low = np.full(labels.max() + 1, n)
            np.minimum.at(low, labels, np.arange(n))
            rep = low[labels]
    return rep


def tidy(V, F) -> Tidy:
    """Weld, drop duplicated faces and orient the windings of ``(V, F)``.

    Parameters
    ----------
    V : (n, 3) array_like of float
    F : (m, 3) array_like of int
        Non-degenerate triangles (indices into ``V``).
    """
    F = np.asarray(F, np.int64).reshape(-1, 3)
    V = np.asarray(V, np.float64)
    n = len(V)
    rep = weld_map(V)
    welded = int(np.count_nonzero(rep != np.arange(n)))
    Fw = rep[F]
    ok = (Fw[:, 0] != Fw[:, 1]) & (Fw[:, 1] != Fw[:, 2]) & (Fw[:, 0] != Fw[:, 2])
    collapsed = int(np.count_nonzero(~ok))
    Fw = Fw[ok]
    keep, shared = _unique_faces(Fw, n)
    duplicates = len(Fw) - len(keep) - shared
    Fw = Fw[keep]
    flip, open_edges, closed, parts = _orient(V, Fw, n)
    Fw[flip] = Fw[flip][:, ::-1]
    return Tidy(Fw.astype(np.int32), welded, duplicates, collapsed, shared,
                int(np.count_nonzero(flip)), open_edges, closed, parts)


def _unique_faces(F, n):
    """Faces to keep (sorted indices) and how many went as walls between
    touching parts (see the module docstring, 2.)."""
    m = len(F)
    if m == 0:
        return np.zeros(0, np.int64), 0
    srt = np.sort(F, axis=1)
    # winding class: the corners in cyclic order from the lowest one ascend or not
    lo_at = np.argmin(F, axis=1)
    nxt = F[np.arange(m), (lo_at + 1) % 3]
    cls = (nxt == srt[:, 1]).astype(np.int64)
    keyed = np.column_stack([srt, cls])
    _, first, inv = np.unique(keyed, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    keep = np.sort(first)  # one face per (corners, winding)
    # the same corners wound both ways: a wall between touching parts if every
    # one of its edges is also shared by exactly two other kept faces
    corners = srt[keep]
    _, grp, gcount = np.unique(corners, axis=0, return_inverse=True, return_counts=True)
    grp = grp.reshape(-1)
    pair = gcount[grp] == 2
    if not pair.any():
        return keep, 0
    key, _, face = _edges(F[keep], n)
    _, inv_key, ucount = np.unique(key, return_inverse=True, return_counts=True)
    # every edge of the face shared by exactly 4 kept faces: the pair and two more
    four = np.ones(len(keep), bool)
    np.logical_and.at(four, face, ucount[inv_key.reshape(-1)] == 4)
    wall = pair & four  # (both faces of a pair decide alike)
    # any other pair: one duplicated face, the first kept
    low = np.full(len(gcount), len(keep))
    np.minimum.at(low, grp, np.arange(len(keep)))
    second = pair & ~wall & (np.arange(len(keep)) != low[grp])
    return keep[~wall & ~second], int(np.count_nonzero(wall))


def _edges(F, n):
    """Undirected edge of every face corner: (key (3m,), sign (3m,), face (3m,)).
    ``sign`` is +1 where the corner runs from the lower to the higher vertex."""
    a = np.concatenate([F[:, 0], F[:, 1], F[:, 2]])
    b = np.concatenate([F[:, 1], F[:, 2], F[:, 0]])
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    face = np.tile(np.arange(len(F)), 3)
    return lo * n + hi, np.where(a < b, 1, -1), face


def _orient(V, F, n):
    """Faces to flip: windings agree across shared edges, each part keeps its
    majority winding, closed parts are turned as the module docstring says.
    Returns (flip (m,) bool, number of open edges, every part closed, parts)."""
    m = len(F)
    flip = np.zeros(m, bool)
    if m == 0:
        return flip, 0, False, 0
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
    n_parts = int(labels.max()) + 1
    if not agree.all():
        flip = _propagate(f1, f2, agree, m)
    size = np.bincount(labels, minlength=n_parts)
    turned = np.bincount(labels, weights=flip.astype(float), minlength=n_parts)
    flip ^= (turned * 2 > size)[labels]  # each part keeps its majority winding
    # closed part: each of its edges has two of its faces, running opposite ways
    s = np.where(flip[face], -sign, sign)
    lab = labels[face]
    po = np.lexsort((key, lab))
    pk, pl, ps = key[po], lab[po], s[po]
    pstart = np.flatnonzero(np.r_[True, (pk[1:] != pk[:-1]) | (pl[1:] != pl[:-1])])
    pcount = np.diff(np.r_[pstart, len(pk)])
    good = pcount == 2
    good[good] = ps[pstart[good]] != ps[pstart[good] + 1]
    closed_part = np.ones(n_parts, bool)
    closed_part[labels[face[po][pstart[~good]]]] = False
    # signed volume of each part (with the flips so far): the artist's sense
    G = np.where(flip[:, None], F[:, ::-1], F)
    p0, p1, p2 = V[G[:, 0]], V[G[:, 1]], V[G[:, 2]]
    c = V.mean(axis=0)  # about the mesh's centre: better conditioned
    vol = np.einsum("ij,ij->i", p0 - c, np.cross(p1 - c, p2 - c))
    part_vol = np.bincount(labels, weights=vol, minlength=n_parts)
    want = _wanted_senses(V, G, labels, closed_part, np.sign(part_vol))
    turn = closed_part & (np.sign(part_vol) != want) & (want != 0)
    flip ^= turn[labels]
    return flip, open_edges, bool(closed_part.all()), n_parts


def _wanted_senses(V, G, labels, closed_part, sense):
    """(parts,) +1 / -1: the signed-volume sense each closed part should have
    (0 for open parts): outward unless it lies wholly inside another closed
    part, then its parent's sense times its own relative to the parent's."""
    parts = np.flatnonzero(closed_part)
    want = np.zeros(len(closed_part))
    if len(parts) == 0:
        return want
    want[parts] = 1.0
    if len(parts) == 1 or len(parts) > tol.NEST_MAX_PARTS:
        return want
    lo = np.full((len(closed_part), 3), np.inf)
    hi = np.full((len(closed_part), 3), -np.inf)
    T = V[G]  # (m, 3, 3)
    np.minimum.at(lo, labels, T.min(axis=1))
    np.maximum.at(hi, labels, T.max(axis=1))
    by = np.argsort(labels, kind="stable")
    bounds = np.searchsorted(labels[by], np.arange(len(closed_part) + 1))
    faces_of = {int(p): by[bounds[p]:bounds[p + 1]] for p in parts}
    parent = {}
    depth = {int(p): 0 for p in parts}
    for j in parts:
        fj = faces_of[int(j)]
        probe = T[fj[np.linspace(0, len(fj) - 1, min(len(fj), _NEST_PROBES)).astype(int)]]
        probe = probe.mean(axis=1)  # face centres: on no other part's surface
        holders = [i for i in parts if i != j and (lo[i] <= lo[j]).all()
                   and (hi[j] <= hi[i]).all()
                   and _inside(probe, T[faces_of[int(i)]]).all()]
        depth[int(j)] = len(holders)
        if holders:  # the innermost one holding it
            parent[int(j)] = holders[int(np.argmin([(hi[i] - lo[i]).prod() for i in holders]))]
    for j in sorted(depth, key=depth.get):
        if j in parent:
            p = parent[j]
            want[j] = want[p] * sense[j] * sense[p] if sense[j] and sense[p] else want[p]
    return want


#: Face centres of a closed part tested against another to call it nested.
_NEST_PROBES = 16
#: A fixed, generic direction for the parity rays of :func:`_inside`.
_RAY = np.array([0.5773502691896258, 0.5773502691896257, 0.5773502691896259]) + np.array(
    [0.0123, -0.0071, 0.0049])


def _inside(points, T):
    """(k,) bool: is each point inside the closed triangle set ``T`` (m, 3, 3)?
    Ray parity along one generic direction (the numpy ray backend)."""
    m = len(T)
    be = NumpyBackend(T.reshape(-1, 3), np.arange(3 * m).reshape(m, 3))
    d = np.broadcast_to(_RAY / np.linalg.norm(_RAY), (len(points), 3))
    return be.crossings(points, d) % 2 == 1


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
