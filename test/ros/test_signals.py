"""Signals while a bag is being finished: it is finished whole, whatever arrives.

A ``kill -INT`` of ``timeout`` reaches the node twice within microseconds (directly and
through its group); a second SIGINT used to raise KeyboardInterrupt inside the final
``metadata.yaml`` write, leaving the initial one (``message_count: 0``) beside a complete
MCAP, which rosbags then read as empty.
"""

import os
from pathlib import Path
import signal
import sys
import textwrap
import time

import pytest
import yaml

from rigidrot_ros.ros.spin import SIGNAL_MERGE_S
from ros_helpers import next_domain_id, ros_env, script, start, wait_for


def _mcap_count(bag):
    """Messages in the bag's MCAP files, counted by the mcap library (not the metadata)."""
    from mcap.reader import make_reader
    n = 0
    for f in sorted(Path(bag).glob('*.mcap')):
        with open(f, 'rb') as fh:
            n += sum(1 for _ in make_reader(fh).iter_messages())
    return n


def _rosbags_count(bag):
    """Messages rosbags reads from the bag directory (its metadata.yaml), and its total."""
    from rosbags.highlevel import AnyReader
    with AnyReader([Path(bag)]) as reader:
        read = sum(1 for _ in reader.messages())
        listed = sum(c.msgcount for c in reader.connections)
    return read, listed


def _listed(bag):
    with open(Path(bag) / 'metadata.yaml', encoding='utf-8') as fh:
        return yaml.safe_load(fh)['rosbag2_bagfile_information']['message_count']


@pytest.fixture
def default_sigint():
    """Python's own SIGINT handler (KeyboardInterrupt), restored afterwards."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def _slow_dump(monkeypatch, module):
    """Make ``module``'s YAML dump send this process a SIGINT and take 0.2 s."""
    real = module.yaml.safe_dump
    calls = []

    def dump(*args, **kwargs):
        calls.append(1)
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)
        return real(*args, **kwargs)
    monkeypatch.setattr(module.yaml, 'safe_dump', dump)
    return calls


def test_a_ctrl_c_during_the_metadata_write_waits_for_it(tmp_path, monkeypatch, default_sigint):
    from rigidrot_ros.bag import metadata
    topics = {'/a': ('std_msgs/msg/String', metadata.qos_yaml())}
    calls = _slow_dump(monkeypatch, metadata)
    with pytest.raises(KeyboardInterrupt):
        metadata.write_metadata_yaml(str(tmp_path), ['b_0.mcap'], topics, {'/a': 7}, 1, 9)
    assert calls
    assert _listed(tmp_path) == 7
    assert os.listdir(tmp_path) == ['metadata.yaml']          # no .tmp left behind


def test_a_ctrl_c_while_a_bag_closes_leaves_it_whole(tmp_path, monkeypatch, default_sigint):
    from rigidrot_ros.bag import BagWriter, metadata
    from rigidrot_ros.msgs.cdr import vector
    import numpy as np
    writer = BagWriter(None, 'n', path=str(tmp_path / 'bag'))
    writer.add_topic('/v', 'geometry_msgs/msg/Vector3Stamped')
    stamps = np.arange(1, 501, dtype=np.int64) * 1_000_000
    writer.write_many(['/v'] * 500, vector(stamps, np.ones((500, 3)), 'b').tolist(),
                      stamps.tolist())
    _slow_dump(monkeypatch, metadata)       # the signal arrives in the final metadata.yaml
    with pytest.raises(KeyboardInterrupt):
        writer.close()
    monkeypatch.undo()
    bag = tmp_path / 'bag'
    assert _mcap_count(bag) == 500
    assert _rosbags_count(bag) == (500, 500)


#: attitude_node whose final metadata.yaml write says when it starts and takes a second, so
#: that signals sent then arrive inside it (the test's own instrument, not the node's).
SLOW_CLOSE = textwrap.dedent('''
    import sys, time
    import yaml
    from rigidrot_ros.bag import writer as w
    from rigidrot_ros.ros.attitude_node import main
    real_close, real_dump, closing = w.BagWriter.close, yaml.safe_dump, []

    def close(self):
        closing.append(1)
        return real_close(self)

    def dump(*args, **kwargs):
        if closing and args and isinstance(args[0], dict) and \\
                'rosbag2_bagfile_information' in args[0]:
            print('writing the final metadata.yaml', file=sys.stderr, flush=True)
            time.sleep(1.0)
        return real_dump(*args, **kwargs)
    w.BagWriter.close, yaml.safe_dump = close, dump
    sys.argv[0] = 'attitude_node'
    sys.exit(main())
''')


