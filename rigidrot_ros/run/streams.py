"""Sensor streams: each sensor's samples on its own clock grid, as messages (no rclpy).

A :class:`SensorStream` owns one sensor of a run: its rate, the last sample index it
published, the topics it publishes (relative names and message classes) and how sample k
becomes messages (:meth:`SensorStream.messages`). Sample k is stamped
``t_start + k / rate`` (:func:`rigidrot_ros.run.grid.stamp_ns`) and taken at scene time
``(stamp - t_start) * time_scale``; every message of a sample shares its stamp. The node
calls :meth:`SensorStream.take` from one timer per stream and publishes what it returns; the
offline generator calls :meth:`SensorStream.messages` for k = first, first + 1, ...

A new sensor is one more subclass with ``name``,
``topics`` and ``messages``, and one more line in :func:`make_streams`.
"""

import abc
import time

from geometry_msgs.msg import PoseWithCovarianceStamped, Vector3Stamped
from sensor_msgs.msg import Imu, MagneticField

from rigidrot_ros.msgs import messages as msgs
from rigidrot_ros.run import grid, settings

__all__ = ['SensorStream', 'ImuStream', 'StarTrackerStream', 'MagStream', 'make_streams',
           'STREAMS',
           'scene_time']


def scene_time(stamp_ns, t_start_ns, time_scale):
    """Return the scene time (s) of a stamp: ``(stamp - t_start) * time_scale``."""
    return (stamp_ns - t_start_ns) * 1e-9 * time_scale


class SensorStream(abc.ABC):
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

    @abc.abstractmethod
    def messages(self, k, t_start_ns, time_scale, frames):
        """Return ``[(topic, msg), ...]`` of sample k (raises if it cannot be evaluated).

        ``frames`` is ``(frame_id, body_frame_id)``.
        """

    def take(self, t_start_ns, now_ns, time_scale, frames, counters, on_error):
        """Return the messages of every sample due at ``now_ns``, oldest first.

        At most ``settings.SAMPLE_BUDGET_S`` of work: the rest stays due for the next
        call. A sample that fails is passed to ``on_error(t, exc)`` and skipped;
        ``counters`` (:class:`rigidrot_ros.runtime.diagnostics.Counters`) counts samples,
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
    """The gyro (and the accelerometer): sensor_msgs/Imu, the exact increments, in B.

    Sample k covers the interval from sample k - 1 to k (so k starts at 1: [0, 1 / rate]).
    With an accelerometer (``accel``, a :class:`rigidrot_ros.sensors.Accelerometer`) the
    same message carries its specific force in ``linear_acceleration`` (m/s^2, in B) with
    its covariance, and ``delta_velocity`` (the exact ∫ f_B dt over the interval, m/s, in
    B) is published too; without one the message is the gyro's alone, as before.
    """

    name = 'imu'
    topics = (('imu', Imu), ('delta_angle', Vector3Stamped), ('delta_rotation', Vector3Stamped))
    first = 1

    def __init__(self, rate, model, accel=None):
        super().__init__(rate, model)
        self.accel = accel
        if accel is not None:
            self.topics = type(self).topics + (('delta_velocity', Vector3Stamped),)

    def messages(self, k, t_start_ns, time_scale, frames):
        """Return sample k's interval: imu, delta_angle, delta_rotation (, delta_velocity)."""
        ns1 = self.stamp_ns(t_start_ns, k)
        t0 = scene_time(self.stamp_ns(t_start_ns, k - 1), t_start_ns, time_scale)
        t1 = scene_time(ns1, t_start_ns, time_scale)
        r = self.model.read(t0, t1, budget=settings.SAMPLE_BUDGET_S)
        a = None if self.accel is None else \
            self.accel.read(t0, t1, budget=settings.SAMPLE_BUDGET_S)
        body = frames[1]
        stamp = msgs.stamp(ns1)
        self.bound = max(self.bound, r.delta_angle_bound, r.delta_rotation_bound)
        if a is None:
            imu = msgs.imu(stamp, body, r.omega, r.variance)
        else:
            imu = msgs.imu(stamp, body, r.omega, r.variance, a.specific_force, a.variance)
        out = [('imu', imu),
               ('delta_angle', msgs.vector(stamp, body, r.delta_angle)),
               ('delta_rotation', msgs.vector(stamp, body, r.delta_rotation))]
        if a is not None:
            out.append(('delta_velocity', msgs.delta_velocity(stamp, body, a.delta_velocity)))
        return out


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


class MagStream(SensorStream):
    """The magnetometer: sensor_msgs/MagneticField (tesla, in B, frame body_frame_id), k >= 0.

    Sample k is the field at its stamp; its white noise is discretised over one sample
    interval (``time_scale / rate`` s of scene time).
    """

    name = 'mag'
    topics = (('mag', MagneticField),)
    first = 0

    def messages(self, k, t_start_ns, time_scale, frames):
        """Return the magnetometer reading of sample k."""
        ns = self.stamp_ns(t_start_ns, k)
        r = self.model.read(scene_time(ns, t_start_ns, time_scale), time_scale / self.rate)
        return [('mag', msgs.magnetic_field(msgs.stamp(ns), frames[1], r.field,
                                            r.covariance))]


#: Every sensor stream class, by name (the diagnostics report each, on or off).
STREAMS = {cls.name: cls for cls in (ImuStream, StarTrackerStream, MagStream)}


def make_streams(setup):
    """Return the sensor streams of a :class:`rigidrot_ros.run.settings.RunSetup` (on ones)."""
    cfg = setup.sensors
    out = []
    if setup.gyro is not None:
        out.append(ImuStream(cfg.imu_rate, setup.gyro, getattr(setup, 'accel', None)))
    if setup.star_tracker is not None:
        out.append(StarTrackerStream(cfg.star_tracker_rate, setup.star_tracker))
    if getattr(setup, 'mag', None) is not None:
        out.append(MagStream(cfg.mag_rate, setup.mag))
    return out
