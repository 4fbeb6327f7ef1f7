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
  with seeded noise and bias, and the exact increments over each gyro interval; with
  ``accel.enable`` the same ``imu`` carries the accelerometer's specific force, and
  ``delta_velocity`` (Vector3Stamped, m/s, in B) its exact increment.
- ``mag`` (sensor_msgs/MagneticField, tesla, in B) with ``mag.enable``.
- ``star_tracker`` (geometry_msgs/PoseWithCovarianceStamped) with ``star_tracker.enable``.
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) at 1 Hz.
- ``~/run`` (std_msgs/String, transient-local, depth 1): the run description as JSON
  (scene, model, method, tol, backend, ``start_ns``, ``time_scale``, version, topics),
  published with the first tick of each run, so a bag of any recorder can be scored.
Service ``~/reset`` (std_srvs/Trigger): restart at t = 0 from the current parameters.

This module is the wiring; the parts are elsewhere: the parameters in
:mod:`rigidrot_ros.run.params`, the run set-up in :func:`rigidrot_ros.run.settings.prepare_run`,
the tick grids in :mod:`~rigidrot_ros.run.grid` (stamps: see there), the sensor streams
in :mod:`~rigidrot_ros.run.streams` and each one's schedule, look-ahead and messages in
:mod:`~rigidrot_ros.run.sensor_ahead`, the schedule's grid, timing and choice of the next
batch in :mod:`~rigidrot_ros.run.scheduler`, the truth ahead of time in
:mod:`~rigidrot_ros.runtime.lookahead`, the messages in :mod:`~rigidrot_ros.run.outputs`,
the diagnostics in :mod:`~rigidrot_ros.runtime.diagnostics`, ``~/run`` and the recorder in
:mod:`~rigidrot_ros.ros.recording`, ``--help`` and ``main`` in
:mod:`~rigidrot_ros.ros.cli`. Because the coming ticks' times are known, their samples are
evaluated, and the attitude and rate messages built and serialized, ahead in batches; a
tick reads the clock and publishes the bytes.
"""

import contextlib
import os
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import QuaternionStamped, TransformStamped, Vector3Stamped
from nav_msgs.msg import Odometry
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

from rigidrot_ros.core import PrecisionError
from rigidrot_ros.msgs import cdr
from rigidrot_ros.msgs import messages as msgs
from rigidrot_ros.ros import cli, recording
from rigidrot_ros.ros.cli import SceneError
from rigidrot_ros.ros.ros_params import descriptor, UnknownParameterError, warn_unknown_overrides
from rigidrot_ros.run import grid, outputs, scheduler, settings
from rigidrot_ros.run.params import BY_NAME, PARAMS
from rigidrot_ros.run.sensor_ahead import Sensor
from rigidrot_ros.run.streams import make_streams, scene_time, STREAMS
from rigidrot_ros.runtime import collector, diagnostics, realtime
from rigidrot_ros.runtime.lookahead import BatchWorker, Lookahead

__all__ = ['AttitudeNode', 'main', 'SceneError']

#: The truth outputs beyond the pair, by topic: message class.
_EXTRA_TYPES = {'transform': TransformStamped, 'odom': Odometry, 'markers': MarkerArray}
_LEVELS = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)
#: A scheduler call this many timer periods after its due time is a catch-up (see _refill).
_CATCH_UP = 1.0
#: A call that ended within this share of its timer period after its due time runs the
#: collector's pending pass (collector.Passes; a pass takes 0.3 to 1 ms under load).
_GC_ROOM = 0.4


def _use_worker():
    """Whether look-ahead batches run in a worker thread (``RIGIDROT_LOOKAHEAD_WORKER=0``: not).

    The variable is for measuring the two against each other; anything but ``0`` means on.
    """
    return os.environ.get('RIGIDROT_LOOKAHEAD_WORKER', '1').strip() != '0'


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
        self._gc = diagnostics.GcWatch()
        #: Freezes the start-up heap out of the collector's full passes (node.collector)
        self._freezer = collector.Freezer()
        #: The young passes, run right after a call that ended early (node.collector)
        self._passes = collector.Passes()
        #: The publishing thread's scheduling policy (realtime.request; diagnostics)
        self._scheduling = realtime.describe()
        #: Runs the look-ahead batches off the executor's thread (lookahead.BatchWorker)
        self._worker = BatchWorker() if _use_worker() else None
        self._gate_last = (0, 0)        # the worker gate's holds and ns at the last report
        self.add_on_set_parameters_callback(self._on_set)
        self.add_post_set_parameters_callback(self._on_post_set)
        self._make_publishers()
        self._srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self._runs = recording.RunLog(self._pub_run, recording.open_recorder(
            self, self._values, self._worker) if self._values['record'] else None)
        self._timer = None
        self._period_hz = float(self._values['publish_rate'])
        self._streams, self._sensors = [], []
        self._next_diag = time.monotonic() + 1.0
        self._start_streams()
        self._make_timer(self._values['publish_rate'])
        self._freezer.start()           # before the first tick: a full pass costs ~70 ms
        self._passes.start()
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
        # the run description: JSON on ~/run, kept for late joiners (recording.RunLog)
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
            with self._eval_lock():     # solving a candidate: not beside a batch (mpmath)
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
        the diagnostics once a second. Each phase's time goes to the diagnostics (the
        window's longest call: ``call_max_phases``).
        """
        c_tick = time.perf_counter_ns()
        gc0 = self._gc.total_ns
        now_ns = self._now_ns()
        due_ns = self._grid_due_ns(now_ns)
        groups = []                     # (stamp ns, rank, [(publisher, msg, raw), ...])
        owed = []                       # (stream, samples due, of them evaluated now)
        truth = self._truth_due(now_ns, groups, owed)
        if self._t_start is not None:
            for sensor in self._sensors:
                n0, m0 = len(groups), sensor.ahead.misses
                sensor.due(now_ns, groups, self._pubs, self._failed)
                owed.append((sensor.stream.name, len(groups) - n0,
                             sensor.ahead.misses - m0))
        c_collect = c_publish = c_record = time.perf_counter_ns()
        if groups:
            groups.sort(key=lambda g: (g[0], g[1]))
            items = [it for g in groups for it in g[2]]
            pub_ns = self._now_ns()
            if not self._publish(items):
                return
            for sensor in self._sensors:
                sensor.published(pub_ns, self._counters)
            c_publish = time.perf_counter_ns()
            if truth:
                self._counters.tick_times.append(c_publish - c_tick)
            start = self._t_start.nanoseconds if self._t_start is not None else now_ns
            self._runs.tick(self, self._setup, start, now_ns, items)
            c_record = time.perf_counter_ns()
        # a call that came late (a catch-up) leaves its batch to the next call while the
        # buffers hold enough: a batch now would make the next samples late too
        batch = self._refill(behind=now_ns - due_ns > _CATCH_UP * self._timer_ns)
        c_batch = time.perf_counter_ns()
        if time.monotonic() >= self._next_diag:
            self._next_diag = max(self._next_diag + 1.0, time.monotonic() + 0.5)
            self._freezer.poll()        # once per run, a few seconds in (O(1))
            self._publish_diagnostics()
        wake = max(now_ns - due_ns, 0)
        # the collector's pass, where the next call is most of a period away (or overdue)
        self._passes.poll(wake + time.perf_counter_ns() - c_tick <= _GC_ROOM * self._timer_ns)
        c_end = time.perf_counter_ns()
        if self._worker is not None:
            self._open_gate(c_tick, now_ns, c_end)
        gc_ns = self._gc.total_ns - gc0
        self._counters.call(wake + c_end - c_tick, lambda: [
            ('wake', wake),
            ('collect', (c_collect - c_tick, ', '.join(
                f'{name} {n} owed/{m} now' for name, n, m in owed if n or m))),
            ('publish', c_publish - c_collect), ('record', c_record - c_publish),
            ('batch', (c_batch - c_record, batch)), ('diag', c_end - c_batch),
            ('gc', gc_ns)])

    def _open_gate(self, c_tick, now_ns, c_end):
        """Let the worker run until shortly before the next call (lookahead.SlackGate).

        For good while a stream's batch in the worker is needed soon (``Ahead.urgent``).
        ``c_tick``, ``c_end``: the call's start and end (perf_counter ns); ``now_ns``: its
        start on the node's clock.
        """
        gate = self._worker.gate
        if (self._ahead is not None and self._ahead.urgent()) or \
                any(s.ahead.urgent() for s in self._sensors):
            gate.open()
            return
        nxt = self._grid_due_ns(now_ns + c_end - c_tick) + self._timer_ns
        gate.open_until(gate.deadline_ns(c_tick + (nxt - now_ns), self._timer_ns))

    def _grid_due_ns(self, now_ns):
        """Return the scheduler grid time this call was due at (the last one at or before now)."""
        if self._grid0 is None or now_ns < self._grid0:
            return now_ns
        return now_ns - (now_ns - self._grid0) % self._timer_ns

    def _refill(self, behind=False):
        """Start the look-ahead batches this call owes (:func:`scheduler.next_batch` chooses).

        Inline (no worker) at most one: a batch holds the executor. With the worker every
        stream that needs one gets its batch queued there (each stream at most one at a
        time): after a catch-up every buffer is empty, and a stream left for a later call
        would evaluate its next sample alone. Returns what ran, for the diagnostics:
        ``'<stream> <samples>'`` (comma-separated), ``'deferred'`` or ''.
        """
        streams = [(s.ahead, s.track.last, s.track.rate) for s in self._sensors]
        names = [s.stream.name for s in self._sensors]
        if self._ahead is not None:
            streams.insert(0, (self._ahead, self._tick_k, self._period_hz))
            names.insert(0, 'truth')
        ran = []
        while streams:
            best = scheduler.next_batch(streams, behind)
            if best is scheduler.DEFERRED:
                self._counters.deferred += 1
                ran.append('deferred')
                break
            if best is None:
                break
            n = best[0].refill(best[1])
            i = next(i for i, (a, _, _) in enumerate(streams) if a is best[0])
            if n:
                ran.append(f'{names[i]} {n}')
            if self._worker is None:
                break
            del streams[i], names[i]
        return ', '.join(ran)

    # -- the truth ---------------------------------------------------------------------------
    def _anchor(self, now_ns):
        """Anchor the truth grid at the scheduled time of this timer call (grid.anchor_ns).

        The first anchor of a run is also its ``t_start`` (scene time 0).
        """
        until = self._timer.time_until_next_call() if self._timer is not None else None
        g0 = grid.anchor_ns(now_ns, until, self._timer_ns)
        if self._t_start is None:
            self._t_start = Time(nanoseconds=g0, clock_type=self.get_clock().clock_type)
            self._runs.pending = True       # the first publication announces it on ~/run
            self._start_sensor_tracks()
            self._freezer.arm()             # what the run's start makes: frozen soon
        self._grid0, self._tick_k = g0, -1
        # the grid, run start and scale are bound now: a batch may run in the worker thread
        hz, t0, scale = self._period_hz, self._t_start.nanoseconds, self._setup.time_scale
        self._ahead = Lookahead(
            self.solution, lambda k: scene_time(grid.stamp_ns(g0, hz, k), t0, scale),
            self._period, build=lambda start, data: self._build_ahead(start, data, g0, hz),
            worker=self._worker)

    def _build_ahead(self, start, data, g0, hz):
        """Serialize (CDR) the attitude and rate messages of a batch of ticks to come.

        One :mod:`rigidrot_ros.msgs.cdr` call per topic: the tick then publishes the bytes
        (``publish_raw``), and the recorder writes the same bytes. ``g0``, ``hz``: the grid.
        """
        q, w, _ = data
        stamps = [grid.stamp_ns(g0, hz, k) for k in range(start, start + len(q))]
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

    def _truth_due(self, now_ns, groups, owed):
        """Append the truth ticks due at ``now_ns`` to ``groups``; True if any.

        Every grid tick from the last published one to now goes out (a call that comes
        late publishes the ticks it owes: counted ``ticks_late``, not lost); only a backlog
        beyond a second (a clock jump) is skipped and counted ``ticks_missed``
        (:func:`grid.truth_due`). Appends ``('truth', ticks, of them evaluated now)`` to
        ``owed``.
        """
        st = self._counters
        if self._grid0 is None or now_ns < self._grid0:     # new grid, or the clock went back
            self._anchor(now_ns)
        due = grid.truth_due(self._grid0, self._period_hz, self._tick_k, now_ns)
        if due is None:
            return False                # this grid time is published already
        if due is grid.NEW_GRID:
            self._anchor(now_ns)        # the clock went back: a new grid, from its tick 0
            due = (0, 0, 0)
        first, k, missed = due
        st.missed += missed
        if k > first:
            st.late += 1
        m0 = self._ahead.misses
        n0 = len(groups)
        self._ahead.fill_to(first, k)       # a catch-up: the owed ticks as one batch
        for j in range(first, k + 1):
            if not self._truth_tick(j, now_ns, groups):
                break
        owed.append(('truth', len(groups) - n0, self._ahead.misses - m0))
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
        self._sensors = [Sensor(s, t0, rank, self._setup, self._counters, lambda: self._frames,
                                self._worker)
                         for rank, s in enumerate(self._streams, start=1)]

    # -- diagnostics -------------------------------------------------------------------------
    def _publish_diagnostics(self, wait=False):
        """Take the window's counts now; build and publish the report in the worker thread.

        The report (percentiles, ~60 key-value pairs, one message) took 1.5 to 3 ms in the
        scheduler call (under load): a sample or two late every second at 1 kHz. With
        ``wait``, return once it is published.
        """
        ahead = self._ahead
        snap = {'raw': self._counters.take(self._gc.take()),
                'batches': ahead.take_stats() if ahead is not None else [],
                'ahead': ahead, 'solution': self.solution, 'period_hz': self._period_hz,
                'sensors': {s.stream.name: s.take_latencies() for s in self._sensors},
                'gyro': [s.bound for s in self._streams if s.name == 'imu'],
                'delivered': self._delivered_rate(), 'last': self._last_sample,
                'stamp': self.get_clock().now(), 'scheduling': self._scheduling,
                'gate': self._gate_window()}
        if self._worker is None:
            self._send_diagnostics(snap)
        else:
            self._worker.call(lambda: self._send_diagnostics(snap), self._diag_failed)
            if wait:
                self._worker.drain()

    def _gate_window(self):
        """Return the worker gate over the window, as text: holds and time held (or why none)."""
        gate = self._worker.gate if self._worker is not None else None
        if gate is None or not gate.on:
            return 'off'
        last, self._gate_last = self._gate_last, (gate.holds, gate.held_ns)
        if gate.deadline == gate.FREE and gate.holds == last[0]:
            return 'open'
        return f'{gate.holds - last[0]} holds, {(gate.held_ns - last[1]) / 1e6:.1f} ms'

    def _diag_failed(self, exc):
        if self.context.ok():
            self.get_logger().error(f'diagnostics failed: {type(exc).__name__}: {exc}',
                                    throttle_duration_sec=10.0)

    def _send_diagnostics(self, snap):
        """Build the report of a :meth:`_publish_diagnostics` snapshot, and publish it."""
        last, gyro = snap['last'], snap['gyro']
        level, msg, values = diagnostics.report(
            diagnostics.Counters.summarize(snap['raw'], STREAMS), snap['solution'],
            period_hz=snap['period_hz'], delivered=snap['delivered'],
            error_bound=float(last[1]) if last else 0.0,
            scene_time=last[0] if last else None,
            increment_bound=gyro[0] if gyro else 0.0, lookahead=snap['ahead'],
            batches=snap['batches'],
            sensors={k: Sensor.report_of(v) for k, v in snap['sensors'].items()})
        status = DiagnosticStatus(level=_LEVELS[level], name=f'{self.get_name()}: exact '
                                  'attitude', message=msg,
                                  hardware_id=self.get_fully_qualified_name())
        values['scheduling'] = snap['scheduling']
        values['worker_gate'] = snap['gate']
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr = DiagnosticArray()
        arr.header.stamp = snap['stamp'].to_msg()
        arr.status = [status]
        self._pub_diag.publish(arr)

    def _delivered_rate(self):
        """Ticks published per second since the last call, or None (diagnostics.delivered)."""
        rate, self._rate_window = diagnostics.delivered(
            getattr(self, '_rate_window', None), time.monotonic(), self._counters.published,
            self._period_hz)
        return rate

    def destroy_node(self):
        """Finish the bag (summary, index, metadata.yaml), then destroy the node."""
        self._gc.remove()
        self._passes.stop()
        if self._worker is not None:
            self._worker.stop()
        self._runs.close(self._counters.published)
        return super().destroy_node()

    # -- reset -------------------------------------------------------------------------------
    def _eval_lock(self):
        """Return the worker's evaluation lock (mpmath's precision, the core's caches), if any."""
        return self._worker.locked() if self._worker is not None else contextlib.nullcontext()

    def _on_reset(self, request, response):
        try:
            with self._eval_lock():
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
        self._runs.pending = True           # the next tick announces the new run on ~/run
        self._start_streams()               # fresh noise; a new run's increment bound
        self._make_timer(self._values['publish_rate'])     # the new run's sensor rates
        response.success = True
        response.message = f'running model {setup.solution.model} ({setup.solution.method})'
        self.get_logger().info(f'reset: {response.message}')
        return response


def main(args=None):
    """Entry point of ``attitude_node`` (accepts the usual ``--ros-args``); see cli.main."""
    return cli.main(args, AttitudeNode)


if __name__ == '__main__':
    sys.exit(main())
