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
"""

import concurrent.futures as cf
import math
import multiprocessing
import os
import sys
import time
import zlib

import numpy as np

from rigidrot_ros.bench import common

NAME = 'leaderboard'
NEEDS = ('ahrs', 'imufusion', 'vqf', 'scipy')
KEYS = ('leaderboard',)

_D2R = math.pi / 180.0
#: Correlation time given to the datasheets' bias instability (a first-order Gauss-Markov
#: bias whose stationary sigma is the datasheet's figure): no datasheet states one.
BIAS_TAU_S = 100.0

#: IMU grades: each figure as its datasheet states it, then in the node's units.
GRADES = {
    'consumer': {
        'part': 'Bosch BMI088',
        'source': 'Bosch Sensortec, BMI088 data sheet, BST-BMI088-DS001 (rev. 1.x)',
        'gyro': '0.014 °/s/√Hz rate noise density; bias stability 2 °/h',
        'accel': '160 µg/√Hz noise density (x, y; 190 µg/√Hz z); no bias stability given',
        'gyro_noise_density': 0.014 * _D2R, 'gyro_bias_instability': 2.0 * _D2R / 3600,
        'accel_noise_density': 160e-6 * 9.80665, 'accel_bias_instability': 0.0,
    },
    'industrial': {
        'part': 'Analog Devices ADIS16465-1',
        'source': 'Analog Devices, ADIS16465 data sheet',
        'gyro': '0.15 °/√h angle random walk; in-run bias stability 2 °/h',
        'accel': '0.012 m/s/√h velocity random walk; in-run bias stability 3.6 µg',
        'gyro_noise_density': 0.15 * _D2R / 60, 'gyro_bias_instability': 2.0 * _D2R / 3600,
        'accel_noise_density': 0.012 / 60, 'accel_bias_instability': 3.6e-6 * 9.80665,
    },
    'tactical': {
        'part': 'Honeywell HG4930',
        'source': 'Honeywell, HG4930 MEMS IMU data sheet',
        'gyro': '0.04 °/√h angle random walk; in-run bias stability 0.25 °/h',
        'accel': '0.03 m/s/√h velocity random walk; in-run bias stability 0.025 mg',
        'gyro_noise_density': 0.04 * _D2R / 60, 'gyro_bias_instability': 0.25 * _D2R / 3600,
        'accel_noise_density': 0.03 / 60, 'accel_bias_instability': 0.025e-3 * 9.80665,
    },
}

#: Motions: overrides of config/air_bearing.yaml and the campaign dispersions of each run.
MOTIONS = {
    'slow': {
        'label': 'slow rotation on a supported point',
        'what': 'rate about 0.5 rad/s, axisymmetric body, IMU 0.15 m above the pivot',
        'overrides': {},
        'dispersions': {'attitude0': 'uniform',
                        'omega0': {'mean': [0.2, -0.1, 0.4], 'sigma': [0.05] * 3},
                        'inertia': {'low': [1.9, 1.9, 0.9], 'high': [2.1, 2.1, 1.1]}},
    },
    'tumbling': {
        'label': 'fast tumbling',
        'what': 'triaxial body spun near its intermediate axis at about 3 rad/s (it '
                'flips), IMU at the pivot',
        'overrides': {'inertia': [1.0, 2.0, 3.0], 'accel.lever_arm': [0.0, 0.0, 0.0]},
        'dispersions': {'attitude0': 'uniform',
                        'omega0': {'mean': [0.3, 3.0, 0.3], 'sigma': [0.1, 0.2, 0.1]},
                        'inertia': {'low': [0.95, 1.95, 2.95], 'high': [1.05, 2.05, 3.05]}},
    },
    'lever': {
        'label': 'rotation with lever-arm acceleration',
        'what': 'rate about 2.2 rad/s, IMU 0.29 m from the pivot: centripetal and '
                'tangential acceleration about 1.4 m/s² (15 % of g)',
        'overrides': {'accel.lever_arm': [0.25, 0.0, 0.15]},
        'dispersions': {'attitude0': 'uniform',
                        'omega0': {'mean': [0.8, -0.6, 2.0], 'sigma': [0.1] * 3},
                        'inertia': {'low': [1.9, 1.9, 0.9], 'high': [2.1, 2.1, 1.1]}},
    },
    'uncal': {
        'label': 'slow rotation, uncalibrated offsets',
        'what': 'the slow motion with the turn-on offsets the BMI088 data sheet gives '
                '(zero-rate offset ±1 °/s, zero-g offset ±20 mg) drawn as 1σ per axis',
        'overrides': {'imu.gyro_bias_stddev': 1.0 * _D2R, 'accel.bias_stddev': 20e-3 * 9.80665},
        'dispersions': {'attitude0': 'uniform',
                        'omega0': {'mean': [0.2, -0.1, 0.4], 'sigma': [0.05] * 3},
                        'inertia': {'low': [1.9, 1.9, 0.9], 'high': [2.1, 2.1, 1.1]}},
    },
    'magdist': {
        'label': 'slow rotation, magnetic disturbance',
        'what': 'the slow motion with an uncalibrated hard-iron offset of 9.8 µT in B '
                '(20 % of the 49 µT field)',
        'overrides': {'mag.hard_iron': [6e-6, -6e-6, 5e-6]},
        'dispersions': {'attitude0': 'uniform',
                        'omega0': {'mean': [0.2, -0.1, 0.4], 'sigma': [0.05] * 3},
                        'inertia': {'low': [1.9, 1.9, 0.9], 'high': [2.1, 2.1, 1.1]}},
    },
}

#: The cells: every grade on the three motions; the consumer grade uncalibrated, and with a
#: magnetic disturbance.
CELLS = [(g, m) for g in GRADES for m in ('slow', 'tumbling', 'lever')] + \
    [('consumer', 'uncal'), ('consumer', 'magdist')]
#: The sensors of every cell beyond air_bearing.yaml: 100 Hz imu on the truth's grid, a
#: 20 Hz magnetometer (air_bearing.yaml's), a 10 Hz star tracker (5" / 35") for the MEKF.
SENSOR_OVERRIDES = {'imu.rate': 0.0, 'publish_rate': 100.0, 'mag.rate': 20.0,
                    'star_tracker.enable': True, 'imu.gyro_random_walk': 0.0,
                    'accel.random_walk': 0.0, 'imu.gyro_bias_correlation_time': BIAS_TAU_S,
                    'accel.bias_correlation_time': BIAS_TAU_S}
#: Run sizes: full and --quick.
SIZES = {
    'full': {'duration': 6.0, 'window': 2.0, 'train': 4, 'test': 50, 'default': 10,
             'seed': 2026, 'cells': CELLS},
    'quick': {'duration': 4.0, 'window': 1.0, 'train': 2, 'test': 4, 'default': 2,
              'seed': 2026, 'cells': [('consumer', 'slow'), ('tactical', 'lever')]},
}
#: Curves (the charts' only data) are stored every this many samples, of the tuned filters.
CURVE_STEP = 10
#: A cell has a leader when its RMSE is this much below the runner-up's and it is lower on
#: significantly more held-out runs (two-sided sign test, p below SIGN_P); else a tie.
TIE = 0.02
SIGN_P = 0.05


def grade_values(grade):
    """Return the node parameters of an IMU grade."""
    g = GRADES[grade]
    return {'imu.gyro_noise_density': g['gyro_noise_density'],
            'imu.gyro_bias_instability': g['gyro_bias_instability'],
            'accel.noise_density': g['accel_noise_density'],
            'accel.bias_instability': g['accel_bias_instability']}


def cell_values(grade, motion):
    """Return the node parameter values of a cell (before its dispersions)."""
    from rigidrot_ros.run import settings
    values = settings.load_defaults(settings.find_config('air_bearing.yaml'))
    values.update(SENSOR_OVERRIDES)
    values.update(grade_values(grade))
    values.update(MOTIONS[motion]['overrides'])
    return values


def _seed(seed, grade, motion, split):
    key = zlib.crc32(f'{grade}/{motion}/{split}'.encode())
    return int(np.random.SeedSequence([seed, key]).generate_state(1, np.uint64)[0] >> 1)


def cell_spec(grade, motion, split, seed):
    """Return a campaign spec (the parts :func:`draw_run` reads) of one split of a cell."""
    return {'seed': _seed(seed, grade, motion, split), 'sensor_seeds': 'per_run',
            'dispersions': MOTIONS[motion]['dispersions'],
            'base': {'values': cell_values(grade, motion)}}


def sensor_runs(spec, count, duration):
    """Generate ``count`` runs of ``spec`` in memory: a list of SensorRun (and values)."""
    from rigidrot_ros.campaign.spec import draw_run, run_values
    from rigidrot_ros.estimators.thirdparty import SensorRun
    from rigidrot_ros.run.generate import run_arrays
    out = []
    for i in range(count):
        draws, _ = draw_run(spec, i)
        values = run_values(spec, draws)
        values['mag.seed'] = int(np.random.SeedSequence([spec['seed'], i, 3])
                                 .generate_state(1, np.uint64)[0] >> 1)
        out.append(SensorRun.from_arrays(run_arrays(values, duration), values))
    return out


def _mekf_defaults(grade, motion):
    """Return the MEKF matched to the cell's gyro: noise density, bias walk and prior."""
    v = cell_values(grade, motion)
    b = v['imu.gyro_bias_instability']
    return {'sigma_v': v['imu.gyro_noise_density'],
            'sigma_u': b * math.sqrt(2.0 / v['imu.gyro_bias_correlation_time']),
            'bias_sigma': math.hypot(b, v.get('imu.gyro_bias_stddev', 0.0))}


