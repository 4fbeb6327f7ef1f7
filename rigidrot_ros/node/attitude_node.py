"""attitude_node: publish the exact attitude and body rate of the configured scene.

Topics (relative names, so namespaces and remapping apply):
- ``attitude`` (geometry_msgs/QuaternionStamped): ``q_NB``, (x, y, z, w), header.frame_id
  = ``frame_id`` (the inertial frame N).
- ``angular_velocity`` (geometry_msgs/Vector3Stamped): omega of B relative to N, in B,
  rad/s, header.frame_id = ``body_frame_id``.
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) at 1 Hz.
Service ``~/reset`` (std_srvs/Trigger): restart at t = 0 from the current parameters.

Both messages of a tick carry the same stamp: the clock time that the scene time
``t = (now - t_start) * time_scale`` was computed for (``use_sim_time`` works).
"""

import importlib
import math
import sys
import textwrap
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rcl_interfaces.msg import ParameterType, SetParametersResult
import rclpy
from rclpy.exceptions import ParameterException, ParameterNotDeclaredException
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from std_srvs.srv import Trigger

from rigidrot_ros import __version__
from rigidrot_ros.core import NoExactSolution, PrecisionError, solve
from rigidrot_ros.io.bag import BagWriter, qos_yaml
from rigidrot_ros.node.spin import init_ros, spin_until_shutdown, split_ros_args
from rigidrot_ros.settings import load_defaults, scene_from_params, SCENE_KEYS, solver_options

__all__ = ['AttitudeNode', 'main', 'SceneError']

_DOUBLE_ARRAY = ParameterType.PARAMETER_DOUBLE_ARRAY
_DESCRIPTIONS = {
    'inertia': ('principal moments of inertia [I1, I2, I3], kg m^2 (positive, triangle '
                'inequality); applied at the next ~/reset', _DOUBLE_ARRAY),
    'torque': ('constant torque [m1, m2, m3], N m, components in torque_frame; applied at '
               'the next ~/reset', _DOUBLE_ARRAY),
    'torque_frame': ("'body' (torque fixed in B) or 'virtual' (fixed in the virtual-sphere "
                     'frame S, Theorem 3); applied at the next ~/reset',
                     ParameterType.PARAMETER_STRING),
    'omega0': ('initial angular velocity [p0, q0, r0] of B relative to N, in B, rad/s; '
               'applied at the next ~/reset', _DOUBLE_ARRAY),
    'attitude0': ('initial attitude q_NB [x, y, z, w] (rotates body vectors into N), '
                  'normalised; applied at the next ~/reset', _DOUBLE_ARRAY),
    'tol': ('attitude accuracy asked of the exact solution, rad; applied at the next '
            '~/reset', ParameterType.PARAMETER_DOUBLE),
    'backend': ("special functions: 'auto', 'flint' (Arb, certified) or 'mpmath'; applied "
                'at the next ~/reset', ParameterType.PARAMETER_STRING),
    'publish_rate': ('timer rate, Hz', ParameterType.PARAMETER_DOUBLE),
    'time_scale': ('scene seconds per clock second; applied at the next ~/reset',
                   ParameterType.PARAMETER_DOUBLE),
    'frame_id': ('header.frame_id of attitude: the inertial frame N',
                 ParameterType.PARAMETER_STRING),
    'body_frame_id': ('header.frame_id of angular_velocity: the body frame B',
                      ParameterType.PARAMETER_STRING),
    'qos_depth': ('history depth of the publishers (read only)',
                  ParameterType.PARAMETER_INTEGER),
    'record': ('write every published message to an MCAP bag (read only)',
               ParameterType.PARAMETER_BOOL),
    'record_path': ('directory under which each run gets a new bag directory (read only)',
                    ParameterType.PARAMETER_STRING),
    'record_topics': ('further topics to record raw as they arrive, e.g. an estimator '
                      'output (read only)', ParameterType.PARAMETER_STRING_ARRAY),
}
_READ_ONLY = ('qos_depth', 'record', 'record_path', 'record_topics')
_RANGES = {
    'tol': FloatingPointRange(from_value=2e-14, to_value=1.0),
    'publish_rate': FloatingPointRange(from_value=1e-3, to_value=1e4),
    'time_scale': FloatingPointRange(from_value=0.0, to_value=1e9),
}


