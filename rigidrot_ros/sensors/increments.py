"""Exact increments over a sensor interval: the delta-angle and the incremental rotation.

Frames: N inertial, B body; ``R_NB`` means ``v_N = R_NB @ v_B``. Quaternions are
(x, y, z, w), active, ``q_NB``; omega is the angular velocity of B relative to N, in B.

Over an interval ``[t0, t1]``:

- ``delta_angle = ∫ omega_B dt`` (rad, in B): what a rate-integrating gyro accumulates.
  Computed by Gauss–Legendre quadrature of the closed-form rate
  :meth:`Solution.omega_at`, with the number of nodes and subintervals chosen so that a
  proved truncation bound (analytic continuation into a Bernstein ellipse) plus a
  rounding bound meets the target.
- ``delta_rotation = Log(q_NB(t0)^-1 ⊗ q_NB(t1))`` (rad, in B): the rotation vector of
  the exact incremental rotation. ``delta_rotation - delta_angle`` is the coning term
  (Bortz): zero when the rate keeps its direction, second order in the interval otherwise.

The truncation bound (Trefethen, *Approximation Theory and Approximation Practice*,
Thm 19.3): if ``g`` is analytic in the Bernstein ellipse ``E_rho`` of ``[-1, 1]`` with
``|g| <= M`` there, the n-point Gauss rule errs by at most
``64 M / (15 (rho^2 - 1) rho^(2 n - 2))`` (``n - 1`` in the exponent: the weaker of the
two readings of the theorem's index, so the bound holds either way). ``M`` comes from
the closed form of the rate (the models of Romano 2008): in the body axes B' with the
symmetry axis third, ``omega_B' = (a cos f + b sin f, -a sin f + b cos f, r)`` with
``a, b, r`` linear in t and ``f = c1 t + c2 t^2``; for complex ``t = x + i y``,
``|Im f| = |y f'(x)|``, so ``|omega_1,2| <= (|a| + |b|) cosh(|y| max |f'|)``; the axial
rate is linear and integrated exactly. For a model without that closed form (a body
under a body-fixed torque, e.g. a triaxial body) ``M`` comes from Cauchy's majorant of
Euler's equations ``I w' = m - w x I w``: ``|w_i| <= y(|t - t_m|)`` with
``y' = mu + c y^2``, ``y(0) = max |w_i(t_m)|``.
"""

import math
import time

import numpy as np

from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core.solution import majorant_envelope

__all__ = ['delta_angle', 'delta_rotation', 'rotvec_from_quaternion', 'RateBound',
           'DELTA_TOL']

#: Default target of the delta-angle error bound, rad.
DELTA_TOL = 1e-13
_EPS = np.finfo(float).eps
_NODES = (2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 24, 32)
_RULES = {n: np.polynomial.legendre.leggauss(n) for n in _NODES}
_RHO = np.geomspace(1.02, 1e6, 40)
_A_RHO = 0.5 * (_RHO + 1.0 / _RHO)           # semi-axes of the Bernstein ellipses
_B_RHO = 0.5 * (_RHO - 1.0 / _RHO)
_LOG_RHO = np.log(_RHO)
_LOG_C = math.log(64.0 / 15.0) - np.log(_RHO ** 2 - 1.0)
_MAX_PIECES = 4096


