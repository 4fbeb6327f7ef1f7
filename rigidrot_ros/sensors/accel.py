"""An accelerometer on the exact motion: the specific force at the IMU and its exact Δv.

Frames: N inertial, B body; ``R_NB`` means ``v_N = R_NB @ v_B`` (so ``R_BN = R_NB^T``).
Quaternions (x, y, z, w), active, ``q_NB``; ``omega`` is the rate of B relative to N, in
B, rad/s. The body turns about a point O that does not accelerate (its centre of mass
in free flight, or the supported pivot of an air-bearing table or a gimbal); the IMU
sits at ``r`` (the lever arm, m, in B) from O. Its specific force (what an
accelerometer measures, acceleration minus gravity), in B, m/s^2::

    f_B = omega_dot x r + omega x (omega x r) - R_BN g_N

with ``omega_dot`` exact from Euler's equations with the model's torque
(:meth:`Solution.omega_dot_at`) and ``g_N`` the gravity in N (m/s^2): ``(0, 0, 0)`` for a
free-flying body (only the lever-arm terms remain), ``(0, 0, -9.80665)`` for a body on
a supported point with N's z up, so that an accelerometer at rest reads +9.80665 m/s^2
along the up axis (REP 145).

Over an interval ``[t0, t1]`` a rate-integrating accelerometer reports
``Δv = ∫ f_B dt`` (m/s, in B), evaluated here exactly:

- ``∫ omega_dot x r dt = (omega(t1) - omega(t0)) x r``, no quadrature;
- ``∫ omega x (omega x r) dt`` and ``∫ R_BN g_N dt`` by Gauss–Legendre quadrature
  with a proved truncation bound (Trefethen, *ATAP*, Thm 19.3, as
  :mod:`.increments` for Δθ): on the Bernstein ellipse ``E_rho`` the complex rate obeys
  ``|omega| <= W(rho)`` (from the closed forms of Romano 2008, or Cauchy's majorant of
  Euler's equations; :func:`rate_bound_on_ellipse`), so the centripetal integrand is at
  most ``2 |r| W^2``; ``h = R_BN g_N`` solves ``h' = -omega x h`` with ``|h| = |g|`` on
  the real axis, so by Grönwall along vertical segments
  ``|h| <= |g| exp(sqrt(2) W hh B_rho)`` (``hh`` the half interval, ``B_rho`` the
  ellipse's semi-minor axis, ``sqrt(2)`` the complex cross product's norm).
  The attitude's own error bound ``e`` (rad) adds ``|g| e (t1 - t0)``, float64 rounding
  a few ulp per node.

A block of consecutive intervals is read at once (:meth:`Accelerometer.read_many`,
:func:`delta_velocity_many`): the rule of each interval from one vectorised pass over
the ellipses, the nodes of all intervals of one rule in one ``omega_at`` and one
``solution.at`` call, sums over the nodes in a fixed order, elementwise products only
(no BLAS), so a row's bits depend on its interval alone; :meth:`Accelerometer.read` is
the block of one interval (the gyro's arrangement, :mod:`.batch`).
"""

from dataclasses import dataclass
import math
import time

import numpy as np

from rigidrot_ros.core import quaternion as quat
from .batch import check_ends, norm3, rules_from_log
from .imu_noise import ImuNoise
from .increments import _A_RHO, _B_RHO, _LOG_C, _LOG_RHO, _MAX_PIECES, _NODES, _RHO, _RULES
from .increments import RateBound
from .noise import check_vector

__all__ = ['Accelerometer', 'AccelReading', 'AccelBlock', 'specific_force', 'delta_velocity',
           'delta_velocity_many', 'rate_bound_on_ellipse', 'DV_TOL', 'STANDARD_GRAVITY',
           'MAX_LEVER_ARM', 'MAX_GRAVITY']

#: Default target of the Δv error bound, m/s.
DV_TOL = 1e-13
#: Standard gravity (CGPM 1901), m/s^2.
STANDARD_GRAVITY = 9.80665
#: Largest accepted lever-arm component, m; largest gravity component, m/s^2.
MAX_LEVER_ARM = 1e3
MAX_GRAVITY = 1e3
_EPS = np.finfo(float).eps
_RHO_FULL = _A_RHO + _B_RHO          # = rho: |t - tm| <= hh rho on the ellipse's box


