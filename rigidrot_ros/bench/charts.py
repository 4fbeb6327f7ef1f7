"""Charts of the benchmark results (matplotlib, PNG and SVG)."""

import math
import os

import numpy as np

STATUS_COLORS = {
    'meets 1e-12': '#1a9850', 'meets 1e-9': '#a6d96a', 'loses accuracy': '#fdae61',
    'no reference': '#bdbdbd', 'fail: time-out': '#d73027', 'fail: NaN': '#7f0000',
}
MARKERS = {'DOP853': 'o', 'RK45': 's', 'RK4': '^', 'RKMK4': 'v', 'Magnus4': 'D',
           'exact (flint)': '*', 'exact (mpmath)': 'P'}


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


def draw(results, out):
    """Draw every chart the results allow; return the written paths."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    foot = results['footer']
    paths = []
    wp = results.get('work_precision', [])
    for workload in ('query', 'stream'):
        rows = [r for r in wp if r['workload'] == workload]
        if not rows:
            continue
        horizon = rows[0]['horizon_s']
        title = (f'one query at T = {horizon:g} s' if workload == 'query' else
                 f'100 Hz stream over {horizon:g} s ({rows[0]["samples"]} samples)')
        scenes = list(dict.fromkeys(r['scene'] for r in rows))
        fig, axes = plt.subplots(1, len(scenes), figsize=(4.2 * len(scenes), 4.3),
                                 squeeze=False)
        for ax, sname in zip(axes[0], scenes):
            for method in dict.fromkeys(r['method'] for r in rows):
                pts = [(max(r['error_rad'], 1e-16), r['cpu_s']) for r in rows
                       if r['scene'] == sname and r['method'] == method and
                       r['status'] in ('ok', 'claim violated') and
                       math.isfinite(r['error_rad'])]
                if pts:
                    pts.sort()
                    ax.loglog(*zip(*pts), marker=MARKERS.get(method, 'x'), ms=5, lw=1,
                              label=method)
            ax.set_title(sname, fontsize=9)
            ax.set_xlabel('max attitude error [rad]')
            ax.grid(True, which='both', alpha=0.25)
            ax.invert_xaxis()
        axes[0][0].set_ylabel('CPU time [s] (median)')
        axes[0][-1].legend(fontsize=7, loc='best')
        fig.suptitle(f'Work-precision: {title} (reference: exact, tol 2e-14 rad)',
                     fontsize=10)
        fig.tight_layout(rect=(0, 0.03, 1, 1))
        _caption(fig, foot)
        paths += _save(fig, out, f'work_precision_{workload}')
        plt.close(fig)
    hz = results.get('horizon', [])
    if hz:
        fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True)
        for ax, target in zip(axes, (1e-9, 1e-12)):
            for method in dict.fromkeys(r['method'] for r in hz):
                pts = [(r['T_s'], r['cpu_s']) for r in hz if r['method'] == method and
                       r['target_rad'] == target and r['status'] == 'ok']
                if pts:
                    ax.loglog(*zip(*sorted(pts)), marker=MARKERS.get(method, 'x'), ms=5,
                              lw=1, label=method)
            ax.set_title(f'attitude error <= {target:g} rad at T', fontsize=9)
            ax.set_xlabel('horizon T [s] (one query at T)')
            ax.grid(True, which='both', alpha=0.25)
        axes[0].set_ylabel('CPU time at the cheapest setting that meets it [s]')
        axes[1].legend(fontsize=7)
        fig.suptitle('Horizon scaling, axial-torque scene (missing points: not reached)',
                     fontsize=10)
        fig.tight_layout(rect=(0, 0.03, 1, 1))
        _caption(fig, foot)
        paths += _save(fig, out, 'horizon')
        plt.close(fig)
    st = results.get('stability', [])
    if st:
        methods = list(dict.fromkeys(c['method'] for c in st))
        axes_kinds = list(dict.fromkeys(c['axis'] for c in st))
        fig, axes = plt.subplots(len(axes_kinds), len(methods),
                                 figsize=(3.3 * len(methods), 3.0 * len(axes_kinds) + 0.8),
                                 squeeze=False)
        names = list(STATUS_COLORS)
        for i, kind in enumerate(axes_kinds):
            vals = sorted({c['value'] for c in st if c['axis'] == kind})
            ts = sorted({c['T_s'] for c in st if c['axis'] == kind})
            for j, method in enumerate(methods):
                ax = axes[i][j]
                grid = np.full((len(vals), len(ts), 3), 1.0)
                for c in st:
                    if c['axis'] == kind and c['method'] == method:
                        col = STATUS_COLORS.get(c['status'], '#542788')
                        rgb = matplotlib.colors.to_rgb(col)
                        grid[vals.index(c['value']), ts.index(c['T_s'])] = rgb
                ax.imshow(grid, origin='lower', aspect='auto')
                ax.set_xticks(range(len(ts)), [f'{t:g}' for t in ts], fontsize=7)
                ax.set_yticks(range(len(vals)), [f'{v:g}' for v in vals], fontsize=7)
                ax.set_xlabel('horizon T [s]', fontsize=8)
                ax.set_ylabel('U [rad/s^2]' if kind == 'U' else 'r0 [rad/s]', fontsize=8)
                ax.set_title(method, fontsize=8)
        handles = [matplotlib.patches.Patch(color=STATUS_COLORS[n], label=n) for n in names]
        handles.append(matplotlib.patches.Patch(color='#542788', label='fail: exception'))
        fig.legend(handles=handles, loc='lower center', ncol=4, fontsize=7)
        fig.suptitle('Where each method meets 1e-12 / 1e-9 rad, loses accuracy, or fails '
                     '(sphere, p0, q0 = 0.3, -0.2 rad/s; r0 = 0.5 or U = 0.01)', fontsize=9)
        fig.tight_layout(rect=(0, 0.09, 1, 1))
        _caption(fig, foot)
        paths += _save(fig, out, 'stability')
        plt.close(fig)
    return paths