def _evaluate(filt, runs, override, window):
    """Return ``(run_errors, CPU s (NaN: failed), failures)`` of ``filt`` on ``runs``."""
    from rigidrot_ros.campaign.metrics import run_errors
    errs, cpu, failed = [], [], []
    for i, s in enumerate(runs):
        try:
            est = filt.run(s, override)
            errs.append(run_errors(s.q_true, est.q, est.P))
            cpu.append(est.cpu_s)
        except Exception as exc:  # noqa: B902 - a filter that fails a run is scored NaN
            failed.append(f'run {i}: {type(exc).__name__}: {" ".join(str(exc).split())}'[:200])
            cpu.append(math.nan)
            n = len(s.t)
            errs.append({'total': np.full(n, np.nan), 'incl': np.full(n, np.nan),
                         'head': np.full(n, np.nan),
                         'nees': np.full(n, np.nan) if filt.has_cov else None})
    return errs, cpu, failed


def _rmse(errs, t, window):
    win = np.asarray(t) >= window
    x = np.concatenate([e['total'][win] for e in errs])
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if len(x) and len(x) == win.sum() * len(errs) \
        else math.inf


def run_cell(grade, motion, size='full', names=None, seed=None):
    """Tune and score every filter in one cell; the cell's results (a dict).

    Parameters
    ----------
    grade, motion : str
        Keys of :data:`GRADES` and :data:`MOTIONS`.
    size : str or dict
        ``'full'``, ``'quick'`` or a dict like :data:`SIZES`' entries.
    names : list of str, optional
        Filters to run (default: all of :data:`thirdparty.FILTERS`).
    seed : int, optional
        The leaderboard seed (default: the size's).
    """
    from rigidrot_ros.campaign.metrics import summarise
    from rigidrot_ros.estimators import thirdparty
    sz = SIZES[size] if isinstance(size, str) else size
    seed = sz['seed'] if seed is None else seed
    window, duration = sz['window'], sz['duration']
    t0, c0 = time.perf_counter(), time.process_time()
    train = sensor_runs(cell_spec(grade, motion, 'train', seed), sz['train'], duration)
    test = sensor_runs(cell_spec(grade, motion, 'test', seed), sz['test'], duration)
    t_gen = time.perf_counter() - t0
    t = test[0].t
    fl = thirdparty.filters()
    fl['mekf'].defaults = _mekf_defaults(grade, motion)
    fl['mekf'].grid = [{'sigma_v': k * fl['mekf'].defaults['sigma_v']}
                       for k in (0.5, 1.0, 2.0, 4.0)]
    out = {'grade': grade, 'motion': motion, 'seed': seed, 'duration_s': duration,
           'window_s': window, 'runs_train': len(train), 'runs_test': len(test),
           'runs_default': min(sz['default'], len(test)), 'generate_s': t_gen,
           't_curve_s': t[::CURVE_STEP].tolist(), 'filters': {}}
    for name in names or thirdparty.FILTERS:
        filt = fl[name]
        tuning = []
        for override in [{}] + filt.grid:        # the defaults are a candidate too
            errs, _, _ = _evaluate(filt, train, override, window)
            tuning.append({'params': override,
                           'train_rmse_deg': math.degrees(_rmse(errs, t, window))})
        finite = [r for r in tuning if math.isfinite(r['train_rmse_deg'])]
        best = min(finite, key=lambda r: r['train_rmse_deg'])['params'] if finite else {}
        res = {'label': filt.label, 'library': filt.library, 'sensors': filt.sensors,
               'has_cov': filt.has_cov, 'default_params': filt.params(),
               'tuned_params': filt.params(best), 'tuning': tuning}
        errs, cpu, failed = _evaluate(filt, test, best, window)
        res['tuned'] = _decimate(summarise(t, errs, window, cpu or None))
        res['tuned']['failed'] = failed
        win = t >= window
        res['per_run_rmse_deg'] = [
            math.degrees(float(np.sqrt(np.nanmean(e['total'][win] ** 2))))
            if np.isfinite(e['total'][win]).any() else math.nan for e in errs]
        m = out['runs_default']
        if filt.params(best) != filt.params():      # else the same runs, the same errors
            errs, cpu, failed = _evaluate(filt, test[:m], None, window)
            m = len(errs)
        res['default'] = _decimate(summarise(t, errs[:m], window, cpu[:m] or None), False)
        res['default']['failed'] = [f for f in failed if int(f.split()[1][:-1]) < m]
        out['filters'][name] = res
    out['wall_s'] = time.perf_counter() - t0
    out['cpu_s'] = time.process_time() - c0
    return out


