"""Score attitude and rate streams from a bag against the exact truth (no rclpy here).

The truth at a message is the exact solution of the run that contains its stamp (the
latest run description with ``start_ns <= stamp``), evaluated at scene time
``t = (stamp - start_ns) * 1e-9 * time_scale``; or, with a second bag as truth, that
bag's own stream interpolated at the same scene time.

Error conventions (quaternions (x, y, z, w), ``q_NB``):

- attitude: the rotation vector ``e`` with ``q_true^-1 ⊗ q_est = exp(e / 2)``, so ``e``
  is expressed in the body frame B (a right, body-frame perturbation:
  ``q_est = q_true ⊗ exp(e / 2)``); the scored error is the angle ``|e|``, rad. With
  ``cov_frame='inertial'`` the covariance is read as that of ``e_N = R_NB e``
  (``q_est = exp(e_N / 2) ⊗ q_true``) instead.
- rate: ``omega_est - omega_true`` in B, its norm in rad/s.
- sensor timing: a run description's ``sensor_timing`` (the node's and the generator's
  timing models) says which sensor topics (``imu``, ``star_tracker``, ``mag`` of the
  node, by the last component of the topic name and the run's ``topics``) carry stamps
  that are not their true sample times. A **clock offset** c is recovered exactly: the
  message is scored at ``stamp - c`` (and belongs to the run whose start that time
  follows). **Stamp jitter** cannot be: neither the bag nor the run records a sample's
  true time, so the message is scored at ``stamp - c`` and the jitter shows up as error
  (about ``sigma_j |omega|`` rad of attitude, ``sigma_j |omega_dot|`` of rate, which a
  stated covariance does not include); each such result says so
  (``timing``: ``clock_offset_s``, ``stamp_jitter_s``, ``scored_at``).
- sensor error model: a run description's ``sensors`` (the node's and the generator's
  effective sensor configuration: noise densities, random walks, biases and the drawn
  turn-on bias, scale factors, misalignment, quanta, Gauss-Markov terms, soft and hard
  iron, the values a Kalibr file supplied) goes with each result of a sensor topic
  (``sensor``: the sensor's name, rate and parameters), found as the timing model is;
  :func:`describe_sensor` says it in one line.
- consistency: ``NEES = e^T P^-1 e`` per sample with an orientation covariance ``P``;
  ANEES is its mean over the M samples that have one, and its 95 % bounds are
  ``chi2.ppf([0.025, 0.975], 3 M) / M``. They assume independent samples; the errors of a
  filter are correlated in time, so read the bounds as a check of the mean (ANEES near
  3), not as a significance test of the run.
"""

import functools
import math

import mpmath
import numpy as np

from rigidrot_ros.bag import BagError
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.scoring.decode import decode_bag, ORIENTATION, RATE

__all__ = ['ScoreError', 'extract_streams', 'score_against_runs', 'score_against_stream',
           'rotation_error', 'nees', 'anees_bounds', 'check_bag']


class ScoreError(ValueError):
    """The log cannot be scored as asked, with the reason."""


def extract_streams(bag, topics=None):
    """Decode the scorable topics of a bag: ``(streams, skipped)``; ScoreError if none."""
    try:
        streams, skipped = decode_bag(bag, topics)
    except ValueError as exc:
        raise ScoreError(str(exc)) from None
    if not streams:
        why = '; '.join(f'{s["topic"]}: {s["reason"]}' for s in skipped) or 'no topics'
        raise ScoreError(f'{bag.path}: holds no topic that can be scored ({why})')
    return streams, skipped


def rotation_error(q_true, q_est):
    """Rotation vectors ``e`` (in B) with ``q_true^-1 ⊗ q_est = exp(e / 2)``; (N, 3)."""
    d = quat.multiply(quat.conjugate(np.asarray(q_true)), np.asarray(q_est))
    d = np.where(d[..., 3:4] < 0, -d, d)              # the shorter way round
    v = np.linalg.norm(d[..., :3], axis=-1)
    ang = 2.0 * np.arctan2(v, d[..., 3])
    with np.errstate(invalid='ignore', divide='ignore'):
        scale = np.where(v > 0, ang / np.where(v > 0, v, 1.0), 2.0)
    return d[..., :3] * scale[..., None]


