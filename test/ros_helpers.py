"""Helpers for tests that touch ROS: isolated environments and real processes."""

import itertools
import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap
import time

_counter = itertools.count()


def next_domain_id():
    """Return a ROS_DOMAIN_ID not used by any earlier test of this run.

    IDs run from ``RIGIDROT_TEST_DOMAIN_BASE`` (default 1) over ``RIGIDROT_TEST_DOMAIN_SPAN``
    values (default 100), so test runs side by side on one machine can be kept apart. Under
    pytest-xdist each worker (``gw0``, ``gw1``, ...) takes its own slice of the span, so two
    workers never share a domain.
    """
    base = int(os.environ.get('RIGIDROT_TEST_DOMAIN_BASE', '1'))
    span = int(os.environ.get('RIGIDROT_TEST_DOMAIN_SPAN', '100'))
    worker = os.environ.get('PYTEST_XDIST_WORKER', '')
    workers = int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1') or 1)
    if worker.startswith('gw') and workers > 1:
        span //= workers
        base += int(worker[2:]) * span
    return base + (os.getpid() * 7 + next(_counter)) % span


def ros_env(domain_id):
    """Environment for a ROS process: this machine only, its own domain, no shm files."""
    env = dict(os.environ)
    env.update({
        'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
        'ROS_DOMAIN_ID': str(domain_id),
        # a killed process would leave Fast DDS shared-memory files behind
        'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4',
        'PYTHONUNBUFFERED': '1',
        # a process that hangs dumps every thread's stack when stop() aborts it
        'PYTHONFAULTHANDLER': '1',
    })
    env.pop('ROS_LOCALHOST_ONLY', None)
    return env


def script(name):
    """Path of a console script installed beside this interpreter."""
    path = Path(sys.executable).parent / name
    if not path.exists():
        raise FileNotFoundError(f'{name} is not installed beside {sys.executable}: '
                                f'pip install -e .')
    return str(path)


#: Runs a console script's main() with some top-level modules made unimportable, as after a
#: plain ``pip install .`` without an extra: ``python -c BLOCKER mod,mod module:func prog args``.
BLOCKER = textwrap.dedent('''
    import importlib, importlib.abc, sys
    blocked = set(sys.argv[1].split(','))

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split('.')[0] in blocked:
                raise ModuleNotFoundError(f'No module named {name!r}', name=name)
            return None

    for mod in [m for m in sys.modules if m.split('.')[0] in blocked]:
        del sys.modules[mod]
    sys.meta_path.insert(0, Block())
    module, func = sys.argv[2].split(':')
    sys.argv = [sys.argv[3]] + sys.argv[4:]
    sys.exit(getattr(importlib.import_module(module), func)())
''')


def cli_command(prog, args, block=(), entries=None):
    """Command line of console script ``prog``; with ``block``, ``entries[prog]`` under BLOCKER.

    ``entries`` maps a script's name to its ``module:func``.
    """
    if block:
        return [sys.executable, '-c', BLOCKER, ','.join(block), entries[prog], prog] + args
    return [script(prog)] + args


def check_as_typed(out, prog, code, words, lines=1):
    """Check a finished command line: status ``code``, ``words`` shown, no traceback.

    Status 0 prints usage on stdout; any other prints exactly ``lines`` lines on stderr,
    the last one starting with the program name.
    """
    both = out.stdout + out.stderr
    assert out.returncode == code, both[-3000:]
    assert 'Traceback' not in both, both[-3000:]
    for w in words:
        assert w in both, (w, both[-3000:])
    if code == 0:
        assert out.stdout.startswith('usage:'), out.stdout[:500]
    else:
        err_lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
        assert len(err_lines) == lines, out.stderr
        assert err_lines[-1].startswith(f'{prog}:'), out.stderr


def start(cmd, env, **kwargs):
    """Start a process with pipes for its output."""
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, **kwargs)


