"""attitude_node: publish the exact attitude and body rate of the configured scene.

Topics (relative names, so namespaces and remapping apply):
- ``attitude`` (geometry_msgs/QuaternionStamped): ``q_NB``, (x, y, z, w), header.frame_id
  = ``frame_id`` (the inertial frame N).
- ``angular_velocity`` (geometry_msgs/Vector3Stamped): omega of B relative to N, in B,
  rad/s, header.frame_id = ``body_frame_id``.
- ``transform`` (geometry_msgs/TransformStamped, parent N, child B; ``transform.enable``),
  ``odom`` (nav_msgs/Odometry; ``odom.enable``), ``markers``
  (visualization_msgs/MarkerArray; ``markers.enable``): the same truth for evo, odometry
  consumers and Foxglove/RViz. All off by default: the default output stays two topics.
- ``imu`` (sensor_msgs/Imu), ``delta_angle`` and ``delta_rotation``
  (geometry_msgs/Vector3Stamped, rad, in B) with ``imu.enable``: a rate-integrating gyro
  with seeded noise and bias, and the exact increments over each gyro interval.
- ``star_tracker`` (geometry_msgs/PoseWithCovarianceStamped) with ``star_tracker.enable``.
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) at 1 Hz.
- ``~/run`` (std_msgs/String, transient-local, depth 1): the run description as JSON
  (scene, model, method, tol, backend, ``start_ns``, ``time_scale``, version, topics),
  published with the first tick of each run, so a bag of any recorder can be scored.
Service ``~/reset`` (std_srvs/Trigger): restart at t = 0 from the current parameters.

The truth is sampled on the timer's own grid: tick k is stamped ``g0 + k / publish_rate``
(``g0`` the scheduled time of the timer's first call, which is also ``t_start`` of the
run) and carries the scene time ``t = (stamp - t_start) * time_scale``; all messages of a
tick share that stamp (``use_sim_time`` works). Because the coming ticks' times are known,
their samples are evaluated, and the attitude and rate messages built and serialized,
ahead in batches (:mod:`rigidrot_ros.node.lookahead`); a tick reads the clock and
publishes the bytes. The sensors sample their own fixed grids ``t_start + k / rate`` (so
a seed reproduces the stream bit for bit); each sample's messages share its grid stamp.
Messages are built by :mod:`rigidrot_ros.io.messages`.
"""

