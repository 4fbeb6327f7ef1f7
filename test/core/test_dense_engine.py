"""The compiled dense engine: its cache and fallbacks, its chains and far anchors (issue 20).

- numba's on-disk cache goes to ``NUMBA_CACHE_DIR`` when set, and a function numba cannot
  cache (no file to cache it beside) is compiled in memory instead of failing;
- without numba (``RIGIDROT_NO_JIT=1``) the interpreted engine gives the compiled one's
  bits, sample for sample, in another process;
- anchors chained outwards and inwards from a block's exact anchor, and samples in their
  windows, lie within their bounds of an mpmath Taylor integration at 30 digits (no shared
  code: mpmath's own ODE solver on the real form of the spinor equation);
- the far routes of the 1F1 kernel (Tricomi's U, cached gamma factors: the four Kummer
  functions, and the spinor itself from two U) give balls that overlap those of Arb's 1F1
  at both signs of s and at several precisions, and are as narrow (or far below the
  anchors' floor where the U are summed at fewer bits), also at delta = 325 against
  1F1 at 1200 bits; a U precision too low for tol is repeated at the working precision;
- a block's layout holds every window's own anchor and width, exactly.
"""

import json
import os
import subprocess
import sys

import mpmath
import numpy as np
import pytest

from rigidrot_ros.core import engine, Scene, solve

SCENE = Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05), omega0=(0.3, -0.2, 0.5))
#: Times on both sides of t = 0, in several octaves (windows of several blocks).
TIMES = [-7.3, -0.4, 0.0, 0.3, 1.7, 5.2, 9.9, 33.3, 61.0, 130.7]

_CHILD = r'''
import json, sys
from rigidrot_ros.core import engine, Scene, solve
scene = Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05), omega0=(0.3, -0.2, 0.5))
sol = solve(scene)
out = [sol.at(t).quaternion.tolist() + [float(sol.at(t).error_bound)] for t in TIMES]
print(json.dumps({'state': engine.jit_state(), 'samples': [[x.hex() for x in r] for r in out],
                  'linalg': 'scipy.linalg' in sys.modules, 'numba': 'numba' in sys.modules}))
'''


