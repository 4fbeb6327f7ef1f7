"""The compiled MEKF run gives the interpreted filter's estimates and state, bit for bit.

Oracle: the same filter interpreted (``receive_arrays(..., compiled=False)``, itself
checked against the messages' path in test_mekf_arrays), on generated runs with every
sensor timing model, and on a synthetic run with every kind of sample the filter refuses
(a non-finite gyro sample, a star tracker quaternion that is not unit or not finite, a
covariance that is not positive definite, a star tracker sample older than the state)
and star tracker samples at a gyro stamp and between gyro stamps.
"""

import os
import subprocess
import sys

import numpy as np
import pytest

from rigidrot_ros.estimators import mekf_kernel
from rigidrot_ros.estimators.mekf import make
from rigidrot_ros.run.feed import sensor_feed
from rigidrot_ros.run.generate import run_arrays

PARAMS = {'sigma_v': 1.7e-4, 'sigma_u': 2e-5, 'bias_sigma': 2e-3}

#: Where the compiled filter cannot be had at all (no numba, numpy without the OpenBLAS
#: of its wheels, RIGIDROT_NO_JIT): the filter stays interpreted, nothing to compare. A
#: kernel that fails to compile or differs from the interpreted filter fails below.
UNAVAILABLE = not make(PARAMS).warm() and not mekf_kernel.state()['reason'].startswith(
    ('the kernel does not compile', 'the compiled filter differs'))
pytestmark = pytest.mark.skipif(UNAVAILABLE, reason=f'no compiled MEKF here: '
                                                    f'{mekf_kernel.state()["reason"]}')


def test_the_compiled_filter_loads_and_passes_its_check():
    assert mekf_kernel.state() == {'loaded': True, 'ok': True, 'reason': ''}


