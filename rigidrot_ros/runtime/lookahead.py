"""Samples of every stream on its grid, evaluated and serialized ahead in batches (no rclpy).

The node knows the times of every stream's coming samples (the truth's ticks, each
sensor's grid), so it evaluates them a batch at a time: the truth with the vectorised
path of :meth:`Solution.at`, the gyro with :meth:`Gyro.read_many` (bit for bit the
per-sample reads), the star tracker sample by sample; and each batch's messages are
serialized with the vectorised CDR writer :mod:`rigidrot_ros.msgs.cdr`, one call per batch
and topic. A tick then takes its bytes from the buffer and publishes them; the node runs at
most one batch per scheduler call, after that call has published, so a batch never delays
the messages already due.

**Batch sizes.** A batch costs a fixed part plus a small part per sample (measured in
the node at 1 kHz on the 2-core machine under load, CPU: a truth batch about 0.7 ms, a
gyro batch 0.5 to 2 ms). The size is chosen from that cost model, fitted to the CPU times
of the recent batches (:meth:`Ahead._fit`): the largest that is predicted to fit the
budget, at most double the last, within [:data:`AHEAD_MIN`, :data:`AHEAD_MAX`]. The
budget is :data:`PERIOD_SHARE` of the stream's period (a batch then fits between two
samples), or where the fixed part does not allow that :data:`LATE_SHARE` of it, else
:data:`BATCH_BUDGET_S`. A batch holds the executor: the samples due
meanwhile go out with the next call, late (more than a period after their stamp once a
batch passes about 1.7 periods at 1 kHz) but not lost; so a batch is kept short rather
than rare. A batch of :data:`AHEAD_MIN` that does not fit is
a strike; :data:`STRIKES` strikes in a row turn the look-ahead off, except within its first
:data:`WARMUP_S` seconds (first calls, caches, the process starting: measured 3 slow
batches in a row at start-up on a loaded machine), when they only keep the size small.
A batch that raises (a far sample beyond the precision ceiling) turns it off at once.
Once off, the samples already buffered are published first (a sensor's were read, its
noise stream ran on: each sample is read exactly once), then each sample is evaluated
when it is due (the truth: one scalar call; a sensor: its per-sample reader).

Each buffered truth sample is the same exact solution, with its own error bound, as a
scalar call at that time would give (both within the bound; the last bits may differ).

**Off the publishing thread.** With a :class:`BatchWorker` (the node has one), a batch
that :meth:`Ahead.refill` starts runs in the worker's thread: the indices are reserved at
once, and the publishing thread takes the results in when it next touches that buffer, so
a batch no longer holds the executor (a gyro batch has a fixed part of ~0.6 ms, past
half a period at 1 kHz). There the next batch starts when a whole batch, and at least
:data:`WORKER_AHEAD_S` of samples, is left (not half a batch), and a batch beyond its
budget is no strike. Its batches are :data:`WORKER_BATCH` samples (the fixed part paid
once per 256; fewer only where the cost model predicts more than :data:`WORKER_BUDGET_S`
of CPU). Only one evaluation runs at a
time (:attr:`BatchWorker.lock`: the core's caches, a sensor's noise stream and mpmath's
working precision are not thread-safe): an index asked for while its batch runs waits for
it, and the publishing thread's own evaluations (a miss, a catch-up) take the lock. A
sensor's samples are still read in index order, each once. The process's thread switch
interval is lowered (:data:`SWITCH_INTERVAL_S`) so that the publishing thread gets the
interpreter within that time of its wake-up while a batch runs. The node's diagnostics
report is built in the worker too (:meth:`BatchWorker.call`).

**In the scheduler's slack.** Sharing the interpreter still cost the publishing thread:
handed back and forth every 0.1 ms, a call of 60 µs took up to 1.7 ms beside a batch. So
where the scheduler's period is at least :data:`GATE_MIN_PERIOD_S` the worker runs only
between the end of one call and shortly before the next (:class:`SlackGate`), unless a
batch is needed soon (:meth:`Ahead.urgent`); the publishing thread never waits on a held
worker (it opens the gate first).
"""

