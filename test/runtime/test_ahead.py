"""The look-ahead buffers, without ROS: values, batch sizes, skips, failures, worker batches."""

import math

import numpy as np
import pytest

from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.runtime.ahead import (AHEAD_MAX, AHEAD_MIN, AMORTIZE, BATCH_BUDGET_S,
                                        LATE_SHARE, Lookahead, PERIOD_SHARE, SensorAhead,
                                        STRIKES, WARMUP_S, WORKER_AHEAD_S, WORKER_BATCH,
                                        WORKER_BUDGET_S)
from rigidrot_ros.runtime.worker import BatchWorker

from lookahead_helpers import sensor  # noqa: I100, I201 - a helper module beside it

SCENE = Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05), omega0=(0.3, -0.2, 0.5))
PERIOD = 0.01


def _time_of(k):
    return 3.0 * PERIOD * k                 # time_scale 3


def test_buffered_samples_are_the_exact_solution_within_their_bounds():
    sol = solve(SCENE)
    ref = solve(SCENE, tol=2e-14)
    # a long period for the budget's aim: the sizes here do not depend on this CPU's speed
    la = Lookahead(sol, _time_of, 10.0, budget_s=1.0,
                   build=lambda start, data: ['buffered'] * len(data[0]))
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


def test_build_is_called_once_per_batch_with_its_arrays_and_can_be_dropped():
    calls = []

    def build(start, data):
        q, w, e = data
        calls.append((start, q.shape, w.shape, e.shape))
        return [('msg', start + i, e[i]) for i in range(len(q))]
    la = Lookahead(solve(SCENE), _time_of, PERIOD, budget_s=1.0, build=build)
    la.get(0)
    la.refill(0)
    assert calls == [(1, (AHEAD_MIN, 4), (AHEAD_MIN, 3), (AHEAD_MIN,))]
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
    assert la.size == 0 and 'ArithmeticError' in la.off_reason and 'per sample' in la.off_reason
    (q, w, b), built = la.get(1)                     # per tick from now on
    assert built is None and math.isfinite(b)
    assert la.refill(1) == 0


