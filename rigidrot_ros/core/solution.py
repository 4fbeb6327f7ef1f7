"""The contract every model's solution keeps: :class:`BaseSolution` and :class:`Samples`.

Frames: N inertial, B body (principal axes). ``R_NB`` means ``v_N = R_NB @ v_B``;
quaternions are (x, y, z, w), active, ``q_NB`` rotates body vectors into N;
``omega_BN_B`` is the angular velocity of B relative to N, in B, rad/s.

A model (Romano's closed forms and 1F1 kernels in :mod:`.models`, the Euler-Poinsot
body in :mod:`.triaxial`) subclasses :class:`BaseSolution` and implements four hooks on
already-checked times: ``_at_scalar(t)`` (one Python float), ``_at_array(tt)`` (a finite
1-D float array), ``_omega(tt)`` and ``_torque_body(tt)`` (float arrays of any shape).
The base class parses and checks ``t`` once for every model, and derives the angular
acceleration from Euler's equations with the model's own torque. This module imports no
model, so the models import it and not each other (scipy's ``integrate/_ivp`` keeps its
``OdeSolver`` base apart from the methods the same way).
"""

import abc
from dataclasses import dataclass
import reprlib

import numpy as np

from . import quaternion as quat

__all__ = ['BaseSolution', 'Samples', 'RateEnvelope', 'majorant_envelope', 'as_times',
           'FLOAT_FLOOR']

#: Attitude error (rad) of composing float64 quaternions, included in every error bound.
#: Some 30 roundings of 1.1e-16 (products, sines, the reduced angles) stay below 4e-15;
#: the floor also covers the first ddphase.IN_FLOOR (1e-18 rad) of each phase's bound.
FLOAT_FLOOR = 1e-14


@dataclass(frozen=True)
class Samples:
    """The exact motion at the times ``t``.

    Attributes
    ----------
    t : ndarray (...,)
        Seconds since t = 0.
    quaternion : ndarray (..., 4)
        ``q_NB``, order (x, y, z, w), active (rotates body vectors into N); continuous
        in t (no sign flips between samples).
    omega : ndarray (..., 3)
        Angular velocity of B relative to N, in B, rad/s.
    error_bound : ndarray (...,)
        Bound on the attitude error, rad (certified with the flint backend, a running
        error estimate with mpmath).
    """

    t: np.ndarray
    quaternion: np.ndarray
    omega: np.ndarray
    error_bound: np.ndarray

    @property
    def rotation(self):
        """``R_NB`` (..., 3, 3): ``v_N = R_NB @ v_B``."""
        return quat.to_matrix(self.quaternion)


def as_times(t):
    """``t`` as a float array, or ValueError naming the problem."""
    try:
        return np.asarray(t, dtype=float)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ValueError(f't must be a float or a 1-D array of floats (seconds), got '
                         f'{reprlib.repr(t)}: {exc}') from None


def _finite(tt):
    if not np.all(np.isfinite(tt)):
        raise ValueError('t must be finite')


@dataclass(frozen=True)
class RateEnvelope:
    """What bounds the analytic continuation of a solution's body rate (for sensors).

    A sensor that integrates the rate (Gauss quadrature of ``omega_at``) needs a bound
    of ``|omega_B(t)|`` for complex t near an interval; the solution states which form
    its rate takes, and the constants of that form, so that no caller has to infer it
    from the model's name.

    Attributes
    ----------
    kind : {'linear', 'closed-form', 'majorant'}
        'linear': ``omega_B(t)`` is a polynomial of degree at most 1 in t (Gauss rules
        integrate it exactly). 'closed-form': in the axes B' (symmetry axis third),
        ``omega_B' = (a cos f + b sin f, b cos f - a sin f, r)`` with ``a, b, r`` linear
        in t and ``f = c1 t + c2 t^2``. 'majorant': only Euler's equations are known;
        Cauchy's majorant ``y' = mu + c y^2`` bounds every component.
    c1, c2 : float
        ``|f'(x)| <= c1 + c2 |x|`` ('closed-form').
    w_t, m_t : float
        ``|a(x)| + |b(x)| <= w_t + m_t |x|``, rad/s and rad/s^2 ('closed-form').
    r0, rdot : float
        ``|r(x)| <= r0 + rdot |x|`` ('closed-form').
    c, mu : float
        ``max |I_j - I_k| / I_i`` and ``max |m_i / I_i|`` (rad/s^2) ('majorant').
    accel : float
        A bound on ``|d omega / dt|`` from the torque alone, ``|M / I|`` (rad/s^2)
        ('linear').
    """

    kind: str
    c1: float = 0.0
    c2: float = 0.0
    w_t: float = 0.0
    m_t: float = 0.0
    r0: float = 0.0
    rdot: float = 0.0
    c: float = 0.0
    mu: float = 0.0
    accel: float = 0.0