def nees(e, cov):
    """``e^T P^-1 e`` per sample; NaN where ``cov`` is NaN."""
    out = np.full(len(e), np.nan)
    ok = np.all(np.isfinite(cov.reshape(len(e), -1)), axis=1) & np.all(np.isfinite(e), axis=1)
    if ok.any():
        sol = np.linalg.solve(cov[ok], e[ok][..., None])[..., 0]
        out[ok] = np.einsum('ij,ij->i', e[ok], sol)
    return out


def _chi2_ppf(p, k):
    """Quantile of chi-square with ``k`` degrees of freedom (safeguarded Newton on the CDF).

    The CDF is ``1 - Q(k/2, x/2)`` with ``Q`` mpmath's regularized upper incomplete gamma:
    its series for the lower ``P(a, 0, x)`` stops converging for ``k`` above about 15000
    (5000 samples of 3 degrees of freedom), the upper one does not. Newton starts at the
    Wilson-Hilferty approximation and falls back to bisection when a step leaves the
    bracket, so a million samples take milliseconds, not a bisection from zero.
    """
    a = mpmath.mpf(k) / 2
    log_norm = mpmath.loggamma(a) + mpmath.log(2)

    def cdf(x):
        return 1 - mpmath.gammainc(a, x / 2, mpmath.inf, regularized=True)

    def pdf(x):
        return mpmath.exp((a - 1) * mpmath.log(x / 2) - x / 2 - log_norm)
    z = mpmath.sqrt(2) * mpmath.erfinv(2 * mpmath.mpf(p) - 1)
    c = mpmath.mpf(2) / (9 * k)
    x = max(k * (1 - c + z * mpmath.sqrt(c)) ** 3, mpmath.mpf(k) * 1e-3)
    lo, hi = mpmath.mpf(0), mpmath.inf
    for _ in range(200):
        f = cdf(x) - p
        if f < 0:
            lo = x
        else:
            hi = x
        nxt = x - f / pdf(x)
        if not lo < nxt < hi:
            nxt = 2 * x if hi == mpmath.inf else (lo + hi) / 2
        if abs(nxt - x) <= 1e-15 * nxt:
            return nxt
        x = nxt
    raise ArithmeticError(f'chi-square quantile {p} with {k} degrees of freedom did not '
                          f'converge in 200 steps (last bracket [{lo}, {hi}])')


def anees_bounds(m, dof=3, level=0.95):
    """Two-sided ``level`` bounds of ANEES over ``m`` independent samples of ``dof``."""
    return list(_anees_bounds(m, dof, level))


@functools.lru_cache(maxsize=1024, typed=True)
def _anees_bounds(m, dof, level):
    """:func:`anees_bounds`, kept: a campaign asks for the same ``m`` run after run."""
    alpha = (1.0 - level) / 2
    with mpmath.workdps(30):
        lo = _chi2_ppf(alpha, dof * m) / m
        hi = _chi2_ppf(1 - alpha, dof * m) / m
    return float(lo), float(hi)


def _runs(bag, topic=None):
    """Return the runs that give the truth for ``topic``, sorted by start.

    With runs of one node that is all of them. With several nodes in one bag (namespaces),
    a topic goes with the node that publishes it (the run's ``topics``), else with the
    node whose namespace prefixes it (``/sat1/estimator/odom`` -> ``/sat1/...``); a topic
    that matches no node, or several, cannot be scored against one truth.
    """
    runs = sorted(bag.runs, key=lambda r: int(r['start_ns']))
    if not runs:
        raise ScoreError(f'{bag.path}: the log has no rigidrot_run metadata and no run '
                         f'description (the ~/run topic of the node), so the truth cannot be '
                         f'recomputed; record ~/run with the other topics, or compare '
                         f'against another log with --truth')
    nodes = {str(r.get('node', '')) for r in runs}
    if topic is None or len(nodes) == 1:
        return runs
    own = {n for n in nodes
           if any(topic in (r.get('topics') or {}) or topic in (r.get('topics') or {}).values()
                  for r in runs if str(r.get('node', '')) == n)}
    if not own:
        own = {n for n in nodes if n.rsplit('/', 1)[0] and topic.startswith(
            n.rsplit('/', 1)[0] + '/')}
        if len(own) > 1:          # the longest namespace wins (/a/b over /a)
            best = max(len(n.rsplit('/', 1)[0]) for n in own)
            own = {n for n in own if len(n.rsplit('/', 1)[0]) == best}
    if len(own) != 1:
        raise ScoreError(f'{bag.path}: runs of several nodes {sorted(nodes)}: cannot tell '
                         f'which one is the truth for {topic} (put the estimator in the '
                         f'namespace of its node, or score each node in its own bag)')
    return [r for r in runs if str(r.get('node', '')) in own]


