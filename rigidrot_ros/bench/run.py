"""rigidrot_bench: speed against accuracy, horizon scaling, and where each method fails.

Every method is timed (CPU time, median of repeats) and its answer is checked against a
reference far tighter than anything measured: the exact solution at tol = 2e-14 rad
(certified by Arb). An exact evaluation whose error exceeds its own tol is reported as a
violated claim, not plotted as a win.
"""

import csv
import datetime
import json
import math
import os
import platform
import sys
import time
import tracemalloc

import mpmath
import numpy as np

from rigidrot_ros import __version__
from rigidrot_ros.core import PrecisionError, Scene, solve
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core.kernel import HyperKernel
from rigidrot_ros.core.taylor import TaylorKernel
from rigidrot_ros.tools.cli import OneLineParser

try:
    from rigidrot_ros.bench import peers
except ImportError as _exc:     # scipy is the 'bench' extra: main() says what to install
    peers = None
    _PEERS_MISSING = _exc.name or str(_exc)
else:
    _PEERS_MISSING = None

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
    try:
        import scipy
        sp = scipy.__version__
    except ImportError:
        sp = 'absent'
    try:
        import flint
        fl = flint.__version__
    except ImportError:
        fl = 'absent'
    return {
        'rigidrot_ros': __version__, 'python': platform.python_version(),
        'numpy': np.__version__, 'scipy': sp, 'mpmath': mpmath.__version__,
        'python-flint': fl, 'cpu': _cpu(), 'cores': os.cpu_count(),
        'machine': platform.node(),
        'date': datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC'),
    }


def timed(fn, repeats=1):
    """Call ``fn`` ``repeats`` times; return (median CPU seconds, its last value)."""
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
                    cpu, q = timed(lambda: fn(t_eval, budget), repeats)
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
                    cpu, q = timed(lambda: fn(t_eval, budget), 1)
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


def run_method(fn, scene, t_eval, budget, error):
    """Run one method once: return (CPU seconds, error in rad, status of the cell).

    ``fn(scene, t_eval, budget)`` returns quaternions; ``error(q)`` their angle to the
    reference in rad, or ``error`` is None where there is no reference (status 'no
    reference', error NaN). The status is 'meets 1e-12', 'meets 1e-9', 'loses accuracy',
    'fail: NaN', 'fail: time-out' (the budget ran out) or 'fail: <exception>'.
    """
    c = time.process_time()
    try:
        q = fn(scene, t_eval, budget)
        cpu = time.process_time() - c
        err = error(q) if error is not None else math.nan
        if not np.all(np.isfinite(q)):
            status = 'fail: NaN'
        elif error is None:
            status = 'no reference'
        elif err <= 1e-12:
            status = 'meets 1e-12'
        elif err <= 1e-9:
            status = 'meets 1e-9'
        else:
            status = 'loses accuracy'
    except peers.TimeBudget:
        cpu, err, status = time.process_time() - c, math.nan, 'fail: time-out'
    except (PrecisionError, ArithmeticError, ValueError) as exc:
        cpu, err, status = time.process_time() - c, math.nan, f'fail: {type(exc).__name__}'
    return cpu, err, status


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
                cpu, err, status = run_method(
                    fn, scene, t_eval, budget,
                    None if ref is None else lambda q: float(quat.angle_between(q, ref).max()))
                if status == 'fail: time-out':
                    timed_out.add(name)
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


def _mpf_bits(v):
    """Bits of the mantissa of an mpf (or of a float or int), as it is stored."""
    m = v if isinstance(v, mpmath.mpf) else mpmath.mpf(v)     # a float converts exactly
    return max(53, int(m._mpf_[1]).bit_length())


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
                # the same exact inputs, unrounded (mpmath.mpf(v) would round them to the
                # ambient 53 bits) and with their derived constants at as many bits as the
                # inputs carry: otherwise the two would answer slightly different scenes
                bits = max(256, *(_mpf_bits(v) for v in (p, q, kr0, ku)))
                if isinstance(kern, TaylorKernel) and delta < 300:
                    alt = HyperKernel(p, q, kr0, ku, 'flint', tol=kern.tol, setup_prec=bits)
                elif isinstance(kern, HyperKernel) and abs(float(kr0)) + float(ku) * t0 \
                        + math.hypot(float(p), float(q)) < 1e5 / max(t0, 1):
                    alt = TaylorKernel(p, q, kr0, ku, tol=kern.tol)
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


