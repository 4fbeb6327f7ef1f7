"""The complete IMU error model: today's gyro stream kept, each term checked on its own.

References share no code with the model: GyroNoise (today's stream), mpmath quadrature of
the Gauss–Markov covariance integrals, allantools' overlapping Allan deviation.
"""

import math

import allantools
import mpmath
from mpmath import mp
import numpy as np
from numpy.testing import assert_allclose, assert_array_equal
import pytest

from rigidrot_ros.core import Scene, solve
from rigidrot_ros.sensors import Gyro, GyroNoise, ImuNoise
from rigidrot_ros.sensors.imu_noise import gauss_markov_coefficients


def test_every_new_term_zero_keeps_todays_gyro_stream_bit_identical():
    w = np.random.default_rng(5).normal(size=(700, 3))
    for nd, rw, b in ((1e-3, 1e-4, (0.01, -0.02, 0.0)), (1.7e-4, 2e-5, (0.0, 0.0, 0.0)),
                      (0.0, 0.0, (0.1, 0.2, 0.3))):
        old = GyroNoise(nd, rw, b, seed=11)
        new = ImuNoise(nd, rw, b, seed=11)
        assert_array_equal(new.corrupt_many(w, 0.01), old.corrupt_many(w, 0.01))
        assert_array_equal(new.bias, old.bias)
        # one at a time too, and a later batch continues the same stream
        assert_array_equal(np.array([new.corrupt(row, 0.005) for row in w[:50]]),
                           np.array([old.corrupt(row, 0.005) for row in w[:50]]))
        assert new.white_variance(0.01) == old.white_variance(0.01)
    # through the sensor: the same readings, field by field
    sol = solve(Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05),
                      omega0=(0.3, -0.2, 0.5)))
    a = Gyro(sol, GyroNoise(1.7e-4, 2e-5, (0.001, 0.0, 0.0), seed=3))
    b = Gyro(sol, ImuNoise(1.7e-4, 2e-5, (0.001, 0.0, 0.0), seed=3))
    for k in range(20):
        ra, rb = a.read(0.01 * k, 0.01 * (k + 1)), b.read(0.01 * k, 0.01 * (k + 1))
        assert_array_equal(ra.omega, rb.omega)
        assert_array_equal(ra.bias, rb.bias)
        assert ra.variance == rb.variance


def test_a_batch_equals_single_samples_with_every_term_on():
    kw = dict(noise_density=1e-3, random_walk=1e-4, bias=(0.01, 0.0, 0.0), seed=9,
              bias_stddev=0.02, bias_instability=3e-3, bias_correlation_time=5.0,
              scale_factor=(1e-3, -2e-3, 5e-4),
              misalignment=[0, 1e-3, 0, 0, 0, -2e-3, 5e-4, 0, 0],
              quantum=1e-4, increment_quantum=1e-6)
    w = np.random.default_rng(1).normal(size=(300, 3))
    a, b = ImuNoise(**kw), ImuNoise(**kw)
    sa = a.apply(w, 0.01)
    singles = [b.apply(row[None, :], 0.01) for row in w]
    for field in ('value', 'increment', 'bias'):
        assert_array_equal(getattr(sa, field), np.vstack([getattr(s, field) for s in singles]))
    a.reset()
    assert_array_equal(a.apply(w, 0.01).value, sa.value)           # reset replays it


def test_scale_factor_and_misalignment_apply_the_stated_matrix():
    s = (1e-3, -2e-3, 5e-4)
    m = [[0.0, 1e-3, -3e-4], [2e-4, 0.0, 7e-4], [-1e-3, 5e-4, 0.0]]
    noise = ImuNoise(scale_factor=s, misalignment=m, kind='accel')
    u = np.random.default_rng(2).normal(size=(50, 3)) * 10
    c = np.array([[1 + s[0], m[0][1], m[0][2]], [m[1][0], 1 + s[1], m[1][2]],
                  [m[2][0], m[2][1], 1 + s[2]]])
    assert_allclose(noise.apply(u, 0.01).value, u @ c.T, rtol=0, atol=1e-14)
    assert_array_equal(noise.matrix, c)