import abc
import contextlib
import queue
import sys
import threading
import time

import numpy as np

from rigidrot_ros.runtime import switches

__all__ = ['Ahead', 'Lookahead', 'SensorAhead', 'BatchWorker', 'AHEAD_MIN', 'AHEAD_MAX',
           'BATCH_BUDGET_S', 'PERIOD_SHARE', 'LATE_SHARE', 'AMORTIZE', 'STRIKES', 'WARMUP_S',
           'SWITCH_INTERVAL_S', 'WORKER_AHEAD_S', 'WORKER_BATCH',
           'WORKER_BUDGET_S', 'SlackGate', 'GATE_GUARD_S', 'GATE_HOLD_MAX_S',
           'GATE_URGENT_S', 'GATE_MIN_PERIOD_S']

#: The first batch's size, and the smallest.
AHEAD_MIN = 8
#: The largest batch: bounded memory, and a bounded stale tail after a change of
#: publish_rate or a reset, which drop the buffer.
AHEAD_MAX = 256
#: One batch takes at most this much CPU time (predicted from the fitted cost), and at
#: most :data:`PERIOD_SHARE` of the stream's period where its fixed cost allows.
BATCH_BUDGET_S = 2e-3
#: The share of a period a batch aims at when its fixed cost leaves room for it.
PERIOD_SHARE = 0.6
#: Else the share of a period a batch stays under, where its fixed cost allows: past
#: about 1.7 periods a batch makes the next sample late (published over a period after
#: its stamp).
LATE_SHARE = 1.2
#: Where not even the smallest batch fits the budget, a sensor's batch aims at this many
#: times the smallest batch's cost (the imu with an accelerometer: ~2 ms of fixed part under load).
AMORTIZE = 1.5
#: Batches in a row beyond the budget at the smallest size before the look-ahead stops.
STRIKES = 3
#: Seconds after a look-ahead starts during which slow batches are no strikes.
WARMUP_S = 2.0
#: With a worker, every batch is this many samples (``RIGIDROT_WORKER_BATCH`` overrides it;
#: ``0``: sized by the cost model as inline, the choice before). A gyro read has a fixed
#: part of ~1 ms (its numpy steps); sized by the cost model, 57 % of the gyro's batches were
#: under 32 samples (traced at 1 kHz, 20 s, under load: 505 batches, 0.85 s of the worker's
#: time), and 30 of that run's 34 late gyro samples waited while one ran: the worker and
#: the publishing thread share the interpreter, which changes hands every
#: :data:`SWITCH_INTERVAL_S`, so the publishing call runs at about half speed meanwhile.
#: Fixed-size batches pay the fixed part once per 256 samples, as far as
#: :data:`WORKER_BUDGET_S` allows.
WORKER_BATCH = AHEAD_MAX
#: A worker batch is made smaller than :data:`WORKER_BATCH` where its predicted CPU time
#: (the cost model) would pass this: a slow model (e.g. ``backend:=flint`` at low rates)
#: keeps batches a reset, a parameter check or a shutdown waits for short.
WORKER_BUDGET_S = 6e-3
#: Batches the cost model remembers.
_HISTORY = 8
#: With a worker, the next batch starts while at least this many seconds of samples are
#: buffered (measured: calls waited 4 to 11 ms for batches of 8 to 16 samples at 1 kHz,
#: under load, when they started with a batch left).
WORKER_AHEAD_S = 0.05
#: The interpreter's thread switch interval with a worker (``sys.setswitchinterval``; 5 ms
#: by default: the publishing thread would wait that long for a running batch).
SWITCH_INTERVAL_S = 1e-4


