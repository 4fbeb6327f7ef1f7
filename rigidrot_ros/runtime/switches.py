"""Every environment variable rigidrot_ros reads, read here and nowhere else (no rclpy).

None of them is a parameter of a run: a run is its parameters (``rigidrot_ros.run.params``).
Two set something of the process (:func:`rt_priority`, the real-time policy the node asks
for; :func:`no_jit`, the dense output's engine interpreted instead of compiled); the
others turn off one mechanism of the node, or resize it, so that it can be measured
against its absence, each one measured to help before it became the default.

Each function reads its variable when it is called (the node at start-up, the core when
its engine loads), from ``environ`` where given, else ``os.environ``.
``doc/development.md`` ("Environment variables") has the table of them, defaults and
effects; a test checks that it lists exactly the names :data:`SWITCHES` holds and this
module reads, and that no other module of the package reads one.
"""

import os

__all__ = ['SWITCHES', 'rt_priority', 'no_jit', 'no_native', 'lookahead_worker', 'worker_gate',
           'worker_batch', 'gc_freeze', 'gc_schedule', 'record_offload', 'pacer', 'turned_off']


def _text(name, environ):
    return (os.environ if environ is None else environ).get(name, '').strip()


def _on(name, environ):
    """Read a switch that is on by default: anything but ``0`` (unset, empty) is on."""
    return _text(name, environ) != '0'


def rt_priority(default, environ=None):
    """Return the ``SCHED_FIFO`` priority ``RIGIDROT_RT_PRIORITY`` asks for (0: off).

    Unset or empty: ``default``. Anything but an integer from 0 to 99 raises ValueError,
    one line naming the variable (``attitude_node`` exits 2 with it).
    """
    text = _text('RIGIDROT_RT_PRIORITY', environ)
    if not text:
        return default
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 99:
        raise ValueError(f'RIGIDROT_RT_PRIORITY must be an integer from 0 (off) to 99, '
                         f'got {text!r}')
    return value


def no_jit(environ=None):
    """Whether ``RIGIDROT_NO_JIT`` asks for the interpreted engine (set, and not ``0``)."""
    return _text('RIGIDROT_NO_JIT', environ) not in ('', '0')


def no_native(environ=None):
    """Whether ``RIGIDROT_NO_NATIVE`` asks for numba's own load of the compiled kernels.

    Set and not ``0``: the kernels are not loaded as object code
    (:mod:`rigidrot_ros.runtime.native`) but through numba, as before that loader.
    """
    return _text('RIGIDROT_NO_NATIVE', environ) not in ('', '0')


def lookahead_worker(environ=None):
    """Whether look-ahead batches run in a worker thread (``RIGIDROT_LOOKAHEAD_WORKER=0``: not)."""
    return _on('RIGIDROT_LOOKAHEAD_WORKER', environ)


def worker_gate(environ=None):
    """Whether the worker runs only in the scheduler's slack (``RIGIDROT_WORKER_GATE`` set).

    Set and not ``0``; off by default: measured on and off alternately at 1 kHz beside
    another process's load, it did not lower the late gyro samples
    (:class:`~rigidrot_ros.runtime.gate.SlackGate`).
    """
    return _text('RIGIDROT_WORKER_GATE', environ) not in ('', '0')


def worker_batch(default, low, high, environ=None):
    """Return the worker's batch size: ``RIGIDROT_WORKER_BATCH`` if set, else ``default``.

    ``0`` (sized by the cost model, as inline batches) is kept; another integer is clipped
    to ``[low, high]``; a value that is not an integer reads as ``default``.
    """
    text = _text('RIGIDROT_WORKER_BATCH', environ)
    try:
        n = int(text) if text else int(default)
    except ValueError:
        return int(default)
    return n if n == 0 else min(max(n, low), high)


def gc_freeze(environ=None):
    """Whether the node freezes its start-up heap (``RIGIDROT_GC_FREEZE=0``: it does not)."""
    return _on('RIGIDROT_GC_FREEZE', environ)


def gc_schedule(environ=None):
    """Whether the node runs the young collector passes (``RIGIDROT_GC_SCHEDULE=0``: not)."""
    return _on('RIGIDROT_GC_SCHEDULE', environ)


def record_offload(environ=None):
    """Whether the node's bag writes chunks in the worker (``RIGIDROT_RECORD_OFFLOAD=0``: not)."""
    return _on('RIGIDROT_RECORD_OFFLOAD', environ)


def pacer(environ=None):
    """Whether the node paces its calls at >= 1 kHz (``RIGIDROT_PACER=0``: it does not)."""
    return _on('RIGIDROT_PACER', environ)


#: Every variable, by name: the function that reads it.
SWITCHES = {
    'RIGIDROT_RT_PRIORITY': rt_priority,
    'RIGIDROT_NO_JIT': no_jit,
    'RIGIDROT_NO_NATIVE': no_native,
    'RIGIDROT_LOOKAHEAD_WORKER': lookahead_worker,
    'RIGIDROT_WORKER_GATE': worker_gate,
    'RIGIDROT_WORKER_BATCH': worker_batch,
    'RIGIDROT_GC_FREEZE': gc_freeze,
    'RIGIDROT_GC_SCHEDULE': gc_schedule,
    'RIGIDROT_RECORD_OFFLOAD': record_offload,
    'RIGIDROT_PACER': pacer,
}


def turned_off(switch):
    """Return the environment entry that turns off ``switch`` (one of this module's readers).

    For a process started to be measured against the default, e.g. the node without its
    pacer: ``turned_off(pacer)`` is ``{'RIGIDROT_PACER': '0'}``.
    """
    name = next(n for n, fn in SWITCHES.items() if fn is switch)
    return {name: '0'}
