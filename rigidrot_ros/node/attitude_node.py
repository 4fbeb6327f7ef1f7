"""attitude_node: publish the exact attitude and body rate of the configured scene.

Topics (relative names, so namespaces and remapping apply):
- ``attitude`` (geometry_msgs/QuaternionStamped): ``q_NB``, (x, y, z, w), header.frame_id
  = ``frame_id`` (the inertial frame N).
- ``angular_velocity`` (geometry_msgs/Vector3Stamped): omega of B relative to N, in B,
  rad/s, header.frame_id = ``body_frame_id``.
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) at 1 Hz.
- ``~/run`` (std_msgs/String, transient-local, depth 1): the run description as JSON
  (scene, model, method, tol, backend, ``start_ns``, ``time_scale``, version, topics),
  published with the first tick of each run, so a bag of any recorder can be scored.
Service ``~/reset`` (std_srvs/Trigger): restart at t = 0 from the current parameters.

Both messages of a tick carry the same stamp: the clock time that the scene time
``t = (now - t_start) * time_scale`` was computed for (``use_sim_time`` works).
"""

import json
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rcl_interfaces.msg import ParameterType, SetParametersResult
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from std_srvs.srv import Trigger

from rigidrot_ros import __version__
from rigidrot_ros.core import NoExactSolution, PrecisionError, solve
from rigidrot_ros.io.bag import BagWriter
from rigidrot_ros.io.recorder import Recorder, type_name_of
from rigidrot_ros.node.spin import spin_until_shutdown
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
                      'output; NAME:pkg/msg/Type subscribes at once, so the first message '
                      'is kept (read only)', ParameterType.PARAMETER_STRING_ARRAY),
}
_READ_ONLY = ('qos_depth', 'record', 'record_path', 'record_topics')
_RANGES = {
    'tol': FloatingPointRange(from_value=2e-14, to_value=1.0),
    'publish_rate': FloatingPointRange(from_value=1e-3, to_value=1e4),
    'time_scale': FloatingPointRange(from_value=0.0, to_value=1e9),
}


class SceneError(ValueError):
    """The parameters at start-up are invalid or do not describe a solvable scene."""


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
        # the run description: JSON on ~/run, kept for late joiners (see _record_tick)
        self._pub_run = self.create_publisher(
            String, '~/run', QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                        durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self._run_index = 0
        self._run_pending = True
        self._recorder = None
        if self.get_parameter('record').value:
            self._start_recording()
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

    def _on_set(self, params):
        names = [p.name for p in params]
        unknown = [n for n in names if n not in _DESCRIPTIONS]
        if unknown:
            return SetParametersResult(successful=False,
                                       reason=f'unknown parameter(s) {unknown}')
        candidate = self._values(params)
        try:
            if any(n in SCENE_KEYS or n in ('tol', 'backend') for n in names):
                build_solution(candidate)          # validate the whole scene, keep running
            else:
                _check_run_params(candidate)
        except ValueError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if 'publish_rate' in names:
            self._make_timer(candidate['publish_rate'])
        return SetParametersResult(successful=True)

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
        except (PrecisionError, ValueError) as exc:
            st.errors += 1
            st.last_error = str(exc)
            self.get_logger().error(f'evaluation failed at t = {t} s: {exc}',
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
        self._record_tick(now.nanoseconds, [(self._pub_att.topic_name, att),
                                            (self._pub_rate.topic_name, rate)])

    def _publish_diagnostics(self):
        st = self._stats
        mean, p99, mx = st.window()
        sol = self._solution
        bound = float(self._last_sample[1].error_bound) if self._last_sample else 0.0
        level, msg = DiagnosticStatus.OK, f'exact solution: {sol.model}'
        if mx > self._period:
            level, msg = DiagnosticStatus.WARN, 'evaluation slower than the timer period'
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
        }
        status = DiagnosticStatus(level=level, name=f'{self.get_name()}: exact attitude',
                                  message=msg, hardware_id=self.get_fully_qualified_name())
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [status]
        self._pub_diag.publish(arr)

    # -- recording and the run description -------------------------------------------------
    def _start_recording(self):
        path = self.get_parameter('record_path').value or 'runs'
        topics = [t for t in (self.get_parameter('record_topics').value or []) if t]
        try:
            writer = BagWriter(path, self.get_name(), flush_period=0.4)
        except OSError as exc:
            raise SceneError(f'cannot record to {path!r}: {exc}') from None
        try:
            self._recorder = Recorder(self, writer, topics=topics, exclude_own=True)
        except Exception as exc:  # noqa: B902 - ValueError, or rclpy's invalid-name errors
            writer.close()
            raise SceneError(f'parameter record_topics: {exc}') from None
        self.get_logger().info(f'recording to {writer.path}')

    def _run_description(self, start_ns):
        sol = self._solution
        return {
            'rigidrot_run': 1, 'run': self._run_index, 'start_ns': int(start_ns),
            'time_scale': self._time_scale, 'scene': sol.scene.as_dict(), 'tol': sol.tol,
            'backend': sol.backend, 'model': sol.model, 'method': sol.method,
            'package': f'rigidrot_ros {__version__}', 'node': self.get_fully_qualified_name(),
            'topics': {p.topic_name: type_name_of(p.msg_type) for p in self.publishers},
        }

    def _record_tick(self, now_ns, published):
        """After each publication: announce a new run on ``~/run``, record what was published.

        ``published`` lists ``(resolved_topic_name, msg)`` for every message of this call.
        The first call after start-up or a ``~/reset`` publishes the run description (JSON
        in std_msgs/String, transient-local, depth 1), so any recorder keeps it.
        """
        if self._run_pending:
            self._run_pending = False
            self._run_index += 1
            start = self._t_start.nanoseconds if self._t_start is not None else now_ns
            info = self._run_description(start)
            msg = String(data=json.dumps(info))
            self._pub_run.publish(msg)
            published = list(published) + [(self._pub_run.topic_name, msg)]
            if self._recorder is not None:
                self._recorder.add_run(info)
        if self._recorder is not None:
            self._recorder.record_published(now_ns, published)

    def destroy_node(self):
        """Finish the bag (summary, index, metadata.yaml), then destroy the node."""
        if self._recorder is not None:
            try:
                path, counts = self._recorder.close()
                # the context may be shut down already: no rosout logging here
                print(f'attitude_node: bag finished: {path} {counts}, '
                      f'published {self._stats.published} ticks', file=sys.stderr)
            except (OSError, ValueError) as exc:
                print(f'attitude_node: could not finish the bag: {exc}', file=sys.stderr)
            self._recorder = None
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
        self._run_pending = True            # the next tick announces the new run on ~/run
        response.success = True
        response.message = f'running model {solution.model} ({solution.method})'
        self.get_logger().info(f'reset: {response.message}')
        return response

    @property
    def solution(self):
        """Return the core solution being published."""
        return self._solution


def main(args=None):
    """Entry point of ``attitude_node`` (accepts the usual ``--ros-args``)."""
    rclpy.init(args=args)
    try:
        node = AttitudeNode()
    except SceneError as exc:
        print(f'attitude_node: invalid parameters: {exc}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        rclpy.try_shutdown()
        return 0
    spin_until_shutdown(node)
    return 0


if __name__ == '__main__':
    sys.exit(main())
