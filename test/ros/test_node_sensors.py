"""The node's sensors and further truth outputs: types, frames, stamps, values, parameters."""

import json
import math
import signal
import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import (
    PoseWithCovarianceStamped, QuaternionStamped, TransformStamped, Vector3Stamped,
)
from nav_msgs.msg import Odometry
import numpy as np
from numpy.testing import assert_allclose, assert_array_equal
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu
from visualization_msgs.msg import Marker, MarkerArray

from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.ros.attitude_node import SceneError
from rigidrot_ros.sensors import ARCSEC, rotvec_from_quaternion
from ros_helpers import (
    attitude_node, next_domain_id, NODE_SCENE, ros_env, script, spin_until, stamp_ns, start, stop,
)

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures('ros_context')]

TOPICS = {'attitude': QuaternionStamped, 'angular_velocity': Vector3Stamped,
          'transform': TransformStamped, 'odom': Odometry, 'markers': MarkerArray,
          'imu': Imu, 'delta_angle': Vector3Stamped, 'delta_rotation': Vector3Stamped,
          'star_tracker': PoseWithCovarianceStamped, '/diagnostics': DiagnosticArray}


def _node(**params):
    return attitude_node(**{'time_scale': 2.0, **params})


def _all_on(**params):
    values = {'imu.enable': True, 'star_tracker.enable': True, 'odom.enable': True,
              'transform.enable': True, 'markers.enable': True, 'imu.rate': 50.0,
              'star_tracker.rate': 10.0, 'imu.gyro_noise_density': 0.0,
              'imu.gyro_random_walk': 0.0, 'imu.gyro_bias': [0.01, -0.02, 0.03],
              'star_tracker.boresight': [1.0, 0.0, 1.0]}
    values.update(params)
    return _node(**values)


class Listener:
    """Collect every topic of :data:`TOPICS`."""

    def __init__(self, executor, topics=TOPICS):
        self.node = rclpy.create_node('listener')
        self.got = {name: [] for name in topics}
        for name, cls in topics.items():
            self.node.create_subscription(cls, name, self.got[name].append, 1000)
        executor.add_node(self.node)


def _q(m):
    return np.array([m.x, m.y, m.z, m.w])


def _v(m):
    return np.array([m.x, m.y, m.z])


