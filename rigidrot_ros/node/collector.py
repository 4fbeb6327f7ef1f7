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
- :meth:`Freezer.arm` at each run's start and :meth:`Freezer.poll` from the scheduler:
  :data:`FREEZE_AFTER_S` seconds into a run (its first batches, the compiled kernels and
  the caches they fill), one more freeze. A freeze is a list splice (O(1)), so it costs
  nothing in a scheduler call; a full collection would cost the 71 ms above, so none is
  run there: whatever cyclic garbage is alive in that instant stays (bounded: once per
  run).

The full passes after that walk only the objects made since, and take what the young
passes take. ``RIGIDROT_GC_FREEZE=0`` turns it off (for measuring the two).
"""

import gc
import os
import time

__all__ = ['Freezer', 'FREEZE_AFTER_S', 'enabled']

#: Seconds into a run at which the objects made by its start are frozen too.
FREEZE_AFTER_S = 2.0


def enabled():
    """Whether the node freezes its heap (``RIGIDROT_GC_FREEZE=0``: it does not)."""
    return os.environ.get('RIGIDROT_GC_FREEZE', '1').strip() != '0'


class Freezer:
    """Freeze the heap at start-up and once per run after :data:`FREEZE_AFTER_S` s.

    ``on``: whether to act at all (default: :func:`enabled`); ``clock``: seconds, monotonic.
    :attr:`freezes` counts the freezes made.
    """

    def __init__(self, on=None, clock=time.monotonic):
        self.on = enabled() if on is None else bool(on)
        self._clock = clock
        self._due = None
        self.freezes = 0

    def start(self):
        """Collect everything once, then freeze what is left (before any publishing)."""
        if not self.on:
            return
        gc.collect()
        self._freeze()

    def arm(self):
        """Freeze once more :data:`FREEZE_AFTER_S` s from now (a run started)."""
        if self.on:
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
