"""Samples and sensor readings -> ROS messages: the one conversion layer.

Used by the node for every publisher, and available to recorders and compare. Frames: N
inertial (``frame_id``), B body (``body_frame_id``); ``R_NB`` means ``v_N = R_NB @ v_B``.
Quaternions are (x, y, z, w), active, ``q_NB`` (rotates body vectors into N); rates are
of B relative to N, in B, rad/s.

Covariance conventions:

- ``sensor_msgs/Imu`` from the gyro: ``orientation_covariance[0] = -1`` (no orientation);
  ``angular_velocity_covariance`` diagonal = the white-noise variance of one sample
  (bias and its drift are not in it, as in Gazebo); ``linear_acceleration`` zero with
  ``linear_acceleration_covariance[0] = -1``: not provided (no accelerometer is
  modelled: the specific force at the centre of mass of a free body is zero, and a
  consumer that fused that zero as gravity would diverge).
- Orientation covariances (star tracker, Odometry) are of the rotation-vector error e in
  B, ``q_true^-1 ⊗ q = exp(e / 2)``.
- Unused blocks of a 6x6 covariance (the zero position, the zero linear velocity) have
  -1 on their diagonal, as the Imu message marks a field it does not provide.
"""

import math

from builtin_interfaces.msg import Time
from geometry_msgs.msg import (
    PoseWithCovarianceStamped, QuaternionStamped, TransformStamped, Vector3Stamped,
)
from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import Imu, MagneticField
from visualization_msgs.msg import Marker, MarkerArray

from rigidrot_ros.core.quaternion import multiply_floats

__all__ = ['stamp', 'attitude', 'vector', 'imu', 'odometry', 'transform', 'star_tracker',
           'body_markers', 'box_size', 'delta_velocity', 'magnetic_field', 'axis_from_x',
           'UNUSED']

#: Diagonal value that marks a covariance block as "not provided".
UNUSED = -1.0
_SEC = 1_000_000_000


