"""Attitude error metrics of a filter over Monte Carlo runs (pure numpy, no rclpy).

Quaternions (x, y, z, w), ``q_NB``; N has its z axis up (against gravity).

- **Total error**: the angle of ``q_true^-1 ⊗ q_est`` (:func:`rigidrot_ros.scoring.score.
  rotation_error`, the scorer's body-frame error ``e``).
- **Inclination and heading** (the split of BROAD, Laidig et al., *Data* 6(7):72, 2021):
  the error rotation in N, ``q_d = q_est ⊗ q_true^-1``, is written ``q_d = q_s ⊗ q_t``
  with ``q_t`` a rotation about N's z (the *twist*, heading error ``|psi|``) and ``q_s``
  about a horizontal axis (the *swing*, inclination error, which is the angle between
  the true and the estimated vertical seen in B). ``cos(theta/2) = cos(alpha/2) cos(psi/2)``
  ties them to the total angle theta.
- **NEES** ``e^T P^-1 e`` with ``P`` the body rotation-vector covariance (the scorer's
  :func:`rigidrot_ros.scoring.score.nees`).
- **Time to converge**: the first time after which the error, RMS over the runs at each
  step, stays at or below :data:`CONVERGED` times its own RMS over the scored window.
"""

import math

import numpy as np

from rigidrot_ros.core import quaternion as quat

__all__ = ['split_error', 'run_errors', 'summarise', 'CONVERGED', 'time_to_converge',
           'mc_nees_band']

#: Time to converge: the run-RMS error stays within this factor of its level in the window.
CONVERGED = 2.0


def split_error(q_true, q_est):
    """Return ``(inclination, heading)`` error angles, rad, of (N, 4) quaternion arrays.

    Swing-twist of ``q_d = q_est ⊗ q_true^-1`` about N's z (module text). A 180 degree
    swing leaves the twist undefined: heading 0 there, inclination pi.
    """
    d = quat.multiply(np.asarray(q_est, float), quat.conjugate(np.asarray(q_true, float)))
    z, w = d[..., 2], d[..., 3]
    r = np.hypot(z, w)
    with np.errstate(invalid='ignore', divide='ignore'):
        tw = np.where(r[..., None] > 0, np.stack([np.zeros_like(z), np.zeros_like(z), z, w],
                                                 axis=-1) / np.where(r > 0, r, 1.0)[..., None],
                      np.array([0.0, 0.0, 0.0, 1.0]))
    swing = quat.multiply(d, quat.conjugate(tw))
    incl = 2.0 * np.arctan2(np.linalg.norm(swing[..., :3], axis=-1), np.abs(swing[..., 3]))
    head = 2.0 * np.arctan2(np.abs(tw[..., 2]), np.abs(tw[..., 3]))
    return incl, head


def run_errors(q_true, q_est, P=None):
    """Per-sample errors of one run: dict of (N,) arrays ``total``, ``incl``, ``head``, ``nees``.

    ``nees`` is None without a covariance; NaN where the estimate is missing.
    """
    from rigidrot_ros.scoring.score import nees, rotation_error
    q_true, q_est = np.asarray(q_true, float), np.asarray(q_est, float)
    ok = np.all(np.isfinite(q_est), axis=1)
    e = np.full((len(q_true), 3), np.nan)
    e[ok] = rotation_error(q_true[ok], q_est[ok])
    incl, head = np.full(len(q_true), np.nan), np.full(len(q_true), np.nan)
    incl[ok], head[ok] = split_error(q_true[ok], q_est[ok])
    out = {'total': np.linalg.norm(e, axis=1), 'incl': incl, 'head': head, 'nees': None}
    if P is not None:
        out['nees'] = nees(e, np.asarray(P, float))
    return out


def time_to_converge(t, rms, level, factor=CONVERGED):
    """First ``t[k]`` after which ``rms[k:] <= factor * level`` throughout; NaN if never.

    ``t[0]`` when it holds from the start.
    """
    rms = np.asarray(rms, float)
    bad = ~(rms <= factor * level)
    if not bad.any():
        return float(t[0])
    last = int(np.nonzero(bad)[0][-1])
    return float(t[last + 1]) if last + 1 < len(t) else math.nan


