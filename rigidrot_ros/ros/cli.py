"""The ``attitude_node`` command: ``--help`` text and ``main`` (start, spin, exit status).

The node itself is :class:`rigidrot_ros.ros.attitude_node.AttitudeNode`; its module's
``main`` (the console script's entry point) forwards here with the node class.
"""

import sys
import textwrap

import rclpy
from rclpy.executors import ExternalShutdownException

from rigidrot_ros.ros.spin import init_ros, spin_until_shutdown, split_ros_args
from rigidrot_ros.run import table
from rigidrot_ros.run.params import help_text
from rigidrot_ros.runtime import realtime

__all__ = ['SceneError', 'usage', 'main']

PROG = 'attitude_node'


class SceneError(ValueError):
    """The parameters at start-up are invalid or do not describe a solvable scene."""


def usage():
    """Return the ``attitude_node --help`` text: parameters, defaults, topics, services."""
    lines = [
        'usage: attitude_node [-h] [--ros-args [-p NAME:=VALUE] [--params-file FILE] '
        '[-r FROM:=TO] ...]',
        '',
        'Publish the exact attitude and body rate of the configured scene.',
        '',
        'Topics and services (relative names: namespaces and remapping apply):',
        '  attitude            geometry_msgs/QuaternionStamped  q_NB (x, y, z, w), frame_id N',
        '  angular_velocity    geometry_msgs/Vector3Stamped     omega of B rel. N, in B, rad/s',
        '  /diagnostics        diagnostic_msgs/DiagnosticArray  1 Hz: model, error bound, '
        'timing, delivered rate',
        '  ~/reset             std_srvs/srv/Trigger             restart at t = 0 from the '
        'current parameters',
        '  ~/run               std_msgs/String                  run description as JSON '
        '(transient-local)',
        *_switched_topics(),
        '',
        'Truth tick k is stamped g + k / publish_rate: g is t_start (scene time 0, the '
        "timer's first",
        'call) until publish_rate changes, then the first call at the new rate. A sensor '
        'sample k is',
        'stamped t_start + k / rate. Every sample holds the scene at t = (stamp - t_start) * '
        'time_scale.',
        '',
        'Parameters (-p NAME:=VALUE or --params-file FILE; default in brackets):',
        help_text(),
        '',
        'An invalid scene or argument exits with status 2 and one line saying why; '
        'Ctrl-C or SIGTERM end the node (and finish a recording) with status 0.',
        'Where the system allows it (root, CAP_SYS_NICE or an rtprio limit) the node runs '
        'on SCHED_FIFO',
        f'priority {realtime.PRIORITY} (RIGIDROT_RT_PRIORITY: 1-99, or 0 for the ordinary '
        'policy), else as an',
        'ordinary process; /diagnostics reports which (key scheduling).',
    ]
    return '\n'.join(lines)


def _switched_topics():
    """Return the help lines of the outputs a switch turns on, from the output table."""
    lines = []
    for kind in table.OUTPUTS:
        if kind.enable is None:
            continue
        parts = []
        for t in kind.topics:
            needs = [p for p in t.needs if p != kind.enable]
            parts.append(f'{t.name} ({t.type.replace("/msg/", "/")})' +
                         (f' with {" and ".join(needs)}' if needs else ''))
        lines += textwrap.wrap(f'with {kind.enable}: {"; ".join(parts)}', 92,
                               initial_indent='  ', subsequent_indent='      ')
    return lines


def main(args=None, node_class=None):
    """Run ``attitude_node`` (accepts the usual ``--ros-args``); return the exit status.

    ``args`` is a full command line as in ``sys.argv`` (program name first); ``node_class``
    builds the node (raises :class:`SceneError` for bad parameters). Returns 0 after
    Ctrl-C/SIGTERM or ``--help``, 2 for bad arguments or parameters.
    """
    argv = list(sys.argv if args is None else args)
    own, ros_args = split_ros_args(argv[1:])
    if any(a in ('-h', '--help') for a in own):
        print(usage())
        return 0
    if own:
        print(f'{PROG}: unrecognized arguments: {" ".join(own)} (ROS arguments go '
              f'after --ros-args; see {PROG} --help)', file=sys.stderr)
        return 2
    try:        # before ROS starts: its threads and the look-ahead worker inherit the policy
        _, sched = realtime.request()
    except ValueError as exc:
        print(f'{PROG}: {exc}', file=sys.stderr)
        return 2
    reason = init_ros(PROG, ros_args)
    if reason is not None:
        print(f'{PROG}: {reason}', file=sys.stderr)
        return 2
    try:
        node = node_class()
    except SceneError as exc:
        print(f'{PROG}: invalid parameters: {_one_line(exc)}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        rclpy.try_shutdown()
        return 0
    except Exception as exc:            # e.g. an invalid remapped name: one line, status 2
        if not rclpy.ok():              # a Ctrl-C or SIGTERM while it started shut ROS down
            return 0
        print(f'{PROG}: cannot start: {type(exc).__name__}: {_one_line(exc)}',
              file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    node.get_logger().info(sched)
    spin_until_shutdown(node)
    return 0


def _one_line(exc):
    return ' '.join(str(exc).split())
