"""rigidrot_compare: score a log's attitude and rate topics against the exact truth.

Every geometry_msgs/QuaternionStamped and Vector3Stamped topic of the bag (or those given
with --topic) is compared at each message's stamp with the exact solution recomputed from
the log's own run records (all resets honoured), or with a second log (--truth).
Attitude error: rotation angle between the two quaternions, rad. Rate error: norm of the
difference, rad/s.
"""

import argparse
import json
import sys

from rigidrot_ros.io.bag import BagError, read_bag
from rigidrot_ros.io.score import (
    check_bag, extract_streams, score_against_runs, score_against_stream, ScoreError,
)


def _table(results):
    lines = [f'{"topic":32s} {"type":18s} {"n":>7s} {"max":>11s} {"rms":>11s} {"p95":>11s}']
    for r in results:
        kind = r['type'].split('/')[-1]
        if not r['count']:
            lines.append(f'{r["topic"]:32s} {kind:18s} {0:7d}  (no message inside a run)')
            continue
        lines.append(f'{r["topic"]:32s} {kind:18s} {r["count"]:7d} {r["max"]:11.3e} '
                     f'{r["rms"]:11.3e} {r["p95"]:11.3e}  {r["unit"]}')
    return '\n'.join(lines)


def _plot(results, path, title):
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        raise ScoreError('--plot needs matplotlib: pip install matplotlib') from None
    fig, axes = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True)
    for r in results:
        if not r['count']:
            continue
        ax = axes[0] if r['unit'] == 'rad' else axes[1]
        err = [max(e, 1e-18) for e in r['error']]
        ax.semilogy(r['t'], err, '.', ms=2, label=r['topic'])
    axes[0].text(0.01, 0.02, 'exact zeros drawn at 1e-18', transform=axes[0].transAxes,
                 fontsize=7, color='gray')
    axes[0].set_ylabel('attitude error angle [rad]')
    axes[1].set_ylabel('angular velocity error [rad/s]')
    axes[1].set_xlabel('scene time t since the run started [s]')
    for ax in axes:
        ax.grid(True, which='both', alpha=0.3)
        if ax.lines:
            ax.legend(loc='best', fontsize=8)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    """Entry point of ``rigidrot_compare``; returns the exit status."""
    ap = argparse.ArgumentParser(prog='rigidrot_compare', description=__doc__.splitlines()[0])
    ap.add_argument('bag', help='bag directory or .mcap file')
    ap.add_argument('--topic', action='append', help='topic to score (repeatable)')
    ap.add_argument('--truth', help='compare with this second log instead of the exact truth')
    ap.add_argument('--json', help='write a JSON summary here')
    ap.add_argument('--plot', help='draw the error over time into this PNG')
    opts = ap.parse_args(argv)
    try:
        bag = read_bag(opts.bag)
        check_bag(bag)
        if bag.truncated or bag.note:
            print(f'note: {bag.path}: unfinished file, {bag.note}', file=sys.stderr)
        streams = extract_streams(bag, opts.topic)
        if opts.truth:
            tbag = read_bag(opts.truth)
            check_bag(tbag)
            results = score_against_stream(bag, streams, tbag, extract_streams(tbag))
            title = f'{opts.bag} against {opts.truth}'
        else:
            results = score_against_runs(bag, streams)
            models = sorted({r.get('model', '?') for r in bag.runs})
            title = f'{opts.bag} against the exact solution ({", ".join(models)})'
        print(_table(results))
        if opts.json:
            with open(opts.json, 'w', encoding='utf-8') as fh:
                json.dump({'bag': opts.bag, 'truth': opts.truth or 'exact',
                           'truncated': bag.truncated, 'runs': bag.runs,
                           'topics': [{k: v for k, v in r.items() if k not in ('t', 'error')}
                                      for r in results]}, fh, indent=2)
        if opts.plot:
            _plot(results, opts.plot, title)
    except (BagError, ScoreError, OSError) as exc:
        print(f'rigidrot_compare: {exc}', file=sys.stderr)
        return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
