"""Compiled arithmetic of dense output: window series, Horner's rule, block chains.

Every function here is written in plain float64 scalar operations (products, sums,
quotients, ``math.sqrt``, ``abs``, ``max``: each correctly rounded by IEEE 754) and
compiled by numba with ``fastmath`` off: no contraction into fused multiply-adds, no
reassociation. Interpreted by Python, the same functions give the same bits (so the
module works, slower, without numba; ``RIGIDROT_NO_JIT=1`` forces that, and the tests
compare both). Scalar calls, batches and chains all go through :func:`_series` and
:func:`_horner`, so a sample's bits are a function of its window and t alone.

The kernels are loaded on first use (:func:`kernels`, called when a dense solution is
made), not with the package, so that a command's ``--help`` or a process that never makes a
dense solution pays nothing; every kernel is then called once (:func:`_warm`), so that
compiling or loading the cached code happens there, not at a caller's first sample.
The kernels load as object code (:mod:`rigidrot_ros.runtime.native`): numba compiles
them once for this processor and this source as C functions (:func:`_c_kernels`), each
with a Python entry that checks its arrays; later processes map that machine code without
importing numba or LLVM (about 100 MB and 0.3 s less a process). Where that cannot be
(a machine other than x86-64 Linux, ``RIGIDROT_NO_NATIVE=1``), numba loads them from its
own cache through :func:`rigidrot_ros.runtime.jit.cached_load`: none of numba's compiler
registries, no BLAS probe (no kernel calls a BLAS). Both ways compile the same functions
with the same options (:data:`_FLAGS`). Compiled code is cached in ``NUMBA_CACHE_DIR``
when set, else next to this file (``__pycache__``) or in the user's cache directory;
where none is writable it is compiled in memory at each start. The tests check that the
compiled kernels give the interpreted ones' bits (no fused multiply-add slipped in), and
that both loads give the same bits.

Scene constants travel as one float64 array ``prm``:
``(r0, U, p, q, dabs, d_r0, d_u, d_d, tol, chain_limit)``; an anchor or a chain state as
``(c1.re, c1.im, c2.re, c2.im, bound)`` (the spinor ``v1 = w + i z``, ``v2 = -y + i x``).
"""

import math

import numpy as np

from rigidrot_ros.runtime import switches
from rigidrot_ros.runtime.jit import cached_load

__all__ = ['kernels', 'jit_state', 'MAX_TERMS', 'EPS']

EPS = 2.0 ** -52
#: Coefficients of a window series at most (the recurrence stops by n = 201).
MAX_TERMS = 203


