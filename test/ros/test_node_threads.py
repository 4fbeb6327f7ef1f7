"""The node's threads: catch-ups from one batch, the look-ahead worker serving resets."""

import functools
import re
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
import pytest

from rigidrot_ros.runtime import realtime
from rigidrot_ros.runtime.ahead import AHEAD_MAX
from ros_helpers import node_and_listener, read_node_bag, reset_twice, spin_until

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures('ros_context')]

_spin_until = functools.partial(spin_until, timeout=30.0)
_WORKER = 'rigidrot-lookahead'


def _alive(name):
    return [t for t in threading.enumerate() if t.name == name and t.is_alive()]


def _step(node, clock, ns):
    """One scheduler call at ``clock[0] + ns`` of the node's clock; then the worker's done."""
    clock[0] += ns
    node._on_timer()
    assert node._worker.drain(30.0)


def test_a_stall_is_caught_up_from_one_batch_nothing_missed_nothing_alone(monkeypatch):
    """0.9 s without a call at 1 kHz owes 900 ticks, past what a buffer can hold ahead.

    (With the worker a buffer holds at most two batches of ``AHEAD_MAX`` = 256 ahead; a
    backlog beyond a second would be skipped.)

    Each owed truth tick and gyro sample comes from one catch-up batch (``fill_to``), none
    is evaluated alone (which costs more than a period at 2 kHz: the stall spiral), and
    none is skipped; after the catch-up every stream's next batch is queued, so none
    evaluates its next sample alone either. The scheduler is called by hand on a clock
    the test moves (1 ms a call, then a 0.9 s jump), and the worker's batches are waited
    for after each call: the same calls every run, whatever the machine's load. The
    calls publish themselves (the pacer, which publishes on the real clock, is off).
    """
    monkeypatch.setenv('RIGIDROT_PACER', '0')
    node, ex, lis = node_and_listener(publish_rate=1000.0, **{'imu.enable': True,
                                                              'imu.rate': 1000.0})
    clock = [time.time_ns()]
    node._now_ns = lambda: clock[0]
    try:
        assert node._worker is not None
        for _ in range(400):
            _step(node, clock, 1_000_000)
        imu = node._schedule.sensors[0].ahead
        truth_misses, imu_misses = node._schedule.truth.ahead.misses, imu.misses
        catch_ups = node._schedule.truth.ahead.catch_ups + imu.catch_ups
        published = node._counters.published
        truth = node._schedule.truth
        assert max(truth.ahead.ahead_of(truth.k), imu.ahead_of(imu._last)) <= 2 * AHEAD_MAX < 900
        _step(node, clock, 900_000_000)                 # the process was held 0.9 s
        assert node._counters.published == published + 900
        for _ in range(400):
            _step(node, clock, 1_000_000)
        assert node._counters.published == published + 1300
        assert node._counters.missed == 0 and node._counters.skipped == 0
        assert node._schedule.truth.ahead.catch_ups + imu.catch_ups >= catch_ups + 2
        assert (node._schedule.truth.ahead.misses, imu.misses) == (truth_misses, imu_misses)
        assert node._schedule.truth.ahead.off_reason == '' and imu.off_reason == ''
    finally:
        node.destroy_node()
        lis.destroy_node()


def test_the_worker_serves_resets_and_stops_with_the_node(tmp_path):
    node, ex, lis = node_and_listener(publish_rate=500.0, record=True,
                                      record_path=str(tmp_path), **{'imu.enable': True,
                                                                    'imu.rate': 500.0})
    ex.add_node(lis)
    try:
        worker = node._worker
        assert len(_alive(_WORKER)) == 1
        reset_twice(node, ex)
        assert node._worker is worker and worker.alive      # one worker for every run
        counts = node._runs.recorder.counts
    finally:
        node.destroy_node()
        lis.destroy_node()
    assert not _alive(_WORKER)
    bag = next(tmp_path.iterdir())
    imu, logs, runs, _ = read_node_bag(bag)
    assert len(imu) >= counts['/imu'] >= 200        # everything queued before the close
    assert logs == sorted(logs)                     # written in the order handed over
    assert all(b > a for a, b in zip(imu, imu[1:]))     # no sample twice, none reordered
    assert runs == 3                                # start-up and two resets


def test_diagnostics_name_the_longest_call_by_phase_and_the_gc():
    node, ex, lis = node_and_listener(publish_rate=400.0, **{'imu.enable': True,
                                                             'imu.rate': 400.0})
    got = []
    lis.create_subscription(DiagnosticArray, '/diagnostics', got.append, 10)
    ex.add_node(lis)
    try:
        _spin_until(ex, lambda: len(got) >= 2)
    finally:
        node.destroy_node()
        lis.destroy_node()
    values = {kv.key: kv.value for kv in got[-1].status[0].values}
    assert float(values['call_max_us']) > 0
    phases = re.sub(r' \([^)]*\)', '', values['call_max_phases'])   # without the details
    names = re.findall(r'(?:^|, )([a-z]+) [0-9.]+', phases)
    assert names == ['wake', 'collect', 'publish', 'record', 'batch', 'diag', 'gc'], phases
    times = dict((k, float(x)) for k, x in re.findall(r'([a-z]+) ([0-9.]+)', phases))
    # the phases add up to the call; the collector's passes happened within them
    total = sum(t for k, t in times.items() if k != 'gc')
    assert total == pytest.approx(float(values['call_max_us']), rel=1e-3, abs=1.0)
    assert times['gc'] <= total + 1.0
    assert re.fullmatch(r'\d+/\d+/\d+', values['gc_collections'])
    assert float(values['gc_max_us']) >= 0
    assert values['scheduling'] == realtime.describe()      # this process's policy
    assert re.fullmatch(r'\d+ holds, \d+\.\d ms|open|off', values['worker_gate'])
