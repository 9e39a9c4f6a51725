"""Procedural, deterministic paper-scale scene for the FurCollide benchmark.

Nothing here depends on ``core``: only numpy. Everything is seeded, so two
runs with the same options build bit-identical inputs.

The scene (defaults):

* **Body** (growth surface): a unit sphere at the origin, translating slightly
  over the shot (the fur moves with it; the input curves of frame ``f`` are the
  rest curves plus the body translation).
* **Fur**: 50,000 curves x 8 CVs (350,000 segments), roots uniformly random on
  the body, 0.15-0.25 long, leaving along the normal with up to 30 degrees of
  tilt and a progressive curl.
* **Collider**: a closed UV ellipsoid (semi-axes 0.90 x 0.80 x 0.70,
  ~130,000 triangles) that orbits 360 degrees around the body, dipping into
  the fur until its surface sinks 0.15 below the skin mid-shot (roots inside
  it are pinched), spinning about a tilted axis: a rigid motion given as a
  4x4 world matrix per frame. The deforming variant bakes the same motion into
  the vertices plus a small travelling wobble.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

BODY_RADIUS = 1.0
COLLIDER_AXES = (0.90, 0.80, 0.70)
SWEEP_DEG = 360.0  # how far the collider orbits around the body over the shot
DEPTH = 0.15  # deepest sink of the collider's surface below the skin


@dataclass
class Fur:
    rest: np.ndarray  # (P, 3) float32, body at rest
    offsets: np.ndarray  # (C + 1,) int64
    cvs: int

    @property
    def curves(self) -> int:
        return len(self.offsets) - 1

    @property
    def segments(self) -> int:
        return self.curves * (self.cvs - 1)


def make_fur(curves: int, cvs: int, seed: int = 1) -> Fur:
    """Curves on the body sphere; CV ``k`` of every curve is at ``k::cvs``."""
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(curves, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    roots = n * BODY_RADIUS

    # Tangent frame from a helper axis not parallel to n.
    helper = np.where(np.abs(n[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(n, t1)

    length = rng.uniform(0.15, 0.25, size=curves)
    tilt = np.radians(rng.uniform(0.0, 30.0, size=curves))
    curl = np.radians(rng.uniform(0.0, 40.0, size=curves))
    phi = rng.uniform(0.0, 2.0 * math.pi, size=curves)
    side = t1 * np.cos(phi)[:, None] + t2 * np.sin(phi)[:, None]

    nseg = cvs - 1
    seg_len = (length / nseg)[:, None]
    pts = np.empty((curves, cvs, 3), dtype=np.float64)
    pts[:, 0] = roots
    for k in range(nseg):
        a = tilt + curl * (k / max(nseg - 1, 1))
        d = n * np.cos(a)[:, None] + side * np.sin(a)[:, None]
        pts[:, k + 1] = pts[:, k] + seg_len * d
    offsets = np.arange(0, curves * cvs + 1, cvs, dtype=np.int64)
    return Fur(np.ascontiguousarray(pts.reshape(-1, 3), dtype=np.float32), offsets, cvs)


def uv_sphere(tris: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed unit UV sphere with about ``tris`` triangles (2 * lon * rings = 4 k^2)."""
    k = max(2, round(math.sqrt(tris / 4.0)))
    n_lon, n_lat = 2 * k, k + 2  # n_lat latitude rows including both poles
    theta = np.linspace(0.0, math.pi, n_lat)[1:-1]  # rings without poles
    lon = np.linspace(0.0, 2.0 * math.pi, n_lon, endpoint=False)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    ring = np.stack(
        [st * np.cos(lon)[None], st * np.sin(lon)[None], np.broadcast_to(ct, (len(theta), n_lon))],
        axis=-1,
    ).reshape(-1, 3)
    V = np.concatenate([[[0.0, 0.0, 1.0]], ring, [[0.0, 0.0, -1.0]]])
    nr = len(theta)
    top, bottom = 0, len(V) - 1

    def vid(r, j):
        return 1 + r * n_lon + (j % n_lon)

    j = np.arange(n_lon)
    faces = [np.stack([np.full(n_lon, top), vid(0, j), vid(0, j + 1)], axis=1)]
    r = np.arange(nr - 1)[:, None]
    a, b = vid(r, j), vid(r, j + 1)
    c, d = vid(r + 1, j), vid(r + 1, j + 1)
    faces.append(np.stack([a, c, d], axis=-1).reshape(-1, 3))
    faces.append(np.stack([a, d, b], axis=-1).reshape(-1, 3))
    faces.append(np.stack([vid(nr - 1, j), np.full(n_lon, bottom), vid(nr - 1, j + 1)], axis=1))
    F = np.concatenate(faces).astype(np.int32)
    return V, F


def make_collider(tris: int) -> tuple[np.ndarray, np.ndarray]:
    """The collider in its own space: a closed ellipsoid, outward normals."""
    V, F = uv_sphere(tris)
    V = V * np.asarray(COLLIDER_AXES)
    return np.ascontiguousarray(V, dtype=np.float32), F


