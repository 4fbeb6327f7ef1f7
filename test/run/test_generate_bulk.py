"""generate_bag's bulk writer: the bytes of the block-by-block writer, read back by others.

The reference is the generator as it was before the bulk path: each block of
``BLOCK_S`` evaluated alone, every message serialized as ``bytes`` by its kind, merged,
written with ``BagWriter.write_many`` (the run description's metadata record before
the rest of its block) and flushed. :func:`generate_bag` evaluates several blocks at
once, builds the MCAP records in arrays and writes each chunk whole on a thread of its
own: the file must be the same, byte for byte, and ``mcap`` and ``rosbags`` (readers
the project did not write) must read every message of it.
"""

import math
from pathlib import Path

from mcap.reader import make_reader
import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from rigidrot_ros.bag import BagWriter
from rigidrot_ros.run import generate as gen

#: A gyro with both increments, a star tracker, the truth with every output (markers
#: with variable-free but long CDR), the accelerometer and magnetometer, every sensor's
#: timing model (latency, jitter, drops, clock offset), a clock start far from 0.
FULL = {
    'imu.enable': True, 'imu.rate': 200.0, 'imu.seed': 11, 'star_tracker.enable': True,
    'star_tracker.seed': 5, 'odom.enable': True, 'transform.enable': True,
    'markers.enable': True, 'accel.enable': True, 'accel.lever_arm': [0.1, -0.05, 0.2],
    'accel.noise_density': 0.002, 'accel.increment_quantum': 1e-5,
    'imu.gyro_increment_quantum': 1e-7, 'mag.enable': True, 'mag.rate': 50.0,
    'mag.seed': 9, 'imu.latency': 0.003, 'imu.stamp_jitter': 1e-4,
    'imu.drop_probability': 0.1, 'imu.clock_offset': 0.25, 'star_tracker.latency': 0.05,
    'star_tracker.drop_probability': 0.2, 'mag.latency': 0.01, 'mag.drop_probability': 0.15,
}
#: 4 kHz with both increments: blocks of about 1.9 MB, so chunks close past 1 MiB inside
#: a block; a latency of 1.7 s (blocks past the span), the triaxial torque-free model.
FAST = {'imu.enable': True, 'imu.rate': 4000.0, 'publish_rate': 1000.0,
        'star_tracker.enable': True, 'imu.latency': 1.7, 'inertia': [1.0, 2.0, 3.0],
        'torque': [0.0, 0.0, 0.0], 'omega0': [0.02, 1.0, 0.03]}
#: A truth rate off the 1 s grid and a scaled scene clock.
SLOW = {'publish_rate': 3.0, 'time_scale': 2.5}


def _reference_bag(values, duration_s, out_dir, start_ns):
    """Write the bag block by block, as the generator did before its bulk path."""
    run = gen._Run(values, duration_s, start_ns)
    qos, latched = gen._qos_yamls(run.p)
    writer = BagWriter(None, 'attitude_node', flush_period=math.inf, path=out_dir,
                       split_seconds=0.0)
    for topic, type_name, is_latched, _ in run.topics:
        writer.add_topic(topic, type_name, latched if is_latched else qos)
    for _, _, parts in run.blocks():
        topics, datas, stamps = gen._merged(parts, [gen._serialized(run, p) for p in parts])
        cut = topics.index(gen.RUN_TOPIC) if gen.RUN_TOPIC in topics else len(topics)
        writer.write_many(topics[:cut], datas[:cut], stamps[:cut])
        if cut < len(topics):
            writer.add_run(run.description())
            writer.write_many(topics[cut:], datas[cut:], stamps[cut:])
        writer.flush()
    writer.close()
    return writer.path


def _files(path):
    """The bag directory's files by name."""
    return {f.name: f.read_bytes() for f in Path(path).iterdir()}


@pytest.mark.parametrize('values, duration, start_ns', [
    (FULL, 12.5, 1_795_552_911_119_937_992), (FAST, 3.2, 123), (SLOW, 7.3, 5)],
    ids=['every-output-timing', 'chunks-past-1MiB-latency', 'off-grid-rate-scaled'])
def test_bulk_bag_is_the_block_by_block_bag(tmp_path, monkeypatch, values, duration,
                                            start_ns):
    monkeypatch.setattr(gen, 'EVAL_BLOCKS', 4)      # spans of 4 blocks: several per run
    got = generate_bulk = gen.generate_bag(values, duration, tmp_path / 'bulk' / 'bag',
                                           start_ns=start_ns)
    want = _reference_bag(values, duration, tmp_path / 'blocks' / 'bag', start_ns)
    assert _files(got) == _files(want)              # the .mcap and metadata.yaml, bytes
    mcap_path = next(Path(generate_bulk).glob('*.mcap'))
    with open(mcap_path, 'rb') as fh:               # mcap's reader: summary, indexes, crcs
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        seen = [(ch.topic, m.log_time, m.sequence, bytes(m.data))
                for _, ch, m in reader.iter_messages(log_time_order=False)]
    assert summary.statistics.message_count == len(seen)
    if values is FAST:
        sizes = [c.uncompressed_size for c in summary.chunk_indexes]
        assert max(sizes) > 1 << 20 and len(sizes) > math.ceil(duration + 1.7)
    # the messages of the run, in the order it publishes them, and their sequence numbers
    items = list(gen.iter_serialized(values, duration, start_ns=start_ns))
    assert [(t, ns, d) for t, ns, _, d in seen] == items
    count = {}
    for topic, _, sequence, _ in seen:
        assert sequence == count.get(topic, 0)
        count[topic] = sequence + 1
    with AnyReader([Path(generate_bulk)]) as reader:   # rosbags: the rosbag2 view
        rows = [(c.topic, ts, bytes(raw)) for c, ts, raw in reader.messages()]
        assert {c.topic: c.msgcount for c in reader.connections} == count
    assert sorted(rows) == sorted(items)


def test_a_sample_that_fails_writes_the_blocks_before_it(tmp_path, monkeypatch):
    """The error of a sample is raised after every block before its own is written."""
    from rigidrot_ros.run.imu_output import ImuOutput
    read = ImuOutput.read
    bad_t = 5.4321                                  # scene s: in block 5 (of 1 s)

    def failing(self, times, budget=None):
        cols, errors = read(self, times, budget)
        ends = np.asarray(times)[1:]
        return cols, [RuntimeError('no bound') if t >= bad_t else e
                      for t, e in zip(ends.tolist(), errors)]
    monkeypatch.setattr(ImuOutput, 'read', failing)
    monkeypatch.setattr(gen, 'EVAL_BLOCKS', 4)
    values = {'imu.enable': True, 'imu.rate': 100.0}
    with pytest.raises(gen.GenerationError, match=r'imu sample 544 .*no bound'):
        gen.generate_bag(values, 9.0, tmp_path / 'b')
    with AnyReader([tmp_path / 'b']) as reader:
        logs = [ts for _, ts, _ in reader.messages()]
    assert logs and max(logs) < 5 * 10 ** 9 <= max(logs) + 10 ** 8
