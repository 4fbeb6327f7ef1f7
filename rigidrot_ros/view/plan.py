"""What to show of a log, as arrays: the plan that :mod:`rigidrot_ros.view.rr_log` draws.

Pure (numpy, the project's decoder and scorer; no rerun, no rclpy): a bag, or a batch of
live messages decoded into :class:`~rigidrot_ros.scoring.decode.Stream`, becomes a
:class:`Plan` with the truth at its stamps and each stream's errors, in the conventions of
:mod:`rigidrot_ros.view.compute`.
"""

from dataclasses import dataclass, field
import math

import numpy as np

from rigidrot_ros.bag import BagContents, BagError, read_bag
from rigidrot_ros.scoring.decode import decode_bag, ORIENTATION
from rigidrot_ros.scoring.score import ScoreError
from rigidrot_ros.view import compute as cp

__all__ = ['Plan', 'read_bags', 'plan_bag', 'plan_streams', 'ViewError', 't0_of',
           'truth_stamps']


class ViewError(ValueError):
    """Input the viewer cannot show at all, with the reason (one line)."""


@dataclass
class Plan:
    """Everything to draw of a log (or of a batch of a live one)."""

    t0_ns: int = 0
    half_sizes: np.ndarray = None
    arrow_scale: float = 1.0
    truth: dict = None             # stamps, q, omega
    estimates: list = field(default_factory=list)   # label, stamps, q, angle, bound3, nees
    gyro: list = field(default_factory=list)        # label, stamps, residual (N, 3)
    star: list = field(default_factory=list)        # label, stamps, e (N, 3)
    rates: list = field(default_factory=list)       # label, stamps, error
    notes: list = field(default_factory=list)
    problems: list = field(default_factory=list)    # what could not be shown, and why
    runs: list = field(default_factory=list)        # the run descriptions of the truth


def _run_key(run):
    return (str(run.get('node', '')), int(run.get('start_ns', -1)), run.get('run'))


def read_bags(paths):
    """Read one bag, or several merged (e.g. a node's bag and an estimator's recording).

    Raises
    ------
    ViewError
        A path that is not a bag, or two bags with one topic of different types.
    """
    bags = []
    for p in paths:
        try:
            bags.append(read_bag(p))
        except (BagError, OSError) as exc:
            raise ViewError(str(exc)) from None
    notes = [f'{b.path}: {b.note}' for b in bags if b.note]
    if len(bags) == 1:
        return bags[0], notes
    out = BagContents(path=' + '.join(b.path for b in bags))
    seen = set()
    for b in bags:
        for topic, info in b.topics.items():
            if topic in out.topics and out.topics[topic][0] != info[0]:
                raise ViewError(f'{topic} is {out.topics[topic][0]} in one bag and {info[0]} '
                                f'in {b.path}: open them one at a time')
            out.topics.setdefault(topic, info)
        out.messages.extend(b.messages)
        out.metadata.extend(b.metadata)
        out.truncated = out.truncated or b.truncated
        for r in b.runs:
            if _run_key(r) not in seen:
                seen.add(_run_key(r))
                out.runs.append(r)
    out.messages.sort(key=lambda m: m[2])
    return out, notes


def t0_of(runs, streams):
    """Return the time origin (ns): the first run's start, else the first stamp."""
    if runs:
        return min(int(r['start_ns']) for r in runs)
    firsts = [int(s.stamps.min()) for s in streams if len(s.stamps)]
    return min(firsts) if firsts else 0


def _stride(n, max_points):
    if not max_points or n <= max_points:
        return np.arange(n), 1
    step = int(math.ceil(n / max_points))
    return np.arange(0, n, step), step


def truth_stamps(runs, streams, roles, rate):
    """Stamps at which the box shows the truth: the node's truth topic's, else a grid.

    The grid runs at ``rate`` Hz from each run's start to the next run's (or the last
    stamp of the log).
    """
    for s in streams:
        if roles.by_label.get(s.label) == cp.TRUTH and s.field == ORIENTATION:
            return np.sort(s.stamps), f'the stamps of {s.topic}'
    last = max((int(s.stamps.max()) for s in streams if len(s.stamps)), default=None)
    starts = sorted(int(r['start_ns']) for r in runs)
    if last is None:
        last = starts[-1]
    period = int(round(1e9 / rate))
    out = []
    for k, start in enumerate(starts):
        end = starts[k + 1] if k + 1 < len(starts) else last + 1
        out.append(np.arange(start, max(end, start + 1), period, dtype=np.int64))
    return np.concatenate(out), f'a {rate:g} Hz grid'


