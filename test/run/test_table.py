"""The table of outputs: a new sensor is one class and one row; the increment quanta act.

Oracles: for the toy sensor, the node's own recording against the offline generator (two
paths that share only the table row); for the quanta, the imu message's own rate and
specific force (the sum of the quantised increments stays within half an LSB of the sum
of rate x interval, whatever the noise), read back by rosbags.
"""

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rosbags.typesys import get_typestore, Stores

from rigidrot_ros.msgs import cdr
from rigidrot_ros.msgs import messages as msgs
from rigidrot_ros.run import params, settings, table
from rigidrot_ros.run.generate import generate_bag
from rigidrot_ros.run.output import header_stamps, SensorOutput, Topic
from rigidrot_ros.run.outputs import run_description
from ros_helpers import attitude_node, NODE_SCENE, spin_until
from run_helpers import canonical, payloads

_STORE = get_typestore(Stores.ROS2_JAZZY)
VECTOR = 'geometry_msgs/msg/Vector3Stamped'


class ToySun(SensorOutput):
    """A toy sun sensor: the unit sun direction (N's x axis) in B, with seeded noise, 25 Hz."""

    name = 'toy_sun'
    topics = (Topic('toy_sun', 'geometry_msgs/msg/Vector3Stamped', 40),)

    @classmethod
    def rate_of(cls, setup):
        """Return 25 Hz whatever the parameters."""
        return 25.0

    def __init__(self, setup):
        super().__init__(setup)
        self.rng = np.random.default_rng(17)

    def read(self, times, budget=None):
        """Read the sun direction at each of ``times``: R_BN x_N plus N(0, 1e-3^2)."""
        def one(t):
            x, y, z, w = self.setup.solution.at(t).quaternion.tolist()
            # first column of R_NB^T (row 0 of R_NB), from the quaternion by hand
            sun = (1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w))
            return (np.array(sun) + 1e-3 * self.rng.standard_normal(3),)
        return self.read_each(times, one, {'s': (3,)})

    def encode(self, topic, stamps, cols, frames):
        """Return the CDR of each row."""
        return cdr.vector(stamps, cols['s'], frames[1]).tolist()

    def messages(self, topic, stamps, cols, frames):
        """Return the message of each row."""
        return [msgs.vector(s, frames[1], v) for s, v in zip(header_stamps(stamps), cols['s'])]


@pytest.fixture
def toy():
    table.register(ToySun)
    try:
        yield ToySun
    finally:
        table.unregister(ToySun)
    assert ToySun not in table.OUTPUTS


def _values(**over):
    v = params.defaults()
    v.update(NODE_SCENE, publish_rate=100.0)
    v.update(over)
    return v


def test_a_registered_sensor_is_in_the_run_its_timing_and_the_diagnostics(toy):
    setup = settings.prepare_run(_values(**{'imu.enable': True}))
    assert [k.name for k in setup.outputs] == ['truth', 'imu', 'toy_sun', 'run']
    assert [o.name for o in table.make(setup)][2] == 'toy_sun'
    assert 'toy_sun' in table.sensor_names()
    info = run_description(setup, 0, 1, '/n', {})
    assert set(info['sensor_timing']) == {'imu', 'toy_sun'}


@pytest.mark.ros
@pytest.mark.usefixtures('ros_context')
def test_a_toy_sensor_is_byte_identical_in_a_node_recording_and_a_generated_bag(tmp_path, toy):
    over = {'imu.enable': True, 'imu.rate': 50.0}
    node = attitude_node(record=True, record_path=str(tmp_path / 'runs'), **over)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    try:
        assert '/toy_sun' in {p.topic_name for p in node.publishers}
        spin_until(ex, lambda: node._counters.published >= 150, timeout=30.0)
    finally:
        node.destroy_node()
    recorded, run = payloads(next((tmp_path / 'runs').iterdir()))
    assert run['topics']['/toy_sun'] == 'geometry_msgs/msg/Vector3Stamped'
    last = max(recorded['/attitude'])
    gen = generate_bag(_values(**over), (last - run['start_ns']) * 1e-9 + 0.5,
                       tmp_path / 'gen', start_ns=run['start_ns'])
    generated, gen_run = payloads(gen)
    assert gen_run == run and set(generated) == set(recorded)
    got = recorded['/toy_sun']
    assert len(got) >= 0.8 * 1.5 * 25 and set(got) <= set(generated['/toy_sun'])
    assert all(canonical(raw, VECTOR) == generated['/toy_sun'][ns] for ns, raw in got.items())
    imu = payloads.types['/imu']
    assert all(canonical(raw, imu) == canonical(generated['/imu'][ns], imu)
               for ns, raw in recorded['/imu'].items())