def _series(prm, a, tau, c1r, c1i, c2r, c2i, m0, co):
    """Taylor coefficients about ``a`` of the spinor from (c1, c2) into ``co``; bound terms.

    Fills ``co[0..n]`` (rows re v1, im v1, re v2, im v2) by the recurrence
    ``(n + 1) c_(n+1) = (i/2) (H_a c_n + U J c_(n-1))`` and returns
    ``(n, own_no_horner, s0, s1)``: the term count, the window's a-priori bound less
    Horner's rounding, and the majorant sums (module docstring of :mod:`.dense`).
    """
    r0 = prm[0]
    u = prm[1]
    p = prm[2]
    q = prm[3]
    dabs = prm[4]
    xa = r0 + u * a
    ra = math.sqrt(xa * xa + dabs * dabs) * (1.0 + 4.0 * EPS)
    co[0, 0] = c1r
    co[0, 1] = c1i
    co[0, 2] = c2r
    co[0, 3] = c2i
    ar, ai, br, bi = c1r, c1i, c2r, c2i
    pr1 = 0.0
    pi1 = 0.0
    pr2 = 0.0
    pi2 = 0.0
    m_prev = 0.0
    m_n = m0
    mpow = m_n
    s0 = mpow
    s1 = 0.0
    tpow = 1.0
    half_r = 0.5 * ra
    half_u = 0.5 * u
    qnum = half_r * tau + half_u * tau * tau
    prev_term = mpow
    n = 0
    while True:
        k2 = 2.0 * (n + 1.0)
        # S1 = X c1 + conj(D) c2 + U p1, S2 = D c1 - X c2 - U p2; c' = (i / 2) S / (n + 1)
        s1r = xa * ar + (p * br + q * bi) + u * pr1
        s1i = xa * ai + (p * bi - q * br) + u * pi1
        s2r = (p * ar - q * ai) - xa * br - u * pr2
        s2i = (p * ai + q * ar) - xa * bi - u * pi2
        pr1 = ar
        pi1 = ai
        pr2 = br
        pi2 = bi
        ar = -s1i / k2
        ai = s1r / k2
        br = -s2i / k2
        bi = s2r / k2
        n += 1
        co[n, 0] = ar
        co[n, 1] = ai
        co[n, 2] = br
        co[n, 3] = bi
        m_next = (half_r * m_n + half_u * m_prev) / n
        m_prev = m_n
        m_n = m_next
        tpow = tpow * tau
        prev_term = mpow
        mpow = m_n * tpow
        s0 = s0 + mpow
        s1 = s1 + n * mpow
        if qnum / (n + 1) <= 0.25 and max(mpow, prev_term) <= 1e-19:
            break
        if n > 200:
            break
    tail = 4.0 * max(mpow, prev_term)
    d_x = prm[5] + prm[6] * abs(a) + 2.0 * EPS * (abs(r0) + 2.0 * abs(u * a))
    pert = (d_x + prm[7]) * tau / 2.0 + prm[6] * tau * tau / 4.0
    return n, tail + 8.1 * EPS * s1 + pert, s0, s1


def _horner(co, n, dt):
    """Horner's rule of ``co[0..n]`` at the real ``dt``: two roundings a step a component."""
    s1r = co[n, 0]
    s1i = co[n, 1]
    s2r = co[n, 2]
    s2i = co[n, 3]
    for k in range(n - 1, -1, -1):
        s1r = s1r * dt + co[k, 0]
        s1i = s1i * dt + co[k, 1]
        s2r = s2r * dt + co[k, 2]
        s2i = s2i * dt + co[k, 3]
    return s1r, s1i, s2r, s2i


def _own(common, s0, s1):
    """Window bound beyond its anchor's: ``common`` plus Horner's rounding, padded."""
    return (common + 2.02 * EPS * (s0 + s1)) * (1.0 + 1e-9)


def eval_one(prm, a, tau, dt, anc, co):
    """One sample: ``(x, y, z, w, bound, ok)`` at ``a + dt`` of the window anchored at a.

    ``anc`` is the window's anchor ``(c1.re, c1.im, c2.re, c2.im, bound)``; ``ok`` is
    False where the window's bound passes tol or its series did not converge (the caller
    then evaluates the kernel itself).
    """
    err = anc[4]
    n, common, s0, s1 = _series(prm, a, tau, anc[0], anc[1], anc[2], anc[3], 1.0 + err, co)
    bound = err + _own(common, s0, s1)
    s1r, s1i, s2r, s2i = _horner(co, n, dt)
    ok = bound <= prm[8] and n <= 200
    return s2i, -s2r, s1i, s1r, bound, ok


def eval_many(prm, a_w, tau_w, anc_w, lo_w, hi_w, t, out_q, out_err, ok_w, co):
    """Fill the samples of many windows: window i gives ``t[lo_w[i]:hi_w[i]]``.

    The series of a window is built once and Horner's rule run for each of its samples:
    the very operations :func:`eval_one` makes for one sample. ``ok_w[i]`` is set False
    where window i is not usable (its samples are then left untouched).
    """
    for i in range(len(a_w)):
        err = anc_w[i, 4]
        a = a_w[i]
        n, common, s0, s1 = _series(prm, a, tau_w[i], anc_w[i, 0], anc_w[i, 1],
                                    anc_w[i, 2], anc_w[i, 3], 1.0 + err, co)
        bound = err + _own(common, s0, s1)
        ok = bound <= prm[8] and n <= 200
        ok_w[i] = ok
        if not ok:
            continue
        for j in range(lo_w[i], hi_w[i]):
            s1r, s1i, s2r, s2i = _horner(co, n, t[j] - a)
            out_q[j, 0] = s2i
            out_q[j, 1] = -s2r
            out_q[j, 2] = s1i
            out_q[j, 3] = s1r
            out_err[j] = bound
    return 0


