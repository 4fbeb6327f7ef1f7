"""Dense output: many samples of the exact spinor from few exact evaluations.

The time axis is cut into a fixed grid of windows: each octave ``[2^e, 2^(e+1))`` of |t|
(and ``[0, 1)``) into windows of one power-of-two width ``h`` with ``R h <= RT`` and
``U h^2 <= RT`` (``R`` the largest rate ``sqrt(X^2 + |D|^2)`` in the octave). Window
boundaries are exact floats, so ``t - a`` is exact (Sterbenz), and a window is the same
whichever query builds it. Inside a window anchored at ``a`` (the end nearer t = 0) the
exact solution's own Taylor series about ``a`` (the recurrence of :mod:`.taylor`, in
float64) gives every sample by Horner's rule. The anchors are checkpoints kept in blocks
of ``BLOCK`` consecutive windows at every horizon: a block starts from
an exact evaluation (1F1, certified Taylor continuation or the adiabatic series; the
identity at t = 0) and chains window to window, re-anchored exactly where the chained
bound would pass 0.9 of the kernel's tol. A block's propagators are computed whole, the
first time a query needs it, its chain only as far as queries reach (each anchor follows
from the one before alone, so the values do not depend on where the chain stopped); blocks
are kept in a bounded store (``CHECKPOINT_BYTES``). So a sample is
a function of t alone: the same bits from a scalar call, from a batch of any size or
order, and whatever was evaluated before (issue 18: the node and the offline generator
agree byte for byte).

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
#: Windows (series) kept between calls, least recently used dropped (about 2 kB each, so
#: at most about 0.5 MB: a long-running node's stream must not grow without bound). A
#: window is a function of its key alone, so the cache changes the cost, never the bits.
CACHE = 256
#: A batch builds the series of this many windows or more at once (numpy, the same
#: bits; below this, one at a time is cheaper).
SERIES_BATCH = 32
#: Checkpoints for random access: the spinor at the anchor of every window, in blocks of
#: this many consecutive windows per direction. A block chains from an exact evaluation
#: at its first anchor (the identity at t = 0), re-anchored exactly where the chained
#: bound would pass 0.9 tol; 40 bytes a window (two complex, one bound), 128 while the
#: block's chain is partial (its propagators and bound terms kept). One block costs one
#: numpy sweep and the exact evaluations its chain reaches (measured under load: about
#: 0.3-1 ms).
BLOCK = 128
#: Windows per direction the checkpoint store holds at 40 bytes a window. (Blocks of
#: BLOCK windows run at every horizon: blocks of one window past this index, each its own
#: exact anchor, made a 1 kHz stream 6-12x dearer there, from t ~ 2400 s on the default
#: scene; random access far out paid less.)
SWEEP_MAX = 1 << 16
#: An exact anchor's bound is at least this fraction of the kernel's tol (see
#: DenseSpinor._exact).
ANCHOR_TOL = 1.0 / 64
#: ... but not below this (the kernels' own float floor is about 2.3e-16).
ANCHOR_FLOOR = 4e-15
#: Checkpoint blocks kept, least recently used dropped beyond this many bytes (2.6 MB).
CHECKPOINT_BYTES = 40 * SWEEP_MAX
#: The most bytes one block holds (its chain partial): the store can pass
#: CHECKPOINT_BYTES by at most this (the block in use is never dropped).
BLOCK_BYTES = 128 * BLOCK


class _Win:
    __slots__ = ('a', 'h', 'sign', 'c1', 'c2', 'bound', 'own', 'ok', 'arr')

    def coefficients(self):
        """Return the coefficients as one (terms, 2) complex array (made once)."""
        if self.arr is None:
            self.arr = np.array((self.c1, self.c2)).T
        return self.arr


class _Block:
    """Checkpoints of one block: anchors chained so far, and what the chain needs next.

    ``c1s``, ``c2s``, ``errs`` hold the anchors of windows ``0 .. done - 1``; ``state`` is
    the chained value at window ``done``; ``sweep`` the block's propagators and bound
    terms (dropped once the chain has reached the block's end).
    """

    __slots__ = ('c1s', 'c2s', 'errs', 'done', 'state', 'sweep')

    def nbytes(self):
        """Bytes held by the block's arrays."""
        out = self.c1s.nbytes + self.c2s.nbytes + self.errs.nbytes
        if self.sweep is not None:
            out += sum(v.nbytes for v in self.sweep)
        return out


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
        self._offsets = {1: [0], -1: [0]}           # windows before octave e (index e + 1)
        self._blocks = OrderedDict()                # (sign, first index) -> (c1, c2, err)
        self._block_bytes = 0
        self._scache = OrderedDict()                # window key -> _Win
        self.exact_anchors = 0
        self.windows_built = 0
        self.blocks_filled = 0

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
    def window_at(self, key):
        """Return the window of a key (its series from its checkpoint); None past the grid.

        A window is a function of its key alone: its anchor is the block checkpoint of
        :meth:`anchor`, its coefficients :meth:`_series` of that anchor, so the same key
        gives the same bits whatever was evaluated before (and whatever is cached).
        """
        win = self._scache.get(key)
        if win is not None:
            self._scache.move_to_end(key)
            return win
        anchor = self.anchor(key)
        if anchor is None:
            return None
        sign, e, j = key
        lo, hi, h = self._octave(sign, e)
        win = self._series(sign * (lo + j * h), sign * h, *anchor)
        self._scache[key] = win
        if len(self._scache) > CACHE:
            self._scache.popitem(last=False)
        self.windows_built += 1
        return win

    def windows(self, keys):
        """Return the windows of many keys (as :meth:`window_at` each); None past the grid.

        Windows not kept are built together by :meth:`_series_many` when there are at
        least :data:`SERIES_BATCH` of them (the same bits as :meth:`_series`).
        """
        cache = self._scache
        out = [None] * len(keys)
        todo = []
        for i, key in enumerate(keys):
            win = cache.get(key)
            if win is not None:
                cache.move_to_end(key)
                out[i] = win
            else:
                todo.append(i)
        if len(todo) < SERIES_BATCH:
            for i in todo:
                out[i] = self.window_at(keys[i])
            return out
        build, args = [], []
        for i in todo:
            anchor = self.anchor(keys[i])
            if anchor is not None:
                sign, e, j = keys[i]
                lo, hi, h = self._octave(sign, e)
                build.append(i)
                args.append((sign * (lo + j * h), sign * h) + anchor)
        if build:
            for i, win in zip(build, self._series_many(*zip(*args))):
                out[i] = win
                cache[keys[i]] = win
            while len(cache) > CACHE:
                cache.popitem(last=False)
            self.windows_built += len(build)
        return out

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
        qnum = half_r * tau + half_u * tau * tau
        # Python multiplies a float by a complex as (x, 0) times it, divides by an int as
        # by (float(n), 0): the same operations, written so
        xc, uc = complex(xa), complex(u)
        app1, app2 = l1.append, l2.append
        while True:
            k = n + 1.0
            a1 = (xc * c1 + dbar * c2 + uc * p1) * 0.5j / k
            a2 = (d * c1 - xc * c2 - uc * p2) * 0.5j / k
            p1, p2, c1, c2 = c1, c2, a1, a2
            app1(a1)
            app2(a2)
            m_prev, m_n = m_n, (half_r * m_n + half_u * m_prev) / k
            n += 1
            tpow *= tau
            prev_term = mpow
            mpow = m_n * tpow
            s0 += mpow
            s1 += n * mpow
            if qnum / (n + 1) <= 0.25 and max(mpow, prev_term) <= 1e-19:
                break
            if n > 200:
                break
        tail = 4.0 * max(mpow, prev_term)
        d_x = self.d_r0 + self.d_u * abs(a) + 2.0 * _EPS * (abs(r0) + 2.0 * abs(u * a))
        pert = (d_x + self.d_d) * tau / 2 + self.d_u * tau * tau / 4
        common = tail + 8.1 * _EPS * s1 + pert
        own = (common + 2.02 * _EPS * (s0 + s1)) * (1 + 1e-9)
        win = _Win()
        win.a, win.h, win.sign = a, hs, (1 if hs > 0 else -1)
        win.c1, win.c2 = l1, l2
        win.arr = None
        win.own = own
        win.bound = err_a + own
        win.ok = win.bound <= self.tol and n <= 200
        return win

    def _series_many(self, a_l, hs_l, c1_l, c2_l, err_l):
        """:meth:`_series` of many windows at once, with the same bits for each.

        Python's complex arithmetic is written out on separate real and imaginary rows
        (numpy's elementwise float64 products, sums and quotients round as Python's do):
        ``x * z`` for a real x is ``(x, 0) * z``, ``z * 0.5j`` and ``z / (n + 1)`` are
        Python's complex product and quotient, zero terms and signs of zeros included.
        No complex product runs in numpy (its loops may fuse a multiply and an add). A
        window stops at its own term count, as in :meth:`_series`.
        """
        nw = len(a_l)
        a = np.array(a_l, dtype=float)
        hs = np.array(hs_l, dtype=float)
        err_a = np.array(err_l, dtype=float)
        r0, u, p, q = self.r0, self.u, self.p, self.q
        xa = r0 + u * a
        ra = np.array([math.hypot(x, self.dabs) for x in xa.tolist()]) * (1 + 4 * _EPS)
        tau = np.abs(hs)
        top = 202                                   # coefficients 0..201 at most
        # hc[k + 1] = coefficient k as (spinor component, re/im, window); hc[0] = 0
        hc = np.empty((top + 1, 2, 2, nw))
        hc[0] = 0.0
        c1a, c2a = np.array(c1_l, dtype=complex), np.array(c2_l, dtype=complex)
        hc[1, 0, 0], hc[1, 0, 1], hc[1, 1, 0], hc[1, 1, 1] = (c1a.real, c1a.imag, c2a.real,
                                                              c2a.imag)
        # rows: u * (p1, p2), xa * (c1, c2), (d * c1, dbar * c2); (x, 0) * z has -0 zi, +0 zr
        mul = np.empty((3, 2, 2, nw))
        mul[0], mul[1], mul[2] = u, xa, p
        zer = np.array([[-0.0, 0.0], [-0.0, 0.0]])
        cross = np.array([zer, zer, [[-q, q], [q, -q]]])[..., None]
        half_j = np.array([-0.5, 0.5])[:, None]             # z * 0.5j
        quo = np.array([0.0, -0.0])[:, None]                # z / (n + 1)
        sm = np.empty((2, 2, nw))
        # majorant: mp[n] = m_n tau^n, s0s[n] = sum m_k tau^k, s1s[n] = sum k m_k tau^k
        mp, s0s, s1s = np.empty((top, nw)), np.empty((top, nw)), np.empty((top, nw))
        m_prev, m_n = np.zeros(nw), 1.0 + err_a
        mp[0] = m_n
        s0s[0] = m_n
        s1s[0] = 0.0
        tpow = np.ones(nw)
        half_r, half_u = 0.5 * ra, 0.5 * u
        qnum = half_r * tau + half_u * tau * tau
        met = np.zeros(nw, dtype=bool)
        checked = 1
        n = 0
        while True:
            x = hc[[n, n + 1, n + 1]]
            t = mul * x
            t += cross * x[:, :, ::-1]
            np.add(t[1, 0], t[2, 1], out=sm[0])
            sm[0] += t[0, 0]
            np.subtract(t[2, 0], t[1, 1], out=sm[1])
            sm[1] -= t[0, 1]
            mj = sm * 0.0
            mj += sm[:, ::-1] * half_j
            nxt = mj[:, ::-1] * quo
            nxt += mj
            np.divide(nxt, n + 1, out=hc[n + 2])
            m_prev, m_n = m_n, (half_r * m_n + half_u * m_prev) / (n + 1)
            n += 1
            tpow *= tau
            np.multiply(m_n, tpow, out=mp[n])
            np.add(s0s[n - 1], mp[n], out=s0s[n])
            np.add(s1s[n - 1], n * mp[n], out=s1s[n])
            if n % 4 == 0 or n > 200:
                ns = np.arange(checked, n + 1)
                cond = (qnum / (ns + 1)[:, None] <= 0.25) & (
                    np.maximum(mp[checked:n + 1], mp[checked - 1:n]) <= 1e-19)
                met |= cond.any(axis=0)
                checked = n + 1
                if n > 200 or met.all():
                    break
        ns = np.arange(1, n + 1)
        cond = (qnum / (ns + 1)[:, None] <= 0.25) & (np.maximum(mp[1:n + 1], mp[:n]) <= 1e-19)
        cond[-1] |= n > 200
        nfin = cond.argmax(axis=0) + 1
        cols = np.arange(nw)
        f_mpow, f_prev = mp[nfin, cols], mp[nfin - 1, cols]
        f_s0, f_s1 = s0s[nfin, cols], s1s[nfin, cols]
        tail = 4.0 * np.maximum(f_mpow, f_prev)
        d_x = self.d_r0 + self.d_u * np.abs(a) + 2.0 * _EPS * (abs(r0) + 2.0 * np.abs(u * a))
        pert = (d_x + self.d_d) * tau / 2 + self.d_u * tau * tau / 4
        common = tail + 8.1 * _EPS * f_s1 + pert
        own = (common + 2.02 * _EPS * (f_s0 + f_s1)) * (1 + 1e-9)
        bound = err_a + own
        co = np.empty((nw, 2, n + 1), dtype=complex)
        co.real = hc[1:n + 2, :, 0].transpose(2, 1, 0)
        co.imag = hc[1:n + 2, :, 1].transpose(2, 1, 0)
        wins = []
        for i, (nf, ow, bd) in enumerate(zip(nfin.tolist(), own.tolist(), bound.tolist())):
            win = _Win()
            win.a, win.h = a_l[i], hs_l[i]
            win.sign = 1 if win.h > 0 else -1
            win.c1 = co[i, 0, :nf + 1].tolist()
            win.c2 = co[i, 1, :nf + 1].tolist()
            win.arr = co[i, :, :nf + 1].T
            win.own = ow
            win.bound = bd
            win.ok = bd <= self.tol and nf <= 200
            wins.append(win)
        return wins

    @staticmethod
    def _horner(l1, l2, dt):
        s1, s2 = l1[-1], l2[-1]
        for k in range(len(l1) - 2, -1, -1):
            s1 = s1 * dt + l1[k]
            s2 = s2 * dt + l2[k]
        return s1, s2

    # -- checkpoints for random access ----------------------------------------------------
    def _index(self, key):
        """Return the window index (per direction, from t = 0 outwards) of a key."""
        sign, e, j = key
        offs = self._offsets[sign]
        while len(offs) <= e + 1:
            lo, hi, h = self._octave(sign, len(offs) - 2)
            if h is None:
                return None
            offs.append(offs[-1] + int((hi - lo) / h))
        return offs[e + 1] + j

    def block_of(self, n):
        """Return (first index, length) of the checkpoint block holding window index n."""
        return n - n % BLOCK, BLOCK

    def anchor(self, key):
        """Return the spinor (c1, c2) and its bound at the anchor of a window; None: no grid.

        Deterministic: the anchors of a block (:data:`BLOCK` windows) chain from an
        exact evaluation at the block's first anchor (the identity at t = 0),
        re-anchored exactly where the chained bound would pass 0.9 tol. A block's
        propagators are computed whole at its first query, its chain only as far as the
        queries so far reached (each anchor follows from the one before it alone), so its
        values never depend on which query built it or on what
        was evaluated before.
        """
        n = self._index(key)
        if n is None:
            return None
        sign = key[0]
        b0, g = self.block_of(n)
        bk = (sign, b0)
        blk = self._blocks.get(bk)
        if blk is None:
            blk = self._fill(sign, b0, g)
            self._blocks[bk] = blk
            self._block_bytes += blk.nbytes()
        else:
            self._blocks.move_to_end(bk)
        i = n - b0
        if i >= len(blk.errs):
            return None
        if i >= blk.done:
            before = blk.nbytes()
            self._chain(blk, i + 1)
            self._block_bytes += blk.nbytes() - before
        while len(self._blocks) > 1 and self._block_bytes > CHECKPOINT_BYTES:
            old = self._blocks.popitem(last=False)[1]
            self._block_bytes -= old.nbytes()
        return complex(blk.c1s[i]), complex(blk.c2s[i]), float(blk.errs[i])

    def _fill(self, sign, b0, g):
        """Checkpoints of the block of g windows from index b0 (cut where windows end)."""
        offs = self._offsets[sign]
        while offs[-1] < b0 + g:                     # octaves up to the block's end
            lo, hi, h = self._octave(sign, len(offs) - 2)
            if h is None:
                break
            offs.append(offs[-1] + int((hi - lo) / h))
        # the windows b0 .. end - 1: octave e and index j in it, anchor a, signed width
        idx = np.arange(b0, max(b0, min(b0 + g, offs[-1])))
        g = len(idx)
        es = np.searchsorted(offs, idx, side='right') - 2
        los, hsz, first = np.empty(g), np.empty(g), np.empty(g, dtype=np.int64)
        for e in np.unique(es).tolist():
            lo, hi, h = self._octave(sign, e)
            at = es == e
            los[at], hsz[at], first[at] = lo, h, offs[e + 1]
        a = sign * (los + (idx - first) * hsz)
        blk = _Block()
        blk.c1s, blk.c2s, blk.errs = np.empty(g, complex), np.empty(g, complex), np.empty(g)
        blk.done, blk.state, blk.sweep = g, None, None
        if g == 1:
            a = float(a[0])
            if a == 0.0:
                blk.c1s[0], blk.c2s[0], blk.errs[0] = 1.0, 0.0, 0.0
            else:
                blk.c1s[0], blk.c2s[0], blk.errs[0] = self._exact(a)
        elif g:
            blk.sweep = self._sweep_block(a, sign * hsz)
            blk.done = 0
        self.blocks_filled += 1
        return blk

    def _exact(self, a):
        """Return the spinor (c1, c2) at an anchor by the exact kernel, and a fixed bound.

        The kernel adapts its working precision to what earlier calls needed, so the bound
        it states (and, rarely, the last bit of a value) could depend on history. Here the
        1F1 kernel starts from the precision it started with, and the anchor's bound is
        ``max(stated, cap)`` with ``cap = max(ANCHOR_TOL tol, ANCHOR_FLOOR)`` (at most tol):
        the stated bound is nearly always far below cap, so the bound is the same for
        every anchor whatever came before.
        """
        kernel = self.kernel
        cap = min(self.tol, max(ANCHOR_TOL * self.tol, ANCHOR_FLOOR))
        if hasattr(kernel, 'start_prec'):
            kernel.prec = kernel.start_prec
        (x, y, z, w), err_a = kernel.evaluate(a)
        self.exact_anchors += 1
        return complex(w, z), complex(-y, x), max(float(err_a), cap)

    def _sweep_block(self, a, hs):
        """Propagators of consecutive windows (anchors a, signed widths hs), bound terms.

        Returns ``(phi, end, pert, a)``: phi (4, n) the window propagators (a11, a12, a21,
        a22), end and pert the chained bound's terms per window (see :meth:`_chain`).
        """
        nw = len(a)
        r0, u, d, dbar = self.r0, self.u, self.d, self.dbar
        xa = r0 + u * a
        ra = np.hypot(xa, self.dabs) * (1 + 4 * _EPS)
        tau = np.abs(hs)
        # A_n as rows (a11, a12) and (a21, a22): elementwise, the same products as one
        # array an entry
        cur = (np.array([np.ones(nw), np.zeros(nw)], dtype=complex),
               np.array([np.zeros(nw), np.ones(nw)], dtype=complex))       # A_0 = I
        prv = (np.zeros((2, nw), dtype=complex), np.zeros((2, nw), dtype=complex))
        mats = [cur]
        m_prev, m_n = np.zeros(nw), np.ones(nw)
        tpow = np.ones(nw)
        s0, s1 = np.ones(nw), np.zeros(nw)
        mpow = np.ones(nw)
        half_r, half_u = 0.5 * ra, 0.5 * u
        qnum = half_r * tau + half_u * tau * tau
        n = 0
        while True:
            k = 0.5j / (n + 1)
            top, bot = cur
            ptop, pbot = prv
            nxt = ((xa * top + dbar * bot + u * ptop) * k, (d * top - xa * bot - u * pbot) * k)
            prv, cur = cur, nxt
            mats.append(cur)
            m_prev, m_n = m_n, (half_r * m_n + half_u * m_prev) / (n + 1)
            n += 1
            tpow = tpow * tau
            prev_term = mpow
            mpow = m_n * tpow
            s0 += mpow
            s1 += n * mpow
            if (np.all(qnum / (n + 1) <= 0.25) and np.all(np.maximum(mpow, prev_term) <= 1e-19)) \
                    or n > 200:
                break
        # propagators Phi = sum A_n hs^n by Horner's rule, as _build_run
        # (complex times real: the product by (hs, 0) rounds as Python's does)
        mats = np.array(mats).reshape(len(mats), 4, nw)      # (terms, 4, windows)
        phi = mats[-1].copy()
        for mt in mats[-2::-1]:
            phi *= hs
            phi += mt
        tail = 4.0 * np.maximum(mpow, prev_term)
        d_x = self.d_r0 + self.d_u * np.abs(a) + 2.0 * _EPS * (abs(r0) + 2.0 * np.abs(u * a))
        pert = ((d_x + self.d_d) * tau / 2 + self.d_u * tau * tau / 4) * (1 + 1e-9)
        # the chained end value, bounded exactly as in _build_run
        end_unit = (_EPS * (12.1 * s1 + 4.7 * s0 + 2.0 * (s0 + s1)) + tail) * (1 + 1e-9)
        return phi, end_unit, pert, np.asarray(a, dtype=float)

    def _chain(self, blk, upto):
        """Chain a block's anchors on to its window ``upto - 1`` at least.

        Re-anchored exactly where the chained bound would pass 0.9 tol. Each anchor
        follows from the one before it alone, so the values are the same whether the
        chain runs in one go or in steps. Past ``upto`` the chain goes on while it is
        cheap: up to the block's end or the next window that needs an exact evaluation.
        """
        phi, end_unit, pert, a = blk.sweep
        lo = blk.done
        end_l, pert_l, a_l = end_unit[lo:].tolist(), pert[lo:].tolist(), a[lo:].tolist()
        phis = list(zip(*phi[:, lo:].tolist()))
        c1s, c2s, errs = blk.c1s, blk.c2s, blk.errs
        limit = self.chain_limit
        state = blk.state
        k, stop = 0, len(a_l)
        while k < stop:
            if state is None or state[2] + 2.0 * ((1 + state[2]) * end_l[k] + pert_l[k]) \
                    > limit:
                if lo + k >= upto:
                    break                             # an exact anchor nobody asked for yet
                if a_l[k] == 0.0:
                    state = (1.0 + 0j, 0j, 0.0)
                else:
                    state = self._exact(a_l[k])
            c1, c2, e_a = state
            c1s[lo + k], c2s[lo + k], errs[lo + k] = c1, c2, e_a
            f11, f12, f21, f22 = phis[k]
            state = (f11 * c1 + f12 * c2, f21 * c1 + f22 * c2,
                     e_a + (1 + e_a) * end_l[k] + pert_l[k])
            k += 1
        blk.state, blk.done = state, lo + k
        if blk.done == len(errs):
            blk.sweep = blk.state = None

    def checkpoint_bytes(self):
        """Bytes held by the checkpoint blocks now (at most :data:`CHECKPOINT_BYTES`)."""
        return self._block_bytes

    # -- evaluation -----------------------------------------------------------------------
    def at(self, t):
        """Return the kernel quaternion (x, y, z, w) tuple and its bound at one float time.

        The same bits as :meth:`many` gives for t in any batch.
        """
        k = self.key(t)
        if k is not None:
            win = self.window_at(k)
            if win is not None and win.ok:
                s1, s2 = self._horner(win.c1, win.c2, t - win.a)
                return (s2.imag, -s2.real, s1.imag, s1.real), win.bound
        q, err = self.kernel.evaluate(t)
        return tuple(float(v) for v in q), float(err)

    def many(self, t, out_q, out_err):
        """Fill ``out_q`` (n, 4) and ``out_err`` (n,) at the sorted times ``t``.

        Every sample has the bits :meth:`at` gives for it alone: the window of a sample
        is a function of its key, and Horner's rule runs over the samples of all windows
        at once with the very operations of :meth:`_horner` (complex times real and
        complex sums, which numpy rounds as Python does).
        """
        n = len(t)
        if n == 0:
            return
        neg = int(np.searchsorted(t, 0.0, side='left'))
        segs, slow = [], []
        if neg:
            self._segments(t[:neg], -1, 0, segs, slow)
        if neg < n:
            self._segments(t[neg:], 1, neg, segs, slow)
        if segs:
            self._horner_many(t, segs, out_q, out_err)
        for s, e_ in slow:
            for i in range(s, e_):
                q, err = self.kernel.evaluate(float(t[i]))
                out_q[i] = q
                out_err[i] = err

    @staticmethod
    def _horner_many(t, segs, out_q, out_err):
        """Horner's rule over the samples of all windows at once, as :meth:`_horner` each.

        Windows are taken by term count, most first, so the samples still in Horner's
        rule at term k are a prefix; a window's samples join at its top coefficient
        (set, not added, as in :meth:`_horner`). Complex times real: numpy multiplies by
        ``(dt, 0)``, as Python does.
        """
        segs = sorted(segs, key=lambda s: -len(s[2].c1))
        nts = [len(w.c1) for _, _, w in segs]
        cnt = [b0 - a0 for a0, b0, _ in segs]
        idx = np.concatenate([np.arange(a0, b0) for a0, b0, _ in segs])
        dt = t[idx] - np.array([w.a for _, _, w in segs]).repeat(cnt)
        dtc = dt.astype(complex)[:, None]
        nmax = nts[0]
        co = np.zeros((len(segs), nmax, 2), dtype=complex)
        for i, (_, _, w) in enumerate(segs):
            co[i, :nts[i]] = w.coefficients()
        ends = np.cumsum(cnt).tolist()
        s = np.empty((len(idx), 2), dtype=complex)
        nwin = nsamp = 0                          # windows and samples in Horner's rule
        for k in range(nmax - 1, -1, -1):
            if nsamp:
                s[:nsamp] *= dtc[:nsamp]
            new = nwin
            while new < len(segs) and nts[new] > k:
                new += 1
            if new > nwin:                        # windows whose top coefficient is k
                top = ends[new - 1]
                if nsamp:
                    s[:nsamp] += co[:nwin, k].repeat(cnt[:nwin], axis=0)
                s[nsamp:top] = co[nwin:new, k].repeat(cnt[nwin:new], axis=0)
                nwin, nsamp = new, top
            else:
                s[:nsamp] += co[:nwin, k].repeat(cnt[:nwin], axis=0)
        s1, s2 = s[:, 0], s[:, 1]
        out_q[idx, 0], out_q[idx, 1] = s2.imag, -s2.real
        out_q[idx, 2], out_q[idx, 3] = s1.imag, s1.real
        out_err[idx] = np.array([w.bound for _, _, w in segs]).repeat(cnt)

    def _segments(self, t, sign, off, segs, slow):
        """Split the sorted times t of one sign into (start, end, window) runs and slow runs."""
        at = np.abs(t)
        e_arr = np.where(at < 1.0, -1, np.frexp(at)[1] - 1)
        bounds = np.flatnonzero(np.diff(e_arr)) + 1
        starts = np.concatenate([[0], bounds])
        ends = np.concatenate([bounds, [len(t)]])
        runs, keys = [], []
        for s, e_ in zip(starts.tolist(), ends.tolist()):
            e = int(e_arr[s])
            lo, hi, h = self._octave(sign, e)
            if h is None:
                slow.append((off + s, off + e_))
                continue
            j = ((at[s:e_] - lo) // h).astype(np.int64)
            change = np.flatnonzero(np.diff(j)) + 1
            js = np.concatenate([[0], change]).tolist()
            je = np.concatenate([change, [e_ - s]]).tolist()
            jl = j.tolist()
            for a0, b0 in zip(js, je):
                runs.append((off + s + a0, off + s + b0))
                keys.append((sign, e, jl[a0]))
        for (a0, b0), win in zip(runs, self.windows(keys)):
            if win is not None and win.ok:
                segs.append((a0, b0, win))
            else:
                slow.append((a0, b0))


def dense_spinor(kernel, ts):
    """Quaternions (n, 4) and component-error bounds (n,) of ``kernel`` at sorted ``ts``."""
    ts = np.asarray(ts, dtype=float)
    out = np.empty((len(ts), 4))
    errs = np.empty(len(ts))
    DenseSpinor(kernel).many(ts, out, errs)
    return out, errs
