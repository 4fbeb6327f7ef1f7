"""The torque-free triaxial body (Euler-Poinsot) against references that share no formula.

- a 42-digit Taylor-series integrator of Euler's equations and the quaternion kinematics
  (:func:`rigidrot_ros.bench.triaxial.taylor_reference`: time domain, fixed-point
  integers, no elliptic function), to t = 1e3 s: the attitude within the solution's own
  error bound (which is within tol) and within 2e-14 rad (the t = 1e3 s cases and the
  quick benchmark are marked ``slow``, some 35 s: ``-m "not slow"`` skips them);
- scipy DOP853 at short t; the flip period of the tennis-racket motion (DOP853 events)
  against 4K(m)/lambda computed here from mpmath;
- invariants to t = 1e5 s (h in N, kinetic energy); continuity across every limit (two
  moments meeting: Theorem 5; m -> 1 from both sides: the separatrix; rotation about a
  principal axis: the fixed-axis model); no NaN on extreme-but-valid inputs.
"""

import math

import mpmath
import numpy as np
from numpy.testing import assert_allclose
import pytest
from scipy.integrate import solve_ivp

from conftest import integrate
from rigidrot_ros.bench.triaxial import taylor_reference as reference
from rigidrot_ros.core import PrecisionError, Scene, solve
from rigidrot_ros.core import quaternion as quat


def _body(rng):
    """A seeded triaxial body (any order of the moments) and a generic state."""
    while True:
        inertia = rng.uniform(1.0, 3.0, 3)
        gaps = [abs(inertia[i] - inertia[j]) for i, j in ((0, 1), (1, 2), (0, 2))]
        if min(gaps) > 0.1 and 2 * inertia.max() <= inertia.sum():
            break
    return Scene(inertia=tuple(inertia), omega0=tuple(rng.uniform(-1.0, 1.0, 3)),
                 attitude0=tuple(rng.normal(size=4)))


def _check_against_reference(scene, t, tol=1e-12, backend=None):
    sol = solve(scene, tol=tol, backend=backend)
    assert sol.model == 'torque-free-triaxial'
    s = sol.at(t)
    w_ref, q_ref = reference(scene, t)
    err = quat.angle_between(s.quaternion, q_ref)
    assert np.all(err <= s.error_bound), (err.max(), s.error_bound.max())
    assert np.all(s.error_bound <= tol)
    assert err.max() <= 2e-14                      # measured: <= 6e-15 to t = 1e3 s
    scale = np.linalg.norm(scene.omega0)
    assert_allclose(s.omega, w_ref, rtol=0, atol=4e-15 * scale + 1e-300)
    return err


def test_reference_integrator_converges():
    """The reference itself: degree 22 instead of 30 changes it by < 1e-25."""
    scene = Scene(inertia=(1.0, 2.0, 3.0), omega0=(0.3, -0.2, 0.5),
                  attitude0=(0.1, 0.2, 0.3, 0.9))
    w1, q1 = reference(scene, [3.0])
    w2, q2 = reference(scene, [3.0], deg=22)
    assert np.abs(q1 - q2).max() < 1e-25 and np.abs(w1 - w2).max() < 1e-25


@pytest.mark.parametrize('backend', ['flint', 'mpmath'])
@pytest.mark.parametrize('seed', range(6))
def test_random_bodies_against_42_digit_reference(seed, backend):
    rng = np.random.default_rng(1000 + seed)
    _check_against_reference(_body(rng), np.array([0.0, 0.7, 3.1, 9.9, 20.0]),
                             backend=backend)


@pytest.mark.slow
@pytest.mark.parametrize('seed', range(2))
def test_long_horizon_against_42_digit_reference(seed):
    rng = np.random.default_rng(2000 + seed)
    scene = _body(rng)
    _check_against_reference(scene, np.array([1.0, 100.0, 1000.0]))