#: The worker stops this long before the publishing thread's next call is due (at most
#: :data:`_GUARD_SHARE` of the scheduler's period): the publishing thread wakes to a free
#: interpreter, not to one the worker holds.
GATE_GUARD_S = 2e-4
_GUARD_SHARE = 0.4
#: Top-level packages whose code the worker is never held in: they hold locks across
#: Python code (threading's conditions and events, queue, the import system, logging's
#: handlers, numba's compiler lock), and a held worker would keep them from the thread
#: that waits for it.
_NO_HOLD = frozenset({'threading', 'queue', 'importlib', 'logging', 'numba', 'llvmlite',
                      'concurrent'})
#: The gate holds the worker only where the scheduler's period is at least this long:
#: at 2 kHz the slack between two calls (a period less the call, the executor's own
#: work and the guard: ~0.15 ms) did not fit the worker's batches (measured: batches of
#: ~200 samples took 38 ms of wall time instead of ~4, the publishing thread waited for
#: them, 2025 late gyro samples in 20 s against ~260 without the gate).
GATE_MIN_PERIOD_S = 1e-3
#: A stream with a batch in the worker and less than this many seconds of samples
#: buffered before it makes the gate open for good until the batch is in
#: (:meth:`Ahead.urgent`): a worker held to the slack must never make the publishing
#: thread wait for its batch.
GATE_URGENT_S = 0.02
#: The longest the worker waits for the publishing thread to open the gate again; past it
#: (the scheduler stopped: a reset, a shutdown) the worker goes on for as long again.
GATE_HOLD_MAX_S = 0.02


class SlackGate:
    """The worker's work, held to the publishing thread's slack between two calls.

    The worker and the publishing thread share the interpreter. While a batch runs, the
    interpreter changes hands every :data:`SWITCH_INTERVAL_S`, and each hand-over makes the
    publishing thread wait for the next: traced at 1 kHz, a call of 60 µs took 0.5 to
    1.7 ms while a batch ran beside it, and most of the samples published more than a
    period late waited so (with the diagnostics report, built in the worker too). Yet the
    worker has little to do: at 1 kHz about 15 ms of CPU a second.

    So the worker runs only where the publishing thread has nothing to do. At the end of
    each call the scheduler opens the gate until shortly before its next call is due
    (:meth:`open_until`: :data:`GATE_GUARD_S` before, at most :data:`_GUARD_SHARE` of a
    period). The worker checks the gate at every Python and C call it makes (:meth:`profile`,
    the worker thread's ``sys.setprofile``: no yield points written into the models), and
    past the deadline waits, without the interpreter, until the scheduler opens it again.

    The publishing thread never waits on a held worker: where it needs the worker's result
    now (a sample whose batch still runs, the evaluation lock, a drain) it opens the gate
    first (:meth:`open`). A worker held for :data:`GATE_HOLD_MAX_S` (the scheduler stopped
    calling) goes on, for as long again. ``RIGIDROT_WORKER_GATE=0`` leaves the gate open.

    ``clock``: ns, monotonic (the deadlines' clock). :attr:`holds` counts the waits,
    :attr:`held_ns` sums them.
    """

    #: The deadline of a gate open for good.
    FREE = (1 << 63) - 1

    def __init__(self, clock=time.perf_counter_ns, hold_max_s=GATE_HOLD_MAX_S, on=None):
        self.on = switches.worker_gate() if on is None else bool(on)
        self._clock = clock
        self._hold_max_ns = int(hold_max_s * 1e9)
        self._deadline = self.FREE
        self._cond = threading.Condition(threading.Lock())
        self._waiting = False
        self.holds = 0
        self.held_ns = 0

    @property
    def deadline(self):
        """The time (``clock``) until which the worker may run; :data:`FREE` if open for good."""
        return self._deadline

    def open_until(self, deadline_ns):
        """Let the worker run until ``deadline_ns`` (``clock``; the publishing thread)."""
        self._deadline = int(deadline_ns) if self.on else self.FREE
        if self._waiting:
            with self._cond:
                self._cond.notify_all()

    def open(self):
        """Let the worker run until the next :meth:`open_until` (the caller waits for it)."""
        self.open_until(self.FREE)

    def check(self):
        """In the worker: return at once if the gate is open, else wait until it opens."""
        if self._clock() >= self._deadline:
            self._hold()

    def profile(self, frame, event, arg):
        """``sys.setprofile`` function of the worker thread: :meth:`check` at every event.

        Not in the code of a package that holds a lock the publishing thread may take
        (:data:`_NO_HOLD`: an ``Event.set`` held half way kept its lock from the thread
        waiting on the event, until the hold timed out).
        """
        if self._clock() >= self._deadline and \
                frame.f_globals.get('__name__', '').partition('.')[0] not in _NO_HOLD:
            self._hold()

    def _hold(self):
        t0 = self._clock()
        end = t0 + self._hold_max_ns
        with self._cond:
            self._waiting = True
            try:
                while True:
                    now = self._clock()
                    if now < self._deadline:
                        break
                    if now >= end:          # the scheduler went quiet: run for as long
                        self._deadline = now + self._hold_max_ns
                        break
                    self._cond.wait((end - now) / 1e9)
            finally:
                self._waiting = False
        self.holds += 1
        self.held_ns += self._clock() - t0

    def deadline_ns(self, due_ns, period_ns):
        """Return the deadline for a call due at ``due_ns`` (``clock``) every ``period_ns``.

        :data:`GATE_GUARD_S` before it (at most :data:`_GUARD_SHARE` of a period), or
        :data:`FREE` where the period is shorter than :data:`GATE_MIN_PERIOD_S`.
        """
        if period_ns < GATE_MIN_PERIOD_S * 1e9:
            return self.FREE
        return due_ns - int(min(GATE_GUARD_S * 1e9, _GUARD_SHARE * period_ns))