def plan_streams(streams, truth, roles, max_points=None, plan=None, stand_in=True):
    """Compute each stream's errors against ``truth`` (a :class:`~compute.Truth` or None).

    Adds to ``plan`` (a new one if None) and returns it; decimation (every n-th sample
    beyond ``max_points`` per stream) is said in its notes. Without an estimate, the
    star tracker stands in for one if ``stand_in``.
    """
    plan = plan or Plan()
    stars = [s for s in streams if roles.by_label.get(s.label) == cp.STAR]
    ests = [s for s in streams if roles.by_label.get(s.label) == cp.ESTIMATE] or (
        stars if stand_in else [])
    for s in streams:
        role = roles.by_label.get(s.label)
        if role == cp.TRUTH or not len(s.stamps):
            continue
        idx, step = _stride(len(s.stamps), max_points)
        if step > 1:
            plan.notes.append(f'{s.label}: every {step}th of {len(s.stamps)} samples shown '
                              f'(at most {max_points} a series)')
        stamps = s.stamps[idx]
        values = s.values[idx]
        q_t = w_t = None
        if truth is not None and truth.runs:
            try:
                _, q_t, w_t = truth.at(stamps, s.topic)
            except ScoreError as exc:
                plan.problems.append(f'{s.label}: no truth: {str(exc).split(": ", 1)[-1]}')
        if any(s is e for e in ests):
            cov = None if s.cov is None else s.cov[idx]
            if q_t is None:
                plan.estimates.append(dict(label=s.label, stamps=stamps, q=values,
                                           angle=np.full(len(stamps), np.nan),
                                           bound3=np.full(len(stamps), np.nan),
                                           nees=np.full(len(stamps), np.nan)))
            else:
                _, angle, bound3, nees = cp.attitude_errors(q_t, values, cov)
                plan.estimates.append(dict(label=s.label, stamps=stamps, q=values,
                                           angle=angle, bound3=bound3, nees=nees))
        if q_t is None:
            continue
        if role == cp.STAR:
            plan.star.append(dict(label=s.label, stamps=stamps,
                                  e=cp.attitude_errors(q_t, values)[0]))
        elif role == cp.GYRO:
            plan.gyro.append(dict(label=s.label, stamps=stamps,
                                  residual=cp.rate_residual(w_t, values)))
        elif role == cp.RATE_ESTIMATE:
            plan.rates.append(dict(label=s.label, stamps=stamps, error=np.linalg.norm(
                cp.rate_residual(w_t, values), axis=1)))
    return plan


def plan_bag(bag, max_points=20000, truth_rate=50.0):
    """Return the :class:`Plan` of a bag: the truth recomputed, every stream's errors.

    Topics that cannot be shown, and a bag without a run description (no truth: the
    estimates are drawn without errors), are said in the notes; the rest is shown.
    """
    if not bag.messages:
        raise ViewError(f'{bag.path}: the log holds no messages')
    streams, skipped = decode_bag(bag)
    runs = sorted(bag.runs, key=lambda r: int(r['start_ns']))
    roles = cp.topic_roles(streams, runs)
    plan = Plan(t0_ns=t0_of(runs, streams), runs=runs)
    notes = plan.notes
    if not streams:
        plan.problems.append(f'{bag.path}: no topic of a type with an attitude or a body rate')
    truth = None
    if runs:
        truth = cp.Truth(runs, bag.path)
        models = sorted({str(r.get('model', '?')) for r in runs})
        notes.append(f'truth: the exact solution ({", ".join(models)}) of {len(runs)} '
                     f'run(s), recomputed from the run description')
        stamps, where = truth_stamps(runs, streams, roles, truth_rate)
        idx, step = _stride(len(stamps), max_points)
        stamps = stamps[idx]
        try:
            _, q, w = truth.at(stamps)
        except ScoreError as exc:
            raise ViewError(str(exc)) from None
        ok = np.all(np.isfinite(q), axis=1)
        plan.truth = dict(stamps=stamps[ok], q=q[ok], omega=w[ok])
        notes.append(f'the box at {where}' + (f', every {step}th' if step > 1 else ''))
        inertia = truth.inertia()
        plan.half_sizes = cp.box_half_sizes(inertia)
        top = float(np.nanmax(np.linalg.norm(w[ok], axis=1))) if ok.any() else 0.0
        plan.arrow_scale = 1.5 / top if top > 0 else 1.0
        notes.append(f'inertia {inertia} kg m²; rate arrow: ω in B × {plan.arrow_scale:.3g} '
                     f'(1.5 at the largest |ω|, {top:.3g} rad/s)')
    else:
        plan.problems.append(f"{bag.path}: no run description (the node's ~/run topic or "
                             f'its rigidrot_run record): the truth cannot be recomputed; the '
                             f'estimates are drawn without errors')
        plan.half_sizes = cp.box_half_sizes([1.0, 1.0, 1.0])
    plan.notes.extend(roles.notes)
    plan_streams(streams, truth, roles, max_points, plan)
    for s in skipped:
        if s['type'] == 'std_msgs/msg/String' and s['topic'].endswith('/run'):
            continue
        # increments are not rates (the scorer's reason): said, but not a problem
        (plan.notes if 'increment' in s['reason'] else plan.problems).append(
            f'{s["topic"]} ({s["type"]}) not shown: {s["reason"]}')
    return plan
