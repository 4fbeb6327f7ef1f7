"""rigidrot_bench: speed against accuracy, horizon scaling, and where each method fails.

The command: it loops over the parts of :mod:`rigidrot_ros.bench.registry` (each a module
``rigidrot_ros.bench.<part>``) through :mod:`rigidrot_ros.bench.driver`. Every method is
timed (CPU time, median of repeats) and its answer is checked against a reference far
tighter than anything measured. No part imports this module.
"""

import sys

from rigidrot_ros.bench import driver, figures, registry, stamps
from rigidrot_ros.bench.common import footer  # noqa: F401  (was importable from here)
from rigidrot_ros.tools.cli import OneLineParser


def list_parts():
    """Print each part: name, whether it runs by default, its first docstring line."""
    for name, mod in registry.available().items():
        if isinstance(mod, registry.Unavailable):
            print(f'{name:12s} unavailable: {mod}')
        else:
            tag = 'default' if getattr(mod, 'DEFAULT', False) else '       '
            print(f'{name:12s} {tag} {registry.summary(mod)}')
    return 0


def main(argv=None):
    """Entry point of ``rigidrot_bench``."""
    defaults = []
    modules = []
    for name, mod in registry.available(needs=False).items():
        if not isinstance(mod, registry.Unavailable):
            modules.append(mod)
            if getattr(mod, 'DEFAULT', False):
                defaults.append(name)
    ap = OneLineParser(prog='rigidrot_bench', description=__doc__.splitlines()[0])
    ap.add_argument('--out', default='bench_out', help='directory for charts and data')
    ap.add_argument('--quick', action='store_true', help='a smoke run, under a minute')
    ap.add_argument('--only', choices=list(registry.PARTS), action='append',
                    help=f'run only this part (repeatable; default: {", ".join(defaults)}); '
                         'results merge into an existing OUT/results.json; --list shows '
                         'the parts')
    ap.add_argument('--list', action='store_true', help='list the parts and exit')
    driver.add_part_arguments(ap, modules)
    ap.add_argument('--charts-from', metavar='RESULTS_JSON',
                    help='only redraw the charts and the Markdown tables (<part>.md) from '
                         'a results.json into --out (needs matplotlib, runs nothing)')
    ap.add_argument('--stale', action='store_true',
                    help='run nothing: list the committed tables older than the code they '
                         'measure (their commit against git history; see --results, --strict)')
    stamps.add_arguments(ap)
    ap.add_argument('--figures', action='store_true',
                    help='run nothing: check every figure README.md and doc/*.md quote '
                         'against its results file (see --write)')
    figures.add_arguments(ap)
    opts = ap.parse_args(argv)
    if opts.list:
        return list_parts()
    if opts.stale:
        return stamps.run(opts)
    if opts.figures:
        return figures.run(opts)
    if opts.results or opts.strict:
        ap.error('--results and --strict go with --stale')
    if opts.write:
        ap.error('--write goes with --figures')
    log = driver.clock_log()
    if opts.charts_from is not None:
        missing = driver.missing_modules(['matplotlib'])
        if missing:
            print(f'rigidrot_bench: {driver.install_hint(missing)}', file=sys.stderr)
            return 2
        return driver.redraw(opts.charts_from, opts.out, log)
    return driver.run_parts(opts.only or defaults, opts, log)


if __name__ == '__main__':
    sys.exit(main())
