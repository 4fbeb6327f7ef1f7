"""Sensor models over the exact motion: pure math, seeded, no ROS.

Error models (:mod:`.noise`) are kept apart from the sensors that sample the exact motion
(:mod:`.sensors`), as gz-sensors keeps its noise models apart from its sensors.
Conventions: frames N inertial, B body; quaternions (x, y, z, w), active, ``q_NB``;
rates of B relative to N, in B, rad/s.
"""

from .accel import (
    Accelerometer, AccelReading, delta_velocity, DV_TOL, specific_force, STANDARD_GRAVITY,
)
from .imu_noise import ImuNoise, ImuSample
from .increments import delta_angle, delta_rotation, DELTA_TOL, RateBound
from .increments import rotvec_from_quaternion
from .kalibr import load_kalibr_imu
from .mag import EARTH_FIELD, Magnetometer, MagReading
from .noise import ARCSEC, AttitudeNoise, GyroNoise
from .sensors import Gyro, GyroReading, StarTracker, StarTrackerReading

__all__ = ['delta_angle', 'delta_rotation', 'rotvec_from_quaternion', 'RateBound',
           'DELTA_TOL', 'ARCSEC', 'GyroNoise', 'AttitudeNoise', 'Gyro', 'GyroReading',
           'StarTracker', 'StarTrackerReading', 'ImuNoise', 'ImuSample', 'Accelerometer',
           'AccelReading', 'delta_velocity', 'specific_force', 'DV_TOL', 'STANDARD_GRAVITY',
           'Magnetometer', 'MagReading', 'EARTH_FIELD', 'load_kalibr_imu']
