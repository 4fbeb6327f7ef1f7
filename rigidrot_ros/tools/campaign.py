"""rigidrot_campaign: Monte Carlo consistency campaign of an attitude estimator.

Reads a YAML spec (``rigidrot_ros.campaign.spec``), runs its M runs on a local process
pool, a Dask LocalCluster (--workers N) or a running Dask cluster (--scheduler), and
writes report.json, runs.csv and charts into -o DIR. Rerun with the same -o to continue a
stopped campaign.
"""

import os
import sys

from rigidrot_ros.tools.cli import fail, OneLineParser

__all__ = ['main']


def _parser():
    ap = OneLineParser(prog='rigidrot_campaign', description=__doc__.splitlines()[0],
                       epilog='Example: rigidrot_campaign mekf.yaml -o runs/mekf --workers 2')
    ap.add_argument('spec', help='campaign spec (YAML)')
    ap.add_argument('-o', '--output', required=True,
                    help='output directory (created; a rerun with the same one continues)')
    eng = ap.add_mutually_exclusive_group()
    eng.add_argument('--workers', type=int,
                     help='start a Dask distributed.LocalCluster of N worker processes')
    eng.add_argument('--scheduler', help='run on a Dask cluster: tcp://HOST:PORT')
    eng.add_argument('--processes', type=int,
                     help='size of the local process pool (the default engine; default: '
                          'one per core)')
    ap.add_argument('--bags', help="keep each run's bags under this directory (a shared "
                                   'path with a cluster); default: temporary, removed')
    ap.add_argument('--quiet', action='store_true', help='no progress bar')
    return ap


def main(argv=None):
    """Entry point of ``rigidrot_campaign``; returns the exit status."""
    opts = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    for name in ('workers', 'processes'):
        v = getattr(opts, name)
        if v is not None and not 1 <= v <= 4096:
            return fail('rigidrot_campaign', f'--{name} must be in [1, 4096], got {v}')
    if opts.workers is not None or opts.scheduler:
        try:
            import distributed  # noqa: F401
        except ImportError:
            from rigidrot_ros.campaign.engine import DASK_MISSING
            return fail('rigidrot_campaign', DASK_MISSING)
    from rigidrot_ros.campaign.engine import run_campaign
    from rigidrot_ros.campaign.spec import load_spec, SpecError
    try:
        spec = load_spec(opts.spec)
        if opts.bags:
            os.makedirs(opts.bags, exist_ok=True)
        report = run_campaign(spec, opts.output,
                              workers=opts.workers if opts.workers else opts.processes,
                              scheduler=opts.scheduler, dask_local=opts.workers is not None,
                              bag_root=opts.bags and os.path.abspath(opts.bags),
                              progress=not opts.quiet)
    except SpecError as exc:
        return fail('rigidrot_campaign', exc)
    except KeyboardInterrupt:
        print('rigidrot_campaign: stopped; finished runs are kept: run the same command '
              'again to continue', file=sys.stderr)
        return 130
    if 'estimators' in spec:                # several on the same runs
        from rigidrot_ros.campaign.multi import summary_lines
        for line in summary_lines(report):
            print(line)
        print(f'report: {os.path.join(opts.output, "report.json")}, comparison: '
              f'{os.path.join(opts.output, "comparison.md")}')
        return 0 if any(e['runs_ok'] for e in report['comparison']['table']) else 1
    a = report.get('anees')
    if a:
        mc = report['mc_nees']
        print(f'{report["runs_ok"]}/{report["runs"]} runs ok, ANEES {a["value"]:.3f} '
              f'(95 % [{a["bounds_95"][0]:.3f}, {a["bounds_95"][1]:.3f}] over '
              f'{a["samples"]} samples); Monte Carlo NEES inside chi2(3M)/M '
              f'[{mc["band_95"][0]:.3f}, {mc["band_95"][1]:.3f}] at '
              f'{100 * mc["fraction_inside"]:.1f} % of {report["steps"]} steps')
    else:
        print(f'{report["runs_ok"]}/{report["runs"]} runs ok: nothing to aggregate')
    print(f'report: {os.path.join(opts.output, "report.json")}')
    return 0 if report['runs_ok'] else 1


if __name__ == '__main__':
    sys.exit(main())