@pytest.mark.parametrize('name, inertia, omega0', [
    ('near separatrix, above', (1.0, 2.0, 3.0), (0.01, 1.0, 0.0100001)),
    ('near separatrix, below', (1.0, 2.0, 3.0), (0.0100001, 1.0, 0.01)),
    ('on the separatrix', (3.0, 2.0, 1.5), (0.1, 0.9, -0.2)),
    ('near symmetry (I2 -> I1)', (1.0, 1.0 + 1e-7, 2.0), (0.3, -0.4, 0.8)),
    ('near symmetry (I2 -> I3)', (1.0, 2.0 - 1e-7, 2.0), (0.3, -0.4, 0.8)),
    ('near the major axis', (1.0, 2.0, 3.0), (1e-6, -2e-6, 1.0)),
    ('near the minor axis', (1.0, 2.0, 3.0), (-1.0, 1e-6, 2e-6)),
    ('descending order', (3.0, 2.0, 1.0), (0.2, 0.5, -0.4)),
])
def test_special_bodies_against_42_digit_reference(name, inertia, omega0):
    scene = Scene(inertia=inertia, omega0=omega0, attitude0=(0.3, -0.1, 0.2, 0.9))
    _check_against_reference(scene, np.array([0.0, 2.5, 11.0, 40.0]))


@pytest.mark.slow
def test_separatrix_long_horizon_against_reference():
    scene = Scene(inertia=(1.0, 2.0, 3.0), omega0=(0.01, 1.0, 0.0100001))
    _check_against_reference(scene, np.array([50.0, 300.0, 1000.0]))


@pytest.mark.parametrize('seed', range(4))
def test_dop853_agrees_at_short_t(seed):
    rng = np.random.default_rng(3000 + seed)
    scene = _body(rng)
    t = np.linspace(0.0, 10.0, 21)
    s = solve(scene).at(t)
    w_ref, q_ref = integrate(scene, t)
    assert quat.angle_between(s.quaternion, q_ref).max() < 1e-10
    assert_allclose(s.omega, w_ref, rtol=0, atol=1e-10)


@pytest.mark.parametrize('omega0', [(0.3, -0.2, 0.5), (0.02, 1.0, 0.03), (0.03, 1.0, 0.02),
                                    (1e-6, 2e-6, 1.0)])
def test_mean_precession_rate_against_the_third_kind_integral(omega0):
    """The table's mean of g = dn/(1 + beta dn) equals its closed form with Pi(n|m).

    ``∫_0^K g = (K - Pi(n|m)/(1 - beta^2) + beta pi / (2 sqrt(a (a + b)))) / beta`` with
    ``n = -beta^2 m/(1 - beta^2)``, ``a = 1 - beta^2``, ``b = beta^2 m`` (mpmath's ellippi;
    the table steps the Jacobi system instead): the long-run rate about h hangs on it.
    """
    sol = solve(Scene(inertia=(1.0, 2.0, 3.0), omega0=omega0))
    with mpmath.workprec(sol.precision):
        m, beta, kk = sol.m, sol._beta_mp, sol._kk_mp
        a, b = 1 - beta ** 2, beta ** 2 * m
        pi_c = mpmath.ellippi(-b / a, m)
        total = (kk - pi_c / a + beta * mpmath.pi / (2 * mpmath.sqrt(a * (a + b)))) / beta
        assert abs(total / kk - sol._gbar_mp) <= mpmath.mpf(10) ** -25 * abs(total / kk)


@pytest.mark.parametrize('omega0', [(0.3, -0.2, 0.5), (0.02, 1.0, 0.03), (0.01, 1.0, 0.0100001)])
def test_table_values_at_the_cell_centres_are_correctly_rounded(omega0):
    """sn, cn, dn at every centre (i + 1/2) / 8, which the set-up reaches by the addition
    theorem, against mpmath's theta-function ellipfun at 200 bits: within one rounding."""
    sol = solve(Scene(inertia=(1.0, 2.0, 3.0), omega0=omega0))
    with mpmath.workprec(200):
        m = mpmath.mpf(sol.m)
        for i, centre in enumerate(sol._centres):
            u = mpmath.mpf(centre)
            for f, name in enumerate(('sn', 'cn', 'dn')):
                ref = mpmath.ellipfun(name, u, m=m)
                assert abs(sol._coef[0, i, f] - ref) <= abs(ref) * 2.0 ** -53, (i, name)


