"""Dense output: many samples of the exact spinor from few exact evaluations.

The time axis is cut into a fixed grid of windows: each octave ``[2^e, 2^(e+1))`` of |t|
(and ``[0, 1)``) into windows of one power-of-two width ``h`` with ``R h <= RT`` and ``U
h^2 <= RT`` (``R`` the largest rate ``sqrt(X^2 + |D|^2)`` in the octave). Window
boundaries are exact floats, so ``t - a`` is exact (Sterbenz), and a window is the same
whichever query builds it. Inside a window anchored at ``a`` (the end nearer t = 0) the
exact solution's own Taylor series about ``a`` (the recurrence of :mod:`.taylor`, in
float64) gives every sample by Horner's rule. The anchors are checkpoints kept in blocks
of at most ``BLOCK`` consecutive windows at every horizon: a block starts from an exact
evaluation (1F1, certified Taylor continuation or the adiabatic series; the identity at
t = 0) in its middle and chains window to window outwards and inwards (the next anchor
is the window's own series at its end), re-anchored exactly where the chained bound
would pass the kernel's tol less room for one window (``chain_limit``); a block is twice
the windows a chain can go at that tol, so a query pays one exact evaluation. A block is
chained as far as the queries need it, on to its ends where queries come back
(:data:`REVISITS`), never past an exact anchor nobody asked for yet (each anchor follows
from the one before alone, so the values do not depend on where a chain stopped); blocks
are kept in a bounded store (``CHECKPOINT_BYTES``). The arithmetic (series, Horner's
rule, chain) is compiled (:mod:`.engine`, numba, no fused or reassociated operations)
and shared by scalar calls, batches and chains. So a sample is a function of t alone:
the same bits from a scalar call, from a batch of any size or order, and whatever was
evaluated before (issue 18: the node and the offline generator agree byte for byte). No
window's series is kept: a scalar call builds it (about 0.5 us compiled) and a batch
builds it once per window.

Bound for every sample of a window (2-norm of the spinor error), all terms a priori:

    E_a                                   the anchor's bound (exact or chained)
    + 4 max(m_N h^N, m_(N-1) h^(N-1))     the truncated tail (majorant ratio <= 1/4)
    + 8.1 eps sum n m_n h^n               rounding in the coefficient recurrence
    + 2.02 eps sum (n + 1) m_n h^n        rounding in Horner's rule (samples and chaining)
    + (dX + dD) h / 2 + dU h^2 / 4        float64 parameters against the exact ones

with the majorant ``(n + 1) m_(n+1) = (R_a/2) m_n + (U/2) m_(n-1)``, ``m_0 = 1 + E_a``
(``H_a`` is Hermitian with norm ``R_a``, so ``|c_n| <= m_n``; ``R_a`` is formed as
``sqrt(X_a^2 + |D|^2) (1 + 4 eps)``, above the exact norm of the float generator). A
rounding error made at coefficient n propagates under the same majorant, so the computed
coefficients are off by at most ``m_n sum_(k<=n) rho_k / m_k`` with ``rho_k <= 7.5 eps
m_k``: per component, each step forms ``X a + (p b + q b') + U c`` (three products,
three sums, as Python's complex arithmetic did) and one quotient by ``2 (n + 1)`` (the
factor ``i / 2`` is exact). Horner's rule with real ``dt`` makes two roundings per step
(a product, a sum: never fused), each relative to a partial sum bounded by ``sum_(j>=k)
m_j h^(j-k)``. The last line is Duhamel's bound for a generator off by at most ``dX + dU
|dt| + dD`` (the float inputs and the float ``X_a = r0 + U a`` against the exact
inputs), under unitary propagators. The chain's next anchor is such a sample (at ``dt =
h``), so its bound is the window's bound, ``E_a + own``: the exact solution from a
perturbed anchor moves by no more than the perturbation (unitary). A window whose bound
exceeds the kernel's tol is evaluated sample by sample (certified) instead.
"""

import bisect
from collections import OrderedDict
import math

import mpmath
from mpmath import mp
import numpy as np

from . import engine
from .backends import PrecisionError

__all__ = ['DenseSpinor', 'dense_spinor', 'RT']

