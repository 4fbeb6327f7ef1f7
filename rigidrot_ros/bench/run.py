"""rigidrot_bench: speed against accuracy, horizon scaling, and where each method fails.

Every method is timed (CPU time, median of repeats) and its answer is checked against a
reference far tighter than anything measured: the exact solution at tol = 2e-14 rad
(certified by Arb). An exact evaluation whose error exceeds its own tol is reported as a
violated claim, not plotted as a win.
"""

import argparse
import csv
import datetime
import json
import math
import os
import platform
import sys
import time

import mpmath
import numpy as np

from rigidrot_ros import __version__
from rigidrot_ros.bench import peers
from rigidrot_ros.core import PrecisionError, Scene, solve
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core.kernel import HyperKernel
from rigidrot_ros.core.taylor import TaylorKernel

REF_TOL = 2e-14

SCENES = {
    'sphere (Thm 1)': Scene(inertia=(2.0, 2.0, 2.0), torque=(0.06, -0.04, 0.08),
                            omega0=(0.3, -0.2, 0.5), attitude0=(0.1, 0.2, 0.3, 0.9)),
    'axial torque (Thm 2)': Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05),
                                  omega0=(0.3, -0.2, 0.5), attitude0=(0.1, 0.2, 0.3, 0.9)),
    'transverse, virtual (Thm 3)': Scene(inertia=(2.0, 2.0, 1.0), torque=(0.04, 0.0, 0.0),
                                         torque_frame='virtual', omega0=(0.3, -0.2, 0.5),
                                         attitude0=(0.1, 0.2, 0.3, 0.9)),
    'torque-free (Thm 5)': Scene(inertia=(2.0, 2.0, 1.0), omega0=(0.3, -0.2, 1.5),
                                 attitude0=(0.1, 0.2, 0.3, 0.9)),
}


def _cpu():
    try:
        with open('/proc/cpuinfo', encoding='utf-8') as fh:
            for line in fh:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown CPU'


def footer():
    """Versions, CPU and date: printed with every result."""
    import scipy
    try:
        import flint
        fl = flint.__version__
    except ImportError:
        fl = 'absent'
    return {
        'rigidrot_ros': __version__, 'python': platform.python_version(),
        'numpy': np.__version__, 'scipy': scipy.__version__, 'mpmath': mpmath.__version__,
        'python-flint': fl, 'cpu': _cpu(), 'cores': os.cpu_count(),
        'machine': platform.node(),
        'date': datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC'),
    }


