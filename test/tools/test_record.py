"""Record -> replay -> compare, as users run it, checked with readers we did not write."""

import json
import os
from pathlib import Path
import re
import signal
import sys
import textwrap
import time

from mcap.reader import make_reader
import pytest
from rosbags.highlevel import AnyReader
import yaml

from rigidrot_ros.bag import BagWriter, read_bag
from ros_helpers import next_domain_id, ros_env, script, start, stop, wait_for

pytestmark = pytest.mark.ros

# plays the estimator: republishes each attitude rotated by 0.01 rad about a fixed body axis
ESTIMATOR = textwrap.dedent('''
    import math, sys, time
    import rclpy
    from geometry_msgs.msg import QuaternionStamped
    rclpy.init()
    node = rclpy.create_node('estimator')
    pub = node.create_publisher(QuaternionStamped, '/estimator/attitude', 100)
    h = 0.005                       # half of 0.01 rad, about the unit axis (0.6, 0, 0.8)
    d = (0.6 * math.sin(h), 0.0, 0.8 * math.sin(h), math.cos(h))
    def cb(m):
        if not pub.get_subscription_count():
            return                  # not matched yet: no recorder could have this answer
        x, y, z, w = m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w
        bx, by, bz, bw = d
        out = QuaternionStamped()
        out.header = m.header
        out.quaternion.x = w * bx + x * bw + y * bz - z * by
        out.quaternion.y = w * by - x * bz + y * bw + z * bx
        out.quaternion.z = w * bz + x * by - y * bx + z * bw
        out.quaternion.w = w * bw - x * bx - y * by - z * bz
        pub.publish(out)
        print(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, time.monotonic(),
              flush=True)
    node.create_subscription(QuaternionStamped, '/attitude', cb, 100)
    end = time.monotonic() + float(sys.argv[1])
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
''')

# records everything it receives with arrival times (ns, monotonic) and the raw values
CAPTURE = textwrap.dedent('''
    import json, signal, sys, time
    import rclpy
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
    rclpy.init()
    node = rclpy.create_node('capture')
    got = []
    def add(kind):
        def cb(m):
            st = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            v = m.quaternion if kind == 'q' else m.vector
            vals = [v.x, v.y, v.z] + ([v.w] if kind == 'q' else [])
            got.append([kind, st, time.monotonic(), vals])
            heard[0] = time.monotonic()
            if len(got) == 1:
                print('first', flush=True)
        return cb
    node.create_subscription(QuaternionStamped, '/attitude', add('q'), 1000)
    node.create_subscription(Vector3Stamped, '/angular_velocity', add('w'), 1000)
    # until told that the publishers are done (SIGUSR1), then until 0.5 s pass with nothing
    # new (what was in flight); at most argv[1] s
    done, heard = [], [time.monotonic()]
    signal.signal(signal.SIGUSR1, lambda *_: done.append(time.monotonic()))
    print('ready', flush=True)
    end = time.monotonic() + float(sys.argv[1])
    while time.monotonic() < end and not (
            done and time.monotonic() - max(done[0], heard[0]) > 0.5):
        rclpy.spin_once(node, timeout_sec=0.01)
    print(json.dumps(got))
''')


def _captured(cap):
    """Tell a CAPTURE process that the publishers are done; the JSON list it prints last."""
    cap.send_signal(signal.SIGUSR1)
    return json.loads(cap.communicate(timeout=60)[0].splitlines()[-1])


def _record(tmp_path, env, seconds, sig=signal.SIGTERM, extra=(), cap=None):
    """Run attitude_node with recording for about ``seconds``, end it with ``sig``.

    With ``cap`` (a CAPTURE process), the seconds count from its first message: discovery
    on a loaded machine takes up to seconds.
    """
    root = tmp_path / 'runs'
    node = start([script('attitude_node'), '--ros-args', '-p', 'record:=true',
                  '-p', f'record_path:={root}', *extra], env)
    assert wait_for(lambda: root.exists() and any(root.iterdir()), timeout=60)
    if cap is not None:
        assert cap.stdout.readline().strip() == 'first'
    time.sleep(seconds)
    code, out, err = stop(node, sig)
    bags = sorted(root.iterdir())
    assert len(bags) == 1
    return bags[0], code, err


