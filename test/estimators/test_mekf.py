"""The reference MEKF: consistent when tuned to its gyro, not when it assumes a quieter one.

Oracles: the exact truth of the generator's runs, NEES from the project's scorer
functions against a chi-square band, and a bias estimate that converges to the bias the
generator was given. The node: fed out of order, it gives the in-process filter's output.
"""

import numpy as np
import pytest

from rigidrot_ros.core import Scene, solve
from rigidrot_ros.estimators.mekf import make, MEKF, MekfParams
from rigidrot_ros.estimators.mekf_node import StampOrder
from rigidrot_ros.run.generate import iter_run
from rigidrot_ros.scoring.score import anees_bounds, nees, rotation_error

SIGMA_V, SIGMA_U = 1.7e-4, 2.0e-5


def _run(seed, sigma_v, duration=8.0, bias=(1e-3, -2e-3, 1.5e-3)):
    values = {'imu.enable': True, 'star_tracker.enable': True, 'imu.seed': seed,
              'star_tracker.seed': seed + 1000, 'imu.gyro_noise_density': SIGMA_V,
              'imu.gyro_random_walk': SIGMA_U, 'imu.gyro_bias': list(bias)}
    f = make({'sigma_v': sigma_v, 'sigma_u': SIGMA_U, 'bias_sigma': 3e-3})
    out, run = [], None
    for topic, _, msg in iter_run(values, duration):
        if topic.endswith('/run'):
            import json
            run = json.loads(msg.data)
        out += f.receive(topic, msg)
    out += f.finish()
    t = np.array([(o.header.stamp.sec * 10 ** 9 + o.header.stamp.nanosec - run['start_ns'])
                  * 1e-9 for o in out])
    q = np.array([[o.pose.pose.orientation.x, o.pose.pose.orientation.y,
                   o.pose.pose.orientation.z, o.pose.pose.orientation.w] for o in out])
    cov = np.array([np.reshape(o.pose.covariance, (6, 6))[3:, 3:] for o in out])
    truth = solve(Scene.from_dict(run['scene'])).at(t).quaternion
    return f, t, nees(rotation_error(truth, q), cov)


def test_tuned_consistent_and_mistuned_not():
    m = 8
    tuned = np.array([_run(s, SIGMA_V)[2] for s in range(m)])
    mistuned = np.array([_run(s, SIGMA_V / 10)[2] for s in range(m)])
    lo, hi = anees_bounds(m * tuned.shape[1], level=0.999)
    assert lo <= tuned.mean() <= hi, tuned.mean()
    band = anees_bounds(m)                            # per step, chi2(3M)/M
    mc = tuned.mean(axis=0)
    assert np.mean((mc >= band[0]) & (mc <= band[1])) >= 0.85
    assert mistuned.mean() > 5 * hi, mistuned.mean()
    assert np.mean(mistuned.mean(axis=0) > band[1]) > 0.8


def test_bias_converges_to_the_generator_bias():
    bias = np.array([2e-3, -1e-3, 3e-3])
    f, _, _ = _run(3, SIGMA_V, duration=20.0, bias=bias)
    sig = np.sqrt(np.diag(f.P)[3:])
    # the bias walks (sigma_u sqrt(20 s) ~ 9e-5 rad/s) away from its start
    assert np.all(np.abs(f.beta - bias) <= 4 * sig + 4 * SIGMA_U * np.sqrt(20.0)), (f.beta, sig)
    assert np.all(sig < 1e-4)


def test_node_order_gives_the_in_process_answer():
    """Messages of two topics interleaved out of stamp order: StampOrder restores it."""
    values = {'imu.enable': True, 'star_tracker.enable': True}
    msgs = [(t, ns, m) for t, ns, m in iter_run(values, 3.0) if not t.endswith('/run')]
    ref = MEKF({'sigma_v': SIGMA_V})
    want = [o for t, _, m in msgs for o in ref.receive(t, m)] + ref.finish()
    got = []
    filt = MEKF({'sigma_v': SIGMA_V})
    order = StampOrder(lambda t, m: got.extend(filt.receive(t, m)),
                       ('/imu', '/star_tracker'))
    imu = [x for x in msgs if x[0].endswith('imu')]
    star = [x for x in msgs if x[0].endswith('star_tracker')]
    for x in imu[:150] + star[:12] + imu[150:] + star[12:]:     # each topic in order
        order.push(x[0], x[1], x[2])
    order.drain()
    got += filt.finish()
    assert len(got) == len(want) > 20
    for a, b in zip(got, want):
        assert a.header.stamp == b.header.stamp
        assert list(a.pose.covariance) == list(b.pose.covariance)
        assert a.pose.pose.orientation == b.pose.pose.orientation


@pytest.mark.parametrize('params, word', [
    ({}, 'sigma_v'), ({'sigma_v': -1.0}, 'sigma_v'), ({'sigma_v': 1e-4, 'nope': 1}, 'nope'),
    ({'sigma_v': 1e-4, 'bias0': [0, 0]}, 'bias0'), ({'sigma_v': float('nan')}, 'sigma_v'),
    ({'sigma_v': 1e-4, 'output_every': 0}, 'output_every')])
def test_bad_params_named(params, word):
    with pytest.raises(ValueError, match=word):
        MekfParams(params)
