"""The node's diagnostics: counters, and the report as a pure function of them (no rclpy).

The node counts into one :class:`Counters`; once a second it takes a :class:`Window` of
them (:meth:`Counters.window`, which starts the next window) and publishes
:func:`report` of it as one ``diagnostic_msgs/DiagnosticStatus`` (levels :data:`OK`,
:data:`WARN`, :data:`ERROR` are DiagnosticStatus's).

Keys of the report: ``model``, ``method``, ``backend``, ``tol_rad``, ``error_bound_rad``
(the last tick's bound); ``multiprecision_bits`` (the solution's ``precision``: the
mpmath/Arb working precision its model last used, at set-up for a closed form or a table,
or in its last multiprecision evaluation; the samples themselves are float64);
``eval_*`` (getting a tick's sample: from the look-ahead buffer, or evaluated then),
``tick_*`` (the whole scheduler call that published truth ticks, up to its messages'
publication) and ``latency_*`` (the wake-up latency: from a tick's stamp to the start of
the call that publishes it, node clock), each mean, p99 and max over the window, µs;
``lookahead*`` (the truth's; ``lookahead_deferred``: batches of any stream that a late
call left to a later one, since start-up); per sensor stream ``<name>_samples`` (since start-up),
``<name>_sample_mean_us``/``_max_us`` (reading one sample, its share of a batch, over the
window), ``<name>_latency_mean_us``/``_p99_us``/``_max_us`` (publication time minus the
sample's true time, over the window; with a ``<name>.latency`` model at least that) and
``<name>_dropped`` (samples a ``<name>.drop_probability`` model dropped, since the run
started);
``increment_error_bound_rad`` (the largest bound of this run's gyro increments);
``sensor_samples_skipped``, ``ticks_published``, ``ticks_late``, ``ticks_missed``,
``publish_rate_hz`` and ``delivered_rate_hz``. The node adds ``scheduling`` (its
policy, :mod:`~rigidrot_ros.runtime.realtime`) and ``worker_gate`` (the look-ahead worker
held to the scheduler's slack over the window,
:class:`~rigidrot_ros.runtime.gate.SlackGate`: ``<n> holds, <ms> ms``; ``open`` where
it is not held, e.g. below a 1 ms period; ``off`` by default (``RIGIDROT_WORKER_GATE``
unset or ``0``) or with no worker).

Where a window's time went: ``call_max_us`` (the window's longest scheduler call, from
its due time on the scheduler grid to its end, µs) and ``call_max_phases`` (that call's
phases, µs: ``wake`` its due time to its start, ``collect`` the samples due taken from
the buffers, or evaluated then (``owed``: samples per stream, ``now``: of those not
buffered), ``publish``, ``record`` (handing the messages to the recorder), ``batch`` (the
look-ahead batch, and whose), ``diag`` (these add up to the call), and ``gc``: the
garbage collector's passes within the call, a part of the phases above, e.g. of ``diag``
for a pass the scheduler ran at its end); ``gc_collections`` (passes in the window,
generations 0/1/2) and ``gc_max_us`` (the longest, :class:`GcWatch`).
"""

from dataclasses import dataclass, field
import gc
import time

import numpy as np

__all__ = ['Counters', 'Window', 'report', 'summary', 'delivered', 'GcWatch', 'OK', 'WARN',
           'ERROR']

#: Levels, as diagnostic_msgs/DiagnosticStatus numbers them.
OK, WARN, ERROR = 0, 1, 2


def summary(values, scale=1.0):
    """Return (mean, p99, max) of ``values`` times ``scale`` (zeros if empty)."""
    a = np.array(values) * scale if values else np.zeros(1)
    return float(a.mean()), float(np.percentile(a, 99)), float(a.max())


_summary = summary


@dataclass
class Window:
    """What the counters held over one diagnostics window (plain numbers, seconds)."""

    eval_s: tuple
    tick_s: tuple
    latency_s: tuple
    streams: dict           # name -> (samples since start-up, mean s, max s) of this window
    published: int
    late: int
    missed: int
    skipped: int
    new_skips: bool
    errors: int
    last_error: str
    deferred: int = 0
    slowest: tuple = None       # (ns, phases) of the window's longest scheduler call
    gc: tuple = (0, 0, 0, 0)    # collections of generations 0, 1, 2; the longest, ns