def check_lever_arm(value, name='accel.lever_arm'):
    """Return the lever arm (m, in B) as a float 3-vector, |r_i| <= 1e3 m."""
    return check_vector(name, value, MAX_LEVER_ARM)


def check_gravity(value, name='accel.gravity'):
    """Return gravity (m/s^2, in N) as a float 3-vector, |g_i| <= 1e3 m/s^2."""
    return check_vector(name, value, MAX_GRAVITY)


def rate_bound_on_ellipse(bound, t0, t1):
    """Bound ``W(rho)`` of the complex rate norm on the box around each Bernstein ellipse.

    Parameters
    ----------
    bound : RateBound
        The solution's rate constants (:mod:`.increments`).
    t0, t1 : float
        The real interval; the ellipses ``E_rho`` (``rho`` in ``increments._RHO``) have
        foci t0, t1, and the bound holds on the box ``|Re t - tm| <= hh A_rho``,
        ``|Im t| <= hh B_rho`` that contains each (so also on vertical segments from the
        real axis).

    Returns
    -------
    ndarray
        ``W`` per rho (rad/s; inf where no bound exists).
    """
    hh, tm = 0.5 * (t1 - t0), 0.5 * (t0 + t1)
    reach = abs(tm) + hh * _RHO_FULL
    with np.errstate(over='ignore', invalid='ignore'):
        if bound.kind in ('linear', 'closed-form'):
            return _closed_rate(bound, hh, reach)
        w = float(np.max(np.abs(bound.solution.omega_at(tm))))
        w = w * (1 + 1e-12) + 1e-300
        return math.sqrt(3.0) * bound.majorant(w, hh * _RHO_FULL)


def _closed_rate(bound, hh, reach):
    """``W`` of a linear or closed-form rate, given ``hh`` and ``reach`` shaped alike, rad/s.

    ``reach`` is the largest ``|t|`` on each ellipse; the caller sets ``np.errstate``.
    """
    if bound.kind == 'linear':
        scene = bound.solution.scene
        w0 = float(np.linalg.norm(scene.omega0))
        wd = float(np.linalg.norm(np.asarray(scene.torque) / np.asarray(scene.inertia)))
        return w0 + wd * reach
    y = hh * _B_RHO * (bound.c1 + bound.c2 * reach)           # max |Im f|
    trans = (bound.w_t + bound.m_t * reach) * np.cosh(y)
    axial = bound.r0 + bound.rdot * reach
    return np.sqrt(2.0 * trans * trans + axial * axial)


def _truncation(bound, t0, t1, n, lever, grav):
    """Best bound over rho of the n-point Gauss error of the two quadratures, m/s."""
    hh = 0.5 * (t1 - t0)
    w = rate_bound_on_ellipse(bound, t0, t1)
    log_scale = _LOG_C - (2 * n - 2) * _LOG_RHO + math.log(math.sqrt(3.0) * hh)
    with np.errstate(over='ignore', divide='ignore', invalid='ignore'):
        terms = np.zeros_like(_RHO)
        if lever > 0.0 and not (bound.kind == 'linear' and n >= 2):
            # a linear rate makes the centripetal term a quadratic: exact for n >= 2
            terms = terms + np.exp(np.log(2.0 * lever) + 2.0 * np.log(w) + log_scale)
        if grav > 0.0:
            terms = terms + np.exp(math.log(grav) + math.sqrt(2.0) * w * hh * _B_RHO
                                   + log_scale)
        terms = np.where(np.isnan(terms), np.inf, terms)
    return float(np.min(terms, initial=np.inf))


def _nodes(t0, t1, pieces, n):
    edges = np.linspace(t0, t1, pieces + 1)
    edges[0], edges[-1] = t0, t1
    x, wts = _RULES[n]
    hh = 0.5 * (edges[1:] - edges[:-1])
    tm = 0.5 * (edges[1:] + edges[:-1])
    ts = (tm[:, None] + hh[:, None] * x[None, :]).ravel()
    ws = (hh[:, None] * wts[None, :]).ravel()
    return edges, ts, ws


