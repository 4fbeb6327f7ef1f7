"""Reference estimator: a multiplicative EKF with gyro bias (pure numpy, no rclpy needed).

Markley & Crassidis, *Fundamentals of Spacecraft Attitude Determination and Control*
(2014), §6.2.4 (the MEKF with a rate-integrating gyro); the same filter as Crassidis &
Junkins, *Optimal Estimation of Dynamic Systems*, table 7.1. Quaternions (x, y, z, w),
active, ``q_NB`` (``v_N = R_NB @ v_B``); rates of B relative to N, in B, rad/s.

State ``(q_NB, beta)``, error state ``x = (a, db)`` with ``q_true = q_est ⊗ exp(a / 2)``
(``a`` in B) and ``beta_true = beta + db``. Gyro model (the rate-integrating gyro the
project simulates): ``omega_meas = omega + beta + n_v``, ``beta' = n_u``, with spectral
densities ``sigma_v^2`` (rad^2/s) and ``sigma_u^2`` (rad^2/s^3).

Propagation over ``dt`` with ``w = omega_meas - beta``, ``x = |w|``, ``W = [w]x``::

    q <- q ⊗ exp(w dt / 2)
    Phi = [[Phi11, Phi12], [0, I]],
    Phi11 = I - W sin(x dt)/x + W^2 (1 - cos(x dt))/x^2            (= exp(-W dt))
    Phi12 = W (1 - cos(x dt))/x^2 - I dt - W^2 (x dt - sin(x dt))/x^3
    Q = [[(sigma_v^2 dt + sigma_u^2 dt^3 / 3) I, -(sigma_u^2 dt^2 / 2) I],
         [-(sigma_u^2 dt^2 / 2) I, sigma_u^2 dt I]]
    P <- Phi P Phi^T + Q                                   (Markley & Crassidis 6.83, 6.93)

Star tracker update at its stamp, measurement ``q_m = q_true ⊗ exp(v / 2)``, ``v ~ N(0,
R)`` in B (R from the message's orientation block): residual ``z = Log(q^-1 ⊗ q_m)``,
``H = [I 0]``, ``K = P H^T (H P H^T + R)^-1``, Joseph-form covariance, then the reset
``q <- q ⊗ exp(K z / 2)``, ``beta <- beta + (K z)_b``.

Time: a gyro sample stamped ``t_k`` is the mean rate over ``(t_{k-1}, t_k]``. A star
tracker sample stamped ``t_s`` waits for the gyro sample that covers it; the state is
propagated to ``t_s`` with it, updated, and propagated on to ``t_k``. Messages must come
in stamp order (as a campaign feeds them; a node sorts what the network delivers).

Outputs: ``nav_msgs/Odometry`` at every ``output_every``-th gyro stamp (after any star
tracker update at that stamp): orientation with the covariance of ``a`` in B in the
rotation block of ``pose.covariance`` (position marked unused, -1), and
``twist.angular = omega_meas - beta`` with ``P_bb + R_gyro`` in the rotation block of
``twist.covariance``. The scorer's NEES reads that block as the covariance of its body
error ``e`` (``q_true^-1 ⊗ q_est = exp(e / 2)``): ``e = -a`` to first order, same covariance.

The filter starts at the first star tracker sample: ``q = q_m``, ``P_aa = R``,
``beta = bias0``, ``P_bb = bias_sigma^2 I``; gyro samples before it are dropped.
"""

import math

import numpy as np

__all__ = ['MEKF', 'MekfParams', 'make', 'PARAMS']

#: Parameters of :func:`make`: name -> (default, meaning).
PARAMS = {
    'sigma_v': (None, "assumed gyro angle random walk, rad/s/sqrt(Hz) (the gyro's "
                      'noise density; required)'),
    'sigma_u': (0.0, 'assumed gyro rate random walk, rad/s^2/sqrt(Hz)'),
    'bias_sigma': (0.0, 'standard deviation of the initial bias per axis, rad/s'),
    'bias0': ([0.0, 0.0, 0.0], 'initial bias estimate, rad/s, in B'),
    'output_every': (10, 'publish an estimate at every n-th gyro sample'),
    'imu_topic': ('imu', 'topic name (last component) of sensor_msgs/Imu'),
    'star_tracker_topic': ('star_tracker', 'topic name (last component) of the star '
                                           'tracker PoseWithCovarianceStamped'),
    'frame_id': ('inertial', 'frame of the output orientation (N)'),
    'child_frame_id': ('body', 'body frame of the output (B)'),
}


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def _qexp(v):
    """Quaternion ``exp(v / 2)`` (x, y, z, w) of a rotation vector ``v``."""
    a = math.sqrt(float(v @ v))
    s = 0.5 - a * a / 48.0 if a < 1e-6 else math.sin(0.5 * a) / a
    return np.array([v[0] * s, v[1] * s, v[2] * s, math.cos(0.5 * a)])


