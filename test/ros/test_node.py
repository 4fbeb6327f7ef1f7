"""The attitude node in-process: values, parameter rules, reset."""

import functools
import math

from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
import numpy as np
from numpy.testing import assert_allclose
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.ros.attitude_node import SceneError
from ros_helpers import attitude_node, NODE_SCENE, spin_until, stamp_ns

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures('ros_context')]


class Listener:
    """A subscriber node collecting both topics."""

    def __init__(self, executor):
        self.node = rclpy.create_node('listener')
        self.att, self.rate = [], []
        self.node.create_subscription(QuaternionStamped, 'attitude', self.att.append, 100)
        self.node.create_subscription(Vector3Stamped, 'angular_velocity', self.rate.append,
                                      100)
        executor.add_node(self.node)


def _node(**params):
    return attitude_node(**{'time_scale': 3.0, **params})


def _listening(**params):
    """Return a node on ``params``, an executor spinning it, and a Listener of its topics."""
    node = _node(**params)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    return node, ex, Listener(ex)


_spin_until = functools.partial(spin_until, timeout=15.0)


def test_published_values_equal_the_core_at_the_stamp_time():
    node, ex, lis = _listening()
    _spin_until(ex, lambda: len(lis.att) >= 30 and len(lis.rate) >= 30)
    sol = solve(Scene(**{k: tuple(v) if isinstance(v, list) else v
                         for k, v in NODE_SCENE.items()}))
    assert node.solution.model == sol.model == 'transverse-virtual'
    t0 = stamp_ns(lis.att[0])                       # the first tick is t = 0
    n = min(len(lis.att), len(lis.rate))
    for a, r in zip(lis.att[:n], lis.rate[:n]):
        assert a.header.stamp == r.header.stamp     # one stamp per tick
        assert a.header.frame_id == 'inertial' and r.header.frame_id == 'body'
        t = (stamp_ns(a) - t0) * 1e-9 * 3.0         # time_scale
        ref = sol.at(t)
        q = np.array([a.quaternion.x, a.quaternion.y, a.quaternion.z, a.quaternion.w])
        assert quat.angle_between(q, ref.quaternion) <= 1e-12
        assert_allclose([r.vector.x, r.vector.y, r.vector.z], ref.omega, rtol=0, atol=1e-14)
    qs = np.array([[m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w]
                   for m in lis.att])
    assert np.all(np.einsum('ij,ij->i', qs[1:], qs[:-1]) > 0)   # continuous, no flips
    node.destroy_node()


@pytest.mark.parametrize('name, value, words', [
    ('inertia', [1.0, math.nan, 1.0], 'inertia[1] must be finite'),
    ('inertia', [1.0, -1.0, 1.0], 'inertia[1] must be positive'),
    ('inertia', [1.0, 1.0, 3.0], 'triangle inequality'),
    ('inertia', 'heavy', 'inertia must be a list'),
    ('inertia', [1.0, 1.0], 'inertia must have 3'),
    ('torque', [0.0, math.inf, 0.0], 'torque[1] must be finite'),
    ('attitude0', [0.0, 0.0, 0.0, 0.0], 'attitude0 must be a nonzero quaternion'),
    ('torque_frame', 'world', 'torque_frame must be one of'),
    ('inertia', [1.0, 2.0, 2.5], 'no exact solution'),
    ('tol', math.nan, 'tol'),
    ('tol', 1e-20, 'tol'),
    ('tol', 0, 'tol must be a number in [2e-14, 1]'),          # an int: rclpy's range skips it
    ('tol', 2, 'tol must be a number in [2e-14, 1]'),
    ('backend', 'numpy', 'backend must be one of'),
    ('publish_rate', -5.0, 'publish_rate'),
    ('time_scale', math.inf, 'time_scale'),
    ('frame_id', '', 'frame_id must be a non-empty string'),
])
def test_invalid_parameter_is_rejected_and_state_kept(name, value, words):
    node = _node()
    before = {n: node.get_parameter(n).value for n in NODE_SCENE}
    sol = node.solution
    result = node.set_parameters([Parameter(name, value=value)])[0]
    assert not result.successful
    assert words in result.reason
    assert {n: node.get_parameter(n).value for n in NODE_SCENE} == before
    assert node.solution is sol
    node.destroy_node()


def test_invalid_scene_at_start_up_raises_scene_error():
    with pytest.raises(SceneError, match='no exact solution'):
        _node(inertia=[1.0, 2.0, 2.5])


