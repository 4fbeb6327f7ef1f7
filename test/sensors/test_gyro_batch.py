"""The gyro over blocks of intervals (sensors.batch): the per-sample reads, bit for bit."""

import math

import mpmath
from mpmath import mp
import numpy as np
import pytest

from conftest import random_scene, read_in_blocks
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.sensors import Gyro, GyroNoise, ImuNoise, RateBound
from rigidrot_ros.sensors.batch import delta_angle_many, rounding_many, truncation_many
from rigidrot_ros.sensors.increments import _NODES, _RULES
from sensor_helpers import _mp_rate

FIELDS = ('omega', 'omega_avg', 'delta_angle', 'delta_angle_bound', 'delta_rotation',
          'delta_rotation_bound', 'bias', 'variance', 'quaternion', 'delta_angle_measured')


def _grid(rate, k0, k1):
    """Scene times of the node's sensor grid (ns stamps, as ``node.streams.scene_time``)."""
    return np.array([round(k * 1e9 / rate) * 1e-9 for k in range(k0, k1 + 1)])


NOISES = {
    'ideal': lambda: GyroNoise(),
    'gyro-noise': lambda: GyroNoise(1.7e-4, 2e-5, (0.01, -0.02, 0.003), seed=3),
    'imu-off': lambda: ImuNoise(seed=3),
    'imu-all': lambda: ImuNoise(1.7e-4, 2e-5, (0.01, -0.02, 0.003), seed=3,
                                bias_stddev=1e-3, bias_instability=1e-4,
                                bias_correlation_time=2.0, scale_factor=(1e-3, -2e-3, 5e-4),
                                misalignment=[[0, 1e-3, 0], [0, 0, -2e-3], [1e-3, 0, 0]],
                                quantum=1e-6, increment_quantum=1e-8),
    # a dense misalignment: a BLAS product u @ C^T gave other bits in a batch than alone
    'imu-dense': lambda: ImuNoise(1.7e-4, seed=3, scale_factor=(1e-3, -2e-3, 5e-4),
                                  misalignment=[[0, 1.1e-3, -7e-4], [3e-4, 0, -2e-3],
                                                [1e-3, 9e-4, 0]]),
}
SCENES = {
    'axisymmetric': Scene(inertia=(2.0, 2.0, 1.0), omega0=(0.3, -0.2, 0.5)),
    'triaxial': Scene(inertia=(1.0, 2.0, 3.0), omega0=(0.3, -0.2, 0.5)),
    'axial-torque': Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05),
                          omega0=(0.3, -0.2, 0.5)),
}


def _readings(sol, noise, times, sizes):
    """Read the intervals of ``times`` in blocks of the given sizes (0: one ``read``)."""
    return read_in_blocks(Gyro(sol, noise()), times, sizes, FIELDS)


def _bits(rows, field):
    return [None if r[field] is None else np.asarray(r[field], dtype=float).tobytes()
            for r in rows]


@pytest.mark.parametrize('scene', ['axisymmetric', 'axial-torque', 'triaxial'])
@pytest.mark.parametrize('noise', sorted(NOISES))
def test_blocks_of_any_size_give_the_per_sample_bits(scene, noise):
    sol = solve(SCENES[scene])
    times = _grid(1000.0, 0, 300)            # intervals differ in their last bits
    single = _readings(sol, NOISES[noise], times, [0])
    for sizes in ([1], [7], [8], [256], [3, 0, 17, 1, 64, 0, 0, 5]):
        got = _readings(sol, NOISES[noise], times, sizes)
        assert len(got) == len(single) == 300
        for field in FIELDS:
            assert _bits(got, field) == _bits(single, field), (sizes, field)


@pytest.mark.parametrize('scene', ['axial-torque', 'triaxial'])
def test_the_attitudes_at_the_ends_are_solution_at_of_t_alone(scene):
    """The ends' attitudes: whatever the block or the order, ``solution.at(t)``'s bits
    (the core's samples depend on t alone); the rotation bound covers their bounds."""
    sol = solve(SCENES[scene])
    times = _grid(1000.0, 0, 40)
    block = Gyro(sol).read_many(times)
    fresh = solve(SCENES[scene])
    want = [fresh.at(float(t)) for t in times[::-1]][::-1]      # another order, same bits
    assert block.quaternion.tobytes() == np.array([s.quaternion for s in want[1:]]).tobytes()
    bounds = np.array([float(s.error_bound) for s in want])
    rv = np.array([np.linalg.norm(r) for r in block.delta_rotation])
    gain = np.where(rv < 1e-8, 1.0, (0.5 * rv) / np.sin(0.5 * rv))
    assert np.all(block.delta_rotation_bound >= 1.01 * gain * (bounds[:-1] + bounds[1:]))