def delta_velocity(solution, t0, t1, lever_arm, gravity, tol=DV_TOL, bound=None,
                   deadline=None):
    """Return the exact ``Δv = ∫_{t0}^{t1} f_B dt`` (m/s, in B) and its error bound.

    Parameters
    ----------
    solution : rigidrot_ros.core.Solution
        The exact motion (``omega_at``, ``at``).
    t0, t1 : float
        The interval, s, ``t0 <= t1``, finite.
    lever_arm : 3 floats
        ``r``, the IMU's position in B from the point the body turns about, m.
    gravity : 3 floats
        ``g_N``, gravity in N, m/s^2.
    tol : float
        Target of the truncation bound, m/s (default 1e-13).
    bound : RateBound, optional
        Reuse the per-solution constants across calls.
    deadline : float, optional
        A :func:`time.perf_counter` value past which the call gives up (ValueError).

    Returns
    -------
    (ndarray (3,), float)
        Δv in B (m/s) and a bound on the Euclidean norm of its error (truncation,
        proved; the attitude's error bound carried; float64 rounding).

    Examples
    --------
    >>> from rigidrot_ros.core import Scene, solve
    >>> sol = solve(Scene(omega0=(0.0, 0.0, 2.0)))
    >>> dv, err = delta_velocity(sol, 0.0, 0.5, (1.0, 0.0, 0.0), (0.0, 0.0, -9.80665))
    >>> [round(float(v), 12) for v in dv]       # centripetal -omega^2 r t, gravity along z
    [-2.0, 0.0, 4.903325]
    """
    t0, t1 = float(t0), float(t1)
    if not (math.isfinite(t0) and math.isfinite(t1)):
        raise ValueError(f'delta_velocity needs finite times, got [{t0!r}, {t1!r}]')
    if t1 < t0:
        raise ValueError(f'delta_velocity needs t0 <= t1, got [{t0!r}, {t1!r}]')
    r = check_lever_arm(lever_arm)
    g = check_gravity(gravity)
    if t1 == t0:
        return np.zeros(3), 0.0
    lever, grav = float(np.linalg.norm(r)), float(np.linalg.norm(g))
    w_ends = np.asarray(solution.omega_at(np.array([t0, t1])), dtype=float)
    # the angular-acceleration term integrates in closed form
    tangential = np.cross(w_ends[1] - w_ends[0], r)
    w_max = float(np.max(np.linalg.norm(w_ends, axis=-1)))
    rnd = (64.0 * _EPS * w_max + 2 * _EPS * float(np.linalg.norm(w_ends[1] - w_ends[0]))) \
        * lever
    if lever == 0.0 and grav == 0.0:
        return tangential, rnd
    bound = bound or RateBound(solution)
    pieces = 1
    while pieces <= _MAX_PIECES:
        for n in _NODES:
            if deadline is not None and time.perf_counter() > deadline:
                raise ValueError(f'delta_velocity over [{t0}, {t1}] s ran out of its time '
                                 f'budget ({pieces} subintervals of {n} nodes)')
            edges = np.linspace(t0, t1, pieces + 1)
            trunc = sum(_truncation(bound, a, b, n, lever, grav)
                        for a, b in zip(edges[:-1], edges[1:]))
            if trunc <= 0.5 * tol:
                return _evaluate(solution, t0, t1, pieces, n, r, g, tangential,
                                 trunc + rnd)
        pieces *= 2
    raise ValueError(f'delta_velocity over [{t0}, {t1}] s cannot reach {tol:g} m/s within '
                     f'{_MAX_PIECES} subintervals; shorten the interval')


