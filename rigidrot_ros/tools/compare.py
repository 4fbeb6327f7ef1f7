"""rigidrot_compare: score a log's attitude and rate topics against the exact truth.

Every topic of a supported type (QuaternionStamped, Vector3Stamped, Imu, Odometry,
PoseStamped, PoseWithCovarianceStamped, TransformStamped) is compared at each message's
stamp with the exact solution recomputed from the log's run descriptions (all resets
honoured), or with a second log (--truth). Attitude error: the angle ``|e|`` of
q_true^-1 * q_est = exp(e/2) (e in the body frame), rad. Rate error: norm of the
difference, rad/s. Where a message carries an orientation covariance: NEES per sample and
ANEES with its 95 % chi-square bounds. Topics it cannot score are listed with the reason.
"""

import csv
import json
import math
import os
import sys

from rigidrot_ros.bag import BagError, read_bag
from rigidrot_ros.bag.metadata import bags_below
from rigidrot_ros.scoring.score import (
    check_bag, describe_sensor, extract_streams, score_against_runs, score_against_stream,
    ScoreError,
)
from rigidrot_ros.tools.cli import OneLineParser

CONVENTION = ('attitude error e: q_true^-1 * q_est = exp(e/2), e in the body frame B '
              '(rad); rate error: omega_est - omega_true in B (rad/s); '
              'NEES = e^T P^-1 e with P the orientation covariance')
_ARRAYS = ('t', 'error', 'nees', 'components', 'sigma')
_FLOOR = 1e-17
#: The log error axes start at the decade below this quantile of a panel's errors: a few
#: samples far below the rest (an estimator started at the truth, t = 0 exact to 1e-17)
#: would otherwise stretch the axis over many empty decades.
AXIS_QUANTILE = 0.01
#: Colours of the error components x, y, z in the covariance panels (ColorBrewer Dark2:
#: none of them is a topic's colour, which come from matplotlib's C0...C9).
_AXIS_COLORS = ('#1b9e77', '#d95f02', '#7570b3')
PLOT_SUFFIXES = ('.png', '.svg', '.pdf')


def _table(results, skipped):
    lines = [f'{"topic":36s} {"type":26s} {"n":>6s} {"max":>10s} {"rms":>10s} {"p95":>10s}'
             f'  {"unit":5s} {"ANEES [95% bounds]"}']
    for r in results:
        kind = r['type'].split('/')[-1]
        if not r['count']:
            why = r.get('reason', 'no message inside a run')
            lines.append(f'{r["label"]:36s} {kind:26s} {0:6d}  ({why})')
            continue
        nees_txt = ''
        if 'anees' in r:
            lo, hi = r['anees_bounds_95']
            flag = ('' if lo <= r['anees'] <= hi else '  below: conservative'
                    if r['anees'] < lo else '  above: over-confident')
            nees_txt = f'{r["anees"]:.3g} [{lo:.3g}, {hi:.3g}]{flag}'
        elif r.get('nees_count') == 0:
            nees_txt = 'no usable covariance'
        lines.append(f'{r["label"]:36s} {kind:26s} {r["count"]:6d} {r["max"]:10.3e} '
                     f'{r["rms"]:10.3e} {r["p95"]:10.3e}  {r["unit"]:5s} {nees_txt}')
        if r.get('truth_gaps'):
            lines.append(f'{"":36s} {r["truth_gaps"]} message(s) inside gaps of the truth '
                         f'log ({r["truth_topic"]}) not scored')
    for s in skipped:
        lines.append(f'{s["topic"]:36s} {s["type"].split("/")[-1]:26s}  not scored: '
                     f'{s["reason"]}')
    sensors = {}
    for r in results:
        if r.get('sensor'):
            sensors.setdefault(r['sensor'].get('name'), r['sensor'])
    if sensors:
        lines.append('sensor error models (from the run description):')
        lines += [f'  {describe_sensor(s)}' for s in sensors.values()]
    return '\n'.join(lines)


def _truth_topics(runs):
    out = set()
    for r in runs:
        topics = r.get('topics') or {}
        out.update(topics.keys() if all(k.startswith('/') for k in topics) else
                   topics.values())
    return out


def _import_pyplot():
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        raise ScoreError('--plot needs matplotlib: pip install matplotlib (or pip install '
                         '"rigidrot_ros[plot]")') from None
    return plt


