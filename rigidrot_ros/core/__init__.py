"""Exact attitude and angular velocity of a spherical or axisymmetric rigid body.

Also the torque-free triaxial body (Euler-Poinsot, :mod:`.triaxial`).

Pure math (numpy, mpmath, optionally python-flint); nothing here imports rclpy.
Conventions: frames N (inertial) and B (body); ``R_NB`` means ``v_N = R_NB @ v_B``;
quaternions are (x, y, z, w), active, ``q_NB``; angular velocity is of B relative to N,
in B, rad/s.
"""

from .kernel import available_backends, PrecisionError
from .models import FLOAT_FLOOR, MIN_TOL, MODELS, NoExactSolution, Samples, Solution, solve
from .scene import Scene, TORQUE_FRAMES
from .triaxial import TriaxialSolution

__all__ = [
    'Scene', 'solve', 'Solution', 'Samples', 'NoExactSolution', 'PrecisionError',
    'MODELS', 'TORQUE_FRAMES', 'FLOAT_FLOOR', 'MIN_TOL', 'available_backends',
    'TriaxialSolution',
]