def test_turn_on_bias_is_drawn_from_the_seed_with_the_stated_spread():
    a = ImuNoise(bias=(0.1, 0.0, 0.0), seed=4, bias_stddev=0.01)
    b = ImuNoise(bias=(0.1, 0.0, 0.0), seed=4, bias_stddev=0.01)
    assert_array_equal(a.turn_on_bias, b.turn_on_bias)
    assert_array_equal(a.bias, np.array([0.1, 0.0, 0.0]) + a.turn_on_bias)
    # over seeds: zero mean, standard deviation bias_stddev (2000 x 3 draws: ~1.3 % spread)
    draws = np.array([ImuNoise(seed=s, bias_stddev=0.01, kind='accel').turn_on_bias
                      for s in range(2000)])
    assert draws.std() == pytest.approx(0.01, rel=0.05)
    assert abs(draws.mean()) < 4 * 0.01 / math.sqrt(draws.size)
    # an ideal sensor with a turn-on bias reads exactly truth + that bias
    ideal = ImuNoise(seed=4, bias_stddev=0.01)
    w = np.array([[0.3, -0.2, 0.1]])
    assert_array_equal(ideal.apply(w, 0.01).value, w + ideal.turn_on_bias)
    # the turn-on draw comes from its own stream: the white noise does not change
    plain = ImuNoise(1e-3, 0.0, seed=4).apply(np.zeros((10, 3)), 0.01).value
    with_bias = ImuNoise(1e-3, 0.0, seed=4, bias_stddev=0.01)
    assert_allclose(with_bias.apply(np.zeros((10, 3)), 0.01).value - with_bias.turn_on_bias,
                    plain, rtol=0, atol=1e-17)


def test_quantisation_rate_lsb_and_increments_with_the_residual_carried():
    q, qi, dt = 1e-3, 1e-5, 0.01
    noise = ImuNoise(2e-3, 0.0, seed=8, quantum=q, increment_quantum=qi)
    raw = ImuNoise(2e-3, 0.0, seed=8)
    u = np.random.default_rng(3).normal(size=(5000, 3)) * 0.1
    s = noise.apply(u, dt)
    y = raw.apply(u, dt).value
    assert_allclose(s.value / q, np.round(s.value / q), rtol=0, atol=1e-9)
    assert np.max(np.abs(s.value - y)) <= 0.5 * q * (1 + 1e-12)
    assert_allclose(s.increment / qi, np.round(s.increment / qi), rtol=0, atol=1e-6)
    # carried: the running sum never strays more than half an LSB from the true sum
    drift = np.cumsum(s.increment, axis=0) - np.cumsum(y * dt, axis=0)
    assert np.max(np.abs(drift)) <= 0.5 * qi * (1 + 1e-9)
    # the stated variances include the rounding's
    assert noise.white_variance(dt) == pytest.approx(raw.white_variance(dt) + q * q / 12)
    err = s.value - u
    assert err.var() == pytest.approx(noise.white_variance(dt), rel=0.05)


