"""What the viewer shows, computed from decoded streams and run descriptions (no rerun, no rclpy).

Quaternions are (x, y, z, w), active, ``q_NB`` (``v_N = R_NB @ v_B``); rates are omega of
B relative to N, in B, rad/s; times are integer nanosecond stamps. The truth at a stamp
is the exact solution of the run that holds it, recomputed from the run description as
the scorer does (:func:`rigidrot_ros.scoring.score.scene_times`, the same ``Scene`` and
``solve`` call); errors follow the scorer's conventions:

- attitude error ``e`` in B with ``q_true^-1 ⊗ q_est = exp(e / 2)``
  (:func:`~rigidrot_ros.scoring.score.rotation_error`), its angle ``|e|`` in rad;
- its 3σ: ``3 sqrt(lambda_max(P))`` with ``P`` the orientation covariance of the message
  (the standard deviation along the covariance's longest axis: an isotropic ``P = s^2 I``
  gives ``3 s``);
- ``NEES = e^T P^-1 e`` (:func:`~rigidrot_ros.scoring.score.nees`); one sample's 95 % band is
  that of chi-square with 3 degrees of freedom, ``[0.216, 9.35]``
  (:func:`~rigidrot_ros.scoring.score.anees_bounds` with one sample);
- gyro residual ``omega_meas - omega_true`` in B, rad/s; star tracker residual: the
  attitude error ``e`` of its measurement, rad.
"""

from dataclasses import dataclass, field

import numpy as np

from rigidrot_ros.bag import BagContents
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.scoring.decode import ORIENTATION, RATE
from rigidrot_ros.scoring.score import (
    anees_bounds, nees, rotation_error, scene_times, ScoreError, TRUTH_NAMES,
)

__all__ = ['Truth', 'box_half_sizes', 'attitude_errors', 'rate_residual',
           'topic_roles', 'NEES_BAND_1', 'Roles', 'ESTIMATE', 'GYRO', 'STAR', 'TRUTH',
           'RATE_ESTIMATE', 'node_topics']

#: 95 % band of one sample's NEES (chi-square, 3 degrees of freedom).
NEES_BAND_1 = tuple(anees_bounds(1))

TRUTH, GYRO, STAR, ESTIMATE, RATE_ESTIMATE = (
    'truth', 'gyro', 'star_tracker', 'estimate', 'rate_estimate')


def box_half_sizes(inertia, floor=0.05):
    """Half sizes of the uniform box with these principal moments, scaled to a longest 1.

    A box of mass m and half sizes (a, b, c) along its principal axes has
    ``I1 = m (b^2 + c^2) / 3`` and its permutations, so ``a^2 ∝ I2 + I3 - I1`` (the
    triangle inequality keeps it >= 0). A flat body (``I1 + I2 = I3``) gets ``floor``
    instead of 0, so it is still drawn.

    Examples
    --------
    >>> box_half_sizes([2.0, 2.0, 1.0]).round(3).tolist()
    [0.378, 0.378, 1.0]
    """
    i1, i2, i3 = (float(x) for x in inertia)
    sq = np.array([i2 + i3 - i1, i1 + i3 - i2, i1 + i2 - i3])
    half = np.sqrt(np.clip(sq, 0.0, None))
    top = half.max()
    if not top > 0:
        return np.ones(3)
    return np.maximum(half / top, floor)


