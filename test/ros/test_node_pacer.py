"""The node's pacer at >= 1 kHz: on, the same stream, never early, counted as published.

The bytes themselves are checked against the generator in test/run/test_generate.py: a
node process recording at 2 kHz, stopped with Ctrl-C, byte for byte. The resets of
test/ros/test_record_worker.py run paced too (1 kHz).
"""

from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import Imu

from rigidrot_ros.runtime import pacer as pacer_mod
from ros_helpers import node_and_listener, spin_until, stamp_ns

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures('ros_context'),
              pytest.mark.skipif(not pacer_mod.pacer_available()[0],
                                 reason='no native pacer here')]


def _bag(path):
    """Return {topic: (stamps ns, log times ns)} of a node's bag, read with rosbags."""
    out = {}
    with AnyReader([Path(path)]) as reader:
        for conn, log_ns, raw in reader.messages():
            if conn.topic.endswith('/run'):
                continue
            msg = reader.deserialize(raw, conn.msgtype)
            stamps, logs = out.setdefault(conn.topic, ([], []))
            stamps.append(stamp_ns(msg))
            logs.append(log_ns)
    return {t: (np.array(s), np.array(g)) for t, (s, g) in out.items()}


@pytest.mark.parametrize('rate,latency', [(1000.0, 0.0), (4000.0, 0.0), (2000.0, 0.0013)])
def test_a_paced_node_publishes_every_sample_once_in_order_never_before_it_is_due(
        tmp_path, rate, latency):
    """Due: a truth tick at its stamp, a gyro sample at its stamp plus its latency."""
    node, ex, lis = node_and_listener(publish_rate=rate, record=True,
                                      record_path=str(tmp_path),
                                      **{'imu.enable': True, 'imu.rate': rate,
                                         'imu.latency': latency})
    try:
        got = []
        lis.create_subscription(Imu, '/imu', lambda m: got.append(stamp_ns(m)), 1000)
        ex.add_node(lis)
        spin_until(ex, lambda: node._counters.published >= rate, timeout=60)
        assert node._pace_state() == 'on (lead 20 ms)'
        assert node._paced is not None and node._paced.pacer.alive
        writer = node._runs.recorder._writer
    finally:
        node.destroy_node()
        lis.destroy_node()
    published = node._counters.published
    bag = _bag(writer.path)
    period = round(1e9 / rate)
    for topic in ('/attitude', '/angular_velocity', '/imu'):
        stamps, logs = bag[topic]
        assert np.all(np.abs(np.diff(stamps) - period) <= 1), topic  # every one, in order
        due = stamps + (round(latency * 1e9) if topic == '/imu' else 0)
        assert np.all(logs >= due), topic                      # never before its time
    # what the node counts as published is what rcl took and the bag holds
    assert len(bag['/attitude'][0]) == published
    assert got and set(got) <= set(bag['/imu'][0].tolist())   # a subscriber's copy
    assert not node._paced.pacer.alive                         # stopped with the node


@pytest.mark.parametrize('rate,switch,state', [
    (500.0, None, 'off (below 1 kHz)'), (2000.0, '0', 'off (RIGIDROT_PACER=0)')])
def test_below_1_khz_and_with_the_switch_off_the_node_publishes_itself(
        monkeypatch, rate, switch, state):
    if switch is not None:
        monkeypatch.setenv('RIGIDROT_PACER', switch)
    node, ex, lis = node_and_listener(publish_rate=rate)
    try:
        spin_until(ex, lambda: node._counters.published >= rate / 10)
        assert node._paced is None and node._pace_state() == state
    finally:
        node.destroy_node()
        lis.destroy_node()


def test_a_reset_drops_the_old_runs_queue_and_the_new_run_starts_clean(tmp_path):
    from std_srvs.srv import Trigger
    node, ex, lis = node_and_listener(publish_rate=2000.0, record=True,
                                      record_path=str(tmp_path))
    try:
        spin_until(ex, lambda: node._counters.published >= 500, timeout=60)
        assert len(node._paced) > 0                         # calls queued ahead
        first = node._schedule.t_start_ns
        resp = node._on_reset(Trigger.Request(), Trigger.Response())
        assert resp.success and len(node._paced) == 0
        spin_until(ex, lambda: node._schedule.t_start_ns is not None
                   and node._counters.published >= 1000, timeout=60)
        second = node._schedule.t_start_ns
        writer = node._runs.recorder._writer
    finally:
        node.destroy_node()
        lis.destroy_node()
    stamps, logs = _bag(writer.path)['/attitude']
    old = stamps[stamps < second]
    assert old.size and old.min() == first
    assert np.all(np.diff(stamps[stamps >= second]) == 500_000)
    # nothing of the old run went out after the new run's first message
    assert logs[stamps < second].max() <= logs[stamps >= second].min()
    assert len(stamps) == node._counters.published


def test_a_rate_change_starts_its_grid_after_the_last_queued_tick(tmp_path):
    """The new grid's first tick comes after every tick already queued on the old one."""
    from rclpy.parameter import Parameter
    node, ex, lis = node_and_listener(publish_rate=2000.0, record=True,
                                      record_path=str(tmp_path),
                                      **{'imu.enable': True, 'imu.rate': 2000.0})
    try:
        spin_until(ex, lambda: node._counters.published >= 400, timeout=60)
        for rate in (1000.0, 4000.0):
            assert len(node._paced) > 0
            assert node.set_parameters([Parameter('publish_rate', value=rate)])[0].successful
            published = node._counters.published
            spin_until(ex, lambda: node._counters.published >= published + 400, timeout=60)
        writer = node._runs.recorder._writer
    finally:
        node.destroy_node()
        lis.destroy_node()
    bag = _bag(writer.path)
    stamps, logs = bag['/attitude']
    steps = np.unique(np.diff(stamps))
    assert np.all(steps > 0), steps                      # strictly later, across changes
    assert {500_000, 1_000_000, 250_000} <= set(steps.tolist()), steps
    imu, imu_logs = bag['/imu']
    assert np.all(np.diff(imu) == 500_000)               # the gyro's grid runs on
    assert np.all(np.diff(logs) >= 0) and np.all(logs >= stamps)