@pytest.fixture(scope='module')
def plain_bag(tmp_path_factory):
    """A finished bag of about 1.5 s of the default node, recorded once for the tests that
    only read it (replay, its clock, bad inputs beside it)."""
    tmp = tmp_path_factory.mktemp('plain')
    bag, code, err = _record(tmp, ros_env(next_domain_id()), 1.5)
    assert code == 0 and 'Traceback' not in err, err
    return bag


def test_round_trip_read_by_rosbags_and_mcap(tmp_path):
    env = ros_env(next_domain_id())
    cap = start([sys.executable, '-c', CAPTURE, '30'], env)
    assert cap.stdout.readline().strip() == 'ready'
    bag, code, err = _record(tmp_path, env, 2.5, cap=cap)
    assert code == 0 and 'Traceback' not in err, err
    published = int(re.search(r'published (\d+) ticks', err).group(1))
    got = _captured(cap)
    sent = {(k, st): vals for k, st, _, vals in got}
    # the independent reader: rosbags, on the bag directory (metadata.yaml + mcap)
    with AnyReader([bag]) as reader:
        conns = {c.topic: c for c in reader.connections}
        assert conns['/attitude'].msgtype == 'geometry_msgs/msg/QuaternionStamped'
        assert conns['/angular_velocity'].msgtype == 'geometry_msgs/msg/Vector3Stamped'
        assert conns['/attitude'].msgcount == conns['/angular_velocity'].msgcount == published
        qos = conns['/attitude'].ext.offered_qos_profiles
        assert qos and qos[0].depth == 10 and qos[0].reliability.name == 'RELIABLE'
        matched = 0
        for conn, _, raw in reader.messages():
            m = reader.deserialize(raw, conn.msgtype)
            if conn.topic == '/attitude_node/run':
                run = json.loads(m.data)           # the run description, as published
                assert run['rigidrot_run'] == 1 and run['scene']['inertia'] == [2, 2, 1]
                continue
            st = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
            if conn.topic == '/attitude':
                vals = [m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w]
                key = ('q', st)
                assert m.header.frame_id == 'inertial'
            else:
                vals = [m.vector.x, m.vector.y, m.vector.z]
                key = ('w', st)
                assert m.header.frame_id == 'body'
            if key in sent:
                assert vals == sent[key]          # bit for bit what was published
                matched += 1
    assert matched >= len(sent) - 4 and matched > 200
    # the mcap reader: ROS 2 profile, schemas, encodings, channel metadata
    mcap_file = next(bag.glob('*.mcap'))
    with open(mcap_file, 'rb') as fh:
        r = make_reader(fh)
        assert r.get_header().profile == 'ros2'
        summary = r.get_summary()
        assert {s.name for s in summary.schemas.values()} == {
            'geometry_msgs/msg/QuaternionStamped', 'geometry_msgs/msg/Vector3Stamped',
            'std_msgs/msg/String'}
        assert all(s.encoding == 'ros2msg' for s in summary.schemas.values())
        assert b'MSG: std_msgs/Header' in summary.schemas[1].data
        for ch in summary.channels.values():
            assert ch.message_encoding == 'cdr'
            prof = yaml.safe_load(ch.metadata['offered_qos_profiles'])[0]
            if ch.topic == '/attitude_node/run':
                assert prof['durability'] == 'transient_local' and prof['depth'] == 1
            else:
                assert prof['depth'] == 10 and prof['durability'] == 'volatile'
        assert summary.chunk_indexes and all(c.compression == 'zstd'
                                             for c in summary.chunk_indexes)
        runs = [m for m in r.iter_metadata() if m.name == 'rigidrot_run']
        assert len(runs) == 1 and json.loads(runs[0].metadata['scene'])['inertia'] == [2, 2, 1]
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['storage_identifier'] == 'mcap' and meta['message_count'] == 2 * published + 1
    # compare on the node's own log: within tol
    out = _run(['rigidrot_compare', str(bag), '--json', str(tmp_path / 's.json'),
                '--plot', str(tmp_path / 's.png'), '--plot-truth'], env)
    assert out.returncode == 0, out.stderr
    summary = json.loads((tmp_path / 's.json').read_text())
    att = [t for t in summary['topics'] if t['topic'] == '/attitude'][0]
    assert att['count'] == published and att['max'] <= 1e-12
    assert (tmp_path / 's.png').stat().st_size > 10000


def _run(cmd, env, **kw):
    import subprocess
    return subprocess.run([script(cmd[0])] + cmd[1:], env=env, capture_output=True,
                          text=True, timeout=120, **kw)