def test_every_output_arrives_typed_framed_stamped_and_equal_to_the_core():
    node = _all_on()
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    lis = Listener(ex)
    got = lis.got
    spin_until(ex, lambda: len(got['imu']) >= 40 and len(got['star_tracker']) >= 8
               and len(got['attitude']) >= 40 and len(got['/diagnostics']) >= 2)
    sol = node.solution
    t0 = node._schedule.t_start_ns
    scale = 2.0

    # the truth: one stamp per tick on every truth topic, values of the core at that t
    by_stamp = {name: {stamp_ns(m): m for m in got[name]}
                for name in ('attitude', 'angular_velocity', 'transform', 'odom')}
    markers = {stamp_ns(m.markers[0]): m for m in got['markers']}
    stamps = sorted(by_stamp['attitude'])[:-2]           # the last may still be in flight
    for st in stamps:
        for name in ('angular_velocity', 'transform', 'odom'):
            assert st in by_stamp[name], (name, st)
        assert st in markers
        ref = sol.at((st - t0) * 1e-9 * scale)
        att, tf, od = by_stamp['attitude'][st], by_stamp['transform'][st], by_stamp['odom'][st]
        assert quat.angle_between(_q(att.quaternion), ref.quaternion) <= 1e-12
        assert_array_equal(_q(tf.transform.rotation), _q(att.quaternion))
        assert_array_equal(_v(tf.transform.translation), [0.0, 0.0, 0.0])
        assert (tf.header.frame_id, tf.child_frame_id) == ('inertial', 'body')
        assert (od.header.frame_id, od.child_frame_id) == ('inertial', 'body')
        assert_array_equal(_q(od.pose.pose.orientation), _q(att.quaternion))
        assert_allclose(_v(od.twist.twist.angular), ref.omega, rtol=0, atol=1e-14)
        assert_array_equal(_v(od.pose.pose.position), [0.0, 0.0, 0.0])
        pc = np.reshape(od.pose.covariance, (6, 6))
        assert_array_equal(np.diag(pc)[:3], [-1.0, -1.0, -1.0])     # position: unused
        # the attitude's own error bound squared (rad^2): positive, below tol^2
        assert np.all(np.diag(pc)[3:] > 0) and np.all(np.diag(pc)[3:] <= 1e-24)
        tc = np.reshape(od.twist.covariance, (6, 6))
        assert_array_equal(np.diag(tc)[:3], [-1.0, -1.0, -1.0])
        mk = markers[st].markers
        assert [m.type for m in mk] == [Marker.CUBE, Marker.ARROW, Marker.ARROW, Marker.ARROW]
        assert all(m.header.frame_id == 'inertial' for m in mk)
        assert_array_equal(_q(mk[0].pose.orientation), _q(att.quaternion))
        size = np.array([mk[0].scale.x, mk[0].scale.y, mk[0].scale.z])
        assert_allclose(size * np.sqrt(NODE_SCENE['inertia']), size[0] * math.sqrt(2.0))
        for k, arrow in enumerate(mk[1:]):      # each arrow's x axis is body axis k in N
            axis_n = quat.to_matrix(_q(arrow.pose.orientation))[:, 0]
            assert_allclose(axis_n, quat.to_matrix(ref.quaternion)[:, k], atol=1e-12)

    # the gyro: a fixed 50 Hz grid from t_start, three topics per sample sharing its stamp
    imu = got['imu']
    da = {stamp_ns(m): m for m in got['delta_angle']}
    dr = {stamp_ns(m): m for m in got['delta_rotation']}
    ks = [(stamp_ns(m) - t0) * 50 / 1e9 for m in imu]
    assert_allclose(ks, np.arange(1, len(imu) + 1), rtol=0, atol=1e-6)   # k = 1, 2, ...
    for m in imu[:-2]:
        st = stamp_ns(m)
        assert m.header.frame_id == 'body'
        assert da[st].header.frame_id == 'body' and dr[st].header.frame_id == 'body'
        t1 = (st - t0) * 1e-9 * scale
        t_prev = (t0 + round((round((st - t0) * 50 / 1e9) - 1) * 1e9 / 50) - t0) * 1e-9 * scale
        dt = t1 - t_prev
        # delta_angle against a fine trapezoid of the core's rate (independent of the rule)
        ts = np.linspace(t_prev, t1, 4001)
        w = sol.omega_at(ts)
        trap = np.sum(0.5 * (w[1:] + w[:-1]) * np.diff(ts)[:, None], axis=0)
        assert_allclose(_v(da[st].vector), trap, rtol=0, atol=1e-10)
        # delta_rotation: the exact incremental rotation of the core's attitudes
        rel = quat.multiply(quat.conjugate(sol.at(t_prev).quaternion), sol.at(t1).quaternion)
        assert np.linalg.norm(_v(dr[st].vector) - rotvec_from_quaternion(rel)) <= 1e-12
        # an ideal gyro with a bias: the average rate plus exactly that bias
        assert_allclose(_v(m.angular_velocity), _v(da[st].vector) / dt + [0.01, -0.02, 0.03],
                        rtol=1e-13, atol=1e-16)
        # covariance fields as stated in the README
        assert m.orientation_covariance[0] == -1.0
        assert m.linear_acceleration_covariance[0] == -1.0
        assert_array_equal(_v(m.linear_acceleration), [0.0, 0.0, 0.0])
        c = np.reshape(m.angular_velocity_covariance, (3, 3))
        assert np.all(c == np.diag(np.diag(c))) and c[0, 0] == c[1, 1] == c[2, 2]
        assert 0.0 < c[0, 0] < 1e-20          # no noise: only the exact rate's own bound

    # the star tracker: 10 Hz grid from t = 0, error within its stated covariance
    star = got['star_tracker']
    assert_allclose([(stamp_ns(m) - t0) * 10 / 1e9 for m in star], np.arange(len(star)), atol=1e-6)
    b = np.array([1.0, 0.0, 1.0]) / math.sqrt(2.0)
    p_b = (5 * ARCSEC) ** 2 * (np.eye(3) - np.outer(b, b)) + (35 * ARCSEC) ** 2 * np.outer(b, b)
    for m in star:
        assert m.header.frame_id == 'inertial'
        cov = np.reshape(m.pose.covariance, (6, 6))
        assert_array_equal(np.diag(cov)[:3], [-1.0, -1.0, -1.0])
        assert_allclose(cov[3:, 3:], p_b, rtol=1e-6, atol=1e-20)
        ref = sol.at((stamp_ns(m) - t0) * 1e-9 * scale).quaternion
        e = rotvec_from_quaternion(quat.multiply(quat.conjugate(ref),
                                                 _q(m.pose.pose.orientation)))
        assert e @ np.linalg.solve(p_b, e) < 30.0        # chi2(3) > 30: p < 2e-6

    values = {kv.key: kv.value for kv in got['/diagnostics'][-1].status[0].values}
    for key in ('tick_mean_us', 'tick_p99_us', 'tick_max_us', 'eval_mean_us'):
        assert float(values[key]) > 0
    assert float(values['tick_max_us']) >= float(values['tick_p99_us']) > 0
    assert int(values['imu_samples']) > 0 and int(values['star_tracker_samples']) > 0
    assert float(values['increment_error_bound_rad']) <= 1e-12
    node.destroy_node()