def _decimate(summ, curves=True):
    """Keep the charts' curves (total RMS, NEES) every CURVE_STEP samples, or none."""
    for key in ('incl_curve_deg', 'head_curve_deg'):
        summ.pop(key, None)
    for key in ('rms_curve_deg', 'nees_curve'):
        if key in summ:
            if curves:
                summ[key] = [float(f'{v:.4g}') for v in summ[key][::CURVE_STEP]]
            else:
                del summ[key]
    return summ


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
            best = _leader(res)
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


# -- reading the results ----------------------------------------------------------------------
def _ahrs_names(cell):
    return [n for n, f in cell['filters'].items() if f['sensors'] == 'gyro + acc + mag']


def _leader(cell, key='total'):
    """``(name, rmse, runner-up name, its rmse)`` of the AHRS filters, by tuned RMSE."""
    ranked = sorted(((cell['filters'][n]['tuned']['rmse_deg'][key], n)
                     for n in _ahrs_names(cell)
                     if math.isfinite(cell['filters'][n]['tuned']['rmse_deg'][key])))
    if not ranked:
        return None
    second = ranked[1] if len(ranked) > 1 else (math.nan, '')
    return ranked[0][1], ranked[0][0], second[1], second[0]


def _wins(cell, a, b):
    """Count the held-out runs where ``a``'s RMSE is below ``b``'s: (k, n)."""
    ra = np.array(cell['filters'][a]['per_run_rmse_deg'], float)
    rb = np.array(cell['filters'][b]['per_run_rmse_deg'], float)
    ok = np.isfinite(ra) & np.isfinite(rb)
    return int(np.sum(ra[ok] < rb[ok])), int(ok.sum())


