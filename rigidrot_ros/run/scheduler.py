"""One schedule for every stream of the node, and the sensors' timing models (no rclpy).

The node runs one timer (:func:`timer_period_ns`: the shortest period of its streams, at
most a second) instead of a timer per stream. Each call publishes every sample that is due
by then, of every stream, in stamp order; so a sample goes out as soon after its due time
as the executor calls the timer, and one that a slow call delayed goes out with the next
call (a catch-up, counted as late, not lost). A :class:`Track` is one stream's place on
its grid (:mod:`rigidrot_ros.run.grid`): the last index published and the samples due.

Timing models (:class:`Timing`, per sensor, each off by default; parameters
``<sensor>.latency``, ``.stamp_jitter``, ``.drop_probability``, ``.clock_offset``):

- **latency** L (s): sample k is due at ``t_start + k / rate + L`` of clock time, not at
  its grid time; its stamp does not change.
- **stamp jitter** sigma (s): the message's stamp is the grid time plus a draw of
  N(0, sigma^2) (rounded to ns), while the sample is taken at the grid time (the true
  sample time, which the truth knows). Publication is still due at the grid time + L.
- **drop probability** p: each sample is dropped (evaluated, so the sensor's state and
  noise run on, but not published nor recorded) with probability p.
- **clock offset** c (s): the sensor's stamps run c ahead of the truth's clock: the stamp
  is the grid time + c (+ jitter); the sample is taken at the grid time.

The jitter and drop draws come from their own generator, seeded by the sensor's
``seed`` (and a constant per model), drawn once per sample in index order as the samples
are evaluated: the same seed gives the same drop pattern and the same jitter sequence.
"""

from dataclasses import dataclass

import numpy as np

from rigidrot_ros.run import grid

__all__ = ['Timing', 'timing_of', 'Track', 'timer_period_ns', 'next_batch', 'TIMING_KEYS',
           'MAX_PERIOD_S', 'KEEP_AHEAD_S', 'KEEP_AHEAD', 'DEFERRED']

#: The longest scheduler period, s (the diagnostics are due once a second).
MAX_PERIOD_S = 1.0
#: The timing parameters of a sensor, by the suffix of their names.
TIMING_KEYS = ('latency', 'stamp_jitter', 'drop_probability', 'clock_offset')
_TAG = 0x5C4ED          # keeps the timing draws apart from the sensor's own noise stream


@dataclass(frozen=True)
class Timing:
    """A sensor's timing model (all zero: samples due and stamped on their grid).

    Attributes
    ----------
    latency, stamp_jitter, clock_offset : float
        Seconds of clock time (see the module text).
    drop_probability : float
        In [0, 1).
    seed : int
        Seed of the jitter and drop draws.
    """

    latency: float = 0.0
    stamp_jitter: float = 0.0
    drop_probability: float = 0.0
    clock_offset: float = 0.0
    seed: int = 0

    @property
    def latency_ns(self):
        """Return the latency in integer ns."""
        return round(self.latency * 1e9)

    @property
    def offset_ns(self):
        """Return the clock offset in integer ns."""
        return round(self.clock_offset * 1e9)

    def as_dict(self):
        """Return the model as the run description records it (seconds, probability)."""
        return {'latency_s': self.latency, 'stamp_jitter_s': self.stamp_jitter,
                'drop_probability': self.drop_probability,
                'clock_offset_s': self.clock_offset}


def timing_of(values, name):
    """Return the :class:`Timing` of sensor ``name`` from checked parameter ``values``.

    A parameter absent from ``values`` counts as 0 (off).
    """
    kw = {key: float(values.get(f'{name}.{key}', 0.0)) for key in TIMING_KEYS}
    return Timing(seed=int(values.get(f'{name}.seed', 0)), **kw)


def timer_period_ns(rates):
    """Return the scheduler's period (ns): the shortest of ``1 / rate``, at most 1 s."""
    return min([round(MAX_PERIOD_S * 1e9)] + [round(1e9 / float(r)) for r in rates if r > 0])