def chain(prm, a_b, hs_b, k, stop, state, fresh, anc_b, co):
    """Chain a block's anchors from window k (state ``state``) up to window ``stop - 1``.

    Window k's anchor is ``state``; the next anchor is the window's series at its end
    (Horner's rule at ``hs``), with bound ``err + own`` (the window's own bound). Where
    that bound would pass ``chain_limit`` and the state is not ``fresh`` (an exact
    anchor), the chain stops and returns ``(k, True)``: the caller puts an exact value in
    ``state`` and calls again with ``fresh``. Returns ``(next window, needs exact)``;
    ``state`` is updated in place to the anchor of the next window. Each anchor follows
    from the one before alone: the values do not depend on where a chain stopped.
    """
    limit = prm[9]
    while k < stop:
        err = state[4]
        hs = hs_b[k]
        n, common, s0, s1 = _series(prm, a_b[k], abs(hs), state[0], state[1], state[2],
                                    state[3], 1.0 + err, co)
        bound = err + _own(common, s0, s1)
        if bound > limit and not fresh:
            return k, True
        anc_b[k, 0] = state[0]
        anc_b[k, 1] = state[1]
        anc_b[k, 2] = state[2]
        anc_b[k, 3] = state[3]
        anc_b[k, 4] = err
        s1r, s1i, s2r, s2i = _horner(co, n, hs)
        state[0] = s1r
        state[1] = s1i
        state[2] = s2r
        state[3] = s2i
        state[4] = bound
        fresh = False
        k += 1
    return k, False


def chain_back(prm, a_b, hs_b, k, stop, state, fresh, anc_b, co):
    """Chain a block's anchors inwards: from the anchor of window k down to window ``stop``.

    ``state`` is the anchor of window k (stored already); the anchor of window k - 1,
    ``a_(k-1) = a_k - hs_(k-1)``, is the series about ``a_k`` (radius ``|hs_(k-1)|``)
    at ``dt = -hs_(k-1)``, with bound ``err + own``, as :func:`chain` but towards t = 0.
    Returns ``(lowest window chained, needs exact)``: with True, window ``k - 1`` needs an
    exact anchor (its chained bound would pass ``chain_limit``): the caller puts it in
    ``state`` and in ``anc_b[k - 1]`` and calls again from ``k - 1``.
    """
    limit = prm[9]
    while k > stop:
        err = state[4]
        hs = hs_b[k - 1]
        n, common, s0, s1 = _series(prm, a_b[k], abs(hs), state[0], state[1], state[2],
                                    state[3], 1.0 + err, co)
        bound = err + _own(common, s0, s1)
        if bound > limit:
            return k, True
        s1r, s1i, s2r, s2i = _horner(co, n, -hs)
        state[0] = s1r
        state[1] = s1i
        state[2] = s2r
        state[3] = s2i
        state[4] = bound
        k -= 1
        anc_b[k, 0] = s1r
        anc_b[k, 1] = s1i
        anc_b[k, 2] = s2r
        anc_b[k, 3] = s2i
        anc_b[k, 4] = bound
    return k, False


def own_per_window(rt):
    """Return a window's ``own`` bound at ``R h = rt`` (U h^2 = 0, no parameter error).

    Interpreted where the kernels load as object code (numba's ``_series`` is not in the
    process): on Python floats, the same bits, and no numpy warning where a sum
    overflows to inf (as in compiled code).
    """
    prm = [0.0, 0.0, float(rt), 0.0, float(rt), 0.0, 0.0, 0.0, 1.0, 1.0]
    co = np.empty((MAX_TERMS, 4))
    if hasattr(_series, 'py_func'):             # compiled by numba: it takes an array
        prm = np.array(prm)
    n, common, s0, s1 = _series(prm, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, co)
    return float(_own(common, s0, s1))


