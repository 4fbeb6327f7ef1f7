"""Benchmark rows for the torque-free triaxial body (``rigidrot_bench --only triaxial``).

- work-precision: one query at T = 60 s and a 100 Hz stream over 60 s, the exact model
  against DOP853 / RK45 / RK4 / RKMK4 across their knobs;
- horizon scaling: CPU time of one query at T = 1 ... 1e5 s at 1e-9 and 1e-12 rad;
- stability map across the separatrix: bodies at signed distance delta from it (h
  circulating about the largest axis for delta < 0, the smallest for delta > 0, on it for
  delta = 0) over horizons T;
- per-sample cost: scalar calls and batches, next to the axisymmetric closed form
  (Theorem 5) measured in the same run.

Reference: :func:`taylor_reference`, a 42-digit Taylor-series integration of Euler's
equations and the quaternion kinematics in the time domain (no elliptic function); where
it would take too long (streams, T > 1e3 s) the exact model itself, whose agreement with
that integration is shown by the query rows and by ``test/core/test_core_triaxial.py``.
"""

import math
import os
import sys
import time

import mpmath
import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene, solve

__all__ = ['taylor_reference', 'SCENE', 'run', 'draw', 'draw_charts', 'render_md']

NAME = 'triaxial'
NEEDS = ('scipy',)
#: The code this part measures (``rigidrot_bench --stale``): modules, with what they import.
MEASURES = ('rigidrot_ros.core',)
KEYS = ('triaxial',)

#: The work-precision and horizon scene: a generic triaxial body, m = 0.37.
SCENE = Scene(inertia=(1.0, 2.0, 3.0), omega0=(0.3, -0.2, 0.5), attitude0=(0.1, 0.2, 0.3, 0.9))
#: An axisymmetric body with the same rates (Theorem 5), timed beside it.
AXISYMMETRIC = Scene(inertia=(2.0, 2.0, 3.0), omega0=(0.3, -0.2, 0.5),
                     attitude0=(0.1, 0.2, 0.3, 0.9))
_PREC = 140


def _fx(x):
    return int(mpmath.nint(mpmath.ldexp(mpmath.mpf(x), _PREC)))


