"""Shared helpers of the look-ahead tests: a logged sensor look-ahead, a gated worker."""

import time

from rigidrot_ros.runtime.ahead import SensorAhead
from rigidrot_ros.runtime.gate import SlackGate
from rigidrot_ros.runtime.worker import BatchWorker


def sensor(reads, worker=None, gate=None):
    """Return a SensorAhead whose reads are logged in ``reads`` (and wait for ``gate``)."""
    def read(ks):
        if gate is not None:
            gate.wait()
        reads.extend(ks)
        return [('s', k) for k in ks], None
    return SensorAhead(read, lambda k: read(range(k, k + 1))[0][0], 1e-3, first=1,
                       budget_s=1.0, worker=worker)


def gated_worker(hold_max_s):
    """Return a gate that is on and a worker held by it."""
    gate = SlackGate(hold_max_s=hold_max_s, on=True)
    return gate, BatchWorker(gate=gate)


def busy(worker, counter, stop, entered=None):
    """Queue a call that counts Python calls until ``stop`` (each call a gate check)."""
    def bump():
        counter[0] += 1

    def body():
        if entered is not None:
            entered.set()
        while not stop.is_set():
            bump()
    worker.call(body)


def until(cond, timeout=10.0):
    """Wait until ``cond()`` is true, at most ``timeout`` s (then fail)."""
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, 'timed out'
        time.sleep(0.001)
