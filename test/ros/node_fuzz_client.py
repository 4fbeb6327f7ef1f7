"""Fuzz client for a running attitude_node (run as its own process by test_node_fuzz.py).

Usage: ``python node_fuzz_client.py NODE N SEED`` prints one JSON summary on stdout.

Sends ``N`` seeded random parameter sets through the node's parameter services
(SetParameters and SetParametersAtomically, chosen at random): magnitudes from 1e-300 to
1e300, zeros, NaN and infinities, wrong types (strings, booleans, integers, byte, boolean
and string arrays, unset values), unknown names and wrong array lengths, mixed with
plausible scenes so that many are accepted. After every accepted scene change it calls
``~/reset`` and waits for an ``attitude`` message stamped after the reset, checking it is
finite and of unit norm. It keeps its own model of the parameters (what was accepted) and
compares it with ``GetParameters`` every 100 sets and at the end: a refused change must
change nothing.
"""

import json
import math
import sys
import time

from geometry_msgs.msg import QuaternionStamped
import numpy as np
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters, SetParametersAtomically
import rclpy
from rclpy.parameter import parameter_value_to_python
from std_srvs.srv import Trigger

from rigidrot_ros.run.params import BY_NAME, PARAMS

#: Changes that take effect at the next ~/reset (the sensor settings too).
SCENE = ('inertia', 'torque', 'torque_frame', 'omega0', 'attitude0', 'tol', 'backend') + \
    tuple(n for n in BY_NAME if n.startswith(('imu.', 'star_tracker.')))
NAMES = tuple(BY_NAME)
READ_ONLY = tuple(p.name for p in PARAMS if p.read_only)
UNKNOWN = ('inertiaa', 'Torque', 'omega', 'foo.bar', 'publish-rate', 'imu.rat', 'x' * 40)
#: Run parameters put back after each set, so ticks keep coming at a checkable pace.
SANE_RUN = {'publish_rate': 100.0, 'time_scale': 1.0, 'imu.rate': 0.0,
            'star_tracker.rate': 10.0}
T = ParameterType

#: The issue's reproductions, sent first (atomically, with the default scene).
DEFAULT = {'inertia': [2.0, 2.0, 1.0], 'torque': [0.0, 0.0, 0.05], 'torque_frame': 'body',
           'omega0': [0.3, -0.2, 0.5]}
REPRODUCTIONS = [
    {'omega0': [1e300, -0.2, 0.5]}, {'inertia': [2e300, 2e300, 1e300]},
    {'inertia': [2e-300, 2e-300, 1e-300]},
    {'torque': [1e300, 0.0, 0.0], 'torque_frame': 'virtual'},
    {'torque': [1e-300, 0.0, 0.0], 'torque_frame': 'virtual'},
    {'torque': [0.0, 0.0, 1e300]}, {'omega0': [1e150, -0.2, 0.5]},
]


def _value(ptype, v):
    pv = ParameterValue(type=ptype)
    field = {T.PARAMETER_BOOL: 'bool_value', T.PARAMETER_INTEGER: 'integer_value',
             T.PARAMETER_DOUBLE: 'double_value', T.PARAMETER_STRING: 'string_value',
             T.PARAMETER_BYTE_ARRAY: 'byte_array_value',
             T.PARAMETER_BOOL_ARRAY: 'bool_array_value',
             T.PARAMETER_INTEGER_ARRAY: 'integer_array_value',
             T.PARAMETER_DOUBLE_ARRAY: 'double_array_value',
             T.PARAMETER_STRING_ARRAY: 'string_array_value'}.get(ptype)
    if field is not None:
        setattr(pv, field, v)
    return pv


def _typed(v):
    """Infer the message type of a plain python value (as rclpy would)."""
    if isinstance(v, bool):
        return T.PARAMETER_BOOL
    if isinstance(v, int):
        return T.PARAMETER_INTEGER
    if isinstance(v, float):
        return T.PARAMETER_DOUBLE
    if isinstance(v, str):
        return T.PARAMETER_STRING
    if isinstance(v, list) and v and all(isinstance(x, float) for x in v):
        return T.PARAMETER_DOUBLE_ARRAY
    raise TypeError(v)


