"""The recording and scoring console scripts as typed, and rigidrot_record / rigidrot_reindex.

Table-driven like test_cli.py: one row per command line with its exit status and words
that must appear; a failing row prints exactly one line on stderr, starting with the
program name, and never a traceback; ``--help`` prints usage and starts no node.
"""

import json
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import textwrap
import time

from mcap.writer import Writer
import pytest
from rosbags.highlevel import AnyReader
import yaml

from rigidrot_ros.bag import read_bag
from ros_helpers import (
    check_as_typed, cli_command, next_domain_id, ros_env, script, start, stop, wait_for,
)
from score_helpers import _make, _truth, _write_bag

pytestmark = pytest.mark.ros


def row(prog, args, code, words=(), block=(), id=None):
    """One command line and what it must do."""
    return pytest.param(prog, args, code, tuple(words), tuple(block),
                        id=id or f'{prog} {" ".join(args)}'[:80])


CASES = [
    row('rigidrot_compare', ['--help'], 0, ['usage: rigidrot_compare', 'NEES', '--csv',
                                            '--plot-truth', '--yscale', '--cov-frame']),
    row('rigidrot_compare', [], 2, ['required: bag']),
    row('rigidrot_compare', ['{tmp}/good', '--bogus'], 2, ['unrecognized arguments']),
    row('rigidrot_compare', ['{tmp}/missing'], 2, ['no such file']),
    row('rigidrot_compare', ['{tmp}/notes.mcap'], 2, ['not an MCAP file']),
    row('rigidrot_compare', ['{tmp}/torn.mcap'], 2, ['no readable records']),
    row('rigidrot_compare', ['{tmp}/empty'], 2, ['no .mcap file']),
    row('rigidrot_compare', ['{tmp}/badmeta'], 2, ['not a valid rosbag2 metadata file']),
    row('rigidrot_compare', ['{tmp}/good', '--yscale', 'cubic'], 2, ['invalid choice']),
    row('rigidrot_compare', ['{tmp}/good', '--cov-frame', 'x'], 2, ['invalid choice']),
    row('rigidrot_compare', ['{tmp}/good', '--topic', '/nope'], 2, ["no topic '/nope'"]),
    row('rigidrot_compare', ['{tmp}/good', '--csv', '/proc/no/such/x.csv'], 2, ['x.csv']),
    row('rigidrot_compare', ['{tmp}/good', '--plot', '{tmp}/out.txt'], 2,
        ['--plot', 'out.txt', 'must end in .png, .svg, .pdf']),
    row('rigidrot_compare', ['{tmp}/good', '--plot', '{tmp}/x.png'], 2,
        ['pip install matplotlib'], block=('matplotlib',),
        id='rigidrot_compare --plot without matplotlib'),
    row('rigidrot_replay', ['--help'], 0,
        ['usage: rigidrot_replay', '--clock', '--wait', '--wait-for']),
    row('rigidrot_replay', ['{tmp}/good', '--rate', '0'], 2, ['--rate']),
    row('rigidrot_replay', ['{tmp}/good', '--rate', 'nan'], 2, ['--rate']),
    row('rigidrot_replay', ['{tmp}/good', '--start', '-1'], 2, ['--start']),
    row('rigidrot_replay', ['{tmp}/good', '--start', '1000'], 2,
        ['past the end of the log (0.190 s long)']),
    row('rigidrot_replay', ['{tmp}/proto.mcap'], 2, ["'foo.Bar' is not a ROS 2 message type"]),
    row('rigidrot_replay', ['{tmp}/good', '--duration', 'inf'], 2, ['--duration']),
    row('rigidrot_replay', ['{tmp}/missing'], 2, ['no such file']),
    row('rigidrot_replay', ['{tmp}/good', '--wait-for', '/nope'], 2,
        ["--wait-for ['/nope']: not replayed", '/attitude']),
    row('rigidrot_replay', ['{tmp}/good', '--wait-for', '/attitude', '--wait', '0.5'], 2,
        ['no subscriber of /attitude matched within --wait 0.5 s; nothing was played']),
    row('rigidrot_replay', ['{tmp}/notes.mcap'], 2, ['not an MCAP file']),
    row('rigidrot_replay', ['{tmp}/torn.mcap'], 2, ['no readable records']),
    row('rigidrot_record', ['--help'], 0, ['usage: rigidrot_record', 'NAME:pkg/msg/Type']),
    row('rigidrot_record', ['/attitude'], 2, ['-o/--output']),
    row('rigidrot_record', ['-o', '{tmp}/r1'], 2, ['name the topics']),
    row('rigidrot_record', ['-o', '{tmp}/good', '/attitude'], 2, ['not an empty directory']),
    row('rigidrot_record', ['-o', '{tmp}/r2', '/a', '--duration', '-1'], 2, ['--duration']),
    row('rigidrot_record', ['-o', '{tmp}/r3', 'a b'], 2, ['invalid topic name']),
    row('rigidrot_record', ['-o', '{tmp}/r4', '/x:foo_msgs/msg/Nope'], 2, ['not installed']),
    row('rigidrot_record', ['-o', '{tmp}/r5', '/x:Nope'], 2, ['not a message type']),
    row('rigidrot_record', ['-o', '{tmp}/r6', '/a', '--ros-args', '-p'], 2,
        ['invalid --ros-args']),
    row('rigidrot_record', ['-o', '{tmp}/r7', '/a', '--ros-args', '--params-file',
                            '{tmp}/nope.yaml'], 2, ['nope.yaml', 'no such file']),
    row('rigidrot_replay', ['{tmp}/good', '--ros-args', '-p'], 2, ['invalid --ros-args']),
    row('rigidrot_demo_estimator', ['--ros-args', '-p'], 2, ['invalid --ros-args']),
    row('rigidrot_reindex', ['--help'], 0, ['usage: rigidrot_reindex', '--no-backup']),
    row('rigidrot_reindex', [], 2, ['required: bag']),
    row('rigidrot_reindex', ['{tmp}/missing'], 2, ['no such file']),
    row('rigidrot_reindex', ['{tmp}/notes.mcap'], 2, ['not an MCAP file']),
    row('rigidrot_reindex', ['{tmp}/empty'], 2, ['no .mcap file']),
    row('rigidrot_reindex', ['{tmp}/torn.mcap'], 2, ['no readable records']),
    row('rigidrot_demo_estimator', ['--help'], 0, ['usage: rigidrot_demo_estimator',
                                                   'ahrs', '--bias-sigma']),
    row('rigidrot_demo_estimator', ['--bogus'], 2, ['unrecognized arguments']),
    row('rigidrot_demo_estimator', ['--bias-sigma', '-1'], 2, ['--bias-sigma']),
    row('rigidrot_demo_estimator', ['--initial-sigma', '0'], 2, ['--initial-sigma']),
    row('rigidrot_demo_estimator', ['--bias-sigma', 'x'], 2, ['invalid float value']),
    row('rigidrot_demo_estimator', [], 2, ['pip install ahrs'], block=('ahrs',),
        id='rigidrot_demo_estimator without ahrs'),
]

