"""Speed ratios against scipy DOP853 at rtol 1e-12 (``rigidrot_bench --only ratios``).

(a) a 100 Hz stream over 60 s per preset scene; (b) 1e6 samples over 1e4 s (spacecraft);
(c) one query at T = 1e3 s, ``solve`` included; (d) random-access scalar ``at(t)``; (e) the
node's tight loop; (f) the peak memory of the 1e6-sample batch. Every exact answer is
checked against single evaluations at the reference tol, and its bound against its error.
"""

import math
import os
import sys

import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import solve

NAME = 'ratios'
NEEDS = ('scipy',)
#: The code this part measures (``rigidrot_bench --stale``): modules, with what they import.
MEASURES = ('rigidrot_ros.core',)
KEYS = ('ratios',)

RATIO_FIELDS = (
    'part', 'scene', 'samples', 'horizon_s', 'exact_cpu_s', 'dop853_cpu_s',
    'dop853_lean_cpu_s', 'speedup_vs_dop853', 'speedup_vs_dop853_lean', 'exact_error_rad',
    'exact_max_bound_rad', 'bounds_hold', 'dop853_error_rad', 'mean_us', 'p50_us', 'p99_us',
    'memory_ratio')


def _row(**kw):
    row = {k: math.nan for k in RATIO_FIELDS}
    row.update(kw)
    return row


def _check(scene, t, samples, every):
    """Exact errors against single evaluations at REF_TOL, and whether every bound held."""
    pick = np.unique(np.concatenate([np.arange(0, len(t), every), [len(t) - 1]]))
    sol = common.reference_solution(scene)
    ref_q = np.empty((len(pick), 4))
    ref_b = np.empty(len(pick))
    for i, j in enumerate(pick):
        r = sol.at(float(t[j]))
        ref_q[i], ref_b[i] = r.quaternion, r.error_bound
    err = quat.angle_between(samples.quaternion[pick], ref_q)
    held = bool(np.all(err <= samples.error_bound[pick] + ref_b))
    return float(err.max()), float(samples.error_bound.max()), held, pick, ref_q


def _versus_dop853(part, name, scene, t, repeats, budget, log, every):
    """Time solve + at(t) and both DOP853 forms at rtol 1e-12 on t; check every answer."""
    from rigidrot_ros.bench import peers
    cpu, s = common.timed(lambda: solve(scene, tol=1e-12).at(t), repeats)
    err, mb, held, pick, ref_q = _check(scene, t, s, every)
    dop = {}
    for key, fn in (('dop853', peers.scipy_ivp), ('lean', peers.scipy_ivp_lean)):
        reps = repeats if t[-1] <= 100.0 else 1          # long DOP853 runs: once
        try:
            c, q = common.timed(lambda: fn(scene, t, 'DOP853', 1e-12, budget=budget), reps)
            dop[key] = (c, float(quat.angle_between(q[pick], ref_q).max()))
        except peers.TimeBudget:
            dop[key] = (math.nan, math.nan)
    row = _row(part=part, scene=name, samples=len(t), horizon_s=float(t[-1]), exact_cpu_s=cpu,
               dop853_cpu_s=dop['dop853'][0], dop853_lean_cpu_s=dop['lean'][0],
               speedup_vs_dop853=dop['dop853'][0] / cpu,
               speedup_vs_dop853_lean=dop['lean'][0] / cpu, exact_error_rad=err,
               exact_max_bound_rad=mb, bounds_hold=held, dop853_error_rad=dop['dop853'][1])
    log(f'{part:22s} {name:18s} exact {1e3 * cpu:9.2f} ms  DOP853 '
        f'{1e3 * dop["dop853"][0]:10.1f} ms ({row["speedup_vs_dop853"]:7.1f}x)  lean DOP853 '
        f'{1e3 * dop["lean"][0]:10.1f} ms ({row["speedup_vs_dop853_lean"]:7.1f}x)  err '
        f'{err:.1e} (bound {mb:.1e}, held {held})  DOP853 err {dop["dop853"][1]:.1e}')
    return row