def sign_test(k, n):
    """Two-sided sign test: P(a count at least as far from n/2 as k) under Bin(n, 1/2)."""
    if not n:
        return 1.0
    far = max(k, n - k)
    tail = sum(math.comb(n, i) for i in range(far, n + 1)) / 2.0 ** n
    return min(1.0, 2.0 * tail)


def _tied(cell, lead):
    """Whether the leader's margin over the runner-up is too small or not significant."""
    name, rm, second, rm2 = lead
    if not second:
        return False
    k, n = _wins(cell, name, second)
    return (rm2 - rm) / rm2 < TIE or sign_test(k, n) >= SIGN_P


def headlines(lb):
    """One line per cell: the leading AHRS filter and its margin (text, for the page)."""
    lines = []
    for c in lb['cells']:
        lead = _leader(c)
        if lead is None:
            continue
        name, rm, second, rm2 = lead
        fl = c['filters']
        k, n = _wins(c, name, second) if second else (0, 0)
        inc, hed = _leader(c, 'incl'), _leader(c, 'head')
        grade, motion = GRADES[c['grade']]['part'], MOTIONS[c['motion']]['label']
        line = f'**{grade} ({c["grade"]}), {motion}**: '
        p = f'sign test p = {common.fmt(sign_test(k, n), 2)}'
        if _tied(c, lead):
            line += (f'no clear leader: {fl[name]["label"]} {common.fmt(rm)}° and '
                     f'{fl[second]["label"]} {common.fmt(rm2)}° total RMSE (the first lower '
                     f'in {k} of {n} held-out runs, {p})')
        else:
            line += f'{fl[name]["label"]} leads at {common.fmt(rm)}° total RMSE'
            if second:
                line += (f', {100 * (rm2 - rm) / rm2:.0f} % below {fl[second]["label"]} '
                         f'({common.fmt(rm2)}°; lower in {k} of {n} held-out runs, {p})')
        line += (f'; best inclination {fl[inc[0]]["label"]} {common.fmt(inc[1])}°, best '
                 f'heading {fl[hed[0]]["label"]} {common.fmt(hed[1])}°')
        if 'mekf' in fl and math.isfinite(fl['mekf']['tuned']['rmse_deg']['total']):
            mekf = fl['mekf']['tuned']['rmse_deg']['total']
            line += f'; the MEKF with its star tracker {common.fmt(mekf)}°'
        lines.append(line)
    return lines


