"""What every benchmark part shares: timing, the footer, references, results files, tables.

A part (:mod:`rigidrot_ros.bench.registry`) imports what it needs from here and never the
command (:mod:`rigidrot_ros.bench.run`). Nothing here imports scipy at module level: the
peers (:mod:`rigidrot_ros.bench.peers`) are imported by the functions that run them, so the
parts without peers run without the ``bench`` extra.
"""

import argparse
import csv
import datetime
import json
import math
import os
import platform
import subprocess
import time
import tracemalloc

import mpmath
import numpy as np

from rigidrot_ros import __version__
from rigidrot_ros.core import PrecisionError, Scene, solve
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.runtime.processes import script, stop  # noqa: F401 - the parts' names

#: The reference's tol, rad: far tighter than anything measured (certified by Arb).
REF_TOL = 2e-14

#: The issue's spacecraft scene: axial torque 2e-4 N m on I = (2, 2, 3) (delta = 325,
#: the certified Taylor path).
SPACECRAFT = Scene(inertia=(2.0, 2.0, 3.0), torque=(0.0, 0.0, 2e-4), omega0=(0.3, -0.2, 0.5))


class MissingInput(RuntimeError):
    """A part needs results of another part that the results file does not hold.

    Parameters
    ----------
    what : str
        What is missing, in words ('the stability map').
    part : str
        The part that makes it.
    """

    def __init__(self, what, part):
        super().__init__(f'needs {what} (run --only {part} first)')
        self.what, self.part = what, part


# -- the machine --------------------------------------------------------------------------

def _cpu():
    try:
        with open('/proc/cpuinfo', encoding='utf-8') as fh:
            for line in fh:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown CPU'


def _version(module):
    try:
        return __import__(module).__version__
    except ImportError:
        return 'absent'


