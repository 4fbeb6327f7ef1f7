"""Sensor streams: each sensor's samples on its own clock grid, as messages (no rclpy).

A :class:`SensorStream` owns one sensor of a run: its rate, the last sample index it
published, the topics it publishes (relative names and message classes) and how sample k
becomes messages (:meth:`SensorStream.messages`). Sample k is stamped
``t_start + k / rate`` (:func:`rigidrot_ros.node.grid.stamp_ns`) and taken at scene time
``(stamp - t_start) * time_scale``; every message of a sample shares its stamp. The node
calls :meth:`SensorStream.take` from one timer per stream and publishes what it returns; the
offline generator calls :meth:`SensorStream.messages` for k = first, first + 1, ...

A new sensor (an accelerometer, a magnetometer) is one more subclass with ``name``,
``topics`` and ``messages``, and one more line in :func:`make_streams`.
"""

import time

from geometry_msgs.msg import PoseWithCovarianceStamped, Vector3Stamped
from sensor_msgs.msg import Imu

from rigidrot_ros import settings
from rigidrot_ros.io import messages as msgs
from rigidrot_ros.node import grid

__all__ = ['SensorStream', 'ImuStream', 'StarTrackerStream', 'make_streams', 'STREAMS',
           'scene_time']


def scene_time(stamp_ns, t_start_ns, time_scale):
    """Return the scene time (s) of a stamp: ``(stamp - t_start) * time_scale``."""
    return (stamp_ns - t_start_ns) * 1e-9 * time_scale


class SensorStream:
    """One sensor's samples k = :attr:`first`, ... on the grid ``t_start + k / rate``.

    Attributes
    ----------
    name : str
        The sensor's name: its parameters' prefix and its diagnostics keys' prefix.
    topics : tuple
        ``((topic, message class), ...)`` it publishes, relative names.
    first : int
        The first sample's index.
    rate : float
        Samples per second of clock time, Hz.
    model : object
        The sensor model of the run (:class:`rigidrot_ros.sensors.Gyro`, ...).
    last : int
        The last sample index taken (``first - 1`` before any).
    bound : float
        The largest error bound of this run's samples, rad (0.0 where none is stated).
    """

    name = ''
    topics = ()
    first = 0

    def __init__(self, rate, model):
        self.rate = float(rate)
        self.model = model
        self.last = self.first - 1
        self.bound = 0.0

    def stamp_ns(self, t_start_ns, k):
        """Return the stamp (ns) of sample k."""
        return grid.stamp_ns(t_start_ns, self.rate, k)

    def messages(self, k, t_start_ns, time_scale, frames):
        """Return ``[(topic, msg), ...]`` of sample k (raises if it cannot be evaluated).

        ``frames`` is ``(frame_id, body_frame_id)``.
        """
        raise NotImplementedError

    def take(self, t_start_ns, now_ns, time_scale, frames, counters, on_error):
        """Return the messages of every sample due at ``now_ns``, oldest first.

        At most ``settings.SAMPLE_BUDGET_S`` of work: the rest stays due for the next
        call. A sample that fails is passed to ``on_error(t, exc)`` and skipped;
        ``counters`` (:class:`rigidrot_ros.node.diagnostics.Counters`) counts samples,
        their build times and the samples a clock jump skipped.
        """
        first, newest, skipped = grid.due(t_start_ns, self.rate, self.last, now_ns)
        counters.skipped += skipped
        items = []
        c0 = time.perf_counter()
        for k in range(first, newest + 1):
            c_sample = time.perf_counter()
            if c_sample - c0 > settings.SAMPLE_BUDGET_S:
                newest = k - 1          # the rest stays due: the next callback goes on
                break
            try:
                items += self.messages(k, t_start_ns, time_scale, frames)
            except Exception as exc:    # PrecisionError or anything else: report it
                on_error(scene_time(self.stamp_ns(t_start_ns, k), t_start_ns, time_scale),
                         exc)
                continue
            counters.sampled(self.name, time.perf_counter() - c_sample)
        self.last = max(self.last, newest)
        return items


class ImuStream(SensorStream):
    """The gyro: sensor_msgs/Imu, and the exact delta_angle and delta_rotation, in B.

    Sample k covers the interval from sample k - 1 to k (so k starts at 1: [0, 1 / rate]).
    """

    name = 'imu'
    topics = (('imu', Imu), ('delta_angle', Vector3Stamped), ('delta_rotation', Vector3Stamped))
    first = 1

    def messages(self, k, t_start_ns, time_scale, frames):
        """Return the gyro reading over sample k's interval: imu, delta_angle, delta_rotation."""
        ns1 = self.stamp_ns(t_start_ns, k)
        t0 = scene_time(self.stamp_ns(t_start_ns, k - 1), t_start_ns, time_scale)
        t1 = scene_time(ns1, t_start_ns, time_scale)
        r = self.model.read(t0, t1, budget=settings.SAMPLE_BUDGET_S)
        body = frames[1]
        stamp = msgs.stamp(ns1)
        self.bound = max(self.bound, r.delta_angle_bound, r.delta_rotation_bound)
        return [('imu', msgs.imu(stamp, body, r.omega, r.variance)),
                ('delta_angle', msgs.vector(stamp, body, r.delta_angle)),
                ('delta_rotation', msgs.vector(stamp, body, r.delta_rotation))]


class StarTrackerStream(SensorStream):
    """The star tracker: geometry_msgs/PoseWithCovarianceStamped in N, from k = 0 (t = 0)."""

    name = 'star_tracker'
    topics = (('star_tracker', PoseWithCovarianceStamped),)
    first = 0

    def messages(self, k, t_start_ns, time_scale, frames):
        """Return the star tracker's attitude reading of sample k."""
        ns = self.stamp_ns(t_start_ns, k)
        r = self.model.read(scene_time(ns, t_start_ns, time_scale))
        return [('star_tracker', msgs.star_tracker(msgs.stamp(ns), frames[0], r.quaternion,
                                                   r.covariance))]


#: Every sensor stream class, by name (the diagnostics report each, on or off).
STREAMS = {cls.name: cls for cls in (ImuStream, StarTrackerStream)}


def make_streams(setup):
    """Return the sensor streams of a :class:`rigidrot_ros.settings.RunSetup` (on ones)."""
    cfg = setup.sensors
    out = []
    if setup.gyro is not None:
        out.append(ImuStream(cfg.imu_rate, setup.gyro))
    if setup.star_tracker is not None:
        out.append(StarTrackerStream(cfg.star_tracker_rate, setup.star_tracker))
    return out
