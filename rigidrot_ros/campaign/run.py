"""One campaign run: generate it, run the estimator, score its output (worker side).

:func:`run_one` returns a plain dict (JSON-serialisable) and writes nothing the client
owns: the client writes each result atomically, so a worker on another machine needs no
shared disk (bags go to ``bag_root`` if given, else to a temporary directory that is
removed). The result holds no wall time (that goes in ``timing``, kept apart by the
client), so the same spec and seed give the same result bytes on any engine.

Scoring is the project's scorer, on a bag: the estimator's messages (in process,
:mod:`rigidrot_ros.campaign.inproc`), its answers to the paced feed (a ROS program,
:mod:`rigidrot_ros.campaign.session`) or the recorder's bag (a ROS program fed by a replay
at ``rate``), with the run's description (``~/run``), read back by
:func:`rigidrot_ros.bag.read_bag` and scored by
:func:`rigidrot_ros.scoring.score.score_against_runs`. ``timing`` also holds each path's
phases (seconds) and counts.
"""

import contextlib
import fcntl
import os
import shutil
import signal
import subprocess
import time
import traceback

from rigidrot_ros.campaign.failure import RunFailed
from rigidrot_ros.campaign.spec import draw_run, run_values
from rigidrot_ros.campaign.workdir import claim_domain, claim_work_dir
from rigidrot_ros.runtime.processes import script, stop

__all__ = ['run_one', 'RunFailed', 'score_bag', 'score_estimates']

_SEC = 1_000_000_000


def score_bag(path, topic, runs=None):
    """Score ``topic`` of the bag at ``path`` against the exact truth: the series and row.

    ``runs`` (the run descriptions of the input bag) give the truth when the bag holds
    none (a recorder that joined after the replay published ``~/run``).
    """
    from rigidrot_ros.bag import BagError, read_bag
    from rigidrot_ros.scoring.score import extract_streams, score_against_runs, ScoreError
    try:
        bag = read_bag(path)
        if not bag.runs and runs:
            bag.runs = list(runs)
        if topic not in bag.topics or not any(m[0] == topic for m in bag.messages):
            raise RunFailed(f'the estimator published nothing on {topic}')
        streams, _ = extract_streams(bag, [topic])
        res = score_against_runs(bag, [s for s in streams if s.field == 'orientation'])
    except (BagError, ScoreError) as exc:
        raise RunFailed(f'scoring failed: {" ".join(str(exc).split())}') from None
    return _row_series(res, topic, bag.runs)


def score_estimates(est):
    """Score an in-process run's :class:`~rigidrot_ros.campaign.inproc.Estimates`: as a bag.

    The row and series :func:`score_bag` gives for the bag of the same estimates (the
    estimates as its reader gives them, the run description as its ``rigidrot_run``
    record gives it), without the bag; the truth is the generator's own solution where
    the estimates carry it (``est.solutions``), else solved from the description.
    """
    from rigidrot_ros.bag import BagContents
    from rigidrot_ros.scoring.decode import ORIENTATION, stream_of_rows
    from rigidrot_ros.scoring.score import score_against_runs, ScoreError
    bag = BagContents(path=f'(the estimates of {est.topic}, in memory)', runs=[est.run])
    stream = stream_of_rows(est.topic, est.type, ORIENTATION, est.rows)
    try:
        res = score_against_runs(bag, [] if stream is None else [stream],
                                 solutions=getattr(est, 'solutions', None))
    except ScoreError as exc:
        raise RunFailed(f'scoring failed: {" ".join(str(exc).split())}') from None
    return _row_series(res, est.topic, bag.runs)


def _row_series(res, topic, runs):
    """Return the run's ``(row, series)`` from the scorer's results for ``topic``."""
    if not res or not res[0].get('count'):
        raise RunFailed(f'{topic}: no orientation sample could be scored')
    r = res[0]
    if not r.get('nees_count'):
        raise RunFailed(f'{topic}: no usable orientation covariance (no NEES)')
    series = {'t_ns': [int(round(t * 1e9)) for t in r['t']], 'nees': r['nees'],
              'error': r['error']}
    row = {'count': r['count'], 'nees_count': r['nees_count'], 'anees': r['anees'],
           'anees_lo': r['anees_bounds_95'][0], 'anees_hi': r['anees_bounds_95'][1],
           'rms_rad': r['rms'], 'max_rad': r['max'], 'p95_rad': r['p95']}
    sensors = [run['sensors'] for run in runs if isinstance(run.get('sensors'), dict)]
    if sensors:                 # the error model the estimator was fed (run description)
        row['sensors'] = sensors[0]
    return row, series