def _log_bottom(rs):
    """Return the bottom of a log error axis: the decade below the AXIS_QUANTILE of errors."""
    errs = sorted(e for r in rs for e in r['error'] if math.isfinite(e) and e >= _FLOOR)
    if not errs:
        return _FLOOR
    pos = AXIS_QUANTILE * (len(errs) - 1)               # linear interpolation, as numpy's
    k = int(pos)
    q = errs[k] + (pos - k) * (errs[min(k + 1, len(errs) - 1)] - errs[k])
    return max(_FLOOR, 10.0 ** math.floor(math.log10(q)))


def _plot(plt, results, path, title, yscale):
    # one colour per topic in every panel (its attitude and its rate alike)
    topics = list(dict.fromkeys(r['topic'] for r in results))
    color = {t: f'C{k % 10}' for k, t in enumerate(topics)}
    angle = [r for r in results if r['unit'] == 'rad' and r['count']]
    rate = [r for r in results if r['unit'] == 'rad/s' and r['count']]
    banded = [r for r in angle if 'components' in r][:3]
    rows = [('angle', angle)] * bool(angle) + [('rate', rate)] * bool(rate) + [
        ('band', [r]) for r in banded]
    fig, axes = plt.subplots(len(rows), 1, figsize=(9, 2.6 * len(rows) + 0.8), sharex=True,
                             squeeze=False)
    for ax, (kind, rs) in zip(axes[:, 0], rows):
        if kind in ('angle', 'rate'):
            # a log axis cannot show zeros, and a few samples far below the rest (errors
            # below float64 rounding of a unit quantity, 1e-17, say nothing more) would
            # squeeze the useful range: the axis starts at the decade below the panel's
            # 1st percentile, and the samples below it are drawn on it, and counted
            floor = _log_bottom(rs) if yscale == 'log' else None
            for r in rs:
                err = r['error']
                low = sum(1 for e in err if not e >= floor) if floor else 0
                label = r['label']
                if low:
                    err = [e if e >= floor else floor for e in err]
                    label += f' ({low} below {floor:.0e}, drawn on the axis bottom)'
                ax.plot(r['t'], err, '.', ms=2, label=label, color=color[r['topic']])
            ax.set_yscale(yscale)
            if floor:
                ax.set_ylim(bottom=floor)
            ax.set_ylabel('attitude error |e| [rad]' if kind == 'angle'
                          else 'rate error [rad/s]')
            ax.legend(loc='best', fontsize=7, markerscale=4, framealpha=0.9)
        else:
            r = rs[0]
            t = r['t']
            for k, (axis, c_axis) in enumerate(zip('xyz', _AXIS_COLORS)):
                comp = [c[k] for c in r['components']]
                sig = [3 * s[k] for s in r['sigma']]
                ax.plot(t, comp, '-', lw=0.8, color=c_axis, label=f'e_{axis}')
                ax.fill_between(t, [-v for v in sig], sig, color=c_axis, alpha=0.12,
                                lw=0, label=f'±3σ_{axis}')
            lo, hi = r['anees_bounds_95']
            ax.set_ylabel('error e in B [rad]')
            ax.set_title(f'{r["label"]}: error components and ±3σ from its covariance; '
                         f'ANEES {r["anees"]:.3g} (95 % bounds [{lo:.3g}, {hi:.3g}], '
                         f'{r["nees_count"]} samples)', fontsize=8)
            ax.legend(loc='upper left', fontsize=7, ncol=6, framealpha=0.9)
        ax.grid(True, which='both', alpha=0.3)
    axes[-1, 0].set_xlabel('scene time t since the run started [s]')
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _write_csv(results, path):
    with open(path, 'w', newline='', encoding='utf-8') as fh:
        w = csv.writer(fh)
        w.writerow(['topic', 'field', 't_s', 'error', 'unit', 'nees'])
        for r in results:
            nees = r.get('nees') or [math.nan] * len(r['t'])
            for t, e, n in zip(r['t'], r['error'], nees):
                w.writerow([r['topic'], r['field'], repr(t), repr(e), r['unit'],
                            '' if n is None or math.isnan(n) else repr(n)])


