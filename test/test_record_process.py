"""The recorder's writer process: the same bag, nothing lost, clean shutdowns, a death survived."""

import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap
import threading
import time

from geometry_msgs.msg import Vector3Stamped
import pytest
import rclpy
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from std_msgs.msg import String

from rigidrot_ros.bag import BagWriter, read_bag
from rigidrot_ros.bag.process import ProcessBagWriter
from rigidrot_ros.msgs import messages as msgs
from rigidrot_ros.ros.recorder import Recorder
from ros_helpers import (next_domain_id, node_and_listener, read_node_bag, reset_twice,
                         ros_env, script, start, stop, wait_for)

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures('ros_context')]

_NEVER = 1e9                    # no flush by the clock: chunks close by size and by flush()


def _calls(n, pad=0):
    """``n`` calls of published messages: a raw vector and a String object (serialized later)."""
    out = []
    for i in range(n):
        vec = msgs.vector(msgs.stamp(10**9 + i * 10**6), 'body', (i, -i, 0.5 * i))
        out.append((10**9 + i * 10**6 + 7,
                    [('/rate', Vector3Stamped, serialize_message(vec)),
                     ('/note', String(data=f'call {i} ' + 'x' * (pad + i % 97)), None)]))
    return out


def _node(name):
    node = rclpy.create_node(name)
    node.create_publisher(Vector3Stamped, '/rate', 10)
    node.create_publisher(String, '/note', 10)
    return node


def _record(writer, calls, name, on_event=None, between=None):
    node = _node(name)
    try:
        rec = Recorder(node, writer, exclude_own=True, on_event=on_event)
        for i, (now_ns, items) in enumerate(calls):
            rec.record_published(now_ns, items)
            if i == len(calls) // 2:
                rec.add_run({'index': '1', 'note': 'half way'})
                writer.flush()
            if between is not None:
                between(i, rec)
        path, counts = rec.close()
        return rec, path, counts
    finally:
        node.destroy_node()


def _read(path):
    with AnyReader([Path(path)]) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def _files(path):
    return {p.name: p.read_bytes() for p in sorted(Path(path).iterdir())}


def test_the_writer_process_writes_the_bytes_the_inline_recorder_writes(tmp_path):
    calls = _calls(4000, pad=200)           # past the 1 MiB chunk size: chunks close by size
    inline = BagWriter(None, '', flush_period=_NEVER, path=str(tmp_path / 'a' / 'bag'))
    child = ProcessBagWriter(None, '', flush_period=_NEVER, path=str(tmp_path / 'b' / 'bag'))
    _, ref, ref_counts = _record(inline, calls, 'rec_inline')
    rec, path, counts = _record(child, calls, 'rec_child')
    assert counts == ref_counts == {'/rate': 4000, '/note': 4000}
    assert child._proc.returncode == 0 and rec.active is False
    want, got = _files(ref), _files(path)
    assert sorted(got) == ['bag_0.mcap', 'metadata.yaml']
    assert got == want                      # the .mcap and metadata.yaml, byte for byte
    rows = _read(path)
    assert rows == _read(ref) and len(rows) == 8000
    assert len(read_bag(path).runs) == 1


def test_a_child_that_falls_behind_blocks_the_caller_and_loses_nothing(tmp_path):
    calls = _calls(3000, pad=600)           # about 2 MiB: more than the ring holds
    ref = BagWriter(None, '', flush_period=0.05, path=str(tmp_path / 'a' / 'bag'))
    _, ref, _ = _record(ref, calls, 'rec_ref')
    child = ProcessBagWriter(None, '', flush_period=0.05, path=str(tmp_path / 'b' / 'bag'),
                             ring_bytes=1 << 16)
    os.kill(child.pid, signal.SIGSTOP)      # a child that does not read at all
    done = threading.Event()
    result = {}

    def feed():
        result['out'] = _record(child, calls, 'rec_blocked')
        done.set()
    thread = threading.Thread(target=feed)
    thread.start()
    try:
        assert not done.wait(1.0)           # the caller waits on the full ring ...
    finally:
        os.kill(child.pid, signal.SIGCONT)  # ... and goes on when the child reads again
    thread.join(60)
    assert done.is_set()
    _, path, counts = result['out']
    assert counts == {'/rate': 3000, '/note': 3000}
    assert _read(path) == _read(ref)        # every message, same bytes, same order