class _Job:
    """One batch for the worker: ``ahead``'s ``n`` indices from ``start``; its result."""

    __slots__ = ('ahead', 'start', 'n', 'samples', 'built', 'exc', 'wall', 'cost', 'done',
                 'keep_built')

    def __init__(self, ahead, start, n):
        self.ahead, self.start, self.n = ahead, start, n
        self.samples = self.built = self.exc = None
        self.wall = self.cost = 0.0
        self.keep_built = True
        self.done = threading.Event()

    def run(self):
        c0, cpu0 = time.perf_counter(), time.thread_time()
        try:
            self.samples, data = self.ahead._batch(self.start, self.n)
            b = self.ahead.build
            self.built = b(self.start, data) if b is not None else [None] * self.n
        except Exception as exc:    # noqa: B902 - whatever the model raises: the owner judges
            self.exc = exc
        self.wall = time.perf_counter() - c0
        self.cost = time.thread_time() - cpu0
        self.done.set()


class _Call:
    """A plain call for the worker; its exception goes to ``on_error``.

    ``evaluates``: it runs under :attr:`BatchWorker.lock` (it touches a model's state).
    """

    __slots__ = ('fn', 'on_error', 'evaluates')

    def __init__(self, fn, on_error, evaluates=True):
        self.fn, self.on_error, self.evaluates = fn, on_error, evaluates

    def run(self):
        try:
            self.fn()
        except Exception as exc:    # noqa: B902 - the worker thread never ends on a call
            if self.on_error is not None:
                self.on_error(exc)


