"""rigidrot_ros: exact analytic attitude of rotating rigid bodies, for ROS 2.

The packages, from the ground up (a package imports only those at or below its floor;
``test/project/test_layering.py`` checks it):

- ``core`` (the exact solutions, pure math) and ``runtime`` (the mechanisms of a live
  run: the look-ahead worker and its gate, the collector, real-time scheduling, the
  diagnostics windows, the environment switches);
- ``sensors`` (seeded sensor models over the exact motion) and ``msgs`` (ROS messages and
  CDR without rclpy);
- ``bag`` (rosbag2 MCAP bags: write, read, reindex);
- ``run`` (the run model without ROS: parameters, set-up, grid, schedule, streams,
  outputs, offline generation);
- ``scoring`` (estimates decoded from a bag, scored against the truth, NEES);
- ``ros`` (the one rclpy layer: the node, its recorder, spinning);
- ``campaign`` (Monte Carlo campaigns); ``estimators`` (the reference MEKF), ``tools``
  (the console scripts' thin mains); ``bench`` (the benchmark parts).
"""

__version__ = '0.1.0'
