"""Build the package with colcon in a temporary workspace and run the installed executable.

This is the closest check of ``ros2 run rigidrot_ros attitude_node`` these machines allow:
``ros2 run`` executes ``install/rigidrot_ros/lib/rigidrot_ros/attitude_node``.
"""

import json
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys

import pytest

from process_helpers import SUBSCRIBER
from ros_helpers import next_domain_id, ros_env, start, stop

pytestmark = pytest.mark.ros
ROOT = Path(__file__).resolve().parents[2]


def test_colcon_build_installs_a_runnable_executable(tmp_path):
    colcon = Path(sys.executable).parent / 'colcon'
    if not colcon.exists():
        pytest.fail('colcon is not installed: pip install -e .[test]')
    src = tmp_path / 'ws' / 'src' / 'rigidrot_ros'
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        '.venv', '.git', 'build', 'install', 'log', '__pycache__', '*.egg-info', 'runs'))
    ws = tmp_path / 'ws'
    env = dict(os.environ)
    env['PATH'] = f'{Path(sys.executable).parent}{os.pathsep}{env["PATH"]}'
    build = subprocess.run([str(colcon), 'build', '--event-handlers', 'console_direct-'],
                           cwd=ws, env=env, capture_output=True, text=True, timeout=600)
    assert build.returncode == 0, build.stdout + build.stderr
    exe = ws / 'install' / 'rigidrot_ros' / 'lib' / 'rigidrot_ros' / 'attitude_node'
    assert exe.exists(), sorted(p.name for p in exe.parent.parent.rglob('*'))
    share = ws / 'install' / 'rigidrot_ros' / 'share' / 'rigidrot_ros'
    assert (share / 'package.xml').exists()
    assert (share / 'config' / 'default.yaml').exists()
    # source install/setup.sh, then run the installed executable, as `ros2 run` would
    renv = ros_env(next_domain_id())
    renv['PATH'] = env['PATH']
    cmd = f'. install/setup.sh && echo "$AMENT_PREFIX_PATH" >&2 && exec {exe}'
    node = start(['bash', '-c', cmd], renv, cwd=ws)
    try:
        sub = start([sys.executable, '-c', SUBSCRIBER, '', '1.0'], renv)
        out, err = sub.communicate(timeout=90)
        assert sub.returncode == 0, err
        got = json.loads(out)
        assert len(got['attitude']) >= 50 and len(got['angular_velocity']) >= 50
    finally:
        code, out, err = stop(node, signal.SIGINT)
    assert code == 0, err
    assert str(ws / 'install' / 'rigidrot_ros') in err   # the workspace was sourced