@pytest.mark.ros
@pytest.mark.parametrize('when', ['at once', 'while the bag is finished'])
def test_sigint_twice_then_sigterm_leave_every_bag_whole(tmp_path, when):
    """SIGINT twice within microseconds, then SIGTERM: exit 0, each bag read whole.

    'at once': as ``kill -INT`` of ``timeout`` does, while the node records. 'while the
    bag is finished': the three arrive during the final metadata.yaml write, the second
    SIGINT well after the first (a second request, raised after the bag is whole).
    """
    slow = when != 'at once'
    prog = [sys.executable, '-c', SLOW_CLOSE] if slow else \
        [str(Path(sys.executable).parent / 'attitude_node')]
    proc = start(prog + ['--ros-args', '-p', 'imu.enable:=true', '-p', 'imu.rate:=400.0',
                         '-p', 'record:=true', '-p', f'record_path:={tmp_path}'],
                 ros_env(next_domain_id()), start_new_session=True)
    err_lines = []
    try:
        assert wait_for(lambda: list(tmp_path.glob('*/*.mcap'))
                        and list(tmp_path.glob('*/*.mcap'))[0].stat().st_size > 8192,
                        timeout=60), 'the node did not record'
        proc.send_signal(signal.SIGINT)
        if slow:                # the node's stderr until its final write begins
            for line in proc.stderr:
                err_lines.append(line)
                if 'writing the final metadata.yaml' in line:
                    break
        proc.send_signal(signal.SIGINT)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    err = ''.join(err_lines) + err
    assert proc.returncode == 0, err[-3000:]
    assert 'Traceback' not in err and 'bag finished' in err, err[-3000:]
    bags = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert bags
    for bag in bags:
        n = _mcap_count(bag)
        assert n > 100
        assert _rosbags_count(bag) == (n, n)
        assert _listed(bag) == n
        assert not list(bag.glob('*.tmp'))


@pytest.mark.ros
def test_signals_that_keep_coming_while_the_node_exits_leave_its_status_0(tmp_path):
    """SIGINT, then SIGTERM every millisecond until the node is gone: exit 0, bag whole.

    A signal that arrives after the clean-up, while the process exits, used to find the
    default action (rclpy puts back what it found for SIGTERM; Python's finalisation does
    so for SIGINT) and end a node that had finished its bag by that signal. A second SIGINT
    inside the merge window goes along, as ``kill -INT`` of ``timeout`` sends it.
    """
    proc = start([script('attitude_node'), '--ros-args', '-p', 'imu.enable:=true',
                  '-p', 'record:=true', '-p', f'record_path:={tmp_path}'],
                 ros_env(next_domain_id()), start_new_session=True)
    try:
        assert wait_for(lambda: list(tmp_path.glob('*/*.mcap'))
                        and list(tmp_path.glob('*/*.mcap'))[0].stat().st_size > 8192,
                        timeout=60), 'the node did not record'
        first = time.monotonic()
        proc.send_signal(signal.SIGINT)
        sent = 1
        while proc.poll() is None and time.monotonic() - first < 60:
            late = time.monotonic() - first
            if late < SIGNAL_MERGE_S * 0.5 and sent == 1:
                proc.send_signal(signal.SIGINT)
            proc.send_signal(signal.SIGTERM)
            sent += 1
            time.sleep(0.001)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert sent > 10, f'only {sent} signals were sent before it exited'
    assert proc.returncode == 0, err[-3000:]
    assert 'Traceback' not in err and 'bag finished' in err, err[-3000:]
    (bag,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    n = _mcap_count(bag)
    assert n > 10 and _rosbags_count(bag) == (n, n) and _listed(bag) == n


def test_the_merge_window_is_documented():
    """The window is said in the node's page in the same number."""
    from rigidrot_ros.ros.spin import SIGNAL_MERGE_S
    text = (Path(__file__).resolve().parents[2] / 'doc' / 'node.md').read_text()
    assert f'{SIGNAL_MERGE_S:g} s' in text and 'one request' in text