def _imu_stream(seed, count=25):
    node = _node(**{'imu.enable': True, 'imu.rate': 100.0, 'imu.seed': seed,
                    'imu.gyro_noise_density': 1e-3, 'imu.gyro_random_walk': 1e-4,
                    'imu.gyro_bias': [0.001, 0.0, -0.002]})
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    lis = Listener(ex, {'imu': Imu})
    spin_until(ex, lambda: len(lis.got['imu']) >= count)
    t0 = node._schedule.t_start_ns
    out = [(stamp_ns(m) - t0, tuple(_v(m.angular_velocity))) for m in lis.got['imu'][:count]]
    node.destroy_node()
    lis.node.destroy_node()
    return out


def test_same_seed_gives_a_bit_identical_imu_stream():
    a, b, c = _imu_stream(42), _imu_stream(42), _imu_stream(43)
    assert a == b                                   # stamps from t_start and values
    assert [x[0] for x in c] == [x[0] for x in a]
    assert all(x[1] != y[1] for x, y in zip(a, c))


@pytest.mark.parametrize('name, value, words', [
    ('imu.gyro_noise_density', math.nan, 'imu.gyro_noise_density'),
    ('imu.gyro_noise_density', -1e-3, 'imu.gyro_noise_density'),
    ('imu.gyro_random_walk', 1e300, 'imu.gyro_random_walk'),
    ('imu.gyro_bias', [0.0, math.nan, 0.0], 'imu.gyro_bias[1] must be finite'),
    ('imu.gyro_bias', [1e300, 0.0, 0.0], 'imu.gyro_bias[0] must be finite'),
    ('imu.gyro_bias', 'none', 'imu.gyro_bias must be a list of 3'),
    ('imu.seed', -1, 'imu.seed'),
    ('imu.seed', 'abc', 'imu.seed must be an integer'),
    ('imu.rate', 1e9, 'imu.rate'),
    ('imu.rate', 'fast', 'imu.rate must be 0'),
    ('star_tracker.boresight', [0.0, 0.0, 0.0], 'boresight must be a nonzero axis'),
    ('star_tracker.cross_boresight_arcsec', math.inf, 'cross_boresight_arcsec'),
    ('star_tracker.rate', -1.0, 'star_tracker.rate'),
    ('star_tracker.seed', 2.5, 'star_tracker.seed must be an integer'),
    ('imu.enable', False, 'read-only'),
    ('time_scale', 0.0, 'time_scale = 0 freezes the scene'),
])
def test_bad_sensor_parameters_are_refused_and_state_kept(name, value, words):
    node = _all_on()
    names = [n for n in node._parameters if n.startswith(('imu.', 'star_tracker.'))]
    before = {n: node.get_parameter(n).value for n in names}
    setup = node._setup
    result = node.set_parameters([Parameter(name, value=value)])[0]
    assert not result.successful
    assert words in result.reason, result.reason
    after = {n: node.get_parameter(n).value for n in names}
    assert {k: list(v) if hasattr(v, '__len__') and not isinstance(v, str) else v
            for k, v in after.items()} == \
        {k: list(v) if hasattr(v, '__len__') and not isinstance(v, str) else v
         for k, v in before.items()}
    assert node._setup is setup
    node.destroy_node()


def test_bad_sensor_parameter_at_start_up_raises_scene_error():
    with pytest.raises(SceneError, match=r'imu.gyro_bias\[1\] must be finite'):
        _node(**{'imu.gyro_bias': [0.0, math.nan, 0.0]})
    with pytest.raises(SceneError, match='imu.enable must be true or false'):
        _node(**{'imu.enable': 1})


