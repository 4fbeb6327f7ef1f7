"""Helpers for tests that touch ROS: isolated environments and real processes."""

import itertools
import os
from pathlib import Path
import subprocess
import sys
import time

_counter = itertools.count()


def next_domain_id():
    """Return a ROS_DOMAIN_ID not used by any earlier test of this run.

    IDs run from ``RIGIDROT_TEST_DOMAIN_BASE`` (default 1) over ``RIGIDROT_TEST_DOMAIN_SPAN``
    values (default 100), so test runs side by side on one machine can be kept apart.
    """
    base = int(os.environ.get('RIGIDROT_TEST_DOMAIN_BASE', '1'))
    span = int(os.environ.get('RIGIDROT_TEST_DOMAIN_SPAN', '100'))
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


def start(cmd, env, **kwargs):
    """Start a process with pipes for its output."""
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, **kwargs)


def stop(proc, sig, timeout=20.0):
    """Send ``sig`` and wait; return (returncode, stdout, stderr)."""
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        out, err = proc.communicate(timeout=timeout)
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
    """An in-process AttitudeNode on :data:`NODE_SCENE` at 100 Hz; ``params`` override any."""
    from rclpy.parameter import Parameter

    from rigidrot_ros.node.attitude_node import AttitudeNode
    values = dict(NODE_SCENE, publish_rate=100.0)
    values.update(params)
    return AttitudeNode(parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])


def spin_until(executor, cond, timeout=20.0):
    """Spin ``executor`` until ``cond()`` holds; fail the test if ``timeout`` s pass first."""
    import rclpy
    end = rclpy.clock.Clock().now().nanoseconds + timeout * 1e9
    while not cond() and rclpy.clock.Clock().now().nanoseconds < end:
        executor.spin_once(timeout_sec=0.05)
    assert cond(), 'timed out'


def stamp_ns(msg):
    """Stamp as integer nanoseconds (a float64 of ~1.8e9 s resolves only ~2e-7 s)."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
