"""The in-process path of a campaign: a factory's object fed the run's messages.

``estimator.factory: module:callable`` is called with ``estimator.params`` (a dict) once
per run; the object it returns gets ``receive(topic, msg)`` for the run description and
every sensor message of the run (:data:`rigidrot_ros.campaign.session.SENSORS`: never the
truth's topics), in log-time order, and ``finish()`` at the end. Each returns a list (or
tuple, or None for none) of estimate messages of a scored type
(:data:`~rigidrot_ros.campaign.session.SCORED_TYPES`), on ``estimator.topic``.

**In memory** (the default): the run's messages are generated in memory (the bag's
messages, :func:`rigidrot_ros.run.generate.iter_serialized`, read back as messages), the
estimates are kept as what a bag of them would give the scorer
(:func:`rigidrot_ros.scoring.decode.message_rows`) and scored from there
(:func:`rigidrot_ros.campaign.run.score_estimates`): no file. An object that also has
``receive_arrays(arrays, order)`` (defined by its class or a subclass of the one that
defines ``receive`` and ``finish``: a subclass that changes how messages are taken is fed
messages) is given the whole run at once instead, as arrays
(:func:`rigidrot_ros.run.generate.run_arrays`, the sensor topics and ``'run'``, the run
description) with the order its messages would arrive in
(:func:`rigidrot_ros.run.feed.sensor_feed`), and returns its estimates as arrays
(``type``, ``stamps_ns``, ``orientation`` (n, 4) and ``orientation_cov`` (n, 3, 3) or
None; the reference MEKF's :meth:`~rigidrot_ros.estimators.mekf.MEKF.receive_arrays`): no
message is built. It must give the estimates its messages would carry, bit for bit. An
object with a ``warm()`` method has it called once in the campaign's client before the
local pool forks its workers (:func:`rigidrot_ros.campaign.engine.start_method`), for
what every run would otherwise load again in each worker (the MEKF's compiled filter).

**Bags kept** (``rigidrot_campaign --keep-bags DIR``): the messages are fed and the
estimates bagged on ``estimator.topic`` with their header stamps as log times, with the
run description, in ``DIR/run_NNNNNN/estimate``; that bag is read back and scored. Both
ways give the same row and series, so the same ``report.json``.

What fails the run, with its reason: the factory raises or returns an object without
``receive``/``finish`` (a start-up failure: the campaign stops with that line when no
run has succeeded yet), ``receive``/``finish``/``receive_arrays`` raises, returns
something that is not a list of messages (or arrays) of a type the campaign scores, or
the run outlives ``timeout`` (a filter stuck inside a call is interrupted: by SIGALRM in
a process's main thread, which also ends a ``time.sleep``, else by an exception set on
its thread, which takes effect at its next Python instruction; a call blocked in C code
outside the main thread is not interrupted).
"""

import json
import os
import signal
import threading
import time
import traceback

import numpy as np

from rigidrot_ros.campaign.failure import RunFailed
from rigidrot_ros.runtime import interrupt

__all__ = ['run_inproc', 'Estimates', 'logged_run']

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
                interrupt.raise_in(self._tid, _Hung)

    def __exit__(self, *exc):
        if self._main:
            signal.setitimer(signal.ITIMER_REAL, 0)
            self._armed = False
            signal.signal(signal.SIGALRM, self._previous)
        else:
            with self._lock:
                self._armed = False
                if self._fired:           # set, maybe not raised yet: take it back
                    # (settle, not None: that leaves the interpreter's flag up, runtime.interrupt)
                    interrupt.settle()
            self._timer.cancel()
        return False


def _is_message(obj):
    return callable(getattr(type(obj), 'get_fields_and_field_types', None))


def _owner(cls, name):
    return next((c for c in cls.__mro__ if name in vars(c)), None)


def _takes_arrays(filt):
    """Whether ``filt`` is fed arrays: its ``receive_arrays`` is its messages' own.

    A class that overrides ``receive`` or ``finish`` of a class with ``receive_arrays``
    (a filter with a twist on the messages) is fed the messages: its arrays would skip
    the twist.
    """
    if not callable(getattr(filt, 'receive_arrays', None)) or \
            any(n in getattr(filt, '__dict__', {}) for n in ('receive', 'finish')):
        return False
    cls = type(filt)
    arrays = _owner(cls, 'receive_arrays')
    return arrays is not None and all(issubclass(arrays, _owner(cls, n))
                                      for n in ('receive', 'finish'))


class Estimates:
    """An in-process run's estimates in memory: what the scorer would read from their bag.

    ``rows`` as :func:`rigidrot_ros.scoring.decode.message_rows` gives them, in the order
    the estimator returned them; ``run`` the run description as the bag's reader gives it;
    ``solutions`` the run's exact solution where the generator's is at hand (``{(node,
    start_ns): solution}``, for :func:`rigidrot_ros.scoring.score.score_against_runs`).
    """

    def __init__(self, topic, type_name, rows, run, solutions=None):
        self.topic, self.type, self.rows, self.run = topic, type_name, rows, run
        self.solutions = solutions


