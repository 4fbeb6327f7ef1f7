"""Charts of the benchmark results (matplotlib, PNG and SVG).

Each method has one colour and one marker on every chart and panel (:data:`COLORS`,
:data:`MARKERS`), and every chart has one legend listing every method in its data. Log
axes cannot show an error of 0: errors below :data:`ERROR_FLOOR` are drawn at it, and the
chart says so and how many points it concerns.
"""

import math
import os
import textwrap

import numpy as np

STATUS_COLORS = {
    'meets 1e-12': '#1a9850', 'meets 1e-9': '#a6d96a', 'loses accuracy': '#fdae61',
    'no reference': '#bdbdbd', 'fail: time-out': '#d73027', 'fail: NaN': '#7f0000',
}
MARKERS = {'DOP853': 'o', 'RK45': 's', 'RK4': '^', 'RKMK4': 'v', 'Magnus4': 'D',
           'exact (flint)': '*', 'exact (mpmath)': 'P'}
#: One colour per method on every chart and panel (tab10), so a method keeps its colour.
COLORS = {'DOP853': '#1f77b4', 'RK45': '#ff7f0e', 'RK4': '#2ca02c', 'RKMK4': '#d62728',
          'Magnus4': '#9467bd', 'exact (flint)': '#8c564b', 'exact (mpmath)': '#e377c2'}
_SPARE = ('#7f7f7f', '#bcbd22', '#17becf', '#000000')
#: Errors below this are drawn at it on log axes; the chart says so.
ERROR_FLOOR = 1e-16


def _style(method):
    """Return ``(color, marker)`` of a method, the same on every chart and panel."""
    if method in COLORS:
        return COLORS[method], MARKERS.get(method, 'x')
    extra = sorted(m for m in COLORS if m not in MARKERS)
    COLORS[method] = _SPARE[len(extra) % len(_SPARE)]
    return COLORS[method], 'x'


def _method_handles(methods, labels=None):
    """Legend handles for ``methods`` in their fixed styles, whether drawn or not."""
    from matplotlib.lines import Line2D
    out = []
    for k, m in enumerate(methods):
        color, marker = _style(m)
        out.append(Line2D([], [], color=color, marker=marker, ms=5, lw=1,
                          label=labels[k] if labels else m))
    return out


def _caption(fig, foot):
    fig.text(0.01, 0.005, f'{foot["cpu"]} ({foot["cores"]} cores), {foot["date"]}; '
             f'rigidrot_ros {foot["rigidrot_ros"]}, numpy {foot["numpy"]}, scipy '
             f'{foot["scipy"]}, mpmath {foot["mpmath"]}, python-flint {foot["python-flint"]}',
             fontsize=6, color='gray')


def _save(fig, out, name):
    paths = []
    for ext in ('png', 'svg'):
        path = os.path.join(out, f'{name}.{ext}')
        fig.savefig(path, dpi=110)
        paths.append(path)
    return paths


def _finish(fig, foot, out, name):
    """Caption ``fig`` with the footer, save it as ``name`` (PNG, SVG), close it; the paths."""
    import matplotlib.pyplot as plt
    _caption(fig, foot)
    paths = _save(fig, out, name)
    plt.close(fig)
    return paths


def _pyplot():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return matplotlib, plt


def work_precision(rows, workload, foot, out):
    """Draw the work-precision chart of one workload's rows; return the written paths."""
    return _work_precision(rows, workload, foot, out, _pyplot()[1])


def horizon(hz, foot, out):
    """Draw the horizon-scaling chart; return the written paths."""
    return _horizon(hz, foot, out, _pyplot()[1])


def stability(st, foot, out, cross=()):
    """Draw the stability map (marks from the cross-check ``cross``); the written paths."""
    matplotlib, plt = _pyplot()
    return _stability(st, foot, out, plt, matplotlib, cross)


