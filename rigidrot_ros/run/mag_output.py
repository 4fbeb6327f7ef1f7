"""The magnetometer: the field in B (tesla) with its covariance, from k = 0.

``mag`` (sensor_msgs/MagneticField, frame ``body_frame_id``). Sample k is the field at its
stamp; its white noise is discretised over one sample interval, ``time_scale / rate``
seconds of scene time. Columns: ``m`` (n, 3) T, ``cov`` (n, 3, 3) T^2.
"""

from rigidrot_ros.msgs import cdr
from rigidrot_ros.run.output import header_stamps, msgs, SensorOutput, Topic

__all__ = ['MagOutput']


class MagOutput(SensorOutput):
    """The magnetometer (:class:`rigidrot_ros.sensors.Magnetometer`), sample by sample."""

    name = 'mag'
    enable = 'mag.enable'
    rate_param = 'mag.rate'
    topics = (Topic('mag', 'sensor_msgs/msg/MagneticField', 30),)

    def __init__(self, setup):
        super().__init__(setup)
        self.model = setup.mag

    def read(self, times, budget=None):
        """Read the field at each of ``times`` (scene s), noise over one interval."""
        dt = self.setup.time_scale / self.rate

        def one(t):
            r = self.model.read(t, dt)
            return r.field, r.covariance
        return self.read_each(times, one, {'m': (3,), 'cov': (3, 3)})

    def encode(self, topic, stamps, cols, frames):
        """Return the CDR of each row."""
        return self.encode_batch(topic, stamps, cols, frames).tolist()

    def encode_batch(self, topic, stamps, cols, frames):
        """Return the CDR of each row: a Batch."""
        return cdr.magnetic_field(stamps, cols['m'], cols['cov'], frames[1])

    def messages(self, topic, stamps, cols, frames):
        """Return the message of each row."""
        return [msgs.magnetic_field(s, frames[1], m, c)
                for s, m, c in zip(header_stamps(stamps), cols['m'], cols['cov'])]
