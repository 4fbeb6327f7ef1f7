"""The imu: the gyro (and the accelerometer) and their increments, one message set per interval.

Sample k >= 1 covers the interval from sample k - 1 to k. The gyro is read a block at a
time (:meth:`rigidrot_ros.sensors.Gyro.read_many`, bit for bit the per-sample reads), the
accelerometer over the same intervals after it (:meth:`Accelerometer.read_many`). Topics,
all in B (``body_frame_id``):

- ``imu`` (sensor_msgs/Imu): the measured rate with its variance; with ``accel.enable``
  the specific force (m/s^2) with its variance in ``linear_acceleration``;
- ``delta_angle`` (rad), ``delta_rotation`` (rad) and, with the accelerometer,
  ``delta_velocity`` (m/s): the exact increments over the interval (Vector3Stamped), the
  truth an estimator's pre-integration is checked against;
- ``delta_angle_measured`` with ``imu.gyro_increment_quantum`` > 0 and
  ``delta_velocity_measured`` with ``accel.increment_quantum`` > 0: what an
  increment-output IMU reports, the measured increments (every error term) quantised
  to that LSB with the residual carried to the next sample.

Columns: ``w`` (n, 3) rad/s and ``var`` (n,) of the gyro, ``da``, ``dr``, ``dam`` (n, 3)
its exact and measured increments; ``f`` (n, 3) m/s^2 and ``avar`` (n,) of the
accelerometer, ``dv``, ``dvm`` (n, 3) its exact and measured increments.
"""

import numpy as np

from rigidrot_ros.msgs import cdr
from rigidrot_ros.run.output import columns, header_stamps, msgs, SensorOutput, Topic

__all__ = ['ImuOutput']

VECTOR = 'geometry_msgs/msg/Vector3Stamped'
#: The increments' topics and their columns.
_INCREMENTS = {'delta_angle': 'da', 'delta_rotation': 'dr', 'delta_velocity': 'dv',
               'delta_angle_measured': 'dam', 'delta_velocity_measured': 'dvm'}
_GYRO = {'w': (3,), 'var': (), 'da': (3,), 'dr': (3,), 'dam': (3,)}
_ACCEL = {'f': (3,), 'avar': (), 'dv': (3,), 'dvm': (3,)}


class ImuOutput(SensorOutput):
    """The gyro, the accelerometer riding in its message, and their increments."""

    name = 'imu'
    enable = 'imu.enable'
    rate_param = 'imu.rate'
    first = 1
    interval = True
    topics = (Topic('imu', 'sensor_msgs/msg/Imu', 10),
              Topic('delta_angle', VECTOR, 11),
              Topic('delta_rotation', VECTOR, 12),
              Topic('delta_velocity', VECTOR, 13, ('accel.enable',)),
              Topic('delta_angle_measured', VECTOR, 14, ('imu.gyro_increment_quantum',)),
              Topic('delta_velocity_measured', VECTOR, 15,
                    ('accel.enable', 'accel.increment_quantum')))

    def __init__(self, setup):
        super().__init__(setup)
        self.model, self.accel = setup.gyro, setup.accel

    def read(self, times, budget=None):
        """Read the gyro over the intervals between ``times``, then the accelerometer.

        The gyro as one block (per interval if the block fails), the accelerometer over
        the same intervals whose gyro read succeeded (:meth:`_read_accel`).
        """
        model, n = self.model, len(times) - 1
        try:
            blocks, errors = [model.read_many(times, budget=budget)], [None] * n
        except ValueError:              # one interval too hard: each on its own
            blocks, errors = [], []
            for i in range(n):
                try:
                    blocks.append(model.read_many(times[i:i + 2], budget=budget))
                    errors.append(None)
                except ValueError as exc:
                    errors.append(exc)
        rows = {k: [] for k in _GYRO}
        for b in blocks:
            self.bound = max(self.bound, float(b.delta_angle_bound.max()),
                             float(b.delta_rotation_bound.max()))
            for k, v in zip(_GYRO, (b.omega, b.variance, b.delta_angle, b.delta_rotation,
                                    b.delta_angle_measured)):
                rows[k].append(v)
        cols = columns({k: np.concatenate(v) if v else None for k, v in rows.items()},
                       errors, _GYRO)
        if self.accel is not None:
            acc, errors = self._read_accel(times, errors, budget)
            cols.update(acc)
        return cols, errors

    def _read_accel(self, times, errors, budget):
        """Read the accelerometer over the intervals whose gyro read succeeded, in order.

        One :meth:`Accelerometer.read_many` block (bit for bit the per-sample reads), else
        interval by interval: a failed gyro interval leaves the accelerometer's noise
        stream untouched; a failed accelerometer read makes the sample an error.
        """
        acc = self.accel
        if errors.count(None) == len(errors):
            try:
                b = acc.read_many(times, budget=budget)
                return {'f': b.specific_force, 'avar': b.variance, 'dv': b.delta_velocity,
                        'dvm': b.delta_velocity_measured}, errors
            except ValueError:          # one interval too hard: each on its own
                pass
        rows, out = {k: [] for k in _ACCEL}, []
        for i, err in enumerate(errors):
            if err is None:
                try:
                    b = acc.read_many(times[i:i + 2], budget=budget)
                    for k, v in zip(_ACCEL, (b.specific_force, b.variance, b.delta_velocity,
                                             b.delta_velocity_measured)):
                        rows[k].append(v)
                except Exception as exc:    # noqa: B902 - reported when the sample is due
                    err = exc
            out.append(err)
        return columns({k: np.concatenate(v) if v else None for k, v in rows.items()},
                       out, _ACCEL), out

    def encode(self, topic, stamps, cols, frames):
        """Return the CDR of ``topic`` for each row."""
        return self.encode_batch(topic, stamps, cols, frames).tolist()

    def encode_batch(self, topic, stamps, cols, frames):
        """Return the CDR of ``topic`` for each row: a Batch."""
        body = frames[1]
        if topic != 'imu':
            return cdr.vector(stamps, cols[_INCREMENTS[topic]], body)
        if self.accel is None:
            return cdr.imu(stamps, cols['w'], cols['var'], body)
        return cdr.imu(stamps, cols['w'], cols['var'], body, cols['f'], cols['avar'])

    def messages(self, topic, stamps, cols, frames):
        """Return the messages of ``topic`` for each row."""
        body = frames[1]
        st = header_stamps(stamps)
        if topic != 'imu':
            return [msgs.vector(s, body, v) for s, v in zip(st, cols[_INCREMENTS[topic]])]
        if self.accel is None:
            return [msgs.imu(s, body, w, v)
                    for s, w, v in zip(st, cols['w'], cols['var'].tolist())]
        return [msgs.imu(s, body, w, v, f, a) for s, w, v, f, a in
                zip(st, cols['w'], cols['var'].tolist(), cols['f'], cols['avar'].tolist())]
