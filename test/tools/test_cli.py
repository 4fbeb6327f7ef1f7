"""Every console script as typed: --help, bad arguments, missing files, missing extras.

Table-driven: one row per command line. A row gives the script, its arguments (``{tmp}``
is the test's temporary directory, which holds the fixture files below), the expected exit
status, words that must appear, and any environment overrides. Status 0 rows
(``--help``) must print usage on stdout; every other row must print exactly ``lines``
lines on stderr (default one) and never a traceback. ``block`` names modules made
unimportable, as after a plain ``pip install .`` without the ``bench`` extra.
"""

import json
from pathlib import Path
import subprocess

import pytest

from ros_helpers import check_as_typed, cli_command, next_domain_id, ros_env

ROOT = Path(__file__).resolve().parents[2]


def row(prog, args, code, words=(), lines=1, block=(), env=None, id=None):
    """One command line (with ``env`` overrides) and what it must do."""
    return pytest.param(prog, args, code, tuple(words), lines, tuple(block), env or {},
                        id=id or f'{prog} {" ".join(args)}'[:80])


CASES = [
    # attitude_node
    row('attitude_node', ['--help'], 0, ['usage: attitude_node', 'publish_rate', 'inertia',
                                         '~/reset', '/diagnostics', 'angular_velocity',
                                         '~/run', 'std_msgs/String']),
    row('attitude_node', ['-h'], 0, ['usage: attitude_node']),
    row('attitude_node', ['--bogus'], 2, ['unrecognized arguments: --bogus']),
    row('attitude_node', ['--ros-args', '--params-file', 'config/nope.yaml'], 2,
        ['config/nope.yaml', 'no such file']),
    row('attitude_node', ['--ros-args', '--params-file', '{tmp}'], 2, ['not a file']),
    row('attitude_node', ['--ros-args', '--params-file', '{tmp}/garbage.yaml'], 2,
        ['invalid --ros-args', 'garbage.yaml']),
    row('attitude_node', ['--ros-args', '--params-file'], 2, ['--params-file needs']),
    row('attitude_node', ['--ros-args', '-p'], 2, ['invalid --ros-args', '-p']),
    row('attitude_node', ['--ros-args', '-r', '__ns:=bad//ns'], 2, ['invalid --ros-args']),
    # the crashers that the core solves but cannot evaluate one tick in: refused
    # (those it can evaluate, omega0 = [1e300, ...] and kin, start: see test_node_limits.py)
    row('attitude_node', ['--ros-args', '-p', 'inertia:=[2e-300, 2e-300, 1e-300]'], 2,
        ['invalid parameters', 'inertia', 't = 0.01 s']),
    row('attitude_node', ['--ros-args', '-p', 'tol:=1e-20'], 2, ['tol']),
    row('attitude_node', ['--ros-args', '-p', 'tol:=5'], 2, ['invalid parameters', 'tol',
                                                             '[2e-14, 1]']),
    row('attitude_node', ['--ros-args', '-p', 'torque:=[0.0, 0.0, 1e300]'], 2,
        ['invalid parameters', 'torque']),
    row('attitude_node', ['--ros-args', '-p', 'torque:=[1e300, 0.0, 0.0]', '-p',
                          'torque_frame:=virtual'], 2, ['invalid parameters', 'torque']),
    row('attitude_node', ['--ros-args', '-p', 'imu.enable:=true', '-p', 'time_scale:=1e9'], 2,
        ['invalid parameters', 'first gyro sample', 'time_scale']),
    row('attitude_node', ['--ros-args', '-p', 'imu.enable:=true', '-p',
                          'omega0:=[1e300, -0.2, 0.5]'], 2,
        ['invalid parameters', 'gyro']),    # no finite bound (or, under load, its budget)
    row('attitude_node', ['--ros-args', '-p', 'publish_rate:=abc'], 2, ['publish_rate']),
    row('attitude_node', ['--ros-args', '-p', 'publish_rate:=1e5'], 2, ['publish_rate']),
    row('attitude_node', ['--ros-args', '-p', 'backend:=gpu'], 2, ['backend']),
    # (record:=yes is YAML 1.1 true to rcl, as in any ROS 2 node: it does record)
    row('attitude_node', ['--ros-args', '-p', 'record:=1'], 2,
        ['invalid parameters', 'parameter record must be true or false']),
    row('attitude_node', ['--ros-args', '-p', 'record:=true', '-p', 'record_topics:=5'], 2,
        ['invalid parameters', 'parameter record_topics must be a list of strings']),
    row('attitude_node', ['--ros-args', '-p', 'record:=true', '-p', 'record_path:=5'], 2,
        ['invalid parameters', 'parameter record_path must be a string']),
    row('attitude_node', ['--ros-args', '-p', 'record:=true', '-p',
                          'record_path:=/proc/no/such/dir'], 2, ['cannot record']),
    row('attitude_node', [], 2, ['invalid environment', 'ROS_DOMAIN_ID'],
        env={'ROS_DOMAIN_ID': 'abc'}, id='attitude_node with ROS_DOMAIN_ID=abc'),
    # rigidrot_echo
    row('rigidrot_echo', ['--help'], 0, ['usage: rigidrot_echo', '--timeout', '--count']),
    row('rigidrot_echo', ['--bogus'], 2, ['unrecognized arguments: --bogus']),
    row('rigidrot_echo', ['--count', 'x'], 2, ['--count', 'not an integer']),
    row('rigidrot_echo', ['--count', '-1'], 2, ['--count', '>= 0']),
    row('rigidrot_echo', ['--timeout', 'nan'], 2, ['--timeout']),
    row('rigidrot_echo', ['--timeout', '-3'], 2, ['--timeout']),
    row('rigidrot_echo', ['--ns', 'a b'], 2, ['--ns', 'a b']),
    row('rigidrot_echo', ['--ros-args', '--params-file', 'nope.yaml'], 2, ['no such file']),
    row('rigidrot_echo', ['--ros-args', '-p'], 2, ['invalid --ros-args']),
    row('rigidrot_echo', ['--timeout', '0.5'], 1,
        ['waiting for /attitude and /angular_velocity', 'no message on /attitude'], lines=2),
    row('rigidrot_echo', ['--ns', '/sat9', '--timeout', '0.3', '--count', '1'], 1,
        ['/sat9/attitude'], lines=2),
    # rigidrot_bench
    row('rigidrot_bench', ['--help'], 0, ['usage: rigidrot_bench', '--charts-from', 'soak']),
    row('rigidrot_bench', ['--only', 'nope'], 2, ['--only', 'invalid choice']),
    row('rigidrot_bench', ['--quick', '--bogus'], 2, ['unrecognized arguments']),
    row('rigidrot_bench', ['--only', 'soak', '--soak-minutes', '-1'], 2, ['--soak-minutes']),
    row('rigidrot_bench', ['--only', 'soak', '--soak-minutes', 'nan'], 2, ['--soak-minutes']),
    row('rigidrot_bench', ['--only', 'crosscheck', '--out', '{tmp}/x'], 2,
        ['needs the stability map']),
    row('rigidrot_bench', ['--charts-from', '{tmp}/nope.json'], 2, ['nope.json', 'No such']),
    row('rigidrot_bench', ['--charts-from', '{tmp}/garbage.yaml'], 2, ['not JSON']),
    row('rigidrot_bench', ['--charts-from', '{tmp}/other.json'], 2,
        ['not a rigidrot_bench results.json']),
    row('rigidrot_bench', ['--charts-from', '{tmp}/empty_results.json', '--out', '{tmp}/c'],
        2, ['no chartable results']),
    row('rigidrot_bench', ['--help'], 0, ['usage: rigidrot_bench'],
        block=('scipy', 'matplotlib'), id='rigidrot_bench --help without the bench extra'),
    row('rigidrot_bench', ['--quick', '--out', '{tmp}/b'], 2,
        ["pip install -e '.[bench]'", 'scipy', 'matplotlib'], block=('scipy', 'matplotlib'),
        id='rigidrot_bench --quick without the bench extra'),
    row('rigidrot_bench', ['--charts-from', 'doc/bench/results.json', '--out', '{tmp}/c'], 2,
        ["pip install -e '.[bench]'", 'matplotlib'], block=('matplotlib',),
        id='rigidrot_bench --charts-from without matplotlib'),
    # rigidrot_generate (the run itself: test_generate.py)
    row('rigidrot_generate', ['--help'], 0, ['usage: rigidrot_generate', '--duration',
                                             '--start-ns']),
    row('rigidrot_generate', ['-o', '{tmp}/g', '--duration', '-1'], 2, ['--duration']),
    row('rigidrot_generate', ['-o', '{tmp}/g', '--duration', '1', '-p', 'tol:=5'], 2,
        ['tol']),
    row('rigidrot_generate', ['-o', '{tmp}/g', '--duration', '1', '--params-file',
                              '{tmp}/garbage.yaml'], 2, ['garbage.yaml']),
    # rigidrot_campaign (specs and engines: test_campaign.py)
    row('rigidrot_campaign', ['--help'], 0, ['usage: rigidrot_campaign', '--workers',
                                             '--scheduler']),
    row('rigidrot_campaign', ['{tmp}/nope.yaml', '-o', '{tmp}/c'], 2, ['nope.yaml']),
    row('rigidrot_campaign', ['{tmp}/garbage.yaml', '-o', '{tmp}/c'], 2, ['garbage.yaml']),
    # rigidrot_mekf (the filter: test_mekf.py, test_campaign_ros.py)
    row('rigidrot_mekf', ['--help'], 0, ['usage: rigidrot_mekf', '--sigma-v']),
    row('rigidrot_mekf', ['--bogus'], 2, ['unrecognized arguments: --bogus']),
    # rigidrot_view (the views, a port in use: test/view/test_view.py)
    row('rigidrot_view', ['--help'], 0, ['usage: rigidrot_view', '--live', '--save', '--run',
                                         '--port', '--max-rate']),
    row('rigidrot_view', [], 2, ['give bag directories, a campaign directory, or --live']),
    row('rigidrot_view', ['--live', '{tmp}'], 2, ['--live takes no']),
    row('rigidrot_view', ['{tmp}/nope'], 2, ['nope', 'no such file']),
    row('rigidrot_view', ['{tmp}/garbage.yaml'], 2, ['garbage.yaml', 'not an MCAP file']),
    row('rigidrot_view', ['{tmp}/garbage.yaml', '--save', '{tmp}/x.txt'], 2, ['.rrd']),
    row('rigidrot_view', ['{tmp}/garbage.yaml', '--run', '1'], 2, ['campaign directory']),
    row('rigidrot_view', ['--port', '0', '{tmp}/garbage.yaml'], 2, ['--port 0']),
    row('rigidrot_view', ['--live', '--topic', 'odom'], 2, ['expected /name:pkg/msg/Type']),
    row('rigidrot_view', ['{tmp}/garbage.yaml'], 2, ['pip install "rigidrot_ros[view]"'],
        block=('rerun',), id='rigidrot_view without the view extra'),
]