#: The checkout the package runs from (a git work tree, or not: an installed package).
CHECKOUT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _git(*args, cwd=CHECKOUT):
    """Return git's output (stripped) for ``args`` in ``cwd``, or None where git fails."""
    try:
        out = subprocess.run(['git', *args], cwd=cwd, capture_output=True, text=True,
                             timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def measured_commit(cwd=CHECKOUT):
    """Return ``{'commit', 'changes'}`` of the code a run measures, or ``{}`` outside git.

    ``commit``: the checkout's HEAD (40 hex digits); ``changes``: whether ``rigidrot_ros/``
    differed from it (uncommitted changes: the run measured code no commit holds).
    """
    top = _git('rev-parse', '--show-toplevel', cwd=cwd)
    if not top or os.path.realpath(top) != os.path.realpath(cwd):
        return {}           # not a checkout of its own (an installed copy, maybe in a venv)
    head = _git('rev-parse', 'HEAD', cwd=cwd)
    if not head:
        return {}
    status = _git('status', '--porcelain', '--', 'rigidrot_ros', cwd=cwd)
    return {'commit': head, 'changes': bool(status)}


def footer():
    """Versions, CPU, date and the commit measured: printed with every result."""
    return {
        'rigidrot_ros': __version__, 'python': platform.python_version(),
        'numpy': np.__version__, 'scipy': _version('scipy'), 'mpmath': mpmath.__version__,
        'python-flint': _version('flint'), 'cpu': _cpu(), 'cores': os.cpu_count(),
        'machine': platform.node(),
        'date': datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC'),
        **measured_commit(),
    }


def commit_text(foot):
    """Return how a table names the commit it measured: ``commit 0123456789ab`` and so on.

    A footer written before runs recorded their commit carries the commit that added the
    run to the repository instead, marked ``commit_backfilled`` (the code measured was that
    commit's or older).
    """
    commit = foot.get('commit')
    if not commit:
        return 'commit not recorded'
    if foot.get('commit_backfilled'):
        return f'added at commit {commit[:12]}'
    text = f'commit {commit[:12]}'
    if foot.get('changes'):
        text += ' with uncommitted changes'
    return text


# -- timing -------------------------------------------------------------------------------

def timed(fn, repeats=1):
    """Call ``fn`` ``repeats`` times; return (median CPU seconds, its last value)."""
    times, out = [], None
    for _ in range(repeats):
        c = time.process_time()
        out = fn()
        times.append(time.process_time() - c)
    return float(np.median(times)), out


def latencies(fn, times):
    """Return the wall-clock latency (us) of each call on ``times``, in order."""
    out = np.empty(len(times))
    clock = time.perf_counter
    for i, x in enumerate(times):
        c = clock()
        fn(x)
        out[i] = clock() - c
    return 1e6 * out


def percentiles(us):
    """Return ``{'mean_us', 'p50_us', 'p99_us'}`` of latencies ``us`` (floats)."""
    us = np.asarray(us)
    return {'mean_us': float(us.mean()), 'p50_us': float(np.percentile(us, 50)),
            'p99_us': float(np.percentile(us, 99))}


def run_method(fn, scene, t_eval, budget, error):
    """Run one method once: return (CPU seconds, error in rad, status of the cell).

    ``fn(scene, t_eval, budget)`` returns quaternions; ``error(q)`` their angle to the
    reference in rad, or ``error`` is None where there is no reference (status 'no
    reference', error NaN). The status is 'meets 1e-12', 'meets 1e-9', 'loses accuracy',
    'fail: NaN', 'fail: time-out' (the budget ran out) or 'fail: <exception>'.
    """
    from rigidrot_ros.bench import peers
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


# -- the peers, swept ---------------------------------------------------------------------

def peer_sweep(rtols, steps, magnus_omega=None):
    """List ``(method, knob, value, fn(scene, t, budget) -> q)`` over the peers' knobs.

    DOP853 and RK45 at each rtol (RK45 not below 1e-11: minutes), RK4 and RKMK4 at each
    step ``h``, and Magnus-4 at each step where ``magnus_omega`` (the exact body rate,
    ``t -> omega_BN_B``) is given.
    """
    from rigidrot_ros.bench import peers
    out = []
    for rt in rtols:
        for m in ('DOP853', 'RK45'):
            if m == 'RK45' and rt < 1e-11:
                continue                       # RK45 at these tolerances takes minutes
            out.append((m, 'rtol', rt, lambda sc, t, b, m=m, rt=rt: peers.scipy_ivp(
                sc, t, m, rt, budget=b)))
    for h in steps:
        out.append(('RK4', 'h', h, lambda sc, t, b, h=h: peers.rk4(sc, t, h, budget=b)))
        out.append(('RKMK4', 'h', h, lambda sc, t, b, h=h: peers.rkmk4(sc, t, h, budget=b)))
        if magnus_omega is not None:
            out.append(('Magnus4', 'h', h, lambda sc, t, b, h=h: peers.magnus4(
                sc, t, h, magnus_omega, budget=b)))
    return out


def cheapest_meeting(T, target, methods, given_up, fn_error, skip, budget):
    """For one horizon and target: ``{method: (cpu, knob, value, err)}`` of the cheapest knob.

    ``methods`` lists ``(name, knob, value, fn)`` in the order tried (cheapest first);
    ``fn_error(q)`` is the error of an answer; ``skip(name, knob, value)`` leaves a run
    out; a ``(name, target)`` in ``given_up`` (not reached at a shorter horizon) is not
    tried. A time-out or arithmetic failure counts as not reached.
    """
    from rigidrot_ros.bench import peers
    best = {}
    for name, knob, value, fn in methods:
        if name in best or (name, target) in given_up or skip(name, knob, value):
            continue
        try:
            cpu, q = timed(lambda: fn(np.array([T]), budget))
            err = fn_error(q)
        except (peers.TimeBudget, ArithmeticError, ValueError):
            continue
        if err <= target:
            best[name] = (cpu, knob, value, err)
    return best


def horizon_rows(horizons, methods, names, reference, budget, log, skip, label='',
                 extra=None):
    """Rows of a horizon-scaling table: each method's cheapest knob per horizon and target.

    ``reference(T) -> (q_ref, extra columns dict)``; ``names`` the method names in their
    row order; ``skip(name, knob, value, T, target)`` leaves a run out.
    """
    rows = []
    given_up = set()            # (method, target): not reached at a shorter horizon
    for T in horizons:
        ref, cols = reference(T)
        for target in (1e-9, 1e-12):
            best = cheapest_meeting(
                T, target, methods, given_up,
                lambda q: float(quat.angle_between(np.reshape(q, (-1, 4))[-1], ref)),
                lambda n, k, v: skip(n, k, v, T, target), budget)
            for name in names:
                if name not in best:
                    given_up.add((name, target))
                cpu, knob, value, err = best.get(name, (math.nan, '', math.nan, math.nan))
                rows.append(dict({'T_s': T, 'target_rad': target, 'method': name,
                                  'cpu_s': cpu, 'knob': knob, 'value': value,
                                  'error_rad': err}, **cols,
                                 status='ok' if name in best else 'not reached'))
                log(f'{label}T={T:<8g} target {target:g} {name:16s} cpu {cpu:9.4f} s '
                    f'{knob}={value:<8g} err {err:9.2e}')
    return rows


# -- references and scenes ----------------------------------------------------------------

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


def batch_memory(sol, t):
    """Return the tracemalloc peak (bytes) of ``sol.at(t)`` and the size of its output.

    One small call first, so that what the first call sets up once is not counted.
    """
    sol.at(t[:10])
    tracemalloc.start()
    try:
        s = sol.at(t)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak, s.t.nbytes + s.quaternion.nbytes + s.omega.nbytes + s.error_bound.nbytes


def ratio_scenes():
    """Return the preset scenes (config/*.yaml) and the spacecraft scene, by name."""
    from rigidrot_ros.run import settings
    folder = os.path.dirname(settings.find_config('default.yaml'))
    out = {}
    for name in sorted(os.listdir(folder)):
        if name.endswith('.yaml'):
            params = settings.load_defaults(os.path.join(folder, name))
            out[name[:-5]] = settings.scene_from_params(params)
    out['spacecraft'] = SPACECRAFT
    return out


# -- processes ---------------------------------------------------------------------------

def positive_number(text):
    """Parse a positive finite number for an option (argparse ``type``)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'must be a positive number, got {text!r}')
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f'must be a positive number, got {value}')
    return value


# -- results files ------------------------------------------------------------------------

def write_csv(path, rows, foot):
    """Write ``rows`` (dicts with the same keys) to ``path``, the footer as a last comment."""
    if not rows:
        return
    with open(path, 'w', newline='', encoding='utf-8') as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
        fh.write('# ' + json.dumps(foot) + '\n')


def write_json(path, data):
    """Write ``data`` as indented JSON (numpy floats as floats, NaN as NaN)."""
    with open(path, 'w', encoding='utf-8') as fh:
        json.dump(data, fh, indent=1, default=float)


def part_footer(results, name):
    """Return part ``name``'s footer in merged results: its own run's, else the shared one."""
    return results.get(f'footer_{name}_run') or results.get('footer') or {}


# -- Markdown tables ----------------------------------------------------------------------

def fmt(x, digits=3):
    """Format a number for a table: ``digits`` significant digits, '—' for NaN or None."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return '—'
    if isinstance(x, bool) or isinstance(x, str):
        return str(x)
    if isinstance(x, int):
        return str(x)
    return f'{x:.{digits}g}'


def sci(x):
    """Format a power of ten as people write it: ``1e-9``, ``1e5`` (not ``1e-09``)."""
    m, e = f'{x:.0e}'.split('e')
    return f'{m}e{int(e)}'


def span(values, digits=3, unit=''):
    """``'a–b unit'`` over the finite ``values`` (one value: ``'a unit'``; none: '—')."""
    vals = [v for v in values if v is not None and math.isfinite(v)]
    if not vals:
        return '—'
    lo, hi = fmt(min(vals), digits), fmt(max(vals), digits)
    text = lo if lo == hi else f'{lo}–{hi}'
    return f'{text} {unit}'.rstrip()


def md_table(header, rows):
    """Return a Markdown (MyST) pipe table: ``header`` the column titles, ``rows`` of cells."""
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    lines += ['| ' + ' | '.join(str(c) for c in row) + ' |' for row in rows]
    return '\n'.join(lines) + '\n'


def worst(rows, key):
    """Return the largest finite ``row[key]`` over ``rows`` (a missing key: none), or NaN."""
    vals = [r.get(key) for r in rows]
    return max((v for v in vals if v is not None and math.isfinite(v)), default=math.nan)


def md_columns(columns, items):
    """Return a table of ``items``, a line each: ``columns`` lists ``(title, cell(item))``."""
    return md_table([title for title, _ in columns],
                    [[cell(item) for _, cell in columns] for item in items])


def md_bullets(lines):
    """Return a Markdown bullet list of ``lines`` (a blank line after it), '' for none."""
    return ''.join(f'- {line}\n' for line in lines) + '\n' if lines else ''


def part_md(results, name, title, body):
    """Return part ``name``'s fragment: ``body`` under ``title``, with the part's footer."""
    return md_fragment(title, part_footer(results, name), body)


def md_fragment(title, foot, body):
    """Return a fragment: a bold caption, the machine, date and commit from ``foot``, ``body``.

    No ``#`` heading, so that a page can ``{include}`` it under its own. The first line
    says it is generated, so nobody edits it by hand; the caption names the commit the
    run measured (:func:`commit_text`), which ``rigidrot_bench --stale`` compares with the
    code's history.
    """
    machine = (f'{foot.get("cpu", "?")} ({foot.get("cores", "?")} cores), '
               f'{foot.get("date", "?")}, {commit_text(foot)}; '
               f'rigidrot_ros {foot.get("rigidrot_ros", "?")}, '
               f'numpy {foot.get("numpy", "?")}, scipy {foot.get("scipy", "?")}, '
               f'python-flint {foot.get("python-flint", "?")}')
    return (f'<!-- generated by rigidrot_bench from the results JSON: do not edit -->\n\n'
            f'**{title}** (measured on {machine})\n\n{body}')


# -- the axisymmetric and sphere scenes of wp, horizon ------------------------------------

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


def sweep(scene, quick, workload):
    """List (method, knob label, knob value, callable(t_eval, budget) -> q) for a scene.

    The peers across their knobs (:func:`peer_sweep`, Magnus-4 given the exact rates) and
    the exact solution on both backends across tols.
    """
    rtols = [1e-5, 1e-7, 1e-9, 1e-11, 1e-13] if not quick else [1e-6, 1e-9, 1e-12]
    steps = [0.1, 0.05, 0.02, 0.01, 0.005, 0.0025] if not quick else [0.05, 0.01]
    if workload == 'stream':
        steps = [h for h in steps if abs(0.01 / h - round(0.01 / h)) < 1e-9]
    tols = [1e-6, 1e-9, 1e-12] if not quick else [1e-9, 1e-12]
    out = [(m, k, v, lambda t, b, fn=fn: fn(scene, t, b))
           for m, k, v, fn in peer_sweep(rtols, steps, solve(scene).omega_at)]
    for be in ('flint', 'mpmath'):
        for tol in tols:
            out.append((f'exact ({be})', 'tol', tol,
                        lambda t, b, be=be, tol=tol: solve(scene, tol=tol,
                                                           backend=be).at(t).quaternion))
    return out
