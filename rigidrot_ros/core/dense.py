"""Dense output: many samples of the exact spinor from few exact evaluations.

The time axis is cut into a fixed grid of windows: each octave ``[2^e, 2^(e+1))`` of |t|
(and ``[0, 1)``) into windows of one power-of-two width ``h`` with ``R h <= RT`` and
``U h^2 <= RT`` (``R`` the largest rate ``sqrt(X^2 + |D|^2)`` in the octave). Window
boundaries are exact floats, so ``t - a`` is exact (Sterbenz), and a window is the same
whichever query builds it. Inside a window anchored at ``a`` (the end nearer t = 0) the
exact solution's own Taylor series about ``a`` (the recurrence of :mod:`.taylor`, in
float64) gives every sample by Horner's rule; the window's end value is the next window's
anchor ("chaining"), until the accumulated bound reaches 0.9 of the kernel's tol, when the
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
#: Windows kept between calls (about 2 kB each, so at most about 0.5 MB: a long-running
#: node's stream must not grow without bound). A batch keeps every window it builds until
#: it ends, then trims back to this.
CACHE = 256
#: A window whose predecessor is uncached walks back this many windows to chain.
WALK = 8
#: Batches build runs of at least this many consecutive windows at once (numpy).
RUN_MIN = 8
#: Checkpoints for random access: the spinor at the anchor of every window, per direction,
#: from t = 0 outwards (chained as batches chain, re-anchored exactly where the chained
#: bound would pass 0.9 tol), in compact arrays of 40 bytes a window (two complex, one
#: bound). At most this many per direction (2.6 MB): beyond, windows chain as before.
SWEEP_MAX = 1 << 16
#: Checkpoints are swept in blocks of this many windows (numpy temporaries ~1.3 MB).
SWEEP_BLOCK = 1024


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
        self.chain_limit = 0.9 * self.tol
        self._octaves = {}
        self._cache = OrderedDict()
        self._batch = False             # inside many(): defer trimming the cache
        # random access: checkpoints (see SWEEP_MAX) and the windows built from them
        self._ck = {sign: [np.empty(0, complex), np.empty(0, complex), np.empty(0), 0]
                    for sign in (1, -1)}
        self._offsets = {1: [0], -1: [0]}           # windows before octave e (index e + 1)
        self._scache = OrderedDict()
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
        if len(self._cache) > CACHE and not self._batch:
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

    def _prepare(self, keys):
        """Build the uncached windows among ``keys`` (chain order), runs at a time."""
        run = []
        for key in keys:
            if key in self._cache:
                if len(run) >= RUN_MIN:
                    self._build_run(run)
                run = []
                continue
            if run and self._prev(key) != run[-1]:
                if len(run) >= RUN_MIN:
                    self._build_run(run)
                run = []
            run.append(key)
        if len(run) >= RUN_MIN:
            self._build_run(run)

    def _build_run(self, keys):
        """Build consecutive windows at once: the propagator series of all in numpy.

        The columns of ``A_n`` (with ``c_n = A_n c_0``) obey the recurrence of the
        module docstring from ``e_1``, ``e_2``, so ``|A_n| <= m_n`` with ``m_0 = 1``; the
        window propagator is ``Phi = sum A_n dt^n``. Only the chaining ``c <- Phi c`` runs
        one window at a time. Bounds as in the module docstring, with the matrix forms:
        recurrence ``12.1 eps sum n m_n h^n`` (two columns, a rounded ``0.5 i / (n+1)``),
        matrix-vector products ``4.7 eps sum m_n h^n``, all times ``1 + E_a``.
        """
        nw = len(keys)
        a = np.empty(nw)
        hs = np.empty(nw)
        for i, (sign, e, j) in enumerate(keys):
            lo, hi, h = self._octave(sign, e)
            a[i] = sign * (lo + j * h)
            hs[i] = sign * h
        r0, u, d, dbar = self.r0, self.u, self.d, self.dbar
        xa = r0 + u * a
        ra = np.hypot(xa, self.dabs) * (1 + 4 * _EPS)
        tau = np.abs(hs)
        one = np.ones(nw, dtype=complex)
        zero = np.zeros(nw, dtype=complex)
        cur = [one, zero, zero, one]                 # A_0 = I (a11, a12, a21, a22)
        prv = [zero, zero, zero, zero]
        mats = [cur]
        m_prev, m_n = np.zeros(nw), np.ones(nw)
        tpow = np.ones(nw)
        s0, s1 = np.ones(nw), np.zeros(nw)
        mpow = np.ones(nw)
        n = 0
        while True:
            k = 0.5j / (n + 1)
            a11, a12, a21, a22 = cur
            p11, p12, p21, p22 = prv
            nxt = [(xa * a11 + dbar * a21 + u * p11) * k, (xa * a12 + dbar * a22 + u * p12) * k,
                   (d * a11 - xa * a21 - u * p21) * k, (d * a12 - xa * a22 - u * p22) * k]
            prv, cur = cur, nxt
            mats.append(cur)
            m_prev, m_n = m_n, (0.5 * ra * m_n + 0.5 * u * m_prev) / (n + 1)
            n += 1
            tpow = tpow * tau
            prev_term = mpow
            mpow = m_n * tpow
            s0 += mpow
            s1 += n * mpow
            q_n = (0.5 * ra * tau + 0.5 * u * tau * tau) / (n + 1)
            if (np.all(q_n <= 0.25) and np.all(np.maximum(mpow, prev_term) <= 1e-19)) \
                    or n > 200:
                break
        tail = 4.0 * np.maximum(mpow, prev_term)
        d_x = self.d_r0 + self.d_u * np.abs(a) + 2.0 * _EPS * (abs(r0) + 2.0 * np.abs(u * a))
        pert = (d_x + self.d_d) * tau / 2 + self.d_u * tau * tau / 4
        base = 12.1 * s1 + 4.7 * s0
        own_unit = (_EPS * (base + 2.02 * (s0 + s1)) + tail) * (1 + 1e-9)
        mm_unit = (_EPS * (base + 1.01 * (s1 + (n + 1) * s0)) + tail) * (1 + 1e-9)
        end_unit = (_EPS * (base + 2.0 * (s0 + s1)) + tail) * (1 + 1e-9)
        pert = pert * (1 + 1e-9)
        # propagators Phi = sum A_n hs^n (Horner over n)
        phi = [m.copy() for m in mats[-1]]
        for mt in reversed(mats[:-1]):
            for c in range(4):
                phi[c] *= hs
                phi[c] += mt[c]
        phis = list(zip(*(p.tolist() for p in phi)))
        own_l, mm_l, end_l = own_unit.tolist(), mm_unit.tolist(), end_unit.tolist()
        pert_l, a_l, hs_l = pert.tolist(), a.tolist(), hs.tolist()
        # the chain, one window at a time
        prev = self._cache.get(self._prev(keys[0])) if self._prev(keys[0]) else None
        c1s, c2s = np.empty(nw, dtype=complex), np.empty(nw, dtype=complex)
        errs = np.empty(nw)
        state = None
        if prev is not None and prev.ok and prev.end is not None:
            state = prev.end
        for i in range(nw):
            if state is not None and state[2] + 2.0 * ((1 + state[2]) * own_l[i] + pert_l[i]) \
                    > self.chain_limit:
                state = None
            if state is None:
                if a_l[i] == 0.0:
                    state = (1.0 + 0j, 0j, 0.0)
                else:
                    (x, y, z, w), err_a = self.kernel.evaluate(a_l[i])
                    state = (complex(w, z), complex(-y, x), err_a)
                    self.exact_anchors += 1
            c1, c2, e_a = state
            c1s[i], c2s[i], errs[i] = c1, c2, e_a
            f11, f12, f21, f22 = phis[i]
            state = (f11 * c1 + f12 * c2, f21 * c1 + f22 * c2,
                     e_a + (1 + e_a) * end_l[i] + pert_l[i])
        # coefficients c_n = A_n c_0 of every window
        co1 = np.array([mt[0] * c1s + mt[1] * c2s for mt in mats])      # (N+1, nw)
        co2 = np.array([mt[2] * c1s + mt[3] * c2s for mt in mats])
        arr = np.stack([co2.imag, -co2.real, co1.imag, co1.real], axis=-1)   # (N+1, nw, 4)
        arr = np.ascontiguousarray(arr.transpose(1, 0, 2))
        co1_l, co2_l = co1.T.tolist(), co2.T.tolist()
        errs_l = errs.tolist()
        for i, key in enumerate(keys):
            win = _Win()
            e_a = errs_l[i]
            win.a, win.h, win.sign = a_l[i], hs_l[i], (1 if hs_l[i] > 0 else -1)
            win.c1, win.c2 = co1_l[i], co2_l[i]
            win.arr = arr[i]
            win.own = (1 + e_a) * own_l[i] + pert_l[i]
            win.bound = e_a + win.own
            win.bound_mm = e_a + (1 + e_a) * mm_l[i] + pert_l[i]
            win.ok = win.bound <= self.tol and n <= 200
            if win.ok:
                f11, f12, f21, f22 = phis[i]
                c1, c2 = c1s[i], c2s[i]
                win.end = (complex(f11 * c1 + f12 * c2), complex(f21 * c1 + f22 * c2),
                           e_a + (1 + e_a) * end_l[i] + pert_l[i])
            else:
                win.end = None
            self._cache[key] = win
            self.windows_built += 1
        self._trim()

    def _trim(self):
        if not self._batch:
            while len(self._cache) > CACHE:
                self._cache.popitem(last=False)

    # -- checkpoints for random access ----------------------------------------------------
    def _index(self, key):
        """Return the checkpoint index (sweep order) of a window key; None past the grid."""
        sign, e, j = key
        offs = self._offsets[sign]
        while len(offs) <= e + 1:
            lo, hi, h = self._octave(sign, len(offs) - 2)
            if h is None:
                return None
            offs.append(offs[-1] + int((hi - lo) / h))
        n = offs[e + 1] + j
        return n if n < SWEEP_MAX else None

    def _key_of(self, sign, n):
        offs = self._offsets[sign]
        e = int(np.searchsorted(offs, n, side='right')) - 2
        return sign, e, n - offs[e + 1]

    def _sweep(self, sign, upto):
        """Extend the checkpoints of a direction to index ``upto`` (inclusive), in blocks."""
        ck = self._ck[sign]
        done = ck[3]
        if upto < done:
            return True
        # past the query: to the end of the next octave (amortised), within SWEEP_MAX
        sign_, e, _ = self._key_of(sign, upto)
        target = upto + 1
        for ee in (e + 1, e + 2):
            if self._index((sign, ee - 1, 0)) is None:
                break
            lo, hi, h = self._octave(sign, ee - 1)
            end = self._index((sign, ee - 1, 0))
            if end is None:
                break
            target = max(target, min(SWEEP_MAX, end + int((hi - lo) / h)))
        target = min(target, SWEEP_MAX)
        c1s = np.concatenate([ck[0], np.empty(target - done, complex)])
        c2s = np.concatenate([ck[1], np.empty(target - done, complex)])
        errs = np.concatenate([ck[2], np.empty(target - done)])
        state = None
        if done:
            state = self._ck_end
        n = done
        while n < target:
            m = min(SWEEP_BLOCK, target - n)
            keys = [self._key_of(sign, i) for i in range(n, n + m)]
            if any(self._octave(k[0], k[1])[2] is None for k in keys):
                target = n
                break
            state = self._sweep_block(keys, state, c1s, c2s, errs, n)
            n += m
        ck[0], ck[1], ck[2], ck[3] = c1s[:target], c2s[:target], errs[:target], target
        self._ck_end = state
        return upto < target

    def _sweep_block(self, keys, state, c1s, c2s, errs, n0):
        """Chain the anchors of consecutive windows (as :meth:`_build_run`), store them."""
        nw = len(keys)
        a = np.empty(nw)
        hs = np.empty(nw)
        for i, (sign, e, j) in enumerate(keys):
            lo, hi, h = self._octave(sign, e)
            a[i] = sign * (lo + j * h)
            hs[i] = sign * h
        r0, u, d, dbar = self.r0, self.u, self.d, self.dbar
        xa = r0 + u * a
        ra = np.hypot(xa, self.dabs) * (1 + 4 * _EPS)
        tau = np.abs(hs)
        one = np.ones(nw, dtype=complex)
        zero = np.zeros(nw, dtype=complex)
        cur = [one, zero, zero, one]                 # A_0 = I (a11, a12, a21, a22)
        prv = [zero, zero, zero, zero]
        mats = [cur]
        m_prev, m_n = np.zeros(nw), np.ones(nw)
        tpow = np.ones(nw)
        s0, s1 = np.ones(nw), np.zeros(nw)
        mpow = np.ones(nw)
        n = 0
        while True:
            k = 0.5j / (n + 1)
            a11, a12, a21, a22 = cur
            p11, p12, p21, p22 = prv
            nxt = [(xa * a11 + dbar * a21 + u * p11) * k, (xa * a12 + dbar * a22 + u * p12) * k,
                   (d * a11 - xa * a21 - u * p21) * k, (d * a12 - xa * a22 - u * p22) * k]
            prv, cur = cur, nxt
            mats.append(cur)
            m_prev, m_n = m_n, (0.5 * ra * m_n + 0.5 * u * m_prev) / (n + 1)
            n += 1
            tpow = tpow * tau
            prev_term = mpow
            mpow = m_n * tpow
            s0 += mpow
            s1 += n * mpow
            q_n = (0.5 * ra * tau + 0.5 * u * tau * tau) / (n + 1)
            if (np.all(q_n <= 0.25) and np.all(np.maximum(mpow, prev_term) <= 1e-19)) \
                    or n > 200:
                break
        # propagators Phi = sum A_n hs^n by Horner's rule, as _build_run
        phi = [m.copy() for m in mats[-1]]
        for mt in reversed(mats[:-1]):
            for c in range(4):
                phi[c] *= hs
                phi[c] += mt[c]
        tail = 4.0 * np.maximum(mpow, prev_term)
        d_x = self.d_r0 + self.d_u * np.abs(a) + 2.0 * _EPS * (abs(r0) + 2.0 * np.abs(u * a))
        pert = ((d_x + self.d_d) * tau / 2 + self.d_u * tau * tau / 4) * (1 + 1e-9)
        # the chained end value, bounded exactly as in _build_run
        end_unit = (_EPS * (12.1 * s1 + 4.7 * s0 + 2.0 * (s0 + s1)) + tail) * (1 + 1e-9)
        end_l, pert_l, a_l = end_unit.tolist(), pert.tolist(), a.tolist()
        phis = list(zip(*(p.tolist() for p in phi)))
        limit = self.chain_limit
        for i in range(nw):
            if state is not None and state[2] + 2.0 * ((1 + state[2]) * end_l[i] + pert_l[i]) \
                    > limit:
                state = None
            if state is None:
                if a_l[i] == 0.0:
                    state = (1.0 + 0j, 0j, 0.0)
                else:
                    (x, y, z, w), err_a = self.kernel.evaluate(a_l[i])
                    state = (complex(w, z), complex(-y, x), err_a)
                    self.exact_anchors += 1
            c1, c2, e_a = state
            c1s[n0 + i], c2s[n0 + i], errs[n0 + i] = c1, c2, e_a
            f11, f12, f21, f22 = phis[i]
            state = (f11 * c1 + f12 * c2, f21 * c1 + f22 * c2,
                     e_a + (1 + e_a) * end_l[i] + pert_l[i])
        return state

    def checkpoint_window(self, key):
        """Return the window of a key built from its checkpoint; None beyond the grid.

        Its value depends only on the checkpoint, never on the order of queries.
        """
        win = self._scache.get(key)
        if win is not None:
            self._scache.move_to_end(key)
            return win
        n = self._index(key)
        if n is None or not self._sweep(key[0], n):
            return None
        ck = self._ck[key[0]]
        sign, e, j = key
        lo, hi, h = self._octave(sign, e)
        win = self._series(sign * (lo + j * h), sign * h, complex(ck[0][n]), complex(ck[1][n]),
                           float(ck[2][n]))
        self._scache[key] = win
        if len(self._scache) > CACHE:
            self._scache.popitem(last=False)
        return win

    def checkpoint_bytes(self):
        """Bytes held by the checkpoint arrays (both directions)."""
        return sum(ck[0].nbytes + ck[1].nbytes + ck[2].nbytes for ck in self._ck.values())

    # -- evaluation -----------------------------------------------------------------------
    def at(self, t):
        """Return the kernel quaternion (x, y, z, w) tuple and its bound at one float time."""
        k = self.key(t)
        if k is not None:
            win = self.checkpoint_window(k)
            if win is None:
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
        self._batch = True                        # every window of this call stays cached
        try:
            if neg:                               # negative times: away from 0, reversed
                self._many_dir(t[:neg][::-1], out_q[:neg][::-1], out_err[:neg][::-1], -1)
            if neg < n:
                self._many_dir(t[neg:], out_q[neg:], out_err[neg:], 1)
        finally:
            self._batch = False
            self._trim()

    def _many_dir(self, t, out_q, out_err, sign):
        at = np.abs(t)
        e_arr = np.where(at < 1.0, -1, np.frexp(at)[1] - 1)
        # octave boundaries (few): per octave, window indices
        bounds = np.flatnonzero(np.diff(e_arr)) + 1
        starts = np.concatenate([[0], bounds])
        ends = np.concatenate([bounds, [len(t)]])
        segs, slow, need = [], [], []
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
                need.append(((sign, e, int(j[a0])), s + a0, s + b0))
        self._prepare([k for k, _, _ in need])
        for key, a0, b0 in need:
            win = self.window(key)
            if win.ok and win.bound_mm <= self.tol:
                segs.append((a0, b0, win))
            else:
                slow.append((a0, b0))
        if segs:
            dt = np.empty(len(t))
            nmax = 1
            for a0, b0, w in segs:
                np.subtract(t[a0:b0], w.a, out=dt[a0:b0])
                nmax = max(nmax, len(w.c1))
            # powers dt^0 .. dt^(nmax-1) by cumulative products (error bound: bound_mm)
            pw = np.empty((nmax, len(t)))
            pw[0] = 1.0
            pw[1:] = dt
            np.cumprod(pw, axis=0, out=pw)
            for a0, b0, w in segs:
                if w.arr is None:
                    c1 = np.array(w.c1)
                    c2 = np.array(w.c2)
                    w.arr = np.stack([c2.imag, -c2.real, c1.imag, c1.real], axis=-1)
                out_q[a0:b0] = pw[:len(w.c1), a0:b0].T @ w.arr
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