class SceneError(ValueError):
    """The parameters at start-up are invalid or do not describe a solvable scene."""


class UnknownParameterError(ParameterNotDeclaredException):
    """A parameter name the node does not declare; the message names it and the known ones."""

    def __init__(self, names, known):
        Exception.__init__(self, f'unknown parameter(s) {", ".join(map(str, names))}: '
                                 f'attitude_node declares {", ".join(known)}')


def _check_run_params(p):
    """Validate the non-scene parameters; ValueError names the parameter and the rule."""
    for name in ('publish_rate', 'time_scale'):
        v = p[name]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f'parameter {name} must be a finite number, got {v!r}')
        r = _RANGES[name]
        if not r.from_value <= v <= r.to_value:
            raise ValueError(f'parameter {name} must lie in [{r.from_value}, {r.to_value}], '
                             f'got {v!r}')
    if p['publish_rate'] <= 0:
        raise ValueError('parameter publish_rate must be positive')
    for name in ('frame_id', 'body_frame_id'):
        if not isinstance(p[name], str) or not p[name]:
            raise ValueError(f'parameter {name} must be a non-empty string, got {p[name]!r}')
    d = p['qos_depth']
    if isinstance(d, bool) or not isinstance(d, int) or not 1 <= d <= 10000:
        raise ValueError(f'parameter qos_depth must be an integer in [1, 10000], got {d!r}')


def build_solution(p):
    """Validate parameters and return the core :class:`Solution` (ValueError otherwise)."""
    _check_run_params(p)
    scene = scene_from_params(p)
    tol, backend = solver_options(p)
    try:
        return solve(scene, tol=tol, backend=backend)
    except NoExactSolution as exc:
        raise ValueError(f'no exact solution for this scene: {exc}') from None
    except PrecisionError as exc:
        raise ValueError(f'the scene cannot be evaluated to tol: {exc}') from None
    except Exception as exc:        # whatever else the core raises: refuse the scene
        raise ValueError(f'the scene cannot be solved: {type(exc).__name__}: {exc} (inertia '
                         f'{list(scene.inertia)}, torque {list(scene.torque)}, omega0 '
                         f'{list(scene.omega0)}; magnitudes this far from 1 are out of '
                         'range)') from None


class _Stats:
    """Evaluation times and tick accounting for the diagnostics."""

    def __init__(self):
        self.times = []
        self.published = 0
        self.late = 0
        self.missed = 0
        self.last_tick = None
        self.errors = 0
        self.last_error = ''

    def window(self):
        t = np.array(self.times) if self.times else np.zeros(1)
        self.times = []
        return float(t.mean()), float(np.percentile(t, 99)), float(t.max())


