"""The documented public surface of ``core``."""

from __future__ import annotations

import enum
import time

import numpy as np
import pytest
import scenes

import core
from core import Collider, Settings, Solver, Status
from core.errors import ColliderError, InputError, SettingsError


def test_status_values():
    assert issubclass(Status, enum.IntEnum)
    assert [(s.name, int(s)) for s in Status] == [
        ("FREE", 0), ("COLLIDING", 1), ("RECOVERING", 2), ("PINCHED", 3),
        ("UNRESOLVED", 4), ("DISABLED", 5), ("INVALID", 6)]


def test_exports():
    for name in ("Collider", "Settings", "Solver", "Status"):
        assert hasattr(core, name)
    for E in (InputError, ColliderError, SettingsError):
        assert issubclass(E, ValueError)


def test_step_result_and_defaults():
    pts, offs = scenes.pack([scenes.straight_curve([0, 0, 0], [0, 0, 1], 1.0, 4)])
    V, F = scenes.uv_sphere([0.05, 0, 0.8], 0.3, 16, 8)
    col = Collider(V, F)
    assert col.closed
    solver = Solver(offs, Settings())
    res = solver.step(pts, [col])
    assert isinstance(res.points, np.ndarray) and res.points.shape == pts.shape
    assert res.status.dtype == np.int8
    assert res.status[0] == Status.COLLIDING
    # Settings() is the default
    res2 = Solver(offs).step(pts, [col])
    assert np.array_equal(res.points, res2.points)
    # colliders may be any iterable; a tuple works
    res3 = Solver(offs, Settings()).step(pts, (col,))
    assert np.array_equal(res.points, res3.points)


def test_timings_are_milliseconds_per_phase_and_the_ray_count():
    """README: ``res.timings`` holds milliseconds per phase (set-up, pinch, local
    frames, solve, output, total) and ``rays``, the number of rays cast."""
    pts, offs = scenes.pack([scenes.straight_curve([x, 0, 0], [0, 0, 1], 1.0, 6)
                             for x in np.linspace(-0.3, 0.3, 40)])
    V, F = scenes.uv_sphere([0.0, 0, 0.8], 0.3, 32, 16)
    solver = Solver(offs, Settings(mode="soft"))
    t0 = time.perf_counter()
    res = solver.step(pts, [Collider(V, F)])
    wall = (time.perf_counter() - t0) * 1e3
    t = res.timings
    phases = ("setup", "pinch", "frames", "solve", "output")
    assert set(phases) | {"total", "rays"} <= set(t), sorted(t)
    for k in (*phases, "total"):
        assert isinstance(t[k], float) and t[k] >= 0.0, (k, t[k])
    assert t["total"] <= wall
    # the phases run one after another (the pinch beside the local frames)
    assert t["setup"] + t["frames"] + t["solve"] + t["output"] <= t["total"]
    assert t["total"] >= 0.5 * wall or wall < 1.0, (t, wall)  # milliseconds, not seconds
    assert t["solve"] > 0.0 and isinstance(t["rays"], int) and t["rays"] > 0


@pytest.mark.parametrize("mode", ["stiff", "bend", "soft"])
@pytest.mark.parametrize("ragged", [False, True], ids=["uniform", "ragged"])
def test_the_ray_count_is_the_rays_traced(mode, ragged, monkeypatch):
    """``timings["rays"]`` counts every ray given to the tracer in the step, for a groom
    of one CV count (the component-array paths) and of several (the general ones)."""
    traced = []
    segment_hits_local = Collider.segment_hits_local

    def spy(self, o, d, offset_wo=0.0, threads=1, reach=None):
        traced.append(len(o))
        return segment_hits_local(self, o, d, offset_wo, threads, reach)

    monkeypatch.setattr(Collider, "segment_hits_local", spy)
    roots = [(x, y) for x in np.linspace(-0.5, 0.5, 6) for y in np.linspace(-0.5, 0.5, 6)]
    pts, offs = scenes.pack([scenes.straight_curve([x, y, 0.0], [0, 0, 1], 0.8,
                                                   5 + i % 3 if ragged else 6)
                             for i, (x, y) in enumerate(roots)], np.float32)
    V, F = scenes.uv_sphere([0.0, 0, 0.9], 0.4, 24, 12)
    solver = Solver(offs, Settings(mode=mode, recovery_rate=0.5))
    for f in range(4):  # contacts, recoveries and contacts that last
        traced.clear()
        res = solver.step(pts, [Collider(V, F, matrix=scenes.translation((0.05 * f, 0,
                                                                          -0.05 * f)))])
        assert (np.asarray(res.status) == Status.COLLIDING).sum() >= 10
        assert res.timings["rays"] == sum(traced) > 0, f


def test_collider_properties_roundtrip():
    V, F = scenes.box()
    M = scenes.translation([1, 2, 3])
    col = Collider(V, F, matrix=M)
    np.testing.assert_array_equal(np.asarray(col.vertices, float), V)
    np.testing.assert_array_equal(np.asarray(col.matrix, float), M)
    assert isinstance(col.build_count, int)
    # getters hand out copies (or read-only views): mutating them is harmless
    v = np.asarray(col.vertices)
    try:
        v[0] = 99.0
    except ValueError:
        pass
    np.testing.assert_array_equal(np.asarray(col.vertices, float), V)