#: The issue's spacecraft scene: axial torque 2e-4 N m on I = (2, 2, 3) (delta = 325,
#: the certified Taylor path).
SPACECRAFT = Scene(inertia=(2.0, 2.0, 3.0), torque=(0.0, 0.0, 2e-4), omega0=(0.3, -0.2, 0.5))
RATIO_FIELDS = (
    'part', 'scene', 'samples', 'horizon_s', 'exact_cpu_s', 'dop853_cpu_s',
    'dop853_lean_cpu_s', 'speedup_vs_dop853', 'speedup_vs_dop853_lean', 'exact_error_rad',
    'exact_max_bound_rad', 'bounds_hold', 'dop853_error_rad', 'mean_us', 'p50_us', 'p99_us',
    'memory_ratio')


def ratio_scenes():
    """Return the preset scenes (config/*.yaml) and the spacecraft scene, by name."""
    from rigidrot_ros import settings
    folder = os.path.dirname(settings.find_config('default.yaml'))
    out = {}
    for name in sorted(os.listdir(folder)):
        if name.endswith('.yaml'):
            params = settings.load_defaults(os.path.join(folder, name))
            out[name[:-5]] = settings.scene_from_params(params)
    out['spacecraft'] = SPACECRAFT
    return out


def _row(**kw):
    row = {k: math.nan for k in RATIO_FIELDS}
    row.update(kw)
    return row


def reference_solution(scene):
    """Solve the scene at REF_TOL, or at the tightest doubling of it its model accepts.

    The triaxial model's float64 evaluation is bounded near 5e-14 rad, so it refuses
    REF_TOL with a PrecisionError; the reference is then its own tightest certified tol.
    """
    tol = REF_TOL
    while True:
        try:
            return solve(scene, tol=tol)
        except PrecisionError:
            if tol >= 1e-12:
                raise
            tol *= 2


def _check(scene, t, samples, every):
    """Exact errors against single evaluations at REF_TOL, and whether every bound held."""
    pick = np.unique(np.concatenate([np.arange(0, len(t), every), [len(t) - 1]]))
    sol = reference_solution(scene)
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
    cpu, s = timed(lambda: solve(scene, tol=1e-12).at(t), repeats)
    err, mb, held, pick, ref_q = _check(scene, t, s, every)
    dop = {}
    for key, fn in (('dop853', peers.scipy_ivp), ('lean', peers.scipy_ivp_lean)):
        reps = repeats if t[-1] <= 100.0 else 1          # long DOP853 runs: once
        try:
            c, q = timed(lambda: fn(scene, t, 'DOP853', 1e-12, budget=budget), reps)
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


def _latencies(fn, times):
    out = np.empty(len(times))
    clock = time.perf_counter
    for i, x in enumerate(times):
        c = clock()
        fn(x)
        out[i] = clock() - c
    return 1e6 * out