def _same(a, b):
    """Assert two receive_arrays results and the filters after them are the same bits."""
    (out_a, fa), (out_b, fb) = a, b
    assert out_a.keys() == out_b.keys()
    for key, va in out_a.items():
        if isinstance(va, np.ndarray):
            vb = out_b[key]
            assert va.shape == vb.shape and va.dtype == vb.dtype, key
            assert va.tobytes() == vb.tobytes(), key        # signed zeros and NaNs too
        else:
            assert va == out_b[key], key
    for name in ('q', 'P', 'beta', 'omega', 'gyro_var'):
        x, y = getattr(fa, name), getattr(fb, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert np.asarray(x).tobytes() == np.asarray(y).tobytes(), name
    assert (fa.t_ns, fa._gyro_count, fa.updates, fa.rejected) == \
        (fb.t_ns, fb._gyro_count, fb.updates, fb.rejected)
    assert [(t, q.tolist(), r.tolist()) for t, q, r in fa.pending_star] == \
        [(t, q.tolist(), r.tolist()) for t, q, r in fb.pending_star]


def _both(params, feed, order):
    runs = []
    for compiled in (False, True):
        filt = make(params)
        runs.append((filt.receive_arrays(feed, order, compiled=compiled), filt))
    return runs


@pytest.mark.parametrize('every', [1, 10])
def test_a_generated_run_gives_the_same_bits(every):
    values = {'imu.enable': True, 'star_tracker.enable': True, 'imu.seed': 3,
              'star_tracker.seed': 4, 'imu.gyro_bias': [1e-3, -2e-3, 5e-4],
              'star_tracker.rate': 7.0, 'imu.latency': 0.0031, 'imu.stamp_jitter': 2e-4,
              'imu.drop_probability': 0.05, 'star_tracker.latency': 0.0013,
              'star_tracker.clock_offset': 0.004, 'star_tracker.drop_probability': 0.1}
    arrays = run_arrays(values, 6.0)
    feed, order = sensor_feed(arrays)
    a, b = _both(dict(PARAMS, output_every=every), dict(feed, run=arrays['run']), order)
    _same(a, b)
    assert len(a[0]['stamps_ns']) > 50 and a[1].updates > 20


def _synthetic(rng):
    n, m = 200, 24
    imu_t = np.arange(1, n + 1, dtype=np.int64) * 10_000_000 + rng.integers(0, 4000, n)
    star_t = np.sort(rng.integers(0, imu_t[-1] + 30_000_000, m)).astype(np.int64)
    star_t[3] = imu_t[40]                           # at a gyro stamp
    star_t[10] = star_t[9]                          # two at once
    q = rng.standard_normal((m, 4))
    q /= np.linalg.norm(q, axis=1)[:, None]
    q[5] *= 1.01                                    # not unit: refused
    q[7, 2] = np.nan                                # not finite: refused
    cov = np.tile(np.diag([1e-8, 2e-8, 3e-7]), (m, 1, 1))
    cov[12] = np.diag([1e-8, -1e-8, 1e-8])          # not positive definite: refused
    w = 0.4 * rng.standard_normal((n, 3))
    w[60, 1] = np.inf                               # refused
    feed = {'/imu': {'stamps_ns': imu_t, 'w': w, 'var': np.full(n, 2.9e-6)},
            '/star_tracker': {'stamps_ns': star_t, 'q': q, 'cov': cov},
            '/mag': {'stamps_ns': imu_t[:5]}}
    order = sorted([('/imu', k) for k in range(n)] + [('/star_tracker', k) for k in range(m)]
                   + [('/mag', k) for k in range(5)],
                   key=lambda e: (int(feed[e[0]]['stamps_ns'][e[1]]), e[0]))
    late = order.index(('/star_tracker', 15))       # one star sample arrives late: older
    order.insert(late + 25, order.pop(late))        # than the state, refused
    return feed, order


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_refused_and_simultaneous_samples_give_the_same_bits(seed):
    feed, order = _synthetic(np.random.default_rng(seed))
    a, b = _both(dict(PARAMS, output_every=3, bias0=[1e-3, 0.0, -1e-3]), feed, order)
    _same(a, b)
    assert a[1].rejected >= 4 and a[1].updates > 10


def test_star_samples_after_the_last_gyro_sample_stay_pending():
    feed, order = _synthetic(np.random.default_rng(4))
    keep = int(feed['/imu']['stamps_ns'][150])
    order = [(t, k) for t, k in order if t != '/imu' or feed[t]['stamps_ns'][k] <= keep]
    a, b = _both(PARAMS, feed, order)
    _same(a, b)
    assert len(b[1].pending_star) >= 3


def test_a_run_without_star_tracker_gives_nothing_either_way():
    feed, order = _synthetic(np.random.default_rng(5))
    order = [(t, k) for t, k in order if t == '/imu']
    a, b = _both(PARAMS, feed, order)
    _same(a, b)
    assert len(b[0]['stamps_ns']) == 0 and b[1].q is None


def test_compiled_needs_a_fresh_filter():
    feed, order = _synthetic(np.random.default_rng(6))
    filt = make(PARAMS)
    filt.receive_arrays(feed, order[:50], compiled=False)
    with pytest.raises(ValueError, match='fresh filter'):
        filt.receive_arrays(feed, order[50:], compiled=True)
    again = make(PARAMS)                            # the default: interpreted, then
    again.receive_arrays(feed, order[:50])
    rest = again.receive_arrays(feed, order[50:])
    ref = make(PARAMS)
    whole = ref.receive_arrays(feed, order, compiled=False)
    assert len(rest['stamps_ns']) > 10
    assert rest['orientation'].tobytes() == \
        whole['orientation'][-len(rest['stamps_ns']):].tobytes()


def test_no_jit_keeps_the_filter_interpreted():
    code = ('from rigidrot_ros.estimators.mekf import make\n'
            'from rigidrot_ros.estimators import mekf_kernel\n'
            "print(make({'sigma_v': 1e-4}).warm(), mekf_kernel.state()['reason'])\n")
    res = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         env=dict(os.environ, RIGIDROT_NO_JIT='1'), timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.split(None, 1) == ['False', 'RIGIDROT_NO_JIT is set\n']


def test_rows_are_indexed_as_python_indexes_them():
    feed, order = _synthetic(np.random.default_rng(7))
    n = len(feed['/imu']['stamps_ns'])
    order = [(t, k - n if t == '/imu' and k % 2 else k) for t, k in order]
    a, b = _both(PARAMS, feed, order)
    _same(a, b)
    bad = order[:30] + [('/imu', n)]
    for compiled in (False, True):
        with pytest.raises(IndexError):
            make(PARAMS).receive_arrays(feed, bad, compiled=compiled)
