"""The leaderboard's charts: RMSE bars per cell, error and NEES curves over time.

:func:`draw` draws them from the results alone (``rigidrot_bench --charts-from``), as PNG
and SVG with fixed metadata, so that the same results give the same files.
"""

import math
import os

import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.bench.leaderboard_cells import NAME


_COLORS = {'madgwick': '#1f77b4', 'mahony': '#ff7f0e', 'ekf': '#2ca02c', 'aqua': '#d62728',
           'fusion': '#9467bd', 'vqf': '#8c564b', 'mekf': '#000000'}


def draw(results, out):
    """Draw the RMSE bars, the error curves and the NEES curves; the written paths."""
    lb = results.get(NAME)
    if not lb or not lb.get('cells'):
        return []
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    foot = common.part_footer(results, NAME)
    caption = (f'{foot.get("cpu", "?")} ({foot.get("cores", "?")} cores), '
               f'{foot.get("date", "?")}; rigidrot_ros {foot.get("rigidrot_ros", "?")}')
    cells = lb['cells']
    names = list(cells[0]['filters'])
    paths = _draw_rmse(plt, cells, names, caption, out)

    def error(ax, c):
        for n in names:
            ax.plot(c['t_curve_s'], c['filters'][n]['tuned']['rms_curve_deg'], lw=0.9,
                    color=_COLORS.get(n, 'gray'), label=c['filters'][n]['label'])
        ax.axvline(c['window_s'], color='k', ls=':', lw=0.8)
    paths += _draw_cells(plt, cells, error, 'RMS error over runs, deg',
                         'Total attitude error over time, RMS over the held-out runs (tuned; '
                         'dotted: start of scoring)', caption, out, 'leaderboard_error')
    cov = [n for n in names if cells[0]['filters'][n]['has_cov']]

    def nees(ax, c):
        band = None
        for n in cov:
            s = c['filters'][n]['tuned']
            if 'nees_curve' in s:
                ax.plot(c['t_curve_s'], s['nees_curve'], lw=0.9, color=_COLORS.get(n, 'gray'),
                        label=c['filters'][n]['label'])
                band = s['mc_nees_band']
        if band:
            ax.axhspan(band[0], band[1], color='tab:green', alpha=0.2)
        ax.axhline(3.0, color='k', lw=0.6, ls=':')
    if cov:
        paths += _draw_cells(plt, cells, nees, 'NEES averaged over runs',
                             'Monte Carlo NEES of the filters that state a covariance (tuned); '
                             'shaded: chi2(3M)/M 95 % band', caption, out, 'leaderboard_nees')
    return paths


def _draw_rmse(plt, cells, names, caption, out):
    """Draw the RMSE bars, inclination over heading, a group of bars a cell."""
    fig, axes = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    width = 0.8 / len(names)
    for ax, key, title in ((axes[0], 'incl', 'inclination'), (axes[1], 'head', 'heading')):
        for j, n in enumerate(names):
            vals = [c['filters'][n]['tuned']['rmse_deg'][key] for c in cells]
            ax.bar(np.arange(len(cells)) + (j - (len(names) - 1) / 2) * width, vals, width,
                   color=_COLORS.get(n, 'gray'), label=cells[0]['filters'][n]['label'])
        ax.set_yscale('log')
        ax.set_ylabel(f'{title} RMSE, deg')
        ax.grid(axis='y', alpha=0.3)
    axes[0].legend(fontsize=7, ncol=4)
    axes[1].set_xticks(np.arange(len(cells)))
    axes[1].set_xticklabels([f'{c["grade"]}\n{c["motion"]}' for c in cells], fontsize=8)
    axes[0].set_title(f'Tuned filters on held-out runs (M = {cells[0]["runs_test"]} per cell), '
                      'RMSE after the start-up window')
    fig.text(0.01, 0.005, caption, fontsize=6, color='gray')
    paths = _save(fig, out, 'leaderboard_rmse')
    plt.close(fig)
    return paths


def _draw_cells(plt, cells, plot, ylabel, title, caption, out, name):
    """Draw a grid of panels, one a cell (``plot(ax, cell)`` draws its curves), log y."""
    cols = 4
    rows = math.ceil(len(cells) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(13, 3.0 * rows), squeeze=False)
    for k, c in enumerate(cells):
        ax = axes[k // cols][k % cols]
        plot(ax, c)
        ax.set_yscale('log')
        ax.set_title(f'{c["grade"]}, {c["motion"]}', fontsize=9)
        ax.set_xlabel('scene time, s', fontsize=8)
        ax.set_ylabel(ylabel, fontsize=8)
        ax.tick_params(labelsize=7)
    for k in range(len(cells), rows * cols):
        axes[k // cols][k % cols].axis('off')
    axes[0][0].legend(fontsize=6)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.02, 1, 0.97))
    fig.text(0.01, 0.005, caption, fontsize=6, color='gray')
    paths = _save(fig, out, name)
    plt.close(fig)
    return paths


def _save(fig, out, name):
    import matplotlib
    matplotlib.rcParams['svg.hashsalt'] = 'rigidrot'
    paths = []
    for ext, meta in (('png', {'Software': None}), ('svg', {'Date': None, 'Creator': None})):
        path = os.path.join(out, f'{name}.{ext}')
        fig.savefig(path, dpi=110, metadata=meta)
        paths.append(path)
    return paths