class Truth:
    """The exact truth of a log's runs at any stamps, each run solved once.

    Parameters
    ----------
    runs : list of dict
        Run descriptions (``~/run`` JSON or ``rigidrot_run`` records).
    path : str
        Named in errors.
    """

    def __init__(self, runs, path='live'):
        self.bag = BagContents(path=path, runs=list(runs))
        self._solutions = {}

    @property
    def runs(self):
        """Return the run descriptions."""
        return self.bag.runs

    def add_run(self, run):
        """Take a new run description (a reset of the node); False if already known."""
        key = (str(run.get('node', '')), int(run['start_ns']))
        if any((str(r.get('node', '')), int(r['start_ns'])) == key for r in self.bag.runs):
            return False
        self.bag.runs.append(run)
        return True

    def solution(self, run):
        """Return the core solution of ``run`` (solved on first use, as the scorer does)."""
        key = (str(run.get('node', '')), int(run['start_ns']))
        if key not in self._solutions:
            try:
                scene = Scene.from_dict(run['scene'])
                self._solutions[key] = solve(scene, tol=float(run.get('tol', 1e-12)),
                                             backend=run.get('backend'))
            except (ValueError, KeyError, TypeError, ArithmeticError) as exc:
                raise ScoreError(f'{self.bag.path}: run {run.get("run", "?")} has an '
                                 f'unusable scene: {exc}') from None
        return self._solutions[key]

    def at(self, stamps, topic=None):
        """Return ``(t, q_NB, omega_BN_B)`` at integer ns ``stamps``; NaN outside every run.

        ``t`` is the scene time (s) of each stamp in its run; ``topic`` selects the run's
        sensor timing model (a clock offset is undone, as the scorer does).
        """
        stamps = np.asarray(stamps, dtype=np.int64)
        idx, t, runs = scene_times(self.bag, stamps, topic)
        q = np.full((len(stamps), 4), np.nan)
        w = np.full((len(stamps), 3), np.nan)
        for i, run in enumerate(runs):
            sel = np.nonzero(idx == i)[0]
            if len(sel):
                s = self.solution(run).at(t[sel])
                q[sel] = s.quaternion
                w[sel] = s.omega
        return t, q, w

    def inertia(self):
        """Return the principal moments of the latest run (kg m^2), or None."""
        if not self.bag.runs:
            return None
        run = max(self.bag.runs, key=lambda r: int(r['start_ns']))
        return run.get('scene', {}).get('inertia')


def attitude_errors(q_true, q_est, cov=None):
    """Return ``(e, angle, bound3, nees)`` of estimates against the truth.

    ``e`` (N, 3) rad in B; ``angle`` ``|e|``; ``bound3`` ``3 sqrt(lambda_max(P))`` and
    ``nees`` ``e^T P^-1 e``, NaN where a sample has no usable covariance (all NaN when
    ``cov`` is None).
    """
    e = rotation_error(q_true, q_est)
    angle = np.linalg.norm(e, axis=-1)
    n = len(angle)
    if cov is None:
        return e, angle, np.full(n, np.nan), np.full(n, np.nan)
    cov = np.asarray(cov, dtype=float)
    bound = np.full(n, np.nan)
    ok = np.all(np.isfinite(cov.reshape(n, -1)), axis=1)
    if ok.any():
        bound[ok] = 3.0 * np.sqrt(np.clip(np.linalg.eigvalsh(cov[ok])[:, -1], 0.0, None))
    return e, angle, bound, nees(e, cov)


def rate_residual(omega_true, omega_meas):
    """Return ``omega_meas - omega_true`` (N, 3), rad/s in B."""
    return np.asarray(omega_meas, dtype=float) - np.asarray(omega_true, dtype=float)


def node_topics(runs):
    """Return the topics the runs' node publishes (from the run descriptions)."""
    out = set()
    for r in runs:
        topics = r.get('topics') or {}
        out.update(topics.keys() if all(str(k).startswith('/') for k in topics)
                   else topics.values())
    return out


@dataclass
class Roles:
    """What each stream of a log is shown as; ``notes`` say what was chosen and why."""

    by_label: dict = field(default_factory=dict)   # stream label -> role
    notes: list = field(default_factory=list)


def topic_roles(streams, runs):
    """Sort streams into truth, gyro, star tracker, estimates and estimated rates.

    The node's exact topics (:data:`~rigidrot_ros.scoring.score.TRUTH_NAMES`) are the truth
    (the box shows the recomputed solution, which they equal); its ``imu`` rate is the
    gyro and its ``star_tracker`` the star tracker; any other attitude stream is an
    estimate, any other rate stream an estimated rate. Without an estimate, the star
    tracker's measurement (it carries a covariance) stands in for one.
    """
    own = node_topics(runs)
    roles = Roles()
    for s in streams:
        name = s.topic.rsplit('/', 1)[-1]
        mine = s.topic in own or not own
        if mine and name in TRUTH_NAMES:
            role = TRUTH
        elif mine and name == 'imu' and s.field == RATE:
            role = GYRO
        elif mine and name == 'star_tracker' and s.field == ORIENTATION:
            role = STAR
        elif s.field == ORIENTATION:
            role = ESTIMATE
        else:
            role = RATE_ESTIMATE
        roles.by_label[s.label] = role
    if not any(r == ESTIMATE for r in roles.by_label.values()):
        stars = [lbl for lbl, r in roles.by_label.items() if r == STAR]
        if stars:
            roles.notes.append(f'no estimator topic: the star tracker {stars[0]} is shown '
                               f'as the estimate (its measurement, with its covariance)')
    return roles
