"""The node's one scheduler and the sensors' timing models: every sample once, in order.

Correctness only (no timed asserts): the grids and stamps, each stream's samples published
exactly once and in order across a rate change and a reset, the timing models (a seeded
drop pattern, latency at least the set value, jitter statistics, a clock offset in the
stamps), the run description and the per-sensor diagnostics keys.
"""

import json

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu
from std_msgs.msg import String
from std_srvs.srv import Trigger

from rigidrot_ros.run import grid, params, scheduler
from rigidrot_ros.run.scheduler import timer_period_ns, Timing, Track
from rigidrot_ros.runtime import diagnostics
from ros_helpers import attitude_node, spin_until, stamp_ns

# -- the schedule without ROS ---------------------------------------------------------------


def test_timer_period_is_the_shortest_stream_period_at_most_a_second():
    assert timer_period_ns([100.0, 1000.0, 10.0]) == 1_000_000
    assert timer_period_ns([0.001]) == 1_000_000_000
    assert timer_period_ns([3.0]) == 333_333_333


def test_a_track_hands_out_each_index_once_in_order_and_waits_for_the_latency():
    t = Track('imu', 1_000, 300.0, first=1, timing=Timing(latency=0.0105))
    assert len(t.due(1_000 + grid.stamp_ns(0, 300.0, 1))[0]) == 0      # not yet: latency
    seen = []
    for now in range(0, 200_000_000, 777_777):
        ks, skipped = t.due(1_000 + now)
        assert skipped == 0
        for k in ks:
            assert t.stamp_ns(k) + 10_500_000 <= 1_000 + now             # due: grid + latency
        seen += list(ks)
    assert seen == list(range(1, seen[-1] + 1)) and len(seen) > 50


def test_the_drop_pattern_is_seeded_and_reproducible():
    def pattern(seed):
        t = Track('imu', 0, 100.0, timing=Timing(drop_probability=0.3, seed=seed))
        return np.concatenate([t.marks(range(a, a + 37))[1] for a in range(0, 3700, 37)])
    a, b, c = pattern(7), pattern(7), pattern(8)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    n = len(a)
    dropped = n - a.sum()
    assert abs(dropped - 0.3 * n) < 5 * np.sqrt(n * 0.3 * 0.7)          # binomial, 5 sigma
    # in batches of any size: the same pattern (one draw per sample, in order)
    t = Track('imu', 0, 100.0, timing=Timing(drop_probability=0.3, seed=7))
    odd = np.concatenate([t.marks(range(a, a + 100))[1] for a in range(0, 3700, 100)])
    assert np.array_equal(odd, a)


def test_jitter_statistics_and_the_clock_offset_in_the_stamps():
    sigma, offset = 2e-4, -0.0123
    t = Track('star_tracker', 5_000, 10.0, timing=Timing(stamp_jitter=sigma,
                                                         clock_offset=offset, seed=3))
    ks = range(20_000)
    stamps, keep = t.marks(ks)
    true = np.array([t.stamp_ns(k) for k in ks])
    e = (stamps - true) * 1e-9 - offset
    assert keep.all()
    n = len(e)
    assert abs(e.mean()) < 5 * sigma / np.sqrt(n)
    assert abs(e.std() / sigma - 1) < 5 / np.sqrt(2 * n)
    t = Track('star_tracker', 5_000, 10.0, timing=Timing(clock_offset=offset))
    stamps, _ = t.marks(range(10))
    assert np.array_equal(stamps - [t.stamp_ns(k) for k in range(10)],
                          np.full(10, round(offset * 1e9)))


class _Buffer:
    """A look-ahead stand-in: ``held`` samples buffered after any index, refill wanted."""

    def __init__(self, held, wants=True):
        self.held, self.wants = held, wants

    def needs(self, last):
        return self.wants

    def ahead_of(self, last):
        return self.held


def test_the_next_batch_is_the_buffer_that_runs_out_first_unless_a_late_call_can_wait():
    truth, imu, star = _Buffer(4), _Buffer(3), _Buffer(0, wants=False)
    # seconds ahead: truth 4 / 100 Hz = 40 ms, imu 3 / 1 kHz = 3 ms; star needs nothing
    streams = [(truth, 7, 100.0), (imu, 30, 1000.0), (star, 2, 10.0)]
    assert scheduler.next_batch(streams) == (imu, 30)
    assert scheduler.next_batch(streams, behind=True) == (imu, 30)     # under 4 ms ahead
    imu.held = 5                        # 5 ms ahead, 5 samples: a late call leaves it
    assert scheduler.next_batch(streams, behind=True) is scheduler.DEFERRED
    assert scheduler.next_batch(streams) == (imu, 30)
    tie = [(truth, 7, 100.0), (_Buffer(40), 1, 1000.0)]              # 40 ms each: the first
    assert scheduler.next_batch(tie) == (truth, 7)
    assert scheduler.next_batch([(star, 2, 10.0)]) is None


