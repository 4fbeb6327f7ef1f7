"""rigidrot_demo_estimator: attitude estimators from the ahrs library, to score.

``--filter gyro`` (the default) is a gyro-only integrator; ``--filter madgwick``, ``mahony``
or ``ekf`` runs ahrs' Madgwick, Mahony or quaternion EKF on the node's ``imu`` (gyro and
accelerometer: start the node with ``accel.enable`` and a gravity, e.g.
``config/air_bearing.yaml``) and, with ``--mag``, its ``mag`` (see :class:`AhrsFilter` for
the conventions). Each filter starts from the first ``attitude`` fix, turned by
``--initial-error-deg`` (to watch it converge), and publishes its estimate at each imu
stamp, with the EKF's covariance (Madgwick and Mahony keep none: their rotation block is
zero, "unknown").

The gyro integrator subscribes to the node's ``imu`` (sensor_msgs/Imu) and integrates each
gyro sample with ``ahrs.filters.AngularRate`` (closed-form quaternion exponential; ahrs
orders its quaternions (w, x, y, z), converted here to ROS's (x, y, z, w)). Its state lives
on the gyro's time grid; it starts from the first ``attitude`` message stamped at or after
the first gyro sample it hears (a perfect initial fix, the only use of the truth besides its
stamps; from there on the gyro stream is whole), and propagates a 6-state error
covariance (attitude error e in B, with q_est = q_true * exp(e/2), and gyro bias):

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

__all__ = ['main', 'GyroIntegrator', 'AhrsFilter', 'FILTERS']

#: The ahrs filters besides the gyro integrator.
FILTERS = ('madgwick', 'mahony', 'ekf')
#: The node's default mag.field (T, in N): the magnetic reference unless --mag-field.
EARTH_FIELD = (0.0, 2.0e-5, -4.5e-5)

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


def _qmul(a, b):
    """Hamilton product of (w, x, y, z) quaternions."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def _rotz(angle):
    return np.array([np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)])


class AhrsFilter:
    """ahrs' Madgwick, Mahony or EKF on the node's imu (and mag), in N and (x, y, z, w).

    Conventions, read from ahrs 0.4's source and checked on static data: ahrs orders
    quaternions (w, x, y, z) and its ``q`` rotates sensor vectors into its Earth frame E
    (Hamilton, ``q' = q ⊗ (0, omega) / 2``), so it is ``q_EB``. All three compare the
    *normalised* accelerometer with E's +z, so fed the specific force (REP 145: +g up at
    rest) E's z is up, like N's (ENU, REP 103); they normalise the field too, so its unit
    does not matter (ahrs' docstrings say nT or uT; tesla is used unscaled). E's heading:
    Madgwick puts the field's horizontal part on E's x (``q_NE = Rz(psi)``, ``psi`` the
    field's heading in N), Mahony on E's y (``Rz(psi - 90 deg)``), the EKF (``frame='NED'``,
    which only sets its gravity reference to +z, and ``magnetic_ref`` = our field) on the
    field itself (E = N). Without the field E's heading is N's (the first fix sets it).

    Parameters
    ----------
    kind : {'madgwick', 'mahony', 'ekf'}
    q0_xyzw : array_like
        Initial ``q_NB``, (x, y, z, w).
    use_mag : bool
        Fuse the magnetometer (MARG) or not (IMU: gyro + accelerometer).
    field_n : 3 floats
        The magnetic field in N (any unit; its direction is used).
    """

    def __init__(self, kind, q0_xyzw, use_mag=False, field_n=EARTH_FIELD):
        import ahrs.filters as af
        self.kind, self.use_mag = kind, bool(use_mag)
        field = np.asarray(field_n, dtype=float)
        psi = float(np.arctan2(field[1], field[0]))
        turn = {'madgwick': psi, 'mahony': psi - np.pi / 2, 'ekf': 0.0}[kind]
        self.q_ne = _rotz(turn) if self.use_mag else np.array([1.0, 0.0, 0.0, 0.0])
        self._q_en = self.q_ne * np.array([1.0, -1.0, -1.0, -1.0])
        x, y, z, w = (float(v) for v in q0_xyzw)
        self.q_eb = _qmul(self._q_en, np.array([w, x, y, z]))
        if kind == 'madgwick':
            self._f = af.Madgwick()
            self._f.gain = self._f.gain_marg if self.use_mag else self._f.gain_imu
        elif kind == 'mahony':
            self._f = af.Mahony()
        elif kind == 'ekf':
            self._f = af.EKF(frame='NED', magnetic_ref=field / np.linalg.norm(field))
            self._f.mag = True if self.use_mag else None     # its h() asks self.mag
        else:
            raise ValueError(f'unknown filter {kind!r}: one of {FILTERS}')
        self.P = None

    @property
    def q_xyzw(self):
        """Current ``q_NB``, (x, y, z, w)."""
        w, x, y, z = _qmul(self.q_ne, self.q_eb)
        return np.array([x, y, z, w])

    def update(self, gyr, acc, mag, dt, var_gyr, var_acc, var_mag=None):
        """One sample: rate (rad/s), specific force (m/s^2), field (or None), in B; variances.

        The EKF takes its noises from the messages' covariances: the gyro's per-sample
        variance, and the accelerometer's and magnetometer's divided by the squared norm
        (it fuses unit vectors).
        """
        gyr, acc = np.asarray(gyr, dtype=float), np.asarray(acc, dtype=float)
        mag = None if (mag is None or not self.use_mag) else np.asarray(mag, dtype=float)
        f, q = self._f, self.q_eb
        if self.kind == 'ekf':
            a2 = float(acc @ acc) or 1.0
            vm = var_mag / float(mag @ mag) if mag is not None and var_mag else 1e-6
            f.noises = [var_gyr, var_acc / a2, vm]
            f.g_noise = var_gyr
            q_new = f.update(q, gyr, acc, mag, dt=dt)
            xi = np.array([[-q_new[1], -q_new[2], -q_new[3]], [q_new[0], -q_new[3], q_new[2]],
                           [q_new[3], q_new[0], -q_new[1]], [-q_new[2], q_new[1], q_new[0]]])
            p = 4.0 * xi.T @ f.P @ xi                 # body rotation-vector error, rad^2
            self.P = 0.5 * (p + p.T)
        elif mag is not None:
            q_new = f.updateMARG(q, gyr, acc, mag, dt=dt)
        else:
            q_new = f.updateIMU(q, gyr, acc, dt=dt)
        q_new = np.asarray(q_new, dtype=float)
        self.q_eb = q_new / np.linalg.norm(q_new)


