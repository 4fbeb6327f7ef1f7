"""rigidrot_mekf: the reference MEKF as a ROS node (thin over ``estimators.mekf.MEKF``).

Subscribes ``imu`` (sensor_msgs/Imu) and ``star_tracker``
(geometry_msgs/PoseWithCovarianceStamped); publishes ``estimator/odom``
(nav_msgs/Odometry, orientation covariance of the body error in the rotation block),
reliable and transient-local (depth 10000), so a recorder that joins late still gets every
estimate. The two topics arrive on separate subscriptions, so messages are held until the
other topic has reached their stamp (or for 0.5 s at most) and fed to the filter in stamp
order. Each callback also takes every message already waiting on either subscription (one
executor round for a burst, not one per message: a campaign's paced feed sends bursts).
The subscriptions are raw: the fields the filter reads are unpacked from the CDR bytes
(:func:`cdr_view`; rclpy's message objects cost more than the filter itself here), the
same doubles as rclpy's; a message of another layout goes through rclpy's deserializer.

At SIGINT/SIGTERM it takes what has been delivered, feeds what is held, publishes the last
estimates and waits (1 s at most) until its subscribers have acknowledged them, then
exits. Service ``~/reset`` (std_srvs/Trigger; ``/mekf/reset`` by default) does the same
without exiting, then starts a new filter: the contract of a campaign's long-lived
estimator (``reset: /mekf/reset``). Estimates carry the sensors' stamps, so the node runs
the same on wall or sim time (``use_sim_time``).
"""

import heapq
import struct
import sys
import time
from types import SimpleNamespace

from rigidrot_ros.estimators.mekf import MekfParams, PARAMS
from rigidrot_ros.tools.cli import fail, OneLineParser

__all__ = ['main', 'cdr_view', 'StampOrder']


#: What ``--help`` says about the node's topics and services.
TOPICS = '''topics (relative names: -r __ns:=/sat1 moves them all):
  subscribes  imu             sensor_msgs/msg/Imu (angular_velocity and its covariance)
              star_tracker    geometry_msgs/msg/PoseWithCovarianceStamped (rotation block)
  publishes   estimator/odom  nav_msgs/msg/Odometry at every --output-every-th gyro stamp:
                              orientation q_NB with the covariance of the body error in
                              the rotation block of pose.covariance; reliable,
                              transient-local, depth 10000
  service     ~/reset         std_srvs/srv/Trigger: publish what is held, start over

ROS arguments go after --ros-args (e.g. --ros-args -p use_sim_time:=true).'''


#: Doubles after the header: sensor_msgs/Imu (orientation, its covariance, angular_velocity,
#: its covariance, linear_acceleration, its covariance) and
#: geometry_msgs/PoseWithCovarianceStamped (position, orientation, covariance).
_DOUBLES = {'imu': 37, 'star_tracker': 43}


def cdr_view(kind, data):
    """Return the fields the MEKF reads from a CDR message, or None for another layout.

    ``kind`` is ``'imu'`` (sensor_msgs/Imu: ``header.stamp``, ``angular_velocity``,
    ``angular_velocity_covariance``) or ``'star_tracker'``
    (geometry_msgs/PoseWithCovarianceStamped: ``header.stamp``, ``pose.pose.orientation``,
    ``pose.covariance``), as attributes of the same names. XCDR1 little endian (what rmw
    writes): the encapsulation ``00 01 00 00``, the stamp, the frame id (length, bytes),
    then the doubles aligned to 8 from after the encapsulation.
    """
    from builtin_interfaces.msg import Time
    count = _DOUBLES[kind]
    if len(data) < 16 or data[0] != 0 or data[1] != 1:
        return None
    sec, nsec, n = struct.unpack_from('<iII', data, 4)
    start = 4 + ((12 + n + 7) & ~7)
    if len(data) != start + 8 * count:
        return None
    v = struct.unpack_from(f'<{count}d', data, start)
    header = SimpleNamespace(stamp=Time(sec=sec, nanosec=nsec))
    if kind == 'imu':
        return SimpleNamespace(header=header,
                               angular_velocity=SimpleNamespace(x=v[13], y=v[14], z=v[15]),
                               angular_velocity_covariance=v[16:25])
    q = SimpleNamespace(x=v[3], y=v[4], z=v[5], w=v[6])
    return SimpleNamespace(header=header, pose=SimpleNamespace(
        pose=SimpleNamespace(orientation=q), covariance=v[7:43]))