class RateBound:
    """Bounds of the analytic rate of a solution on complex neighbourhoods of intervals.

    Parameters
    ----------
    solution : rigidrot_ros.core.Solution
        Its :meth:`rate_envelope` says which bound applies; any object with ``scene``,
        ``model`` and ``omega_at`` but no ``rate_envelope`` gets Euler's majorant.

    Raises
    ------
    ValueError
        For a model whose rate this module cannot bound (a torque turning in B that is
        not one of Romano's closed forms).
    """

    def __init__(self, solution):
        self.solution = solution
        self.last_rule = 0          # index into the rules of the last one that sufficed
        # the solution says which form its rate takes (no model names here); an object
        # without rate_envelope() gets the majorant of Euler's equations
        ask = getattr(solution, 'rate_envelope', None)
        env = ask() if ask is not None else majorant_envelope(solution.scene, solution.model)
        self.envelope = env
        self.kind = env.kind
        self.c1, self.c2, self.w_t, self.m_t = env.c1, env.c2, env.w_t, env.m_t
        self.r0, self.rdot, self.c, self.mu = env.r0, env.rdot, env.c, env.mu

    def majorant(self, w, r):
        """Return Cauchy's majorant ``y(r)`` of Euler's equations, inf past its pole.

        ``y' = mu + c y^2``, ``y(0) = w``: bounds every ``|w_i|`` at distance ``r`` (s, real
        or complex) from a time where ``max |w_i| = w`` (rad/s). ``w`` is a float (its
        arctangent then taken by :func:`math.atan`) or an array that broadcasts with ``r``.
        Callers choose the ``np.errstate`` (``r`` near the pole overflows).
        """
        if self.c == 0.0:
            return w + self.mu * r
        if self.mu == 0.0:
            return np.where(self.c * w * r < 1.0, w / (1.0 - self.c * w * r), np.inf)
        s = math.sqrt(self.mu / self.c)
        atan = math.atan if isinstance(w, float) else np.arctan
        phase = math.sqrt(self.mu * self.c) * r + atan(w / s)
        return np.where(phase < 0.5 * math.pi, s * np.tan(phase), np.inf)

    def truncation(self, t0, t1, n):
        """Return the best bound (over rho) of the n-point Gauss error on [t0, t1], rad.

        The bound is on the Euclidean norm of the error of the integrated vector.
        """
        hh = 0.5 * (t1 - t0)
        tm = 0.5 * (t0 + t1)
        if self.kind == 'linear':
            return 0.0
        # logs throughout: rho^(2n-2) and cosh overflow long before the minimum is reached
        log_scale = _LOG_C - (2 * n - 2) * _LOG_RHO
        if self.kind == 'closed-form':
            reach = abs(tm) + hh * _A_RHO                      # max |t| on the ellipse
            y = hh * _B_RHO * (self.c1 + self.c2 * reach)      # max |Im f|
            big = self.w_t + self.m_t * reach
            log_cosh = y + np.log1p(np.exp(-2.0 * y)) - math.log(2.0)
            with np.errstate(divide='ignore'):
                log_err = math.log(math.sqrt(2.0) * hh) + np.log(big) + log_cosh + log_scale
        else:
            w = float(np.max(np.abs(self.solution.omega_at(tm))))
            w = w * (1 + 1e-12) + 1e-300
            r = hh * _A_RHO
            with np.errstate(over='ignore', invalid='ignore', divide='ignore'):
                y = self.majorant(w, r)
                log_err = math.log(math.sqrt(3.0) * hh) + np.log(y) + log_scale
        with np.errstate(over='ignore'):          # a bound beyond float64 is inf, no warning
            err = np.exp(np.min(log_err[~np.isnan(log_err)], initial=np.inf))
        return float(err)

    def rounding(self, t0, t1, n, w):
        """Bound on the float64 rounding of the quadrature and of the rate, rad.

        ``w`` is the largest rate norm seen at the nodes (rad/s).
        """
        h = t1 - t0
        tmax = max(abs(t0), abs(t1))
        if self.kind == 'closed-form':
            w = max(w, self.w_t + self.m_t * tmax + self.r0 + self.rdot * tmax)
            dw = (self.c1 + self.c2 * tmax) * (self.w_t + self.m_t * tmax) + self.m_t \
                + self.rdot
        elif self.kind == 'linear':
            dw = self.envelope.accel
        else:
            w = w * 2.0 + self.mu * h       # the majorant keeps |w| within 2x over 1 node
            dw = self.mu + self.c * w * w
        # per node: reduced angle (4 pi eps), cos/sin and products (~16 eps) of the rate,
        # rounded node time (eps |t| |w'|); then the n-term weighted sum
        per_node = 32.0 * _EPS * w + _EPS * tmax * dw
        return math.sqrt(3.0) * h * (per_node + (n + 4) * _EPS * w)


def _gauss(solution, t0, t1, n):
    x, wts = _RULES[n]
    hh = 0.5 * (t1 - t0)
    tm = 0.5 * (t0 + t1)
    om = np.asarray(solution.omega_at(tm + hh * x))
    return hh * (wts @ om), float(np.max(np.linalg.norm(om, axis=-1)))


def _check_deadline(deadline, t0, t1, pieces, n):
    if deadline is not None and time.perf_counter() > deadline:
        raise ValueError(f'delta_angle over [{t0}, {t1}] s ran out of its time budget '
                         f'({pieces} subintervals of {n} nodes); shorten the interval')


