"""The fast paths against independent references: double-double phases, dense windows.

- :mod:`rigidrot_ros.core.ddphase` against mpmath at 300 bits, t up to 1e9 s, with its
  stated bound;
- windowed streams (grid windows chained by float continuation) against single
  evaluations at tol = 2e-14 (certified Arb balls, their bounds at most 2e-14), on every
  preset, the spacecraft scene, negative times and a 1e4 s horizon; and, sharing no
  formula with the solver, against DOP853 (``conftest.reference``) within the claim
  (1e-12 rad) plus the integrator's own error;
- the scalar path against the batch path, in any call order;
- the method chooser over leaf modules that do not import each other;
- the memory of a batch against its output.
"""

import ast
import functools
import os

import mpmath
from mpmath import mp
import numpy as np
from numpy.testing import assert_allclose
import pytest

from conftest import CLAIM, reference
from rigidrot_ros.bench import common
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.core.ddphase import DDPoly, IN_FLOOR, MAX_TURNS
from rigidrot_ros.core.kernel import PolyAngle
import rigidrot_ros.core.models as models

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SPACECRAFT = common.SPACECRAFT
PRESETS = common.ratio_scenes()


def _mod4pi_distance(a, ref):
    four_pi = 4 * mp.pi
    d = mpmath.mpf(a) - ref
    return abs(d - four_pi * mpmath.nint(d / four_pi))


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_dd_phase_against_300_bits(seed):
    rng = np.random.default_rng(seed)
    for _ in range(6):
        with mp.workprec(256):
            c1 = mpmath.mpf(rng.normal()) * 10 ** rng.uniform(-3, 2) / 3
            c2 = mpmath.mpf(rng.normal()) * 10 ** rng.uniform(-9, 0) / 7
        ph = DDPoly(c1, c2)
        t = np.concatenate([10 ** rng.uniform(-6, 9, 60) * rng.choice([-1, 1], 60), [0.0]])
        ang, bound, covered = ph.angles(t)
        for ti, a, b, cov in zip(t, ang, bound, covered):
            with mp.workprec(300):
                x = (c1 + c2 * mpmath.mpf(ti)) * mpmath.mpf(ti)
                turns = abs(x) / (4 * mp.pi)
                assert bool(cov) or turns > 0.5 * MAX_TURNS
                if not cov:
                    continue
                err = _mod4pi_distance(a, x)
                # the stated bound, plus the final rounding of the reduced angle
                assert err <= b + IN_FLOOR + abs(a) * 2.0 ** -53, (ti, float(err), b)
                # and the bound is as small as stated: about 4 pi 2^-100 per turn
                mag = (abs(c1) * abs(ti) + abs(c2) * ti * ti) / (4 * mp.pi)
                assert b <= 4 * np.pi * 2.0 ** -99 * (float(mag) + 1)
            sa, sb = ph.angle(float(ti))
            assert sa == pytest.approx(a, abs=4e-16)
            assert sb == pytest.approx(b, rel=1e-12, abs=1e-30)


def test_dd_phase_refuses_what_it_cannot_cover():
    ph = DDPoly(mpmath.mpf(1e8) / 3, mpmath.mpf(1e3) / 7)
    t = np.array([1.0, 1e9, 1e-250, 1e250])
    _, _, covered = ph.angles(t)
    assert covered.tolist() == [True, False, False, False]
    assert ph.angle(1e9) is None
    # PolyAngle then evaluates in multiple precision: the same value mod 4 pi
    pa = PolyAngle(mpmath.mpf(1e8) / 3, mpmath.mpf(1e3) / 7)
    ang, _ = pa.angles(t)
    with mp.workprec(400):
        for ti, a in zip(t, ang):
            tt = mpmath.mpf(ti)
            assert _mod4pi_distance(a, (pa.c1 + pa.c2 * tt) * tt) <= 1e-15


