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


_I3 = np.eye(3)
_I6 = np.eye(6)


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


def _finite(*values):
    return all(math.isfinite(v) for v in values)


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
    :meth:`receive_arrays` takes a whole run as arrays instead and returns the same
    estimates as arrays, bit for bit (the same operations on the same values, without
    building a message), compiled where it can be
    (:mod:`rigidrot_ros.estimators.mekf_kernel`: about 30 times faster, the same bits).
    """

    #: The type of the estimates (:meth:`receive_arrays` says it too).
    output_type = 'nav_msgs/msg/Odometry'

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
        self._sink = None                # receive_arrays: where the estimates go
        self._phi = _I6.copy()           # Phi's buffer: its lower rows [0 I] never change
        self._noise = {}                 # Q by dt (the same dt gives the same Q)
        self._var = {}                   # the gyro covariance matrix by its variance
        self._checked = {}               # star tracker covariances checked, by their bytes

    # -- the filter --------------------------------------------------------------------
    def _q_noise(self, dt):
        q = self._noise.get(dt)
        if q is None:
            su2, sv2 = self.p.sigma_u ** 2, self.p.sigma_v ** 2
            q = np.zeros((6, 6))
            q[:3, :3] = (sv2 * dt + su2 * dt ** 3 / 3) * _I3
            q[:3, 3:] = q[3:, :3] = -(su2 * dt * dt / 2) * _I3
            q[3:, 3:] = su2 * dt * _I3
            if len(self._noise) < 64:
                self._noise[dt] = q
        return q

    def _propagate(self, dt):
        # The operations of the module text, element by element where they are elementwise
        # (the same IEEE operations on the same values as the matrix expressions), with
        # BLAS for every product that sums, as ``@`` calls it (``np.dot`` of 1-D and 2-D
        # float arrays makes the same ddot and dgemm calls): the numbers do not change.
        if dt <= 0:
            return
        dot = np.dot
        w = self.omega - self.beta
        x = math.sqrt(float(dot(w, w)))
        w0, w1, w2 = w.tolist()
        n0, n1, n2 = -w0, -w1, -w2
        W = np.array(((0.0, n2, w1), (w2, 0.0, n0), (n1, w0, 0.0)))
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = dot(W, W).tolist()
        if x * dt < 1e-5:           # series of the coefficients below
            s1, s2, s3 = dt, dt * dt / 2, dt ** 3 / 6
        else:
            s1 = math.sin(x * dt) / x
            s2 = (1 - math.cos(x * dt)) / (x * x)
            s3 = (x * dt - math.sin(x * dt)) / x ** 3
        # Phi11 = I - W s1 + W^2 s2, Phi12 = W s2 - I dt - W^2 s3, every element written
        # out with its zeros (the same operations as the matrix expressions, signed zeros
        # included)
        phi = self._phi
        phi[:3] = (
            (1.0 - 0.0 * s1 + a0 * s2,
             0.0 - n2 * s1 + a1 * s2,
             0.0 - w1 * s1 + a2 * s2,
             0.0 * s2 - 1.0 * dt - a0 * s3,
             n2 * s2 - 0.0 * dt - a1 * s3,
             w1 * s2 - 0.0 * dt - a2 * s3),
            (0.0 - w2 * s1 + b0 * s2,
             1.0 - 0.0 * s1 + b1 * s2,
             0.0 - n0 * s1 + b2 * s2,
             w2 * s2 - 0.0 * dt - b0 * s3,
             0.0 * s2 - 1.0 * dt - b1 * s3,
             n0 * s2 - 0.0 * dt - b2 * s3),
            (0.0 - n1 * s1 + c0 * s2,
             0.0 - w0 * s1 + c1 * s2,
             1.0 - 0.0 * s1 + c2 * s2,
             n1 * s2 - 0.0 * dt - c0 * s3,
             w0 * s2 - 0.0 * dt - c1 * s3,
             0.0 * s2 - 1.0 * dt - c2 * s3))
        P = dot(dot(phi, self.P), phi.T)
        P += self._q_noise(dt)
        P = P + P.T
        P *= 0.5
        self.P = P
        v = w * dt
        a = math.sqrt(float(dot(v, v)))              # _qexp(v), as floats
        s = 0.5 - a * a / 48.0 if a < 1e-6 else math.sin(0.5 * a) / a
        vx, vy, vz = v.tolist()
        q = np.array(_qmul(self.q.tolist(), (vx * s, vy * s, vz * s, math.cos(0.5 * a))))
        q /= math.sqrt(float(dot(q, q)))             # np.linalg.norm(q)
        self.q = q

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
            v = msg.angular_velocity
            return self._on_imu(_stamp_ns(msg), v.x, v.y, v.z,
                                msg.angular_velocity_covariance, msg.header.stamp)
        if name == self.p.star_tracker_topic:
            o = msg.pose.pose.orientation
            return self._on_star(_stamp_ns(msg), (o.x, o.y, o.z, o.w), msg.pose.covariance)
        return []

    def finish(self):
        """Return the estimates still waiting (at the end of the input)."""
        out = self._flush(None)
        return out

    def _flush(self, t_ns):
        """Publish the due estimate if a message later than it has come (or at the end)."""
        if self._due is not None and (t_ns is None or t_ns > self._due[0]):
            due, self._due = self._due, None
            if self._sink is not None:
                self._sink.append((due[0], self.q.copy(), self.P.copy(), self.omega - self.beta,
                                   self.gyro_var))
                return []
            return [self._odometry(due[1])]
        return []

    def _on_star(self, t, q_m, cov6):
        out = self._flush(t)
        q_m = np.array(q_m, dtype=float)
        R = np.asarray(cov6, dtype=float).reshape(6, 6)[3:, 3:]
        if not self._takes_star(q_m, R):
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

    def _takes_star(self, q_m, R):
        """Whether a star tracker sample is taken: ``q_m`` finite and unit, ``R`` usable."""
        return (_finite(*q_m.tolist()) and abs(math.sqrt(float(q_m.dot(q_m))) - 1) < 1e-6
                and self._usable(R))

    def _usable(self, R):
        """Whether ``R`` is finite and positive definite (the answer kept by its bytes)."""
        key = R.tobytes()
        ok = self._checked.get(key)
        if ok is None:
            ok = bool(np.all(np.isfinite(R)) and np.all(np.linalg.eigvalsh(0.5 * (R + R.T)) > 0))
            if len(self._checked) < 64:
                self._checked[key] = ok
        return ok

    def _on_imu(self, t, wx, wy, wz, cov9, stamp):
        out = self._flush(t)
        if self.q is None or t <= self.t_ns:
            return out
        if not _finite(wx, wy, wz):
            self.rejected += 1
            return out
        self.omega = np.array([wx, wy, wz], dtype=float)
        self.gyro_var = np.asarray(cov9, dtype=float).reshape(3, 3)
        self._advance(t)
        if self._gyro_count % self.p.output_every == 0:
            self._due = (t, stamp)
        return out

    def _advance(self, t):
        """Take the star tracker samples up to ``t``, propagate to ``t``; count the sample."""
        if self.pending_star:
            self.pending_star.sort(key=lambda s: s[0])
            while self.pending_star and self.pending_star[0][0] <= t:
                ts, q_m, R = self.pending_star.pop(0)
                self._propagate((ts - self.t_ns) * 1e-9)
                self.t_ns = ts
                self._update(q_m, R)
        self._propagate((t - self.t_ns) * 1e-9)
        self.t_ns = t
        self._gyro_count += 1

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

    # -- arrays ------------------------------------------------------------------------
    def warm(self):
        """Load the compiled filter of :meth:`receive_arrays` now; whether it is used.

        A campaign calls it once in its client, before its workers fork, so that they
        start with it loaded.
        """
        from rigidrot_ros.estimators import mekf_kernel
        return mekf_kernel.available(_self_check)

    def receive_arrays(self, arrays, order, compiled=None):
        """Take a whole run as arrays; return all its estimates as arrays.

        The estimates the messages of :meth:`receive` and :meth:`finish` would carry, fed
        the same samples in the same order, bit for bit (the last ones included: no
        :meth:`finish` after it).

        Parameters
        ----------
        arrays : dict
            By topic, the columns of :func:`rigidrot_ros.run.generate.run_arrays`: the
            imu's ``stamps_ns``, ``w`` (rad/s, in B) and ``var`` (its per-axis variance,
            the diagonal of ``angular_velocity_covariance``); the star tracker's
            ``stamps_ns``, ``q`` (x, y, z, w) ``q_NB`` and ``cov`` (the rotation block of
            its covariance). Other topics are ignored.
        order : iterable of (topic, row)
            The samples in the order they arrive.
        compiled : bool, optional
            Run the loop compiled (:mod:`rigidrot_ros.estimators.mekf_kernel`: the same
            operations, bit for bit) or interpreted; default: compiled where it is
            available.

        Returns
        -------
        dict
            ``type`` (nav_msgs/msg/Odometry), ``frame_id``, ``stamps_ns`` (n,) int64,
            ``orientation`` (n, 4) q_NB (x, y, z, w), ``orientation_cov`` (n, 3, 3) of the
            error in B, ``angular_velocity`` (n, 3) rad/s in B, ``angular_velocity_cov``
            (n, 3, 3).
        """
        imu = star = None
        for topic, cols in arrays.items():
            name = topic.rsplit('/', 1)[-1] if isinstance(topic, str) else None
            if name == self.p.imu_topic:
                imu = topic, cols
            elif name == self.p.star_tracker_topic:
                star = topic, cols
        from rigidrot_ros.estimators import mekf_kernel
        ready = mekf_kernel.available(_self_check)
        if compiled is None:
            compiled = ready and self.q is None
        if compiled:
            if self.q is not None:
                raise ValueError('receive_arrays(compiled=True) takes a fresh filter')
            t, q, P, w, gv = mekf_kernel.run(self, mekf_kernel.RunArrays(imu, star, order))
            return self._arrays_out(t, q, P[:, :3, :3], w, P[:, 3:, 3:] + gv)
        if imu is not None:
            cols = imu[1]
            imu = imu[0], cols['stamps_ns'].tolist(), cols['w'].tolist(), cols['var'].tolist()
        if star is not None:
            cols = star[1]
            cov6 = np.zeros((len(cols['cov']), 6, 6))
            cov6[:, 3:, 3:] = cols['cov']
            star = star[0], cols['stamps_ns'].tolist(), cols['q'].tolist(), cov6
        self._sink = sink = []
        try:
            for topic, k in order:
                if imu is not None and topic == imu[0]:
                    self._on_imu(imu[1][k], *imu[2][k], self._cov9(imu[3][k]), None)
                elif star is not None and topic == star[0]:
                    self._on_star(star[1][k], star[2][k], star[3][k])
            self._flush(None)
        finally:
            self._sink = None
        n = len(sink)
        return self._arrays_out(
            np.array([s[0] for s in sink], dtype=np.int64),
            np.array([s[1] for s in sink]).reshape(n, 4),
            np.array([s[2][:3, :3] for s in sink]).reshape(n, 3, 3),
            np.array([s[3] for s in sink]).reshape(n, 3),
            np.array([s[2][3:, 3:] + s[4] for s in sink]).reshape(n, 3, 3))

    def _arrays_out(self, stamps, q, q_cov, w, w_cov):
        return {'type': self.output_type, 'frame_id': self.p.frame_id, 'stamps_ns': stamps,
                'orientation': q, 'orientation_cov': q_cov, 'angular_velocity': w,
                'angular_velocity_cov': w_cov}

    def _cov9(self, v):
        """Return the gyro covariance a message of variance ``v`` carries (the node's)."""
        c = self._var.get(v)
        if c is None:
            c = np.array([v, 0.0, 0.0, 0.0, v, 0.0, 0.0, 0.0, v])
            if len(self._var) < 64 and v == v:
                self._var[v] = c
        return c


def _cov6(block):
    c = np.zeros((6, 6))
    c[0, 0] = c[1, 1] = c[2, 2] = -1.0
    c[3:, 3:] = block
    return [float(v) for v in c.ravel()]


def _self_check():
    """Run the compiled and interpreted filters on a synthetic run; what differs, or ''.

    The check :func:`rigidrot_ros.estimators.mekf_kernel.available` makes on load.
    """
    rng = np.random.default_rng(7)
    n, m = 120, 13
    imu_t = np.arange(1, n + 1, dtype=np.int64) * 10_000_000 + rng.integers(0, 3000, n)
    star_t = np.arange(m, dtype=np.int64) * 95_000_000 + 1_000_000
    star_t[5] = imu_t[50]                         # a star sample at a gyro stamp
    q = rng.standard_normal((m, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    cov = np.tile(np.diag([1e-8, 2e-8, 3e-7]), (m, 1, 1))
    imu = {'stamps_ns': imu_t, 'w': 0.3 * rng.standard_normal((n, 3)),
           'var': np.full(n, 2.9e-6)}
    star = {'stamps_ns': star_t, 'q': q, 'cov': cov}
    feed = {'/imu': imu, '/star_tracker': star}
    order = sorted([('/imu', k) for k in range(n)] + [('/star_tracker', k) for k in range(m)],
                   key=lambda e: (feed[e[0]]['stamps_ns'][e[1]], e[0]))
    params = {'sigma_v': 1.7e-4, 'sigma_u': 2e-5, 'bias_sigma': 2e-3, 'output_every': 7}
    a = MEKF(params).receive_arrays(feed, order, compiled=False)
    b = MEKF(params).receive_arrays(feed, order, compiled=True)
    for key, va in a.items():
        vb = b[key]
        if isinstance(va, np.ndarray) and (va.shape != vb.shape or
                                           va.tobytes() != vb.tobytes()):
            return key
    return ''


def make(params=None):
    """Campaign factory (``rigidrot_ros.estimators.mekf:make``): a new :class:`MEKF`."""
    return MEKF(params)
