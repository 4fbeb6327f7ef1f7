"""A gyro integrator with an honest covariance, as a ROS 2 node (rclpy).

Run it:  python3 skeleton_node.py --ros-args -p use_sim_time:=true
Subscribes imu (sensor_msgs/Imu) and star_tracker (geometry_msgs/PoseWithCovarianceStamped);
publishes estimator/odom (nav_msgs/Odometry) at every gyro stamp; service ~/reset
(std_srvs/Trigger) starts over, for a campaign's long-lived estimator.
Quaternions are (x, y, z, w), q_NB (body to inertial); rates are in the body frame B.
"""

from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import Imu
from std_srvs.srv import Trigger


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


def stamp_ns(msg):
    """Return the header stamp in integer nanoseconds."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


class SkeletonNode(Node):
    """Integrate the gyro from the first star tracker fix; never correct.

    Error state (e, b): e the attitude error in B (q_est = q_true * exp(e / 2)), b the
    gyro bias it does not estimate; P <- F P F^T + Q per gyro sample, with
    F = [[R(-w dt), dt I], [0, I]], Q = [[C dt^2, 0], [0, bias_random_walk^2 dt I]] and
    C the sample's angular_velocity_covariance.
    """

    def __init__(self):
        super().__init__('skeleton')
        self.bias_sigma = self.declare_parameter('bias_sigma', 0.0).value
        self.bias_random_walk = self.declare_parameter('bias_random_walk', 0.0).value
        self.pub = self.create_publisher(Odometry, 'estimator/odom', 100)
        # star_tracker first: of two messages waiting, the executor takes the first
        # subscription's first, and the first fix (t = 0) must come before the gyro
        self.create_subscription(PoseWithCovarianceStamped, 'star_tracker',
                                 self.on_star, 100)
        self.create_subscription(Imu, 'imu', self.on_imu, 100)
        self.create_service(Trigger, '~/reset', self.on_reset)
        self.q = None       # q_NB, (x, y, z, w)
        self.t_ns = None    # time of the state
        self.P = None       # 6x6 covariance of (e, b)

    def on_reset(self, request, response):
        """Forget the run: the next star tracker fix starts a new one."""
        self.q = self.t_ns = self.P = None
        response.success = True
        return response

    def on_star(self, msg):
        """Start at the first fix: its attitude, its covariance, the bias prior."""
        if self.q is not None:
            return
        o = msg.pose.pose.orientation
        self.q = np.array([o.x, o.y, o.z, o.w])
        self.t_ns = stamp_ns(msg)
        self.P = np.zeros((6, 6))
        self.P[:3, :3] = np.reshape(msg.pose.covariance, (6, 6))[3:, 3:]
        self.P[3:, 3:] = self.bias_sigma ** 2 * np.eye(3)

    def on_imu(self, msg):
        """Integrate one gyro sample (the mean rate since the last one); publish."""
        t_ns = stamp_ns(msg)
        if self.q is None or t_ns <= self.t_ns:
            return
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
        Q[3:, 3:] = self.bias_random_walk ** 2 * dt * np.eye(3)
        self.P = F @ self.P @ F.T + Q
        self.t_ns = t_ns
        odom = Odometry()
        odom.header.stamp = msg.header.stamp     # the sensor's stamp: scored against it
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
        self.pub.publish(odom)


def main():
    """Spin the node until Ctrl-C (SIGINT) or SIGTERM."""
    rclpy.init()
    node = SkeletonNode()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    main()