class _Clock:
    """A monotonic clock the test moves."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_batches_beyond_their_budget_turn_the_lookahead_off_after_strikes_past_warmup():
    clock = _Clock()
    la = Lookahead(solve(SCENE), _time_of, PERIOD, budget_s=1e-9, clock=clock)
    k = 0
    for _ in range(2 * STRIKES):                     # warm-up: slow batches only keep it small
        k += la.refill(k)
        assert la.size == AHEAD_MIN and la.off_reason == ''
    clock.t += WARMUP_S
    for strike in range(STRIKES - 1):
        k += la.refill(k)
        assert la.size == AHEAD_MIN and la.off_reason == ''
    assert la.refill(k) == AHEAD_MIN
    assert la.size == 0 and 'beyond the budget' in la.off_reason
    assert 'after the warm-up' in la.off_reason
    assert len(la.take_stats()) == 3 * STRIKES and la.take_stats() == []


def test_one_slow_batch_only_shrinks_the_next():
    la = Lookahead(solve(SCENE), _time_of, PERIOD, budget_s=1.0)
    k = 0
    for _ in range(4):
        k += la.refill(k)
    assert la.size == 128
    la.budget_s = 1e-9                              # as if a batch were slowed down once
    la.period_s = 1e-9
    k += la.refill(k)
    assert la.size == AHEAD_MIN
    la.budget_s, la.period_s = 1.0, PERIOD
    la._costs = []                                  # (the slow one would be fitted too)
    k += la.refill(k)
    assert la.size == 2 * AHEAD_MIN and la.off_reason == ''


@pytest.mark.parametrize('rate', [1000.0, 2000.0, 4000.0])
def test_a_gyro_like_cost_keeps_the_lookahead_on_and_sized_at_khz_rates(rate):
    """A fixed 0.4 ms a batch plus 1.5 us a sample (the gyro, measured) at 1-4 kHz."""
    clock = _Clock()
    la = Lookahead(solve(SCENE), _time_of, 1.0 / rate, clock=clock)
    clock.t += 10 * WARMUP_S
    n = AHEAD_MIN
    for _ in range(12):
        la._judge(n, 4e-4 + 1.5e-6 * n)
        assert la.size >= AHEAD_MIN, la.off_reason
        n = la.size
    fixed, per = la._fit()
    assert fixed == pytest.approx(4e-4, rel=1e-6) and per == pytest.approx(1.5e-6, rel=1e-6)
    for share in (PERIOD_SHARE, LATE_SHARE):        # room between two samples: aim there,
        if 4e-4 + 1.5e-6 * AHEAD_MIN <= share / rate:   # else within 1.2 periods
            assert 4e-4 + 1.5e-6 * n <= share / rate
            assert 4e-4 + 1.5e-6 * min(2 * n, AHEAD_MAX) > share / rate or n == AHEAD_MAX
            break
    else:                                           # no room: large batches within budget
        assert n == AHEAD_MAX and 4e-4 + 1.5e-6 * n <= BATCH_BUDGET_S


def test_a_sensor_lookahead_reads_each_sample_once_in_order():
    reads = []

    def read(ks):
        reads.extend(ks)
        return [('s', k) for k in ks], None
    la = SensorAhead(read, lambda k: read(range(k, k + 1))[0][0], 1e-3, first=1,
                     budget_s=1.0)
    got = []
    for k in range(1, 200):
        got.append(la.get(k)[0])
        la.refill(k)
    assert got == [('s', k) for k in range(1, 200)]
    assert reads == sorted(set(reads)) and reads[:199] == list(range(1, 200))


@pytest.mark.parametrize('how', ['strikes', 'failing batch'])
def test_a_sensor_lookahead_turned_off_keeps_what_it_read(how):
    """Samples read before the look-ahead went off are published, none is read twice."""
    reads, fail = [], [False]
    clock = _Clock()

    def read(ks):
        if fail[0] and len(ks) > 1:
            raise ValueError('a block too hard')
        reads.extend(ks)
        return [('s', k) for k in ks], None
    la = SensorAhead(read, lambda k: read(range(k, k + 1))[0][0], 1e-3, first=1,
                     budget_s=1.0 if how == 'failing batch' else 1e-9, clock=clock)
    clock.t += 10 * WARMUP_S
    got = []
    for k in range(1, 120):
        got.append(la.get(k)[0])
        la.refill(k)
        if k == 30:
            fail[0] = True
    assert la.size == 0 and la.off_reason
    assert got == [('s', k) for k in range(1, 120)]
    assert reads == list(range(1, max(reads) + 1))      # each once, in order


def test_a_sensor_batch_beyond_the_budget_is_amortized_never_turned_off():
    """An imu with an accelerometer: ~2 ms fixed a batch (under load) beyond the 2 ms budget."""
    clock = _Clock()
    la = SensorAhead(lambda ks: ([None] * len(ks), None), None, 1e-3, first=1, clock=clock)
    clock.t += 10 * WARMUP_S
    n = AHEAD_MIN
    for _ in range(4 * STRIKES):
        la._judge(n, 2.1e-3 + 1e-5 * n)
        assert la.size >= AHEAD_MIN and la.off_reason == ''
        n = la.size
    aim = AMORTIZE * (2.1e-3 + 1e-5 * AHEAD_MIN)
    assert n > 4 * AHEAD_MIN and 2.1e-3 + 1e-5 * n <= aim < 2.1e-3 + 1e-5 * (n + 1)


def test_disabled_lookahead_evaluates_every_tick():
    la = Lookahead(solve(SCENE), _time_of, PERIOD, enabled=False)
    assert la.refill(0) == 0 and la.off_reason == 'disabled'
    assert la.get(3)[1] is None


def test_a_catch_up_reads_the_owed_samples_as_one_batch_each_once():
    """fill_to: the samples a late call owes come from one batch, none evaluated alone."""
    reads = []
    la = sensor(reads)
    la.get(1)
    la.refill(1)                                    # 2 .. 9 buffered
    assert la.fill_to(2, 300) == 300 - (1 + AHEAD_MIN)   # 10 .. 300 in one read
    assert la.catch_ups == 1
    misses = la.misses
    assert [la.get(k)[0] for k in range(2, 301)] == [('s', k) for k in range(2, 301)]
    assert la.misses == misses                      # every one was buffered
    assert reads == list(range(1, 301))             # each once, in order
    assert la.fill_to(301, 301) == 0                # one missing sample: evaluated alone
    la.refill(300)
    assert la.fill_to(500, 520) == 21               # indices skipped: read from 500 on
    assert la.get(500)[0] == ('s', 500) and 400 not in reads


def test_a_truth_catch_up_is_the_solution_and_no_strike():
    sol = solve(SCENE)
    la = Lookahead(sol, _time_of, PERIOD, budget_s=1e-9)     # every judged batch is over
    la.get(0)
    la.fill_to(1, 400)
    assert la.size == AHEAD_MIN and la.off_reason == '' and la.catch_ups == 1
    for k in (1, 200, 400):
        (q, _, bound), built = la.get(k)
        assert built is None                        # no build: the sample alone
        r = sol.at(_time_of(k))
        assert float(quat.angle_between(np.array(q), r.quaternion)) <= 2 * bound
    assert la.misses == 1                           # tick 0 only


def test_worker_batches_give_the_samples_of_inline_batches_bit_for_bit():
    sol = solve(SCENE)
    worker = BatchWorker()
    try:
        inline = Lookahead(sol, _time_of, PERIOD, budget_s=1.0)
        threaded = Lookahead(sol, _time_of, PERIOD, budget_s=1.0, worker=worker)
        for k in range(1000):
            a, b = inline.get(k), threaded.get(k)
            assert a[0] == b[0], k                  # plain floats: exactly equal
            inline.refill(k)
            threaded.refill(k)
        assert threaded.misses == 1 and len(threaded.take_stats()) > 3
    finally:
        worker.stop()
    assert not worker.alive
    with pytest.raises(RuntimeError, match='stopped'):
        worker.submit(None)


def test_a_sensor_in_the_worker_is_read_once_in_order_and_waited_for():
    """An index whose batch still runs in the worker waits for it; none is read twice."""
    import threading
    reads, gate = [], threading.Event()
    gate.set()
    worker = BatchWorker()
    try:
        la = sensor(reads, worker, gate)
        got = []
        for k in range(1, 300):
            got.append(la.get(k)[0])
            if k == 100:
                la._collect(wait=True)
                gate.clear()                        # the next batch blocks in the worker
                threading.Timer(0.2, gate.set).start()      # released while get() waits
            n = la.refill(k)
            if n and not gate.is_set():
                assert la.ahead_of(k) >= n          # reserved at once, read later
        assert got == [('s', k) for k in range(1, 300)]
        assert reads == list(range(1, max(reads) + 1))      # each once, in order
        assert la.misses == 1
    finally:
        gate.set()
        worker.stop()


def test_frames_changed_while_a_batch_runs_drop_its_built_messages():
    import threading
    gate = threading.Event()
    worker = BatchWorker()
    try:
        def build(start, data):
            gate.wait()
            return ['old frames'] * len(data[0])
        la = Lookahead(solve(SCENE), _time_of, PERIOD, budget_s=1.0, build=build,
                       worker=worker)
        la.get(0)
        assert la.refill(0) == AHEAD_MIN            # in the worker, blocked in build
        la.drop_built()
        gate.set()
        assert all(la.get(k)[1] is None for k in range(1, 1 + AHEAD_MIN))
    finally:
        gate.set()
        worker.stop()


def test_a_failing_batch_in_the_worker_turns_off_and_evaluates_per_sample():
    worker = BatchWorker()
    try:
        la = Lookahead(_FailingBatches(solve(SCENE)), _time_of, PERIOD, worker=worker)
        assert la.refill(0) == AHEAD_MIN            # queued: the failure shows when taken in
        (q, w, b), built = la.get(1)
        assert built is None and math.isfinite(b)
        assert la.size == 0 and 'ArithmeticError' in la.off_reason
    finally:
        worker.stop()


def test_with_a_worker_a_batch_starts_a_batch_ahead_and_is_never_a_strike(monkeypatch):
    monkeypatch.setenv('RIGIDROT_WORKER_BATCH', '0')     # sized by the cost model
    clock = _Clock()
    worker = BatchWorker()
    try:
        la = Lookahead(solve(SCENE), _time_of, PERIOD, budget_s=1e-9, clock=clock,
                       worker=worker)
        clock.t += 10 * WARMUP_S                    # past the warm-up: these would be strikes
        sizes = []
        for k in range(300):
            la.get(k)
            before, size = la.ahead_of(k), la.size
            n = la.refill(k)
            if n:
                sizes.append(n)
                assert before <= max(size, WORKER_AHEAD_S / PERIOD)    # then, not sooner
        assert len(sizes) > 3 * STRIKES and set(sizes) == {AHEAD_MIN}
        assert la.off_reason == '' and la.size == AHEAD_MIN
        la._collect(wait=True)
        k = la._next - 1 - la.size                  # a whole batch (5 samples) after k
        assert WORKER_AHEAD_S / PERIOD < la.size
        inline = Lookahead(solve(SCENE), _time_of, PERIOD)
        inline.size, inline._next = la.size, la._next
        assert la.needs(k) and not inline.needs(k)  # a batch sooner than inline
    finally:
        worker.stop()


def test_with_a_worker_batches_are_fixed_size_within_the_worker_budget(monkeypatch):
    """In the worker every batch after the first is WORKER_BATCH: the fixed part paid once."""
    import itertools
    import time
    monkeypatch.delenv('RIGIDROT_WORKER_BATCH', raising=False)
    ticks = itertools.count()
    monkeypatch.setattr(time, 'thread_time', lambda: next(ticks) * 1e-6)    # 1 us a batch
    clock = _Clock()
    worker = BatchWorker()
    try:
        la = Lookahead(solve(SCENE), _time_of, PERIOD, budget_s=1e-9, clock=clock,
                       worker=worker)
        clock.t += 10 * WARMUP_S                    # past the warm-up: no excuse for cost
        sizes = []
        for k in range(1000):
            la.get(k)
            n = la.refill(k)
            if n:
                sizes.append(n)
        assert sizes[0] == AHEAD_MIN and set(sizes[1:]) == {WORKER_BATCH} and len(sizes) > 3
        assert la.off_reason == '' and la.size == WORKER_BATCH == AHEAD_MAX
        # a slow model: the batch shrinks to the worker's budget (cost model), never a strike
        la._costs = []
        la._judge(WORKER_BATCH, 4 * WORKER_BUDGET_S)        # one size seen: all per sample
        assert la.size == WORKER_BATCH // 4 and la.off_reason == ''
        la._judge(la.size, WORKER_BUDGET_S)                 # two sizes: a fixed part fitted
        assert AHEAD_MIN <= la.size <= WORKER_BATCH // 4
        la._costs = []
        la._judge(WORKER_BATCH, 1e3)                        # far over: the smallest batch
        assert la.size == AHEAD_MIN and la.off_reason == ''
    finally:
        worker.stop()


@pytest.mark.parametrize('value, size', [('0', 0), ('1', AHEAD_MIN), ('64', 64),
                                         ('100000', AHEAD_MAX), ('x', WORKER_BATCH)])
def test_the_worker_batch_size_from_the_environment(monkeypatch, value, size):
    monkeypatch.setenv('RIGIDROT_WORKER_BATCH', value)
    worker = BatchWorker()
    try:
        assert Lookahead(solve(SCENE), _time_of, PERIOD, worker=worker)._fixed_size == size
        assert Lookahead(solve(SCENE), _time_of, PERIOD)._fixed_size == 0    # inline
    finally:
        worker.stop()


def test_a_call_owing_samples_of_the_running_batch_does_not_wait_in_fill_to():
    """fill_to only waits for the worker's batch when it must evaluate past it."""
    import threading
    reads, gate = [], threading.Event()
    worker = BatchWorker()
    try:
        gate.set()
        la = sensor(reads, worker, gate)
        la.get(1)
        la._collect(wait=True)
        gate.clear()
        timer = threading.Timer(2.0, gate.set)      # releases the batch in any case
        timer.start()
        assert la.refill(1) == AHEAD_MIN            # 2 .. 9 reserved, blocked in the worker
        assert la.fill_to(2, 9) == 0                # all reserved: returns at once
        assert not la._job.done.is_set()            # (it did not wait for the batch)
        assert la.fill_to(2, 20) == 11              # past it: waits, then 10 .. 20
        assert reads == list(range(1, 21))          # in order, each once
        timer.cancel()
    finally:
        gate.set()
        worker.stop()