def stamp(ns):
    """Return a ``builtin_interfaces/Time`` of integer nanoseconds (clock time)."""
    ns = int(ns)
    return Time(sec=ns // _SEC, nanosec=ns % _SEC)


def _header(msg, stamp_msg, frame_id):
    msg.header.stamp = stamp_msg
    msg.header.frame_id = frame_id
    return msg


def _set_quaternion(target, q):
    target.x, target.y, target.z, target.w = (float(v) for v in q)


def _set_vector(target, v):
    target.x, target.y, target.z = (float(c) for c in v)


def attitude(stamp_msg, frame_id, q):
    """``geometry_msgs/QuaternionStamped``: q_NB (x, y, z, w), frame_id N."""
    msg = _header(QuaternionStamped(), stamp_msg, frame_id)
    _set_quaternion(msg.quaternion, q)
    return msg


def vector(stamp_msg, frame_id, v):
    """``geometry_msgs/Vector3Stamped`` of a 3-vector in ``frame_id``."""
    msg = _header(Vector3Stamped(), stamp_msg, frame_id)
    _set_vector(msg.vector, v)
    return msg


def imu(stamp_msg, body_frame_id, omega, variance, linear_acceleration=None,
        accel_variance=None):
    """``sensor_msgs/Imu`` of a gyro sample (and an accelerometer's): no orientation.

    Parameters
    ----------
    stamp_msg : builtin_interfaces/Time
    body_frame_id : str
    omega : 3 floats
        Measured rate of B relative to N, in B, rad/s.
    variance : float
        Per-axis variance of the rate, (rad/s)^2, on the covariance diagonal.
    linear_acceleration : 3 floats, optional
        Measured specific force in B, m/s^2 (acceleration minus gravity). Without it the
        field stays zero with ``linear_acceleration_covariance[0] = -1`` (not provided).
    accel_variance : float, optional
        Per-axis variance of the specific force, (m/s^2)^2, on the diagonal of
        ``linear_acceleration_covariance`` (in B); needed with ``linear_acceleration``.
    """
    msg = _header(Imu(), stamp_msg, body_frame_id)
    msg.orientation_covariance[0] = UNUSED
    _set_vector(msg.angular_velocity, omega)
    v = float(variance)
    msg.angular_velocity_covariance = [v, 0.0, 0.0, 0.0, v, 0.0, 0.0, 0.0, v]
    if linear_acceleration is None:
        msg.linear_acceleration_covariance[0] = UNUSED
        return msg
    if accel_variance is None:
        raise ValueError('imu: linear_acceleration needs accel_variance (its covariance)')
    _set_vector(msg.linear_acceleration, linear_acceleration)
    a = float(accel_variance)
    msg.linear_acceleration_covariance = [a, 0.0, 0.0, 0.0, a, 0.0, 0.0, 0.0, a]
    return msg


def delta_velocity(stamp_msg, body_frame_id, dv):
    """``geometry_msgs/Vector3Stamped`` of a Δv = ∫ f_B dt over one interval, m/s, in B."""
    return vector(stamp_msg, body_frame_id, dv)


def magnetic_field(stamp_msg, body_frame_id, field, covariance):
    """``sensor_msgs/MagneticField``: the field in B (tesla) and its covariance (T^2, in B).

    ``covariance`` is a 3x3 matrix (or a per-axis variance for a diagonal one); all zero
    would mean "unknown" to a consumer, so a zero-noise sensor still states the attitude's
    error (see :class:`rigidrot_ros.sensors.Magnetometer`).
    """
    msg = _header(MagneticField(), stamp_msg, body_frame_id)
    _set_vector(msg.magnetic_field, field)
    c = np.asarray(covariance, dtype=float)
    c = c * np.eye(3) if c.ndim == 0 else c.reshape(3, 3)
    msg.magnetic_field_covariance = [float(x) for x in c.ravel()]
    return msg


def _cov6(rot_block, second_block=None):
    """Row-major 6x6: -1 diagonal for the first block (unused), ``rot_block`` second."""
    c = np.zeros((6, 6))
    c[0, 0] = c[1, 1] = c[2, 2] = UNUSED
    c[3:, 3:] = rot_block
    return [float(x) for x in c.ravel()]


def odometry(stamp_msg, frame_id, child_frame_id, q, omega, attitude_variance=0.0,
             rate_variance=0.0):
    """``nav_msgs/Odometry`` of the truth.

    ``pose``: zero position (covariance block marked unused), orientation q_NB in
    ``frame_id`` (N) with ``attitude_variance`` (rad^2, of e in B) on its diagonal;
    ``twist``: zero linear velocity (marked unused), angular = omega in
    ``child_frame_id`` (B), rad/s, with ``rate_variance`` on its diagonal.
    """
    msg = _header(Odometry(), stamp_msg, frame_id)
    msg.child_frame_id = child_frame_id
    _set_quaternion(msg.pose.pose.orientation, q)
    msg.pose.covariance = _cov6(float(attitude_variance) * np.eye(3))
    _set_vector(msg.twist.twist.angular, omega)
    msg.twist.covariance = _cov6(float(rate_variance) * np.eye(3))
    return msg


def transform(stamp_msg, parent_frame_id, child_frame_id, q):
    """``geometry_msgs/TransformStamped`` N -> B: zero translation, rotation q_NB."""
    msg = _header(TransformStamped(), stamp_msg, parent_frame_id)
    msg.child_frame_id = child_frame_id
    _set_quaternion(msg.transform.rotation, q)
    return msg


def star_tracker(stamp_msg, frame_id, q, covariance_b):
    """``geometry_msgs/PoseWithCovarianceStamped`` of a star tracker's attitude.

    ``pose.orientation`` = measured q_NB in ``frame_id`` (N); the orientation block of
    the covariance (rows/columns 3-5) is the covariance of the rotation-vector error e in
    B, ``q_true^-1 ⊗ q_meas = exp(e / 2)``, rad^2; the position block is marked unused.
    """
    msg = _header(PoseWithCovarianceStamped(), stamp_msg, frame_id)
    _set_quaternion(msg.pose.pose.orientation, q)
    msg.pose.covariance = _cov6(np.asarray(covariance_b, dtype=float))
    return msg


def box_size(inertia, longest=1.0):
    """Edge lengths (m) of a box with the inertia ellipsoid's proportions.

    The ellipsoid ``x^T I x = 1`` has semi-axes ``1 / sqrt(I_i)``; the box is scaled so
    that its longest edge is ``longest``.
    """
    axes = 1.0 / np.sqrt(np.asarray(inertia, dtype=float))
    return longest * axes / float(np.max(axes))


_AXIS_COLOURS = ((1.0, 0.2, 0.2), (0.2, 0.9, 0.2), (0.3, 0.4, 1.0))


def body_markers(stamp_msg, frame_id, q, inertia, namespace='body'):
    """``visualization_msgs/MarkerArray``: the body as a box and its three axes.

    All markers are in ``frame_id`` (N) with pose orientation q_NB, so they render
    without any transform: a box with the inertia ellipsoid's proportions (longest edge
    1 m) and arrows along the body axes x (red), y (green), z (blue).
    """
    size = box_size(inertia)
    out = MarkerArray()
    box = _header(Marker(), stamp_msg, frame_id)
    box.ns, box.id, box.type, box.action = namespace, 0, Marker.CUBE, Marker.ADD
    _set_quaternion(box.pose.orientation, q)
    box.scale.x, box.scale.y, box.scale.z = (float(s) for s in size)
    box.color.r, box.color.g, box.color.b, box.color.a = 0.7, 0.7, 0.75, 0.6
    box.frame_locked = False
    out.markers.append(box)
    length = 0.75 * float(np.max(size))
    x, y, z, w = (float(v) for v in q)
    for k, (r, g, b) in enumerate(_AXIS_COLOURS):
        arrow = _header(Marker(), stamp_msg, frame_id)
        arrow.ns, arrow.id, arrow.type, arrow.action = namespace, k + 1, Marker.ARROW, \
            Marker.ADD
        # an ARROW points along its pose's x axis: rotate body x onto body axis k
        qa = axis_from_x(k)
        _set_quaternion(arrow.pose.orientation, multiply_floats((x, y, z, w), qa))
        arrow.scale.x, arrow.scale.y, arrow.scale.z = length, 0.04, 0.04
        arrow.color.r, arrow.color.g, arrow.color.b, arrow.color.a = r, g, b, 1.0
        out.markers.append(arrow)
    return out


def axis_from_x(k):
    """Quaternion (x, y, z, w) turning the x axis onto axis k (0, 1, 2)."""
    h = math.sqrt(0.5)
    return ((0.0, 0.0, 0.0, 1.0), (0.0, 0.0, h, h), (0.0, -h, 0.0, h))[k]
