"""Campaign charts (PNG and SVG), each with its band and its count of runs.

``python -m rigidrot_ros.campaign.charts DIR [DIR ...] -o PREFIX`` draws the Monte Carlo
NEES of several campaigns (e.g. a tuned and a mistuned filter) on one chart.

A campaign's three charts take about as long to draw as a hundred short runs: the
campaign imports matplotlib while its runs go (:func:`preload`) and draws them in two
processes (``write_charts(..., jobs=2)``), each chart drawn by the same code either way.
"""

import argparse
import json
import os
import sys
import threading

__all__ = ['write_charts', 'compare_chart', 'preload']

_META = {'png': {'Software': None}, 'svg': {'Date': None, 'Creator': None}}


def _plt():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _plain_log(ax):
    """Label a log y axis with plain numbers (``3``, ``0.5``, ``20``), not ``3×10⁰``.

    matplotlib's log formatter writes every tick as a power of ten, which over the one or
    two decades of a NEES chart gives ``2×10⁰``, ``3×10⁰``... The same ticks are labelled
    (matplotlib's choice of which minor ticks to label is kept), in ``%g``.
    """
    from matplotlib import ticker

    class Plain(ticker.LogFormatter):
        def __call__(self, x, pos=None):
            return f'{x:g}' if super().__call__(x, pos) else ''

    ax.yaxis.set_major_formatter(Plain())
    ax.yaxis.set_minor_formatter(Plain(labelOnlyBase=False))


def _save(fig, prefix):
    paths = []
    for ext in ('png', 'svg'):
        tmp = f'{prefix}.tmp.{ext}'
        kw = {'metadata': _META[ext]}
        if ext == 'svg':
            import matplotlib
            matplotlib.rcParams['svg.hashsalt'] = 'rigidrot'
        fig.savefig(tmp, dpi=110, bbox_inches='tight', **kw)
        os.replace(tmp, f'{prefix}.{ext}')
        paths.append(f'{prefix}.{ext}')
    return paths


def _label(rep):
    return rep.get('name') or os.path.basename(rep.get('_dir', '')) or 'campaign'


def preload():
    """Import matplotlib (Agg) and pyplot now; False if it is not installed."""
    try:
        _plt()
    except ImportError:
        return False
    return True


def _nees_chart(plt, report, out_dir):
    """Draw the Monte Carlo NEES with its band (``nees``)."""
    m, mc = report['runs_ok'], report['mc_nees']
    lo, hi = mc['band_95']
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.axhspan(lo, hi, color='tab:green', alpha=0.2,
               label=f'95 % band chi2(3M)/M = [{lo:.2f}, {hi:.2f}]')
    ax.axhline(3.0, color='k', lw=0.8, ls=':')
    ax.plot(mc['t_s'], mc['nees'], lw=1.0, color='tab:blue',
            label=f'NEES averaged over runs ({100 * mc["fraction_inside"]:.0f} % of steps '
                  f'inside)')
    ax.set_yscale('log')
    _plain_log(ax)
    ax.set_xlabel('scene time, s')
    ax.set_ylabel('Monte Carlo NEES')
    ax.set_title(f'{_label(report)}: M = {m} runs, ANEES {report["anees"]["value"]:.2f}')
    ax.legend(loc='upper right', fontsize=8)
    _save(fig, os.path.join(out_dir, 'nees'))
    plt.close(fig)


def _rms_chart(plt, report, out_dir):
    """Draw the RMS attitude error over the runs (``rms_error``)."""
    m = report['runs_ok']
    fig, ax = plt.subplots(figsize=(8, 4))
    rms = report['rms_error']
    ax.plot(rms['t_s'], [r * 206264.806 for r in rms['rad']], lw=1.0)
    ax.set_xlabel('scene time, s')
    ax.set_ylabel('RMS attitude error over runs, arcsec')
    ax.set_title(f'{_label(report)}: M = {m} runs')
    _save(fig, os.path.join(out_dir, 'rms_error'))
    plt.close(fig)


