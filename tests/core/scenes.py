"""Small scene builders for the core tests (numpy only, no core imports).

Meshes use Blender's convention: a face (v0, v1, v2) faces the side of
``cross(v1 - v0, v2 - v0)``. Closed builders return outward-facing meshes.
"""

from __future__ import annotations

import numpy as np


# ---------------------------------------------------------------- meshes
def uv_sphere(center=(0.0, 0.0, 0.0), radius=1.0, segments=32, rings=16):
    """Closed UV sphere, outward normals. Vertices lie on the sphere."""
    c = np.asarray(center, dtype=np.float64)
    # (each sine and cosine taken as a scalar, as the rings and segments are drawn)
    sp = np.array([np.sin(np.pi * i / rings) for i in range(1, rings)])
    cp = np.array([np.cos(np.pi * i / rings) for i in range(1, rings)])
    ct = np.array([np.cos(2 * np.pi * j / segments) for j in range(segments)])
    st = np.array([np.sin(2 * np.pi * j / segments) for j in range(segments)])
    ring = np.stack([sp[:, None] * ct, sp[:, None] * st,
                     np.broadcast_to(cp[:, None], (rings - 1, segments))], -1)
    V = np.concatenate([[c + [0, 0, radius]], (c + radius * ring).reshape(-1, 3),
                        [c + [0, 0, -radius]]])
    south = len(V) - 1
    j = np.arange(segments)
    a = 1 + np.arange(rings - 2)[:, None] * segments + j  # ring i (from 1), segment j
    b = 1 + np.arange(rings - 2)[:, None] * segments + (j + 1) % segments
    band = np.stack([np.stack([a, a + segments, b + segments], -1),
                     np.stack([a, b + segments, b], -1)], 2).reshape(-1, 3)
    last = 1 + (rings - 2) * segments
    F = np.concatenate([np.stack([np.zeros(segments, int), 1 + j, 1 + (j + 1) % segments], 1),
                        band,
                        np.stack([np.full(segments, south), last + (j + 1) % segments,
                                  last + j], 1)])
    return V, F.astype(np.int64)


