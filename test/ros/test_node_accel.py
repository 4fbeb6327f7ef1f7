"""The node's accelerometer, magnetometer, IMU error terms and Kalibr import (issue 19 wiring).

Oracles: the former gyro path (``GyroNoise``, today's stream) for the bit-identical default;
scipy's rotations (no code shared with the core's quaternions) for the field and gravity in
B; the sensor models' own error messages for the refusals, seen through the node's start-up
(a real process), its set-parameters callback (``set_parameters_atomically``, the path the
parameter services take) and ``~/reset``.
"""

import math

from geometry_msgs.msg import Vector3Stamped
import numpy as np
from numpy.testing import assert_allclose
import pytest
from rclpy.parameter import Parameter
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Imu, MagneticField

from rigidrot_ros.msgs import messages as msgs
from rigidrot_ros.ros.attitude_node import SceneError
from rigidrot_ros.run import grid, params, settings
from rigidrot_ros.run.imu_output import ImuOutput
from rigidrot_ros.run.mag_output import MagOutput
from rigidrot_ros.run.output import scene_time
from rigidrot_ros.sensors import Gyro, GyroNoise
from ros_helpers import attitude_node, node_and_listener, NODE_SCENE, spin_until, stamp_ns
from run_helpers import per_sample, sensors

FRAMES = ('inertial', 'body')
G = [0.0, 0.0, -9.80665]
AIR = {'imu.enable': True, 'accel.enable': True, 'mag.enable': True, 'accel.gravity': G,
       'accel.lever_arm': [0.1, -0.05, 0.2], 'imu.rate': 50.0, 'mag.rate': 25.0}


def _values(**over):
    v = params.defaults()
    v.update(NODE_SCENE)
    v.update(over)
    return v


def _msgs(stream, ks, scale=1.0):
    return [m for k in ks for m in per_sample(stream, k, 0, scale, FRAMES)]


def test_every_new_term_off_by_default_keeps_todays_imu_stream_bit_identical():
    values = _values(**{'imu.enable': True, 'imu.seed': 11, 'imu.gyro_bias': [1e-3, 0.0, -2e-3],
                        'imu.rate': 50.0, 'time_scale': 2.0})
    setup = settings.prepare_run(values)
    streams = sensors(setup)
    assert [s.name for s in streams] == ['imu']
    assert [t.name for t in streams[0].active] == ['imu', 'delta_angle', 'delta_rotation']
    new = _msgs(streams[0], range(1, 60), 2.0)
    # the former path: Gyro with GyroNoise, messages built as before
    old_gyro = Gyro(setup.solution, GyroNoise(1.7e-4, 2e-5, [1e-3, 0.0, -2e-3], 11))
    old = []
    for k in range(1, 60):
        ns0, ns1 = grid.stamp_ns(0, 50.0, k - 1), grid.stamp_ns(0, 50.0, k)
        r = old_gyro.read(scene_time(ns0, 0, 2.0), scene_time(ns1, 0, 2.0))
        stamp = msgs.stamp(ns1)
        old += [('imu', msgs.imu(stamp, 'body', r.omega, r.variance)),
                ('delta_angle', msgs.vector(stamp, 'body', r.delta_angle)),
                ('delta_rotation', msgs.vector(stamp, 'body', r.delta_rotation))]
    assert [t for t, _ in new] == [t for t, _ in old]
    # field by field (exact float equality): rclpy's serialize_message leaves the CDR
    # alignment padding uninitialised, so its bytes can differ between equal messages
    assert [m for _, m in new] == [m for _, m in old]
    imu = new[0][1]
    assert imu.linear_acceleration_covariance[0] == -1.0          # not provided, as before
    # a gyro term switched on changes the stream (the comparison above can fail)
    on = settings.prepare_run({**values, 'imu.gyro_scale_factor': [1e-3, 0.0, 0.0]})
    assert _msgs(sensors(on)[0], [1])[0][1] != \
        _msgs(sensors(settings.prepare_run(values))[0], [1])[0][1]


