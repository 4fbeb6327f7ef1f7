"""Polynomial phases in double-double arithmetic, reduced modulo 4 pi with a proved bound.

An angle ``phi(t) = c1 t + c2 t^2`` (rad) whose coefficients are known exactly (to
``SETUP_PREC`` bits) is evaluated in turns of the half-angle period, ``u = phi / (4 pi)``
with ``g_k = c_k / (4 pi)`` stored as double-double pairs ``g_k = hi + lo + r_k``
(``|r_k|`` measured at setup). With error-free transformations (Knuth's two-sum, Dekker's
split and two-product; Dekker 1971, Ogita-Rump-Oishi 2005) the products ``hi * t`` and
``t * t`` are exact, the leading sum is exact, and everything else is a correction some
2^-52 smaller. The integer part of the leading sum is removed exactly (``S - rint(S)`` is
exact for ``|S| < 2^52``), and the fraction is multiplied by ``4 pi`` split into two
doubles. Error, before the final rounding of the reduced angle to a float (the methods
return it net of ``IN_FLOOR``, which the samples' float64 floor covers):

    |phi_reduced - (phi mod 4 pi)| <= 4 pi (2^-100 (|g1 t| + |g2| t^2 + 1)
                                             + |r_1| |t| + |r_2| t^2),

each term of the analysis being at most a few 2^-105 |u| (see :func:`bound`). The tests
check it against mpmath at 300 bits on seeded t up to 1e9 s. It holds while the exact
steps stay exact: ``|u| <= 2^50`` turns (angles up to about 1.4e16 rad), ``t`` zero or
within ``[2^-200, 2^200]`` and the coefficients zero or within ``[2^-400, 2^400]``; outside
that, :class:`DDPoly` reports the samples as not covered and the caller evaluates them
in multiple precision.
"""

import math

import mpmath
from mpmath import mp
import numpy as np

__all__ = ['DDPoly', 'two_sum', 'two_prod', 'MAX_TURNS', 'IN_FLOOR']

#: Largest |phase| in turns of 4 pi that the double-double path covers.
MAX_TURNS = 2.0 ** 50
#: The part of a phase's bound (rad) that the samples' float64 floor (FLOAT_FLOOR of
#: :mod:`.models`, 1e-14 rad against some 4e-15 of rounding) already covers; the bounds
#: returned by :meth:`DDPoly.angles` and :meth:`DDPoly.angle` are net of it.
IN_FLOOR = 1e-18
_SPLIT = 134217729.0                    # 2^27 + 1 (Dekker's splitter)
_T_MIN, _T_MAX = 2.0 ** -200, 2.0 ** 200
_G_MIN, _G_MAX = 2.0 ** -400, 2.0 ** 400
_B_REL = 2.0 ** -100
_SETUP_BITS = 320


def two_sum(a, b):
    """Return ``(s, e)`` with ``s = fl(a + b)`` and ``s + e = a + b`` exactly (Knuth)."""
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


def _split(a):
    c = _SPLIT * a
    hi = c - (c - a)
    return hi, a - hi


def two_prod(a, b):
    """Return ``(p, e)`` with ``p = fl(a b)`` and ``p + e = a b`` exactly (Dekker).

    Exact when no overflow or underflow occurs (the callers keep |a|, |b| in range).
    """
    p = a * b
    ah, al = _split(a)
    bh, bl = _split(b)
    return p, ((ah * bh - p) + ah * bl + al * bh) + al * bl


def _dd(x):
    """Double-double (hi, lo) of an mpf and a bound on what it leaves out."""
    hi = float(x)
    lo = float(x - hi)
    rest = abs(x - hi - lo)
    return hi, lo, float(rest) * (1.0 + 2.0 ** -40)


