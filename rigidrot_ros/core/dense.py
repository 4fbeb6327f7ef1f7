"""Dense output: many samples of the exact spinor from few exact evaluations.

The time axis is cut into a fixed grid of windows: each octave ``[2^e, 2^(e+1))`` of |t|
(and ``[0, 1)``) into windows of one power-of-two width ``h`` with ``R h <= RT`` and
``U h^2 <= RT`` (``R`` the largest rate ``sqrt(X^2 + |D|^2)`` in the octave). Window
boundaries are exact floats, so ``t - a`` is exact (Sterbenz), and a window is the same
whichever query builds it. Inside a window anchored at ``a`` (the end nearer t = 0) the
exact solution's own Taylor series about ``a`` (the recurrence of :mod:`.taylor`, in
float64) gives every sample by Horner's rule; the window's end value is the next window's
anchor ("chaining"), until the accumulated bound reaches half the kernel's tol, when the
next anchor is evaluated exactly again (1F1, certified Taylor continuation or the
adiabatic series). Nothing accumulates past that.

Bound for every sample of a window (2-norm of the spinor error), all terms a priori:

    E_a                                   the anchor's bound (exact or chained)
    + 4 max(m_N h^N, m_(N-1) h^(N-1))     the truncated tail (majorant ratio <= 1/4)
    + 8.1 eps sum n m_n h^n               rounding in the coefficient recurrence
    + 2.02 eps sum (n + 1) m_n h^n        rounding in Horner's rule (scalar calls, chaining)
    + (dX + dD) h / 2 + dU h^2 / 4        float64 parameters against the exact ones

with the majorant ``(n + 1) m_(n+1) = (R_a/2) m_n + (U/2) m_(n-1)``, ``m_0 = 1 + E_a``
(``H_a`` is Hermitian with norm ``R_a``, so ``|c_n| <= m_n``). A rounding error made at
coefficient n propagates under the same majorant, so the computed coefficients are off
by at most ``m_n sum_(k<=n) rho_k / m_k`` with ``rho_k <= 7.5 eps m_k`` (one complex
product and real products and sums per step). Horner's rule with real ``dt`` makes two
roundings per step, each relative to a partial sum bounded by ``sum_(j>=k) m_j h^(j-k)``.
The last line is Duhamel's bound for a generator off by at most ``dX + dU |dt| + dD``
(the float inputs and the float ``X_a = r0 + U a`` against the exact inputs), under
unitary propagators. A window whose bound exceeds the kernel's tol is evaluated sample
by sample (certified) instead.
"""

from collections import OrderedDict
import math

import mpmath
from mpmath import mp
import numpy as np

__all__ = ['DenseSpinor', 'dense_spinor', 'RT']

_EPS = 2.0 ** -52
#: Window size in radians turned: ``R h <= RT``. Measured here: 2 gives about 1e-14
#: per window with 20-term series; 4 would need 30 terms and give 5e-14.
RT = 2.0
#: Windows kept for scalar calls (about 1 kB each).
CACHE = 4096
#: A window whose predecessor is uncached walks back this many windows to chain.
WALK = 8


class _Win:
    __slots__ = ('a', 'h', 'sign', 'c1', 'c2', 'arr', 'bound', 'bound_mm', 'own', 'end', 'ok')


