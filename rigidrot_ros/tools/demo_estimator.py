"""rigidrot_demo_estimator: a gyro-only attitude estimator from the ahrs library, to score.

It subscribes to the node's ``imu`` (sensor_msgs/Imu) and integrates each gyro sample
with ``ahrs.filters.AngularRate`` (closed-form quaternion exponential; ahrs orders its
quaternions (w, x, y, z), converted here to ROS's (x, y, z, w)). Its state lives on the
gyro's time grid; it starts from the first ``attitude`` message it hears (a perfect
initial fix, the only use of the truth besides its stamps), and propagates a 6-state
error covariance (attitude error e in B, with q_est = q_true * exp(e/2), and gyro bias):

    Phi = [[exp(-[omega dt]x), -dt I], [0, I]],
    Q = [[C dt^2, 0], [0, sigma_u^2 dt I]],  P <- Phi P Phi^T + Q,

with C the imu's angular_velocity_covariance (the per-sample white-noise variance) and
sigma_u the assumed bias random walk; the bias block starts at bias_sigma^2. It publishes
at the stamp of each ``attitude`` tick of the node (so its output pairs exactly with the
truth's ``odom`` stamps in evo), as soon as the gyro sample covering that time has come,
propagated from its state with that sample:
``estimator/odom`` (nav_msgs/Odometry: orientation, its covariance in the rotation block,
position block marked unused with -1, twist.angular = the last gyro rate),
``estimator/pose`` (PoseWithCovarianceStamped) and ``estimator/attitude``
(QuaternionStamped), all reliable and transient-local (depth 1000), so a recorder that
joins late still gets the start-up transient. Without a bias model it is over-confident
as soon as the gyro has a bias: that is what NEES shows.
"""

import sys

import numpy as np

from rigidrot_ros.tools.cli import OneLineParser

__all__ = ['main', 'GyroIntegrator']

_INSTALL = ('rigidrot_demo_estimator: needs the ahrs package: pip install ahrs '
            '(or pip install "rigidrot_ros[estimator]")')


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _rot(v):
    """Rotation matrix exp([v]x) (Rodrigues)."""
    a = float(np.linalg.norm(v))
    k = _skew(v)
    if a < 1e-8:
        return np.eye(3) + k + 0.5 * k @ k
    return np.eye(3) + np.sin(a) / a * k + (1 - np.cos(a)) / a ** 2 * k @ k


class GyroIntegrator:
    """Attitude from gyro samples by ahrs' AngularRate, with an error covariance.

    Parameters
    ----------
    q0_xyzw : array_like
        Initial attitude q_NB, (x, y, z, w).
    initial_sigma : float
        Initial attitude standard deviation per axis, rad.
    bias_sigma : float
        Standard deviation of an unknown constant gyro bias per axis, rad/s.
    bias_random_walk : float
        Assumed gyro rate random walk, rad/s^2/sqrt(Hz).
    """

    def __init__(self, q0_xyzw, initial_sigma=1e-6, bias_sigma=0.0, bias_random_walk=0.0):
        from ahrs.filters import AngularRate
        self._ahrs = AngularRate()
        x, y, z, w = (float(v) for v in q0_xyzw)
        self.q_wxyz = np.array([w, x, y, z])
        self.P = np.diag([initial_sigma ** 2] * 3 + [bias_sigma ** 2] * 3)
        self._sigma_u2 = bias_random_walk ** 2

    @property
    def q_xyzw(self):
        """Current attitude q_NB, (x, y, z, w)."""
        w, x, y, z = self.q_wxyz
        return np.array([x, y, z, w])

    def update(self, omega_b, cov_omega, dt):
        """Integrate one gyro sample ``omega_b`` (rad/s, in B) held over ``dt`` seconds."""
        self.q_wxyz, self.P = self._step(omega_b, cov_omega, dt)

    def predicted(self, omega_b, cov_omega, dt):
        """``(q_xyzw, P)`` after ``dt`` seconds (may be negative) at ``omega_b``; no update."""
        q_wxyz, p = self._step(omega_b, cov_omega, dt)
        w, x, y, z = q_wxyz
        return np.array([x, y, z, w]), p

    def _step(self, omega_b, cov_omega, dt):
        omega_b = np.asarray(omega_b, dtype=float)
        q_new = np.asarray(self._ahrs.update(self.q_wxyz, omega_b, method='closed', dt=dt),
                           dtype=float)
        phi = np.eye(6)
        phi[:3, :3] = _rot(-omega_b * dt)
        phi[:3, 3:] = -dt * np.eye(3)
        q = np.zeros((6, 6))
        q[:3, :3] = np.asarray(cov_omega, dtype=float).reshape(3, 3) * dt * dt
        q[3:, 3:] = self._sigma_u2 * abs(dt) * np.eye(3)
        p = phi @ self.P @ phi.T + q
        return q_new, 0.5 * (p + p.T)