def _work_precision(rows, workload, foot, out, plt):
    horizon = rows[0]['horizon_s']
    title = (f'one query at T = {horizon:g} s' if workload == 'query' else
             f'100 Hz stream over {horizon:g} s ({rows[0]["samples"]} samples)')
    scenes = list(dict.fromkeys(r['scene'] for r in rows))
    methods = list(dict.fromkeys(r['method'] for r in rows))
    fig, axes = plt.subplots(1, len(scenes), figsize=(4.2 * len(scenes), 4.8), squeeze=False)
    floored, drawn = 0, set()
    for ax, sname in zip(axes[0], scenes):
        for method in methods:
            sel = [r for r in rows if r['scene'] == sname and r['method'] == method and
                   r['status'] in ('ok', 'claim violated') and math.isfinite(r['error_rad'])]
            floored += sum(r['error_rad'] < ERROR_FLOOR for r in sel)
            pts = sorted((max(r['error_rad'], ERROR_FLOOR), r['cpu_s']) for r in sel)
            if pts:
                color, marker = _style(method)
                ax.loglog(*zip(*pts), marker=marker, color=color, ms=5, lw=1, label=method)
                drawn.add(method)
        ax.set_title(sname, fontsize=9)
        ax.set_xlabel('max attitude error [rad]')
        ax.grid(True, which='both', alpha=0.25)
        ax.invert_xaxis()
    axes[0][0].set_ylabel('CPU time [s] (median)')
    shown = [m for m in methods if m in drawn]
    fig.legend(handles=_method_handles(shown), loc='lower center', ncol=len(shown),
               fontsize=7, bbox_to_anchor=(0.5, 0.035))
    fig.suptitle(f'Work-precision: {title} (reference: exact, tol 2e-14 rad)', fontsize=10)
    if floored:
        fig.text(0.5, 0.93, f'errors below {ERROR_FLOOR:g} rad (exact zeros included; '
                 f'{floored} points) are drawn at {ERROR_FLOOR:g} rad', ha='center',
                 fontsize=8, color='dimgray')
    fig.tight_layout(rect=(0, 0.1, 1, 0.93 if floored else 0.97))
    return _finish(fig, foot, out, f'work_precision_{workload}')


def _horizon(hz, foot, out, plt):
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.8), sharey=True)
    methods = list(dict.fromkeys(r['method'] for r in hz))
    reached = set()
    for ax, target in zip(axes, (1e-9, 1e-12)):
        for method in methods:
            pts = [(r['T_s'], r['cpu_s']) for r in hz if r['method'] == method and
                   r['target_rad'] == target and r['status'] == 'ok']
            if pts:
                color, marker = _style(method)
                ax.loglog(*zip(*sorted(pts)), marker=marker, color=color, ms=5, lw=1,
                          label=method)
                reached.add(method)
        ax.set_title(f'attitude error <= {target:g} rad at T', fontsize=9)
        ax.set_xlabel('horizon T [s] (one query at T)')
        ax.grid(True, which='both', alpha=0.25)
    axes[0].set_ylabel('CPU time at the cheapest setting that meets it [s]')
    labels = [m if m in reached else f'{m} (reaches neither target)' for m in methods]
    fig.legend(handles=_method_handles(methods, labels), loc='lower center',
               ncol=min(len(methods), 7), fontsize=7, bbox_to_anchor=(0.5, 0.035))
    fig.suptitle('Horizon scaling, axial-torque scene (one colour per method in both panels; '
                 'missing points: not reached)', fontsize=10)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    return _finish(fig, foot, out, 'horizon')


def independent_marks(st, cross=()):
    """Map ``(axis, value, T)`` to the strongest independent check of that cell.

    The exact cells are scored against the exact solution at a tighter tol, which shares
    its formulas with them. DOP853 on Euler's equations shares none: where it meets 1e-12
    against that reference the mark is ``'meets 1e-12'``. Else, where the cross-check
    (``cross``, rows of :func:`rigidrot_ros.bench.crosscheck.stability_crosscheck`) found
    the two backends on different representations agreeing within 1e-12, the mark is
    ``'other representation'``; else, where DOP853 meets 1e-9, ``'meets 1e-9'``.
    """
    marks = {}
    for c in st:
        if c['method'].startswith('DOP853') and c['status'] in ('meets 1e-12', 'meets 1e-9'):
            marks[(c['axis'], c['value'], c['T_s'])] = c['status']
    for r in cross:
        key = (r['axis'], r['value'], r['T_s'])
        if r.get('independent') and r['flint_vs_mpmath_rad'] <= 1e-12 and \
                marks.get(key) != 'meets 1e-12':
            marks[key] = 'other representation'
    return marks


