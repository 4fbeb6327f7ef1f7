"""Several estimators on the same Monte Carlo runs: one generation, every estimator fed.

A spec lists them under ``estimators:`` (each entry an ``estimator:`` mapping with a
``label``)::

    estimators:
      - label: tuned
        factory: rigidrot_ros.estimators.mekf:make
        params: {sigma_v: 1.7e-4, sigma_u: 2.0e-5, bias_sigma: 2.0e-3}
      - label: sigma_v / 10
        factory: rigidrot_ros.estimators.mekf:make
        params: {sigma_v: 1.7e-5, sigma_u: 2.0e-5, bias_sigma: 2.0e-3}

Each run is drawn and generated once: in-process estimators are all fed from one pass of
:func:`rigidrot_ros.run.generate.iter_run`; with a ROS program among them the run's bag is
generated once, replayed to each program in turn, and the in-process ones read its
messages. Each estimator's output is scored by the same scorer as a one-estimator
campaign (:func:`rigidrot_ros.campaign.run.score_bag`), so its section of the report is
the report its own campaign would give. An estimator that fails a run fails it alone.

The report compares them on the same runs: a table (ANEES, Monte Carlo NEES inside its
band, RMS error), overlaid charts of the Monte Carlo NEES and of the RMS error, and the
paired differences of the per-run RMS error and ANEES between every two estimators over
the runs both scored, with their spread (standard deviation, a Student-t 95 % interval
of the mean, the count of runs where the first is lower).
"""

import csv
import io
import json
import math
import os
import re
import shutil
import tempfile
import time
import traceback

import numpy as np

from rigidrot_ros.campaign.spec import draw_run, load_factory, run_values

__all__ = ['run_one_multi', 'finish_multi', 'paired', 't_ppf', 'comparison_md',
           'summary_lines', 'aggregate_multi']

_SEC = 1_000_000_000
#: Per-run metrics compared pairwise: row key -> (name, unit).
PAIRED = {'rms_rad': ('RMS error', 'rad'), 'anees': ('ANEES', ''),
          'p95_rad': ('p95 error', 'rad')}


# -- worker side ------------------------------------------------------------------------------
class _Sink:
    """One in-process estimator of a run: its filter, its bag, its outcome."""

    def __init__(self, est, work):
        from rigidrot_ros.campaign.run import RunFailed
        from rigidrot_ros.bag import BagWriter
        self.est, self.topic, self.failure, self.n_out = est, est['topic'], None, 0
        try:
            self.filt = load_factory(est['factory'])(dict(est['params']))
        except Exception as exc:  # noqa: B902 - the estimator's own failure
            self.filt = None
            self.failure = RunFailed(f'the factory failed: {type(exc).__name__}: {exc}',
                                     traceback.format_exc())
        self.writer = BagWriter(None, 'campaign', flush_period=60.0,
                                path=os.path.join(work, 'estimate'), split_seconds=0.0)

    def put(self, msgs):
        from rclpy.serialization import serialize_message

        from rigidrot_ros.ros.recorder import type_name_of
        for m in msgs:
            if not self.writer.has_topic(self.topic):
                self.writer.add_topic(self.topic, type_name_of(m))
            ns = m.header.stamp.sec * _SEC + m.header.stamp.nanosec
            self.writer.write(self.topic, serialize_message(m), ns)
            self.n_out += 1

    def run_message(self, msg, data, ns):
        from rigidrot_ros.run.generate import RUN_TOPIC
        self.writer.add_topic(RUN_TOPIC, 'std_msgs/msg/String')
        self.writer.add_run(json.loads(msg.data))
        self.writer.write(RUN_TOPIC, data, ns)

    def receive(self, name, msg, ns):
        from rigidrot_ros.campaign.run import RunFailed
        if self.failure is not None:
            return
        try:
            self.put(self.filt.receive(name, msg))
        except Exception as exc:  # noqa: B902 - the estimator crashed
            self.failure = RunFailed(f'the estimator crashed on {name} at stamp {ns} ns: '
                                     f'{type(exc).__name__}: {exc}', traceback.format_exc())

    def finish(self):
        from rigidrot_ros.campaign.run import RunFailed, score_bag
        if self.failure is None:
            try:
                self.put(self.filt.finish())
            except Exception as exc:  # noqa: B902
                self.failure = RunFailed(f'the estimator crashed in finish(): '
                                         f'{type(exc).__name__}: {exc}', traceback.format_exc())
        self.writer.close()
        if self.failure is not None:
            raise self.failure
        if not self.n_out:
            raise RunFailed(f'the estimator published nothing on {self.topic}')
        return score_bag(self.writer.path, self.topic)


