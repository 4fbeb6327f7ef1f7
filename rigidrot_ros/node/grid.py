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
  :func:`due` says which samples a callback at ``now_ns`` owes.
"""

import math

__all__ = ['stamp_ns', 'index', 'anchor_ns', 'due', 'BACKLOG_MIN']

#: A sensor backlog of more than ``max(BACKLOG_MIN, rate)`` samples (over a second: a clock
#: jump) restarts the sensor's chain at the newest sample.
BACKLOG_MIN = 10


def stamp_ns(origin_ns, rate, k):
    """Return the stamp (ns) of index ``k`` on the grid ``origin_ns + k / rate`` (Hz)."""
    return origin_ns + round(k * 1e9 / rate)


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
