"""Exceptions raised into a thread, without the interpreter's flag left up (no ROS)."""

import ctypes
import sys
import threading

import pytest

from rigidrot_ros.runtime import interrupt
from thread_helpers import profiled_calls


def _take_back_with_none():
    """Take back an exception on this thread as the campaign's watchdog did (``None``)."""
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(threading.get_ident()), None)


@pytest.mark.skipif(sys.version_info[:2] != (3, 11), reason='the 3.11 eval loop')
def test_a_request_taken_back_with_none_stalls_a_profiled_thread_until_settled():
    """The mechanism of the node's hang: the flag stays up, a profiled thread spins at a call."""
    _take_back_with_none()
    try:
        done = profiled_calls()
        assert not done.wait(0.5)           # spinning at its first call's first instruction
    finally:
        interrupt.settle()
    assert done.wait(30.0)                  # the flag down: it goes on


def test_after_settle_a_profiled_thread_runs():
    _take_back_with_none()
    interrupt.settle()
    assert profiled_calls().wait(30.0)


def test_raise_in_raises_in_the_thread_and_leaves_no_flag_up():
    started, caught = threading.Event(), []

    class Stop(BaseException):
        pass

    def spin():
        started.set()
        try:
            while True:
                pass
        except Stop:
            caught.append(True)
    th = threading.Thread(target=spin, daemon=True)
    th.start()
    assert started.wait(30.0)
    assert interrupt.raise_in(th.ident, Stop) == 1
    th.join(30.0)
    assert caught == [True] and not th.is_alive()
    assert profiled_calls().wait(30.0)
    assert interrupt.raise_in(th.ident, Stop) == 0          # no such thread any more