#: The ``module:func`` of each script that a row runs with modules blocked.
ENTRY = {'attitude_node': 'rigidrot_ros.ros.attitude_node:main',
         'rigidrot_echo': 'rigidrot_ros.tools.echo:main',
         'rigidrot_bench': 'rigidrot_ros.bench.run:main',
         'rigidrot_view': 'rigidrot_ros.tools.view:main'}


@pytest.fixture
def files(tmp_path):
    (tmp_path / 'garbage.yaml').write_bytes(b'\x00\x01: [: {\n\xff\xfe')
    (tmp_path / 'other.json').write_text('{"a": 1}')
    (tmp_path / 'empty_results.json').write_text(json.dumps({'footer': {}}))
    return tmp_path


def _run(prog, args, block, env, timeout=90):
    return subprocess.run(cli_command(prog, args, block, ENTRY), env=env, cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)


@pytest.mark.ros
@pytest.mark.parametrize('prog, args, code, words, lines, block, env', CASES)
def test_command_as_typed(files, prog, args, code, words, lines, block, env):
    args = [a.replace('{tmp}', str(files)) for a in args]
    out = _run(prog, args, block, {**ros_env(next_domain_id()), **env})
    check_as_typed(out, prog, code, words, lines)


def test_every_console_script_has_a_row():
    """A console script added to setup.py without CLI rows here fails this test."""
    text = (ROOT / 'setup.py').read_text()
    scripts = {line.split('=')[0].strip().strip("'") for line in text.splitlines()
               if ' = rigidrot_ros.' in line}
    covered = {c.values[0] for c in CASES}
    others = {'rigidrot_compare', 'rigidrot_replay', 'rigidrot_demo_estimator',
              'rigidrot_record', 'rigidrot_reindex'}      # tested in test_record.py
    assert scripts - others <= covered, scripts - others - covered


def test_charts_redraw_from_results(tmp_path):
    out = _run('rigidrot_bench', ['--charts-from', 'doc/bench/results.json', '--out',
                                  str(tmp_path)], (), ros_env(next_domain_id()))
    assert out.returncode == 0, out.stdout + out.stderr
    for name in ('work_precision_query', 'work_precision_stream', 'horizon', 'stability'):
        assert (tmp_path / f'{name}.png').stat().st_size > 10000
        assert (tmp_path / f'{name}.svg').exists()
