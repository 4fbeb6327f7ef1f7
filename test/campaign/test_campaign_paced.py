"""Campaigns with a ROS program fed at its own pace (no ``rate:``), and bad estimators.

Oracles: the same runs in process (the same filter class, no DDS), step by step: every
estimate is there and its NEES equal to 1e-9; the count of messages sent equals the
run's sensor messages (read back from the generated bag by the bag reader). A command
that cannot start stops the campaign with one line (exit 2); one that misbehaves later
fails its run with the reason, and the campaign goes on.
"""

import os
import sys

import pytest

from rigidrot_ros.campaign import session
from rigidrot_ros.campaign.run import run_one
from rigidrot_ros.campaign.spec import load_spec
from rigidrot_ros.tools.campaign import main
from ros_helpers import next_domain_id

from campaign_helpers import _write, SPEC  # noqa: I100, I201 - a helper module beside it

pytestmark = pytest.mark.ros
HERE = os.path.dirname(os.path.abspath(__file__))
PARAMS = SPEC['estimator']['params']
MEKF = (f'rigidrot_mekf --sigma-v {PARAMS["sigma_v"]} --sigma-u {PARAMS["sigma_u"]} '
        f'--bias-sigma {PARAMS["bias_sigma"]} --ros-args -p use_sim_time:=true')


@pytest.fixture
def ros_path(monkeypatch):
    """The venv's scripts on PATH, discovery on this machine only; a domain of its own."""
    monkeypatch.setenv('PATH', os.path.dirname(sys.executable) + os.pathsep
                       + os.environ['PATH'])
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    return next_domain_id()


@pytest.mark.parametrize('reset', [False, True], ids=['process_per_run', 'long_lived'])
def test_paced_mekf_equals_in_process_step_by_step(tmp_path, ros_path, reset):
    est = {'command': MEKF, 'settle': 0.0, 'domain_base': ros_path, 'domain_span': 1}
    if reset:
        est['reset'] = '/mekf/reset'
    ros = load_spec(_write(tmp_path, dict(SPEC, duration=3.0, estimator=est), 'ros.yaml'))
    inproc = load_spec(_write(tmp_path, dict(SPEC, duration=3.0)))
    try:
        for i in range(2):
            a, b = run_one(ros, i), run_one(inproc, i)
            assert a['row']['status'] == 'ok', a['row']
            # every estimate, each with the in-process NEES
            assert a['series']['t_ns'] == b['series']['t_ns'] and len(b['series']['t_ns']) > 20
            for x, y in zip(a['series']['nees'], b['series']['nees']):
                assert abs(x - y) <= 1e-9 * max(1.0, y)
            # [0, 3) s: a 100 Hz gyro (samples 1..299) and a 10 Hz star tracker (0..29)
            assert a['timing']['sent'] == 299 + 30, a['timing']
            # the long-lived estimator starts once
            assert ('process_start_s' in a['timing']) == (i == 0 or not reset)
    finally:
        session._close_live()


def _one(tmp_path, domain, command, name, **est):
    spec = dict(SPEC, runs=1, duration=3.0, timeout=est.pop('timeout', 60), estimator=dict(
        {'command': command, 'domain_base': domain, 'domain_span': 1}, **est))
    return run_one(load_spec(_write(tmp_path, spec, f'{name}.yaml')), 0)


@pytest.mark.parametrize('mode, words', [
    ('crash', 'exited with status 1 during the run: RuntimeError: bad estimator: crashed'),
    ('wrong_type', 'publishes std_msgs/msg/String on /estimator/odom'),
    ('silent', 'published nothing on /estimator/odom'),
    ('hang', 'did not exit within 1 s of SIGINT (killed)'),
])
def test_a_misbehaving_command_fails_its_run_with_the_reason(
        tmp_path, ros_path, monkeypatch, mode, words):
    monkeypatch.setattr(session, 'STOP_S', 1.0)
    out = _one(tmp_path, ros_path, f'{sys.executable} {HERE}/bad_estimator_node.py {mode}',
               mode)
    assert out['row']['status'] == 'failed' and words in out['row']['reason'], out['row']
    assert 'fatal' not in out


def test_a_command_that_never_subscribes_fails_after_the_timeout(tmp_path, ros_path):
    out = _one(tmp_path, ros_path, f'{sys.executable} {HERE}/bad_estimator_node.py deaf',
               'deaf', timeout=3)
    assert out['row']['reason'].startswith(
        "the estimator did not subscribe to /imu, /star_tracker before the run's timeout"), \
        out['row']