def _hist_chart(plt, report, out_dir):
    """Draw the histogram of the runs' ANEES (``anees_hist``)."""
    m = report['runs_ok']
    fig, ax = plt.subplots(figsize=(6, 4))
    pr = report['per_run_anees']
    ax.hist(pr['values'], bins=max(10, min(50, m // 3)), color='tab:blue', alpha=0.8)
    for b in pr['bounds_95']:
        ax.axvline(b, color='tab:green', ls='--')
    ax.set_xlabel(f'ANEES of one run (K = {report["steps"]} steps); dashed: chi2(3K)/K 95 %')
    ax.set_ylabel('runs')
    ax.set_title(f'{_label(report)}: M = {m} runs, {100 * pr["fraction_inside"]:.0f} % inside')
    _save(fig, os.path.join(out_dir, 'anees_hist'))
    plt.close(fig)


#: A campaign's charts in the order they are written: the drawing, its file name, and the
#: relative time it takes (the Monte Carlo NEES on a log axis with its legend is the longest).
_CHARTS = ((_nees_chart, 'nees', 3), (_rms_chart, 'rms_error', 2),
           (_hist_chart, 'anees_hist', 2))


def _forked(groups, draw):
    """Draw ``groups[1:]`` in forked children and ``groups[0]`` here; redraw what failed.

    A child that fails (or cannot be forked) has its charts drawn again here, so that
    its error, if any, is raised in this process.
    """
    children = []
    sys.stdout.flush()
    sys.stderr.flush()
    for group in groups[1:]:
        try:
            pid = os.fork()
        except OSError:
            children.append((None, group))
            continue
        if pid == 0:                                    # the child: draw, exit at once
            code = 1
            try:
                for chart in group:
                    draw(chart)
                code = 0
            finally:
                os._exit(code)
        children.append((pid, group))
    failed = []
    try:
        for chart in groups[0]:
            draw(chart)
    finally:
        for pid, group in children:
            if pid is None or os.waitpid(pid, 0)[1] != 0:
                failed += group
    for chart in failed:
        draw(chart)


def write_charts(report, out_dir, jobs=1):
    """Write nees, rms_error and anees_hist charts of one campaign; their paths.

    ``jobs`` > 1 draws them in that many processes (forked, on a platform that forks and
    in a process with no other thread; else here, one after the other): the same files.
    """
    if 'mc_nees' not in report:
        return []
    plt = _plt()

    def draw(chart):
        chart(plt, report, out_dir)

    jobs = max(1, min(int(jobs), len(_CHARTS)))
    if jobs > 1 and hasattr(os, 'fork') and threading.active_count() == 1:
        groups, load = [[] for _ in range(jobs)], [0] * jobs
        for chart, _, cost in sorted(_CHARTS, key=lambda c: -c[2]):
            i = load.index(min(load))
            groups[i].append(chart)
            load[i] += cost
        _forked(groups, draw)
    else:
        for chart, _, _ in _CHARTS:
            draw(chart)
    return [os.path.join(out_dir, f'{name}.{ext}') for _, name, _ in _CHARTS
            for ext in ('png', 'svg')]


def compare_chart(reports, prefix):
    """One Monte Carlo NEES chart of several campaigns, with their bands; the paths."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4.2))
    colors = ['tab:blue', 'tab:red', 'tab:purple', 'tab:orange']
    for i, rep in enumerate(reports):
        mc = rep['mc_nees']
        lo, hi = mc['band_95']
        c = colors[i % len(colors)]
        ax.axhspan(lo, hi, color=c, alpha=0.12)
        ax.plot(mc['t_s'], mc['nees'], lw=1.0, color=c,
                label=f'{_label(rep)}: M = {rep["runs_ok"]}, ANEES '
                      f'{rep["anees"]["value"]:.2f}, {100 * mc["fraction_inside"]:.0f} % of '
                      f'steps in [{lo:.2f}, {hi:.2f}]')
    ax.axhline(3.0, color='k', lw=0.8, ls=':')
    ax.set_yscale('log')
    _plain_log(ax)
    ax.set_xlabel('scene time, s')
    ax.set_ylabel('NEES averaged over the runs')
    ax.set_title('Monte Carlo NEES with its 95 % band chi2(3M)/M (shaded)')
    ax.legend(loc='center right', fontsize=8)
    paths = _save(fig, prefix)
    plt.close(fig)
    return paths


def main(argv=None):
    """Draw campaigns' Monte Carlo NEES on one chart."""
    ap = argparse.ArgumentParser(prog='python -m rigidrot_ros.campaign.charts',
                                 description=__doc__.splitlines()[0])
    ap.add_argument('dirs', nargs='+', help='campaign output directories')
    ap.add_argument('-o', '--output', required=True, help='chart path without extension')
    opts = ap.parse_args(argv)
    reps = []
    for d in opts.dirs:
        with open(os.path.join(d, 'report.json'), encoding='utf-8') as fh:
            rep = json.load(fh)
        rep['_dir'] = d
        reps.append(rep)
    for p in compare_chart(reps, opts.output):
        print(p)
    return 0


if __name__ == '__main__':
    sys.exit(main())