import difflib
import json
import math
import sys
import textwrap
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import (
    PoseWithCovarianceStamped, QuaternionStamped, TransformStamped, Vector3Stamped,
)
from nav_msgs.msg import Odometry
import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rcl_interfaces.msg import ParameterType, SetParametersResult
import rclpy
from rclpy.exceptions import ParameterException, ParameterNotDeclaredException
from rclpy.executors import ExternalShutdownException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rclpy.time import Time
from sensor_msgs.msg import Imu
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from rigidrot_ros import __version__
from rigidrot_ros.core import MIN_TOL, NoExactSolution, PrecisionError, solve
from rigidrot_ros.io import messages as msgs
from rigidrot_ros.io.bag import BagWriter
from rigidrot_ros.io.recorder import Recorder, type_name_of
from rigidrot_ros.node.lookahead import Lookahead
from rigidrot_ros.node.spin import init_ros, spin_until_shutdown, split_ros_args
from rigidrot_ros.sensors import Gyro, StarTracker
from rigidrot_ros.settings import (
    load_defaults, MAX_TOL, OUTPUT_KEYS, scene_from_params, SCENE_KEYS, sensor_settings,
    solver_options,
)

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
    'publish_rate': ('timer rate, Hz; the truth is sampled at t_start + k / publish_rate; '
                     'takes effect at once (a new grid from the next tick)',
                     ParameterType.PARAMETER_DOUBLE),
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
    'imu.enable': ('publish a gyro as sensor_msgs/Imu on imu, and the exact delta_angle and '
                   'delta_rotation (Vector3Stamped, rad, in B) over each sample interval '
                   '(read only)', ParameterType.PARAMETER_BOOL),
    'imu.rate': ('gyro sample rate, Hz of clock time; 0 = publish_rate; applied at the next '
                 '~/reset', ParameterType.PARAMETER_DOUBLE),
    'imu.gyro_noise_density': ('angle random walk sigma_v, rad/s/sqrt(Hz) (Kalibr '
                               'gyroscope_noise_density; Gazebo <stddev> = sigma_v / '
                               'sqrt(dt)); applied at the next ~/reset',
                               ParameterType.PARAMETER_DOUBLE),
    'imu.gyro_random_walk': ('rate random walk sigma_u of the bias, rad/s^2/sqrt(Hz) (Kalibr '
                             'gyroscope_random_walk); applied at the next ~/reset',
                             ParameterType.PARAMETER_DOUBLE),
    'imu.gyro_bias': ('initial gyro bias [bx, by, bz], rad/s, in B; applied at the next '
                      '~/reset', _DOUBLE_ARRAY),
    'imu.seed': ('seed of the gyro noise: the same seed gives the same stream; applied at '
                 'the next ~/reset', ParameterType.PARAMETER_INTEGER),
    'star_tracker.enable': ('publish a star tracker as geometry_msgs/PoseWithCovarianceStamped '
                            'on star_tracker (read only)', ParameterType.PARAMETER_BOOL),
    'star_tracker.rate': ('star tracker sample rate, Hz of clock time; 0 = publish_rate; '
                          'applied at the next ~/reset', ParameterType.PARAMETER_DOUBLE),
    'star_tracker.cross_boresight_arcsec': ('1-sigma error across the boresight, arc seconds; '
                                            'applied at the next ~/reset',
                                            ParameterType.PARAMETER_DOUBLE),
    'star_tracker.about_boresight_arcsec': ('1-sigma error about the boresight (roll), arc '
                                            'seconds; applied at the next ~/reset',
                                            ParameterType.PARAMETER_DOUBLE),
    'star_tracker.boresight': ('boresight axis [x, y, z] in B (normalised); applied at the '
                               'next ~/reset', _DOUBLE_ARRAY),
    'star_tracker.seed': ('seed of the star tracker noise; applied at the next ~/reset',
                          ParameterType.PARAMETER_INTEGER),
    'odom.enable': ('publish the truth as nav_msgs/Odometry on odom (read only)',
                    ParameterType.PARAMETER_BOOL),
    'transform.enable': ('publish the truth as geometry_msgs/TransformStamped on transform '
                         '(read only)', ParameterType.PARAMETER_BOOL),
    'markers.enable': ('publish the body as visualization_msgs/MarkerArray on markers (read '
                       'only)', ParameterType.PARAMETER_BOOL),
}
_READ_ONLY = ('qos_depth', 'record', 'record_path', 'record_topics') + OUTPUT_KEYS
_RANGES = {
    'tol': FloatingPointRange(from_value=MIN_TOL, to_value=MAX_TOL),
    'publish_rate': FloatingPointRange(from_value=1e-3, to_value=1e4),
    'time_scale': FloatingPointRange(from_value=0.0, to_value=1e9),
    'imu.rate': FloatingPointRange(from_value=0.0, to_value=1e4),
    'imu.gyro_noise_density': FloatingPointRange(from_value=0.0, to_value=1.0),
    'imu.gyro_random_walk': FloatingPointRange(from_value=0.0, to_value=1.0),
    'star_tracker.rate': FloatingPointRange(from_value=0.0, to_value=1e4),
    'star_tracker.cross_boresight_arcsec': FloatingPointRange(from_value=0.0, to_value=3600.0),
    'star_tracker.about_boresight_arcsec': FloatingPointRange(from_value=0.0, to_value=3600.0),
}
_SEEDS = ('imu.seed', 'star_tracker.seed')
#: Parameters rclpy declares by itself (rclpy.time_source, rclpy.type_description_service).
_BUILTIN = ('use_sim_time', 'start_type_description_service')
_EPS = float(np.finfo(float).eps)
#: Work one sensor callback may do before it leaves due samples to the next one, s; also
#: the most one gyro sample's quadrature may take (past it the sample fails, reported).
_BUDGET_S = 0.02


#: A new scene is refused when either of its two trial samples takes longer than this, s.
_TRIAL_LIMIT_S = 1.0


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
    if not isinstance(p['record'], bool):
        raise ValueError(f'parameter record must be true or false, got {p["record"]!r}')
    if not isinstance(p['record_path'], str):
        raise ValueError(f'parameter record_path must be a string (a directory), '
                         f'got {p["record_path"]!r}')
    topics = p['record_topics']
    if isinstance(topics, (str, bytes)) or not isinstance(topics, (list, tuple)) or \
            not all(isinstance(t, str) for t in topics):
        raise ValueError(f'parameter record_topics must be a list of strings '
                         f"(['NAME:pkg/msg/Type', ...]), got {topics!r}")


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
                         f'{list(scene.omega0)})') from None


