"""The in-process path of a campaign: a factory's object fed the run's messages.

``estimator.factory: module:callable`` is called with ``estimator.params`` (a dict) once
per run; the object it returns gets ``receive(topic, msg)`` for the run description and
every sensor message of the run (:data:`rigidrot_ros.campaign.session.SENSORS`: never the
truth's topics), in log-time order, and ``finish()`` at the end. Each returns a list (or
tuple, or None for none) of estimate messages of a scored type
(:data:`~rigidrot_ros.campaign.session.SCORED_TYPES`); they are bagged on
``estimator.topic`` with their header stamps as log times, with the run description, and
the bag is scored.

What fails the run, with its reason: the factory raises or returns an object without
``receive``/``finish`` (a start-up failure: the campaign stops with that line when no
run has succeeded yet), ``receive``/``finish`` raises, returns something that is not a
list of messages or a message of a type the campaign does not score, or the run outlives
``timeout`` (a filter stuck inside a call is interrupted: by SIGALRM in a process's main
thread, which also ends a ``time.sleep``, else by an exception set on its thread, which
takes effect at its next Python instruction; a call blocked in C code outside the main
thread is not interrupted).
"""

import ctypes
import json
import os
import signal
import threading
import time
import traceback

from rigidrot_ros.campaign.failure import RunFailed

__all__ = ['run_inproc']

_SEC = 1_000_000_000


class _Hung(BaseException):
    """Raised into the run when its time is up.

    A BaseException: ``except Exception`` in a filter does not swallow it.
    """


class _Watchdog:
    """Raise :class:`_Hung` in this thread at ``deadline`` (``time.monotonic()``)."""

    def __init__(self, deadline):
        self.deadline = deadline
        self._main = threading.current_thread() is threading.main_thread()
        self._tid = threading.get_ident()
        self._lock = threading.Lock()
        self._armed = False
        self._fired = False
        self._timer = None
        self._previous = None

    def __enter__(self):
        left = max(1e-3, self.deadline - time.monotonic())
        self._armed = True
        if self._main:
            self._previous = signal.signal(signal.SIGALRM, self._on_alarm)
            signal.setitimer(signal.ITIMER_REAL, left)
        else:
            self._timer = threading.Timer(left, self._fire)
            self._timer.daemon = True
            self._timer.start()
        return self

    def _on_alarm(self, signum, frame):
        if self._armed:
            self._fired = True
            raise _Hung()

    def _fire(self):
        with self._lock:
            if self._armed:
                self._fired = True
                ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._tid),
                                                           ctypes.py_object(_Hung))

    def __exit__(self, *exc):
        if self._main:
            signal.setitimer(signal.ITIMER_REAL, 0)
            self._armed = False
            signal.signal(signal.SIGALRM, self._previous)
        else:
            with self._lock:
                self._armed = False
                if self._fired:           # set, maybe not raised yet: take it back
                    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._tid),
                                                               None)
            self._timer.cancel()
        return False


def _is_message(obj):
    return callable(getattr(type(obj), 'get_fields_and_field_types', None))


def run_inproc(spec, values, work, timing):
    """Feed run ``values`` to the factory's object; return the bag of its estimates."""
    from rclpy.serialization import serialize_message

    from rigidrot_ros.bag import BagWriter
    from rigidrot_ros.campaign.session import SCORED_TYPES, SENSORS
    from rigidrot_ros.campaign.spec import load_factory
    from rigidrot_ros.ros.recorder import type_name_of
    from rigidrot_ros.run.generate import iter_run, RUN_TOPIC
    est = spec['estimator']
    topic = est['topic']
    deadline = time.monotonic() + spec['timeout']
    where = ['the factory']
    writer = None
    counts = {'n': 0, 'type': None}

    def put(out):
        if out is None:
            return
        if isinstance(out, (str, bytes)) or _is_message(out) or \
                not isinstance(out, (list, tuple)):
            raise RunFailed(f'{where[0]} returned {type(out).__name__}, not a list of '
                            f'messages')
        for m in out:
            name = type_name_of(m) if _is_message(m) else type(m).__name__
            if name not in SCORED_TYPES:
                raise RunFailed(f'{where[0]} returned a {name}: the campaign scores '
                                f'{", ".join(SCORED_TYPES)} (an orientation with its '
                                f'covariance)')
            if counts['type'] is None:
                writer.add_topic(topic, name)
                counts['type'] = name
            elif name != counts['type']:
                raise RunFailed(f'{where[0]} returned a {name} after {counts["type"]}s: one '
                                f'type per topic')
            stamp = m.header.stamp
            writer.write(topic, serialize_message(m), stamp.sec * _SEC + stamp.nanosec)
            counts['n'] += 1

    t0 = time.perf_counter()
    try:
        with _Watchdog(deadline):
            factory = load_factory(est['factory'])
            try:
                filt = factory(dict(est['params']))
            except RunFailed:
                raise
            except Exception as exc:  # noqa: B902 - the estimator's own failure
                raise RunFailed(f'the factory failed: {type(exc).__name__}: {exc}',
                                traceback.format_exc(), startup=True) from None
            missing = [m for m in ('receive', 'finish')
                       if not callable(getattr(filt, m, None))]
            if missing:
                raise RunFailed(f'the factory made no estimator: its {type(filt).__name__} '
                                f'has no {" and no ".join(m + "()" for m in missing)}',
                                startup=True)
            writer = BagWriter(None, 'campaign', flush_period=60.0,
                               path=os.path.join(work, 'estimate'), split_seconds=0.0)
            for k, (name, ns, msg) in enumerate(iter_run(values, spec['duration'])):
                if name == RUN_TOPIC:
                    writer.add_topic(RUN_TOPIC, 'std_msgs/msg/String')
                    writer.add_run(json.loads(msg.data))
                    writer.write(RUN_TOPIC, serialize_message(msg), ns)
                elif name.rsplit('/', 1)[-1] not in SENSORS:
                    continue
                where[0] = f'receive() on {name} at stamp {ns} ns'
                try:
                    out = filt.receive(name, msg)
                except Exception as exc:  # noqa: B902 - the estimator crashed
                    raise RunFailed(f'the estimator crashed in {where[0]}: '
                                    f'{type(exc).__name__}: {exc}',
                                    traceback.format_exc()) from None
                put(out)
            where[0] = 'finish()'
            try:
                out = filt.finish()
            except Exception as exc:  # noqa: B902
                raise RunFailed(f'the estimator crashed in finish(): {type(exc).__name__}: '
                                f'{exc}', traceback.format_exc()) from None
            put(out)
    except _Hung:
        raise RunFailed(f'timeout: the run took longer than {spec["timeout"]:g} s (in '
                        f'{where[0]})', traceback.format_exc()) from None
    finally:
        if writer is not None:
            writer.close()
    timing['filter_s'] = time.perf_counter() - t0
    if not counts['n']:
        raise RunFailed(f'the estimator published nothing on {topic}')
    return writer.path
