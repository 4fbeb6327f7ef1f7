"""A three-axis magnetometer on the exact motion: field in B with soft and hard iron.

Frames: N inertial, B body; ``R_NB`` means ``v_N = R_NB @ v_B`` (``R_BN = R_NB^T``);
quaternions (x, y, z, w), active, ``q_NB``. One sample at time t, tesla, in B::

    m_B = S (R_BN m_N) + b_hard + n,     n ~ N(0, (sigma_m^2 / dt) I)

with ``m_N`` the field in N, ``S`` the soft-iron matrix (identity by default),
``b_hard`` the hard-iron offset (in B) and ``sigma_m`` the white-noise density
(T/sqrt(Hz)), discretised over the sample interval ``dt`` as Kalibr discretises a
density (``sigma_m / sqrt(dt)`` per sample). The stated covariance (in B, as REP 145 and
``sensor_msgs/MagneticField`` ask) is ``sigma_m^2 / dt I`` plus the square of the
attitude's own error carried through the field (``|S| |m_N| e``); soft and hard iron
are deterministic calibration errors and are not in it (as Gazebo leaves its biases
out). The noise stream is the child ``SeedSequence(seed, spawn_key=(2,))`` of the seed:
independent of the gyro's and the accelerometer's even for the same seed value.
"""

from dataclasses import dataclass
import math

import numpy as np

from rigidrot_ros.core import quaternion as quat
from .imu_noise import check_matrix
from .noise import _check_dt, check_nonnegative, check_seed, check_vector

__all__ = ['Magnetometer', 'MagReading', 'EARTH_FIELD', 'MAX_SOFT_IRON_CONDITION']

#: Default field in N, tesla: an Earth-like 49.2 uT with 66 degrees inclination (the order
#: of the field at 50 degrees north), with N taken as ENU (x east, y north, z up, REP
#: 103): no east component, 20 uT north, 45 uT down.
EARTH_FIELD = (0.0, 2.0e-5, -4.5e-5)
#: The largest 2-norm condition number accepted for the soft-iron matrix.
MAX_SOFT_IRON_CONDITION = 1e3
_MAX_FIELD = 1e-2          # T: 200x the Earth's field, a magnet nearby
_MAX_DENSITY = 1e-3        # T/sqrt(Hz)
_MAX_SOFT = 10.0


def check_soft_iron(value, name='mag.soft_iron'):
    """Return the soft-iron matrix (3x3) or refuse it: singular, ill-conditioned, det <= 0."""
    s = check_matrix(name, value, _MAX_SOFT)
    sv = np.linalg.svd(s, compute_uv=False)
    if not sv[-1] > 0.0 or sv[0] / sv[-1] > MAX_SOFT_IRON_CONDITION:
        cond = math.inf if not sv[-1] > 0.0 else sv[0] / sv[-1]
        raise ValueError(f'{name} must be well conditioned (condition number <= '
                         f'{MAX_SOFT_IRON_CONDITION:g}); got singular values '
                         f'{[float(v) for v in sv]}, condition {cond:g}')
    if not np.linalg.det(s) > 0.0:
        raise ValueError(f'{name} must have a positive determinant (a distortion, not a '
                         f'reflection), got det {float(np.linalg.det(s)):g}')
    return s


@dataclass(frozen=True)
class MagReading:
    """One magnetometer sample at t (tesla, in B).

    Attributes
    ----------
    t : float
        Scene time, s.
    field : ndarray (3,)
        Measured ``m_B``.
    field_true : ndarray (3,)
        The undistorted ``R_BN m_N``.
    field_distorted : ndarray (3,)
        ``S R_BN m_N + b_hard``: the measurement without the noise.
    covariance : ndarray (3, 3)
        Covariance of the noise in B, T^2 (the attitude's error included).
    quaternion : ndarray (4,)
        True ``q_NB`` (x, y, z, w) at t.
    """

    t: float
    field: np.ndarray
    field_true: np.ndarray
    field_distorted: np.ndarray
    covariance: np.ndarray
    quaternion: np.ndarray


class Magnetometer:
    """A magnetometer on the exact motion.

    Parameters
    ----------
    solution : rigidrot_ros.core.Solution
    field : 3 floats
        ``m_N``, the field in N, tesla (default :data:`EARTH_FIELD`), ``|m_i| <= 1e-2`` T.
    soft_iron : 9 floats or 3x3, optional
        ``S`` (row-major), default identity; refused if singular, ill-conditioned
        (condition number > 1e3), of nonpositive determinant, or ``|S_ij| > 10``.
    hard_iron : 3 floats
        ``b_hard`` in B, tesla, ``|b_i| <= 1e-2`` T.
    noise_density : float
        ``sigma_m``, T/sqrt(Hz), in [0, 1e-3].
    seed : int
        In [0, 2^63 - 1].

    Examples
    --------
    >>> from rigidrot_ros.core import Scene, solve
    >>> mag = Magnetometer(solve(Scene(attitude0=(0.0, 0.0, 0.7071067811865476,
    ...                                           0.7071067811865476))))
    >>> [round(float(v) * 1e6, 9) + 0.0 for v in mag.read(0.0, 0.01).field]   # uT; B: +90 z
    [20.0, 0.0, -45.0]
    """

    def __init__(self, solution, field=EARTH_FIELD, soft_iron=None,
                 hard_iron=(0.0, 0.0, 0.0), noise_density=0.0, seed=0):
        self.solution = solution
        self.field = check_vector('mag.field', field, _MAX_FIELD)
        self.soft_iron = np.eye(3) if soft_iron is None else check_soft_iron(soft_iron)
        self.hard_iron = check_vector('mag.hard_iron', hard_iron, _MAX_FIELD)
        self.noise_density = check_nonnegative('mag.noise_density', noise_density,
                                               _MAX_DENSITY)
        self.seed = check_seed('mag.seed', seed)
        self._identity = bool(np.all(self.soft_iron == np.eye(3)))
        self.reset()

    def reset(self):
        """Restart the noise stream."""
        self._rng = np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=(2,)))

    def variance(self, dt):
        """Per-axis variance of the white noise of one sample over ``dt`` s, T^2."""
        return self.noise_density ** 2 / _check_dt(dt)

    def read(self, t, dt):
        """Sample at scene time t (s); ``dt`` is the sample interval (s) for the noise."""
        t = float(t)
        var = self.variance(dt)
        s = self.solution.at(t)
        q = np.asarray(s.quaternion, dtype=float)
        true = quat.to_matrix(q).T @ self.field                     # R_BN m_N
        distorted = true if self._identity else self.soft_iron @ true
        distorted = distorted + self.hard_iron
        noise = math.sqrt(var) * self._rng.standard_normal(3)
        # the attitude's error e (rad) moves the field by at most |S| |m_N| e
        att = float(np.linalg.norm(self.soft_iron, 2)) * float(np.linalg.norm(self.field)) \
            * float(s.error_bound)
        cov = (var + att * att) * np.eye(3)
        return MagReading(t, distorted + noise, true, distorted, cov, q)
