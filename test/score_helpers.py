"""Helpers that test_score.py shares with other test modules."""

import json
from pathlib import Path

from geometry_msgs.msg import (
    PoseStamped, PoseWithCovarianceStamped, QuaternionStamped, TransformStamped,
    Vector3Stamped,
)
from nav_msgs.msg import Odometry
import numpy as np
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu
from std_msgs.msg import String

from rigidrot_ros.bag import BagWriter
from rigidrot_ros.core import Scene, solve


SCENE = Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05), omega0=(0.3, -0.2, 0.5),
              attitude0=(0.1, 0.2, 0.3, 0.9))
START = 1_700_000_000_000_000_000
RATE = 100.0


def _run_msg(start=START, scale=1.0):
    info = {'rigidrot_run': 1, 'run': 1, 'start_ns': start, 'time_scale': scale,
            'scene': SCENE.as_dict(), 'tol': 1e-12, 'backend': None, 'model': 'test',
            'method': 'test', 'node': '/attitude_node',
            'topics': {'/attitude': 'geometry_msgs/msg/QuaternionStamped'}}
    return String(data=json.dumps(info))


def _stamp(msg, ns):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(ns), 1_000_000_000)


def _q(m, q):
    m.x, m.y, m.z, m.w = (float(v) for v in q)


def _v(m, v):
    m.x, m.y, m.z = (float(c) for c in v)


def _truth(n):
    t = np.arange(n) / RATE
    sol = solve(SCENE, tol=1e-12)
    s = sol.at(t)
    return t, START + np.round(t * 1e9).astype(np.int64), s.quaternion, s.omega


def _cov6(p):
    c = np.zeros((6, 6))
    c[3:, 3:] = p
    return [float(v) for v in c.ravel()]


def _make(kind, stamp, q, w, cov=None):
    """One message of ``kind`` with attitude ``q``, rate ``w`` and orientation cov."""
    if kind == 'QuaternionStamped':
        m = QuaternionStamped()
        _q(m.quaternion, q)
    elif kind == 'PoseStamped':
        m = PoseStamped()
        _q(m.pose.orientation, q)
    elif kind == 'PoseWithCovarianceStamped':
        m = PoseWithCovarianceStamped()
        _q(m.pose.pose.orientation, q)
        if cov is not None:
            m.pose.covariance = _cov6(cov)
    elif kind == 'TransformStamped':
        m = TransformStamped()
        _q(m.transform.rotation, q)
        m.child_frame_id = 'body'
    elif kind == 'Odometry':
        m = Odometry()
        _q(m.pose.pose.orientation, q)
        _v(m.twist.twist.angular, w)
        if cov is not None:
            m.pose.covariance = _cov6(cov)
    elif kind == 'Imu':
        m = Imu()
        _q(m.orientation, q)
        _v(m.angular_velocity, w)
        m.orientation_covariance = [float(v) for v in np.ravel(cov)] if cov is not None \
            else [0.0] * 9
        m.angular_velocity_covariance = [1e-6, 0, 0, 0, 1e-6, 0, 0, 0, 1e-6]
        m.linear_acceleration_covariance[0] = -1.0
    elif kind == 'Vector3Stamped':
        m = Vector3Stamped()
        _v(m.vector, w)
    else:
        raise ValueError(kind)
    _stamp(m, stamp)
    m.header.frame_id = 'inertial'
    return m


def _write_bag(tmp_path, topics, n=300, with_run=True, name='syn'):
    """Bag with a run description message and ``topics``: {topic: (kind, fn(k) -> msg)}."""
    w = BagWriter(str(tmp_path / 'bags'), name)
    if with_run:
        w.add_topic('/attitude_node/run', 'std_msgs/msg/String')
        w.write('/attitude_node/run', serialize_message(_run_msg()), START)
    for topic, (type_name, _) in topics.items():
        w.add_topic(topic, type_name)
    for k in range(n):
        for topic, (_, fn) in topics.items():
            msg = fn(k)
            ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            w.write(topic, serialize_message(msg), ns)
    w.close()
    return Path(w.path)