def _child(env_extra, tmp_path):
    env = dict(os.environ, **env_extra)
    code = _CHILD.replace('TIMES', repr(TIMES))
    out = subprocess.run([sys.executable, '-c', code], env=env, cwd=str(tmp_path),
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_interpreted_engine_gives_the_compiled_bits_in_another_process(tmp_path):
    # numba is an install requirement: the compiled engine must be in use here
    assert engine.jit_state()['compiled'], engine.jit_state()['reason']
    sol = solve(SCENE)
    here = [[x.hex() for x in sol.at(t).quaternion.tolist() + [float(sol.at(t).error_bound)]]
            for t in TIMES]
    got = _child({'RIGIDROT_NO_JIT': '1'}, tmp_path)
    assert got['state']['compiled'] is False
    assert 'RIGIDROT_NO_JIT' in got['state']['reason']
    assert got['samples'] == here


def test_numba_cache_goes_to_numba_cache_dir(tmp_path):
    cache = tmp_path / 'numba-cache'
    env = {'NUMBA_CACHE_DIR': str(cache), 'RIGIDROT_NO_JIT': '', 'RIGIDROT_NO_NATIVE': '1'}
    got = _child(env, tmp_path)
    assert got['state']['compiled'] and got['state']['cached']
    assert got['state']['how'] == 'numba' and 'RIGIDROT_NO_NATIVE' in got['state']['reason']
    files = [f for _, _, fs in os.walk(cache) for f in fs]
    assert any(f.endswith('.nbi') for f in files) and any(f.endswith('.nbc') for f in files)
    # a second process loads from that cache and gives the same bits
    again = _child(env, tmp_path)
    assert again['samples'] == got['samples']
    # numba's BLAS probe (an import of scipy.linalg) was refused while it compiled or loaded
    assert got['linalg'] is False and again['linalg'] is False


def test_the_native_kernels_build_once_then_load_without_numba_and_give_numbas_bits(
        tmp_path):
    cache = tmp_path / 'native-cache'
    env = {'NUMBA_CACHE_DIR': str(cache), 'RIGIDROT_NO_JIT': '', 'RIGIDROT_NO_NATIVE': ''}
    built = _child(env, tmp_path)
    assert built['state'] == {'compiled': True, 'cached': False, 'how': 'native',
                              'reason': ''}
    assert [f for f in os.listdir(cache) if f.startswith('engine.')
            and f.endswith('.native')], os.listdir(cache)
    loaded = _child(env, tmp_path)
    assert loaded['state']['how'] == 'native' and loaded['state']['cached']
    assert loaded['numba'] is False             # machine code alone: no numba, no LLVM
    by_numba = _child({'NUMBA_CACHE_DIR': str(tmp_path / 'numba-cache'),
                       'RIGIDROT_NO_JIT': '', 'RIGIDROT_NO_NATIVE': '1'}, tmp_path)
    assert by_numba['state']['how'] == 'numba'
    assert built['samples'] == loaded['samples'] == by_numba['samples']


def test_the_blas_probe_is_refused_to_the_loading_thread_alone():
    import threading
    from rigidrot_ros.runtime import jit
    hook = jit._RefuseScipyLinalg()
    for name in ('scipy.linalg', 'scipy.linalg.cython_blas'):
        with pytest.raises(ModuleNotFoundError, match='while compiled code loads'):
            hook.find_spec(name, None)
    assert hook.find_spec('scipy.linalgebra', None) is None
    assert hook.find_spec('scipy.special', None) is None
    other = []
    t = threading.Thread(target=lambda: other.append(hook.find_spec('scipy.linalg', None)))
    t.start()
    t.join()
    assert other == [None]


def test_a_function_numba_cannot_cache_is_compiled_in_memory():
    import numba
    scope = {}
    exec('def twice(x):\n    return 2.0 * x\n', scope)     # no source file: no cache locator
    with pytest.raises(RuntimeError):
        numba.njit(cache=True)(scope['twice'])
    fn, cached = engine._jit(numba, scope['twice'])
    assert cached is False
    assert fn(1.5) == 3.0


def _reference(dense, times, dps=30):
    """Spinor (v1, v2) at sorted times by mpmath.odefun (Taylor) from v(0) = (1, 0)."""
    with mpmath.workdps(dps):
        p, q, r0, u = (mpmath.mpf(v) for v in dense.kernel._inputs)

        def rhs(t, y):
            a, b, c, d = y                       # v1 = a + i b, v2 = c + i d
            x = r0 + u * t
            # dv1/dt = (i/2)(X v1 + conj(D) v2), dv2/dt = (i/2)(D v1 - X v2), D = p + i q
            s1r = x * a + p * c + q * d
            s1i = x * b + p * d - q * c
            s2r = p * a - q * b - x * c
            s2i = p * b + q * a - x * d
            return [-s1i / 2, s1r / 2, -s2i / 2, s2r / 2]

        out = {}
        for sign in (1, -1):
            f = mpmath.odefun(lambda t, y: [sign * v for v in rhs(sign * t, y)], 0,
                              [mpmath.mpf(1), 0, 0, 0])
            for t in times:
                if (t >= 0) == (sign > 0):
                    y = f(abs(mpmath.mpf(t)))
                    out[t] = (complex(float(y[0]), float(y[1])), complex(float(y[2]), float(y[3])))
        return out


def test_chained_anchors_both_ways_within_their_bounds_of_mpmath():
    """Anchors chained outwards and inwards, and samples, against mpmath's own integrator."""
    sol = solve(SCENE, tol=1e-12)
    dense = sol._dense
    dense._half, dense._blen = 6, 12               # short blocks: inward chains below 3 s
    cases = []                                     # (t, c1, c2, bound, chained inwards)
    for sign in (1, -1):
        for n in list(range(0, 30, 3)) + [13, 17, 18]:
            blk = dense._block(sign, n)
            anc = blk.anc[n % dense._blen]
            inward = n >= dense._blen and n % dense._blen < dense._half
            cases.append((_anchor_time(dense, sign, n), complex(anc[0], anc[1]),
                          complex(anc[2], anc[3]), anc[4], inward))
    assert any(c[4] for c in cases), 'no anchor chained inwards'
    ts = sorted({c[0] for c in cases} | {0.37, 1.91, -2.2})
    ref = _reference(dense, ts)
    for a, c1, c2, bound, _ in cases:
        r1, r2 = ref[a]
        err = float(np.hypot(abs(c1 - r1), abs(c2 - r2)))
        assert err <= bound, (a, err, bound)
        assert bound <= dense.tol
    for t in (0.37, 1.91, -2.2):
        (x, y, z, w), bound = dense.at(t)
        r1, r2 = ref[t]
        err = float(np.hypot(abs(complex(w, z) - r1), abs(complex(-y, x) - r2)))
        assert err <= bound <= dense.tol, (t, err, bound)


def _anchor_time(dense, sign, n):
    """Anchor time of window index n (direction sign), from the grid's octaves."""
    e = -1
    while True:
        lo, hi, h = dense._octave(sign, e)
        count = int((hi - lo) / h)
        if n < count:
            return sign * (lo + n * h)
        n -= count
        e += 1


def _flint_kernel(prec):
    """Return (kernel, constants at prec, backend) of SCENE's 1F1 kernel (Arb: certified)."""
    kernel = solve(SCENE, tol=1e-12)._dense.kernel
    # python-flint is an install requirement: the scene's kernel is Arb's
    assert kernel.backend.certified, kernel.backend.name
    return kernel, kernel._constants(prec), kernel.backend


@pytest.mark.parametrize('prec', [70, 128])
def test_far_kummer_route_overlaps_arb_1f1(prec):
    kernel, c, b = _flint_kernel(prec)
    far_z = kernel.FAR_Z
    with b.workprec(prec):
        for sv in (40.0, -40.0, 311.5, -2.5e3, 1e5):
            s = b.real(sv)
            try:
                kernel.FAR_Z = None
                ref = kernel._fundamental(c, s)
            finally:
                kernel.FAR_Z = far_z
            far = kernel._fundamental(c, s)
            for x, y in zip(ref, far):
                assert x.overlaps(y)
                # and the ball is about as narrow (within 4x, plus the absolute floor)
                assert float(abs(y).rad()) <= 4 * float(abs(x).rad()) + 2.0 ** -(prec - 8)


@pytest.mark.parametrize('prec', [70, 128])
@pytest.mark.parametrize('uprec', [None, 'auto'])
def test_far_spinor_route_overlaps_the_1f1_route(prec, uprec):
    # (v1, v2) from three Tricomi U and the Wronskian (DLMF 13.2.42), the U summed at the
    # working precision or at the cheaper _u_prec, against Arb's four 1F1 (no U at all)
    kernel, c, b = _flint_kernel(prec)
    seen = 0
    with b.workprec(prec):
        for tv in (-2e4, -300.0, 0.0, 10.0, 90.0, 311.5, 2.5e3, 9.9e4):
            s = (c['r0'] + c['U'] * b.real(tv)) / c['sqrtU']
            up = None if uprec is None else \
                kernel._u_prec(float((s * s).real.mid()), prec)
            far = kernel._spinor_far(c, s, up)
            if far is None:
                assert float(abs(s * s).upper()) <= 2 * kernel.FAR_Z * (1 + 1e-9)
                continue
            seen += 1
            far_z = kernel.FAR_Z
            try:
                kernel.FAR_Z = None                       # Arb's 1F1 itself, no U
                ye, yep, yo, yop = kernel._fundamental(c, s)
            finally:
                kernel.FAR_Z = far_z
            v1 = c['C1'] * ye + c['C2'] * yo
            v1s = c['C1'] * yep + c['C2'] * yop
            v2 = -(2 * c['i'] * v1s + s * v1) / c['dbar']
            for ref, got in ((v1, far[0]), (v2, far[1])):
                assert ref.overlaps(got)
                # and the ball is narrow: about as the reference's, or far below the
                # anchors' floor (dense.ANCHOR_FLOOR 4e-15) where the U are summed cheaper
                floor = 2.0 ** -(prec - 8) if up is None or up >= prec else 1e-17
                assert b.radius(got) <= 4 * b.radius(ref) + floor, (tv, up)
    assert seen >= 5


def test_far_route_repeats_its_u_at_the_working_precision_where_the_bound_misses():
    # a U precision far too low for tol: _at_prec repeats the U at prec (the same value
    # as asking for prec outright) rather than returning the wide ball
    kernel, c, b = _flint_kernel(96)
    t = 311.5
    full = kernel._at_prec(t, 96, 96)
    low = kernel._spinor_far(c, (c['r0'] + c['U'] * b.real(t)) / c['sqrtU'], 24)
    assert b.radius(low[1]) > kernel.FAR_RETRY * kernel.tol       # the cheap try misses
    bits = kernel.U_BITS
    try:
        kernel.U_BITS = -100                                     # _u_prec gives 16 bits
        again = kernel._at_prec(t, 96)
    finally:
        kernel.U_BITS = bits
    assert np.array_equal(again[0], full[0]) and again[1] == full[1]
    assert full[1] <= 2.3e-16 + kernel.FAR_RETRY * kernel.tol


def test_far_route_at_large_delta_overlaps_arb_1f1_at_high_precision():
    # the spacecraft's kernel (delta = 325, alpha = 1/2 + 162.5 i): the dense anchors' route
    # (two U, at _u_prec bits with _u_terms terms, or Arb's own choice where |alpha|^2 is
    # large against |z|) against Arb's four 1F1 at 1200 bits (they cancel some 740 bits)
    from rigidrot_ros.core.kernel import HyperKernel
    mp_ = mpmath.mpf
    kernel = HyperKernel(mp_(0.3), mp_(-0.2), mp_(0.75), mp_(1e-4), 'flint', tol=1e-13,
                         check=False)
    far_z = kernel.FAR_Z
    b = kernel.backend
    for tv in (-300.0, 880.0, 5e4):
        with b.workprec(128):
            c = kernel._constants(128)
            s = (c['r0'] + c['U'] * b.real(tv)) / c['sqrtU']
            sf = float(s.mid())
            up = kernel._u_prec(sf * sf, 128)
            assert up < 128
            v1, v2 = kernel._spinor_far(c, s, up, sf * sf)
        assert b.radius(v1) < 1e-16 and b.radius(v2) < 1e-16, tv
        with b.workprec(1200):
            c = kernel._constants(1200)
            s = (c['r0'] + c['U'] * b.real(tv)) / c['sqrtU']
            try:
                kernel.FAR_Z = None
                ye, yep, yo, yop = kernel._fundamental(c, s)
            finally:
                kernel.FAR_Z = far_z
            r1 = c['C1'] * ye + c['C2'] * yo
            r2 = -(2 * c['i'] * (c['C1'] * yep + c['C2'] * yop) + s * r1) / c['dbar']
        assert b.radius(r1) < 1e-20 and b.radius(r2) < 1e-20
        assert r1.overlaps(v1) and r2.overlaps(v2), tv
    assert len(kernel._nterms) >= 1             # 5e4 s: the terms were chosen here


SPACECRAFT = Scene(inertia=(2.0, 2.0, 3.0), torque=(0.0, 0.0, 2e-4), omega0=(0.3, -0.2, 0.5))


@pytest.mark.parametrize('scene', [SCENE, SPACECRAFT])
def test_block_layout_is_every_windows_own_anchor_and_width(scene):
    # blocks laid out from a shared ramp (one octave) or octave by octave (near t = 0)
    # hold each window's anchor and signed width as the grid defines them, exactly
    dense = solve(scene, tol=1e-12)._dense
    dense._exact_state = lambda a: (1.0, 0.0, 0.0, 0.0, 0.0)     # the layout only
    for sign in (1, -1):
        for b0 in range(0, 6 * dense._blen, dense._blen):
            blk = dense._fill(sign, b0, dense._blen)
            for i in range(len(blk.anc)):
                a = _anchor_time(dense, sign, b0 + i)
                assert blk.a[i] == a
                assert a + blk.hs[i] == _anchor_time(dense, sign, b0 + i + 1)
