"""The node's recorder: chunk writes in its worker, nothing lost; Ctrl-C and SIGTERM finish it."""

import os
import signal
import subprocess
import threading
import time

import pytest

from rigidrot_ros.bag import BagWriter, read_bag
from rigidrot_ros.bag import chunks
from rigidrot_ros.ros.recorder import Recorder

from record_helpers import published_calls, publishing_node, rosbags_rows  # noqa: I100, I201
from ros_helpers import (next_domain_id, node_and_listener, read_node_bag,  # noqa: I100, I201
                         reset_twice, ros_env, script, start, stop, wait_for)
from record_helpers import _Disk, _Thread  # noqa: I100, I201 - a helper module beside it

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures('ros_context')]


def test_a_disk_error_of_an_offloaded_chunk_stops_the_recording_with_one_event(tmp_path):
    node = publishing_node('rec_offload_fail')
    events, worker = [], _Thread()
    try:
        # chunks close at the test's own flush() calls alone: with a short flush period a
        # slow machine closed the failing chunk inside record_published, whose next call
        # reported (and cleared) the error before the test looked for it
        writer = BagWriter(str(tmp_path), 'full', flush_period=3600.0, offload=worker)
        rec = Recorder(node, writer, exclude_own=True,
                       on_event=lambda level, text: events.append((level, text)))
        calls = published_calls(60)
        for now_ns, items in calls[:20]:
            rec.record_published(now_ns, items)
        writer.flush()
        deadline = time.monotonic() + 30.0
        while writer._pending:
            assert time.monotonic() < deadline, 'the worker never wrote the chunks'
            time.sleep(0.01)
        disk = _Disk.under(writer)
        disk.full = True
        for now_ns, items in calls[20:40]:
            rec.record_published(now_ns, items)
        writer.flush()                          # this chunk's write fails in the thread
        while writer._error is None:
            assert time.monotonic() < deadline + 30.0, 'the failed write was never noted'
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
    threads = []
    write_chunk = chunks.write_detached

    def spy(*args):
        threads.append(threading.current_thread().name)
        return write_chunk(*args)
    monkeypatch.setattr(chunks, 'write_detached', spy)
    node, ex, lis = node_and_listener(publish_rate=1000.0, record=True,
                                      record_path=str(tmp_path), **{'imu.enable': True,
                                                                    'imu.rate': 1000.0})
    ex.add_node(lis)
    try:
        writer = node._runs.recorder._writer
        assert (writer._offload is not None) == (offload == '1')
        reset_twice(node, ex, ticks=1000 if offload == '1' else 100)  # chunks at the resets
    finally:
        node.destroy_node()                     # the worker stops, then the bag is finished
        lis.destroy_node()
    counts = writer.counts                      # with what the pacer published to the end
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


@pytest.mark.parametrize('sig', ['group-SIGINT', 'SIGTERM'])
def test_ctrl_c_or_sigterm_of_the_node_finishes_its_bag(tmp_path, sig):
    """The console script, its chunks written in its worker: Ctrl-C to the whole group (a
    terminal's job) or SIGTERM stop the worker after its queued writes, then finish the bag:
    rosbags reads the summary, and every tick the node says it published is in it."""
    env = ros_env(next_domain_id())
    proc = start([script('attitude_node'), '--ros-args', '-p', 'publish_rate:=200.0',
                  '-p', 'record:=true', '-p', f'record_path:={tmp_path}'], env,
                 start_new_session=True)            # its own group, as a terminal's job
    try:
        assert wait_for(lambda: list(tmp_path.glob('*/*.mcap'))
                        and list(tmp_path.glob('*/*.mcap'))[0].stat().st_size > 4096,
                        timeout=60)
    finally:
        if sig == 'group-SIGINT':
            os.killpg(proc.pid, signal.SIGINT)      # Ctrl-C
            # once: a second SIGINT right behind it is a forced stop (KeyboardInterrupt
            # wherever the main thread is), which may lose the tick being recorded
            try:
                out, err = proc.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                code, out, err = stop(proc, signal.SIGKILL)
            code = proc.returncode
        else:
            code, out, err = stop(proc, signal.SIGTERM)
    assert code == 0, err
    assert 'bag finished' in err and 'Traceback' not in err, err
    rows = rosbags_rows(next(tmp_path.iterdir()))   # rosbags: the summary is there
    ticks = int(err.split('published ')[1].split(' ticks')[0])
    recorded = sum(t == '/attitude' for t, _, _ in rows)
    # a signal inside a scheduler call, between two publications, used to lose that tick
    # (test_a_shutdown_inside_a_publication_leaves_every_tick_it_counts_in_the_bag)
    assert recorded == ticks > 0, (recorded, ticks)


@pytest.mark.parametrize('at', ['/attitude', '/angular_velocity'])
def test_a_shutdown_inside_a_publication_leaves_every_tick_it_counts_in_the_bag(tmp_path, at):
    """ROS shut down (SIGTERM, SIGINT) between two publications of one scheduler call.

    The messages that went out are recorded; a truth tick none of whose messages went out
    is not counted as published. A tick counted before its publication used to be missing
    from the bag (``published N ticks`` one more than the bag's ``/attitude``).
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException
    node, ex, lis = node_and_listener(record=True, record_path=str(tmp_path))
    lis.destroy_node()
    pub = node._pubs[at.lstrip('/')][0]
    real = pub.publish
    calls = []

    def publish(raw):
        calls.append(1)
        if len(calls) == 40:            # a few ticks in: shut down, then publish as rclpy
            rclpy.shutdown()
        return real(raw)
    pub.publish = publish
    try:
        try:
            ex.spin()                   # ends when the context is shut down
        except ExternalShutdownException:
            pass
        writer = node._runs.recorder._writer
        ticks = node._counters.published
    finally:
        node.destroy_node()
    attitude = [t for t, _, _ in rosbags_rows(writer.path) if t == '/attitude']
    assert len(calls) == 40
    # '/attitude' is each tick's first message: when it is the one refused, the tick did not
    # go out and is not counted; when '/angular_velocity' is, the tick went out in part
    assert len(attitude) == ticks == (39 if at == '/attitude' else 40)
