"""The complete error model of an inertial sensor, shared by the gyro and the accelerometer.

Frames: B body (the sensor axes are the body axes); every vector here is in B. The model
of one sample over an interval of ``dt`` seconds, for a true input ``u_avg`` averaged over
the interval (the rate for a gyro, rad/s; the specific force for an accelerometer,
m/s^2)::

    y = C u_avg + beta_avg + g_avg + n             C = I + diag(s) + M
    beta_{k+1} = beta_k + sigma_u sqrt(dt) N_u     beta_0 = b_given + sigma_t N_t
    n ~ N(0, (sigma_v^2 / dt + sigma_u^2 dt / 12 + r_gm) I)

with ``beta_avg = (beta_k + beta_{k+1}) / 2`` (Markley & Crassidis 2014, the
rate-integrating gyro: :class:`rigidrot_ros.sensors.GyroNoise` is this model with every
other term zero, bit for bit), ``s`` the scale-factor errors, ``M`` the axis
misalignment (off-diagonal, a small non-orthogonality), ``sigma_t`` the turn-on bias
spread (drawn once from the seed, as Gazebo's ``bias_stddev``), and ``g`` a first-order
Gauss–Markov bias (bias instability, stationary standard deviation ``sigma_b``,
correlation time ``tau``), discretised exactly for an integrating sensor: with
``x = dt / tau``, ``a = 1 - exp(-x)``, ``a2 = 1 - exp(-2 x)``,
``G(x) = x - 2 a + a2 / 2``::

    g_{k+1} = (1 - a) g_k + w,          w ~ N(0, sigma_b^2 a2)
    g_avg   = (a / x) g_k + a^2 / (x a2) w + residual,
    residual ~ N(0, sigma_b^2 (2 G(x) - a^4 / a2) / x^2)

which is the joint law of the end value and the interval mean of the process; as
``tau -> inf`` with ``sigma_b^2 2 / tau = sigma_u^2`` held it becomes the random walk's
``(beta_k + beta_{k+1}) / 2`` with its ``sigma_u^2 dt / 12``. ``g_0`` is drawn from the
stationary law (a sensor that has been on for a while).

Quantisation, after the noise: the output value ``y`` is rounded to a multiple of
``quantum`` (a rate-output ADC, memoryless), and the increment ``y dt`` (Δθ, rad, or
Δv, m/s) to a multiple of ``increment_quantum`` with the residual carried to the next
sample, as integrating sensors do (Basilisk's ``imuSensor``): the sum of the reported
increments never strays more than half an LSB from the sum of the unquantised ones.

Random numbers: the white noise and the random walk come from
``numpy.random.default_rng(seed)`` for the gyro (today's stream) and from the child
``SeedSequence(seed, spawn_key=(1,))`` for the accelerometer, six normals a sample in
the order ``N_u, N_v`` (as :class:`GyroNoise`); the turn-on bias and the Gauss–Markov
process come from their own children ``(stream, 1)`` and ``(stream, 2)``. So a term
switched on or off never changes the draws of another, and the same seed and intervals
give a bit-identical stream whether samples are drawn one at a time or in batches.
"""

from dataclasses import dataclass
import math
import numbers

import numpy as np

from .noise import _check_dt, check_components, check_dt_rows, check_nonnegative, check_seed
from .noise import check_vector

__all__ = ['ImuNoise', 'ImuSample', 'gauss_markov_coefficients', 'check_positive',
           'check_matrix', 'KINDS']

#: Per kind: the parameter-name prefix (the node's dotted names), the unit of the input,
#: and the largest value accepted per term (a sanity bound, not a physical limit).
KINDS = {
    'gyro': dict(prefix='imu.gyro_', unit='rad/s', increment='rad', stream=0,
                 limits=dict(noise_density=1.0, random_walk=1.0, bias=10.0,
                             bias_stddev=10.0, bias_instability=10.0, quantum=1.0,
                             increment_quantum=1.0)),
    'accel': dict(prefix='accel.', unit='m/s^2', increment='m/s', stream=1,
                  limits=dict(noise_density=10.0, random_walk=10.0, bias=100.0,
                              bias_stddev=100.0, bias_instability=100.0, quantum=10.0,
                              increment_quantum=10.0)),
}
_MAX_TAU = 1e9             # s: beyond ~30 years a correlation time is a random walk's
_MAX_SCALE = 0.5           # scale-factor error, fraction
_MAX_MISALIGN = 0.1        # rad: "small" non-orthogonality


