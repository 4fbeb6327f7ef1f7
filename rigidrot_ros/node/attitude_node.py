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

This module is the wiring; the parts are elsewhere: the parameters in
:mod:`rigidrot_ros.params`, the run set-up in :func:`rigidrot_ros.settings.prepare_run`,
the tick grids in :mod:`~rigidrot_ros.node.grid` (stamps: see there), the sensors in
:mod:`~rigidrot_ros.node.streams`, the truth ahead of time in
:mod:`~rigidrot_ros.node.lookahead`, the messages in :mod:`~rigidrot_ros.node.outputs`,
the diagnostics in :mod:`~rigidrot_ros.node.diagnostics`, ``--help`` and ``main`` in
:mod:`~rigidrot_ros.node.cli`. Because the coming ticks' times are known, their samples are
evaluated, and the attitude and rate messages built and serialized, ahead in batches; a
tick reads the clock and publishes the bytes.
"""

import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import QuaternionStamped, TransformStamped, Vector3Stamped
from nav_msgs.msg import Odometry
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.time import Time
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from rigidrot_ros import settings
from rigidrot_ros.core import PrecisionError
from rigidrot_ros.io import cdr
from rigidrot_ros.io import messages as msgs
from rigidrot_ros.io.bag import BagWriter
from rigidrot_ros.io.recorder import Recorder, type_name_of
from rigidrot_ros.node import cli, diagnostics, grid, outputs, scheduler
from rigidrot_ros.node.cli import SceneError
from rigidrot_ros.node.lookahead import Lookahead, SensorAhead
from rigidrot_ros.node.ros_params import descriptor, UnknownParameterError
from rigidrot_ros.node.ros_params import warn_unknown_overrides
from rigidrot_ros.node.streams import ImuStream, MagStream, StarTrackerStream
from rigidrot_ros.node.streams import make_streams, scene_time, STREAMS
from rigidrot_ros.params import BY_NAME, PARAMS
from rigidrot_ros.settings import SAMPLE_BUDGET_S

__all__ = ['AttitudeNode', 'main', 'SceneError']

#: The truth outputs beyond the pair, by topic: message class.
_EXTRA_TYPES = {'transform': TransformStamped, 'odom': Odometry, 'markers': MarkerArray}
_LEVELS = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)
#: A scheduler call this many timer periods after its due time is a catch-up (see _refill).
_CATCH_UP = 1.0
#: A catch-up call still runs a batch when its stream has less than this buffered ahead:
#: seconds of samples, and samples.
_KEEP_AHEAD_S, _KEEP_AHEAD = 4e-3, 3
#: Seconds between the recorder's chunk flushes: a flush's cost grows with the chunk, and
#: a flush of 0.4 s of kHz streams took 1.5 ms (p99 3.7 ms, under load), past a period.
RECORD_FLUSH_S = 0.1


class AttitudeNode(Node):
    """Publishes the exact attitude and body angular velocity of a rigid body."""

    def __init__(self, **kwargs):
        super().__init__('attitude_node', **kwargs)
        for p in PARAMS:
            try:
                self.declare_parameter(p.name, p.default, descriptor(p))
            except ParameterException as exc:      # an override outside its declared range
                raise SceneError(f'parameter {p.name}: {exc}') from None
        self.unknown_overrides = warn_unknown_overrides(self)
        #: The parameters' current values (read once here, then kept by _on_post_set).
        self._values = {p.name: self.get_parameter(p.name).value for p in PARAMS}
        try:
            self._setup = settings.prepare_run(self._values)
        except settings.TrialError as exc:
            raise SceneError(f'scene {self._scene_summary()}: {exc}') from None
        except ValueError as exc:
            raise SceneError(str(exc)) from None
        self._frames = self._setup.frames
        self._t_start = None
        self._grid0 = None              # clock ns of the truth grid's index 0 (see _anchor)
        self._tick_k = -1               # the last truth grid index published
        self._ahead = None
        self._last_sample = None
        self._counters = diagnostics.Counters()
        self.add_on_set_parameters_callback(self._on_set)
        self.add_post_set_parameters_callback(self._on_post_set)
        self._make_publishers()
        self._srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self._run_index = 0
        self._run_pending = True
        self._recorder = None
        if self._values['record']:
            self._start_recording()
        self._timer = None
        self._period_hz = float(self._values['publish_rate'])
        self._streams, self._sensors = [], []
        self._next_diag = time.monotonic() + 1.0
        self._start_streams()
        self._make_timer(self._values['publish_rate'])
        self.get_logger().info(
            f'running model {self.solution.model} ({self.solution.method}) at '
            f'{self._period_hz:g} Hz')

    def _make_publishers(self):
        """Create the publishers of the outputs that are on (the switches are read only)."""
        qos = QoSProfile(depth=self._values['qos_depth'],
                         reliability=ReliabilityPolicy.RELIABLE)
        self._pub_att = self.create_publisher(QuaternionStamped, 'attitude', qos)
        self._pub_rate = self.create_publisher(Vector3Stamped, 'angular_velocity', qos)
        #: Publisher by topic for the outputs built as ``(topic, msg)`` (extras, sensors).
        self._pubs = {}
        for topic, switch in outputs.TRUTH_EXTRAS:
            if self._values[switch]:
                self._pubs[topic] = self.create_publisher(_EXTRA_TYPES[topic], topic, qos)
        self._pubs_extra = bool(self._pubs)
        for stream in make_streams(self._setup):
            for topic, cls in stream.topics:
                self._pubs[topic] = self.create_publisher(cls, topic, qos)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # the run description: JSON on ~/run, kept for late joiners (see _record_tick)
        self._pub_run = self.create_publisher(
            String, '~/run', QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                        durability=DurabilityPolicy.TRANSIENT_LOCAL))

    @property
    def solution(self):
        """Return the core solution being published."""
        return self._setup.solution

    # -- parameters: validation in _on_set, side effects in _on_post_set --------------------
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
            raise UnknownParameterError(unknown)

    def _scene_summary(self):
        return ', '.join(f'{k} {self._values[k]!r}' for k in ('inertia', 'torque', 'omega0'))

    def _on_set(self, params):
        """Validate a change against the whole run; refuse with a reason naming it."""
        names = [p.name for p in params]
        try:
            reason = self._check_change(params, names)
        except Exception as exc:        # never let a parameter change kill the node
            reason = f'{type(exc).__name__}: {exc}'
        if reason is None:
            return SetParametersResult(successful=True)
        if not any(n in reason for n in names):
            reason = f'parameter(s) {", ".join(names)}: {reason}'
        return SetParametersResult(successful=False, reason=reason)

    def _check_change(self, params, names):
        """Return None if ``params`` may be set, else the reason (str)."""
        unknown = [n for n in names if n not in BY_NAME and not self.has_parameter(n)]
        if unknown:
            return str(UnknownParameterError(unknown))
        for p in params:
            if p.type_ == Parameter.Type.NOT_SET:
                return f'parameter {p.name} cannot be unset (it would be undeclared)'
        if not any(n in BY_NAME for n in names):
            return None                 # rclpy's own (use_sim_time, ...): rclpy checks them
        candidate = {**self._values, **{p.name: p.value for p in params if p.name in BY_NAME}}
        # a change the next run depends on (or publish_rate: the trial's first ticks, and
        # sensor rates of 0) is solved and tried as a whole run; the running one is kept
        try_samples = any(n == 'publish_rate' or BY_NAME[n].applies == 'reset'
                          for n in names if n in BY_NAME)
        try:
            if try_samples:
                settings.prepare_run(candidate)
            else:
                settings.check_run(candidate)
        except settings.TrialError as exc:
            return f'parameter(s) {", ".join(names)}: {exc}'
        except ValueError as exc:
            return str(exc)
        return None

    def _on_post_set(self, params):
        """Apply a change that was accepted: keep the values, and act on those that apply now."""
        names = set()
        for p in params:
            if p.name in BY_NAME:
                self._values[p.name] = p.value
                names.add(p.name)
        if 'publish_rate' in names:
            self._make_timer(self._values['publish_rate'])
        if names & {'frame_id', 'body_frame_id'}:
            self._frames = (self._values['frame_id'], self._values['body_frame_id'])
            if self._ahead is not None:
                self._ahead.drop_built()     # messages built ahead carry the old frames

    def _make_timer(self, rate):
        """(Re)create the one scheduler timer: the shortest period of every stream."""
        if self._timer is not None:
            self.destroy_timer(self._timer)
        self._period_hz = float(rate)
        self._period = 1.0 / float(rate)
        self._grid0 = None              # the next tick anchors a new grid (same t_start)
        self._timer_ns = scheduler.timer_period_ns([rate] + [s.rate for s in self._streams])
        self._timer = self.create_timer(self._timer_ns * 1e-9, self._on_timer)

    # -- the scheduler -----------------------------------------------------------------------
    def _on_timer(self):
        """Publish every sample due now, of every stream, in stamp order (the one timer).

        Then at most one look-ahead batch (the stream whose buffer runs out first), and
        the diagnostics once a second.
        """
        c_tick = time.perf_counter_ns()
        now_ns = self._now_ns()
        groups = []                     # (stamp ns, rank, [(publisher, msg, raw), ...])
        truth = self._truth_due(now_ns, groups)
        if self._t_start is not None:
            for sensor in self._sensors:
                self._sensor_due(sensor, now_ns, groups)
        if groups:
            groups.sort(key=lambda g: (g[0], g[1]))
            items = [it for g in groups for it in g[2]]
            pub_ns = self._now_ns()
            if not self._publish(items):
                return
            for sensor in self._sensors:
                sensor.published(pub_ns, self._counters)
            if truth:
                self._counters.tick_times.append(time.perf_counter_ns() - c_tick)
            self._record_tick(now_ns, items)
        # a call that came late (a catch-up) leaves its batch to the next call while the
        # buffers hold enough: a batch now would make the next samples late too
        self._refill(behind=now_ns - self._grid_due_ns(now_ns) > _CATCH_UP * self._timer_ns)
        if time.monotonic() >= self._next_diag:
            self._next_diag = max(self._next_diag + 1.0, time.monotonic() + 0.5)
            self._publish_diagnostics()

    def _grid_due_ns(self, now_ns):
        """Return the scheduler grid time this call was due at (the last one at or before now)."""
        if self._grid0 is None or now_ns < self._grid0:
            return now_ns
        return now_ns - (now_ns - self._grid0) % self._timer_ns

    def _refill(self, behind=False):
        """Run at most one look-ahead batch: of the stream whose buffer runs out first.

        ``behind``: this call came late; then the batch waits for a later call unless its
        stream has less than :data:`_KEEP_AHEAD_S` (or :data:`_KEEP_AHEAD` samples) buffered.
        """
        best, when = None, None
        if self._ahead is not None and self._ahead.needs(self._tick_k):
            best = (self._ahead, self._tick_k)
            when = self._ahead.ahead_of(self._tick_k) / self._period_hz
        for s in self._sensors:
            if s.ahead.needs(s.track.last):
                t = s.ahead.ahead_of(s.track.last) / s.track.rate
                if when is None or t < when:
                    best, when = (s.ahead, s.track.last), t
        if best is None:
            return
        if behind and when >= _KEEP_AHEAD_S and best[0].ahead_of(best[1]) >= _KEEP_AHEAD:
            self._counters.deferred += 1
            return
        best[0].refill(best[1])

    # -- the truth ---------------------------------------------------------------------------
    def _anchor(self, now_ns):
        """Anchor the truth grid at the scheduled time of this timer call (grid.anchor_ns).

        The first anchor of a run is also its ``t_start`` (scene time 0).
        """
        until = self._timer.time_until_next_call() if self._timer is not None else None
        g0 = grid.anchor_ns(now_ns, until, self._timer_ns)
        if self._t_start is None:
            self._t_start = Time(nanoseconds=g0, clock_type=self.get_clock().clock_type)
            self._run_pending = True        # _record_tick announces the run on ~/run
            self._start_sensor_tracks()
        self._grid0, self._tick_k = g0, -1
        self._ahead = Lookahead(self.solution,
                                lambda k: self._scene_time(self._tick_stamp_ns(k)),
                                self._period, build=self._build_ahead)

    def _build_ahead(self, start, data):
        """Serialize (CDR) the attitude and rate messages of a batch of ticks to come.

        One :mod:`rigidrot_ros.io.cdr` call per topic: the tick then publishes the bytes
        (``publish_raw``), and the recorder writes the same bytes.
        """
        q, w, _ = data
        stamps = [self._tick_stamp_ns(k) for k in range(start, start + len(q))]
        frame, body = self._frames
        return list(zip(cdr.attitude(stamps, q, frame).tolist(),
                        cdr.vector(stamps, w, body).tolist()))

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
        return grid.stamp_ns(self._grid0, self._period_hz, k)

    def _scene_time(self, ns):
        return scene_time(ns, self._t_start.nanoseconds, self._setup.time_scale)

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
        """Build the truth of one sample as ``(publisher, msg or class, raw)`` items.

        ``sample``: ``(quaternion, omega, error_bound)`` as :class:`Lookahead` gives it;
        ``built``: the ``(attitude, rate)`` bytes :meth:`_build_ahead` made, if any.
        """
        if built is None:
            att, rate = outputs.truth_pair(stamp_ns, sample, self._frames)
            out = [(self._pub_att, att, None), (self._pub_rate, rate, None)]
        else:
            out = [(self._pub_att, QuaternionStamped, built[0]),
                   (self._pub_rate, Vector3Stamped, built[1])]
        if self._pubs_extra:
            stamp = msgs.stamp(stamp_ns)
            for topic, msg in outputs.truth_extras(stamp, sample, self._frames, self._setup):
                out.append((self._pubs[topic], msg, None))
        return out

    def _truth_due(self, now_ns, groups):
        """Append the truth ticks due at ``now_ns`` to ``groups``; True if any.

        Every grid tick from the last published one to now goes out (a call that comes
        late publishes the ticks it owes: counted ``ticks_late``, not lost); only a backlog
        beyond a second (a clock jump) is skipped and counted ``ticks_missed``.
        """
        st = self._counters
        if self._grid0 is None or now_ns < self._grid0:     # new grid, or the clock went back
            self._anchor(now_ns)
        k = grid.index(self._grid0, self._period_hz, now_ns)
        if k <= self._tick_k:
            if k >= self._tick_k - 1:
                return False            # this grid time is published already
            self._anchor(now_ns)        # the clock went back: a new grid
            k = 0
        first = self._tick_k + 1
        if k - first >= max(grid.BACKLOG_MIN, self._period_hz):
            st.missed += k - first
            first = k
        if k > first:
            st.late += 1
        for j in range(first, k + 1):
            if not self._truth_tick(j, now_ns, groups):
                break
        return True

    def _truth_tick(self, k, now_ns, groups):
        """Append tick k's items to ``groups`` (False if its sample failed)."""
        st = self._counters
        self._tick_k = k
        stamp_ns = self._tick_stamp_ns(k)
        st.latencies.append(now_ns - stamp_ns)
        c0 = time.perf_counter()
        try:
            sample, built = self._ahead.get(k)
        except Exception as exc:        # PrecisionError, or anything else: report, keep going
            self._failed(self._scene_time(stamp_ns), exc)
            return False
        st.times.append(time.perf_counter() - c0)
        groups.append((stamp_ns, 0, self._truth_messages(stamp_ns, sample, built)))
        st.published += 1
        self._last_sample = (self._scene_time(stamp_ns), sample[2])
        return True

    def _failed(self, t, exc):
        text = str(exc) if isinstance(exc, (PrecisionError, ValueError)) else \
            f'{type(exc).__name__}: {exc}'
        self._counters.failed(text)
        self.get_logger().error(f'evaluation failed at t = {t} s: {text}',
                                throttle_duration_sec=1.0)

    # -- the sensors -------------------------------------------------------------------------
    def _start_streams(self):
        """Make the sensor streams of the run (fresh noise); their grids start with t_start."""
        self._streams = make_streams(self._setup)
        self._sensors = []

    def _start_sensor_tracks(self):
        """At a run's t_start: each sensor's grid, timing model and look-ahead."""
        t0 = self._t_start.nanoseconds
        self._sensors = [_Sensor(self, s, t0, rank)
                         for rank, s in enumerate(self._streams, start=1)]

    def _sensor_due(self, sensor, now_ns, groups):
        """Append the samples of ``sensor`` due at ``now_ns`` to ``groups``."""
        ks, skipped = sensor.track.due(now_ns)
        self._counters.skipped += skipped
        for k in ks:
            try:
                sample, built = sensor.ahead.get(k)
            except Exception as exc:    # noqa: B902 - a sample that cannot be read: report
                self._failed(self._scene_time(sensor.track.stamp_ns(k)), exc)
                continue
            true_ns, _, keep, err, _ = sample
            if err is not None:
                self._failed(self._scene_time(true_ns), err)
                continue
            if not keep:
                sensor.dropped += 1
                continue
            if built is None:
                built = sensor.build_one(sample)
            groups.append((true_ns, sensor.rank,
                           [(self._pubs[topic], cls, raw) for topic, cls, raw in built]))
            sensor.pending.append(true_ns)

    # -- diagnostics -------------------------------------------------------------------------
    def _publish_diagnostics(self):
        ahead = self._ahead
        batches = ahead.take_stats() if ahead is not None else []
        gyro = [s.bound for s in self._streams if s.name == 'imu']
        sensors = {s.stream.name: s.report() for s in self._sensors}
        level, msg, values = diagnostics.report(
            self._counters.window(STREAMS), self.solution, period_hz=self._period_hz,
            delivered=self._delivered_rate(),
            error_bound=float(self._last_sample[1]) if self._last_sample else 0.0,
            scene_time=self._last_sample[0] if self._last_sample else None,
            increment_bound=gyro[0] if gyro else 0.0, lookahead=ahead, batches=batches,
            sensors=sensors)
        status = DiagnosticStatus(level=_LEVELS[level], name=f'{self.get_name()}: exact '
                                  'attitude', message=msg,
                                  hardware_id=self.get_fully_qualified_name())
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
        now, count = time.monotonic(), self._counters.published
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
        path = self._values['record_path'] or 'runs'
        topics = [t for t in (self._values['record_topics'] or []) if t]
        try:
            writer = BagWriter(path, self.get_name(), flush_period=RECORD_FLUSH_S)
        except OSError as exc:
            raise SceneError(f'cannot record to {path!r}: {exc}') from None
        try:
            self._recorder = Recorder(self, writer, topics=topics, exclude_own=True)
        except Exception as exc:  # noqa: B902 - ValueError, or rclpy's invalid-name errors
            writer.close()
            raise SceneError(f'parameter record_topics: {exc}') from None
        self.get_logger().info(f'recording to {writer.path}')

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
            info = outputs.run_description(
                self._setup, start, self._run_index, self.get_fully_qualified_name(),
                {p.topic_name: type_name_of(p.msg_type) for p in self.publishers})
            msg = outputs.run_message(info)
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
                      f'published {self._counters.published} ticks', file=sys.stderr)
            except (OSError, ValueError) as exc:
                print(f'attitude_node: could not finish the bag: {exc}', file=sys.stderr)
            self._recorder = None
        return super().destroy_node()

    # -- reset -------------------------------------------------------------------------------
    def _on_reset(self, request, response):
        try:
            setup = settings.prepare_run(self._values)
        except ValueError as exc:
            response.success = False
            response.message = f'reset refused, previous scene keeps running: {exc}'
            return response
        self._setup = setup
        self._t_start = None
        self._grid0 = None                  # the next tick anchors the new run's grid
        self._ahead = None
        self._last_sample = None
        self._run_pending = True            # the next tick announces the new run on ~/run
        self._start_streams()               # fresh noise; a new run's increment bound
        self._make_timer(self._values['publish_rate'])     # the new run's sensor rates
        response.success = True
        response.message = f'running model {setup.solution.model} ({setup.solution.method})'
        self.get_logger().info(f'reset: {response.message}')
        return response