def ratios(quick, log, budget=600.0):
    """Measure the issue's ratios against scipy DOP853 at rtol 1e-12, all in one run.

    (a) a 100 Hz stream over 60 s per scene; (b) 1e6 samples over 1e4 s (spacecraft);
    (c) one query at T = 1e3 s, ``solve`` included; (d) random-access scalar ``at(t)``,
    t uniform in [0, 60] s, after ``solve``; (e) the node's tight loop: successive 100 Hz
    scalar calls; (f) the peak memory of the 1e6-sample batch (tracemalloc) as a multiple
    of its output arrays. DOP853 runs in two forms: the peers' array right-hand side, and
    a lean one in plain floats (the same equations, about 4x cheaper per step).
    """
    scenes = common.ratio_scenes()
    if quick:
        scenes = {k: scenes[k] for k in ('default', 'spacecraft', 'torque_free_triaxial')}
    repeats = 1 if quick else 3
    rows = []
    horizon = 5.0 if quick else 60.0
    t_stream = np.arange(1, int(round(horizon * 100)) + 1) * 0.01
    for name, scene in scenes.items():
        rows.append(_versus_dop853('stream 100 Hz', name, scene, t_stream, repeats, budget,
                                   log, every=10))
    n_big, t_big = (10 ** 4, 100.0) if quick else (10 ** 6, 1e4)
    t = np.arange(1, n_big + 1) * (t_big / n_big)
    rows.append(_versus_dop853(f'{n_big:.0e} samples', 'spacecraft', common.SPACECRAFT, t, 1,
                               budget,
                               log, every=max(1, n_big // 200)))
    peak, size = common.batch_memory(solve(common.SPACECRAFT, tol=1e-12), t)
    rows.append(_row(part='batch memory', scene='spacecraft', samples=n_big,
                     horizon_s=t_big, memory_ratio=peak / size))
    log(f'batch memory           spacecraft         peak {peak / 1e6:.1f} MB for '
        f'{size / 1e6:.1f} MB of output: {peak / size:.2f}x')
    t_query = np.array([100.0 if quick else 1e3])
    for name, scene in scenes.items():
        rows.append(_versus_dop853('one query', name, scene, t_query, repeats, budget, log,
                                   every=1))
    rng = np.random.default_rng(10)
    for name, scene in scenes.items():
        sol = solve(scene, tol=1e-12)
        lat = common.latencies(lambda x: sol.at(x),
                               rng.uniform(0.0, horizon, 200 if quick else 3000))
        rows.append(_row(part='scalar at(t) random', scene=name, samples=len(lat),
                         horizon_s=horizon, **common.percentiles(lat)))
        sol = solve(scene, tol=1e-12)
        tick = common.latencies(lambda x: sol.at(x), [float(x) for x in t_stream])
        rows.append(_row(part='tick 100 Hz tight loop', scene=name, samples=len(tick),
                         horizon_s=horizon, **common.percentiles(tick)))
        log(f'scalar at(t)           {name:18s} random p50 {rows[-2]["p50_us"]:6.1f} us p99 '
            f'{rows[-2]["p99_us"]:7.1f} us | 100 Hz tick mean {rows[-1]["mean_us"]:6.1f} us '
            f'p50 {rows[-1]["p50_us"]:6.1f} us p99 {rows[-1]["p99_us"]:7.1f} us')
    return rows


def run(quick=False, log=print):
    """Measure the ratios; return ``{'ratios': rows}``."""
    return {'ratios': ratios(quick, log)}


def write(res, out, foot, log):
    """Write ``ratios.csv`` and the speed-up chart."""
    common.write_csv(os.path.join(out, 'ratios.csv'), res['ratios'], foot)
    from rigidrot_ros.bench import charts
    for path in charts.ratios(res['ratios'], foot, out):
        log(f'wrote {path}')


def draw(results, out):
    """Draw the speed-up chart from merged results; return the written paths."""
    from rigidrot_ros.bench import charts
    if not results.get('ratios'):
        return []
    return charts.ratios(results['ratios'], common.part_footer(results, NAME), out)


def _ms(x):
    return f'{common.fmt(1e3 * x)} ms' if math.isfinite(x) else '—'


def _times(x):
    return f'{common.fmt(x)}×'


#: The ratios table's columns: (title, cell of one timed row).
_TIMED = (
    ('part', lambda r: r['part']), ('scene', lambda r: r['scene']),
    ('samples', lambda r: str(r['samples'])), ('to T [s]', lambda r: common.fmt(r['horizon_s'])),
    ('exact', lambda r: _ms(r['exact_cpu_s'])), ('DOP853', lambda r: _ms(r['dop853_cpu_s'])),
    ('lean DOP853', lambda r: _ms(r['dop853_lean_cpu_s'])),
    ('speed-up', lambda r: _times(r['speedup_vs_dop853'])),
    ('vs lean', lambda r: _times(r['speedup_vs_dop853_lean'])),
    ('exact error [rad]', lambda r: common.fmt(r['exact_error_rad'])),
    ('exact bound [rad]', lambda r: common.fmt(r['exact_max_bound_rad'])),
    ('bounds held', lambda r: 'yes' if r['bounds_hold'] else 'NO'),
    ('DOP853 error [rad]', lambda r: common.fmt(r['dop853_error_rad'])),
)
#: The scalar calls' columns.
_LATENCY = (
    ('scalar calls', lambda r: r['part']), ('scene', lambda r: r['scene']),
    ('calls', lambda r: str(r['samples'])), ('mean [µs]', lambda r: common.fmt(r['mean_us'])),
    ('p50 [µs]', lambda r: common.fmt(r['p50_us'])),
    ('p99 [µs]', lambda r: common.fmt(r['p99_us'])),
)


def summary(rows):
    """Summary lines: per timed part the ranges over scenes, the checks, the scalar calls."""
    lines = []
    timed = [r for r in rows if math.isfinite(r['exact_cpu_s'])]
    for part in dict.fromkeys(r['part'] for r in timed):
        mine = [r for r in timed if r['part'] == part]
        lines.append(
            f'{part} ({len(mine)} scene{"s" if len(mine) > 1 else ""}, {mine[0]["samples"]} '
            f'sample{"s" if mine[0]["samples"] > 1 else ""} to T = '
            f'{common.fmt(mine[0]["horizon_s"])} s): exact '
            f'{common.span([1e3 * r["exact_cpu_s"] for r in mine], unit="ms")}, DOP853 '
            f'{common.span([1e3 * r["dop853_cpu_s"] for r in mine], unit="ms")}: '
            f'{common.span([r["speedup_vs_dop853"] for r in mine])}× faster, '
            f'{common.span([r["speedup_vs_dop853_lean"] for r in mine])}× against the lean '
            'DOP853')
    if timed:
        held = sum(bool(r['bounds_hold']) for r in timed)
        lines.append(f'every exact answer checked against single evaluations at the reference '
                     f'tol: largest error {common.fmt(common.worst(timed, "exact_error_rad"))} '
                     'rad, largest bound '
                     f'{common.fmt(common.worst(timed, "exact_max_bound_rad"))} rad, '
                     f'bounds held in {held} of {len(timed)} runs; DOP853 errors '
                     f'{common.span([r["dop853_error_rad"] for r in timed])} rad')
    for part in dict.fromkeys(r['part'] for r in rows if math.isfinite(r['p50_us'])):
        mine = [r for r in rows if r['part'] == part]
        lines.append(f'{part} ({mine[0]["samples"]} calls to T = '
                     f'{common.fmt(mine[0]["horizon_s"])} s): p50 '
                     f'{common.span([r["p50_us"] for r in mine], unit="µs")}, p99 '
                     f'{common.span([r["p99_us"] for r in mine], unit="µs")} over the scenes')
    return lines


def render_md(results):
    """Per timed part and scene: exact, DOP853 (both forms), speed-ups, errors, bounds."""
    rows = results.get('ratios')
    if not rows:
        return None
    body = common.md_bullets(summary(rows)) + common.md_columns(
        _TIMED, [r for r in rows if math.isfinite(r['exact_cpu_s'])])
    lat = [r for r in rows if math.isfinite(r['p50_us'])]
    if lat:
        body += '\n' + common.md_columns(_LATENCY, lat)
    for r in rows:
        if math.isfinite(r['memory_ratio']):
            body += (f'\nPeak memory of the {r["samples"]}-sample batch (tracemalloc): '
                     f'{common.fmt(r["memory_ratio"])}× its output arrays.\n')
    return common.part_md(
        results, NAME, 'Speed ratios: the exact solution (tol 1e-12, solve included) against '
        'scipy DOP853 (rtol = atol = 1e-12), CPU time', body)


def main(argv=None):
    """``python -m rigidrot_ros.bench.ratios``: this part alone."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