def _inproc(spec, values, work, timing, keep):
    """Feed the run to the factory's object; score its answers, from their bag if kept."""
    from rigidrot_ros.campaign.inproc import run_inproc
    if keep:
        return score_bag(run_inproc(spec, values, work, timing), spec['estimator']['topic'])
    out = run_inproc(spec, values, None, timing)
    t0 = time.perf_counter()
    try:
        return score_estimates(out)
    finally:
        timing['score_s'] = time.perf_counter() - t0


@contextlib.contextmanager
def _domain(base, span):
    """Hold a domain of :func:`claim_domain` for the block."""
    d, fh = claim_domain(base, span)
    try:
        yield d
    finally:
        fcntl.flock(fh, fcntl.LOCK_UN)
        fh.close()


def _tail(path, lines=40):
    try:
        with open(path, encoding='utf-8', errors='replace') as fh:
            return ''.join(fh.readlines()[-lines:])
    except OSError:
        return ''


def _ros(spec, values, work, timing=None, bag=None):
    """Feed the run (its bag if given) to the command, paced or replayed at ``rate``; score."""
    from rigidrot_ros.run.generate import generate_bag
    est = spec['estimator']
    if est.get('rate') is None:
        from rigidrot_ros.campaign.session import run_paced
        timing = {} if timing is None else timing
        path, runs = run_paced(spec, values, work, timing, bag=bag)
        t0 = time.perf_counter()
        try:
            return score_bag(path, est['topics'][0], runs)
        finally:
            timing['score_s'] = time.perf_counter() - t0
    if bag is None:
        bag = generate_bag(values, spec['duration'], os.path.join(work, 'input'))
    from rigidrot_ros.bag import read_bag
    contents = read_bag(bag)
    names = sorted(t for t in contents.topics
                   if t.rsplit('/', 1)[-1] in ('imu', 'star_tracker', 'run'))
    rec_dir = os.path.join(work, 'recorded')
    deadline = time.monotonic() + spec['timeout']
    with _domain(est['domain_base'], est['domain_span']) as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED='1',
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                   FASTDDS_BUILTIN_TRANSPORTS='UDPv4')
        env.pop('ROS_LOCALHOST_ONLY', None)
        logs = {k: open(os.path.join(work, f'{k}.log'), 'w') for k in
                ('estimator', 'recorder', 'replay')}
        procs = {}
        try:
            procs['recorder'] = subprocess.Popen(
                [script('rigidrot_record')] + ['-o', rec_dir] + est['topics']
                + [f'{t}:std_msgs/msg/String' for t in names if t.endswith('/run')], env=env,
                stdout=logs['recorder'], stderr=subprocess.STDOUT)
            try:
                procs['estimator'] = subprocess.Popen(
                    est['command'], env=env, stdout=logs['estimator'],
                    stderr=subprocess.STDOUT)
            except OSError as exc:
                raise RunFailed(f'the estimator command {est["command"][0]} did not start: '
                                f'{exc.strerror or exc}') from None
            _wait_for_line(os.path.join(work, 'recorder.log'),
                           f'matched {est["topics"][0]} ', procs['estimator'],
                           min(30.0, spec['timeout']))
            inputs = est.get('inputs') or [t for t in names if not t.endswith('/run')]
            procs['replay'] = subprocess.Popen(
                [script('rigidrot_replay'), bag, '--clock', '--rate', repr(est['rate']),
                 '--quiet', '--wait', '10', '--topics'] + names
                + ['--wait-for'] + inputs,
                env=env, stdout=logs['replay'], stderr=subprocess.STDOUT)
            while procs['replay'].poll() is None:
                if procs['estimator'].poll() is not None:
                    raise RunFailed(f'the estimator exited with status '
                                    f'{procs["estimator"].returncode} during the replay')
                if time.monotonic() > deadline:
                    raise RunFailed(f'timeout: the run took longer than {spec["timeout"]:g} s')
                time.sleep(0.05)
            if procs['replay'].returncode != 0:
                said = _tail(os.path.join(work, 'replay.log'), 5).strip().splitlines()
                raise RunFailed(f'the replay failed with status {procs["replay"].returncode}'
                                + (f': {said[-1]}' if said else ''))
            time.sleep(1.0 if est.get('settle') is None else est['settle'])
            if procs['estimator'].poll() is not None:
                raise RunFailed(f'the estimator exited with status '
                                f'{procs["estimator"].returncode} during the replay')
            code = stop(procs['estimator'], 10.0)
            time.sleep(0.3)
            if code not in (0, -signal.SIGINT):
                raise RunFailed(f'the estimator exited with status {code} when stopped')
        finally:
            for name in ('replay', 'estimator', 'recorder'):
                if name in procs:
                    stop(procs[name], 10.0)
            for fh in logs.values():
                fh.close()
    if not os.path.isdir(rec_dir):
        raise RunFailed('the recorder wrote no bag')
    return score_bag(rec_dir, est['topics'][0], contents.runs)