def test_reset_restarts_the_sensors_with_new_values():
    node = _node(**{'imu.enable': True, 'imu.gyro_noise_density': 0.0,
                    'imu.gyro_random_walk': 0.0, 'imu.rate': 100.0})
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    lis = Listener(ex, {'imu': Imu, 'delta_angle': Vector3Stamped})
    spin_until(ex, lambda: len(lis.got['imu']) >= 5)
    assert node.set_parameters([Parameter('imu.gyro_bias', value=[0.5, 0.0, 0.0])])[0] \
        .successful
    response = node._on_reset(None, type('R', (), {})())
    assert response.success, response.message
    start = node._schedule.t_start_ns
    n0 = len(lis.got['imu'])
    spin_until(ex, lambda: len(lis.got['imu']) >= n0 + 5 and node._schedule.t_start_ns is not None)
    new = [m for m in lis.got['imu'][n0:] if stamp_ns(m) > node._schedule.t_start_ns]
    assert start is None and new
    da = {stamp_ns(m): _v(m.vector) for m in lis.got['delta_angle']}
    first = new[0]
    assert stamp_ns(first) - node._schedule.t_start_ns == 10_000_000          # k = 1 at 100 Hz
    dt = 0.01 * 2.0
    assert_allclose(_v(first.angular_velocity), da[stamp_ns(first)] / dt + [0.5, 0.0, 0.0],
                    rtol=1e-13)
    node.destroy_node()


def test_unknown_override_is_named_not_dropped_in_silence():
    node = _node(**{'imu.enabel': True, 'publish_rat': 5.0})
    assert node.unknown_overrides == ['imu.enabel', 'publish_rat']
    node.destroy_node()
    node = _node(use_sim_time=False, start_type_description_service=False)   # rclpy's own
    assert node.unknown_overrides == []
    node.destroy_node()
    env = ros_env(next_domain_id())
    proc = start([script('attitude_node'), '--ros-args', '-p', 'imu.enabel:=true'], env)
    try:
        proc.wait(timeout=4.0)
    except Exception:       # still running, as it should
        pass
    code, out, err = stop(proc, signal.SIGINT)
    assert code == 0, err
    assert "unknown parameter 'imu.enabel'" in err and 'did you mean imu.enable' in err


def test_a_clock_jump_restarts_the_sensor_grid_and_is_counted():
    """5 s of backlog at 100 Hz: the sensor jumps to the newest sample, 499 counted, and
    read (not published) so that its noise runs on as offline generation's."""
    from rigidrot_ros.run import params, settings
    from rigidrot_ros.run.sensor_ahead import Sensor
    from rigidrot_ros.runtime.diagnostics import Counters
    from run_helpers import sensors
    values = params.defaults()
    values.update(NODE_SCENE, **{'imu.enable': True, 'imu.rate': 100.0, 'time_scale': 2.0})
    setup = settings.prepare_run(values)
    counters, failed, groups = Counters(), [], []
    t0 = 1_000_000_000
    sensor = Sensor(sensors(setup)[0], t0, setup, counters, lambda: ('inertial', 'body'))
    assert sensor.track.last == 0
    sensor.due(t0 + 5_000_000_000, groups, lambda t, exc: failed.append(exc))
    assert not failed and counters.skipped == 499 and counters.samples == {'imu': 500}
    assert sensor.track.last == 500 and len(groups) == 1
    true_ns, _, items = groups[0]
    assert true_ns == t0 + 5_000_000_000
    assert [topic for topic, _ in items] == ['imu', 'delta_angle', 'delta_rotation']
    sensor.due(t0 + 5_029_999_999, groups, failed.append)
    assert sensor.track.last == 502 and counters.samples == {'imu': 502} and len(groups) == 3
    sensor.due(0, groups, failed.append)                        # clock before t_start
    assert sensor.track.last == 502 and counters.skipped == 499 and len(groups) == 3


IMU_SUBSCRIBER = '''
import json, sys, time
import rclpy
from sensor_msgs.msg import Imu
from geometry_msgs.msg import Vector3Stamped
rclpy.init()
node = rclpy.create_node('estimator')
got = {'imu': [], 'delta_angle': []}
node.create_subscription(Imu, '/sat/imu', lambda m: got['imu'].append(
    [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, m.header.frame_id,
     m.angular_velocity_covariance[0], m.orientation_covariance[0]]), 100)
node.create_subscription(Vector3Stamped, '/sat/delta_angle', lambda m: got['delta_angle'].append(
    m.header.stamp.sec * 10**9 + m.header.stamp.nanosec), 100)
end = time.monotonic() + 30
while time.monotonic() < end and len(got['imu']) < 60:
    rclpy.spin_once(node, timeout_sec=0.05)
print(json.dumps(got))
'''