class AttitudeNode(Node):
    """Publishes the exact attitude and body angular velocity of a rigid body."""

    def __init__(self, **kwargs):
        super().__init__('attitude_node', **kwargs)
        defaults = load_defaults()
        for name, (text, ptype) in _DESCRIPTIONS.items():
            desc = ParameterDescriptor(description=text, type=ptype,
                                       read_only=(name in _READ_ONLY), dynamic_typing=True)
            if name in _RANGES:
                desc.floating_point_range = [_RANGES[name]]
            if name == 'qos_depth':
                desc.integer_range = [IntegerRange(from_value=1, to_value=10000, step=1)]
            value = defaults[name]
            if name == 'record_topics' and not value:
                value = ['']      # an empty list carries no type; empty names are ignored
            try:
                self.declare_parameter(name, value, desc)
            except ParameterException as exc:      # an override outside its declared range
                raise SceneError(f'parameter {name}: {exc}') from None
        try:
            self._solution = build_solution(self._values())
        except ValueError as exc:
            raise SceneError(str(exc)) from None
        self._time_scale = float(self.get_parameter('time_scale').value)
        self._t_start = None
        self._last_sample = None
        self._stats = _Stats()
        self.add_on_set_parameters_callback(self._on_set)
        qos = QoSProfile(depth=self.get_parameter('qos_depth').value,
                         reliability=ReliabilityPolicy.RELIABLE)
        self._pub_att = self.create_publisher(QuaternionStamped, 'attitude', qos)
        self._pub_rate = self.create_publisher(Vector3Stamped, 'angular_velocity', qos)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self._bag = None
        self._run_index = 0
        self._extra = {}
        if self.get_parameter('record').value:
            self._start_recording(qos.depth)
        self._timer = None
        self._make_timer(self.get_parameter('publish_rate').value)
        self._diag_timer = self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(
            f'running model {self._solution.model} ({self._solution.method}) at '
            f'{self._period_hz:g} Hz')

    # -- parameters -------------------------------------------------------------------------
    def _values(self, overrides=()):
        p = {name: self.get_parameter(name).value for name in _DESCRIPTIONS}
        for param in overrides:
            p[param.name] = param.value
        return p

    def set_parameters(self, parameter_list):
        """Set parameters one by one (rclpy), naming any undeclared one in the error."""
        self._refuse_undeclared(parameter_list)
        return super().set_parameters(parameter_list)

    def set_parameters_atomically(self, parameter_list):
        """Set parameters all at once (rclpy), naming any undeclared one in the error.

        The parameter services call this; rclpy's own check reports an undeclared name as
        ``Invalid access to undeclared parameter(s): []``.
        """
        self._refuse_undeclared(parameter_list)
        return super().set_parameters_atomically(parameter_list)

    def _refuse_undeclared(self, parameter_list):
        unknown = [getattr(p, 'name', p) for p in parameter_list
                   if not self.has_parameter(getattr(p, 'name', ''))]
        if unknown:
            raise UnknownParameterError(unknown, sorted(_DESCRIPTIONS))

    def _on_set(self, params):
        """Validate a change against the whole scene; refuse with a reason naming it."""
        names = [p.name for p in params]
        try:
            reason = self._check_change(params, names)
        except Exception as exc:        # never let a parameter change kill the node
            reason = f'{type(exc).__name__}: {exc}'
        if reason is None:
            if 'publish_rate' in names:
                self._make_timer(float(self._values(params)['publish_rate']))
            return SetParametersResult(successful=True)
        if not any(n in reason for n in names):
            reason = f'parameter(s) {", ".join(names)}: {reason}'
        return SetParametersResult(successful=False, reason=reason)

    def _check_change(self, params, names):
        """Return None if ``params`` may be set, else the reason (str)."""
        unknown = [n for n in names if n not in _DESCRIPTIONS and not self.has_parameter(n)]
        if unknown:
            return str(UnknownParameterError(unknown, sorted(_DESCRIPTIONS)))
        for p in params:
            if p.type_ == Parameter.Type.NOT_SET:
                return f'parameter {p.name} cannot be unset (it would be undeclared)'
        if not any(n in _DESCRIPTIONS for n in names):
            return None                 # rclpy's own (use_sim_time, ...): rclpy checks them
        candidate = self._values(params)
        try:
            if any(n in SCENE_KEYS or n in ('tol', 'backend') for n in names):
                build_solution(candidate)          # validate the whole scene, keep running
            else:
                _check_run_params(candidate)
        except ValueError as exc:
            return str(exc)
        return None

    def _make_timer(self, rate):
        if self._timer is not None:
            self.destroy_timer(self._timer)
        self._period_hz = float(rate)
        self._period = 1.0 / float(rate)
        self._timer = self.create_timer(self._period, self._tick)

    # -- publishing -------------------------------------------------------------------------
    def _tick(self):
        now = self.get_clock().now()
        st = self._stats
        if st.last_tick is not None:
            gap = (now - st.last_tick).nanoseconds * 1e-9
            if gap > 1.5 * self._period:
                st.late += 1
                st.missed += max(0, int(round(gap / self._period)) - 1)
        st.last_tick = now
        if self._t_start is None:
            self._t_start = now
        t = (now - self._t_start).nanoseconds * 1e-9 * self._time_scale
        c0 = time.perf_counter()
        try:
            s = self._solution.at(t)
        except Exception as exc:        # PrecisionError, or anything else: report, keep going
            st.errors += 1
            st.last_error = str(exc) if isinstance(exc, (PrecisionError, ValueError)) else \
                f'{type(exc).__name__}: {exc}'
            self.get_logger().error(f'evaluation failed at t = {t} s: {st.last_error}',
                                    throttle_duration_sec=1.0)
            return
        st.times.append(time.perf_counter() - c0)
        stamp = now.to_msg()
        att = QuaternionStamped()
        att.header.stamp = stamp
        att.header.frame_id = self.get_parameter('frame_id').value
        qx, qy, qz, qw = (float(v) for v in s.quaternion)
        att.quaternion.x, att.quaternion.y, att.quaternion.z, att.quaternion.w = qx, qy, qz, qw
        rate = Vector3Stamped()
        rate.header.stamp = stamp
        rate.header.frame_id = self.get_parameter('body_frame_id').value
        rate.vector.x, rate.vector.y, rate.vector.z = (float(v) for v in s.omega)
        try:
            self._pub_att.publish(att)
            self._pub_rate.publish(rate)
        except _rclpy.RCLError:
            if self.context.ok():
                raise
            return                  # shut down (SIGINT/SIGTERM) while this tick ran
        st.published += 1
        self._last_sample = (t, s)
        if self._bag is not None:
            self._record_tick(now, att, rate, now == self._t_start)

    def _publish_diagnostics(self):
        st = self._stats
        mean, p99, mx = st.window()
        sol = self._solution
        bound = float(self._last_sample[1].error_bound) if self._last_sample else 0.0
        level, msg = DiagnosticStatus.OK, f'exact solution: {sol.model}'
        if mx > self._period:
            level, msg = DiagnosticStatus.WARN, 'evaluation slower than the timer period'
        delivered = self._delivered_rate()
        if delivered is not None and delivered < 0.9 * self._period_hz:
            level, msg = DiagnosticStatus.WARN, (
                f'delivering {delivered:.4g} Hz of the {self._period_hz:g} Hz asked '
                '(publish_rate beyond what this machine and executor deliver)')
        if bound > sol.tol:
            level, msg = DiagnosticStatus.WARN, 'error bound above tol'
        if st.errors:
            level, msg = DiagnosticStatus.ERROR, f'evaluation failed: {st.last_error}'
            st.errors = 0
        values = {
            'model': sol.model, 'method': sol.method, 'backend': sol.backend,
            'working_precision_bits': str(sol.precision), 'tol_rad': f'{sol.tol:.3g}',
            'error_bound_rad': f'{bound:.3g}',
            'scene_time_s': f'{self._last_sample[0]:.6f}' if self._last_sample else '',
            'eval_mean_us': f'{mean * 1e6:.1f}', 'eval_p99_us': f'{p99 * 1e6:.1f}',
            'eval_max_us': f'{mx * 1e6:.1f}', 'ticks_published': str(st.published),
            'ticks_late': str(st.late), 'ticks_missed': str(st.missed),
            'publish_rate_hz': f'{self._period_hz:g}',
            'delivered_rate_hz': '' if delivered is None else f'{delivered:.4g}',
        }
        status = DiagnosticStatus(level=level, name=f'{self.get_name()}: exact attitude',
                                  message=msg, hardware_id=self.get_fully_qualified_name())
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [status]
        self._pub_diag.publish(arr)

    def _delivered_rate(self):
        """Ticks published per second since the last call (steady clock), or None.

        None while the window is shorter than 0.5 s or holds fewer than 5 periods at the
        asked rate (too few ticks to judge), and for the first window after a rate change.
        """
        now, count = time.monotonic(), self._stats.published
        last = getattr(self, '_rate_window', None)
        self._rate_window = (now, count, self._period_hz)
        if last is None or last[2] != self._period_hz:
            return None
        span = now - last[0]
        if span < 0.5 or span * self._period_hz < 5:
            self._rate_window = last            # keep accumulating
            return None
        return (count - last[1]) / span

    # -- recording --------------------------------------------------------------------------
    def _start_recording(self, depth):
        path = self.get_parameter('record_path').value or 'runs'
        try:
            self._bag = BagWriter(path, self.get_name())
            for pub, type_name in ((self._pub_att, 'geometry_msgs/msg/QuaternionStamped'),
                                   (self._pub_rate, 'geometry_msgs/msg/Vector3Stamped')):
                self._bag.add_topic(pub.topic_name, type_name, qos_yaml(depth=depth))
        except OSError as exc:
            raise SceneError(f'cannot record to {path!r}: {exc}') from None
        self.get_logger().info(f'recording to {self._bag.path}')
        topics = [t for t in (self.get_parameter('record_topics').value or []) if t]
        if topics:
            self._extra = {self.resolve_topic_name(t): None for t in topics}
            self._discover_timer = self.create_timer(0.5, self._discover_topics)

    def _discover_topics(self):
        """Subscribe (raw) to each record_topics entry once its type is known."""
        types = dict(self.get_topic_names_and_types())
        for topic, sub in self._extra.items():
            if sub is not None or topic not in types:
                continue
            type_name = types[topic][0]
            pkg, _, name = type_name.split('/')
            try:
                cls = getattr(importlib.import_module(f'{pkg}.msg'), name)
                self._bag.add_topic(topic, type_name, qos_yaml(depth=100))
            except (ImportError, AttributeError, OSError) as exc:
                self.get_logger().error(f'cannot record {topic} ({type_name}): {exc}')
                self._extra[topic] = False
                continue
            self._extra[topic] = self.create_subscription(
                cls, topic, lambda data, tp=topic: self._record_raw(tp, data), 100, raw=True)
            self.get_logger().info(f'recording {topic} ({type_name})')

    def _record_raw(self, topic, data):
        if self._bag is not None:
            self._guard(lambda: self._bag.write(topic, data,
                                                self.get_clock().now().nanoseconds))

    def _record_tick(self, now, att, rate, first):
        ns = now.nanoseconds

        def write():
            if first:
                self._run_index += 1
                sol = self._solution
                self._bag.add_run({
                    'run': self._run_index, 'start_ns': ns, 'time_scale': self._time_scale,
                    'scene': sol.scene.as_dict(), 'tol': sol.tol, 'backend': sol.backend,
                    'model': sol.model, 'method': sol.method,
                    'package': f'rigidrot_ros {__version__}',
                    'node': self.get_fully_qualified_name(),
                    'topics': {'attitude': self._pub_att.topic_name,
                               'angular_velocity': self._pub_rate.topic_name},
                })
            self._bag.write(self._pub_att.topic_name, serialize_message(att), ns)
            self._bag.write(self._pub_rate.topic_name, serialize_message(rate), ns)
        self._guard(write)

    def _guard(self, fn):
        try:
            fn()
        except OSError as exc:   # disk full, removed directory: stop recording, keep running
            self.get_logger().error(f'recording stopped: {exc}')
            try:
                self._bag.close()
            except (OSError, ValueError):
                pass
            self._bag = None

    def destroy_node(self):
        """Finish the bag (summary, index, metadata.yaml), then destroy the node."""
        if self._bag is not None:
            try:
                self._bag.close()
                # the context may be shut down already: no rosout logging here
                print(f'attitude_node: bag finished: {self._bag.path} {self._bag.counts}, '
                      f'published {self._stats.published} ticks', file=sys.stderr)
            except OSError as exc:
                print(f'attitude_node: could not finish the bag: {exc}', file=sys.stderr)
            self._bag = None
        return super().destroy_node()

    # -- reset ------------------------------------------------------------------------------
    def _on_reset(self, request, response):
        try:
            solution = build_solution(self._values())
        except ValueError as exc:
            response.success = False
            response.message = f'reset refused, previous scene keeps running: {exc}'
            return response
        self._solution = solution
        self._time_scale = float(self.get_parameter('time_scale').value)
        self._t_start = None
        self._last_sample = None
        response.success = True
        response.message = f'running model {solution.model} ({solution.method})'
        self.get_logger().info(f'reset: {response.message}')
        return response

    @property
    def solution(self):
        """Return the core solution being published."""
        return self._solution