#: The node's sensors whose topics may carry a timing model (``sensor_timing`` of a run).
TIMED_SENSORS = ('imu', 'star_tracker', 'mag')


def sensor_timing(run, topic):
    """Return the timing model (dict) of the run's sensor that publishes ``topic``, or None.

    A topic is the sensor's if its last name component is the sensor's name and the run
    lists it among its topics (a run without a topic list: by the name alone), so an
    estimator's ``/filter/imu`` under another node is not taken for the node's sensor.
    """
    if topic is None:
        return None
    name = topic.rsplit('/', 1)[-1]
    timing = run.get('sensor_timing') or {}
    if name not in TIMED_SENSORS or name not in timing:
        return None
    listed = run.get('topics')
    if listed and topic not in listed:
        return None
    return timing[name]


#: The node's sensor topics (last name component) and the sensor that publishes each.
SENSOR_TOPICS = {'imu': 'imu', 'delta_angle': 'imu', 'delta_rotation': 'imu',
                 'delta_velocity': 'imu', 'star_tracker': 'star_tracker', 'mag': 'mag'}


def sensor_config(run, topic):
    """Return ``(sensor, configuration)`` of the run's sensor that publishes ``topic``, or None.

    The configuration is the run description's ``sensors`` entry (``rate_hz``,
    ``parameters``, ...); the topic is matched as :func:`sensor_timing` matches it.
    """
    if topic is None:
        return None
    sensor = SENSOR_TOPICS.get(topic.rsplit('/', 1)[-1])
    config = (run.get('sensors') or {}).get(sensor)
    listed = run.get('topics')
    if not isinstance(config, dict) or (listed and topic not in listed):
        return None
    return sensor, config


def _sensor_note(runs, topic):
    """Return the ``sensor`` entry of a result: the last run's sensor for ``topic``, or None."""
    found = [c for c in (sensor_config(r, topic) for r in runs) if c is not None]
    if not found:
        return None
    sensor, config = found[-1]
    return dict(config, name=sensor)


#: Parameters shown by :func:`describe_sensor` even at their default: the noise levels.
_ALWAYS_SHOWN = ('noise_density', 'random_walk', '_arcsec')


def describe_sensor(note):
    """Return one line for a result's ``sensor`` entry: the values that shape its error.

    Its rate, then each parameter that is not at its default in the parameter table, and
    the noise levels (densities, random walks, star tracker sigmas) always; the drawn
    turn-on biases where not zero; the Kalibr file, if any.
    """
    from rigidrot_ros.run.params import BY_NAME
    parts = []
    for name, value in (note.get('parameters') or {}).items():
        p = BY_NAME.get(name)
        default = None if p is None else p.default
        if value != default or name.endswith(_ALWAYS_SHOWN):
            parts.append(f'{name} {_short(value)}')
    for which, bias in sorted((note.get('turn_on_bias') or {}).items()):
        if any(bias):
            parts.append(f'{which} turn-on bias {_short(bias)}')
    rate = note.get('rate_hz')
    head = f'{note.get("name", "sensor")} at {_short(rate)} Hz' if rate else \
        str(note.get('name', 'sensor'))
    if not parts:
        return f'{head}: every parameter at its default'
    return f'{head}: {", ".join(parts)} (the rest at their defaults)'


