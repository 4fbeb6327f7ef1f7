"""The node's look-ahead buffer, without ROS: values, batch sizes, skips, failures."""

import math

import numpy as np
import pytest

from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.node.lookahead import AHEAD_MAX, AHEAD_MIN, Lookahead, STRIKES

SCENE = Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05), omega0=(0.3, -0.2, 0.5))
PERIOD = 0.01


def _time_of(k):
    return 3.0 * PERIOD * k                 # time_scale 3


def test_buffered_samples_are_the_exact_solution_within_their_bounds():
    sol = solve(SCENE)
    ref = solve(SCENE, tol=2e-14)
    la = Lookahead(sol, _time_of, PERIOD, budget_s=1.0, build=lambda k, smp: 'buffered')
    seen_buffered = 0
    for k in range(600):
        (q, w, bound), built = la.get(k)
        r = ref.at(_time_of(k))
        err = float(quat.angle_between(np.array(q), r.quaternion))
        assert err <= bound + float(r.error_bound), (k, err, bound)
        assert bound <= sol.tol
        np.testing.assert_allclose(w, r.omega, rtol=0, atol=1e-14)
        seen_buffered += built == 'buffered'
        la.refill(k)
    assert seen_buffered > 500
    assert la.size == AHEAD_MAX


def test_batch_sizes_double_from_the_minimum_and_refill_at_half():
    la = Lookahead(solve(SCENE), _time_of, PERIOD, budget_s=1.0)
    sizes = []
    for k in range(400):
        la.get(k)
        n = la.refill(k)
        if n:
            sizes.append((k, n, len(la)))
    assert [n for _, n, _ in sizes[:6]] == [AHEAD_MIN, 16, 32, 64, 128, 256]
    for k, n, buffered in sizes[1:]:
        assert buffered - n <= n // 2 + 1            # refilled once half a batch was left
    assert all(n <= AHEAD_MAX for _, n, _ in sizes)


def test_skipped_ticks_drop_their_samples_and_a_miss_evaluates_at_once():
    sol = solve(SCENE)
    la = Lookahead(sol, _time_of, PERIOD, budget_s=1.0)
    la.get(0)
    la.refill(0)                                     # buffers 1..8
    assert len(la) == AHEAD_MIN
    (q, _, _), built = la.get(50)                    # far ahead: not buffered
    assert built is None
    assert quat.angle_between(np.array(q), sol.at(_time_of(50)).quaternion) <= 2e-12
    la.refill(50)
    assert min(la._buf) == 51 and len(la) == 16      # the stale 1..8 are gone


def test_build_is_called_with_each_buffered_sample_and_can_be_dropped():
    calls = []
    la = Lookahead(solve(SCENE), _time_of, PERIOD, budget_s=1.0,
                   build=lambda k, smp: calls.append(k) or ('msg', k, smp[2]))
    la.get(0)
    la.refill(0)
    assert calls == list(range(1, 1 + AHEAD_MIN))
    smp, built = la.get(1)
    assert built == ('msg', 1, smp[2])
    la.drop_built()
    smp2, built2 = la.get(2)
    assert built2 is None and len(smp2) == 3


class _FailingBatches:
    """A solution whose scalar calls work and whose batches raise (a far sample)."""

    def __init__(self, sol):
        self.sol = sol

    def at(self, t):
        if np.ndim(t):
            raise ArithmeticError('beyond the precision ceiling at t = 1e9 s')
        return self.sol.at(t)


def test_a_failing_batch_turns_the_lookahead_off_with_its_reason():
    sol = _FailingBatches(solve(SCENE))
    la = Lookahead(sol, _time_of, PERIOD)
    assert la.refill(0) == 0
    assert la.size == 0 and 'ArithmeticError' in la.off_reason and 'per tick' in la.off_reason
    (q, w, b), built = la.get(1)                     # per tick from now on
    assert built is None and math.isfinite(b)
    assert la.refill(1) == 0


def test_batches_beyond_their_budget_turn_the_lookahead_off_after_strikes():
    la = Lookahead(solve(SCENE), _time_of, PERIOD, budget_s=1e-9)
    k = 0
    for strike in range(STRIKES - 1):                # measured, then judged: shrink, go on
        k += la.refill(k)
        assert la.size == AHEAD_MIN and la.off_reason == ''
    assert la.refill(k) == AHEAD_MIN
    assert la.size == 0 and 'beyond the budget' in la.off_reason
    assert len(la.take_stats()) == STRIKES and la.take_stats() == []


def test_one_slow_batch_only_shrinks_the_next():
    la = Lookahead(solve(SCENE), _time_of, PERIOD, budget_s=1.0)
    k = 0
    for _ in range(4):
        k += la.refill(k)
    assert la.size == 128
    la.budget_s = 1e-9                              # as if a batch were slowed down once
    k += la.refill(k)
    assert la.size == AHEAD_MIN
    la.budget_s = 1.0
    k += la.refill(k)
    assert la.size == 2 * AHEAD_MIN and la.off_reason == ''


def test_budget_is_at_most_half_a_period():
    la = Lookahead(solve(SCENE), _time_of, 1e-3)
    assert la.budget_s == pytest.approx(5e-4)


def test_disabled_lookahead_evaluates_every_tick():
    la = Lookahead(solve(SCENE), _time_of, PERIOD, enabled=False)
    assert la.refill(0) == 0 and la.off_reason == 'disabled'
    assert la.get(3)[1] is None