def logged_run(description):
    """Return a run description as a bag of it reads back (its ``rigidrot_run`` record).

    :meth:`rigidrot_ros.bag.BagWriter.add_run` writes each value that is not a string as
    JSON, and the reader decodes each value that reads as JSON.
    """
    from rigidrot_ros.bag.metadata import decode_run
    return decode_run({k: (v if isinstance(v, str) else json.dumps(v))
                       for k, v in description.items()})


def _message_feed(values, duration):
    """Yield ``(topic, log_ns, msg)`` of the run's sensors and description, in log order.

    The messages :func:`rigidrot_ros.run.generate.iter_run` yields for these topics (the
    bag's bytes read back as messages: the same fields, bit for bit).
    """
    from rclpy.serialization import deserialize_message

    from rigidrot_ros.campaign.session import SENSORS
    from rigidrot_ros.ros.recorder import msg_class
    from rigidrot_ros.run.feed import sensor_types
    from rigidrot_ros.run.generate import iter_serialized, RUN_TOPIC
    types = sensor_types(SENSORS)
    classes = {}
    for topic, ns, data in iter_serialized(values, duration, SENSORS + ('run',)):
        cls = classes.get(topic)
        if cls is None:
            cls = classes[topic] = msg_class(
                'std_msgs/msg/String' if topic == RUN_TOPIC else types[topic.rsplit('/', 1)[-1]])
        yield topic, ns, deserialize_message(data, cls)


def run_inproc(spec, values, work, timing):
    """Feed run ``values`` to the factory's object: its :class:`Estimates`, or their bag.

    With ``work`` (bags kept), the estimates are bagged in ``work/estimate`` and its path
    is returned; without, they are returned in memory.
    """
    from rigidrot_ros.run.generate import RUN_TOPIC
    est = spec['estimator']
    topic = est['topic']
    deadline = time.monotonic() + spec['timeout']
    where = ['the factory']
    sink = None
    t0 = time.perf_counter()
    try:
        with _Watchdog(deadline):
            filt = _make_filter(est)
            if work is None and _takes_arrays(filt):
                return _feed_arrays(filt, spec, values, topic, timing, t0, where)
            sink = _Sink(topic, work, where)
            for name, ns, msg in _message_feed(values, spec['duration']):
                if name == RUN_TOPIC:
                    sink.run(msg, ns)
                where[0] = f'receive() on {name} at stamp {ns} ns'
                try:
                    out = filt.receive(name, msg)
                except Exception as exc:  # noqa: B902 - the estimator crashed
                    raise RunFailed(f'the estimator crashed in {where[0]}: '
                                    f'{type(exc).__name__}: {exc}',
                                    traceback.format_exc()) from None
                sink.put(out)
            where[0] = 'finish()'
            try:
                out = filt.finish()
            except Exception as exc:  # noqa: B902
                raise RunFailed(f'the estimator crashed in finish(): {type(exc).__name__}: '
                                f'{exc}', traceback.format_exc()) from None
            sink.put(out)
    except _Hung:
        raise RunFailed(f'timeout: the run took longer than {spec["timeout"]:g} s (in '
                        f'{where[0]})', traceback.format_exc()) from None
    finally:
        if sink is not None:
            sink.close()
    timing['filter_s'] = time.perf_counter() - t0
    return sink.result()


def _make_filter(est):
    """Make the run's estimator with the spec's factory; RunFailed says why it cannot."""
    from rigidrot_ros.campaign.spec import load_factory
    factory = load_factory(est['factory'])
    try:
        filt = factory(dict(est['params']))
    except RunFailed:
        raise
    except Exception as exc:  # noqa: B902 - the estimator's own failure
        raise RunFailed(f'the factory failed: {type(exc).__name__}: {exc}',
                        traceback.format_exc(), startup=True) from None
    missing = [m for m in ('receive', 'finish') if not callable(getattr(filt, m, None))]
    if missing:
        raise RunFailed(f'the factory made no estimator: its {type(filt).__name__} '
                        f'has no {" and no ".join(m + "()" for m in missing)}',
                        startup=True)
    return filt


