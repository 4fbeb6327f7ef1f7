"""Work-precision: CPU time against attitude error, one query and a 100 Hz stream.

Workload (a): one query at T = 60 s; (b): a 100 Hz stream over 60 s, for each scene of
:data:`~rigidrot_ros.bench.common.SCENES`, every method across its knobs
(:func:`~rigidrot_ros.bench.common.sweep`). Error = rotation angle to the exact solution at
tol = 2e-14 (certified); an exact evaluation whose error exceeds its own tol is reported
as 'claim violated', not plotted as a win.
"""

import math
import os
import sys

import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import solve

NAME = 'wp'
NEEDS = ('scipy',)
#: The code this part measures (``rigidrot_bench --stale``): modules, with what they import.
MEASURES = ('rigidrot_ros.core',)
KEYS = ('work_precision',)
DEFAULT = True
SHARED_FOOTER = True


def work_precision(quick, repeats, budget, log):
    """Workload (a): one query at T = 60 s; (b): a 100 Hz stream over 60 s."""
    from rigidrot_ros.bench import peers
    rows = []
    scenes = common.SCENES if not quick else dict(list(common.SCENES.items())[1:2])
    horizon = 60.0 if not quick else 5.0
    n_stream = int(round(horizon * 100))
    for sname, scene in scenes.items():
        ref_sol = solve(scene, tol=common.REF_TOL)
        for workload, t_eval in (('query', np.array([horizon])),
                                 ('stream', np.arange(1, n_stream + 1) * 0.01)):
            ref = ref_sol.at(t_eval).quaternion
            for name, knob, value, fn in common.sweep(scene, quick, workload):
                try:
                    cpu, q = common.timed(lambda: fn(t_eval, budget), repeats)
                    err = float(quat.angle_between(q, ref).max())
                    status = 'ok' if np.isfinite(err) else 'nan'
                except peers.TimeBudget:
                    cpu, err, status = budget, math.nan, 'time-out'
                except (ArithmeticError, ValueError) as exc:
                    cpu, err, status = math.nan, math.nan, f'error: {exc}'[:80]
                if name.startswith('exact') and status == 'ok' and err > value:
                    status = 'claim violated'
                rows.append({'scene': sname, 'workload': workload, 'method': name,
                             'knob': knob, 'value': value, 'cpu_s': cpu, 'error_rad': err,
                             'samples': len(t_eval), 'horizon_s': horizon,
                             'status': status})
                log(f'{sname:28s} {workload:6s} {name:16s} {knob}={value:<8g} '
                    f'cpu {cpu:9.4f} s  err {err:9.2e}  {status}')
    return rows


def run(quick=False, log=print):
    """Run the work-precision sweep; return ``{'work_precision': rows}``."""
    return {'work_precision': work_precision(quick, 1 if quick else 3,
                                             1.0 if quick else 60.0, log)}


def write(res, out, foot, log):
    """Write ``work_precision.csv``."""
    common.write_csv(os.path.join(out, 'work_precision.csv'), res['work_precision'], foot)


def failed(results):
    """Lines naming every exact evaluation whose error exceeded its own tol."""
    return [f'CLAIM VIOLATED: {r}' for r in results.get('work_precision', [])
            if r['status'] == 'claim violated']


def draw(results, out):
    """Draw the work-precision charts, one per workload; return the written paths."""
    from rigidrot_ros.bench import charts
    paths = []
    for workload in ('query', 'stream'):
        rows = [r for r in results.get('work_precision', []) if r['workload'] == workload]
        if rows:
            paths += charts.work_precision(rows, workload, results['footer'], out)
    return paths