def mc_nees_band(m):
    """95 % band of the NEES averaged over ``m`` runs at one step: chi2(3m)/m."""
    from rigidrot_ros.scoring.score import anees_bounds
    return anees_bounds(m)


def summarise(t, errors, window_start, cpu_s=None):
    """Metrics of a filter over M runs on the same time grid ``t`` (scene s).

    Parameters
    ----------
    t : (K,) array
        Sample times, the same in every run.
    errors : list of dict
        :func:`run_errors` of each run.
    window_start : float
        Errors are scored from this time on (the start-up before it is left out).
    cpu_s : list of float, optional
        Each run's filter CPU seconds (for the cost per sample).

    Returns
    -------
    dict
        ``rmse_deg`` (total, inclination, heading), ``p95_deg``, ``max_deg``,
        ``t_converge_s``, ``runs``, ``samples``; with covariances ``anees``, its
        ``anees_bounds_95`` (over all samples, read as a check of the mean: samples are
        correlated in time), ``mc_nees_inside`` (fraction of steps whose NEES averaged
        over the runs is inside chi2(3M)/M) and ``mc_nees_band``; else ``anees`` None.
        ``us_per_sample`` (median over runs) with ``cpu_s``.
    """
    t = np.asarray(t, float)
    win = t >= window_start
    tot = np.array([e['total'] for e in errors])
    inc = np.array([e['incl'] for e in errors])
    hed = np.array([e['head'] for e in errors])
    d = math.degrees(1.0)
    w_tot = tot[:, win]
    finite = np.isfinite(w_tot)
    out = {
        'runs': len(errors), 'samples': int(finite.sum()),
        'rmse_deg': {'total': d * _rms(w_tot), 'incl': d * _rms(inc[:, win]),
                     'head': d * _rms(hed[:, win])},
        'p95_deg': d * float(np.percentile(w_tot[finite], 95)) if finite.any() else math.nan,
        'max_deg': d * float(np.max(w_tot[finite])) if finite.any() else math.nan,
    }
    curve = _rms_over_runs(tot)
    out['t_converge_s'] = time_to_converge(t, curve, out['rmse_deg']['total'] / d)
    out['rms_curve_deg'] = (d * curve).tolist()
    out['incl_curve_deg'] = (d * _rms_over_runs(inc)).tolist()
    out['head_curve_deg'] = (d * _rms_over_runs(hed)).tolist()
    if errors and errors[0]['nees'] is not None:
        from rigidrot_ros.scoring.score import anees_bounds
        nees = np.array([e['nees'] for e in errors])[:, win]
        good = np.isfinite(nees)
        out['anees'] = float(nees[good].mean()) if good.any() else math.nan
        out['anees_bounds_95'] = anees_bounds(int(good.sum())) if good.any() else None
        steps = np.all(good, axis=0)
        mc = nees[:, steps].mean(axis=0)
        band = mc_nees_band(len(errors))
        out['mc_nees_band'] = band
        out['mc_nees_inside'] = float(np.mean((mc >= band[0]) & (mc <= band[1]))) \
            if len(mc) else math.nan
        full = np.array([e['nees'] for e in errors])
        out['nees_curve'] = np.where(np.all(np.isfinite(full), axis=0),
                                     np.mean(full, axis=0), np.nan).tolist()
    else:
        out['anees'] = None
    if cpu_s is not None and np.isfinite(cpu_s).any():
        out['us_per_sample'] = 1e6 * float(np.nanmedian(cpu_s)) / len(t)
    return out


def _rms_over_runs(x):
    """RMS over the runs (axis 0) of the finite values at each step; NaN where none."""
    ok = np.isfinite(x)
    n = ok.sum(axis=0)
    total = np.where(ok, x, 0.0) ** 2
    return np.where(n > 0, np.sqrt(total.sum(axis=0) / np.maximum(n, 1)), np.nan)


def _rms(x):
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if len(x) else math.nan
