"""The leaderboard's Markdown: each cell's leader, its table, what tuning changed.

:func:`render_md` is the part's table (``leaderboard.md``), from the results alone. A
cell's leader (:func:`leader`) is the AHRS filter (gyro + accelerometer + magnetometer) of
lowest tuned total RMSE, when it is :data:`TIE` below the runner-up and lower on
significantly more held-out runs (:func:`sign_test`); else the cell has no clear leader.
"""

import math

import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.bench.leaderboard_cells import GRADES, MOTIONS, NAME

#: A cell has a leader when its RMSE is this much below the runner-up's and it is lower on
#: significantly more held-out runs (two-sided sign test, p below SIGN_P); else a tie.
TIE = 0.02
SIGN_P = 0.05


def _ahrs_names(cell):
    return [n for n, f in cell['filters'].items() if f['sensors'] == 'gyro + acc + mag']


def leader(cell, key='total'):
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
        lead = leader(c)
        if lead is None:
            continue
        name, rm, second, rm2 = lead
        fl = c['filters']
        k, n = _wins(c, name, second) if second else (0, 0)
        inc, hed = leader(c, 'incl'), leader(c, 'head')
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
    lead = leader(c)
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
        f'process{"es" if lb["processes"] != 1 else ""} ({lb["cpu_s"]:.0f} CPU s; load average '
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