def majorant_envelope(scene, model):
    """Return Cauchy's majorant of Euler's equations for a body-fixed torque.

    Valid for any model of a body under a torque constant in B: ``|w_i| <= y`` with
    ``y' = mu + c y^2``, ``c = max |I_j - I_k| / I_i``, ``mu = max |m_i / I_i|``.

    Raises
    ------
    ValueError
        For a torque that turns in B (``torque_frame='virtual'``): no bound here.
    """
    if scene.torque_frame != 'body':
        raise ValueError(f'cannot bound the rate of model {model!r} with a torque turning in '
                         f'the body; delta_angle needs a bound')
    inertia = np.array(scene.inertia, dtype=float)
    m = np.array(scene.torque, dtype=float)
    c = max(abs(inertia[(i + 1) % 3] - inertia[(i + 2) % 3]) / inertia[i] for i in range(3))
    return RateEnvelope('majorant', c=float(c), mu=float(np.max(np.abs(m) / inertia)))


class BaseSolution(abc.ABC):
    """The exact motion of a scene, whichever model evaluates it.

    Attributes
    ----------
    scene : Scene
    model : str
        Which exact model covers the scene (a key of ``rigidrot_ros.core.MODELS``).
    method : str
        How the model is evaluated (each model lists its methods).
    backend : str
        The special-function backend asked for ('flint' or 'mpmath').
    tol : float
        Attitude accuracy asked, rad; every sample's ``error_bound`` is at most this.
    reference : str
        What the model evaluates (the paper's results).

    Notes
    -----
    Subclasses set ``MODELS`` (the model names they evaluate, with their references)
    and implement ``_at_scalar``, ``_at_array``, ``_omega``, ``_torque_body`` and
    ``rate_envelope``.
    """

    #: Model names this class evaluates and what each is (filled by subclasses).
    MODELS = {}

    scene = None
    model = None
    tol = None
    backend = None

    @property
    def reference(self):
        """Return what the model evaluates (its entry in ``MODELS``)."""
        return self.MODELS[self.model]

    # -- what every model gives ------------------------------------------------------
    def at(self, t):
        """Evaluate the exact motion at time(s) t.

        Parameters
        ----------
        t : float or 1-D array of float
            Seconds since t = 0.

        Returns
        -------
        Samples
            ``quaternion`` q_NB (x, y, z, w), ``rotation`` R_NB, ``omega`` (rad/s, B
            relative to N, in B) and ``error_bound`` (rad), shaped like ``t``.

        Raises
        ------
        ValueError
            ``t`` not a finite float or 1-D array of them.
        PrecisionError
            When the bound of a sample cannot meet ``tol``.
        """
        if type(t) is float:                  # the scalar path, without an array round trip
            return self._at_scalar(t)
        t_arr = as_times(t)
        if t_arr.ndim == 0:
            return self._at_scalar(float(t_arr))
        if t_arr.ndim > 1:
            raise ValueError(f't must be a float or a 1-D array, got shape {t_arr.shape}')
        _finite(t_arr)
        return self._at_array(t_arr)

    def omega_at(self, t):
        """Angular velocity of B relative to N, in B, rad/s, at t (float or 1-D array).

        Returns an array shaped ``t.shape + (3,)``.
        """
        tt = self._checked(t)
        return self._omega(tt)

    def torque_body_at(self, t):
        """Torque on the body in B, N m, at t (float or 1-D array): shape ``t.shape + (3,)``.

        Constant for ``torque_frame='body'``; turning about the symmetry axis for
        ``'virtual'`` (fixed in the virtual sphere); zero for torque-free models.
        """
        tt = self._checked(t)
        return self._torque_body(tt)

    def omega_dot_at(self, t):
        """Angular acceleration of B relative to N, in B, rad/s^2, at t (float or 1-D array).

        Exact, from Euler's equations with the model's own torque:

            I d(omega)/dt = M_B(t) - omega x (I omega),

        ``I`` the principal moments, ``omega`` = :meth:`omega_at`, ``M_B`` =
        :meth:`torque_body_at`. Shape ``t.shape + (3,)``.
        """
        tt = self._checked(t)
        w = self._omega(tt)
        m = self._torque_body(tt)
        inertia = np.asarray(self.scene.inertia, dtype=float)
        with np.errstate(over='ignore', invalid='ignore'):
            return (m - np.cross(w, inertia * w)) / inertia

    def rate_envelope(self):
        """Return the :class:`RateEnvelope` of this solution's body rate (for sensors).

        The default is the majorant of Euler's equations (:func:`majorant_envelope`),
        valid for a torque constant in B; models with a closed-form rate say more.
        """
        return majorant_envelope(self.scene, self.model)

    # -- shared helpers --------------------------------------------------------------
    def _checked(self, t):
        tt = as_times(t)
        if tt.ndim > 1:
            raise ValueError(f't must be a float or a 1-D array, got shape {tt.shape}')
        _finite(tt)
        return tt

    @abc.abstractmethod
    def _at_scalar(self, t):
        """Return one sample at a float time t: a :class:`Samples` of scalars."""

    @abc.abstractmethod
    def _at_array(self, tt):
        """Return the samples at a finite 1-D float array of times."""

    @abc.abstractmethod
    def _omega(self, tt):
        """Return the body rate at a finite 1-D float array of times, (n, 3)."""

    def _torque_body(self, tt):
        return np.zeros(np.shape(tt) + (3,))
