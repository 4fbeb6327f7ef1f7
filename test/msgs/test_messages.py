"""The conversion layer: every message it builds, serialised by rclpy, read by rosbags.

rosbags (what evo reads bags with) has its own Jazzy type store and CDR decoder: it shares
no code with rclpy, so a field that round-trips here is what an independent reader sees.
"""

import math

import numpy as np
from numpy.testing import assert_allclose, assert_array_equal
import pytest
from rclpy.serialization import serialize_message
from rosbags.typesys import get_typestore, Stores

from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.msgs import messages as msgs

STORE = get_typestore(Stores.ROS2_JAZZY)
Q = np.array([0.1, -0.2, 0.3, 0.9]) / np.linalg.norm([0.1, -0.2, 0.3, 0.9])
W = np.array([0.3, -0.2, 0.5])
NS = 1_795_000_000_123_456_789


def _read(msg, type_name):
    return STORE.deserialize_cdr(bytes(serialize_message(msg)), type_name)


def _q(m):
    return np.array([m.x, m.y, m.z, m.w])


def _v(m):
    return np.array([m.x, m.y, m.z])


def test_stamp_keeps_every_nanosecond():
    st = msgs.stamp(NS)
    assert (st.sec, st.nanosec) == (1_795_000_000, 123_456_789)
    m = _read(msgs.attitude(st, 'inertial', Q), 'geometry_msgs/msg/QuaternionStamped')
    assert m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec == NS
    assert m.header.frame_id == 'inertial'
    assert_array_equal(_q(m.quaternion), Q)


def test_imu_fields_and_covariance_conventions():
    m = _read(msgs.imu(msgs.stamp(NS), 'body', W, 2.5e-6), 'sensor_msgs/msg/Imu')
    assert m.header.frame_id == 'body'
    assert_array_equal(_v(m.angular_velocity), W)
    assert_array_equal(m.angular_velocity_covariance, np.diag([2.5e-6] * 3).ravel())
    assert m.orientation_covariance[0] == -1.0
    assert m.linear_acceleration_covariance[0] == -1.0
    assert_array_equal(_v(m.linear_acceleration), [0.0, 0.0, 0.0])


def test_odometry_transform_and_star_tracker():
    st = msgs.stamp(NS)
    od = _read(msgs.odometry(st, 'inertial', 'body', Q, W, 1e-26, 4e-30), 'nav_msgs/msg/Odometry')
    assert (od.header.frame_id, od.child_frame_id) == ('inertial', 'body')
    assert_array_equal(_q(od.pose.pose.orientation), Q)
    assert_array_equal(_v(od.pose.pose.position), [0.0, 0.0, 0.0])
    assert_array_equal(_v(od.twist.twist.angular), W)
    assert_array_equal(_v(od.twist.twist.linear), [0.0, 0.0, 0.0])
    pc = od.pose.covariance.reshape(6, 6)
    assert_array_equal(np.diag(pc), [-1, -1, -1, 1e-26, 1e-26, 1e-26])
    assert np.count_nonzero(pc - np.diag(np.diag(pc))) == 0
    assert_array_equal(np.diag(od.twist.covariance.reshape(6, 6)), [-1, -1, -1] + [4e-30] * 3)
    tf = _read(msgs.transform(st, 'inertial', 'body', Q), 'geometry_msgs/msg/TransformStamped')
    assert (tf.header.frame_id, tf.child_frame_id) == ('inertial', 'body')
    assert_array_equal(_q(tf.transform.rotation), Q)
    cov_b = np.array([[4.0, 0.5, 0.0], [0.5, 3.0, 0.1], [0.0, 0.1, 9.0]]) * 1e-10
    ps = _read(msgs.star_tracker(st, 'inertial', Q, cov_b),
               'geometry_msgs/msg/PoseWithCovarianceStamped')
    assert ps.header.frame_id == 'inertial'
    assert_array_equal(_q(ps.pose.pose.orientation), Q)
    c = ps.pose.covariance.reshape(6, 6)
    assert_array_equal(c[3:, 3:], cov_b)                  # the orientation block, error in B
    assert_array_equal(np.diag(c)[:3], [-1.0, -1.0, -1.0])
    assert np.count_nonzero(c[:3, 3:]) == np.count_nonzero(c[3:, :3]) == 0


@pytest.mark.parametrize('inertia', [(2.0, 2.0, 1.0), (1.0, 2.0, 3.0), (5.0, 5.0, 5.0)])
def test_markers_draw_the_inertia_ellipsoid_box_and_the_body_axes(inertia):
    m = _read(msgs.body_markers(msgs.stamp(NS), 'inertial', Q, inertia),
              'visualization_msgs/msg/MarkerArray')
    box, *arrows = m.markers
    assert box.type == 1 and [a.type for a in arrows] == [0, 0, 0]        # CUBE, ARROW
    assert len({(x.ns, x.id) for x in m.markers}) == 4
    size = np.array([box.scale.x, box.scale.y, box.scale.z])
    assert size.max() == pytest.approx(1.0)
    assert_allclose(size * np.sqrt(inertia), size[0] * math.sqrt(inertia[0]), rtol=1e-15)
    assert_array_equal(_q(box.pose.orientation), Q)
    r_nb = quat.to_matrix(Q)
    for k, a in enumerate(arrows):
        assert a.header.frame_id == 'inertial'
        assert_allclose(quat.to_matrix(_q(a.pose.orientation))[:, 0], r_nb[:, k], atol=1e-15)
        assert a.color.a == 1.0
