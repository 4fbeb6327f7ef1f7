"""Cross-check of the stability map's exact cells by a second representation.

The stability map scores each exact cell against the exact solution at tol = 2e-14 (flint),
which shares its formulas with the cell. For each cell this part records which evaluation
each backend used at T (``sol.method``: ₁F₁, Taylor continuation, adiabatic series, closed
form) and the angle between the flint and the mpmath answers at tol = 1e-12. Where the two
used different representations (say Taylor against ₁F₁), their agreement is a check that
shares no evaluation formula; where they used the same one, it only compares two
implementations of the special functions, and the chart says so.

The scenes are rebuilt from the cells as :func:`rigidrot_ros.bench.stability.stability_map`
builds them: a unit sphere, omega0 = (0.3, -0.2, r0), torque (0, 0, U), with r0 = 0.5 on
the U rows and U = 0.01 on the r0 rows.
"""

import math
import os
import sys
import time

import numpy as np

from rigidrot_ros.bench import common
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene, solve

__all__ = ['representation', 'stability_crosscheck', 'stability_scene', 'run']

NAME = 'crosscheck'
NEEDS = ()
#: The code this part measures (``rigidrot_bench --stale``): modules, with what they import.
MEASURES = ('rigidrot_ros.core',)
KEYS = ('stability_crosscheck',)


def stability_scene(axis, value):
    """Return the stability map's scene for row ``axis`` ('U' or 'r0') at ``value``."""
    u, r0 = (value, 0.5) if axis == 'U' else (1e-2, value)
    return Scene(inertia=(1.0, 1.0, 1.0), torque=(0.0, 0.0, u), omega0=(0.3, -0.2, r0))


def representation(method):
    """Return the set of representations in ``sol.method`` (backend names dropped).

    Examples
    --------
    >>> sorted(representation('hypergeometric-flint+taylor-series-flint'))
    ['hypergeometric', 'taylor-series']
    """
    out = set()
    for part in method.split('+'):
        for suffix in ('-flint', '-mpmath'):
            if part.endswith(suffix):
                part = part[:-len(suffix)]
        out.add(part)
    return out


def stability_crosscheck(cells, log, tol=1e-12):
    """Return one row per (axis, value, T) of the stability cells: methods and agreement."""
    keys = list(dict.fromkeys((c['axis'], c['value'], c['T_s']) for c in cells))
    rows = []
    for axis, value, T in keys:
        scene = stability_scene(axis, value)
        t = np.array([float(T)])
        out = {'axis': axis, 'value': value, 'T_s': T}
        c0 = time.process_time()
        try:
            sf = solve(scene, tol=tol)
            qf = sf.at(t).quaternion
            sm = solve(scene, tol=tol, backend='mpmath')
            qm = sm.at(t).quaternion
            out.update(flint_method=sf.method, mpmath_method=sm.method,
                       flint_vs_mpmath_rad=float(quat.angle_between(qf, qm).max()))
            out['independent'] = not (representation(sf.method) &
                                      representation(sm.method))
        except (ArithmeticError, ValueError) as exc:
            out.update(flint_method='', mpmath_method='', flint_vs_mpmath_rad=math.nan,
                       independent=False, error=f'{type(exc).__name__}: {exc}'[:120])
        out['cpu_s'] = time.process_time() - c0
        rows.append(out)
        log(f'crosscheck {axis}={value:<8g} T={T:<8g} flint {out["flint_method"]:28s} '
            f'mpmath {out["mpmath_method"]:28s} diff {out["flint_vs_mpmath_rad"]:9.2e}'
            f'{"  (different representations)" if out["independent"] else ""}')
    return rows


def run(quick=False, log=print, results=None):
    """Cross-check the stability map in ``results``; return ``{'stability_crosscheck': rows}``.

    Raises :class:`~rigidrot_ros.bench.common.MissingInput` where ``results`` holds no map.
    """
    if not (results or {}).get('stability'):
        raise common.MissingInput('the stability map', 'stability')
    return {'stability_crosscheck': stability_crosscheck(results['stability'], log)}


def write(res, out, foot, log):
    """Write ``stability_crosscheck.csv``."""
    common.write_csv(os.path.join(out, 'stability_crosscheck.csv'),
                     res['stability_crosscheck'], foot)


def render_md(results):
    """Per row of the map: the representations each backend took and their agreement."""
    rows = results.get('stability_crosscheck')
    if not rows:
        return None
    lines = [[r['axis'], common.fmt(r['value']), common.fmt(r['T_s']),
              r['flint_method'] or '—', r['mpmath_method'] or '—',
              common.fmt(r['flint_vs_mpmath_rad']), 'yes' if r['independent'] else 'no']
             for r in rows]
    return common.md_fragment(
        'Cross-check of the stability map: flint against mpmath at tol 1e-12',
        common.part_footer(results, NAME),
        common.md_table(['row', 'value', 'T [s]', 'flint', 'mpmath', 'angle [rad]',
                         'different representations'], lines))


def main(argv=None):
    """``python -m rigidrot_ros.bench.crosscheck --out DIR``: cross-check DIR's map."""
    from rigidrot_ros.bench import driver
    return driver.part_main(NAME, argv)


if __name__ == '__main__':
    sys.exit(main())