def _reference(scene, t, monkeypatch):
    """Single certified evaluations at tol = 2e-14 (no windows): their bounds are that small."""
    monkeypatch.setattr(models, 'DENSE_MIN', 10 ** 9)
    ref = solve(scene, tol=2e-14).at(t)
    monkeypatch.undo()
    assert np.all(ref.error_bound <= 2e-14)
    return ref


# the triaxial model has no windows and its own 42-digit reference (test_core_triaxial.py)
@pytest.mark.parametrize('name', sorted(n for n in PRESETS if n != 'torque_free_triaxial'))
def test_stream_windows_against_single_evaluations(name, monkeypatch):
    """A 100 Hz stream over 60 s: every sample within its bound of a certified reference."""
    scene = PRESETS[name]
    t = np.arange(1, 6001) * 0.01
    sol = solve(scene, tol=1e-12)
    s = sol.at(t)
    assert np.all(s.error_bound <= 1e-12)
    pick = np.unique(np.concatenate([np.arange(0, 6000, 97), [5999]]))
    ref = _reference(scene, t[pick], monkeypatch)
    err = quat.angle_between(s.quaternion[pick], ref.quaternion)
    assert np.all(err <= s.error_bound[pick] + ref.error_bound)
    assert_allclose(s.omega[pick], ref.omega, rtol=0, atol=1e-13)
    # a reference that shares no formula with the solver: DOP853 on Euler's equations
    _, q_dop, q_err, _ = reference(scene, t[pick])
    err = quat.angle_between(s.quaternion[pick], q_dop)
    assert np.all(err <= CLAIM + q_err), (err - q_err).max()
    if sol._dense is not None:
        # windows chain: far fewer exact anchors than windows
        assert sol._dense.exact_anchors < sol._dense.windows_built / 3


def test_long_horizon_chained_stream_holds_its_bounds(monkeypatch):
    """1e4 s on the spacecraft scene (some 1e4 rad turned) at 10 Hz."""
    t = np.arange(1, 100001) * 0.1
    sol = solve(SPACECRAFT, tol=1e-12)
    s = sol.at(t)
    assert np.all(s.error_bound <= 1e-12)
    pick = np.linspace(0, len(t) - 1, 25).astype(int)
    ref = _reference(SPACECRAFT, t[pick], monkeypatch)
    err = quat.angle_between(s.quaternion[pick], ref.quaternion)
    assert np.all(err <= s.error_bound[pick] + ref.error_bound)


@pytest.mark.parametrize('name', ['sphere_oblique', 'transverse_virtual', 'spacecraft'])
def test_negative_and_unsorted_times(name, monkeypatch):
    scene = PRESETS[name]
    rng = np.random.default_rng(7)
    t = rng.uniform(-30.0, 30.0, 500)
    s = solve(scene).at(t)
    assert np.all(s.error_bound <= CLAIM)
    ref = _reference(scene, t[::25], monkeypatch)
    err = quat.angle_between(s.quaternion[::25], ref.quaternion)
    assert np.all(err <= s.error_bound[::25] + ref.error_bound)
    assert_allclose(s.t, t)


@pytest.mark.parametrize('name', ['default', 'sphere_oblique', 'torque_free', 'spacecraft'])
def test_scalar_calls_equal_the_batch_in_any_order(name):
    """Windows sit on a fixed grid: the value at t does not depend on the call order."""
    scene = PRESETS[name]
    t = np.arange(0, 3000) * 0.01
    batch = solve(scene).at(t)
    sol = solve(scene)
    order = np.random.default_rng(3).permutation(len(t))
    q = np.empty((len(t), 4))
    bound = np.empty(len(t))
    for i in order:
        s = sol.at(float(t[i]))
        q[i], bound[i] = s.quaternion, s.error_bound
    # chained anchors may differ with the order; both are within their bounds
    err = quat.angle_between(q, batch.quaternion)
    assert np.all(err <= bound + batch.error_bound)
    assert np.all(bound <= 1e-12)