def test_sigkill_loses_at_most_about_half_a_second(tmp_path):
    env = ros_env(next_domain_id())
    cap = start([sys.executable, '-c', CAPTURE, '30'], env)
    assert cap.stdout.readline().strip() == 'ready'
    bag, code, err = _record(tmp_path, env, 3.0, sig=signal.SIGKILL, cap=cap)
    assert code == -signal.SIGKILL
    got = _captured(cap)
    last_sent = max(st for k, st, _, _ in got if k == 'q')
    contents = read_bag(str(bag))
    assert contents.truncated
    stamps = [m[2] for m in contents.messages if m[0] == '/attitude']
    lost = (last_sent - max(stamps)) * 1e-9
    assert lost <= 0.6, f'lost {lost:.3f} s'        # 0.4 s flush period + 0.1 s timer
    out = _run(['rigidrot_compare', str(bag)], env)
    assert out.returncode == 0, out.stderr
    assert 'unfinished file' in out.stderr and 'Traceback' not in out.stderr


@pytest.mark.parametrize('typed', [True, False])
def test_compare_scores_a_perturbed_estimator(tmp_path, typed):
    """record_topics keeps an estimator from its first matched message; compare scores it.

    With its type given the topic is subscribed at the node's start; by name only, once
    the estimator's publisher appears in the graph. Either way the estimator answers only
    once its publisher has matched a subscription (what the recorder guarantees: a
    volatile message sent before the match is lost to every recorder), and every answer
    from the first is in the bag; the node's log says when its subscription matched.
    """
    from rigidrot_ros.scoring.score import extract_streams
    env = ros_env(next_domain_id())
    est = start([sys.executable, '-c', ESTIMATOR, '60'], env)
    root = tmp_path / 'runs'
    node = start([script('attitude_node'), '--ros-args', '-p', 'record:=true',
                  '-p', f'record_path:={root}',
                  '-p', "record_topics:=['/estimator/attitude%s', '/attitude']" % (
                      ':geometry_msgs/msg/QuaternionStamped' if typed else '')], env)
    first = est.stdout.readline()                # the estimator's first output (volatile)
    assert first.strip(), est.stderr.read()
    time.sleep(2.0)
    code, _, err = stop(node, signal.SIGTERM)
    _, est_out, _ = stop(est, signal.SIGINT)
    assert code == 0, err
    sent = [int(first.split()[0])] + [int(line.split()[0]) for line in est_out.splitlines()
                                      if line.strip()]
    bag = next(root.iterdir())
    streams, _ = extract_streams(read_bag(str(bag)), ['/estimator/attitude'])
    got = set(streams[0].stamps.tolist())
    assert 'matched /estimator/attitude (1 publisher)' in err, err
    assert sent[0] in got                            # from its very first answer
    assert set(sent[:-2]) <= got                     # (the last may cross the shutdown)
    # /attitude, listed too, is the node's own: written once per tick, not also raw
    counts = {}
    for m in read_bag(str(bag)).messages:
        counts[m[0]] = counts.get(m[0], 0) + 1
    assert counts['/attitude'] == counts['/angular_velocity']
    out = _run(['rigidrot_compare', str(bag), '--json', str(tmp_path / 'e.json')], env)
    assert out.returncode == 0, out.stderr
    topics = {t['topic']: t for t in json.loads((tmp_path / 'e.json').read_text())['topics']}
    est_score = topics['/estimator/attitude']
    assert est_score['count'] > 50
    assert abs(est_score['max'] - 0.01) <= 1e-6 and abs(est_score['rms'] - 0.01) <= 1e-6
    assert topics['/attitude']['max'] <= 1e-12
    # --truth: the same log against itself scores zero (to the interpolation's rounding)
    out = _run(['rigidrot_compare', str(bag), '--topic', '/attitude', '--truth', str(bag),
                '--json', str(tmp_path / 't.json')], env)
    assert out.returncode == 0, out.stderr
    self_score = json.loads((tmp_path / 't.json').read_text())['topics'][0]
    assert self_score['count'] > 50 and self_score['max'] <= 1e-15


