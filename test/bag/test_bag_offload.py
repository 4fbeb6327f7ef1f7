"""BagWriter(offload=...): chunks written off the caller's thread, the same file, nothing lost."""

import os
from pathlib import Path
import struct
import threading
import time

from mcap.reader import make_reader
import pytest
from rosbags.highlevel import AnyReader

from record_helpers import _Disk, _Thread
from rigidrot_ros.bag import BagWriter, read_bag
from rigidrot_ros.bag import chunks
from rigidrot_ros.bag.metadata import MAX_PENDING_CHUNKS
from rigidrot_ros.runtime.worker import BatchWorker

_NEVER = 1e9                    # no flush by the clock: chunks close by size and by flush()


def _cdr_string(text):
    """CDR (little endian) of a std_msgs/String, built by hand."""
    raw = text.encode() + b'\x00'
    return b'\x00\x01\x00\x00' + struct.pack('<I', len(raw)) + raw


def _payload(i):
    return _cdr_string(f'message {i} ' + 'abcdefghij'[i % 10] * (200 + 37 * (i % 29)))


def _scenario(writer, n=3000):
    """Writes, size-closed chunks, explicit flushes, a reset's metadata, file splits."""
    writer.add_topic('/a', 'std_msgs/msg/String')
    writer.add_topic('/b', 'std_msgs/msg/String')
    expect = []
    flushes, reset = [400, 410, 1195, 2500], 1201
    i = 0
    while i < n:
        if i % 7 == 0:                              # the batched path
            topics = ['/a', '/b', '/a']
            datas = [_payload(i + k) for k in range(3)]
            stamps = [10**9 + (i + k) * 10**6 for k in range(3)]
            writer.write_many(topics, datas, stamps)
            expect += list(zip(topics, stamps, datas))
            i += 3
        else:
            data, stamp = _payload(i), 10**9 + i * 10**6
            writer.write('/a' if i % 3 else '/b', data, stamp)
            expect.append(('/a' if i % 3 else '/b', stamp, data))
            i += 1
        if flushes and i >= flushes[0]:
            flushes.pop(0)
            writer.flush()
        if reset is not None and i >= reset:        # a ~/reset: metadata, then a flush
            reset = None
            writer.add_run({'index': 2, 'note': 'a reset half way', 'start_ns': i})
    return expect


def _bag(tmp_path, name, offload=None, split=True):
    # split_seconds tiny: every flush of a file with messages starts the next file at the
    # next write (the same flushes for both writers: explicit ones only)
    return BagWriter(str(tmp_path), name, flush_period=_NEVER, path=str(tmp_path / name),
                     split_seconds=1e-9 if split else 0, offload=offload)


def _mcaps(path):
    files = sorted(Path(path).glob('*.mcap'), key=lambda p: int(p.stem.rsplit('_', 1)[1]))
    return [p.read_bytes() for p in files]


def _rosbags(path):
    with AnyReader([Path(path)]) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


def _mcap_reader(path):
    rows, meta = [], []
    files = sorted(Path(path).glob('*.mcap'), key=lambda p: int(p.stem.rsplit('_', 1)[1]))
    for p in files:
        with open(p, 'rb') as fh:
            reader = make_reader(fh)
            meta += [m.name for m in reader.iter_metadata()]
            rows += [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages()]
    return rows, meta


@pytest.mark.parametrize('split', [True, False])
def test_an_offloaded_writer_writes_the_inline_writers_bytes(tmp_path, split):
    inline = _bag(tmp_path, 'inline', split=split)
    want = _scenario(inline)
    inline.close()
    worker = _Thread(delay=0.02)                    # chunks stay in flight a while
    offloaded = _bag(tmp_path, 'offload', offload=worker, split=split)
    worker.writer = offloaded
    got = _scenario(offloaded)
    offloaded.close()
    worker.stop()
    assert got == want
    assert worker.most >= 1                         # a chunk was in flight at a later close
    a, b = _mcaps(inline.path), _mcaps(offloaded.path)
    assert len(a) == len(b) == (6 if split else 1)  # split into files, or not
    assert a == b                                   # byte for byte, file by file
    for path in (inline.path, offloaded.path):
        assert _rosbags(path) == want               # every message, in order
        rows, meta = _mcap_reader(path)
        assert sorted(rows, key=lambda r: r[1]) == want
        assert meta == ['rigidrot_run']
    assert read_bag(offloaded.path).runs[0]['note'] == 'a reset half way'


def test_a_stopped_worker_or_a_raising_offload_writes_inline_and_loses_nothing(tmp_path):
    inline = _bag(tmp_path, 'inline')
    want = _scenario(inline, 1500)
    inline.close()
    stopped = BatchWorker()
    stopped.stop()
    calls = []

    def flaky(fn):                                  # every other call refused
        calls.append(fn)
        if len(calls) % 2:
            raise RuntimeError('refused')
        fn()
    for name, offload in (('stopped', stopped.call), ('flaky', flaky)):
        writer = _bag(tmp_path, name, offload=offload)
        assert _scenario(writer, 1500) == want
        writer.close()
        assert _mcaps(writer.path) == _mcaps(inline.path)
        assert _rosbags(writer.path) == want
    assert len(calls) >= 3                          # refused and taken


