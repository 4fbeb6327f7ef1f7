"""A gyro integrator with an honest covariance, for rigidrot_campaign (in process).

The campaign calls make(params) once per run, then receive(topic, msg) for every
message of the run in log-time order, then finish(). Each returns a list of estimates.
Quaternions are (x, y, z, w), q_NB (body to inertial); rates are in the body frame B.
"""

from nav_msgs.msg import Odometry
import numpy as np


def quat_mul(a, b):
    """Hamilton product a * b of (x, y, z, w) quaternions."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def quat_exp(v):
    """Return the (x, y, z, w) quaternion of the rotation vector v (angle |v|, rad)."""
    angle = np.linalg.norm(v)
    axis = v / angle if angle > 0 else np.zeros(3)
    return np.append(axis * np.sin(angle / 2), np.cos(angle / 2))


def rotation(v):
    """Return the rotation matrix of the rotation vector v (Rodrigues)."""
    angle = np.linalg.norm(v)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    if angle < 1e-9:
        return np.eye(3) + k
    return (np.eye(3) + np.sin(angle) / angle * k
            + (1 - np.cos(angle)) / angle ** 2 * k @ k)


class GyroIntegrator:
    """Integrate the gyro from the first star tracker fix; never correct.

    State error x = (e, b): e the attitude error in B (q_est = q_true * exp(e / 2), the
    scorer's convention), b the gyro bias it does not estimate. Per gyro sample (the
    mean rate over the last dt):
        P <- F P F^T + Q,  F = [[R(-w dt), dt I], [0, I]],
        Q = [[C dt^2, 0], [0, bias_random_walk^2 dt I]]
    with C the sample's angular_velocity_covariance. P starts as the star tracker's
    covariance R and bias_sigma^2 I.
    """

    def __init__(self, bias_sigma=0.0, bias_random_walk=0.0):
        self.bias_var = float(bias_sigma) ** 2
        self.walk_var = float(bias_random_walk) ** 2
        self.q = None       # q_NB, (x, y, z, w)
        self.t_ns = None    # time of the state
        self.P = None       # 6x6 covariance of (e, b)

    def receive(self, topic, msg):
        """Take one message; return the estimates it makes (a list)."""
        name = topic.rsplit('/', 1)[-1]          # '/imu' -> 'imu'
        if name not in ('imu', 'star_tracker'):
            return []                            # the run description, a magnetometer
        t_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if name == 'star_tracker':
            if self.q is None:                   # the first fix starts the integration
                o = msg.pose.pose.orientation
                self.q = np.array([o.x, o.y, o.z, o.w])
                self.t_ns = t_ns
                self.P = np.zeros((6, 6))
                self.P[:3, :3] = np.reshape(msg.pose.covariance, (6, 6))[3:, 3:]
                self.P[3:, 3:] = self.bias_var * np.eye(3)
            return []
        if self.q is None or t_ns <= self.t_ns:
            return []
        dt = (t_ns - self.t_ns) * 1e-9
        w = msg.angular_velocity
        omega = np.array([w.x, w.y, w.z])
        C = np.reshape(msg.angular_velocity_covariance, (3, 3))
        self.q = quat_mul(self.q, quat_exp(omega * dt))
        self.q /= np.linalg.norm(self.q)
        F = np.eye(6)
        F[:3, :3] = rotation(-omega * dt)
        F[:3, 3:] = dt * np.eye(3)
        Q = np.zeros((6, 6))
        Q[:3, :3] = C * dt * dt
        Q[3:, 3:] = self.walk_var * dt * np.eye(3)
        self.P = F @ self.P @ F.T + Q
        self.t_ns = t_ns
        return [self.estimate(msg.header.stamp, omega, C)]

    def finish(self):
        """Return the estimates still held at the end of the run (none here)."""
        return []

    def estimate(self, stamp, omega, C):
        """nav_msgs/Odometry: q_NB, and the covariance of e in its rotation block."""
        odom = Odometry()
        odom.header.stamp = stamp                # the sensor's stamp: scored against it
        odom.header.frame_id = 'inertial'
        odom.child_frame_id = 'body'
        o = odom.pose.pose.orientation
        o.x, o.y, o.z, o.w = (float(v) for v in self.q)
        pose_cov = np.zeros((6, 6))
        pose_cov[:3, :3] = -np.eye(3)            # no position: -1 marks it unused
        pose_cov[3:, 3:] = self.P[:3, :3]        # rotation about x, y, z of B, rad^2
        odom.pose.covariance = pose_cov.ravel().tolist()
        a = odom.twist.twist.angular
        a.x, a.y, a.z = (float(v) for v in omega)
        twist_cov = np.zeros((6, 6))
        twist_cov[:3, :3] = -np.eye(3)
        twist_cov[3:, 3:] = C + self.P[3:, 3:]
        odom.twist.covariance = twist_cov.ravel().tolist()
        return odom


def make(params):
    """Make the estimator of one run: the campaign's factory (params as keywords)."""
    return GyroIntegrator(**params)