ENTRY = {'rigidrot_compare': 'rigidrot_ros.tools.compare:main',
         'rigidrot_demo_estimator': 'rigidrot_ros.tools.demo_estimator:main'}


@pytest.fixture(scope='module')
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('cli')
    _, stamps, q, _ = _truth(20)
    bag = _write_bag(tmp, {'/attitude': ('geometry_msgs/msg/QuaternionStamped',
                                         lambda i: _make('QuaternionStamped', stamps[i], q[i],
                                                         None))}, n=20)
    shutil.copytree(bag, tmp / 'good')
    (tmp / 'notes.mcap').write_text('hello, not a bag')
    (tmp / 'torn.mcap').write_bytes(next(bag.glob('*.mcap')).read_bytes()[:40])
    (tmp / 'empty').mkdir()
    with open(tmp / 'proto.mcap', 'wb') as fh:          # legal MCAP, not ROS 2
        w = Writer(fh)
        w.start(profile='', library='test')
        sid = w.register_schema(name='foo.Bar', encoding='protobuf', data=b'\x0a\x00')
        cid = w.register_channel(topic='/p', message_encoding='protobuf', schema_id=sid)
        w.add_message(cid, 1, b'\x08\x01', 1)
        w.finish()
    shutil.copytree(bag, tmp / 'badmeta')
    (tmp / 'badmeta' / 'metadata.yaml').write_text('rosbag2_bagfile_information: [{{')
    return tmp


