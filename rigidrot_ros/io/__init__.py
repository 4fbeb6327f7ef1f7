"""Bags and messages: MCAP on disk, decoding, scoring, recording.

``bag`` (rosbag2-compatible MCAP writing, tolerant reading, reindex), ``decode``
(messages -> attitude/rate streams with covariances) and ``score`` (against the exact
truth, NEES) import no rclpy; ``recorder`` (the recording component of the node and of
rigidrot_record) and ``messages`` (samples -> ROS messages) are the ROS side.
"""
