"""rigidrot_view: the truth against estimates in a browser, live, from bags or a campaign.

The body is drawn as a box along its principal axes, turned by the exact attitude (solid)
and by each estimate (a wireframe ghost), with its rate vector; beside it the attitude
error angle with the estimate's 3σ from its covariance, the NEES against its band, and the
gyro and star tracker residuals. Three sources: ``--live`` (the node's topics and any
``--topic NAME:TYPE`` estimator, decimated to ``--max-rate``), bag directories (the truth
recomputed from the run description, as rigidrot_compare does) or a campaign directory
(Monte Carlo NEES with its chi-square band, each run's ANEES, ``--run I`` opens a run).
The viewer is rerun's web viewer, served from the installed wheel on ``--port`` (no
network access); ``--save FILE.rrd`` writes the recording for rerun's desktop viewer.
"""

import os
import signal
import socket
import sys
import tempfile
import threading
from urllib.parse import quote

from rigidrot_ros.tools.cli import fail, OneLineParser

__all__ = ['main']

PROG = 'rigidrot_view'
VIEW_MISSING = ('the viewer needs rerun-sdk: pip install "rigidrot_ros[view]" '
                '(or pip install rerun-sdk)')


def _parser():
    ap = OneLineParser(
        prog=PROG, description=__doc__.split('\n\n')[0].split(': ', 1)[1],
        epilog='Examples: rigidrot_view runs/loop/rec; rigidrot_view --live --topic '
               '/estimator/odom:nav_msgs/msg/Odometry; rigidrot_view runs/tuned --run 3. '
               'ROS arguments go after --ros-args. Exit status 0 on Ctrl-C, 2 for bad input.')
    ap.add_argument('paths', nargs='*', metavar='BAG_OR_CAMPAIGN',
                    help='bag directories or .mcap files (shown together), or one campaign '
                         'directory')
    ap.add_argument('--live', action='store_true', help="show the node's topics as they come")
    ap.add_argument('--ns', default='', help="live: the node's namespace (default none)")
    ap.add_argument('--topic', action='append', default=[], metavar='NAME:TYPE',
                    help='live: an estimator topic, e.g. '
                         '/estimator/odom:nav_msgs/msg/Odometry (repeatable)')
    ap.add_argument('--run-topic',
                    help="live: the node's run description (default "
                         '<ns>/attitude_node/run)')
    ap.add_argument('--max-rate', type=float, default=50.0, metavar='HZ',
                    help='live: show each topic at most this often (default 50 Hz; 0: all)')
    ap.add_argument('--run', type=int, metavar='I', help='campaign: open run I')
    ap.add_argument('--bags', help='campaign: the --bags directory it was run with (else a '
                                   'run opened is generated and run again)')
    ap.add_argument('--max-points', type=int, default=20000,
                    help='bags: at most this many points a series (every n-th beyond)')
    ap.add_argument('--port', type=int, default=9090, help='web viewer port (default 9090)')
    ap.add_argument('--grpc-port', type=int, default=9876,
                    help="the recording's port on 127.0.0.1 (default 9876)")
    ap.add_argument('--save', metavar='FILE.rrd',
                    help='write the recording to this file; without --serve, serve nothing '
                         '(bags and campaigns: exit once written)')
    ap.add_argument('--serve', action='store_true', help='with --save: serve it as well')
    return ap


def _port_free(port, host):
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def _check(opts):
    """Return one line naming what is wrong with the arguments, or None."""
    if opts.live and opts.paths:
        return '--live takes no bag or campaign path'
    if not opts.live and not opts.paths:
        return 'give bag directories, a campaign directory, or --live'
    for name in ('port', 'grpc_port'):
        v = getattr(opts, name)
        if not 0 < v < 65536:
            return f'--{name.replace("_", "-")} {v}: not a port (1 to 65535)'
    if opts.port == opts.grpc_port:
        return f'--port and --grpc-port are both {opts.port}: they must differ'
    if opts.max_rate < 0 or opts.max_points < 0:
        return '--max-rate and --max-points must be >= 0'
    if opts.save and not opts.save.endswith('.rrd'):
        return f'--save {opts.save}: the file name must end in .rrd'
    if opts.save and os.path.exists(opts.save):
        return f'--save {opts.save}: exists; nothing is overwritten, choose another name'
    if opts.save and not os.path.isdir(os.path.dirname(os.path.abspath(opts.save))):
        return f'--save {opts.save}: its directory does not exist'
    if opts.serve and not opts.save:
        return '--serve goes with --save (without --save the view is always served)'
    return None


def _serving(opts):
    return not opts.save or opts.serve


def _ports(opts):
    """Return one line naming a port in use, or None."""
    if not _serving(opts):
        return None
    if not _port_free(opts.grpc_port, '127.0.0.1'):
        return (f'port {opts.grpc_port} (--grpc-port, the recording) is in use: choose another '
                f'with --grpc-port')
    if not _port_free(opts.port, ''):
        return f'port {opts.port} (--port, the web viewer) is in use: choose another with --port'
    return None