def test_gauss_markov_coefficients_against_the_covariance_integrals():
    """Var/cov of (end value, interval integral) by 30-digit quadrature of their kernels."""
    for sigma, tau, dt in ((1.0, 10.0, 0.01), (2e-3, 3600.0, 0.005), (0.5, 0.2, 0.3),
                           (1.0, 1e8, 1.0)):
        phi, sd, cm, cg, res = gauss_markov_coefficients(sigma, tau, dt)
        with mp.workdps(30):
            s, t, h = mpmath.mpf(sigma), mpmath.mpf(tau), mpmath.mpf(dt)
            q2 = 2 * s * s / t                         # driving density^2
            v1 = q2 * mpmath.quad(lambda u: mpmath.exp(-2 * u / t), [0, h])
            kern = lambda u: t * (1 - mpmath.exp(-u / t))          # noqa: E731
            c12 = q2 * mpmath.quad(lambda u: mpmath.exp(-u / t) * kern(u), [0, h])
            v2 = q2 * mpmath.quad(lambda u: kern(u) ** 2, [0, h])
            mean_coef = mpmath.quad(lambda u: mpmath.exp(-u / t), [0, h]) / h
            ref = [mpmath.exp(-h / t), mpmath.sqrt(v1), mean_coef, c12 / (v1 * h),
                   (v2 - c12 ** 2 / v1) / h ** 2]
        for got, want in zip((phi, sd, cm, cg, res), ref):
            assert got == pytest.approx(float(want), rel=1e-9), (sigma, tau, dt)
    # tau -> inf with 2 sigma^2 / tau = sigma_u^2: the random walk's 1/2 and sigma_u^2 dt/12
    su, dt, tau = 1e-3, 0.01, 1e9
    _, _, cm, cg, res = gauss_markov_coefficients(su * math.sqrt(tau / 2), tau, dt)
    assert cg == pytest.approx(0.5, rel=1e-9) and cm == pytest.approx(1.0, rel=1e-9)
    assert res == pytest.approx(su * su * dt / 12, rel=1e-6)


def test_gauss_markov_bias_is_stationary_with_the_stated_sigma_and_correlation():
    sigma, tau, dt = 0.02, 0.5, 0.01
    noise = ImuNoise(seed=6, bias_instability=sigma, bias_correlation_time=tau)
    b = noise.apply(np.zeros((100_000, 3)), dt).bias
    assert b.std() == pytest.approx(sigma, rel=0.05)        # interval means: ~sigma here
    lag = int(tau / dt)
    r = np.mean(b[lag:] * b[:-lag]) / np.mean(b * b)
    assert r == pytest.approx(math.exp(-1.0), abs=0.05)


def _fit_white_and_walk(taus, adev):
    var = adev ** 2
    rows = np.stack([1.0 / taus, taus / 3.0], axis=1)
    w = 1.0 / var
    sol, *_ = np.linalg.lstsq(rows * w[:, None], var * w, rcond=None)
    return np.sqrt(sol)


def _gm_avar(taus, sigma, tc):
    """Allan variance of a first-order Gauss–Markov rate process (sigma, tc)."""
    u = taus / tc
    return 2 * sigma ** 2 * tc / taus * (1 - (3 - 4 * np.exp(-u) + np.exp(-2 * u))
                                         / (2 * u))


def _adev(y, dt, taus):
    # allantools, averaged over the three axes
    return np.mean([allantools.oadev(y[:, i], rate=1.0 / dt, data_type='freq',
                                     taus=taus)[1] for i in range(3)], axis=0)


@pytest.mark.parametrize('kind, n_dens, k_walk', [('gyro', 2e-3, 1e-3),
                                                  ('accel', 5e-2, 2e-2)])
def test_allan_deviation_recovers_white_noise_and_random_walk(kind, n_dens, k_walk):
    """sigma^2(T) = N^2 / T + K^2 T / 3; 2e5 samples at 100 Hz; tolerance 10 %."""
    dt = 0.01
    noise = ImuNoise(n_dens, k_walk, seed=2024, kind=kind)
    y = noise.apply(np.zeros((200_000, 3)), dt).value
    taus = np.unique(np.geomspace(1, 1000, 25).astype(int)) * dt
    adev = _adev(y, dt, taus)
    n_fit, k_fit = _fit_white_and_walk(taus, adev)
    assert n_fit == pytest.approx(n_dens, rel=0.10)
    assert k_fit == pytest.approx(k_walk, rel=0.10)
    # the white slope read directly at T = 1 s (the Kalibr / IEEE-952 N)
    i1 = int(np.argmin(abs(taus - 1.0)))
    direct = math.sqrt(adev[i1] ** 2 - k_walk ** 2 * taus[i1] / 3.0) * math.sqrt(taus[i1])
    assert direct == pytest.approx(n_dens, rel=0.10)


@pytest.mark.parametrize('kind, n_dens, sigma, tc', [('gyro', 2e-4, 1e-3, 20.0),
                                                     ('accel', 1e-2, 5e-2, 10.0)])
