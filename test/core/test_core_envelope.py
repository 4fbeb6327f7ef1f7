"""Small torque, long horizons, fast spin: the regimes where 1F1 cancels.

The certified Taylor continuation and the 1F1 form are two representations of the same
exact solution that share no formula; they check each other where both are cheap, and
DOP853 checks the small-torque regime directly.
"""

import mpmath
import numpy as np
from numpy.testing import assert_allclose
import pytest

from conftest import CLAIM, rate_claim, reference
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.core.adiabatic import ADIABATIC_DELTA, AdiabaticKernel
from rigidrot_ros.core.kernel import HyperKernel
from rigidrot_ros.core.method import hyper_kernel, taylor_kernel
from rigidrot_ros.core.models import DELTA_SWITCH
from rigidrot_ros.core.taylor import TaylorKernel


@pytest.mark.parametrize('delta', [0.3, 3.0, 30.0])
def test_taylor_and_1f1_agree_to_long_horizons(delta, rng):
    p, q, r0 = rng.uniform(-1, 1, 3)
    U = (p * p + q * q) / (4 * delta)
    t = np.array([0.0, 0.7, 13.0, 100.0, 400.0])
    hyper = HyperKernel(p, q, r0, U, 'flint', tol=1e-13)
    taylor = TaylorKernel(*(mpmath.mpf(v) for v in (p, q, r0, U)), tol=1e-13)
    for ti in t:
        a, ea = hyper.evaluate(ti)
        b, eb = taylor.evaluate(ti)
        assert np.linalg.norm(a - b) <= ea + eb
        assert np.linalg.norm(a - b) <= 1e-14


def test_spacecraft_torque_against_dop853():
    """I = 1000 kg m^2, 1 mN m: U = 1e-6 rad/s^2, delta = 3e4 (1F1 would need ~7e4 bits)."""
    scene = Scene(inertia=(1000.0, 1000.0, 1000.0), torque=(0.0, 6e-4, 8e-4),
                  omega0=(0.3, -0.2, 0.5), attitude0=(0.1, 0.2, 0.3, 0.9))
    sol = solve(scene)
    assert sol.method == 'adiabatic-series'
    t = np.linspace(0.0, 10.0, 11)
    s = sol.at(t)
    w, q, q_err, w_err = reference(scene, t)
    err = quat.angle_between(s.quaternion, q)
    assert np.all(err <= CLAIM + q_err), (err - q_err).max()
    w_dev = np.linalg.norm(s.omega - w, axis=-1)
    assert np.all(w_dev <= rate_claim(s.omega) + w_err), (w_dev - w_err).max()
    assert np.all(s.error_bound <= CLAIM)


def test_axisymmetric_small_torque_long_horizon_invariants():
    """Axial torque 1e-7 rad/s^2 over 1e4 s: unit, continuous, rates exact, bound held."""
    scene = Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 2e-7),
                  omega0=(0.05, -0.02, 0.3))
    sol = solve(scene)
    assert sol.model == 'axial-torque' and 'taylor' in sol.method
    t = np.linspace(9990.0, 10000.0, 1001)
    s = sol.at(t)
    assert np.all(s.error_bound <= 1e-12)
    assert_allclose(np.linalg.norm(s.quaternion, axis=-1), 1.0, atol=1e-15)
    assert np.all(np.einsum('ij,ij->i', s.quaternion[1:], s.quaternion[:-1]) > 0)
    # r grows as m3 / I3 t, the transverse rate keeps its magnitude
    assert_allclose(s.omega[:, 2], 0.3 + 2e-7 * t, rtol=0, atol=1e-15)
    assert_allclose(np.hypot(s.omega[:, 0], s.omega[:, 1]), np.hypot(0.05, 0.02), atol=1e-15)


def test_continuity_across_the_1f1_taylor_switch():
    """At the switch both methods give the same motion; either side, solve picks each."""
    p, q, r0 = 0.3, -0.2, 0.5
    t = np.array([0.0, 1.0, 10.0, 60.0])
    u_switch = (p * p + q * q) / (4 * DELTA_SWITCH)
    hyper = HyperKernel(p, q, r0, u_switch, 'flint', tol=1e-13)
    taylor = TaylorKernel(*(mpmath.mpf(v) for v in (p, q, r0, u_switch)), tol=1e-13)
    for ti in t:
        a, ea = hyper.evaluate(ti)
        b, eb = taylor.evaluate(ti)
        assert np.linalg.norm(a - b) <= ea + eb
    out = []
    for factor in (1 - 1e-13, 1 + 1e-13):
        u = (p * p + q * q) / (4 * DELTA_SWITCH * factor)
        sol = solve(Scene(inertia=(1.0, 1.0, 1.0), torque=(0.0, 0.0, u), omega0=(p, q, r0)))
        out.append((sol.method, sol.at(t)))
    assert out[0][0] == 'hypergeometric-flint' and out[1][0] == 'taylor-series-flint'
    # the scenes differ by 2e-13 in U: the motion moves by well under 1e-12 rad by t = 60 s
    diff = quat.angle_between(out[0][1].quaternion, out[1][1].quaternion)
    assert diff.max() < 2e-12


