"""Random access: scalar ``at(t)`` at random times after ``solve``, first pass included.

For every preset (``config/*.yaml``) and the spacecraft scene, and each horizon T: solve
at tol = 1e-12, then 200 scalar ``sol.at(t)`` calls with t uniform in [0, T] s, timed one
by one (first pass: nothing cached but what ``solve`` built); p50 and p99 in µs. Memory
per solution: the bytes its random-access checkpoints hold (``dense.CHECKPOINT_BYTES``
bounds them) and the peak traced by tracemalloc over the calls. Accuracy in the same run: every
sample against a reference solved at the tightest tol its model accepts, evaluated as a
batch (a different path): the angle between them within the sum of the two bounds.
"""

import argparse
import json
import os
import time
import tracemalloc

import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.core import MIN_TOL, PrecisionError, solve
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core.dense import BLOCK_BYTES, CACHE, CHECKPOINT_BYTES

NAME = 'random_access'
NEEDS = ('numpy', 'yaml')

CALLS = 200
TOL = 1e-12
#: Bytes a solution's random-access state can hold at most: checkpoint blocks (40 B a
#: window, 128 while a block's chain is partial; CHECKPOINT_BYTES in all, plus the one
#: block in use, BLOCK_BYTES at most) and the cache of CACHE windows (about 2 kB each).
MEMORY_BOUND = CHECKPOINT_BYTES + BLOCK_BYTES + CACHE * 2048


def _reference(scene):
    tol = MIN_TOL
    while True:
        try:
            return solve(scene, tol=tol)
        except PrecisionError:
            tol *= 2.0
            if tol > TOL:
                raise


def _one(name, scene, horizon, seed, log):
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
           'reference_tol': ref.tol, 'bounds_hold': ok}
    log(f'{name:22s} {sol.method:28s} T={horizon:7.0e} s  p50 {row["p50_us"]:7.1f} us  '
        f'p99 {row["p99_us"]:8.1f} us  max {row["max_us"]:9.1f} us  checkpoints '
        f'{ck / 1e6:5.2f} MB  peak {peak / 1e6:5.2f} MB  err {row["max_error_rad"]:.1e} '
        f'<= bound {row["max_bound_rad"]:.1e}: {"ok" if ok else "FAILED"}')
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
    rows = []
    for horizon in horizons:
        for i, (name, scene) in enumerate(picked.items()):
            rows.append(_one(name, scene, horizon, 100 + i, log))
    return {'part': NAME, 'tol': TOL, 'memory_bound_bytes': MEMORY_BOUND, 'rows': rows,
            'bounds_hold': all(r['bounds_hold'] for r in rows)}


def main(argv=None):
    """Run the part alone: ``python -m rigidrot_ros.bench.random_access [--quick]``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--quick', action='store_true', help='one horizon, three scenes')
    ap.add_argument('--json', help='write the results to this file')
    args = ap.parse_args(argv)
    res = run(quick=args.quick)
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as fh:
            json.dump(res, fh, indent=1)
    return 0 if res['bounds_hold'] else 1


if __name__ == '__main__':
    raise SystemExit(main())
