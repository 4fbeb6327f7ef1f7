"""Bags on disk: rosbag2-compatible MCAP writing and tolerant reading (no rclpy here)."""