def _short(v):
    if isinstance(v, list):
        return '[' + ', '.join(_short(x) for x in v) + ']'
    return f'{v:.4g}' if isinstance(v, float) else f'{v:g}' if isinstance(v, int) and \
        not isinstance(v, bool) else str(v)


def _offset_ns(run, topic):
    t = sensor_timing(run, topic)
    return 0 if t is None else round(float(t.get('clock_offset_s', 0.0)) * 1e9)


def scene_times(bag, stamps, topic=None):
    """(run index per stamp, scene time t per stamp, runs); index -1 before the first run.

    The scene time is that of the true sample time where the run's ``sensor_timing``
    gives ``topic`` a clock offset (``stamp - offset``, module text); else of the stamp.
    """
    runs = _runs(bag, topic)
    stamps = np.asarray(stamps, dtype=np.int64)
    starts = np.array([int(r['start_ns']) for r in runs], dtype=np.int64)
    offsets = np.array([_offset_ns(r, topic) for r in runs], dtype=np.int64)
    idx = np.full(len(stamps), -1)
    true = stamps.copy()
    for i in range(len(runs)):          # each run's offset; a later run takes over
        shifted = stamps - offsets[i]
        sel = shifted >= starts[i]
        if i + 1 < len(runs):
            sel &= shifted < starts[i + 1]
        idx[sel] = i
        true[sel] = shifted[sel]
    t = np.full(len(stamps), np.nan)
    for i, r in enumerate(runs):
        sel = idx == i
        t[sel] = (true[sel] - starts[i]) * 1e-9 * float(r.get('time_scale', 1.0))
    return idx, t, runs


def _timing_note(runs, topic):
    """Return the ``timing`` entry of a result: the models of the runs for ``topic``."""
    models = [m for m in (sensor_timing(r, topic) for r in runs) if m is not None]
    if not models or not any(m.get('clock_offset_s') or m.get('stamp_jitter_s')
                             for m in models):
        return None
    m = models[-1]
    jitter = float(m.get('stamp_jitter_s', 0.0))
    return {'clock_offset_s': float(m.get('clock_offset_s', 0.0)), 'stamp_jitter_s': jitter,
            'scored_at': 'stamp - clock_offset' + (
                ' (the stamp jitter is not recoverable from the log: it shows up as '
                'error)' if jitter > 0 else ' (the true sample time)')}


def _summary(stream, t, err, comp=None, nees_values=None):
    ok = np.isfinite(err)
    e = err[ok]
    out = {'topic': stream.topic, 'type': stream.type, 'field': stream.field,
           'label': stream.label, 'count': int(len(e)), 'skipped': int((~ok).sum()),
           'unit': 'rad' if stream.field == ORIENTATION else 'rad/s'}
    if stream.invalid:
        out['invalid_values'] = stream.invalid
    if not len(e):
        out.update(t=[], error=[])
        return out
    out.update({
        'max': float(e.max()), 'rms': float(np.sqrt(np.mean(e ** 2))),
        'p95': float(np.percentile(e, 95)), 't': t[ok].tolist(), 'error': e.tolist(),
    })
    if nees_values is not None:
        good = ok & np.isfinite(nees_values)
        m = int(good.sum())
        out['nees_count'] = m
        if stream.cov_unknown:
            out['cov_unknown'] = stream.cov_unknown
        if stream.cov_unusable:
            out['cov_unusable'] = stream.cov_unusable
        if m:
            out['anees'] = float(np.mean(nees_values[good]))
            out['anees_bounds_95'] = anees_bounds(m)
            out['nees'] = np.where(good, nees_values, np.nan)[ok].tolist()
            sig = np.sqrt(np.einsum('nii->ni', stream.cov))
            out['components'] = comp[ok].tolist()
            out['sigma'] = sig[ok].tolist()
    return out