def _params_text(p, ref=None):
    keys = [k for k in p if ref is None or p[k] != ref.get(k)]
    if not keys:
        return 'defaults'
    return ', '.join(f'{k} {common.fmt(p[k]) if isinstance(p[k], float) else p[k]}'
                     for k in keys)


def _edge(f):
    """Return ' (grid edge)' when a tuned value is the smallest or largest tried."""
    for key, value in f['tuned_params'].items():
        tried = [r['params'][key] for r in f['tuning'] if key in r['params']
                 and isinstance(r['params'][key], (int, float))]
        if value != f['default_params'].get(key) and tried and \
                value in (min(tried), max(tried)):
            return ' (grid edge)'
    return ''


def _nees_text(s):
    if s.get('anees') is None:
        return 'no covariance'
    if not math.isfinite(s['anees']):
        return '—'
    lo, hi = s['mc_nees_band']
    return (f'{common.fmt(s["anees"])}; {100 * s["mc_nees_inside"]:.0f} % of steps in '
            f'[{common.fmt(lo)}, {common.fmt(hi)}]')


def _dispersion_text(disp):
    out = []
    for k, d in disp.items():
        if d == 'uniform':
            out.append(f'{k} uniform on SO(3)')
        elif 'sigma' in d:
            out.append(f'{k} normal, mean {_vec(d["mean"])}, σ {_vec(d["sigma"])}')
        else:
            out.append(f'{k} uniform in [{_vec(d["low"])}, {_vec(d["high"])}]')
    return '; '.join(out)


def _vec(v):
    return '(' + ', '.join(common.fmt(float(x)) for x in v) + ')'


def _cell_table(c):
    rows = []
    lead = _leader(c)
    for name, f in c['filters'].items():
        s, d = f['tuned'], f['default']
        tag = ' **(leads)**' if lead and lead[0] == name and not _tied(c, lead) else ''
        rows.append([
            f['label'] + tag, f['sensors'],
            _params_text(f['tuned_params'], f['default_params']) + _edge(f),
            common.fmt(s['rmse_deg']['incl']), common.fmt(s['rmse_deg']['head']),
            common.fmt(s['rmse_deg']['total']), common.fmt(s['p95_deg']),
            common.fmt(s['t_converge_s']), _nees_text(s),
            common.fmt(s.get('us_per_sample')),
            f'{common.fmt(d["rmse_deg"]["total"])} → {common.fmt(tuned_on_default_runs(c, name))}',
            _nees_text(d) if f['has_cov'] else '—'])
    return common.md_table(
        ['filter', 'sensors', 'tuned (changed from defaults)', 'incl. RMSE °',
         'heading RMSE °', 'total RMSE °', 'p95 °', 'converged by s', 'NEES: ANEES; MC band',
         'µs / sample', f'defaults → tuned: total RMSE ° (first {c["runs_default"]} runs)',
         'defaults: NEES'], rows)


def tuned_on_default_runs(cell, name):
    """Return the tuned filter's total RMSE (deg) on the runs its defaults were scored on.

    Every run has the same samples in the window, so the RMSE over runs is the RMS of the
    runs' own RMSE.
    """
    v = np.array(cell['filters'][name]['per_run_rmse_deg'][:cell['runs_default']], float)
    return float(np.sqrt(np.mean(v ** 2))) if len(v) and np.all(np.isfinite(v)) else math.nan


