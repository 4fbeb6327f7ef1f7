"""The node's threads on a real-time scheduling policy, where the system allows it (no rclpy).

What the late gyro samples at 1 kHz were (traced per scheduler call, under load from other
processes on the 2 cores; doc/node.md): calls that began more than a period after their
due time while the process did next to no work in the wait, or while the look-ahead
worker held the interpreter for far longer than its batch costs (5 to 10 ms against 1 to
2 ms): the operating system had given both cores to other processes. No scheduling inside
the process helps there; a real-time policy does: a ``SCHED_FIFO`` thread that becomes
runnable preempts every ordinary (``SCHED_OTHER``) thread. Measured in the same
conditions, back to back: 229 late samples of 13 001 as an ordinary process, 0 with
``SCHED_FIFO``; through the benchmark, 362 and 432 of 20 000 against 1 and 4 (doc/node.md).

:func:`request` (called by ``attitude_node``'s ``main`` before ROS starts) asks for
``SCHED_FIFO`` at :data:`PRIORITY` for the main thread; every thread made afterwards
inherits it: ROS's, the look-ahead worker (it holds the interpreter lock while it runs: an
ordinary worker preempted with the lock held stalls the publishing thread; measured: 61
and 9 late against 1 and 4 with the publishing thread alone on ``SCHED_FIFO``), and any
child process. It needs the right to (root, ``CAP_SYS_NICE``, or an ``rtprio``
limit in ``/etc/security/limits.conf``: the set-up ROS documents for real-time nodes);
without it the node runs as before and says so in one line. The kernel's real-time
throttling (``sched_rt_runtime_us``: 95 % by default) keeps a run-away real-time thread
from taking a core whole. ``RIGIDROT_RT_PRIORITY`` sets the priority (1 to 99), or ``0``
keeps the ordinary policy.
"""

import os

from rigidrot_ros.runtime import switches

__all__ = ['request', 'describe', 'PRIORITY', 'priority_from_env']

#: The ``SCHED_FIFO`` priority asked for (1 lowest .. 99; low: above every ordinary
#: thread, below the kernel's own real-time threads and other real-time programs).
PRIORITY = 10


def priority_from_env(environ=None):
    """Return the priority ``RIGIDROT_RT_PRIORITY`` asks for (0: off), or raise ValueError.

    Unset or empty: :data:`PRIORITY` (:func:`rigidrot_ros.runtime.switches.rt_priority`).
    """
    return switches.rt_priority(PRIORITY, environ)


def request(priority=None, environ=None):
    """Put the calling thread (and the threads it makes later) on ``SCHED_FIFO``.

    Parameters
    ----------
    priority : int, optional
        1 to 99, or 0 for no change; default :func:`priority_from_env`.
    environ : mapping, optional
        Where to read ``RIGIDROT_RT_PRIORITY`` (default ``os.environ``).

    Returns
    -------
    (bool, str)
        Whether the policy is in force, and one line saying what happened (for the log).
        Never raises for a refusal: the node then runs on the ordinary policy.
    """
    if priority is None:
        priority = priority_from_env(environ)
    if priority == 0:
        return False, 'ordinary scheduling (RIGIDROT_RT_PRIORITY=0)'
    if not hasattr(os, 'sched_setscheduler'):
        return False, 'ordinary scheduling (no sched_setscheduler on this system)'
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority)))
    except OSError as exc:
        return False, (f'ordinary scheduling: SCHED_FIFO {priority} not permitted '
                       f'({exc.strerror}); samples may be late on a loaded machine')
    return True, f'real-time scheduling: SCHED_FIFO priority {priority}'


def describe():
    """Return the calling thread's scheduling policy as the diagnostics report it.

    ``'SCHED_FIFO 10'`` (policy and priority) or ``'SCHED_OTHER'`` (the ordinary one).
    """
    if not hasattr(os, 'sched_getscheduler'):
        return 'unknown'
    policy = os.sched_getscheduler(0) & ~getattr(os, 'SCHED_RESET_ON_FORK', 0)
    names = {getattr(os, n): n for n in ('SCHED_OTHER', 'SCHED_FIFO', 'SCHED_RR',
                                         'SCHED_BATCH', 'SCHED_IDLE') if hasattr(os, n)}
    name = names.get(policy, str(policy))
    if policy in (getattr(os, 'SCHED_FIFO', None), getattr(os, 'SCHED_RR', None)):
        return f'{name} {os.sched_getparam(0).sched_priority}'
    return name