def _energy_momentum(scene, s):
    inertia = np.array(scene.inertia)
    h_n = np.einsum('nij,nj->ni', s.rotation, inertia * s.omega)
    energy = 0.5 * np.sum(inertia * s.omega ** 2, axis=-1)
    return h_n, energy


@pytest.mark.parametrize('seed', range(3))
def test_invariants_to_1e5_seconds(seed):
    rng = np.random.default_rng(4000 + seed)
    scene = _body(rng)
    t = np.concatenate([[0.0], np.geomspace(1e-3, 1e5, 400)])
    s = solve(scene).at(t)
    h_n, energy = _energy_momentum(scene, s)
    hn0 = np.linalg.norm(h_n[0])
    # the float64 floor: a few eps of |h| (h is formed from float R and omega here)
    assert np.abs(h_n - h_n[0]).max() <= 3e-15 * hn0
    assert np.abs(energy - energy[0]).max() <= 3e-15 * energy[0]
    assert np.all(s.error_bound <= 1e-12)


def test_invariants_on_the_separatrix_to_1e5_seconds():
    """On the separatrix no fixed-precision integration follows the motion for long."""
    scene = Scene(inertia=(3.0, 4.0, 6.0), omega0=(0.1, 1.0, 0.05),
                  attitude0=(0.1, 0.2, 0.3, 0.9))
    sol = solve(scene)
    assert sol.method == 'separatrix-closed-form'
    t = np.concatenate([[0.0], np.geomspace(1e-3, 1e5, 400)])
    s = sol.at(t)
    h_n, energy = _energy_momentum(scene, s)
    assert np.abs(h_n - h_n[0]).max() <= 3e-15 * np.linalg.norm(h_n[0])
    assert np.abs(energy - energy[0]).max() <= 3e-15 * energy[0]
    # it settles on the intermediate axis: omega -> (0, |h| / I2, 0)
    assert_allclose(s.omega[-1], [0.0, np.linalg.norm(h_n[0]) / 4.0, 0.0], atol=1e-15)
    for i in (0, 50, 200, 400):                     # the scalar path: the same bits
        one = sol.at(float(t[i]))
        assert one.quaternion.tobytes() == s.quaternion[i].tobytes()
        assert one.omega.tobytes() == s.omega[i].tobytes()
        assert float(one.error_bound) == float(s.error_bound[i])


def test_initial_state_continuity_and_scalar_path(rng):
    scene = _body(rng)
    sol = solve(scene)
    s0 = sol.at(0.0)
    assert_allclose(s0.quaternion, scene.attitude0, rtol=0, atol=1e-15)
    assert_allclose(s0.omega, scene.omega0, rtol=0, atol=1e-15)
    t = np.linspace(0.0, 200.0, 20001)
    s = sol.at(t)
    assert_allclose(np.linalg.norm(s.quaternion, axis=-1), 1.0, rtol=0, atol=1e-15)
    dots = np.einsum('ij,ij->i', s.quaternion[1:], s.quaternion[:-1])
    assert np.all(dots > 0)                        # no sign flips, across every period
    step = quat.angle_between(s.quaternion[1:], s.quaternion[:-1])
    wmax = np.linalg.norm(s.omega, axis=-1).max()
    assert np.all(step <= wmax * (t[1] - t[0]) * (1 + 1e-6) + 1e-13)
    for ti in (0.0, 1.234, 77.7, 199.99, -3.5, 1e5):
        one = sol.at(ti)
        many = sol.at(np.array([ti]))
        assert one.quaternion.tobytes() == many.quaternion[0].tobytes()
        assert one.omega.tobytes() == many.omega[0].tobytes()
        assert float(one.error_bound) == float(many.error_bound[0])
        assert_allclose(sol.omega_at(ti), one.omega, rtol=0, atol=0)
        assert one.error_bound <= 1e-12


def _period_events(scene, k, t_end):
    """Zero crossings of omega_k (upward), by DOP853 events: the flip times."""
    inertia = np.array(scene.inertia)

    def rhs(t, w):
        return -np.cross(w, inertia * w) / inertia

    def ev(t, w):
        return w[k]
    ev.direction = 1.0
    r = solve_ivp(rhs, (0.0, t_end), scene.omega0, method='DOP853', rtol=1e-13,
                  atol=1e-14, events=ev)
    return r.t_events[0]


