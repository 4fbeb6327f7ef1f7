"""Exact attitude and angular velocity of a rotating rigid body.

Romano's exact solutions (spherical and axisymmetric bodies, torque-free or under a
constant torque fixed in the body or in the virtual sphere, :mod:`.models`, with their
constants from :mod:`.constants`) and the torque-free triaxial body (Euler-Poinsot,
:mod:`.triaxial`). :func:`solve` (:mod:`.registry`) classifies a :class:`Scene`
(:mod:`.classify`) and builds the solution class its model is registered with
(:data:`SOLUTIONS`); every solution is a :class:`BaseSolution` (:mod:`.solution`) with
``at``, ``omega_at``, ``omega_dot_at``, ``torque_body_at``, ``rate_envelope``, ``model``,
``method``, ``tol`` and ``scene``. Beneath them: the spherical-body kernel
(:mod:`.kernel`; :mod:`.method` picks its evaluation: 1F1 with :mod:`.backends`,
:mod:`.taylor`, :mod:`.adiabatic`), dense output (:mod:`.dense`, :mod:`.engine`,
:mod:`.ddphase`), the :class:`Scene` (:mod:`.scene`) and quaternion helpers
(:mod:`.quaternion`).

Pure math (numpy, mpmath, optionally python-flint); nothing here imports rclpy.
Conventions: frames N (inertial) and B (body); ``R_NB`` means ``v_N = R_NB @ v_B``;
quaternions are (x, y, z, w), active, ``q_NB``; angular velocity is of B relative to N,
in B, rad/s.
"""

from .classify import NoExactSolution
from .kernel import available_backends, PrecisionError
from .models import Solution
from .registry import MIN_TOL, MODELS, SOLUTIONS, solve
from .scene import Scene, TORQUE_FRAMES
from .solution import BaseSolution, FLOAT_FLOOR, RateEnvelope, Samples
from .triaxial import TriaxialSolution

__all__ = [
    'Scene', 'solve', 'Solution', 'Samples', 'NoExactSolution', 'PrecisionError',
    'MODELS', 'TORQUE_FRAMES', 'FLOAT_FLOOR', 'MIN_TOL', 'available_backends',
    'TriaxialSolution', 'BaseSolution', 'RateEnvelope', 'SOLUTIONS',
]
