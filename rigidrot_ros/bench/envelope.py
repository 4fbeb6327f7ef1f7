"""Random scenes across the envelope: per-sample cost of a 100 Hz stream, bounds, errors.

60 seeded scenes of every torque model (U from 1e-10 to 1e2 rad/s^2, transverse rate up to
10 rad/s, |r0| up to 100 rad/s, I3/I from 0.05 to 1.95), each streamed at 100 Hz from a
random start time up to 1e5 s; where it is affordable, a second representation (1F1
against Taylor) built from the same unrounded inputs is compared with the first.
"""

import math
import os
import sys
import time

import mpmath
import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.core import PrecisionError, solve
from rigidrot_ros.core import Scene
from rigidrot_ros.core.kernel import HyperKernel
from rigidrot_ros.core.taylor import TaylorKernel

NAME = 'envelope'
NEEDS = ()
#: The code this part measures (``rigidrot_bench --stale``): modules, with what they import.
MEASURES = ('rigidrot_ros.core',)
KEYS = ('envelope',)


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


def run(quick=False, log=print):
    """Run the envelope sweep; return ``{'envelope': rows}``."""
    return {'envelope': envelope(quick, log)}


def write(res, out, foot, log):
    """Write ``envelope.csv``."""
    common.write_csv(os.path.join(out, 'envelope.csv'), res['envelope'], foot)


#: The envelope table's columns: (title, cell of one method's (name, rows)).
_COLUMNS = (
    ('method', lambda g: g[0]),
    ('scenes', lambda g: str(len(g[1]))),
    ('within tol', lambda g: str(sum(r['status'] == 'ok' for r in g[1]))),
    ('p50 per tick', lambda g: common.span([r.get('p50_us', math.nan) for r in g[1]],
                                           unit='µs')),
    ('worst p99 [µs]', lambda g: common.fmt(common.worst(g[1], 'p99_us'))),
    ('worst bound [rad]', lambda g: common.fmt(common.worst(g[1], 'max_bound_rad'))),
    ('worst first query [s]', lambda g: common.fmt(common.worst(g[1], 'first_query_s'))),
    ('vs other representation [rad]',
     lambda g: common.fmt(common.worst(g[1], 'vs_other_representation_rad'))),
)


def render_md(results):
    """Per evaluation method: scenes, cost per tick, worst bound, second representation."""
    rows = results.get('envelope')
    if not rows:
        return None
    groups = [(m, [r for r in rows if r['method'] == m])
              for m in sorted({r['method'] for r in rows})]
    return common.part_md(
        results, NAME,
        f'Envelope: {len(rows)} seeded random scenes streamed at 100 Hz, tol 1e-12',
        common.md_columns(_COLUMNS, groups))


def main(argv=None):
    """``python -m rigidrot_ros.bench.envelope``: this part alone."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
