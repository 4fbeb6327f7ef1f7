"""The garbage collector in the node: the start-up heap frozen out of its full passes (no rclpy).

Measured (1 kHz, truth and gyro, recording, 20 s traced in-process, under load): one
generation-2 pass of the collector took 71 ms, in the look-ahead worker, holding the
interpreter: 76 samples in a row were published more than a period after their stamps,
three quarters of that run's late samples. A full pass walks every container object of
the process, and the process holds ROS, numpy, numba, python-flint and the solution's
caches: almost all of them made at start-up and alive until the end.

:class:`Freezer` takes them out of the collector's view with :func:`gc.freeze` (they stay
alive, refcounting still frees them; only the cycle finder stops walking them):

- :meth:`Freezer.start` (the node's constructor, before its timer exists): one full
  collection, so no garbage is frozen, then a freeze;
- :meth:`Freezer.arm` at the first run's start and :meth:`Freezer.poll` from the
  scheduler: :data:`FREEZE_AFTER_S` seconds into it (its first batches, the compiled
  kernels and the caches they fill, made once per process), one more freeze. A freeze is
  a list splice (O(1)), so it costs nothing in a scheduler call; a full collection would
  cost the 71 ms above, so none is run there: whatever cyclic garbage is alive in that
  instant is never freed. That is why it happens once, not at every run: a freeze at
  each ``~/reset`` kept each run's cyclic garbage for good, measured 350 kB a reset
  (80 resets 2.5 s apart at 500 Hz: RSS 223 -> 251 MB, still rising; 41 kB a reset and
  levelling off at 228 MB without it).

The full passes after that walk only the objects made since, and take what the young
passes take. ``RIGIDROT_GC_FREEZE=0`` turns it off (for measuring the two).

:class:`Passes` moves the young passes to known moments. A pass holds the interpreter for
its whole length (0.3 to 1 ms here, under load), and it runs in whichever thread makes
the allocation that crosses the threshold: traced at 1 kHz, 4 of the 10 late gyro samples
left after fixed-size worker batches waited on a young pass in the look-ahead worker.
While a node runs, the automatic threshold of generation 0 is raised to
:data:`SAFETY_THRESHOLD` (a net: the passes still happen if the scheduler stops calling),
and the scheduler calls :meth:`Passes.poll` at the end of every call. Once :data:`STEP`
(the interpreter's default threshold, 700) allocations are pending and the call ended
early in its period (the next sample a good part of a period away), or once
:data:`LATE_STEP` are pending whenever it ended, it runs the pass the interpreter would
have run (generation 1 every 10th, 2 every 100th: the same counters,
:func:`gc.get_count`). Memory then stays as bounded as with the automatic passes.
``RIGIDROT_GC_SCHEDULE=0`` leaves the automatic passes alone.
"""

import gc
import time

from rigidrot_ros.runtime import switches

__all__ = ['Freezer', 'FREEZE_AFTER_S', 'enabled', 'Passes', 'STEP', 'LATE_STEP',
           'SAFETY_THRESHOLD', 'scheduled']

#: Seconds into a run at which the objects made by its start are frozen too.
FREEZE_AFTER_S = 2.0
#: Allocations pending (generation 0's count) at which :meth:`Passes.poll` runs a pass.
STEP = 700
#: Allocations pending at which :meth:`Passes.poll` runs a pass even in a call that did
#: not end early.
LATE_STEP = 3 * STEP
#: Generation 0's automatic threshold while :class:`Passes` runs them (a net only).
SAFETY_THRESHOLD = 20 * STEP


def scheduled():
    """Whether the node runs the young passes itself (``RIGIDROT_GC_SCHEDULE=0``: not)."""
    return switches.gc_schedule()


def enabled():
    """Whether the node freezes its heap (``RIGIDROT_GC_FREEZE=0``: it does not)."""
    return switches.gc_freeze()


class Freezer:
    """Freeze the heap at start-up and once more :data:`FREEZE_AFTER_S` s into the first run.

    ``on``: whether to act at all (default: :func:`enabled`); ``clock``: seconds, monotonic.
    :attr:`freezes` counts the freezes made.
    """

    def __init__(self, on=None, clock=time.monotonic):
        self.on = enabled() if on is None else bool(on)
        self._clock = clock
        self._due = None
        self._armed = False
        self.freezes = 0

    def start(self):
        """Collect everything once, then freeze what is left (before any publishing)."""
        if not self.on:
            return
        gc.collect()
        self._freeze()

    def arm(self):
        """Freeze once more :data:`FREEZE_AFTER_S` s from now if this is the first run.

        Later runs (after ``~/reset``) are not frozen: their cyclic garbage must stay
        collectable.
        """
        if self.on and not self._armed:
            self._armed = True
            self._due = self._clock() + FREEZE_AFTER_S

    def poll(self):
        """Freeze if the armed time has come (O(1): no collection); True if it did."""
        if self._due is None or self._clock() < self._due:
            return False
        self._due = None
        self._freeze()
        return True

    def _freeze(self):
        gc.freeze()
        self.freezes += 1


class Passes:
    """The collector's passes run at known moments (:meth:`poll`), not at any allocation.

    ``on``: whether to act at all (default: :func:`scheduled`). :meth:`start` raises the
    automatic threshold of generation 0 to :data:`SAFETY_THRESHOLD` (the older ones are
    kept), :meth:`stop` puts back what it found. :attr:`passes` counts the passes run per
    generation.
    """

    def __init__(self, on=None):
        self.on = scheduled() if on is None else bool(on)
        self._saved = None
        self.passes = [0, 0, 0]

    @property
    def active(self):
        """True between :meth:`start` and :meth:`stop` (when on)."""
        return self._saved is not None

    def start(self):
        """Take generation 0's passes over (idempotent)."""
        if not self.on or self._saved is not None:
            return
        self._saved = gc.get_threshold()
        gc.set_threshold(max(SAFETY_THRESHOLD, self._saved[0]), *self._saved[1:])

    def stop(self):
        """Give them back: the thresholds found by :meth:`start` (idempotent)."""
        if self._saved is None:
            return
        if gc.get_threshold()[0] == max(SAFETY_THRESHOLD, self._saved[0]):
            gc.set_threshold(*self._saved)      # unless someone else set them since
        self._saved = None

    def poll(self, early=True):
        """Run the pass that is due, if :data:`STEP` allocations are pending; its generation.

        ``early``: the caller has room now (the next sample is a good part of a period
        away); else the pass runs only once :data:`LATE_STEP` are pending (a stream whose
        calls never end early, e.g. 4 kHz: the pass stays young, at the end of a call).
        None if no pass was due (or not started). The generation is the one the
        interpreter would collect: the oldest whose count reached its threshold.
        """
        if self._saved is None:
            return None
        c0, c1, c2 = gc.get_count()
        if c0 < (STEP if early else LATE_STEP):
            return None
        _, t1, t2 = self._saved
        gen = 2 if c2 > t2 else 1 if c1 > t1 else 0      # as the interpreter chooses
        gc.collect(gen)
        self.passes[gen] += 1
        return gen
