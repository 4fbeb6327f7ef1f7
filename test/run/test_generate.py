"""rigidrot_generate: byte identity with the recording node, streaming, SIGINT, bad input."""

import os
from pathlib import Path
import signal
import subprocess
import time

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader

from rigidrot_ros.run.generate import generate_bag, GenerationError, iter_run
from ros_helpers import next_domain_id, ros_env, script, start, stop, wait_for
from run_helpers import canonical, payloads as _payloads

SENSORS = ['-p', 'imu.enable:=true', '-p', 'imu.rate:=200.0', '-p', 'imu.seed:=11',
           '-p', 'star_tracker.enable:=true', '-p', 'star_tracker.seed:=5']
TRUTH = ['-p', 'odom.enable:=true', '-p', 'transform.enable:=true']
#: accelerometer (gravity, lever arm, every error term of note, both increment quanta: the
#: measured increments published) and magnetometer, with every sensor's timing model on:
#: latency, stamp jitter, drops, clock offset
ACCEL_MAG = [
    '-p', 'accel.enable:=true', '-p', 'accel.gravity:=[0.0, 0.0, -9.80665]',
    '-p', 'accel.lever_arm:=[0.1, -0.05, 0.2]', '-p', 'accel.noise_density:=0.002',
    '-p', 'accel.random_walk:=0.0001', '-p', 'accel.scale_factor:=[0.001, -0.002, 0.0005]',
    '-p', 'accel.bias_instability:=0.001', '-p', 'accel.increment_quantum:=0.00001',
    '-p', 'imu.gyro_increment_quantum:=1.0e-7',
    '-p', 'mag.enable:=true', '-p', 'mag.rate:=50.0', '-p', 'mag.noise_density:=1.0e-8',
    '-p', 'mag.hard_iron:=[1.0e-6, 0.0, -2.0e-6]', '-p', 'mag.seed:=9',
    '-p', 'imu.latency:=0.003', '-p', 'imu.stamp_jitter:=0.0001',
    '-p', 'imu.drop_probability:=0.1', '-p', 'imu.clock_offset:=0.25',
    '-p', 'star_tracker.latency:=0.05', '-p', 'star_tracker.drop_probability:=0.2',
    '-p', 'star_tracker.clock_offset:=-0.002',
    '-p', 'mag.latency:=0.01', '-p', 'mag.stamp_jitter:=0.0002',
    '-p', 'mag.drop_probability:=0.15', '-p', 'mag.clock_offset:=-0.5',
]
#: the torque-free triaxial preset (config/torque_free_triaxial.yaml): its own model
TRIAXIAL = ['-p', 'inertia:=[1.0, 2.0, 3.0]', '-p', 'torque:=[0.0, 0.0, 0.0]',
            '-p', 'omega0:=[0.02, 1.0, 0.03]']


def _values(args):
    from rigidrot_ros.run.generate import parse_override
    return dict(parse_override(a) for a in args[1::2])


#: truth and gyro at 2 kHz: the node publishes through its pacer (ros/pacing.py); the
#: gyro's timing model on (its latency moves a sample to a later slot of the pacer)
PACED = ['-p', 'publish_rate:=2000.0', '-p', 'imu.rate:=2000.0',
         '-p', 'imu.latency:=0.0013', '-p', 'imu.stamp_jitter:=0.0001',
         '-p', 'imu.drop_probability:=0.1', '-p', 'imu.clock_offset:=0.25']


@pytest.mark.parametrize('extra', [[], ACCEL_MAG, TRIAXIAL, PACED],
                         ids=['gyro-star', 'accel-mag-timing', 'triaxial-gyro-star',
                              'gyro-star-2khz-paced'])