def test_kernels_are_leaves_and_one_module_chooses():
    core = os.path.join(ROOT, 'rigidrot_ros', 'core')

    def imports(mod):
        with open(os.path.join(core, mod + '.py'), encoding='utf-8') as fh:
            tree = ast.parse(fh.read())
        out = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                out.add(node.module)
        return out
    leaves = {'kernel', 'taylor', 'adiabatic'}
    for leaf in leaves:
        assert not (imports(leaf) & leaves), (leaf, imports(leaf))
    assert leaves <= imports('method')


def test_batch_memory_is_a_small_multiple_of_its_output():
    t = np.arange(1, 200001) * 0.01
    peak, size = common.batch_memory(solve(SPACECRAFT), t)
    assert peak <= 3 * size


def test_far_query_by_cheap_1f1_seed_equals_stepping():
    """The spacecraft scene at t = 1e3 s: a 128-bit certified 1F1 seed, against stepping."""
    from rigidrot_ros.core.taylor import TaylorKernel
    sol = solve(SPACECRAFT)
    kernel = sol._kernel
    assert sol.method == 'taylor-series-flint'
    a, ea = kernel.evaluate(1e3)
    assert kernel.seeded == 1 and kernel.seeder.hyper is not None
    stepping = TaylorKernel(*kernel._inputs, tol=kernel.tol)          # no seeder
    b, eb = stepping.evaluate(1e3)
    assert np.linalg.norm(a - b) <= ea + eb
    assert ea <= kernel.tol


_CROSSING = Scene(inertia=(1.0, 1.0, 1.0), torque=(0.0, 0.0, 5 / 42000),
                  omega0=(2.0, 1.0, -3.0))
#: Just past 2^15 s: from a checkpoint a few seconds before it, the kernel steps (a turn
#: under 40 rad is not seeded) and one of its steps crosses 2^15, where the float time's
#: last bit goes; a fresh kernel seeds 32770 s directly (a certified 1F1), no step taken.
_PAST = 32770.0


@functools.lru_cache(maxsize=1)
def _fresh_kernel_answer():
    """The crossing scene's kernel at 32770 s, asked nothing before: (spinor, bound)."""
    return solve(_CROSSING, tol=1e-13)._kernel.evaluate(_PAST)


@pytest.mark.parametrize('first', [32760.3, 32760.7, 32767.99])
def test_taylor_answer_does_not_depend_on_earlier_queries(first):
    """A checkpoint at an arbitrary t whose step crosses 2^15 s keeps the time it reached.

    Asked ``first`` (seeded there: a checkpoint at an arbitrary t), then 32770 s (stepped
    from it, across 2^15), the kernel agrees with one asked 32770 s alone within the two
    bounds. Before the continuation stepped to the time it stores, a step across 2^15
    dropped the time's last bit unaccounted: 4.4e-12 rad apart under a 9.2e-16 bound.
    """
    a, ea = _fresh_kernel_answer()
    kernel = solve(_CROSSING, tol=1e-13)._kernel
    kernel.evaluate(first)
    assert kernel.seeded == 1 and first in kernel._ck[1][0]   # a checkpoint at ``first``
    b, eb = kernel.evaluate(_PAST)
    assert kernel.seeded == 1                                  # stepped there, not seeded
    assert np.linalg.norm(a - b) <= ea + eb


def test_taylor_answer_through_the_solution_does_not_depend_on_earlier_queries():
    """The same through ``Solution.at``: 32770 s after 32760.3 s, against the kernel alone."""
    fresh, bound = _fresh_kernel_answer()
    sol = solve(_CROSSING, tol=1e-13)
    sol.at(np.array([32760.3]))
    later = sol.at(np.array([_PAST]))
    err = quat.angle_between(later.quaternion, fresh)
    assert np.all(err <= later.error_bound + bound)