_KERNELS = None
_STATE = {'compiled': False, 'cached': False, 'how': 'python', 'reason': 'not loaded yet'}
#: numba's options for every kernel: no fast-math (no contraction, no reassociation), and
#: numpy's error model (a quotient by zero is inf, not an exception: none occurs, every
#: divisor here is at least 1, and a C function may not raise).
_FLAGS = dict(fastmath=False, error_model='numpy')


def _jit(numba, fn, **kw):
    """``numba.njit(fn)`` with the on-disk cache where it can be had, else without."""
    try:
        return numba.njit(cache=True, **_FLAGS, **kw)(fn), True
    except Exception:                     # no writable cache location: compile in memory
        return numba.njit(cache=False, **_FLAGS, **kw)(fn), False


def _f8(ndim=1, width=0, out=False):
    return ('f8', ndim, width, out)


#: Each kernel's Python arguments (:func:`rigidrot_ros.runtime.native.trampoline_ir`) and
#: its result: ``'sample'`` the tuple of :func:`eval_one`, ``'int'``, ``'pair'`` ``(k,
#: needs exact)``.
_CHAIN = ([_f8(), _f8(), _f8(), 'i', 'i', _f8(out=True), 'b', _f8(2, 5, True),
           _f8(2, 4, True)], 'pair')
_NATIVE = {
    'eval_one': ([_f8(), 'f', 'f', 'f', _f8(), _f8(2, 4, True)], 'sample'),
    'eval_many': ([_f8(), _f8(), _f8(), _f8(2, 5), ('i8', 1, 0, False), ('i8', 1, 0, False),
                   _f8(), _f8(2, 4, True), _f8(out=True), ('b1', 1, 0, True),
                   _f8(2, 4, True)], 'int'),
    'chain': _CHAIN, 'chain_back': _CHAIN}


def _c_kernels():
    """Compile the kernels as C functions (numba imported): ``{name: (cfunc, spec, result)}``.

    Each takes its arrays as pointers and lengths (``numba.carray`` views of them) and
    calls the kernel compiled with :data:`_FLAGS`, as numba's own load does; this
    module's helpers are compiled first, so that the kernels call the compiled ones.
    """
    import numba
    from numba import carray
    from rigidrot_ros.runtime.native import c_signature
    g = globals()
    for name in ('_series', '_horner', '_own'):
        g[name] = numba.njit(**_FLAGS)(getattr(g[name], 'py_func', g[name]))
    one, many, fwd, back = (numba.njit(**_FLAGS)(getattr(f, 'py_func', f))
                            for f in (eval_one, eval_many, chain, chain_back))

    def sig(name):
        return c_signature(*_NATIVE[name])

    @numba.cfunc(sig('eval_one'), **_FLAGS)
    def c_eval_one(prm, nprm, a, tau, dt, anc, nanc, co, nco, out):
        x, y, z, w, bound, ok = one(carray(prm, (nprm,)), a, tau, dt, carray(anc, (nanc,)),
                                    carray(co, (nco, 4)))
        o = carray(out, (5,))
        o[0] = x
        o[1] = y
        o[2] = z
        o[3] = w
        o[4] = bound
        return 1 if ok else 0

    @numba.cfunc(sig('eval_many'), **_FLAGS)
    def c_eval_many(prm, nprm, a_w, na, tau_w, ntau, anc_w, nanc, lo_w, nlo, hi_w, nhi, t, nt,
                    out_q, nq, out_err, ne, ok_w, nok, co, nco):
        return many(carray(prm, (nprm,)), carray(a_w, (na,)), carray(tau_w, (ntau,)),
                    carray(anc_w, (nanc, 5)), carray(lo_w, (nlo,)), carray(hi_w, (nhi,)),
                    carray(t, (nt,)), carray(out_q, (nq, 4)), carray(out_err, (ne,)),
                    carray(ok_w, (nok,)), carray(co, (nco, 4)))

    def c_chain(fn):
        @numba.cfunc(sig('chain'), **_FLAGS)
        def c(prm, nprm, a_b, na, hs_b, nh, k, stop, state, ns, fresh, anc_b, nanc, co, nco):
            k, need = fn(carray(prm, (nprm,)), carray(a_b, (na,)), carray(hs_b, (nh,)), k,
                         stop, carray(state, (ns,)), fresh != 0, carray(anc_b, (nanc, 5)),
                         carray(co, (nco, 4)))
            return 2 * k + (1 if need else 0)
        return c

    cf = {'eval_one': c_eval_one, 'eval_many': c_eval_many, 'chain': c_chain(fwd),
          'chain_back': c_chain(back)}
    return {name: (cf[name], *_NATIVE[name]) for name in cf}


