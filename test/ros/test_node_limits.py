"""The node at its limits, in-process: delivered rate, unknown names, slow or failing scenes."""

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from rigidrot_ros.ros.attitude_node import AttitudeNode

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures('ros_context')]


def _spin(executor, seconds):
    end = rclpy.clock.Clock().now().nanoseconds + seconds * 1e9
    while rclpy.clock.Clock().now().nanoseconds < end:
        executor.spin_once(timeout_sec=0.02)


def test_diagnostics_give_the_delivered_rate_and_warn_when_it_falls_short():
    """At 1e4 Hz asked, the reported rate matches the ticks counted, and WARN iff < 90 %."""
    node = AttitudeNode(parameter_overrides=[Parameter('publish_rate', value=1e4)])
    listener = rclpy.create_node('diag_listener')
    got = []
    listener.create_subscription(DiagnosticArray, '/diagnostics', got.append, 50)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    ex.add_node(listener)
    try:
        _spin(ex, 4.5)
    finally:
        ex.shutdown()
        node.destroy_node()
        listener.destroy_node()
    rows = []
    for arr in got:
        st = arr.status[0]
        v = {kv.key: kv.value for kv in st.values}
        ns = arr.header.stamp.sec * 10 ** 9 + arr.header.stamp.nanosec
        rows.append((ns, int(v['ticks_published']), v['delivered_rate_hz'], st))
    rated = [(ns, n, float(d), st) for ns, n, d, st in rows if d]
    assert len(rated) >= 2, rows
    for (ns0, n0, _, _), (ns1, n1, d1, st1) in zip(rated, rated[1:]):
        counted = (n1 - n0) / ((ns1 - ns0) * 1e-9)
        assert d1 == pytest.approx(counted, rel=0.25), (d1, counted)
        if d1 < 9000:
            assert st1.level in (DiagnosticStatus.WARN, DiagnosticStatus.ERROR), st1
            if st1.level == DiagnosticStatus.WARN:
                assert 'delivering' in st1.message or 'bound' in st1.message or \
                    'skipped' in st1.message, st1.message
        assert st1.values[[kv.key for kv in st1.values].index('publish_rate_hz')].value \
            == '10000'


def test_unknown_names_are_refused_naming_them():
    node = AttitudeNode()
    try:
        res = node.set_parameters([Parameter('inertiaa', value=[1.0, 1.0, 1.0])])
    except Exception as exc:       # rclpy raises for undeclared names: the message names it
        text = str(exc)
    else:
        text = res[0].reason
    finally:
        node.destroy_node()
    assert 'inertiaa' in text and 'unknown parameter' in text and 'inertia,' in text, text


@pytest.mark.parametrize('params, word', [
    ({'omega0': [1e300, -0.2, 0.5]}, 'omega0'),
    ({'inertia': [2e300, 2e300, 1e300]}, 'inertia'),
    ({'inertia': [2e-300, 2e-300, 1e-300]}, 'inertia'),
    ({'torque': [1e300, 0.0, 0.0], 'torque_frame': 'virtual'}, 'torque'),
    ({'torque': [0.0, 0.0, 1e300]}, 'torque'),
    ({'omega0': [1e150, -0.2, 0.5]}, 'omega0'),
])
def test_extreme_values_are_refused_or_published_sound(params, word):
    """The issue's crashers: refused naming the parameter (nothing changes), or solved.

    If the core solves the scene, ``~/reset`` must switch to it and its samples must be
    finite unit quaternions with a finite bound.
    """
    node = AttitudeNode()
    try:
        before = {n: list(node.get_parameter(n).value) for n in ('inertia', 'torque', 'omega0')}
        model = node.solution.model
        res = node.set_parameters_atomically([Parameter(k, value=v) for k, v in params.items()])
        after = {n: list(node.get_parameter(n).value) for n in ('inertia', 'torque', 'omega0')}
        if res.successful:
            reset = node._on_reset(Trigger.Request(), Trigger.Response())
            assert reset.success, reset.message
            s = node.solution.at(np.array([0.0, 0.01]))      # the ticks the node tried
            assert np.all(np.isfinite(s.quaternion)) and np.all(np.isfinite(s.error_bound))
            assert np.allclose(np.linalg.norm(s.quaternion, axis=-1), 1.0, atol=1e-12)
            assert np.all(s.error_bound <= node.solution.tol)
        else:
            assert word in res.reason, res.reason
            assert before == after and node.solution.model == model
    finally:
        node.destroy_node()


def test_a_failing_solver_is_a_refusal_not_a_crash(monkeypatch):
    """Whatever solve() raises (here ZeroDivisionError) reaches the caller as a reason."""
    import rigidrot_ros.run.settings as mod
    node = AttitudeNode()

    def broken(*a, **k):
        raise ZeroDivisionError('float division by zero')
    monkeypatch.setattr(mod, 'solve', broken)
    try:
        res = node.set_parameters_atomically([Parameter('omega0', value=[0.1, 0.2, 0.3])])
    finally:
        node.destroy_node()
    assert not res.successful
    assert 'omega0' in res.reason and 'ZeroDivisionError' in res.reason, res.reason


def test_a_scene_too_slow_to_evaluate_is_refused(monkeypatch):
    """A first sample over the limit is refused with its cost, and the scene is unchanged."""
    import rigidrot_ros.run.settings as mod
    node = AttitudeNode()
    monkeypatch.setattr(mod, 'TRIAL_LIMIT_S', 0.0)       # every sample is "too slow"
    try:
        res = node.set_parameters_atomically([Parameter('omega0', value=[0.1, 0.2, 0.3])])
        omega0 = list(node.get_parameter('omega0').value)
    finally:
        node.destroy_node()
    assert not res.successful
    assert 'omega0' in res.reason and 'to evaluate' in res.reason, res.reason
    assert omega0 == [0.3, -0.2, 0.5]


def _diagnostics_of(node):
    """Publish one diagnostics array of ``node`` and return its status (captured, not sent)."""
    sent = []
    node._pub_diag.publish = sent.append
    node._publish_diagnostics(wait=True)
    return sent[0].status[0]


def test_diagnostics_keep_every_warn_reason():
    """A starved truth stream, skipped sensor samples and a loose bound: all three named."""
    import time
    node = AttitudeNode()
    try:
        node._rate_window = (time.monotonic() - 1.0, node._counters.published, node._period_hz)
        node._counters.skipped = 7
        node._schedule.truth.last_sample = (0.0, 1.0)
        st = _diagnostics_of(node)
        assert st.level == DiagnosticStatus.WARN
        for words in ('delivering 0 Hz', 'sensor samples skipped', 'error bound above tol'):
            assert words in st.message, st.message
        node._counters.errors, node._counters.last_error = 1, 'boom'
        node._counters.skipped = 8
        st = _diagnostics_of(node)
        assert st.level == DiagnosticStatus.ERROR
        assert 'evaluation failed: boom' in st.message and 'skipped' in st.message, st.message
    finally:
        node.destroy_node()