@pytest.mark.parametrize('model', ['torque-free-axisymmetric', 'axial-torque',
                                   'oblique-virtual', 'transverse-virtual', 'sphere'])
def test_block_delta_angle_against_30_digit_quadrature(model, rng):
    scene = random_scene(model, rng)
    sol = solve(scene)
    rate = _mp_rate(scene)
    t0 = np.array([0.0, 0.01, float(rng.uniform(1, 50)), float(rng.uniform(100, 2000)), 3.25])
    t1 = t0 + np.array([0.001, 0.01, 0.005, 0.01, 0.7])
    got, bound = delta_angle_many(sol, t0, t1, 1e-13, RateBound(sol))
    for k in range(len(t0)):
        with mp.workdps(30):
            ref = [mpmath.quad(lambda t, i=i: rate(t)[i], [mpmath.mpf(t0[k]), mpmath.mpf(t1[k])])
                   for i in range(3)]
        err = float(mpmath.sqrt(sum((mpmath.mpf(float(g)) - r) ** 2
                                    for g, r in zip(got[k], ref))))
        assert err <= bound[k], (t0[k], err, bound[k])
        if t1[k] < 100:      # far out the rounded node times alone may cost more, stated
            assert bound[k] <= 1e-12


def test_vectorised_bounds_hold_for_coarse_rules_and_match_the_scalar_formula(rng):
    """Force coarse rules on long intervals: the stated bound still covers the error."""
    for model in ('axial-torque', 'oblique-virtual', 'transverse-virtual'):
        scene = random_scene(model, rng)
        sol = solve(scene)
        rb = RateBound(sol)
        rate = _mp_rate(scene)
        t0 = np.array([0.0, 40.0, 5.0])
        t1 = t0 + np.array([2.0, 1.0, 4.0])
        with mp.workdps(30):
            ref = np.array([[float(mpmath.quad(lambda t, i=i: rate(t)[i], [a, b]))
                             for i in range(3)] for a, b in zip(t0, t1)])
        for n in (2, 3, 4, 6):
            x, wts = _RULES[n]
            hh, tm = 0.5 * (t1 - t0), 0.5 * (t0 + t1)
            om = sol.omega_at((tm[:, None] + hh[:, None] * x).ravel()).reshape(3, n, 3)
            got = hh[:, None] * np.einsum('j,mjk->mk', wts, om)
            w = np.max(np.linalg.norm(om, axis=-1), axis=1)
            stated = truncation_many(rb, t0, t1, n) + rounding_many(rb, t0, t1, n, w)
            err = np.linalg.norm(got - ref, axis=1)
            assert np.all(err <= stated), (model, n, err, stated)
            scalar = [rb.truncation(a, b, n) for a, b in zip(t0, t1)]
            np.testing.assert_allclose(truncation_many(rb, t0, t1, n), scalar, rtol=1e-12)


def test_each_interval_takes_the_fewest_nodes_that_meet_tol():
    sol = solve(SCENES['axial-torque'])
    rb = RateBound(sol)
    t0 = np.array([0.0, 1.0, 10.0, 100.0, 0.5])
    t1 = t0 + np.array([0.001, 0.01, 0.05, 0.2, 0.1])
    from rigidrot_ros.sensors.batch import _rules
    n, trunc = _rules(rb, 0.5 * (t1 - t0), 0.5 * (t0 + t1), 1e-13)
    assert len(set(n.tolist())) > 1
    for i, rule in enumerate(n.tolist()):
        assert trunc[i] == truncation_many(rb, t0[i:i + 1], t1[i:i + 1], rule)[0] <= 0.5e-13
        smaller = _NODES[_NODES.index(rule) - 1] if rule > _NODES[0] else None
        if smaller is not None:
            assert truncation_many(rb, t0[i:i + 1], t1[i:i + 1], smaller)[0] > 0.5e-13


