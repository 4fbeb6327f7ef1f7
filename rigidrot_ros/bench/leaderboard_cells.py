"""The leaderboard's cells: IMU grades x motions, their runs, one cell tuned and scored.

A cell is an IMU grade (:data:`GRADES`, a named datasheet's figures) on a motion
(:data:`MOTIONS`, overrides of ``config/air_bearing.yaml`` and the campaign dispersions of
its runs). :func:`run_cell` draws the cell's training and held-out runs
(:func:`cell_spec`, :func:`sensor_runs`), tunes every filter on the training runs and
scores it on the held-out ones, with its tuned parameters and with its defaults. The part
(:mod:`.leaderboard`) runs the cells of a :data:`SIZES` entry on a process pool.
"""

import math
import time
import zlib

import numpy as np

#: The part's name, and the key of its results in ``results.json``.
NAME = 'leaderboard'

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