class GcWatch:
    """Time the garbage collector's passes (``gc.callbacks``): per window, and the running sum.

    :attr:`total_ns` only grows (a scheduler call reads it before and after to know its
    share); :meth:`take` returns the window's ``(gen 0, gen 1, gen 2 collections, longest
    ns)`` and starts the next. :meth:`remove` takes the callback out again.
    """

    def __init__(self, clock=time.perf_counter_ns):
        self.total_ns = 0
        self._clock = clock
        self._t0 = None
        self._counts = [0, 0, 0]
        self._longest = 0
        gc.callbacks.append(self._on_gc)

    def _on_gc(self, phase, info):
        if phase == 'start':
            self._t0 = self._clock()
            return
        if self._t0 is None:
            return
        dt = self._clock() - self._t0
        self._t0 = None
        self.total_ns += dt
        self._counts[min(int(info.get('generation', 0)), 2)] += 1
        self._longest = max(self._longest, dt)

    def take(self):
        """Return ``(gen 0, gen 1, gen 2 collections, longest ns)`` of the window; reset."""
        out = tuple(self._counts) + (self._longest,)
        self._counts, self._longest = [0, 0, 0], 0
        return out

    def remove(self):
        """Stop watching (idempotent)."""
        if self._on_gc in gc.callbacks:
            gc.callbacks.remove(self._on_gc)


@dataclass
class Counters:
    """Tick and sample accounting of a node; times of the current window.

    ``times``: evaluation seconds per tick; ``tick_times`` and ``latencies``: ns.
    """

    times: list = field(default_factory=list)
    tick_times: list = field(default_factory=list)
    latencies: list = field(default_factory=list)
    samples: dict = field(default_factory=dict)        # stream name -> count
    sample_times: dict = field(default_factory=dict)   # stream name -> seconds, this window
    published: int = 0
    skipped: int = 0
    skipped_reported: int = 0
    late: int = 0
    missed: int = 0
    deferred: int = 0       # look-ahead batches a late call left to the next one
    errors: int = 0
    last_error: str = ''
    slowest: tuple = None   # (ns, phases) of the longest scheduler call of this window

    def call(self, total_ns, phases):
        """Note one scheduler call of ``total_ns``; keep its phases if the window's longest.

        ``phases()`` returns a list of ``(name, ns or (ns, detail text))`` in the order they
        ran; it is called only for a call that is the window's longest so far (every call
        passes here, at up to some kHz: its detail text is built only when kept).
        """
        if self.slowest is None or total_ns > self.slowest[0]:
            self.slowest = (total_ns, phases())

    def sampled(self, name, seconds):
        """Count one sample of stream ``name`` that took ``seconds`` to build."""
        self.samples[name] = self.samples.get(name, 0) + 1
        self.sample_times.setdefault(name, []).append(seconds)

    def failed(self, text):
        """Count one failed evaluation, ``text`` saying why."""
        self.errors += 1
        self.last_error = text

    def take(self, gc_counts=(0, 0, 0, 0)):
        """Return the window's raw counts and start the next one (cheap: lists moved out).

        :meth:`summarize` turns them into a :class:`Window` (in another thread, if need
        be); ``gc_counts``: the window's :meth:`GcWatch.take`, carried along.
        """
        raw = {'times': self.times, 'tick_times': self.tick_times,
               'latencies': self.latencies, 'sample_times': self.sample_times,
               'samples': dict(self.samples), 'published': self.published,
               'late': self.late, 'missed': self.missed, 'skipped': self.skipped,
               'new_skips': self.skipped > self.skipped_reported, 'errors': self.errors,
               'last_error': self.last_error, 'deferred': self.deferred,
               'slowest': self.slowest, 'gc': tuple(gc_counts)}
        self.times, self.tick_times, self.latencies, self.sample_times = [], [], [], {}
        self.slowest = None
        self.skipped_reported = self.skipped
        self.errors = 0
        return raw

    @staticmethod
    def summarize(raw, stream_names):
        """Return the :class:`Window` of raw counts (:meth:`take`)."""
        streams = {}
        for name in stream_names:
            mean, _, mx = _summary(raw['sample_times'].get(name, []))
            streams[name] = (raw['samples'].get(name, 0), mean, mx)
        return Window(eval_s=_summary(raw['times']), tick_s=_summary(raw['tick_times'], 1e-9),
                      latency_s=_summary(raw['latencies'], 1e-9), streams=streams,
                      published=raw['published'], late=raw['late'], missed=raw['missed'],
                      skipped=raw['skipped'], new_skips=raw['new_skips'],
                      errors=raw['errors'], last_error=raw['last_error'],
                      deferred=raw['deferred'], slowest=raw['slowest'], gc=raw['gc'])

    def window(self, stream_names, gc_counts=(0, 0, 0, 0)):
        """Return the :class:`Window` since the last call, and start the next one.

        ``gc_counts``: the window's :meth:`GcWatch.take`, carried into the window.
        """
        return self.summarize(self.take(gc_counts), stream_names)