def _trial(sol, p, cfg=None):
    """Evaluate the first two ticks of a candidate scene; return None or why it fails.

    A scene whose first tick (t = 0) or second (one period in, scaled by ``time_scale``)
    cannot be evaluated, or costs more than :data:`_TRIAL_LIMIT_S`, would leave the node
    publishing nothing, or blocking its services; it is refused instead. With the sensor
    settings ``cfg`` (:func:`sensor_settings`), the first gyro sample (one interval,
    ``time_scale / imu_rate`` s of scene time, its quadrature within :data:`_BUDGET_S` as
    in the node) and the first star tracker sample are tried the same way, and a gyro
    sample whose increment bound is not finite refuses the scene too.
    """
    t1 = float(p['time_scale']) / float(p['publish_rate'])
    for t in (0.0, t1):
        c0 = time.perf_counter()
        try:
            sol.at(t)
        except Exception as exc:    # PrecisionError, ValueError, or anything else
            return (f'the scene cannot be evaluated at t = {t:g} s (the first ticks): '
                    f'{type(exc).__name__}: {exc}')
        cost = time.perf_counter() - c0
        if cost > _TRIAL_LIMIT_S:
            return (f'one sample of this scene takes {cost:.3g} s to evaluate ({sol.model}, '
                    f"{sol.method}), beyond the node's limit of {_TRIAL_LIMIT_S:g} s; try "
                    "backend 'auto' or a larger tol")
    if cfg is None:
        return None
    if cfg.imu:
        dt = float(p['time_scale']) / cfg.imu_rate
        c0 = time.perf_counter()
        try:                        # an ideal gyro: the run's own noise stream stays fresh
            with np.errstate(over='ignore', invalid='ignore'):  # judged below, not warned
                r = Gyro(sol).read(0.0, dt, budget=_BUDGET_S)
        except Exception as exc:
            return (f'the first gyro sample (imu.rate {cfg.imu_rate:g} Hz, time_scale '
                    f'{float(p["time_scale"]):g}: {dt:g} s of scene time) cannot be '
                    f'evaluated: {type(exc).__name__}: {exc}; lower time_scale or raise '
                    'imu.rate')
        cost = time.perf_counter() - c0
        if cost > _TRIAL_LIMIT_S:
            return (f'the first gyro sample ({dt:g} s of scene time) takes {cost:.3g} s, '
                    f"beyond the node's limit of {_TRIAL_LIMIT_S:g} s; lower time_scale or "
                    'raise imu.rate')
        bound = float(max(r.delta_angle_bound, r.delta_rotation_bound))
        if not math.isfinite(bound):
            return (f'the gyro increments of this scene have no finite error bound '
                    f'({bound!r} rad over the first {dt:g} s; omega0 or torque too large '
                    'for float64); turn imu.enable off or choose a smaller scene')
    if cfg.star_tracker:
        t = float(p['time_scale']) / cfg.star_tracker_rate
        c0 = time.perf_counter()
        try:
            StarTracker(sol).read(t)
        except Exception as exc:
            return (f'the first star tracker sample (t = {t:g} s) cannot be evaluated: '
                    f'{type(exc).__name__}: {exc}')
        cost = time.perf_counter() - c0
        if cost > _TRIAL_LIMIT_S:
            return (f'the first star tracker sample takes {cost:.3g} s, beyond the '
                    f"node's limit of {_TRIAL_LIMIT_S:g} s")
    return None


class _Stats:
    """Evaluation times and tick accounting for the diagnostics."""

    def __init__(self):
        self.times = []
        self.tick_times = []
        self.latencies = []
        self.imu_times = []
        self.published = 0
        self.imu_samples = 0
        self.star_samples = 0
        self.skipped = 0
        self.skipped_reported = 0
        self.increment_bound = 0.0
        self.late = 0
        self.missed = 0
        self.errors = 0
        self.last_error = ''

    def window(self):
        """Return (mean, p99, max) seconds since the last call of: evaluation, tick, latency.

        Evaluation: getting a tick's sample (from the look-ahead buffer, or evaluated then);
        tick: the whole callback up to its messages' publication; latency: from the tick's
        grid time (its stamp) to the start of its callback, on the node clock.
        """
        out = []
        for name, scale in (('times', 1.0), ('tick_times', 1e-9), ('latencies', 1e-9)):
            v = getattr(self, name)
            a = np.array(v) * scale if v else np.zeros(1)
            setattr(self, name, [])
            out.append((float(a.mean()), float(np.percentile(a, 99)), float(a.max())))
        return out

    def imu_window(self):
        """Return the gyro samples' build seconds (mean, max) since the last call."""
        g = np.array(self.imu_times) if self.imu_times else np.zeros(1)
        self.imu_times = []
        return float(g.mean()), float(g.max())


