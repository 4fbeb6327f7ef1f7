"""Sensor models over the exact motion: pure math, seeded, no ROS.

Error models (:mod:`.noise`, :mod:`.imu_noise`: white noise, bias random walk,
Gauss-Markov and turn-on bias, scale factor, misalignment, quantisation) are kept apart
from the sensors that sample the exact motion (:mod:`.sensors`: the rate-integrating gyro
and the star tracker; :mod:`.batch`: the gyro over a block of intervals; :mod:`.accel`:
the accelerometer and its exact delta-v; :mod:`.mag`: the magnetometer), as gz-sensors
keeps its noise models apart from its sensors. :mod:`.increments` holds the exact
delta-angle and delta-rotation, :mod:`.kalibr` the import of Kalibr's ``imu.yaml``.
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