def report(w, sol, *, period_hz, delivered, error_bound, scene_time, increment_bound,
           lookahead=None, batches=(), sensors=None):
    """Return ``(level, message, values)`` of one diagnostics window (pure).

    Parameters
    ----------
    w : Window
        The counters of the window.
    sol : Solution
        The solution being published (model, method, backend, precision, tol).
    period_hz : float
        The truth rate asked, Hz.
    delivered : float or None
        Ticks published per second over the window (None: too short a window to judge).
    error_bound : float
        The last tick's error bound, rad (0.0 before the first tick).
    scene_time : float or None
        The last tick's scene time, s.
    increment_bound : float
        The largest error bound of this run's gyro increments, rad.
    lookahead : Lookahead or None
        The truth look-ahead (its size, why it is off, its cost per sample).
    batches : sequence of float
        The look-ahead's batch times in the window, s.
    sensors : dict or None
        Per running sensor stream: ``(latency mean, p99, max s, samples dropped)``; the
        latency is the publication time minus the sample's grid time (its true sample
        time), over the window.
    """
    level, msg = _level(w, sol, period_hz, delivered, error_bound, increment_bound)
    values = _solution_values(w, sol, error_bound, scene_time)
    values.update(_lookahead_values(w, lookahead, batches))
    values.update(_stream_values(w, sensors))
    values.update({
        'sensor_samples_skipped': str(w.skipped),
        'increment_error_bound_rad': f'{increment_bound:.3g}',
        'ticks_published': str(w.published),
        'ticks_late': str(w.late), 'ticks_missed': str(w.missed),
        'publish_rate_hz': f'{period_hz:g}',
        'delivered_rate_hz': '' if delivered is None else f'{delivered:.4g}',
    })
    values.update(phase_values(w.slowest))
    g0, g1, g2, longest = w.gc
    values.update({'gc_collections': f'{g0}/{g1}/{g2}', 'gc_max_us': f'{longest / 1e3:.1f}'})
    return level, msg, values


def _level(w, sol, period_hz, delivered, error_bound, increment_bound):
    """Return ``(level, message)`` of a window: OK, or every reason to warn, or the error."""
    warns = []                  # every reason of this window, not only the last
    if w.eval_s[2] > 1.0 / period_hz:
        warns.append('evaluation slower than the timer period')
    if delivered is not None and delivered < 0.9 * period_hz:
        warns.append(f'delivering {delivered:.4g} Hz of the {period_hz:g} Hz asked '
                     '(publish_rate beyond what this machine and executor deliver)')
    if error_bound > sol.tol:
        warns.append('error bound above tol')
    if not increment_bound <= sol.tol:      # also NaN and inf
        warns.append(f'gyro increment error bound {increment_bound:.3g} rad above tol')
    if w.new_skips:
        warns.append('sensor samples skipped (a clock jump, or sensor rates above what '
                     'this CPU keeps up)')
    level, msg = OK, f'exact solution: {sol.model}'
    if warns:
        level, msg = WARN, '; '.join(warns)
    if w.errors:
        level, msg = ERROR, '; '.join([f'evaluation failed: {w.last_error}'] + warns)
    return level, msg


