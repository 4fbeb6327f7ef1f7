"""BagWriter.write_chunk: records built in arrays, the file of write_many then flush."""

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from mcap.reader import make_reader
import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from rigidrot_ros.bag import BagWriter
from rigidrot_ros.bag.chunks import fill_records, record_dtype

TOPICS = {'/a': 'geometry_msgs/msg/Vector3Stamped', '/b': 'sensor_msgs/msg/Imu',
          '/c': 'std_msgs/msg/String'}


def _blocks(seed=7):
    """Blocks of messages: ``[(topic, payload, log ns), ...]`` each, log times rising."""
    rng = np.random.default_rng(seed)
    blocks, t = [], 10 ** 9
    for n in (1, 40, 3, 900, 25):
        block = []
        for _ in range(n):
            topic = ['/a', '/b', '/c'][int(rng.integers(0, 3))]
            size = {'/a': 52, '/b': 324, '/c': int(rng.integers(5, 3000))}[topic]
            t += int(rng.integers(0, 2_000_000))
            block.append((topic, bytes(rng.integers(0, 256, size, dtype=np.uint8)), t))
        blocks.append(block)
    return blocks


def _records(writer, block):
    """Build a block's records as the generator does: one record array per message."""
    parts, offsets, at = [], [], 0
    for topic, data, log in block:
        rows = np.empty(1, dtype=record_dtype([len(data)]))
        fill_records(rows, 0, writer.channel_id(topic), writer.sequence(topic) +
                     sum(1 for t, _, _ in block[:len(parts)] if t == topic),
                     np.array([log]), np.frombuffer(data, dtype=np.uint8)[None, :])
        parts.append(rows.tobytes())
        offsets.append(at)
        at += len(parts[-1])
    return (b''.join(parts), [writer.channel_id(t) for t, _, _ in block],
            [log for _, _, log in block], offsets)


def _write(path, mode, offload):
    pool = ThreadPoolExecutor(max_workers=1) if offload else None
    w = BagWriter(None, 'x', flush_period=1e9, path=path, split_seconds=0.0,
                  offload=pool.submit if pool else None)
    for topic, type_name in TOPICS.items():
        w.add_topic(topic, type_name)
    for i, block in enumerate(_blocks()):
        if i == 2:              # a message held open by write(): write_chunk closes it too
            w.write('/a', b'\x00\x01\x00\x00' + bytes(48), block[0][2] - 1)
        if i == 3:
            w.add_run({'index': 1, 'note': 'between two chunks'})
        if mode == 'write_many':
            w.write_many(*zip(*block))
            w.flush()
        else:
            w.write_chunk(*_records(w, block))
    w.close()
    if pool:
        pool.shutdown()
    return {f.name: f.read_bytes() for f in Path(path).iterdir()}


@pytest.mark.parametrize('offload', [False, True], ids=['inline', 'offload'])
def test_write_chunk_writes_the_bytes_of_write_many_and_flush(tmp_path, offload):
    want = _write(tmp_path / 'many' / 'bag', 'write_many', False)
    got = _write(tmp_path / 'chunk' / 'bag', 'write_chunk', offload)
    assert got == want                              # the .mcap and metadata.yaml, bytes
    blocks = _blocks()
    expect = [m for b in blocks for m in b]
    with open(tmp_path / 'chunk' / 'bag' / 'bag_0.mcap', 'rb') as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        seen = [(ch.topic, bytes(m.data), m.log_time)
                for _, ch, m in reader.iter_messages(log_time_order=False)]
    assert len(summary.chunk_indexes) == len(blocks)
    assert [s for s in seen if s[1] != b'\x00\x01\x00\x00' + bytes(48)] == expect
    with AnyReader([tmp_path / 'chunk' / 'bag']) as reader:
        rows = [(c.topic, bytes(raw), ts) for c, ts, raw in reader.messages()]
    assert sorted(rows) == sorted(seen)


def test_write_chunk_refuses_mismatched_arrays(tmp_path):
    w = BagWriter(None, 'x', path=tmp_path / 'b', split_seconds=0.0)
    w.add_topic('/a', TOPICS['/a'])
    with pytest.raises(ValueError, match='one channel, one stamp and one offset'):
        w.write_chunk(b'', [1, 1], [0], [0, 10])
    w.close()