def check_positive(name, value, upper):
    """Return ``value`` as float if it is a finite number in (0, upper]; ValueError else."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f'{name} must be a number, got {value!r}')
    v = float(value)
    if not math.isfinite(v) or not 0.0 < v <= upper:
        raise ValueError(f'{name} must be a finite number in (0, {upper:g}], got {value!r}')
    return v


def check_matrix(name, value, limit):
    """Return a float 3x3 matrix from 9 numbers (row-major) or 3 rows, each |.| <= limit."""
    if isinstance(value, (str, bytes)) or not hasattr(value, '__len__'):
        raise ValueError(f'{name} must be 9 numbers (a 3x3 matrix, row-major), got {value!r}')
    flat = []
    for row in value:
        if hasattr(row, '__len__') and not isinstance(row, (str, bytes)):
            flat.extend(row)
        else:
            flat.append(row)
    if len(flat) != 9 or len(value) not in (3, 9):
        raise ValueError(f'{name} must be 9 numbers (a 3x3 matrix, row-major), got {value!r}')
    return check_components(name, flat, limit).reshape(3, 3)


def _gm_g(x):
    """``G(x) = x - 2 (1 - e^-x) + (1 - e^-2x) / 2`` without cancellation (x > 0)."""
    if x > 0.5:
        return x + 2.0 * math.expm1(-x) - 0.5 * math.expm1(-2.0 * x)
    # G = sum_{n>=3} (-1)^n (2 - 2^(n-1)) x^n / n!: terms fall by ~x at least
    total, term = 0.0, x * x / 2.0
    for n in range(3, 40):
        term *= x / n                              # x^n / n!
        c = (2.0 - 2.0 ** (n - 1)) * term
        total += c if n % 2 == 0 else -c
        if abs(c) < 1e-18 * abs(total):
            break
    return total


def gauss_markov_coefficients(sigma, tau, dt):
    """Exact discretisation of a first-order Gauss–Markov bias for an integrating sensor.

    Parameters
    ----------
    sigma : float
        Stationary standard deviation of the process (units of the input).
    tau, dt : float
        Correlation time and sample interval, s (both > 0).

    Returns
    -------
    (phi, sd_step, c_mean, c_gain, var_residual) : floats
        ``g_{k+1} = phi g_k + sd_step N``, and the interval mean
        ``g_avg = c_mean g_k + c_gain (sd_step N) + sqrt(var_residual) N'``.

    Examples
    --------
    >>> phi, sd, cm, cg, r = gauss_markov_coefficients(1.0, 1e6, 1.0)
    >>> round(cg, 6), round(r * 1e6 * 6, 6)     # -> 1/2 and sigma^2 dt / (6 tau)
    (0.5, 1.0)
    """
    x = dt / tau
    a = -math.expm1(-x)
    a2 = -math.expm1(-2.0 * x)
    phi = math.exp(-x)
    sd_step = sigma * math.sqrt(a2)
    c_mean = a / x
    c_gain = a * a / (x * a2)
    res = sigma * sigma * max(2.0 * _gm_g(x) - a ** 4 / a2, 0.0) / (x * x)
    return phi, sd_step, c_mean, c_gain, res


@dataclass(frozen=True)
class ImuSample:
    """Samples from :meth:`ImuNoise.apply` (arrays of n rows, in B).

    Attributes
    ----------
    value : ndarray (n, 3)
        Measured rate (rad/s) or specific force (m/s^2), quantised if asked.
    increment : ndarray (n, 3)
        Measured Δθ (rad) or Δv (m/s) over each interval, quantised with the residual
        carried if asked (``value * dt`` when not).
    bias : ndarray (n, 3)
        The bias in each sample: turn-on + random walk ``(beta_k + beta_{k+1}) / 2`` +
        Gauss–Markov interval mean (the conditional residual not included).
    """

    value: np.ndarray
    increment: np.ndarray
    bias: np.ndarray


class ImuNoise:
    """A gyro's or an accelerometer's errors: every term seeded, each zero by default.

    Parameters
    ----------
    noise_density : float
        ``sigma_v``: angle random walk (gyro, rad/s/sqrt(Hz)) or velocity random walk
        (accelerometer, m/s^2/sqrt(Hz)); Kalibr ``*_noise_density``.
    random_walk : float
        ``sigma_u``: bias random walk, rad/s^2/sqrt(Hz) or m/s^3/sqrt(Hz); Kalibr
        ``*_random_walk``.
    bias : 3 floats
        Given initial bias, in B (rad/s or m/s^2).
    seed : int
        In [0, 2^63 - 1]; see the module docstring for the streams.
    bias_stddev : float
        Turn-on bias spread: ``N(0, bias_stddev^2)`` per axis drawn once from the seed and
        added to ``bias`` (Gazebo's ``<bias_stddev>``).
    bias_instability : float
        Stationary standard deviation ``sigma_b`` of the Gauss–Markov bias (0 = off).
    bias_correlation_time : float
        Its correlation time ``tau``, s, in (0, 1e9].
    scale_factor : 3 floats
        Scale-factor errors ``s`` (fraction: 1e-3 = 1000 ppm), ``|s_i| <= 0.5``.
    misalignment : 9 floats or 3x3
        ``M`` row-major, rad, zero diagonal (the diagonal is ``scale_factor``),
        ``|M_ij| <= 0.1``: axis i senses ``M_ij`` of the input along axis j.
    quantum : float
        LSB of the output value (rad/s or m/s^2); 0 = not quantised.
    increment_quantum : float
        LSB of the increment (rad or m/s), residual carried; 0 = not quantised.
    kind : {'gyro', 'accel'}
        Names the parameters in error messages (``imu.gyro_*``, ``accel.*``), sets the
        bounds and the random stream.

    Raises
    ------
    ValueError
        Naming the parameter: negative or non-finite densities, ``tau <= 0``, a nonzero
        misalignment diagonal, values beyond their bounds.

    Examples
    --------
    >>> noise = ImuNoise(1e-3, 1e-5, seed=7, scale_factor=(1e-3, 0.0, 0.0))
    >>> noise.apply(np.array([[1.0, 0.0, 0.0]]), 0.01).value.shape
    (1, 3)
    """

    def __init__(self, noise_density=0.0, random_walk=0.0, bias=(0.0, 0.0, 0.0), seed=0,
                 bias_stddev=0.0, bias_instability=0.0, bias_correlation_time=3600.0,
                 scale_factor=(0.0, 0.0, 0.0), misalignment=None, quantum=0.0,
                 increment_quantum=0.0, kind='gyro'):
        if kind not in KINDS:
            raise ValueError(f'kind must be one of {sorted(KINDS)}, got {kind!r}')
        spec = KINDS[kind]
        p, lim = spec['prefix'], spec['limits']
        self.kind = kind
        self.noise_density = check_nonnegative(p + 'noise_density', noise_density,
                                               lim['noise_density'])
        self.random_walk = check_nonnegative(p + 'random_walk', random_walk,
                                             lim['random_walk'])
        self.bias0 = check_vector(p + 'bias', bias, lim['bias'])
        self.seed = check_seed(('imu.' if kind == 'gyro' else p) + 'seed', seed)
        self.bias_stddev = check_nonnegative(p + 'bias_stddev', bias_stddev,
                                             lim['bias_stddev'])
        self.bias_instability = check_nonnegative(p + 'bias_instability', bias_instability,
                                                  lim['bias_instability'])
        self.bias_correlation_time = check_positive(p + 'bias_correlation_time',
                                                    bias_correlation_time, _MAX_TAU)
        self.scale_factor = check_vector(p + 'scale_factor', scale_factor, _MAX_SCALE)
        mis = np.zeros((3, 3)) if misalignment is None else \
            check_matrix(p + 'misalignment', misalignment, _MAX_MISALIGN)
        if np.any(np.diag(mis) != 0.0):
            raise ValueError(f'{p}misalignment must have a zero diagonal (the diagonal is '
                             f'{p}scale_factor), got {np.diag(mis).tolist()}')
        self.misalignment = mis
        self.quantum = check_nonnegative(p + 'quantum', quantum, lim['quantum'])
        self.increment_quantum = check_nonnegative(p + 'increment_quantum',
                                                   increment_quantum,
                                                   lim['increment_quantum'])
        self._stream = spec['stream']
        self._error = np.diag(self.scale_factor) + self.misalignment
        self._has_error = bool(np.any(self._error != 0.0))
        self.reset()

    @property
    def matrix(self):
        """The input-to-output matrix ``C = I + diag(s) + M`` (3x3)."""
        return np.eye(3) + self._error

    def _child(self, *key):
        return np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=key))

    def reset(self):
        """Restart the stream: turn-on bias redrawn (the same), generators re-seeded."""
        self._rng = (np.random.default_rng(self.seed) if self._stream == 0
                     else self._child(self._stream))
        self.turn_on_bias = np.zeros(3)
        self.bias = self.bias0.copy()
        if self.bias_stddev > 0.0:
            self.turn_on_bias = self.bias_stddev * self._child(self._stream, 1) \
                .standard_normal(3)
            self.bias = self.bias0 + self.turn_on_bias
        self._gm_rng = self._child(self._stream, 2)
        self.gm_bias = np.zeros(3)
        if self.bias_instability > 0.0:
            self.gm_bias = self.bias_instability * self._gm_rng.standard_normal(3)
        self._residual = [0.0, 0.0, 0.0]

    def _white_core(self, dt):
        return self.noise_density ** 2 / dt + self.random_walk ** 2 * dt / 12.0

    def white_variance(self, dt):
        """Variance per axis of the white part of one output value over ``dt`` s.

        ``sigma_v^2 / dt + sigma_u^2 dt / 12`` + the Gauss–Markov residual +
        ``quantum^2 / 12`` (the rounding, uniform); the biases, the scale factor and the
        misalignment are not in it (as in Gazebo).
        """
        dt = _check_dt(dt)
        var = self._white_core(dt)
        if self.bias_instability > 0.0:
            var += gauss_markov_coefficients(self.bias_instability,
                                             self.bias_correlation_time, dt)[4]
        return var + self.quantum ** 2 / 12.0

    def increment_variance(self, dt):
        """Variance per axis of one reported increment over ``dt`` s.

        ``(white_variance - quantum^2 / 12) dt^2 + increment_quantum^2 / 6`` (with the
        residual carried, an increment's rounding error is the difference of two
        residuals).
        """
        dt = _check_dt(dt)
        core = self.white_variance(dt) - self.quantum ** 2 / 12.0
        return core * dt * dt + self.increment_quantum ** 2 / 6.0

    def corrupt(self, value_avg, dt):
        """Return one measured value (in B) for the true average over ``dt`` s."""
        return self.apply(np.reshape(value_avg, (1, 3)), dt).value[0]

    def corrupt_many(self, value_avg, dt):
        """Measured values for consecutive intervals of ``dt`` s (array (n, 3) in, out)."""
        return self.apply(value_avg, dt).value

    def apply(self, value_avg, dt):
        """Measure consecutive intervals of ``dt`` s: an :class:`ImuSample`.

        Bit-identical to ``n`` calls with one row each; advances :attr:`bias` (the random
        walk, turn-on included), :attr:`gm_bias` and the carried quantisation residual.
        ``dt`` is one interval length (s) or n of them (one per row).
        """
        u = np.asarray(value_avg, dtype=float)
        if u.ndim != 2 or u.shape[1] != 3 or not np.all(np.isfinite(u)):
            raise ValueError(f'the true {KINDS[self.kind]["unit"]} input must be finite, '
                             f'shaped (n, 3), got shape {u.shape}')
        n = len(u)
        dt = check_dt_rows(dt, n)
        if self._has_error:         # elementwise, not a BLAS product: a row's bits alone
            e = self._error
            x = u + (u[:, 0:1] * e[:, 0] + u[:, 1:2] * e[:, 1] + u[:, 2:3] * e[:, 2])
        else:
            x = u
        draws = self._rng.standard_normal((n, 6))
        steps = (self.random_walk * np.sqrt(dt)) * draws[:, :3]
        betas = np.cumsum(np.vstack([self.bias[None, :], steps]), axis=0)
        white_var = self._white_core(dt)
        gm = None
        if self.bias_instability > 0.0:
            coef = self._gm_rows(dt, n)
            white_var = white_var + (coef[4] if np.ndim(dt) == 0 else coef[4][:, None])
            gm = self._gauss_markov(n, *coef[:4])
        white = np.sqrt(white_var) * draws[:, 3:]
        self.bias = betas[-1].copy()
        bias = 0.5 * (betas[:-1] + betas[1:])
        y = x + bias + white
        if gm is not None:
            y = y + gm
            bias = bias + gm
        if self.quantum > 0.0:
            y_out = self.quantum * np.round(y / self.quantum)
        else:
            y_out = y
        inc = y * dt
        if self.increment_quantum > 0.0:
            inc = self._carry(inc, self.increment_quantum)
        return ImuSample(y_out, inc, bias)

    def _gm_rows(self, dt, n):
        """:func:`gauss_markov_coefficients` for one dt (floats) or per row (arrays (n,)).

        Each distinct dt is computed once by the scalar function, so a row has the bits a
        single call with its dt has.
        """
        sigma, tau = self.bias_instability, self.bias_correlation_time
        if np.ndim(dt) == 0:
            return gauss_markov_coefficients(sigma, tau, dt)
        values, inverse = np.unique(dt[:, 0], return_inverse=True)
        table = np.array([gauss_markov_coefficients(sigma, tau, float(v)) for v in values])
        return tuple(table[np.reshape(inverse, -1)].T)

    def _gauss_markov(self, n, phi, sd, cm, cg):
        """Interval means of the Gauss–Markov bias (n, 3); advances :attr:`gm_bias`.

        One sample after another in Python floats: a batch gives the same bits as single
        calls. The coefficients are floats, or arrays (n,) with one value per sample.
        """
        rows = [np.broadcast_to(np.asarray(c, dtype=float), (n,)).tolist()
                for c in (phi, sd, cm, cg)]
        draws = self._gm_rng.standard_normal((n, 3)).tolist()
        g0, g1, g2 = self.gm_bias.tolist()
        out = []
        for (d0, d1, d2), p, s, m, k in zip(draws, *rows):
            a, b, c = s * d0, s * d1, s * d2
            out.append((m * g0 + k * a, m * g1 + k * b, m * g2 + k * c))
            g0, g1, g2 = p * g0 + a, p * g1 + b, p * g2 + c
        self.gm_bias = np.array([g0, g1, g2])
        return np.array(out).reshape(n, 3)

    def _carry(self, inc, q):
        """Quantise increments to multiples of q, carrying each residual forward."""
        r0, r1, r2 = self._residual
        out = []
        for a, b, c in inc.tolist():
            a, b, c = a + r0, b + r1, c + r2
            qa, qb, qc = q * round(a / q), q * round(b / q), q * round(c / q)
            r0, r1, r2 = a - qa, b - qb, c - qc
            out.append((qa, qb, qc))
        self._residual = [r0, r1, r2]
        return np.array(out).reshape(len(inc), 3)
