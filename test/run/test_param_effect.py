"""Every parameter of the table has an effect: set away from its default, something changes.

Data-driven over :data:`rigidrot_ros.run.params.PARAMS`, so a new parameter that does nothing
fails here. For each parameter, two runs differ in that parameter alone: one with it at its
default, one with it away from it (:func:`away`: a value of the table's type and range,
unless :data:`AWAY` gives one). Both share :data:`BASE` (every output on, every noise term
on, so that seeds, correlation times and quanta have something to act on) and the
parameter's :data:`CONTEXT`. The value away must be accepted; the two generated runs
(``iter_run``: the bag's messages, without the run description, which echoes every
parameter; and the model and method that evaluate the scene) must differ, or the
default's run must be refused where the other is not.
The parameters that act in the node only (:data:`NODE_ONLY`: recording, QoS) are checked
on an in-process node: its publishers (topic, depth), its subscriptions and the files it
writes.
"""

import json
import os

import pytest

from rigidrot_ros.run import params
from rigidrot_ros.run.generate import GenerationError, iter_run, RUN_TOPIC

#: Every output and every noise term on.
BASE = {
    'imu.enable': True, 'accel.enable': True, 'mag.enable': True, 'star_tracker.enable': True,
    'odom.enable': True, 'transform.enable': True, 'markers.enable': True,
    'imu.rate': 200.0, 'star_tracker.rate': 20.0, 'mag.rate': 50.0,
    'accel.noise_density': 1e-3, 'accel.random_walk': 1e-4, 'mag.noise_density': 1e-8,
    'imu.gyro_bias_instability': 1e-3, 'accel.bias_instability': 1e-3,
    'accel.gravity': [0.0, 0.0, -9.80665],  # a specific force for scale and misalignment
}
#: Scene seconds generated per run, and for the parameters that need longer.
DURATION = 0.2
DURATIONS = {'tol': 2.0}                    # a tighter tol shows after a second or so
#: Parameters that act in the node alone: checked on the node, not in a generated bag.
NODE_ONLY = ('record', 'record_path', 'record_topics', 'qos_depth')
#: Values away from the default where the table's type and range alone give none that acts.
KALIBR = ('accelerometer_noise_density: 1.0e-3\naccelerometer_random_walk: 1.0e-4\n'
          'gyroscope_noise_density: 3.0e-4\ngyroscope_random_walk: 2.0e-5\n'
          'update_rate: 200.0\nrostopic: /imu0\n')
AWAY = {
    'inertia': [2.5, 2.5, 1.0],             # axially symmetric, as the torque asks
    'torque': [0.0, 0.0, 0.1],
    'backend': 'mpmath',                    # 'auto' takes flint where it can
    'tol': params.BY_NAME['tol'].range[0],  # looser changes no bit of a short run
    'imu.kalibr_yaml': lambda tmp: _kalibr(tmp),
}
#: Suffixes whose generic value (a small step) would act on no sample of a short run.
AWAY_BY_SUFFIX = {'.drop_probability': 0.9}
#: Parameters whose effect needs another value besides: given to both runs.
CONTEXT = {
    'imu.enable': {'accel.enable': False},  # the accelerometer rides in imu
    'torque_frame': {'torque': [0.05, 0.0, 0.0]},   # a torque across the symmetry axis
    'tol': {'time_scale': 10.0},            # DURATIONS['tol'] in 0.2 s of clock
    'record_path': {'record': True},
    'record_topics': {'record': True},
}


def _kalibr(tmp):
    path = os.path.join(tmp, 'kalibr_imu.yaml')
    with open(path, 'w', encoding='utf-8') as fh:
        fh.write(KALIBR)
    return path


def away(p, tmp):
    """Return a value of parameter ``p`` away from its default that its validator accepts."""
    if p.name in AWAY:
        v = AWAY[p.name]
        return v(tmp) if callable(v) else v
    for suffix, v in AWAY_BY_SUFFIX.items():
        if p.name.endswith(suffix):
            return v
    d = p.default
    if p.type == 'bool':
        return not d
    if p.choices:
        return next(c for c in p.choices if c != d)
    if p.type == 'integer':
        return d + 1 if d + 1 <= p.range[1] else d - 1
    if p.type == 'double':
        lo, hi = p.range
        for v in (d * 2.0, d + (hi - lo) * 1e-3, (lo + hi) / 2.0):
            if v != d and lo <= v <= hi:
                return v
    if p.type == 'double[]':
        v = list(d)
        v[min(1, len(v) - 1)] += 1e-3
        return v
    if p.type == 'string':
        return f'{d}_x' if d else 'x'
    if p.type == 'string[]':
        return ['/param_effect:std_msgs/msg/String']
    raise AssertionError(f'no value away from the default for {p.name} ({p.type})')


_cache = {}


def _generated(values, duration=DURATION):
    """What a generated run shows: its messages and how its solution is evaluated.

    ``(messages, (model, method))``: the messages ``(topic, log_ns, msg)`` without ``~/run``
    (its description echoes every parameter), and the description's model and method (the
    backend changes the method, not the bits); or ``('refused', reason)``.
    """
    key = repr((duration, sorted(values.items())))
    if key not in _cache:
        try:
            msgs = list(iter_run(values, duration))
            run = json.loads(next(m for t, _, m in msgs if t == RUN_TOPIC).data)
            _cache[key] = ([m for m in msgs if m[0] != RUN_TOPIC],
                           (run['model'], run['method']))
        except GenerationError as exc:
            _cache[key] = ('refused', str(exc))
    return _cache[key]


def _node(values, cwd):
    """What an in-process node with ``values`` publishes, subscribes to and writes."""
    from rclpy.parameter import Parameter

    from rigidrot_ros.ros.attitude_node import AttitudeNode
    os.makedirs(cwd)
    before = os.getcwd()
    os.chdir(cwd)
    try:
        node = AttitudeNode(parameter_overrides=[Parameter(k, value=v)
                                                 for k, v in values.items()])
        try:
            out = (sorted((p.topic_name, p.qos_profile.depth) for p in node.publishers),
                   sorted(s.topic_name for s in node.subscriptions))
        finally:
            node.destroy_node()
        return out + (sorted(os.listdir(cwd)),)
    finally:
        os.chdir(before)


@pytest.mark.parametrize('name', [p.name for p in params.PARAMS])
def test_a_parameter_away_from_its_default_changes_the_run(name, tmp_path, request):
    p = params.BY_NAME[name]
    value = away(p, str(tmp_path))
    assert p.check(value) is not None and value != p.default
    context = CONTEXT.get(name, {})
    if name in NODE_ONLY:
        request.getfixturevalue('ros_context')
        default = _node(dict(context, **{name: p.default}), str(tmp_path / 'default'))
        changed = _node(dict(context, **{name: value}), str(tmp_path / 'away'))
        assert default != changed, f'{name} = {value!r} changes nothing the node does'
        return
    base = dict(BASE, **context)
    duration = DURATIONS.get(name, DURATION)
    default = _generated(dict(base, **{name: p.default}), duration)
    changed = _generated(dict(base, **{name: value}), duration)
    assert not (isinstance(changed, tuple) and changed[0] == 'refused'), \
        f'{name} = {value!r} is refused: {changed[1]}'
    assert changed != default, \
        f'{name} = {value!r} changes no message of the run, nor how it is evaluated'


def test_every_parameter_is_checked_one_way():
    """The node-only list and the table of values name parameters that exist."""
    names = set(params.BY_NAME)
    for table in (NODE_ONLY, AWAY, CONTEXT, DURATIONS):
        assert set(table) <= names, set(table) - names
