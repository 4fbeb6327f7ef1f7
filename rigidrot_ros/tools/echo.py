"""rigidrot_echo: print the node's attitude and angular velocity as they arrive.

A stand-in for ``ros2 topic echo`` where ros2cli is not installed. One line per tick:
stamp (s), q_NB (x, y, z, w) and omega of B relative to N in B (rad/s).
"""

import argparse
import sys

from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
import rclpy

from rigidrot_ros.node.spin import spin_until_shutdown


def main(argv=None):
    """Entry point of ``rigidrot_echo``."""
    argv = sys.argv[1:] if argv is None else argv
    ros_args = []
    if '--ros-args' in argv:
        i = argv.index('--ros-args')
        argv, ros_args = argv[:i], argv[i:]
    ap = argparse.ArgumentParser(prog='rigidrot_echo', description=__doc__.splitlines()[0])
    ap.add_argument('--ns', default='', help='namespace of the node, e.g. /sat1')
    ap.add_argument('--count', type=int, default=0, help='stop after N ticks (0: never)')
    opts = ap.parse_args(argv)
    rclpy.init(args=['rigidrot_echo'] + ros_args)
    node = rclpy.create_node('rigidrot_echo')
    pending = {}
    printed = [0]

    def show(key, msg):
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
            printed[0] += 1

    ns = opts.ns.rstrip('/')
    node.create_subscription(QuaternionStamped, f'{ns}/attitude', lambda m: show('q', m), 10)
    node.create_subscription(Vector3Stamped, f'{ns}/angular_velocity',
                             lambda m: show('w', m), 10)

    def loop(n):
        while rclpy.ok() and (opts.count == 0 or printed[0] < opts.count):
            rclpy.spin_once(n, timeout_sec=0.1)

    spin_until_shutdown(node, loop)
    return 0


if __name__ == '__main__':
    sys.exit(main())
