"""Accelerometer and magnetometer through the node's look-ahead, with the timing models.

Oracle: the kinds' per-sample path (each sample read alone, messages built one by one by
:mod:`rigidrot_ros.msgs.messages` and serialized by rclpy), on a fresh run set-up from the
same parameters. The node's
messages (read in blocks, serialized by the vectorised CDR writer, published as bytes)
must equal them field for field, every sample once and in order; the magnetometer's
timing model (drops, clock offset, jitter, latency) must act as the scheduler's seeded
:class:`Track` says, the values underneath unchanged.
"""

from geometry_msgs.msg import Vector3Stamped
import numpy as np
import pytest
from sensor_msgs.msg import Imu, MagneticField

from rigidrot_ros.msgs import messages as msgs
from rigidrot_ros.run import grid, outputs, params, settings
from rigidrot_ros.run.scheduler import timing_of, Track
from rigidrot_ros.runtime.ahead import AHEAD_MIN
from ros_helpers import node_and_listener, NODE_SCENE, spin_until, stamp_ns
from run_helpers import per_sample, sensors

IMU_RATE, MAG_RATE = 200.0, 50.0
MAG_TIMING = {'mag.drop_probability': 0.3, 'mag.clock_offset': 0.0042,
              'mag.stamp_jitter': 2e-4, 'mag.latency': 0.015}
PARAMS = {'imu.enable': True, 'imu.rate': IMU_RATE, 'imu.seed': 3,
          'accel.enable': True, 'accel.gravity': [0.0, 0.0, -9.80665],
          'accel.lever_arm': [0.1, -0.05, 0.2], 'accel.noise_density': 2e-3,
          'accel.random_walk': 1e-4,
          'mag.enable': True, 'mag.rate': MAG_RATE, 'mag.noise_density': 1e-8, 'mag.seed': 5,
          'time_scale': 1.5, **MAG_TIMING}
TOPICS = {'imu': Imu, 'delta_angle': Vector3Stamped, 'delta_rotation': Vector3Stamped,
          'delta_velocity': Vector3Stamped, 'mag': MagneticField}


def test_the_magnetometer_timing_parameters_are_in_the_table_and_the_run_description():
    for key in ('latency', 'stamp_jitter', 'drop_probability', 'clock_offset'):
        assert params.BY_NAME[f'mag.{key}'].default == 0.0
    values = params.defaults()
    values.update(NODE_SCENE, **PARAMS)
    info = outputs.run_description(settings.prepare_run(values), 0, 1, '/n', {})
    assert info['sensor_timing']['mag'] == {
        'latency_s': 0.015, 'stamp_jitter_s': 2e-4, 'drop_probability': 0.3,
        'clock_offset_s': 0.0042}


@pytest.mark.ros
@pytest.mark.usefixtures('ros_context')
def test_accel_and_mag_batched_equal_the_per_sample_messages_with_the_mag_timing_model():
    node, ex, lis = node_and_listener('sensors_listener', **PARAMS)
    got = {t: [] for t in TOPICS}
    arrived = {t: [] for t in TOPICS}

    def cb(topic):
        def f(msg):
            got[topic].append(msg)
            arrived[topic].append(lis.get_clock().now().nanoseconds)
        return f
    for topic, cls in TOPICS.items():
        lis.create_subscription(cls, topic, cb(topic), 10000)
    ex.add_node(lis)
    spin_until(ex, lambda: len(got['imu']) >= 120 and len(got['mag']) >= 25 and
               len(got['delta_velocity']) >= 120)
    # both sensors went through the batched path, look-ahead on
    by_name = {s.output.name: s for s in node._schedule.sensors}
    assert set(by_name) == {'imu', 'mag'}
    assert all(s.ahead.size >= AHEAD_MIN for s in by_name.values())
    t0 = node._schedule.t_start_ns
    values = dict(node._values)
    frames = (values['frame_id'], values['body_frame_id'])
    node.destroy_node()
    lis.destroy_node()

    # the oracle: a fresh run from the same parameters, sample by sample
    streams = {s.name: s for s in sensors(settings.prepare_run(values))}
    scale = values['time_scale']
    n_imu = min(len(got[t]) for t in ('imu', 'delta_angle', 'delta_rotation',
                                      'delta_velocity'))
    ref = [dict(per_sample(streams['imu'], k, t0, scale, frames)) for k in range(1, n_imu + 1)]
    for topic in ('imu', 'delta_angle', 'delta_rotation', 'delta_velocity'):
        for i in range(n_imu):          # every sample once, in order, field for field
            assert got[topic][i] == ref[i][topic], (topic, i)
    assert got['imu'][0].linear_acceleration_covariance[0] > 0.0    # the accelerometer's

    # the magnetometer: each sample read in order (dropped ones too), the kept published
    track = Track('mag', t0, MAG_RATE, 0, timing_of(values, 'mag'))
    n_read = round((stamp_ns(got['mag'][-1]) - t0) * MAG_RATE / 1e9) + 3
    marks, keep = track.marks(range(n_read))
    kept = [k for k in range(n_read) if keep[k]][:len(got['mag'])]
    assert len(kept) == len(got['mag']) and len(kept) < kept[-1] + 1    # some dropped
    mag_ref = [per_sample(streams['mag'], k, t0, scale, frames)[0][1] for k in range(n_read)]
    for msg, k in zip(got['mag'], kept):
        want = mag_ref[k]
        want.header.stamp = msgs.stamp(int(marks[k]))      # grid + offset + jitter
        assert msg == want, k
    jitter = np.array([stamp_ns(m) for m in got['mag']]) - \
        np.array([grid.stamp_ns(t0, MAG_RATE, k) for k in kept]) - round(0.0042e9)
    assert np.any(jitter != 0) and np.all(np.abs(jitter) < 10 * 2e-4 * 1e9)
    late = np.array(arrived['mag'][:len(kept)]) - \
        np.array([grid.stamp_ns(t0, MAG_RATE, k) for k in kept])
    assert np.all(late >= 0.015e9)