def _parser():
    ap = OneLineParser(prog='rigidrot_demo_estimator', description=__doc__.splitlines()[0],
                       epilog='ROS arguments go after --ros-args (e.g. -r __ns:=/sat1).')
    ap.add_argument('--initial-sigma', type=float, default=1e-6,
                    help='initial attitude standard deviation per axis, rad (default 1e-6)')
    ap.add_argument('--bias-sigma', type=float, default=0.0,
                    help='assumed standard deviation of a constant gyro bias, rad/s '
                         '(default 0: the filter believes the gyro unbiased)')
    ap.add_argument('--bias-random-walk', type=float, default=0.0,
                    help='assumed gyro rate random walk, rad/s^2/sqrt(Hz) (default 0)')
    return ap


def _check(opts):
    for name in ('initial_sigma', 'bias_sigma', 'bias_random_walk'):
        v = getattr(opts, name)
        if not (np.isfinite(v) and 0 <= v <= 1e3):
            return f'--{name.replace("_", "-")} must be a finite number in [0, 1e3], got {v!r}'
    if opts.initial_sigma <= 0:
        return '--initial-sigma must be positive (the covariance must stay invertible)'
    return None


def main(argv=None):
    """Entry point of ``rigidrot_demo_estimator``; returns the exit status."""
    from rigidrot_ros.node.spin import split_ros_args
    argv, ros_args = split_ros_args(sys.argv[1:] if argv is None else list(argv))
    opts = _parser().parse_args(argv)
    problem = _check(opts)
    if problem:
        print(f'rigidrot_demo_estimator: {problem}', file=sys.stderr)
        return 2
    try:
        import ahrs  # noqa: F401
    except ImportError:
        print(_INSTALL, file=sys.stderr)
        return 2
    try:
        return _run(opts, ros_args)
    except KeyboardInterrupt:      # Ctrl-C while starting, before rclpy's handler is in
        return 0