def test_generated_bag_matches_the_recording_node(tmp_path, extra):
    env = ros_env(next_domain_id())
    root = tmp_path / 'runs'
    node = start([script('attitude_node'), '--ros-args', '-p', 'record:=true',
                  '-p', f'record_path:={root}', *SENSORS, *TRUTH, *extra], env)
    assert wait_for(lambda: root.exists() and any(root.iterdir()), timeout=60)
    time.sleep(3.0)
    code, _, err = stop(node, signal.SIGINT)
    assert code == 0 and 'Traceback' not in err, err
    assert ('publishing through the pacer' in err) == (extra is PACED), err
    recorded, run = _payloads(next(root.iterdir()))
    start_ns = run['start_ns']
    last = max(recorded['/attitude'])           # the truth's stamps carry no timing model
    duration = (last - start_ns) * 1e-9 + 0.5
    gen = generate_bag(_values(SENSORS + TRUTH + extra), duration, tmp_path / 'gen',
                       start_ns=start_ns)
    generated, gen_run = _payloads(gen)
    assert gen_run == run                       # the run description, field for field
    assert set(generated) == set(recorded)
    missing = {t: [ns for ns in got if ns not in generated[t]] for t, got in recorded.items()}
    assert not any(missing.values()), missing   # every recorded stamp is generated
    types = _payloads.types
    report = {}
    for topic, got in recorded.items():
        if topic.endswith('/run'):
            continue
        differ = [ns for ns, raw in got.items()
                  if canonical(raw, types[topic]) != canonical(generated[topic][ns],
                                                               types[topic])]
        report[topic] = (len(got) - len(differ), len(got))
        assert not differ, (topic, report)   # every value byte, every topic
    print('identical samples per topic (node, generated):', report)
    # the node delivered most of its grid (a loaded machine may miss a few ticks)
    assert len(recorded['/attitude']) >= 0.8 * len(generated['/attitude'])
    assert len(recorded['/imu']) >= 0.8 * len(generated['/imu'])
    if extra is TRIAXIAL:
        assert run['model'] == 'torque-free-triaxial', run
    if extra is ACCEL_MAG:
        assert {'/delta_velocity', '/mag', '/delta_angle_measured',
                '/delta_velocity_measured'} <= set(recorded)
        # the same drops: within the span the node recorded, the generator has no sample
        # the node left out, but for a skip (a backlog beyond a second: a process held
        # that long on a loaded machine), which leaves out a second or more at once
        for topic in ('/imu', '/delta_velocity', '/star_tracker', '/mag'):
            lo, hi = min(recorded[topic]), max(recorded[topic])
            inside = sorted(ns for ns in generated[topic] if lo <= ns <= hi)
            gaps = _left_out(inside, recorded[topic])
            assert all(last - first >= 0.9e9 for first, last in gaps), (topic, gaps)
        _check_timing(generated, start_ns, run['sensor_timing'])
    # the generated bytes are canonical CDR (padding zero), message by message
    for topic, got in generated.items():
        if not topic.endswith('/run'):
            assert all(canonical(raw, types[topic]) == raw for raw in got.values()), topic


def _left_out(inside, recorded):
    """Return the runs of ``inside`` (sorted stamps) missing from ``recorded``: (first, last)."""
    runs, run = [], None
    for ns in inside:
        if ns in recorded:
            run = None
        elif run is None:
            run = [ns, ns]
            runs.append(run)
        else:
            run[1] = ns
    return [tuple(r) for r in runs]


def _check_timing(bag, start_ns, timing):
    """The generated stamps carry the models of ``~/run``: offset, jitter, drop rate."""
    for topic, name, rate in (('/imu', 'imu', 200.0), ('/mag', 'mag', 50.0),
                              ('/star_tracker', 'star_tracker', 10.0)):
        t = timing[name]
        stamps = np.array(sorted(bag[topic]), dtype=np.int64) - start_ns
        shifted = stamps - round(t['clock_offset_s'] * 1e9)
        k = np.rint(shifted * rate * 1e-9)
        resid = shifted - np.rint(k * 1e9 / rate)
        if t['stamp_jitter_s'] > 0:
            assert np.std(resid) == pytest.approx(t['stamp_jitter_s'] * 1e9, rel=0.35)
        else:
            assert not np.any(resid), topic
        first = 1 if name == 'imu' else 0
        grid = k.max() - first + 1
        kept = len(stamps) / grid
        p = t['drop_probability']
        assert abs(kept - (1 - p)) <= 4 * np.sqrt(p * (1 - p) / grid) + 1e-9, (topic, kept)


