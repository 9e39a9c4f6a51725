"""The angle search's promises about its work (README "Temporal coherence").

The answers of the search are held bit for bit elsewhere (``test_warm_start.py``,
``test_settings_precision.py``); these tests hold *how little* it probes where it
knows something: a known bracket is bisected, not searched again from its bottom; a
first stride is used; a lasting contact is confirmed in one round of two to four
probes (``rigid.Plan`` docstring). Each probe of a real curve costs a ray per segment,
so a search that forgets what it knows gives the same picture, only slower: what a
speed benchmark would notice late and a picture never.

The searches run on a stand-in batch whose curve ``i`` clears exactly from the angle
``clear_from[i]`` up (clearance monotone in the angle), which counts every probe.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from core import rigid

P = 0.01  # Rotation Precision of the stand-in context (radians)


class Batch:
    """Curves that are blocked below ``clear_from`` and clear from it up."""

    def __init__(self, clear_from):
        self.clear_from = np.asarray(clear_from, np.float64)
        self.curves = np.arange(len(self.clear_from))
        self.probes = np.zeros(len(self.clear_from), np.int64)

    def hits(self, items, theta):
        items = np.asarray(items)
        np.add.at(self.probes, items, 1)
        # half a step of slack: the angles are sums of steps
        return np.asarray(theta) < self.clear_from[items] - 0.5 * P


def _ctx(n, max_angle=10.0, contact=None, delta=None):
    state = SimpleNamespace(
        contact=np.zeros(n, bool) if contact is None else np.asarray(contact, bool),
        delta=np.zeros(n) if delta is None else np.asarray(delta, np.float64),
    )
    return SimpleNamespace(prec=P, max_angle=max_angle, guess=np.zeros(n), state=state,
                           max_angle_of=lambda curves: max_angle)


@pytest.mark.parametrize("width", [2, 3, 5, 8, 13, 32, 64, 100])
def test_a_known_bracket_is_bisected(width):
    """Blocked at ``lo``, clear at ``hi``: at most ceil(log2(hi - lo)) probes,
    whatever step in between is the answer."""
    n = width
    lo = np.full(n, 7, np.int64)
    hi = lo + width
    answer = lo + 1 + np.arange(n) % width  # every step of the bracket
    th0 = np.zeros(n)
    batch = Batch(th0 + answer * P)
    ctx = _ctx(n)
    k, _ = rigid.search_angles(ctx, batch, np.arange(n), th0, lo, hi,
                               np.ones(n, np.int64), np.zeros(n, bool))
    np.testing.assert_array_equal(k, answer)
    assert batch.probes.max() <= math.ceil(math.log2(width))


@pytest.mark.parametrize("stride", [4, 16, 64])
def test_the_first_stride_is_used(stride):
    """Nothing known above ``lo`` and a first stride ``s`` (the warm start's guess of
    the step): an answer within ``s`` costs at most 1 + log2(s) probes."""
    n = stride
    lo = np.zeros(n, np.int64)
    answer = 1 + np.arange(n)  # 1 .. s
    th0 = np.full(n, 0.5)
    batch = Batch(th0 + answer * P)
    ctx = _ctx(n)
    k, _ = rigid.search_angles(ctx, batch, np.arange(n), th0, lo, np.full(n, -1, np.int64),
                               np.full(n, stride, np.int64), np.zeros(n, bool))
    np.testing.assert_array_equal(k, answer)
    assert batch.probes.max() <= 1 + math.ceil(math.log2(stride))


def test_a_recovery_bracket_is_bisected_in_the_same_rounds():
    """Recovery searches (``bisect=``) keep their known blocked step: a bracket of 4
    near the top of a 64-step recovery arc costs 2 probes, not a search of the arc."""
    n = 6
    K = np.full(n, 64, np.int64)
    blo = K - 4
    bhi = K.copy()
    base = np.full(n, 0.2)  # the recovery step th1
    cap = base + K * P  # th0
    answer = blo + 1 + np.arange(n) % 4
    batch = Batch(np.concatenate([[9.0], base + answer * P]))  # item 0: a collision search
    ctx = _ctx(n + 1)
    items = np.array([0])
    k_col, k_rec = rigid.search_angles(
        ctx, batch, items, np.array([8.0]), np.array([99], np.int64), np.array([100], np.int64),
        np.ones(1, np.int64), np.zeros(1, bool),
        bisect=(np.arange(1, n + 1), base, cap, K, blo, bhi))
    np.testing.assert_array_equal(k_col, [100])  # already settled: not probed
    np.testing.assert_array_equal(k_rec, answer)
    assert batch.probes[0] == 0
    assert batch.probes[1:].max() <= 2


def _warm(th0, th1, delta, clear_from, max_angle=10.0):
    """The rigid solver's sequence for curves in contact: warm first round, then the
    searches it leaves. Returns (plan, collision steps, probes per curve)."""
    n = len(th0)
    ctx = _ctx(n, max_angle, contact=np.ones(n, bool), delta=delta)
    batch = Batch(clear_from)
    plan = rigid.Plan(ctx, np.arange(n), np.asarray(th0, float), np.asarray(th1, float))
    plan.first_round_warm(batch)
    items, lo, hi, stride, guess = plan.collision_searches()
    assert not guess.any()  # a contact's memory is a start: no tangent-plane guess needed
    k_col, k_rec = rigid.search_angles(ctx, batch, items, plan.th0[items], lo, hi, stride,
                                       guess, plan.recovery_searches())
    plan.recovery_found(k_rec)
    k = np.full(n, -9, np.int64)
    k[items] = k_col
    return plan, k, batch.probes


@pytest.mark.parametrize("turn", [1, 2, 3, 7, 20])
def test_a_contact_turning_as_last_step_is_confirmed_in_one_round(turn):
    """A contact that turned by ``turn`` steps last step and turns as much again: one
    round probes th0 (blocked), the predicted step (clear), the step below it (blocked,
    where it is not th0) and the recovery step (blocked): nothing left to search."""
    n = 5
    th0 = np.full(n, 0.5)
    th1 = th0 - 0.1  # Recovery Rate 0.2 of the angle
    clear_from = th0 + turn * P
    plan, k, probes = _warm(th0, th1, np.full(n, turn * P), clear_from)
    np.testing.assert_array_equal(plan.regime, 1)  # collision
    np.testing.assert_array_equal(k, turn)
    np.testing.assert_array_equal(probes, 4 if turn > 1 else 3)


@pytest.mark.parametrize("off", [-3, -1, 1, 4])
def test_a_contact_that_turns_otherwise_is_searched_from_its_prediction(off):
    """When the prediction misses by a few steps, the search goes on from what the
    first round found (a gallop from the blocked prediction with half the predicted
    turn as its stride, or a bisection below the clear one): at most one round plus
    1 + log2(turn) probes."""
    n = 4
    turn = 12
    th0 = np.full(n, 0.5)
    plan, k, probes = _warm(th0, th0 - 0.1, np.full(n, turn * P), th0 + (turn + off) * P)
    np.testing.assert_array_equal(k, turn + off)
    assert probes.max() <= 4 + 1 + math.ceil(math.log2(turn))


def test_a_held_contact_is_confirmed_in_one_round():
    """A contact that held last step (no change) and holds: th0 (clear), the step
    below it on the recovery arc (blocked) and the recovery step (blocked)."""
    n = 5
    th0 = np.full(n, 0.6)
    th1 = th0 - 0.12
    plan, k, probes = _warm(th0, th1, np.zeros(n), th0)
    np.testing.assert_array_equal(plan.regime, 2)  # recovery, stopped before contact
    np.testing.assert_array_equal(plan.recovered_angle(np.arange(n)), th0)
    np.testing.assert_array_equal(probes, 3)


@pytest.mark.parametrize("clear_step", [0, 1])
def test_a_contact_that_gave_way_to_one_step_above_its_recovery_step(clear_step):
    """A contact predicted one step above its recovery step (it gave way almost all of
    the recovery last step): the prediction and the recovery step, each probed once
    (the step below the prediction is the recovery step: not probed twice)."""
    n = 5
    th0 = np.full(n, 0.6)
    th1 = th0 - 10 * P
    plan, k, probes = _warm(th0, th1, np.full(n, -9 * P), th1 + clear_step * P)
    np.testing.assert_array_equal(plan.regime, 2)
    np.testing.assert_allclose(plan.recovered_angle(np.arange(n)), th1 + clear_step * P)
    np.testing.assert_array_equal(probes, 2)


def test_a_contact_pushed_further_starts_from_the_tangent_plane_estimate(monkeypatch):
    """A curve in contact whose shape the collider moved into (nothing known above
    its angle) starts its search from the tangent-plane estimate at its first hit
    (``StepContext.plane_guess``): one round at the estimate, then a bisection of the
    bracket it leaves or a gallop with a stride of a fraction of the estimate, instead
    of a gallop from one step."""
    import scenes

    from core import Collider, Settings, Solver

    probes = []
    hits = rigid.RigidBatch.hits

    def counting(self, items, theta):
        probes.append(len(items))
        return hits(self, items, theta)

    pts, offs = scenes.pack([scenes.straight_curve([0.0, 0.0, 0.0], [0, 0, 1], 1.0, 6)])
    solver = Solver(offs, Settings(mode="stiff", rotation_precision=0.25))
    solver.warm_start = False  # every collision is searched from its current angle
    V, F = scenes.box([-2.0, -2.0, 0.7], [2.0, 2.0, 3.0])
    M = scenes.affine(scenes.rotation_matrix([1.0, 0.0, 0.0], np.radians(8.0)))
    col = Collider(V, F, matrix=M)
    solver.step(pts, [col])
    a1 = solver.state["angle"][0]
    assert a1 > 0
    col.matrix = M @ scenes.translation([0.0, 0.0, -0.25])  # further into the fur
    monkeypatch.setattr(rigid.RigidBatch, "hits", counting)
    solver.step(pts, [col])
    a2 = solver.state["angle"][0]
    assert a2 > a1 + np.radians(5.0)  # a search of more than 20 steps
    # th1, th0, the estimate's probe and a short bisection below it: 9 probes here,
    # where a gallop from one step (no estimate) takes 15
    assert sum(probes) <= 12


def test_each_curve_starts_from_its_own_estimate():
    """The estimate round (``use_guess``) probes ``rigid._GUESS_FACTOR`` (1.3) times
    each curve's own estimate: a curve with a small estimate next to one with a large
    one is bracketed near its own answer, not at the other's probes."""
    n = 8
    th0 = np.zeros(n)
    kmax_angle = 3.0
    answer = np.where(np.arange(n) % 2 == 0, 80, 4)  # big and small, interleaved
    batch = Batch(th0 + answer * P)
    ctx = _ctx(n, max_angle=kmax_angle)
    guess = answer * P  # exact estimates
    k, _ = rigid.search_angles(ctx, batch, np.arange(n), th0, np.zeros(n, np.int64),
                               np.full(n, -1, np.int64), np.ones(n, np.int64),
                               np.ones(n, bool), guess=guess)
    np.testing.assert_array_equal(k, answer)
    small = answer == 4
    # the estimate's probe (step 5, clear), then a bisection of (0, 5]: 3 and 4
    assert batch.probes[small].max() <= 3