_EPS = engine.EPS
#: Window size in radians turned: ``R h <= RT``. Measured here: 2 gives about 1e-14
#: per window with 20-term series; 4 would need 30 terms and give 5e-14.
RT = 2.0
#: Checkpoints for random access: the spinor at the anchor of every window, in blocks of
#: at most this many consecutive windows per direction. A block chains from an exact
#: evaluation in its middle (the identity at t = 0), re-anchored exactly where the chained
#: bound would pass ``chain_limit`` (at tol = 1e-12 about every 110-150 windows); 40 bytes
#: a window (two complex, one bound), 56 while the block's chain is partial (anchor times
#: and widths kept). One block costs its exact evaluation and about 0.2 us a window
#: chained.
BLOCK = 512
#: A chain re-anchors exactly where its bound would pass ``tol - 2 own_per_window(RT)``
#: (room for one more window's samples), but not below this share of tol.
CHAIN_LIMIT_FLOOR = 0.5
#: An exact anchor's bound is at least this fraction of the kernel's tol (see
#: DenseSpinor._exact).
ANCHOR_TOL = 1.0 / 64
#: ... but not below this (the kernels' own float floor is about 2.3e-16).
ANCHOR_FLOOR = 4e-15
#: Arrays of one window width (a block's widths are a view of one) kept at most: with the
#: ramp of anchor offsets, ``GRID_BYTES`` in all.
WIDTHS_KEPT = 4
GRID_BYTES = (WIDTHS_KEPT + 1) * 8 * BLOCK
#: Checkpoint blocks kept, least recently used dropped beyond this many bytes (2.6 MB:
#: 512 full blocks).
CHECKPOINT_BYTES = 40 * 65536
#: Bytes a block holds besides its arrays' data, counted in its size: the block and its
#: arrays as Python objects and its entry in the store (measured with tracemalloc: about
#: 830 bytes a partial block). Without it the store held some 10-25 % more than
#: CHECKPOINT_BYTES after many far queries (one partial block each).
BLOCK_OVERHEAD = 1024
#: The most bytes one block holds (its chain partial): the store can pass
#: CHECKPOINT_BYTES by at most this (the block in use is never dropped).
BLOCK_BYTES = 56 * BLOCK + 40 + BLOCK_OVERHEAD
#: A new block is chained whole at once while at least this share of recent queries fell
#: in blocks already kept (a stream, random access over a short span); else only as far
#: as the query (random access far and wide: each query a new block). The chained extent
#: changes the cost, never the values.
REVISITS = 0.25
#: From the octave ``[2^FAR_OCTAVE, 2^(FAR_OCTAVE+1))`` s of |t| on, blocks are half as
#: long (:meth:`DenseSpinor.block_of`): out there nearly every random query is a block of
#: its own, and its cost is the exact evaluation plus a chain of a quarter block on
#: average; a stream pays one more exact evaluation per half block, a few per hour.
FAR_OCTAVE = 12