def _turned(q_xyzw, degrees):
    """``q ⊗ exp(e / 2)``, e = ``degrees`` about (1, 1, 1)/sqrt(3) in B: a start error."""
    if not degrees:
        return np.asarray(q_xyzw, dtype=float)
    a = np.radians(degrees) / 2
    s = np.sin(a) / np.sqrt(3.0)
    x, y, z, w = q_xyzw
    qw, qx, qy, qz = _qmul([w, x, y, z], [np.cos(a), s, s, s])
    return np.array([qx, qy, qz, qw])


#: What ``--help`` says about the node's topics.
TOPICS = '''topics (relative names: -r __ns:=/sat1 moves them all):
  subscribes  attitude            geometry_msgs/msg/QuaternionStamped: the truth, at the
                                  start only (the gyro filter: the first stamped at or after
                                  the first gyro sample), and its stamps (gyro filter)
              imu                 sensor_msgs/msg/Imu: the gyro (and the accelerometer for
                                  madgwick, mahony, ekf)
              mag                 sensor_msgs/msg/MagneticField (--mag only)
  publishes   estimator/odom      nav_msgs/msg/Odometry: q_NB, the covariance of the body
                                  error in the rotation block of pose.covariance (zero,
                                  unknown, for madgwick and mahony)
              estimator/pose      geometry_msgs/msg/PoseWithCovarianceStamped: the same
              estimator/attitude  geometry_msgs/msg/QuaternionStamped: the same, no covariance
  all three reliable, transient-local, depth 1000; the gyro filter publishes at each
  attitude stamp, the others at each imu stamp

ROS arguments go after --ros-args (e.g. -r __ns:=/sat1).'''


def _parser():
    import argparse
    ap = OneLineParser(prog='rigidrot_demo_estimator', description=__doc__.splitlines()[0],
                       epilog=TOPICS, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--filter', choices=('gyro',) + FILTERS, default='gyro',
                    help='gyro: integrate the gyro alone (default); madgwick, mahony, ekf: '
                         "ahrs' filters on imu (gyro + accelerometer), with --mag also on mag")
    ap.add_argument('--mag', action='store_true',
                    help='fuse the magnetometer (sensor_msgs/MagneticField on mag)')
    ap.add_argument('--mag-field', type=float, nargs=3, default=list(EARTH_FIELD),
                    metavar=('X', 'Y', 'Z'),
                    help="the field in N, as the node's mag.field (only its direction is "
                         'used; default the node default)')
    ap.add_argument('--initial-error-deg', type=float, default=0.0,
                    help='start the ahrs filters this far (deg, about (1,1,1) in B) from the '
                         'first attitude fix, to watch them converge (default 0)')
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
    if opts.mag and opts.filter == 'gyro':
        return '--mag needs --filter madgwick, mahony or ekf (the gyro integrator has no mag)'
    if not (np.isfinite(opts.initial_error_deg) and 0 <= opts.initial_error_deg <= 180):
        return f'--initial-error-deg must be in [0, 180], got {opts.initial_error_deg!r}'
    field = np.asarray(opts.mag_field, dtype=float)
    if not (np.all(np.isfinite(field)) and np.linalg.norm(field[:2]) > 0):
        return f'--mag-field must be finite with a horizontal part, got {opts.mag_field}'
    return None


