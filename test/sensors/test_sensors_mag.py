"""Magnetometer: the field against a hand-rotated one, iron distortions, noise, refusals."""

import math

import mpmath
from mpmath import mp
import numpy as np
from numpy.testing import assert_allclose, assert_array_equal
import pytest

from rigidrot_ros.core import Scene, solve
from rigidrot_ros.sensors import EARTH_FIELD, Magnetometer


def _hand_rotated(q0, omega, t, field):
    """R_BN m_N for q_NB(t) = q0 ⊗ exp(omega t / 2), by Rodrigues' formula at 30 digits.

    A torque-free sphere turns at constant omega (in B): R_NB(t) = R(q0) Rot(omega, |w| t).
    Written from the axis-angle form, not from the package's quaternion code.
    """
    with mp.workdps(30):
        x, y, z, w = [mpmath.mpf(v) for v in q0]
        n = mpmath.sqrt(x * x + y * y + z * z + w * w)
        x, y, z, w = x / n, y / n, z / n, w / n
        r0 = mpmath.matrix([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        om = [mpmath.mpf(v) for v in omega]
        rate = mpmath.sqrt(sum(v * v for v in om))
        k = [v / rate for v in om]
        kx = mpmath.matrix([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        angle = rate * mpmath.mpf(t)
        rot = mpmath.eye(3) + mpmath.sin(angle) * kx + (1 - mpmath.cos(angle)) * kx * kx
        r_nb = r0 * rot
        m = mpmath.matrix([mpmath.mpf(v) for v in field])
        return np.array([float(v) for v in (r_nb.T * m)])


def test_field_against_a_hand_rotated_field_with_soft_and_hard_iron():
    q0, omega = (0.3, -0.1, 0.5, 0.8), (0.4, -0.7, 0.25)
    sol = solve(Scene(omega0=omega, attitude0=q0))
    soft = [[1.05, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 1.01]]
    hard = (3e-6, -1e-6, 2e-6)
    ideal = Magnetometer(sol)
    bent = Magnetometer(sol, soft_iron=soft, hard_iron=hard)
    for t in (0.0, 0.7, 12.3, 400.0):
        ref = _hand_rotated(q0, omega, t, EARTH_FIELD)
        got = ideal.read(t, 0.01)
        assert_allclose(got.field, ref, rtol=0, atol=1e-19)        # 49 uT, ~1e-14 relative
        assert_array_equal(got.field, got.field_true)
        assert_allclose(bent.read(t, 0.01).field, np.array(soft) @ ref + hard, rtol=0,
                        atol=1e-19)
        # the norm of the undistorted field is the field's (a rotation)
        assert np.linalg.norm(got.field_true) == pytest.approx(np.linalg.norm(EARTH_FIELD),
                                                               rel=1e-14)
        assert np.all(np.diag(got.covariance) > 0)                  # the attitude's bound


def test_noise_statistics_and_reproducibility():
    sol = solve(Scene(omega0=(0.0, 0.0, 0.1)))
    a = Magnetometer(sol, noise_density=1e-7, seed=3)
    b = Magnetometer(sol, noise_density=1e-7, seed=3)
    dt = 0.02
    ra = [a.read(dt * k, dt) for k in range(4000)]
    rb = [b.read(dt * k, dt) for k in range(5)]
    assert_array_equal(ra[4].field, rb[4].field)
    err = np.array([r.field - r.field_distorted for r in ra])
    assert err.var() == pytest.approx(1e-14 / dt, rel=0.05)
    assert ra[0].covariance[0, 0] == pytest.approx(1e-14 / dt, rel=1e-9)
    assert ra[0].covariance[0, 1] == 0.0
    # the stream is not the gyro's for the same seed value
    assert not np.allclose(err[0] / math.sqrt(1e-14 / dt),
                           np.random.default_rng(3).standard_normal(3))


@pytest.mark.parametrize('kwargs, words', [
    (dict(soft_iron=[[1, 0, 0], [0, 1, 0], [0, 0, 0]]), 'mag.soft_iron must be well cond'),
    (dict(soft_iron=[[1, 0, 0], [0, 1, 0], [0, 0, 1e-4]]), 'condition'),
    (dict(soft_iron=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]), 'positive determinant'),
    (dict(soft_iron=[1, 0, 0, 0, math.nan, 0, 0, 0, 1]), 'mag.soft_iron[4] must be finite'),
    (dict(soft_iron=[1, 0, 0]), 'mag.soft_iron must be 9 numbers'),
    (dict(field=(0.0, 1e300, 0.0)), 'mag.field[1] must be finite'),
    (dict(field=(0.0, math.nan, 0.0)), 'mag.field[1] must be finite'),
    (dict(hard_iron=(math.inf, 0.0, 0.0)), 'mag.hard_iron[0] must be finite'),
    (dict(noise_density=-1e-9), 'mag.noise_density must be a finite number'),
    (dict(seed=-3), 'mag.seed must be an integer'),
])
def test_bad_values_are_refused_naming_the_parameter(kwargs, words):
    sol = solve(Scene(omega0=(0.0, 0.0, 1.0)))
    with pytest.raises(ValueError) as err:
        Magnetometer(sol, **kwargs)
    assert words in str(err.value)