def _rot(axis, angle) -> np.ndarray:
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    x, y, z = axis
    c, s, C = math.cos(angle), math.sin(angle), 1.0 - math.cos(angle)
    return np.array(
        [
            [c + x * x * C, x * y * C - z * s, x * z * C + y * s],
            [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
            [z * x * C - y * s, z * y * C + x * s, c + z * z * C],
        ]
    )


_ORBIT = _rot([1.0, 0.0, 0.3], 0.35)  # tilt of the orbit plane


def body_translation(frame: int, frames: int) -> np.ndarray:
    """The body (and its fur) drifts a little over the shot."""
    u = frame / max(frames - 1, 1)
    return np.array([0.04 * math.sin(2.0 * math.pi * u), 0.03 * u, -0.02 * u])


def collider_matrix(frame: int, frames: int) -> np.ndarray:
    """4x4 world matrix of the collider at ``frame`` (rigid: rotation + translation).

    The centre orbits 360 degrees around the body on a tilted great circle
    while its distance to the body centre dips from just outside the fur
    (first frame) to its deepest mid-shot, where the ellipsoid's surface sinks
    ``DEPTH`` below the skin (roots inside it are pinched), then rises back
    out. The ellipsoid also spins about a tilted axis, so the matrix is a real
    rotation, not just a translation. Over the shot about a fifth of the
    curves are colliding or still recovering in its wake (recovery_rate 0.2).
    """
    u = frame / max(frames - 1, 1)
    ang = math.radians(SWEEP_DEG * (u - 0.5))
    far = BODY_RADIUS + 0.25 + max(COLLIDER_AXES) + 0.05
    deep = BODY_RADIUS + min(COLLIDER_AXES) - DEPTH
    dip = math.sin(math.pi * u) ** 0.5
    dist = far + (deep - far) * dip
    centre = _ORBIT @ (dist * np.array([math.sin(ang), 0.0, math.cos(ang)]))
    R = _rot([0.3, 1.0, 0.2], ang * 1.5) @ _rot([0.0, 0.0, 1.0], 0.6)
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = centre + body_translation(frame, frames)
    return M


def deformed_vertices(V: np.ndarray, frame: int, frames: int) -> np.ndarray:
    """World-space vertices of the deforming collider: the rigid motion baked
    in, plus a travelling radial wobble of up to 4% (so every frame differs)."""
    u = frame / max(frames - 1, 1)
    Vd = V.astype(np.float64)
    r = np.linalg.norm(Vd, axis=1, keepdims=True)
    w = 1.0 + 0.04 * np.sin(6.0 * Vd[:, 0:1] / r + 4.0 * Vd[:, 2:3] / r + 2.0 * math.pi * u)
    Vd = Vd * w
    M = collider_matrix(frame, frames)
    return np.ascontiguousarray(Vd @ M[:3, :3].T + M[:3, 3], dtype=np.float32)


def fur_points(fur: Fur, frame: int, frames: int) -> np.ndarray:
    """Input curves of ``frame`` (world space, float32)."""
    return fur.rest + body_translation(frame, frames).astype(np.float32)


# ----------------------------------------------------------------------------- sustained contact
# A hat resting on the fur (issue 10): most of the contact lasts the whole shot.

# The hat is a shell of revolution about the head's centre: over the crown its
# inner surface clears the skin by HAT_GAP (the fur, 0.15-0.25 long, is pressed
# flat under it: about a fifth of the curves), toward the rim it narrows into a
# band that dips below the skin (roots there are inside the hat's wall: about
# 4.5 % of them, pinched). Swinging about the head's centre slides it over the
# fur, so most contacts last from frame to frame, as a hat resting on a head.
HAT_GAP = 0.10
HAT_THICKNESS = 0.04
HAT_CROWN_DEG = 40.0  # polar angle where the band starts narrowing
HAT_BRIM_DEG = 60.0  # polar angle of the rim
HAT_DIP = 0.03  # the rim's inner surface sits this far below the skin
HAT_SWING_DEG = 25.0


def _hat_inner_radius(theta):
    t = np.clip((np.degrees(theta) - HAT_CROWN_DEG) / (HAT_BRIM_DEG - HAT_CROWN_DEG), 0.0, 1.0)
    smooth = t * t * (3.0 - 2.0 * t)
    return BODY_RADIUS + HAT_GAP - (HAT_GAP + HAT_DIP) * smooth


def hat_shell(tris: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed, outward-wound hat in its own space (the head's centre at the
    origin): inner and outer caps (polar angle 0..``HAT_BRIM_DEG`` about +z)
    joined by a rim band; about ``tris`` triangles."""
    # 2 caps x (2 * n_lon * n_lat) + the rim (2 * n_lon) ~ tris, n_lon = 2 n_lat
    n_lat = max(2, round(math.sqrt(tris / 8.0)))
    n_lon = 2 * n_lat
    theta = np.linspace(0.0, math.radians(HAT_BRIM_DEG), n_lat + 1)[1:]
    lon = np.linspace(0.0, 2.0 * math.pi, n_lon, endpoint=False)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    ring = np.stack(
        [st * np.cos(lon)[None], st * np.sin(lon)[None], np.broadcast_to(ct, (n_lat, n_lon))],
        axis=-1,
    )  # (n_lat, n_lon, 3)
    r_in = _hat_inner_radius(theta)[:, None, None]
    crown = _hat_inner_radius(0.0)
    outer = np.concatenate([[[0.0, 0.0, crown + HAT_THICKNESS]],
                            (ring * (r_in + HAT_THICKNESS)).reshape(-1, 3)])
    inner = np.concatenate([[[0.0, 0.0, crown]], (ring * r_in).reshape(-1, 3)])
    nv = len(outer)
    V = np.concatenate([outer, inner])

    def vid(r, j, shell):
        return shell * nv + 1 + r * n_lon + (j % n_lon)

    j = np.arange(n_lon)
    faces = []
    for shell, flip in ((0, False), (1, True)):  # outer faces out, inner faces in (toward 0)
        pole = shell * nv
        f = [np.stack([np.full(n_lon, pole), vid(0, j, shell), vid(0, j + 1, shell)], axis=1)]
        r = np.arange(n_lat - 1)[:, None]
        a, b = vid(r, j, shell), vid(r, j + 1, shell)
        c, d = vid(r + 1, j, shell), vid(r + 1, j + 1, shell)
        f.append(np.stack([a, c, d], axis=-1).reshape(-1, 3))
        f.append(np.stack([a, d, b], axis=-1).reshape(-1, 3))
        f = np.concatenate(f)
        faces.append(f[:, ::-1] if flip else f)
    last = n_lat - 1  # the rim band joins the last rings of both caps
    a, b = vid(last, j, 0), vid(last, j + 1, 0)
    c, d = vid(last, j, 1), vid(last, j + 1, 1)
    faces.append(np.stack([a, c, d], axis=1))
    faces.append(np.stack([a, d, b], axis=1))
    F = np.concatenate(faces).astype(np.int32)
    return np.ascontiguousarray(V, dtype=np.float32), F


def hat_matrix(frame: int, frames: int) -> np.ndarray:
    """4x4 world matrix of the hat: resting on the head, swinging
    +-``HAT_SWING_DEG`` about the head's centre (a slow rock about x, half as
    much about y), and moving with the body."""
    u = frame / max(frames - 1, 1)
    a = math.radians(HAT_SWING_DEG) * math.sin(2.0 * math.pi * u)
    b = 0.5 * math.radians(HAT_SWING_DEG) * math.sin(4.0 * math.pi * u)
    R = _rot([1.0, 0.0, 0.0], a) @ _rot([0.0, 1.0, 0.0], b)
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = body_translation(frame, frames)
    return M


def hat_vertices(V: np.ndarray, frame: int, frames: int) -> np.ndarray:
    """World vertices of the deforming hat: the rigid swing baked in, plus a
    soft travelling bulge of up to 1.5% of the radius (a cloth hat breathing),
    so every vertex moves differently every frame."""
    u = frame / max(frames - 1, 1)
    Vd = V.astype(np.float64)
    r = np.linalg.norm(Vd, axis=1, keepdims=True)
    w = 1.0 + 0.015 * np.sin(5.0 * Vd[:, 0:1] / r + 3.0 * Vd[:, 1:2] / r + 2.0 * math.pi * u)
    Vd = Vd * w
    M = hat_matrix(frame, frames)
    return np.ascontiguousarray(Vd @ M[:3, :3].T + M[:3, 3], dtype=np.float32)


@dataclass
class Shot:
    """One benchmark scene: the fur, a collider and its motion."""

    name: str
    title: str
    fur: Fur
    V: np.ndarray  # collider in its own space
    F: np.ndarray
    matrix: object  # frame, frames -> (4, 4) (rigid)
    vertices: object  # V, frame, frames -> (n, 3) world (deforming)

    def points(self, frame: int, frames: int) -> np.ndarray:
        return fur_points(self.fur, frame, frames)


def brief_contact(curves: int, cvs: int, tris: int, seed: int = 1) -> Shot:
    """An ellipsoid orbiting through the fur: contact that passes."""
    V, F = make_collider(tris)
    return Shot("brief", "brief contact (a collider orbiting through the fur)",
                make_fur(curves, cvs, seed), V, F, collider_matrix, deformed_vertices)


def sustained_contact(curves: int, cvs: int, tris: int, seed: int = 1) -> Shot:
    """A hat resting on the fur and swinging: contact that lasts."""
    V, F = hat_shell(tris)
    return Shot("sustained", "sustained contact (a hat resting on the fur, swinging)",
                make_fur(curves, cvs, seed), V, F, hat_matrix, hat_vertices)
