"""attitude_node: publish the exact attitude and body rate of the configured scene.

Topics (relative names, so namespaces and remapping apply): those of the output table
(:mod:`rigidrot_ros.run.table`) that the parameters switch on: ``attitude`` (q_NB in N) and
``angular_velocity`` (in B) always; ``transform``, ``odom``, ``markers`` (the same truth);
``imu`` with its increments, ``star_tracker``, ``mag`` (sensors); and ``~/run``
(std_msgs/String, transient-local, depth 1: the run description as JSON, published with the
first tick of each run, so a bag of any recorder can be scored). ``/diagnostics`` at 1 Hz.
Service ``~/reset`` (std_srvs/Trigger): restart at t = 0 from the current parameters.

This module is the wiring; the parts are elsewhere: the parameters in
:mod:`rigidrot_ros.run.params`, the run set-up in :func:`rigidrot_ros.run.settings.prepare_run`,
every output (topic, type, rank, switch, reading, encoding) in the table
:mod:`rigidrot_ros.run.table`, the one scheduler timer's calls in
:mod:`~rigidrot_ros.run.schedule` (the truth's grid and look-ahead in
:mod:`~rigidrot_ros.run.truth_ahead`, each sensor's in :mod:`~rigidrot_ros.run.sensor_ahead`,
the grids in :mod:`~rigidrot_ros.run.grid`), the diagnostics in
:mod:`~rigidrot_ros.runtime.diagnostics`, ``~/run`` and the recorder in
:mod:`~rigidrot_ros.ros.recording`, ``--help`` and ``main`` in :mod:`~rigidrot_ros.ros.cli`.
Because the coming samples' times are known, they are evaluated and their messages encoded
ahead in batches; a call reads the clock and publishes the bytes.
"""

import contextlib
import sys
import time
import weakref

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from rigidrot_ros.core import PrecisionError
from rigidrot_ros.ros import cli, pacing, recording
from rigidrot_ros.ros.cli import SceneError
from rigidrot_ros.ros.recorder import msg_class
from rigidrot_ros.ros.ros_params import descriptor, UnknownParameterError, warn_unknown_overrides
from rigidrot_ros.run import settings, table
from rigidrot_ros.run.params import BY_NAME, PARAMS
from rigidrot_ros.run.schedule import Call, Schedule
from rigidrot_ros.run.sensor_ahead import Sensor
from rigidrot_ros.runtime import collector, diagnostics, realtime, switches
from rigidrot_ros.runtime.pacer import LEAD_S
from rigidrot_ros.runtime.worker import BatchWorker

__all__ = ['AttitudeNode', 'main', 'SceneError']