def _messages(spec, values, bag):
    """Yield ``(topic, log_ns, msg, serialized or None)`` of the run, in log-time order."""
    from rigidrot_ros.run.generate import iter_run
    if bag is None:
        for name, ns, msg in iter_run(values, spec['duration']):
            yield name, ns, msg, None
        return
    from rclpy.serialization import deserialize_message

    from rigidrot_ros.bag import read_bag
    from rigidrot_ros.ros.recorder import msg_class
    classes = {}
    for topic, type_name, log_ns, _, data in read_bag(bag).messages:
        if type_name not in classes:
            classes[type_name] = msg_class(type_name)
        yield topic, log_ns, deserialize_message(data, classes[type_name]), data


def _feed(spec, values, work):
    """Run every estimator on the run: ``{label: (score, series) or RunFailed}``."""
    from rigidrot_ros.campaign import run as one
    from rigidrot_ros.run.generate import generate_bag, RUN_TOPIC
    ests = spec['estimators']
    results = {}
    bag = None
    if any(e['kind'] == 'ros' for e in ests):
        bag = generate_bag(values, spec['duration'], os.path.join(work, 'input'))
        for k, est in enumerate(ests):
            if est['kind'] != 'ros':
                continue
            sub = os.path.join(work, f'ros_{k}')
            os.makedirs(sub)
            try:
                results[est['label']] = one._ros(dict(spec, estimator=est), values, sub,
                                                 bag=bag)
            except one.RunFailed as exc:
                exc.log += ''.join(f'--- {n}.log\n{one._tail(os.path.join(sub, n + ".log"))}'
                                   for n in ('estimator', 'recorder', 'replay')
                                   if os.path.exists(os.path.join(sub, n + '.log')))
                results[est['label']] = exc
    sinks = {}
    for k, est in enumerate(ests):
        if est['kind'] == 'inproc':
            sub = os.path.join(work, f'inproc_{k}')
            os.makedirs(sub)
            sinks[est['label']] = _Sink(est, sub)
    if sinks:
        from rclpy.serialization import serialize_message
        deadline = time.monotonic() + spec['timeout']
        from rigidrot_ros.campaign.session import SENSORS
        for k, (name, ns, msg, data) in enumerate(_messages(spec, values, bag)):
            if name == RUN_TOPIC:
                raw = data if data is not None else serialize_message(msg)
                for s in sinks.values():
                    s.run_message(msg, raw, ns)
            elif name.rsplit('/', 1)[-1] not in SENSORS:
                continue            # the truth's topics: not given (as with one estimator)
            for s in sinks.values():
                s.receive(name, msg, ns)
            if k % 256 == 0 and time.monotonic() > deadline:
                for s in sinks.values():
                    if s.failure is None:
                        s.failure = one.RunFailed(f'timeout: the run took longer than '
                                                  f'{spec["timeout"]:g} s')
                break
        for label, s in sinks.items():
            try:
                results[label] = s.finish()
            except one.RunFailed as exc:
                results[label] = exc
    return results


def run_one_multi(spec, index, bag_root=None):
    """Run ``index`` of a several-estimator campaign (the worker's job).

    Returns ``row`` (the draws, ``status`` ok / partial / failed, and per estimator its
    score row under ``estimators``), ``series`` (per estimator) and ``timing``.
    """
    from rigidrot_ros.campaign import run as one
    t0 = time.perf_counter()
    draws, redraws = draw_run(spec, index)
    row = {'run': int(index), 'status': 'ok', 'reason': '', 'redraws': redraws}
    row.update(draws)
    out = {'row': row, 'series': {}, 'log': ''}
    work = os.path.join(bag_root, f'run_{index:06d}') if bag_root else \
        tempfile.mkdtemp(prefix=f'rigidrot_campaign_{index}_')
    if bag_root:
        shutil.rmtree(work, ignore_errors=True)
        os.makedirs(work)
    labels = [e['label'] for e in spec['estimators']]
    results = {}
    try:
        values = run_values(spec, draws)
        results = _feed(spec, values, work)     # offline: no wall-time budget to retry
    except Exception as exc:  # noqa: B902 - anything else fails this run, not the campaign
        reason = f'{type(exc).__name__}: {" ".join(str(exc).split())}'[:300]
        results = {label: one.RunFailed(reason, traceback.format_exc()) for label in labels}
    finally:
        if not bag_root:
            shutil.rmtree(work, ignore_errors=True)
    rows, logs = {}, []
    for label in labels:
        res = results.get(label)
        if isinstance(res, tuple):
            score, series = res
            rows[label] = dict({'status': 'ok', 'reason': ''}, **score)
            out['series'][label] = series
        else:
            res = res or one.RunFailed('not run')
            rows[label] = {'status': 'failed', 'reason': res.reason}
            logs.append(f'=== {label}: {res.reason}\n{res.log}')
    row['estimators'] = rows
    failed = [label for label in labels if rows[label]['status'] != 'ok']
    if failed:
        row['status'] = 'failed' if len(failed) == len(labels) else 'partial'
        row['reason'] = '; '.join(f'{label}: {rows[label]["reason"]}' for label in failed)[:300]
        out['log'] = '\n'.join(logs)
    out['timing'] = {'wall_s': time.perf_counter() - t0}
    return out


