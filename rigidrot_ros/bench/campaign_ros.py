"""Benchmark part ``campaign_ros``: a ROS estimator's campaign, runs a minute, and what bounds it.

``python -m rigidrot_ros.bench.campaign_ros [--campaign-runs M] [--campaign-domain D]``
(or ``rigidrot_bench --only campaign_ros``) runs ``doc/campaigns/mekf_ros.yaml``'s
campaign (the reference MEKF as the ROS program ``rigidrot_mekf``; M runs, default 10, 4
with ``--quick``) on a process pool of 2, three ways, in one run:

- **replay at 5×** (``rate: 5.0``): a ``rigidrot_replay`` and a ``rigidrot_record`` process
  per run beside the estimator, at five times real time (the path before the paced one);
- **paced, a process per run** (no ``rate:``): the worker feeds the estimator as fast as it
  answers (:mod:`rigidrot_ros.campaign.session`); a new ``rigidrot_mekf`` per run;
- **paced, long-lived** (``reset: /mekf/reset``): one ``rigidrot_mekf`` per worker, reset
  between runs.

For each: runs a minute including start-up (pool, imports, the first estimator), the
median of each run's phases (generate, estimator start until it listens, play, confirm,
settle, stop or reset, score) and the largest difference of each step's NEES from the same
runs in process (``rigidrot_ros.estimators.mekf:make``). Then what bounds a run, measured
apart on the campaign's first run: a Python start, ``import rclpy``, an echo node's start
until its subscriptions exist and until they are matched (discovery), the paced transport
of the run to that echo node (raw subscriptions taken the way ``rigidrot_mekf`` takes them,
a stamp-only answer at every 10th gyro sample as the MEKF answers: DDS and rclpy without a
filter), and the MEKF in
process on the same messages (the filter alone). :func:`render_md` writes
``OUT/campaign_ros.md`` (``doc/bench/campaign_ros.md``, included by ``doc/estimator.md``).
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

from rigidrot_ros.bench import common

__all__ = ['NAME', 'NEEDS', 'run', 'main', 'render_md', 'add_arguments', 'VARIANTS']

NAME = 'campaign_ros'
NEEDS = ('rclpy', 'yaml')
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SPEC = os.path.join(ROOT, 'doc', 'campaigns', 'mekf_ros.yaml')
#: The ways, by key: (label, estimator keys set, estimator keys removed, runs: None for
#: the campaign's M, else at most that many). The replay at 5x is bound by the wall clock
#: (6 s a run): 10 runs measure it; the long-lived way is run on 10 runs too, to show what
#: start-up weighs in a short campaign.
VARIANTS = (
    ('replay_5x', 'replay at 5× (`rate: 5.0`), replay and recorder processes',
     {'rate': 5.0}, ('reset', 'settle', 'window', 'clock_step'), 10),
    ('paced_process', 'paced, a process per run', {'settle': 0.0}, ('rate', 'reset'), None),
    ('paced_long_lived', 'paced, long-lived (`reset: /mekf/reset`)',
     {'settle': 0.0, 'reset': '/mekf/reset'}, ('rate',), None),
    ('paced_long_lived_10', 'paced, long-lived, 10 runs',
     {'settle': 0.0, 'reset': '/mekf/reset'}, ('rate',), 10),
)
TYPES = {'/imu': 'sensor_msgs/msg/Imu',
         '/star_tracker': 'geometry_msgs/msg/PoseWithCovarianceStamped'}
PHASES = ('generate_s', 'ready_s', 'play_s', 'confirm_s', 'settle_s', 'end_s', 'score_s',
          'wall_s', 'estimator_cpu_s', 'feeder_cpu_s')
_ECHO = r'''
import struct, time
import rclpy
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped, QuaternionStamped
from sensor_msgs.msg import Imu
rclpy.init()
node = rclpy.create_node('echo')
pub = node.create_publisher(QuaternionStamped, 'estimator/odom', 10000)
subs = []
count = [0]
def answer(data, imu):
    count[0] += imu
    if imu and count[0] % 10 == 0:     # as the MEKF: at every 10th gyro sample, its stamp
        sec, nsec = struct.unpack_from('<iI', data, 4)
        msg = QuaternionStamped()
        msg.header.stamp = Time(sec=sec, nanosec=nsec)
        pub.publish(msg)
def on(data):           # this message, then every one waiting (rigidrot_mekf's way)
    answer(data, True)
    more = True
    while more:
        more = False
        for sub, imu in subs:
            with sub.handle:
                got = sub.handle.take_message(sub.msg_type, sub.raw)
            if got is not None:
                answer(got[0], imu)
                more = True
subs.append((node.create_subscription(Imu, 'imu', on, 10000, raw=True), True))
subs.append((node.create_subscription(PoseWithCovarianceStamped, 'star_tracker',
                                      lambda data: None, 10000, raw=True), False))
print(f'ready {time.monotonic()!r}', flush=True)
try:
    rclpy.spin(node)
except BaseException:
    pass
'''


def _spec_doc(runs, domain):
    import yaml
    with open(SPEC, encoding='utf-8') as fh:
        doc = yaml.safe_load(fh)
    doc['runs'] = runs or doc['runs']
    if domain is not None:
        doc['estimator']['domain_base'] = domain
    return doc


def _campaign(doc, tmp, name, log):
    """Run the campaign ``doc``; (wall s, report, per-run timing dicts, series by run)."""
    import yaml

    from rigidrot_ros.campaign.engine import run_campaign
    from rigidrot_ros.campaign.spec import load_spec
    path = os.path.join(tmp, f'{name}.yaml')
    with open(path, 'w', encoding='utf-8') as fh:
        yaml.safe_dump(doc, fh)
    spec = load_spec(path)
    out = os.path.join(tmp, name)
    t0 = time.perf_counter()
    report = run_campaign(spec, out, workers=2, progress=False)
    wall = time.perf_counter() - t0
    timings, series = [], {}
    for i in range(spec['runs']):
        with open(os.path.join(out, 'runs', f'{i:06d}.time.json'), encoding='utf-8') as fh:
            timings.append(json.load(fh))
        with open(os.path.join(out, 'runs', f'{i:06d}.json'), encoding='utf-8') as fh:
            series[i] = json.load(fh)['series']
    return wall, report, timings, series


def _nees_diff(a, b):
    """Largest relative difference of the per-step NEES of two runs' series; NaN if unlike."""
    if not a or not b or a['t_ns'] != b['t_ns']:
        return float('nan')
    return max((abs(x - y) / max(1.0, abs(y)) for x, y in zip(a['nees'], b['nees'])),
               default=float('nan'))