def _k_and_lambda(inertia, w):
    """K(m) and lambda from the body alone (Landau-Lifshitz Sec. 37), in mpmath."""
    with mpmath.workdps(40):
        i = [mpmath.mpf(v) for v in inertia]
        ww = [mpmath.mpf(v) for v in w]
        order = sorted(range(3), key=lambda j: i[j])
        two_t = sum(i[j] * ww[j] ** 2 for j in range(3))
        h2 = sum((i[j] * ww[j]) ** 2 for j in range(3))
        i1, i2, i3 = (i[j] for j in order)
        if h2 > two_t * i2:
            lam = mpmath.sqrt((i3 - i2) * (h2 - two_t * i1) / (i1 * i2 * i3))
            m = (i2 - i1) * (two_t * i3 - h2) / ((i3 - i2) * (h2 - two_t * i1))
        else:
            lam = mpmath.sqrt((i2 - i1) * (two_t * i3 - h2) / (i1 * i2 * i3))
            m = (i3 - i2) * (h2 - two_t * i1) / ((i2 - i1) * (two_t * i3 - h2))
        return float(mpmath.ellipk(m)), float(lam)


@pytest.mark.parametrize('omega0', [(0.02, 1.0, 0.03), (0.03, 1.0, 0.02), (0.3, -0.2, 0.5)])
def test_flip_period_is_4k_over_lambda(omega0):
    """The tennis-racket flip: omega_2 returns every 4K(m)/lambda, in the integration."""
    inertia = (1.0, 2.0, 3.0)
    scene = Scene(inertia=inertia, omega0=omega0)
    kk, lam = _k_and_lambda(inertia, omega0)
    period = 4 * kk / lam
    # the rate about the intermediate axis (sigma A2 sn u) rises through 0 once a period
    ev = _period_events(scene, 1, 4.5 * period)
    assert len(ev) >= 4
    assert_allclose(np.diff(ev), period, rtol=1e-10)
    # and the exact solution's own rate has the same period
    sol = solve(scene)
    t = np.linspace(0.0, period, 7)
    assert_allclose(sol.omega_at(t + period), sol.omega_at(t), rtol=0, atol=1e-14)


def _axis_angle(a, b):
    return quat.angle_between(a.quaternion, b.quaternion)


def test_two_moments_meeting_is_continuous_with_theorem_5():
    """I2 = I1 (1 + eps) -> the axisymmetric model, error O(eps t)."""
    t = np.linspace(0.0, 20.0, 11)
    base = dict(omega0=(0.3, -0.4, 0.8), attitude0=(0.1, 0.2, 0.3, 0.9))
    limit = solve(Scene(inertia=(1.0, 1.0, 2.0), **base))
    assert limit.model == 'torque-free-axisymmetric'
    lim = limit.at(t)
    errs = []
    for eps in (1e-4, 1e-6, 1e-8, 1e-10, 1e-12):
        near = solve(Scene(inertia=(1.0, 1.0 + eps, 2.0), **base))
        assert near.model == 'torque-free-triaxial'
        s = near.at(t)
        err = _axis_angle(s, lim).max()
        errs.append(err)
        assert err <= 5 * eps * 20.0 + 1e-13
        assert_allclose(s.omega, lim.omega, rtol=0, atol=5 * eps * 20.0 + 1e-14)
    assert errs[-1] < 1e-11


@pytest.mark.parametrize('sign', [1, -1])
def test_separatrix_is_approached_from_both_sides(sign):
    """m -> 1 from above and below the separatrix meets the closed form at m = 1."""
    inertia = (3.0, 2.0, 1.5)
    exact = solve(Scene(inertia=inertia, omega0=(0.1, 0.9, -0.2)))
    assert exact.method == 'separatrix-closed-form'
    t = np.linspace(0.0, 15.0, 16)
    ref = exact.at(t)
    for eps in (1e-6, 1e-9, 1e-12, 1e-15):
        near = solve(Scene(inertia=inertia, omega0=(0.1 * (1 + sign * eps), 0.9, -0.2)))
        assert near.method == 'jacobi-elliptic-table'
        assert (near.m < 1)
        s = near.at(t)
        # sensitivity near the separatrix grows like e^(lam t): a loose envelope
        assert _axis_angle(s, ref).max() <= 1e3 * eps + 1e-12
        assert_allclose(s.omega, ref.omega, rtol=0, atol=1e3 * eps + 1e-12)


