"""Accelerometer: specific force and Δv against a 30-digit integration of the motion.

The reference integrates Euler's equations and the quaternion kinematics with mpmath's
Taylor ODE solver at 30 digits, takes the IMU's position ``p_N = R_NB r`` and
differentiates it twice numerically (the acceleration comes from the
motion alone, not from the formula ``omega_dot x r + omega x (omega x r)``; 7-point
central differences at 30 digits). Δv is
checked against mpmath.quad of the specific force of that 30-digit motion.
"""

import math

import mpmath
from mpmath import mp
import numpy as np
from numpy.testing import assert_allclose, assert_array_equal
import pytest

from conftest import random_scene, read_in_blocks
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.sensors import (
    Accelerometer, delta_velocity, DV_TOL, ImuNoise, specific_force, STANDARD_GRAVITY,
)
from rigidrot_ros.sensors.accel import _evaluate, _truncation
from rigidrot_ros.sensors.increments import RateBound

G_UP = (0.0, 0.0, -STANDARD_GRAVITY)


def _sym_axis(inertia):
    for k in range(3):
        if inertia[(k + 1) % 3] == inertia[(k + 2) % 3]:
            return k
    return 2


def _mp_motion(scene):
    """30-digit Taylor solution of I w' = m_B - w x I w, q' = q ⊗ (w, 0) / 2 (x, y, z, w).

    A 'virtual' torque turns in B by -f, f' = ((I - I3) / I) w_k (the scene's definition).
    Returns (motion(t) -> mp state, rhs) at 30 digits.
    """
    virtual = scene.torque_frame == 'virtual'
    k = _sym_axis(scene.inertia)
    i1, i2 = (k + 1) % 3, (k + 2) % 3
    with mp.workdps(30):
        inertia = [mpmath.mpf(v) for v in scene.inertia]
        torque = [mpmath.mpf(v) for v in scene.torque]
        y0 = [mpmath.mpf(v) for v in scene.omega0] + \
            [mpmath.mpf(v) for v in scene.attitude0] + [mpmath.mpf(0)]

    def rhs(t, y):
        w, (x, yy, z, s), f = y[:3], y[3:7], y[7]
        m = list(torque)
        if virtual:
            c, sn = mpmath.cos(f), mpmath.sin(f)
            m[i1] = c * torque[i1] + sn * torque[i2]
            m[i2] = -sn * torque[i1] + c * torque[i2]
        iw = [inertia[j] * w[j] for j in range(3)]
        cross = [w[1] * iw[2] - w[2] * iw[1], w[2] * iw[0] - w[0] * iw[2],
                 w[0] * iw[1] - w[1] * iw[0]]
        dw = [(m[j] - cross[j]) / inertia[j] for j in range(3)]
        dq = [0.5 * (s * w[0] + yy * w[2] - z * w[1]), 0.5 * (s * w[1] + z * w[0] - x * w[2]),
              0.5 * (s * w[2] + x * w[1] - yy * w[0]), -0.5 * (x * w[0] + yy * w[1] + z * w[2])]
        df = (inertia[i1] - inertia[k]) / inertia[i1] * w[k] if virtual else mpmath.mpf(0)
        return dw + dq + [df]
    with mp.workdps(30):
        return mpmath.odefun(rhs, 0, y0), rhs


def _mp_matrix(q):
    x, y, z, w = q
    return [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]