def taylor_reference(scene, times, deg=30):
    """Integrate ``I w' = -w x I w``, ``q' = q ⊗ (w, 0) / 2`` by Taylor series at 42 digits.

    Fixed-point integers scaled by 2^140; the step keeps ``h |w|max <= 1/4``, so the series
    of degree ``deg`` is truncated far below 1e-25 per step, and the time is carried
    exactly (each sample is reached by a final partial step). Shares no formula with the
    elliptic solution. Returns (omega_B, q_NB (x, y, z, w)) at ``times`` (ascending, >= 0).
    """
    prec = _PREC
    one = 1 << prec
    inertia = scene.inertia
    # w_i' = c_i w_j w_k, (i, j, k) cyclic, c_i = (I_j - I_k) / I_i
    cc = [_fx((mpmath.mpf(inertia[(i + 1) % 3]) - inertia[(i + 2) % 3]) / inertia[i])
          for i in range(3)]
    w = [_fx(v) for v in scene.omega0]
    q = [_fx(v) for v in scene.attitude0]
    wmax = math.sqrt(sum(i * v * v for i, v in zip(inertia, scene.omega0)) / min(inertia))
    hmax = _fx(0.25 / max(wmax, 1e-9))

    def series(w0, q0):
        ws = [[v] for v in w0]
        qs = [[v] for v in q0]
        for k in range(deg):
            def cv(u, v):
                return sum(u[j] * v[k - j] for j in range(k + 1))
            new = [((cc[i] * (cv(ws[(i + 1) % 3], ws[(i + 2) % 3]) >> prec)) >> prec) // (k + 1)
                   for i in range(3)]
            x, y, z, s = qs
            wx, wy, wz = ws
            dq = [cv(s, wx) + cv(y, wz) - cv(z, wy), cv(s, wy) - cv(x, wz) + cv(z, wx),
                  cv(s, wz) + cv(x, wy) - cv(y, wx), -cv(x, wx) - cv(y, wy) - cv(z, wz)]
            for i in range(3):
                ws[i].append(new[i])
            for i in range(4):
                qs[i].append((dq[i] >> (prec + 1)) // (k + 1))
        return ws, qs

    def advance(ser, hf):
        out = []
        for comp in ser:
            acc = 0
            for a in reversed(comp):
                acc = ((acc * hf) >> prec) + a
            out.append(acc)
        return out

    t = 0
    omegas, quats = [], []
    for target in times:
        tf = _fx(target)
        while tf > t:
            h = min(hmax, tf - t)
            ws, qs = series(w, q)
            w, q = advance(ws, h), advance(qs, h)
            t += h
        omegas.append([v / one for v in w])
        quats.append([v / one for v in q])
    return np.array(omegas), np.array(quats)


def _peer_methods(quick):
    return common.peer_sweep([1e-6, 1e-9, 1e-12] if quick else [1e-5, 1e-7, 1e-9, 1e-11, 1e-13],
                             [0.05, 0.01] if quick else [0.1, 0.05, 0.02, 0.01, 0.005])


def _exact(sc, t, b=None):
    return solve(sc, tol=1e-12).at(t).quaternion


def work_precision(quick, repeats, budget, log):
    """One query at T and a 100 Hz stream over T, for SCENE."""
    from rigidrot_ros.bench import peers
    horizon = 5.0 if quick else 60.0
    rows = []
    q_ref_query = taylor_reference(SCENE, [horizon])[1]
    stream = np.arange(1, int(round(horizon * 100)) + 1) * 0.01
    sol = solve(SCENE)
    q_ref_stream = sol.at(stream).quaternion
    # the exact stream's own error, against the 42-digit integration every 1 s
    sub = stream[99::100]
    q_sub = taylor_reference(SCENE, sub)[1]
    own_stream = float(quat.angle_between(sol.at(sub).quaternion, q_sub).max())
    for workload, t_eval, ref in (('query', np.array([horizon]), q_ref_query),
                                  ('stream', stream, q_ref_stream)):
        methods = [('exact (triaxial)', 'tol', 1e-12, _exact)] + _peer_methods(quick)
        for name, knob, value, fn in methods:
            try:
                cpu, q = common.timed(lambda: fn(SCENE, t_eval, budget), repeats)
                err = float(quat.angle_between(q, ref).max())
                if name.startswith('exact') and workload == 'stream':
                    err = own_stream                # not against itself: see above
                status = 'ok' if np.isfinite(err) else 'nan'
            except peers.TimeBudget:
                cpu, err, status = budget, math.nan, 'time-out'
            if name.startswith('exact') and status == 'ok' and err > value:
                status = 'claim violated'
            rows.append({'workload': workload, 'method': name, 'knob': knob, 'value': value,
                         'cpu_s': cpu, 'error_rad': err, 'samples': len(t_eval),
                         'horizon_s': horizon, 'status': status})
            log(f'triaxial {workload:6s} {name:16s} {knob}={value:<8g} cpu {cpu:9.4f} s '
                f'err {err:9.2e} {status}')
    return rows


def horizon_scaling(quick, budget, log):
    """CPU time of one query at T meeting 1e-9 and 1e-12 rad, cheapest knob per method."""
    horizons = [1.0, 10.0] if quick else [1.0, 10.0, 100.0, 1e3, 1e4, 1e5]
    ref_max = 100.0 if quick else 1e3
    refs = dict(zip([T for T in horizons if T <= ref_max],
                    taylor_reference(SCENE, [T for T in horizons if T <= ref_max])[1]))

    def reference(T):
        if T in refs:
            return refs[T], {'reference': '42-digit Taylor'}
        return (solve(SCENE).at(np.array([T])).quaternion[0],
                {'reference': 'exact (bound <= 1e-13)'})

    methods = [(name, knob, value, lambda t, b, fn=fn: fn(SCENE, t, b)) for
               name, knob, value, fn in [('exact (triaxial)', 'tol', 1e-12, _exact)] +
               _peer_methods(quick)]
    names = ['exact (triaxial)'] + sorted({m for m, *_ in _peer_methods(quick)})
    return common.horizon_rows(
        horizons, methods, names, reference, budget, log,
        lambda name, knob, value, T, target: T >= 1e3 and knob == 'h',  # 1e5+ Python steps
        label='triaxial ')


def separatrix_scene(delta):
    """I = (3, 4, 6), omega0 = (2 z (1 + delta), 1, z): exactly on the separatrix at 0."""
    z = 0.05
    return Scene(inertia=(3.0, 4.0, 6.0), omega0=(2 * z * (1 + delta), 1.0, z),
                 attitude0=(0.1, 0.2, 0.3, 0.9))


def stability_map(quick, budget, log):
    """Status of each method over the signed distance to the separatrix x horizon T."""
    from rigidrot_ros.bench import peers
    deltas = [-1e-3, 0.0, 1e-9] if quick else \
        [-1e-2, -1e-5, -1e-8, -1e-11, -1e-14, 0.0, 1e-14, 1e-11, 1e-8, 1e-5, 1e-2]
    ts = [1.0, 10.0] if quick else [1.0, 10.0, 100.0, 1e3]
    methods = {
        'exact (triaxial), tol 1e-12': _exact,
        'DOP853, rtol 1e-13': lambda sc, t, b: peers.scipy_ivp(sc, t, 'DOP853', 1e-13,
                                                               budget=b),
        'RKMK4, h = 0.01 s': lambda sc, t, b: peers.rkmk4(sc, t, 0.01, budget=b),
    }
    cells = []
    for delta in deltas:
        scene = separatrix_scene(delta)
        c = time.process_time()
        refs = taylor_reference(scene, ts)[1]
        log(f'separatrix delta={delta:g}: reference in {time.process_time() - c:.1f} s')
        # on the separatrix itself a perturbation grows like e^(lam_h t), lam_h the saddle's
        # rate: no fixed-precision integration follows the motion once that exceeds
        # 1e16 (its truncation is ~1e-30 a step); past that the cell has no reference
        i1, i2, i3 = scene.inertia
        lam_h = abs(scene.omega0[1]) * math.sqrt((i2 - i1) * (i3 - i2) / (i1 * i3))
        t_trust = math.inf if delta != 0 else math.log(1e16) / lam_h
        timed_out = set()
        for T, ref in zip(ts, refs):
            if T > t_trust:
                for name in methods:
                    cells.append({'delta': delta, 'T_s': T, 'method': name,
                                  'status': 'no reference', 'error_rad': math.nan,
                                  'cpu_s': math.nan})
                log(f'delta={delta:<8g} T={T:<8g} no reference (e^(lam t) > 1e16)')
                continue
            for name, fn in methods.items():
                if name.startswith('RKMK4') and T > 100.0:
                    continue                      # 1e5 Python steps: not run (blank)
                if name in timed_out:
                    cells.append({'delta': delta, 'T_s': T, 'method': name,
                                  'status': 'fail: time-out', 'error_rad': math.nan,
                                  'cpu_s': math.nan})
                    continue
                cpu, err, status = common.run_method(
                    fn, scene, np.array([T]), budget,
                    lambda q, ref=ref: float(quat.angle_between(q[0], ref)))
                if status == 'fail: time-out':
                    timed_out.add(name)
                cells.append({'delta': delta, 'T_s': T, 'method': name, 'status': status,
                              'error_rad': err, 'cpu_s': cpu})
                log(f'delta={delta:<8g} T={T:<8g} {name:28s} {status:16s} err {err:9.2e} '
                    f'cpu {cpu:8.3f} s')
    return cells


def cost(quick, log):
    """Per-sample cost, scalar and batch: triaxial beside the axisymmetric closed form."""
    rows = []
    n_scalar = 200 if quick else 2000
    n_batch = 1000 if quick else 100000
    for name, scene in (('torque-free-triaxial', SCENE),
                        ('torque-free-axisymmetric', AXISYMMETRIC)):
        c = time.process_time()
        sol = solve(scene)
        setup = time.process_time() - c
        ts = 12.3 + 0.01 * np.arange(n_scalar)
        tl = ts.tolist()
        c = time.process_time()
        for t in tl:
            sol.at(t)
        scalar = (time.process_time() - c) / n_scalar
        tb = 12.3 + 0.01 * np.arange(n_batch)
        c = time.process_time()
        sol.at(tb)
        batch = (time.process_time() - c) / n_batch
        far = 1e5 + ts
        c = time.process_time()
        for t in far.tolist():
            sol.at(t)
        scalar_far = (time.process_time() - c) / n_scalar
        rows.append({'model': name, 'method': sol.method, 'setup_s': setup,
                     'scalar_us': 1e6 * scalar, 'scalar_at_1e5_s_us': 1e6 * scalar_far,
                     'batch_us_per_sample': 1e6 * batch, 'batch_size': n_batch})
        log(f'cost {name:26s} setup {setup * 1e3:7.1f} ms scalar {1e6 * scalar:7.1f} us '
            f'(at 1e5 s {1e6 * scalar_far:7.1f} us) batch {1e6 * batch:7.3f} us/sample')
    return rows


def run(quick=False, log=print):
    """Run every triaxial part; return ``{'triaxial': {cost, work_precision, horizon, ...}}``."""
    repeats = 1 if quick else 3
    budget = 1.0 if quick else 20.0
    return {'triaxial': {
        'cost': cost(quick, log),
        'work_precision': work_precision(quick, repeats, budget, log),
        'horizon': horizon_scaling(quick, budget, log),
        'stability': stability_map(quick, 10.0 if not quick else 1.0, log),
    }}


def write(res, out, foot, log):
    """Write the CSVs, ``triaxial_results.json`` and the charts into ``out``."""
    res = res['triaxial']
    for key, rows in res.items():
        common.write_csv(os.path.join(out, f'triaxial_{key}.csv'), rows, foot)
    common.write_json(os.path.join(out, 'triaxial_results.json'), dict(res, footer=foot))
    for path in draw_charts(res, out, foot):
        log(f'wrote {path}')


def draw_charts(res, out, foot):
    """Chart the triaxial rows (PNG and SVG); return the written paths."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from rigidrot_ros.bench.charts import _finish, MARKERS, STATUS_COLORS
    markers = dict(MARKERS, **{'exact (triaxial)': '*'})
    paths = []
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    wp = res.get('work_precision', [])
    for ax, workload in zip(axes[:2], ('query', 'stream')):
        rows = [r for r in wp if r['workload'] == workload]
        for method in dict.fromkeys(r['method'] for r in rows):
            pts = sorted((max(r['error_rad'], 1e-16), r['cpu_s']) for r in rows
                         if r['method'] == method and r['status'] in ('ok', 'claim violated')
                         and math.isfinite(r['error_rad']))
            if pts:
                ax.loglog(*zip(*pts), marker=markers.get(method, 'x'), ms=6, lw=1,
                          label=method)
        if rows:
            title = (f'one query at T = {rows[0]["horizon_s"]:g} s' if workload == 'query'
                     else f'100 Hz stream, {rows[0]["samples"]} samples')
            ax.set_title(title, fontsize=9)
        ax.set_xlabel('max attitude error [rad]')
        ax.set_ylabel('CPU time [s] (median)')
        ax.invert_xaxis()
        ax.grid(True, which='both', alpha=0.25)
    axes[0].legend(fontsize=7)
    ax = axes[2]
    hz = res.get('horizon', [])
    for target, ls in ((1e-9, '--'), (1e-12, '-')):
        for method in dict.fromkeys(r['method'] for r in hz):
            pts = sorted((r['T_s'], r['cpu_s']) for r in hz if r['method'] == method and
                         r['target_rad'] == target and r['status'] == 'ok')
            if pts:
                ax.loglog(*zip(*pts), ls=ls, marker=markers.get(method, 'x'), ms=5, lw=1,
                          label=f'{method}, {target:g} rad')
    ax.set_title('horizon: one query at T (cheapest setting that meets the target)',
                 fontsize=9)
    ax.set_xlabel('horizon T [s]')
    ax.set_ylabel('CPU time [s]')
    ax.grid(True, which='both', alpha=0.25)
    ax.legend(fontsize=6)
    fig.suptitle('Torque-free triaxial body I = (1, 2, 3), omega0 = (0.3, -0.2, 0.5) rad/s '
                 '(reference: 42-digit Taylor integration)', fontsize=10)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    paths += _finish(fig, foot, out, 'triaxial_work_precision')
    st = res.get('stability', [])
    if st:
        methods = list(dict.fromkeys(c['method'] for c in st))
        deltas = sorted({c['delta'] for c in st})
        ts = sorted({c['T_s'] for c in st})
        fig, axes = plt.subplots(1, len(methods), figsize=(3.6 * len(methods), 4.2),
                                 squeeze=False)
        for ax, method in zip(axes[0], methods):
            grid = np.ones((len(deltas), len(ts), 3))
            for c in st:
                if c['method'] == method:
                    col = STATUS_COLORS.get(c['status'], '#542788')
                    grid[deltas.index(c['delta']), ts.index(c['T_s'])] = \
                        matplotlib.colors.to_rgb(col)
            ax.imshow(grid, origin='lower', aspect='auto')
            ax.set_xticks(range(len(ts)), [f'{t:g}' for t in ts], fontsize=7)
            ax.set_yticks(range(len(deltas)), [f'{d:g}' for d in deltas], fontsize=7)
            ax.set_xlabel('horizon T [s]', fontsize=8)
            ax.set_ylabel('distance to the separatrix delta', fontsize=8)
            ax.set_title(method, fontsize=8)
        handles = [matplotlib.patches.Patch(color=v, label=k) for k, v in
                   STATUS_COLORS.items()]
        handles.append(matplotlib.patches.Patch(color='#542788', label='fail: exception'))
        fig.legend(handles=handles, loc='lower center', ncol=4, fontsize=7)
        fig.suptitle('Across the separatrix: I = (3, 4, 6), omega0 = (0.1 (1 + delta), 1, '
                     '0.05) rad/s; delta < 0 about the largest axis, > 0 the smallest '
                     '(blank: not run)', fontsize=9)
        fig.tight_layout(rect=(0, 0.1, 1, 1))
        paths += _finish(fig, foot, out, 'triaxial_stability')
    return paths


def draw(results, out):
    """Draw the triaxial charts from merged results (``'triaxial'``); the written paths."""
    if not results.get('triaxial'):
        return []
    return draw_charts(results['triaxial'], out, common.part_footer(results, NAME))


def render_md(results):
    """Per-sample cost, the horizon table and the separatrix map's counts, from the results."""
    from rigidrot_ros.bench import horizon, stability
    res = results.get('triaxial')
    if not res:
        return None
    body = ''
    if res.get('cost'):
        body += common.md_table(
            ['model', 'method', 'set-up [ms]', 'scalar call [µs]', 'at t = 1e5 s [µs]',
             'batch [µs a sample]'],
            [[r['model'], r['method'], common.fmt(1e3 * r['setup_s']),
              common.fmt(r['scalar_us']), common.fmt(r['scalar_at_1e5_s_us']),
              f'{common.fmt(r["batch_us_per_sample"])} ({r["batch_size"]} samples)']
             for r in res['cost']]) + '\n'
    if res.get('work_precision'):
        body += common.md_table(
            ['workload', 'method', 'knob', 'CPU [ms]', 'error [rad]', 'status'],
            [[r['workload'], r['method'], f'{r["knob"]} {common.fmt(r["value"])}',
              common.fmt(1e3 * r['cpu_s']), common.fmt(r['error_rad']), r['status']]
             for r in res['work_precision']]) + '\n'
    if res.get('horizon'):
        body += ('CPU time [ms] of one query at T at the cheapest setting meeting 1e-9 / '
                 '1e-12 rad (— not reached):\n\n' + common.md_bullets(horizon.summary(
                     res['horizon'])) + horizon.table(res['horizon']) + '\n')
    if res.get('stability'):
        body += ('Across the separatrix, cells per status:\n\n'
                 + stability.status_counts(res['stability'], 'delta x horizons'))
    return common.md_fragment(
        'Torque-free triaxial body: I = (1, 2, 3), omega0 = (0.3, -0.2, 0.5) rad/s '
        '(reference: 42-digit Taylor integration)', common.part_footer(results, NAME),
        body)


def main(argv=None):
    """``python -m rigidrot_ros.bench.triaxial``: this part alone."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