def score_against_runs(bag, streams, cov_frame='body', solutions=None):
    """Score each stream against the exact solution of the log's own runs.

    Parameters
    ----------
    bag : BagContents
        The log (its runs give the truth).
    streams : list of Stream
        From :func:`extract_streams`.
    cov_frame : {'body', 'inertial'}
        Frame in which orientation covariances are read (module docstring).
    solutions : dict, optional
        ``{(node, start_ns): solution}``: the solutions of runs made already (by the
        generator of the run, from the scene, ``tol`` and ``backend`` its description
        gives), used instead of solving them again; the other runs are solved here.
    """
    if cov_frame not in ('body', 'inertial'):
        raise ScoreError(f'cov_frame must be body or inertial, got {cov_frame!r}')
    results = []
    solutions = dict(solutions or {})
    for s in streams:
        try:
            idx, t, runs = scene_times(bag, s.stamps, s.topic)
        except ScoreError as exc:
            if not bag.runs:
                raise
            results.append({'topic': s.topic, 'type': s.type, 'field': s.field,
                            'label': s.label, 'count': 0, 'unit': '', 't': [], 'error': [],
                            'reason': str(exc).split(': ', 1)[-1]})
            continue
        err = np.full(len(t), np.nan)
        comp = np.full((len(t), 3), np.nan)
        for i, r in enumerate(runs):
            sel = np.nonzero((idx == i) & np.all(np.isfinite(s.values), axis=1))[0]
            if not len(sel):
                continue
            key = (str(r.get('node', '')), int(r['start_ns']))
            if key not in solutions:
                try:
                    scene = Scene.from_dict(r['scene'])
                    solutions[key] = solve(scene, tol=float(r.get('tol', 1e-12)),
                                           backend=r.get('backend'))
                except (ValueError, KeyError, TypeError, ArithmeticError) as exc:
                    raise ScoreError(f'{bag.path}: run {r.get("run", i)} has an unusable '
                                     f'scene: {exc}') from None
            truth = solutions[key].at(t[sel])
            if s.field == ORIENTATION:
                e = rotation_error(truth.quaternion, s.values[sel])
                if cov_frame == 'inertial':
                    e = np.einsum('nij,nj->ni', quat.to_matrix(truth.quaternion), e)
                comp[sel] = e
                err[sel] = np.linalg.norm(e, axis=-1)
            else:
                d = s.values[sel] - truth.omega
                comp[sel] = d
                err[sel] = np.linalg.norm(d, axis=-1)
        nv = nees(comp, s.cov) if (s.field == ORIENTATION and s.cov is not None) else None
        out = _summary(s, t, err, comp, nv)
        _notes(out, runs, s.topic)
        results.append(out)
    return results


def _notes(out, runs, topic):
    """Add the timing model and the sensor's configuration of ``topic`` to a result."""
    note = _timing_note(runs, topic)
    if note is not None:
        out['timing'] = note
    sensor = _sensor_note(runs, topic)
    if sensor is not None:
        out['sensor'] = sensor


def _slerp(q0, q1, w):
    d = quat.multiply(quat.conjugate(q0), q1)
    d = d if d[3] >= 0 else -d
    ang = 2 * math.atan2(float(np.linalg.norm(d[:3])), float(d[3]))
    axis = d[:3] / np.linalg.norm(d[:3]) if ang > 0 else np.zeros(3)
    return quat.multiply(q0, quat.from_rotvec(axis * ang * w))


#: The node's exact topics, by name (last component), in order of preference; its sensor
#: topics (imu, star_tracker, delta_angle, delta_rotation) carry noise and are never a truth.
TRUTH_NAMES = ('attitude', 'angular_velocity', 'odom', 'transform')
#: A stream sample is interpolated only between truth samples at most this many median
#: spacings apart; across a longer gap it is skipped and counted (``truth_gaps``).
GAP_FACTOR = 2.0