class DDPoly:
    """Angle ``c1 t + c2 t^2`` (rad) reduced modulo 4 pi, vectorised in double-double.

    Parameters
    ----------
    c1, c2 : mpf or float
        The exact coefficients (rad/s, rad/s^2), e.g. computed at 256 bits from the
        scene's float inputs.

    Examples
    --------
    >>> ph = DDPoly(mpmath.mpf(1) / 3, 0)
    >>> angle, bound, covered = ph.angles(np.array([3e8]))
    >>> bool(covered[0]) and bound[0] < 1e-21
    True
    """

    def __init__(self, c1, c2):
        with mp.workprec(_SETUP_BITS):
            four_pi = 4 * mp.pi
            g1 = mpmath.mpf(c1) / four_pi
            g2 = mpmath.mpf(c2) / four_pi
            self.g1h, self.g1l, self.r1 = _dd(g1)
            self.g2h, self.g2l, self.r2 = _dd(g2)
            self.p_hi, self.p_lo, _ = _dd(four_pi)
        self.zero = (g1 == 0 and g2 == 0)
        self.usable = all(g == 0.0 or _G_MIN <= abs(g) <= _G_MAX for g in (self.g1h, self.g2h))
        self._ag1 = abs(self.g1h) + abs(self.g1l)
        self._ag2 = abs(self.g2h) + abs(self.g2l)
        # Dekker splits of the constants, made once (angle makes the same operations)
        self._s1, self._s2, self._sp = _split(self.g1h), _split(self.g2h), _split(self.p_hi)

    # -- vectorised ---------------------------------------------------------------------
    def angles(self, t):
        """Reduced angles, bounds and coverage at the times ``t`` (float ndarray).

        Returns
        -------
        angle : ndarray
            ``phi(t)`` reduced to about (-2 pi, 2 pi] (rad), float64.
        bound : ndarray
            Bound on the error of ``angle`` before its final rounding to float64, rad.
        covered : ndarray of bool
            False where the double-double path does not apply (then ``angle`` is
            meaningless there and the caller must evaluate in multiple precision).
        """
        t = np.asarray(t, dtype=float)
        shape = t.shape
        t = t.reshape(-1)
        if self.zero:
            return np.zeros(shape), np.zeros(shape), np.ones(shape, dtype=bool)
        at = np.abs(t)
        with np.errstate(over='ignore', invalid='ignore'):
            mag = self._ag1 * at + self._ag2 * (at * at)
        covered = ((at == 0.0) | ((at >= _T_MIN) & (at <= _T_MAX))) & (mag <= MAX_TURNS)
        if not self.usable:
            covered[...] = False
        tt = np.where(covered, t, 0.0)
        p1, e1 = two_prod(self.g1h, tt)
        l1 = self.g1l * tt
        s, se = two_prod(tt, tt)
        p2, e2 = two_prod(self.g2h, s)
        l2 = self.g2h * se + self.g2l * s
        big, sig = two_sum(p1, p2)
        low = sig + (e1 + e2) + (l1 + l2)
        k = np.rint(big)
        fh, fl = two_sum(big - k, low)
        ah, ae = two_prod(self.p_hi, fh)
        angle = ah + (ae + (self.p_hi * fl + self.p_lo * fh))
        with np.errstate(over='ignore', invalid='ignore'):
            bound = (4.0 * math.pi * 1.0000001) * (
                _B_REL * (mag + 1.0) + self.r1 * at + self.r2 * (at * at))
        bound = np.where(covered, np.maximum(bound - IN_FLOOR, 0.0), np.inf)
        return angle.reshape(shape), bound.reshape(shape), covered.reshape(shape)

    # -- one time, plain floats -----------------------------------------------------------
    def angle(self, t):
        """``(angle, bound)`` at one float time, or None where not covered (see angles)."""
        if self.zero:
            return 0.0, 0.0
        at = abs(t)
        mag = self._ag1 * at + self._ag2 * at * at
        if not self.usable or mag > MAX_TURNS or (at != 0.0 and not _T_MIN <= at <= _T_MAX):
            return None
        g1h, g2h = self.g1h, self.g2h
        p1 = g1h * t
        ah, al = self._s1
        c = _SPLIT * t                              # _split(t), inline
        th = c - (c - t)
        tl = t - th
        e1 = ((ah * th - p1) + ah * tl + al * th) + al * tl
        s = t * t
        se = ((th * th - s) + 2.0 * th * tl) + tl * tl
        p2 = g2h * s
        bh, bl = self._s2
        c = _SPLIT * s                              # _split(s)
        sh = c - (c - s)
        sl = s - sh
        e2 = ((bh * sh - p2) + bh * sl + bl * sh) + bl * sl
        l1 = self.g1l * t
        l2 = g2h * se + self.g2l * s
        big = p1 + p2
        bb = big - p1
        sig = (p1 - (big - bb)) + (p2 - bb)
        low = sig + (e1 + e2) + (l1 + l2)
        frac = big - float(round(big))
        fh = frac + low
        bb = fh - frac
        fl = (frac - (fh - bb)) + (low - bb)
        ph = self.p_hi
        x = ph * fh
        ch, cl = self._sp
        c = _SPLIT * fh                             # _split(fh)
        fhh = c - (c - fh)
        fhl = fh - fhh
        xe = ((ch * fhh - x) + ch * fhl + cl * fhh) + cl * fhl
        out = x + (xe + (ph * fl + self.p_lo * fh))
        bound = (4.0 * math.pi * 1.0000001) * (
            _B_REL * (mag + 1.0) + self.r1 * at + self.r2 * at * at)
        return out, max(bound - IN_FLOOR, 0.0)


def bound(turns, t, r1=0.0, r2=0.0):
    """Return the error limit, rad, documented above for a phase of so many turns."""
    return 4.0 * math.pi * 1.0000001 * (_B_REL * (abs(turns) + 1.0) + r1 * abs(t) + r2 * t * t)