def _evaluate(solution, t0, t1, pieces, n, r, g, tangential, err):
    _, ts, ws = _nodes(t0, t1, pieces, n)
    h = t1 - t0
    total = tangential.copy()
    scale = 0.0
    if np.any(r != 0.0):
        om = np.asarray(solution.omega_at(ts), dtype=float)
        cen = np.cross(om, np.cross(om, r))
        total = total + ws @ cen
        w = float(np.max(np.linalg.norm(om, axis=-1)))
        # rate rounding (32 eps |w| per node, as in increments) through 2 |w| |r|
        err += h * 64.0 * _EPS * w * w * float(np.linalg.norm(r))
        scale = max(scale, w * w * float(np.linalg.norm(r)))
    if np.any(g != 0.0):
        s = solution.at(ts)
        r_nb = quat.to_matrix(np.asarray(s.quaternion, dtype=float))
        g_b = np.einsum('kji,j->ki', r_nb, g)             # R_BN g_N = R_NB^T g_N
        total = total - ws @ g_b
        gn = float(np.linalg.norm(g))
        err += h * gn * float(np.max(s.error_bound))      # the attitude's own error
        scale = max(scale, gn)
    err += math.sqrt(3.0) * h * (len(ts) + 24) * _EPS * scale \
        + 4 * _EPS * float(np.linalg.norm(total))
    return total, err


def specific_force(solution, t, lever_arm, gravity):
    """Return ``f_B(t) = omega_dot x r + omega x (omega x r) - R_BN g_N`` (m/s^2, in B).

    Parameters
    ----------
    solution : rigidrot_ros.core.Solution
        Needs ``omega_at``, ``omega_dot_at`` and ``at``.
    t : float or 1-D array
        Seconds since t = 0.
    lever_arm, gravity : 3 floats
        ``r`` in B (m) and ``g_N`` in N (m/s^2).

    Returns
    -------
    (ndarray (..., 3), ndarray (...,))
        The specific force and a bound on its error norm: the attitude's error bound
        times ``|g|``, plus a rounding allowance of 64 ulp of the largest term.
    """
    r = check_lever_arm(lever_arm)
    g = check_gravity(gravity)
    tt = np.asarray(t, dtype=float)
    w = np.asarray(solution.omega_at(tt), dtype=float)
    wd = np.asarray(solution.omega_dot_at(tt), dtype=float)
    # elementwise throughout: a sample's bits depend on its t alone, in any batch
    f = _cross(wd, r) + _cross(w, _cross(w, r))
    lever = float(norm3(r))
    size = (norm3(wd) + (w[..., 0] * w[..., 0] + w[..., 1] * w[..., 1]
                         + w[..., 2] * w[..., 2])) * lever
    err = np.zeros(np.shape(tt))
    if np.any(g != 0.0):
        s = solution.at(tt)
        f = f - _gravity_in_body(np.asarray(s.quaternion, dtype=float), g)
        gn = float(norm3(g))
        err = err + gn * np.asarray(s.error_bound, dtype=float)
        size = size + gn
    return f, err + 64.0 * _EPS * size


