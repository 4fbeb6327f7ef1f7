"""Tick grids on the node clock: anchor, index, stamp (no rclpy; integer nanoseconds).

A grid is ``origin_ns + k / rate``: index k is stamped :func:`stamp_ns` (one rounding, so
every stamp is exact in ns and the same wherever it is computed, node or offline
generator).

- The truth: tick k is stamped ``g + k / publish_rate``, where ``g``, the anchor, is the
  scheduled time of the timer call that started the grid (:func:`anchor_ns`). At start-up
  and after ``~/reset`` the anchor is ``t_start``, the run's scene time 0. A change of
  ``publish_rate`` (or a clock that went back) anchors a new grid at the next call of the
  new timer, with the same ``t_start``: from then on tick j is stamped ``g' + j / rate'``
  and ``g' - t_start`` need not be a multiple of either period. In every case the sample
  is taken at scene time ``t = (stamp - t_start) * time_scale``.
- A sensor: sample k is stamped ``t_start + k / rate`` for the whole run (its own rate,
  unaffected by ``publish_rate``), so a seed reproduces its stream bit for bit;
  :func:`due` says which samples a callback at ``now_ns`` owes (:func:`truth_due`: which
  truth ticks).
"""

import math

import numpy as np

__all__ = ['stamp_ns', 'stamps_ns', 'index', 'anchor_ns', 'due', 'truth_due', 'BACKLOG_MIN',
           'NEW_GRID']

#: A sensor backlog of more than ``max(BACKLOG_MIN, rate)`` samples (over a second: a clock
#: jump) restarts the sensor's chain at the newest sample.
BACKLOG_MIN = 10
#: :func:`truth_due`'s answer when the clock went back before the last tick published.
NEW_GRID = 'new grid'


def stamp_ns(origin_ns, rate, k):
    """Return the stamp (ns) of index ``k`` on the grid ``origin_ns + k / rate`` (Hz)."""
    return origin_ns + round(k * 1e9 / rate)


def stamps_ns(origin_ns, rate, ks):
    """Return :func:`stamp_ns` of the indices ``ks`` (a range) as an int64 array, vectorised.

    ``origin + round(k * 1e9 / rate)``: the same float64 product and quotient, and
    ``np.rint`` rounds half to even as Python's ``round`` does, so every stamp is the
    scalar function's (``test/run/test_generate.py`` compares them index by index).
    """
    k = np.arange(ks.start, ks.stop, dtype=np.int64)
    return int(origin_ns) + np.rint(k * 1e9 / rate).astype(np.int64)


def index(origin_ns, rate, now_ns):
    """Return the last k whose :func:`stamp_ns` is at or before ``now_ns`` (may be < 0)."""
    k = math.floor((now_ns - origin_ns) * rate * 1e-9)
    while stamp_ns(origin_ns, rate, k + 1) <= now_ns:
        k += 1
    while stamp_ns(origin_ns, rate, k) > now_ns:
        k -= 1
    return k


def anchor_ns(now_ns, until_next_ns, period_ns):
    """Return the scheduled time (ns) of the timer call being served at ``now_ns``.

    rclpy keeps a timer's calls on the schedule ``created + k * period``; in a callback,
    ``now + time_until_next_call() - period`` is the scheduled time of the call being
    served (a few µs early: the two clock reads), so every later call, however late within
    its period, falls in its own grid slot. ``until_next_ns`` None, or outside
    ``[0, period_ns]``, gives ``now_ns``; a clock (sim time) starts at 0, so neither does
    the anchor.
    """
    if until_next_ns is not None and 0 <= until_next_ns <= period_ns:
        return max(0, now_ns + until_next_ns - period_ns)
    return now_ns


def due(origin_ns, rate, last, now_ns):
    """Return ``(first, newest, skipped)``: the sensor samples a callback at ``now_ns`` owes.

    ``last`` is the last index published; samples ``first..newest`` are due (none if
    ``newest < first``). A backlog beyond ``max(BACKLOG_MIN, int(rate))`` samples (a clock
    jump) restarts the chain at the newest: ``skipped`` samples are dropped and counted.
    """
    k = max(0, index(origin_ns, rate, now_ns))
    first, skipped = last + 1, 0
    if k - last > max(BACKLOG_MIN, int(rate)):
        skipped, first = k - last - 1, k
    return first, k, skipped


def truth_due(origin_ns, rate, last, now_ns):
    """Return ``(first, newest, missed)``: the truth ticks a scheduler call at ``now_ns`` owes.

    ``last`` is the last tick published (-1: none yet). Every tick from ``last + 1`` to
    the newest at or before ``now_ns`` is owed (a call that comes late publishes the ticks
    it owes); a backlog of ``max(BACKLOG_MIN, rate)`` ticks or more (a clock jump) is
    skipped but for the newest, and counted in ``missed``. None if the newest tick is
    ``last`` or ``last - 1`` (published already); :data:`NEW_GRID` if the clock went
    back further (the caller anchors a new grid and publishes its tick 0).
    """
    k = index(origin_ns, rate, now_ns)
    if k <= last:
        return None if k >= last - 1 else NEW_GRID
    first, missed = last + 1, 0
    if k - first >= max(BACKLOG_MIN, rate):
        missed, first = k - first, k
    return first, k, missed