_LEVELS = (DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR)
#: A scheduler call this many timer periods after its due time is a catch-up (see refill).
_CATCH_UP = 1.0
#: A call that ended within this share of its timer period after its due time runs the
#: collector's pending pass (collector.Passes; a pass takes 0.3 to 1 ms under load).
_GC_ROOM = 0.4


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
        self._counters = diagnostics.Counters()
        self._gc = diagnostics.GcWatch()
        #: Freezes the start-up heap out of the collector's full passes (runtime.collector)
        self._freezer = collector.Freezer()
        #: The young passes, run right after a call that ended early (runtime.collector)
        self._passes = collector.Passes()
        #: The publishing thread's scheduling policy (realtime.request; diagnostics)
        self._scheduling = realtime.describe()
        #: Runs the look-ahead batches off the executor's thread (worker.BatchWorker)
        self._worker = BatchWorker() if switches.lookahead_worker() else None
        self._gate_last = (0, 0)        # the worker gate's holds and ns at the last report
        #: The native pacer's calls (pacing.PacedCalls), made at the first call it serves
        self._paced = None
        #: Why the node does not pace (None: it may, at >= 1 kHz on the system clock)
        self._pace_off = None if switches.pacer() else 'off (RIGIDROT_PACER=0)'
        self._lead_ns = int(LEAD_S * 1e9)
        self.add_on_set_parameters_callback(self._on_set)
        self.add_post_set_parameters_callback(self._on_post_set)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        #: (publisher, message class) by relative topic, for the outputs' encoded bytes
        self._pubs = {}
        self._make_publishers()
        self._srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self._runs = recording.RunLog(self._pub_run, recording.open_recorder(
            self, self._values, self._worker) if self._values['record'] else None)
        self._timer, self._timer_paced = None, False
        self._schedule = self._new_schedule()
        self._next_diag = time.monotonic() + 1.0
        self._make_timer(self._values['publish_rate'])
        self._freezer.start()           # before the first tick: a full pass costs ~70 ms
        self._passes.start()
        self.get_logger().info(
            f'running model {self.solution.model} ({self.solution.method}) at '
            f'{self._period_hz:g} Hz')
        self.get_logger().info('publishing ' + ', '.join(
            f'{p.topic_name} ({p.msg_type.__name__})' for p in self.publishers
            if p.topic_name not in ('/rosout', '/parameter_events')))

    def _make_publishers(self):
        """Create the publishers of the topics of the run's outputs (the table's), ``~/run`` too.

        At ``~/reset`` only those of topics that come or go with the new run are created or
        destroyed (a topic that needs an increment quantum set).
        """
        qos = QoSProfile(depth=self._values['qos_depth'],
                         reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        want = {t.name: (t.type, kind) for kind in self._setup.outputs
                for t in kind.topics_on(self._setup.values)}
        for name in [n for n in self._pubs if n not in want]:
            self.destroy_publisher(self._pubs.pop(name)[0])
        for name, (type_name, kind) in want.items():
            if name not in self._pubs:
                cls = msg_class(type_name)
                self._pubs[name] = (self.create_publisher(
                    cls, name, latched if kind.latched else qos), cls)
        # ~/run: published by RunLog with a run's first call, kept for late joiners
        self._pub_run = next(self._pubs[t.name][0] for kind in self._setup.outputs
                             if kind.grid == 'start' for t in kind.topics)

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
            self._schedule.drop_built()     # messages built ahead carry the old frames

    def _new_schedule(self):
        """Return the schedule of the current run set-up (its outputs fresh: new noise)."""
        return Schedule(self._setup, self._counters, lambda: self._frames, self._worker)

    def _make_timer(self, rate):
        """(Re)create the one scheduler timer: the shortest period of every stream."""
        self._period_hz = float(rate)
        self._timer_ns = self._schedule.retime(rate)    # a new truth grid at the next call
        self._make_call_timer()

    def _make_call_timer(self):
        """(Re)create the rcl timer of the scheduler calls, on the grid's period or paced.

        Paced (:meth:`_pacing`), a call serves every slot of the lead, so the calls come
        every ``pacing.PACED_CALL_NS`` (or the grid's period, if longer): the fixed part of
        a call (the executor's round, the bookkeeping, the recording's batch) is paid once
        for several slots. The grid keeps its own period (:attr:`_timer_ns`).
        """
        if self._timer is not None:
            self.destroy_timer(self._timer)
        self._timer_paced = self._may_pace()
        period = max(self._timer_ns, pacing.PACED_CALL_NS) if self._timer_paced else \
            self._timer_ns
        self._timer = self.create_timer(period * 1e-9, self._on_timer)

    def _may_pace(self):
        """Whether the node paces its calls: a period of at most 1 ms, the system clock."""
        return self._pace_off is None and self._timer_ns <= pacing.PACE_PERIOD_NS and \
            not self._sim_time()

    def _sim_time(self):
        """Whether the node's clock is ``/clock`` (``use_sim_time``)."""
        return self._time_source is not None and self._time_source.ros_time_is_active

    # -- the scheduler call ------------------------------------------------------------------
    def _on_timer(self):
        """Publish every sample due now, of every output, in stamp order (the one timer).

        Then the look-ahead batches owed (:meth:`Schedule.refill`), and the diagnostics once
        a second. Each phase's time goes to the diagnostics (the window's longest call:
        ``call_max_phases``).
        """
        paced = self._pacing()
        if paced != self._timer_paced:  # the pacer failed, or sim time came or went
            self._make_call_timer()
        if paced:
            return self._on_timer_paced()
        c_tick = time.perf_counter_ns()
        gc0 = self._gc.total_ns
        now_ns = self._now_ns()
        sch = self._schedule
        due_ns = sch.grid_due_ns(now_ns)
        call = sch.collect(now_ns, self._timer.time_until_next_call, self._failed)
        if call.started:
            self._freezer.arm()         # what the run's start makes: frozen soon
        c_collect = c_publish = c_record = time.perf_counter_ns()
        if call.groups:
            items = [self._pubs[topic] + (raw,) for topic, raw in call.items()]
            pub_ns = self._now_ns()
            if not self._publish_now(call, items, now_ns):
                return
            sch.published(pub_ns)
            c_publish = time.perf_counter_ns()
            if call.truth:
                self._counters.tick_times.append(c_publish - c_tick)
            self._runs.tick(self, self._setup, sch.t_start_ns, now_ns, items)
            c_record = time.perf_counter_ns()
        if self._paced is not None and len(self._paced):
            self._took(self._paced.harvest())
            c_record = time.perf_counter_ns()
        # a call that came late (a catch-up) leaves its batch to the next call while the
        # buffers hold enough: a batch now would make the next samples late too
        batch = sch.refill(behind=now_ns - due_ns > _CATCH_UP * self._timer_ns)
        c_batch = time.perf_counter_ns()
        self._diag_due()
        wake = max(now_ns - due_ns, 0)
        # the collector's pass, where the next call is most of a period away (or overdue)
        self._passes.poll(wake + time.perf_counter_ns() - c_tick <= _GC_ROOM * self._timer_ns)
        c_end = time.perf_counter_ns()
        if self._worker is not None:
            sch.open_gate(c_tick, now_ns, c_end)
        gc_ns = self._gc.total_ns - gc0
        self._counters.call(wake + c_end - c_tick, lambda: [
            ('wake', wake),
            ('collect', (c_collect - c_tick, ', '.join(
                f'{name} {n} owed/{m} now' for name, n, m in call.owed if n or m))),
            ('publish', c_publish - c_collect), ('record', c_record - c_publish),
            ('batch', (c_batch - c_record, batch)), ('diag', c_end - c_batch),
            ('gc', gc_ns)])

    def _publish_now(self, call, items, log_ns):
        """Publish a call's ``items`` from this thread; False if ROS shut down meanwhile.

        Then (SIGINT/SIGTERM while the call ran) the truth ticks none of whose messages
        went out are not counted, and what went out is recorded at ``log_ns``.
        """
        sent = recording.publish_all(self, [(pub, raw) for pub, _, raw in items])
        if sent < len(items):
            self._counters.published -= call.ticks - call.ticks_within(sent)
            self._runs.tick(self, self._setup, self._schedule.t_start_ns, log_ns, items[:sent])
            return False
        return True

    def _diag_due(self):
        """Publish the diagnostics once a second (and poll the collector's freezer)."""
        if time.monotonic() >= self._next_diag:
            self._next_diag = max(self._next_diag + 1.0, time.monotonic() + 0.5)
            self._freezer.poll()        # once per run, a few seconds in (O(1))
            self._publish_diagnostics()

    def _on_timer_paced(self):
        """Collect every sample due up to the lead ahead of now; the pacer publishes them.

        One collection (as an unpaced call at that time would make it: the same samples,
        read in the same order), split by the timer slot each sample falls due in (its
        grid time, plus its sensor's latency, rounded up to the timer's grid: where an
        unpaced call would have published it); each slot's messages are queued on the
        pacer, due at the slot's time, in the unpaced order. A slot already past (the
        node fell behind by more than the lead) goes out at once, as an unpaced catch-up
        would. A new grid (a ``publish_rate`` change) is anchored after the last slot
        still queued. Then the calls the pacer finished are recorded and counted
        (:meth:`_took`).
        """
        c_tick = time.perf_counter_ns()
        gc0 = self._gc.total_ns
        sch = self._schedule
        self._paced.pacer.spin_ns = min(pacing.SPIN_NS, self._timer_ns // 4)
        target = self._now_ns() + self._lead_ns
        if sch.truth.grid0 is not None and target >= sch.truth.grid0:
            target = sch.grid_due_ns(target)        # the last slot within the lead
        elif sch.truth.grid0 is None and self._paced.last_due is not None:
            # a new grid (a rate change) starts after the old grid's ticks still queued
            target = max(target, self._paced.last_due + self._timer_ns + 1)
        call = sch.collect(target, self._timer.time_until_next_call, self._failed, True)
        sch.forget_pending()            # the latencies come from each slot's samples
        if call.started:
            self._freezer.arm()
        c_collect = time.perf_counter_ns()
        slots = self._slots_of(call) if call.groups else []
        queued = [(due, [self._pubs[topic] + (raw,) for topic, raw in sub.items()], sub,
                   pending) for due, sub, pending in slots]
        if queued and self._paced.push_many(queued):
            self._counters.published -= call.ticks         # counted once rcl takes them
            queued = []
        for due, items, sub, pending in queued:
            pub_ns = self._now_ns()     # no room (the loop lags or stopped): publish now
            if not self._publish_now(sub, items, pub_ns):
                return
            sch.note_published(pending, pub_ns)
            self._runs.tick(self, self._setup, sch.t_start_ns, pub_ns, items)
        c_publish = time.perf_counter_ns()
        if call.truth:
            self._counters.tick_times.append(c_publish - c_tick)
        self._took(self._paced.harvest())
        c_record = time.perf_counter_ns()
        batch = sch.refill()
        c_batch = time.perf_counter_ns()
        self._diag_due()
        self._passes.poll(time.perf_counter_ns() - c_tick <=
                          _GC_ROOM * max(self._timer_ns, pacing.PACED_CALL_NS))
        c_end = time.perf_counter_ns()
        gc_ns = self._gc.total_ns - gc0
        self._counters.call(c_end - c_tick, lambda: [
            ('wake', 0),
            ('collect', (c_collect - c_tick, f'{len(slots)} slots: ' + ', '.join(
                f'{name} {n} owed/{m} now' for name, n, m in call.owed if n or m))),
            ('publish', c_publish - c_collect), ('record', c_record - c_publish),
            ('batch', (c_batch - c_record, batch)), ('diag', c_end - c_batch),
            ('gc', gc_ns)])

    def _slots_of(self, call):
        """Split ``call`` by timer slot: ``[(slot ns, Call, pending latencies)]``, in order.

        A truth tick falls due at its stamp, a sensor sample at its grid time plus its
        latency; a slot is the first timer grid time at or after that. Each slot's
        :class:`~rigidrot_ros.run.schedule.Call` has its truth ticks first, as collected;
        its pending latencies are ``Schedule.note_published``'s.
        """
        sch = self._schedule
        g0, period = sch.truth.grid0, self._timer_ns
        sensors = {s.rank: s for s in sch.sensors}
        out = {}
        for i, group in enumerate(call.groups):
            t, rank, _ = group
            truth = i < call.ticks
            where = self._counters if truth else sensors[rank]
            due = t if truth else t + where.track.timing.latency_ns
            slot = g0 + -(-(due - g0) // period) * period if due > g0 else g0
            sub, pending = out.get(slot) or out.setdefault(slot, (Call(), {}))
            sub.groups.append(group)
            if truth:
                sub.ticks += 1
                sub.truth = True
            pending.setdefault(id(where), (where, []))[1].append(t)
        return [(slot, sub, list(pending.values())) for slot, (sub, pending)
                in sorted(out.items(), key=lambda kv: kv[0])]

    def _pacing(self):
        """Whether this call is served ahead and published by the pacer (ros.pacing).

        At a scheduler period of at most ``PACE_PERIOD_NS`` on the system clock, unless
        ``RIGIDROT_PACER=0`` or the pacer cannot run here (said once in the log).
        """
        if not self._may_pace():
            return False
        if self._paced is None:
            try:
                self._paced = pacing.PacedCalls()
            except pacing.PacerError as exc:
                self._pace_off = f'off ({exc})'
                self.get_logger().warning(f'publishing from the executor: {exc}')
                return False
            # a node dropped without destroy_node frees its publishers: stop the loop first
            weakref.finalize(self, self._paced.pacer.stop)
            self.get_logger().info(f'publishing through the pacer, '
                                   f'{self._lead_ns / 1e6:g} ms ahead')
        return self._paced.pacer.alive

    def _pace_state(self):
        """Return the pacer's state for the diagnostics: on, with its lead, or why not."""
        if self._pace_off is not None:
            return self._pace_off
        if self._timer_ns > pacing.PACE_PERIOD_NS:
            return 'off (below 1 kHz)'
        if self._sim_time():
            return 'off (sim time)'
        if self._paced is None:
            return 'off (not started yet)'
        if not self._paced.pacer.alive:
            return 'off (its loop stopped)'
        return f'on (lead {self._lead_ns / 1e6:g} ms)'

    def _took(self, finished):
        """Record, count and announce what the pacer published (PacedCalls.harvest)."""
        sch = self._schedule
        calls = []
        for items, call, pending, sent, at_ns, statuses in finished:
            self._counters.published += call.ticks_within(sent)
            if sent < len(items):       # shut down meanwhile, cut by a reset, or refused
                failed = [s for s in statuses if s != pacing.STATUS_PENDING]
                if failed and self.context.ok():
                    self.get_logger().error(
                        f'rcl refused to publish (return code {failed[0]})',
                        throttle_duration_sec=1.0)
            if sent:
                sch.note_published(pending, at_ns)
                calls.append((at_ns, items[:sent]))
        if calls:
            self._runs.tick_many(self, self._setup, sch.t_start_ns, calls)

    def _now_ns(self):
        """Return the node clock's time (ns).

        Unless ``use_sim_time`` drives it, the ROS clock is the system clock
        (CLOCK_REALTIME, what rcl reads): read here directly, at a tenth of the cost of
        ``get_clock().now()`` after an idle gap (measured: README, the node's cost per tick).
        """
        if self._time_source is not None and not self._time_source.ros_time_is_active:
            return time.time_ns()
        return self.get_clock().now().nanoseconds

    def _failed(self, t, exc):
        text = str(exc) if isinstance(exc, (PrecisionError, ValueError)) else \
            f'{type(exc).__name__}: {exc}'
        self._counters.failed(text)
        self.get_logger().error(f'evaluation failed at t = {t} s: {text}',
                                throttle_duration_sec=1.0)

    # -- diagnostics -------------------------------------------------------------------------
    def _publish_diagnostics(self, wait=False):
        """Take the window's counts now; build and publish the report in the worker thread.

        The report (percentiles, ~60 key-value pairs, one message) took 1.5 to 3 ms in the
        scheduler call (under load): a sample or two late every second at 1 kHz. With
        ``wait``, return once it is published.
        """
        snap = self._schedule.snapshot()
        snap.update(raw=self._counters.take(self._gc.take()), solution=self.solution,
                    period_hz=self._period_hz, delivered=self._delivered_rate(),
                    stamp=self.get_clock().now(), scheduling=self._scheduling,
                    gate=self._gate_window(), pacer=self._pace_state())
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
        last = snap['last']
        level, msg, values = diagnostics.report(
            diagnostics.Counters.summarize(snap['raw'], table.sensor_names()),
            snap['solution'], period_hz=snap['period_hz'], delivered=snap['delivered'],
            error_bound=float(last[1]) if last else 0.0,
            scene_time=last[0] if last else None, increment_bound=snap['bound'],
            lookahead=snap['ahead'], batches=snap['batches'],
            sensors={k: Sensor.report_of(v) for k, v in snap['sensors'].items()})
        status = DiagnosticStatus(level=_LEVELS[level], name=f'{self.get_name()}: exact '
                                  'attitude', message=msg,
                                  hardware_id=self.get_fully_qualified_name())
        values['scheduling'] = snap['scheduling']
        values['worker_gate'] = snap['gate']
        values['pacer'] = snap['pacer']
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
        if self._paced is not None:     # before the publishers go: the pacer uses them
            self._took(self._paced.stop())
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
        if self._paced is not None:         # the old run's calls not yet due: dropped
            self._took(self._paced.cut())
        self._setup = setup
        self._make_publishers()             # topics that come or go with the new run
        self._runs.pending = True           # the next tick announces the new run on ~/run
        self._schedule = self._new_schedule()   # fresh noise; a new run's increment bound
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