def stop(proc, sig, timeout=20.0):
    """Send ``sig`` and wait; return (returncode, stdout, stderr).

    A process still running after ``timeout`` s is sent SIGABRT first: with
    ``PYTHONFAULTHANDLER`` (:func:`ros_env`) it writes every thread's stack to its stderr,
    which the caller's assertion then shows; SIGKILL after 5 s more.
    """
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)
        try:
            out, err = proc.communicate(timeout=5.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
    return proc.returncode, out, err


def wait_for(predicate, timeout=20.0, step=0.05):
    """Poll ``predicate`` until it is true or ``timeout`` s pass; return its last value."""
    end = time.monotonic() + timeout
    value = predicate()
    while not value and time.monotonic() < end:
        time.sleep(step)
        value = predicate()
    return value


#: The scene of the in-process node tests: axisymmetric, transverse torque in the virtual frame.
NODE_SCENE = dict(inertia=[2.0, 2.0, 1.0], torque=[0.1, 0.0, 0.0], torque_frame='virtual',
                  omega0=[0.3, -0.2, 0.5], attitude0=[0.1, 0.2, 0.3, 0.9])


def attitude_node(**params):
    """Start an in-process AttitudeNode on :data:`NODE_SCENE` at 100 Hz; ``params`` override."""
    from rclpy.parameter import Parameter

    from rigidrot_ros.ros.attitude_node import AttitudeNode
    values = dict(NODE_SCENE, publish_rate=100.0)
    values.update(params)
    return AttitudeNode(parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])


def node_and_listener(listener='lis', **params):
    """Return ``(node, executor, listener)`` for an in-process test of the live node.

    ``node``: :func:`attitude_node` with ``params``, on a single-threaded ``executor``;
    ``listener``: a bare node of that name (add it to the executor once its subscriptions
    are made).
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    node = attitude_node(**params)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    return node, ex, rclpy.create_node(listener)


def start_up_error(*overrides, timeout=60):
    """Run attitude_node with ``-p`` ``overrides`` on a fresh domain until it exits.

    Return ``(returncode, stderr)``; a node still running after ``timeout`` s is stopped
    (SIGINT) and the test fails on the timeout.
    """
    cmd = [script('attitude_node'), '--ros-args']
    for override in overrides:
        cmd += ['-p', override]
    proc = start(cmd, ros_env(next_domain_id()))
    try:
        _, err = proc.communicate(timeout=timeout)
    finally:
        stop(proc, signal.SIGINT)
    return proc.returncode, err


def spin_until(executor, cond, timeout=20.0):
    """Spin ``executor`` until ``cond()`` holds; fail the test if ``timeout`` s pass first."""
    import rclpy
    end = rclpy.clock.Clock().now().nanoseconds + timeout * 1e9
    while not cond() and rclpy.clock.Clock().now().nanoseconds < end:
        executor.spin_once(timeout_sec=0.05)
    assert cond(), 'timed out'


def reset_twice(node, executor, ticks=100, timeout=30.0):
    """Let ``node`` publish ``ticks`` ticks, then ``~/reset``, twice; then 2 ``ticks`` more."""
    from std_srvs.srv import Trigger
    for _ in range(2):
        published = node._counters.published
        spin_until(executor, lambda: node._counters.published >= published + ticks, timeout)
        resp = node._on_reset(Trigger.Request(), Trigger.Response())
        assert resp.success, resp.message
    spin_until(executor, lambda: node._counters.published >= published + 2 * ticks, timeout)


def stamp_ns(msg):
    """Stamp as integer nanoseconds (a float64 of ~1.8e9 s resolves only ~2e-7 s)."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def read_node_bag(path):
    """Return a node's bag read with rosbags: (imu stamps, log times, run messages, total).

    ``total``: the messages the bag's summary counts.
    """
    from rosbags.highlevel import AnyReader
    imu, logs, runs = [], [], 0
    with AnyReader([Path(path)]) as reader:
        for conn, log_ns, raw in reader.messages():
            logs.append(log_ns)
            if conn.topic == '/imu':
                imu.append(stamp_ns(reader.deserialize(raw, conn.msgtype)))
            runs += conn.topic.endswith('/run')
        total = sum(c.msgcount for c in reader.connections)
    return imu, logs, runs, total