@pytest.mark.parametrize('extra', [[], ACCEL_MAG], ids=['gyro-star', 'accel-mag-timing'])
def test_iter_run_gives_the_messages_of_the_bag(tmp_path, extra):
    values = _values(SENSORS + extra)
    items = list(iter_run(values, 1.0, start_ns=123))
    logs = [ns for _, ns, _ in items]
    assert logs == sorted(logs) and logs[0] == 123
    bag, _ = _payloads(generate_bag(values, 1.0, tmp_path / 'b', start_ns=123))
    types = _payloads.types
    assert sum(len(v) for v in bag.values()) == len(items)
    for topic, _, msg in items:
        ns = 0 if topic.endswith('/run') else \
            msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        assert canonical(serialize_message(msg), types[topic]) == bag[topic][ns], topic


def test_the_timing_models_in_the_generated_bag(tmp_path):
    """Stamps offset and jittered, drops at their rate, log time = grid time + latency."""
    start_ns = 10 ** 12
    values = _values(SENSORS + ACCEL_MAG)
    bag = generate_bag(values, 20.0, tmp_path / 'b', start_ns=start_ns)
    got, run = _payloads(bag)
    _check_timing(got, start_ns, run['sensor_timing'])
    rates = {'/imu': 200.0, '/mag': 50.0, '/star_tracker': 10.0, '/attitude': 100.0}
    with AnyReader([Path(bag)]) as reader:
        logs = [(c.topic, ts) for c, ts, _ in reader.messages()]
    assert [ts for _, ts in logs] == sorted(ts for _, ts in logs)      # in log-time order
    for topic, rate in rates.items():
        name = topic[1:]
        lat = round(run['sensor_timing'][name]['latency_s'] * 1e9) if name != 'attitude' \
            else 0
        ts = np.array([t for tp, t in logs if tp == topic]) - start_ns - lat
        assert np.array_equal(ts, np.rint(np.rint(ts * rate * 1e-9) * 1e9 / rate)), topic
        assert 19 * 10 ** 9 <= ts.max() < 20 * 10 ** 9, topic     # the span, to its end
    assert run['sensor_timing']['mag']['clock_offset_s'] == -0.5


def test_sigint_leaves_a_finished_readable_bag(tmp_path):
    out = tmp_path / 'long'
    proc = subprocess.Popen(
        [script('rigidrot_generate'), '-o', str(out), '--duration', '36000',
         '-p', 'imu.enable:=true', '-p', 'star_tracker.enable:=true'],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=dict(os.environ, PYTHONUNBUFFERED='1'))
    line = proc.stderr.readline()               # the first progress line
    assert 'scene s' in line, line + proc.stderr.read()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and 'Traceback' not in err, err
    assert 'interrupted' in err
    got, run = _payloads(out)                   # summary and metadata.yaml are there
    assert run['start_ns'] == 0 and len(got['/attitude']) >= 100
    assert (out / 'metadata.yaml').read_text().count('message_count') >= 8


@pytest.mark.parametrize('args, words', [
    (['-p', 'inertia:=[1.0, 2.0, 5.0]'], ['triangle inequality']),
    (['-p', 'imu.rat:=5.0'], ['imu.rat', 'did you mean imu.rate']),
    (['-p', 'tol:=5.0'], ['tol']),
    (['-p', 'omega0:=[.nan, 0.0, 1.0]'], ['omega0']),
    (['-p', 'imu.seed:=-3', '-p', 'imu.enable:=true'], ['seed']),
    (['--params-file', '/nonexistent.yaml'], ['/nonexistent.yaml']),
    (['--duration', '-1'], ['--duration']),
])
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, args, words):
    out = tmp_path / 'bag'
    cmd = [script('rigidrot_generate'), '-o', str(out)]
    if '--duration' not in args:
        cmd += ['--duration', '2']
    proc = subprocess.run(cmd + args, capture_output=True, text=True, timeout=120)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith('rigidrot_generate:')
    for w in words:
        assert w in lines[0], lines[0]
    assert not out.exists()


def test_api_refuses_before_writing(tmp_path):
    with pytest.raises(GenerationError, match='publish_rate'):
        generate_bag({'publish_rate': 0.0}, 1.0, tmp_path / 'x')
    with pytest.raises(GenerationError, match='start-ns'):
        next(iter_run({}, 1.0, start_ns=-1))
    assert not (tmp_path / 'x').exists()


