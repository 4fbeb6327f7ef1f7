"""Sensor models without ROS: noise statistics, reproducibility, exact increments."""

import math

import mpmath
from mpmath import mp
import numpy as np
from numpy.testing import assert_allclose, assert_array_equal
import pytest

from conftest import integrate, random_scene
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.sensors import (
    ARCSEC, AttitudeNoise, delta_angle, Gyro, GyroNoise, RateBound, rotvec_from_quaternion,
    StarTracker,
)
from rigidrot_ros.sensors.increments import _gauss
from sensor_helpers import _mp_rate


# -- noise ------------------------------------------------------------------------------------
def _allan(rate, tau0, ms):
    """Overlapping Allan deviation of rate samples ``rate`` (n, 3) at tau = m tau0."""
    theta = np.vstack([np.zeros((1, 3)), np.cumsum(rate, axis=0) * tau0])
    out = []
    for m in ms:
        d = theta[2 * m:] - 2 * theta[m:-m] + theta[:-2 * m]
        out.append(np.sqrt(np.mean(d ** 2, axis=0) / (2 * (m * tau0) ** 2)))
    return np.array(out)


def test_allan_deviation_recovers_noise_density_and_random_walk():
    # 2e5 samples at 100 Hz; N and K chosen so both slopes show within the record. Over
    # 20 seeds this fit's error was at most 0.6 % (N) and 4.4 % (K), std 0.2 % and 1.3 %.
    n_density, k_walk, dt = 2e-3, 1e-3, 0.01
    gyro = GyroNoise(n_density, k_walk, (0.0, 0.0, 0.0), seed=2024)
    rate = gyro.corrupt_many(np.zeros((200_000, 3)), dt)
    ms = np.unique(np.geomspace(1, 1000, 30).astype(int))      # tau 0.01 s to 10 s
    taus = ms * dt
    adev = _allan(rate, dt, ms)
    # sigma^2(tau) = N^2 / tau + K^2 tau / 3, fitted with relative weights on all axes
    var = adev ** 2
    rows = np.repeat(np.stack([1.0 / taus, taus / 3.0], axis=1), 3, axis=0)
    target = var.reshape(-1)
    w = 1.0 / target
    sol, *_ = np.linalg.lstsq(rows * w[:, None], target * w, rcond=None)
    n_fit, k_fit = np.sqrt(sol)
    assert n_fit == pytest.approx(n_density, rel=0.10)
    assert k_fit == pytest.approx(k_walk, rel=0.10)
    # and read directly: tau = 1 s is dominated by the angle random walk
    i1 = int(np.argmin(abs(taus - 1.0)))
    direct = math.sqrt(np.mean(var[i1]) - k_walk ** 2 * taus[i1] / 3.0) * math.sqrt(taus[i1])
    assert direct == pytest.approx(n_density, rel=0.10)


def test_same_seed_is_bit_identical_one_at_a_time_or_in_a_batch():
    w = np.random.default_rng(5).normal(size=(500, 3))
    a = GyroNoise(1e-3, 1e-4, (0.01, -0.02, 0.0), seed=11)
    b = GyroNoise(1e-3, 1e-4, (0.01, -0.02, 0.0), seed=11)
    batch = a.corrupt_many(w, 0.01)
    single = np.array([b.corrupt(row, 0.01) for row in w])
    assert_array_equal(batch, single)
    assert_array_equal(a.bias, b.bias)
    a.reset()
    assert_array_equal(a.corrupt_many(w, 0.01), batch)          # reset replays the stream
    other = GyroNoise(1e-3, 1e-4, (0.01, -0.02, 0.0), seed=12).corrupt_many(w, 0.01)
    assert not np.any(other == batch)