def _qlog(q):
    """Rotation vector ``v`` with ``q = exp(v / 2)`` (shorter way round)."""
    if q[3] < 0:
        q = -q
    n = math.sqrt(float(q[:3] @ q[:3]))
    ang = 2.0 * math.atan2(n, float(q[3]))
    return q[:3] * (ang / n if n > 1e-12 else 2.0)


def _stamp_ns(msg):
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


class MekfParams:
    """Validated MEKF parameters (see :data:`PARAMS`); ValueError names a bad one."""

    def __init__(self, params=None):
        params = dict(params or {})
        unknown = sorted(set(params) - set(PARAMS))
        if unknown:
            raise ValueError(f'unknown MEKF parameter(s) {unknown}; known: {sorted(PARAMS)}')
        vals = {k: params.get(k, d) for k, (d, _) in PARAMS.items()}
        for name in ('sigma_v', 'sigma_u', 'bias_sigma'):
            v = vals[name]
            if v is None:
                raise ValueError(f'MEKF parameter {name} is required ({PARAMS[name][1]})')
            if isinstance(v, bool) or not isinstance(v, (int, float)) or \
                    not (math.isfinite(v) and 0 <= v <= 10):
                raise ValueError(f'MEKF parameter {name} must be a number in [0, 10], '
                                 f'got {v!r}')
            setattr(self, name, float(v))
        b = vals['bias0']
        try:
            b = np.array(b, dtype=float).reshape(3)
        except (TypeError, ValueError):
            raise ValueError(f'MEKF parameter bias0 must be 3 numbers, got {b!r}') from None
        if not np.all(np.isfinite(b)) or np.any(np.abs(b) > 10):
            raise ValueError(f'MEKF parameter bias0 must be 3 finite numbers within 10 rad/s, '
                             f'got {b.tolist()}')
        self.bias0 = b
        n = vals['output_every']
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 1_000_000:
            raise ValueError(f'MEKF parameter output_every must be an integer >= 1, got {n!r}')
        self.output_every = n
        for name in ('imu_topic', 'star_tracker_topic', 'frame_id', 'child_frame_id'):
            if not isinstance(vals[name], str) or not vals[name]:
                raise ValueError(f'MEKF parameter {name} must be a non-empty string')
            setattr(self, name, vals[name])

    def as_dict(self):
        """Return the parameters as plain values."""
        return {'sigma_v': self.sigma_v, 'sigma_u': self.sigma_u,
                'bias_sigma': self.bias_sigma, 'bias0': self.bias0.tolist(),
                'output_every': self.output_every, 'imu_topic': self.imu_topic,
                'star_tracker_topic': self.star_tracker_topic, 'frame_id': self.frame_id,
                'child_frame_id': self.child_frame_id}