def _cross(a, b):
    """Return ``a x b`` over the last axis by elementwise products (no BLAS)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _gravity_in_body(q, g):
    """``R_BN g_N = R_NB^T g_N`` (..., 3) of quaternions ``q_NB`` (..., 4), elementwise."""
    m = quat.to_matrix(q)
    return np.stack([m[..., 0, i] * g[0] + m[..., 1, i] * g[1] + m[..., 2, i] * g[2]
                     for i in range(3)], axis=-1)


def _ellipse_rate_many(bound, t0, t1):
    """:func:`rate_bound_on_ellipse` for arrays of intervals: ``W`` (m, rho), rad/s."""
    hh, tm = 0.5 * (t1 - t0), 0.5 * (t0 + t1)
    reach = np.abs(tm)[:, None] + hh[:, None] * _RHO_FULL
    with np.errstate(over='ignore', invalid='ignore'):
        if bound.kind in ('linear', 'closed-form'):
            return _closed_rate(bound, hh[:, None], reach)
        om = np.asarray(bound.solution.omega_at(tm), dtype=float).reshape(len(tm), 3)
        w = np.max(np.abs(om), axis=-1)[:, None] * (1 + 1e-12) + 1e-300
        return math.sqrt(3.0) * bound.majorant(w, hh[:, None] * _RHO_FULL)


def _log_truncation_many(bound, t0, t1, lever, grav):
    """``L`` (m, rho): the log of :func:`_truncation`'s sum without ``rho^-(2n - 2)``.

    The same two terms (centripetal ``2 |r| W^2``, gravity ``|g| exp(sqrt 2 W hh B_rho)``,
    each times ``64 / (15 (rho^2 - 1)) sqrt 3 hh``), added in the log (logaddexp).
    """
    hh = 0.5 * (t1 - t0)
    w = _ellipse_rate_many(bound, t0, t1)
    with np.errstate(over='ignore', divide='ignore', invalid='ignore'):
        base = _LOG_C + np.log(math.sqrt(3.0) * hh)[:, None]
        out = np.full(w.shape, -np.inf)
        if lever > 0.0 and bound.kind != 'linear':
            # a linear rate makes the centripetal term a quadratic: exact for n >= 2
            out = np.logaddexp(out, math.log(2.0 * lever) + 2.0 * np.log(w) + base)
        if grav > 0.0:
            out = np.logaddexp(out, math.log(grav) + math.sqrt(2.0) * w * hh[:, None] * _B_RHO
                               + base)
    return np.where(np.isnan(out), np.inf, out)


def delta_velocity_many(solution, t0, t1, lever_arm, gravity, tol=DV_TOL, bound=None,
                        deadline=None):
    """Exact ``Δv = ∫ f_B dt`` over each ``[t0[i], t1[i]]`` (m/s, in B) and its bounds.

    :func:`delta_velocity` for arrays of intervals, one row at a time in effect: each
    row's rule (the fewest Gauss nodes whose proved truncation bound is at most
    ``tol / 2``, on the whole interval), nodes, sums (over the nodes in a fixed order)
    and bound depend on ``t0[i], t1[i]`` alone, never on the block. A row that no single
    rule of up to 32 nodes serves is integrated alone by :func:`delta_velocity`
    (subintervals). The bound of a row is the one :func:`delta_velocity` states for the
    same rule: truncation (proved), the attitude's own error times ``|g| h``, float64
    rounding of the rate (32 ulp per node through ``2 |w| |r|``), of the sums
    (``sqrt 3 h (n + 24) eps`` of the largest integrand) and of the result (4 ulp).

    Parameters
    ----------
    solution : rigidrot_ros.core.Solution
    t0, t1 : ndarray (m,)
        The intervals, s, ``t0 < t1``, finite.
    lever_arm, gravity : 3 floats
        ``r`` in B (m) and ``g_N`` in N (m/s^2).
    tol : float
        Target of each truncation bound, m/s.
    bound : RateBound, optional
        The solution's rate constants.
    deadline : float, optional
        A :func:`time.perf_counter` value past which a subdivided row gives up (ValueError).

    Returns
    -------
    (ndarray (m, 3), ndarray (m,))
        The Δv rows and bounds on the Euclidean norms of their errors.
    """
    t0 = np.asarray(t0, dtype=float).reshape(-1)
    t1 = np.asarray(t1, dtype=float).reshape(-1)
    r = check_lever_arm(lever_arm)
    g = check_gravity(gravity)
    m = len(t0)
    lever, grav = float(norm3(r)), float(norm3(g))
    ends = np.concatenate([t0, t1])
    w_ends = np.asarray(solution.omega_at(ends), dtype=float).reshape(2 * m, 3)
    w0, w1 = w_ends[:m], w_ends[m:]
    tangential = _cross(w1 - w0, r)       # the angular-acceleration term, closed form
    w_max = np.maximum(norm3(w0), norm3(w1))
    err = (64.0 * _EPS * w_max + 2 * _EPS * norm3(w1 - w0)) * lever
    if lever == 0.0 and grav == 0.0:
        return tangential, err
    bound = bound or RateBound(solution)
    n, trunc = rules_from_log(_log_truncation_many(bound, t0, t1, lever, grav), tol)
    total = tangential.copy()
    err = err + trunc
    for rule in np.unique(n[n != 0]).tolist():
        _add_rule(solution, rule, np.flatnonzero(n == rule), t0, t1, r, g, total, err)
    for i in np.flatnonzero(n == 0):            # past 32 nodes: subintervals, alone
        total[i], err[i] = delta_velocity(solution, float(t0[i]), float(t1[i]), r, g,
                                          tol=tol, bound=bound, deadline=deadline)
    return total, err


def _add_rule(solution, rule, idx, t0, t1, r, g, total, err):
    """Add the ``rule``-node Gauss sums and their bounds to rows ``idx`` of total, err.

    In place; the rows' centripetal term (if ``|r| > 0``) and gravity term (if
    ``|g| > 0``), each summed over the nodes in order, then the rounding of the sums.
    """
    lever, grav = float(norm3(r)), float(norm3(g))
    hh, tm, h = 0.5 * (t1 - t0), 0.5 * (t0 + t1), t1 - t0
    x, wts = _RULES[rule]
    h_i = hh[idx, None]
    ts = (tm[idx, None] + h_i * x).ravel()
    ws = h_i * wts                                    # (k, n): hh w_j, as _nodes
    part, e = total[idx], err[idx]
    scale = np.zeros(len(idx))
    if lever > 0.0:
        om = np.asarray(solution.omega_at(ts), dtype=float).reshape(len(idx), rule, 3)
        part = part + _node_sum(ws, _cross(om, _cross(om, r)))
        w = np.max(norm3(om), axis=1)
        e = e + h[idx] * 64.0 * _EPS * w * w * lever
        scale = np.maximum(scale, w * w * lever)
    if grav > 0.0:
        s = solution.at(ts)
        g_b = _gravity_in_body(np.asarray(s.quaternion, dtype=float), g)
        part = part - _node_sum(ws, g_b.reshape(len(idx), rule, 3))
        eb = np.asarray(s.error_bound, dtype=float).reshape(len(idx), rule)
        e = e + h[idx] * grav * np.max(eb, axis=1)
        scale = np.maximum(scale, grav)
    e = e + math.sqrt(3.0) * h[idx] * (rule + 24) * _EPS * scale \
        + 4 * _EPS * norm3(part)
    total[idx], err[idx] = part, e


def _node_sum(ws, vals):
    """Return ``sum_j ws[:, j] vals[:, j]`` over the nodes j in order: (k, n), (k, n, 3)."""
    acc = ws[:, 0, None] * vals[:, 0]
    for j in range(1, vals.shape[1]):
        acc = acc + ws[:, j, None] * vals[:, j]
    return acc


@dataclass(frozen=True)
class AccelReading:
    """One accelerometer sample over ``[t - dt, t]`` (all vectors in B).

    Attributes
    ----------
    t, dt : float
        End of the interval and its length, s.
    specific_force : ndarray (3,)
        Measured specific force, m/s^2: the error model applied to ``specific_force_avg``
        (what goes into ``Imu.linear_acceleration``).
    specific_force_avg : ndarray (3,)
        True ``Δv / dt``, m/s^2.
    specific_force_true : ndarray (3,)
        True instantaneous ``f_B(t)``, m/s^2.
    delta_velocity, delta_velocity_bound : ndarray (3,), float
        Exact ``∫ f_B dt`` (m/s) and the bound on its error norm.
    delta_velocity_measured : ndarray (3,)
        Measured Δv (m/s), quantised with the carried residual if asked.
    bias : ndarray (3,)
        The bias in this sample, m/s^2.
    variance : float
        Per-axis variance of ``specific_force``, (m/s^2)^2: the white part of the error
        model plus the square of the true average's error bound.
    """

    t: float
    dt: float
    specific_force: np.ndarray
    specific_force_avg: np.ndarray
    specific_force_true: np.ndarray
    delta_velocity: np.ndarray
    delta_velocity_bound: float
    delta_velocity_measured: np.ndarray
    bias: np.ndarray
    variance: float


@dataclass(frozen=True)
class AccelBlock:
    """Accelerometer samples over m consecutive intervals ``[t[i] - dt[i], t[i]]`` (rows).

    The fields of :class:`AccelReading`, one row per interval (vectors (m, 3) in B,
    scalars (m,)).
    """

    t: np.ndarray
    dt: np.ndarray
    specific_force: np.ndarray
    specific_force_avg: np.ndarray
    specific_force_true: np.ndarray
    delta_velocity: np.ndarray
    delta_velocity_bound: np.ndarray
    delta_velocity_measured: np.ndarray
    bias: np.ndarray
    variance: np.ndarray

    def __len__(self):
        """Return the number of intervals."""
        return len(self.t)


class Accelerometer:
    """A rate-integrating accelerometer at ``lever_arm`` on the exact motion.

    Parameters
    ----------
    solution : rigidrot_ros.core.Solution
    noise : ImuNoise, optional
        Its error model, ``kind='accel'`` (default: ideal).
    lever_arm : 3 floats
        The IMU's position in B from the point the body turns about, m.
    gravity : 3 floats
        Gravity in N, m/s^2 (default zero: a free-flying body).
    tol : float
        Target of the Δv truncation bound, m/s.

    Examples
    --------
    >>> from rigidrot_ros.core import Scene, solve
    >>> acc = Accelerometer(solve(Scene()), gravity=(0.0, 0.0, -STANDARD_GRAVITY))
    >>> [float(v) for v in acc.read(0.0, 0.01).specific_force]     # at rest: +g up
    [0.0, 0.0, 9.80665]
    """

    def __init__(self, solution, noise=None, lever_arm=(0.0, 0.0, 0.0),
                 gravity=(0.0, 0.0, 0.0), tol=DV_TOL):
        self.solution = solution
        self.noise = noise if noise is not None else ImuNoise(kind='accel')
        if not isinstance(self.noise, ImuNoise) or self.noise.kind != 'accel':
            raise ValueError("an Accelerometer needs ImuNoise(kind='accel') as its noise")
        self.lever_arm = check_lever_arm(lever_arm)
        self.gravity = check_gravity(gravity)
        self.tol = tol
        self._bound = RateBound(solution)

    def reset(self):
        """Restart the noise stream."""
        self.noise.reset()

    def read(self, t0, t1, budget=None):
        """Sample ``[t0, t1]`` (s, ``t0 < t1``): an :class:`AccelReading`.

        ``budget`` (s, optional) bounds the quadrature's time; past it the read raises
        ValueError and leaves the noise stream untouched. The one-interval case of
        :meth:`read_many` (the same bits, sample by sample).
        """
        t0, t1 = float(t0), float(t1)
        if not t1 > t0:
            raise ValueError(f'an accelerometer interval needs t0 < t1, got [{t0!r}, '
                             f'{t1!r}]')
        b = self.read_many(np.array([t0, t1]), budget=budget)
        return AccelReading(t1, float(b.dt[0]), b.specific_force[0], b.specific_force_avg[0],
                            b.specific_force_true[0], b.delta_velocity[0],
                            float(b.delta_velocity_bound[0]), b.delta_velocity_measured[0],
                            b.bias[0], float(b.variance[0]))

    def read_many(self, times, budget=None):
        """Sample the m intervals between consecutive ``times`` (m + 1 ends, s) at once.

        Parameters
        ----------
        times : 1-D array of float
            Interval ends, strictly increasing, finite (at least 2).
        budget : float, optional
            Seconds the quadrature may take; past it ValueError, the noise stream untouched.

        Returns
        -------
        AccelBlock
            Bit for bit the m readings :meth:`read` gives over the same intervals (the
            error model's state carried either way): every row's Δv, bound and specific
            force depend on its own interval alone (:func:`delta_velocity_many`).
        """
        ts, t0, t1 = check_ends(times, 'an accelerometer')
        deadline = None if budget is None else time.perf_counter() + budget
        dt = t1 - t0
        dv, dv_bound = delta_velocity_many(self.solution, t0, t1, self.lever_arm,
                                           self.gravity, tol=self.tol, bound=self._bound,
                                           deadline=deadline)
        f_true = specific_force(self.solution, t1, self.lever_arm, self.gravity)[0]
        avg = dv / dt[:, None]
        sample = self.noise.apply(avg, dt)
        values, inverse = np.unique(dt, return_inverse=True)
        white = np.array([self.noise.white_variance(float(v)) for v in values])
        var = white[np.reshape(inverse, -1)] + (dv_bound / dt) ** 2
        return AccelBlock(t1.copy(), dt, sample.value, avg, f_true, dv, dv_bound,
                          sample.increment, sample.bias, var)
