"""Superadiabatic evaluation of the spherical-body kernel for very small torque.

With ``omega_K = (p, q, X(t))``, ``X = r0 + U t``, ``d = |p + i q|`` and
``eps = U / d^2 = 1 / (4 delta)``, the body rate turns slowly compared with the rotation
about it. Frames that follow it, one per order of eps (rotations about the second, first,
second axes by

    theta = atan2(d, X),   alpha = atan(d U / R^3),   beta = atan2(alpha', R_1),

``R = sqrt(X^2 + d^2)``, ``R_1 = sqrt(R^2 + theta'^2)``, ``theta' = -d U / R^2``), leave a rate
along the last third axis of magnitude ``R_2 = R + theta'^2 / (2R) + O(eps^4 R)`` and a
transverse rate ``beta' = O(eps^3 R)``. Neglecting the latter moves the attitude by
``O(eps^3)`` uniformly in t (the neglected rate is averaged by the fast rotation; it does
not accumulate), and the phase

    Phi(t) = int_0^t R_2 dt = [x R(x) + d^2 asinh(x/d)] / (2U)
             + (U / (6 d^2)) [x (2x^2 + 3d^2) / R(x)^3]      from X(0) to X(t)

is elementary (its neglected part integrates to O(eps^3)). So

    q_NK(t) = q_z(psi) ⊗ F(0) ⊗ q_z(Phi(t)) ⊗ F(t)^-1 ⊗ q_z(-psi),   psi = arg(p + i q),

with F the product of the three frame rotations: O(1) cost at any horizon. The error is an
estimate, ``10 eps^3`` (not certified): this module is used only where that is far below
tol (delta >= ADIABATIC_DELTA), and the tests check it against the certified Taylor
continuation.
"""

import math

import mpmath
from mpmath import mp
import numpy as np

from .backends import PrecisionError, reduce_angle, SETUP_PREC
from .quaternion import axis_floats as _axis
from .quaternion import multiply_floats as _qmul

__all__ = ['AdiabaticKernel', 'ADIABATIC_DELTA']

#: Used from this delta = (p^2 + q^2) / (4U) up: 10 eps^3 = 1.6e-13 here, and less above.
ADIABATIC_DELTA = 1e4


class AdiabaticKernel:
    """Kernel quaternion of omega_K = (p, q, r0 + U t) for delta >= ADIABATIC_DELTA."""

    method = 'adiabatic-series'

    def __init__(self, p, q, r0, U, tol):
        with mp.workprec(SETUP_PREC):
            p, q, r0, U = (mpmath.mpf(v) for v in (p, q, r0, U))
            self._d = mpmath.sqrt(p * p + q * q)
            self._u, self._r0 = U, r0
            self._s0 = self._phase(r0)
            eps = U / (self._d * self._d)
            psi = mpmath.atan2(q, p)
        self._df, self._uf = float(self._d), float(U)
        self.err = 10.0 * float(eps) ** 3 + 1e-15        # + float64 composition
        self.tol = float(tol)
        self.params = {'p': float(p), 'q': float(q), 'r0': float(r0), 'U': float(U)}
        self._inputs = (p, q, r0, U)
        self._zpsi = _axis(2, float(psi))
        self._zpsi_inv = _axis(2, -float(psi))
        self._f0 = self._frame(float(r0))
        self.prec = SETUP_PREC
        if self.err > self.tol:
            raise PrecisionError(f'adiabatic series estimate {self.err:.2g} exceeds tol '
                                 f'{self.tol:.2g}: delta too small for it')

    def _phase(self, x):
        """Antiderivative of R_2 dt in X (current mp precision)."""
        d, u = self._d, self._u
        r = mpmath.sqrt(x * x + d * d)
        return (x * r + d * d * mpmath.asinh(x / d)) / (2 * u) + \
            u / (6 * d * d) * x * (2 * x * x + 3 * d * d) / (r * r * r)

    def _frame(self, x):
        """Return the frame F at X = x: rotations about e2 (theta), e1 (alpha), e2 (beta)."""
        d, u = self._df, self._uf
        r = math.hypot(x, d)
        theta = math.atan2(d, x)
        th_dot = -d * u / (r * r)
        r1 = math.hypot(r, th_dot)
        g = d * u / r ** 3
        alpha = math.atan(g)
        alpha_dot = (-3.0 * d * u * u * x / r ** 5) / (1.0 + g * g)
        beta = math.atan2(alpha_dot, r1)
        return _qmul(_qmul(_axis(1, theta), _axis(0, alpha)), _axis(1, beta))

    def evaluate(self, t):
        """Quaternion (x, y, z, w) at t and the error estimate (component 2-norm)."""
        with mp.workprec(SETUP_PREC):
            x = self._r0 + self._u * mpmath.mpf(t)
            phi = reduce_angle(self._phase(x) - self._s0)
            xf = float(x)
        fx, fy, fz, fw = self._frame(xf)
        g = _qmul(_qmul(self._f0, _axis(2, phi)), (-fx, -fy, -fz, fw))
        q = _qmul(_qmul(self._zpsi, g), self._zpsi_inv)
        return np.array(q), self.err