def _solution_values(w, sol, error_bound, scene_time):
    """Return the solution's values and the window's evaluation, tick and latency times."""
    mean, p99, mx = w.eval_s
    values = {
        'model': sol.model, 'method': sol.method, 'backend': sol.backend,
        'multiprecision_bits': str(sol.precision), 'tol_rad': f'{sol.tol:.3g}',
        'error_bound_rad': f'{error_bound:.3g}',
        'scene_time_s': '' if scene_time is None else f'{scene_time:.6f}',
        'eval_mean_us': f'{mean * 1e6:.1f}', 'eval_p99_us': f'{p99 * 1e6:.1f}',
        'eval_max_us': f'{mx * 1e6:.1f}',
    }
    for name, (m, p, x) in (('tick', w.tick_s), ('latency', w.latency_s)):
        values.update({f'{name}_mean_us': f'{m * 1e6:.1f}', f'{name}_p99_us': f'{p * 1e6:.1f}',
                       f'{name}_max_us': f'{x * 1e6:.1f}'})
    return values


def _lookahead_values(w, ahead, batches):
    """Return the look-ahead's values: its size (or why it is off), batches, cost."""
    return {
        'lookahead': ('' if ahead is None else f'{ahead.size} samples a batch'
                      if ahead.size else f'off: {ahead.off_reason}'),
        'lookahead_batches': str(len(batches)),
        'lookahead_deferred': str(w.deferred),
        'lookahead_batch_max_us': f'{max(batches, default=0.0) * 1e6:.1f}',
        'lookahead_sample_us': f'{(ahead.last_per_sample if ahead else 0.0) * 1e6:.2f}',
    }


def _stream_values(w, sensors):
    """Return each stream's sample counts and times, then each sensor's latency."""
    values = {}
    for name, (count, s_mean, s_max) in w.streams.items():
        values.update({f'{name}_samples': str(count),
                       f'{name}_sample_mean_us': f'{s_mean * 1e6:.1f}',
                       f'{name}_sample_max_us': f'{s_max * 1e6:.1f}'})
    for name, (m, p, x, dropped) in (sensors or {}).items():
        values.update({f'{name}_latency_mean_us': f'{m * 1e6:.1f}',
                       f'{name}_latency_p99_us': f'{p * 1e6:.1f}',
                       f'{name}_latency_max_us': f'{x * 1e6:.1f}',
                       f'{name}_dropped': str(dropped)})
    return values


def phase_values(slowest):
    """Return ``call_max_us`` and ``call_max_phases`` of a window's longest call (or empty).

    ``slowest`` is ``(ns, [(name, ns or (ns, detail)), ...])`` (:meth:`Counters.call`).

    Examples
    --------
    >>> phase_values((1500000, [('wake', 1200000), ('batch', (300000, 'imu 64'))]))
    {'call_max_us': '1500.0', 'call_max_phases': 'wake 1200.0, batch 300.0 (imu 64)'}
    """
    if not slowest:
        return {'call_max_us': '', 'call_max_phases': ''}
    total, phases = slowest
    parts = []
    for name, value in phases:
        ns, detail = value if isinstance(value, tuple) else (value, '')
        parts.append(f'{name} {ns / 1e3:.1f}' + (f' ({detail})' if detail else ''))
    return {'call_max_us': f'{total / 1e3:.1f}', 'call_max_phases': ', '.join(parts)}


def delivered(last, now, count, period_hz):
    """Return ``(rate, window)``: ticks published per second since ``last``, or None.

    ``last`` and the returned window are ``(steady clock s, ticks published, asked rate
    Hz)`` (None at first). The rate is None while the window is shorter than 0.5 s or
    holds fewer than 5 periods at the asked rate (too few ticks to judge: the window keeps
    accumulating), and for the first window after a rate change.
    """
    window = (now, count, period_hz)
    if last is None or last[2] != period_hz:
        return None, window
    span = now - last[0]
    if span < 0.5 or span * period_hz < 5:
        return None, last                   # keep accumulating
    return (count - last[1]) / span, window
