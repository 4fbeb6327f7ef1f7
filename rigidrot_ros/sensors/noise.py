"""Seeded sensor error models, apart from the sensors that use them (as gz-sensors does).

Frames: B body; rates are of B relative to N, in B, rad/s. Quaternions are (x, y, z, w),
active, ``q_NB``.

Every model draws from its own ``numpy.random.default_rng(seed)``: the same seed and the
same sample intervals give a bit-identical stream, whether samples are drawn one at a
time or in a batch.
"""

import math
import numbers

import numpy as np

from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core.scene import float_vector

__all__ = ['GyroNoise', 'AttitudeNoise', 'ARCSEC', 'check_seed', 'check_nonnegative',
           'check_vector']

#: One arc second in radians.
ARCSEC = math.pi / (180.0 * 3600.0)
_MAX_SEED = 2 ** 63 - 1


def check_nonnegative(name, value, upper):
    """Return ``value`` as float if it is a finite number in [0, upper]; ValueError else."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f'{name} must be a number, got {value!r}')
    v = float(value)
    if not math.isfinite(v) or not 0.0 <= v <= upper:
        raise ValueError(f'{name} must be a finite number in [0, {upper:g}], got {value!r}')
    return v


def check_vector(name, value, limit):
    """Return a float 3-vector with finite components of magnitude <= limit.

    The sequence, its length and its elements are checked by
    :func:`rigidrot_ros.core.scene.float_vector` (the one check of a list of numbers);
    this adds the magnitude limit.
    """
    return _within(name, float_vector(name, value, 3, 'list', finite=False), limit)


def check_components(name, values, limit):
    """Return a float array of ``values``, each a finite real number with ``|.| <= limit``.

    An error names the first bad one as ``name[i]`` (its index in ``values``).
    """
    values = list(values)
    return _within(name, float_vector(name, values, len(values), 'list', finite=False),
                   limit)


def _within(name, values, limit):
    for i, v in enumerate(values):
        if not math.isfinite(v) or abs(v) > limit:
            raise ValueError(f'{name}[{i}] must be finite with magnitude <= {limit:g}, '
                             f'got {v!r}')
    return np.array(values)


def check_seed(name, value):
    """Return ``value`` if it is an integer in [0, 2^63 - 1]; ValueError otherwise."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or \
            not 0 <= int(value) <= _MAX_SEED:
        raise ValueError(f'{name} must be an integer in [0, 2^63 - 1], got {value!r}')
    return int(value)


def check_dt_rows(dt, n):
    """Return the interval length(s) for n rows: a float, or an (n, 1) column of floats.

    ``dt`` is one positive finite number for every row, or n of them (one per row: a
    sensor grid's intervals differ in their last bits). Elementwise arithmetic on the
    column gives each row the bits the float would give it.
    """
    if np.ndim(dt) == 0:
        return _check_dt(dt)
    d = np.asarray(dt, dtype=float)
    if d.shape != (n,) or not np.all(np.isfinite(d)) or not np.all(d > 0.0):
        raise ValueError(f'the sample intervals dt must be {n} positive finite numbers of '
                         f'seconds, got shape {d.shape}')
    return d[:, None]


def _check_dt(dt):
    if isinstance(dt, bool) or not isinstance(dt, numbers.Real) or \
            not math.isfinite(float(dt)) or float(dt) <= 0.0:
        raise ValueError(f'the sample interval dt must be a positive finite number of '
                         f'seconds, got {dt!r}')
    return float(dt)


