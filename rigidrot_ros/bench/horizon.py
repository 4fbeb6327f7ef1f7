"""Horizon scaling: CPU time of one query at T meeting 1e-9 and 1e-12 rad, T up to 1e5 s.

Each method at its cheapest knob that meets the target (axial-torque scene); a method that
misses a target at one horizon is not tried at longer ones.
"""

import math
import os
import sys

import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.core import solve

NAME = 'horizon'
NEEDS = ('scipy',)
#: The code this part measures (``rigidrot_bench --stale``): modules, with what they import.
MEASURES = ('rigidrot_ros.core',)
KEYS = ('horizon',)
DEFAULT = True
SHARED_FOOTER = True


def horizon_scaling(quick, budget, log):
    """CPU time to reach 1e-9 and 1e-12 rad at T, each method at its cheapest knob."""
    scene = common.SCENES['axial torque (Thm 2)']
    horizons = [1.0, 10.0] if quick else [1.0, 10.0, 100.0, 1e3, 1e4, 1e5]
    ref_sol = solve(scene, tol=common.REF_TOL)
    methods = common.sweep(scene, quick, 'query')

    def skip(name, knob, value, T, target):
        return (knob == 'tol' and value > target) or \
            (T >= 1e4 and knob == 'h' and value < 0.01)   # millions of Python steps

    return common.horizon_rows(
        horizons, methods, sorted({m for m, *_ in methods}),
        lambda T: (ref_sol.at(np.array([T])).quaternion[0], {}), budget, log, skip)


def run(quick=False, log=print):
    """Run the horizon sweep; return ``{'horizon': rows}``."""
    return {'horizon': horizon_scaling(quick, min(1.0 if quick else 60.0, 30.0), log)}


def write(res, out, foot, log):
    """Write ``horizon.csv``."""
    common.write_csv(os.path.join(out, 'horizon.csv'), res['horizon'], foot)


def draw(results, out):
    """Draw the horizon chart; return the written paths."""
    from rigidrot_ros.bench import charts
    if not results.get('horizon'):
        return []
    return charts.horizon(results['horizon'], results['footer'], out)


def table(rows):
    """Markdown table: per method and horizon, the CPU time (ms) to 1e-9 and to 1e-12 rad."""
    horizons = sorted({r['T_s'] for r in rows})
    cells = {(r['method'], r['T_s'], r['target_rad']): r for r in rows}
    out = []
    for method in dict.fromkeys(r['method'] for r in rows):
        line = [method]
        for T in horizons:
            got = []
            for target in (1e-9, 1e-12):
                r = cells.get((method, T, target))
                got.append(common.fmt(1e3 * r['cpu_s']) if r and r['status'] == 'ok'
                           and math.isfinite(r['cpu_s']) else '—')
            line.append(' / '.join(got))
        out.append(line)
    return common.md_table(['method'] + [f'T = {T:g} s' for T in horizons], out)


def summary(rows):
    """Summary lines: the exact solution's cost over every T, how far each peer reaches."""
    ok = [r for r in rows if r['status'] == 'ok' and math.isfinite(r['cpu_s'])]
    horizons = sorted({r['T_s'] for r in rows})
    lines = []
    for method in dict.fromkeys(r['method'] for r in rows):
        mine = [r for r in ok if r['method'] == method]
        if method.startswith('exact'):
            cells = {(r['T_s'], r['target_rad']) for r in mine}
            cost = common.span([1e3 * r['cpu_s'] for r in mine], unit='ms')
            lines.append(f'{method}: {cost} at every T from {horizons[0]:g} s to '
                         f'{horizons[-1]:g} s, at both targets' if len(cells) == 2 * len(
                             horizons) else f'{method}: {cost} where it reaches, '
                         f'{len(cells)} of {2 * len(horizons)} (T, target) cells')
            continue
        reach = []
        for target in (1e-9, 1e-12):
            ts = [r['T_s'] for r in mine if r['target_rad'] == target]
            reach.append(f'{common.sci(target)} up to T = {max(ts):g} s' if ts else
                         f'{common.sci(target)} at no T')
        lines.append(f'{method} reaches {" and ".join(reach)}')
    peers = [r['T_s'] for r in ok if not r['method'].startswith('exact')
             and r['target_rad'] == 1e-9]
    beyond = [T for T in horizons if not peers or T > max(peers)]
    if beyond:
        lines.append(f'past T = {max(peers) if peers else 0:g} s no peer reaches 1e-9 rad')
    return lines


def render_md(results):
    """Render the horizon summary and table from the results, or None where they hold none."""
    if not results.get('horizon'):
        return None
    return common.md_fragment(
        'Horizon scaling, axial-torque scene: CPU time [ms] of one query at T at the '
        'cheapest setting meeting 1e-9 / 1e-12 rad (— not reached)', results['footer'],
        common.md_bullets(summary(results['horizon'])) + table(results['horizon']))


def main(argv=None):
    """``python -m rigidrot_ros.bench.horizon``: this part alone."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