def _run(opts, ros_args):
    from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped
    from nav_msgs.msg import Odometry
    import rclpy
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu

    from rigidrot_ros.node.spin import init_ros, spin_until_shutdown

    reason = init_ros('rigidrot_demo_estimator', ros_args)
    if reason is not None:
        print(f'rigidrot_demo_estimator: {reason}', file=sys.stderr)
        return 2
    node = rclpy.create_node('demo_estimator')
    out_qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub_odom = node.create_publisher(Odometry, 'estimator/odom', out_qos)
    pub_pose = node.create_publisher(PoseWithCovarianceStamped, 'estimator/pose', out_qos)
    pub_att = node.create_publisher(QuaternionStamped, 'estimator/attitude', out_qos)
    # state on the gyro's time grid: f (filter), t (ns) of its state, the last gyro
    # sample, and the output stamps waiting for the gyro sample that covers them
    st = {'f': None, 't': None, 'frame': 'inertial', 'body': 'body', 'omega': None,
          'cov': np.zeros(9), 'pending': []}

    def stamp_of(msg):
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    def publish(header_stamp, t_ns):
        """Publish the estimate at ``t_ns`` from the state and the sample covering it."""
        f = st['f']
        q_xyzw, p = f.predicted(st['omega'], st['cov'], (t_ns - st['t']) * 1e-9)
        x, y, z, w = (float(v) for v in q_xyzw)
        odom = Odometry()
        odom.header.stamp = header_stamp
        odom.header.frame_id = st['frame']
        odom.child_frame_id = st['body']
        o = odom.pose.pose.orientation
        o.x, o.y, o.z, o.w = x, y, z, w
        odom.pose.covariance = _cov6(p[:3, :3])
        odom.twist.twist.angular.x, odom.twist.twist.angular.y, odom.twist.twist.angular.z = (
            float(v) for v in st['omega'])
        odom.twist.covariance = _cov6(np.asarray(st['cov']).reshape(3, 3) + p[3:, 3:])
        pose = PoseWithCovarianceStamped()
        pose.header = odom.header
        pose.pose = odom.pose
        att = QuaternionStamped()
        att.header = odom.header
        att.quaternion = odom.pose.pose.orientation
        try:
            pub_odom.publish(odom)
            pub_pose.publish(pose)
            pub_att.publish(att)
        except _rclpy.RCLError:
            if rclpy.ok():
                raise               # a real failure; after a shutdown it is only the race

    def on_imu(msg):
        if st['f'] is None:
            return                                  # not initialised yet (no fix)
        t_k = stamp_of(msg)
        if t_k <= st['t']:
            return                                  # a repeated or out-of-order sample
        v = msg.angular_velocity
        # the sample is the mean rate over (t_k-1, t_k]: it carries the state to t_k, and
        # every output stamp on the way is published from it
        st['omega'] = np.array([v.x, v.y, v.z])
        st['cov'] = np.asarray(msg.angular_velocity_covariance, dtype=float)
        st['body'] = msg.header.frame_id or st['body']
        st['pending'].sort(key=lambda item: item[0])
        while st['pending'] and st['pending'][0][0] <= t_k:
            t_out, header_stamp = st['pending'].pop(0)
            publish(header_stamp, t_out)
        st['f'].update(st['omega'], st['cov'], (t_k - st['t']) * 1e-9)
        st['t'] = t_k

    def on_attitude(msg):
        t = stamp_of(msg)
        if st['f'] is None:
            q = msg.quaternion
            st['f'] = GyroIntegrator((q.x, q.y, q.z, q.w), opts.initial_sigma,
                                     opts.bias_sigma, opts.bias_random_walk)
            st['t'] = t
            st['frame'] = msg.header.frame_id or 'inertial'
            node.get_logger().info(f'initialised from the attitude at stamp {t} ns')
        if t < st['t'] and st['omega'] is not None:
            publish(msg.header.stamp, t)            # late: back from the last sample
        elif t >= st['t']:
            st['pending'].append((t, msg.header.stamp))
            if len(st['pending']) > 1000:
                del st['pending'][0]
                node.get_logger().warning(
                    'no gyro sample on imu yet: start attitude_node with -p imu.enable:=true',
                    throttle_duration_sec=5.0)

    node.create_subscription(Imu, 'imu', on_imu, 1000)
    node.create_subscription(QuaternionStamped, 'attitude', on_attitude, 1000)
    spin_until_shutdown(node, _spin_quietly_to_shutdown)
    return 0


def _spin_quietly_to_shutdown(node):
    """Spin; an rclpy error raised while SIGINT/SIGTERM shuts the context down ends it."""
    import rclpy
    while rclpy.ok():
        try:
            rclpy.spin_once(node, timeout_sec=0.1)
        except Exception:  # noqa: B902 - a take racing the shutdown (rclpy raises several)
            if rclpy.ok():
                raise
            return


def _cov6(rot_block):
    """Row-major 6x6 covariance: position block marked unused (-1 diagonal), then rotation."""
    c = np.zeros((6, 6))
    c[0, 0] = c[1, 1] = c[2, 2] = -1.0
    c[3:, 3:] = rot_block
    return [float(v) for v in c.ravel()]


if __name__ == '__main__':
    sys.exit(main())
