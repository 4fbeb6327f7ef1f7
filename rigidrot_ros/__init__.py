"""rigidrot_ros: exact analytic attitude of rotating rigid bodies, for ROS 2."""

__version__ = '0.1.0'