class MEKF:
    """The multiplicative EKF fed with ROS messages in stamp order.

    Parameters
    ----------
    params : dict or MekfParams
        See :data:`PARAMS`.

    Notes
    -----
    :meth:`receive` takes ``(topic, msg)`` and returns the estimate messages that became
    final with it (an estimate at stamp ``t`` is final once a message with a later stamp
    has come, so that a star tracker sample at ``t`` is in it whichever of the two came
    first); :meth:`finish` returns the last ones. The in-process campaign API.
    """

    def __init__(self, params=None):
        self.p = params if isinstance(params, MekfParams) else MekfParams(params)
        self.q = None                    # q_NB (x, y, z, w)
        self.beta = self.p.bias0.copy()
        self.P = None
        self.t_ns = None                 # time of the state
        self.omega = None                # last gyro sample, rad/s
        self.gyro_var = np.zeros((3, 3))
        self.pending_star = []           # (t_ns, q_m, R) waiting for a covering gyro sample
        self._due = None                 # (t_ns, stamp msg) of an estimate not yet final
        self._gyro_count = 0
        self.updates = 0
        self.rejected = 0

    # -- the filter --------------------------------------------------------------------
    def _propagate(self, dt):
        if dt <= 0:
            return
        w = self.omega - self.beta
        x = math.sqrt(float(w @ w))
        W = _skew(w)
        W2 = W @ W
        if x * dt < 1e-5:           # series of the coefficients below
            s1, s2, s3 = dt, dt * dt / 2, dt ** 3 / 6
        else:
            s1 = math.sin(x * dt) / x
            s2 = (1 - math.cos(x * dt)) / (x * x)
            s3 = (x * dt - math.sin(x * dt)) / x ** 3
        phi = np.eye(6)
        phi[:3, :3] = np.eye(3) - W * s1 + W2 * s2
        phi[:3, 3:] = W * s2 - np.eye(3) * dt - W2 * s3
        su2, sv2 = self.p.sigma_u ** 2, self.p.sigma_v ** 2
        q = np.zeros((6, 6))
        q[:3, :3] = (sv2 * dt + su2 * dt ** 3 / 3) * np.eye(3)
        q[:3, 3:] = q[3:, :3] = -(su2 * dt * dt / 2) * np.eye(3)
        q[3:, 3:] = su2 * dt * np.eye(3)
        P = phi @ self.P @ phi.T + q
        self.P = 0.5 * (P + P.T)
        self.q = _qmul(self.q, _qexp(w * dt))
        self.q /= np.linalg.norm(self.q)

    def _update(self, q_m, R):
        z = _qlog(_qmul(np.array([-self.q[0], -self.q[1], -self.q[2], self.q[3]]), q_m))
        S = self.P[:3, :3] + R
        K = np.linalg.solve(S, self.P[:3, :]).T          # P H^T S^-1, S symmetric
        dx = K @ z
        IKH = np.eye(6)
        IKH[:, :3] -= K
        P = IKH @ self.P @ IKH.T + K @ R @ K.T
        self.P = 0.5 * (P + P.T)
        self.q = _qmul(self.q, _qexp(dx[:3]))
        self.q /= np.linalg.norm(self.q)
        self.beta = self.beta + dx[3:]
        self.updates += 1

    # -- messages ----------------------------------------------------------------------
    def receive(self, topic, msg):
        """Take one sensor message; return the estimate messages final by now (list)."""
        name = topic.rsplit('/', 1)[-1]
        if name == self.p.imu_topic:
            return self._on_imu(msg)
        if name == self.p.star_tracker_topic:
            return self._on_star(msg)
        return []

    def finish(self):
        """Return the estimates still waiting (at the end of the input)."""
        out = self._flush(None)
        return out

    def _flush(self, t_ns):
        """Publish the due estimate if a message later than it has come (or at the end)."""
        if self._due is not None and (t_ns is None or t_ns > self._due[0]):
            msg = self._odometry(self._due[1])
            self._due = None
            return [msg]
        return []

    def _on_star(self, msg):
        t = _stamp_ns(msg)
        out = self._flush(t)
        o = msg.pose.pose.orientation
        q_m = np.array([o.x, o.y, o.z, o.w], dtype=float)
        R = np.asarray(msg.pose.covariance, dtype=float).reshape(6, 6)[3:, 3:]
        if not (np.all(np.isfinite(q_m)) and abs(np.linalg.norm(q_m) - 1) < 1e-6
                and np.all(np.isfinite(R)) and np.all(np.linalg.eigvalsh(0.5 * (R + R.T)) > 0)):
            self.rejected += 1
            return out
        if self.q is None:
            self.q = q_m / np.linalg.norm(q_m)
            self.P = np.zeros((6, 6))
            self.P[:3, :3] = R
            self.P[3:, 3:] = self.p.bias_sigma ** 2 * np.eye(3)
            self.t_ns = t
            return out
        if t == self.t_ns:
            self._update(q_m, R)
        elif t > self.t_ns:
            self.pending_star.append((t, q_m, R))
        else:
            self.rejected += 1           # older than the state: not in stamp order
        return out

    def _on_imu(self, msg):
        t = _stamp_ns(msg)
        out = self._flush(t)
        if self.q is None or t <= self.t_ns:
            return out
        v = msg.angular_velocity
        omega = np.array([v.x, v.y, v.z], dtype=float)
        if not np.all(np.isfinite(omega)):
            self.rejected += 1
            return out
        self.omega = omega
        self.gyro_var = np.asarray(msg.angular_velocity_covariance, dtype=float).reshape(3, 3)
        self.pending_star.sort(key=lambda s: s[0])
        while self.pending_star and self.pending_star[0][0] <= t:
            ts, q_m, R = self.pending_star.pop(0)
            self._propagate((ts - self.t_ns) * 1e-9)
            self.t_ns = ts
            self._update(q_m, R)
        self._propagate((t - self.t_ns) * 1e-9)
        self.t_ns = t
        self._gyro_count += 1
        if self._gyro_count % self.p.output_every == 0:
            self._due = (t, msg.header.stamp)
        return out

    def _odometry(self, stamp):
        from nav_msgs.msg import Odometry
        odom = Odometry()
        odom.header.stamp = stamp
        odom.header.frame_id = self.p.frame_id
        odom.child_frame_id = self.p.child_frame_id
        o = odom.pose.pose.orientation
        o.x, o.y, o.z, o.w = (float(v) for v in self.q)
        odom.pose.covariance = _cov6(self.P[:3, :3])
        w = self.omega - self.beta
        a = odom.twist.twist.angular
        a.x, a.y, a.z = (float(v) for v in w)
        odom.twist.covariance = _cov6(self.P[3:, 3:] + self.gyro_var)
        return odom


def _cov6(block):
    c = np.zeros((6, 6))
    c[0, 0] = c[1, 1] = c[2, 2] = -1.0
    c[3:, 3:] = block
    return [float(v) for v in c.ravel()]


def make(params=None):
    """Campaign factory (``rigidrot_ros.estimators.mekf:make``): a new :class:`MEKF`."""
    return MEKF(params)
