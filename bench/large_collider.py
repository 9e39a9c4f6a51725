"""The large-collider case of ``make bench``: a shirt far larger than the fur on it.

Chest fur (a cap of the unit body sphere, 50,000 curves x 8 CVs by default) under
an open, deforming shirt (a tube around the body, about 130,000 triangles, breathing
and pressing into the fur every frame). The shirt is about ten times larger than what
the fur can reach. Three runs on the same frames, each a ``deforming=True`` collider
updated with ``col.vertices`` every frame (the time of a frame: the update plus one
``Solver.step``):

* **shirt**: the whole shirt; the core builds the part the curves can reach
  (``Collider.set_reach``);
* **its reachable part alone**: only the shirt's faces near the fur (every face with
  a vertex within the fur's reach, grown by the deformation's amplitude), as its own
  collider: what an artist would get by cutting the shirt by hand;
* **shirt, built whole**: the whole shirt with its shell built whole every frame
  (``Collider.set_reach`` switched off): what a frame cost before.

Nothing here is asserted; ``bench_core`` prints the figures and the target (issue 32:
the shirt no slower than its reachable part alone).
"""

from __future__ import annotations

import math
import time

import numpy as np

CHEST_DEG = 25.0  # the fur's cap: this polar angle around +y
SHIRT_RADIUS = 1.2
SHIRT_HALF_HEIGHT = 1.6


def chest_fur(curves: int, cvs: int, seed: int = 1):
    """(points (P, 3) float32, offsets (C+1,) int64): curves 0.15-0.25 long on a cap
    of the unit sphere around +y, leaving along the normal with up to 30 degrees of
    tilt."""
    rng = np.random.default_rng(seed)
    cos_max = math.cos(math.radians(CHEST_DEG))
    y = rng.uniform(cos_max, 1.0, curves)
    phi = rng.uniform(0.0, 2.0 * math.pi, curves)
    r = np.sqrt(1.0 - y * y)
    n = np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=1)
    helper = np.where(np.abs(n[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    tilt = np.radians(rng.uniform(0.0, 30.0, curves))
    d = n * np.cos(tilt)[:, None] + t1 * np.sin(tilt)[:, None]
    length = rng.uniform(0.15, 0.25, curves)
    t = np.linspace(0.0, 1.0, cvs)
    pts = n[:, None, :] + (length[:, None] * t)[:, :, None] * d[:, None, :]
    offsets = np.arange(0, curves * cvs + 1, cvs, dtype=np.int64)
    return pts.reshape(-1, 3).astype(np.float32), offsets


def shirt(tris: int):
    """(V (n, 3) float32, F (m, 3)): an open tube around the z axis (the body's
    height), rings along z, about ``tris`` triangles."""
    seg = 256
    rings = max(2, tris // (2 * seg))
    th = np.arange(seg) * (2.0 * math.pi / seg)
    z = np.linspace(-SHIRT_HALF_HEIGHT, SHIRT_HALF_HEIGHT, rings + 1)
    V = np.stack([np.broadcast_to(SHIRT_RADIUS * np.cos(th), (rings + 1, seg)),
                  np.broadcast_to(SHIRT_RADIUS * np.sin(th), (rings + 1, seg)),
                  np.broadcast_to(z[:, None], (rings + 1, seg))], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(rings), np.arange(seg), indexing="ij")
    a = i * seg + j
    b = i * seg + (j + 1) % seg
    c, d = a + seg, b + seg
    F = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                        np.stack([a, d, c], -1).reshape(-1, 3)])
    return V.astype(np.float32), F.astype(np.int64)


def shirt_at(V, f: int):
    """The shirt at frame ``f``: breathing waves, and a press into the chest fur that
    comes and goes (float32, as a cloth simulation hands it over)."""
    W = V.astype(np.float64)
    th = np.arctan2(W[:, 1], W[:, 0])
    z = W[:, 2]
    chest = np.exp(-((th - math.pi / 2) / 0.45) ** 2) * np.exp(-(z / 0.5) ** 2)
    k = 1.0 + 0.03 * np.sin(3.0 * th + 0.6 * f) * np.cos(1.5 * z)
    k -= (0.05 + 0.03 * math.sin(0.3 * f)) * chest
    W[:, :2] *= k[:, None]
    return W.astype(np.float32)


def reachable_part(V, F, points, offsets, grow=0.2):
    """The faces of ``F`` with a vertex within the fur's reach (its roots grown by
    the longest curve), grown by ``grow`` (the deformation's amplitude): as its own
    mesh (V, F) with the used vertices only."""
    roots = points[offsets[:-1]].astype(np.float64)
    seg = np.diff(points.astype(np.float64), axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    first = np.zeros(len(points), bool)
    first[offsets[:-1]] = True
    longest = np.add.reduceat(np.where(first[1:], 0.0, lengths), offsets[:-1]).max()
    lo = roots.min(axis=0) - longest - grow
    hi = roots.max(axis=0) + longest + grow
    near = ((V >= lo) & (V <= hi)).all(axis=1)
    keep = near[F].any(axis=1)
    used = np.unique(F[keep])
    remap = np.full(len(V), -1, np.int64)
    remap[used] = np.arange(len(used))
    return used, remap[F[keep]]


def run(core, curves: int, cvs: int, tris: int, frames: int, threads: int, seed: int = 1):
    """Time the three runs on the same frames; a dict of figures per run."""
    pts, offs = chest_fur(curves, cvs, seed)
    V, F = shirt(tris)
    used, F_part = reachable_part(V, F, pts, offs)
    runs = {}
    for name in ("shirt", "reachable part alone", "shirt, built whole"):
        rest = V[used] if name == "reachable part alone" else V
        faces = F_part if name == "reachable part alone" else F
        col = core.Collider(shirt_at(V, 0)[used] if name == "reachable part alone"
                            else shirt_at(V, 0), faces, deforming=True, rest=rest,
                            name="shirt")
        if name == "shirt, built whole":
            col.set_reach = lambda *a, **k: None  # (the reach never set: whole shells)
        solver = core.Solver(offs, core.Settings(mode="bend", threads=threads))
        ms, colliding, outs = [], [], []
        for f in range(frames):
            Vf = shirt_at(V, f)
            if name == "reachable part alone":
                Vf = Vf[used]
            t0 = time.perf_counter()
            col.vertices = Vf
            res = solver.step(pts, [col])
            ms.append(1000.0 * (time.perf_counter() - t0))
            colliding.append(int(np.count_nonzero(np.asarray(res.status) != 0)))
            outs.append(np.asarray(res.points).tobytes())
        built = col.shells.built[-1][2] if col.shells.built else None
        runs[name] = dict(ms=np.median(ms[1:]) if len(ms) > 1 else ms[0],
                          triangles=len(faces),
                          shell=len(built.real) if built is not None else 0,
                          colliding=int(np.median(colliding)), builds=col.build_count,
                          outs=outs)
    same = runs["shirt"]["outs"] == runs["shirt, built whole"]["outs"]
    for r in runs.values():
        del r["outs"]
    return runs, same
