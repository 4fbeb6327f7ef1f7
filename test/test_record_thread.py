"""The recorder's writer thread: a writer that falls behind loses and reorders nothing."""

import threading
import time

import pytest

from rigidrot_ros.io.bag import BagWriter
from rigidrot_ros.io.recorder import Recorder

from test_record_process import _calls, _node, _read  # noqa: I100, I201 - a test module beside it

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures('ros_context')]


class _SlowWriter(BagWriter):
    """A BagWriter whose writes wait (a stalled disk): the recorder falls behind."""

    delay = 0.0

    def write_many(self, topics, datas, log_times_ns):
        time.sleep(self.delay)
        return super().write_many(topics, datas, log_times_ns)

    def write(self, topic, data, log_time_ns, publish_time_ns=None):
        time.sleep(self.delay / 10)
        return super().write(topic, data, log_time_ns, publish_time_ns)


def _record(tmp_path, name, threaded, delay, calls):
    node = _node(f'rec_{name}')
    try:
        writer = _SlowWriter(str(tmp_path), name, flush_period=0.01)
        writer.delay = delay
        rec = Recorder(node, writer, exclude_own=True, threaded=threaded)
        queued, c0 = 0, time.perf_counter()
        for i, (now_ns, items) in enumerate(calls):
            rec.record_published(now_ns, items)
            if i == len(calls) // 2:
                rec.add_run({'index': '1', 'note': 'half way'})
                rec._flush()                        # as the flush timer would
            queued = max(queued, rec.queued)
        handed = time.perf_counter() - c0
        path, counts = rec.close()
        return path, counts, queued, handed
    finally:
        node.destroy_node()


def test_a_writer_that_falls_behind_loses_and_reorders_nothing(tmp_path):
    calls = _calls(300)
    ref, ref_counts, _, _ = _record(tmp_path / 'a', 'direct', False, 0.0, calls)
    path, counts, queued, handed = _record(tmp_path / 'b', 'threaded', True, 0.002, calls)
    assert queued > 10                      # it fell behind: the calls only queued
    assert counts == ref_counts == {'/rate': 300, '/note': 300}
    got, want = _read(path), _read(ref)
    assert got == want                      # every message, same bytes, same order
    assert [t for _, t, _ in got] == sorted(t for _, t, _ in got)
    assert not any(t.name == 'rigidrot-recorder' and t.is_alive()
                   for t in threading.enumerate())


def test_a_failing_disk_stops_the_threaded_recording_with_one_event(tmp_path):
    node = _node('rec_fail')
    events = []
    try:
        writer = BagWriter(str(tmp_path), 'fail', flush_period=0.01)

        def broken(*args):
            raise OSError(28, 'No space left on device')
        writer.write_many = broken
        rec = Recorder(node, writer, exclude_own=True, threaded=True,
                       on_event=lambda level, text: events.append((level, text)))
        for now_ns, items in _calls(20):
            rec.record_published(now_ns, items[:1])
        rec.close()
        assert not rec.active
        assert [lv for lv, _ in events] == ['error']
        assert 'No space left on device' in events[0][1]
    finally:
        node.destroy_node()
