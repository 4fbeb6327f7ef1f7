"""Score attitude and rate streams from a bag against the exact truth (no rclpy here).

The truth at a message is the exact solution of the run that contains its stamp (the
latest ``rigidrot_run`` record with ``start_ns <= stamp``), evaluated at scene time
``t = (stamp - start_ns) * 1e-9 * time_scale``; or, with a second bag as truth, that
bag's own stream interpolated at the same scene time.
"""

from dataclasses import dataclass

from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
import numpy as np

from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.io.bag import BagError

__all__ = ['ScoreError', 'Stream', 'extract_streams', 'score_against_runs',
           'score_against_stream', 'ATTITUDE_TYPE', 'RATE_TYPE']

ATTITUDE_TYPE = 'geometry_msgs/msg/QuaternionStamped'
RATE_TYPE = 'geometry_msgs/msg/Vector3Stamped'


class ScoreError(ValueError):
    """The log cannot be scored as asked, with the reason."""


@dataclass
class Stream:
    """One topic decoded: stamps (int ns) and values (quaternions or vectors)."""

    topic: str
    type: str
    stamps: np.ndarray
    values: np.ndarray


def extract_streams(bag, topics=None):
    """Decode the QuaternionStamped / Vector3Stamped topics of a :class:`BagContents`."""
    wanted = topics or [t for t, (ty, _, _) in bag.topics.items()
                        if ty in (ATTITUDE_TYPE, RATE_TYPE)]
    if not wanted:
        raise ScoreError(f'{bag.path}: holds no {ATTITUDE_TYPE} or {RATE_TYPE} topic to score '
                         f'(it has {sorted(bag.topics)})')
    for t in wanted:
        if t not in bag.topics:
            raise ScoreError(f'{bag.path}: no topic {t!r} in the log (it has '
                             f'{sorted(bag.topics)})')
        if bag.topics[t][0] not in (ATTITUDE_TYPE, RATE_TYPE):
            raise ScoreError(f'{bag.path}: topic {t!r} is {bag.topics[t][0]}, not '
                             f'{ATTITUDE_TYPE} or {RATE_TYPE}')
    factory = DecoderFactory()
    out = {}
    for n, t in enumerate(wanted):
        type_name, _, schema_text = bag.topics[t]
        # the factory caches decoders by schema id: one id per topic
        decode = factory.decoder_for('cdr', Schema(id=n + 1, name=type_name,
                                                   encoding='ros2msg',
                                                   data=schema_text.encode('utf-8')))
        stamps, values = [], []
        for topic, _, _, _, data in bag.messages:
            if topic != t:
                continue
            m = decode(data)
            stamps.append(m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec)
            if type_name == ATTITUDE_TYPE:
                q = m.quaternion
                values.append((q.x, q.y, q.z, q.w))
            else:
                v = m.vector
                values.append((v.x, v.y, v.z))
        out[t] = Stream(t, type_name, np.array(stamps, dtype=np.int64),
                        np.array(values, dtype=float).reshape(len(values), -1))
    return out


def _runs(bag):
    runs = sorted(bag.runs, key=lambda r: int(r['start_ns']))
    if not runs:
        raise ScoreError(f'{bag.path}: the log has no rigidrot_run metadata, so the truth '
                         f'cannot be recomputed; record it with attitude_node, or compare '
                         f'against another log with --truth')
    return runs


def scene_times(bag, stamps):
    """(run index per stamp, scene time t per stamp); index -1 before the first run."""
    runs = _runs(bag)
    starts = np.array([int(r['start_ns']) for r in runs], dtype=np.int64)
    idx = np.searchsorted(starts, stamps, side='right') - 1
    t = np.full(len(stamps), np.nan)
    for i, r in enumerate(runs):
        sel = idx == i
        t[sel] = (stamps[sel] - starts[i]) * 1e-9 * float(r.get('time_scale', 1.0))
    return idx, t, runs


def _summary(stream, t, err):
    ok = np.isfinite(err)
    e = err[ok]
    if not len(e):
        return {'topic': stream.topic, 'type': stream.type, 'count': 0}
    return {
        'topic': stream.topic, 'type': stream.type, 'count': int(len(e)),
        'skipped': int((~ok).sum()), 'max': float(e.max()),
        'rms': float(np.sqrt(np.mean(e ** 2))), 'p95': float(np.percentile(e, 95)),
        'unit': 'rad' if stream.type == ATTITUDE_TYPE else 'rad/s',
        't': t[ok].tolist(), 'error': e.tolist(),
    }


def score_against_runs(bag, streams):
    """Score each stream against the exact solution of the log's own runs."""
    results = []
    solutions = {}
    for s in streams.values():
        idx, t, runs = scene_times(bag, s.stamps)
        err = np.full(len(t), np.nan)
        for i, r in enumerate(runs):
            sel = np.nonzero(idx == i)[0]
            if not len(sel):
                continue
            if i not in solutions:
                try:
                    scene = Scene.from_dict(r['scene'])
                    solutions[i] = solve(scene, tol=float(r.get('tol', 1e-12)),
                                         backend=r.get('backend'))
                except (ValueError, KeyError, TypeError) as exc:
                    raise ScoreError(f'{bag.path}: run {r.get("run", i)} has an unusable '
                                     f'scene: {exc}') from None
            truth = solutions[i].at(t[sel])
            if s.type == ATTITUDE_TYPE:
                err[sel] = quat.angle_between(s.values[sel], truth.quaternion)
            else:
                err[sel] = np.linalg.norm(s.values[sel] - truth.omega, axis=-1)
        results.append(_summary(s, t, err))
    return results


def score_against_stream(bag, streams, truth_bag, truth_streams):
    """Score streams against a second log's stream of the same type, by scene time."""
    results = []
    for s in streams.values():
        ref = [r for r in truth_streams.values() if r.type == s.type]
        if not ref:
            raise ScoreError(f'{truth_bag.path}: no {s.type} topic to compare {s.topic} with')
        ref = ref[0]
        _, t, _ = scene_times(bag, s.stamps)
        _, tr, _ = scene_times(truth_bag, ref.stamps)
        order = np.argsort(tr)
        tr, vals = tr[order], ref.values[order]
        err = np.full(len(t), np.nan)
        for k, tk in enumerate(t):
            if not np.isfinite(tk) or not tr[0] <= tk <= tr[-1]:
                continue                              # outside the truth log: skipped
            hi = int(min(max(np.searchsorted(tr, tk), 1), len(tr) - 1))
            lo = max(hi - 1, 0)
            w = 0.0 if tr[hi] == tr[lo] else (tk - tr[lo]) / (tr[hi] - tr[lo])
            if s.type == ATTITUDE_TYPE:
                q0, q1 = vals[lo], vals[hi]
                d = quat.multiply(quat.conjugate(q0), q1)
                d = d if d[3] >= 0 else -d
                ang = 2 * np.arctan2(np.linalg.norm(d[:3]), d[3])
                axis = d[:3] / np.linalg.norm(d[:3]) if ang > 0 else np.zeros(3)
                qi = quat.multiply(q0, quat.from_rotvec(axis * ang * w))
                err[k] = quat.angle_between(s.values[k], qi)
            else:
                err[k] = np.linalg.norm(s.values[k] - ((1 - w) * vals[lo] + w * vals[hi]))
        results.append(_summary(s, t, err))
    return results


def check_bag(bag):
    """Raise BagError when a bag holds nothing to score."""
    if not bag.messages:
        raise BagError(f'{bag.path}: the log holds no messages')
