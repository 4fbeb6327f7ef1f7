"""Truth samples on the node's tick grid, evaluated ahead in batches (no rclpy).

The node publishes the truth at the grid times ``g0 + k / publish_rate`` of its timer, so
it knows the scene times of the coming ticks. :class:`Lookahead` evaluates them a batch at
a time with the vectorised path of :meth:`Solution.at` (about 1 µs a sample warm and 3-5 µs
after an idle gap, against 10-20 µs for a scalar call warm and 120-200 µs for a scalar
call that runs after the 10 ms idle gap of a 100 Hz timer on a shared virtual CPU, whose
caches the other tenants have emptied meanwhile; ``python -m rigidrot_ros.bench.node_tick``
measures both). A tick
then takes its sample from the buffer, and the batch runs after a tick has published, so
it never delays a message.

Each buffered sample is the same exact solution, with its own error bound, as a scalar
call at that time would give (both within the bound; the last bits may differ). A batch
that raises (a far sample beyond the precision ceiling) turns the look-ahead off, and so
do :data:`STRIKES` batches in a row that do not fit their budget even at the smallest
size (one slow batch, say a garbage collection or a first call's set-up, only shrinks the
next): the ticks then evaluate one sample each, and a failing sample is reported at its
own tick as before.
"""

import time

import numpy as np

__all__ = ['Lookahead', 'AHEAD_MIN', 'AHEAD_MAX', 'BATCH_BUDGET_S', 'STRIKES']

#: The first batch's size, and the smallest (see :data:`STRIKES`).
AHEAD_MIN = 8
#: The largest batch (2.56 s at 100 Hz): bounded memory, and a bounded stale tail after a
#: change of publish_rate or a reset, which drop the buffer.
AHEAD_MAX = 256
#: One batch takes at most this much CPU time, and at most half a tick period: the
#: executor runs nothing else meanwhile (measured here: 90-130 samples and their
#: messages in 2 ms). CPU time, not wall: on a loaded machine a batch is preempted, but
#: evaluating per tick would cost more, not less.
BATCH_BUDGET_S = 2e-3
#: Batches in a row that miss their budget at the smallest size before the look-ahead stops.
STRIKES = 3


class Lookahead:
    """Samples of ``solution`` at the grid indices k >= 0, batched ahead of the ticks.

    ``time_of(k)`` returns the scene time (s) of grid index k. A sample is a tuple
    ``(quaternion, omega, error_bound)`` of a 4-list (x, y, z, w), a 3-list (rad/s, in B)
    and a float (rad), plain Python floats. ``build(k, sample)``, if given, is called for
    each sample of a batch right after it is evaluated (while the process is warm: the
    node builds the tick's messages there) and its result is handed out with the sample.
    """

    def __init__(self, solution, time_of, period_s, budget_s=BATCH_BUDGET_S, enabled=True,
                 build=None):
        self.solution = solution
        self.time_of = time_of
        self.build = build
        self.budget_s = min(float(budget_s), 0.5 * float(period_s))
        self.size = AHEAD_MIN if enabled else 0
        self.off_reason = '' if enabled else 'disabled'
        self._buf = {}
        self._next = 0                  # the first index not yet buffered
        self._last = -1                 # the last tick refill() was told of
        self._strikes = 0               # batches in a row over budget at AHEAD_MIN
        self.batch_times = []           # wall seconds per batch, since the last take_stats()
        self.last_per_sample = 0.0      # wall seconds per sample of the last batch

    def __len__(self):
        return len(self._buf)

    def get(self, k):
        """Return ``(sample, built)`` for grid index k (evaluated now if not buffered).

        ``built`` is what ``build`` made of a buffered sample, None for a sample evaluated
        now. Raises what :meth:`Solution.at` raises for that time (PrecisionError,
        ValueError).
        """
        entry = self._buf.pop(k, None)
        if entry is not None:
            return entry
        s = self.solution.at(self.time_of(k))
        return (s.quaternion.tolist(), s.omega.tolist(), float(s.error_bound)), None

    def refill(self, k):
        """After tick k: evaluate the next batch if at most half a batch is left; its size."""
        if self.size < AHEAD_MIN:
            return 0
        if k != self._last + 1 and self._buf:     # ticks skipped: drop their samples
            self._buf = {j: v for j, v in self._buf.items() if j > k}
        self._last = k
        start = max(self._next, k + 1)
        if start - (k + 1) > self.size // 2:
            return 0
        n = self.size
        ts = np.array([self.time_of(j) for j in range(start, start + n)])
        c0, cpu0 = time.perf_counter(), time.thread_time()
        try:
            s = self.solution.at(ts)
        except Exception as exc:    # noqa: B902 - whatever the core raises: per tick from now
            self.size = 0
            self.off_reason = (f'a batch of {n} samples from t = {ts[0]:.6g} s failed '
                               f'({type(exc).__name__}: {exc}); evaluating per tick')
            return 0
        q, w, e = s.quaternion.tolist(), s.omega.tolist(), s.error_bound.tolist()
        build = self.build
        for j, smp in enumerate(zip(q, w, e), start):
            self._buf[j] = (smp, build(j, smp) if build is not None else None)
        self._next = start + n
        wall = time.perf_counter() - c0
        cost = time.thread_time() - cpu0        # CPU: another process's load is no reason
        self.batch_times.append(wall)
        self.last_per_sample = wall / n
        # the next batch: at most double, within the budget at this batch's cost a sample
        fits = int(self.budget_s * n / cost) if cost > 0 else AHEAD_MAX
        if fits >= AHEAD_MIN:
            self.size = min(AHEAD_MAX, 2 * n, fits)
            self._strikes = 0
        else:
            self._strikes += 1
            self.size = AHEAD_MIN
            if self._strikes >= STRIKES:
                self.size = 0
                self.off_reason = (f'{STRIKES} batches in a row beyond the budget of '
                                   f'{self.budget_s * 1e3:.3g} ms (the last: {n} samples in '
                                   f'{cost * 1e3:.3g} ms of CPU); evaluating per tick')
        return n

    def drop_built(self):
        """Forget what ``build`` made (e.g. the frame ids changed); keep the samples."""
        self._buf = {j: (smp, None) for j, (smp, _) in self._buf.items()}

    def take_stats(self):
        """Return the batch times (s) since the last call, and forget them."""
        out, self.batch_times = self.batch_times, []
        return out
