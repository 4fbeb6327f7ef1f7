"""Why a tick costs more in the node than in a tight loop: the same calls, three settings.

``python -m rigidrot_ros.bench.node_tick [--seconds S] [--preset NAME ...]`` times
``Solution.at(t)`` (wall clock, perf_counter) for successive 100 Hz scene times

1. in a tight loop (the figure the benchmark quotes per tick);
2. in a loop that waits for the next 10 ms tick between calls (no ROS), sleeping or
   spinning on the clock, and a second call right after each: what the idle gap alone
   does (measured here: the first call after a 10 ms gap costs 10x a call made at once,
   spinning or not, so the cost is cold state - caches, TLB, branch predictors - on a
   shared virtual CPU, not ROS);
3. inside a 100 Hz rclpy timer callback of a real node that publishes a
   QuaternionStamped and Vector3Stamped every tick, with a subscriber to both in the same
   process (the node's evaluation figure, as its diagnostics report it).

It prints mean, p50, p99 and max of each, per preset, and the whole callback's p99 in the
node. ROS traffic stays on the machine: it sets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``
unless already set; use your own ``ROS_DOMAIN_ID``.
"""

import argparse
import os
import time

import numpy as np

from rigidrot_ros.bench.run import ratio_scenes
from rigidrot_ros.core import solve


def _stats(us):
    us = np.asarray(us)
    return (f'mean {us.mean():7.1f}  p50 {np.percentile(us, 50):7.1f}  '
            f'p99 {np.percentile(us, 99):7.1f}  max {us.max():8.1f} us')


def tight(scene, n):
    """Latencies (us) of successive 100 Hz calls in a tight loop."""
    sol = solve(scene)
    out = []
    for k in range(1, n + 1):
        c = time.perf_counter()
        sol.at(0.01 * k)
        out.append(time.perf_counter() - c)
    return 1e6 * np.array(out)


def paced(scene, n, busy=False):
    """Latencies (us) of the same calls, one every 10 ms of wall time.

    Between calls the loop sleeps, or with ``busy`` spins on the clock. Returns the
    latencies of the paced calls and of a second call made right after each.
    """
    sol = solve(scene)
    out, again = [], []
    nxt = time.perf_counter()
    for k in range(1, n + 1):
        nxt += 0.01
        if busy:
            while time.perf_counter() < nxt:
                pass
        else:
            delay = nxt - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        c = time.perf_counter()
        sol.at(0.01 * k)
        c1 = time.perf_counter()
        sol.at(0.01 * k + 0.001)                  # the same work again, caches now warm
        again.append(time.perf_counter() - c1)
        out.append(c1 - c)
    return 1e6 * np.array(out), 1e6 * np.array(again)


def in_node(scene, n):
    """Time the evaluation and the whole callback (us) in a 100 Hz rclpy timer."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped

    rclpy.init()
    try:
        node = rclpy.create_node('rigidrot_tick_probe')
        pub_q = node.create_publisher(QuaternionStamped, 'probe/attitude', 10)
        pub_w = node.create_publisher(Vector3Stamped, 'probe/angular_velocity', 10)
        got = [0]
        sub_node = rclpy.create_node('rigidrot_tick_listener')
        sub_node.create_subscription(QuaternionStamped, 'probe/attitude',
                                     lambda m: got.__setitem__(0, got[0] + 1), 10)
        sub_node.create_subscription(Vector3Stamped, 'probe/angular_velocity',
                                     lambda m: None, 10)
        sol = solve(scene)
        evals, calls = [], []
        k = [0]

        def tick():
            c0 = time.perf_counter()
            k[0] += 1
            s = sol.at(0.01 * k[0])
            c1 = time.perf_counter()
            stamp = node.get_clock().now().to_msg()
            att = QuaternionStamped()
            att.header.stamp = stamp
            att.quaternion.x, att.quaternion.y, att.quaternion.z, att.quaternion.w = (
                float(v) for v in s.quaternion)
            rate = Vector3Stamped()
            rate.header.stamp = stamp
            rate.vector.x, rate.vector.y, rate.vector.z = (float(v) for v in s.omega)
            pub_q.publish(att)
            pub_w.publish(rate)
            evals.append(c1 - c0)
            calls.append(time.perf_counter() - c0)

        node.create_timer(0.01, tick)
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        ex.add_node(sub_node)
        while len(evals) < n:
            ex.spin_once(timeout_sec=0.1)
        ex.shutdown()
        node.destroy_node()
        sub_node.destroy_node()
        return 1e6 * np.array(evals), 1e6 * np.array(calls), got[0]
    finally:
        rclpy.try_shutdown()


def main(argv=None):
    """Print the three settings' latencies per preset."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--seconds', type=float, default=10.0, help='scene time per setting')
    ap.add_argument('--preset', action='append', help='scene name (default: all)')
    opts = ap.parse_args(argv)
    scenes = ratio_scenes()
    n = int(round(opts.seconds * 100))
    for name in opts.preset or list(scenes):
        scene = scenes[name]
        print(f'{name}:')
        print(f'  tight loop      {_stats(tight(scene, n))}')
        for label, busy in (('sleeping', False), ('spinning', True)):
            first, again = paced(scene, n, busy)
            print(f'  paced, {label} {_stats(first)}')
            print(f'    at once again {_stats(again)}')
        ev, cb, got = in_node(scene, n)
        print(f'  node timer eval {_stats(ev)}')
        print(f'  node callback   {_stats(cb)}  ({got} messages received)', flush=True)


if __name__ == '__main__':
    main()