# -- client side: statistics --------------------------------------------------------------------
def t_ppf(p, dof):
    """Quantile ``p`` of Student's t with ``dof`` degrees of freedom (mpmath, bisection).

    The CDF is ``1 - I_x(dof/2, 1/2) / 2`` for t > 0 with ``x = dof / (dof + t^2)``
    (the regularised incomplete beta function).
    """
    import mpmath
    if not 0 < p < 1 or dof < 1:
        raise ValueError(f't quantile needs 0 < p < 1 and dof >= 1, got {p}, {dof}')
    if p < 0.5:
        return -t_ppf(1 - p, dof)
    if p == 0.5:
        return 0.0
    with mpmath.workdps(30):
        nu = mpmath.mpf(dof)

        def cdf(t):
            x = nu / (nu + t * t)
            return 1 - mpmath.betainc(nu / 2, mpmath.mpf(1) / 2, 0, x, regularized=True) / 2
        lo, hi = mpmath.mpf(0), mpmath.mpf(1)
        while cdf(hi) < p:
            hi *= 2
        for _ in range(200):
            mid = (lo + hi) / 2
            if cdf(mid) < p:
                lo = mid
            else:
                hi = mid
            if hi - lo <= 1e-15 * hi:
                break
        return float((lo + hi) / 2)


def paired(a, b):
    """Paired differences ``a - b`` (arrays of per-run values, NaN = not scored).

    Returns ``n`` (runs both scored), ``mean``, ``sd`` (sample standard deviation),
    ``ci95`` (Student-t interval of the mean; None below 2 runs), ``median``,
    ``a_lower`` (runs where a < b), ``min`` and ``max``.
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    ok = np.isfinite(a) & np.isfinite(b)
    d = a[ok] - b[ok]
    n = int(len(d))
    out = {'n': n, 'mean': None, 'sd': None, 'ci95': None, 'median': None,
           'a_lower': int(np.sum(a[ok] < b[ok])), 'min': None, 'max': None}
    if not n:
        return out
    out.update(mean=float(d.mean()), median=float(np.median(d)), min=float(d.min()),
               max=float(d.max()))
    if n >= 2:
        sd = float(d.std(ddof=1))
        half = t_ppf(0.975, n - 1) * sd / math.sqrt(n)
        out.update(sd=sd, ci95=[out['mean'] - half, out['mean'] + half])
    return out


def _per_estimator(results, spec):
    """Return the one-estimator results (rows and series) of each estimator, by label."""
    out = {}
    for est in spec['estimators']:
        label = est['label']
        rs = []
        for r in results:
            common = {k: v for k, v in r['row'].items()
                      if k not in ('estimators', 'status', 'reason')}
            rs.append({'row': dict(common, **r['row']['estimators'][label]),
                       'series': r['series'].get(label)})
        out[label] = rs
    return out


def aggregate_multi(results, spec):
    """Return the comparison report (JSON-serialisable) from all runs' results."""
    from rigidrot_ros.campaign.aggregate import aggregate
    per = _per_estimator(results, spec)
    labels = [e['label'] for e in spec['estimators']]
    reports = {}
    for est in spec['estimators']:
        rep = aggregate(per[est['label']], dict(spec, estimator=est, name=est['label']))
        reports[est['label']] = rep
    all_ok = sum(1 for r in results if r['row']['status'] == 'ok')
    report = {'name': spec['name'], 'seed': spec['seed'], 'runs': spec['runs'],
              'duration_s': spec['duration'], 'estimators': labels,
              'runs_all_ok': all_ok, 'per_estimator': reports}
    table = []
    for label in labels:
        rep = reports[label]
        entry = {'label': label, 'runs_ok': rep['runs_ok'], 'runs_failed': rep['runs_failed']}
        if 'anees' in rep:
            entry.update(anees=rep['anees']['value'], anees_bounds_95=rep['anees']['bounds_95'],
                         mc_inside=rep['mc_nees']['fraction_inside'],
                         mc_band_95=rep['mc_nees']['band_95'],
                         rms_rad=rep['rms_error']['overall_rad'],
                         runs_inside=rep['per_run_anees']['fraction_inside'])
        table.append(entry)
    per_run = {label: {key: [r['row'][key] if r['row']['status'] == 'ok' else None
                             for r in per[label]] for key in PAIRED} for label in labels}
    pairs = []
    for i, a in enumerate(labels):
        for b in labels[i + 1:]:
            entry = {'a': a, 'b': b}
            for key in PAIRED:
                entry[key] = paired(_nan(per_run[a][key]), _nan(per_run[b][key]))
            pairs.append(entry)
    report['comparison'] = {'table': table, 'paired': pairs, 'per_run': per_run}
    return report