def _wait_for_line(path, text, proc, limit):
    """Wait (``limit`` s at most) until the log at ``path`` shows ``text``, or proc ends.

    The runner waits for the recorder's ``matched <topic>``: the recorder's subscription
    has matched the estimator's publisher, so the estimator's answers to the replay (which
    itself waits for the estimator's subscriptions to match) are all recorded. Seeing the
    publisher in the graph (``recording <topic>``) is not enough: on a loaded machine the
    two ends matched seconds later, after a short replay had ended.
    """
    end = time.monotonic() + limit
    while time.monotonic() < end and proc.poll() is None:
        if text in _tail(path, 1000):
            return True
        time.sleep(0.05)
    return False


def run_one(spec, index, bag_root=None):
    """Run ``index`` of the campaign: a dict with ``row``, ``series`` and ``timing``.

    A failure of the estimator (crash, timeout, no output) is a result too: ``row`` has
    ``status: failed`` and the ``reason``, and ``log`` the details.
    """
    t0 = time.perf_counter()
    draws, redraws = draw_run(spec, index)
    row = {'run': int(index), 'status': 'ok', 'reason': '', 'redraws': redraws}
    row.update({k: v for k, v in draws.items()})
    out = {'row': row, 'series': None, 'log': ''}
    timing = {}
    in_memory = spec['estimator']['kind'] == 'inproc' and not bag_root   # no file at all
    owned = None if bag_root or in_memory else claim_work_dir(index)   # removed even if killed
    work = os.path.join(bag_root, f'run_{index:06d}') if bag_root else \
        (owned.path if owned is not None else None)
    if bag_root:
        shutil.rmtree(work, ignore_errors=True)
        os.makedirs(work)
    try:
        values = run_values(spec, draws)
        if spec['estimator']['kind'] == 'inproc':
            score, series = _inproc(spec, values, work, timing, keep=bool(bag_root))
        else:
            score, series = _ros(spec, values, work, timing)
        row.update(score)
        out['series'] = series
    except RunFailed as exc:
        row.update(status='failed', reason=exc.reason)
        if exc.startup:
            est = spec['estimator']
            what = (f'factory {est["factory"]}' if est['kind'] == 'inproc' else
                    f'command {" ".join(est["command"])}')
            out['fatal'] = f'estimator {what}: cannot start: {exc.reason}'
        out['log'] = exc.log + ''.join(
            f'--- {n}.log\n{_tail(os.path.join(work, n + ".log"))}'
            for n in ('estimator', 'recorder', 'replay')
            if work is not None and os.path.exists(os.path.join(work, n + '.log')))
    except Exception as exc:  # noqa: B902 - anything else fails this run, not the campaign
        row.update(status='failed', reason=f'{type(exc).__name__}: '
                                           f'{" ".join(str(exc).split())}'[:300])
        out['log'] = traceback.format_exc()
    finally:
        if owned is not None:
            owned.release()
    out['timing'] = dict(timing, wall_s=time.perf_counter() - t0)
    return out