def test_accelerometer_rides_in_imu_and_mag_stream_match_hand_rotated_references():
    setup = settings.prepare_run(_values(**AIR))
    imu_s, mag_s = sensors(setup)
    assert isinstance(imu_s, ImuOutput) and isinstance(mag_s, MagOutput)
    assert [t.name for t in imu_s.active][-1] == 'delta_velocity'
    sol, r_arm = setup.solution, np.array(AIR['accel.lever_arm'])
    for k in (1, 7, 40):
        got = dict(per_sample(imu_s, k, 0, 1.0, FRAMES))
        imu, dv = got['imu'], got['delta_velocity']
        assert isinstance(imu, Imu) and isinstance(dv, Vector3Stamped)
        assert imu.header.frame_id == 'body' and dv.header.frame_id == 'body'
        f = np.array([imu.linear_acceleration.x, imu.linear_acceleration.y,
                      imu.linear_acceleration.z])
        dv = np.array([dv.vector.x, dv.vector.y, dv.vector.z])
        dt = 1.0 / 50.0
        assert_allclose(f, dv / dt, rtol=0, atol=1e-12)         # ideal: the exact mean
        # hand reference at the midpoint: -R_BN g + centripetal + tangential (scipy rotation;
        # omega, omega_dot from the core), the mean differs by O(dt^2)
        tm = (k - 0.5) * dt
        rot = Rotation.from_quat(sol.at(tm).quaternion)
        w, wd = sol.omega_at(tm), sol.omega_dot_at(tm)
        ref = -rot.inv().apply(G) + np.cross(wd, r_arm) + np.cross(w, np.cross(w, r_arm))
        assert np.linalg.norm(f - ref) < 1e-3, (f, ref)
        assert abs(np.linalg.norm(f) - 9.80665) < 0.1           # gravity dominates
        cov = np.asarray(imu.linear_acceleration_covariance).reshape(3, 3)
        assert cov[0, 0] > 0 and np.all(cov == np.diag(np.diag(cov)))
    for k in (0, 3, 20):
        (topic, m), = per_sample(mag_s, k, 0, 1.0, FRAMES)
        assert topic == 'mag' and isinstance(m, MagneticField) and m.header.frame_id == 'body'
        assert stamp_ns(m) == round(k * 1e9 / 25.0)
        rot = Rotation.from_quat(sol.at(k / 25.0).quaternion)
        ref = rot.inv().apply([0.0, 2.0e-5, -4.5e-5])
        got = np.array([m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z])
        assert_allclose(got, ref, rtol=0, atol=1e-18)
        assert m.magnetic_field_covariance[0] > 0


def test_noise_terms_reach_the_messages_seeded_and_stated():
    over = dict(AIR, **{'accel.noise_density': 2e-3, 'accel.bias': [0.05, 0.0, 0.0],
                        'mag.noise_density': 1e-8, 'mag.seed': 4, 'imu.seed': 9})
    a = sensors(settings.prepare_run(_values(**over)))
    b = sensors(settings.prepare_run(_values(**over)))
    ideal = sensors(settings.prepare_run(_values(**AIR)))
    for s1, s2, s0 in zip(a, b, ideal):
        ks = range(s1.first, s1.first + 30)
        m1, m2, m0 = _msgs(s1, ks), _msgs(s2, ks), _msgs(s0, ks)
        assert [m for _, m in m1] == [m for _, m in m2]
        assert [m for _, m in m1] != [m for _, m in m0]
    imu1 = [m for t, m in _msgs(a[0], range(1, 200)) if t == 'imu']
    imu0 = [m for t, m in _msgs(ideal[0], range(1, 200)) if t == 'imu']
    err = np.array([[m.linear_acceleration.x - n.linear_acceleration.x,
                     m.linear_acceleration.y - n.linear_acceleration.y,
                     m.linear_acceleration.z - n.linear_acceleration.z]
                    for m, n in zip(imu1, imu0)])
    sd = 2e-3 / math.sqrt(1 / 50.0)
    assert abs(err[:, 0].mean() - 0.05) < 5 * sd / math.sqrt(len(err))      # the bias
    assert 0.8 < err[:, 1].std() / sd < 1.2                                 # the density
    assert imu1[0].linear_acceleration_covariance[0] == pytest.approx(sd ** 2, rel=1e-9)


BAD = [
    ('accel.noise_density', -1e-3, 'parameter accel.noise_density'),
    ('accel.random_walk', math.nan, 'parameter accel.random_walk'),
    ('accel.bias_correlation_time', 0.0, 'parameter accel.bias_correlation_time'),
    ('imu.gyro_bias_correlation_time', -5.0, 'parameter imu.gyro_bias_correlation_time'),
    ('accel.lever_arm', [1e300, 0.0, 0.0], 'accel.lever_arm[0] must be finite'),
    ('accel.gravity', [0.0, math.nan, 0.0], 'accel.gravity[1] must be finite'),
    ('mag.soft_iron', [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0], 'mag.soft_iron must be well'),
    ('mag.soft_iron', [-1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], 'positive determinant'),
    ('mag.field', [0.0, 1.0, 0.0], 'mag.field[1] must be finite with magnitude'),
    ('mag.noise_density', -1.0, 'parameter mag.noise_density'),
    ('imu.gyro_misalignment', [0.01] + [0.0] * 8, 'zero diagonal'),
    ('accel.scale_factor', [0.0, 0.9, 0.0], 'accel.scale_factor[1]'),
    ('imu.gyro_quantum', 2.0, 'parameter imu.gyro_quantum'),
    ('imu.kalibr_yaml', '/nonexistent/imu.yaml', 'parameter imu.kalibr_yaml'),
]


