"""Leaderboard: attitude filters people use, tuned, scored on exact truth per IMU grade x motion.

Each cell of the grid is an IMU grade (noise densities and bias instabilities of a named
datasheet, :data:`GRADES`) on a motion of a body turning on a supported point with
gravity (:data:`MOTIONS`, expressed in the node's parameters over
``config/air_bearing.yaml``). Per cell, runs are drawn as a Monte Carlo campaign draws them
(:func:`rigidrot_ros.campaign.spec.draw_run`: attitude uniform on SO(3), dispersed rates
and inertia, sensor seeds per run) and generated in memory
(:func:`rigidrot_ros.run.generate.run_arrays`). Every filter of
:mod:`rigidrot_ros.estimators.thirdparty` is tuned on training runs (its grid, lowest
total RMSE) and scored on held-out runs of other seeds with its tuned parameters and with
its defaults: inclination and heading RMSE (BROAD's split, :mod:`rigidrot_ros.campaign.
metrics`), total RMSE, p95, time to converge, NEES where it states a covariance, and CPU
µs per sample of its own update calls.

``rigidrot_bench --only leaderboard --out doc/bench/leaderboard`` runs it (minutes on
2 cores); ``rigidrot_bench --charts-from doc/bench/leaderboard/results.json --out
doc/bench/leaderboard`` redraws its charts and ``leaderboard.md`` from the results file alone.

The grid and one cell's run are :mod:`.leaderboard_cells`, the Markdown table
:mod:`.leaderboard_report`, the charts :mod:`.leaderboard_charts`; this module is the part
(``NAME``, ``run``, ``render_md``, ``draw``) that runs the cells on a process pool.
"""

import concurrent.futures as cf
import multiprocessing
import os
import sys
import time

from rigidrot_ros.bench.leaderboard_cells import (BIAS_TAU_S, GRADES, MOTIONS, NAME, run_cell,
                                                  SENSOR_OVERRIDES, SIZES)
from rigidrot_ros.bench.leaderboard_charts import draw
from rigidrot_ros.bench.leaderboard_report import leader, render_md

__all__ = ['NAME', 'NEEDS', 'KEYS', 'run', 'add_arguments', 'render_md', 'draw', 'main']

NEEDS = ('ahrs', 'imufusion', 'vqf', 'scipy')
KEYS = ('leaderboard',)


def _cell_job(args):
    grade, motion, size, seed = args
    return run_cell(grade, motion, size, seed=seed)


def _processes(text):
    import argparse
    try:
        n = int(text)
    except ValueError:
        n = 0
    if not 1 <= n <= 256:
        raise argparse.ArgumentTypeError(f'must be an integer in [1, 256], got {text!r}')
    return n


def add_arguments(ap):
    """Add ``--leaderboard-processes``."""
    ap.add_argument('--leaderboard-processes', type=_processes, default=None, metavar='N',
                    help='leaderboard: cells run on N processes (default: one per core)')


def run(quick=False, log=print, leaderboard_processes=None):
    """Run every cell on a process pool; return ``{'leaderboard': ...}``."""
    sz = SIZES['quick' if quick else 'full']
    size = 'quick' if quick else 'full'
    procs = leaderboard_processes or os.cpu_count() or 1
    jobs = [(g, m, size, sz['seed']) for g, m in sz['cells']]
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    cells = {}
    ctx = multiprocessing.get_context('spawn')
    with cf.ProcessPoolExecutor(max_workers=min(procs, len(jobs)), mp_context=ctx) as ex:
        futs = {ex.submit(_cell_job, j): j for j in jobs}
        for f in cf.as_completed(futs):
            res = f.result()
            cells[(res['grade'], res['motion'])] = res
            best = leader(res)
            log(f'leaderboard: {res["grade"]:10s} {res["motion"]:8s} done in '
                f'{res["wall_s"]:6.1f} s; leader {best[0] if best else "-"}')
    wall = time.perf_counter() - t0
    cpu = sum(c['cpu_s'] for c in cells.values())
    load = [load0, os.getloadavg()[0]]
    log(f'leaderboard: {len(jobs)} cells in {wall:.1f} s on {min(procs, len(jobs))} '
        f'processes ({cpu:.1f} CPU s; load average {load[0]:.1f} at the start, '
        f'{load[1]:.1f} at the end)')
    return {'leaderboard': {'size': size, 'wall_s': wall, 'cpu_s': cpu, 'load_average': load,
                            'processes': min(procs, len(jobs)),
                            'cells': [cells[c] for c in [(g, m) for g, m in sz['cells']]],
                            'grades': GRADES, 'motions': {k: {kk: vv for kk, vv in v.items()}
                                                          for k, v in MOTIONS.items()},
                            'sensor_overrides': SENSOR_OVERRIDES,
                            'bias_tau_s': BIAS_TAU_S}}


def main(argv=None):
    """Run the leaderboard alone (``python -m rigidrot_ros.bench.leaderboard``)."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
