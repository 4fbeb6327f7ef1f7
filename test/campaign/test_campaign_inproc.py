"""In-process campaigns: in memory and with bags kept, the same report; misbehaving filters.

In memory (the default) and with ``--keep-bags`` (every run's estimates bagged, read back
and scored) give the same bytes of every output; the kept bags, read by the ``mcap``
library, hold the estimates the filter gives fed the run as arrays; an in-memory campaign
makes no directory. (A kept bag's messages carry CDR padding bytes that rclpy's serializer
leaves as it finds them, before as now: the bags are compared field by field.)

Misbehaving filters: a factory that raises, a filter that returns a message of a type the
campaign does not score, one message instead of a list, nothing at all, an object without
receive(), a ``receive_arrays`` that raises or returns what cannot be scored, and filters
stuck in ``time.sleep`` (main thread: interrupted by SIGALRM) or in a busy loop (another
thread, as on a Dask worker: interrupted by an exception set on the thread).
"""

import os
import tempfile
import threading
import time

import numpy as np
import pytest

from rigidrot_ros.campaign.run import run_one
from rigidrot_ros.campaign.spec import draw_run, load_spec, run_values
from rigidrot_ros.runtime import interrupt
from rigidrot_ros.tools.campaign import main

from campaign_helpers import _write, SPEC  # noqa: I100, I201 - a helper module beside it
from thread_helpers import profiled_calls


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


@pytest.mark.parametrize('how, words', [
    ('raises', 'the estimator crashed in receive_arrays(): ValueError: no arrays today'),
    ('not_a_dict', 'receive_arrays() returned list, not a dict of arrays'),
    ('wrong_type', "receive_arrays() returned estimates of type 'std_msgs/msg/String': the "
                   'campaign scores nav_msgs/msg/Odometry'),
    ('short', 'receive_arrays() returned unreadable estimates (ValueError'),
    ('empty', 'the estimator published nothing on /estimator/odom'),
])
def test_a_misbehaving_receive_arrays_fails_its_run(tmp_path, how, words):
    out = run_one(_spec(tmp_path, 'bad_arrays', dict(SPEC['estimator']['params'], how=how)), 0)
    assert out['row']['status'] == 'failed' and words in out['row']['reason'], out['row']


def _outputs(d):
    return {p: open(os.path.join(d, p), 'rb').read() for p in
            ['report.json', 'runs.csv', 'nees.svg'] + [f'runs/{i:06d}.json' for i in range(3)]}


def _bag(path):
    """The bag at ``path`` as the mcap library reads it (not the project's reader).

    Its metadata records, and each message's channel, times and every field decoded: the
    CDR padding bytes, which rclpy's serializer leaves as it finds them, are not compared.
    """
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    def fields(m):
        if isinstance(m, (int, float, str)):
            return m
        if isinstance(m, (list, tuple)):
            return [fields(x) for x in m]
        return {k: fields(getattr(m, k)) for k in m.__slots__}
    name = next(n for n in os.listdir(path) if n.endswith('.mcap'))
    with open(os.path.join(path, name), 'rb') as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        msgs = [(ch.topic, raw.log_time, raw.publish_time, raw.sequence, fields(m))
                for _, ch, raw, m in reader.iter_decoded_messages(log_time_order=True)]
        fh.seek(0)
        meta = [(r.name, dict(r.metadata)) for r in make_reader(fh).iter_metadata()]
    return meta, msgs


def _bag_estimates(msgs):
    """The orientation estimates of the messages of :func:`_bag` on /estimator/odom."""
    odom = [m[4] for m in msgs if m[0] == '/estimator/odom']
    q = [m['pose']['pose']['orientation'] for m in odom]
    return {'stamps_ns': [m['header']['stamp']['sec'] * 10 ** 9 + m['header']['stamp']['nanosec']
                          for m in odom],
            'orientation': [[o['x'], o['y'], o['z'], o['w']] for o in q],
            'orientation_cov': [np.reshape(m['pose']['covariance'], (6, 6))[3:, 3:]
                                for m in odom]}


def test_in_memory_and_kept_bags_give_the_same_bytes(tmp_path, monkeypatch):
    from rigidrot_ros.estimators.mekf import make
    from rigidrot_ros.run.feed import sensor_feed
    from rigidrot_ros.run.generate import run_arrays
    scratch = tmp_path / 'tmp'
    scratch.mkdir()
    monkeypatch.setenv('TMPDIR', str(scratch))
    monkeypatch.setattr(tempfile, 'tempdir', str(scratch))
    path = _write(tmp_path, dict(SPEC, runs=3, duration=3.0))
    assert main([path, '-o', str(tmp_path / 'mem'), '--quiet']) == 0
    assert os.listdir(scratch) == []                        # in memory: no directory made
    for n, bags in (('kept', 'bags'), ('again', 'bags2')):
        assert main([path, '-o', str(tmp_path / n), '--quiet', '--keep-bags',
                     str(tmp_path / bags)]) == 0
    mem = _outputs(tmp_path / 'mem')
    assert mem == _outputs(tmp_path / 'kept') == _outputs(tmp_path / 'again')
    spec = load_spec(path)
    for i in range(3):
        kept = tmp_path / 'bags' / f'run_{i:06d}' / 'estimate'
        again = tmp_path / 'bags2' / f'run_{i:06d}' / 'estimate'
        assert sorted(os.listdir(kept)) == sorted(os.listdir(again))
        assert (kept / 'metadata.yaml').read_bytes() == (again / 'metadata.yaml').read_bytes()
        meta, msgs = _bag(str(kept))
        assert (meta, msgs) == _bag(str(again))             # the same every time
        assert any(name == 'rigidrot_run' for name, _ in meta)
        arrays = run_arrays(run_values(spec, draw_run(spec, i)[0]), spec['duration'])
        feed, order = sensor_feed(arrays)
        want = make(spec['estimator']['params']).receive_arrays(feed, order)
        got = _bag_estimates(msgs)
        assert len(got['stamps_ns']) > 20
        for key in got:
            np.testing.assert_array_equal(got[key], want[key])


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
    # the exception taken back leaves no flag up: a profiled thread (a node's gated
    # look-ahead worker in the same process) is not stalled at its next call
    try:
        assert profiled_calls().wait(10.0)
    finally:
        interrupt.settle()