def summary(rows):
    """Summary lines per workload: the exact cost at any tol, DOP853 to 1e-9, who meets 1e-12.

    The speed-up per scene is DOP853's cheapest run within 1e-9 rad over the exact
    solution's costliest run (flint, any tol) on that scene.
    """
    fine = [r for r in rows if r['status'] in ('ok', 'claim violated')
            and math.isfinite(r['error_rad'])]
    lines = []
    for workload in dict.fromkeys(r['workload'] for r in rows):
        mine = [r for r in fine if r['workload'] == workload]
        scenes = list(dict.fromkeys(r['scene'] for r in mine))
        horizon = mine[0]['horizon_s'] if mine else math.nan
        what = (f'one query at T = {horizon:g} s' if workload == 'query' else
                f'{mine[0]["samples"] / horizon:g} Hz {workload} over {horizon:g} s')
        exact = {be: [r for r in mine if r['method'] == f'exact ({be})']
                 for be in ('flint', 'mpmath')}
        text = (f'{what}: the exact solution costs '
                f'{common.span([1e3 * r["cpu_s"] for r in exact["flint"]], unit="ms")} at any '
                f'requested tol (flint; mpmath '
                f'{common.span([1e3 * r["cpu_s"] for r in exact["mpmath"]], unit="ms")}), '
                f'error ≤ '
                f'{common.fmt(common.worst(exact["flint"] + exact["mpmath"], "error_rad"))} rad')
        dop, ratio = [], []
        for sc in scenes:
            met = [r['cpu_s'] for r in mine if r['scene'] == sc and r['method'] == 'DOP853'
                   and r['error_rad'] <= 1e-9]
            ex = [r['cpu_s'] for r in exact['flint'] if r['scene'] == sc]
            if met and ex:
                dop.append(1e3 * min(met))
                ratio.append(min(met) / max(ex))
        if dop:
            text += (f'; DOP853 at the rtol that reaches 1e-9 costs '
                     f'{common.span(dop, unit="ms")}, {common.span(ratio)}× the exact')
        lines.append(text)
        tight = []
        for method in dict.fromkeys(r['method'] for r in mine):
            got = [r for r in mine if r['method'] == method and r['error_rad'] <= 1e-12]
            n = len({r['scene'] for r in got})
            tight.append(f'{method} on {n} of {len(scenes)} scenes'
                         + (f' ({common.span([1e3 * r["cpu_s"] for r in got], unit="ms")})'
                            if n else ''))
        lines.append(f'{what}, within 1e-12 rad: ' + ', '.join(tight))
    return lines


def render_md(results):
    """Per scene and workload: the exact solution's cost and error, and each peer's best.

    For each method, the cheapest run that reached 1e-9 rad and the smallest error any of
    its runs reached; None where the results hold no work-precision rows.
    """
    rows = results.get('work_precision')
    if not rows:
        return None
    table = []
    for (sname, workload) in dict.fromkeys((r['scene'], r['workload']) for r in rows):
        sel = [r for r in rows if r['scene'] == sname and r['workload'] == workload and
               r['status'] in ('ok', 'claim violated') and math.isfinite(r['error_rad'])]
        for method in dict.fromkeys(r['method'] for r in rows):
            mine = [r for r in sel if r['method'] == method]
            if not mine:
                table.append([sname, workload, method, '—', '—', 'no run finished'])
                continue
            met = [r for r in mine if r['error_rad'] <= 1e-9]
            cheap = min(met, key=lambda r: r['cpu_s']) if met else None
            best = min(mine, key=lambda r: r['error_rad'])
            table.append([
                sname, workload, method,
                f'{common.fmt(1e3 * cheap["cpu_s"])} ms ({cheap["knob"]} '
                f'{common.fmt(cheap["value"])})' if cheap else 'not reached',
                common.fmt(best['error_rad']), f'{common.fmt(1e3 * best["cpu_s"])} ms'])
    first = rows[0]
    body = common.md_bullets(summary(rows)) + common.md_table(
        ['scene', 'workload', 'method', 'cheapest run within 1e-9 rad',
         'smallest error [rad]', 'its CPU time'], table)
    return common.md_fragment(
        f'Work-precision: one query at T = {first["horizon_s"]:g} s and a 100 Hz stream over '
        f'{first["horizon_s"]:g} s (CPU time, median of repeats; error against the exact '
        'solution at tol 2e-14 rad)', results['footer'], body)


def main(argv=None):
    """``python -m rigidrot_ros.bench.wp``: this part alone (options as rigidrot_bench)."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
