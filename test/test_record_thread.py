"""The recorder's writer thread, and the node's chunk writes in its worker: nothing lost."""

import threading
import time

import pytest

from rigidrot_ros.bag import BagWriter, read_bag
from rigidrot_ros.bag import writer as bagmod
from rigidrot_ros.ros.recorder import Recorder

from ros_helpers import node_and_listener, read_node_bag, reset_twice  # noqa: I100, I201
from test_bag_offload import _Disk, _Thread  # noqa: I100, I201 - test modules beside it
from test_record_process import _calls, _node, _read  # noqa: I100, I201

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


def test_a_disk_error_of_an_offloaded_chunk_stops_the_recording_with_one_event(tmp_path):
    node = _node('rec_offload_fail')
    events, worker = [], _Thread()
    try:
        writer = BagWriter(str(tmp_path), 'full', flush_period=0.01, offload=worker)
        rec = Recorder(node, writer, exclude_own=True,
                       on_event=lambda level, text: events.append((level, text)))
        calls = _calls(60)
        for now_ns, items in calls[:20]:
            rec.record_published(now_ns, items)
        writer.flush()
        while writer._pending:
            time.sleep(0.01)
        disk = _Disk.under(writer)
        disk.full = True
        for now_ns, items in calls[20:40]:
            rec.record_published(now_ns, items)
        writer.flush()                          # this chunk's write fails in the thread
        while writer._error is None:
            time.sleep(0.01)
        for now_ns, items in calls[40:]:
            rec.record_published(now_ns, items)     # the error surfaces here, once
        rec.close()
        assert not rec.active
        assert [lv for lv, _ in events] == ['error']
        assert 'No space left on device' in events[0][1]
    finally:
        worker.stop()
        node.destroy_node()
    # what was written before the error is in the file (no summary: read as torn)
    got = read_bag(writer.path)
    assert [m[2] for m in got.messages] == [t for t, _ in calls[:20] for _ in range(2)]


@pytest.mark.parametrize('offload', ['1', '0'])
def test_the_node_at_1_khz_writes_its_chunks_in_its_worker(tmp_path, monkeypatch, offload):
    monkeypatch.setenv('RIGIDROT_RECORD_OFFLOAD', offload)
    monkeypatch.delenv('RIGIDROT_RECORD_THREAD', raising=False)
    monkeypatch.delenv('RIGIDROT_RECORD_PROCESS', raising=False)
    threads = []
    write_chunk = bagmod._write_chunk

    def spy(*args):
        threads.append(threading.current_thread().name)
        return write_chunk(*args)
    monkeypatch.setattr(bagmod, '_write_chunk', spy)
    node, ex, lis = node_and_listener(publish_rate=1000.0, record=True,
                                      record_path=str(tmp_path), **{'imu.enable': True,
                                                                    'imu.rate': 1000.0})
    ex.add_node(lis)
    try:
        writer = node._runs.recorder._writer
        assert (writer._offload is not None) == (offload == '1')
        reset_twice(node, ex, ticks=1000 if offload == '1' else 100)  # chunks at the resets
        counts = node._runs.recorder.counts
    finally:
        node.destroy_node()                     # the worker stops, then the bag is finished
        lis.destroy_node()
    assert writer.closed and not writer._pending
    if offload == '1':
        assert threads.count('rigidrot-lookahead') >= 20       # 3 s, a chunk every 0.1 s
    else:
        assert not threads
    imu, logs, runs, total = read_node_bag(writer.path)
    assert len(logs) == total == sum(counts.values())       # all of it, summary and all
    assert len(imu) == counts['/imu'] >= (2900 if offload == '1' else 290)
    assert logs == sorted(logs)
    assert all(b > a for a, b in zip(imu, imu[1:]))         # every sample, in order
    assert runs == 3                                        # start-up and two resets
    assert len(read_bag(writer.path).runs) == 3