class _Sink:
    """Where a run's estimates go: rows in memory, or (``work``: bags kept) a bag."""

    def __init__(self, topic, work, where):
        from rigidrot_ros.scoring.decode import message_rows
        self.topic, self.where, self.keep = topic, where, work is not None
        self.n, self.type, self.rows, self.runs = 0, None, [], []
        self._rows_of = message_rows
        self.writer = None
        if self.keep:
            from rclpy.serialization import serialize_message

            from rigidrot_ros.bag import BagWriter
            self._serialize = serialize_message
            self.writer = BagWriter(None, 'campaign', flush_period=60.0,
                                    path=os.path.join(work, 'estimate'), split_seconds=0.0)

    def run(self, msg, ns):
        """Take the run description (``~/run``) at log time ``ns``."""
        from rigidrot_ros.run.generate import RUN_TOPIC
        run = json.loads(msg.data)
        if self.keep:
            self.writer.add_topic(RUN_TOPIC, 'std_msgs/msg/String')
            self.writer.add_run(run)
            self.writer.write(RUN_TOPIC, self._serialize(msg), ns)
        else:
            self.runs.append(logged_run(run))

    def put(self, out):
        """Take what ``receive`` or ``finish`` returned: a list of scored messages, or None."""
        from rigidrot_ros.campaign.session import SCORED_TYPES
        from rigidrot_ros.ros.recorder import type_name_of
        where = self.where[0]
        if out is None:
            return
        if isinstance(out, (str, bytes)) or _is_message(out) or \
                not isinstance(out, (list, tuple)):
            raise RunFailed(f'{where} returned {type(out).__name__}, not a list of messages')
        for m in out:
            name = type_name_of(m) if _is_message(m) else type(m).__name__
            if name not in SCORED_TYPES:
                raise RunFailed(f'{where} returned a {name}: the campaign scores '
                                f'{", ".join(SCORED_TYPES)} (an orientation with its '
                                f'covariance)')
            if self.type is None:
                if self.keep:
                    self.writer.add_topic(self.topic, name)
                self.type = name
            elif name != self.type:
                raise RunFailed(f'{where} returned a {name} after {self.type}s: one type per '
                                f'topic')
            if self.keep:
                stamp = m.header.stamp
                self.writer.write(self.topic, self._serialize(m),
                                  stamp.sec * _SEC + stamp.nanosec)
            else:
                self.rows.append(self._rows_of(name, m))
            self.n += 1

    def close(self):
        """Finish the bag, if one is kept."""
        if self.writer is not None:
            self.writer.close()

    def result(self):
        """Return the bag's path (kept) or the :class:`Estimates`; RunFailed if none."""
        if not self.n:
            raise RunFailed(f'the estimator published nothing on {self.topic}')
        if self.keep:
            return self.writer.path
        if not self.runs:
            raise RunFailed('the run description was not generated (no ~/run message)')
        return Estimates(self.topic, self.type, self.rows, self.runs[0])


def _feed_arrays(filt, spec, values, topic, timing, t0, where):
    """Give ``filt`` the whole run as arrays (``receive_arrays``); its :class:`Estimates`."""
    from rigidrot_ros.campaign.session import SCORED_TYPES, SENSORS
    from rigidrot_ros.run.feed import sensor_feed
    from rigidrot_ros.run.generate import run_arrays
    from rigidrot_ros.campaign.spec import take_prepared
    from rigidrot_ros.run.generate import prepare_run
    from rigidrot_ros.scoring.decode import ORIENTATION
    setup = take_prepared(values) or prepare_run(values)
    arrays = run_arrays(values, spec['duration'], setup=setup)
    feed, order = sensor_feed(arrays, SENSORS)
    feed['run'] = arrays['run']
    where[0] = 'receive_arrays()'
    try:
        out = filt.receive_arrays(feed, order)
    except Exception as exc:  # noqa: B902 - the estimator crashed
        raise RunFailed(f'the estimator crashed in receive_arrays(): {type(exc).__name__}: '
                        f'{exc}', traceback.format_exc()) from None
    if not isinstance(out, dict):
        raise RunFailed(f'receive_arrays() returned {type(out).__name__}, not a dict of '
                        f'arrays')
    name = out.get('type')
    if name not in SCORED_TYPES:
        raise RunFailed(f'receive_arrays() returned estimates of type {name!r}: the campaign '
                        f'scores {", ".join(SCORED_TYPES)} (an orientation with its '
                        f'covariance)')
    try:
        stamps = np.asarray(out['stamps_ns'], dtype=np.int64).reshape(-1)
        n = len(stamps)
        q = np.asarray(out['orientation'], dtype=float).reshape(n, 4)
        cov = out.get('orientation_cov')
        cov = None if cov is None else np.asarray(cov, dtype=float).reshape(n, 3, 3)
    except (KeyError, TypeError, ValueError) as exc:
        raise RunFailed(f'receive_arrays() returned unreadable estimates ({type(exc).__name__}: '
                        f'{exc}): it needs stamps_ns (n,), orientation (n, 4) and '
                        f'orientation_cov (n, 3, 3) or None') from None
    timing['filter_s'] = time.perf_counter() - t0
    if not n:
        raise RunFailed(f'the estimator published nothing on {topic}')
    frame = str(out.get('frame_id', ''))
    covs = [None] * n if cov is None else list(cov)
    rows = [(s, [(ORIENTATION, tuple(v), c, frame)])
            for s, v, c in zip(stamps.tolist(), q.tolist(), covs)]
    run = logged_run(json.loads(json.dumps(arrays['run'])))
    return Estimates(topic, name, rows, run,
                     {(str(run.get('node', '')), int(run['start_ns'])): setup.solution})
