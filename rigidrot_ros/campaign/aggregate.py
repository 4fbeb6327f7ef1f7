"""Monte Carlo consistency statistics over a campaign's runs (Bar-Shalom et al. 2001, §5.4.2).

With M runs of a consistent filter and n = 3 (attitude error):

- per time step k, ``NEES_bar_k = (1/M) sum_i NEES_ik`` has ``M NEES_bar_k ~ chi2(3M)``:
  two-sided 95 % band ``[chi2_3M(0.025), chi2_3M(0.975)] / M``; the fraction of steps
  inside it should be near 0.95;
- the ANEES over runs and time (M runs, K steps) is compared with
  ``chi2(3MK)/(MK)`` (too narrow when a run's steps are correlated in time: read it with the
  per-step band);
- each run's own ANEES over its K steps against ``chi2(3K)/K`` (the histogram).

Steps are matched across runs by their scene time (ns); only the steps every successful run
scored are used (``steps_dropped`` counts the others). Everything is computed from the runs
in index order, so the same runs give the same bytes whichever engine produced them.

``sensors`` is the sensor configuration the runs' descriptions record (the error model the
estimator was fed, :func:`rigidrot_ros.run.outputs.sensor_config`), a value that differs
between runs (a seed, a dispersed bias, a drawn turn-on bias) given as :data:`VARIES`.
"""

import math

import numpy as np

from rigidrot_ros.scoring.score import anees_bounds

__all__ = ['aggregate', 'CSV_FIELDS', 'csv_rows', 'VARIES']

#: A value of the report's ``sensors`` that differs between runs.
VARIES = 'varies by run'


def aggregate(results, spec):
    """Return the report (a JSON-serialisable dict) from all runs' results, in run order."""
    rows = [r['row'] for r in results]
    ok = [r for r in results if r['row']['status'] == 'ok']
    failed = [{'run': r['run'], 'reason': r['reason']} for r in rows if r['status'] != 'ok']
    report = {'name': spec['name'], 'seed': spec['seed'], 'runs': spec['runs'],
              'duration_s': spec['duration'], 'estimator': _est_label(spec['estimator']),
              'runs_ok': len(ok), 'runs_failed': len(failed), 'failed': failed}
    if not ok:
        return report
    sensors = [r['row']['sensors'] for r in ok if 'sensors' in r['row']]
    if sensors:
        report['sensors'] = _common(sensors)
    maps = []
    for r in ok:
        s = r['series']
        maps.append({t: (n, e) for t, n, e in zip(s['t_ns'], s['nees'], s['error'])
                     if n is not None and math.isfinite(n)})
    common = set(maps[0])
    for m in maps[1:]:
        common &= set(m)
    steps = sorted(common)
    union = set().union(*[set(m) for m in maps])
    m_runs, k_steps = len(ok), len(steps)
    report['steps'] = k_steps
    report['steps_dropped'] = len(union) - k_steps
    if not k_steps:
        return report
    nees = np.array([[m[t][0] for t in steps] for m in maps])
    err = np.array([[m[t][1] for t in steps] for m in maps])
    mc = nees.mean(axis=0)
    band = anees_bounds(m_runs)
    inside = (mc >= band[0]) & (mc <= band[1])
    run_anees = nees.mean(axis=1)
    run_band = anees_bounds(k_steps)
    report.update({
        'anees': {'value': float(nees.mean()), 'bounds_95': anees_bounds(m_runs * k_steps),
                  'samples': m_runs * k_steps},
        'mc_nees': {'band_95': band, 'fraction_inside': float(inside.mean()),
                    'mean_over_time': float(mc.mean()), 'max': float(mc.max()),
                    't_s': [t * 1e-9 for t in steps], 'nees': mc.tolist()},
        'rms_error': {'t_s': [t * 1e-9 for t in steps],
                      'rad': np.sqrt(np.mean(err ** 2, axis=0)).tolist(),
                      'overall_rad': float(np.sqrt(np.mean(err ** 2)))},
        'per_run_anees': {'values': run_anees.tolist(), 'runs': [r['row']['run'] for r in ok],
                          'bounds_95': run_band,
                          'fraction_inside': float(np.mean((run_anees >= run_band[0])
                                                           & (run_anees <= run_band[1])))},
    })
    return report


def _common(values):
    """Return the value all of ``values`` share, mapping by mapping; :data:`VARIES` else."""
    first = values[0]
    if all(v == first for v in values[1:]):
        return first
    if all(isinstance(v, dict) and v.keys() == first.keys() for v in values):
        return {k: _common([v[k] for v in values]) for k in first}
    return VARIES


def _est_label(est):
    if est['kind'] == 'inproc':
        return {'kind': 'inproc', 'factory': est['factory'], 'params': est['params']}
    return {'kind': 'ros', 'command': est['command'], 'rate': est['rate']}


#: Columns of runs.csv (vectors as one column per component).
CSV_FIELDS = ['run', 'status', 'reason', 'anees', 'anees_lo', 'anees_hi', 'nees_count',
              'count', 'rms_rad', 'max_rad', 'p95_rad', 'redraws']
_VECTORS = [('attitude0', 4), ('omega0', 3), ('imu.gyro_bias', 3), ('inertia', 3),
            ('torque', 3)]


def csv_rows(results):
    """Header and rows of runs.csv (lists of strings; floats as repr, exact)."""
    header = list(CSV_FIELDS)
    present = [(k, n) for k, n in _VECTORS if any(k in r['row'] for r in results)]
    for k, n in present:
        header += [f'{k}[{i}]' for i in range(n)]
    seeds = [k for k in ('imu.seed', 'star_tracker.seed') if any(k in r['row'] for r in results)]
    header += seeds
    out = []
    for r in results:
        row = r['row']
        line = [_cell(row.get(f, '')) for f in CSV_FIELDS]
        for k, n in present:
            v = row.get(k) or [''] * n
            line += [_cell(x) for x in v]
        line += [_cell(row.get(k, '')) for k in seeds]
        out.append(line)
    return header, out


def _cell(v):
    return repr(v) if isinstance(v, float) else str(v)