def _parser():
    import argparse
    ap = OneLineParser(prog='rigidrot_mekf', description=__doc__.splitlines()[0],
                       epilog=TOPICS, formatter_class=argparse.RawDescriptionHelpFormatter)
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
    import signal

    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from rigidrot_ros.ros.spin import init_ros

    reason = init_ros('rigidrot_mekf', ros_args)
    if reason is not None:
        return fail('rigidrot_mekf', reason)
    stop = []

    def on_signal(signum, frame):
        if stop:
            raise KeyboardInterrupt      # a second signal: give up on the last estimates
        stop.append(signum)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)   # in place of rclpy's: ROS stays up to publish
    node = rclpy.create_node('mekf')
    mekf = _MekfNode(node, params)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        while not stop and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
        if rclpy.ok():
            mekf.flush()
    except KeyboardInterrupt:
        pass
    finally:
        executor.shutdown(0)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


class _MekfNode:
    """The MEKF on ``node``: raw subscriptions in stamp order, ``estimator/odom``, ``~/reset``."""

    def __init__(self, node, params):
        from geometry_msgs.msg import PoseWithCovarianceStamped
        from nav_msgs.msg import Odometry
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import Imu
        from std_srvs.srv import Trigger

        self.params, self._deserialize = params, deserialize_message
        qos = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pub = node.create_publisher(Odometry, 'estimator/odom', qos)
        self.start()
        self.subs = []
        in_qos = QoSProfile(depth=10000, reliability=ReliabilityPolicy.RELIABLE)
        for topic, kind, msg_type in ((params.imu_topic, 'imu', Imu),
                                      (params.star_tracker_topic, 'star_tracker',
                                       PoseWithCovarianceStamped)):
            self.subs.append((topic, kind, node.create_subscription(
                msg_type, kind, self._on(topic, kind, msg_type), in_qos, raw=True)))
        node.create_service(Trigger, '~/reset', self.on_reset)
        node.create_timer(0.2, lambda: self.order.release_old())

    def start(self):
        """Start a fresh filter and a fresh stamp order."""
        from rigidrot_ros.estimators.mekf import MEKF
        self.filter = MEKF(self.params)
        self.order = StampOrder(self.feed, (self.params.imu_topic,
                                            self.params.star_tracker_topic))

    def feed(self, topic, msg):
        """Give the filter one message in stamp order; publish what it answers."""
        for out in self.filter.receive(topic, msg):
            self.pub.publish(out)

    def push(self, topic, data, kind, msg_type):
        """Decode one raw message (a view of its CDR where it can) into the stamp order."""
        msg = cdr_view(kind, data)
        if msg is None:
            msg = self._deserialize(data, msg_type)
        self.order.push(topic, msg.header.stamp.sec * 1_000_000_000
                        + msg.header.stamp.nanosec, msg)

    def take_waiting(self):
        """Take every message already delivered to the subscriptions."""
        more = True
        while more:
            more = False
            for topic, kind, sub in self.subs:
                with sub.handle:
                    got = sub.handle.take_message(sub.msg_type, sub.raw)
                if got is not None:
                    self.push(topic, got[0], kind, sub.msg_type)
                    more = True

    def _on(self, topic, kind, msg_type):
        def cb(data):
            self.push(topic, data, kind, msg_type)
            self.take_waiting()
        return cb

    def flush(self):
        """Feed everything delivered and held; publish the last estimates; wait for acks."""
        from rclpy.duration import Duration
        self.take_waiting()
        self.order.drain()
        n = 0
        for out in self.filter.finish():
            self.pub.publish(out)
            n += 1
        self.pub.wait_for_all_acked(Duration(seconds=1.0))
        return n

    def on_reset(self, request, response):
        """Flush the run so far, then start a fresh filter (``~/reset``)."""
        n, updates = self.flush(), self.filter.updates
        self.start()
        response.success = True
        response.message = f'reset ({updates} star tracker updates, {n} last estimates)'
        return response


if __name__ == '__main__':
    sys.exit(main())
