"""A thread that evaluates look-ahead batches off the publishing thread (no rclpy).

With a :class:`BatchWorker` (the node has one), a batch that
:meth:`~rigidrot_ros.runtime.ahead.Ahead.refill` starts runs in the worker's thread: the
indices are reserved at once, and the publishing thread takes the results in when it next
touches that buffer, so a batch no longer holds the executor (a gyro batch has a fixed
part of ~0.6 ms, past half a period at 1 kHz). Only one evaluation runs at a time
(:attr:`BatchWorker.lock`: the core's caches, a sensor's noise stream and mpmath's working
precision are not thread-safe): an index asked for while its batch runs waits for it, and
the publishing thread's own evaluations (a miss, a catch-up) take the lock. A sensor's
samples are still read in index order, each once. The process's thread switch interval is
lowered (:data:`SWITCH_INTERVAL_S`) so that the publishing thread gets the interpreter
within that time of its wake-up while a batch runs; the worker is held to the scheduler's
slack by its :class:`~rigidrot_ros.runtime.gate.SlackGate`. The node's diagnostics report
is built in the worker too (:meth:`BatchWorker.call`).
"""

import contextlib
import queue
import sys
import threading
import time

from rigidrot_ros.runtime import interrupt
from rigidrot_ros.runtime.gate import SlackGate

__all__ = ['BatchWorker', 'SWITCH_INTERVAL_S']

#: The interpreter's thread switch interval with a worker (``sys.setswitchinterval``; 5 ms
#: by default: the publishing thread would wait that long for a running batch).
SWITCH_INTERVAL_S = 1e-4


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
        self._let_go()
        return done.wait(timeout)

    @contextlib.contextmanager
    def locked(self):
        """Hold :attr:`lock` (from the publishing thread: a held worker is let go first)."""
        if not self.lock.acquire(blocking=False):
            self._let_go()
            self.lock.acquire()
        try:
            yield
        finally:
            self.lock.release()

    def wait_for(self, job):
        """Wait until ``job`` has run (from the publishing thread: the gate is opened)."""
        if not job.done.is_set():
            self._let_go()
            job.done.wait()

    def _let_go(self):
        """Open the gate before the publishing thread waits for the worker.

        With the gate on, also take down the interpreter's flag of a pending asynchronous
        exception (:func:`~rigidrot_ros.runtime.interrupt.settle`) in case it went up while a
        profiled job ran: the worker would spin at its next call until someone does.
        """
        self.gate.open()
        if self.gate.on:
            interrupt.settle()

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
            if self.gate.deadline != SlackGate.FREE:
                # profiled, a thread spins at its next call while the interpreter's flag
                # of a pending asynchronous exception is left up (interrupt): down first
                interrupt.settle()
                sys.setprofile(self.gate.profile)
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