def _mp_specific_force_by_differences(motion, t, r, g):
    """f_B = R_NB^T (d^2/dt^2 (R_NB r) - g_N), the second derivative by differences.

    The 7-point central difference (error h^6 f^(8) / 560, with h = 1e-3 s below 1e-17
    here; rounding 30 digits / h^2 ~ 1e-24).
    """
    with mp.workdps(30):
        coef = [mpmath.mpf(1) / 90, -mpmath.mpf(3) / 20, mpmath.mpf(3) / 2,
                -mpmath.mpf(49) / 18, mpmath.mpf(3) / 2, -mpmath.mpf(3) / 20,
                mpmath.mpf(1) / 90]
        tm, h = mpmath.mpf(t), mpmath.mpf('1e-3')
        pos = [[sum(_mp_matrix(motion(tm + k * h)[3:7])[i][j] * r[j] for j in range(3))
                for i in range(3)] for k in range(-3, 4)]
        acc = [sum(c * p[i] for c, p in zip(coef, pos)) / (h * h) for i in range(3)]
        rm = _mp_matrix(motion(tm)[3:7])
        return np.array([float(sum(rm[j][i] * (acc[j] - g[j]) for j in range(3)))
                         for i in range(3)])


def _mp_delta_v(motion, rhs, t0, t1, r, g):
    """∫ f_B dt by mpmath.quad at 30 digits, f_B from the 30-digit motion.

    The three components' quadratures share their nodes: f_B is computed once a node.
    """
    seen = {}

    def f(t, i):
        if t not in seen:
            y = motion(t)
            w, dw = y[:3], rhs(t, y)[:3]
            wr = [w[1] * r[2] - w[2] * r[1], w[2] * r[0] - w[0] * r[2],
                  w[0] * r[1] - w[1] * r[0]]
            cen = [w[1] * wr[2] - w[2] * wr[1], w[2] * wr[0] - w[0] * wr[2],
                   w[0] * wr[1] - w[1] * wr[0]]
            tan = [dw[1] * r[2] - dw[2] * r[1], dw[2] * r[0] - dw[0] * r[2],
                   dw[0] * r[1] - dw[1] * r[0]]
            rm = _mp_matrix(y[3:7])
            seen[t] = [tan[k] + cen[k] - sum(rm[j][k] * g[j] for j in range(3))
                       for k in range(3)]
        return seen[t][i]
    with mp.workdps(30):
        return [mpmath.quad(lambda t, i=i: f(t, i), [mpmath.mpf(t0), mpmath.mpf(t1)])
                for i in range(3)]


def _scene(model, rng):
    if model == 'torque-free-triaxial':
        return Scene(inertia=(1.0, 1.6, 2.1), omega0=tuple(rng.uniform(-1, 1, 3)),
                     attitude0=tuple(rng.normal(size=4)))
    return random_scene(model, rng)


@pytest.mark.parametrize('model', ['axial-torque', 'transverse-virtual', 'transverse-body',
                                   'sphere', 'oblique-virtual', 'torque-free-triaxial'])
def test_specific_force_and_delta_v_against_the_30_digit_motion(model, rng):
    scene = _scene(model, rng)
    sol = solve(scene)
    motion, rhs = _mp_motion(scene)
    r = tuple(rng.uniform(-0.5, 0.5, 3))
    with mp.workdps(30):
        rm = [mpmath.mpf(v) for v in r]
        gm = [mpmath.mpf(v) for v in G_UP]
    for t in (0.35, 1.2):
        ref = _mp_specific_force_by_differences(motion, t, rm, gm)
        got, bound = specific_force(sol, t, r, G_UP)
        err = float(np.linalg.norm(got - ref))
        assert err <= 1e-12 and err <= bound, (t, err, bound)
    for t0, t1 in ((0.2, 0.21), (0.9, 1.4)):
        for g in (G_UP, (0.0, 0.0, 0.0)):
            with mp.workdps(30):
                ref = _mp_delta_v(motion, rhs, t0, t1, rm, [mpmath.mpf(v) for v in g])
            dv, bound = delta_velocity(sol, t0, t1, r, g)
            with mp.workdps(30):
                err = float(mpmath.sqrt(sum((mpmath.mpf(float(a)) - b) ** 2
                                            for a, b in zip(dv, ref))))
            assert err <= 1e-13 and err <= bound, (t0, t1, g, err, bound)
            assert bound <= 1e-12, (t0, t1, bound)


