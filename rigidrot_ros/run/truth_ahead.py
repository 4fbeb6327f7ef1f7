"""The truth of a run on the node's schedule: its tick grid, look-ahead and messages (no rclpy).

:class:`TruthAhead` serves the table's truth outputs (:mod:`rigidrot_ros.run.truth_outputs`:
attitude and angular_velocity, and transform, odom, markers where on) at the truth's
ticks: tick j of a grid anchored at ``g`` is stamped ``g + j / publish_rate``
(:mod:`rigidrot_ros.run.grid`) and holds the scene at ``(stamp - t_start) * time_scale``.
The coming ticks' samples are evaluated ahead in batches
(:class:`~rigidrot_ros.runtime.ahead.Lookahead`: one ``solution.at`` a batch) and
their messages encoded there by the kinds (:meth:`Output.build`, CDR, one call per topic),
so a tick takes its bytes from the buffer.
"""

import time

import numpy as np

from rigidrot_ros.run import grid
from rigidrot_ros.run.output import scene_time
from rigidrot_ros.runtime.ahead import Lookahead

__all__ = ['TruthAhead']


class TruthAhead:
    """The truth outputs of a run at the truth's ticks: grid, look-ahead, due ticks.

    Parameters
    ----------
    setup : RunSetup
        The run.
    outputs : list of Output
        The run's outputs on the truth's grid, in rank order.
    counters : rigidrot_ros.runtime.diagnostics.Counters
        Ticks published, their latencies and evaluation times go there.
    frames : callable
        Returns ``(frame_id, body_frame_id)`` now.
    worker : BatchWorker, optional
        Where the look-ahead's batches run.

    Attributes
    ----------
    grid0 : int or None
        Clock ns of the grid's index 0 (None: the next call anchors a new grid).
    k : int
        The last tick index published on this grid (-1: none).
    ahead : Lookahead or None
        The grid's look-ahead (None before the first anchor).
    last_sample : tuple or None
        ``(scene time s, error bound rad)`` of the last tick published.
    """

    def __init__(self, setup, outputs, counters, frames, worker=None):
        self.setup, self.outputs = setup, outputs
        self.counters, self.frames, self.worker = counters, frames, worker
        self.grid0, self.k, self.ahead, self.last_sample = None, -1, None, None
        self.rate_hz = float(setup.publish_rate)

    def retime(self, rate):
        """Take a new tick rate (Hz): the next call anchors a new grid (same ``t_start``)."""
        self.rate_hz = float(rate)
        self.grid0 = None

    def anchor(self, g0, t_start_ns):
        """Start a grid at clock ``g0`` (ns) of a run whose scene time 0 is ``t_start_ns``."""
        self.grid0, self.k = g0, -1
        # the grid, run start and scale are bound now: a batch may run in the worker thread
        hz, scale = self.rate_hz, self.setup.time_scale
        self.ahead = Lookahead(
            self.setup.solution, lambda k: scene_time(grid.stamp_ns(g0, hz, k), t_start_ns,
                                                      scale),
            1.0 / hz, build=lambda start, data: self._build(start, data, g0, hz),
            worker=self.worker)

    def _build(self, start, data, g0, hz):
        """Encode the truth outputs of a batch of ticks to come: each tick's items.

        ``data``: the batch's ``(q, omega, bound)`` arrays; ``g0``, ``hz``: the grid.
        """
        q, w, e = data
        stamps = grid.stamps_ns(g0, hz, range(start, start + len(q)))
        cols = {'q': q, 'w': w, 'e': e}
        per_output = [o.build(stamps, cols, self.frames()) for o in self.outputs]
        return [[item for items in tick for item in items] for tick in zip(*per_output)]

    def stamp_ns(self, k):
        """Return the stamp (ns) of tick k of the current grid."""
        return grid.stamp_ns(self.grid0, self.rate_hz, k)

    def publish_due(self, due, now_ns, t_start_ns, groups, failed, paced=False):
        """Append the ticks ``due`` (``(first, newest, missed)``) to ``groups``.

        A late call publishes every tick it owes (counted ``late``); ``missed`` ticks (a
        clock jump) are counted. Each tick as ``(stamp ns, 0, [(topic, bytes), ...])``; a
        tick that cannot be evaluated goes to ``failed(scene time s, exception)`` and ends
        the call's ticks. Returns ``(ticks appended, of them evaluated now)``.
        ``paced``: the call runs ahead of its publication (:mod:`rigidrot_ros.runtime.pacer`);
        the ticks' latencies are noted at publication (:meth:`Schedule.note_published`),
        not taken now, and so are the late ones.
        """
        first, k, missed = due
        st = self.counters
        st.missed += missed
        if k > first and not paced:     # paced: counted at publication (note_published)
            st.late += 1
        m0, n0 = self.ahead.misses, len(groups)
        self.ahead.fill_to(first, k)        # a catch-up: the owed ticks as one batch
        for j in range(first, k + 1):
            self.k = j
            stamp_ns = self.stamp_ns(j)
            if not paced:               # paced: noted at publication
                st.latencies.append(now_ns - stamp_ns)
            c0 = time.perf_counter()
            t = scene_time(stamp_ns, t_start_ns, self.setup.time_scale)
            try:
                sample, built = self.ahead.get(j)
            except Exception as exc:    # noqa: B902 - PrecisionError, or anything: report
                failed(t, exc)
                break
            st.times.append(time.perf_counter() - c0)
            if built is None:
                built = self._build(j, tuple(np.array([x]) for x in sample),
                                    self.grid0, self.rate_hz)[0]
            groups.append((stamp_ns, 0, built))
            st.published += 1
            self.last_sample = (t, sample[2])
        return len(groups) - n0, self.ahead.misses - m0
