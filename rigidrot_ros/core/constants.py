"""The constants of Romano's models at any mp precision, from a scene's exact float inputs.

Frames (as in :mod:`.models`): B the body (principal axes); B' the body axes cyclically
permuted so that the symmetry axis is the third (:func:`cyclic` gives ``R_B'B``); S the
virtual sphere, equal to B' at t = 0; K fixed in S with its third axis along the torque.
:func:`constants_at_prec` returns the scene's constants in those frames (moments,
omega0 and the torque in S, ``q_SK``, omega in K, the coefficients of ``f(t)``) at the
current mp precision, each precision computed once; :func:`transverse_sq` is the squared
transverse rate in K exactly, in rationals. Quaternions are (x, y, z, w), active.
"""

from fractions import Fraction

import mpmath
from mpmath import mp
import numpy as np

__all__ = ['cyclic', 'transverse_sq', 'mag', 'constants_at_prec', 'const', 'check_accel']


def cyclic(k):
    """Proper rotation ``R_B'B`` (rows e_{k+1}, e_{k+2}, e_k) moving axis k to the third."""
    eye = np.eye(3)
    return np.stack([eye[(k + 1) % 3], eye[(k + 2) % 3], eye[k]])


def _q_from_e3(u):
    """Return the unit quaternion (mpf, x y z w) of a rotation taking e3 to unit u."""
    ux, uy, uz = u
    if uz >= 0:
        qv = [-uy, ux, mpmath.mpf(0), 1 + uz]
    else:
        # rotate e3 -> -e3 by pi about e1, then -e3 -> u
        qa = [uy, -ux, mpmath.mpf(0), 1 - uz]
        n = mpmath.sqrt(sum(c * c for c in qa))
        qa = [c / n for c in qa]
        ax, ay, az, aw = qa
        qv = [aw, az, -ay, -ax]  # qa ⊗ (1, 0, 0, 0)
    n = mpmath.sqrt(sum(c * c for c in qv))
    return [c / n for c in qv]


def _rotate_inverse(qv, v):
    """``R(q)^T v`` at the current mp precision (q unit, x y z w)."""
    x, y, z, w = qv
    r = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
         [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
         [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    return [sum(r[j][i] * v[j] for j in range(3)) for i in range(3)]


def transverse_sq(w0, m, i_t, i_3):
    """Exact ``|omega_S x m|^2 / |m|^2`` (Fraction): the squared transverse rate in K."""
    a = [Fraction(i_t) * Fraction(w0[0]), Fraction(i_t) * Fraction(w0[1]),
         Fraction(i_3) * Fraction(w0[2])]                      # I omega_S
    b = [Fraction(v) for v in m]
    c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    return sum(x * x for x in c) / (sum(x * x for x in b) * Fraction(i_t) ** 2)


def mag(x):
    """Return an integer e with ``|x| <= 2^e`` (a large negative one for zero)."""
    return -100000 if x == 0 else int(mpmath.mag(x))


def constants_at_prec(i_t, i_3, w0f, mf):
    """Return ``constants()``: the scene constants at the current mp precision, cached.

    From the exact float inputs: the transverse and axial moments, omega0 and the torque
    in B'.
    """
    cache = {}

    def constants():
        """Scene constants at the current mp precision, from the exact float inputs."""
        c = cache.get(mp.prec)
        if c is not None:
            return c
        mI, mI3 = mpmath.mpf(i_t), mpmath.mpf(i_3)
        r0s = mI3 * w0f[2] / mI                            # omega_S3(0) = (I3/I) r0
        w_s = [mpmath.mpf(w0f[0]), mpmath.mpf(w0f[1]), r0s]
        ms = [mpmath.mpf(v) for v in mf]
        mnorm = mpmath.sqrt(sum(v * v for v in ms))
        c = cache[mp.prec] = {
            'mI': mI, 'mI3': mI3, 'w_s': w_s, 'ms': ms, 'mnorm': mnorm,
            # f(t) = A ((I3/I) r0 t + (m3/I) t^2 / 2), A = (I - I3) / I3; zero for a
            # sphere and a fixed axis
            'c1': (mI - mI3) * w0f[2] / mI,
            'c2': (mI - mI3) * ms[2] / (2 * mI * mI3),
            'r0': mpmath.mpf(w0f[2]), 'rdot': ms[2] / mI3,
        }
        if mnorm != 0:
            q_sk = _q_from_e3([v / mnorm for v in ms])
            c['q_sk'] = q_sk
            c['wk'] = _rotate_inverse(q_sk, w_s)          # omega_K = R_KS omega_S
            c['U'] = mnorm / mI
        return c

    return constants


def const(constants, name, i=None):
    """Return a function giving one constant at the current mp precision."""
    if i is None:
        return lambda: constants()[name]
    return lambda: constants()[name][i]


def check_accel(c, scene):
    """Raise ValueError if torque / inertia is beyond float64's range (c: the constants)."""
    ms = c['ms']
    mI, mI3 = c['mI'], c['mI3']
    accel = max(abs(v) for v in ms) / min(mI, mI3)
    if accel > np.finfo(float).max:
        raise ValueError(
            f'torque / inertia reaches {mpmath.nstr(accel, 3)} rad/s^2: beyond the '
            f'float64 range (1.8e308) of the body rates returned; scale torque '
            f'{scene.torque} N m or inertia {scene.inertia} kg m^2 into range')