def test_reset_applies_an_atomic_scene_change_and_restarts_at_t0():
    node, ex, lis = _listening(time_scale=1.0)
    _spin_until(ex, lambda: len(lis.att) >= 5)
    new = dict(inertia=[3.0, 3.0, 3.0], torque=[0.0, 0.2, 0.1], torque_frame='body',
               omega0=[1.0, 0.5, -0.5], attitude0=[0.0, 0.0, 0.6, 0.8])
    res = node.set_parameters_atomically([Parameter(k, value=v) for k, v in new.items()])
    assert res.successful, res.reason
    assert node.solution.model == 'transverse-virtual'      # not before the reset
    client_node = rclpy.create_node('reset_client')
    ex.add_node(client_node)
    cli = client_node.create_client(Trigger, '/attitude_node/reset')
    assert cli.wait_for_service(timeout_sec=10.0)
    count = len(lis.att)        # before the call: the new run's first tick may come first

    def first_new():            # the new run's first attitude, and its rate
        att = [m for m in lis.att[count:]
               if abs(m.quaternion.z - 0.6) < 1e-12 and abs(m.quaternion.w - 0.8) < 1e-12]
        return [(a, r) for a in att[:1] for r in lis.rate if r.header.stamp == a.header.stamp]
    future = cli.call_async(Trigger.Request())
    _spin_until(ex, future.done)
    assert future.result().success
    assert 'sphere' in future.result().message
    _spin_until(ex, first_new)
    assert first_new(), 'no message at t = 0 of the new scene'
    rate = first_new()[0][1]
    assert_allclose([rate.vector.x, rate.vector.y, rate.vector.z], new['omega0'], atol=1e-15)
    node.destroy_node()
    client_node.destroy_node()


def test_diagnostics_report_model_costs_and_ticks():
    from diagnostic_msgs.msg import DiagnosticArray
    node = _node()
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    sub = rclpy.create_node('diag_listener')
    got = []
    sub.create_subscription(DiagnosticArray, '/diagnostics', got.append, 10)
    ex.add_node(sub)
    _spin_until(ex, lambda: len(got) >= 2, timeout=20)
    values = {kv.key: kv.value for kv in got[-1].status[0].values}
    assert values['model'] == 'transverse-virtual'
    assert values['method'] == 'hypergeometric-flint' and values['backend'] == 'flint'
    assert int(values['ticks_published']) >= 50
    assert float(values['eval_p99_us']) > 0 and float(values['error_bound_rad']) <= 1e-12
    assert float(values['tick_p99_us']) >= float(values['eval_p99_us'])
    assert float(values['latency_p99_us']) >= 0.0
    assert values['lookahead'].endswith('samples a batch'), values['lookahead']
    assert int(values['lookahead_batches']) >= 0 and float(values['lookahead_sample_us']) > 0
    assert got[-1].status[0].level in (b'\x00', 0, b'\x01', 1)     # OK, or WARN if slow
    node.destroy_node()
    sub.destroy_node()


def _now_ns():
    return rclpy.clock.Clock().now().nanoseconds


def _after(messages, t_ns):
    """The messages stamped after ``t_ns``: those published after a change made then.

    A tick is stamped with its grid time and published at or after it, so a message still
    in flight when the change was made carries a stamp no later than the change.
    """
    return [m for m in messages if stamp_ns(m) > t_ns]


def test_publish_rate_change_takes_effect_at_once():
    node, ex, lis = _listening(publish_rate=100.0)
    _spin_until(ex, lambda: len(lis.att) >= 10)
    before = _now_ns()          # ticks published before the change: stamped no later
    assert node.set_parameters([Parameter('publish_rate', value=20.0)])[0].successful
    _spin_until(ex, lambda: len(_after(lis.att, before)) >= 12)
    stamps = [stamp_ns(m) for m in _after(lis.att, before)]
    gaps = np.diff(stamps) * 1e-9
    assert np.median(gaps) == pytest.approx(0.05, abs=0.01)
    node.destroy_node()


def test_stamps_lie_on_the_timer_grid_from_t_start():
    """Tick k is stamped t_start + k / publish_rate exactly; the first tick is t = 0."""
    node, ex, lis = _listening(publish_rate=100.0)
    _spin_until(ex, lambda: len(lis.att) >= 60)
    start = node._schedule.t_start_ns
    stamps = np.array([stamp_ns(m) for m in lis.att])
    assert stamps[0] == start
    offsets = stamps - start
    assert np.all(offsets % 10_000_000 == 0), offsets[offsets % 10_000_000 != 0][:5]
    assert np.all(np.diff(stamps) > 0)
    # most samples came from the look-ahead buffer, built ahead
    ahead = node._schedule.truth.ahead
    assert ahead.size >= 8, ahead.off_reason     # on (AHEAD_MIN or more)
    node.destroy_node()