def test_rotation_about_a_principal_axis_is_continuous():
    """omega0 -> the major or minor axis meets the fixed-axis model."""
    t = np.linspace(0.0, 30.0, 16)
    for axis_rate in ((0.0, 0.0, 1.3), (1.3, 0.0, 0.0)):
        k = int(np.argmax(np.abs(axis_rate)))
        limit = solve(Scene(inertia=(1.0, 2.0, 3.0), omega0=axis_rate))
        assert limit.model == 'fixed-axis'
        lim = limit.at(t)
        for eps in (1e-3, 1e-6, 1e-9, 1e-12):
            w = np.array(axis_rate)
            w[(k + 1) % 3] = eps
            w[(k + 2) % 3] = -eps
            s = solve(Scene(inertia=(1.0, 2.0, 3.0), omega0=tuple(w))).at(t)
            assert _axis_angle(s, lim).max() <= 10 * eps + 1e-13
            assert_allclose(s.omega, lim.omega, rtol=0, atol=10 * eps + 1e-14)


def test_no_nan_on_extreme_but_valid_inputs():
    rng = np.random.default_rng(7)
    t = np.concatenate([[0.0, 1e-9], np.geomspace(1e-3, 1e5, 30), [-1e5]])
    cases = [((1.0, 2.0, 3.0), (s * 0.3, s * -0.2, s * 0.5)) for s in (1e-150, 1e-8, 1e4)]
    cases += [((1e-6, 1.0, 1.0 + 1e-6), (0.3, 0.2, 0.1)),
              ((1e8, 1e8 + 1, 2e8), (1.0, -2.0, 0.5)),
              ((1.0, 1.0 + 2e-16, 1.5), (0.3, -0.2, 0.5)),
              ((1.0, 2.0, 3.0), (1e-20, 1.0, 1e-20)),
              ((1.0, 2.0, 3.0), (1.0, 1e-300, 1e-300))]
    cases += [(tuple(rng.uniform(0.5, 1.5, 3)), tuple(rng.normal(size=3) * 10.0 **
               rng.uniform(-5, 3))) for _ in range(10)]
    for inertia, w in cases:
        sol = solve(Scene(inertia=inertia, omega0=w, attitude0=(0.5, 0.5, 0.5, 0.5)))
        s = sol.at(t)
        assert np.all(np.isfinite(s.quaternion)) and np.all(np.isfinite(s.omega))
        assert np.all(np.isfinite(s.error_bound)) and np.all(s.error_bound <= 1e-12)
        assert_allclose(np.linalg.norm(s.quaternion, axis=-1), 1.0, atol=1e-15)
        one = sol.at(float(t[-2]))
        assert np.all(np.isfinite(one.quaternion))


def test_refusals_name_the_problem():
    scene = Scene(inertia=(1.0, 2.0, 3.0), omega0=(0.3, -0.2, 0.5))
    with pytest.raises(PrecisionError, match='ask tol'):
        solve(scene, tol=2e-14)
    sol = solve(scene)
    with pytest.raises(PrecisionError, match='beyond'):
        sol.at(1e300)
    with pytest.raises(ValueError, match='finite'):
        sol.at(np.array([0.0, math.nan]))
    # within 1e-600 of the separatrix but not on it: the table would be 5500 cells long
    with pytest.raises(PrecisionError, match='separatrix'):
        solve(Scene(inertia=(1.0, 2.0, 3.0), omega0=(1e-300, 1.0, 1e-300)))
    # a torque still has no exact solution for three different moments
    from rigidrot_ros.core import NoExactSolution
    with pytest.raises(NoExactSolution, match='three different moments'):
        solve(Scene(inertia=(1.0, 2.0, 3.0), omega0=(0.3, -0.2, 0.5), torque=(0, 0, 0.1)))


