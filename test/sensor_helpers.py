"""Helpers that test_sensors.py shares with other test modules."""

import mpmath
from mpmath import mp


# -- exact increments -------------------------------------------------------------------------
def _mp_rate(scene):
    """Return the closed-form body rate at 30 digits (Romano 2008, Eq. 39, 47, 56, 58).

    In body axes B' (symmetry axis third): omega_S = omega_S(0) + (m / I) t in the
    virtual sphere, omega_B' = (Rz(-f) omega_S transverse, r0 + (m3 / I3) t),
    f = A ((I3 / I) r0 t + (m3 / I) t^2 / 2), A = (I - I3) / I3.
    """
    inertia = scene.inertia
    ks = [k for k in range(3) if inertia[(k + 1) % 3] == inertia[(k + 2) % 3]]
    k = ks[0] if ks else 2
    i1, i2 = (k + 1) % 3, (k + 2) % 3
    with mp.workdps(40):
        it, i3 = mpmath.mpf(inertia[i1]), mpmath.mpf(inertia[k])
        a_c = (it - i3) / i3
        w0 = [mpmath.mpf(v) for v in scene.omega0]
        m = [mpmath.mpf(v) for v in scene.torque]

    def rate(t):
        a = w0[i1] + m[i1] / it * t
        b = w0[i2] + m[i2] / it * t
        f = a_c * (i3 / it * w0[k] * t + m[k] / it * t * t / 2)
        out = [None] * 3
        out[i1] = a * mpmath.cos(f) + b * mpmath.sin(f)
        out[i2] = -a * mpmath.sin(f) + b * mpmath.cos(f)
        out[k] = w0[k] + m[k] / i3 * t
        return out
    return rate