def _recorder(opts, blueprint):
    from rigidrot_ros.view.rr_log import Recorder
    rec = Recorder(blueprint, grpc_port=opts.grpc_port if _serving(opts) else None,
                   save=opts.save)
    return rec


def _announce(opts, rec):
    if _serving(opts):
        rec.serve_web(opts.port)
        url = f'http://127.0.0.1:{opts.port}/?url={quote(rec.url, safe="")}'
        print(f'{PROG}: serving the view at {url} (Ctrl-C to stop)', file=sys.stderr,
              flush=True)


def _say(line):
    print(f'{PROG}: {" ".join(str(line).split())}', file=sys.stderr, flush=True)


def _wait():
    """Block until SIGINT or SIGTERM."""
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    while not done.wait(0.5):
        pass


def _show_bags(opts, paths, campaign=None):
    from rigidrot_ros.view import rr_log
    from rigidrot_ros.view.plan import plan_bag, read_bags
    problems = []
    plan = None
    if paths:
        bag, notes = read_bags(paths)
        for n in notes:
            _say(f'note: {n}')
        plan = plan_bag(bag, max_points=opts.max_points)
        problems = plan.problems
    if campaign is None:
        bp = rr_log.blueprint()
    else:
        bp = rr_log.campaign_blueprint(with_run=opts.run if paths else None)
    rec = _recorder(opts, bp)
    if plan is not None:
        rec.t0_ns = plan.t0_ns
        rr_log.log_plan(rec, plan)
    if campaign is not None:
        rr_log.log_campaign(rec, campaign)
    for p in problems:
        _say(p)
    return rec


def _campaign(opts, work):
    from rigidrot_ros.view.campaign import campaign_plan, read_campaign, run_bags
    path = opts.paths[0]
    spec, report, problems = read_campaign(path)
    for p in problems:
        _say(p)
    paths = []
    if opts.run is not None:
        _say(f'opening run {opts.run}' + ('' if opts.bags else ': generating it and running '
                                          'its estimator again'))
        paths, more = run_bags(path, spec, opts.run, work, opts.bags)
        for p in more:
            _say(p)
            problems.append(p)
    return _show_bags(opts, paths, campaign_plan(report, problems))


def _live(opts, ros_args):
    from rigidrot_ros.ros.spin import init_ros, spin_until_shutdown
    from rigidrot_ros.view import rr_log
    from rigidrot_ros.view.live import check_topic, LiveView
    estimators = {}
    for text in opts.topic:
        topic, type_name = check_topic(text)
        estimators[topic] = type_name
    reason = init_ros(PROG, ros_args)
    if reason is not None:
        return fail(PROG, reason)
    import rclpy
    from rclpy.exceptions import NotInitializedException
    rec = _recorder(opts, rr_log.blueprint())
    _announce(opts, rec)
    try:
        node = rclpy.create_node('rigidrot_view')
    except NotInitializedException:
        rec.close()                 # Ctrl-C came before the node: nothing to show
        return 0
    ns = '/' + opts.ns.strip('/') if opts.ns.strip('/') else ''
    run_topic = opts.run_topic or f'{ns}/attitude_node/run'
    view = LiveView(node, rec, ns=opts.ns, estimators=estimators, run_topic=run_topic,
                    max_rate=opts.max_rate, say=_say)
    _say(f'live: {", ".join(view.types)}; each topic shown at most {opts.max_rate:g} Hz '
         f'(--max-rate)')
    try:
        spin_until_shutdown(node)
    finally:
        view.close()
        rec.close()
        _say(f'live summary: {view.summary()}')
    return 0


def main(argv=None):
    """Entry point of ``rigidrot_view``; returns the exit status."""
    from rigidrot_ros.ros.spin import split_ros_args
    argv = sys.argv[1:] if argv is None else list(argv)
    own, ros_args = split_ros_args(argv)
    opts = _parser().parse_args(own)
    why = _check(opts) or _ports(opts)
    if why:
        return fail(PROG, why)
    try:
        import rerun  # noqa: F401
    except ImportError:
        return fail(PROG, VIEW_MISSING)
    from rigidrot_ros.view.campaign import is_campaign
    from rigidrot_ros.view.plan import ViewError
    try:
        if opts.live:
            return _live(opts, ros_args)
        for p in opts.paths:
            if not os.path.exists(p):
                raise ViewError(f'{p}: no such file or directory')
        camp = [p for p in opts.paths if is_campaign(p)]
        if camp and len(opts.paths) > 1:
            raise ViewError(f'{camp[0]} is a campaign directory: open it alone')
        if (opts.run is not None or opts.bags) and not camp:
            raise ViewError('--run and --bags go with a campaign directory')
        with tempfile.TemporaryDirectory(prefix='rigidrot_view_') as work:
            rec = _campaign(opts, work) if camp else _show_bags(opts, opts.paths)
            if _serving(opts):
                _announce(opts, rec)
                rec.flush()
                _wait()
            rec.close()
    except (ViewError, ValueError, OSError) as exc:
        return fail(PROG, exc)
    if opts.save:
        print(f'{PROG}: wrote {opts.save}', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