class BatchWorker:
    """A thread that evaluates look-ahead batches, one at a time, off the publishing thread.

    :attr:`lock` is held during every batch; hold it for any other evaluation of the same
    solutions and sensors (:meth:`Ahead.get` and :meth:`Ahead.fill_to` do). :meth:`stop`
    ends the thread (idempotent); a job still queued then is finished first.
    """

    def __init__(self, name='rigidrot-lookahead', gate=None):
        self.lock = threading.RLock()
        #: Holds the worker to the scheduler's slack (:class:`SlackGate`; open until the
        #: scheduler first sets a deadline).
        self.gate = gate if gate is not None else SlackGate()
        self._jobs = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._ended = threading.Event()     # set by the thread as it ends
        self._thread.start()
        if sys.getswitchinterval() > SWITCH_INTERVAL_S:
            sys.setswitchinterval(SWITCH_INTERVAL_S)

    def call(self, fn, on_error=None, evaluates=True):
        """Queue ``fn()`` (any work that should not hold the publishing thread).

        An exception goes to ``on_error(exc)`` if given, else it is dropped. ``evaluates``:
        ``fn`` touches a model's state, so it runs under :attr:`lock`; False for work that
        does not (a chunk of the bag written), which the publishing thread's own
        evaluations then never wait for.
        """
        self.submit(_Call(fn, on_error, evaluates))

    def drain(self, timeout=None):
        """Wait until every job queued so far has run; False if ``timeout`` s passed first."""
        done = threading.Event()
        self.call(done.set)
        self.gate.open()
        return done.wait(timeout)

    @contextlib.contextmanager
    def locked(self):
        """Hold :attr:`lock` (from the publishing thread: a held worker is let go first)."""
        if not self.lock.acquire(blocking=False):
            self.gate.open()
            self.lock.acquire()
        try:
            yield
        finally:
            self.lock.release()

    def wait_for(self, job):
        """Wait until ``job`` has run (from the publishing thread: the gate is opened)."""
        if not job.done.is_set():
            self.gate.open()
            job.done.wait()

    def submit(self, job):
        """Queue a :class:`_Job` (anything with ``run()``)."""
        if not self.alive:
            raise RuntimeError('the look-ahead worker has stopped')
        self._jobs.put(job)

    def _loop(self):
        while True:
            job = self._jobs.get()
            if job is None:
                self._ended.set()
                return
            # the gate's checks cost the worker about its own time again: only while the
            # scheduler holds it to deadlines (none at short periods, nor before its first)
            sys.setprofile(self.gate.profile if self.gate.deadline != SlackGate.FREE else None)
            if getattr(job, 'evaluates', True):
                with self.lock:
                    job.run()
            else:
                job.run()
            sys.setprofile(None)        # idle, the worker waits on its queue, not the gate

    @property
    def alive(self):
        """Whether the thread runs."""
        return self._thread.is_alive() and not self._ended.is_set()

    def stop(self, timeout=5.0):
        """End the thread after the jobs queued; wait at most ``timeout`` s. Idempotent."""
        self.gate.on = False
        self.gate.open()
        if self._thread.is_alive():
            self._jobs.put(None)
            # waited on an event, not join(): a second Ctrl-C (spin's handler raises
            # KeyboardInterrupt) in join() makes Python 3.11 take the running thread for
            # ended; the last batch is waited out (bounded by ``timeout``), the bag is
            # still to be finished
            end = time.monotonic() + timeout
            while not self._ended.is_set() and time.monotonic() < end:
                try:
                    self._ended.wait(max(end - time.monotonic(), 0.0))
                except KeyboardInterrupt:
                    continue