def test_a_killed_child_is_one_error_and_the_bag_keeps_what_was_flushed(tmp_path):
    events = []
    child = ProcessBagWriter(None, '', flush_period=_NEVER, path=str(tmp_path / 'bag'))

    def kill_after_half(i, rec):
        if i == 1000:                       # the half-way flush is in the file: kill it
            for _ in range(300):
                try:
                    if len(read_bag(child.path).messages) >= 2002:
                        break
                except Exception:   # noqa: B902 - the file is being written
                    pass
                time.sleep(0.05)
            os.kill(child.pid, signal.SIGKILL)
            child._proc.wait()              # dead (the timer would just see it later)
        if i in (1001, 1002):
            rec._flush()                    # as the flush timer would: the death is seen
    rec, path, counts = _record(child, _calls(2000), 'rec_killed',
                                on_event=lambda lv, text: events.append((lv, text)),
                                between=kill_after_half)
    assert [lv for lv, _ in events] == ['error'], events
    assert f'pid {child.pid}' in events[0][1] and 'signal 9' in events[0][1]
    assert not rec.active
    bag = read_bag(path)                    # no summary: read by scanning the records
    rate = [m for m in bag.messages if m[0] == '/rate']
    assert len(rate) == 1001 and len(bag.runs) == 1


def test_the_child_ignores_ctrl_c_in_its_own_group_and_stops_with_the_pipe(tmp_path):
    child = ProcessBagWriter(None, '', path=str(tmp_path / 'bag'))
    node = _node('rec_sigint')
    try:
        rec = Recorder(node, child, exclude_own=True)
        assert os.getpgid(child.pid) == child.pid != os.getpgid(0)
        for now_ns, items in _calls(50):
            rec.record_published(now_ns, items)
        time.sleep(0.5)                     # the child has started and set its handlers
        os.kill(child.pid, signal.SIGINT)
        for now_ns, items in _calls(100)[50:]:
            rec.record_published(now_ns, items)
        assert child._proc.poll() is None
        path, counts = rec.close()
    finally:
        node.destroy_node()
    assert child._proc.returncode == 0
    assert len(_read(path)) == 200 == sum(counts.values())


ORPHAN = textwrap.dedent('''
    import os, sys
    from rigidrot_ros.bag.process import ProcessBagWriter
    w = ProcessBagWriter(None, '', path=sys.argv[1])
    w.add_topic('/note', 'std_msgs/msg/String')
    w.write_many(['/note'] * 3, [b'\\x00\\x01\\x00\\x00\\x02\\x00\\x00\\x00a\\x00'] * 3,
                 [1, 2, 3])
    print(w.pid, flush=True)
    os._exit(0)                             # dies without closing
''')


def test_a_caller_that_dies_leaves_a_finished_bag(tmp_path):
    out = subprocess.run([sys.executable, '-c', ORPHAN, str(tmp_path / 'bag')],
                         capture_output=True, text=True, timeout=60, check=True).stdout
    pid = int(out)
    for _ in range(600):                    # the orphan finishes on end-of-file
        if not os.path.exists(f'/proc/{pid}'):
            break
        time.sleep(0.05)
    assert len(_read(tmp_path / 'bag')) == 3     # rosbags reads the summary


def test_the_node_records_through_a_writer_process_over_resets(tmp_path, monkeypatch):
    monkeypatch.setenv('RIGIDROT_RECORD_PROCESS', '1')
    node, ex, lis = node_and_listener(publish_rate=500.0, record=True,
                                      record_path=str(tmp_path), **{'imu.enable': True,
                                                                    'imu.rate': 500.0})
    ex.add_node(lis)
    try:
        writer = node._runs.recorder._writer
        assert isinstance(writer, ProcessBagWriter)
        reset_twice(node, ex)
        counts = node._runs.recorder.counts
    finally:
        node.destroy_node()
        lis.destroy_node()
    assert writer._proc.returncode == 0     # stopped by the node, the bag finished
    imu, logs, runs, _ = read_node_bag(writer.path)
    assert len(imu) >= counts['/imu'] >= 200        # everything handed over before the close
    assert logs == sorted(logs)
    assert all(b > a for a, b in zip(imu, imu[1:]))
    assert runs == 3                                # start-up and two resets


@pytest.mark.parametrize('sig', ['group-SIGINT', 'SIGTERM'])
def test_ctrl_c_or_sigterm_of_the_node_finishes_the_bag_of_its_writer_process(tmp_path, sig):
    env = dict(ros_env(next_domain_id()), RIGIDROT_RECORD_PROCESS='1')
    proc = start([script('attitude_node'), '--ros-args', '-p', 'publish_rate:=200.0',
                  '-p', 'record:=true', '-p', f'record_path:={tmp_path}'], env,
                 start_new_session=True)            # its own group, as a terminal's job
    try:
        assert wait_for(lambda: list(tmp_path.glob('*/*.mcap'))
                        and list(tmp_path.glob('*/*.mcap'))[0].stat().st_size > 4096,
                        timeout=60)
    finally:
        if sig == 'group-SIGINT':
            os.killpg(proc.pid, signal.SIGINT)      # Ctrl-C: node and writer both get it
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
    pid = int(err.split('(writer process ')[1].split(')')[0])
    assert wait_for(lambda: not os.path.exists(f'/proc/{pid}'), timeout=10)
    bag = next(tmp_path.iterdir())
    rows = _read(bag)                               # rosbags: the summary is there
    ticks = int(err.split('published ')[1].split(' ticks')[0])
    assert sum(t == '/attitude' for t, _, _ in rows) == ticks > 0