def _tuning_table(lb):
    """Per filter: cells where tuning kept the defaults, the change on the same runs, values."""
    rows = []
    for name in lb['cells'][0]['filters']:
        kept, change, values = 0, [], {}
        for c in lb['cells']:
            f = c['filters'][name]
            d, t = f['default']['rmse_deg']['total'], tuned_on_default_runs(c, name)
            if f['tuned_params'] == f['default_params']:
                kept += 1
            else:
                for k, v in f['tuned_params'].items():
                    if v != f['default_params'].get(k) and isinstance(v, (int, float)):
                        values.setdefault(k, []).append(v)
            if math.isfinite(d) and math.isfinite(t) and d > 0:
                change.append(100.0 * (t - d) / d)
        label = lb['cells'][0]['filters'][name]['label']
        defaults = [c['filters'][name]['default_params'] for c in lb['cells']]
        default = _params_text(defaults[0], {}) if all(d == defaults[0] for d in defaults) \
            else 'per cell (matched to its IMU grade)'
        tuned = '; '.join(f'{k} {common.span(v)}' for k, v in values.items()) or '—'
        ch = (f'median {_pct(np.median(change))}, from {_pct(min(change))} to '
              f'{_pct(max(change))}') if change else '—'
        rows.append([label, default, f'{kept} of {len(lb["cells"])}', tuned, ch])
    return common.md_table(['filter', 'defaults', 'cells where tuning kept them',
                            'tuned values elsewhere', 'total RMSE from defaults to tuned, same '
                            'runs (negative: tuning helped)'], rows)


def _pct(x):
    r = int(round(float(x)))
    return f'{r:+d} %' if r else '0 %'


def render_md(results):
    """Return the leaderboard's fragment (headline, tables), or None without results."""
    lb = results.get(NAME)
    if not lb or not lb.get('cells'):
        return None
    c0 = lb['cells'][0]
    parts = [
        f'{len(lb["cells"])} cells; per cell {c0["runs_test"]} held-out runs (defaults: the '
        f'first {c0["runs_default"]} of them) and {c0["runs_train"]} training runs of '
        f'other seeds, {common.fmt(c0["duration_s"])} s each at 100 Hz, errors scored from '
        f't = {common.fmt(c0["window_s"])} s',
        f'the whole leaderboard took {lb["wall_s"]:.0f} s on {lb["processes"]} '
        f'processes ({lb["cpu_s"]:.0f} CPU s; load average '
        f'{common.fmt(lb["load_average"][0], 2)} at the start, '
        f'{common.fmt(lb["load_average"][1], 2)} at the end)',
        'leader: lowest total RMSE among the filters on gyro + accelerometer + magnetometer '
        '(the MEKF fuses a star tracker instead and is listed apart), at least '
        f'{100 * TIE:.0f} % below the runner-up and lower on significantly more held-out runs '
        f'(two-sided sign test, p < {SIGN_P:g}); else no clear leader',
    ]
    body = common.md_bullets(parts)
    body += '**Headline**\n\n' + common.md_bullets(headlines(lb))
    body += ('**What tuning changed** (on the training runs; scored on the first '
             f'{c0["runs_default"]} held-out runs of each cell, both ways)\n\n'
             + _tuning_table(lb) + '\n')
    body += ("**IMU grades** (the datasheets' figures; bias instability as the stationary "
             f'σ of a Gauss–Markov bias, τ = {common.fmt(lb["bias_tau_s"])} s)\n\n')
    body += common.md_table(
        ['grade', 'part', 'gyro', 'accelerometer', 'node parameters', 'source'],
        [[g, v['part'], v['gyro'], v['accel'],
          f'imu.gyro_noise_density {common.fmt(v["gyro_noise_density"])}, '
          f'imu.gyro_bias_instability {common.fmt(v["gyro_bias_instability"])}, '
          f'accel.noise_density {common.fmt(v["accel_noise_density"])}, '
          f'accel.bias_instability {common.fmt(v["accel_bias_instability"])}', v['source']]
         for g, v in lb['grades'].items()]) + '\n'
    body += '**Motions** (over `config/air_bearing.yaml`)\n\n'
    body += common.md_table(
        ['motion', 'what', 'parameters', 'dispersions'],
        [[v['label'], v['what'], ', '.join(
            f'{k} {_vec(x) if isinstance(x, list) else common.fmt(x)}'
            for k, x in v['overrides'].items()) or 'air_bearing.yaml',
          _dispersion_text(v['dispersions'])]
         for v in lb['motions'].values()]) + '\n'
    for c in lb['cells']:
        body += (f'**{GRADES[c["grade"]]["part"]} ({c["grade"]}), '
                 f'{MOTIONS[c["motion"]]["label"]}** (M = {c["runs_test"]})\n\n')
        body += _cell_table(c) + '\n'
    return common.part_md(results, NAME, 'Leaderboard: attitude filters on exact truth',
                          body)


# -- charts ---------------------------------------------------------------------------------
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


def main(argv=None):
    """Run the leaderboard alone (``python -m rigidrot_ros.bench.leaderboard``)."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
