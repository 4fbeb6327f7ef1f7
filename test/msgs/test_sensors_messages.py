"""Message builders for the new sensors; the gyro's Imu unchanged when no accelerometer."""

from builtin_interfaces.msg import Time
import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosbags.typesys import get_typestore, Stores

from rigidrot_ros.msgs import messages


def test_imu_without_accelerometer_is_as_before():
    st = Time(sec=3, nanosec=5)
    msg = messages.imu(st, 'body', (0.1, -0.2, 0.3), 1e-6)
    assert msg.linear_acceleration_covariance[0] == -1.0
    assert list(msg.linear_acceleration_covariance[1:]) == [0.0] * 8
    assert (msg.linear_acceleration.x, msg.linear_acceleration.y,
            msg.linear_acceleration.z) == (0.0, 0.0, 0.0)
    assert msg.orientation_covariance[0] == -1.0
    assert list(msg.angular_velocity_covariance) == [1e-6, 0, 0, 0, 1e-6, 0, 0, 0, 1e-6]


def test_imu_with_accelerometer_decodes_with_an_independent_reader():
    st = Time(sec=3, nanosec=5)
    msg = messages.imu(st, 'body', (0.1, -0.2, 0.3), 1e-6, (0.5, -0.25, 9.80665), 4e-4)
    ts = get_typestore(Stores.ROS2_JAZZY)
    back = ts.deserialize_cdr(bytes(serialize_message(msg)), 'sensor_msgs/msg/Imu')
    assert (back.linear_acceleration.x, back.linear_acceleration.y,
            back.linear_acceleration.z) == (0.5, -0.25, 9.80665)
    assert list(back.linear_acceleration_covariance) == [4e-4, 0, 0, 0, 4e-4, 0, 0, 0, 4e-4]
    assert back.header.frame_id == 'body' and back.orientation_covariance[0] == -1.0
    with pytest.raises(ValueError, match='needs accel_variance'):
        messages.imu(st, 'body', (0.0, 0.0, 0.0), 1e-6, (0.0, 0.0, 9.8))


def test_delta_velocity_and_magnetic_field():
    st = Time(sec=1, nanosec=2)
    dv = messages.delta_velocity(st, 'body', (0.01, 0.02, 0.098))
    assert (dv.vector.x, dv.vector.y, dv.vector.z) == (0.01, 0.02, 0.098)
    assert dv.header.frame_id == 'body'
    cov = np.diag([1e-14, 2e-14, 3e-14])
    mag = messages.magnetic_field(st, 'body', (2e-5, 0.0, -4.5e-5), cov)
    ts = get_typestore(Stores.ROS2_JAZZY)
    back = ts.deserialize_cdr(bytes(serialize_message(mag)), 'sensor_msgs/msg/MagneticField')
    assert (back.magnetic_field.x, back.magnetic_field.z) == (2e-5, -4.5e-5)
    assert list(back.magnetic_field_covariance) == list(cov.ravel())
    assert list(messages.magnetic_field(st, 'b', (0, 0, 0), 1e-14).magnetic_field_covariance) \
        == [1e-14, 0, 0, 0, 1e-14, 0, 0, 0, 1e-14]