class _Block:
    """Checkpoints of one block: anchors chained so far, and what the chains need next.

    ``anc`` (g, 5) holds the anchors ``(c1.re, c1.im, c2.re, c2.im, bound)``; window ``m``
    has the block's exact anchor, windows ``m .. hi - 1`` are chained outwards and
    ``lo .. m - 1`` inwards from it. ``fwd`` and ``back`` are the chains' states (the
    anchor of window ``hi``, and of window ``lo``), ``fresh`` says the outward state is
    exact. ``a`` and ``hs`` are the windows' anchor times and signed widths; these are
    dropped once both chains have reached the block's ends.
    """

    __slots__ = ('anc', 'b0', 'm', 'lo', 'hi', 'fwd', 'back', 'fresh', 'a', 'hs')

    def nbytes(self):
        """Bytes held by the block's arrays, and its objects (:data:`BLOCK_OVERHEAD`)."""
        out = self.anc.nbytes + BLOCK_OVERHEAD
        if self.a is not None:
            out += self.a.nbytes + self.hs.nbytes + self.fwd.nbytes + self.back.nbytes
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
        # chains stop where the next window's samples could pass tol: its own bound is at
        # most own_per_window(RT) (R h <= RT), with a factor 2 for the parameter terms
        self.chain_limit = max(CHAIN_LIMIT_FLOOR * self.tol,
                               self.tol - 2.0 * engine.own_per_window(RT))
        # |D| rounded up: the majorant's rate must not fall below the exact one
        dabs_up = math.sqrt(self.p * self.p + self.q * self.q) * (1 + 4 * _EPS)
        self._prm = np.array([self.r0, self.u, self.p, self.q, dabs_up, self.d_r0, self.d_u,
                              self.d_d, self.tol, self.chain_limit])
        self._co = np.empty((engine.MAX_TERMS, 4))       # scratch: one window's series
        # how an exact anchor is had (see _exact), looked up once
        self._cap = min(self.tol, max(ANCHOR_TOL * self.tol, ANCHOR_FLOOR))
        self._prec_at = getattr(kernel, 'prec_at', None)
        self._start_prec = getattr(kernel, 'start_prec', None)
        self._anchor_fn = getattr(kernel, 'anchor', None) or kernel.evaluate
        self._k = None
        self._engine()                 # numba loaded (once a process) here, not at a sample
        self._octaves = {}
        # block length: twice the windows a chain goes from its exact anchor before its
        # bound would pass the limit, at the largest R h of this scene's grid (only a
        # cost estimate: the chains still re-anchor exactly where a bound would pass it)
        cap = min(self.tol, max(ANCHOR_TOL * self.tol, ANCHOR_FLOOR))
        reach = (self.chain_limit - cap) / (1.05 * engine.own_per_window(self._grid_rt()))
        self._half = int(min(BLOCK // 2, max(4, reach)))
        self._blen = 2 * self._half
        self._far_len = 2 * max(2, self._half // 2)        # blocks from FAR_OCTAVE on
        self._ramp = np.arange(self._blen, dtype=float)     # 0, 1, ... for window anchors
        self._widths = {}                                   # signed width -> (blen,) of it
        self._offsets = {1: [0], -1: [0]}           # windows before octave e (index e + 1)
        # first window index of FAR_OCTAVE per direction (never reached: no grid there)
        self._far_n = {sign: self._index((sign, FAR_OCTAVE, 0)) or 1 << 62
                       for sign in (1, -1)}
        self._blocks = OrderedDict()                # (sign, first index) -> _Block
        self._revisits = 1.0                        # running share of queries in kept blocks
        self._block_bytes = 0
        self.exact_anchors = 0
        self.windows_built = 0
        self.blocks_filled = 0

    def _engine(self):
        if self._k is None:
            k = engine.kernels()
            self._k = (k['eval_one'], k['eval_many'], k['chain'], k['chain_back'])
        return self._k

    # -- the grid -------------------------------------------------------------------------
    def _grid_rt(self):
        """Largest ``R h`` of a window over the octaves up to 2^20 s: the block's reach.

        A function of the scene alone (t >= 0; octaves of fewer than 128 windows, near
        t = 0 where ``R`` changes fast, left out). Only a cost estimate: a block whose
        chains would pass the limit before its ends re-anchors exactly there, so a query
        there may pay a second exact evaluation; sized from the largest ``R h`` (not the
        median), a block reaches its ends from its middle at every horizon. ``0.85 RT``
        where no octave qualifies.
        """
        rts = []
        for e in range(-1, 21):
            lo, hi, h = self._octave(1, e)
            if h is not None and (hi - lo) / h >= 128:
                rts.append(max(self._rate(lo), self._rate(hi)) * h)
        return min(RT, max(rts)) if rts else 0.85 * RT

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

    def block_of(self, n, sign=1):
        """Return (first index, length) of the checkpoint block holding window index n.

        Blocks of ``_blen`` windows from t = 0 (the last one cut at the first window of
        ``FAR_OCTAVE``), then of ``_far_len``: a function of the scene alone.
        """
        n0 = self._far_n[sign]
        if n < n0:
            b0 = n - n % self._blen
            return b0, min(self._blen, n0 - b0)
        return n - (n - n0) % self._far_len, self._far_len

    def _block(self, sign, n, last=None):
        """Return the block holding window index n, chained at least through ``last``.

        ``last`` (default n) is cut at the block's end; None where the grid ends before
        n. The chain runs on up to the block's end or the next exact anchor (which waits
        until a query needs it).
        """
        b0, g = self.block_of(n, sign)
        bk = (sign, b0)
        blk = self._blocks.get(bk)
        if blk is None:
            blk = self._fill(sign, b0, g)
            if len(blk.anc) and self._revisits >= REVISITS:
                # queries come back to blocks: chain this one whole both ways now (up to
                # an exact anchor nobody asked for), so later queries in it cost no chain
                self._chain(blk, blk.m + 1)
                self._chain_back(blk, blk.m)
            self._blocks[bk] = blk
            self._block_bytes += blk.nbytes()
            self._revisits *= 0.9
        else:
            self._blocks.move_to_end(bk)
            self._revisits = 0.9 * self._revisits + 0.1
        g = len(blk.anc)
        if n - b0 >= g:
            return None
        i = n - b0
        j = min(g - 1, (n if last is None else last) - b0)
        if j >= blk.hi or i < blk.lo:
            before = blk.nbytes()
            whole = self._revisits >= REVISITS
            if j >= blk.hi:
                self._chain(blk, j + 1, whole)
            if i < blk.lo:
                self._chain_back(blk, i, whole)
            if blk.hi == g and blk.lo == 0:
                blk.a = blk.hs = blk.fwd = blk.back = None
            self._block_bytes += blk.nbytes() - before
        while len(self._blocks) > 1 and self._block_bytes > CHECKPOINT_BYTES:
            old = self._blocks.popitem(last=False)[1]
            self._block_bytes -= old.nbytes()
        return blk

    def _block_or_none(self, sign, n, last=None):
        """:meth:`_block`, or None where an exact anchor cannot be had (PrecisionError).

        The caller then evaluates the kernel at the sample's own t: it either succeeds
        there or raises an error that names that t (not the anchor's).
        """
        try:
            return self._block(sign, n, last)
        except PrecisionError:
            return None

    def anchor(self, key):
        """Return the spinor (c1, c2) and its bound at the anchor of a window; None: no grid.

        Deterministic: the anchors of a block (:data:`BLOCK` windows) chain from an
        exact evaluation at the block's first anchor (the identity at t = 0),
        re-anchored exactly where the chained bound would pass ``chain_limit``. Each anchor
        follows from the one before it alone, so its value never depends on which query
        built the block or on what was evaluated before.
        """
        n = self._index(key)
        if n is None:
            return None
        blk = self._block(key[0], n)
        if blk is None:
            return None
        r = blk.anc[n - blk.b0].tolist()
        return complex(r[0], r[1]), complex(r[2], r[3]), r[4]

    def _fill(self, sign, b0, g):
        """Checkpoints of the block of g windows from index b0 (cut where windows end)."""
        half = g // 2
        offs = self._offsets[sign]
        while offs[-1] < b0 + g:                     # octaves up to the block's end
            lo, hi, h = self._octave(sign, len(offs) - 2)
            if h is None:
                break
            offs.append(offs[-1] + int((hi - lo) / h))
        # the windows b0 .. end - 1: octave e and index j in it, anchor a, signed width
        end = max(b0, min(b0 + g, offs[-1]))
        g = end - b0
        e0 = bisect.bisect_right(offs, b0) - 2
        blk = _Block()
        if g and end <= offs[e0 + 2]:               # one octave (nearly always)
            lo, hi, h = self._octave(sign, e0)
            sh = sign * h
            if g > len(self._ramp):                 # not a block of this grid (tests)
                self._ramp = np.arange(g, dtype=float)
                self._widths = {}
            blk.a = self._ramp[:g] * sh             # exact: h a power of two, k < 2^53
            blk.a += sign * (lo + (b0 - offs[e0 + 1]) * h)      # exact: a window's anchor
            hs = self._widths.get(sh)
            if hs is None or len(hs) < g:
                if len(self._widths) >= WIDTHS_KEPT:
                    self._widths.clear()
                hs = self._widths[sh] = np.full(len(self._ramp), sh)  # shared, never written
            blk.hs = hs[:g]
        else:                                       # several octaves (near t = 0)
            los, hsz, first, count = [], [], [], []
            pos, e = b0, e0
            while pos < end:
                lo, hi, h = self._octave(sign, e)
                last = min(end, offs[e + 2])
                los.append(lo)
                hsz.append(h)
                first.append(offs[e + 1])
                count.append(last - pos)
                pos, e = last, e + 1
            hsz = np.repeat(hsz, count)
            j = np.arange(b0, end) - np.repeat(first, count)
            blk.a = sign * (np.repeat(los, count) + j * hsz)
            blk.hs = sign * hsz
        blk.anc = np.empty((g, 5))
        blk.b0 = b0
        blk.m = 0 if b0 == 0 else min(half, g - 1)
        blk.lo = blk.hi = blk.m
        blk.fresh = True
        if g:
            st = np.array(self._exact_state(float(blk.a[blk.m])))
            blk.anc[blk.m] = st
            blk.fwd, blk.back = st, st.copy()
        else:
            blk.a = blk.hs = blk.fwd = blk.back = None
        self.blocks_filled += 1
        return blk

    def _exact_state(self, a):
        """Anchor state ``(c1.re, c1.im, c2.re, c2.im, bound)`` at a by :meth:`_exact`."""
        if a == 0.0:
            return 1.0, 0.0, 0.0, 0.0, 0.0
        return self._exact(a)

    def _exact(self, a):
        """Return the spinor ``(c1.re, c1.im, c2.re, c2.im)`` at an anchor, and a fixed bound.

        The kernel adapts its working precision to what earlier calls needed, so the bound
        it states (and, rarely, the last bit of a value) could depend on history. Here the
        1F1 kernel starts from a precision that is a function of the anchor's time alone
        (:meth:`.HyperKernel.prec_at`), the Taylor kernel takes its seeder's 1F1 at a
        fixed precision (:meth:`.TaylorKernel.anchor`), and the anchor's bound is
        ``max(stated, cap)`` with ``cap = max(ANCHOR_TOL tol, ANCHOR_FLOOR)`` (at most tol):
        the stated bound is nearly always far below cap, so the bound is the same for
        every anchor whatever came before.
        """
        kernel = self.kernel
        if self._prec_at is not None:
            kernel.prec = self._prec_at(a) or kernel.start_prec
        elif self._start_prec is not None:
            kernel.prec = self._start_prec
        q, err_a = self._anchor_fn(a)
        x, y, z, w = q.tolist() if type(q) is np.ndarray else map(float, q)
        self.exact_anchors += 1
        return w, z, -y, x, max(float(err_a), self._cap)

    def _chain(self, blk, upto, whole=True):
        """Chain a block's anchors outwards on to its window ``upto - 1`` at least.

        Compiled (:func:`.engine.chain`): each anchor is the window before evaluated at
        its end, re-anchored exactly where the chained bound would pass ``chain_limit``.
        With ``whole`` the chain goes on past ``upto`` while it is cheap: up to the block's
        end or the next window that needs an exact evaluation.
        """
        chain = self._engine()[2]
        g = len(blk.anc)
        stop = g if whole else min(g, upto)
        while blk.hi < stop:
            k, need = chain(self._prm, blk.a, blk.hs, blk.hi, stop, blk.fwd, blk.fresh,
                            blk.anc, self._co)
            self.windows_built += k - blk.hi
            blk.hi, blk.fresh = k, False
            if not need or k >= upto:
                break                       # done, or an exact anchor nobody asked for yet
            blk.fwd[:] = self._exact_state(float(blk.a[k]))
            blk.fresh = True

    def _chain_back(self, blk, down, whole=True):
        """Chain a block's anchors inwards (towards t = 0) down to its window ``down``.

        Compiled (:func:`.engine.chain_back`), as :meth:`_chain` the other way: with
        ``whole``, on to the block's first window or the next one that needs an exact
        evaluation.
        """
        chain_back = self._engine()[3]
        stop = 0 if whole else down
        while blk.lo > stop:
            k, need = chain_back(self._prm, blk.a, blk.hs, blk.lo, stop, blk.back, False,
                                 blk.anc, self._co)
            self.windows_built += blk.lo - k
            blk.lo = k
            if not need or k - 1 < down:
                break
            blk.back[:] = self._exact_state(float(blk.a[k - 1]))
            blk.anc[k - 1] = blk.back
            blk.lo = k - 1

    def checkpoint_bytes(self):
        """Bytes held by the checkpoint blocks now (at most :data:`CHECKPOINT_BYTES`)."""
        return self._block_bytes

    # -- evaluation -----------------------------------------------------------------------
    def at(self, t):
        """Return the kernel quaternion (x, y, z, w) tuple and its bound at one float time.

        The same bits as :meth:`many` gives for t in any batch (one compiled call:
        :func:`.engine.eval_one`).
        """
        sign = -1 if t < 0 else 1
        at_ = abs(t)
        e = -1 if at_ < 1.0 else math.frexp(at_)[1] - 1
        lo, hi, h = self._octave(sign, e)
        if h is not None:
            j = int((at_ - lo) // h)
            n = self._index((sign, e, j))
            blk = self._block_or_none(sign, n) if n is not None else None
            if blk is not None:
                a = sign * (lo + j * h)
                x, y, z, w, bound, ok = self._k[0](
                    self._prm, a, h, t - a, blk.anc[n - blk.b0], self._co)
                if ok:
                    return (x, y, z, w), bound
        q, err = self.kernel.evaluate(t)
        return tuple(float(v) for v in q), float(err)

    def many(self, t, out_q, out_err):
        """Fill ``out_q`` (n, 4) and ``out_err`` (n,) at the sorted times ``t``.

        Every sample has the bits :meth:`at` gives for it alone: the window of a sample
        is a function of its index, and :func:`.engine.eval_many` builds each window's
        series once and runs Horner's rule on its samples with the very operations of
        :func:`.engine.eval_one`.
        """
        n = len(t)
        if n == 0:
            return
        t = np.ascontiguousarray(t, dtype=float)
        neg = int(np.searchsorted(t, 0.0, side='left'))
        slow = []
        if neg:
            self._many_sign(t, 0, neg, -1, out_q, out_err, slow)
        if neg < n:
            self._many_sign(t, neg, n, 1, out_q, out_err, slow)
        for s, e_ in slow:
            for i in range(s, e_):
                q, err = self.kernel.evaluate(float(t[i]))
                out_q[i] = q
                out_err[i] = err

    def _many_sign(self, t, s0, s1, sign, out_q, out_err, slow):
        """Fill samples ``s0 .. s1 - 1`` of the sorted t (all of one sign), by window."""
        at = np.abs(t[s0:s1])
        e_arr = np.where(at < 1.0, -1, np.frexp(at)[1] - 1)
        cuts = np.flatnonzero(np.diff(e_arr)) + 1
        starts = np.concatenate([[0], cuts]).tolist()
        ends = np.concatenate([cuts, [len(at)]]).tolist()
        lo_l, hi_l, a_l, h_l, anc_l = [], [], [], [], []
        for s, e_ in zip(starts, ends):
            e = int(e_arr[s])
            lo, hi, h = self._octave(sign, e)
            if h is None:
                slow.append((s0 + s, s0 + e_))
                continue
            j = ((at[s:e_] - lo) // h).astype(np.int64)
            change = np.flatnonzero(np.diff(j)) + 1
            js = np.concatenate([[0], change])                 # first sample of each window
            je = np.concatenate([change, [e_ - s]])
            jw = j[js]                                         # window index in the octave
            n0 = self._index((sign, e, int(jw[0])))
            if n0 is None:
                slow.append((s0 + s, s0 + e_))
                continue
            nw = n0 + (jw - jw[0])                             # window index per direction
            n0 = self._far_n[sign]
            b0s = np.where(nw < n0, nw - nw % self._blen, nw - (nw - n0) % self._far_len)
            bcut = np.flatnonzero(np.diff(b0s)) + 1
            for u0, u1 in zip(np.concatenate([[0], bcut]).tolist(),
                              np.concatenate([bcut, [len(nw)]]).tolist()):
                b0 = int(b0s[u0])
                blk = self._block_or_none(sign, int(nw[u0]), int(nw[u1 - 1]))
                if blk is None:                                # past the grid's end
                    slow.append((s0 + s + int(js[u0]), s0 + s + int(je[u1 - 1])))
                    continue
                rows = nw[u0:u1] - b0
                if int(rows[-1]) >= len(blk.anc):              # the grid ends in this block
                    u2 = u0 + int(np.searchsorted(rows, len(blk.anc)))
                    slow.append((s0 + s + int(js[u2]), s0 + s + int(je[u1 - 1])))
                    u1 = u2
                    rows = rows[:u1 - u0]
                anc_l.append(blk.anc[rows])
                lo_l.append(js[u0:u1] + (s0 + s))
                hi_l.append(je[u0:u1] + (s0 + s))
                a_l.append(sign * (lo + jw[u0:u1] * h))
                h_l.append(np.full(u1 - u0, h))
        if not a_l:
            return
        lo_w, hi_w = np.concatenate(lo_l), np.concatenate(hi_l)
        ok = np.empty(len(lo_w), dtype=np.bool_)
        self._engine()[1](self._prm, np.concatenate(a_l), np.concatenate(h_l),
                          np.concatenate(anc_l), lo_w, hi_w, t, out_q, out_err, ok, self._co)
        for i in np.flatnonzero(~ok).tolist():
            slow.append((int(lo_w[i]), int(hi_w[i])))


def dense_spinor(kernel, ts):
    """Quaternions (n, 4) and component-error bounds (n,) of ``kernel`` at sorted ``ts``."""
    ts = np.asarray(ts, dtype=float)
    out = np.empty((len(ts), 4))
    errs = np.empty(len(ts))
    DenseSpinor(kernel).many(ts, out, errs)
    return out, errs
