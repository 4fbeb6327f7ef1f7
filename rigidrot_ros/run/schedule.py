"""Every output of a run on the node's one timer: what a call publishes, and what it reads next.

The node runs one timer (:func:`rigidrot_ros.run.scheduler.timer_period_ns`). At each call
:meth:`Schedule.collect` gathers every sample due by then, of the truth
(:class:`~rigidrot_ros.run.truth_ahead.TruthAhead`) and of each sensor
(:class:`~rigidrot_ros.run.sensor_ahead.Sensor`), in stamp order then the table's rank, as
encoded bytes; the node publishes them; then :meth:`Schedule.refill` starts the look-ahead
batches the call owes (:func:`rigidrot_ros.run.scheduler.next_batch` chooses), and
:meth:`Schedule.open_gate` lets the worker run in the slack before the next call. The
outputs come from the table (:mod:`rigidrot_ros.run.table`) through the run's set-up; no
rclpy here: the node passes its clock readings and its timer's ``time_until_next_call``.
"""

from rigidrot_ros.run import grid, scheduler, table
from rigidrot_ros.run.sensor_ahead import Sensor
from rigidrot_ros.run.truth_ahead import TruthAhead

__all__ = ['Schedule', 'Call']


class Call:
    """What one scheduler call collected.

    Attributes
    ----------
    groups : list
        ``(stamp ns, rank, [(topic, bytes), ...])`` per sample, unsorted.
    owed : list
        ``(stream name, samples due, of them evaluated now)`` per stream.
    truth : bool
        Whether a truth tick was due.
    started : bool
        Whether this call started a run (its ``t_start``).
    ticks : int
        The truth ticks among ``groups`` (the first ``ticks`` of them, as collected).
    """

    __slots__ = ('groups', 'owed', 'truth', 'started', 'ticks', '_tick_starts')

    def __init__(self):
        self.groups, self.owed, self.truth, self.started = [], [], False, False
        self.ticks, self._tick_starts = 0, []

    def items(self):
        """Return every ``(topic, bytes)`` of the call in publishing order (stamp, rank)."""
        groups = self.groups
        order = sorted(range(len(groups)), key=lambda i: (groups[i][0], groups[i][1]))
        out, self._tick_starts = [], []
        for i in order:
            if i < self.ticks:
                self._tick_starts.append(len(out))
            out += groups[i][2]
        return out

    def ticks_within(self, n):
        """Return how many truth ticks have a message among the first ``n`` of :meth:`items`."""
        return sum(1 for start in self._tick_starts if start < n)