@pytest.mark.parametrize('scene', ['axisymmetric', 'axial-torque'])
def test_the_pruned_rule_choice_is_the_full_one_bit_for_bit(scene):
    """Blocks choose their rules on the ellipses that can win: the same rules and bounds."""
    from rigidrot_ros.sensors.batch import _log_bound, _pruned_rules, rules_from_log
    rb = RateBound(solve(SCENES[scene]))
    assert rb.kind == 'closed-form'
    rng = np.random.default_rng(7)
    grids = [_grid(rate, k0, k0 + 500) for rate, k0 in
             ((1000.0, 0), (1000.0, 3_599_000), (4000.0, 12_345), (10.0, 7), (1.0, 3000))]
    grids += [np.sort(rng.uniform(0.0, 10.0 ** e, 400)) for e in (-1, 1, 3, 6)]
    seen = set()
    for times, tol in zip(grids, (1e-13, 1e-13, 1e-15, 1e-10, 1e-13, 1e-13, 1e-6, 1e-13,
                                  1e-13)):
        hh, tm = 0.5 * np.diff(times), 0.5 * (times[1:] + times[:-1])
        n, trunc = _pruned_rules(rb, hh, tm, tol)
        ref_n, ref_trunc = rules_from_log(_log_bound(rb, hh, tm), tol)
        assert np.array_equal(n, ref_n) and trunc.tobytes() == ref_trunc.tobytes()
        seen.update(n.tolist())
    assert 0 in seen and len(seen) > 6      # rules of many sizes, and intervals none serves


def test_long_intervals_fall_back_to_subintervals_alone():
    from rigidrot_ros.sensors import delta_angle
    sol = solve(SCENES['axial-torque'])
    times = np.array([0.0, 0.001, 60.0, 60.001])      # the middle one needs subintervals
    from rigidrot_ros.sensors.batch import _rules
    assert _rules(RateBound(sol), np.array([30.0]), np.array([30.0005]), 1e-13)[0][0] == 0
    b = Gyro(sol).read_many(times)
    da, bound = delta_angle(sol, 0.001, 60.0)
    assert np.array_equal(b.delta_angle[1], da) and b.delta_angle_bound[1] == bound
    single = [Gyro(sol).read(a, c) for a, c in zip(times[:-1], times[1:])]
    assert [r.delta_angle.tobytes() for r in single] == [v.tobytes() for v in b.delta_angle]


def test_bad_blocks_are_refused_and_the_budget_keeps_the_stream():
    sol = solve(SCENES['axial-torque'])
    gyro = Gyro(sol, GyroNoise(1.7e-4, 2e-5, seed=3))
    for times, words in (([0.0], 'at least 2'), ([[0.0, 1.0]], 'at least 2'),
                         ([0.0, math.nan], 'finite'), ([0.0, 0.1, 0.1], 't0 < t1')):
        with pytest.raises(ValueError, match=words):
            gyro.read_many(times)
    with pytest.raises(ValueError, match='time budget'):
        gyro.read_many([0.0, 0.001, 1e7], budget=0.02)
    fresh = Gyro(sol, GyroNoise(1.7e-4, 2e-5, seed=3))
    assert np.array_equal(gyro.read_many([0.0, 0.01]).omega, fresh.read_many([0.0, 0.01]).omega)


@pytest.mark.parametrize('kind', ['gyro', 'accel'])
def test_the_error_matrix_acts_row_by_row(kind):
    """ImuNoise.apply with scale factor and a dense misalignment: a batch gives each row
    the bits of a call with that row alone (a BLAS ``u @ C^T`` did not)."""
    def make(density=1e-3):
        return ImuNoise(density, seed=1, scale_factor=(1e-3, -2e-3, 5e-4), kind=kind,
                        misalignment=[[0, 1.1e-3, -7e-4], [3e-4, 0, -2e-3], [1e-3, 9e-4, 0]])
    u = np.random.default_rng(0).standard_normal((2000, 3)) * 9.8
    batch = make().apply(u, 1e-3).value
    one = make()
    single = np.array([one.apply(u[i:i + 1], 1e-3).value[0] for i in range(len(u))])
    assert batch.tobytes() == single.tobytes()
    ideal = make(0.0)
    np.testing.assert_allclose(ideal.apply(u, 1e-3).value, u @ ideal.matrix.T, rtol=4e-16,
                               atol=1e-14)     # still C u, to rounding