def main(argv=None):
    """Entry point of ``rigidrot_demo_estimator``; returns the exit status."""
    from rigidrot_ros.ros.spin import split_ros_args
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
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu

    from rigidrot_ros.ros.spin import init_ros, spin_until_shutdown

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
    if opts.filter in FILTERS:
        _wire_ahrs(node, opts, (pub_odom, pub_pose, pub_att))
        spin_until_shutdown(node, _spin_quietly_to_shutdown)
        return 0
    loop = _GyroLoop(node, opts, (pub_odom, pub_pose, pub_att))
    node.create_subscription(Imu, 'imu', loop.on_imu, 1000)
    node.create_subscription(QuaternionStamped, 'attitude', loop.on_attitude, 1000)
    spin_until_shutdown(node, _spin_quietly_to_shutdown)
    return 0


def _stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


class _GyroLoop:
    """The gyro integrator on the gyro's time grid, answering each attitude stamp.

    State: the filter (None until the start fixes it), the time (ns) of its
    state, the last gyro sample and its covariance, and the output stamps waiting for the
    gyro sample that covers them.
    """

    def __init__(self, node, opts, pubs):
        import rclpy
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
        self.node, self.opts, self.pubs = node, opts, pubs
        self._ros_ok, self._rcl_error = rclpy.ok, _rclpy.RCLError
        self.f, self.t, self.omega, self.cov = None, None, None, np.zeros(9)
        self.frame, self.body, self.pending = 'inertial', 'body', []
        self.early = {'imu': [], 'attitude': []}    # what came before the start

    def publish(self, header_stamp, t_ns):
        """Publish the estimate at ``t_ns`` from the state and the sample covering it."""
        q_xyzw, p = self.f.predicted(self.omega, self.cov, (t_ns - self.t) * 1e-9)
        msgs = _estimate_messages(
            header_stamp, self.frame, self.body, q_xyzw, p[:3, :3], self.omega,
            np.asarray(self.cov).reshape(3, 3) + p[3:, 3:])
        try:
            for pub, msg in zip(self.pubs, msgs):
                pub.publish(msg)
        except self._rcl_error:
            if self._ros_ok():
                raise               # a real failure; after a shutdown it is only the race

    def on_imu(self, msg):
        """Carry the state to the sample's stamp, publishing every output stamp on the way."""
        if self.f is None:
            self._hold('imu', msg)                  # not started yet
            return
        t_k = _stamp_ns(msg)
        if t_k <= self.t:
            return                                  # a repeated or out-of-order sample
        v = msg.angular_velocity
        # the sample is the mean rate over (t_k-1, t_k]: it carries the state to t_k, and
        # every output stamp on the way is published from it
        self.omega = np.array([v.x, v.y, v.z])
        self.cov = np.asarray(msg.angular_velocity_covariance, dtype=float)
        self.body = msg.header.frame_id or self.body
        self.pending.sort(key=lambda item: item[0])
        while self.pending and self.pending[0][0] <= t_k:
            t_out, header_stamp = self.pending.pop(0)
            self.publish(header_stamp, t_out)
        self.f.update(self.omega, self.cov, (t_k - self.t) * 1e-9)
        self.t = t_k

    def on_attitude(self, msg):
        """Queue (or, when late, answer) the attitude's stamp; before the start, hold it."""
        if self.f is None:
            self._hold('attitude', msg)
            return
        t = _stamp_ns(msg)
        if t <= self.t and self.omega is not None:
            self.publish(msg.header.stamp, t)       # late: back from the last sample
        elif t >= self.t:
            self.pending.append((t, msg.header.stamp))
            if len(self.pending) > 1000:
                del self.pending[0]
                self.node.get_logger().warning(
                    'no gyro sample on imu for 1000 attitudes: the oldest go unanswered',
                    throttle_duration_sec=5.0)

    def _hold(self, kind, msg):
        """Keep a message heard before the start; start once both streams allow it.

        The start is the first attitude stamped at or after the first gyro sample heard:
        from there on the gyro stream is whole. Started from an earlier attitude (one
        published before this process matched the gyro topic, say), the samples between
        would be missing and the first one heard held over all of them. Either stream may
        come first, in any interleaving (a replay can hand over every attitude before the
        first gyro sample): what is held is replayed in stamp order once started.
        """
        held = self.early[kind]
        held.append(msg)
        if len(held) > 1000:
            del held[0]
            if kind == 'attitude' and not self.early['imu']:
                self.node.get_logger().warning(
                    'no gyro sample on imu yet: start attitude_node with -p imu.enable:=true',
                    throttle_duration_sec=5.0)
        if not self.early['imu']:
            return
        first_gyro = min(_stamp_ns(m) for m in self.early['imu'])
        after = sorted((m for m in self.early['attitude'] if _stamp_ns(m) >= first_gyro),
                       key=_stamp_ns)
        if not after:
            return
        q, opts, t = after[0].quaternion, self.opts, _stamp_ns(after[0])
        self.f = GyroIntegrator((q.x, q.y, q.z, q.w), opts.initial_sigma,
                                opts.bias_sigma, opts.bias_random_walk)
        self.t = t
        self.frame = after[0].header.frame_id or 'inertial'
        self.node.get_logger().info(f'initialised from the attitude at stamp {t} ns')
        gyro = sorted(self.early['imu'], key=_stamp_ns)
        self.early = {'imu': [], 'attitude': []}
        for m in after:
            self.on_attitude(m)
        for m in gyro:
            self.on_imu(m)