def test_imu_from_a_nested_params_file_reaches_another_process(tmp_path):
    params = tmp_path / 'params.yaml'
    params.write_text(
        '/sat/attitude_node:\n  ros__parameters:\n    publish_rate: 20.0\n'
        '    imu:\n      enable: true\n      rate: 50.0\n      gyro_noise_density: 1.0e-3\n'
        '      gyro_random_walk: 0.0\n      seed: 3\n')
    env = ros_env(next_domain_id())
    node = start([script('attitude_node'), '--ros-args', '--params-file', str(params),
                  '-r', '__ns:=/sat'], env)
    try:
        sub = start([sys.executable, '-c', IMU_SUBSCRIBER], env)
        out, err = sub.communicate(timeout=60)
        assert sub.returncode == 0, err
    finally:
        code, _, node_err = stop(node, signal.SIGINT)
    assert code == 0 and 'Traceback' not in node_err, node_err
    got = json.loads(out)
    imu = got['imu']
    assert len(imu) >= 60
    stamps = np.array([m[0] for m in imu])
    assert np.all(np.diff(stamps) == 20_000_000)         # the 50 Hz grid, no gap, no jitter
    assert set(got['delta_angle']) >= set(stamps[:-5].tolist())
    assert all(m[1] == 'body' and m[3] == -1.0 for m in imu)
    assert all(m[2] == pytest.approx(1e-6 / 0.02, rel=1e-9) for m in imu)   # sigma_v^2 / dt
    assert 'unknown parameter' not in node_err


#: The default scene (axial torque): a gyro interval of 2000 s costs it ~2 s of quadrature.
AXIAL = {'inertia': [2.0, 2.0, 1.0], 'torque': [0.0, 0.0, 0.05], 'torque_frame': 'body'}


def test_a_gyro_interval_too_long_to_integrate_is_refused():
    """A huge time_scale or a tiny imu.rate: refused with a reason, quickly, state kept."""
    import time
    node = _node(**{'imu.enable': True, 'imu.rate': 100.0, **AXIAL})
    try:
        c0 = time.perf_counter()
        result = node.set_parameters([Parameter('time_scale', value=1e9)])[0]
        assert time.perf_counter() - c0 < 1.0
        assert not result.successful
        assert 'time_scale' in result.reason and 'first gyro sample' in result.reason, \
            result.reason
        assert node.get_parameter('time_scale').value == 2.0
        c0 = time.perf_counter()
        result = node.set_parameters([Parameter('imu.rate', value=0.001)])[0]   # 2000 s
        assert time.perf_counter() - c0 < 1.0
        assert not result.successful and 'imu.rate' in result.reason, result.reason
    finally:
        node.destroy_node()
    with pytest.raises(SceneError, match='first gyro sample'):
        _node(**{'imu.enable': True, 'time_scale': 1e9})


def test_an_infinite_gyro_bound_is_refused_and_the_bound_is_per_run(monkeypatch):
    """omega0 = [1e300, ...] gives an infinite increment bound: refused with the imu on."""
    import rigidrot_ros.run.settings as mod
    monkeypatch.setattr(mod, 'SAMPLE_BUDGET_S', 10.0)     # let the quadrature end (bound = inf)
    node = _node(**{'imu.enable': True, 'time_scale': 1.0})
    huge = {**AXIAL, 'omega0': [1e300, -0.2, 0.5]}     # the truth itself is sound
    try:
        result = node.set_parameters_atomically(
            [Parameter(k, value=v) for k, v in huge.items()])
        assert not result.successful
        assert 'omega0' in result.reason and 'no finite error bound' in result.reason, \
            result.reason
        # a bound seen in one run is reported (WARN) and forgotten at ~/reset
        node._schedule.streams[0].bound = math.inf
        sent = []
        node._pub_diag.publish = sent.append
        node._publish_diagnostics(wait=True)
        st = sent[0].status[0]
        assert st.level == DiagnosticStatus.WARN and 'gyro increment' in st.message, st.message
        response = node._on_reset(None, type('R', (), {})())
        assert response.success, response.message
        assert node._schedule.streams[0].bound == 0.0
    finally:
        node.destroy_node()
    with pytest.raises(SceneError, match='no finite error bound'):
        _node(**{'imu.enable': True, 'time_scale': 1.0, **huge})
