"""The gyro over a block of consecutive intervals at once: THE gyro implementation.

:meth:`rigidrot_ros.sensors.Gyro.read` is :func:`read_block` with one interval, so a
block of m intervals gives, bit for bit, what m single reads give (same seed, same
times): every step below acts on each interval's row with elementwise float64
operations, in an order that does not depend on the block.

Frames: N inertial, B body; quaternions (x, y, z, w), active, ``q_NB``; rates of B
relative to N, in B, rad/s. Times are scene seconds since t = 0.

Per interval ``[t0, t1]`` (``hh = (t1 - t0) / 2``, ``tm = (t0 + t1) / 2``):

- the Gauss rule: the fewest nodes n (of :data:`increments._NODES`) whose proved
  truncation bound (:class:`increments.RateBound`, Trefethen's Thm 19.3 on the Bernstein
  ellipses ``E_rho``, the same formula evaluated for all intervals and all rho at once)
  is at most ``tol / 2``. The bound is ``exp(L(rho) - (2 n - 2) log rho)``, linear in n
  in the log, so the fewest n comes from one pass over rho; it is then checked, and the
  bound of the chosen rule is what is stated. An interval that no single rule of up to
  32 nodes serves is integrated alone by :func:`increments.delta_angle` (subintervals);
  it does not depend on the block either.
- ``delta_angle = hh sum_j w_j omega(tm + hh x_j)``, the sum over j in a fixed order;
  its bound is the truncation bound plus the rounding bound of
  :meth:`RateBound.rounding` (same formula, vectorised) plus ``3 eps |delta_angle|``.
- ``delta_rotation = Log(q(t0)^-1 ⊗ q(t1))`` and its bound as
  :func:`increments.delta_rotation`, vectorised; the attitudes are one ``solution.at``
  call for the block's ends (the end of the previous call kept), whose samples' bits
  depend on their times alone (the core's checkpoints).
- the error model: :meth:`ImuNoise.apply` or :meth:`GyroNoise.measure` of
  ``(omega_avg, dt)`` with one dt per row, state carried from block to block.
"""

from dataclasses import dataclass
import math
import time

import numpy as np

from rigidrot_ros.core import quaternion as quat
from .imu_noise import ImuNoise
from .increments import _A_RHO, _B_RHO, _LOG_C, _LOG_RHO, _NODES, _RULES, delta_angle
from .increments import rotvec_from_quaternion

__all__ = ['GyroBlock', 'read_block', 'truncation_many', 'rounding_many',
           'delta_angle_many', 'delta_rotation_many', 'rules_from_log', 'norm3']

_EPS = np.finfo(float).eps
_LOG_2 = math.log(2.0)


@dataclass(frozen=True)
class GyroBlock:
    """Gyro samples over m consecutive intervals ``[t[i] - dt[i], t[i]]`` (rows).

    Attributes
    ----------
    t, dt : ndarray (m,)
        End of each interval and its length, s.
    omega : ndarray (m, 3)
        Measured rate, rad/s, in B.
    omega_avg : ndarray (m, 3)
        True rate averaged over the interval, ``delta_angle / dt``.
    delta_angle, delta_angle_bound : ndarray (m, 3), ndarray (m,)
        Exact ``∫ omega_B dt`` (rad, in B) and the bound on its error norm.
    delta_rotation, delta_rotation_bound : ndarray (m, 3), ndarray (m,)
        Exact ``Log(q_NB(t - dt)^-1 ⊗ q_NB(t))`` (rad, in B) and its error bound.
    bias : ndarray (m, 3)
        The bias in each sample, rad/s.
    variance : ndarray (m,)
        Per-axis variance of ``omega``: the error model's white part plus
        ``(delta_angle_bound / dt)^2``.
    quaternion : ndarray (m, 4)
        True ``q_NB`` at t.
    delta_angle_measured : ndarray (m, 3) or None
        Measured Δθ (rad) with an :class:`ImuNoise` (quantised with the carried residual
        if asked); None with a :class:`GyroNoise`.
    """

    t: np.ndarray
    dt: np.ndarray
    omega: np.ndarray
    omega_avg: np.ndarray
    delta_angle: np.ndarray
    delta_angle_bound: np.ndarray
    delta_rotation: np.ndarray
    delta_rotation_bound: np.ndarray
    bias: np.ndarray
    variance: np.ndarray
    quaternion: np.ndarray
    delta_angle_measured: np.ndarray = None

    def __len__(self):
        """Return the number of intervals."""
        return len(self.t)