def test_rate_integrating_discretisation_moments():
    """Mean = true rate + mean bias; white variance sigma_v^2/dt + sigma_u^2 dt/12."""
    sv, su, dt, n = 3e-3, 2e-3, 0.05, 100_000
    g = GyroNoise(sv, su, (0.0, 0.0, 0.0), seed=3)
    rng = np.random.default_rng(3)
    draws = rng.standard_normal((n, 6))      # the same stream, drawn by the test
    out = g.corrupt_many(np.zeros((n, 3)), dt)
    beta = np.vstack([np.zeros((1, 3)), np.cumsum(su * math.sqrt(dt) * draws[:, :3], 0)])
    white = out - 0.5 * (beta[:-1] + beta[1:])
    assert_allclose(white, math.sqrt(sv ** 2 / dt + su ** 2 * dt / 12) * draws[:, 3:],
                    rtol=1e-9, atol=1e-15)
    assert g.white_variance(dt) == pytest.approx(sv ** 2 / dt + su ** 2 * dt / 12, rel=1e-15)
    # an ideal gyro with a bias reports the true average plus exactly that bias
    ideal = GyroNoise(0.0, 0.0, (0.01, -0.002, 0.5), seed=0)
    w = np.array([[0.3, -0.2, 0.1]])
    assert_array_equal(ideal.corrupt_many(w, 0.01), w + [[0.01, -0.002, 0.5]])


@pytest.mark.parametrize('kwargs, words', [
    (dict(noise_density=math.nan), 'gyro_noise_density must be a finite number'),
    (dict(noise_density=-1e-3), 'gyro_noise_density must be a finite number'),
    (dict(random_walk=1e300), 'gyro_random_walk must be a finite number'),
    (dict(random_walk='big'), 'gyro_random_walk must be a number'),
    (dict(bias=(0.0, math.inf, 0.0)), 'gyro_bias[1] must be finite'),
    (dict(bias=(1e300, 0.0, 0.0)), 'gyro_bias[0] must be finite'),
    (dict(bias=(0.0, 0.0)), 'gyro_bias must have 3 components, got 2'),
    (dict(seed=-1), 'seed must be an integer'),
    (dict(seed=1.5), 'seed must be an integer'),
    (dict(seed=True), 'seed must be an integer'),
])
def test_gyro_noise_refuses_bad_parameters(kwargs, words):
    with pytest.raises(ValueError) as err:
        GyroNoise(**kwargs)
    assert words in str(err.value)


def test_gyro_noise_refuses_bad_samples():
    g = GyroNoise(1e-3, 0.0, (0.0, 0.0, 0.0), seed=0)
    for dt in (0.0, -0.01, math.nan, math.inf):
        with pytest.raises(ValueError, match='dt must be a positive finite'):
            g.corrupt(np.zeros(3), dt)
    with pytest.raises(ValueError, match='omega_avg must be finite'):
        g.corrupt(np.array([0.0, math.nan, 0.0]), 0.01)


# -- star tracker -----------------------------------------------------------------------------
@pytest.mark.parametrize('boresight', [(0.0, 0.0, 1.0), (1.0, 1.0, 0.0), (0.2, -0.5, 0.8)])
def test_star_tracker_error_statistics_per_axis(boresight):
    noise = AttitudeNoise(5.0, 40.0, boresight, seed=9)
    b = np.array(boresight) / np.linalg.norm(boresight)
    q_true = quat.from_rotvec(np.random.default_rng(1).normal(size=(20_000, 3)))
    q_meas, e = noise.corrupt(q_true)
    # the stated convention: q_true^-1 ⊗ q_meas = exp(e / 2), e in B
    assert_allclose(rotvec_from_quaternion(quat.multiply(quat.conjugate(q_true), q_meas)), e,
                    rtol=0, atol=1e-15)
    along = e @ b
    across = e - along[:, None] * b
    cross_axes = np.linalg.svd(np.eye(3) - np.outer(b, b))[0][:, :2]
    sd_cross = (across @ cross_axes).std(axis=0) / ARCSEC
    assert_allclose(sd_cross, [5.0, 5.0], rtol=0.03)
    assert along.std() / ARCSEC == pytest.approx(40.0, rel=0.03)
    assert abs(e.mean(axis=0)).max() < 4 * 40.0 * ARCSEC / math.sqrt(len(e))
    expected = (5 * ARCSEC) ** 2 * (np.eye(3) - np.outer(b, b)) + \
        (40 * ARCSEC) ** 2 * np.outer(b, b)
    assert_allclose(noise.covariance, expected, rtol=1e-12, atol=1e-30)
    assert_allclose(np.cov(e.T), expected, rtol=0, atol=0.05 * (40 * ARCSEC) ** 2)
    nees = np.einsum('ij,jk,ik->i', e, np.linalg.pinv(expected), e)
    assert nees.mean() == pytest.approx(3.0, rel=0.05)