def test_the_delivered_rate_waits_for_a_long_enough_window_and_restarts_on_a_rate_change():
    rate, w = diagnostics.delivered(None, 10.0, 0, 100.0)
    assert rate is None and w == (10.0, 0, 100.0)
    rate, w2 = diagnostics.delivered(w, 10.2, 20, 100.0)          # 0.2 s: keep accumulating
    assert rate is None and w2 == w
    rate, w3 = diagnostics.delivered(w2, 11.0, 98, 100.0)
    assert rate == pytest.approx(98.0) and w3 == (11.0, 98, 100.0)
    rate, w4 = diagnostics.delivered(w3, 12.0, 150, 50.0)         # a new rate: a new window
    assert rate is None and w4 == (12.0, 150, 50.0)


def test_the_timing_parameters_are_in_the_table_off_by_default():
    for sensor in ('imu', 'star_tracker'):
        for key in ('latency', 'stamp_jitter', 'drop_probability', 'clock_offset'):
            assert params.BY_NAME[f'{sensor}.{key}'].default == 0.0
    with pytest.raises(ValueError, match='imu.drop_probability'):
        params.check('imu.drop_probability', 1.5)
    with pytest.raises(ValueError, match='star_tracker.latency'):
        params.check('star_tracker.latency', -0.1)


# -- the node ---------------------------------------------------------------------------------


class _Listener:
    def __init__(self, ex):
        self.node = rclpy.create_node('sched_listener')
        self.got = {'attitude': [], 'imu': [], 'star_tracker': [], '/diagnostics': [],
                    '/attitude_node/run': []}
        self.arrived = {k: [] for k in self.got}
        types = {'attitude': QuaternionStamped, 'imu': Imu,
                 'star_tracker': PoseWithCovarianceStamped, '/diagnostics': DiagnosticArray,
                 '/attitude_node/run': String}
        for name, cls in types.items():
            self.node.create_subscription(cls, name, self._cb(name), 10000)
        ex.add_node(self.node)

    def _cb(self, name):
        def cb(msg):
            self.got[name].append(msg)
            self.arrived[name].append(self.node.get_clock().now().nanoseconds)
        return cb


@pytest.mark.ros
@pytest.mark.usefixtures('ros_context')
def test_timing_models_in_the_node_drop_pattern_latency_offset_and_run_description():
    latency, offset = 0.03, 0.0071
    node = attitude_node(**{
        'publish_rate': 100.0, 'imu.enable': True, 'imu.rate': 200.0,
        'imu.drop_probability': 0.25, 'imu.seed': 4,
        'star_tracker.enable': True, 'star_tracker.rate': 20.0,
        'star_tracker.latency': latency, 'star_tracker.clock_offset': offset})
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    lis = _Listener(ex)
    got = lis.got
    spin_until(ex, lambda: len(got['imu']) >= 150 and len(got['star_tracker']) >= 12 and
               len(got['/diagnostics']) >= 2 and got['/attitude_node/run'])
    t0 = node._schedule.t_start_ns
    # the imu: exactly the samples the seeded pattern keeps, once each, in order
    ks = [round((stamp_ns(m) - t0) * 200.0 / 1e9) for m in got['imu']]
    assert [grid.stamp_ns(t0, 200.0, k) for k in ks] == [stamp_ns(m) for m in got['imu']]
    ref = Track('imu', t0, 200.0, first=1, timing=Timing(drop_probability=0.25, seed=4))
    keep = ref.marks(range(1, ks[-1] + 1))[1]
    assert ks == [k for k, kp in zip(range(1, ks[-1] + 1), keep) if kp]
    assert len(ks) < ks[-1]                                   # some were dropped
    # the star tracker: stamps = grid + offset; arrival at least the latency after the grid
    st = [stamp_ns(m) for m in got['star_tracker']]
    off = round(offset * 1e9)
    kst = [round((s - off - t0) * 20.0 / 1e9) for s in st]
    assert kst == list(range(len(st)))
    assert st == [grid.stamp_ns(t0, 20.0, k) + off for k in kst]
    late = np.array(lis.arrived['star_tracker'][:len(st)]) - (np.array(st) - off)
    assert np.all(late >= latency * 1e9)
    # the truth: every tick once, in order
    att = [stamp_ns(m) for m in got['attitude']]
    assert att == [grid.stamp_ns(t0, 100.0, k) for k in range(len(att))]
    # diagnostics keys, and the run description
    values = {kv.key: kv.value for kv in got['/diagnostics'][-1].status[0].values}
    for name in ('imu', 'star_tracker'):
        for key in ('latency_mean_us', 'latency_p99_us', 'latency_max_us', 'dropped'):
            assert f'{name}_{key}' in values
    assert float(values['star_tracker_latency_mean_us']) >= latency * 1e6
    run = json.loads(got['/attitude_node/run'][-1].data)
    assert run['sensor_timing']['star_tracker']['latency_s'] == latency
    assert run['sensor_timing']['star_tracker']['clock_offset_s'] == offset
    assert run['sensor_timing']['imu']['drop_probability'] == 0.25
    node.destroy_node()