def _make_sensors(solution, cfg):
    """Return ``(gyro, star_tracker)`` of validated settings (None where off)."""
    gyro = Gyro(solution, cfg.gyro) if cfg.imu else None
    star = StarTracker(solution, cfg.attitude_noise) if cfg.star_tracker else None
    return gyro, star


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
            if name in _SEEDS:
                desc.integer_range = [IntegerRange(from_value=0, to_value=2 ** 63 - 1,
                                                   step=1)]
            value = defaults[name]
            if name == 'record_topics' and not value:
                value = ['']      # an empty list carries no type; empty names are ignored
            try:
                self.declare_parameter(name, value, desc)
            except ParameterException as exc:      # an override outside its declared range
                raise SceneError(f'parameter {name}: {exc}') from None
        self._warn_unknown_overrides()
        try:
            self._solution = build_solution(self._values())
            self._sensors = sensor_settings(self._values())
            trial = _trial(self._solution, self._values(), self._sensors)
            if trial is not None:
                raise ValueError(f'scene {self._scene_summary()}: {trial}')
            self._use_sensors(_make_sensors(self._solution, self._sensors))
        except ValueError as exc:
            raise SceneError(str(exc)) from None
        self._time_scale = float(self.get_parameter('time_scale').value)
        self._frames = (self.get_parameter('frame_id').value,
                        self.get_parameter('body_frame_id').value)
        self._t_start = None
        self._grid0 = None              # clock ns of the truth grid's index 0 (see _anchor)
        self._tick_k = -1               # the last truth grid index published
        self._ahead = None
        self._last_sample = None
        self._stats = _Stats()
        self.add_on_set_parameters_callback(self._on_set)
        qos = QoSProfile(depth=self.get_parameter('qos_depth').value,
                         reliability=ReliabilityPolicy.RELIABLE)
        self._pub_att = self.create_publisher(QuaternionStamped, 'attitude', qos)
        self._pub_rate = self.create_publisher(Vector3Stamped, 'angular_velocity', qos)
        cfg = self._sensors
        self._pub_tf = (self.create_publisher(TransformStamped, 'transform', qos)
                        if cfg.transform else None)
        self._pub_odom = self.create_publisher(Odometry, 'odom', qos) if cfg.odom else None
        self._pub_markers = (self.create_publisher(MarkerArray, 'markers', qos)
                             if cfg.markers else None)
        self._truth_extra = [p for p in (self._pub_tf, self._pub_odom, self._pub_markers)
                             if p is not None]
        self._pub_imu = self._pub_da = self._pub_dr = self._pub_star = None
        if cfg.imu:
            self._pub_imu = self.create_publisher(Imu, 'imu', qos)
            self._pub_da = self.create_publisher(Vector3Stamped, 'delta_angle', qos)
            self._pub_dr = self.create_publisher(Vector3Stamped, 'delta_rotation', qos)
        if cfg.star_tracker:
            self._pub_star = self.create_publisher(PoseWithCovarianceStamped, 'star_tracker',
                                                   qos)
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
        self._imu_timer = self._star_timer = None
        self._make_sensor_timers()
        self._diag_timer = self.create_timer(1.0, self._publish_diagnostics)
        self.get_logger().info(
            f'running model {self._solution.model} ({self._solution.method}) at '
            f'{self._period_hz:g} Hz')

    def _warn_unknown_overrides(self):
        """Warn about ``-p name:=value`` overrides that name no parameter of this node."""
        known = set(_DESCRIPTIONS) | set(_BUILTIN)
        unknown = sorted(n for n in getattr(self, '_parameter_overrides', {})
                         if n not in known and not self.has_parameter(n))
        for name in unknown:
            close = difflib.get_close_matches(name, sorted(known), n=1)
            hint = f' (did you mean {close[0]}?)' if close else ''
            self.get_logger().warning(
                f'unknown parameter {name!r} ignored{hint}: attitude_node declares no such '
                f'parameter')
        self.unknown_overrides = unknown

    def _use_sensors(self, sensors):
        """Start the sensors of a run (fresh noise streams, grids from k = 0)."""
        self._gyro, self._star = sensors
        self._imu_k = 0             # the last gyro sample published (k = 0 is t = 0)
        self._star_k = -1           # the last star tracker sample published

    def _make_sensor_timers(self):
        for timer in (self._imu_timer, self._star_timer):
            if timer is not None:
                self.destroy_timer(timer)
        self._imu_timer = self._star_timer = None
        cfg = self._sensors
        if cfg.imu:
            self._imu_timer = self.create_timer(1.0 / cfg.imu_rate, self._imu_tick)
        if cfg.star_tracker:
            self._star_timer = self.create_timer(1.0 / cfg.star_tracker_rate,
                                                 self._star_tick)

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

    def _scene_summary(self):
        p = self._values()
        return ', '.join(f'{k} {p[k]!r}' for k in ('inertia', 'torque', 'omega0'))

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
            if 'frame_id' in names or 'body_frame_id' in names:   # at once, as before
                values = self._values(params)
                self._frames = (values['frame_id'], values['body_frame_id'])
                if self._ahead is not None:
                    self._ahead.drop_built()
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
            if any(n in SCENE_KEYS or n in ('tol', 'backend', 'time_scale', 'publish_rate')
                   or n.startswith(('imu.', 'star_tracker.')) for n in names):
                sol = build_solution(candidate)    # validate the whole scene, keep running
                cfg = sensor_settings(candidate)   # the sensors, and time_scale against them
                reason = _trial(sol, candidate, cfg)
                if reason is not None:
                    return f'parameter(s) {", ".join(names)}: {reason}'
            else:
                _check_run_params(candidate)
                sensor_settings(candidate)
        except ValueError as exc:
            return str(exc)
        return None

    def _make_timer(self, rate):
        if self._timer is not None:
            self.destroy_timer(self._timer)
        self._period_hz = float(rate)
        self._period = 1.0 / float(rate)
        self._grid0 = None              # the next tick anchors a new grid (same t_start)
        self._timer = self.create_timer(self._period, self._tick)

    # -- publishing -------------------------------------------------------------------------
    def _anchor(self, now_ns):
        """Anchor the truth grid at the scheduled time of this timer call (ns, <= now).

        rclpy keeps a timer's calls on the schedule ``created + k * period``; in a callback,
        ``now + time_until_next_call() - period`` is the scheduled time of the call being
        served (a few µs early: the two clock reads), so every later call, however late
        within its period, falls in its own grid slot. The first anchor of a run is also
        its ``t_start`` (scene time 0).
        """
        period_ns = round(self._period * 1e9)
        g0 = now_ns
        until = self._timer.time_until_next_call() if self._timer is not None else None
        if until is not None and 0 <= until <= period_ns:
            g0 = max(0, now_ns + until - period_ns)     # a clock (sim time) starts at 0
        if self._t_start is None:
            self._t_start = Time(nanoseconds=g0, clock_type=self.get_clock().clock_type)
            self._run_pending = True        # _record_tick announces the run on ~/run
        self._grid0, self._tick_k = g0, -1
        self._ahead = Lookahead(self._solution,
                                lambda k: self._scene_time(self._tick_stamp_ns(k)),
                                self._period,
                                build=lambda k, smp: self._build_ahead(self._tick_stamp_ns(k),
                                                                       smp))

    def _build_pair(self, stamp_ns, sample):
        """Build the attitude and rate messages of a sample stamped ``stamp_ns``."""
        frame, body = self._frames
        stamp = msgs.stamp(stamp_ns)
        return (msgs.attitude(stamp, frame, sample[0]), msgs.vector(stamp, body, sample[1]))

    def _build_ahead(self, stamp_ns, sample):
        """:meth:`_build_pair` plus both messages serialized (CDR), for a tick to come.

        The tick then publishes the bytes (``publish_raw``): rclpy's conversion of the
        Python message and its serialization, half of a publish after an idle gap, are
        done here, in the batch, and the recorder writes the same bytes.
        """
        att, rate = self._build_pair(stamp_ns, sample)
        return att, rate, serialize_message(att), serialize_message(rate)

    def _now_ns(self):
        """Return the node clock's time (ns).

        Unless ``use_sim_time`` drives it, the ROS clock is the system clock
        (CLOCK_REALTIME, what rcl reads): read here directly, at a tenth of the cost of
        ``get_clock().now()`` after an idle gap (measured: README, the node's cost per tick).
        """
        if self._time_source is not None and not self._time_source.ros_time_is_active:
            return time.time_ns()
        return self.get_clock().now().nanoseconds

    def _tick_stamp_ns(self, k):
        return _grid_stamp_ns(self._grid0, self._period_hz, k)

    def _scene_time(self, ns):
        return (ns - self._t_start.nanoseconds) * 1e-9 * self._time_scale

    def _publish(self, items):
        """Publish ``(publisher, msg, raw)`` items (``raw``: the message's bytes, or None).

        False if the context shut down meanwhile.
        """
        try:
            for pub, msg, raw in items:
                pub.publish(msg if raw is None else raw)
        except _rclpy.RCLError:
            if self.context.ok():
                raise
            return False            # shut down (SIGINT/SIGTERM) while this callback ran
        return True

    def _truth_messages(self, stamp_ns, sample, built=None):
        """Build the truth of one sample as ``(publisher, msg, raw)`` items, one stamp.

        ``sample``: ``(quaternion, omega, error_bound)`` as :class:`Lookahead` gives it;
        ``built``: what :meth:`_build_ahead` made of it ahead of time, if anything.
        """
        frame, body = self._frames
        q, omega, bound = sample
        if built is None:
            built = self._build_pair(stamp_ns, sample) + (None, None)
        out = [(self._pub_att, built[0], built[2]), (self._pub_rate, built[1], built[3])]
        if len(self._truth_extra) == 0:
            return out
        stamp = built[0].header.stamp
        if self._pub_tf is not None:
            out.append((self._pub_tf, msgs.transform(stamp, frame, body, q), None))
        if self._pub_odom is not None:
            rate_sd = 32.0 * _EPS * float(np.linalg.norm(omega))
            out.append((self._pub_odom, msgs.odometry(
                stamp, frame, body, q, omega, attitude_variance=bound ** 2,
                rate_variance=rate_sd ** 2), None))
        if self._pub_markers is not None:
            out.append((self._pub_markers, msgs.body_markers(
                stamp, frame, q, self._solution.scene.inertia), None))
        return out

    def _tick(self):
        c_tick = time.perf_counter_ns()
        now_ns = self._now_ns()
        st = self._stats
        if self._grid0 is None or now_ns < self._grid0:     # new grid, or the clock went back
            self._anchor(now_ns)
        k = _grid_index(self._grid0, self._period_hz, now_ns)
        if k <= self._tick_k:
            if k >= self._tick_k - 1:
                return                  # this grid time is published already
            self._anchor(now_ns)        # the clock went back: a new grid
            k = 0
        if self._tick_k >= 0 and k > self._tick_k + 1:
            st.late += 1
            st.missed += k - self._tick_k - 1
        self._tick_k = k
        stamp_ns = self._tick_stamp_ns(k)
        st.latencies.append(now_ns - stamp_ns)
        t = self._scene_time(stamp_ns)
        c0 = time.perf_counter()
        try:
            sample, built = self._ahead.get(k)
        except Exception as exc:        # PrecisionError, or anything else: report, keep going
            self._failed(t, exc)
            return
        st.times.append(time.perf_counter() - c0)
        items = self._truth_messages(stamp_ns, sample, built)
        if not self._publish(items):
            return
        st.tick_times.append(time.perf_counter_ns() - c_tick)
        st.published += 1
        self._last_sample = (t, sample[2])
        self._record_tick(now_ns, items)
        self._ahead.refill(k)           # after publishing: the batch delays no message

    def _failed(self, t, exc):
        st = self._stats
        st.errors += 1
        st.last_error = str(exc) if isinstance(exc, (PrecisionError, ValueError)) else \
            f'{type(exc).__name__}: {exc}'
        self.get_logger().error(f'evaluation failed at t = {t} s: {st.last_error}',
                                throttle_duration_sec=1.0)

    def _grid(self, rate, last, now_ns):
        """Sample indices due on the grid ``t_start + k / rate`` (clock): (first, last).

        A backlog of more than a second (a clock jump) restarts the grid's chain at the
        newest sample; the skipped samples are counted in the diagnostics.
        """
        k = max(0, _grid_index(self._t_start.nanoseconds, rate, now_ns))
        cap = max(10, int(rate))
        first = last + 1
        if k - last > cap:
            self._stats.skipped += k - last - 1
            first = k
        return first, k

    def _stamp_ns(self, rate, k):
        return _grid_stamp_ns(self._t_start.nanoseconds, rate, k)

    def _imu_tick(self):
        if self._t_start is None:
            return                      # the first truth tick starts the run (t_start)
        now_ns = self._now_ns()
        rate = self._sensors.imu_rate
        first, last = self._grid(rate, self._imu_k, now_ns)
        if last < first:
            return
        body = self._frames[1]
        pairs = []
        c0 = time.perf_counter()
        for k in range(first, last + 1):
            c_sample = time.perf_counter()
            if c_sample - c0 > _BUDGET_S:
                last = k - 1        # the rest stays due: the next callback goes on
                break
            ns1 = self._stamp_ns(rate, k)
            t0, t1 = self._scene_time(self._stamp_ns(rate, k - 1)), self._scene_time(ns1)
            try:
                r = self._gyro.read(t0, t1, budget=_BUDGET_S)
            except Exception as exc:    # PrecisionError or anything else: report it
                self._failed(t1, exc)
                continue
            stamp = msgs.stamp(ns1)
            pairs += [(self._pub_imu, msgs.imu(stamp, body, r.omega, r.variance), None),
                      (self._pub_da, msgs.vector(stamp, body, r.delta_angle), None),
                      (self._pub_dr, msgs.vector(stamp, body, r.delta_rotation), None)]
            self._stats.imu_times.append(time.perf_counter() - c_sample)
            self._stats.increment_bound = max(self._stats.increment_bound,
                                              r.delta_angle_bound, r.delta_rotation_bound)
            self._stats.imu_samples += 1
        self._imu_k = last
        if pairs and self._publish(pairs):
            self._record_tick(now_ns, pairs)

    def _star_tick(self):
        if self._t_start is None:
            return                      # the first truth tick starts the run (t_start)
        now_ns = self._now_ns()
        rate = self._sensors.star_tracker_rate
        first, last = self._grid(rate, self._star_k, now_ns)
        if last < first:
            return
        frame = self._frames[0]
        pairs = []
        c0 = time.perf_counter()
        for k in range(first, last + 1):
            if time.perf_counter() - c0 > _BUDGET_S:
                last = k - 1
                break
            ns = self._stamp_ns(rate, k)
            try:
                r = self._star.read(self._scene_time(ns))
            except Exception as exc:    # PrecisionError or anything else: report it
                self._failed(self._scene_time(ns), exc)
                continue
            pairs.append((self._pub_star, msgs.star_tracker(msgs.stamp(ns), frame,
                                                            r.quaternion, r.covariance), None))
            self._stats.star_samples += 1
        self._star_k = last
        if pairs and self._publish(pairs):
            self._record_tick(now_ns, pairs)

    def _publish_diagnostics(self):
        st = self._stats
        (mean, p99, mx), (tick_mean, tick_p99, tick_max), (lat_mean, lat_p99, lat_max) = \
            st.window()
        imu_mean, imu_max = st.imu_window()
        ahead = self._ahead
        batches = ahead.take_stats() if ahead is not None else []
        sol = self._solution
        bound = float(self._last_sample[1]) if self._last_sample else 0.0
        warns = []                  # every reason of this window, not only the last
        if mx > self._period:
            warns.append('evaluation slower than the timer period')
        delivered = self._delivered_rate()
        if delivered is not None and delivered < 0.9 * self._period_hz:
            warns.append(f'delivering {delivered:.4g} Hz of the {self._period_hz:g} Hz asked '
                         '(publish_rate beyond what this machine and executor deliver)')
        if bound > sol.tol:
            warns.append('error bound above tol')
        if not st.increment_bound <= sol.tol:      # also NaN and inf
            warns.append(f'gyro increment error bound {st.increment_bound:.3g} rad above tol')
        if st.skipped > st.skipped_reported:
            st.skipped_reported = st.skipped
            warns.append('sensor samples skipped (a clock jump, or sensor rates above what '
                         'this CPU keeps up)')
        level, msg = DiagnosticStatus.OK, f'exact solution: {sol.model}'
        if warns:
            level, msg = DiagnosticStatus.WARN, '; '.join(warns)
        if st.errors:
            level = DiagnosticStatus.ERROR
            msg = '; '.join([f'evaluation failed: {st.last_error}'] + warns)
            st.errors = 0
        values = {
            'model': sol.model, 'method': sol.method, 'backend': sol.backend,
            'working_precision_bits': str(sol.precision), 'tol_rad': f'{sol.tol:.3g}',
            'error_bound_rad': f'{bound:.3g}',
            'scene_time_s': f'{self._last_sample[0]:.6f}' if self._last_sample else '',
            'eval_mean_us': f'{mean * 1e6:.1f}', 'eval_p99_us': f'{p99 * 1e6:.1f}',
            'eval_max_us': f'{mx * 1e6:.1f}', 'tick_mean_us': f'{tick_mean * 1e6:.1f}',
            'tick_p99_us': f'{tick_p99 * 1e6:.1f}', 'tick_max_us': f'{tick_max * 1e6:.1f}',
            'latency_mean_us': f'{lat_mean * 1e6:.1f}', 'latency_p99_us': f'{lat_p99 * 1e6:.1f}',
            'latency_max_us': f'{lat_max * 1e6:.1f}',
            'lookahead': ('' if ahead is None else f'{ahead.size} samples a batch'
                          if ahead.size else f'off: {ahead.off_reason}'),
            'lookahead_batches': str(len(batches)),
            'lookahead_batch_max_us': f'{max(batches, default=0.0) * 1e6:.1f}',
            'lookahead_sample_us': f'{(ahead.last_per_sample if ahead else 0.0) * 1e6:.2f}',
            'imu_samples': str(st.imu_samples), 'imu_sample_mean_us': f'{imu_mean * 1e6:.1f}',
            'imu_sample_max_us': f'{imu_max * 1e6:.1f}',
            'star_tracker_samples': str(st.star_samples),
            'sensor_samples_skipped': str(st.skipped),
            'increment_error_bound_rad': f'{st.increment_bound:.3g}',
            'ticks_published': str(st.published),
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

        ``published`` lists ``(publisher, msg, raw)`` for every message of this call, as
        :meth:`_publish` took them (``raw``: the serialized bytes if made already, else None);
        their topic names are looked up only when there is a recorder.
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
            published = list(published) + [(self._pub_run, msg, None)]
            if self._recorder is not None:
                self._recorder.add_run(info)
        if self._recorder is not None:
            self._recorder.record_published(
                now_ns, [(pub.topic_name, m, raw) for pub, m, raw in published])

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
            sensors = sensor_settings(self._values())
            trial = _trial(solution, self._values(), sensors)
            if trial is not None:
                raise ValueError(trial)
            devices = _make_sensors(solution, sensors)
        except ValueError as exc:
            response.success = False
            response.message = f'reset refused, previous scene keeps running: {exc}'
            return response
        self._solution = solution
        self._sensors = sensors
        self._time_scale = float(self.get_parameter('time_scale').value)
        self._t_start = None
        self._grid0 = None                  # the next tick anchors the new run's grid
        self._ahead = None
        self._last_sample = None
        self._stats.increment_bound = 0.0   # the bound of this run's increments only
        self._run_pending = True            # the next tick announces the new run on ~/run
        self._use_sensors(devices)
        self._make_sensor_timers()
        response.success = True
        response.message = f'running model {solution.model} ({solution.method})'
        self.get_logger().info(f'reset: {response.message}')
        return response

    @property
    def solution(self):
        """Return the core solution being published."""
        return self._solution


def _grid_stamp_ns(origin_ns, rate, k):
    """Return the stamp (ns) of index k on the grid ``origin_ns + k / rate`` (one rounding)."""
    return origin_ns + round(k * 1e9 / rate)


def _grid_index(origin_ns, rate, now_ns):
    """Return the last k whose :func:`_grid_stamp_ns` is at or before ``now_ns`` (may be < 0)."""
    k = math.floor((now_ns - origin_ns) * rate * 1e-9)
    while _grid_stamp_ns(origin_ns, rate, k + 1) <= now_ns:
        k += 1
    while _grid_stamp_ns(origin_ns, rate, k) > now_ns:
        k -= 1
    return k


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
        '  ~/run               std_msgs/String                  run description as JSON '
        '(transient-local)',
        '  with imu.enable: imu (sensor_msgs/Imu), delta_angle, delta_rotation '
        '(Vector3Stamped);',
        '  with star_tracker.enable: star_tracker (PoseWithCovarianceStamped); with '
        'odom.enable,',
        '  transform.enable, markers.enable: odom, transform, markers (the truth)',
        '',
        "Tick k of the truth is stamped t_start + k / publish_rate (the timer's schedule, "
        't_start its first call)',
        'and holds the scene at t = (stamp - t_start) * time_scale.',
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