class Ahead(abc.ABC):
    """Samples at grid indices k >= ``first``, evaluated ahead in batches (a base class).

    ``amortize`` (a class attribute): when not even the smallest batch fits the budget,
    aim at :data:`AMORTIZE` times the smallest batch's cost instead, and never turn off for cost (a
    stream whose per-sample path is the batch path on one sample); else such batches are
    strikes.

    Subclasses define ``_batch(start, n) -> (samples, data)`` (``samples`` a list of n
    per-index values, ``data`` what ``build`` needs) and ``_one(k) -> sample``. ``build(start,
    data) -> list of n built entries`` (e.g. each sample's serialized messages), if given,
    is called once per batch.
    """

    amortize = False

    def __init__(self, period_s, budget_s=BATCH_BUDGET_S, enabled=True, build=None,
                 first=0, clock=time.monotonic, worker=None):
        self.period_s = float(period_s)
        self.worker = worker            # a BatchWorker: refill()'s batches run there
        self._fixed_size = (switches.worker_batch(WORKER_BATCH, AHEAD_MIN, AHEAD_MAX)
                            if worker is not None else 0)
        self._job = None                # the batch in the worker, if any
        self.build = build
        self.budget_s = float(budget_s)
        self.size = AHEAD_MIN if enabled else 0
        self.off_reason = '' if enabled else 'disabled'
        self._buf = {}
        self._first = int(first)
        self._next = self._first        # the first index not yet buffered
        self._last = self._first - 1    # the last index refill() was told of
        self._strikes = 0               # batches in a row over budget at AHEAD_MIN
        self._clock = clock
        self._born = clock()
        self._costs = []                # (n, CPU s) of the last batches
        self.batch_times = []           # wall seconds per batch, since the last take_stats()
        self.last_per_sample = 0.0      # wall seconds per sample of the last batch
        self.misses = 0                 # get() calls that evaluated their index then
        self.catch_ups = 0              # fill_to() batches

    def __len__(self):
        return len(self._buf)

    @abc.abstractmethod
    def _one(self, k):
        """Evaluate index k alone: ``(sample, built)``."""

    @abc.abstractmethod
    def _batch(self, start, n):
        """Evaluate ``n`` indices from ``start`` at once: ``(samples, built)``."""

    def _lock(self):
        return self.worker.locked() if self.worker is not None else contextlib.nullcontext()

    def _collect(self, wait):
        """Take the worker's batch in, if it is done (or once done, with ``wait``)."""
        job = self._job
        if job is None or not (wait or job.done.is_set()):
            return
        self.worker.wait_for(job)      # a job is in the worker (refill with a worker only)
        self._job = None
        if job.exc is not None:
            self._failed(job.start, job.n, job.exc)
            self._next = min(self._next, job.start)     # per sample from there
            return
        built = job.built if job.keep_built else [None] * job.n
        for j, entry in enumerate(zip(job.samples, built), job.start):
            if j > self._last:          # not skipped meanwhile
                self._buf[j] = entry
        self._account(job.n, job.wall, job.cost, judge=True)

    def get(self, k):
        """Return ``(sample, built)`` for index k (evaluated now if not buffered).

        ``built`` is what ``build`` made of a buffered sample, None for a sample evaluated
        now. Raises what the evaluation of that sample raises. An index whose batch runs
        in the worker waits for it.
        """
        job = self._job
        self._collect(wait=job is not None and job.start <= k < job.start + job.n)
        entry = self._buf.pop(k, None)
        if entry is not None:
            return entry
        self._collect(wait=True)        # in order: a sensor's batch before its later samples
        entry = self._buf.pop(k, None)
        if entry is not None:
            return entry
        self.misses += 1
        with self._lock():
            return self._one(k), None

    def urgent(self):
        """Whether the batch in the worker is needed soon (:data:`GATE_URGENT_S`)."""
        job = self._job
        return job is not None and not job.done.is_set() and \
            (job.start - self._last - 1) * self.period_s < GATE_URGENT_S

    def ahead_of(self, k):
        """Return how many samples after index k are buffered (or evaluated) already."""
        return max(self._next, k + 1) - (k + 1)

    def needs(self, k):
        """Return True if, after index k, at most half a batch is buffered ahead."""
        if self.size < AHEAD_MIN:
            return False
        return max(self._next, k + 1) - (k + 1) <= self._low_water()

    def refill(self, k):
        """After index k: evaluate the next batch if at most half a batch is left; its size."""
        self._collect(wait=False)
        if self.size < AHEAD_MIN:
            return 0
        if k != self._last + 1 and self._buf:     # indices skipped: drop their samples
            self._buf = {j: v for j, v in self._buf.items() if j > k}
        self._last = k
        if self._job is not None:
            return 0                    # one batch at a time
        start = max(self._next, k + 1)
        if start - (k + 1) > self._low_water():
            return 0
        if self.worker is not None:
            self._job = _Job(self, start, self.size)
            self._next = start + self.size
            self.worker.submit(self._job)
            return self.size
        return self._run(start, self.size, judge=True)

    def fill_to(self, first, k):
        """Evaluate indices ``first`` .. ``k`` not buffered yet as one batch: a catch-up.

        A call that owes many samples (the process was held: a stall, a loaded machine)
        takes them from one batch instead of evaluating each alone, whose fixed cost per
        sample (a gyro read, one message built and serialized) is beyond a period at
        2 kHz: evaluated one by one, the samples owed grow faster than they are published
        until a second's backlog is skipped. Only where two or more are missing and the
        look-ahead is on; the batch is no strike whatever it costs. Returns its size.
        """
        if self.size < AHEAD_MIN or int(k) - max(self._next, int(first)) + 1 < 2:
            return 0                    # buffered, or reserved for the worker's batch
        self._collect(wait=True)        # in order: after the worker's batch
        start = max(self._next, int(first))
        n = int(k) - start + 1
        if self.size < AHEAD_MIN or n < 2:
            return 0
        if self._buf and start > self._next:      # indices skipped: drop their samples
            self._buf = {j: v for j, v in self._buf.items() if j >= start}
        return self._run(start, n, judge=False)

    def _run(self, start, n, judge):
        """Evaluate (and build) ``n`` indices from ``start`` into the buffer; returns n or 0."""
        job = _Job(self, start, n)
        with self._lock():
            job.run()
        if job.exc is not None:
            self._failed(start, n, job.exc)
            return 0
        for j, entry in enumerate(zip(job.samples, job.built), start):
            self._buf[j] = entry
        self._next = start + n
        self._account(n, job.wall, job.cost, judge)
        return n

    def _failed(self, start, n, exc):
        self.size = 0                   # the samples buffered so far are still good: kept
        self.off_reason = (f'a batch of {n} samples from index {start} failed '
                           f'({type(exc).__name__}: {exc}); evaluating per sample')

    def _account(self, n, wall, cost, judge):
        """Note a batch's wall and CPU time (CPU: another process's load is no reason)."""
        self.batch_times.append(wall)
        self.last_per_sample = wall / n
        if judge:
            self._judge(n, cost)
        else:
            self.catch_ups += 1

    def _fit(self):
        """Return ``(fixed s, per sample s)`` of the cost model fitted to the last batches."""
        ns = np.array([c[0] for c in self._costs], dtype=float)
        cs = np.array([c[1] for c in self._costs], dtype=float)
        if len(set(ns.tolist())) < 2:
            return 0.0, float(cs[-1] / ns[-1])      # one size seen: all of it per sample
        b, a = np.polyfit(ns, cs, 1)
        b = max(float(b), 1e-9)
        return max(float(a), 0.0), b

    def _low_water(self):
        """Return how few samples buffered ahead start the next batch.

        Half a batch inline; with a worker a whole batch, and at least
        :data:`WORKER_AHEAD_S` of samples: a batch then has that long to run (a worker
        held up by other processes) before its first sample is due.
        """
        if self.worker is None:
            return self.size // 2
        return max(self.size, int(WORKER_AHEAD_S / self.period_s))

    def _judge(self, n, cost):
        """Choose the next batch size from the cost model; count a strike, or turn off.

        With a worker a batch holds no one up: it is sized the same way (small batches
        keep the garbage collector's young generations small) but never a strike.
        """
        self._costs = (self._costs + [(n, cost)])[-_HISTORY:]
        fixed, per = self._fit()
        if self.worker is not None and self._fixed_size:
            # in the worker: fixed-size batches, as far as the worker's budget allows
            fits = int((WORKER_BUDGET_S - fixed) / per + 1e-9) if per > 0 else AHEAD_MAX
            self.size = min(max(fits, AHEAD_MIN), self._fixed_size)
            return
        # a batch aims at PERIOD_SHARE of a period (it then fits between two samples),
        # else at LATE_SHARE, else at the budget: a longer batch makes samples late
        budget = self.budget_s
        for share in (PERIOD_SHARE, LATE_SHARE):
            aim = share * self.period_s
            if fixed + per * AHEAD_MIN <= aim < budget:
                budget = aim
                break
        if self.amortize and fixed + per * AHEAD_MIN > budget:
            # not even the smallest batch fits, and evaluating per sample would pay the
            # fixed part for every sample: amortize it over larger batches instead
            budget = AMORTIZE * (fixed + per * AHEAD_MIN)
        fits = int((budget - fixed) / per + 1e-9) if budget > fixed else 0
        if fits >= AHEAD_MIN and cost <= max(budget, 2.0 * (fixed + per * n)):
            self.size = min(AHEAD_MAX, 2 * n, fits)
            self._strikes = 0
            return
        self.size = AHEAD_MIN
        if self._clock() - self._born < WARMUP_S or self.amortize or self.worker is not None:
            return                        # starting up (or in the worker): only smaller
        self._strikes += 1
        if self._strikes >= STRIKES:
            self.size = 0               # the buffered samples are kept and published first
            self.off_reason = (f'{STRIKES} batches in a row beyond the budget of '
                               f'{budget * 1e3:.3g} ms after the warm-up (the last: {n} '
                               f'samples in {cost * 1e3:.3g} ms of CPU); evaluating per '
                               'sample')

    def drop_built(self):
        """Forget what ``build`` made (e.g. the frame ids changed); keep the samples."""
        if self._job is not None:
            self._job.keep_built = False        # the batch in the worker too
        self._buf = {j: (smp, None) for j, (smp, _) in self._buf.items()}

    def take_stats(self):
        """Return the batch times (s) since the last call, and forget them."""
        out, self.batch_times = self.batch_times, []
        return out