def _campaigns(runs, domain, log):
    doc = _spec_doc(runs, domain)
    est = doc['estimator']
    out = {'runs': runs, 'spec': os.path.relpath(SPEC, ROOT), 'variants': {}}
    with tempfile.TemporaryDirectory(prefix='rigidrot_bench_camp_') as tmp:
        ref = dict(doc, estimator={
            'factory': 'rigidrot_ros.estimators.mekf:make',
            'params': {'sigma_v': 1.7e-4, 'sigma_u': 2.0e-5, 'bias_sigma': 2.0e-3}})
        wall, ref_report, _, in_series = _campaign(ref, tmp, 'in_process', log)
        out['in_process'] = {'wall_s': wall, 'runs_per_min': 60.0 * runs / wall,
                             'anees': ref_report['anees']['value'],
                             'inside': ref_report['mc_nees']['fraction_inside']}
        log(f'campaign_ros: the same {runs} runs in process: {wall:.1f} s = '
            f'{60.0 * runs / wall:.1f} runs/min, ANEES {ref_report["anees"]["value"]:.3f}')
        for key, label, put, drop, cap in VARIANTS:
            m = runs if cap is None else min(runs, cap)
            e = {k: v for k, v in est.items() if k not in drop}
            e.update(put)
            load0 = os.getloadavg()[0]
            wall, report, timings, series = _campaign(dict(doc, runs=m, estimator=e), tmp,
                                                      key, log)
            phases = {p: statistics.median(t[p] for t in timings if p in t)
                      for p in PHASES if any(p in t for t in timings)}
            started = sum('ready_s' in t for t in timings)
            diff = [_nees_diff(series[i], in_series[i]) for i in range(m)]
            v = {'label': label, 'runs': m, 'wall_s': wall, 'runs_per_min': 60.0 * m / wall,
                 'runs_ok': report['runs_ok'], 'phases': phases, 'started': started,
                 'anees': (report.get('anees') or {}).get('value'),
                 'nees_max_rel_diff': max(diff), 'nees_runs_compared':
                     sum(d == d for d in diff),
                 'load_average': [load0, os.getloadavg()[0]]}
            out['variants'][key] = v
            log(f'campaign_ros: {label}: {m} runs in {wall:.1f} s = '
                f'{v["runs_per_min"]:.1f} runs/min ({report["runs_ok"]} ok; per-step NEES '
                f'vs in process: max rel diff {v["nees_max_rel_diff"]:.2g} over '
                f'{v["nees_runs_compared"]} runs); median per run: '
                + ', '.join(f'{p[:-2]} {s:.3f} s' for p, s in phases.items())
                + f' (load average {load0:.1f} -> {os.getloadavg()[0]:.1f})')
    return out


