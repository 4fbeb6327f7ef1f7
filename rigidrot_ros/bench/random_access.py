"""Random access: scalar ``at(t)`` at random times after ``solve``, first pass included.

For every preset (``config/*.yaml``) and the spacecraft scene, and each horizon T: solve
at tol = 1e-12, then 200 scalar ``sol.at(t)`` calls with t uniform in [0, T] s, timed one
by one (first pass: nothing cached but what ``solve`` built); p50 and p99 in µs. Memory
per solution: the bytes its random-access checkpoints hold (``dense.CHECKPOINT_BYTES``
bounds them) and the peak traced by tracemalloc over the calls. Accuracy in the same run: every
sample against a reference solved at the tightest tol its model accepts, evaluated as a
batch (a different path): the angle between them within the sum of the two bounds. The
targets of issue 20 (p50 <= 20 us and p99 <= 200 us at T = 1e3 s, p50 <= 50 us at
T = 1e5 s) are checked per row and reported, not enforced (timings under load vary).

Each scene and horizon is timed twice, and the table says which is which:

- **warm**: in this process, the scenes one after the other, so a scene runs after others
  have warmed the paths they share (the hypergeometric functions, numba's dispatch, the
  allocator);
- **cold**: in a fresh interpreter for that scene alone (``python -m
  rigidrot_ros.bench.random_access --cold NAME T SEED``, the same times t): what a user's
  first queries pay (``quick``: the first scene only). Imports and ``solve`` are not timed
  in either; the numba engine loads from its disk cache in both.
"""

import json
import os
import subprocess
import sys
import time
import tracemalloc

import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.core import engine
from rigidrot_ros.core import MIN_TOL, PrecisionError, solve
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core.dense import BLOCK_BYTES, CHECKPOINT_BYTES, GRID_BYTES

NAME = 'random_access'
NEEDS = ('numpy', 'yaml')
#: The code this part measures (``rigidrot_bench --stale``): modules, with what they import.
MEASURES = ('rigidrot_ros.core',)

CALLS = 200
TOL = 1e-12
#: Bytes a solution's random-access state can hold at most: checkpoint blocks (40 B a
#: window, 56 while a block's chains are partial; CHECKPOINT_BYTES in all, plus the one
#: block in use, BLOCK_BYTES at most), the grid's shared arrays (GRID_BYTES) and the
#: scratch array of one window's series.
MEMORY_BOUND = CHECKPOINT_BYTES + BLOCK_BYTES + GRID_BYTES + engine.MAX_TERMS * 4 * 8
#: Issue 20's targets, µs: (horizon, p50, p99 or None).
TARGETS = {1e3: (20.0, 200.0), 1e5: (50.0, None)}


def _reference(scene):
    tol = MIN_TOL
    while True:
        try:
            return solve(scene, tol=tol)
        except PrecisionError:
            tol *= 2.0
            if tol > TOL:
                raise