def test_star_tracker_sensor_is_reproducible_and_refuses_bad_input():
    sol = solve(Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05),
                      omega0=(0.3, -0.2, 0.5)))
    a = StarTracker(sol, AttitudeNoise(5.0, 35.0, (0, 0, 1), seed=4))
    b = StarTracker(sol, AttitudeNoise(5.0, 35.0, (0, 0, 1), seed=4))
    for t in (0.0, 0.1, 7.5):
        ra, rb = a.read(t), b.read(t)
        assert_array_equal(ra.quaternion, rb.quaternion)
        assert_allclose(ra.true_quaternion, sol.at(t).quaternion, rtol=0, atol=0)
        assert np.all(np.diag(ra.covariance) > 0)
    with pytest.raises(ValueError, match='boresight must be a nonzero axis'):
        AttitudeNoise(5.0, 35.0, (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match='cross_boresight_arcsec'):
        AttitudeNoise(math.nan, 35.0)
    with pytest.raises(ValueError, match='about_boresight_arcsec'):
        AttitudeNoise(5.0, 1e300)


@pytest.mark.parametrize('boresight', [(0, 0, 1), (0.3, -0.5, 0.8), (1, 2, 3)])
def test_star_tracker_reads_many_as_it_reads_one(boresight):
    """At once, the bits of sample-by-sample reads (a tilted boresight included: a
    matrix-vector product gave other bits than one row's), the stream carried on."""
    for scene in (Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05),
                        omega0=(0.3, -0.2, 0.5)),
                  Scene(inertia=(1.0, 2.0, 3.0), omega0=(0.3, -0.2, 0.5))):
        sol = solve(scene)
        a = StarTracker(sol, AttitudeNoise(5.0, 35.0, boresight, seed=11))
        b = StarTracker(sol, AttitudeNoise(5.0, 35.0, boresight, seed=11))
        for times in (np.array([3.0]), np.arange(1, 300) * 0.1 + 1e-9, np.arange(7) + 5e3):
            one = [a.read(float(t)) for t in times]
            many = b.read_many(times)
            for field in ('quaternion', 'error', 'covariance', 'true_quaternion'):
                assert np.array([getattr(r, field) for r in one]).tobytes() == \
                    getattr(many, field).tobytes(), field


MODELS = ['torque-free-axisymmetric', 'axial-torque', 'transverse-virtual',
          'transverse-body', 'oblique-virtual', 'sphere']


@pytest.mark.parametrize('model', MODELS)
def test_closed_form_oracle_agrees_with_eulers_equations(model, rng):
    """The 30-digit oracle rate shares no formula with DOP853 on Euler's equations."""
    scene = random_scene(model, rng)
    rate = _mp_rate(scene)
    ts = np.linspace(0.0, 3.0, 7)
    omega, _ = integrate(scene, ts)
    with mp.workdps(30):
        ref = np.array([[float(v) for v in rate(mpmath.mpf(t))] for t in ts])
    assert_allclose(ref, omega, rtol=0, atol=1e-10)
    assert_allclose(solve(scene).omega_at(ts), ref, rtol=0, atol=1e-13)


