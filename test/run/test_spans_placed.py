"""spans.placed: a span's records in one buffer, the records of the row-array path.

Every span of a run with every output and every timing model (drops, jitter, latency:
parts of different lengths, messages of one instant from several kinds) is built both
ways; message by message the bytes, channels, log times and sequence numbers must be
the same, and ``span_of`` must take the one-buffer way wherever it can.
"""

import numpy as np
import pytest

from rigidrot_ros.bag import chunks
from rigidrot_ros.run import generate as gen, spans

pytestmark = pytest.mark.skipif(not chunks.can_place(), reason='numba is not importable')

FULL = {
    'imu.enable': True, 'imu.rate': 200.0, 'imu.seed': 11, 'star_tracker.enable': True,
    'odom.enable': True, 'transform.enable': True, 'markers.enable': True,
    'accel.enable': True, 'accel.increment_quantum': 1e-5,
    'imu.gyro_increment_quantum': 1e-7, 'mag.enable': True, 'mag.rate': 50.0,
    'imu.latency': 0.003, 'imu.stamp_jitter': 1e-4, 'imu.drop_probability': 0.1,
    'star_tracker.latency': 0.05, 'star_tracker.drop_probability': 0.2,
    'mag.latency': 0.01, 'mag.drop_probability': 0.15,
}


def _messages(span):
    """Each message's record bytes, in the span's order."""
    return [bytes(span.sources[s][o:o + n]) for s, o, n in
            zip(span.src.tolist(), span.off.tolist(), span.size.tolist())]


def test_placed_spans_are_the_row_array_spans(monkeypatch):
    run = gen._Run(FULL, 7.5, 1_795_552_911_119_937_992)
    cids = {topic: i + 1 for i, (topic, _, _, _) in enumerate(run.topics)}
    seq_a, seq_b = dict.fromkeys(cids, 0), dict.fromkeys(cids, 0)
    taken = 0
    for _, _, parts in run.blocks(3):
        order = gen._order(parts)
        got = spans.span_of(run, parts, cids, seq_a, order)
        with monkeypatch.context() as m:            # the row arrays and their joins
            m.setattr(spans, 'placed', lambda *args: None)
            want = spans.span_of(run, parts, cids, seq_b, order)
        assert _messages(got) == _messages(want)
        assert np.array_equal(got.cid, want.cid) and np.array_equal(got.log, want.log)
        assert got.run_at == want.run_at and seq_a == seq_b
        if want.run_at < 0:                         # every span but the run description's
            assert len(got.sources) == 1 and got.cont[1:].all()
            assert not np.asarray(got.sources[0].obj).flags.writeable
            taken += 1
    assert taken == 2