class Gen:
    """Seeded generator of parameter values, wild and plausible."""

    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)

    def magnitude(self):
        r = self.rng.uniform()
        if r < 0.06:
            return float(self.rng.choice([math.nan, math.inf, -math.inf]))
        if r < 0.12:
            return 0.0
        if r < 0.55:
            return float(self.rng.choice([-1.0, 1.0]) * 10 ** self.rng.uniform(-300, 300))
        return float(self.rng.uniform(-3.0, 3.0))

    def vector(self, n):
        if self.rng.uniform() < 0.12:
            n = int(self.rng.integers(0, 6))
        return [self.magnitude() for _ in range(n)]

    def plausible(self, name):
        rng = self.rng
        if name == 'inertia':
            a = rng.uniform(0.5, 3.0)
            b = a * rng.uniform(0.3, 1.9) if rng.uniform() < 0.7 else a
            v = [a, a, b]
            k = int(rng.integers(3))
            return v[3 - k:] + v[:3 - k]
        if name == 'torque':
            m = 10 ** rng.uniform(-6, 0)
            return [0.0, 0.0, float(m)] if rng.uniform() < 0.5 else \
                [float(x) for x in rng.normal(size=3) * m]
        if name == 'omega0':
            return [float(x) for x in rng.uniform(-2, 2, 3)]
        if name == 'attitude0':
            return [float(x) for x in rng.normal(size=4)]
        if name == 'torque_frame':
            return str(rng.choice(['body', 'virtual']))
        if name == 'tol':
            return float(10 ** rng.uniform(-13.5, -3))
        if name == 'backend':
            return str(rng.choice(['auto', 'flint', 'mpmath']))
        if name == 'publish_rate':
            return float(rng.uniform(10, 500))
        if name == 'time_scale':
            return float(rng.uniform(0, 100))
        if name in ('frame_id', 'body_frame_id'):
            return str(rng.choice(['inertial', 'body', 'map', 'sat1/body']))
        if name == 'qos_depth':
            return int(rng.integers(1, 100))
        if name == 'record':
            return bool(rng.integers(2))
        if name == 'record_path':
            return '/tmp/x'
        if name == 'record_topics':
            return ['']
        return self.wild(name)[1]

    def typed_plausible(self, name):
        """Return ``(ptype, value)`` of a plausible value for ``name``."""
        if name == 'record_topics':
            return T.PARAMETER_STRING_ARRAY, ['']
        if name not in ('inertia', 'torque', 'omega0', 'attitude0', 'torque_frame', 'tol',
                        'backend', 'publish_rate', 'time_scale', 'frame_id',
                        'body_frame_id', 'qos_depth', 'record', 'record_path'):
            return self.wild(name)
        v = self.plausible(name)
        return _typed(v), v

    def wild(self, name):
        """Return ``(ptype, value)``: anything at all for ``name``."""
        rng = self.rng
        r = rng.uniform()
        size = {'inertia': 3, 'torque': 3, 'omega0': 3, 'attitude0': 4}.get(name, 1)
        if r < 0.45:
            v = self.vector(size) if size > 1 else self.magnitude()
            return (T.PARAMETER_DOUBLE_ARRAY if isinstance(v, list) else T.PARAMETER_DOUBLE), v
        choices = [
            (T.PARAMETER_STRING, str(rng.choice(['', 'abc', 'body', 'virtual', 'nan', '1e300',
                                                 'flint', '\u00e9\u00e8', ' ']))),
            (T.PARAMETER_BOOL, bool(rng.integers(2))),
            (T.PARAMETER_INTEGER, int(rng.choice([0, 1, -1, 3, 2 ** 62, -2 ** 63]))),
            (T.PARAMETER_INTEGER_ARRAY, [int(x) for x in rng.integers(-5, 5, size)]),
            (T.PARAMETER_BOOL_ARRAY, [bool(x) for x in rng.integers(0, 2, size)]),
            (T.PARAMETER_STRING_ARRAY, ['a'] * size),
            (T.PARAMETER_BYTE_ARRAY, [bytes([int(x)]) for x in rng.integers(0, 256, size)]),
            (T.PARAMETER_DOUBLE_ARRAY, []),
            (T.PARAMETER_NOT_SET, None),
        ]
        return choices[int(rng.integers(len(choices)))]

    def param_set(self):
        """Return a list of ``(name, ptype, value)``: one to four parameters."""
        rng = self.rng
        k = int(rng.integers(1, 5))
        w = np.array([0.2 if n in READ_ONLY else 1.0 for n in NAMES])
        names = list(rng.choice(NAMES, size=k, replace=False, p=w / w.sum()))
        if rng.uniform() < 0.08:
            names[0] = str(rng.choice(UNKNOWN))
        plausible = rng.uniform() < 0.5
        out = []
        for name in names:
            if plausible and name in NAMES and rng.uniform() < 0.9:
                out.append((name,) + self.typed_plausible(name))
            else:
                out.append((name,) + self.wild(name))
        return out