@pytest.mark.parametrize('model', MODELS)
def test_delta_angle_against_30_digit_quadrature(model, rng):
    scene = random_scene(model, rng)
    sol = solve(scene)
    rate = _mp_rate(scene)
    for t0, h in ((0.0, 0.01), (float(rng.uniform(1, 50)), 0.005),
                  (float(rng.uniform(100, 2000)), 0.01), (3.25, 0.7)):
        t1 = t0 + h
        got, bound = delta_angle(sol, t0, t1)
        with mp.workdps(30):
            ref = [mpmath.quad(lambda t, i=i: rate(t)[i], [mpmath.mpf(t0), mpmath.mpf(t1)])
                   for i in range(3)]
        err = float(mpmath.sqrt(sum((mpmath.mpf(float(g)) - r) ** 2
                                    for g, r in zip(got, ref))))
        assert err <= 1e-12, (t0, h, err)
        assert err <= bound, (t0, h, err, bound)
        if t1 < 100:
            # far out a spun-up body turns fast, and the rounded node times alone
            # (eps t |d omega / dt| h) may state more than 1e-12 honestly
            assert bound <= 1e-12


def test_quadrature_bound_is_never_below_the_error_even_for_few_nodes(rng):
    """Force coarse rules on long intervals: the stated truncation bound still holds."""
    for model in ('axial-torque', 'oblique-virtual', 'transverse-virtual'):
        scene = random_scene(model, rng)
        sol = solve(scene)
        rb = RateBound(sol)
        rate = _mp_rate(scene)
        for t0, h in ((0.0, 2.0), (40.0, 1.0), (5.0, 4.0)):
            with mp.workdps(30):
                ref = np.array([float(mpmath.quad(lambda t, i=i: rate(t)[i],
                                                  [t0, t0 + h])) for i in range(3)])
            for n in (2, 3, 4, 6):
                got, w = _gauss(sol, t0, t0 + h, n)
                err = float(np.linalg.norm(got - ref))
                stated = rb.truncation(t0, t0 + h, n) + rb.rounding(t0, t0 + h, n, w)
                assert err <= stated, (model, t0, h, n, err, stated)


class _Unknown:
    """A solution the closed-form bound does not know: the majorant path must bound it."""

    def __init__(self, sol):
        self._sol = sol
        self.scene = sol.scene
        self.model = 'some-future-model'

    def omega_at(self, t):
        return self._sol.omega_at(t)


def test_majorant_bound_for_models_without_closed_form(rng):
    scene = random_scene('axial-torque', rng)       # body-fixed torque
    sol = _Unknown(solve(scene))
    assert RateBound(sol).kind == 'majorant'
    rate = _mp_rate(scene)
    for t0, h in ((0.0, 0.01), (20.0, 0.2)):
        got, bound = delta_angle(sol, t0, t0 + h)
        with mp.workdps(30):
            ref = np.array([float(mpmath.quad(lambda t, i=i: rate(t)[i], [t0, t0 + h]))
                            for i in range(3)])
        assert np.linalg.norm(got - ref) <= min(bound, 1e-12)
        for n in (2, 3):
            part, w = _gauss(sol, t0, t0 + h, n)
            rb = RateBound(sol)
            assert np.linalg.norm(part - ref) <= rb.truncation(t0, t0 + h, n) + \
                rb.rounding(t0, t0 + h, n, w)
    virtual = _Unknown(solve(random_scene('transverse-virtual', rng)))
    with pytest.raises(ValueError, match='cannot bound the rate'):
        RateBound(virtual)


def test_delta_angle_refuses_bad_intervals():
    sol = solve(Scene(omega0=(0.0, 0.0, 1.0)))
    for t0, t1 in ((1.0, 0.5), (math.nan, 1.0), (0.0, math.inf)):
        with pytest.raises(ValueError, match='delta_angle needs'):
            delta_angle(sol, t0, t1)
    assert delta_angle(sol, 2.0, 2.0)[1] == 0.0