def usage():
    """Return the ``attitude_node --help`` text: parameters, defaults, topics, services."""
    try:
        defaults = load_defaults()
    except (OSError, ValueError) as exc:
        defaults = {}
        missing = f' (defaults unavailable: {exc})'
    else:
        missing = ''
    lines = [
        'usage: attitude_node [-h] [--ros-args [-p NAME:=VALUE] [--params-file FILE] '
        '[-r FROM:=TO] ...]',
        '',
        __doc__.splitlines()[0].split(': ', 1)[1],
        '',
        'Topics and services (relative names: namespaces and remapping apply):',
        '  attitude            geometry_msgs/QuaternionStamped  q_NB (x, y, z, w), frame_id N',
        '  angular_velocity    geometry_msgs/Vector3Stamped     omega of B rel. N, in B, rad/s',
        '  /diagnostics        diagnostic_msgs/DiagnosticArray  1 Hz: model, error bound, '
        'timing, delivered rate',
        '  ~/reset             std_srvs/srv/Trigger             restart at t = 0 from the '
        'current parameters',
        '',
        f'Parameters (-p NAME:=VALUE or --params-file FILE; default in brackets){missing}:',
    ]
    for name, (text, _) in _DESCRIPTIONS.items():
        value = defaults.get(name, '?')
        bounds = ''
        if name in _RANGES:
            bounds = f', range [{_RANGES[name].from_value:g}, {_RANGES[name].to_value:g}]'
        lines.append(f'  {name} [{value!r}{bounds}]')
        lines += textwrap.wrap(text, 92, initial_indent=' ' * 6, subsequent_indent=' ' * 6)
    lines += ['', 'An invalid scene or argument exits with status 2 and one line saying why; '
              'Ctrl-C or SIGTERM end the node (and finish a recording) with status 0.']
    return '\n'.join(lines)