def test_1f1_falls_back_to_taylor_past_its_bit_budget(monkeypatch):
    monkeypatch.setattr(HyperKernel, 'FALLBACK_BITS', 40)    # 40 bits cannot reach 1e-13
    p, q, r0 = 0.3, -0.2, 0.5
    U = (p * p + q * q) / (4 * 30.0)
    kernel = hyper_kernel(p, q, r0, U, 'flint', tol=1e-13)
    a, ea = kernel.evaluate(3.0)
    assert 'taylor' in kernel.method
    b, eb = TaylorKernel(*(mpmath.mpf(v) for v in (p, q, r0, U)), tol=1e-13).evaluate(3.0)
    assert np.linalg.norm(a - b) <= ea + eb


@pytest.mark.parametrize('transverse, r0, U, horizon', [
    (10.0, 100.0, 1e2, 20.0),          # fast spin, large torque
    (10.0, -100.0, 1e-10, 2.0),        # fast spin, tiny torque
    (1e-3, 0.0, 1e-10, 1e5),           # slow, tiny torque, long horizon
    (0.5, 0.0, 1e2, 1e3),              # large torque, long horizon
])
def test_envelope_corners_hold_tol(transverse, r0, U, horizon):
    scene = Scene(inertia=(1.0, 1.0, 1.0), torque=(0.0, 0.0, U),
                  omega0=(transverse * 0.6, transverse * 0.8, r0))
    sol = solve(scene)
    t = np.array([0.0, horizon / 3, horizon])
    s = sol.at(t)
    assert np.all(np.isfinite(s.quaternion)) and np.all(s.error_bound <= 1e-12)
    assert_allclose(np.linalg.norm(s.quaternion, axis=-1), 1.0, atol=1e-15)


@pytest.mark.parametrize('eps', [1e-4, 1e-7, 1e-10])
def test_torque_to_zero_meets_the_torque_free_motion(eps):
    """U -> 0: the axial-torque solution tends to Theorem 5's, at the rate the physics sets."""
    base = dict(inertia=(2.0, 2.0, 1.0), omega0=(0.3, -0.2, 0.5),
                attitude0=(0.1, 0.2, 0.3, 0.9))
    t = np.array([0.0, 1.0, 10.0])
    free = solve(Scene(**base)).at(t)
    near = solve(Scene(torque=(0.0, 0.0, eps), **base)).at(t)
    # the spin changes by eps/I3 t, the attitude by at most about eps t^2 (1 + |A|)
    assert quat.angle_between(near.quaternion, free.quaternion).max() <= 4 * eps * t[-1] ** 2


@pytest.mark.parametrize('eps', [1e-4, 1e-8, 1e-12])
def test_axisymmetric_tends_to_the_sphere(eps):
    """I3 -> I: Theorem 2's motion tends to Theorem 1's; the difference is O(eps)."""
    t = np.array([0.0, 1.0, 10.0])
    kw = dict(torque=(0.0, 0.0, 0.2), omega0=(0.3, -0.2, 0.5), attitude0=(0.1, 0.2, 0.3, 0.9))
    sphere = solve(Scene(inertia=(2.0, 2.0, 2.0), **kw)).at(t)
    near = solve(Scene(inertia=(2.0, 2.0, 2.0 * (1 + eps)), **kw))
    assert near.model == 'axial-torque'
    s = near.at(t)
    assert quat.angle_between(s.quaternion, sphere.quaternion).max() <= 10 * eps * t[-1] ** 2 \
        + 1e-12


@pytest.mark.parametrize('model', ['sphere', 'axial-torque', 'oblique-virtual',
                                   'transverse-body'])
def test_dense_output_matches_sample_by_sample(model, rng, monkeypatch):
    """Batches use windowed expansions; they equal single evaluations within the bounds."""
    from conftest import random_scene
    import rigidrot_ros.core.models as models
    scene = random_scene(model, rng)
    t = np.sort(rng.uniform(-5.0, 50.0, 400))
    dense = solve(scene).at(t)
    monkeypatch.setattr(models, 'DENSE_MIN', 10 ** 9)
    single = solve(scene, tol=2e-14).at(t)
    err = quat.angle_between(dense.quaternion, single.quaternion)
    assert np.all(err <= dense.error_bound + single.error_bound)
    assert np.all(dense.error_bound <= 1e-12)
    assert_allclose(dense.omega, single.omega, rtol=0, atol=1e-13)