def _bag_bytes(path):
    return {f.name: f.read_bytes() for f in Path(path).iterdir()}


def test_write_many_writes_the_bytes_of_write_one_by_one(tmp_path):
    """BagWriter.write_many (the generator's writer) against write: the same .mcap file."""
    from rigidrot_ros.bag import BagWriter
    rng = np.random.default_rng(5)
    topics = ['/a', '/b', '/c']
    n = 700
    which = [topics[i] for i in rng.integers(0, 3, n)]
    datas = [bytes(rng.integers(0, 256, int(k), dtype=np.uint8)) for k in
             rng.integers(4, 200, n)]
    stamps = np.cumsum(rng.integers(0, 1000, n)).tolist()
    cuts = [0, 1, 2, 90, 91, 400, n]               # blocks of 1, 1, 88, 1, 309, 300
    out = {}
    for mode in ('write', 'write_many'):
        w = BagWriter(None, 'x', flush_period=1e9, path=tmp_path / mode, split_seconds=0.0)
        w._writer._Writer__chunk_size = 4096      # several chunks, closed mid-block
        for t in topics:
            w.add_topic(t, 'std_msgs/msg/String')
        for lo, hi in zip(cuts[:-1], cuts[1:]):
            if mode == 'write':
                for i in range(lo, hi):
                    w.write(which[i], datas[i], stamps[i])
            else:
                w.write_many(which[lo:hi], datas[lo:hi], stamps[lo:hi])
            if lo == 91:
                w.add_metadata('m', {'k': 'v'})    # closes the chunk in between
        w.close()
        out[mode] = _bag_bytes(tmp_path / mode)
    mcap_files = {mode: [v for k, v in out[mode].items() if k.endswith('.mcap')]
                  for mode in out}
    assert len(mcap_files['write']) == 1
    assert mcap_files['write'] == mcap_files['write_many']         # byte for byte
    yamls = {mode: out[mode]['metadata.yaml'].replace(mode.encode(), b'BAG') for mode in out}
    assert yamls['write'] == yamls['write_many']
    with AnyReader([tmp_path / 'write_many']) as reader:       # rosbags: an outside reader
        seen = sorted((ts, c.topic, bytes(raw)) for c, ts, raw in reader.messages())
    assert seen == sorted(zip(stamps, which, datas))


def test_vectorised_stamps_are_the_node_grid():
    """grid.stamps_ns (numpy) against grid.stamp_ns (Python ints), index by index."""
    from rigidrot_ros.run import grid
    rng = np.random.default_rng(3)
    for rate in [1000.0, 100.0, 10.0, 3.0, 7.3, 333.3, 999.9999] + list(rng.uniform(1, 2000, 5)):
        for origin in (0, 1_795_552_911_119_937_992):
            k0 = int(rng.integers(0, 4_000_000))
            ks = range(k0, k0 + 3000)
            want = [grid.stamp_ns(origin, rate, k) for k in ks]
            assert grid.stamps_ns(origin, rate, ks).tolist() == want, (rate, origin, k0)


def test_a_slow_machine_never_refuses_a_scene_offline(tmp_path, monkeypatch):
    """The node bounds the wall time of its first samples; generation judges them untimed.

    With every trial sample "too slow" (a limit of 0 s) the node's set-up refuses the scene,
    as on a heavily loaded machine; the generator writes the bag all the same.
    """
    import rigidrot_ros.run.settings as settings
    from rigidrot_ros.run import params
    values = {'imu.enable': True, 'accel.enable': True, 'star_tracker.enable': True,
              'mag.enable': True}
    monkeypatch.setattr(settings, 'TRIAL_LIMIT_S', 0.0)
    monkeypatch.setattr(settings, 'SAMPLE_BUDGET_S', 0.0)
    with pytest.raises(settings.TrialError, match='to evaluate'):
        settings.prepare_run(dict(params.defaults(), **values))
    path = generate_bag(values, 0.5, tmp_path / 'bag')
    with AnyReader([Path(path)]) as reader:
        topics = {c.topic for c in reader.connections if c.msgcount}
    assert {'/attitude', '/imu', '/delta_velocity', '/star_tracker', '/mag'} <= topics
