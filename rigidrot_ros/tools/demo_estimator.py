"""rigidrot_demo_estimator: a deliberately simple attitude estimator to score.

Dead reckoning: it integrates the node's ``angular_velocity`` with one first-order step
per message, ``q <- normalise(q ⊗ exp(omega dt / 2))`` with omega held from the previous
message, starting from the first ``attitude`` it hears, and publishes
``estimator/attitude`` (QuaternionStamped, same stamps). Its error grows with time: a
template for plugging a real filter into the record -> compare loop.
"""

import sys

from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
import numpy as np
import rclpy

from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.node.spin import spin_until_shutdown


def main(args=None):
    """Entry point of ``rigidrot_demo_estimator``."""
    rclpy.init(args=args)
    node = rclpy.create_node('demo_estimator')
    pub = node.create_publisher(QuaternionStamped, 'estimator/attitude', 100)
    state = {'q': None, 'w': None, 'stamp': None}

    def on_attitude(msg):
        if state['q'] is None:
            q = msg.quaternion
            state['q'] = np.array([q.x, q.y, q.z, q.w])

    def on_rate(msg):
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        w = np.array([msg.vector.x, msg.vector.y, msg.vector.z])
        if state['q'] is None:
            return
        if state['stamp'] is not None and state['w'] is not None:
            dt = (stamp - state['stamp']) * 1e-9
            q = quat.multiply(state['q'], quat.from_rotvec(state['w'] * dt))
            state['q'] = q / np.linalg.norm(q)
        state['w'], state['stamp'] = w, stamp
        out = QuaternionStamped()
        out.header = msg.header
        out.header.frame_id = 'inertial'
        out.quaternion.x, out.quaternion.y, out.quaternion.z, out.quaternion.w = (
            float(v) for v in state['q'])
        pub.publish(out)

    node.create_subscription(QuaternionStamped, 'attitude', on_attitude, 100)
    node.create_subscription(Vector3Stamped, 'angular_velocity', on_rate, 100)
    spin_until_shutdown(node)
    return 0


if __name__ == '__main__':
    sys.exit(main())