def test_frame_id_change_applies_at_once_to_messages_built_ahead():
    node, ex, lis = _listening(publish_rate=100.0)
    _spin_until(ex, lambda: len(lis.att) >= 40)     # the buffer holds built messages now
    assert len(node._schedule.truth.ahead) > 0
    before = _now_ns()
    assert node.set_parameters([Parameter('frame_id', value='world'),
                                Parameter('body_frame_id', value='base_link')])[0].successful
    _spin_until(ex, lambda: len(_after(lis.att, before)) >= 3
                and len(_after(lis.rate, before)) >= 3)
    assert {m.header.frame_id for m in _after(lis.att, before)} == {'world'}
    assert {m.header.frame_id for m in _after(lis.rate, before)} == {'base_link'}
    node.destroy_node()


def test_rate_change_anchors_a_new_grid_on_the_same_scene_clock():
    node, ex, lis = _listening(publish_rate=100.0, time_scale=1.0)
    _spin_until(ex, lambda: len(lis.att) >= 10)
    start = node._schedule.t_start_ns
    before = _now_ns()
    assert node.set_parameters([Parameter('publish_rate', value=40.0)])[0].successful
    _spin_until(ex, lambda: len(_after(lis.att, before)) >= 8)
    assert node._schedule.t_start_ns == start        # the scene time runs on
    later = np.array([stamp_ns(m) for m in _after(lis.att, before)])
    assert np.all(np.diff(later) % 25_000_000 == 0) and np.all(np.diff(later) > 0)
    sol = node.solution
    for m in _after(lis.att, before):
        t = (stamp_ns(m) - start) * 1e-9
        q = np.array([m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w])
        assert quat.angle_between(q, sol.at(t).quaternion) <= 2e-12
    node.destroy_node()


def test_sim_time_stamps_are_on_the_grid_of_the_sim_clock():
    """With use_sim_time the timer runs on /clock: stamps on its grid, in sim time."""
    from rosgraph_msgs.msg import Clock
    node, ex, lis = _listening(publish_rate=100.0, time_scale=1.0, use_sim_time=True)
    clock_node = rclpy.create_node('sim_clock')
    pub = clock_node.create_publisher(Clock, '/clock', 10)
    ex.add_node(clock_node)
    sim_ns = 100_000_000_000                        # the simulation starts at 100 s
    end = rclpy.clock.Clock().now().nanoseconds + 20e9
    while len(lis.att) < 25 and rclpy.clock.Clock().now().nanoseconds < end:
        sim_ns += 1_000_000                         # 1 ms of sim time per step
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(sim_ns, 1_000_000_000)
        pub.publish(msg)
        ex.spin_once(timeout_sec=0.005)
    assert len(lis.att) >= 25
    start = node._schedule.t_start_ns
    assert 100e9 <= start <= sim_ns
    stamps = np.array([stamp_ns(m) for m in lis.att])
    assert stamps[0] == start and np.all((stamps - start) % 10_000_000 == 0)
    assert np.all(stamps <= sim_ns)                 # never ahead of the sim clock
    sol = node.solution
    for m in lis.att:
        q = np.array([m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w])
        t = (stamp_ns(m) - start) * 1e-9
        assert quat.angle_between(q, sol.at(t).quaternion) <= 2e-12
    node.destroy_node()
    clock_node.destroy_node()


def test_use_sim_time_switched_on_while_running_moves_the_stamps_to_the_sim_clock():
    """The node reads the system clock directly while no /clock drives it; switching
    use_sim_time on at run time must move every later stamp onto the sim clock."""
    from rosgraph_msgs.msg import Clock
    node, ex, lis = _listening(publish_rate=100.0, time_scale=1.0)
    _spin_until(ex, lambda: len(lis.att) >= 5)
    wall = rclpy.clock.Clock().now().nanoseconds
    assert abs(stamp_ns(lis.att[-1]) - wall) < 5e9             # system time so far
    node.set_parameters([Parameter('use_sim_time', value=True)])
    n_before = len(lis.att)
    clock_node = rclpy.create_node('sim_clock_switch')
    pub = clock_node.create_publisher(Clock, '/clock', 10)
    ex.add_node(clock_node)
    sim_ns = 100_000_000_000
    end = wall + 20e9

    def on_sim():           # stamps after the switch that are in sim time
        return sum(stamp_ns(m) < 1_000_000_000_000 for m in lis.att[n_before:])
    # ticks already due on the system clock may still come first: wait for ten in sim time
    while ((len(lis.att) < n_before + 15 or on_sim() < 10)
           and rclpy.clock.Clock().now().nanoseconds < end):
        sim_ns += 1_000_000
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(sim_ns, 1_000_000_000)
        pub.publish(msg)
        ex.spin_once(timeout_sec=0.005)
    later = np.array([stamp_ns(m) for m in lis.att[n_before:]])
    assert len(later) >= 15
    sim = later[later < 1_000_000_000_000]                      # stamps in sim time
    assert len(sim) >= 10 and np.all(sim >= 100e9) and np.all(sim <= sim_ns)
    assert np.all(later[-5:] < 1_000_000_000_000)               # and they stay there
    node.destroy_node()
    clock_node.destroy_node()