class _Sensor:
    """One sensor stream of a run on the node's schedule: grid, timing, look-ahead.

    A sample is ``(true_ns, stamp_ns, keep, error, row)``: its grid time, the stamp its
    messages carry (:meth:`Track.marks`), whether it is published (not dropped), the
    exception that kept it from being read (else None), and its values (a tuple, one
    entry per array of the batch). The imu is read a block at a time: the gyro by
    :meth:`Gyro.read_many` (bit for bit the per-sample reads) and, where there is one,
    the accelerometer over the same intervals by :meth:`Accelerometer.read_many`
    (:meth:`_read_accel`); the star tracker and the magnetometer sample by sample. Each
    batch is serialized by
    :mod:`rigidrot_ros.io.cdr`, one call per topic, and every one of these streams
    carries its timing model (stamps jittered and offset, samples dropped, latency). A
    stream of another kind is read and built per sample by its own ``messages`` (and
    stamped by it: its stamp is not jittered nor offset).
    """

    def __init__(self, node, stream, t_start_ns, rank):
        self.node, self.stream, self.rank = node, stream, rank
        self.t_start_ns = t_start_ns
        self.track = scheduler.Track(stream.name, t_start_ns, stream.rate, stream.first,
                                     scheduler.timing_of(node._setup.values, stream.name))
        self.dropped = 0
        self.pending = []               # grid times (ns) published by this call
        self.latencies = []             # publication - grid time, ns, this window
        kind = type(stream)
        if kind is ImuStream and hasattr(stream.model, 'read_many'):
            self._read, self._build = self._read_imu, self._build_imu
        elif kind is StarTrackerStream:
            self._read, self._build = self._read_star, self._build_star
        elif kind is MagStream:
            self._read, self._build = self._read_mag, self._build_mag
        else:
            self._read, self._build = self._read_generic, None
        self.types = dict(stream.topics)
        self.ahead = SensorAhead(self._read, lambda k: self._read(range(k, k + 1))[0][0],
                                 1.0 / stream.rate, stream.first,
                                 build=self._build_batch if self._build else None)

    # -- reading -----------------------------------------------------------------------------
    def _scene(self, ns):
        return scene_time(ns, self.t_start_ns, self.node._setup.time_scale)

    def _samples(self, ks, rows, errors):
        stamps, keep = self.track.marks(ks)
        true = [self.track.stamp_ns(k) for k in ks]
        return [(t, int(s), bool(kp), e, r)
                for t, s, kp, e, r in zip(true, stamps.tolist(), keep.tolist(), errors, rows)]

    def _read_imu(self, ks):
        """Read the imu over the intervals of ``ks``: gyro, then accelerometer (if any).

        The gyro as one block (per sample if the block fails), the accelerometer over the
        same intervals (:meth:`_read_accel`).
        """
        c0 = time.perf_counter()
        ends = np.array([self._scene(self.track.stamp_ns(k))
                         for k in range(ks.start - 1, ks.stop)])
        model, n = self.stream.model, len(ks)
        try:
            b = model.read_many(ends, budget=SAMPLE_BUDGET_S)
            blocks, errors = [b], [None] * n
        except ValueError:              # one interval too hard: each on its own
            blocks, errors = [], []
            for i in range(n):
                try:
                    blocks.append(model.read_many(ends[i:i + 2], budget=SAMPLE_BUDGET_S))
                    errors.append(None)
                except ValueError as exc:
                    errors.append(exc)
        rows = []
        for block in blocks:
            self.stream.bound = max(self.stream.bound, float(block.delta_angle_bound.max()),
                                    float(block.delta_rotation_bound.max()))
            rows += list(zip(block.omega, block.variance, block.delta_angle,
                             block.delta_rotation))
        rows = iter(rows)
        rows = [None if e is not None else next(rows) for e in errors]
        if self.stream.accel is not None:
            rows, errors = self._read_accel(ends, rows, errors)
        self._count(n, c0)
        out = self._samples(ks, rows, errors)
        return out, out

    def _read_accel(self, ends, rows, errors):
        """Append the accelerometer's ``(specific force, variance, delta_velocity)`` to rows.

        Over the intervals ``[ends[i], ends[i + 1]]`` whose gyro read succeeded, in order,
        as :meth:`ImuStream.messages` reads it after the gyro: one
        :meth:`Accelerometer.read_many` block (bit for bit the per-sample reads), else
        interval by interval (a failed gyro interval leaves the accelerometer's noise
        stream untouched, as there; a failed accelerometer read makes the sample an error).
        """
        acc = self.stream.accel
        if all(e is None for e in errors):
            try:
                b = acc.read_many(ends, budget=SAMPLE_BUDGET_S)
                return [r + a for r, a in zip(rows, zip(b.specific_force, b.variance,
                                                        b.delta_velocity))], errors
            except ValueError:          # one interval too hard: each on its own
                pass
        out_rows, out_errors = [], []
        for i, (row, err) in enumerate(zip(rows, errors)):
            if err is None:
                try:
                    b = acc.read_many(ends[i:i + 2], budget=SAMPLE_BUDGET_S)
                    row = row + (b.specific_force[0], b.variance[0], b.delta_velocity[0])
                except Exception as exc:    # noqa: B902 - reported when the sample is due
                    row, err = None, exc
            out_rows.append(row)
            out_errors.append(err)
        return out_rows, out_errors

    def _read_each(self, ks, read):
        """Read the samples ``ks`` one by one with ``read(k) -> row``, errors kept per sample."""
        c0 = time.perf_counter()
        rows, errors = [], []
        for k in ks:
            try:
                rows.append(read(k))
                errors.append(None)
            except Exception as exc:    # noqa: B902 - reported when the sample is due
                rows.append(None)
                errors.append(exc)
        self._count(len(ks), c0)
        out = self._samples(ks, rows, errors)
        return out, out

    def _read_star(self, ks):
        def read(k):
            r = self.stream.model.read(self._scene(self.track.stamp_ns(k)))
            return r.quaternion, r.covariance
        return self._read_each(ks, read)

    def _read_mag(self, ks):
        dt = self.node._setup.time_scale / self.stream.rate     # as MagStream.messages

        def read(k):
            r = self.stream.model.read(self._scene(self.track.stamp_ns(k)), dt)
            return r.field, r.covariance
        return self._read_each(ks, read)

    def _read_generic(self, ks):
        node = self.node
        return self._read_each(ks, lambda k: self.stream.messages(
            k, self.t_start_ns, node._setup.time_scale, node._frames))

    def _count(self, n, c0):
        per = (time.perf_counter() - c0) / max(n, 1)
        for _ in range(n):
            self.node._counters.sampled(self.stream.name, per)

    # -- building ----------------------------------------------------------------------------
    def _build_batch(self, start, data):
        """Build a batch's messages (cdr), for the samples that were read and are kept."""
        samples = data
        ok = [i for i, s in enumerate(samples) if s[3] is None and s[2]]
        out = [None] * len(samples)
        if ok:
            built = self._build([samples[i][1] for i in ok], [samples[i][4] for i in ok])
            for i, b in zip(ok, built):
                out[i] = b
        return out

    def build_one(self, sample):
        """Return the ``(topic, class, raw)`` items of one sample read now."""
        if self._build is None:
            return [(topic, msg, None) for topic, msg in sample[4]]
        return self._build([sample[1]], [sample[4]])[0]

    def _build_imu(self, stamps, rows):
        body = self.node._frames[1]
        cols = [np.array(c) for c in zip(*rows)]
        w, var, da, dr = cols[:4]
        accel = len(cols) > 4           # with the accelerometer's three columns
        if accel:
            f, avar, dv = cols[4:]
            imu = cdr.imu(stamps, w, var, body, f, avar).tolist()
        else:
            imu = cdr.imu(stamps, w, var, body).tolist()
        cols = [imu, cdr.vector(stamps, da, body).tolist(),
                cdr.vector(stamps, dr, body).tolist()]
        topics = ['imu', 'delta_angle', 'delta_rotation']
        if accel:
            cols.append(cdr.vector(stamps, dv, body).tolist())
            topics.append('delta_velocity')
        classes = [self.types[name] for name in topics]
        return [list(zip(topics, classes, raws)) for raws in zip(*cols)]

    def _build_star(self, stamps, rows):
        q, cov = (np.array(c) for c in zip(*rows))
        raw = cdr.star_tracker(stamps, q, cov, self.node._frames[0]).tolist()
        cls = self.types['star_tracker']
        return [[('star_tracker', cls, x)] for x in raw]

    def _build_mag(self, stamps, rows):
        f, cov = (np.array(c) for c in zip(*rows))
        raw = cdr.magnetic_field(stamps, f, cov, self.node._frames[1]).tolist()
        cls = self.types['mag']
        return [[('mag', cls, x)] for x in raw]

    # -- accounting --------------------------------------------------------------------------
    def published(self, pub_ns, counters):
        """Note the publication time of the samples this call published."""
        if self.pending:
            self.latencies += [pub_ns - t for t in self.pending]
            self.pending = []

    def report(self):
        """Return ``(latency mean, p99, max s, dropped)`` of this window, and start the next."""
        out = diagnostics.summary(self.latencies, 1e-9) + (self.dropped,)
        self.latencies = []
        return out


def main(args=None):
    """Entry point of ``attitude_node`` (accepts the usual ``--ros-args``); see cli.main."""
    return cli.main(args, AttitudeNode)


if __name__ == '__main__':
    sys.exit(main())