def _start_costs(log, repeats=3):
    """Seconds to start Python, to import rclpy, and an echo node until it listens."""
    def child(code):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, '-c', code], check=True, capture_output=True)
        return time.perf_counter() - t0
    res = {'python_s': statistics.median(child('pass') for _ in range(repeats)),
           'import_rclpy_s': statistics.median(
               child('import rclpy, numpy') for _ in range(repeats))}
    log(f'campaign_ros: a Python start {res["python_s"]:.3f} s, with import rclpy, numpy '
        f'{res["import_rclpy_s"]:.3f} s (median of {repeats})')
    return res


def _transport(domain, log):
    """Play the campaign's first run to an echo node, paced; the MEKF on it in process."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from rigidrot_ros.campaign.session import claim_domain, feed_topics, SENSORS
    from rigidrot_ros.campaign.spec import check_spec, draw_run, run_values
    from rigidrot_ros.estimators.mekf import make
    from rigidrot_ros.ros.paced import fast_dds, PacedPlayer
    from rigidrot_ros.ros.recorder import msg_class
    from rigidrot_ros.run.generate import iter_run, iter_serialized
    doc = _spec_doc(1, domain)
    spec = check_spec(doc, os.path.dirname(SPEC))
    values = run_values(spec, draw_run(spec, 0)[0])
    res = {}
    msgs = list(iter_serialized(values, spec['duration'], SENSORS))
    inputs = {t: TYPES[t] for t in feed_topics({m[0] for m in msgs})}
    res['messages'] = len(msgs)
    d, lock = claim_domain(spec['estimator']['domain_base'], spec['estimator']['domain_span'])
    env = dict(os.environ, ROS_DOMAIN_ID=str(d), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               FASTDDS_BUILTIN_TRANSPORTS='UDPv4')
    env.pop('ROS_LOCALHOST_ONLY', None)
    saved = dict(os.environ)
    os.environ.update({k: env[k] for k in ('ROS_AUTOMATIC_DISCOVERY_RANGE',
                                           'FASTDDS_BUILTIN_TRANSPORTS')})
    fast_dds()
    ctx = Context()
    rclpy.init(args=['bench'], context=ctx, domain_id=d,
               signal_handler_options=SignalHandlerOptions.NO)
    os.environ.clear()
    os.environ.update(saved)
    node = rclpy.create_node('bench_feed', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    player = PacedPlayer(node, ex, {t: msg_class(n) for t, n in inputs.items()},
                         ['/estimator/odom'], clock=True)
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, '-c', _ECHO], env=env, stdout=subprocess.PIPE,
                            text=True)
    try:
        line = proc.stdout.readline().split()
        ready = float(line[1]) if line and line[0] == 'ready' else float('nan')
        while player.missing() or player.poll_outputs() or not player.outputs_matched():
            player.spin(0.005)
            if time.monotonic() - t0 > 60:
                raise RuntimeError('the echo node did not match within 60 s')
        matched = time.monotonic()
        res.update(echo_start_s=ready - t0, discovery_s=matched - ready)
        t1 = time.perf_counter()
        player.play(msgs)
        res['echo_play_s'] = time.perf_counter() - t1
        player.confirm()
        player.settle(1.0, early=False)
        res['echo_answers'] = len(player.answers)
    finally:
        common.stop(proc, 5)
        ex.shutdown(0)
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        lock.close()
    res['echo_msgs_per_s'] = res['messages'] / res['echo_play_s']
    filt = make({'sigma_v': 1.7e-4, 'sigma_u': 2.0e-5, 'bias_sigma': 2.0e-3})
    run_msgs = [(n, m) for n, _, m in iter_run(values, spec['duration'])
                if n.rsplit('/', 1)[-1] in ('imu', 'star_tracker')]
    t1 = time.perf_counter()
    for n, m in run_msgs:
        filt.receive(n, m)
    filt.finish()
    res['mekf_in_process_s'] = time.perf_counter() - t1
    log(f'campaign_ros: one run ({res["messages"]} messages): echo node started in '
        f'{res["echo_start_s"]:.3f} s, discovery (its subscriptions made -> matched) '
        f'{res["discovery_s"]:.3f} s, paced transport to it {res["echo_play_s"]:.3f} s '
        f'({res["echo_msgs_per_s"]:.0f} messages/s, {res["echo_answers"]} answers); the '
        f'MEKF in process on the same messages {res["mekf_in_process_s"]:.3f} s')
    return res


def run(quick=False, log=print, campaign_runs=None, campaign_domain=None):
    """Measure and return the figures (JSON-serialisable); ``quick``: 4 runs a campaign."""
    runs = int(campaign_runs or (4 if quick else _spec_doc(None, None)['runs']))
    res = {'quick': bool(quick), 'cores': os.cpu_count()}
    res['bounds'] = _start_costs(log)
    res['bounds'].update(_transport(campaign_domain, log))
    res.update(_campaigns(runs, campaign_domain, log))
    return res


def add_arguments(ap):
    """Add ``--campaign-runs`` and ``--campaign-domain`` to the parser ``ap``."""
    ap.add_argument('--campaign-runs', type=int, metavar='M',
                    help="campaign_ros: runs a campaign (default: the spec's, 4 with --quick; "
                         'the replay at 5x and the short campaign: 10 at most)')
    ap.add_argument('--campaign-domain', type=int, metavar='D',
                    help="campaign_ros: first ROS domain of the campaigns' (default: the "
                         "spec's domain_base)")


def render_md(results):
    """Return the part's tables from merged results (``'campaign_ros'``), or None."""
    res = results.get(NAME)
    if not res:
        return None
    fmt = common.fmt
    rows = []
    ref = res.get('in_process')
    if ref:
        rows.append(('in process (`factory:`), for reference', res['runs'],
                     f'**{fmt(ref["runs_per_min"])}**', f'{fmt(ref["wall_s"])} s',
                     '—', '—', '—', '—', '—', '—', '—', f'ANEES {ref["anees"]:.3f}'))
    for key, *_ in VARIANTS:
        v = res['variants'].get(key)
        if not v:
            continue
        ph = v['phases']
        m = v.get('runs', res['runs'])
        rows.append((v['label'], m, f'**{fmt(v["runs_per_min"])}**',
                     f'{fmt(v["wall_s"])} s, {v["runs_ok"]}/{m} ok',
                     (f'{fmt(ph["ready_s"])} ({v["started"]}×)' if 'ready_s' in ph else '—'),
                     fmt(ph.get('generate_s')), fmt(ph.get('play_s')),
                     fmt(ph.get('settle_s', 0) + ph.get('end_s', 0)
                         if 'end_s' in ph else None),
                     fmt(ph.get('score_s')), fmt(ph.get('wall_s')),
                     (f'{fmt(ph["estimator_cpu_s"])} / {fmt(ph["feeder_cpu_s"])}'
                      if 'estimator_cpu_s' in ph else '—'),
                     f'max diff {fmt(v["nees_max_rel_diff"], 2)}'))
    table = common.md_table(
        ['way', 'runs', 'runs/min', 'campaign (wall)', 'estimator start (s)',
         'generate (s)', 'play (s)', 'settle + stop or reset (s)', 'score (s)',
         'run (s)', 'CPU in play: estimator / worker (s)', 'per-step NEES vs in process'],
        rows)
    b = res['bounds']
    bounds = common.md_table(['what bounds a run, measured apart', 'seconds'], [
        ('process start: Python / Python with `import rclpy, numpy`',
         f'{fmt(b["python_s"])} / {fmt(b["import_rclpy_s"])}'),
        ('process start: an echo node, spawned until its subscriptions exist',
         fmt(b['echo_start_s'])),
        ('discovery: its subscriptions made until matched', fmt(b['discovery_s'])),
        (f'transport: one run ({b["messages"]} messages) paced to the echo node '
         '(rclpy on both ends, taken as rigidrot_mekf takes them, no filter)',
         f'{fmt(b["echo_play_s"])} ({fmt(b["echo_msgs_per_s"])} messages/s)'),
        ('the filter: the MEKF in process on the same messages',
         fmt(b['mekf_in_process_s']))])
    loads = [x for v in res['variants'].values() for x in v['load_average']]
    title = (f"A ROS estimator's campaign (`rigidrot_bench --only campaign_ros`): "
             f'{res["spec"]} (30 s runs) on a process pool of 2, the ways side by side in '
             f'one run; phases are medians over the runs; load average '
             f'{min(loads):.1f}–{max(loads):.1f} on {res["cores"]} cores')
    if res.get('quick'):
        title += '; quick run'
    return common.part_md(results, NAME, title, table + '\n' + bounds)


def main(argv=None):
    """``python -m rigidrot_ros.bench.campaign_ros``: this part alone, into ``--out``."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
