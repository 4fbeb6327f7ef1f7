"""The slack gate, without ROS: the worker runs only where the publishing thread leaves it room."""

import ctypes
import sys
import threading
import time

import pytest

from rigidrot_ros.runtime import interrupt
from rigidrot_ros.runtime.gate import GATE_GUARD_S, GATE_MIN_PERIOD_S, SlackGate

from lookahead_helpers import busy, gated_worker, sensor, until  # noqa: I100, I201 - beside it


def test_the_gate_holds_the_worker_past_its_deadline_and_lets_it_go_when_opened():
    gate, worker = gated_worker(60.0)
    counter, stop = [0], threading.Event()
    try:
        gate.open_until(time.perf_counter_ns() + 10**10)    # a deadline: the worker checks
        busy(worker, counter, stop)
        until(lambda: counter[0] > 100)
        gate.open_until(time.perf_counter_ns() - 1)     # the deadline has passed
        time.sleep(0.05)                            # the worker reaches its next check
        held = counter[0]
        time.sleep(0.2)
        assert counter[0] == held                   # not one more call while closed
        gate.open_until(time.perf_counter_ns() + 10**10)
        until(lambda: counter[0] > held + 100)
        assert gate.holds == 1 and gate.held_ns >= 0.2e9
    finally:
        stop.set()
        gate.open()
        worker.stop()


def test_a_worker_held_longer_than_the_longest_hold_goes_on():
    """The scheduler stopped opening the gate (a reset, a shutdown): the worker is not stuck."""
    gate, worker = gated_worker(0.05)
    try:
        gate.open_until(0)                          # closed, and nobody opens it
        done = threading.Event()
        t0 = time.monotonic()
        worker.call(lambda: done.set())
        assert done.wait(30.0)
        assert time.monotonic() - t0 >= 0.05
        assert gate.holds >= 1 and gate.held_ns >= 0.05e9
    finally:
        worker.stop()


@pytest.mark.parametrize('how', ['sample', 'lock', 'drain'])
def test_the_publishing_thread_never_waits_for_a_held_worker(how):
    """A sample whose batch is held, the evaluation lock, a drain: the gate opens first.

    The hold would last 20 s here: each of these returns in a fraction of that.
    """
    gate, worker = gated_worker(20.0)
    counter, stop, entered = [0], threading.Event(), threading.Event()
    try:
        if how == 'sample':
            reads = []
            la = sensor(reads, worker)
            la.get(1)
            gate.open_until(0)
            la.refill(1)                            # 2 .. 9 reserved, the worker held
            t0 = time.monotonic()
            assert la.get(2)[0] == ('s', 2)
        else:
            gate.open_until(time.perf_counter_ns() + 10**10)
            busy(worker, counter, stop, entered)
            assert entered.wait(10.0)               # the worker is in the call (the lock held)
            gate.open_until(0)
            time.sleep(0.05)                        # and held there
            t0 = time.monotonic()
            if how == 'lock':
                stop.set()
                with worker.locked():
                    pass
            else:
                stop.set()
                assert worker.drain(timeout=30.0)
        assert time.monotonic() - t0 < 10.0
    finally:
        stop.set()
        gate.open()
        worker.stop()


def test_the_worker_is_never_held_in_code_that_holds_a_lock_across_python():
    """An Event.set held half way kept the event's lock from the thread waiting on it."""
    gate = SlackGate(hold_max_s=0.05, on=True)
    gate.open_until(0)
    frame = eval('_sys._getframe()', vars(threading))      # a frame of threading's code
    t0 = time.monotonic()
    gate.profile(frame, 'call', None)
    assert gate.holds == 0 and time.monotonic() - t0 < 0.05
    gate.profile(sys._getframe(), 'call', None)     # ours: held (until the 0.05 s are up)
    assert gate.holds == 1 and gate.held_ns >= 0.05e9


def test_a_worker_starts_unchecked_while_the_gate_is_open_for_good():
    """No deadline (short periods, before the scheduler's first call): no checks to pay."""
    gate, worker = gated_worker(20.0)
    try:
        seen = []
        worker.call(lambda: seen.append(sys.getprofile()))
        assert worker.drain(timeout=30.0)
        gate.open_until(10**30)
        done = threading.Event()
        worker.call(lambda: (seen.append(sys.getprofile()), done.set()))
        assert done.wait(30.0)
        assert seen == [None, gate.profile]
    finally:
        worker.stop()