def _reference(s, truth_bag, truth_streams):
    """Return the truth log's stream for ``s``: a node truth topic of the same field."""
    names = {r.topic: r.topic.rsplit('/', 1)[-1] for r in truth_streams}
    ref = [r for r in truth_streams if r.field == s.field and names[r.topic] in TRUTH_NAMES]
    if not ref:
        have = sorted({r.topic for r in truth_streams})
        raise ScoreError(f'{truth_bag.path}: no {s.field} stream on a truth topic '
                         f'({", ".join(TRUTH_NAMES)}) to compare {s.label} with; it has '
                         f'{have} (sensor topics such as imu or star_tracker carry noise '
                         f'and are not used as the truth)')
    own = {t for r in truth_bag.runs for t in (r.get('topics') or {})}
    # the node's own where the runs list them (an estimator's /estimator/odom is no truth),
    # and among those the same topic if the truth log has it, else by name
    ref = [r for r in ref if r.topic in own] or ref
    return sorted(ref, key=lambda r: (r.topic != s.topic, TRUTH_NAMES.index(names[r.topic]),
                                      r.topic))[0]


def score_against_stream(bag, streams, truth_bag, truth_streams, cov_frame='body'):
    """Score streams against a second log's stream of the same field, by scene time.

    The truth is the truth log's stream on one of the node's exact topics
    (:data:`TRUTH_NAMES`) of the same field, slerped (attitude) or interpolated linearly
    (rate) between the two truth samples that bracket each message. Messages outside the
    truth log, or inside a gap of it longer than :data:`GAP_FACTOR` times its median
    spacing, are skipped; the latter are counted in ``truth_gaps``. With
    ``cov_frame='inertial'`` the attitude error is rotated into N by the interpolated
    truth's ``R_NB``, as :func:`score_against_runs` does.
    """
    if cov_frame not in ('body', 'inertial'):
        raise ScoreError(f'cov_frame must be body or inertial, got {cov_frame!r}')
    results = []
    for s in streams:
        ref = _reference(s, truth_bag, truth_streams)
        _, t, runs = scene_times(bag, s.stamps, s.topic)
        _, tr, _ = scene_times(truth_bag, ref.stamps, ref.topic)
        keep = np.isfinite(tr) & np.all(np.isfinite(ref.values), axis=1)
        order = np.argsort(tr[keep])
        tr, vals = tr[keep][order], ref.values[keep][order]
        steps = np.diff(tr)
        steps = steps[steps > 0]
        max_gap = GAP_FACTOR * float(np.median(steps)) if len(steps) else math.inf
        err = np.full(len(t), np.nan)
        comp = np.full((len(t), 3), np.nan)
        gaps = 0
        for k, tk in enumerate(t):
            if (not len(tr) or not np.isfinite(tk) or not tr[0] <= tk <= tr[-1]
                    or not np.all(np.isfinite(s.values[k]))):
                continue                              # outside the truth log: skipped
            hi = int(min(max(np.searchsorted(tr, tk), 1), len(tr) - 1))
            lo = max(hi - 1, 0)
            if tr[hi] - tr[lo] > max_gap and tk not in (tr[lo], tr[hi]):
                gaps += 1                             # inside a gap of the truth: skipped
                continue
            w = 0.0 if tr[hi] == tr[lo] else (tk - tr[lo]) / (tr[hi] - tr[lo])
            if s.field == ORIENTATION:
                q_ref = _slerp(vals[lo], vals[hi], w)
                comp[k] = rotation_error(q_ref, s.values[k])
                if cov_frame == 'inertial':
                    comp[k] = quat.to_matrix(q_ref) @ comp[k]
            else:
                comp[k] = s.values[k] - ((1 - w) * vals[lo] + w * vals[hi])
            err[k] = np.linalg.norm(comp[k])
        nv = nees(comp, s.cov) if (s.field == ORIENTATION and s.cov is not None) else None
        out = _summary(s, t, err, comp, nv)
        out['truth_topic'] = ref.topic
        out['truth_gaps'] = gaps
        _notes(out, runs, s.topic)
        results.append(out)
    return results


def check_bag(bag):
    """Raise BagError when a bag holds nothing to score."""
    if not bag.messages:
        raise BagError(f'{bag.path}: the log holds no messages')


__all__ += ['RATE', 'scene_times', 'TRUTH_NAMES', 'GAP_FACTOR', 'sensor_timing',
            'TIMED_SENSORS', 'sensor_config', 'describe_sensor', 'SENSOR_TOPICS']
