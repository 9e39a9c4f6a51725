"""Hypothesis strategies for the core's property tests: scenes drawn from their parameters.

Every number that shapes a scene (each curve's root, lean, length, CV count and curl,
each collider's kind, size, placement, orientation and sidedness, each animation's
speed and phase) is drawn by hypothesis, never derived from a drawn seed: so hypothesis
can shrink a failing scene (fewer curves, straighter, smaller colliders, no motion) and
search around it. Colliders are placed at a point of a drawn curve (plus a drawn offset),
so most scenes collide; ``require_contact`` rejects the few that do not (``assume``),
checked with the brute-force oracle. Numpy only: nothing from ``core``.
"""

from __future__ import annotations

import numpy as np
import oracle
import scenes
from hypothesis import assume
from hypothesis import strategies as st

#: Small meshes only (a few hundred triangles), as the invariant tests have always used.
COLLIDER_KINDS = ("sphere", "icosphere", "box", "plane", "plane2", "bumpy", "torus")


def floats(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


@st.composite
def directions(draw):
    """A unit vector from two drawn angles (shrinks toward +z)."""
    theta = draw(floats(0.0, np.pi))
    phi = draw(floats(0.0, 2 * np.pi))
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


@st.composite
def curves(draw, extent=1.0, n_cvs=(2, 10), length=(0.3, 1.2), curl_max=0.2):
    """One curve rooted on z = 0 growing up: straight or curly (shrinks to straight)."""
    root = np.array([draw(floats(-extent, extent)), draw(floats(-extent, extent)), 0.0])
    lean = np.array([draw(floats(-0.6, 0.6)), draw(floats(-0.6, 0.6)), 1.0])
    L = draw(floats(*length))
    n = draw(st.integers(*n_cvs))
    curl = draw(st.just(0.0) | floats(0.0, curl_max))
    if curl == 0.0:
        return scenes.straight_curve(root, lean, L, n)
    return scenes.curly_curve(root, lean, L, n, amplitude=curl, turns=draw(floats(0.3, 1.5)),
                              phase=draw(floats(0.0, 2 * np.pi)))


def _point_on(curve, t):
    """The point at arc-length fraction ``t`` of a polyline."""
    seg = np.linalg.norm(np.diff(curve, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)]) / seg.sum()
    return np.array([np.interp(t, s, curve[:, k]) for k in range(3)])


@st.composite
def collider_specs(draw, fur_curves, kinds=COLLIDER_KINDS):
    """A collider spec (``V`` local, ``F``, ``matrix``, ``double_sided``), placed at a
    drawn point of a drawn curve plus a drawn offset (so it usually meets the fur)."""
    kind = draw(st.sampled_from(kinds))
    c = fur_curves[draw(st.integers(0, len(fur_curves) - 1))]
    anchor = _point_on(c, draw(floats(0.3, 1.0)))
    center = anchor + np.array([draw(floats(-0.3, 0.3)) for _ in range(3)])
    R = scenes.rotation_matrix(draw(directions()), draw(floats(0.0, np.pi)))
    double = draw(st.booleans())
    if kind in ("sphere", "icosphere"):
        r = draw(floats(0.15, 0.6))
        V, F = (scenes.uv_sphere(radius=1.0, segments=24, rings=12) if kind == "sphere"
                else scenes.icosphere(radius=1.0, subdivisions=2))
        return dict(kind=kind, V=V, F=F, matrix=scenes.affine(R, t=center, s=r),
                    double_sided=double)
    if kind == "box":
        h = np.array([draw(floats(0.05, 0.5)) for _ in range(3)])
        V, F = scenes.box(-h, h)
        return dict(kind=kind, V=V, F=F, matrix=scenes.affine(R, t=center), double_sided=double)
    if kind in ("bumpy", "torus"):
        if kind == "bumpy":
            V, F = scenes.bumpy_sphere(radius=1.0, amplitude=draw(floats(0.0, 0.35)),
                                       lobes=draw(st.integers(2, 4)))
            s = draw(floats(0.2, 0.5))
        else:
            V, F = scenes.torus(R=1.0, r=draw(floats(0.15, 0.45)))
            s = draw(floats(0.25, 0.6))
        return dict(kind=kind, V=V, F=F, matrix=scenes.affine(R, t=center, s=s),
                    double_sided=double)
    # an open sheet crossing the fur, tilted (plane2: facing the other way)
    V, F = scenes.grid(size=draw(floats(0.6, 3.0)), n=3)
    tilt = scenes.rotation_matrix(draw(directions()), draw(floats(0.0, 0.6)))
    if kind == "plane2":
        tilt = tilt @ scenes.rotation_matrix([1, 0, 0], np.pi)
    return dict(kind=kind, V=V, F=F, matrix=scenes.affine(tilt, t=center), double_sided=double)


def colliding(points, offsets, specs):
    """(C,) bool: curves whose input surely crosses one of the colliders (oracle)."""
    hit = np.zeros(len(offsets) - 1, bool)
    for s in specs:
        hit |= oracle.segments_hit_mesh(points, offsets, scenes.world_vertices(s), s["F"])
    return hit


@st.composite
def fur_scenes(draw, max_curves=20, max_colliders=2, kinds=COLLIDER_KINDS, dtype=None,
               require_contact=True, n_cvs=(2, 10)):
    """(points, offsets, collider specs): drawn curves and colliders; with
    ``require_contact`` at least one curve's input crosses a collider.
    ``dtype``: float32 or float64 (drawn when None)."""
    cs = draw(st.lists(curves(n_cvs=n_cvs), min_size=1, max_size=max_curves))
    if dtype is None:
        dtype = draw(st.sampled_from([np.float64, np.float32]))
    pts, offs = scenes.pack(cs, dtype)
    specs = draw(st.lists(collider_specs(cs, kinds), min_size=1, max_size=max_colliders))
    if require_contact:
        assume(colliding(pts, offs, specs).any())
    return pts, offs, specs


@st.composite
def rigid_motions(draw, n):
    """``n`` drawn velocities (3,) for rigid collider motion (shrink toward still)."""
    return [np.array([draw(floats(-0.2, 0.2)) for _ in range(3)]) for _ in range(n)]


@st.composite
def sphere_scenes(draw, max_curves=20, extent=0.6, n_cvs=(3, 10),
                  center=((-0.3, 0.3), (-0.3, 0.3), (0.7, 1.1)), radius=(0.25, 0.5),
                  contact=True, curl_max=0.2, segments=(24, 12)):
    """(points, offsets, V, F, centre, radius): drawn fur under a UV sphere (24 x 12) at
    a drawn centre and radius; with ``contact`` some curve crosses it."""
    # (a few curves at least: a drawn sphere then meets one in most examples, so the
    # contact filter below rejects few)
    cs = draw(st.lists(curves(extent=extent, n_cvs=n_cvs, curl_max=curl_max),
                       min_size=min(4, max_curves) if contact else 1,
                       max_size=max_curves))
    pts, offs = scenes.pack(cs)
    c = np.array([draw(floats(*lim)) for lim in center])
    r = draw(floats(*radius))
    V, F = scenes.uv_sphere(c, r, *segments)
    if contact:
        assume(oracle.segments_hit_mesh(pts, offs, V, F).any())
    return pts, offs, V, F, c, r