QUANTA = {'imu.gyro_increment_quantum': 1e-3, 'accel.increment_quantum': 0.05}
#: issue 31's repro: an imu with an accelerometer under gravity, with noise, 100 Hz
IMU = {'imu.enable': True, 'imu.rate': 100.0, 'accel.enable': True,
       'accel.gravity': [0.0, 0.0, -9.80665], 'accel.noise_density': 2e-3,
       'accel.random_walk': 1e-4, 'time_scale': 1.5}


def _messages(topic_payloads, kind):
    """Return a topic's messages in stamp order, deserialized by rosbags."""
    return [_STORE.deserialize_cdr(topic_payloads[ns], kind) for ns in sorted(topic_payloads)]


def _xyz(vectors):
    return np.array([[v.x, v.y, v.z] for v in vectors])


def test_the_increment_quanta_publish_the_quantised_increments_residual_carried(tmp_path):
    plain, _ = payloads(generate_bag({**NODE_SCENE, **IMU}, 5.0, tmp_path / 'plain'))
    quant, run = payloads(generate_bag({**NODE_SCENE, **IMU, **QUANTA}, 5.0, tmp_path / 'q'))
    new = {'/delta_angle_measured', '/delta_velocity_measured'}
    assert set(quant) == set(plain) | new and not new & set(plain)
    for topic in plain:                 # every other topic: unchanged, byte for byte
        if not topic.endswith('/run'):
            assert quant[topic] == plain[topic], topic
    assert set(quant['/delta_angle_measured']) == set(quant['/imu'])    # one per interval
    imu = _messages(quant['/imu'], 'sensor_msgs/msg/Imu')
    rate = _xyz([m.angular_velocity for m in imu])
    force = _xyz([m.linear_acceleration for m in imu])
    stamps = np.array(sorted(quant['/imu']), dtype=np.int64)
    dt = np.diff(np.concatenate([[run['start_ns']], stamps])) * 1e-9 * IMU['time_scale']
    for topic, q, y in (('/delta_angle_measured', QUANTA['imu.gyro_increment_quantum'], rate),
                        ('/delta_velocity_measured', QUANTA['accel.increment_quantum'],
                         force)):
        inc = _xyz([m.vector for m in _messages(quant[topic], VECTOR)])
        steps = inc / q
        assert np.all(np.abs(steps - np.rint(steps)) < 1e-6), topic     # whole LSBs
        drift = np.cumsum(inc, axis=0) - np.cumsum(y * dt[:, None], axis=0)
        assert np.abs(drift).max() <= 0.5 * q * (1 + 1e-9), topic      # the residual carried
        assert np.abs(drift).max() > 0.05 * q, topic                    # quantised, not exact
    # the exact increments stay on delta_angle: not the quantised ones
    exact = _xyz([m.vector for m in _messages(quant['/delta_angle'], VECTOR)])
    measured = _xyz([m.vector for m in _messages(quant['/delta_angle_measured'], VECTOR)])
    assert np.abs(exact - measured).max() > 1e-4
    assert np.any(np.abs(exact / QUANTA['imu.gyro_increment_quantum'] % 1 - 0.5) < 0.45)


@pytest.mark.ros
@pytest.mark.usefixtures('ros_context')
def test_a_quantum_set_at_run_time_brings_its_topic_at_the_reset_and_takes_it_away():
    from rclpy.parameter import Parameter
    node = attitude_node(**{'imu.enable': True, 'imu.rate': 50.0})
    ex = SingleThreadedExecutor()
    ex.add_node(node)

    def topics():
        return {p.topic_name for p in node.publishers}
    try:
        assert '/delta_angle_measured' not in topics()
        for quantum, present in ((1e-4, True), (0.0, False)):
            name = 'imu.gyro_increment_quantum'
            assert node.set_parameters([Parameter(name, value=quantum)])[0].successful
            assert ('/delta_angle_measured' in topics()) is not present    # at the reset
            assert node._on_reset(None, type('R', (), {})()).success
            assert ('/delta_angle_measured' in topics()) is present
            n = node._counters.published
            spin_until(ex, lambda: node._counters.published >= n + 20, timeout=30.0)
            assert not node._counters.errors
    finally:
        node.destroy_node()
