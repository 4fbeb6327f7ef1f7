"""Sensors that sample the exact motion: a rate-integrating gyro and a star tracker.

Frames: N inertial, B body; quaternions (x, y, z, w), active, ``q_NB``; rates of B
relative to N, in B, rad/s. Times are scene seconds since t = 0.
"""

from dataclasses import dataclass

import numpy as np

from .batch import read_block
from .increments import DELTA_TOL, RateBound
from .noise import AttitudeNoise, GyroNoise

__all__ = ['Gyro', 'GyroReading', 'StarTracker', 'StarTrackerReading']


@dataclass(frozen=True)
class GyroReading:
    """One gyro sample over ``[t - dt, t]``.

    Attributes
    ----------
    t, dt : float
        End of the interval and its length, s.
    omega : ndarray (3,)
        Measured rate, rad/s, in B: ``omega_avg`` plus bias and white noise.
    omega_avg : ndarray (3,)
        True rate averaged over the interval, ``delta_angle / dt``.
    delta_angle, delta_angle_bound : ndarray (3,), float
        Exact ``∫ omega_B dt`` (rad, in B) and the bound on its error norm.
    delta_rotation, delta_rotation_bound : ndarray (3,), float
        Exact ``Log(q_NB(t - dt)^-1 ⊗ q_NB(t))`` (rad, in B) and its error bound.
    bias : ndarray (3,)
        The bias in this sample, ``(beta_k + beta_{k+1}) / 2``, rad/s.
    variance : float
        Variance per axis of the white part, (rad/s)^2, plus the square of the exact
        rate's error bound (so that an ideal gyro still states a nonzero variance).
    quaternion : ndarray (4,)
        True ``q_NB`` at t.
    delta_angle_measured : ndarray (3,) or None
        Measured Δθ (rad, in B), quantised with the carried residual if the noise is an
        :class:`ImuNoise` with ``increment_quantum``; None with a :class:`GyroNoise`.
    """

    t: float
    dt: float
    omega: np.ndarray
    omega_avg: np.ndarray
    delta_angle: np.ndarray
    delta_angle_bound: float
    delta_rotation: np.ndarray
    delta_rotation_bound: float
    bias: np.ndarray
    variance: float
    quaternion: np.ndarray
    delta_angle_measured: np.ndarray = None


class Gyro:
    """A rate-integrating gyro on the exact motion.

    Parameters
    ----------
    solution : rigidrot_ros.core.Solution
    noise : GyroNoise or ImuNoise, optional
        Its error model (default: an ideal gyro); an :class:`ImuNoise` of
        ``kind='gyro'`` adds scale factor, misalignment, quantisation, Gauss–Markov and
        turn-on bias (with those zero its stream is :class:`GyroNoise`'s, bit for bit).
    tol : float
        Target of the delta-angle error bound, rad.

    Examples
    --------
    >>> from rigidrot_ros.core import Scene, solve
    >>> gyro = Gyro(solve(Scene(omega0=(0.0, 0.0, 1.0))))
    >>> r = gyro.read(0.0, 0.01)
    >>> float(r.delta_angle[2])
    0.01
    """

    def __init__(self, solution, noise=None, tol=DELTA_TOL):
        self.solution = solution
        self.noise = noise if noise is not None else GyroNoise()
        self.tol = tol
        self._bound = RateBound(solution)
        self._last = None
        #: ``(times, Samples)`` of the last block's ends evaluated (:func:`.batch._ends`)
        self.last_ends = None

    def reset(self):
        """Restart the noise stream and forget the cached attitude."""
        self.noise.reset()
        self._last = None

    def read(self, t0, t1, budget=None):
        """Sample the interval ``[t0, t1]`` (s, ``t0 < t1``): a :class:`GyroReading`.

        ``budget`` (s, optional) bounds the delta-angle quadrature's time: past it the read
        raises ValueError and leaves the noise stream untouched. The one-interval case of
        :meth:`read_many` (the same bits, sample by sample).
        """
        t0, t1 = float(t0), float(t1)
        if not t1 > t0:
            raise ValueError(f'a gyro interval needs t0 < t1, got [{t0!r}, {t1!r}]')
        b = read_block(self, np.array([t0, t1]), budget=budget)
        return GyroReading(t1, float(b.dt[0]), b.omega[0], b.omega_avg[0], b.delta_angle[0],
                           float(b.delta_angle_bound[0]), b.delta_rotation[0],
                           float(b.delta_rotation_bound[0]), b.bias[0], float(b.variance[0]),
                           b.quaternion[0],
                           None if b.delta_angle_measured is None
                           else b.delta_angle_measured[0])

    def read_many(self, times, budget=None):
        """Sample the intervals between consecutive ``times`` (m + 1 ends, s) at once.

        A :class:`rigidrot_ros.sensors.batch.GyroBlock` of m rows, bit for bit the m
        readings :meth:`read` gives over the same intervals (state carried either way).
        """
        return read_block(self, times, budget=budget)


@dataclass(frozen=True)
class StarTrackerReading:
    """One star tracker sample at t.

    Attributes
    ----------
    t : float
        Scene time, s.
    quaternion : ndarray (4,)
        Measured ``q_NB`` (x, y, z, w): ``q_true ⊗ exp(error / 2)``.
    error : ndarray (3,)
        The rotation-vector error e in B, rad (``q_true^-1 ⊗ q_meas = exp(e / 2)``).
    covariance : ndarray (3, 3)
        Covariance of e in B, rad^2.
    true_quaternion : ndarray (4,)
        The exact ``q_NB`` at t.
    """

    t: float
    quaternion: np.ndarray
    error: np.ndarray
    covariance: np.ndarray
    true_quaternion: np.ndarray


class StarTracker:
    """A star tracker on the exact motion: the attitude with a small rotation error.

    Parameters
    ----------
    solution : rigidrot_ros.core.Solution
    noise : AttitudeNoise
        Cross- and about-boresight errors, boresight axis in B, seed.
    """

    def __init__(self, solution, noise=None):
        self.solution = solution
        self.noise = noise if noise is not None else AttitudeNoise()

    def reset(self):
        """Restart the noise stream."""
        self.noise.reset()

    def read(self, t):
        """Sample at scene time t (s): a :class:`StarTrackerReading`."""
        s = self.solution.at(float(t))
        q_true = np.asarray(s.quaternion, dtype=float)
        q_meas, e = self.noise.corrupt(q_true)
        # the exact attitude's own error adds (in quadrature, at most) to the covariance
        cov = self.noise.covariance + float(s.error_bound) ** 2 * np.eye(3)
        return StarTrackerReading(float(t), q_meas, e, cov, q_true)

    def read_many(self, times):
        """Sample at each of ``times`` (scene s, 1-D) at once: a :class:`StarTrackerReading`.

        Its fields hold one row per time: bit for bit the readings :meth:`read` gives at
        the same times in order (the attitudes' bits depend on t alone, the noise is
        drawn in the same order, the error bound squared as a Python float is). If the
        attitudes cannot be evaluated, ValueError (or PrecisionError) before any noise
        is drawn.
        """
        t = np.asarray(times, dtype=float)
        s = self.solution.at(t)
        q_true = np.asarray(s.quaternion, dtype=float)
        q_meas, e = self.noise.corrupt(q_true)
        square = np.array([b ** 2 for b in np.asarray(s.error_bound, dtype=float).tolist()])
        cov = self.noise.covariance + square[:, None, None] * np.eye(3)
        return StarTrackerReading(t, q_meas, e, cov, q_true)
