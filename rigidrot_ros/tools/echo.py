"""rigidrot_echo: print the node's attitude and angular velocity as they arrive.

A stand-in for ``ros2 topic echo`` where ros2cli is not installed. One line per tick:
stamp (s), q_NB (x, y, z, w) and omega of B relative to N in B (rad/s). What it waits for
is said on stderr; ``--timeout S`` gives up (exit status 1) when S seconds pass without a
message.
"""

import argparse
import os
import sys
import time

from rigidrot_ros.ros.spin import init_ros, spin_until_shutdown, split_ros_args
from rigidrot_ros.tools.cli import OneLineParser


def _parser():
    ap = OneLineParser(
        prog='rigidrot_echo', description=__doc__.split('\n\n')[0].split(': ', 1)[1],
        epilog='ROS arguments go after --ros-args, e.g. --ros-args -r __ns:=/sat1. Exit '
               'status: 0 after --count ticks or Ctrl-C, 1 on --timeout, 2 for bad arguments.')
    ap.add_argument('--ns', default='',
                    help="namespace of the node's topics, e.g. /sat1 (default: none)")
    ap.add_argument('--count', type=_non_negative_int, default=0,
                    help='stop after N ticks (default 0: never)')
    ap.add_argument('--timeout', type=_non_negative_float, default=0.0, metavar='S',
                    help='exit with status 1 if no message arrives for S seconds '
                         '(default 0: wait forever)')
    return ap


def _non_negative_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not an integer: {text!r}') from None
    if value < 0:
        raise argparse.ArgumentTypeError(f'must be >= 0, got {value}')
    return value


def _non_negative_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not value >= 0 or value == float('inf'):
        raise argparse.ArgumentTypeError(f'must be a finite number >= 0, got {text}')
    return value


def _topic(ns, name):
    """Return ``<ns>/<name>`` as an absolute topic name, or raise ValueError naming --ns."""
    from rclpy.validate_full_topic_name import validate_full_topic_name
    ns = ns.strip()
    full = ('/' + ns.strip('/') if ns.strip('/') else '') + '/' + name
    try:
        validate_full_topic_name(full)
    except Exception as exc:            # InvalidTopicNameException and kin
        raise ValueError(f'--ns {ns!r} does not make a valid topic name ({full!r}): '
                         f'{" ".join(str(exc).split())}') from None
    return full


def main(argv=None):
    """Entry point of ``rigidrot_echo``; returns the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    own, ros_args = split_ros_args(argv)
    opts = _parser().parse_args(own)           # exits 2 with one line on bad arguments
    try:
        topics = (_topic(opts.ns, 'attitude'), _topic(opts.ns, 'angular_velocity'))
    except ValueError as exc:
        print(f'rigidrot_echo: {exc}', file=sys.stderr)
        return 2
    reason = init_ros('rigidrot_echo', ros_args)
    if reason is not None:
        print(f'rigidrot_echo: {reason}', file=sys.stderr)
        return 2
    import rclpy
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped

    node = rclpy.create_node('rigidrot_echo')
    pending = {}
    state = {'printed': 0, 'last': time.monotonic(), 'timed_out': False}

    def show(key, msg):
        state['last'] = time.monotonic()
        stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
        pending.setdefault(stamp, {})[key] = msg
        both = pending[stamp]
        if len(both) == 2:
            q, w = both['q'].quaternion, both['w'].vector
            print(f'{stamp[0]}.{stamp[1]:09d}  q_NB = ({q.x:+.12f}, {q.y:+.12f}, '
                  f'{q.z:+.12f}, {q.w:+.12f})  omega_B = ({w.x:+.9f}, {w.y:+.9f}, '
                  f'{w.z:+.9f}) rad/s', flush=True)
            del pending[stamp]
            for old in [s for s in pending if s < stamp]:
                del pending[old]
            state['printed'] += 1

    node.create_subscription(QuaternionStamped, topics[0], lambda m: show('q', m), 10)
    node.create_subscription(Vector3Stamped, topics[1], lambda m: show('w', m), 10)
    domain = os.environ.get('ROS_DOMAIN_ID', '0')
    print(f'rigidrot_echo: waiting for {topics[0]} and {topics[1]} (ROS_DOMAIN_ID={domain}'
          f'{f", timeout {opts.timeout:g} s" if opts.timeout else ", Ctrl-C to stop"})',
          file=sys.stderr, flush=True)

    def loop(n):
        while rclpy.ok() and (opts.count == 0 or state['printed'] < opts.count):
            rclpy.spin_once(n, timeout_sec=0.1)
            if opts.timeout and time.monotonic() - state['last'] > opts.timeout:
                state['timed_out'] = True
                return

    spin_until_shutdown(node, loop)
    if state['timed_out']:
        what = 'no message' if state['printed'] == 0 else 'no further message'
        print(f'rigidrot_echo: {what} on {topics[0]} / {topics[1]} for {opts.timeout:g} s: '
              f'is attitude_node running, in ROS_DOMAIN_ID={domain}, with that namespace '
              '(--ns)?', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