def _nan(values):
    return [math.nan if v is None else v for v in values]


def csv_rows_multi(results, spec):
    """Header and rows of runs.csv: one row per run and estimator (``estimator`` column)."""
    from rigidrot_ros.campaign.aggregate import csv_rows
    per = _per_estimator(results, spec)
    labels = [e['label'] for e in spec['estimators']]
    header = None
    rows_by = {}
    for label in labels:
        h, rows = csv_rows(per[label])
        header = header or h
        rows_by[label] = rows
    out = []
    for i in range(len(results)):
        for label in labels:
            row = rows_by[label][i]
            out.append([row[0], label] + row[1:])
    return [header[0], 'estimator'] + header[1:], out


def _fmt(x, digits=4):
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return '—'
    return f'{x:.{digits}g}'


def comparison_md(report):
    """Return the comparison as Markdown: the table, then the paired differences."""
    lines = [f'# {report["name"] or "campaign"}: {len(report["estimators"])} estimators on '
             f'the same {report["runs"]} runs ({report["runs_all_ok"]} scored for all)', '',
             '| estimator | runs ok | ANEES [95 % bounds] | steps with MC NEES in its band | '
             'runs whose ANEES is in its band | RMS error, rad |', '|---|---|---|---|---|---|']
    for e in report['comparison']['table']:
        if 'anees' in e:
            lo, hi = e['anees_bounds_95']
            mlo, mhi = e['mc_band_95']
            lines.append(f'| {e["label"]} | {e["runs_ok"]} | {_fmt(e["anees"])} '
                         f'[{_fmt(lo)}, {_fmt(hi)}] | {100 * e["mc_inside"]:.1f} % of '
                         f'[{_fmt(mlo)}, {_fmt(mhi)}] | {100 * e["runs_inside"]:.0f} % | '
                         f'{_fmt(e["rms_rad"])} |')
        else:
            lines.append(f'| {e["label"]} | {e["runs_ok"]} | — | — | — | — |')
    lines += ['', 'Paired differences (first minus second) over the runs both scored:', '',
              '| first | second | metric | runs | mean | sd | 95 % interval of the mean | '
              'median | first lower in |', '|---|---|---|---|---|---|---|---|---|']
    for p in report['comparison']['paired']:
        for key, (name, unit) in PAIRED.items():
            d = p[key]
            ci = '—' if d['ci95'] is None else f'[{_fmt(d["ci95"][0])}, {_fmt(d["ci95"][1])}]'
            lines.append(f'| {p["a"]} | {p["b"]} | {name}{", " + unit if unit else ""} | '
                         f'{d["n"]} | {_fmt(d["mean"])} | {_fmt(d["sd"])} | {ci} | '
                         f'{_fmt(d["median"])} | {d["a_lower"]} of {d["n"]} |')
    return '\n'.join(lines) + '\n'


def summary_lines(report):
    """One line per estimator and per pair, for the command's output."""
    lines = []
    for e in report['comparison']['table']:
        if 'anees' in e:
            lines.append(f'{e["label"]}: {e["runs_ok"]}/{report["runs"]} runs ok, ANEES '
                         f'{e["anees"]:.3f} [{e["anees_bounds_95"][0]:.3f}, '
                         f'{e["anees_bounds_95"][1]:.3f}], Monte Carlo NEES inside its band at '
                         f'{100 * e["mc_inside"]:.1f} % of steps, RMS error '
                         f'{e["rms_rad"]:.3g} rad')
        else:
            lines.append(f'{e["label"]}: {e["runs_ok"]}/{report["runs"]} runs ok: nothing '
                         f'to aggregate')
    for p in report['comparison']['paired']:
        d = p['rms_rad']
        if d['n']:
            ci = '' if d['ci95'] is None else \
                f' (95 % interval [{d["ci95"][0]:.3g}, {d["ci95"][1]:.3g}])'
            lines.append(f'{p["a"]} - {p["b"]}: RMS error {d["mean"]:+.3g} rad on average'
                         f'{ci}, {p["a"]} lower in {d["a_lower"]} of {d["n"]} runs')
    return lines


