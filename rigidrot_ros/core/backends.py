"""Shared numerics of the kernels: working precision, angle reduction, 1F1 backends.

A leaf module: the kernels (:mod:`.kernel`, :mod:`.taylor`, :mod:`.adiabatic`) import it
and not each other; :mod:`.method` chooses among them.
"""

import math

import mpmath
from mpmath import mp

__all__ = ['PrecisionError', 'SETUP_PREC', 'reduce_angle', 'angle_prec', 'ANGLE_GUARD_BITS',
           'available_backends', 'make_backend']

#: Bits used for per-scene constants (exact float inputs carried far beyond float64).
SETUP_PREC = 256
_FOUR_PI_CACHE = {}


class PrecisionError(ArithmeticError):
    """The special-function evaluation did not reach the requested accuracy."""


def _four_pi():
    p = mp.prec
    if p not in _FOUR_PI_CACHE:
        _FOUR_PI_CACHE[p] = 4 * mp.pi
    return _FOUR_PI_CACHE[p]


def reduce_angle(x):
    """Reduce an mpf angle modulo 4 pi (the period of the half-angle) to a float.

    Exact to the current mp precision: the caller must carry ``log2 |x| + 70`` bits (see
    :func:`angle_prec`) for the result to be good to float64.
    """
    four_pi = _four_pi()
    return float(x - four_pi * mpmath.nint(x / four_pi))


#: Bits carried beyond ``log2 |angle|`` so that an angle reduced modulo 4 pi keeps about
#: 2^-70 rad absolute accuracy (constants and 4 pi have relative error ~2^-prec).
ANGLE_GUARD_BITS = 80


def angle_prec(mag):
    """Working precision (bits) for an angle with ``|angle| <= 2^mag``: SETUP_PREC or more.

    Rounded up to a multiple of 64 so that precisions (and their cached constants) repeat.
    """
    need = int(mag) + ANGLE_GUARD_BITS
    if need <= SETUP_PREC:
        return SETUP_PREC
    return -(-need // 64) * 64


def _t_mag(t):
    """Return an integer e with ``|t| < 2^e`` (t a finite float; 0 gives a large negative e)."""
    return math.frexp(t)[1] if t != 0.0 else -2000


class _Exact:
    """Per-scene constants computed from exact float inputs at any precision, cached.

    ``source`` is a number (taken as exact) or a function of no arguments that computes
    the value (or a list of values) at the current mpmath precision.
    """

    def __init__(self, source):
        self._source = source
        self._cache = {}

    def at(self, prec):
        """Return the value(s) at ``prec`` bits."""
        v = self._cache.get(prec)
        if v is None:
            with mp.workprec(prec):
                v = self._source() if callable(self._source) else self._source
                v = [+mpmath.mpf(x) for x in v] if isinstance(v, (list, tuple)) \
                    else +mpmath.mpf(v)
            self._cache[prec] = v
        return v


def _mag(x):
    """``mpmath.mag`` with -inf for zero replaced by a large negative integer."""
    return -100000 if x == 0 else int(mpmath.mag(x))


# ---------------------------------------------------------------------------------------
# special-function backends

class _MpmathBackend:
    name = 'mpmath'
    certified = False

    @staticmethod
    def workprec(p):
        return mp.workprec(p)

    @staticmethod
    def real(x):
        return mpmath.mpf(x)

    @staticmethod
    def cplx(re, im):
        return mpmath.mpc(re, im)

    @staticmethod
    def hyp1f1(a, b, z):
        try:
            return mpmath.hyp1f1(a, b, z)
        except mpmath.libmp.NoConvergence as exc:
            raise PrecisionError(f'mpmath hyp1f1 did not converge: {exc}') from None

    @staticmethod
    def exp(z):
        return mpmath.exp(z)

    @staticmethod
    def abs(z):
        return float(abs(z))

    @staticmethod
    def parts(z):
        """(re mid, im mid, radius) as floats; mpmath numbers carry no radius."""
        return float(z.real), float(z.imag), 0.0


class _FlintBackend:
    name = 'flint'
    certified = True

    def __init__(self):
        import flint
        self.flint = flint

    def workprec(self, p):
        return self.flint.ctx.workprec(p)

    def prec(self):
        """Return the working precision, bits."""
        return self.flint.ctx.prec

    def real(self, x):
        """Exact (or correctly rounded) conversion of an mpf/float to an arb ball."""
        if type(x) is float:
            return self.flint.arb(x)            # exact: a double is a binary fraction
        # mpmath.mpf(mpf) would round to the ambient precision: read the bits directly
        if not isinstance(x, mpmath.mpf):
            with mp.workprec(SETUP_PREC):
                x = mpmath.mpf(x)
        sign, man, exp, _ = x._mpf_
        if man == 0:
            return self.flint.arb(0)
        val = self.flint.arb(self.flint.fmpz(-man if sign else man))
        return val * self.flint.arb(2) ** exp if exp >= 0 else val / self.flint.arb(2) ** (-exp)

    def cplx(self, re, im):
        return self.flint.acb(self.real(re), self.real(im))

    @staticmethod
    def hyp1f1(a, b, z):
        return z.hypgeom_1f1(a, b)

    @staticmethod
    def hypu(a, b, z, n=-1):
        """Tricomi's U(a, b, z), principal branch.

        ``n >= 0``: Arb's asymptotic series with n terms (its error bound is rigorous
        whatever n; a poor n only widens the ball); -1: Arb chooses the method and terms.
        """
        if n < 0:
            return z.hypgeom_u(a, b)
        return z.hypgeom_u(a, b, n=n, asymp=True)

    def gamma(self, z):
        return z.gamma()

    def pi_i(self):
        return self.flint.acb(0, self.flint.arb.pi())

    @staticmethod
    def sqrt(z):
        return z.sqrt()

    @staticmethod
    def far_ok(s2, far_z):
        """Whether ``z = i s2 / 2`` (s2 = s^2 a real ball) lies at |z| >= far_z, Im z > 0."""
        return bool(s2.real > 2.0 * far_z) and s2.imag == 0

    @staticmethod
    def exp(z):
        return z.exp()

    @staticmethod
    def abs(z):
        return float(abs(z).upper())

    @staticmethod
    def radius(z):
        """Radius of a complex ball (2-norm of its parts' radii), float."""
        return math.hypot(float(z.real.rad()), float(z.imag.rad()))

    @staticmethod
    def parts(z):
        re, im = z.real, z.imag
        rad = math.hypot(float(re.rad()), float(im.rad()))
        if not (re.is_finite() and im.is_finite()):
            return math.nan, math.nan, math.inf
        return float(re.mid()), float(im.mid()), rad


def available_backends():
    """Names of the installed special-function backends, fastest first."""
    names = []
    try:
        import flint  # noqa: F401
        names.append('flint')
    except ImportError:
        pass
    names.append('mpmath')
    return names


def make_backend(name):
    if name == 'flint':
        try:
            return _FlintBackend()
        except ImportError:
            raise ValueError("backend 'flint' needs python-flint: pip install python-flint") \
                from None
    if name == 'mpmath':
        return _MpmathBackend()
    raise ValueError(f"backend must be None, 'flint' or 'mpmath', got {name!r}")
