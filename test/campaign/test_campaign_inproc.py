"""In-process estimators that misbehave: each run fails with its reason, none hangs.

A factory that raises, a filter that returns a message of a type the campaign does not
score, one message instead of a list, nothing at all, an object without receive(), and
filters stuck in ``time.sleep`` (main thread: interrupted by SIGALRM) or in a busy loop
(another thread, as on a Dask worker: interrupted by an exception set on the thread).
"""

import threading
import time

import pytest

from rigidrot_ros.campaign.run import run_one
from rigidrot_ros.campaign.spec import load_spec

from campaign_helpers import _write, SPEC  # noqa: I100, I201 - a helper module beside it


def _spec(tmp_path, factory, params=None, timeout=60):
    doc = dict(SPEC, runs=1, duration=1.0, timeout=timeout,
               estimator={'factory': f'campaign_helpers:{factory}', 'params': params or {}})
    return load_spec(_write(tmp_path, doc))


@pytest.mark.parametrize('factory, params, words', [
    ('misbehaving', {'how': 'wrong_type'},
     'receive() on /imu at stamp 10000000 ns returned a std_msgs/msg/String: the campaign '
     'scores nav_msgs/msg/Odometry'),
    ('misbehaving', {'how': 'not_a_list'},
     'receive() on /imu at stamp 10000000 ns returned Odometry, not a list of messages'),
    ('misbehaving', {'how': 'none'}, 'the estimator published nothing on /estimator/odom'),
    ('no_receive', {}, 'the factory made no estimator: its object has no receive() and no '
                       'finish()'),
])
def test_a_misbehaving_filter_fails_its_run_with_the_reason(tmp_path, factory, params, words):
    out = run_one(_spec(tmp_path, factory, params), 0)
    assert out['row']['status'] == 'failed' and words in out['row']['reason'], out['row']


def test_a_factory_that_cannot_start_is_fatal(tmp_path):
    spec = _spec(tmp_path, 'fails_after_the_check')
    out = run_one(spec, 0)
    assert out['fatal'] == ('estimator factory campaign_helpers:fails_after_the_check: cannot '
                            'start: the factory failed: OSError: no licence for this filter')


def test_a_filter_asleep_in_the_main_thread_is_interrupted(tmp_path):
    t0 = time.monotonic()
    out = run_one(_spec(tmp_path, 'misbehaving', {'how': 'sleep'}, timeout=2), 0)
    assert time.monotonic() - t0 < 30
    assert out['row']['reason'] == ('timeout: the run took longer than 2 s (in receive() on '
                                    '/imu at stamp 10000000 ns)'), out['row']


def test_a_filter_spinning_in_a_worker_thread_is_interrupted(tmp_path):
    spec = _spec(tmp_path, 'misbehaving', {'how': 'busy'}, timeout=2)
    got = []
    th = threading.Thread(target=lambda: got.append(run_one(spec, 0)))
    th.start()
    th.join(30)
    assert not th.is_alive() and got[0]['row']['reason'].startswith(
        'timeout: the run took longer than 2 s (in receive() on /imu'), got
