"""The star tracker: its attitude reading with the covariance of its error, from k = 0.

``star_tracker`` (geometry_msgs/PoseWithCovarianceStamped): the measured q_NB (x, y, z,
w) in N (``frame_id``), the covariance of the rotation-vector error in B on the
orientation block (rad^2), the position block marked unused. Columns: ``q`` (n, 4),
``cov`` (n, 3, 3).
"""

from rigidrot_ros.msgs import cdr
from rigidrot_ros.run.output import header_stamps, msgs, SensorOutput, Topic

__all__ = ['StarTrackerOutput']


class StarTrackerOutput(SensorOutput):
    """The star tracker (:class:`rigidrot_ros.sensors.StarTracker`), sample by sample."""

    name = 'star_tracker'
    enable = 'star_tracker.enable'
    rate_param = 'star_tracker.rate'
    topics = (Topic('star_tracker', 'geometry_msgs/msg/PoseWithCovarianceStamped', 20),)

    def __init__(self, setup):
        super().__init__(setup)
        self.model = setup.star_tracker

    def read(self, times, budget=None):
        """Read the attitude at each of ``times`` (scene s).

        At once (:meth:`StarTracker.read_many`, the per-sample bits), else, where an
        attitude cannot be evaluated, sample by sample (nothing drawn before).
        """
        try:
            r = self.model.read_many(times)
            return {'q': r.quaternion, 'cov': r.covariance}, [None] * len(r.t)
        except Exception:    # noqa: B902 - each sample's own error, from the reads below
            pass

        def one(t):
            r = self.model.read(t)
            return r.quaternion, r.covariance
        return self.read_each(times, one, {'q': (4,), 'cov': (3, 3)})

    def encode(self, topic, stamps, cols, frames):
        """Return the CDR of each row."""
        return self.encode_batch(topic, stamps, cols, frames).tolist()

    def encode_batch(self, topic, stamps, cols, frames):
        """Return the CDR of each row: a Batch."""
        return cdr.star_tracker(stamps, cols['q'], cols['cov'], frames[0])

    def messages(self, topic, stamps, cols, frames):
        """Return the message of each row."""
        return [msgs.star_tracker(s, frames[0], q, c)
                for s, q, c in zip(header_stamps(stamps), cols['q'], cols['cov'])]
