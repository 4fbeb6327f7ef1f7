"""The MEKF fed a run as arrays gives its messages' estimates, bit for bit.

Oracle: the same filter fed the generator's messages one by one (``receive``), on runs
with every sensor timing model (latency, stamp jitter, drops, clock offset), so the
arrival order of the samples (:func:`rigidrot_ros.run.feed.sensor_feed`) is checked
against the order the generator yields the messages in.
"""

import numpy as np
import pytest

from rigidrot_ros.estimators.mekf import make
from rigidrot_ros.run.feed import sensor_feed
from rigidrot_ros.run.generate import iter_run, iter_serialized, run_arrays

PARAMS = {'sigma_v': 1.7e-4, 'sigma_u': 2e-5, 'bias_sigma': 2e-3}


def _values(timed):
    v = {'imu.enable': True, 'star_tracker.enable': True, 'mag.enable': True,
         'imu.seed': 3, 'star_tracker.seed': 4, 'mag.seed': 5,
         'imu.gyro_bias': [1e-3, -2e-3, 5e-4], 'star_tracker.rate': 7.0}
    if timed:
        v.update({'imu.latency': 0.0031, 'imu.stamp_jitter': 2e-4,
                  'imu.drop_probability': 0.05, 'star_tracker.latency': 0.0013,
                  'star_tracker.clock_offset': 0.004, 'star_tracker.drop_probability': 0.1,
                  'mag.latency': 0.001})
    return v


@pytest.mark.parametrize('timed', [False, True])
def test_the_feed_order_is_the_generators(timed):
    values = _values(timed)
    names = ('imu', 'star_tracker', 'mag')
    want = [(t, ns) for t, ns, _ in iter_serialized(values, 3.0, names)]
    feed, order = sensor_feed(run_arrays(values, 3.0))
    assert sorted(feed) == ['/imu', '/mag', '/star_tracker']
    lat = {'/imu': 3_100_000, '/star_tracker': 1_300_000, '/mag': 1_000_000}
    got = [(t, int(feed[t]['true_ns'][k]) + (lat[t] if timed else 0)) for t, k in order]
    assert got == want


@pytest.mark.parametrize('timed, every', [(False, 10), (True, 1), (True, 7)])
def test_arrays_give_the_messages_estimates_bit_for_bit(timed, every):
    values = _values(timed)
    params = dict(PARAMS, output_every=every)
    ref = make(params)
    msgs = []
    for topic, _, msg in iter_run(values, 4.0):
        msgs += ref.receive(topic, msg)
    msgs += ref.finish()
    arrays = run_arrays(values, 4.0)
    feed, order = sensor_feed(arrays)
    filt = make(params)
    out = filt.receive_arrays(dict(feed, run=arrays['run']), order)
    assert out['type'] == 'nav_msgs/msg/Odometry' and len(msgs) == len(out['stamps_ns']) > 3
    np.testing.assert_array_equal(
        out['stamps_ns'], [m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec for m in msgs])
    o = [m.pose.pose.orientation for m in msgs]
    np.testing.assert_array_equal(out['orientation'], [[q.x, q.y, q.z, q.w] for q in o])
    np.testing.assert_array_equal(out['orientation_cov'],
                                  [np.reshape(m.pose.covariance, (6, 6))[3:, 3:] for m in msgs])
    w = [m.twist.twist.angular for m in msgs]
    np.testing.assert_array_equal(out['angular_velocity'], [[a.x, a.y, a.z] for a in w])
    np.testing.assert_array_equal(out['angular_velocity_cov'],
                                  [np.reshape(m.twist.covariance, (6, 6))[3:, 3:] for m in msgs])
    assert (filt.updates, filt.rejected) == (ref.updates, ref.rejected)
    assert filt.updates > 5 and filt.rejected == 0
    np.testing.assert_array_equal(filt.P, ref.P)