class GyroNoise:
    """A rate-integrating gyro's errors: white rate noise and a random-walk bias.

    The exact discretisation of the continuous model ``omega_meas = omega + beta + n_v``,
    ``beta' = n_u`` over a sample interval ``dt`` (Markley & Crassidis, *Fundamentals of
    Spacecraft Attitude Determination and Control*, 2014, the rate-integrating gyro)::

        beta_{k+1} = beta_k + sigma_u sqrt(dt) N_u
        omega_meas = omega_avg + (beta_k + beta_{k+1}) / 2
                     + sqrt(sigma_v^2 / dt + sigma_u^2 dt / 12) N_v

    with ``omega_avg`` the true rate averaged over the interval (delta-angle / dt) and
    ``N_u, N_v`` independent standard normal 3-vectors, drawn in that order (six numbers
    a sample).

    Parameters
    ----------
    noise_density : float
        ``sigma_v``, angle random walk, rad/s/sqrt(Hz) (Kalibr ``gyroscope_noise_density``;
        Allan deviation at tau = 1 s). In [0, 1].
    random_walk : float
        ``sigma_u``, rate random walk, rad/s^2/sqrt(Hz) (Kalibr
        ``gyroscope_random_walk``; Allan deviation ``K sqrt(tau / 3)``). In [0, 1].
    bias : 3 floats
        Initial bias ``beta_0``, rad/s, in B (``|component| <= 10`` rad/s).
    seed : int
        Seed of the generator, in [0, 2^63 - 1].

    Examples
    --------
    >>> g = GyroNoise(1e-3, 1e-5, (0.01, 0.0, 0.0), seed=7)
    >>> g.white_variance(0.01)            # sigma_v^2 / dt + sigma_u^2 dt / 12
    0.00010000000008333333
    """

    def __init__(self, noise_density=0.0, random_walk=0.0, bias=(0.0, 0.0, 0.0), seed=0):
        self.noise_density = check_nonnegative('gyro_noise_density', noise_density, 1.0)
        self.random_walk = check_nonnegative('gyro_random_walk', random_walk, 1.0)
        self.bias0 = check_vector('gyro_bias', bias, 10.0)
        self.seed = check_seed('seed', seed)
        self.reset()

    def reset(self):
        """Restart the stream: bias back to its initial value, generator re-seeded."""
        self.bias = self.bias0.copy()
        self._rng = np.random.default_rng(self.seed)

    def white_variance(self, dt):
        """Variance (rad/s)^2 per axis of the white part of one sample over ``dt`` s."""
        dt = _check_dt(dt)
        return self.noise_density ** 2 / dt + self.random_walk ** 2 * dt / 12.0

    def corrupt(self, omega_avg, dt):
        """Return one measured rate (rad/s, in B) for the true average rate over dt.

        Also advances the bias; :attr:`bias` is ``beta_{k+1}`` afterwards.
        """
        return self.corrupt_many(np.reshape(omega_avg, (1, 3)), dt)[0]

    def corrupt_many(self, omega_avg, dt):
        """Measured rates for consecutive intervals of ``dt`` s (array (n, 3) in, out).

        Bit-identical to ``n`` calls of :meth:`corrupt` with the same intervals.
        """
        return self.measure(omega_avg, dt)[0]

    def measure(self, omega_avg, dt):
        """Measure consecutive intervals: ``(rates (n, 3), biases (n, 3))``, rad/s in B.

        ``dt`` is one interval length (s) or n of them; the bias of a sample is
        ``(beta_k + beta_{k+1}) / 2``. Bit-identical to ``n`` calls with one row each.
        """
        w = np.asarray(omega_avg, dtype=float)
        if w.ndim != 2 or w.shape[1] != 3 or not np.all(np.isfinite(w)):
            raise ValueError(f'omega_avg must be finite, shaped (n, 3), got shape {w.shape}')
        dt = check_dt_rows(dt, len(w))
        draws = self._rng.standard_normal((len(w), 6))
        steps = (self.random_walk * np.sqrt(dt)) * draws[:, :3]
        betas = np.cumsum(np.vstack([self.bias[None, :], steps]), axis=0)
        white_var = self.noise_density ** 2 / dt + self.random_walk ** 2 * dt / 12.0
        white = np.sqrt(white_var) * draws[:, 3:]
        self.bias = betas[-1].copy()
        bias = 0.5 * (betas[:-1] + betas[1:])
        return w + bias + white, bias


class AttitudeNoise:
    """Small-rotation attitude error of a star tracker, cross- and about-boresight.

    The measured attitude is ``q_meas = q_true ⊗ exp(e / 2)``, i.e.
    ``q_true^-1 ⊗ q_meas = exp(e / 2)``, with the rotation vector ``e`` in B drawn as
    ``e = sigma_c (n - (n.b) b) + sigma_a (n.b) b`` from a standard normal 3-vector
    ``n`` and the unit boresight ``b`` in B: white, zero mean, covariance
    ``P_B = sigma_c^2 (I - b b^T) + sigma_a^2 b b^T`` (the Basilisk star tracker's error,
    white instead of a random walk).

    Parameters
    ----------
    cross_boresight_arcsec, about_boresight_arcsec : float
        ``sigma_c`` and ``sigma_a``, arc seconds, in [0, 3600].
    boresight : 3 floats
        The boresight axis in B (normalised; not zero).
    seed : int
        Seed of the generator, in [0, 2^63 - 1].
    """

    def __init__(self, cross_boresight_arcsec=5.0, about_boresight_arcsec=35.0,
                 boresight=(0.0, 0.0, 1.0), seed=0):
        self.sigma_c = ARCSEC * check_nonnegative('cross_boresight_arcsec',
                                                  cross_boresight_arcsec, 3600.0)
        self.sigma_a = ARCSEC * check_nonnegative('about_boresight_arcsec',
                                                  about_boresight_arcsec, 3600.0)
        b = check_vector('boresight', boresight, 1e6)
        norm = float(np.linalg.norm(b))
        if not norm > 1e-9:
            raise ValueError(f'boresight must be a nonzero axis in B, got {list(boresight)}')
        self.boresight = b / norm
        self.seed = check_seed('seed', seed)
        self.covariance = (self.sigma_c ** 2 * (np.eye(3) - np.outer(self.boresight,
                                                                     self.boresight))
                           + self.sigma_a ** 2 * np.outer(self.boresight, self.boresight))
        self.reset()

    def reset(self):
        """Restart the stream (generator re-seeded)."""
        self._rng = np.random.default_rng(self.seed)

    def draw(self, count=None):
        """Rotation-vector errors e in B (rad): shape (3,), or (count, 3)."""
        n = self._rng.standard_normal((1 if count is None else count, 3))
        if count is None:
            along = n @ self.boresight
        else:   # row by row as one draw: a matrix-vector product gives other bits
            along = np.array([(row @ self.boresight)[0] for row in n[:, None]]).reshape(-1)
        e = self.sigma_c * (n - along[:, None] * self.boresight) + \
            self.sigma_a * along[:, None] * self.boresight
        return e[0] if count is None else e

    def corrupt(self, q_true):
        """Return ``(q_meas, e)``: ``q_true ⊗ exp(e / 2)`` (x, y, z, w) and e (rad, in B)."""
        q_true = np.asarray(q_true, dtype=float)
        e = self.draw(None if q_true.ndim == 1 else len(q_true))
        return quat.multiply(q_true, quat.from_rotvec(e)), e