def main(args=None):
    """Entry point of ``attitude_node`` (accepts the usual ``--ros-args``).

    ``args`` is a full command line as in ``sys.argv`` (program name first). Returns the
    exit status: 0 after Ctrl-C/SIGTERM or ``--help``, 2 for bad arguments or parameters.
    """
    argv = list(sys.argv if args is None else args)
    own, ros_args = split_ros_args(argv[1:])
    if any(a in ('-h', '--help') for a in own):
        print(usage())
        return 0
    if own:
        print(f'attitude_node: unrecognized arguments: {" ".join(own)} (ROS arguments go '
              'after --ros-args; see attitude_node --help)', file=sys.stderr)
        return 2
    reason = init_ros('attitude_node', ros_args)
    if reason is not None:
        print(f'attitude_node: {reason}', file=sys.stderr)
        return 2
    try:
        node = AttitudeNode()
    except SceneError as exc:
        print(f'attitude_node: invalid parameters: {_one_line(exc)}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        rclpy.try_shutdown()
        return 0
    except Exception as exc:            # e.g. an invalid remapped name: one line, status 2
        print(f'attitude_node: cannot start: {type(exc).__name__}: '
              f'{_one_line(exc)}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    spin_until_shutdown(node)
    return 0


def _one_line(exc):
    return ' '.join(str(exc).split())


if __name__ == '__main__':
    sys.exit(main())