@pytest.mark.ros
@pytest.mark.usefixtures('ros_context')
def test_every_stream_once_and_in_order_across_a_rate_change_and_a_reset():
    node = attitude_node(**{'publish_rate': 100.0, 'imu.enable': True, 'imu.rate': 150.0,
                            'star_tracker.enable': True, 'star_tracker.rate': 30.0})
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    lis = _Listener(ex)
    got = lis.got
    spin_until(ex, lambda: len(got['imu']) >= 60)
    t0 = node._schedule.t_start_ns
    node.set_parameters([Parameter('publish_rate', value=40.0)])
    n_imu = len(got['imu'])
    spin_until(ex, lambda: len(got['imu']) >= n_imu + 60)
    cli = lis.node.create_client(Trigger, '/attitude_node/reset')
    fut = cli.call_async(Trigger.Request())
    spin_until(ex, lambda: fut.done())
    assert fut.result().success
    spin_until(ex, lambda: node._schedule.t_start_ns not in (None, t0))
    t1 = node._schedule.t_start_ns
    spin_until(ex, lambda: sum(stamp_ns(m) >= t1 for m in got['imu']) >= 60)
    for name, rate, first in (('imu', 150.0, 1), ('star_tracker', 30.0, 0)):
        stamps = [stamp_ns(m) for m in got[name]]
        before = [s for s in stamps if s < t1]
        after = stamps[len(before):]
        assert before == [grid.stamp_ns(t0, rate, k) for k in range(first, first + len(before))]
        assert after == [grid.stamp_ns(t1, rate, k) for k in range(first, first + len(after))]
    att = [stamp_ns(m) for m in got['attitude']]
    assert att == sorted(set(att))                       # once each, in order
    node.destroy_node()


@pytest.mark.ros
@pytest.mark.usefixtures('ros_context')
def test_samples_after_a_skip_are_the_generated_ones():
    """A stall past a second's backlog skips the sensor's samples it owes; those after it
    carry the stamps (jitter, drops) and values (noise) offline generation gives."""
    import time

    from rclpy.serialization import deserialize_message

    from rigidrot_ros.run.generate import iter_serialized
    from ros_helpers import NODE_SCENE
    imu = {'imu.enable': True, 'imu.rate': 200.0, 'imu.seed': 7, 'imu.stamp_jitter': 1e-4,
           'imu.drop_probability': 0.1, 'imu.gyro_noise_density': 1e-3}
    node = attitude_node(**imu)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    lis = _Listener(ex)
    got = lis.got['imu']
    spin_until(ex, lambda: len(got) >= 60)
    time.sleep(1.6)                     # the node is held: more than a second owed
    n = len(got)
    spin_until(ex, lambda: len(got) >= n + 60)
    assert node._counters.skipped > 0
    t0 = node._schedule.t_start_ns
    values = dict(NODE_SCENE, publish_rate=100.0, **imu)
    duration = (stamp_ns(got[-1]) - t0) * 1e-9 + 0.5
    gen = {}
    for _, _, data in iter_serialized(values, duration, ('imu',), start_ns=t0):
        m = deserialize_message(data, Imu)
        gen[stamp_ns(m)] = m
    assert all(stamp_ns(m) in gen for m in got), 'a stamp generation does not give'
    for m in got:
        g = gen[stamp_ns(m)]
        assert (m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z) == \
            (g.angular_velocity.x, g.angular_velocity.y, g.angular_velocity.z)
    node.destroy_node()