@pytest.mark.parametrize('prog, args, code, words, block', CASES)
def test_command_as_typed(files, prog, args, code, words, block):
    args = [a.replace('{tmp}', str(files)) for a in args]
    t0 = time.monotonic()
    out = subprocess.run(cli_command(prog, args, block, ENTRY),
                         env=ros_env(next_domain_id()), capture_output=True, text=True,
                         timeout=120)
    check_as_typed(out, prog, code, words)
    if code == 0:
        assert '[INFO]' not in out.stdout + out.stderr and time.monotonic() - t0 < 60  # no node
    else:
        assert not any(files.glob('r[0-9]')), 'a refused record left a directory behind'


def test_compare_reads_a_log_cut_in_the_middle(files, tmp_path):
    """A truncated log that still holds records is scored, with one note saying so."""
    src = next((files / 'good').glob('*.mcap')).read_bytes()
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(src[:len(src) // 2])
    out = subprocess.run([script('rigidrot_compare'), str(cut)], capture_output=True,
                         text=True, timeout=120, env=ros_env(next_domain_id()))
    if out.returncode == 0:
        assert 'unfinished file' in out.stderr and 'Traceback' not in out.stderr
    else:                     # the cut fell inside the only chunk: nothing readable
        assert out.returncode == 2 and 'no readable records' in out.stderr


def test_record_then_sigkill_then_reindex(tmp_path):
    """rigidrot_record keeps the node's run description; SIGKILL loses <= 0.5 s; reindex."""
    env = ros_env(next_domain_id())
    out_dir = tmp_path / 'bag'
    node = start([script('attitude_node')], env)
    rec = start([script('rigidrot_record'), '-o', str(out_dir),
                 '/attitude:geometry_msgs/msg/QuaternionStamped', '/angular_velocity'], env)
    try:
        assert wait_for(lambda: out_dir.exists() and any(out_dir.glob('*.mcap')), 60)
        line = ''
        while 'recording /angular_velocity' not in line:
            line = rec.stderr.readline()
            assert line, 'rigidrot_record ended early'
        time.sleep(2.0)
        killed_ns = time.time_ns()
        code, _, _ = stop(rec, signal.SIGKILL)
    finally:
        stop(node, signal.SIGINT)
        stop(rec, signal.SIGKILL)
    assert code == -signal.SIGKILL
    with pytest.raises(Exception):                    # rosbags refuses a torn file
        with AnyReader([out_dir]) as reader:
            list(reader.messages())
    torn = read_bag(str(out_dir))
    assert torn.truncated or torn.note
    last = max(m[2] for m in torn.messages)
    assert (killed_ns - last) * 1e-9 <= 0.5 + 0.1, (killed_ns - last) * 1e-9
    counts = {}
    for m in torn.messages:
        counts[m[0]] = counts.get(m[0], 0) + 1
    r = subprocess.run([script('rigidrot_reindex'), str(out_dir)], capture_output=True,
                       text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr
    # rosbags reads it whole now, with the right counts, every message as written
    with AnyReader([out_dir]) as reader:
        got = {c.topic: c.msgcount for c in reader.connections}
        raw = sorted(bytes(d) for _, _, d in reader.messages())
    assert got == counts and counts['/attitude'] > 100 and counts['/attitude_node/run'] == 1
    assert raw == sorted(bytes(m[4]) for m in torn.messages)
    meta = yaml.safe_load((out_dir / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['message_count'] == sum(counts.values())
    assert list(out_dir.glob('*.mcap.orig'))                  # the torn original is kept
    # and it scores against the exact truth through the recorded ~/run
    c = subprocess.run([script('rigidrot_compare'), str(out_dir), '--json',
                        str(tmp_path / 's.json')], capture_output=True, text=True,
                       timeout=300, env=env)
    assert c.returncode == 0, c.stderr
    topics = {t['topic']: t for t in json.loads((tmp_path / 's.json').read_text())['topics']}
    assert topics['/attitude']['count'] == counts['/attitude']
    assert topics['/attitude']['max'] <= 1e-12
    # a second reindex finds nothing to do
    again = subprocess.run([script('rigidrot_reindex'), str(out_dir)], capture_output=True,
                           text=True, timeout=120, env=env)
    assert again.returncode == 0 and 'nothing' in again.stdout


def test_record_sigterm_finishes_and_keeps_transient_local_history(tmp_path):
    """A late recorder still gets a transient-local publisher's kept messages."""
    env = ros_env(next_domain_id())
    pub = start([sys.executable, '-c', textwrap.dedent('''
        import time, rclpy
        from rclpy.qos import QoSProfile, DurabilityPolicy
        from std_msgs.msg import String
        rclpy.init()
        n = rclpy.create_node('latched')
        p = n.create_publisher(String, '/latched', QoSProfile(
            depth=5, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        for i in range(5):
            p.publish(String(data=f'm{i}'))
        print('published', flush=True)
        end = time.monotonic() + 60
        while time.monotonic() < end:
            rclpy.spin_once(n, timeout_sec=0.1)
    ''')], env)
    try:
        assert pub.stdout.readline().strip() == 'published'
        rec = start([script('rigidrot_record'), '-o', str(tmp_path / 'b'), '/latched'], env)
        line = ''
        while 'recording /latched' not in line:
            line = rec.stderr.readline()
            assert line, 'rigidrot_record ended early'
        assert 'transient-local' in line
        time.sleep(1.5)
        code, _, err = stop(rec, signal.SIGTERM)
    finally:
        stop(pub, signal.SIGINT)
    assert code == 0 and 'bag finished' in err, err
    with AnyReader([tmp_path / 'b']) as reader:
        data = [reader.deserialize(d, c.msgtype).data for c, _, d in reader.messages()]
        qos = reader.connections[0].ext.offered_qos_profiles[0]
    assert data == [f'm{i}' for i in range(5)]
    assert qos.durability.name == 'TRANSIENT_LOCAL'
    assert Path(tmp_path / 'b' / 'metadata.yaml').exists()


def test_record_all_with_duration(tmp_path):
    """--all records every topic that appears; --duration ends and finishes the bag."""
    env = ros_env(next_domain_id())
    node = start([script('attitude_node')], env)
    try:
        out = subprocess.run([script('rigidrot_record'), '-o', str(tmp_path / 'all'), '--all',
                              '--duration', '4'], env=env, capture_output=True, text=True,
                             timeout=120)
    finally:
        stop(node, signal.SIGINT)
    assert out.returncode == 0 and 'bag finished' in out.stderr, out.stderr
    with AnyReader([tmp_path / 'all']) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
    assert topics['/attitude'] == 'geometry_msgs/msg/QuaternionStamped'
    assert topics['/attitude_node/run'] == 'std_msgs/msg/String'
    assert {'/angular_velocity', '/diagnostics'} <= set(topics)


@pytest.mark.parametrize('typed', [True, False])
def test_record_matches_a_best_effort_publisher(tmp_path, typed):
    """A best-effort publisher is recorded (a reliable subscription would never match)."""
    env = ros_env(next_domain_id())
    pub = start([sys.executable, '-c', textwrap.dedent('''
        import time, rclpy
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String
        rclpy.init()
        n = rclpy.create_node('lossy')
        p = n.create_publisher(String, '/lossy', QoSProfile(
            depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
        end = time.monotonic() + 60
        k = 0
        while time.monotonic() < end:
            p.publish(String(data=str(k)))
            k += 1
            rclpy.spin_once(n, timeout_sec=0.01)
    ''')], env)
    topic = '/lossy:std_msgs/msg/String' if typed else '/lossy'
    try:
        out = subprocess.run([script('rigidrot_record'), '-o', str(tmp_path / 'b'), topic,
                              '--duration', '5'], env=env, capture_output=True, text=True,
                             timeout=120)
    finally:
        stop(pub, signal.SIGINT)
    assert out.returncode == 0, out.stderr
    assert 'best-effort' in out.stderr, out.stderr
    with AnyReader([tmp_path / 'b']) as reader:
        conn = reader.connections[0]
        assert conn.msgcount > 50, out.stderr
        assert conn.ext.offered_qos_profiles[0].reliability.name == 'BEST_EFFORT'