class Client:
    """Service clients and a subscriber on the node under test."""

    def __init__(self, target):
        self.node = rclpy.create_node('fuzz_client')
        n = self.node
        self.set = n.create_client(SetParameters, f'{target}/set_parameters')
        self.atomic = n.create_client(SetParametersAtomically,
                                      f'{target}/set_parameters_atomically')
        self.get = n.create_client(GetParameters, f'{target}/get_parameters')
        self.reset = n.create_client(Trigger, f'{target}/reset')
        for c in (self.set, self.atomic, self.get, self.reset):
            if not c.wait_for_service(timeout_sec=30):
                raise SystemExit(f'service {c.srv_name} not available')
        self.msgs = []
        n.create_subscription(QuaternionStamped, 'attitude', self.msgs.append, 50)

    def call(self, client, req, timeout=120.0):
        fut = client.call_async(req)
        rclpy.spin_until_future_complete(self.node, fut, timeout_sec=timeout)
        if not fut.done():
            raise TimeoutError(f'{client.srv_name} did not answer in {timeout} s')
        return fut.result()

    def get_all(self):
        res = self.call(self.get, GetParameters.Request(names=list(NAMES)))
        return {n: parameter_value_to_python(v) for n, v in zip(NAMES, res.values)}

    def send(self, params, atomic):
        msgs = [ParameterMsg(name=n, value=_value(t, v)) for n, t, v in params]
        if atomic:
            r = self.call(self.atomic, SetParametersAtomically.Request(parameters=msgs))
            return [r.result] * len(params)
        return list(self.call(self.set, SetParameters.Request(parameters=msgs)).results)

    def wait_sample(self, after_ns, timeout=10.0):
        """Return the first attitude stamped at or after ``after_ns``, or None."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            rclpy.spin_once(self.node, timeout_sec=0.02)
            while self.msgs:
                m = self.msgs.pop(0)
                if m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec >= after_ns:
                    q = m.quaternion
                    return [q.x, q.y, q.z, q.w]
        return None


def _same(a, b):
    if isinstance(a, (list, tuple)) or isinstance(b, (list, tuple)):
        return a is not None and b is not None and list(a) == list(b)
    return a == b


def _step(cl, i, params, atomic, expected, out):
    """Send one parameter set; on success restore the run rates, reset and check a sample."""
    results = cl.send(params, atomic)
    changed = set()
    for (name, ptype, value), r in zip(params, results):
        if r.successful:
            expected[name] = parameter_value_to_python(_value(ptype, value))
            changed.add(name)
        else:
            sent = [p[0] for p in params] if atomic else [name]
            if not any(s in r.reason for s in sent):
                out['unnamed_reasons'].append([i, sent, r.reason])
            key = r.reason.split(':')[0][:60]
            out['reasons'][key] = out['reasons'].get(key, 0) + 1
    if atomic:
        out['accepted' if results[0].successful else 'rejected'] += 1
    else:
        out['accepted'] += sum(r.successful for r in results)
        out['rejected'] += sum(not r.successful for r in results)
    restore = [(k, T.PARAMETER_DOUBLE, v) for k, v in SANE_RUN.items()
               if not _same(expected.get(k), v)]
    if restore:
        rr = cl.send(restore, True)[0]
        if not rr.successful:
            out['state_mismatch'].append([i, 'restore refused', rr.reason])
        else:
            expected.update({k: v for k, _t, v in restore})
    if not changed & set(SCENE):
        return
    stamp = time.time_ns()
    res = cl.call(cl.reset, Trigger.Request())
    out['resets'] += 1
    if not res.success:
        out['reset_refused'].append([i, [p[0] for p in params], res.message])
        return
    q = cl.wait_sample(stamp)
    if q is None:
        out['silent'].append([i, {k: expected[k] for k in SCENE}])
        return
    out['samples_checked'] += 1
    if not (all(math.isfinite(x) for x in q) and abs(math.hypot(*q) - 1) < 1e-9):
        out['bad_quaternions'].append([i, q])


def main():
    target, n, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    rclpy.init()
    cl = Client(target)
    gen = Gen(seed)
    expected = cl.get_all()
    out = {'sets': 0, 'accepted': 0, 'rejected': 0, 'resets': 0, 'samples_checked': 0,
           'unnamed_reasons': [], 'reset_refused': [], 'silent': [], 'bad_quaternions': [],
           'state_mismatch': [], 'stuck': None, 'by_service': {'atomic': 0, 'each': 0},
           'reasons': {}}
    t0 = time.monotonic()
    history = []
    plan = [([(k, _typed(v), v) for k, v in {**DEFAULT, **r}.items()], True)
            for r in REPRODUCTIONS]
    plan += [(None, None)] * n
    for i, (params, atomic) in enumerate(plan):
        if params is None:
            params, atomic = gen.param_set(), bool(gen.rng.integers(2))
        out['sets'] += 1
        history.append([i, repr(params), atomic])
        out['by_service']['atomic' if atomic else 'each'] += 1
        try:
            _step(cl, i, params, atomic, expected, out)
            if i % 100 == 99 or i == len(plan) - 1:
                actual = cl.get_all()
                for k in NAMES:
                    if not _same(actual[k], expected[k]):
                        out['state_mismatch'].append([i, k, repr(actual[k]),
                                                      repr(expected[k])])
                        expected[k] = actual[k]
        except TimeoutError as exc:
            out['stuck'] = [i, str(exc), history[-4:], expected]
            break
    out['seconds'] = time.monotonic() - t0
    print(json.dumps(out, default=repr))
    cl.node.destroy_node()
    rclpy.try_shutdown()


if __name__ == '__main__':
    main()
