"""One sensor stream of a run on the node's schedule: grid, timing, look-ahead (no rclpy).

:class:`Sensor` serves every sensor the node publishes (:mod:`~rigidrot_ros.run.streams`):
its grid and timing model (:class:`~rigidrot_ros.run.scheduler.Track`), its samples read
ahead in blocks (:class:`~rigidrot_ros.runtime.lookahead.SensorAhead`), their messages
serialized a batch at a time (:mod:`rigidrot_ros.msgs.cdr`), the samples due at a scheduler
call, and its latency and drop counts for the diagnostics. The node only creates one per
stream at a run's ``t_start`` and hands it its publishers.
"""

import time

import numpy as np

from rigidrot_ros.msgs import cdr
from rigidrot_ros.run import scheduler
from rigidrot_ros.run.settings import SAMPLE_BUDGET_S
from rigidrot_ros.run.streams import ImuStream, MagStream, scene_time, StarTrackerStream
from rigidrot_ros.runtime import diagnostics
from rigidrot_ros.runtime.lookahead import SensorAhead

__all__ = ['Sensor']


class Sensor:
    """One sensor stream of a run on the node's schedule: grid, timing, look-ahead.

    A sample is ``(true_ns, stamp_ns, keep, error, row)``: its grid time, the stamp its
    messages carry (:meth:`Track.marks`), whether it is published (not dropped), the
    exception that kept it from being read (else None), and its values (a tuple, one
    entry per array of the batch). The imu is read a block at a time: the gyro by
    :meth:`Gyro.read_many` (bit for bit the per-sample reads) and, where there is one,
    the accelerometer over the same intervals by :meth:`Accelerometer.read_many`
    (:meth:`_read_accel`); the star tracker and the magnetometer sample by sample. Each
    batch is serialized by
    :mod:`rigidrot_ros.msgs.cdr`, one call per topic, and every one of these streams
    carries its timing model (stamps jittered and offset, samples dropped, latency). A
    stream of another kind is read and built per sample by its own ``messages`` (and
    stamped by it: its stamp is not jittered nor offset).
    """

    def __init__(self, stream, t_start_ns, rank, setup, counters, frames, worker=None):
        self.stream, self.rank = stream, rank
        self.setup, self.counters, self.frames = setup, counters, frames
        self.t_start_ns = t_start_ns
        self.track = scheduler.Track(stream.name, t_start_ns, stream.rate, stream.first,
                                     scheduler.timing_of(setup.values, stream.name))
        self.dropped = 0
        self.pending = []               # grid times (ns) published by this call
        self.latencies = []             # publication - grid time, ns, this window
        kind = type(stream)
        if kind is ImuStream and hasattr(stream.model, 'read_many'):
            self._read, self._build = self._read_imu, self._build_imu
        elif kind is StarTrackerStream:
            self._read, self._build = self._read_star, self._build_star
        elif kind is MagStream:
            self._read, self._build = self._read_mag, self._build_mag
        else:
            self._read, self._build = self._read_generic, None
        self.types = dict(stream.topics)
        self.ahead = SensorAhead(self._read, lambda k: self._read(range(k, k + 1))[0][0],
                                 1.0 / stream.rate, stream.first,
                                 build=self._build_batch if self._build else None,
                                 worker=worker)

    # -- reading -----------------------------------------------------------------------------
    def _scene(self, ns):
        return scene_time(ns, self.t_start_ns, self.setup.time_scale)

    def _samples(self, ks, rows, errors):
        stamps, keep = self.track.marks(ks)
        true = [self.track.stamp_ns(k) for k in ks]
        return [(t, int(s), bool(kp), e, r)
                for t, s, kp, e, r in zip(true, stamps.tolist(), keep.tolist(), errors, rows)]

    def _read_imu(self, ks):
        """Read the imu over the intervals of ``ks``: gyro, then accelerometer (if any).

        The gyro as one block (per sample if the block fails), the accelerometer over the
        same intervals (:meth:`_read_accel`).
        """
        c0 = time.perf_counter()
        ends = np.array([self._scene(self.track.stamp_ns(k))
                         for k in range(ks.start - 1, ks.stop)])
        model, n = self.stream.model, len(ks)
        try:
            b = model.read_many(ends, budget=SAMPLE_BUDGET_S)
            blocks, errors = [b], [None] * n
        except ValueError:              # one interval too hard: each on its own
            blocks, errors = [], []
            for i in range(n):
                try:
                    blocks.append(model.read_many(ends[i:i + 2], budget=SAMPLE_BUDGET_S))
                    errors.append(None)
                except ValueError as exc:
                    errors.append(exc)
        rows = []
        for block in blocks:
            self.stream.bound = max(self.stream.bound, float(block.delta_angle_bound.max()),
                                    float(block.delta_rotation_bound.max()))
            rows += list(zip(block.omega, block.variance, block.delta_angle,
                             block.delta_rotation))
        rows = iter(rows)
        rows = [None if e is not None else next(rows) for e in errors]
        if self.stream.accel is not None:
            rows, errors = self._read_accel(ends, rows, errors)
        self._count(n, c0)
        out = self._samples(ks, rows, errors)
        return out, out

    def _read_accel(self, ends, rows, errors):
        """Append the accelerometer's ``(specific force, variance, delta_velocity)`` to rows.

        Over the intervals ``[ends[i], ends[i + 1]]`` whose gyro read succeeded, in order,
        as :meth:`ImuStream.messages` reads it after the gyro: one
        :meth:`Accelerometer.read_many` block (bit for bit the per-sample reads), else
        interval by interval (a failed gyro interval leaves the accelerometer's noise
        stream untouched, as there; a failed accelerometer read makes the sample an error).
        """
        acc = self.stream.accel
        if all(e is None for e in errors):
            try:
                b = acc.read_many(ends, budget=SAMPLE_BUDGET_S)
                return [r + a for r, a in zip(rows, zip(b.specific_force, b.variance,
                                                        b.delta_velocity))], errors
            except ValueError:          # one interval too hard: each on its own
                pass
        out_rows, out_errors = [], []
        for i, (row, err) in enumerate(zip(rows, errors)):
            if err is None:
                try:
                    b = acc.read_many(ends[i:i + 2], budget=SAMPLE_BUDGET_S)
                    row = row + (b.specific_force[0], b.variance[0], b.delta_velocity[0])
                except Exception as exc:    # noqa: B902 - reported when the sample is due
                    row, err = None, exc
            out_rows.append(row)
            out_errors.append(err)
        return out_rows, out_errors

    def _read_each(self, ks, read):
        """Read the samples ``ks`` one by one with ``read(k) -> row``, errors kept per sample."""
        c0 = time.perf_counter()
        rows, errors = [], []
        for k in ks:
            try:
                rows.append(read(k))
                errors.append(None)
            except Exception as exc:    # noqa: B902 - reported when the sample is due
                rows.append(None)
                errors.append(exc)
        self._count(len(ks), c0)
        out = self._samples(ks, rows, errors)
        return out, out

    def _read_star(self, ks):
        def read(k):
            r = self.stream.model.read(self._scene(self.track.stamp_ns(k)))
            return r.quaternion, r.covariance
        return self._read_each(ks, read)

    def _read_mag(self, ks):
        dt = self.setup.time_scale / self.stream.rate     # as MagStream.messages

        def read(k):
            r = self.stream.model.read(self._scene(self.track.stamp_ns(k)), dt)
            return r.field, r.covariance
        return self._read_each(ks, read)

    def _read_generic(self, ks):
        return self._read_each(ks, lambda k: self.stream.messages(
            k, self.t_start_ns, self.setup.time_scale, self.frames()))

    def _count(self, n, c0):
        per = (time.perf_counter() - c0) / max(n, 1)
        for _ in range(n):
            self.counters.sampled(self.stream.name, per)

    # -- building ----------------------------------------------------------------------------
    def _build_batch(self, start, data):
        """Build a batch's messages (cdr), for the samples that were read and are kept."""
        samples = data
        ok = [i for i, s in enumerate(samples) if s[3] is None and s[2]]
        out = [None] * len(samples)
        if ok:
            built = self._build([samples[i][1] for i in ok], [samples[i][4] for i in ok])
            for i, b in zip(ok, built):
                out[i] = b
        return out

    def build_one(self, sample):
        """Return the ``(topic, class, raw)`` items of one sample read now."""
        if self._build is None:
            return [(topic, msg, None) for topic, msg in sample[4]]
        return self._build([sample[1]], [sample[4]])[0]

    def _build_imu(self, stamps, rows):
        body = self.frames()[1]
        cols = [np.array(c) for c in zip(*rows)]
        w, var, da, dr = cols[:4]
        accel = len(cols) > 4           # with the accelerometer's three columns
        if accel:
            f, avar, dv = cols[4:]
            imu = cdr.imu(stamps, w, var, body, f, avar).tolist()
        else:
            imu = cdr.imu(stamps, w, var, body).tolist()
        cols = [imu, cdr.vector(stamps, da, body).tolist(),
                cdr.vector(stamps, dr, body).tolist()]
        topics = ['imu', 'delta_angle', 'delta_rotation']
        if accel:
            cols.append(cdr.vector(stamps, dv, body).tolist())
            topics.append('delta_velocity')
        classes = [self.types[name] for name in topics]
        return [list(zip(topics, classes, raws)) for raws in zip(*cols)]

    def _build_star(self, stamps, rows):
        q, cov = (np.array(c) for c in zip(*rows))
        raw = cdr.star_tracker(stamps, q, cov, self.frames()[0]).tolist()
        cls = self.types['star_tracker']
        return [[('star_tracker', cls, x)] for x in raw]

    def _build_mag(self, stamps, rows):
        f, cov = (np.array(c) for c in zip(*rows))
        raw = cdr.magnetic_field(stamps, f, cov, self.frames()[1]).tolist()
        cls = self.types['mag']
        return [[('mag', cls, x)] for x in raw]

    # -- publishing --------------------------------------------------------------------------
    def due(self, now_ns, groups, pubs, failed):
        """Append the samples due at ``now_ns`` to ``groups`` (the node's scheduler call).

        Each as ``(grid ns, rank, [(publisher, class, raw), ...])``, publishers taken from
        ``pubs`` by topic; a sample that failed goes to ``failed(scene time s, exception)``,
        a dropped one is counted.
        """
        ks, skipped = self.track.due(now_ns)
        self.counters.skipped += skipped
        if len(ks) > 1:
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
            if built is None:
                built = self.build_one(sample)
            groups.append((true_ns, self.rank,
                           [(pubs[topic], cls, raw) for topic, cls, raw in built]))
            self.pending.append(true_ns)

    # -- accounting --------------------------------------------------------------------------
    def published(self, pub_ns, counters):
        """Note the publication time of the samples this call published."""
        if self.pending:
            self.latencies += [pub_ns - t for t in self.pending]
            self.pending = []

    def report(self):
        """Return ``(latency mean, p99, max s, dropped)`` of this window, and start the next."""
        return self.report_of(self.take_latencies())

    def take_latencies(self):
        """Return ``(latencies ns, dropped)`` of this window (moved out), and start the next."""
        out, self.latencies = (self.latencies, self.dropped), []
        return out

    @staticmethod
    def report_of(taken):
        """Return ``(latency mean, p99, max s, dropped)`` of :meth:`take_latencies`."""
        latencies, dropped = taken
        return diagnostics.summary(latencies, 1e-9) + (dropped,)
