"""A ROS estimator that misbehaves one way, for the campaign's failure tests.

``python bad_estimator_node.py MODE``: ``exit`` exits with status 3 at once (cannot
start); ``deaf`` runs but subscribes to nothing; ``wrong_type`` answers each gyro sample
with a std_msgs/String on estimator/odom; ``silent`` subscribes and never publishes;
``crash`` raises at the 50th gyro sample; ``hang`` answers, then stops taking messages
at the 50th gyro sample and ignores SIGINT.
"""

import signal
import sys
import time

import rclpy
from rclpy.node import Node
from sensor_msgs.msg import Imu
from std_msgs.msg import String


def main():
    """Misbehave as told by argv[1]."""
    mode = sys.argv[1]
    if mode == 'exit':
        print('bad estimator: refusing to start', file=sys.stderr)
        sys.exit(3)
    rclpy.init()
    node = Node('bad_estimator')
    if mode == 'wrong_type':
        pub = node.create_publisher(String, 'estimator/odom', 100)
    else:
        from nav_msgs.msg import Odometry
        pub = node.create_publisher(Odometry, 'estimator/odom', 100)
    count = [0]

    def on_imu(msg):
        count[0] += 1
        if mode == 'wrong_type':
            pub.publish(String(data='not an estimate'))
        elif mode == 'crash' and count[0] == 50:
            raise RuntimeError('bad estimator: crashed at the 50th gyro sample')
        elif mode == 'hang' and count[0] == 50:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            while True:
                time.sleep(1.0)
    if mode != 'deaf':
        node.create_subscription(Imu, 'imu', on_imu, 100)
        from geometry_msgs.msg import PoseWithCovarianceStamped
        node.create_subscription(PoseWithCovarianceStamped, 'star_tracker', lambda m: None,
                                 100)
    rclpy.spin(node)


if __name__ == '__main__':
    main()