class Lookahead(Ahead):
    """Truth samples of ``solution`` at the tick indices k >= 0.

    ``time_of(k)`` returns the scene time (s) of tick k. A sample is a tuple
    ``(quaternion, omega, error_bound)`` of a 4-list (x, y, z, w), a 3-list (rad/s, in B)
    and a float (rad), plain Python floats. ``build(start, (q, omega, bound))`` gets the
    batch's arrays ((n, 4), (n, 3), (n,)).
    """

    def __init__(self, solution, time_of, period_s, budget_s=BATCH_BUDGET_S, enabled=True,
                 build=None, clock=time.monotonic, worker=None):
        super().__init__(period_s, budget_s, enabled, build, 0, clock, worker)
        self.solution = solution
        self.time_of = time_of

    def _one(self, k):
        s = self.solution.at(self.time_of(k))
        return s.quaternion.tolist(), s.omega.tolist(), float(s.error_bound)

    def _batch(self, start, n):
        ts = np.array([self.time_of(j) for j in range(start, start + n)])
        s = self.solution.at(ts)
        q, w, e = s.quaternion, s.omega, s.error_bound
        return list(zip(q.tolist(), w.tolist(), e.tolist())), (q, w, e)


class SensorAhead(Ahead):
    """A sensor stream's samples, evaluated ahead in order, each exactly once.

    ``read(ks) -> (samples, data)`` evaluates the samples ``ks`` (a range, in order; the
    sensor's state runs on); ``read_one(k) -> sample`` evaluates one. A sensor sample is
    never evaluated twice: ``get(k)`` of a buffered k pops it, and an index that was
    skipped (a clock jump) drops the buffered samples before it. Its per-sample path is
    ``read`` on one sample, so the fixed part of a batch is paid per sample there: a
    batch beyond the budget is amortized (:attr:`Ahead.amortize`), never a strike.
    """

    amortize = True

    def __init__(self, read, read_one, period_s, first, budget_s=BATCH_BUDGET_S,
                 enabled=True, build=None, clock=time.monotonic, worker=None):
        super().__init__(period_s, budget_s, enabled, build, first, clock, worker)
        self._read, self._read_one = read, read_one

    def _one(self, k):
        return self._read_one(k)

    def _batch(self, start, n):
        return self._read(range(start, start + n))

    def peek_built(self, k):
        """Return True if index k is buffered with its built messages."""
        self._collect(wait=False)
        entry = self._buf.get(k)
        return entry is not None and entry[1] is not None