def _timed(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        c = time.process_time()
        out = fn()
        times.append(time.process_time() - c)
    return float(np.median(times)), out


def _methods(scene, quick, workload):
    """List (method, knob label, knob value, callable(t_eval, budget) -> q) for a scene."""
    rtols = [1e-5, 1e-7, 1e-9, 1e-11, 1e-13] if not quick else [1e-6, 1e-9, 1e-12]
    steps = [0.1, 0.05, 0.02, 0.01, 0.005, 0.0025] if not quick else [0.05, 0.01]
    if workload == 'stream':
        steps = [h for h in steps if abs(0.01 / h - round(0.01 / h)) < 1e-9]
    tols = [1e-6, 1e-9, 1e-12] if not quick else [1e-9, 1e-12]
    omega_sol = solve(scene)
    out = []
    for rt in rtols:
        for m in ('DOP853', 'RK45'):
            if m == 'RK45' and rt < 1e-11:
                continue                       # RK45 at these tolerances takes minutes
            out.append((m, 'rtol', rt,
                        lambda t, b, m=m, rt=rt: peers.scipy_ivp(scene, t, m, rt, budget=b)))
    for h in steps:
        out.append(('RK4', 'h', h, lambda t, b, h=h: peers.rk4(scene, t, h, budget=b)))
        out.append(('RKMK4', 'h', h, lambda t, b, h=h: peers.rkmk4(scene, t, h, budget=b)))
        out.append(('Magnus4', 'h', h, lambda t, b, h=h: peers.magnus4(
            scene, t, h, omega_sol.omega_at, budget=b)))
    for be in ('flint', 'mpmath'):
        for tol in tols:
            out.append((f'exact ({be})', 'tol', tol,
                        lambda t, b, be=be, tol=tol: solve(scene, tol=tol,
                                                           backend=be).at(t).quaternion))
    return out


def work_precision(quick, repeats, budget, log):
    """Workload (a): one query at T = 60 s; (b): a 100 Hz stream over 60 s."""
    rows = []
    scenes = SCENES if not quick else dict(list(SCENES.items())[1:2])
    horizon = 60.0 if not quick else 5.0
    n_stream = int(round(horizon * 100))
    for sname, scene in scenes.items():
        ref_sol = solve(scene, tol=REF_TOL)
        for workload, t_eval in (('query', np.array([horizon])),
                                 ('stream', np.arange(1, n_stream + 1) * 0.01)):
            ref = ref_sol.at(t_eval).quaternion
            for name, knob, value, fn in _methods(scene, quick, workload):
                try:
                    cpu, q = _timed(lambda: fn(t_eval, budget), repeats)
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


def horizon_scaling(quick, budget, log):
    """CPU time to reach 1e-9 and 1e-12 rad at T, each method at its cheapest knob."""
    scene = SCENES['axial torque (Thm 2)']
    horizons = [1.0, 10.0] if quick else [1.0, 10.0, 100.0, 1e3, 1e4, 1e5]
    ref_sol = solve(scene, tol=REF_TOL)
    rows = []
    given_up = set()            # (method, target): not reached at a shorter horizon
    for T in horizons:
        t_eval = np.array([T])
        ref = ref_sol.at(t_eval).quaternion
        for target in (1e-9, 1e-12):
            best = {}
            for name, knob, value, fn in _methods(scene, quick, 'query'):
                if name in best or (knob == 'tol' and value > target) or \
                        (name, target) in given_up:
                    continue
                if T >= 1e4 and knob == 'h' and value < 0.01:
                    continue                   # millions of Python steps: not worth timing
                try:
                    cpu, q = _timed(lambda: fn(t_eval, budget), 1)
                    err = float(quat.angle_between(q, ref).max())
                except peers.TimeBudget:
                    continue
                except (ArithmeticError, ValueError):
                    continue
                if err <= target:
                    best[name] = (cpu, knob, value, err)
            for name in sorted({m for m, *_ in _methods(scene, quick, 'query')}):
                if name not in best:
                    given_up.add((name, target))
                cpu, knob, value, err = best.get(name, (math.nan, '', math.nan, math.nan))
                rows.append({'T_s': T, 'target_rad': target, 'method': name, 'cpu_s': cpu,
                             'knob': knob, 'value': value, 'error_rad': err,
                             'status': 'ok' if name in best else 'not reached'})
                log(f'T={T:<8g} target {target:g} {name:16s} cpu {cpu:9.4f} s '
                    f'{knob}={value:<8g} err {err:9.2e}')
    return rows


def stability_map(quick, budget, log):
    """Status of each method over torque U x horizon T, and over spin rate r0 x T."""
    us = [1e-6, 1.0] if quick else [1e-10, 1e-8, 1e-6, 1e-4, 1e-2, 1.0, 1e2]
    ts = [1.0, 100.0] if quick else [1.0, 10.0, 100.0, 1e3, 1e4, 1e5]
    r0s = [10.0] if quick else [0.1, 1.0, 10.0, 100.0]
    methods = {
        'exact (flint), tol 1e-12': lambda sc, t, b: solve(sc, tol=1e-12).at(t).quaternion,
        'exact (mpmath), tol 1e-12': lambda sc, t, b: solve(
            sc, tol=1e-12, backend='mpmath').at(t).quaternion,
        'DOP853, rtol 1e-13': lambda sc, t, b: peers.scipy_ivp(sc, t, 'DOP853', 1e-13,
                                                               budget=b),
        'RKMK4, h = 0.01 s': lambda sc, t, b: peers.rkmk4(sc, t, 0.01, budget=b),
    }
    cells = []
    grids = [('U', u, 0.5) for u in us] + [('r0', r, 1e-2) for r in r0s]
    for axis, val, other in grids:
        u, r0 = (val, other) if axis == 'U' else (other, val)
        scene = Scene(inertia=(1.0, 1.0, 1.0), torque=(0.0, 0.0, u), omega0=(0.3, -0.2, r0))
        timed_out = set()
        for T in ts:
            t_eval = np.array([T])
            try:
                ref = solve(scene, tol=REF_TOL).at(t_eval).quaternion
            except (PrecisionError, ValueError) as exc:
                ref = None
                log(f'no reference at {axis}={val:g} T={T:g}: {exc}'[:120])
            for name, fn in methods.items():
                if name in timed_out:           # a longer horizon only takes longer
                    cells.append({'axis': axis, 'value': val, 'T_s': T, 'method': name,
                                  'status': 'fail: time-out', 'error_rad': math.nan,
                                  'cpu_s': math.nan})
                    continue
                c = time.process_time()
                try:
                    q = fn(scene, t_eval, budget)
                    cpu = time.process_time() - c
                    err = float(quat.angle_between(q, ref).max()) if ref is not None else \
                        math.nan
                    if not np.all(np.isfinite(q)):
                        status = 'fail: NaN'
                    elif ref is None:
                        status = 'no reference'
                    elif err <= 1e-12:
                        status = 'meets 1e-12'
                    elif err <= 1e-9:
                        status = 'meets 1e-9'
                    else:
                        status = 'loses accuracy'
                except peers.TimeBudget:
                    cpu, err, status = time.process_time() - c, math.nan, 'fail: time-out'
                    timed_out.add(name)
                except (PrecisionError, ArithmeticError, ValueError) as exc:
                    cpu, err, status = time.process_time() - c, math.nan, \
                        f'fail: {type(exc).__name__}'
                cells.append({'axis': axis, 'value': val, 'T_s': T, 'method': name,
                              'status': status, 'error_rad': err, 'cpu_s': cpu})
                log(f'{axis}={val:<8g} T={T:<8g} {name:26s} {status:16s} err {err:9.2e} '
                    f'cpu {cpu:8.3f} s')
    return cells


def _envelope_scene(rng):
    """Draw a random scene inside the envelope: any model with a torque."""
    u = 10 ** rng.uniform(-10, 2)
    wt = 10 * rng.uniform() ** 2                      # transverse rate 0..10 rad/s
    r0 = rng.uniform(-100, 100) * rng.choice([1.0, 0.01])
    ratio = rng.uniform(0.05, 1.95)                    # I3 / I
    phi = rng.uniform(0, 2 * math.pi)
    w = (wt * math.cos(phi), wt * math.sin(phi), r0)
    kind = rng.choice(['sphere', 'axial', 'virtual', 'oblique'])
    inertia = (1.0, 1.0, 1.0) if kind == 'sphere' else (1.0, 1.0, ratio)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    if kind == 'axial':
        torque, frame = (0.0, 0.0, u * ratio), 'body'
    elif kind == 'virtual':
        torque, frame = (u * d[0], u * d[1], 0.0), 'virtual'
    elif kind == 'oblique':
        torque, frame = tuple(u * d), 'virtual'
    else:
        torque, frame = tuple(u * d), 'body'
    return Scene(inertia=inertia, torque=torque, torque_frame=frame, omega0=w), u, wt, r0


def envelope(quick, log, max_turn=2e5):
    """Random scenes across the envelope: per-sample cost of a 100 Hz stream and errors."""
    rng = np.random.default_rng(2026)
    rows = []
    n = 8 if quick else 60
    for i in range(n):
        scene, u, wt, r0 = _envelope_scene(rng)
        sol = solve(scene, tol=1e-12)
        # horizon: up to 1e5 s, capped where a first query would turn > max_turn rad
        rate = abs(r0) + wt
        t_cap = min(1e5, max_turn / max(rate, 1e-9))
        if u > 0:
            t_cap = min(t_cap, math.sqrt(2 * max_turn / u))
        t0 = float(rng.uniform(0, t_cap))
        c = time.process_time()
        try:
            first = sol.at(t0)
        except PrecisionError as exc:
            rows.append({'i': i, 'model': sol.model, 'method': sol.method, 'U': u,
                         'transverse': wt, 'r0': r0, 't0': t0, 'status': f'fail: {exc}'[:90]})
            log(f'envelope {i}: FAIL {exc}'[:140])
            continue
        t_first = time.process_time() - c
        costs, bounds = [], [float(first.error_bound)]
        qs = []
        for k in range(1, 101):
            c = time.process_time()
            smp = sol.at(t0 + 0.01 * k)
            costs.append(time.process_time() - c)
            bounds.append(float(smp.error_bound))
            qs.append(smp.quaternion)
        # an independent representation where it is affordable: 1F1 <-> Taylor
        other = math.nan
        kern = sol._kernel
        if type(kern).__name__ in ('HyperKernel', 'TaylorKernel'):
            p, q, kr0, ku = kern._inputs if hasattr(kern, '_inputs') else (None,) * 4
            delta = (float(p) ** 2 + float(q) ** 2) / (4 * float(ku))
            try:
                if isinstance(kern, TaylorKernel) and delta < 300:
                    # the same exact (256-bit) inputs: floats would move long phases
                    alt = HyperKernel(p, q, kr0, ku, 'flint', tol=kern.tol)
                elif isinstance(kern, HyperKernel) and abs(float(kr0)) + float(ku) * t0 \
                        + math.hypot(float(p), float(q)) < 1e5 / max(t0, 1):
                    alt = TaylorKernel(*(mpmath.mpf(v) for v in (p, q, kr0, ku)),
                                       tol=kern.tol)
                else:
                    alt = None
                if alt is not None:
                    a, _ = kern.evaluate(t0 + 1.0)
                    b, _ = alt.evaluate(t0 + 1.0)
                    other = float(2 * np.linalg.norm(a - b))
            except PrecisionError:
                pass
        row = {'i': i, 'model': sol.model, 'method': sol.method, 'U': u, 'transverse': wt,
               'r0': r0, 't0': t0, 'first_query_s': t_first,
               'p50_us': 1e6 * float(np.percentile(costs, 50)),
               'p99_us': 1e6 * float(np.percentile(costs, 99)),
               'max_bound_rad': max(bounds), 'vs_other_representation_rad': other,
               'status': 'ok' if max(bounds) <= 1e-12 else 'bound above tol'}
        rows.append(row)
        log(f'envelope {i:3d} {sol.model:22s} {sol.method:26s} U={u:8.1e} wt={wt:5.2f} '
            f'r0={r0:8.2f} t0={t0:9.1f} first {t_first:7.3f} s p99 {row["p99_us"]:7.1f} us '
            f'bound {max(bounds):.1e} other {other:.1e}')
    return rows


#: A spacecraft-like scene for the long-horizon ratios: I = 100 kg m^2, 10.8 mN m, so
#: U = 1.08e-4 rad/s^2; omega0 lies near the torque axis (delta = 10.4, the 1F1 path) and
#: the rates stay near 1 rad/s over 1e4 s.
RATIO_SCENE = Scene(inertia=(100.0, 100.0, 100.0), torque=(0.006, -0.004, 0.008),
                    omega0=(0.3, -0.2, 0.5), attitude0=(0.1, 0.2, 0.3, 0.9))


def ratios(quick, log, budget=600.0):
    """Exact against DOP853 at equal accuracy: (a) one query, (b) a 100 Hz stream, at T."""
    scene = RATIO_SCENE
    ref_sol = solve(scene, tol=REF_TOL)
    rows = []
    horizons = (60.0,) if quick else (60.0, 1e4)
    for T in horizons:
        for workload in ('query', 'stream'):
            t_eval = np.array([T]) if workload == 'query' else \
                np.arange(1, int(round(T * 100)) + 1) * 0.01
            ref = ref_sol.at(t_eval).quaternion
            runs = []
            for tol in (1e-9, 1e-12):
                cpu, q = _timed(lambda: solve(scene, tol=tol).at(t_eval).quaternion, 1)
                runs.append(('exact (flint)', tol, cpu, float(quat.angle_between(q, ref).max())))
            for rt in ((1e-9, 1e-10, 1e-11, 1e-12, 1e-13) if T < 1e3 else (1e-10, 1e-13)):
                try:
                    cpu, q = _timed(lambda: peers.scipy_ivp(scene, t_eval, 'DOP853', rt,
                                                            budget=budget), 1)
                    err = float(quat.angle_between(q, ref).max())
                except peers.TimeBudget:
                    cpu, err = budget, math.nan
                runs.append(('DOP853', rt, cpu, err))
            for target in (1e-9, 1e-12):
                best = {}
                for name, knob, cpu, err in runs:
                    if err <= target and (name not in best or cpu < best[name][0]):
                        best[name] = (cpu, knob, err)
                ex, dp = best.get('exact (flint)'), best.get('DOP853')
                dop_best = min((r for r in runs if r[0] == 'DOP853' and math.isfinite(r[3])),
                               key=lambda r: r[3], default=None)
                row = {'T_s': T, 'workload': workload, 'samples': len(t_eval),
                       'target_rad': target,
                       'exact_cpu_s': ex[0] if ex else math.nan,
                       'exact_tol': ex[1] if ex else math.nan,
                       'dop853_cpu_s': dp[0] if dp else math.nan,
                       'dop853_rtol': dp[1] if dp else math.nan,
                       'ratio_exact_over_dop853': (ex[0] / dp[0]) if ex and dp else math.nan,
                       'dop853_best_error_rad': dop_best[3] if dop_best else math.nan,
                       'dop853_best_cpu_s': dop_best[2] if dop_best else math.nan}
                rows.append(row)
                log(f'ratio T={T:g} {workload:6s} target {target:g}: exact '
                    f'{row["exact_cpu_s"]:.4f} s DOP853 {row["dop853_cpu_s"]:.4f} s '
                    f'(rtol {row["dop853_rtol"]:g}) ratio '
                    f'{row["ratio_exact_over_dop853"]:.3g}; DOP853 best error '
                    f'{row["dop853_best_error_rad"]:.2e}')
    return rows


def _write_csv(path, rows, foot):
    if not rows:
        return
    with open(path, 'w', newline='', encoding='utf-8') as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
        fh.write('# ' + json.dumps(foot) + '\n')


def main(argv=None):
    """Entry point of ``rigidrot_bench``."""
    ap = argparse.ArgumentParser(prog='rigidrot_bench', description=__doc__.splitlines()[0])
    ap.add_argument('--out', default='bench_out', help='directory for charts and data')
    ap.add_argument('--quick', action='store_true', help='a smoke run, under a minute')
    ap.add_argument('--only', choices=['wp', 'horizon', 'stability', 'envelope', 'ratios',
                                       'triaxial'], action='append')
    opts = ap.parse_args(argv)
    os.makedirs(opts.out, exist_ok=True)
    repeats = 1 if opts.quick else 3
    budget = 1.0 if opts.quick else 60.0
    foot = footer()
    parts = opts.only or ['wp', 'horizon', 'stability']
    t0 = time.monotonic()

    def log(line):
        print(f'[{time.monotonic() - t0:7.1f} s] {line}', flush=True)

    results = {}
    merged = os.path.join(opts.out, 'results.json')
    if os.path.exists(merged):            # a partial run (--only) adds to an earlier one
        with open(merged, encoding='utf-8') as fh:
            results = json.load(fh)
    results['footer'] = foot
    if 'wp' in parts:
        results['work_precision'] = work_precision(opts.quick, repeats, budget, log)
        _write_csv(os.path.join(opts.out, 'work_precision.csv'), results['work_precision'],
                   foot)
    if 'horizon' in parts:
        results['horizon'] = horizon_scaling(opts.quick, min(budget, 30.0), log)
        _write_csv(os.path.join(opts.out, 'horizon.csv'), results['horizon'], foot)
    if 'stability' in parts:
        results['stability'] = stability_map(opts.quick, 20.0 if not opts.quick else 1.0, log)
        _write_csv(os.path.join(opts.out, 'stability.csv'), results['stability'], foot)
    if 'ratios' in parts:
        results['ratios'] = ratios(opts.quick, log)
        _write_csv(os.path.join(opts.out, 'ratios.csv'), results['ratios'], foot)
    if 'envelope' in parts:
        results['envelope'] = envelope(opts.quick, log)
        _write_csv(os.path.join(opts.out, 'envelope.csv'), results['envelope'], foot)
    if 'triaxial' in parts:                     # torque-free triaxial rows: bench/triaxial.py
        from rigidrot_ros.bench import triaxial
        results['triaxial'] = triaxial.run(opts.out, opts.quick, foot, log)
    with open(os.path.join(opts.out, 'results.json'), 'w', encoding='utf-8') as fh:
        json.dump(results, fh, indent=1, default=float)
    from rigidrot_ros.bench import charts
    for path in charts.draw(results, opts.out):
        log(f'wrote {path}')
    violated = [r for r in results.get('work_precision', []) if r['status'] == 'claim violated']
    for r in violated:
        log(f'CLAIM VIOLATED: {r}')
    print(json.dumps(foot))
    return 1 if violated else 0


if __name__ == '__main__':
    sys.exit(main())
