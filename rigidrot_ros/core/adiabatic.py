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

from .backends import angle_prec, PrecisionError, reduce_angle, SETUP_PREC
from .quaternion import axis_floats as _axis
from .quaternion import multiply_floats as _qmul

__all__ = ['AdiabaticKernel', 'ADIABATIC_DELTA']

#: Used from this delta = (p^2 + q^2) / (4U) up: 10 eps^3 = 1.6e-13 here, and less above.
ADIABATIC_DELTA = 1e4


class AdiabaticKernel:
    """Kernel quaternion of omega_K = (p, q, r0 + U t) for delta >= ADIABATIC_DELTA.

    ``inputs``, if given, computes ``[p, q, r0, U]`` from the scene's exact inputs at the
    current mpmath precision: the phase (about ``X^2 / (2U)`` rad, 1e300 and more for
    extreme scenes) is then formed at ``log2 |phase| + ANGLE_GUARD_BITS`` bits.
    """

    method = 'adiabatic-series'

    def __init__(self, p, q, r0, U, tol, inputs=None):
        self._inputs_fn = inputs if inputs is not None else (lambda: [p, q, r0, U])
        self._at_prec = {}
        with mp.workprec(SETUP_PREC):
            p, q, r0, U = (mpmath.mpf(v) for v in (p, q, r0, U))
            self._d = mpmath.sqrt(p * p + q * q)
            self._u, self._r0 = U, r0
            eps = U / (self._d * self._d)
            psi = mpmath.atan2(q, p)
        self._df, self._uf = float(self._d), float(U)
        self._emag = (_mag(self._d), _mag(U), _mag(r0))
        self.err = 10.0 * float(eps) ** 3 + 1e-15        # + float64 composition
        self.tol = float(tol)
        self.params = {'p': float(p), 'q': float(q), 'r0': float(r0), 'U': float(U)}
        self._inputs = (p, q, r0, U)
        self._zpsi = _axis(2, float(psi))
        self._zpsi_inv = _axis(2, -float(psi))
        self._f0 = self._frame(r0)
        self.prec = SETUP_PREC
        if self.err > self.tol:
            raise PrecisionError(f'adiabatic series estimate {self.err:.2g} exceeds tol '
                                 f'{self.tol:.2g}: delta too small for it')

    def _consts(self, prec):
        """(d, U, r0, Phi(r0)) at ``prec`` bits, cached."""
        c = self._at_prec.get(prec)
        if c is None:
            with mp.workprec(prec):
                p, q, r0, u = (mpmath.mpf(v) for v in self._inputs_fn())
                d = mpmath.sqrt(p * p + q * q)
                c = (d, u, r0, self._phase(r0, d, u))
            self._at_prec[prec] = c
        return c

    @staticmethod
    def _phase(x, d, u):
        """Antiderivative of R_2 dt in X (current mp precision)."""
        r = mpmath.sqrt(x * x + d * d)
        return (x * r + d * d * mpmath.asinh(x / d)) / (2 * u) + \
            u / (6 * d * d) * x * (2 * x * x + 3 * d * d) / (r * r * r)

    def _frame(self, x):
        """Return the frame F at X = x (mpf): rotations about e2 (theta), e1 (alpha), e2 (beta).

        In floats where the scale is moderate, else in 64-bit mpmath (no overflow): the
        angles depend only on ratios.
        """
        d, u = self._df, self._uf
        xf = float(x)
        if 1e-40 < d < 1e40 and 1e-40 < u < 1e40 and abs(xf) < 1e40:   # no over/underflow
            r = math.hypot(xf, d)
            theta = math.atan2(d, xf)
            th_dot = -d * u / (r * r)
            r1 = math.hypot(r, th_dot)
            g = d * u / r ** 3
            alpha = math.atan(g)
            alpha_dot = (-3.0 * d * u * u * xf / r ** 5) / (1.0 + g * g)
            beta = math.atan2(alpha_dot, r1)
        else:
            with mp.workprec(64):
                d, u, x = self._d, self._u, +x
                r = mpmath.hypot(x, d)
                theta = float(mpmath.atan2(d, x))
                th_dot = -d * u / (r * r)
                r1 = mpmath.hypot(r, th_dot)
                g = d * u / r ** 3
                alpha = float(mpmath.atan(g))
                alpha_dot = (-3 * d * u * u * x / r ** 5) / (1 + g * g)
                beta = float(mpmath.atan2(alpha_dot, r1))
        return _qmul(_qmul(_axis(1, theta), _axis(0, alpha)), _axis(1, beta))

    def evaluate(self, t):
        """Quaternion (x, y, z, w) at t and the error estimate (component 2-norm)."""
        # |Phi| <= max(|X|, d)^2 / U (times a small factor) at X(0) and X(t)
        ed, eu, er = self._emag
        et = max(er, eu + (math.frexp(t)[1] if t else -2000)) + 1
        prec = angle_prec(2 * max(ed, et) - eu + 4)
        d, u, r0, s0 = self._consts(prec)
        with mp.workprec(prec):
            x = r0 + u * mpmath.mpf(t)
            phi = reduce_angle(self._phase(x, d, u) - s0)
        fx, fy, fz, fw = self._frame(x)
        g = _qmul(_qmul(self._f0, _axis(2, phi)), (-fx, -fy, -fz, fw))
        q = _qmul(_qmul(self._zpsi, g), self._zpsi_inv)
        return np.array(q), self.err


def _mag(x):
    """Return an integer e with ``|x| <= 2^e`` (a large negative one for zero)."""
    return -100000 if x == 0 else int(mpmath.mag(x))