def test_the_delta_v_truncation_bound_holds_for_coarse_rules(rng):
    """Force 2-6 node rules on long intervals: truncation + rounding stay above the error."""
    for model in ('oblique-virtual', 'transverse-virtual', 'torque-free-triaxial'):
        scene = _scene(model, rng)
        sol = solve(scene)
        rb = RateBound(sol)
        r = np.array([0.3, -0.4, 0.2])
        g = np.array(G_UP)
        ref, _ = delta_velocity(sol, 0.0, 2.0, r, g, tol=1e-15)
        tangential = np.cross(sol.omega_at(2.0) - sol.omega_at(0.0), r)
        for n in (2, 3, 4, 6):
            trunc = _truncation(rb, 0.0, 2.0, n, float(np.linalg.norm(r)),
                                float(np.linalg.norm(g)))
            got, stated = _evaluate(sol, 0.0, 2.0, 1, n, r, g, tangential, trunc)
            err = float(np.linalg.norm(got - ref))
            assert err <= stated, (model, n, err, stated)


def test_zero_noise_reproduces_the_truth_to_the_float64_floor(rng):
    sol = solve(random_scene('oblique-virtual', rng))
    acc = Accelerometer(sol, lever_arm=(0.1, -0.2, 0.05), gravity=G_UP)
    for k in range(5):
        r = acc.read(0.01 * k, 0.01 * (k + 1))
        assert_array_equal(r.specific_force, r.specific_force_avg)
        assert_allclose(r.delta_velocity_measured, r.delta_velocity, rtol=2 ** -52, atol=0)
        assert_array_equal(r.bias, np.zeros(3))
        assert 0 < r.variance < 1e-20                # only the truth's own bound
    # a body at rest on a supported point reads +g along N's up axis, in B
    rest = Accelerometer(solve(Scene(attitude0=(0.0, 0.0, 0.0, 1.0))), gravity=G_UP)
    assert_array_equal(rest.read(0.0, 0.01).specific_force, [0.0, 0.0, STANDARD_GRAVITY])
    # a free body at the pivot reads exactly zero
    free = Accelerometer(sol)
    assert_array_equal(free.read(1.0, 1.01).specific_force, np.zeros(3))
    # a uniformly spinning body: exactly the centripetal -w^2 r
    spin = Accelerometer(solve(Scene(omega0=(0.0, 0.0, 2.0))), lever_arm=(0.5, 0.0, 0.0))
    assert_allclose(spin.read(0.3, 0.31).specific_force, [-2.0, 0.0, 0.0], rtol=1e-15,
                    atol=1e-15)


def test_noise_statistics_match_the_stated_variance():
    sol = solve(Scene(omega0=(0.1, -0.2, 0.3)))            # cheap: constant rotation
    noise = ImuNoise(2e-3, 1e-4, (0.01, 0.0, -0.02), seed=5, kind='accel')
    acc = Accelerometer(sol, noise, lever_arm=(0.2, 0.0, 0.1), gravity=G_UP)
    dt = 0.01
    reads = [acc.read(dt * k, dt * (k + 1)) for k in range(3000)]
    err = np.array([r.specific_force - r.specific_force_avg - r.bias for r in reads])
    assert err.var() == pytest.approx(reads[0].variance, rel=0.05)
    assert reads[0].variance == pytest.approx(noise.white_variance(dt), rel=1e-12)
    assert_allclose(reads[0].bias, [0.01, 0.0, -0.02], rtol=0, atol=1e-4)