def test_a_disk_error_of_an_offloaded_write_surfaces_at_the_next_call(tmp_path):
    worker = _Thread()
    writer = BagWriter(str(tmp_path), 'full', flush_period=_NEVER, offload=worker)
    disk = _Disk.under(writer)
    writer.add_topic('/a', 'std_msgs/msg/String')
    sent = []
    for i in range(300):
        writer.write('/a', _payload(i), 10**9 + i)
        sent.append(_payload(i))
        if i in (99, 199):
            writer.flush()
    while writer._pending:
        time.sleep(0.01)
    disk.full = True
    writer.flush()                                  # the chunk of messages 200..299 fails
    worker.calls.put(lambda: None)
    while writer._error is None:
        time.sleep(0.01)
    with pytest.raises(OSError, match='No space left'):
        writer.write('/a', _payload(300), 10**9 + 300)
    writer.write('/a', _payload(301), 10**9 + 301)  # reported once, as the inline error
    disk.full = False
    writer.close()
    worker.stop()
    got = [raw for _, _, raw in _rosbags(writer.path)]
    assert got == sent[:200] + [_payload(301)]       # the failed chunk alone is lost


def test_an_unreported_error_is_raised_by_close_which_still_finishes_the_file(tmp_path):
    worker = _Thread()
    writer = BagWriter(str(tmp_path), 'full', flush_period=_NEVER, offload=worker)
    disk = _Disk.under(writer)
    writer.add_topic('/a', 'std_msgs/msg/String')
    for i in range(100):
        writer.write('/a', _payload(i), 10**9 + i)
    writer.flush()
    while writer._pending:
        time.sleep(0.01)
    disk.full = True
    writer.write('/a', _payload(100), 10**9 + 100)
    writer.flush()
    while writer._error is None:
        time.sleep(0.01)
    disk.full = False
    with pytest.raises(OSError, match='No space left'):
        writer.close()
    worker.stop()
    assert writer.closed
    assert [raw for _, _, raw in _rosbags(writer.path)] == [_payload(i) for i in range(100)]


def test_writes_never_wait_for_a_chunk_being_written_and_close_waits_for_it(tmp_path):
    release = threading.Event()
    worker = _Thread()
    writer = BagWriter(str(tmp_path), 'slow', flush_period=_NEVER, offload=worker)
    worker.writer = writer
    worker.calls.put(release.wait)                  # the disk stalls: nothing written yet
    writer.add_topic('/a', 'std_msgs/msg/String')
    done = threading.Event()

    def caller():
        for i in range(300):
            writer.write('/a', _payload(i), 10**9 + i)
            if i % 100 == 99:
                writer.flush()                      # three chunks detached, none written
        done.set()
    thread = threading.Thread(target=caller, daemon=True)
    thread.start()
    assert done.wait(30)                            # the writes went on regardless
    assert len(writer._pending) == 3
    size = os.path.getsize(os.path.join(writer.path, writer.file_name))
    closer = threading.Thread(target=writer.close, daemon=True)
    closer.start()
    time.sleep(0.2)
    release.set()                                   # close wrote them (or the worker did)
    closer.join(30)
    worker.stop()
    assert not closer.is_alive() and writer.closed and not writer._pending
    assert os.path.getsize(os.path.join(writer.path, writer.file_name)) > size
    assert [raw for _, _, raw in _rosbags(writer.path)] == [_payload(i) for i in range(300)]


def test_at_most_a_few_chunks_wait_then_the_caller_writes_them(tmp_path):
    held = []
    writer = BagWriter(str(tmp_path), 'held', flush_period=_NEVER, offload=held.append)
    writer.add_topic('/a', 'std_msgs/msg/String')
    most = 0
    for i in range(1000):
        writer.write('/a', _payload(i), 10**9 + i)
        if i % 50 == 49:
            writer.flush()                          # an offload that never runs its calls
            most = max(most, len(writer._pending))
    assert most == MAX_PENDING_CHUNKS
    writer.close()
    assert [raw for _, _, raw in _rosbags(writer.path)] == [_payload(i) for i in range(1000)]
    for fn in held:                                 # run late: nothing left to write
        fn()
    assert not writer._pending


def test_without_offload_no_chunk_is_detached(tmp_path, monkeypatch):
    def never(*args):
        raise AssertionError('an inline writer detached a chunk')
    monkeypatch.setattr(chunks, 'write_detached', never)
    writer = _bag(tmp_path, 'plain')
    want = _scenario(writer, 600)
    writer.close()
    assert _rosbags(writer.path) == want