def _estimate_messages(stamp, frame, body, q_xyzw, rot_cov, omega, rate_cov=None):
    """Odometry, PoseWithCovarianceStamped, QuaternionStamped of one estimate.

    ``rate_cov`` (3x3, (rad/s)^2) is the twist's covariance; None gives zeros.
    """
    from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped
    from nav_msgs.msg import Odometry
    odom = Odometry()
    odom.header.stamp = stamp
    odom.header.frame_id = frame
    odom.child_frame_id = body
    o = odom.pose.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in q_xyzw)
    odom.pose.covariance = _cov6(rot_cov)
    a = odom.twist.twist.angular
    a.x, a.y, a.z = (float(v) for v in omega)
    odom.twist.covariance = _cov6(np.zeros((3, 3)) if rate_cov is None else rate_cov)
    pose = PoseWithCovarianceStamped()
    pose.header = odom.header
    pose.pose = odom.pose
    att = QuaternionStamped()
    att.header = odom.header
    att.quaternion = odom.pose.pose.orientation
    return odom, pose, att


def _wire_ahrs(node, opts, pubs):
    """Subscribe an :class:`AhrsFilter` to imu (and mag); publish at each imu stamp."""
    from geometry_msgs.msg import QuaternionStamped
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
    import rclpy
    from sensor_msgs.msg import Imu, MagneticField

    st = {'f': None, 't': None, 'frame': 'inertial', 'mag': None, 'warned': False}

    def stamp_of(msg):
        return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec

    def on_attitude(msg):
        if st['f'] is not None:
            return
        q = msg.quaternion
        q0 = _turned((q.x, q.y, q.z, q.w), opts.initial_error_deg)
        st['f'] = AhrsFilter(opts.filter, q0, opts.mag, opts.mag_field)
        st['t'] = stamp_of(msg)
        st['frame'] = msg.header.frame_id or 'inertial'
        node.get_logger().info(f'initialised from the attitude at stamp {st["t"]} ns '
                               f'({opts.filter}{" + mag" if opts.mag else ""}, '
                               f'{opts.initial_error_deg:g} deg off)')

    def on_mag(msg):
        m = msg.magnetic_field
        st['mag'] = (np.array([m.x, m.y, m.z]), float(msg.magnetic_field_covariance[0]))

    def on_imu(msg):
        f = st['f']
        t_k = stamp_of(msg)
        if f is None or t_k <= st['t']:
            return
        if msg.linear_acceleration_covariance[0] == -1.0:
            if not st['warned']:
                st['warned'] = True
                node.get_logger().error('imu carries no accelerometer: start attitude_node '
                                        'with accel.enable and a gravity '
                                        '(config/air_bearing.yaml)')
            return
        if opts.mag and st['mag'] is None:
            return                                  # wait for the first field
        v, a = msg.angular_velocity, msg.linear_acceleration
        mag, var_mag = st['mag'] if opts.mag else (None, None)
        f.update([v.x, v.y, v.z], [a.x, a.y, a.z], mag, (t_k - st['t']) * 1e-9,
                 float(msg.angular_velocity_covariance[0]),
                 float(msg.linear_acceleration_covariance[0]), var_mag)
        st['t'] = t_k
        cov = f.P if f.P is not None else np.zeros((3, 3))
        out = _estimate_messages(msg.header.stamp, st['frame'], msg.header.frame_id or 'body',
                                 f.q_xyzw, cov, (v.x, v.y, v.z))
        try:
            for pub, m in zip(pubs, out):
                pub.publish(m)
        except _rclpy.RCLError:
            if rclpy.ok():
                raise

    node.create_subscription(QuaternionStamped, 'attitude', on_attitude, 1000)
    node.create_subscription(MagneticField, 'mag', on_mag, 1000)
    node.create_subscription(Imu, 'imu', on_imu, 1000)


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