def check_ends(times, sensor):
    """Return ``times`` as floats and its interval starts and ends, or refuse them.

    ``times`` must be a 1-D array of at least 2 finite, strictly increasing ends (s);
    ``sensor`` ('a gyro', 'an accelerometer') names the sensor in the error.
    """
    ts = np.asarray(times, dtype=float)
    if ts.ndim != 1 or len(ts) < 2:
        raise ValueError(f'{sensor} block needs a 1-D array of at least 2 interval ends, '
                         f'got shape {ts.shape}')
    if not np.all(np.isfinite(ts)):
        raise ValueError(f'{sensor} block needs finite interval ends')
    t0, t1 = ts[:-1], ts[1:]
    if not np.all(t1 > t0):
        i = int(np.argmin(t1 > t0))
        raise ValueError(f'{sensor} interval needs t0 < t1, got [{t0[i]!r}, {t1[i]!r}]')
    return ts, t0, t1


def norm3(v):
    """Euclidean norms of the rows of (..., 3), in one fixed order (no reduction)."""
    return np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2])


def _closed_form_log(bound, hh, atm, a_rho, b_rho, log_c):
    """``L`` of the closed-form bound at ``hh``, ``|tm|`` and ellipses (arrays that broadcast).

    Elementwise: an entry's bits depend on its own ``hh``, ``|tm|`` and rho alone, whatever
    the shape of the arrays (contiguous operands, as every caller passes them).
    """
    reach = atm + hh * a_rho
    y = hh * b_rho * (bound.c1 + bound.c2 * reach)
    big = bound.w_t + bound.m_t * reach
    log_cosh = y + np.log1p(np.exp(-2.0 * y)) - _LOG_2
    return np.log(math.sqrt(2.0) * hh) + np.log(big) + log_cosh + log_c


def _row_extreme(ufunc, a):
    """``ufunc.reduce`` of each row of ``a`` (m, k): min or max, exact in any order.

    Column by column where the rows are short (numpy reduces a short last axis row by
    row, an order of magnitude slower); NaN propagates either way.
    """
    if a.shape[1] > 16 or a.shape[1] == 0:
        return ufunc.reduce(a, axis=1)
    out = a[:, 0].copy()
    for j in range(1, a.shape[1]):
        ufunc(out, a[:, j], out=out)
    return out


def _log_bound(bound, hh, tm):
    """``L`` (m, rho): the log of the truncation bound without the ``-(2n - 2) log rho``."""
    hh = hh[:, None]
    with np.errstate(over='ignore', invalid='ignore', divide='ignore'):
        if bound.kind == 'closed-form':
            out = _closed_form_log(bound, hh, np.abs(tm)[:, None], _A_RHO, _B_RHO, _LOG_C)
        else:
            om = np.asarray(bound.solution.omega_at(tm), dtype=float)
            w = np.max(np.abs(om), axis=-1)[:, None] * (1 + 1e-12) + 1e-300
            r = hh * _A_RHO
            y = bound.majorant(w, r)
            out = np.log(math.sqrt(3.0) * hh) + np.log(y) + _LOG_C
    return np.where(np.isnan(out), np.inf, out)


def truncation_many(bound, t0, t1, n):
    """Bounds (m,) of the n-point Gauss error on each ``[t0[i], t1[i]]``, rad.

    The formula of :meth:`RateBound.truncation` (the best over rho), for arrays of
    intervals; n is one rule or one per interval (ints of :data:`increments._NODES`).
    """
    t0, t1 = np.asarray(t0, dtype=float), np.asarray(t1, dtype=float)
    hh, tm = 0.5 * (t1 - t0), 0.5 * (t0 + t1)
    if bound.kind == 'linear':
        return np.zeros(len(hh))
    return _truncation(_log_bound(bound, hh, tm), np.broadcast_to(n, hh.shape))


def _truncation(log_l, n, log_rho=_LOG_RHO):
    log_err = log_l - (2.0 * n - 2.0)[:, None] * log_rho
    with np.errstate(over='ignore'):            # a bound beyond float64 is inf
        return np.exp(_row_extreme(np.minimum, log_err))