def test_probe_stages_trace_every_segment_once_tip_first():
    """A probe's segments are traced in ranges (``rigid._stages``): together they are
    every segment exactly once, and the first is the tip segment alone (a colliding
    probe usually collides there: one ray)."""
    for ns in range(1, 40):
        stages = rigid._stages(ns)
        covered = np.concatenate([np.arange(a, b) for a, b in stages])
        np.testing.assert_array_equal(np.sort(covered), np.arange(ns))
        if ns - ns // 2 >= 3:  # (shorter curves: the outer half, then the rest)
            assert stages[0] == (ns - 1, ns)


def test_a_released_curve_forgets_its_largest_angle():
    """A curve back at its input shape drops its local state (``rigid.release``): its
    largest angle too, so Plasticity turned on later imprints the next contact's own
    largest angle, not the old contact's."""
    import scenes

    from core import Collider, Settings, Solver

    pts, offs = scenes.pack([scenes.straight_curve([0.0, 0.0, 0.0], [0, 0, 1], 1.0, 6)])
    V, F = scenes.uv_sphere([0.0, 0.0, 0.0], 1.0, 24, 12)
    solver = Solver(offs, Settings(mode="stiff", recovery_rate=1.0))
    big = Collider(V, F, matrix=scenes.affine(t=[0.1, 0.0, 0.7], s=0.4))
    solver.step(pts, [big])
    assert solver.state["angle_max"][0] > np.radians(20)
    solver.step(pts, [])  # recovery rate 1: back at the input shape, released
    assert solver.state["angle"][0] == 0.0 and solver.state["angle_max"][0] == 0.0
    solver.settings = Settings(mode="stiff", recovery_rate=1.0, plasticity=0.5)
    small = Collider(V, F, matrix=scenes.affine(t=[0.2, 0.0, 0.8], s=0.35))
    solver.step(pts, [small])
    a = solver.state["angle"][0]
    assert 0 < a < np.radians(15)
    solver.step(pts, [])
    np.testing.assert_allclose(solver.state["angle"][0], 0.5 * a, atol=np.radians(0.25))


def test_a_contact_one_step_below_max_angle_is_confirmed_in_one_round():
    """A contact turning by one step that reaches Max Angle with it (one step left:
    kmax = 1) is predicted like any other: th0 (blocked), the step (clear) and the
    recovery step (blocked), and nothing left to search."""
    n = 3
    max_angle = 1.0
    th0 = np.full(n, max_angle - 0.5 * P)
    plan, k, probes = _warm(th0, th0 - 0.1, np.full(n, P), np.full(n, max_angle + 0.25 * P),
                            max_angle=max_angle)
    np.testing.assert_array_equal(plan.kmax, 1)
    np.testing.assert_array_equal(k, 1)
    np.testing.assert_array_equal(probes, 3)