def _mp_relative_rotation(rate, t0, t1):
    """Integrate dq/dt = q ⊗ (omega, 0) / 2 from the identity at 30 digits (mpmath odefun)."""
    with mp.workdps(30):
        t0m = mpmath.mpf(t0)

        def rhs(t, y):
            w = rate(t)
            x, yy, z, s = y
            return [0.5 * (s * w[0] + yy * w[2] - z * w[1]),
                    0.5 * (s * w[1] + z * w[0] - x * w[2]),
                    0.5 * (s * w[2] + x * w[1] - yy * w[0]),
                    -0.5 * (x * w[0] + yy * w[1] + z * w[2])]
        f = mpmath.odefun(rhs, t0m, [mpmath.mpf(0)] * 3 + [mpmath.mpf(1)])
        q = f(mpmath.mpf(t1))
        vec = mpmath.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2)
        angle = 2 * mpmath.atan2(vec, q[3])
        return np.array([float(c * angle / vec) for c in q[:3]])


@pytest.mark.parametrize('model', ['transverse-virtual', 'oblique-virtual', 'sphere'])
def test_delta_rotation_against_the_integrated_attitude_and_the_coning_term(model, rng):
    scene = random_scene(model, rng)
    sol = solve(scene)
    rate = _mp_rate(scene)
    gyro = Gyro(sol)
    for t0 in (0.0, float(rng.uniform(5, 30))):
        t1 = t0 + 0.02
        r = gyro.read(t0, t1)
        ref = _mp_relative_rotation(rate, t0, t1)
        err = float(np.linalg.norm(r.delta_rotation - ref))
        assert err <= 1e-12 and err <= r.delta_rotation_bound, (err, r.delta_rotation_bound)
        # the coning term: delta_rotation - delta_angle ~ (1/2) ∫ alpha x omega dt
        ts = np.linspace(t0, t1, 2001)
        w = sol.omega_at(ts)
        alpha = np.vstack([np.zeros(3), np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(ts)[:, None],
                                                  axis=0)])
        bortz = 0.5 * np.trapezoid(np.cross(alpha, w), ts, axis=0)
        coning = r.delta_rotation - r.delta_angle
        if np.linalg.norm(bortz) > 1e-12:
            assert_allclose(coning, bortz, rtol=2e-2, atol=1e-13)


def test_gyro_reading_is_consistent():
    sol = solve(Scene(inertia=(2.0, 2.0, 1.0), torque=(0.1, 0.0, 0.0), torque_frame='virtual',
                      omega0=(0.3, -0.2, 0.5)))
    gyro = Gyro(sol, GyroNoise(0.0, 0.0, (0.01, 0.02, -0.03), seed=0))
    r = gyro.read(1.0, 1.01)
    assert_allclose(r.omega, r.delta_angle / r.dt + [0.01, 0.02, -0.03], rtol=1e-15,
                    atol=1e-17)
    assert_allclose(r.quaternion, sol.at(1.01).quaternion, rtol=0, atol=0)
    assert 0 < r.variance < 1e-18           # ideal: only the exact rate's own bound
    with pytest.raises(ValueError, match='t0 < t1'):
        gyro.read(1.0, 1.0)


def test_a_time_budget_bounds_one_gyro_sample_and_keeps_the_noise_stream():
    """An interval far too long for the quadrature fails within its budget, not seconds later."""
    import time
    sol = solve(Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05),
                      omega0=(0.3, -0.2, 0.5)))
    gyro = Gyro(sol, GyroNoise(1.7e-4, 2e-5, (0.0, 0.0, 0.0), seed=3))
    c0 = time.perf_counter()
    with pytest.raises(ValueError, match='time budget'):
        gyro.read(0.0, 1e7, budget=0.02)
    assert time.perf_counter() - c0 < 0.5           # not the ~3 s the quadrature would take
    with pytest.raises(ValueError, match='time budget'):
        delta_angle(sol, 0.0, 1e7, deadline=time.perf_counter())
    # the failed read drew no noise: the stream goes on as a fresh gyro's
    fresh = Gyro(sol, GyroNoise(1.7e-4, 2e-5, (0.0, 0.0, 0.0), seed=3))
    assert_array_equal(gyro.read(0.0, 0.01, budget=0.02).omega, fresh.read(0.0, 0.01).omega)