def _one(name, scene, horizon, seed, log, process='warm'):
    t = np.random.default_rng(seed).uniform(0.0, horizon, CALLS)
    sol = solve(scene, tol=TOL)
    q = np.empty((CALLS, 4))
    bound = np.empty(CALLS)
    dts = np.empty(CALLS)
    for i, ti in enumerate(t):
        a = time.perf_counter()
        s = sol.at(float(ti))
        dts[i] = time.perf_counter() - a
        q[i], bound[i] = s.quaternion, s.error_bound
    # memory: the same calls on a fresh solution, traced (tracemalloc slows the calls)
    fresh = solve(scene, tol=TOL)
    tracemalloc.start()
    try:
        for ti in t:
            fresh.at(float(ti))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    dense = getattr(sol, '_dense', None)
    ck = dense.checkpoint_bytes() if dense is not None else 0
    anchors = dense.exact_anchors if dense is not None else 0
    ref = _reference(scene)
    r = ref.at(np.sort(t))
    order = np.argsort(t)
    err = np.empty(CALLS)
    err[order] = quat.angle_between(q[order], r.quaternion)
    rb = np.empty(CALLS)
    rb[order] = r.error_bound
    ok = bool(np.all(err <= bound + rb) and np.all(bound <= TOL))
    us = dts * 1e6
    row = {'scene': name, 'method': sol.method, 'horizon_s': horizon, 'calls': CALLS,
           'p50_us': float(np.percentile(us, 50)), 'p99_us': float(np.percentile(us, 99)),
           'max_us': float(us.max()), 'checkpoint_bytes': int(ck), 'peak_traced_bytes': peak,
           'max_error_rad': float(err.max()), 'max_bound_rad': float(bound.max()),
           'reference_tol': ref.tol, 'bounds_hold': ok, 'exact_anchors': int(anchors),
           'process': process}
    p50_t, p99_t = TARGETS.get(horizon, (None, None))
    row['target_met'] = bool((p50_t is None or row['p50_us'] <= p50_t)
                             and (p99_t is None or row['p99_us'] <= p99_t))
    log(f'{name:22s} {process:4s} {sol.method:28s} T={horizon:7.0e} s  '
        f'p50 {row["p50_us"]:7.1f} us  '
        f'p99 {row["p99_us"]:8.1f} us  max {row["max_us"]:9.1f} us  checkpoints '
        f'{ck / 1e6:5.2f} MB  peak {peak / 1e6:5.2f} MB  exact {anchors:3d}  err '
        f'{row["max_error_rad"]:.1e} <= bound {row["max_bound_rad"]:.1e}: '
        f'{"ok" if ok else "FAILED"}  target {"met" if row["target_met"] else "missed"}')
    return row


def run(quick=False, log=print):
    """Time scalar random access on every preset and the spacecraft scene; check bounds."""
    horizons = (1e3,) if quick else (1e3, 1e5)
    picked = common.ratio_scenes()
    if quick:
        picked = {k: picked[k] for k in ('default', 'spacecraft', 'torque_free_triaxial')}
    log(f'random access: {CALLS} scalar at(t) after solve (first pass), t uniform in [0, T]; '
        f'timings are wall-clock (load average {os.getloadavg()[0]:.2f}); memory bound per '
        f'solution {MEMORY_BOUND / 1e6:.1f} MB')
    t0 = time.perf_counter()
    jit = engine.jit_state()
    jit['load_s'] = time.perf_counter() - t0
    log(f'dense engine: {"compiled (numba)" if jit["compiled"] else "interpreted"}'
        f'{", disk cache" if jit["cached"] else ""}{": " + jit["reason"] if jit["reason"] else ""}'
        f'; loaded in {jit["load_s"]:.2f} s')
    rows = []
    for horizon in horizons:
        for i, (name, scene) in enumerate(picked.items()):
            rows.append(_one(name, scene, horizon, 100 + i, log))
    cold = list(picked)[:1] if quick else list(picked)      # a smoke run: one fresh process
    log(f'cold: {", ".join(cold)} again, each in a fresh process (the same times t)')
    for horizon in horizons:
        for i, name in enumerate(picked):
            if name in cold:
                rows.append(_cold(name, horizon, 100 + i, log))
    return {'part': NAME, 'tol': TOL, 'memory_bound_bytes': MEMORY_BOUND, 'rows': rows,
            'bounds_hold': all(r['bounds_hold'] for r in rows), 'engine': jit,
            'load_average': os.getloadavg()[0]}


def _cold(name, horizon, seed, log):
    """Return the row of :func:`_one` for ``name``, measured in a fresh interpreter."""
    cmd = [sys.executable, '-m', 'rigidrot_ros.bench.random_access', '--cold', name,
           repr(float(horizon)), str(int(seed))]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    lines = out.stdout.strip().splitlines()
    if out.returncode != 0 or not lines:
        raise RuntimeError(f'random_access --cold {name}: exit {out.returncode}: '
                           f'{(out.stderr.strip().splitlines() or ["no output"])[-1]}')
    for line in lines[:-1]:
        log(line)
    return json.loads(lines[-1])


