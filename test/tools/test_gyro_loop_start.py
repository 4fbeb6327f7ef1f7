"""The gyro filter's start, without ROS traffic: the same answers in any arrival order.

Messages are built by hand (attitude at 100 Hz, gyro at 100 Hz with the same stamps), and
handed to the filter's callbacks in the orders a live run or a replay gives: in step, the
gyro topic matched some ticks after the attitude topic, every attitude before the first
gyro sample (a replay's burst), and the reverse. The oracle is the in-step order from the
same start: the filter must start at the first attitude stamped at or after the first gyro
sample and answer every attitude stamp from there, with the same quaternions wherever each
attitude comes before the gyro sample that covers it.
"""

from geometry_msgs.msg import QuaternionStamped
import numpy as np
import pytest
from sensor_msgs.msg import Imu

from rigidrot_ros.tools import demo_estimator as de

pytest.importorskip('ahrs')

DT = 10_000_000                                  # ns
N = 60


class _Logger:
    def __init__(self):
        self.lines = []

    def info(self, text, **_):
        self.lines.append(text)

    warning = info


class _Node:
    def __init__(self):
        self.logger = _Logger()

    def get_logger(self):
        return self.logger


class _Pub:
    def __init__(self):
        self.msgs = []

    def publish(self, msg):
        self.msgs.append(msg)


def _stamp(msg, t):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 1_000_000_000)


def _messages():
    rng = np.random.default_rng(3)
    atts, imus = [], []
    for k in range(N):
        t = 5_000_000_000 + k * DT
        a = QuaternionStamped()
        _stamp(a, t)
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        a.quaternion.x, a.quaternion.y, a.quaternion.z, a.quaternion.w = map(float, q)
        g = Imu()
        _stamp(g, t)
        g.angular_velocity.x, g.angular_velocity.y, g.angular_velocity.z = (
            0.3 + 0.01 * k, -0.2, 0.1 * np.sin(k))
        g.angular_velocity_covariance = [1e-8, 0, 0, 0, 1e-8, 0, 0, 0, 1e-8]
        atts.append(('a', a))
        imus.append(('g', g))
    return atts, imus


def _run(order):
    opts = de._parser().parse_args([])
    pubs = (_Pub(), _Pub(), _Pub())
    node = _Node()
    loop = de._GyroLoop(node, opts, pubs)
    for kind, msg in order:
        (loop.on_attitude if kind == 'a' else loop.on_imu)(msg)
    out = {de._stamp_ns(m): (m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w)
           for m in pubs[2].msgs}
    return node.logger.lines, out


def _interleaved(atts, imus):
    return [m for pair in zip(atts, imus) for m in pair]


def test_every_arrival_order_starts_at_the_same_attitude_and_answers_the_same():
    atts, imus = _messages()
    late = 5                                     # the gyro topic matched 5 ticks late
    t_start = de._stamp_ns(imus[late][1])
    ref_log, ref = _run(_interleaved(atts[late:], imus[late:]))
    assert ref_log == [f'initialised from the attitude at stamp {t_start} ns']
    assert sorted(ref) == [de._stamp_ns(m) for _, m in atts[late:]]
    orders = {
        'gyro matched late': atts[:late] + _interleaved(atts[late:], imus[late:]),
        'every attitude first (a replay)': atts + imus[late:],
        'gyro one tick ahead': (atts[:late] + [imus[late]]
                                + _interleaved(atts[late:-1], imus[late + 1:]) + atts[-1:]),
    }
    for name, order in orders.items():
        log, out = _run(order)
        assert log == ref_log, name
        assert sorted(out) == sorted(ref), name
        for t in ref:
            np.testing.assert_allclose(out[t], ref[t], rtol=0, atol=1e-15, err_msg=name)
    # every gyro sample before any attitude: the same start, every stamp answered (those
    # behind the last sample back from it, so not the same values)
    log, out = _run(imus[late:] + atts)
    assert log == ref_log and sorted(out) == sorted(ref)


def test_no_gyro_holds_at_most_1000_attitudes_and_says_why():
    atts, _ = _messages()
    many = [atts[0]] * 1001
    log, out = _run(many)
    assert out == {}
    assert any('no gyro sample on imu yet' in line for line in log)