class Track:
    """One stream's samples k = first, first + 1, ... on the grid ``origin + k / rate``.

    Parameters
    ----------
    name : str
        The stream's name (diagnostics keys).
    origin_ns : int
        The grid's index 0 (``t_start`` for a sensor).
    rate : float
        Hz.
    first : int
        The first index of the stream.
    timing : Timing
        Its timing model.
    """

    def __init__(self, name, origin_ns, rate, first=0, timing=Timing()):
        self.name = name
        self.origin_ns = int(origin_ns)
        self.rate = float(rate)
        self.first = int(first)
        self.timing = timing
        self.last = self.first - 1          # the last index handed out by due()
        seq = np.random.SeedSequence([int(timing.seed), _TAG])
        jitter_seq, drop_seq = seq.spawn(2)
        self._jitter = np.random.Generator(np.random.PCG64(jitter_seq))
        self._drop = np.random.Generator(np.random.PCG64(drop_seq))

    def stamp_ns(self, k):
        """Return the grid time (ns) of sample k: the true sample time."""
        return grid.stamp_ns(self.origin_ns, self.rate, k)

    def due(self, now_ns):
        """Return ``(ks, skipped)``: the indices due at ``now_ns`` (a range), oldest first.

        Sample k is due at its grid time plus the latency. A backlog of more than
        ``max(grid.BACKLOG_MIN, rate)`` samples (over a second: a clock jump) restarts at
        the newest; ``skipped`` counts the samples left out. Marks them handed out.
        """
        origin = self.origin_ns + self.timing.latency_ns
        if grid.index(origin, self.rate, now_ns) < max(self.last + 1, self.first):
            return range(0), 0          # nothing due yet (grid.due would owe sample 0)
        first, newest, skipped = grid.due(origin, self.rate, self.last, now_ns)
        first = max(first, self.first)
        if newest < first:
            return range(first, first), 0
        self.last = newest
        return range(first, newest + 1), skipped

    def next_due_ns(self):
        """Return the clock time (ns) at which the next sample falls due."""
        return self.stamp_ns(max(self.last + 1, self.first)) + self.timing.latency_ns

    def marks(self, ks):
        """Return ``(stamps_ns, keep)`` of the samples ``ks`` (drawn in order; call once each).

        ``stamps_ns`` (int64): the stamps the messages carry (grid time + clock offset +
        jitter); ``keep`` (bool): False where the sample is dropped.
        """
        n = len(ks)
        true = grid.stamps_ns(self.origin_ns, self.rate, range(ks.start, ks.stop))
        t = self.timing
        stamps = true + t.offset_ns
        if t.stamp_jitter > 0:
            stamps = stamps + np.rint(self._jitter.standard_normal(n) *
                                      (t.stamp_jitter * 1e9)).astype(np.int64)
        keep = np.ones(n, dtype=bool)
        if t.drop_probability > 0:
            keep = self._drop.random(n) >= t.drop_probability
        return stamps, keep


#: A catch-up call still runs a batch when its stream has less than this buffered ahead:
#: seconds of samples, and samples (:func:`next_batch`).
KEEP_AHEAD_S, KEEP_AHEAD = 4e-3, 3
#: :func:`next_batch`'s answer when the batch waits for a later call.
DEFERRED = 'deferred'


def next_batch(streams, behind=False):
    """Choose the one look-ahead batch of a scheduler call: the buffer that runs out first.

    Parameters
    ----------
    streams : list of (ahead, last, rate)
        Each stream's look-ahead (:class:`~rigidrot_ros.runtime.ahead.Ahead`), the index
        of its last published sample, and its rate (Hz); ties go to the first.
    behind : bool
        This call came late (a catch-up); then the batch waits for a later call unless its
        stream has less than :data:`KEEP_AHEAD_S` (or :data:`KEEP_AHEAD` samples) buffered.

    Returns
    -------
    (ahead, last) to refill, None if no buffer needs a batch, or :data:`DEFERRED`.
    """
    best, when = None, None
    for ahead, last, rate in streams:
        if ahead.needs(last):
            t = ahead.ahead_of(last) / rate
            if when is None or t < when:
                best, when = (ahead, last), t
    if best is None:
        return None
    if behind and when >= KEEP_AHEAD_S and best[0].ahead_of(best[1]) >= KEEP_AHEAD:
        return DEFERRED
    return best