def test_dense_output_falls_back_when_its_bound_would_exceed_tol():
    from rigidrot_ros.core.dense import dense_spinor
    sol = solve(Scene(inertia=(2.0, 2.0, 2.0), torque=(0.1, 0.0, 0.2), omega0=(0.3, 0.2, 0.1)))
    kernel = sol._kernel
    t = np.linspace(0.0, 2.0, 50)
    q_ref = np.array([kernel.evaluate(x)[0] for x in t])
    kernel.tol, saved = 1e-15, kernel.tol           # no window can meet this: per sample
    try:
        q, err = dense_spinor(kernel, t)
    finally:
        kernel.tol = saved
    assert_allclose(q, q_ref, rtol=0, atol=1e-15)


@pytest.mark.parametrize('delta0, horizon, methods', [
    (DELTA_SWITCH, 30.0, {'hypergeometric-flint', 'taylor-series-flint'}),
    (ADIABATIC_DELTA, 300.0, {'taylor-series-flint', 'adiabatic-series'}),
])
def test_fine_sweep_across_each_switch_is_continuous(delta0, horizon, methods):
    """21 scenes straddling a delta switch: the motion moves smoothly with U across it."""
    p, q, r0 = 0.3, -0.2, 0.5
    t = np.array([5.0, horizon])
    u0 = (p * p + q * q) / (4 * delta0)
    rel = np.linspace(-1e-10, 1e-10, 21)
    used, quats = set(), []
    for r in rel:
        sol = solve(Scene(inertia=(1.0, 1.0, 1.0), torque=(0.0, 0.0, u0 * (1 + r)),
                          omega0=(p, q, r0)))
        used.add(sol.method)
        quats.append(sol.at(t).quaternion)
    assert methods <= used
    # sensitivity: d(attitude)/dU <= t^2 (rotation U t^2 / 2 about a moving axis, twice)
    step = (rel[1] - rel[0]) * u0 * t ** 2
    for a, b in zip(quats, quats[1:]):
        assert np.all(quat.angle_between(a, b) <= step + 2e-12)


@pytest.mark.parametrize('model', ['sphere', 'oblique-virtual'])
def test_scalar_stream_reuses_windows_within_bounds(model, rng, monkeypatch):
    """Tick-by-tick scalar calls (the node's path) against single evaluations at 2e-14."""
    from conftest import random_scene
    import rigidrot_ros.core.models as models
    scene = random_scene(model, rng)
    sol = solve(scene)
    t = np.arange(0.0, 20.0, 0.01)
    ticks = [sol.at(float(x)) for x in t]
    q = np.array([s.quaternion for s in ticks])
    bound = np.array([float(s.error_bound) for s in ticks])
    monkeypatch.setattr(models, 'DENSE_MIN', 10 ** 9)
    ref = solve(scene, tol=2e-14).at(t)
    assert np.all(quat.angle_between(q, ref.quaternion) <= bound + ref.error_bound)
    assert np.all(bound <= 1e-12)
    assert_allclose(np.array([s.omega for s in ticks]), ref.omega, rtol=0, atol=1e-13)


def test_far_first_query_seeds_a_checkpoint_by_1f1():
    """A query 4e4 rad away tries certified 1F1 first; it equals pure stepping, and a stream
    continues from the seeded checkpoint."""
    p, q, r0 = 6.0, 8.0, 0.5
    u = (p * p + q * q) / (4 * 2500.0)
    args = [mpmath.mpf(v) for v in (p, q, r0, u)]
    hybrid = taylor_kernel(*args, tol=4e-13)
    stepping = TaylorKernel(*args, tol=4e-13)               # no seeder: never tries 1F1
    for t in (2000.0, 2000.01, 2000.02):
        a, ea = hybrid.evaluate(t)
        b, eb = stepping.evaluate(t)
        assert np.linalg.norm(a - b) <= ea + eb
    assert isinstance(hybrid.seeder.hyper, HyperKernel)      # the 1F1 seed was used
    assert hybrid.seeded == 1
    assert 2000.0 in hybrid._ck[1][0]