@pytest.mark.parametrize('kwargs, words', [
    (dict(lever_arm=(1e300, 0.0, 0.0)), 'accel.lever_arm[0] must be finite'),
    (dict(lever_arm=(0.0, math.nan, 0.0)), 'accel.lever_arm[1] must be finite'),
    (dict(gravity=(0.0, 0.0, math.inf)), 'accel.gravity[2] must be finite'),
    (dict(gravity=(0.0, 9.8)), 'accel.gravity must have 3 components, got 2'),
    (dict(noise=ImuNoise()), "needs ImuNoise(kind='accel')"),
])
def test_bad_values_are_refused_naming_the_parameter(kwargs, words):
    sol = solve(Scene(omega0=(0.0, 0.0, 1.0)))
    with pytest.raises(ValueError) as err:
        Accelerometer(sol, **kwargs)
    assert words in str(err.value)
    acc = Accelerometer(sol)
    with pytest.raises(ValueError, match='t0 < t1'):
        acc.read(1.0, 1.0)
    with pytest.raises(ValueError, match='delta_velocity needs finite'):
        delta_velocity(sol, math.nan, 1.0, (0, 0, 0), G_UP)
    assert DV_TOL > 0


# -- the block path (Accelerometer.read_many): read is its one-interval case ----------------
BLOCK_FIELDS = ('specific_force', 'specific_force_avg', 'specific_force_true',
                'delta_velocity', 'delta_velocity_bound', 'delta_velocity_measured', 'bias',
                'variance')
ACCEL_NOISES = {
    'ideal': lambda: ImuNoise(kind='accel'),
    'all-terms': lambda: ImuNoise(2e-3, 1e-4, (0.01, -0.02, 0.003), seed=5, kind='accel',
                                  bias_stddev=1e-3, bias_instability=1e-4,
                                  bias_correlation_time=2.0, scale_factor=(1e-3, -2e-3, 5e-4),
                                  misalignment=[[0, 1e-3, 0], [0, 0, -2e-3], [1e-3, 0, 0]],
                                  quantum=1e-6, increment_quantum=1e-8),
}
ACCEL_SCENES = {
    'axisymmetric': Scene(inertia=(2.0, 2.0, 1.0), omega0=(0.3, -0.2, 0.5)),
    'axial-torque': Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05),
                          omega0=(0.3, -0.2, 0.5)),
    'transverse-virtual': Scene(inertia=(2.0, 2.0, 1.0), torque=(0.03, 0.0, 0.0),
                                torque_frame='virtual', omega0=(0.3, -0.2, 0.5)),
}


def _accel_rows(sol, noise, times, sizes, lever=(0.1, -0.2, 0.05), gravity=G_UP):
    """Read the intervals of ``times`` in blocks of the given sizes (0: one ``read``)."""
    acc = Accelerometer(sol, noise(), lever_arm=lever, gravity=gravity)
    return read_in_blocks(acc, times, sizes, BLOCK_FIELDS,
                          lambda v: np.asarray(v, dtype=float).tobytes())


@pytest.mark.parametrize('scene', sorted(ACCEL_SCENES))
@pytest.mark.parametrize('noise', sorted(ACCEL_NOISES))
def test_accel_blocks_of_any_size_give_the_per_sample_bits(scene, noise):
    sol = solve(ACCEL_SCENES[scene])
    # the node's grid: stamps in ns, so the intervals differ in their last bits
    times = np.array([round(k * 1e9 / 1000.0) * 1e-9 for k in range(0, 201)])
    single = _accel_rows(sol, ACCEL_NOISES[noise], times, [0])
    for sizes in ([1], [8], [200], [3, 0, 17, 1, 64, 0, 0, 5]):
        got = _accel_rows(sol, ACCEL_NOISES[noise], times, sizes)
        assert len(got) == len(single) == 200
        for f in BLOCK_FIELDS:
            assert [r[f] for r in got] == [r[f] for r in single], (sizes, f)


@pytest.mark.parametrize('model', ['axial-torque', 'transverse-virtual', 'oblique-virtual',
                                   'torque-free-triaxial'])