class DenseSpinor:
    """Windowed dense output of a spinor kernel (see the module docstring).

    Parameters
    ----------
    kernel : HyperKernel, TaylorKernel or AdiabaticKernel
        Has ``params`` (float p, q, r0, U), ``_inputs`` (the exact mpf inputs), ``tol``
        and ``evaluate(t) -> (quaternion, bound)``.
    """

    def __init__(self, kernel):
        self.kernel = kernel
        pr = kernel.params
        self.p, self.q, self.r0, self.u = pr['p'], pr['q'], pr['r0'], pr['U']
        self.d = complex(self.p, self.q)
        self.dbar = self.d.conjugate()
        self.dabs = abs(self.d)
        with mp.workprec(256):
            ex = [mpmath.mpf(v) for v in kernel._inputs]
            fl = (self.p, self.q, self.r0, self.u)
            dp, dq, dr, du = (abs(e - f) for e, f in zip(ex, fl))
            self.d_r0 = float(dr) * 1.0001
            self.d_u = float(du) * 1.0001
            self.d_d = float(mpmath.sqrt(dp * dp + dq * dq)) * 1.0001
        self.tol = kernel.tol
        self.chain_limit = 0.5 * self.tol
        self._octaves = {}
        self._cache = OrderedDict()
        self.exact_anchors = 0
        self.windows_built = 0

    # -- the grid -------------------------------------------------------------------------
    def _rate(self, t):
        return math.hypot(abs(self.r0 + self.u * t), self.dabs)

    def _octave(self, sign, e):
        """(start, end, h) of octave e (-1: [0, 1)) in direction sign; h None: no windows."""
        key = (sign, e)
        o = self._octaves.get(key)
        if o is None:
            lo, hi = (0.0, 1.0) if e < 0 else (math.ldexp(1.0, e), math.ldexp(1.0, e + 1))
            rmax = max(self._rate(sign * lo), self._rate(sign * hi)) * (1 + 1e-12)
            h = hi - lo
            if rmax * h > RT:
                h = math.ldexp(1.0, math.floor(math.log2(RT / rmax)))
            if self.u * h * h > RT:
                h = math.ldexp(1.0, math.floor(0.5 * math.log2(RT / self.u)))
            h = min(h, hi - lo)
            if h < math.ldexp(hi, -45):
                h = None                          # windows shorter than float spacing
            o = self._octaves[key] = (lo, hi, h)
        return o

    @staticmethod
    def _exponent(at):
        if at < 1.0:
            return -1
        return math.frexp(at)[1] - 1

    def key(self, t):
        """Return the (sign, e, j) identifying the window of a time; None: no windows there."""
        sign = -1 if t < 0 else 1
        at = abs(t)
        e = self._exponent(at)
        lo, hi, h = self._octave(sign, e)
        if h is None:
            return None
        return sign, e, int((at - lo) // h)

    def _prev(self, key):
        sign, e, j = key
        if j > 0:
            return sign, e, j - 1
        if e < 0:
            return None
        pe = e - 1
        lo, hi, h = self._octave(sign, pe)
        if h is None:
            return None
        return sign, pe, int((hi - lo) / h) - 1

    # -- windows --------------------------------------------------------------------------
    def window(self, key):
        """Return the window of a key, from the cache or built (chained where possible)."""
        win = self._cache.get(key)
        if win is not None:
            self._cache.move_to_end(key)
            return win
        # walk back to a cached window to chain from, if one is near
        path = [key]
        k = key
        for _ in range(WALK):
            k = self._prev(k)
            if k is None or k in self._cache:
                break
            path.append(k)
        start = self._cache.get(k) if k is not None else None
        win = None
        if start is None and k is not None:
            path = [key]                         # nothing near to chain from
        for kk in reversed(path):
            win = self._build(kk, start)
            start = win
        return win

    def _build(self, key, prev):
        sign, e, j = key
        lo, hi, h = self._octave(sign, e)
        a = sign * (lo + j * h)
        if prev is not None and prev.ok and prev.end is not None \
                and prev.end[2] + 2.0 * prev.own <= self.chain_limit:
            c1, c2, err_a = prev.end
        elif a == 0.0:
            c1, c2, err_a = 1.0 + 0j, 0j, 0.0
        else:
            (x, y, z, w), err_a = self.kernel.evaluate(a)
            c1, c2 = complex(w, z), complex(-y, x)
            self.exact_anchors += 1
        win = self._series(a, sign * h, c1, c2, err_a)
        self._cache[key] = win
        if len(self._cache) > CACHE:
            self._cache.popitem(last=False)
        self.windows_built += 1
        return win

    def _series(self, a, hs, c1, c2, err_a):
        r0, u, d, dbar = self.r0, self.u, self.d, self.dbar
        xa = r0 + u * a
        ra = math.hypot(xa, self.dabs) * (1 + 4 * _EPS)
        tau = abs(hs)
        l1, l2 = [c1], [c2]
        m_prev, m_n = 0.0, 1.0 + err_a
        p1, p2 = 0j, 0j
        mpow = m_n                      # m_n tau^n
        s0 = mpow                       # sum m_n tau^n
        s1 = 0.0                        # sum n m_n tau^n
        tpow = 1.0
        n = 0
        half_r, half_u = 0.5 * ra, 0.5 * u
        while True:
            a1 = (xa * c1 + dbar * c2 + u * p1) * 0.5j / (n + 1)
            a2 = (d * c1 - xa * c2 - u * p2) * 0.5j / (n + 1)
            p1, p2, c1, c2 = c1, c2, a1, a2
            l1.append(a1)
            l2.append(a2)
            m_prev, m_n = m_n, (half_r * m_n + half_u * m_prev) / (n + 1)
            n += 1
            tpow *= tau
            prev_term = mpow
            mpow = m_n * tpow
            s0 += mpow
            s1 += n * mpow
            q_n = (half_r * tau + half_u * tau * tau) / (n + 1)
            if q_n <= 0.25 and max(mpow, prev_term) <= 1e-19:
                break
            if n > 200:
                break
        tail = 4.0 * max(mpow, prev_term)
        d_x = self.d_r0 + self.d_u * abs(a) + 2.0 * _EPS * (abs(r0) + 2.0 * abs(u * a))
        pert = (d_x + self.d_d) * tau / 2 + self.d_u * tau * tau / 4
        common = tail + 8.1 * _EPS * s1 + pert
        own = (common + 2.02 * _EPS * (s0 + s1)) * (1 + 1e-9)
        # batches sum c_n dt^n with cumulative-product powers and a dot product
        own_mm = (common + 1.01 * _EPS * (s1 + (n + 1) * s0)) * (1 + 1e-9)
        win = _Win()
        win.a, win.h, win.sign = a, hs, (1 if hs > 0 else -1)
        win.c1, win.c2 = l1, l2
        win.arr = None
        win.own = own
        win.bound = err_a + own
        win.bound_mm = err_a + own_mm
        win.ok = win.bound <= self.tol
        if win.ok and n <= 200:
            e1, e2 = self._horner(l1, l2, hs)
            win.end = (e1, e2, win.bound)
        else:
            win.end = None
            win.ok = False
        return win

    @staticmethod
    def _horner(l1, l2, dt):
        s1, s2 = l1[-1], l2[-1]
        for k in range(len(l1) - 2, -1, -1):
            s1 = s1 * dt + l1[k]
            s2 = s2 * dt + l2[k]
        return s1, s2

    # -- evaluation -----------------------------------------------------------------------
    def at(self, t):
        """Return the kernel quaternion (x, y, z, w) tuple and its bound at one float time."""
        k = self.key(t)
        if k is not None:
            win = self.window(k)
            if win.ok:
                s1, s2 = self._horner(win.c1, win.c2, t - win.a)
                return (s2.imag, -s2.real, s1.imag, s1.real), win.bound
        q, err = self.kernel.evaluate(t)
        return tuple(q), err

    def many(self, t, out_q, out_err):
        """Fill ``out_q`` (n, 4) and ``out_err`` (n,) at the sorted times ``t``."""
        n = len(t)
        if n == 0:
            return
        neg = int(np.searchsorted(t, 0.0, side='left'))
        if neg:                                   # negative times: away from 0, reversed
            self._many_dir(t[:neg][::-1], out_q[:neg][::-1], out_err[:neg][::-1], -1)
        if neg < n:
            self._many_dir(t[neg:], out_q[neg:], out_err[neg:], 1)

    def _many_dir(self, t, out_q, out_err, sign):
        at = np.abs(t)
        e_arr = np.where(at < 1.0, -1, np.frexp(at)[1] - 1)
        # octave boundaries (few): per octave, window indices
        bounds = np.flatnonzero(np.diff(e_arr)) + 1
        starts = np.concatenate([[0], bounds])
        ends = np.concatenate([bounds, [len(t)]])
        segs, slow = [], []
        for s, e_ in zip(starts, ends):
            e = int(e_arr[s])
            lo, hi, h = self._octave(sign, e)
            if h is None:
                slow.append((s, e_))
                continue
            j = ((at[s:e_] - lo) // h).astype(np.int64)
            change = np.flatnonzero(np.diff(j)) + 1
            js = np.concatenate([[0], change])
            je = np.concatenate([change, [e_ - s]])
            for a0, b0 in zip(js, je):
                win = self.window((sign, e, int(j[a0])))
                if win.ok and win.bound_mm <= self.tol:
                    segs.append((s + a0, s + b0, win))
                else:
                    slow.append((s + a0, s + b0))
        if segs:
            dt = np.empty(len(t))
            nmax = 1
            for a0, b0, w in segs:
                np.subtract(t[a0:b0], w.a, out=dt[a0:b0])
                nmax = max(nmax, len(w.c1))
            # powers dt^0 .. dt^(nmax-1) by cumulative products (error bound: bound_mm)
            pw = np.empty((len(t), nmax))
            pw[:, 0] = 1.0
            pw[:, 1:] = dt[:, None]
            np.cumprod(pw, axis=1, out=pw)
            for a0, b0, w in segs:
                if w.arr is None:
                    c1 = np.array(w.c1)
                    c2 = np.array(w.c2)
                    w.arr = np.stack([c2.imag, -c2.real, c1.imag, c1.real], axis=-1)
                out_q[a0:b0] = pw[a0:b0, :len(w.c1)] @ w.arr
                out_err[a0:b0] = w.bound_mm
        for s, e_ in slow:
            for i in range(s, e_):
                q, err = self.kernel.evaluate(float(t[i]))
                out_q[i] = q
                out_err[i] = err


def dense_spinor(kernel, ts):
    """Quaternions (n, 4) and component-error bounds (n,) of ``kernel`` at sorted ``ts``."""
    ts = np.asarray(ts, dtype=float)
    out = np.empty((len(ts), 4))
    errs = np.empty(len(ts))
    DenseSpinor(kernel).many(ts, out, errs)
    return out, errs