def _cold_main(name, horizon, seed):
    """Child side of :func:`_cold`: time one scene first thing; its log, then the row (JSON)."""
    scene = common.ratio_scenes()[name]
    row = _one(name, scene, float(horizon), int(seed), print, process='cold')
    print(json.dumps(row), flush=True)
    return 0


_COLUMNS = (
    ('scene', lambda r: r['scene']), ('process', lambda r: r.get('process', 'warm')),
    ('method', lambda r: r['method']),
    ('T [s]', lambda r: common.sci(r['horizon_s'])),
    ('p50 [µs]', lambda r: common.fmt(r['p50_us'])),
    ('p99 [µs]', lambda r: common.fmt(r['p99_us'])),
    ('max [µs]', lambda r: common.fmt(r['max_us'])),
    ('exact anchors', lambda r: str(r.get('exact_anchors', '—'))),
    ('checkpoints [MB]', lambda r: common.fmt(r['checkpoint_bytes'] / 1e6)),
    ('peak traced [MB]', lambda r: common.fmt(r['peak_traced_bytes'] / 1e6)),
    ('max error [rad]', lambda r: common.fmt(r['max_error_rad'])),
    ('max bound [rad]', lambda r: common.fmt(r['max_bound_rad'])),
    ('bounds held', lambda r: 'yes' if r['bounds_hold'] else 'NO'),
    ('target', lambda r: ('met' if r['target_met'] else 'missed') if 'target_met' in r
     else '—'),
)


def render_md(results):
    """Return the random-access table: latencies, anchors, memory, errors and bounds."""
    res = results.get(NAME)
    if not res or not res.get('rows'):
        return None
    jit = res.get('engine', {})
    lines = [
        f'{CALLS} scalar `sol.at(t)` calls right after `solve` (tol {common.sci(res["tol"])}), '
        f't uniform in [0, T] s, each timed alone (wall clock; load average '
        f'{common.fmt(res.get("load_average"))} at the start)',
        'targets (issue 20): p50 ≤ 20 µs and p99 ≤ 200 µs at T = 1e3 s, p50 ≤ 50 µs at '
        'T = 1e5 s',
        f'memory per solution at most {common.fmt(res["memory_bound_bytes"] / 1e6)} MB '
        '(checkpoint store, one block in use, one series)',
        'dense engine: ' + ('compiled (numba)' if jit.get('compiled') else
                            f'interpreted ({jit.get("reason", "?")})')
        + (f', loaded in {common.fmt(jit["load_s"])} s' if 'load_s' in jit else ''),
        'errors against a reference at the tightest tol its model accepts, same run',
        'process: warm = this process, the scenes in turn (each after the others have '
        'warmed the paths they share); cold = a fresh interpreter for the scene alone, '
        'the same t: what a first query pays (imports and solve untimed in both)',
    ]
    body = common.md_bullets(lines) + common.md_columns(_COLUMNS, res['rows'])
    return common.part_md(results, NAME, 'Random access: scalar at(t) after solve, first '
                          'pass', body)


def failed(results):
    """Return why the command fails: a sample outside its bound (timings never fail)."""
    res = results.get(NAME) or {}
    return [f'random_access: {r["scene"]} T={r["horizon_s"]:g}: a sample outside its bound'
            for r in res.get('rows', []) if not r['bounds_hold']]


def main(argv=None):
    """Run the part alone: ``python -m rigidrot_ros.bench.random_access [--quick] [--out D]``.

    Its results merge into ``D/results.json`` and its table goes to ``D/random_access.md``.
    """
    args = sys.argv[1:] if argv is None else list(argv)
    if args[:1] == ['--cold'] and len(args) == 4:
        return _cold_main(*args[1:])
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    raise SystemExit(main())