@pytest.mark.parametrize('name, value, words', BAD)
@pytest.mark.usefixtures('ros_context')
def test_bad_values_are_refused_at_run_time_and_the_node_keeps_its_configuration(
        name, value, words):
    node = attitude_node(**AIR)
    setup, before = node._setup, dict(node._values)
    result = node.set_parameters_atomically([Parameter(name, value=value)])
    assert not result.successful and words.lower() in result.reason.lower(), result.reason
    assert node._setup is setup and node._values == before
    kept = node.get_parameter(name).value
    assert (list(kept) if isinstance(before[name], list) else kept) == before[name]
    response = node._on_reset(None, type('R', (), {})())       # the last good one restarts
    assert response.success, response.message
    assert [s.name for s in node._schedule.streams] == ['imu', 'mag']
    node.destroy_node()


@pytest.mark.usefixtures('ros_context')
def test_a_live_node_publishes_them_and_applies_a_change_at_reset():
    node, ex, lis = node_and_listener(**AIR)
    got = {'imu': [], 'mag': [], 'delta_velocity': []}
    for topic, cls in (('imu', Imu), ('mag', MagneticField), ('delta_velocity', Vector3Stamped)):
        lis.create_subscription(cls, topic, got[topic].append, 100)
    ex.add_node(lis)
    spin_until(ex, lambda: all(len(v) >= 3 for v in got.values()))
    assert abs(got['imu'][0].linear_acceleration.z) > 5.0         # gravity is in it
    assert not node.set_parameters([Parameter('accel.enable', value=False)])[0].successful
    assert not node.set_parameters([Parameter('mag.enable', value=False)])[0].successful
    assert node.set_parameters([Parameter('accel.bias', value=[0.5, 0.0, 0.0])])[0].successful
    assert node._setup.accel.noise.bias0.tolist() == [0.0, 0.0, 0.0]    # applies at reset
    assert node._on_reset(None, type('R', (), {})()).success
    assert node._setup.accel.noise.bias0.tolist() == [0.5, 0.0, 0.0]
    lis.destroy_node()
    node.destroy_node()


@pytest.mark.usefixtures('ros_context')
def test_bad_start_up_in_process_raises_scene_error():
    with pytest.raises(SceneError, match='accel.enable needs imu.enable'):
        attitude_node(**{'accel.enable': True})


KALIBR = '''\
rostopic: /imu0
update_rate: 200.0
accelerometer_noise_density: 2.0e-3
accelerometer_random_walk: 3.0e-3
gyroscope_noise_density: 1.6e-4
gyroscope_random_walk: 2.2e-5
'''


def test_kalibr_file_maps_onto_the_parameters_with_a_stated_precedence(tmp_path):
    path = tmp_path / 'imu.yaml'
    path.write_text(KALIBR)
    base = _values(**{'imu.enable': True, 'accel.enable': True,
                      'imu.kalibr_yaml': str(path)})
    setup = settings.prepare_run(base)
    v = setup.values
    assert (v['imu.gyro_noise_density'], v['imu.gyro_random_walk'], v['accel.noise_density'],
            v['accel.random_walk'], v['imu.rate']) == (1.6e-4, 2.2e-5, 2e-3, 3e-3, 200.0)
    assert setup.gyro.noise.noise_density == 1.6e-4 and setup.accel.noise.random_walk == 3e-3
    assert setup.sensors.imu_rate == 200.0
    # the same value both ways is fine; a different one is refused naming both
    settings.prepare_run({**base, 'accel.noise_density': 2e-3})
    with pytest.raises(ValueError) as exc:
        settings.prepare_run({**base, 'accel.noise_density': 5e-3})
    msg = str(exc.value)
    assert msg.startswith('parameter accel.noise_density') and \
        'accelerometer_noise_density' in msg and 'imu.kalibr_yaml' in msg, msg
    path.write_text(KALIBR.replace('gyroscope_random_walk: 2.2e-5\n', ''))
    with pytest.raises(ValueError, match='imu.kalibr_yaml.*missing key gyroscope_random_walk'):
        settings.prepare_run(base)
    path.write_text(KALIBR.replace('2.0e-3', '-2.0e-3'))
    with pytest.raises(ValueError, match='imu.kalibr_yaml.*accelerometer_noise_density'):
        settings.prepare_run(base)
