"""One sensor of a run on the node's schedule: grid, timing, look-ahead (no rclpy).

:class:`Sensor` serves a sensor output of the table (:class:`rigidrot_ros.run.output.SensorOutput`)
on the node's schedule: its grid and timing model (:class:`~rigidrot_ros.run.scheduler.Track`),
its samples read ahead in blocks by its kind (:meth:`SensorOutput.sample`, through
:class:`~rigidrot_ros.runtime.ahead.SensorAhead`), their messages encoded a batch at a
time by its kind (:meth:`Output.build`: CDR, one call per topic), the samples due at a
scheduler call, and its latency and drop counts for the diagnostics. The schedule
(:mod:`rigidrot_ros.run.schedule`) creates one per sensor at a run's ``t_start``.
"""

import time

from rigidrot_ros.run import scheduler
from rigidrot_ros.run.output import scene_time
from rigidrot_ros.run.settings import SAMPLE_BUDGET_S
from rigidrot_ros.runtime import diagnostics
from rigidrot_ros.runtime.ahead import AHEAD_MIN, SensorAhead

__all__ = ['Sensor', 'PASS_OVER_MAX_S']

#: Samples a skip leaves out (a backlog beyond a second: the process was held, or the
#: clock jumped) are still read, up to this many seconds of them, and not published: a
#: sensor's noise and its timing draws run on in sample order, so that the samples after
#: the skip are the ones offline generation gives (byte for byte). Beyond it (a clock
#: jump of minutes), or with the look-ahead off (each read alone would cost more than the
#: backlog), they are not read, and the samples after differ from generation's.
PASS_OVER_MAX_S = 60.0


class Sensor:
    """One sensor output of a run on the node's schedule: grid, timing, look-ahead.

    A sample is ``(true_ns, stamp_ns, keep, error, (block, row))``: its grid time, the
    stamp its messages carry (:meth:`Track.marks`), whether it is published (not
    dropped), the exception that kept it from being read (else None), and where its
    values are (a :class:`rigidrot_ros.run.output.Block` and its row). Blocks are read
    with the node's per-read budget (:data:`SAMPLE_BUDGET_S`).

    Parameters
    ----------
    output : SensorOutput
        The run's output of this sensor (its model, rate and topics).
    t_start_ns : int
        The run's scene time 0 (the origin of the sensor's grid).
    setup : RunSetup
        The run.
    counters : rigidrot_ros.runtime.diagnostics.Counters
        Sample counts and read times go there.
    frames : callable
        Returns ``(frame_id, body_frame_id)`` now (they may change at run time).
    worker : BatchWorker, optional
        Where the look-ahead's batches run.
    """

    def __init__(self, output, t_start_ns, setup, counters, frames, worker=None):
        self.output, self.rank = output, output.rank
        self.setup, self.counters, self.frames = setup, counters, frames
        self.t_start_ns = t_start_ns
        self.track = scheduler.Track(output.name, t_start_ns, output.rate, output.first,
                                     scheduler.timing_of(setup.values, output.name))
        self.dropped = 0
        self.pending = []               # grid times (ns) published by this call
        self.latencies = []             # publication - grid time, ns, this window
        self.ahead = SensorAhead(self._read, lambda k: self._read(range(k, k + 1))[0][0],
                                 1.0 / output.rate, output.first, build=self._build_batch,
                                 worker=worker)

    # -- reading and building ----------------------------------------------------------------
    def _scene(self, ns):
        return scene_time(ns, self.t_start_ns, self.setup.time_scale)

    def _read(self, ks):
        """Read the samples ``ks`` (a range): ``(samples, block)`` for the look-ahead."""
        c0 = time.perf_counter()
        block = self.output.sample(self.track, ks, self.setup.time_scale,
                                   budget=SAMPLE_BUDGET_S)
        per = (time.perf_counter() - c0) / max(len(ks), 1)
        for _ in ks:
            self.counters.sampled(self.output.name, per)
        samples = [(t, s, kp, e, (block, i)) for i, (t, s, kp, e) in enumerate(zip(
            block.true_ns.tolist(), block.stamps_ns.tolist(), block.keep.tolist(),
            block.errors))]
        return samples, block

    def _build_batch(self, start, block):
        """Encode a batch's messages (CDR), for the samples that were read and are kept."""
        out = [None] * len(block)
        ok = block.published()
        if len(ok):
            stamps, cols = block.rows(ok)
            for i, built in zip(ok.tolist(), self.output.build(stamps, cols, self.frames())):
                out[i] = built
        return out

    def build_one(self, sample):
        """Return the ``[(topic, bytes), ...]`` of one sample read now."""
        block, i = sample[4]
        stamps, cols = block.rows([i])
        return self.output.build(stamps, cols, self.frames())[0]

    # -- publishing --------------------------------------------------------------------------
    def due(self, now_ns, groups, failed):
        """Append the samples due at ``now_ns`` to ``groups`` (the node's scheduler call).

        Each as ``(grid ns, rank, [(topic, bytes), ...])``; a sample that failed goes to
        ``failed(scene time s, exception)``, a dropped one is counted.
        """
        ks, skipped = self.track.due(now_ns)
        self.counters.skipped += skipped
        if skipped:
            self._pass_over(range(ks.start - skipped, ks.start), ks.stop - 1)
        elif len(ks) > 1:
            self.ahead.fill_to(ks.start, ks.stop - 1)     # a catch-up: as one batch
        for k in ks:
            try:
                sample, built = self.ahead.get(k)
            except Exception as exc:    # noqa: B902 - a sample that cannot be read: report
                failed(self._scene(self.track.stamp_ns(k)), exc)
                continue
            true_ns, _, keep, err, _ = sample
            if err is not None:
                failed(self._scene(true_ns), err)
                continue
            if not keep:
                self.dropped += 1
                continue
            groups.append((true_ns, self.rank, built or self.build_one(sample)))
            self.pending.append(true_ns)

    def _pass_over(self, passed, newest):
        """Read the skipped samples ``passed`` (a range) and let them go.

        Up to :data:`PASS_OVER_MAX_S` of them, with the look-ahead on; ``newest`` is the
        last sample due, read in the same batch.
        """
        if self.ahead.size < AHEAD_MIN or len(passed) > PASS_OVER_MAX_S * self.output.rate:
            return
        self.ahead.fill_to(passed.start, newest)        # with the samples due: one batch
        for k in passed:
            try:
                self.ahead.get(k)
            except Exception:   # noqa: B902 - a sample that cannot be read is left out anyway
                pass

    # -- accounting --------------------------------------------------------------------------
    def published(self, pub_ns):
        """Note the publication time of the samples this call published."""
        if self.pending:
            self.latencies += [pub_ns - t for t in self.pending]
            self.pending = []

    def take_latencies(self):
        """Return ``(latencies ns, dropped)`` of this window (moved out), and start the next."""
        out, self.latencies = (self.latencies, self.dropped), []
        return out

    @staticmethod
    def report_of(taken):
        """Return ``(latency mean, p99, max s, dropped)`` of :meth:`take_latencies`."""
        latencies, dropped = taken
        return diagnostics.summary(latencies, 1e-9) + (dropped,)