def _load():
    py = {'eval_one': eval_one, 'eval_many': eval_many, 'chain': chain,
          'chain_back': chain_back}
    if switches.no_jit():
        _STATE.update(compiled=False, cached=False, how='python',
                      reason='RIGIDROT_NO_JIT is set')
        return py
    why = 'RIGIDROT_NO_NATIVE is set'
    if not switches.no_native():
        from rigidrot_ros.runtime import native
        try:
            out, cached = native.load_kernels(__file__, 'engine', _c_kernels)
        except native.NativeError as exc:
            why = str(exc)
        else:
            _warm(out)
            _STATE.update(compiled=True, cached=cached, how='native', reason='')
            return out
    try:
        import numba
    except ImportError as exc:
        _STATE.update(compiled=False, cached=False, how='python',
                      reason=f'numba not importable: {exc}')
        return py
    cached = True
    g = globals()
    for name in ('_series', '_horner', '_own'):
        g[name], ok = _jit(numba, getattr(g[name], 'py_func', g[name]))
        cached = cached and ok
    out = {}
    for name, fn in py.items():
        out[name], ok = _jit(numba, fn)
        cached = cached and ok
    with cached_load():
        _warm(out)
    _STATE.update(compiled=True, cached=cached, how='numba', reason=why)
    return out


def _warm(k):
    """Call every kernel once on a tiny case.

    numba compiles or loads its code now, at load time, not at the first sample of the
    caller's (timed) work.
    """
    prm = np.array([0.5, 0.05, 0.3, -0.2, 0.36, 0.0, 0.0, 0.0, 1e-12, 0.9e-12])
    co = np.empty((MAX_TERMS, 4))
    anc = np.array([[1.0, 0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0, 0.0]])
    a, hs = np.array([0.0, 0.5]), np.array([0.5, 0.5])
    k['eval_one'](prm, 0.0, 0.5, 0.25, anc[0], co)
    state = anc[0].copy()
    k['chain'](prm, a, hs, 0, 2, state, True, anc, co)
    k['chain_back'](prm, a, hs, 1, 0, anc[1].copy(), False, anc, co)
    t = np.array([0.1, 0.6])
    idx = np.array([0, 1], dtype=np.int64)
    k['eval_many'](prm, a, hs, anc, idx, idx + 1, t, np.empty((2, 4)), np.empty(2),
                   np.empty(2, dtype=np.bool_), co)
    own_per_window(0.5)            # _series and _own called from Python, as dense.py does


def kernels():
    """Return the kernels ``eval_one``, ``eval_many``, ``chain``, ``chain_back`` by name.

    Compiled by numba where it imports (else the Python functions: the same bits).
    """
    global _KERNELS
    if _KERNELS is None:
        _KERNELS = _load()
    return _KERNELS


def jit_state():
    """Return how the kernels run: compiled, cached on disk, ``how``, and why not native.

    ``how``: ``'native'`` (object code, :mod:`rigidrot_ros.runtime.native`), ``'numba'``
    (numba's own load; ``reason`` says why not native) or ``'python'`` (interpreted;
    ``reason`` says why).
    """
    kernels()
    return dict(_STATE)