@pytest.mark.slow
def test_quick_benchmark_part_runs_and_checks_values(tmp_path):
    """``rigidrot_bench --quick --only triaxial``, in-process: files, and the exact rows."""
    from rigidrot_ros.bench import triaxial
    from rigidrot_ros.bench.common import footer
    res = triaxial.run(True, lambda line: None)
    triaxial.write(res, str(tmp_path), footer(), lambda line: None)
    res = res['triaxial']
    for name in ('cost', 'work_precision', 'horizon', 'stability'):
        assert (tmp_path / f'triaxial_{name}.csv').is_file()
    assert (tmp_path / 'triaxial_work_precision.png').is_file()
    assert (tmp_path / 'triaxial_stability.png').is_file()
    exact = [r for r in res['work_precision'] if r['method'].startswith('exact')]
    assert exact and all(r['status'] == 'ok' and r['error_rad'] <= 1e-13 for r in exact)
    cells = [c for c in res['stability'] if c['method'].startswith('exact')]
    assert cells and all(c['status'] == 'meets 1e-12' for c in cells)
    assert {r['model'] for r in res['cost']} == {'torque-free-triaxial',
                                                 'torque-free-axisymmetric'}


@pytest.mark.parametrize('bad', [10 ** 400, 'x', [[1.0]], np.zeros((2, 2))])
def test_bad_times_refused_like_every_model(bad):
    """Times the core cannot read raise ValueError naming t, as Solution.at does."""
    sol = solve(Scene(inertia=(1.0, 2.0, 3.0), omega0=(0.3, -0.2, 0.5)))
    for f in (sol.at, sol.omega_at):
        with pytest.raises(ValueError, match='t must be a float'):
            f(bad)


@pytest.mark.parametrize('one_minus_m', [0.5, 1e-3, 1e-12, 1e-30])
def test_elliptic_constants_arb_and_mpmath_agree(one_minus_m):
    """K(m) and F(phi0 | m) from Arb balls (flint) and from mpmath, near the separatrix too."""
    pytest.importorskip('flint')
    from mpmath import mp
    from rigidrot_ros.core.triaxial import _elliptic_constants
    with mp.workprec(200):
        m = 1 - mpmath.mpf(one_minus_m)
        for phi0 in (mpmath.mpf('0.3'), mpmath.pi / 2 - mpmath.mpf('1e-9'), -mpmath.mpf(1.2)):
            f_arb, k_arb = _elliptic_constants(m, phi0, True)
            f_mp, k_mp = _elliptic_constants(m, phi0, False)
            assert abs(k_arb - k_mp) <= abs(k_mp) * mpmath.ldexp(1, -190)
            assert abs(f_arb - f_mp) <= abs(f_mp) * mpmath.ldexp(1, -190)


def _mean_rate_by_quadrature(sol):
    """The mean of g = dn / (1 + beta dn) over [0, K] by mpmath's quadrature of ellipfun."""
    m, beta = mpmath.mpf(sol.m), mpmath.mpf(sol._beta_mp)
    kk = mpmath.ellipk(m)

    def g(u):
        dn = mpmath.ellipfun('dn', u, m=m)
        return dn / (1 + beta * dn)
    return mpmath.quad(g, mpmath.linspace(0, kk, 5)) / kk


@pytest.mark.parametrize('backend', ['flint', 'mpmath'])
@pytest.mark.parametrize('omega0', [(0.3, -0.2, 0.5), (0.02, 1.0, 0.03), (0.1, 1.0, 0.05)])
def test_mean_rate_is_accurate_to_the_bits_the_phase_bound_assumes(omega0, backend):
    """The mean of g = dn / (1 + beta dn), which sets the phase at long times, against a
    quadrature at 300 bits, within 2^(8 - precision) relative (what the phase bound takes).

    The table's own mean (its integral over [0, K] / K) was 2^-124.9 off for the second
    scene at 144 bits, 2^11 above that: a bound fooled from t ~ 1e25 s.
    """
    if backend == 'flint':
        pytest.importorskip('flint')
    sol = solve(Scene(inertia=(1.0, 2.0, 3.0), omega0=omega0), backend=backend)
    with mpmath.workprec(300):
        ref = _mean_rate_by_quadrature(sol)
        rel = abs(sol._gbar_mp - ref) / ref
        assert rel <= mpmath.ldexp(1, 8 - sol.precision), float(mpmath.log(rel, 2))