def _slug(label):
    return re.sub(r'[^A-Za-z0-9_.-]+', '_', label).strip('_.') or 'estimator'


def finish_multi(spec, out_dir, results, write_atomic, dumps):
    """Write report.json, runs.csv, comparison.md and the charts of a comparison.

    ``write_atomic(path, text)`` and ``dumps(obj)`` are the engine's (its file writes).
    """
    report = aggregate_multi(results, spec)
    write_atomic(os.path.join(out_dir, 'report.json'), dumps(report))
    header, rows = csv_rows_multi(results, spec)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator='\n')
    w.writerow(header)
    w.writerows(rows)
    write_atomic(os.path.join(out_dir, 'runs.csv'), buf.getvalue())
    write_atomic(os.path.join(out_dir, 'comparison.md'), comparison_md(report))
    try:
        from rigidrot_ros.campaign.charts import write_charts
        slugs = {}
        for label in report['estimators']:
            slug = _slug(label)
            while slug in slugs.values():
                slug += '_'
            slugs[label] = slug
            sub = os.path.join(out_dir, slug)
            os.makedirs(sub, exist_ok=True)
            write_charts(report['per_estimator'][label], sub)
        compare_charts(report, out_dir)
    except ImportError:
        import sys
        print('rigidrot_campaign: no charts: pip install matplotlib', file=sys.stderr)
    return report


def compare_charts(report, out_dir):
    """Overlaid Monte Carlo NEES and RMS error, and the paired differences; the paths."""
    from rigidrot_ros.campaign.charts import _plt, _save, compare_chart
    reps = [dict(report['per_estimator'][label], _dir=label, name=label)
            for label in report['estimators'] if 'mc_nees' in report['per_estimator'][label]]
    paths = []
    if not reps:
        return paths
    paths += compare_chart(reps, os.path.join(out_dir, 'compare_nees'))
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4))
    colors = ['tab:blue', 'tab:red', 'tab:purple', 'tab:orange', 'tab:green', 'tab:brown']
    for i, rep in enumerate(reps):
        rms = rep['rms_error']
        ax.plot(rms['t_s'], [r * 206264.806 for r in rms['rad']], lw=1.0,
                color=colors[i % len(colors)],
                label=f'{rep["name"]}: M = {rep["runs_ok"]}, overall '
                      f'{rms["overall_rad"] * 206264.806:.3g}"')
    ax.set_yscale('log')
    ax.set_xlabel('scene time, s')
    ax.set_ylabel('RMS attitude error over runs, arcsec')
    ax.set_title(f'{report["name"] or "campaign"}: the same {report["runs"]} runs')
    ax.legend(fontsize=8)
    paths += _save(fig, os.path.join(out_dir, 'compare_rms_error'))
    plt.close(fig)
    pairs = report['comparison']['paired']
    if pairs:
        per = report['comparison']['per_run']
        fig, axes = plt.subplots(1, 2, figsize=(10, 4))
        for ax, key, unit in ((axes[0], 'rms_rad', 'RMS error difference, arcsec'),
                              (axes[1], 'anees', 'ANEES difference')):
            data, names = [], []
            for p in pairs:
                va, vb = per[p['a']][key], per[p['b']][key]
                scale = 206264.806 if key == 'rms_rad' else 1.0
                d = [scale * (x - y) for x, y in zip(va, vb) if x is not None and y is not None]
                data.append(d)
                names.append(f'{p["a"]} - {p["b"]}\n(n = {len(d)})')
            ax.boxplot(data, showmeans=True)
            ax.set_xticks(range(1, len(names) + 1))
            ax.set_xticklabels(names, fontsize=7)
            ax.axhline(0.0, color='k', lw=0.8, ls=':')
            ax.set_ylabel(unit)
        axes[0].set_title('Paired per-run differences (box: quartiles, triangle: mean)',
                          fontsize=9)
        paths += _save(fig, os.path.join(out_dir, 'compare_paired'))
        plt.close(fig)
    return paths