def _rules(bound, hh, tm, tol):
    """Fewest nodes (m,) whose truncation bound is <= tol / 2 (0: none of them), bounds."""
    m = len(hh)
    if bound.kind == 'linear':                   # a linear rate: 2 nodes are exact
        return np.full(m, _NODES[0]), np.zeros(m)
    if bound.kind == 'closed-form' and m >= 2 * _GROUP:
        got = _pruned_rules(bound, hh, tm, tol)
        if got is not None:
            return got
    return rules_from_log(_log_bound(bound, hh, tm), tol)


#: Consecutive intervals whose ellipses are pruned together (:func:`_pruned_rules`).
_GROUP = 128
#: Slack on the log bounds of a group, relative (and absolute): far above their rounding.
_SLACK = 1e-9


def _pruned_rules(bound, hh, tm, tol):
    """:func:`rules_from_log` of :func:`_log_bound`, bit for bit, on the ellipses that can win.

    The closed-form ``L`` grows with ``hh`` and ``|tm|`` (``c1, c2, w_t, m_t >= 0``), so
    the rows of a group of :data:`_GROUP` lie between ``L`` at the group's smallest and at
    its largest ``(hh, |tm|)`` (with :data:`_SLACK`). An ellipse whose lower value exceeds
    the least upper value (of the rule estimate, and of the truncation of each rule the
    group can take) is the minimum of no row: its entries are left at +inf and only the
    others are evaluated, each as :func:`_log_bound` evaluates it. The minima, so the
    rules and their bounds, are the same bits. A row whose rule ends past the group's
    range is chosen again over every ellipse. None where the shortcut does not apply.
    """
    if min(bound.c1, bound.c2, bound.w_t, bound.m_t) < 0 or not np.all(hh > 0):
        return None
    m, groups = len(hh), -(-len(hh) // _GROUP)
    atm = np.abs(tm)
    pad = groups * _GROUP - m

    def ends(v):
        g = np.concatenate([v, np.full(pad, v[-1])]).reshape(groups, _GROUP)
        return g.min(axis=1)[:, None], g.max(axis=1)[:, None]
    (h_lo, h_hi), (a_lo, a_hi) = ends(hh), ends(atm)
    with np.errstate(over='ignore', invalid='ignore', divide='ignore'):
        lo = _closed_form_log(bound, h_lo, a_lo, _A_RHO, _B_RHO, _LOG_C)
        hi = _closed_form_log(bound, h_hi, a_hi, _A_RHO, _B_RHO, _LOG_C)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        return None
    lo = lo - _SLACK * (1.0 + np.abs(lo))
    hi = hi + _SLACK * (1.0 + np.abs(hi))
    target = math.log(0.5 * tol)
    f_lo = (lo - target) / (2.0 * _LOG_RHO) + 1.0
    f_hi = (hi - target) / (2.0 * _LOG_RHO) + 1.0
    keep = f_lo <= np.min(f_hi, axis=1)[:, None]
    nodes = np.array(_NODES)
    top = len(nodes) - 1
    first = np.minimum(np.searchsorted(nodes, np.min(f_lo, axis=1)), top)
    last = np.minimum(np.searchsorted(nodes, np.min(f_hi, axis=1)) + 2, top)
    for j in range(int(first.min()), int(last.max()) + 1):
        at = (first <= j) & (j <= last)
        g_lo = lo[at] - (2.0 * nodes[j] - 2.0) * _LOG_RHO
        g_hi = hi[at] - (2.0 * nodes[j] - 2.0) * _LOG_RHO
        keep[at] |= g_lo <= np.min(g_hi, axis=1)[:, None]
    # each group's ellipses in rho order, the first repeated up to the widest group's count
    count = keep.sum(axis=1)
    width = int(count.max())
    cols = np.argsort(~keep, axis=1, kind='stable')[:, :width]
    cols = np.where(np.arange(width) < count[:, None], cols, cols[:, :1])
    cols = np.repeat(cols, _GROUP, axis=0)[:m]
    with np.errstate(over='ignore', invalid='ignore', divide='ignore'):
        log_l = _closed_form_log(bound, hh[:, None], atm[:, None], _A_RHO[cols],
                                 _B_RHO[cols], _LOG_C[cols])
    log_l = np.where(np.isnan(log_l), np.inf, log_l)
    n, trunc = rules_from_log(log_l, tol, _LOG_RHO[cols])
    pick = np.where(n == 0, top, np.searchsorted(nodes, n))
    again = np.flatnonzero(pick > np.repeat(last, _GROUP)[:m])
    if len(again):
        n[again], trunc[again] = rules_from_log(_log_bound(bound, hh[again], tm[again]), tol)
    return n, trunc


def rules_from_log(log_l, tol, log_rho=_LOG_RHO):
    """Fewest nodes (m,) with ``exp(min_rho(L - (2 n - 2) log rho)) <= tol / 2``, bounds.

    ``log_l`` (m, rho): the log of a truncation bound without its ``rho^-(2n - 2)``
    factor, at the ellipses of ``log_rho`` (the logs of :data:`increments._RHO`, or of
    some of them for each row, (m, rho)); 0 nodes where no rule of up to 32 nodes serves.
    Each row's choice depends on its own row alone.
    """
    target = math.log(0.5 * tol)
    with np.errstate(invalid='ignore'):
        need = _row_extreme(np.minimum, (log_l - target) / (2.0 * log_rho) + 1.0)
    nodes = np.array(_NODES)
    pick = np.minimum(np.searchsorted(nodes, np.where(np.isnan(need), np.inf, need)),
                      len(nodes) - 1)
    n = nodes[pick]
    trunc = _truncation(log_l, n.astype(float), log_rho)
    # the log-linear shortcut can miss by a rounding: step up where the bound fails
    while True:
        bad = ~(trunc <= 0.5 * tol) & (pick < len(nodes) - 1)
        if not np.any(bad):
            break
        pick = np.where(bad, pick + 1, pick)
        n = nodes[pick]
        trunc = _truncation(log_l, n.astype(float), log_rho)
    n = np.where(trunc <= 0.5 * tol, n, 0)
    return n, trunc


def rounding_many(bound, t0, t1, n, w):
    """Float64 rounding bounds (m,) of the quadrature and the rate, rad.

    :meth:`RateBound.rounding` for arrays: intervals ``[t0, t1]``, node counts ``n``,
    largest rate norms ``w`` at the nodes (rad/s).
    """
    h = t1 - t0
    tmax = np.maximum(np.abs(t0), np.abs(t1))
    if bound.kind == 'closed-form':
        w = np.maximum(w, bound.w_t + bound.m_t * tmax + bound.r0 + bound.rdot * tmax)
        dw = (bound.c1 + bound.c2 * tmax) * (bound.w_t + bound.m_t * tmax) + bound.m_t \
            + bound.rdot
    elif bound.kind == 'linear':
        env = getattr(bound, 'envelope', None)
        if env is not None:
            dw = env.accel
        else:
            scene = bound.solution.scene
            dw = float(np.linalg.norm(np.array(scene.torque) / np.array(scene.inertia)))
    else:
        w = w * 2.0 + bound.mu * h
        dw = bound.mu + bound.c * w * w
    per_node = 32.0 * _EPS * w + _EPS * tmax * dw
    return math.sqrt(3.0) * h * (per_node + (n + 4) * _EPS * w)


def delta_angle_many(solution, t0, t1, tol, bound, deadline=None):
    """Exact ``∫ omega_B dt`` over each ``[t0[i], t1[i]]`` (rad, in B) and its bounds.

    Parameters
    ----------
    solution : rigidrot_ros.core.Solution
    t0, t1 : ndarray (m,)
        The intervals, s, ``t0 < t1``, finite.
    tol : float
        Target of each error bound, rad.
    bound : RateBound
        The solution's rate constants.
    deadline : float, optional
        A :func:`time.perf_counter` value past which the call gives up (ValueError).

    Returns
    -------
    (ndarray (m, 3), ndarray (m,))
        The delta-angles and bounds on the Euclidean norms of their errors (truncation,
        proved, plus float64 rounding). Row i depends on ``t0[i], t1[i]`` alone.
    """
    m = len(t0)
    hh, tm = 0.5 * (t1 - t0), 0.5 * (t0 + t1)
    n, trunc = _rules(bound, hh, tm, tol)
    da = np.empty((m, 3))
    w = np.zeros(m)
    for rule in np.unique(n[n != 0]).tolist():
        idx = np.flatnonzero(n == rule)
        x, wts = _RULES[rule]
        h_i, m_i = hh[idx, None], tm[idx, None]
        om = np.asarray(solution.omega_at((m_i + h_i * x).ravel()), dtype=float)
        om = om.reshape(len(idx), len(x), 3)
        total = wts[0] * om[:, 0]
        for j in range(1, len(x)):
            total = total + wts[j] * om[:, j]
        da[idx] = h_i * total
        w[idx] = _row_extreme(np.maximum, norm3(om))
    bnd = trunc + rounding_many(bound, t0, t1, n, w) + 3 * _EPS * norm3(da)
    for i in np.flatnonzero(n == 0):            # past 32 nodes: subintervals, alone
        if deadline is not None and time.perf_counter() > deadline:
            raise ValueError(f'delta_angle over [{t0[i]}, {t1[i]}] s ran out of its time '
                             f'budget; shorten the interval')
        bound.last_rule = 0
        da[i], bnd[i] = delta_angle(solution, float(t0[i]), float(t1[i]), tol=tol,
                                    bound=bound, deadline=deadline)
    return da, bnd


def delta_rotation_many(q0, q1, bound0, bound1):
    """``Log(q0^-1 ⊗ q1)`` (m, 3) (rad, in B) and bounds (m,): rows of quaternions.

    :func:`increments.delta_rotation` for arrays (same formula and bound).
    """
    d = quat.multiply(quat.conjugate(q0), q1)
    rv = rotvec_from_quaternion(d)
    theta = norm3(rv)
    with np.errstate(invalid='ignore', divide='ignore'):
        gain = np.where(theta < 1e-8, 1.0, (0.5 * theta) / np.sin(0.5 * theta))
    err = 1.01 * gain * (bound0 + bound1) + 16 * _EPS * (1.0 + theta)
    return rv, err


def _ends(gyro, times):
    """Attitudes and bounds at the block's ends; the last end is cached for the next.

    The ``solution.at`` samples of the ends it evaluated stay in ``gyro.last_ends``
    (``(times, Samples)``): offline generation takes its truth ticks on the same times
    from them.
    """
    q = np.empty((len(times), 4))
    e = np.empty(len(times))
    first = 0
    last = gyro._last
    if last is not None and last[0] == times[0]:
        q[0], e[0] = last[1], last[2]
        first = 1
    s = gyro.solution.at(times[first:])     # one call: a sample's bits depend on t alone
    q[first:], e[first:] = s.quaternion, s.error_bound
    gyro._last = (float(times[-1]), q[-1].copy(), float(e[-1]))
    gyro.last_ends = (times[first:], s)     # the samples, for a caller on the same times
    return q, e


def read_block(gyro, times, budget=None):
    """Sample the m intervals between consecutive ``times`` (m + 1 ends, s): a GyroBlock.

    Parameters
    ----------
    gyro : rigidrot_ros.sensors.Gyro
        Its solution, error model (state carried: bias, Gauss–Markov, quantisation
        residual) and tol; the attitude at the last end is kept for the next call.
    times : 1-D array of float
        Interval ends, strictly increasing, finite (at least 2).
    budget : float, optional
        Seconds the quadrature may take; past it ValueError, the noise stream untouched.

    Returns
    -------
    GyroBlock

    Raises
    ------
    ValueError
        Fewer than 2 ends, non-finite or non-increasing ends, no finite bound, or the
        budget passed (checked in the quadrature of an interval that needs subintervals,
        as :func:`increments.delta_angle` checks it).
    """
    ts, t0, t1 = check_ends(times, 'a gyro')
    deadline = None if budget is None else time.perf_counter() + budget
    dt = t1 - t0
    da, da_bound = delta_angle_many(gyro.solution, t0, t1, gyro.tol, gyro._bound,
                                    deadline=deadline)
    q, e = _ends(gyro, ts)
    dr, dr_bound = delta_rotation_many(q[:-1], q[1:], e[:-1], e[1:])
    avg = da / dt[:, None]
    noise = gyro.noise
    measured_increment = None
    if isinstance(noise, ImuNoise):
        sample = noise.apply(avg, dt)
        meas, bias, measured_increment = sample.value, sample.bias, sample.increment
    else:
        meas, bias = noise.measure(avg, dt)
    values, inverse = np.unique(dt, return_inverse=True)
    white = np.array([noise.white_variance(float(v)) for v in values])
    var = white[np.reshape(inverse, -1)] + (da_bound / dt) ** 2
    return GyroBlock(t1.copy(), dt, meas, avg, da, da_bound, dr, dr_bound, bias, var,
                     q[1:], measured_increment)