class Schedule:
    """The outputs of one run (a :class:`RunSetup`) on the node's one scheduler timer.

    Parameters
    ----------
    setup : RunSetup
        The run; its outputs are the table's kinds it switches on.
    counters : rigidrot_ros.runtime.diagnostics.Counters
        The node's counters.
    frames : callable
        Returns ``(frame_id, body_frame_id)`` now.
    worker : BatchWorker, optional
        Where the look-ahead batches run.

    Attributes
    ----------
    outputs : list of Output
        The run's outputs (:func:`rigidrot_ros.run.table.make`).
    truth : TruthAhead
        The truth outputs on the truth's grid.
    sensors : list of Sensor
        The sensors on their grids (from the run's ``t_start``; empty before).
    t_start_ns : int or None
        The run's scene time 0 on the node's clock (None before its first call).
    timer_ns : int
        The scheduler timer's period.
    """

    def __init__(self, setup, counters, frames, worker=None):
        self.setup, self.counters, self.frames, self.worker = setup, counters, frames, worker
        self.outputs = table.make(setup)
        self.truth = TruthAhead(setup, [o for o in self.outputs if o.grid == 'truth'],
                                counters, frames, worker)
        self.streams = [o for o in self.outputs if o.grid == 'sensor']
        self.sensors = []
        self.t_start_ns = None
        self.timer_ns = None

    @property
    def bound(self):
        """The largest error bound of the sensors' samples so far (rad; 0.0 if none)."""
        return max([o.bound for o in self.streams] + [0.0])

    def retime(self, rate):
        """Take a new truth rate (Hz); return the timer's period (ns): every stream's shortest."""
        self.truth.retime(rate)
        self.timer_ns = scheduler.timer_period_ns([rate] + [o.rate for o in self.streams])
        return self.timer_ns

    def grid_due_ns(self, now_ns):
        """Return the timer grid time a call at ``now_ns`` was due at (the last one before)."""
        g0 = self.truth.grid0
        if g0 is None or now_ns < g0:
            return now_ns
        return now_ns - (now_ns - g0) % self.timer_ns

    def _anchor(self, now_ns, until, call):
        """Anchor the truth grid at this call's scheduled time (:func:`grid.anchor_ns`).

        The first anchor of a run is also its ``t_start``: the sensors' grids start there.
        """
        g0 = grid.anchor_ns(now_ns, until(), self.timer_ns)
        if self.t_start_ns is None:
            self.t_start_ns = g0
            call.started = True
            self.sensors = [Sensor(o, g0, self.setup, self.counters, self.frames, self.worker)
                            for o in self.streams]
        self.truth.anchor(g0, self.t_start_ns)

    def collect(self, now_ns, until, failed, paced=False):
        """Return the :class:`Call` of the samples due at ``now_ns``, of every stream.

        ``until()`` is the timer's time until its next call (ns, or None); ``failed(scene
        time s, exception)`` gets each sample that cannot be evaluated. Every truth tick
        from the last published one to now goes out (a late call publishes what it owes);
        only a backlog beyond a second (a clock jump) is skipped and counted. ``paced``: the
        call runs ahead of the publication (``now_ns`` is the time it is due at); the
        latencies are noted at publication (:meth:`note_published`).
        """
        call = Call()
        t = self.truth
        if t.grid0 is None or now_ns < t.grid0:     # a new grid, or the clock went back
            self._anchor(now_ns, until, call)
        due = grid.truth_due(t.grid0, t.rate_hz, t.k, now_ns)
        if due is not None:
            if due is grid.NEW_GRID:
                self._anchor(now_ns, until, call)   # back before the grid: its tick 0
                due = (0, 0, 0)
            call.truth = True
            n, now = t.publish_due(due, now_ns, self.t_start_ns, call.groups, failed, paced)
            call.owed.append(('truth', n, now))
            call.ticks = n
        for s in self.sensors:
            n0, m0 = len(call.groups), s.ahead.misses
            s.due(now_ns, call.groups, failed)
            call.owed.append((s.output.name, len(call.groups) - n0, s.ahead.misses - m0))
        return call

    def published(self, pub_ns):
        """Note the publication time (ns) of what this call published."""
        for s in self.sensors:
            s.published(pub_ns)

    def forget_pending(self):
        """Drop the sensors' stamps of a paced call (the node notes its slots' own)."""
        for s in self.sensors:
            s.pending = []

    def note_published(self, pending, pub_ns):
        """Note the publication time (ns) of paced samples: ``[(counters or Sensor, stamps)]``.

        A truth tick published more than a timer period after its stamp counts as late
        (``ticks_late``; unpaced, a call that owed more than one tick counts once).
        """
        for where, stamps in pending:
            if stamps:              # the node's counters (truth), or a Sensor
                lat = [pub_ns - t for t in stamps]
                where.latencies += lat
                if where is self.counters:
                    where.late += sum(1 for x in lat if x > self.timer_ns)

    def refill(self, behind=False):
        """Start the look-ahead batches this call owes (:func:`scheduler.next_batch` chooses).

        Inline (no worker) at most one: a batch holds the executor. With the worker every
        stream that needs one gets its batch queued there (each stream at most one at a
        time): after a catch-up every buffer is empty, and a stream left for a later call
        would evaluate its next sample alone. Returns what ran, for the diagnostics:
        ``'<stream> <samples>'`` (comma-separated), ``'deferred'`` or ''.
        """
        streams = [(s.ahead, s.track.last, s.track.rate) for s in self.sensors]
        names = [s.output.name for s in self.sensors]
        if self.truth.ahead is not None:
            streams.insert(0, (self.truth.ahead, self.truth.k, self.truth.rate_hz))
            names.insert(0, 'truth')
        ran = []
        while streams:
            best = scheduler.next_batch(streams, behind)
            if best is scheduler.DEFERRED:
                self.counters.deferred += 1
                ran.append('deferred')
                break
            if best is None:
                break
            n = best[0].refill(best[1])
            i = next(i for i, (a, _, _) in enumerate(streams) if a is best[0])
            if n:
                ran.append(f'{names[i]} {n}')
            if self.worker is None:
                break
            del streams[i], names[i]
        return ', '.join(ran)

    def open_gate(self, c_tick, now_ns, c_end):
        """Let the worker run until shortly before the next call (gate.SlackGate).

        For good while a stream's batch in the worker is needed soon (``Ahead.urgent``).
        ``c_tick``, ``c_end``: the call's start and end (perf_counter ns); ``now_ns``: its
        start on the node's clock.
        """
        gate = self.worker.gate
        if (self.truth.ahead is not None and self.truth.ahead.urgent()) or \
                any(s.ahead.urgent() for s in self.sensors):
            gate.open()
            return
        nxt = self.grid_due_ns(now_ns + c_end - c_tick) + self.timer_ns
        gate.open_until(gate.deadline_ns(c_tick + (nxt - now_ns), self.timer_ns))

    def drop_built(self):
        """Forget the messages built ahead (the frame ids changed); keep the samples."""
        for ahead in [self.truth.ahead] + [s.ahead for s in self.sensors]:
            if ahead is not None:
                ahead.drop_built()

    def snapshot(self):
        """Take the schedule's part of a diagnostics window (moved out of the streams)."""
        ahead = self.truth.ahead
        return {'batches': ahead.take_stats() if ahead is not None else [], 'ahead': ahead,
                'sensors': {s.output.name: s.take_latencies() for s in self.sensors},
                'bound': self.bound, 'last': self.truth.last_sample}
