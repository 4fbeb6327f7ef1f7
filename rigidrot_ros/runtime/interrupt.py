"""Exceptions raised into a running thread, and the mark they leave on the interpreter (no rclpy).

``PyThreadState_SetAsyncExc(thread, exc)`` asks a thread to raise ``exc`` at its next
check of the eval loop's breaker. CPython 3.11 notes that a request is pending in one
flag of the whole interpreter, and takes the flag down only when a thread raises the
exception set on it. Setting ``None`` (to take a request back) raises the flag too and
clears nothing: from then on every thread finds the breaker set and nothing to do, for
the rest of the process. That costs a plain thread little; a thread with a profile or
trace function (``sys.setprofile``: the look-ahead worker's
:class:`~rigidrot_ros.runtime.gate.SlackGate`) spins at the first instruction of its next
Python call, its breaker handled before its profile event and the instruction started
again, for good. Traced in the node tests under ``-n 2``: an in-process campaign's
watchdog had taken back an exception it set on a filter's thread (``campaign.inproc``),
and in the same test process the node's worker sat at its call's first line holding the
interpreter while the publishing thread waited for its batch (pytest-timeout ended it).

:func:`settle` takes the flag down from the calling thread: it sets an exception of its
own on that thread and raises it at once. The worker settles before it installs the
gate's profile, and the publishing thread before it waits for the worker (a flag that
went up while a profiled call ran); any thread's settle lets a spinning thread go on.
"""

import ctypes
import threading

__all__ = ['raise_in', 'settle']


class _Settled(BaseException):
    """Set and raised by :func:`settle` on its own thread, and caught there."""


# a prototype of our own: argtypes set on ``ctypes.pythonapi``'s shared function would
# change what its other callers pass (their ``None`` is NULL there)
_SET = ctypes.PYFUNCTYPE(ctypes.c_int, ctypes.c_ulong, ctypes.py_object)(
    ('PyThreadState_SetAsyncExc', ctypes.pythonapi))


def raise_in(thread_id, exc_type):
    """Ask thread ``thread_id`` (``threading.get_ident``) to raise ``exc_type``.

    The thread raises it at its next Python instruction (not while it waits in C code).
    Returns how many threads were asked (0: no such thread). Take a request back with
    :func:`settle` on that thread, never by setting ``None``.
    """
    return _SET(thread_id, exc_type)


def settle():
    """Take back any exception set on the calling thread, and take the interpreter's flag down.

    The calling thread raises an exception of this module's at once, in place of whatever
    was set on it, and catches it: no request is left, and the eval loop's breaker is
    cleared. A request set meanwhile on another thread is not lost: that thread raises
    the flag again when it next takes the interpreter.
    """
    try:
        _SET(threading.get_ident(), _Settled)
        for _ in range(1000):           # raised at the first check of the breaker
            pass
    except _Settled:
        return
    raise RuntimeError('settle: the exception set on this thread was not raised')