@pytest.mark.parametrize('delta', [1e4, 1e5, 1e6, 1e8])
def test_adiabatic_series_against_certified_taylor(delta, rng):
    """Two representations sharing no formula: superadiabatic frames vs Taylor balls."""
    p, q = rng.uniform(-3, 3, 2)
    r0 = rng.uniform(-2, 2)
    u = (p * p + q * q) / (4 * delta)
    adiabatic = AdiabaticKernel(p, q, r0, u, tol=4e-13)
    taylor = TaylorKernel(*(mpmath.mpf(v) for v in (p, q, r0, u)), tol=4e-14)
    for t in (0.0, 0.3, 7.0, 90.0, 800.0):
        a, ea = adiabatic.evaluate(t)
        b, eb = taylor.evaluate(t)
        assert np.dot(a, b) > 0                                # same sign: continuous
        assert np.linalg.norm(a - b) <= ea + eb
        assert np.linalg.norm(a - b) <= 1e-14


def test_continuity_at_the_adiabatic_switch():
    p, q, r0 = 0.3, -0.2, 0.5
    u = (p * p + q * q) / (4 * ADIABATIC_DELTA)
    t = np.array([0.0, 10.0, 200.0])
    below = solve(Scene(inertia=(1.0, 1.0, 1.0), torque=(0.0, 0.0, u * (1 + 1e-13)),
                        omega0=(p, q, r0)))
    above = solve(Scene(inertia=(1.0, 1.0, 1.0), torque=(0.0, 0.0, u * (1 - 1e-13)),
                        omega0=(p, q, r0)))
    assert below.method == 'taylor-series-flint' and above.method == 'adiabatic-series'
    diff = quat.angle_between(below.at(t).quaternion, above.at(t).quaternion)
    assert diff.max() < 2e-12


def test_mpmath_backend_covers_small_torque_through_the_adiabatic_series():
    scene = Scene(inertia=(1000.0, 1000.0, 1000.0), torque=(0.0, 6e-4, 8e-4),
                  omega0=(0.3, -0.2, 0.5))
    a = solve(scene, backend='mpmath')
    b = solve(scene, backend='flint')
    assert a.method == b.method == 'adiabatic-series'
    t = np.array([1.0, 1e3, 1e5])
    assert quat.angle_between(a.at(t).quaternion, b.at(t).quaternion).max() <= 1e-15


@pytest.mark.parametrize('transverse, r0, U', [(10.0, 100.0, 1e-10), (10.0, -100.0, 1e-6),
                                               (0.5, 0.0, 1e-8)])
def test_far_corners_at_1e5_s(transverse, r0, U):
    """Fast spin, tiny torque, t = 1e5 s: the corner the Taylor path could not reach cheaply."""
    scene = Scene(inertia=(2.0, 2.0, 1.0), torque=(2.0 * U, 0.0, 0.0),
                  torque_frame='virtual', omega0=(transverse * 0.6, transverse * 0.8, r0))
    sol = solve(scene)
    assert sol.method == 'adiabatic-series'
    s = sol.at(np.array([0.0, 5e4, 1e5, 1e5 + 0.01]))
    assert np.all(np.isfinite(s.quaternion)) and np.all(s.error_bound <= 1e-12)
    assert_allclose(np.linalg.norm(s.quaternion, axis=-1), 1.0, atol=1e-15)


def test_mpmath_backend_continues_by_taylor_where_its_1f1_cannot():
    p, q, r0 = 0.3, -0.2, 0.5
    u = (p * p + q * q) / (4 * 3000.0)                        # ~7000 bits for mpmath's 1F1
    scene = Scene(inertia=(1.0, 1.0, 1.0), torque=(0.0, 0.0, u), omega0=(p, q, r0))
    a = solve(scene, backend='mpmath')
    assert a.method == 'taylor-series-flint'
    t = np.array([0.0, 10.0, 100.0])
    b = solve(scene, backend='flint', tol=2e-14).at(t)
    assert quat.angle_between(a.at(t).quaternion, b.quaternion).max() <= 1e-12


def test_tight_tol_uses_the_certified_route_where_the_series_estimate_is_too_coarse():
    p, q, r0 = 0.3, -0.2, 0.5
    u = (p * p + q * q) / (4 * 2e4)                            # 10 eps^3 = 1.25e-15
    scene = Scene(inertia=(1.0, 1.0, 1.0), torque=(0.0, 0.0, u), omega0=(p, q, r0))
    assert solve(scene, tol=1e-12).method == 'adiabatic-series'
    tight = solve(scene, tol=2e-14)
    assert tight.method == 'taylor-series-flint'
    t = np.array([1.0, 500.0])
    assert quat.angle_between(tight.at(t).quaternion,
                              solve(scene).at(t).quaternion).max() <= 1e-12 + 2e-14