def _stability(st, foot, out, plt, matplotlib, cross=()):
    methods = list(dict.fromkeys(c['method'] for c in st))
    axes_kinds = list(dict.fromkeys(c['axis'] for c in st))
    marks = independent_marks(st, cross)
    fig, axes = plt.subplots(len(axes_kinds), len(methods),
                             figsize=(3.3 * len(methods), 3.0 * len(axes_kinds) + 1.6),
                             squeeze=False)
    glyph = {'meets 1e-12': '\u25cf', 'meets 1e-9': '\u25cb', 'other representation': '\u25c6'}
    n_marked = n_exact = 0
    for i, kind in enumerate(axes_kinds):
        vals = sorted({c['value'] for c in st if c['axis'] == kind})
        ts = sorted({c['T_s'] for c in st if c['axis'] == kind})
        for j, method in enumerate(methods):
            ax = axes[i][j]
            grid = np.full((len(vals), len(ts), 3), 1.0)
            for c in st:
                if c['axis'] != kind or c['method'] != method:
                    continue
                y, x = vals.index(c['value']), ts.index(c['T_s'])
                grid[y, x] = matplotlib.colors.to_rgb(STATUS_COLORS.get(c['status'],
                                                                        '#542788'))
                if method.startswith('exact'):
                    n_exact += 1
                    m = marks.get((kind, c['value'], c['T_s']))
                    if m is not None:
                        n_marked += 1
                        ax.text(x, y, glyph[m], ha='center', va='center', fontsize=9,
                                color='white')
            ax.imshow(grid, origin='lower', aspect='auto')
            ax.set_xticks(range(len(ts)), [f'{t:g}' for t in ts], fontsize=7)
            ax.set_yticks(range(len(vals)), [f'{v:g}' for v in vals], fontsize=7)
            ax.set_xlabel('horizon T [s]', fontsize=8)
            ax.set_ylabel('U [rad/s^2]' if kind == 'U' else 'r0 [rad/s]', fontsize=8)
            ax.set_title(method, fontsize=8)
    handles = [matplotlib.patches.Patch(color=STATUS_COLORS[n], label=n)
               for n in STATUS_COLORS]
    handles.append(matplotlib.patches.Patch(color='#542788', label='fail: exception'))
    fig.legend(handles=handles, loc='lower center', ncol=len(handles), fontsize=7,
               bbox_to_anchor=(0.5, 0.03))
    note = ('Colour: error against the exact solution at tol 2e-14 rad (flint). In the exact '
            'panels that reference shares their formulas, so the colour is a consistency check '
            '(mpmath against flint: a second implementation of the special functions, not of '
            "the formulas). Independent checks: DOP853 (rtol 1e-13) on Euler's equations "
            'against the same reference, \u25cf within 1e-12, \u25cb within 1e-9; '
            + ('\u25c6 flint and mpmath on different representations (Taylor against '
               '\u2081F\u2081) agree within 1e-12; ' if cross else '')
            + f'unmarked exact cells ({n_exact - n_marked} of {n_exact}) have no independent '
            'check on this chart (DOP853 did not reach them within its CPU budget'
            + (', and both backends took the same representation)' if cross else ')') + '.')
    note = textwrap.fill(note, width=int(36 * len(methods) + 20))
    fig.text(0.5, 0.085, note, ha='center', va='bottom', fontsize=7)
    fig.suptitle('Where each method meets 1e-12 / 1e-9 rad, loses accuracy, or fails '
                 '(sphere, p0, q0 = 0.3, -0.2 rad/s; r0 = 0.5 or U = 0.01)', fontsize=9)
    fig.tight_layout(rect=(0, 0.16, 1, 1))
    return _finish(fig, foot, out, 'stability')


def ratios(rows, foot, out):
    """Bar chart of the speed-ups over DOP853 (both forms), per part and scene."""
    plt = _pyplot()[1]
    timed = [r for r in rows if math.isfinite(r['speedup_vs_dop853'])]
    if not timed:
        return []
    parts = list(dict.fromkeys(r['part'] for r in timed))
    fig, axes = plt.subplots(1, len(parts), figsize=(4.6 * len(parts), 4.4), squeeze=False)
    for ax, part in zip(axes[0], parts):
        sel = [r for r in timed if r['part'] == part]
        x = np.arange(len(sel))
        ax.bar(x - 0.2, [r['speedup_vs_dop853'] for r in sel], 0.4,
               label='vs DOP853 (peers.scipy_ivp)')
        ax.bar(x + 0.2, [r['speedup_vs_dop853_lean'] for r in sel], 0.4,
               label='vs DOP853, plain-float RHS')
        ax.axhline(10.0, color='gray', lw=0.8, ls='--')
        ax.set_yscale('log')
        ax.set_xticks(x)
        ax.set_xticklabels([r['scene'] for r in sel], rotation=35, ha='right', fontsize=7)
        ax.set_title(f'{part} ({sel[0]["samples"]} samples to {sel[0]["horizon_s"]:g} s)',
                     fontsize=8)
        ax.set_ylabel('DOP853 CPU time / exact CPU time (solve included)', fontsize=7)
    axes[0][0].legend(fontsize=7)
    fig.suptitle('exact solution (tol 1e-12) against scipy DOP853 (rtol = atol = 1e-12)',
                 fontsize=9)
    fig.tight_layout(rect=(0, 0.03, 1, 0.95))
    return _finish(fig, foot, out, 'ratios')