def icosphere(center=(0.0, 0.0, 0.0), radius=1.0, subdivisions=2):
    """Closed icosphere, outward normals."""
    t = (1 + 5**0.5) / 2
    V = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
         (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    V = [np.array(v, float) / np.linalg.norm(v) for v in V]
    F = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(subdivisions):
        cache = {}

        def mid(a, b, cache=cache):
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = V[a] + V[b]
                V.append(m / np.linalg.norm(m))
                cache[key] = len(V) - 1
            return cache[key]

        F2 = []
        for a, b, c in F:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            F2 += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        F = F2
    V = np.asarray(center, float) + radius * np.array(V)
    return V, np.array(F, dtype=np.int64)


def bumpy_sphere(center=(0.0, 0.0, 0.0), radius=1.0, amplitude=0.3, lobes=3, segments=32,
                 rings=16):
    """Closed star-shaped blob with concave regions, outward normals."""
    V, F = uv_sphere((0, 0, 0), 1.0, segments, rings)
    th = np.arctan2(V[:, 1], V[:, 0])
    ph = np.arccos(np.clip(V[:, 2], -1, 1))
    r = radius * (1 + amplitude * np.sin(lobes * th) * np.sin(lobes * ph))
    return V * r[:, None] + np.asarray(center, float), F


def torus(center=(0.0, 0.0, 0.0), R=1.0, r=0.3, segments=32, sides=12):
    """Closed torus around +z, outward normals."""
    c = np.asarray(center, float)
    V = []
    for i in range(segments):
        u = 2 * np.pi * i / segments
        for j in range(sides):
            v = 2 * np.pi * j / sides
            V.append(c + [(R + r * np.cos(v)) * np.cos(u), (R + r * np.cos(v)) * np.sin(u),
                          r * np.sin(v)])
    F = []
    for i in range(segments):
        for j in range(sides):
            a = i * sides + j
            b = ((i + 1) % segments) * sides + j
            a2 = i * sides + (j + 1) % sides
            b2 = ((i + 1) % segments) * sides + (j + 1) % sides
            F += [(a, b, b2), (a, b2, a2)]
    return np.array(V), np.array(F, dtype=np.int64)


def box(lo=(-0.5, -0.5, -0.5), hi=(0.5, 0.5, 0.5)):
    """Closed axis-aligned box (12 triangles), outward normals."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    V = np.array([[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1])
                  for x in (lo[0], hi[0])])
    # index = x + 2*y + 4*z
    quads = [(0, 2, 3, 1),  # bottom (-z)
             (4, 5, 7, 6),  # top (+z)
             (0, 1, 5, 4),  # -y
             (2, 6, 7, 3),  # +y
             (0, 4, 6, 2),  # -x
             (1, 3, 7, 5)]  # +x
    F = []
    for a, b, c, d in quads:
        F += [(a, b, c), (a, c, d)]
    return V, np.array(F, dtype=np.int64)


def grid(size=2.0, n=4, z=0.0, center=(0.0, 0.0)):
    """Open square grid in the plane ``z``, normals +z, ``n`` x ``n`` quads."""
    xs = np.linspace(-size / 2, size / 2, n + 1)
    X, Y = np.meshgrid(xs + center[0], xs + center[1], indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.full(X.size, float(z))], axis=1)
    F = []
    for i in range(n):
        for j in range(n):
            a = i * (n + 1) + j
            b = (i + 1) * (n + 1) + j
            F += [(a, b, b + 1), (a, b + 1, a + 1)]
    return V, np.array(F, dtype=np.int64)


def quad(origin, u, v):
    """Open quad origin + s*u + t*v, s,t in [0,1]; normal = u x v."""
    o, u, v = (np.asarray(x, float) for x in (origin, u, v))
    V = np.array([o, o + u, o + u + v, o + v])
    return V, np.array([(0, 1, 2), (0, 2, 3)], dtype=np.int64)


def flip(F):
    """Reverse every face's winding."""
    return np.asarray(F)[:, ::-1].copy()


def signed_volume(V, F):
    V = np.asarray(V, float)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def is_closed_consistent(F):
    """Every directed edge appears once and its reverse once."""
    from collections import Counter

    E = Counter()
    for a, b, c in np.asarray(F):
        for e in ((a, b), (b, c), (c, a)):
            E[(int(e[0]), int(e[1]))] += 1
    return all(n == 1 and E.get((b, a), 0) == 1 for (a, b), n in E.items())


# ---------------------------------------------------------------- matrices
def translation(t):
    M = np.eye(4)
    M[:3, 3] = t
    return M


def rotation_matrix(axis, angle_rad):
    """3x3 rotation (Rodrigues), right-handed."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * K + (1 - np.cos(angle_rad)) * K @ K


def affine(R=None, t=(0, 0, 0), s=1.0):
    M = np.eye(4)
    M[:3, :3] = (np.eye(3) if R is None else np.asarray(R, float)) * s
    M[:3, 3] = t
    return M


def turning_sweep(f):
    """A collider's matrix at frame ``f`` of a sweep through fur on the plane z = 0
    (``fur_on_plane``, extent about 1): it moves from (-0.7, 0, 0.6) by (0.3, 0.05, -0.05)
    a frame, turning by 0.2 rad a frame about (0, 1, 0.3)."""
    return affine(rotation_matrix([0, 1, 0.3], 0.2 * f),
                  t=[-0.7 + 0.3 * f, 0.05 * f, 0.6 - 0.05 * f])


# ---------------------------------------------------------------- curves
def pack(curves, dtype=np.float64):
    """List of (n_i,3) arrays -> (points, offsets)."""
    lens = [len(c) for c in curves]
    offsets = np.concatenate([[0], np.cumsum(lens)]).astype(np.int64)
    points = np.concatenate([np.asarray(c, float) for c in curves]).astype(dtype)
    return points, offsets


def unpack(points, offsets):
    return [points[offsets[i]:offsets[i + 1]] for i in range(len(offsets) - 1)]


def straight_curve(root, direction, length, n_cvs):
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    t = np.linspace(0.0, 1.0, n_cvs)[:, None]
    return np.asarray(root, float) + t * length * d


def curly_curve(root, direction, length, n_cvs, amplitude=0.15, turns=1.0, phase=0.0):
    """A helix-ish curve around ``direction``; amplitude relative to length."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    tmp = np.array([1.0, 0, 0]) if abs(d[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(d, tmp)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)
    s = np.linspace(0.0, 1.0, n_cvs)
    ang = 2 * np.pi * turns * s + phase
    r = amplitude * length * s  # zero at the root
    P = (np.asarray(root, float) + (s * length * 0.9)[:, None] * d
         + (r * np.cos(ang))[:, None] * e1 + (r * np.sin(ang))[:, None] * e2)
    return P


def fur_on_plane(rng, n_curves=20, n_cvs=(2, 12), length=(0.5, 1.0), extent=1.0,
                 lean=0.3, curly=0.15, z=0.0, dtype=np.float64):
    """Random fur rooted on the plane ``z`` within [-extent, extent]^2, growing +z."""
    curves = []
    for _ in range(n_curves):
        root = np.array([rng.uniform(-extent, extent), rng.uniform(-extent, extent), z])
        d = np.array([rng.normal() * lean, rng.normal() * lean, 1.0])
        n = int(rng.integers(n_cvs[0], n_cvs[1] + 1))
        L = rng.uniform(*length)
        if curly > 0 and rng.random() < 0.7:
            c = curly_curve(root, d, L, n, amplitude=rng.uniform(0, curly),
                            turns=rng.uniform(0.3, 1.5), phase=rng.uniform(0, 6.28))
        else:
            c = straight_curve(root, d, L, n)
        curves.append(c)
    return pack(curves, dtype)


def fur_on_sphere(rng, center=(0, 0, 0), radius=1.0, n_curves=20, n_cvs=(2, 8),
                  length=(0.2, 0.5), curly=0.1, dtype=np.float64):
    """Random fur rooted on a sphere, growing outward."""
    c0 = np.asarray(center, float)
    curves = []
    for _ in range(n_curves):
        nrm = rng.normal(size=3)
        nrm /= np.linalg.norm(nrm)
        root = c0 + radius * nrm
        n = int(rng.integers(n_cvs[0], n_cvs[1] + 1))
        L = rng.uniform(*length)
        d = nrm + 0.2 * rng.normal(size=3)
        if curly > 0 and rng.random() < 0.5:
            c = curly_curve(root, d, L, n, amplitude=curly, turns=rng.uniform(0.3, 1.0))
        else:
            c = straight_curve(root, d, L, n)
        curves.append(c)
    return pack(curves, dtype)


def segment_vectors(points, offsets):
    """List per curve of (n-1, 3) float64 segment vectors."""
    P = np.asarray(points, np.float64)
    return [np.diff(P[offsets[i]:offsets[i + 1]], axis=0) for i in range(len(offsets) - 1)]


def segment_lengths(points, offsets):
    return [np.linalg.norm(s, axis=1) for s in segment_vectors(points, offsets)]


# ---------------------------------------------------------------- random scenes
COLLIDER_KINDS = ("sphere", "box", "icosphere", "plane", "plane2", "bumpy", "torus")


def random_collider(rng, kind):
    """A collider spec dict: V (local), F, matrix, double_sided, and for
    spheres the world centre and radius."""
    if kind in ("sphere", "icosphere"):
        r = rng.uniform(0.2, 0.6)
        c = np.array([rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), rng.uniform(0.1, 1.2)])
        V, F = (uv_sphere(radius=1.0, segments=24, rings=12) if kind == "sphere"
                else icosphere(radius=1.0, subdivisions=2))
        return dict(V=V, F=F, matrix=affine(t=c, s=r), double_sided=False, center=c, radius=r)
    if kind in ("bumpy", "torus"):
        c = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(0.4, 1.0)])
        R = rotation_matrix(rng.normal(size=3), rng.uniform(0, np.pi))
        if kind == "bumpy":
            V, F = bumpy_sphere(radius=1.0, amplitude=0.3, lobes=int(rng.integers(2, 5)))
            s = rng.uniform(0.25, 0.5)
        else:
            V, F = torus(R=1.0, r=0.3)
            s = rng.uniform(0.3, 0.6)
        return dict(V=V, F=F, matrix=affine(R, t=c, s=s), double_sided=bool(rng.random() < 0.3))
    if kind == "box":
        h = rng.uniform(0.1, 0.5, 3)
        c = np.array([rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.8), rng.uniform(0.2, 1.2)])
        R = rotation_matrix(rng.normal(size=3), rng.uniform(0, np.pi))
        V, F = box(-h, h)
        return dict(V=V, F=F, matrix=affine(R, t=c), double_sided=bool(rng.random() < 0.3))
    # open planes, tilted, crossing the fur
    V, F = grid(size=rng.uniform(0.8, 3.0), n=3)
    R = rotation_matrix(rng.normal(size=3), rng.uniform(0, 0.6))
    if kind == "plane2":  # upside-down (normal facing the roots side differently)
        R = R @ rotation_matrix([1, 0, 0], np.pi)
    c = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(0.2, 0.8)])
    return dict(V=V, F=F, matrix=affine(R, t=c), double_sided=bool(rng.random() < 0.5))


def world_vertices(spec):
    V = np.asarray(spec["V"], float)
    M = spec.get("matrix")
    if M is None:
        return V.copy()
    return V @ M[:3, :3].T + M[:3, 3]
