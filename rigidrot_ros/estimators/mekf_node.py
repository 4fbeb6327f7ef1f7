"""rigidrot_mekf: the reference MEKF as a ROS node (thin over ``estimators.mekf.MEKF``).

Subscribes ``imu`` (sensor_msgs/Imu) and ``star_tracker``
(geometry_msgs/PoseWithCovarianceStamped); publishes ``estimator/odom``
(nav_msgs/Odometry, orientation covariance of the body error in the rotation block),
reliable and transient-local (depth 10000), so a recorder that joins late still gets every
estimate. The two topics arrive on separate subscriptions, so messages are held until the
other topic has reached their stamp (or for 0.5 s at most) and fed to the filter in stamp
order; at shutdown
(SIGINT/SIGTERM) what is held is fed and the last estimates are published. Estimates carry
the sensors' stamps, so the node runs the same on wall or sim time (``use_sim_time``).
"""

import heapq
import sys
import time

from rigidrot_ros.estimators.mekf import MekfParams, PARAMS
from rigidrot_ros.tools.cli import fail, OneLineParser

__all__ = ['main']


def _parser():
    ap = OneLineParser(prog='rigidrot_mekf', description=__doc__.splitlines()[0],
                       epilog='ROS arguments go after --ros-args (e.g. -r __ns:=/sat1).')
    for name in ('sigma_v', 'sigma_u', 'bias_sigma'):
        ap.add_argument('--' + name.replace('_', '-'), type=float,
                        default=PARAMS[name][0], help=PARAMS[name][1])
    ap.add_argument('--bias0', type=float, nargs=3, default=PARAMS['bias0'][0],
                    help=PARAMS['bias0'][1])
    ap.add_argument('--output-every', type=int, default=PARAMS['output_every'][0],
                    help=PARAMS['output_every'][1])
    return ap


class StampOrder:
    """Feed messages of several topics to ``sink`` in stamp order, as they become safe.

    A message is passed on once every topic of ``topics`` has delivered one at least as
    late (each topic arrives in order on its own subscription), or once it has been held
    ``max_hold`` seconds (:meth:`release_old`; a topic that has ended, or fell silent, no
    longer holds the others back); :meth:`drain` passes the rest.
    """

    def __init__(self, sink, topics, max_hold=0.5):
        self._sink = sink
        self._heap = []
        self._latest = {t: -1 for t in topics}
        self._n = 0
        self.max_hold = max_hold

    def push(self, topic, stamp_ns, msg):
        """Hold one message; pass on those now safe."""
        self._latest[topic] = max(stamp_ns, self._latest.get(topic, -1))
        heapq.heappush(self._heap, (stamp_ns, self._n, topic, msg, time.monotonic()))
        self._n += 1
        safe = min(self._latest.values())
        while self._heap and self._heap[0][0] <= safe:
            self._pop()

    def _pop(self):
        _, _, t, m, _ = heapq.heappop(self._heap)
        self._sink(t, m)

    def release_old(self):
        """Pass on, in stamp order, everything up to the last message held too long."""
        now = time.monotonic()
        old = [item[0] for item in self._heap if now - item[4] >= self.max_hold]
        if old:
            last = max(old)
            while self._heap and self._heap[0][0] <= last:
                self._pop()

    def drain(self):
        """Pass on everything held."""
        while self._heap:
            self._pop()


def main(argv=None):
    """Entry point of ``rigidrot_mekf``; returns the exit status."""
    from rigidrot_ros.ros.spin import split_ros_args
    argv, ros_args = split_ros_args(sys.argv[1:] if argv is None else list(argv))
    opts = _parser().parse_args(argv)
    try:
        params = MekfParams({'sigma_v': opts.sigma_v, 'sigma_u': opts.sigma_u,
                             'bias_sigma': opts.bias_sigma, 'bias0': list(opts.bias0),
                             'output_every': opts.output_every})
    except ValueError as exc:
        return fail('rigidrot_mekf', exc)
    try:
        return _run(params, ros_args)
    except KeyboardInterrupt:
        return 0


def _run(params, ros_args):
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu

    from rigidrot_ros.estimators.mekf import MEKF
    from rigidrot_ros.ros.spin import init_ros, spin_until_shutdown

    reason = init_ros('rigidrot_mekf', ros_args)
    if reason is not None:
        return fail('rigidrot_mekf', reason)
    node = rclpy.create_node('mekf')
    qos = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    pub = node.create_publisher(Odometry, 'estimator/odom', qos)
    filt = MEKF(params)

    def feed(topic, msg):
        for out in filt.receive(topic, msg):
            pub.publish(out)
    order = StampOrder(feed, (params.imu_topic, params.star_tracker_topic))

    def on(topic):
        def cb(msg):
            order.push(topic, msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
                       msg)
        return cb
    in_qos = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(Imu, 'imu', on(params.imu_topic), in_qos)
    node.create_subscription(PoseWithCovarianceStamped, 'star_tracker',
                             on(params.star_tracker_topic), in_qos)

    node.create_timer(0.2, order.release_old)

    def loop(n):
        while rclpy.ok():
            try:
                rclpy.spin_once(n, timeout_sec=0.1)
            except Exception:  # noqa: B902 - a take racing the shutdown
                if rclpy.ok():
                    raise
                break
        order.drain()
        for out in filt.finish():
            try:
                pub.publish(out)
            except Exception:  # noqa: B902 - the context is already gone
                pass
    spin_until_shutdown(node, loop)
    return 0


if __name__ == '__main__':
    sys.exit(main())
