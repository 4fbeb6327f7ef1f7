"""ROS messages without rclpy: samples -> message fields, CDR encoding, message definitions.

``messages`` (samples -> ROS message objects and their covariances), ``cdr`` (fixed-size
messages encoded to CDR bytes directly, vectorised) and ``msgdefs`` (the ``.msg`` texts MCAP
schemas carry).
"""