def test_mean_rate_out_of_closed_form_reach_widens_the_phase_bound():
    """Within ~1e-30 of the major axis beta^2 rounds to 1: the table's mean rate is used,
    known to what its truncation and its check at K stand for (below 2^-80 relative), and
    the phase bound carries that."""
    sol = solve(Scene(inertia=(1.0, 2.0, 3.0), omega0=(1e-30, -1e-30, 1.3)))
    assert sol.method == 'jacobi-elliptic-table'
    assert 2.0 ** -90 < sol._gbar_rel_err <= 2.0 ** -80
    with mpmath.workprec(300):
        ref = _mean_rate_by_quadrature(sol)
        assert abs(sol._gbar_mp - ref) <= ref * sol._gbar_rel_err
    # the phase carries an error of its rate: |t| rho_err turns, on top of its own
    from rigidrot_ros.core.triaxial import _Turns
    with mpmath.workprec(sol.precision):
        plain = _Turns(mpmath.mpf(1) / 3, 0)
        wide = _Turns(mpmath.mpf(1) / 3, 0, rho_err=1e-20)
    t = np.array([1e10, -1e12])
    assert np.all(wide.reduce(t)[1] >= plain.reduce(t)[1] + 1e-20 * np.abs(t) * (1 - 1e-9))
    fixed = solve(Scene(inertia=(1.0, 2.0, 3.0), omega0=(0.0, 0.0, 1.3)))
    t = np.linspace(0.0, 30.0, 7)
    assert np.all(_axis_angle(sol.at(t), fixed.at(t)) <= 1e-13)


@pytest.mark.parametrize('omega0', [(0.3, -0.2, 0.5), (0.02, 1.0, 0.03), (0.01, 1.0, 0.0100001),
                                    (1e-6, 2e-6, 1.0)])
def test_float_coefficients_within_their_proved_bounds(omega0):
    """Each cell's coefficients beyond the first few come from float64 recurrences over all
    cells at once; against the same recurrences in 240-bit fixed point from mpmath's
    values at the centre (no addition theorem, no float), every stored coefficient of sn,
    cn, dn and of g (as Q's g_(k-1) / k) lies within the bound the table's error analysis
    uses for it."""
    from rigidrot_ros.core.triaxial import _DEG, _U, _float_errors, _series
    sol = solve(Scene(inertia=(1.0, 2.0, 3.0), omega0=omega0))
    k0, deg = sol._degrees
    err_e, err_f = _float_errors(k0, deg)
    prec = 240
    one = 1 << prec
    worst = 0.0
    with mpmath.workprec(prec + 20):
        m, beta = mpmath.mpf(sol.m), mpmath.mpf(sol._beta_mp)

        def fx(v):
            return int(mpmath.nint(mpmath.ldexp(v, prec)))
        for i, centre in enumerate(sol._centres):
            u = mpmath.mpf(centre)
            vals = [fx(mpmath.ellipfun(name, u, m=m)) for name in ('sn', 'cn', 'dn')]
            ref = _series(*vals, fx(m), fx(beta), _DEG, prec)
            for k in range(_DEG + 1):
                for f in range(3):
                    bound = err_e[k] if k > k0 else _U * abs(ref[f][k]) / one + 2.0 ** -80
                    diff = abs(sol._coef[k, i, f] - ref[f][k] / one)
                    assert diff <= bound, (i, k, f, diff, bound)
                    worst = max(worst, diff / bound)
                if 2 <= k and k - 1 > k0:
                    q_ref = mpmath.mpf(ref[3][k - 1]) / one / k
                    bound = (err_f[k - 1] + _U * (2.0 ** (k - 1) + err_f[k - 1])) / k
                    assert abs(sol._coef[k, i, 3] - q_ref) <= bound, (i, k, 'Q')
    assert worst > 0.0          # the comparison saw the float rows' errors at all
