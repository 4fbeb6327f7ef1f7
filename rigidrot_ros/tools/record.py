"""rigidrot_record: record ROS topics into a rosbag2 MCAP bag (``ros2 bag record`` for pip).

Each listed topic is subscribed as soon as a publisher of it appears (graph polled every
50 ms), with its type from the graph and its QoS matched to the publisher (transient-local
publishers are recorded from their first message, whenever the recorder joins). Run
descriptions of rigidrot nodes (std_msgs/String topics named ``.../run``) are recorded
too, so ``rigidrot_compare`` can score the bag against the exact truth. SIGINT/SIGTERM
(or --duration) finish the bag; a SIGKILL loses at most about 0.5 s (rigidrot_reindex
then finishes the file).
"""

import math
import os
import sys
import time

from rigidrot_ros.tools.cli import OneLineParser

__all__ = ['main']


def _parser():
    ap = OneLineParser(
        prog='rigidrot_record', description=__doc__.splitlines()[0],
        epilog='ROS arguments go after --ros-args (e.g. -r __ns:=/sat1). Example: '
               'rigidrot_record -o runs/est /imu /estimator/odom --duration 20')
    ap.add_argument('-o', '--output', required=True,
                    help='bag directory to create (must not exist, or be empty)')
    ap.add_argument('topics', nargs='*',
                    help='topics to record; NAME:pkg/msg/Type subscribes at once (before any '
                         'publisher exists), so a reliable publisher is kept from its first '
                         'message')
    ap.add_argument('--all', action='store_true', help='record every topic that appears')
    ap.add_argument('--no-runs', action='store_true',
                    help='do not add the run descriptions (.../run) of rigidrot nodes')
    ap.add_argument('--duration', type=float,
                    help='stop after this many seconds (default: until SIGINT/SIGTERM)')
    return ap


def main(argv=None):
    """Entry point of ``rigidrot_record``; returns the exit status."""
    from rigidrot_ros.ros.spin import split_ros_args
    argv, ros_args = split_ros_args(sys.argv[1:] if argv is None else list(argv))
    opts = _parser().parse_args(argv)
    problem = _check_args(opts)
    if problem is not None:
        print(f'rigidrot_record: {problem}', file=sys.stderr)
        return 2
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from rigidrot_ros.bag.metadata import uninterrupted
    from rigidrot_ros.ros.spin import init_ros, spin_until_shutdown

    try:
        reason = init_ros('rigidrot_record', ros_args)
        if reason is not None:
            print(f'rigidrot_record: {reason}', file=sys.stderr)
            return 2
        node = rclpy.create_node('rigidrot_record')
    except (ExternalShutdownException, KeyboardInterrupt):
        return 0
    rec, problem = _start(node, opts)
    if problem is not None:
        node.destroy_node()
        rclpy.try_shutdown()
        print(f'rigidrot_record: {problem}', file=sys.stderr)
        return 2
    end = time.monotonic() + opts.duration if opts.duration else None

    def loop(n):
        while rclpy.ok() and (end is None or time.monotonic() < end):
            try:
                rclpy.spin_once(n, timeout_sec=0.05)
            except Exception:  # noqa: B902 - a take racing SIGINT's shutdown
                if rclpy.ok():
                    raise
                return
    try:
        spin_until_shutdown(node, loop)
    finally:
        path, counts = uninterrupted(rec.close)     # the bag whole, whatever signal arrives
        print(f'rigidrot_record: bag finished: {path} {counts}', file=sys.stderr)
    return 0


def _check_args(opts):
    """Return what is wrong with the command line (one line), or None."""
    if not opts.topics and not opts.all:
        return 'name the topics to record, or give --all'
    if opts.duration is not None and not (math.isfinite(opts.duration) and opts.duration > 0):
        return f'--duration must be a positive number of seconds, got {opts.duration!r}'
    from rigidrot_ros.ros.recorder import check_type

    for t in opts.topics:
        name, _, type_name = t.partition(':')
        if not name:
            return f'{t!r}: no topic name before the type'
        if type_name:
            try:
                check_type(type_name)
            except ValueError as exc:
                return f'{t}: {exc}'
    out = opts.output
    if os.path.exists(out) and (not os.path.isdir(out) or os.listdir(out)):
        return (f'{out} exists and is not an empty directory; nothing is overwritten: '
                f'choose another output directory')
    return None


def _start(node, opts):
    """Open the bag and start recording on ``node``: ``(Recorder, None)`` or ``(None, why)``."""
    from rigidrot_ros.bag import BagWriter
    from rigidrot_ros.ros.recorder import Recorder

    try:
        for t in opts.topics:
            node.resolve_topic_name(t.partition(':')[0])
    except Exception as exc:  # noqa: B902 - rclpy raises its own types for bad names
        return None, f'invalid topic name: {str(exc).splitlines()[0]}'
    out = opts.output
    try:
        writer = BagWriter(None, 'rigidrot_record', flush_period=0.4, path=out)
    except OSError as exc:
        return None, f'cannot record to {out}: {exc}'
    try:
        rec = Recorder(node, writer, topics=opts.topics, all_topics=opts.all,
                       runs=not opts.no_runs, on_event=_event)
    except ValueError as exc:
        writer.close()
        return None, str(exc)
    print(f'rigidrot_record: recording to {writer.path}', file=sys.stderr, flush=True)
    return rec, None


def _event(level, text):
    """Print a recorder event on stderr."""
    print(f'rigidrot_record: {text}', file=sys.stderr, flush=True)


if __name__ == '__main__':
    sys.exit(main())
