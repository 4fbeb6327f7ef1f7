"""The look-ahead worker held to the publishing thread's slack between two calls (no rclpy).

Sharing the interpreter cost the publishing thread: handed back and forth every 0.1 ms
(:data:`~rigidrot_ros.runtime.worker.SWITCH_INTERVAL_S`), a call of 60 µs took up to
1.7 ms beside a batch. So where the scheduler's period is at least
:data:`GATE_MIN_PERIOD_S` the worker runs only between the end of one call and shortly
before the next (:class:`SlackGate`), unless a batch is needed soon
(:meth:`~rigidrot_ros.runtime.ahead.Ahead.urgent`); the publishing thread never waits on
a held worker (it opens the gate first).
"""

import threading
import time

from rigidrot_ros.runtime import switches

__all__ = ['SlackGate', 'GATE_GUARD_S', 'GATE_HOLD_MAX_S', 'GATE_URGENT_S',
           'GATE_MIN_PERIOD_S']

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
#: (:meth:`~rigidrot_ros.runtime.ahead.Ahead.urgent`): a worker held to the slack must
#: never make the publishing thread wait for its batch.
GATE_URGENT_S = 0.02
#: The longest the worker waits for the publishing thread to open the gate again; past it
#: (the scheduler stopped: a reset, a shutdown) the worker goes on for as long again.
GATE_HOLD_MAX_S = 0.02


class SlackGate:
    """The worker's work, held to the publishing thread's slack between two calls.

    The worker and the publishing thread share the interpreter. While a batch runs, the
    interpreter changes hands every :data:`~rigidrot_ros.runtime.worker.SWITCH_INTERVAL_S`,
    and each hand-over makes the publishing thread wait for the next: traced at 1 kHz, a
    call of 60 µs took 0.5 to 1.7 ms while a batch ran beside it, and most of the samples
    published more than a period late waited so (with the diagnostics report, built in the
    worker too). Yet the worker has little to do: at 1 kHz about 15 ms of CPU a second.

    So the worker runs only where the publishing thread has nothing to do. At the end of
    each call the scheduler opens the gate until shortly before its next call is due
    (:meth:`open_until`: :data:`GATE_GUARD_S` before, at most :data:`_GUARD_SHARE` of a
    period). The worker checks the gate at every Python and C call it makes (:meth:`profile`,
    the worker thread's ``sys.setprofile``: no yield points written into the models), and
    past the deadline waits, without the interpreter, until the scheduler opens it again.

    The publishing thread never waits on a held worker: where it needs the worker's result
    now (a sample whose batch still runs, the evaluation lock, a drain) it opens the gate
    first (:meth:`open`). A worker held for :data:`GATE_HOLD_MAX_S` (the scheduler stopped
    calling) goes on, for as long again. The gate is off unless ``RIGIDROT_WORKER_GATE``
    is set (and not ``0``): measured on and off alternately at 1 kHz (30 s, six rounds
    each, beside another process's load: late gyro samples 45 to 1252 on, 144 to 731
    off), it did not win.

    With it on, the publishing thread of in-process test nodes once waited for a batch
    that never came: an in-process campaign in the same test process had left the
    interpreter's flag of a pending asynchronous exception up, and the worker, profiled,
    spun at its call's first instruction (:mod:`~rigidrot_ros.runtime.interrupt`; the
    worker takes the flag down before it installs :meth:`profile`).

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
        deadline = int(deadline_ns) if self.on else self.FREE
        self._deadline = deadline
        if self._waiting:
            with self._cond:
                # again under the lock: a held worker that timed out between its reading
                # of the deadline and its own new one (_hold) would else overwrite this
                self._deadline = deadline
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
