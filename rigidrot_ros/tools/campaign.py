"""rigidrot_campaign: Monte Carlo consistency campaign of an attitude estimator.

Reads a YAML spec (``rigidrot_ros.campaign.spec``), runs its M runs on a local process
pool, a Dask LocalCluster (--workers N) or a running Dask cluster (--scheduler, with
--tls-ca-file/--tls-cert/--tls-key for a TLS one), and writes report.json, runs.csv and
charts into -o DIR. Rerun with the same -o to continue a stopped campaign. In-process
runs write no file but their results (--keep-bags DIR keeps each run's bags).
"""

import os
import sys
import time

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
    tls = ap.add_argument_group('TLS with --scheduler tls://HOST:PORT (mutual TLS; default: '
                                "Dask's configuration distributed.comm.tls.*)")
    tls.add_argument('--tls-ca-file', metavar='PEM',
                     help="the CA certificate that signed the scheduler's certificate")
    tls.add_argument('--tls-cert', metavar='PEM',
                     help="this client's certificate, signed by a CA the scheduler trusts")
    tls.add_argument('--tls-key', metavar='PEM',
                     help="this client's private key (if not in --tls-cert's file)")
    ap.add_argument('--keep-bags', '--bags', dest='bags', metavar='DIR',
                    help="keep each run's bags under DIR/run_NNNNNN (a shared path with a "
                         "cluster; an in-process estimator's estimates are then bagged and "
                         'scored from the bag, the same report); default: an in-process run '
                         'writes no bag, a ROS one a temporary one, removed')
    ap.add_argument('--quiet', action='store_true', help='no progress bar')
    return ap


class _CheckProgress:
    """Say on stderr how far the check of the runs' draws is, once it takes over 1 s."""

    def __init__(self):
        self.t0 = self.last = time.monotonic()

    def __call__(self, done, total):
        """Redraw the line (at most ten times a second)."""
        now = time.monotonic()
        if now - self.t0 < 1.0 or (done < total and now - self.last < 0.1):
            return
        self.last = now
        rate = done / (now - self.t0)
        left = f', ~{(total - done) / rate:.0f} s left' if done and done < total else ''
        print(f'\r[campaign] checking the draws as the node would: {done}/{total}{left}   ',
              end='' if done < total else '\n', file=sys.stderr, flush=True)


def main(argv=None):
    """Entry point of ``rigidrot_campaign``; returns the exit status."""
    opts = _parser().parse_args(sys.argv[1:] if argv is None else argv)
    for name in ('workers', 'processes'):
        v = getattr(opts, name)
        if v is not None and not 1 <= v <= 4096:
            return fail('rigidrot_campaign', f'--{name} must be in [1, 4096], got {v}')
    tls = [f'--{k.replace("_", "-")}' for k in ('tls_ca_file', 'tls_cert', 'tls_key')
           if getattr(opts, k)]
    if tls and not opts.scheduler:
        return fail('rigidrot_campaign', f'{" ".join(tls)} apply to --scheduler (a --workers '
                    'LocalCluster makes temporary certificates of its own)')
    if opts.workers is not None or opts.scheduler:
        try:
            import distributed  # noqa: F401
        except ImportError:
            from rigidrot_ros.campaign.engine import DASK_MISSING
            return fail('rigidrot_campaign', DASK_MISSING)
    from rigidrot_ros.campaign.spec import forget_prepared
    try:
        return _run(opts)
    finally:
        forget_prepared()           # what the draws' check kept for the runs


def _run(opts):
    """Run the campaign ``opts`` say; the exit status."""
    from rigidrot_ros.campaign.engine import CampaignStopped, dask_security, run_campaign
    from rigidrot_ros.campaign.spec import load_spec, SpecError
    try:
        security = dask_security(opts.tls_ca_file, opts.tls_cert, opts.tls_key) \
            if opts.scheduler else None
        spec = load_spec(opts.spec, progress=None if opts.quiet else _CheckProgress(),
                         keep=opts.workers is None and not opts.scheduler)
        if opts.bags:
            try:
                os.makedirs(opts.bags, exist_ok=True)
            except OSError as exc:
                raise SpecError(f'--keep-bags {opts.bags}: cannot create it: '
                                f'{exc.strerror or exc}') from None
        report = run_campaign(spec, opts.output,
                              workers=opts.workers if opts.workers else opts.processes,
                              scheduler=opts.scheduler, dask_local=opts.workers is not None,
                              bag_root=opts.bags and os.path.abspath(opts.bags),
                              progress=not opts.quiet, security=security)
    except SpecError as exc:
        return fail('rigidrot_campaign', exc)
    except (OSError, CampaignStopped) as exc:   # a full disk, a worker killed, ...
        what = f'{exc.filename or opts.output}: {exc.strerror or exc}' \
            if isinstance(exc, OSError) else str(exc)
        return fail('rigidrot_campaign', f'{what}; finished runs are kept: run the same '
                    'command again to continue', 1)
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
    if report.get('sensors'):
        from rigidrot_ros.scoring.score import describe_sensor
        print('sensor error models of the runs (report.json "sensors"):')
        for name, config in report['sensors'].items():
            if isinstance(config, dict):
                print(f'  {describe_sensor(dict(config, name=name))}')
    print(f'report: {os.path.join(opts.output, "report.json")}')
    return 0 if report['runs_ok'] else 1


if __name__ == '__main__':
    sys.exit(main())
