"""Stability map: where each method meets 1e-12 / 1e-9 rad, loses accuracy, or fails.

A unit sphere, omega0 = (0.3, -0.2, r0), torque (0, 0, U): over torque U x horizon T
(r0 = 0.5) and over spin rate r0 x T (U = 0.01), each cell scored against the exact
solution at tol = 2e-14 (flint).
"""

import math
import os
import sys

import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.bench.crosscheck import stability_scene
from rigidrot_ros.core import PrecisionError, solve
from rigidrot_ros.core import quaternion as quat

NAME = 'stability'
NEEDS = ('scipy',)
#: The code this part measures (``rigidrot_bench --stale``): modules, with what they import.
MEASURES = ('rigidrot_ros.core',)
KEYS = ('stability',)
DEFAULT = True
SHARED_FOOTER = True


def methods():
    """Return the map's methods by name: ``fn(scene, t, budget) -> q``."""
    from rigidrot_ros.bench import peers
    return {
        'exact (flint), tol 1e-12': lambda sc, t, b: solve(sc, tol=1e-12).at(t).quaternion,
        'exact (mpmath), tol 1e-12': lambda sc, t, b: solve(
            sc, tol=1e-12, backend='mpmath').at(t).quaternion,
        'DOP853, rtol 1e-13': lambda sc, t, b: peers.scipy_ivp(sc, t, 'DOP853', 1e-13,
                                                               budget=b),
        'RKMK4, h = 0.01 s': lambda sc, t, b: peers.rkmk4(sc, t, 0.01, budget=b),
    }


def stability_map(quick, budget, log):
    """Status of each method over torque U x horizon T, and over spin rate r0 x T."""
    us = [1e-6, 1.0] if quick else [1e-10, 1e-8, 1e-6, 1e-4, 1e-2, 1.0, 1e2]
    ts = [1.0, 100.0] if quick else [1.0, 10.0, 100.0, 1e3, 1e4, 1e5]
    r0s = [10.0] if quick else [0.1, 1.0, 10.0, 100.0]
    fns = methods()
    cells = []
    for axis, val in [('U', u) for u in us] + [('r0', r) for r in r0s]:
        scene = stability_scene(axis, val)
        timed_out = set()
        for T in ts:
            t_eval = np.array([T])
            try:
                ref = solve(scene, tol=common.REF_TOL).at(t_eval).quaternion
            except (PrecisionError, ValueError) as exc:
                ref = None
                log(f'no reference at {axis}={val:g} T={T:g}: {exc}'[:120])
            for name, fn in fns.items():
                if name in timed_out:           # a longer horizon only takes longer
                    cells.append({'axis': axis, 'value': val, 'T_s': T, 'method': name,
                                  'status': 'fail: time-out', 'error_rad': math.nan,
                                  'cpu_s': math.nan})
                    continue
                cpu, err, status = common.run_method(
                    fn, scene, t_eval, budget,
                    None if ref is None else lambda q: float(quat.angle_between(q, ref).max()))
                if status == 'fail: time-out':
                    timed_out.add(name)
                cells.append({'axis': axis, 'value': val, 'T_s': T, 'method': name,
                              'status': status, 'error_rad': err, 'cpu_s': cpu})
                log(f'{axis}={val:<8g} T={T:<8g} {name:26s} {status:16s} err {err:9.2e} '
                    f'cpu {cpu:8.3f} s')
    return cells


def run(quick=False, log=print):
    """Run the stability map; return ``{'stability': cells}``."""
    return {'stability': stability_map(quick, 20.0 if not quick else 1.0, log)}


def write(res, out, foot, log):
    """Write ``stability.csv``."""
    common.write_csv(os.path.join(out, 'stability.csv'), res['stability'], foot)


def draw(results, out):
    """Draw the stability map (the cross-check's marks where present); the written paths."""
    from rigidrot_ros.bench import charts
    if not results.get('stability'):
        return []
    return charts.stability(results['stability'], results['footer'], out,
                            results.get('stability_crosscheck', []))


def status_counts(cells, coord):
    """Markdown table: per method, how many cells have each status (``coord`` for the doc)."""
    statuses = list(dict.fromkeys(c['status'] for c in cells))
    out = []
    for method in dict.fromkeys(c['method'] for c in cells):
        mine = [c['status'] for c in cells if c['method'] == method]
        out.append([method] + [str(mine.count(s)) for s in statuses] + [str(len(mine))])
    return common.md_table(['method'] + statuses + [f'cells ({coord})'], out)


def render_md(results):
    """Cells per status and method, from the results; None where they hold no map."""
    cells = results.get('stability')
    if not cells:
        return None
    return common.md_fragment(
        'Stability map: cells per status (sphere, U x T and r0 x T)', results['footer'],
        status_counts(cells, 'U and r0 rows x horizons'))


def main(argv=None):
    """``python -m rigidrot_ros.bench.stability``: this part alone."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