def test_block_delta_v_against_the_30_digit_quadrature(model, rng):
    """Each row of one block (mixed lengths, so mixed rules) within its bound of mpmath."""
    from rigidrot_ros.sensors.accel import delta_velocity_many
    scene = _scene(model, rng)
    sol = solve(scene)
    motion, rhs = _mp_motion(scene)
    r = tuple(rng.uniform(-0.5, 0.5, 3))
    t0 = np.array([0.2, 0.31, 0.9])
    t1 = np.array([0.21, 0.9, 1.4])
    for g in (G_UP, (0.0, 0.0, 0.0)):
        dv, bound = delta_velocity_many(sol, t0, t1, r, g)
        with mp.workdps(30):
            rm = [mpmath.mpf(v) for v in r]
            gm = [mpmath.mpf(v) for v in g]
        for i in range(3):
            with mp.workdps(30):
                ref = _mp_delta_v(motion, rhs, t0[i], t1[i], rm, gm)
                err = float(mpmath.sqrt(sum((mpmath.mpf(float(a)) - b) ** 2
                                            for a, b in zip(dv[i], ref))))
            assert err <= bound[i] and bound[i] <= 1e-12, (model, g, i, err, bound[i])


def test_vectorised_truncation_is_the_scalar_formula(rng):
    """L(rho) of the block path gives the scalar _truncation (which the coarse-rule test
    above proves to hold) to rounding, for every rule, model, lever and gravity."""
    from rigidrot_ros.sensors.accel import _log_truncation_many
    from rigidrot_ros.sensors.batch import _truncation as from_log
    for model in ('axial-torque', 'transverse-virtual', 'oblique-virtual',
                  'torque-free-triaxial', 'sphere'):
        sol = solve(_scene(model, rng))
        rb = RateBound(sol)
        t0 = np.array([0.0, 0.5, 3.0])
        t1 = np.array([2.0, 0.51, 3.3])
        for lever, grav in ((0.5, 9.8), (0.5, 0.0), (0.0, 9.8)):
            log_l = _log_truncation_many(rb, t0, t1, lever, grav)
            for n in (2, 3, 4, 6, 12):
                got = from_log(log_l, np.full(3, float(n)))
                want = [_truncation(rb, a, b, n, lever, grav) for a, b in zip(t0, t1)]
                assert_allclose(got, want, rtol=1e-12, atol=0)


def test_long_intervals_fall_back_to_delta_velocity_alone_and_budget_keeps_the_stream():
    sol = solve(Scene(inertia=(2.0, 2.0, 1.0), torque=(0.03, 0.0, 0.0),
                      torque_frame='virtual', omega0=(0.3, -0.2, 0.5)))
    acc = Accelerometer(sol, lever_arm=(0.3, 0.0, 0.1), gravity=G_UP)
    times = np.array([0.0, 0.01, 40.0, 40.01])
    b = acc.read_many(times)
    for i in range(3):
        dv, bnd = delta_velocity(sol, times[i], times[i + 1], acc.lever_arm, acc.gravity)
        if i == 1:                              # the long one: subintervals, the same bits
            assert dv.tobytes() == b.delta_velocity[1].tobytes() and bnd == \
                b.delta_velocity_bound[1]
        assert_allclose(b.delta_velocity[i], dv, rtol=0, atol=b.delta_velocity_bound[i] + bnd)
    noisy = Accelerometer(sol, ImuNoise(1e-3, seed=2, kind='accel'), lever_arm=(0.3, 0, 0.1),
                          gravity=G_UP)
    with pytest.raises(ValueError, match='time budget'):
        noisy.read_many(times, budget=0.0)
    fresh = Accelerometer(sol, ImuNoise(1e-3, seed=2, kind='accel'), lever_arm=(0.3, 0, 0.1),
                          gravity=G_UP)
    assert noisy.read(0.0, 0.01).specific_force.tobytes() == \
        fresh.read(0.0, 0.01).specific_force.tobytes()      # the noise stream untouched
    with pytest.raises(ValueError, match='at least 2'):
        acc.read_many([0.0])
    with pytest.raises(ValueError, match='t0 < t1'):
        acc.read_many([0.0, 0.2, 0.1])
