"""Commands that say what the user needs next: topics at start-up, where the bags are,
how to finish a torn bag."""

from pathlib import Path
import shutil
import signal
import subprocess
import threading

import pytest

from rigidrot_ros.run.generate import generate_bag
from ros_helpers import next_domain_id, ros_env, script, start, wait_for


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    """A 3 s generated bag: truth, gyro, star tracker; one chunk a second."""
    root = tmp_path_factory.mktemp('bags')
    return Path(generate_bag({'imu.enable': True, 'star_tracker.enable': True}, 3.0,
                             root / 'attitude_node_1'))


def _run(prog, args, timeout=120):
    return subprocess.run([script(prog)] + [str(a) for a in args], capture_output=True,
                          text=True, timeout=timeout, env=ros_env(next_domain_id()))


def _compare(args, capsys):
    """``rigidrot_compare`` in this process: ``(status, stdout, stderr)``."""
    from rigidrot_ros.tools.compare import main
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.ros
def test_the_start_up_log_names_the_topics_it_publishes():
    proc = start([script('attitude_node'), '--ros-args', '-p', 'imu.enable:=true',
                  '-p', 'star_tracker.enable:=true'], ros_env(next_domain_id()))
    lines = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stderr.readline, '')),
                              daemon=True)
    reader.start()
    try:
        wait_for(lambda: any('real-time scheduling' in ln for ln in lines)
                 or proc.poll() is not None, timeout=60)    # the last line of start-up
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
        reader.join(timeout=10)
    line = next((ln for ln in lines if 'publishing' in ln), '')
    for topic in ('/attitude (QuaternionStamped)', '/angular_velocity (Vector3Stamped)',
                  '/imu (Imu)', '/delta_angle', '/delta_rotation', '/star_tracker',
                  '/diagnostics', '/attitude_node/run (String)'):
        assert topic in line, (topic, lines)
    assert '/rosout' not in line and '/parameter_events' not in line


def test_compare_on_a_run_directory_takes_its_one_bag_or_names_them(bag, tmp_path, capsys):
    run = tmp_path / 'loop_1'
    run.mkdir()
    shutil.copytree(bag, run / 'attitude_node_1')
    code, out, err = _compare([run], capsys)
    assert code == 0, err
    assert f'comparing the bag in it, {run / "attitude_node_1"}' in err
    assert '/star_tracker' in out
    shutil.copytree(bag, run / 'rec')                # the README loop: two bags side by side
    code, out, err = _compare([run], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith('rigidrot_compare: ')
    assert 'the bags sit one level down' in lines[0]
    assert str(run / 'attitude_node_1') in lines[0] and str(run / 'rec') in lines[0]


@pytest.fixture
def torn(bag, tmp_path):
    """The bag's file cut after its first chunks, as a killed writer leaves it."""
    src = next(bag.glob('*.mcap')).read_bytes()
    path = tmp_path / 'torn.mcap'
    path.write_bytes(src[:int(len(src) * 0.75)])
    return path


def test_compare_on_a_torn_bag_names_rigidrot_reindex(torn, capsys):
    code, _, err = _compare([torn], capsys)
    assert code == 0, err
    assert 'unfinished file' in err
    assert f'rigidrot_reindex {torn} finishes it in place' in err


@pytest.mark.ros
def test_replay_of_a_torn_bag_names_rigidrot_reindex(torn):
    out = _run('rigidrot_replay', [torn, '--rate', '20', '--quiet', '--wait', '0'])
    assert out.returncode == 0, out.stderr
    assert f'rigidrot_reindex {torn} finishes it in place' in out.stderr
    assert 'Traceback' not in out.stderr
