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

**Off the publishing thread.** With a :class:`~rigidrot_ros.runtime.worker.BatchWorker`
(the node has one), a batch that :meth:`Ahead.refill` starts runs in the worker. There the
next batch starts when a whole batch, and at least :data:`WORKER_AHEAD_S` of samples, is
left (not half a batch), and a batch beyond its budget is no strike. Its batches are
:data:`WORKER_BATCH` samples (the fixed part paid once per 256; fewer only where the cost
model predicts more than :data:`WORKER_BUDGET_S` of CPU).
"""

import abc
import contextlib
import threading
import time

import numpy as np

from rigidrot_ros.runtime import switches
from rigidrot_ros.runtime.gate import GATE_URGENT_S

__all__ = ['Ahead', 'Lookahead', 'SensorAhead', 'AHEAD_MIN', 'AHEAD_MAX',
           'BATCH_BUDGET_S', 'PERIOD_SHARE', 'LATE_SHARE', 'AMORTIZE', 'STRIKES', 'WARMUP_S',
           'WORKER_AHEAD_S', 'WORKER_BATCH', 'WORKER_BUDGET_S']

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
#: :data:`~rigidrot_ros.runtime.worker.SWITCH_INTERVAL_S`, so the publishing call runs at
#: about half speed meanwhile.
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