def test_a_command_that_cannot_start_stops_the_campaign_exit_2(tmp_path, ros_path, capsys):
    spec = dict(SPEC, runs=4, duration=3.0, estimator={
        'command': f'{sys.executable} {HERE}/bad_estimator_node.py exit',
        'domain_base': ros_path, 'domain_span': 1})
    code = main([_write(tmp_path, spec, 'exit.yaml'), '-o', str(tmp_path / 'out'),
                 '--processes', '1', '--quiet'])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith(f'rigidrot_campaign: estimator command {sys.executable} ')
    assert err[0].endswith('cannot start: the estimator exited with status 3 before '
                           'subscribing to its inputs: bad estimator: refusing to start')
    assert not list((tmp_path / 'out' / 'runs').glob('*.json'))


def test_the_played_messages_are_the_generated_bag_s(tmp_path):
    """iter_serialized: the bag's sensor and run messages, same bytes, same order."""
    from rigidrot_ros.bag import read_bag
    from rigidrot_ros.run.generate import generate_bag, iter_serialized, load_values
    values = load_values(None, {'imu.enable': True, 'star_tracker.enable': True,
                                'mag.enable': True, 'imu.latency': 0.004,
                                'star_tracker.latency': 0.02, 'imu.seed': 3}.items())
    bag = read_bag(generate_bag(values, 2.0, str(tmp_path / 'bag')))
    keep = ('imu', 'star_tracker', 'run')
    want = [(t, log, bytes(d)) for t, _, log, _, d in bag.messages
            if t.rsplit('/', 1)[-1] in keep]
    got = [(t, log, bytes(d)) for t, log, d in iter_serialized(values, 2.0, keep)]
    assert got == want and len(want) > 200
    assert [t for t, _, _ in iter_serialized(values, 2.0)] == [m[0] for m in bag.messages]


def test_replay_paced_by_plays_a_bag_and_writes_every_answer(tmp_path, ros_path):
    """rigidrot_replay --paced-by -o: the MEKF node's answers, as the filter in process."""
    import signal
    import subprocess

    from rclpy.serialization import deserialize_message
    from nav_msgs.msg import Odometry

    from rigidrot_ros.bag import read_bag
    from rigidrot_ros.estimators.mekf import make
    from rigidrot_ros.run.generate import generate_bag, iter_run, load_values
    from ros_helpers import ros_env, script
    values = load_values(None, {'imu.enable': True, 'star_tracker.enable': True,
                                'imu.gyro_bias': [1e-3, -5e-4, 1.5e-3], 'imu.seed': 8}.items())
    bag = generate_bag(values, 2.0, str(tmp_path / 'in'))
    env = ros_env(ros_path)
    est = subprocess.Popen(MEKF.split(), env=env, stdout=subprocess.DEVNULL,
                           stderr=subprocess.STDOUT)
    try:
        out = subprocess.run(
            [script('rigidrot_replay'), bag, '--clock', '--topics', '/imu', '/star_tracker',
             '/attitude_node/run', '--paced-by', '/estimator/odom', '-o',
             str(tmp_path / 'answers'), '--wait', '30'],
            env=env, capture_output=True, text=True, timeout=120)
    finally:
        est.send_signal(signal.SIGINT)
        est.wait(30)
    assert out.returncode == 0, out.stderr
    assert '[replay] 220 messages sent and acknowledged' in out.stderr    # 199 + 20 + 1
    answers = read_bag(str(tmp_path / 'answers'))
    assert answers.runs and answers.runs[0]['start_ns'] == 0           # scorable
    got = [deserialize_message(d, Odometry) for t, _, _, _, d in answers.messages
           if t == '/estimator/odom']
    filt = make(PARAMS)
    want = [m for n, _, msg in iter_run(values, 2.0) for m in filt.receive(n, msg)]
    want += filt.finish()
    # every estimate the filter had made when the replay ended (its last one comes at
    # SIGINT, after the replay has written its answers)
    assert len(want) - 1 <= len(got) <= len(want) and len(got) > 15
    for a, b in zip(got, want):
        assert a.header.stamp == b.header.stamp
        assert a.pose.pose.orientation == b.pose.pose.orientation
        assert list(a.pose.covariance) == list(b.pose.covariance)


@pytest.mark.parametrize('args, words', [
    (['--window', '8'], '--window and -o go with --paced-by'),
    (['--paced-by', '/estimator/odom', '--loop'], '--loop does not go with --paced-by'),
    (['--paced-by', '/estimator/odom', '--clock-step', '-1'], '--clock-step must lie in'),
])
def test_replay_paced_by_bad_arguments_one_line_exit_2(tmp_path, capsys, args, words):
    from rigidrot_ros.tools.replay import main as replay
    assert replay([str(tmp_path)] + args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