def delta_angle(solution, t0, t1, tol=DELTA_TOL, bound=None, deadline=None):
    """Return the exact ``∫_{t0}^{t1} omega_B dt`` (rad, in B) and its error bound.

    Parameters
    ----------
    solution : rigidrot_ros.core.Solution
        The exact motion; its closed-form :meth:`omega_at` is integrated.
    t0, t1 : float
        The interval, seconds since t = 0, ``t0 <= t1``, both finite.
    tol : float
        Target of the error bound, rad (default 1e-13).
    bound : RateBound, optional
        Reuse the per-solution constants across calls.
    deadline : float, optional
        A :func:`time.perf_counter` value: give up (ValueError) once it has passed, so one
        call cannot take longer than its caller's budget (checked every few subintervals).

    Returns
    -------
    (ndarray (3,), float)
        The delta-angle (rad, in B) and a bound on the Euclidean norm of its error
        (quadrature truncation, proved, plus float64 rounding).

    Raises
    ------
    ValueError
        Non-finite or reversed times, no rule meets ``tol`` within 4096 subintervals, or
        the ``deadline`` passed.

    Examples
    --------
    >>> from rigidrot_ros.core import Scene, solve
    >>> sol = solve(Scene(omega0=(0.0, 0.0, 2.0)))
    >>> delta_angle(sol, 0.0, 0.5)[0]
    array([0., 0., 1.])
    """
    t0, t1 = float(t0), float(t1)
    if not (math.isfinite(t0) and math.isfinite(t1)):
        raise ValueError(f'delta_angle needs finite times, got [{t0!r}, {t1!r}]')
    if t1 < t0:
        raise ValueError(f'delta_angle needs t0 <= t1, got [{t0!r}, {t1!r}]')
    if t1 == t0:
        return np.zeros(3), 0.0
    bound = bound or RateBound(solution)
    pieces = 1
    while pieces <= _MAX_PIECES:
        edges = np.linspace(t0, t1, pieces + 1)
        edges[0], edges[-1] = t0, t1
        # a stream of like intervals: start at the rule that served the last one
        first = bound.last_rule if pieces == 1 else 0
        for n in _NODES[first:]:
            trunc = 0.0
            for i, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
                if i % 16 == 0:
                    _check_deadline(deadline, t0, t1, pieces, n)
                trunc += bound.truncation(a, b, n)
            if trunc <= 0.5 * tol:
                if pieces == 1:
                    bound.last_rule = max(0, _NODES.index(n) - 1)
                total, w = np.zeros(3), 0.0
                for i, (a, b) in enumerate(zip(edges[:-1], edges[1:])):
                    if i % 16 == 0:
                        _check_deadline(deadline, t0, t1, pieces, n)
                    part, w_part = _gauss(solution, a, b, n)
                    total, w = total + part, max(w, w_part)
                rnd = bound.rounding(t0, t1, n, w) + pieces * 3 * _EPS * float(
                    np.linalg.norm(total))
                return total, trunc + rnd
        pieces *= 2
    raise ValueError(f'delta_angle over [{t0}, {t1}] s cannot reach {tol:g} rad within '
                     f'{_MAX_PIECES} subintervals; shorten the interval')


def rotvec_from_quaternion(q):
    """Rotation vector (rad) of unit quaternions (x, y, z, w), angle in [0, pi].

    ``Log`` of the rotation: the axis times the angle, with the sign of q chosen so the
    angle does not exceed pi; accurate for tiny angles (``2 atan2(|v|, |w|)``).
    """
    q = np.asarray(q, dtype=float)
    v = q[..., :3] * np.where(q[..., 3:] < 0, -1.0, 1.0)
    s = np.linalg.norm(v, axis=-1)
    angle = 2.0 * np.arctan2(s, np.abs(q[..., 3]))
    # angle / s -> 2 / |w| as s -> 0
    safe = np.where(s > 0, s, 1.0)
    scale = np.where(s > 0, angle / safe, 2.0 / np.maximum(np.abs(q[..., 3]), 1e-300))
    return v * scale[..., None]


def delta_rotation(q0, q1, bound0=0.0, bound1=0.0):
    """Return ``Log(q0^-1 ⊗ q1)`` (rad, in B) and its error bound.

    Parameters
    ----------
    q0, q1 : array_like (4,)
        ``q_NB`` at the start and the end of the interval, (x, y, z, w), active.
    bound0, bound1 : float
        Attitude error bounds of q0 and q1, rad (``Samples.error_bound``).

    Returns
    -------
    (ndarray (3,), float)
        The rotation vector of the incremental rotation, in B (rad), and a bound on the
        norm of its error: the attitude errors carried through ``Log`` (whose Jacobian
        has norm ``(θ/2) / sin(θ/2)``), with 1 % for second order, plus rounding.
    """
    d = quat.multiply(quat.conjugate(q0), q1)
    rv = rotvec_from_quaternion(d)
    theta = float(np.linalg.norm(rv))
    gain = 1.0 if theta < 1e-8 else (0.5 * theta) / math.sin(0.5 * theta)
    err = 1.01 * gain * (float(bound0) + float(bound1)) + 16 * _EPS * (1.0 + theta)
    return rv, err