def ratios(quick, log, budget=600.0):
    """Measure the issue's ratios against scipy DOP853 at rtol 1e-12, all in one run.

    (a) a 100 Hz stream over 60 s per scene; (b) 1e6 samples over 1e4 s (spacecraft);
    (c) one query at T = 1e3 s, ``solve`` included; (d) random-access scalar ``at(t)``,
    t uniform in [0, 60] s, after ``solve``; (e) the node's tight loop: successive 100 Hz
    scalar calls; (f) the peak memory of the 1e6-sample batch (tracemalloc) as a multiple
    of its output arrays. DOP853 runs in two forms: the peers' array right-hand side, and
    a lean one in plain floats (the same equations, about 4x cheaper per step).
    """
    scenes = ratio_scenes()
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
    rows.append(_versus_dop853(f'{n_big:.0e} samples', 'spacecraft', SPACECRAFT, t, 1, budget,
                               log, every=max(1, n_big // 200)))
    sol = solve(SPACECRAFT, tol=1e-12)
    sol.at(t[:10])
    tracemalloc.start()
    try:
        s = sol.at(t)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    size = s.t.nbytes + s.quaternion.nbytes + s.omega.nbytes + s.error_bound.nbytes
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
        lat = _latencies(lambda x: sol.at(x), rng.uniform(0.0, horizon, 200 if quick else 3000))
        rows.append(_row(part='scalar at(t) random', scene=name, samples=len(lat),
                         horizon_s=horizon, mean_us=float(lat.mean()),
                         p50_us=float(np.percentile(lat, 50)),
                         p99_us=float(np.percentile(lat, 99))))
        sol = solve(scene, tol=1e-12)
        tick = _latencies(lambda x: sol.at(x), [float(x) for x in t_stream])
        rows.append(_row(part='tick 100 Hz tight loop', scene=name, samples=len(tick),
                         horizon_s=horizon, mean_us=float(tick.mean()),
                         p50_us=float(np.percentile(tick, 50)),
                         p99_us=float(np.percentile(tick, 99))))
        log(f'scalar at(t)           {name:18s} random p50 {rows[-2]["p50_us"]:6.1f} us p99 '
            f'{rows[-2]["p99_us"]:7.1f} us | 100 Hz tick mean {rows[-1]["mean_us"]:6.1f} us '
            f'p50 {rows[-1]["p50_us"]:6.1f} us p99 {rows[-1]["p99_us"]:7.1f} us')
    return rows


def ratios_chart(rows, foot, out):
    """Bar chart of the speed-ups over DOP853 (both forms), per part and scene."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from rigidrot_ros.bench.charts import _finish
    timed = [r for r in rows if math.isfinite(r['speedup_vs_dop853'])]
    if not timed:
        return []
    parts = list(dict.fromkeys(r['part'] for r in timed))
    fig, axes = plt.subplots(1, len(parts), figsize=(4.6 * len(parts), 4.4), squeeze=False)
    for ax, part in zip(axes[0], parts):
        sel = [r for r in timed if r['part'] == part]
        x = np.arange(len(sel))
        ax.bar(x - 0.2, [r['speedup_vs_dop853'] for r in sel], 0.4,
               label='vs DOP853 (peers.scipy_ivp)')
        ax.bar(x + 0.2, [r['speedup_vs_dop853_lean'] for r in sel], 0.4,
               label='vs DOP853, plain-float RHS')
        ax.axhline(10.0, color='gray', lw=0.8, ls='--')
        ax.set_yscale('log')
        ax.set_xticks(x)
        ax.set_xticklabels([r['scene'] for r in sel], rotation=35, ha='right', fontsize=7)
        ax.set_title(f'{part} ({sel[0]["samples"]} samples to {sel[0]["horizon_s"]:g} s)',
                     fontsize=8)
        ax.set_ylabel('DOP853 CPU time / exact CPU time (solve included)', fontsize=7)
    axes[0][0].legend(fontsize=7)
    fig.suptitle('exact solution (tol 1e-12) against scipy DOP853 (rtol = atol = 1e-12)',
                 fontsize=9)
    fig.tight_layout(rect=(0, 0.03, 1, 0.95))
    return _finish(fig, foot, out, 'ratios')


def write_csv(path, rows, foot):
    """Write ``rows`` (dicts with the same keys) to ``path``, the footer as a last comment."""
    if not rows:
        return
    with open(path, 'w', newline='', encoding='utf-8') as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
        fh.write('# ' + json.dumps(foot) + '\n')


_NEEDS = {'wp': ('scipy',), 'horizon': ('scipy',), 'stability': ('scipy',),
          'crosscheck': (), 'envelope': (), 'ratios': ('scipy',), 'soak': (),
          'triaxial': ('scipy',)}


def _missing(modules):
    """Return the names among ``modules`` that cannot be imported."""
    out = []
    for name in modules:
        if name == 'scipy' and _PEERS_MISSING is not None:
            out.append(name)
            continue
        try:
            __import__(name)
        except ImportError:
            out.append(name)
    return out


def _install_hint(missing):
    return (f'rigidrot_bench needs {" and ".join(missing)}, which a plain `pip install .` '
            "does not install: pip install -e '.[bench]' in the checkout (or pip install "
            f'{" ".join(missing)})')


def charts_only(path, out, log):
    """Redraw every chart from a ``results.json`` into ``out``; return the exit status."""
    try:
        with open(path, encoding='utf-8') as fh:
            results = json.load(fh)
    except OSError as exc:
        print(f'rigidrot_bench: --charts-from {path}: {exc.strerror or exc}', file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f'rigidrot_bench: --charts-from {path}: not JSON ({exc})', file=sys.stderr)
        return 2
    if not isinstance(results, dict) or not isinstance(results.get('footer'), dict):
        print(f'rigidrot_bench: --charts-from {path}: not a rigidrot_bench results.json '
              '(no footer)', file=sys.stderr)
        return 2
    os.makedirs(out, exist_ok=True)
    from rigidrot_ros.bench import charts
    paths = charts.draw(results, out)
    if not paths:
        print(f'rigidrot_bench: --charts-from {path}: no chartable results in it',
              file=sys.stderr)
        return 2
    for p in paths:
        log(f'wrote {p}')
    return 0


def main(argv=None):
    """Entry point of ``rigidrot_bench``."""
    ap = OneLineParser(prog='rigidrot_bench', description=__doc__.splitlines()[0])
    ap.add_argument('--out', default='bench_out', help='directory for charts and data')
    ap.add_argument('--quick', action='store_true', help='a smoke run, under a minute')
    ap.add_argument('--only', choices=list(_NEEDS), action='append',
                    help='run only this part (repeatable; default: wp, horizon, stability); '
                         'results merge into an existing OUT/results.json')
    ap.add_argument('--soak-minutes', type=float, default=10.0, metavar='MIN',
                    help='length of the soak part (--only soak), minutes (default 10)')
    ap.add_argument('--charts-from', metavar='RESULTS_JSON',
                    help='only redraw the charts from a results.json into --out '
                         '(needs matplotlib, runs nothing)')
    opts = ap.parse_args(argv)
    t0 = time.monotonic()

    def log(line):
        print(f'[{time.monotonic() - t0:7.1f} s] {line}', flush=True)

    if not (opts.soak_minutes > 0 and math.isfinite(opts.soak_minutes)):
        ap.error(f'argument --soak-minutes: must be a positive number, got {opts.soak_minutes}')
    if opts.charts_from is not None:
        missing = _missing(['matplotlib'])
        if missing:
            print(f'rigidrot_bench: {_install_hint(missing)}', file=sys.stderr)
            return 2
        return charts_only(opts.charts_from, opts.out, log)
    parts = opts.only or ['wp', 'horizon', 'stability']
    missing = _missing(sorted({m for p in parts for m in _NEEDS[p]} | {'matplotlib'}))
    if missing:
        print(f'rigidrot_bench: {_install_hint(missing)}', file=sys.stderr)
        return 2
    try:
        os.makedirs(opts.out, exist_ok=True)
    except OSError as exc:
        print(f'rigidrot_bench: --out {opts.out}: {exc.strerror or exc}', file=sys.stderr)
        return 2
    repeats = 1 if opts.quick else 3
    budget = 1.0 if opts.quick else 60.0
    foot = footer()

    results = {}
    merged = os.path.join(opts.out, 'results.json')
    if os.path.exists(merged):            # a partial run (--only) adds to an earlier one
        try:
            with open(merged, encoding='utf-8') as fh:
                results = json.load(fh)
        except ValueError as exc:
            print(f'rigidrot_bench: {merged} is not JSON ({exc}); move it away or choose '
                  'another --out', file=sys.stderr)
            return 2
    # 'footer' dates the charts of wp, horizon and stability; a part run on its own
    # (crosscheck, ratios, triaxial, ...) keeps its own footer beside theirs
    if set(parts) & {'wp', 'horizon', 'stability'} or 'footer' not in results:
        results['footer'] = foot
    for part in set(parts) - {'wp', 'horizon', 'stability'}:
        results[f'footer_{part}_run'] = foot
    if 'wp' in parts:
        results['work_precision'] = work_precision(opts.quick, repeats, budget, log)
        write_csv(os.path.join(opts.out, 'work_precision.csv'), results['work_precision'],
                  foot)
    if 'horizon' in parts:
        results['horizon'] = horizon_scaling(opts.quick, min(budget, 30.0), log)
        write_csv(os.path.join(opts.out, 'horizon.csv'), results['horizon'], foot)
    if 'stability' in parts:
        results['stability'] = stability_map(opts.quick, 20.0 if not opts.quick else 1.0, log)
        write_csv(os.path.join(opts.out, 'stability.csv'), results['stability'], foot)
    if 'crosscheck' in parts:
        if not results.get('stability'):
            print(f'rigidrot_bench: --only crosscheck needs the stability map in {merged} '
                  '(run --only stability first)', file=sys.stderr)
            return 2
        from rigidrot_ros.bench import crosscheck
        results['stability_crosscheck'] = crosscheck.stability_crosscheck(
            results['stability'], log)
        write_csv(os.path.join(opts.out, 'stability_crosscheck.csv'),
                  results['stability_crosscheck'], foot)
    if 'ratios' in parts:
        results['ratios'] = ratios(opts.quick, log)
        write_csv(os.path.join(opts.out, 'ratios.csv'), results['ratios'], foot)
        for path in ratios_chart(results['ratios'], foot, opts.out):
            log(f'wrote {path}')
    if 'envelope' in parts:
        results['envelope'] = envelope(opts.quick, log)
        write_csv(os.path.join(opts.out, 'envelope.csv'), results['envelope'], foot)
    if 'soak' in parts:
        from rigidrot_ros.bench import soak
        results['soak'] = soak.soak(opts.soak_minutes, log)
        write_csv(os.path.join(opts.out, 'soak.csv'),
                  [{'t_s': t, 'rss_mb': m} for t, m in results['soak']['samples']], foot)
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
    soak_failed = 'soak' in parts and results['soak']['exit_code'] != 0
    if soak_failed:
        log(f'SOAK: attitude_node exited with status {results["soak"]["exit_code"]}: '
            f'{results["soak"]["stderr_tail"][-500:]}')
    print(json.dumps(foot))
    return 1 if violated or soak_failed else 0


if __name__ == '__main__':
    sys.exit(main())
