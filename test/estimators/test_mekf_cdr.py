"""rigidrot_mekf's raw reading: the fields it unpacks from CDR are rclpy's, bit for bit.

Oracle: rclpy's own deserializer on the same bytes (the generator's serialized messages,
and messages rclpy serialized itself, with frame ids of every length modulo 8).
"""

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped
import numpy as np
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Imu

from rigidrot_ros.estimators.mekf_node import cdr_view
from rigidrot_ros.run.generate import iter_serialized, load_values


def _same(view, msg, kind):
    assert view.header.stamp == msg.header.stamp and isinstance(view.header.stamp, Time)
    if kind == 'imu':
        v, m = view.angular_velocity, msg.angular_velocity
        assert (v.x, v.y, v.z) == (m.x, m.y, m.z)
        assert tuple(view.angular_velocity_covariance) == tuple(msg.angular_velocity_covariance)
    else:
        v, m = view.pose.pose.orientation, msg.pose.pose.orientation
        assert (v.x, v.y, v.z, v.w) == (m.x, m.y, m.z, m.w)
        assert tuple(view.pose.covariance) == tuple(msg.pose.covariance)


def test_generated_messages_read_as_rclpy_reads_them():
    values = load_values(None, {'imu.enable': True, 'star_tracker.enable': True,
                                'imu.seed': 4}.items())
    n = 0
    for topic, _, data in iter_serialized(values, 0.5, ('imu', 'star_tracker')):
        kind = topic.rsplit('/', 1)[-1]
        msg = deserialize_message(data, Imu if kind == 'imu' else PoseWithCovarianceStamped)
        _same(cdr_view(kind, data), msg, kind)
        n += 1
    assert n == 49 + 5


def test_every_frame_id_length_and_other_layouts():
    rng = np.random.default_rng(5)
    for length in range(0, 17):
        imu, star = Imu(), PoseWithCovarianceStamped()
        for m in (imu, star):
            m.header.frame_id = 'b' * length
            m.header.stamp = Time(sec=int(rng.integers(0, 2**31)), nanosec=123456789)
        imu.angular_velocity.x, imu.angular_velocity.y, imu.angular_velocity.z = rng.normal(
            size=3)
        imu.angular_velocity_covariance = rng.normal(size=9)
        o = star.pose.pose.orientation
        o.x, o.y, o.z, o.w = rng.normal(size=4)
        star.pose.covariance = rng.normal(size=36)
        for kind, msg in (('imu', imu), ('star_tracker', star)):
            data = serialize_message(msg)
            _same(cdr_view(kind, data), msg, kind)
            assert cdr_view(kind, data + b'\0' * 8) is None             # another layout
            assert cdr_view(kind, b'\x00\x00' + data[2:]) is None        # big endian
    assert cdr_view('imu', serialize_message(PoseWithCovarianceStamped())) is None