def test_allan_deviation_recovers_the_bias_instability_plateau(kind, n_dens, sigma, tc):
    """White + Gauss–Markov: the fit finds sigma and tau; the plateau matches the model.

    2e5 samples at 10 Hz (1000-2000 correlation times). Tolerances: sigma 10 %, tau 25 %,
    N 10 %, the measured peak ADEV within 10 % of the model's.
    """
    dt = 0.1
    noise = ImuNoise(n_dens, 0.0, seed=77, bias_instability=sigma, bias_correlation_time=tc,
                     kind=kind)
    y = noise.apply(np.zeros((200_000, 3)), dt).value
    taus = np.unique(np.geomspace(1, 5000, 30).astype(int)) * dt
    adev = _adev(y, dt, taus)
    var, w = adev ** 2, 1.0 / adev ** 2
    best = None
    for tc_try in np.geomspace(tc / 10, tc * 10, 161):
        rows = np.stack([1.0 / taus, _gm_avar(taus, 1.0, tc_try)], axis=1)
        sol, *_ = np.linalg.lstsq(rows * w[:, None], var * w, rcond=None)
        resid = np.sum(((rows @ sol - var) * w) ** 2)
        if np.all(sol > 0) and (best is None or resid < best[0]):
            best = (resid, tc_try, math.sqrt(sol[0]), math.sqrt(sol[1]))
    _, tc_fit, n_fit, sigma_fit = best
    assert sigma_fit == pytest.approx(sigma, rel=0.10)
    assert tc_fit == pytest.approx(tc, rel=0.25)
    assert n_fit == pytest.approx(n_dens, rel=0.10)
    model = np.sqrt(n_dens ** 2 / taus + _gm_avar(taus, sigma, tc))
    assert adev.max() == pytest.approx(model.max(), rel=0.10)


@pytest.mark.parametrize('kwargs, words', [
    (dict(noise_density=-1e-3), 'imu.gyro_noise_density must be a finite number'),
    (dict(noise_density=math.nan, kind='accel'), 'accel.noise_density must be a finite'),
    (dict(random_walk=1e300, kind='accel'), 'accel.random_walk must be a finite'),
    (dict(bias_correlation_time=0.0), 'imu.gyro_bias_correlation_time must be a finite'),
    (dict(bias_correlation_time=-5.0, kind='accel'), 'accel.bias_correlation_time'),
    (dict(bias_correlation_time=math.inf), 'imu.gyro_bias_correlation_time'),
    (dict(bias_instability=-1.0), 'imu.gyro_bias_instability must be'),
    (dict(bias_stddev=math.nan, kind='accel'), 'accel.bias_stddev must be'),
    (dict(scale_factor=(0.0, 1e300, 0.0)), 'imu.gyro_scale_factor[1] must be finite'),
    (dict(misalignment=[0.0] * 8), 'imu.gyro_misalignment must be 9 numbers'),
    (dict(misalignment=[0.0, math.nan] + [0.0] * 7), 'imu.gyro_misalignment[1] must be'),
    (dict(misalignment=[0.01] + [0.0] * 8), 'imu.gyro_misalignment must have a zero diag'),
    (dict(quantum=-1e-3, kind='accel'), 'accel.quantum must be'),
    (dict(increment_quantum=math.inf), 'imu.gyro_increment_quantum must be'),
    (dict(seed=-1, kind='accel'), 'accel.seed must be an integer'),
    (dict(kind='baro'), 'kind must be one of'),
])
def test_bad_values_are_refused_naming_the_parameter(kwargs, words):
    with pytest.raises(ValueError) as err:
        ImuNoise(**kwargs)
    assert words in str(err.value)


def test_bad_samples_are_refused():
    n = ImuNoise(1e-3, kind='accel')
    for dt in (0.0, -0.01, math.nan):
        with pytest.raises(ValueError, match='dt must be a positive finite'):
            n.apply(np.zeros((1, 3)), dt)
    with pytest.raises(ValueError, match='m/s\\^2 input must be finite'):
        n.apply(np.array([[0.0, math.nan, 0.0]]), 0.01)