def _one_bag(path):
    """Return ``path``, or the one bag one level below a directory that holds no .mcap."""
    if os.path.isdir(path) and not any(f.endswith('.mcap') for f in os.listdir(path)):
        inner = bags_below(path)
        if len(inner) == 1:
            print(f'note: {path} holds no .mcap file: comparing the bag in it, {inner[0]}',
                  file=sys.stderr)
            return inner[0]
    return path             # several bags below: read_bag says so, naming them


def _parser():
    ap = OneLineParser(prog='rigidrot_compare', description=__doc__.splitlines()[0],
                       epilog=CONVENTION)
    ap.add_argument('bag', help='bag directory or .mcap file')
    ap.add_argument('--topic', action='append', help='topic to score (repeatable)')
    ap.add_argument('--truth', help='compare with this second log instead of the exact truth')
    ap.add_argument('--json', help='write a JSON summary here')
    ap.add_argument('--csv', help='write time, error and NEES of every sample here')
    ap.add_argument('--plot',
                    help='draw the errors over time into this .png, .svg or .pdf (matplotlib)')
    ap.add_argument('--plot-topic', action='append',
                    help='plot this topic (repeatable; default: every scored topic that the '
                         'node did not publish, i.e. the estimators)')
    ap.add_argument('--plot-truth', action='store_true',
                    help="also plot the node's own topics scored against the exact truth")
    ap.add_argument('--yscale', choices=('log', 'linear'), default='log',
                    help='axis of the error panels (default log)')
    ap.add_argument('--cov-frame', choices=('body', 'inertial'), default='body',
                    help='frame of the orientation covariances (default body: '
                         'q_est = q_true * exp(e/2))')
    return ap


def main(argv=None):
    """Entry point of ``rigidrot_compare``; returns the exit status."""
    opts = _parser().parse_args(argv)
    try:
        if opts.plot and os.path.splitext(opts.plot)[1].lower() not in PLOT_SUFFIXES:
            raise ScoreError(f'--plot {opts.plot}: the file name must end in '
                             f'{", ".join(PLOT_SUFFIXES)} (the format is taken from it)')
        plt = _import_pyplot() if opts.plot else None
        bag = read_bag(_one_bag(opts.bag))
        if bag.note:
            print(f'note: {bag.path}: {bag.note}', file=sys.stderr)
        check_bag(bag)
        streams, skipped = extract_streams(bag, opts.topic)
        if opts.truth:
            tbag = read_bag(opts.truth)
            check_bag(tbag)
            results = score_against_stream(bag, streams, tbag, extract_streams(tbag)[0],
                                           cov_frame=opts.cov_frame)
            title = f'{opts.bag} against {opts.truth}'
        else:
            results = score_against_runs(bag, streams, cov_frame=opts.cov_frame)
            models = sorted({r.get('model', '?') for r in bag.runs})
            title = f'{opts.bag} against the exact solution ({", ".join(models)})'
        print(_table(results, skipped))
        if opts.json:
            with open(opts.json, 'w', encoding='utf-8') as fh:
                json.dump({'bag': opts.bag, 'truth': opts.truth or 'exact',
                           'truncated': bag.truncated, 'convention': CONVENTION,
                           'cov_frame': opts.cov_frame, 'runs': bag.runs,
                           'topics': [{k: v for k, v in r.items() if k not in _ARRAYS}
                                      for r in results],
                           'not_scored': skipped}, fh, indent=2)
        if opts.csv:
            _write_csv(results, opts.csv)
        if opts.plot:
            if opts.plot_topic:
                missing = set(opts.plot_topic) - {r['topic'] for r in results}
                if missing:
                    raise ScoreError(f'--plot-topic {sorted(missing)}: not among the scored '
                                     f'topics {sorted({r["topic"] for r in results})}')
                chosen = [r for r in results if r['topic'] in opts.plot_topic]
            else:
                truth = _truth_topics(bag.runs) | {'/attitude', '/angular_velocity'}
                chosen = [r for r in results if opts.plot_truth or r['topic'] not in truth]
            if not chosen:
                raise ScoreError('nothing to plot: every scored topic is the truth itself; '
                                 'add --plot-truth to draw it')
            _plot(plt, chosen, opts.plot, title, opts.yscale)
    except (BagError, ScoreError, OSError) as exc:
        print(f'rigidrot_compare: {exc}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