@pytest.mark.parametrize('rate', [1.0, 2.0])
def test_replay_into_another_process(plain_bag, rate):
    bag = plain_bag
    original = [m for m in read_bag(str(bag)).messages]
    env2 = ros_env(next_domain_id())            # a quiet domain for the replay
    cap = start([sys.executable, '-c', CAPTURE, '30'], env2)
    assert cap.stdout.readline().strip() == 'ready'
    rep = _run(['rigidrot_replay', str(bag), '--rate', str(rate), '--quiet'], env2)
    assert rep.returncode == 0, rep.stderr
    got = _captured(cap)
    q_got = [g for g in got if g[0] == 'q']
    q_orig = [m for m in original if m[0] == '/attitude']
    assert [g[1] for g in q_got] == sorted(g[1] for g in q_got)        # same order
    assert len(q_got) >= len(q_orig) - 2
    # timing: arrival spacing follows the log spacing divided by the rate
    span_log = (q_orig[-1][2] - q_orig[0][2]) * 1e-9
    span_got = q_got[-1][2] - q_got[0][2]
    assert span_got == pytest.approx(span_log / rate, rel=0.1, abs=0.05)


def test_bad_inputs_get_one_line_and_status_2(tmp_path, plain_bag):
    env = ros_env(next_domain_id())
    empty = tmp_path / 'empty'
    empty.mkdir()
    text = tmp_path / 'notes.mcap'
    text.write_text('hello')
    # a finished bag without run records, with a topic of another type
    w = BagWriter(str(tmp_path / 'bags'), 'other')
    w.add_topic('/chatter', 'std_msgs/msg/String')
    w.write('/chatter', b'\x00\x01\x00\x00\x06\x00\x00\x00hello\x00', 1_000_000_000)
    w.close()
    other = Path(w.path)
    # a truncated file: cut a finished bag in its middle, past the header
    good_bag = plain_bag
    src = next(good_bag.glob('*.mcap'))
    torn = tmp_path / 'torn.mcap'
    torn.write_bytes(src.read_bytes()[:40])
    cases = [
        (['rigidrot_compare', str(tmp_path / 'missing')], 'no such file'),
        (['rigidrot_compare', str(empty)], 'no .mcap file'),
        (['rigidrot_compare', str(text)], 'not an MCAP file'),
        (['rigidrot_compare', str(torn)], 'no readable records'),
        (['rigidrot_compare', str(other), '--topic', '/chatter'], 'carries no attitude'),
        (['rigidrot_compare', str(other)], 'holds no topic that can be scored'),
        (['rigidrot_compare', str(good_bag), '--topic', '/nope'], "no topic '/nope'"),
        (['rigidrot_replay', str(text)], 'not an MCAP file'),
        (['rigidrot_replay', str(good_bag), '--topics', '/nope'], 'no topic'),
    ]
    for cmd, words in cases:
        out = _run(cmd, env)
        assert out.returncode == 2, (cmd, out.stdout, out.stderr)
        assert words in out.stderr, (cmd, out.stderr)
        assert 'Traceback' not in out.stderr
    # a bag with messages but no run metadata cannot be scored against the exact truth
    w2 = BagWriter(str(tmp_path / 'bags'), 'norun')
    w2.add_topic('/attitude', 'geometry_msgs/msg/QuaternionStamped')
    w2.write('/attitude', next(m[4] for m in read_bag(str(good_bag)).messages
                               if m[0] == '/attitude'), 1)
    w2.close()
    out = _run(['rigidrot_compare', w2.path], env)
    assert out.returncode == 2 and 'no rigidrot_run metadata' in out.stderr, out.stderr
    # nothing recorded is overwritten: a second writer gets a new directory
    assert w2.path != w.path and os.path.isdir(w.path)


def test_compare_honours_resets_in_the_log(tmp_path):
    from process_helpers import CLIENT
    env = ros_env(next_domain_id())
    root = tmp_path / 'runs'
    node = start([script('attitude_node'), '--ros-args', '-p', 'record:=true',
                  '-p', f'record_path:={root}'], env)
    try:
        assert wait_for(lambda: root.exists() and any(root.iterdir()), timeout=60)
        time.sleep(1.0)
        changes = [['sphere', {'inertia': [3.0, 3.0, 3.0], 'torque': [0.1, 0.1, 0.1],
                               'omega0': [0.0, 1.0, 0.0], 'time_scale': 2.0}]]
        import subprocess
        cli = subprocess.run([sys.executable, '-c', CLIENT, '/attitude_node',
                              json.dumps(changes)], env=env, capture_output=True, text=True,
                             timeout=60)
        assert cli.returncode == 0, cli.stderr
        assert json.loads(cli.stdout)['reset'][0] is True
        time.sleep(1.0)
    finally:
        code, _, err = stop(node, signal.SIGINT)
    assert code == 0, err
    bag = next(root.iterdir())
    contents = read_bag(str(bag))
    assert [r['model'] for r in contents.runs] == ['axial-torque', 'sphere']
    assert contents.runs[1]['time_scale'] == 2.0
    out = _run(['rigidrot_compare', str(bag), '--json', str(tmp_path / 'r.json')], env)
    assert out.returncode == 0, out.stderr
    topics = {t['topic']: t for t in json.loads((tmp_path / 'r.json').read_text())['topics']}
    assert topics['/attitude']['count'] > 150 and topics['/attitude']['max'] <= 1e-12
    assert topics['/angular_velocity']['max'] <= 1e-12