def test_a_gate_turned_off_never_closes():
    gate = SlackGate(on=False)
    gate.open_until(0)
    assert gate.deadline == SlackGate.FREE
    gate.check()
    assert gate.holds == 0


def test_the_deadline_leaves_a_guard_and_short_periods_are_never_gated():
    gate = SlackGate(on=True)
    ms = 10**6
    assert gate.deadline_ns(50 * ms, 10 * ms) == 50 * ms - round(GATE_GUARD_S * 1e9)
    assert gate.deadline_ns(50 * ms, ms) == 50 * ms - min(round(GATE_GUARD_S * 1e9), 0.4 * ms)
    short = int(GATE_MIN_PERIOD_S * 1e9) - 1
    assert gate.deadline_ns(50 * ms, short) == SlackGate.FREE


def test_a_batch_held_in_the_worker_is_urgent_once_its_samples_are_near():
    """The scheduler opens the gate for good while a stream's batch is needed soon."""
    gate, worker = gated_worker(20.0)
    try:
        reads = []
        la = sensor(reads, worker)
        la.get(1)
        assert not la.urgent()                      # no batch in the worker
        gate.open_until(0)
        la.refill(1)                                # 2 .. 9, the next sample: held
        assert la.urgent()
        gate.open()
        la._collect(wait=True)
        assert not la.urgent()
    finally:
        worker.stop()


def test_a_gated_worker_runs_its_calls_though_a_taken_back_exception_left_the_flag_up():
    """The node tests' hang: a campaign's watchdog in the same process had taken back an
    exception with ``None`` (interrupt), and the worker, profiled by its gate, spun at its
    call's first instruction while the publishing thread waited for its batch."""
    gate, worker = gated_worker(20.0)
    try:
        ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(threading.get_ident()),
                                                   None)
        gate.open_until(time.perf_counter_ns() + 10**11)    # a deadline: the gate profiles
        done = threading.Event()
        worker.call(lambda: done.set())
        assert done.wait(10.0)
        assert worker.drain(timeout=10.0)
    finally:
        interrupt.settle()              # the flag down for the tests after this one
        gate.open()
        worker.stop()


def test_an_open_that_meets_a_hold_timing_out_is_not_lost():
    """The worker's hold timed out (it sets a deadline of its own) just as the publishing
    thread opened the gate: the open wins. Forced interleaving: the publishing thread's
    write lands between the worker's reading of the deadline and its own write."""
    import inspect
    gate = SlackGate(hold_max_s=0.0, on=True)       # any hold times out at once
    gate.open_until(0)
    lines, first = inspect.getsourcelines(SlackGate._hold)
    own = first + next(i for i, text in enumerate(lines) if 'self._deadline = now' in text)
    opener = threading.Thread(target=gate.open)
    met = []

    def tracer(frame, event, arg):
        if frame.f_code is not SlackGate._hold.__code__:
            return None
        if event == 'line' and frame.f_lineno == own and not met:
            met.append(True)
            opener.start()                          # the publishing thread opens ...
            until(lambda: gate.deadline == SlackGate.FREE)
            # ... and meets this thread holding the gate's lock: it waits for it
        return tracer
    sys.settrace(tracer)
    try:
        gate.check()
    finally:
        sys.settrace(None)
    opener.join(10.0)
    assert met and not opener.is_alive()
    assert gate.deadline == SlackGate.FREE          # open for good, as the opener asked


def test_a_wait_for_the_worker_takes_down_a_flag_left_up_while_its_call_ran():
    """The flag goes up while a profiled call runs (no settle at its start helps): the
    publishing thread, about to wait for the worker, takes it down."""
    gate, worker = gated_worker(20.0)
    go, entered, done = threading.Event(), threading.Event(), threading.Event()

    def call():
        return None

    def body():
        entered.set()
        go.wait()
        for _ in range(100):
            call()                  # profiled calls: each spins while the flag is up
        done.set()
    try:
        gate.open_until(time.perf_counter_ns() + 10**11)    # a deadline: the gate profiles
        worker.call(body)
        assert entered.wait(10.0)
        ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(threading.get_ident()),
                                                   None)
        go.set()
        assert worker.drain(timeout=10.0) and done.is_set()
    finally:
        interrupt.settle()
        gate.open()
        worker.stop()