CLOCK_LISTENER = textwrap.dedent('''
    import json, signal, sys, time
    import rclpy
    from rosgraph_msgs.msg import Clock
    rclpy.init()
    node = rclpy.create_node('clock_listener')
    got = []
    def cb(m):
        got.append(m.clock.sec * 10**9 + m.clock.nanosec)
        heard[0] = time.monotonic()
    node.create_subscription(Clock, '/clock', cb, 100)
    # until told that the publishers are done (SIGUSR1), then until 0.5 s pass with nothing
    # new (what was in flight); at most argv[1] s
    done, heard = [], [time.monotonic()]
    signal.signal(signal.SIGUSR1, lambda *_: done.append(time.monotonic()))
    print('ready', flush=True)
    end = time.monotonic() + float(sys.argv[1])
    while time.monotonic() < end and not (
            done and time.monotonic() - max(done[0], heard[0]) > 0.5):
        rclpy.spin_once(node, timeout_sec=0.01)
    print(json.dumps(got))
''')


def test_replay_publishes_clock_from_the_log(plain_bag):
    bag = plain_bag
    log_times = [m[2] for m in read_bag(str(bag)).messages]
    env2 = ros_env(next_domain_id())
    lis = start([sys.executable, '-c', CLOCK_LISTENER, '30'], env2)
    assert lis.stdout.readline().strip() == 'ready'
    rep = _run(['rigidrot_replay', str(bag), '--clock', '--quiet', '--duration', '0.5'], env2)
    assert rep.returncode == 0, rep.stderr
    clock = _captured(lis)
    assert len(clock) > 50
    assert set(clock) <= set(log_times)               # the log's own times
    assert clock == sorted(clock)
    assert (clock[-1] - clock[0]) * 1e-9 <= 0.5 + 1e-9


@pytest.mark.usefixtures('ros_context')
def test_replay_waits_for_the_subscribers_to_settle():
    """The first match may be a recorder: play only once no new subscriber has matched."""
    import threading

    import rclpy
    from std_msgs.msg import String

    from rigidrot_ros.tools.replay import _wait_for_matching, SETTLE
    node = rclpy.create_node('replay_wait')
    pub = node.create_publisher(String, '/wait_topic', 10)
    subs = [rclpy.create_node(f'late_{k}') for k in range(2)]
    subs[0].create_subscription(String, '/wait_topic', lambda m: None, 10)
    late = threading.Timer(0.3, lambda: subs[1].create_subscription(
        String, '/wait_topic', lambda m: None, 10))
    late.start()
    try:
        t0 = time.monotonic()
        assert _wait_for_matching(node, [pub], 10.0)
        assert pub.get_subscription_count() == 2       # the late subscriber too
        assert time.monotonic() - t0 >= 0.3 + SETTLE
        # nobody there: False after the limit, not a hang
        lone = node.create_publisher(String, '/nobody_here', 10)
        t0 = time.monotonic()
        assert not _wait_for_matching(node, [lone], 0.5)
        assert 0.5 <= time.monotonic() - t0 < 2.0
        # --wait-for: a settled, fully matched graph does not start it without the one
        # required; a subscriber of that one arriving later (as a filter discovered
        # after a recorder) does
        assert not _wait_for_matching(node, [pub, lone], 1.0, required=[lone])
        late = threading.Timer(0.3, lambda: subs[0].create_subscription(
            String, '/nobody_here', lambda m: None, 10))
        late.start()
        t0 = time.monotonic()
        assert _wait_for_matching(node, [pub, lone], 10.0, required=[lone])
        assert lone.get_subscription_count() == 1
        assert time.monotonic() - t0 >= 0.3 + SETTLE
    finally:
        late.cancel()
        for n in subs + [node]:
            n.destroy_node()
