"""The truth's outputs, on the truth's tick grid: attitude and rate, transform, odometry, markers.

Every kind here reads the same block: :func:`read_truth` (``solution.at`` of the ticks'
scene times, one call a block; a sample's bits depend on its time alone, so a batch gives
what single calls give). Columns: ``q`` (n, 4) q_NB (x, y, z, w), ``w`` (n, 3) omega_BN_B
rad/s, ``e`` (n,) the error bound, rad. Frames: N ``frame_id``, B ``body_frame_id``.
"""

import numpy as np

from rigidrot_ros.msgs import cdr
from rigidrot_ros.run.output import header_stamps as _stamps, LazyModule, msgs, Output, Topic

#: :mod:`rigidrot_ros.msgs.template` (it loads ROS's message classes), on first use.
template = LazyModule('rigidrot_ros.msgs.template')
#: The markers' type (``template.MARKERS``).
MARKERS = 'visualization_msgs/msg/MarkerArray'

__all__ = ['read_truth', 'TruthOutput', 'TransformOutput', 'OdomOutput', 'MarkersOutput']

_EPS = float(np.finfo(float).eps)
VECTOR = 'geometry_msgs/msg/Vector3Stamped'


def read_truth(solution, times):
    """Return the truth's columns ``{'q', 'w', 'e'}`` at scene ``times`` (s, an array)."""
    s = solution.at(times)
    return {'q': s.quaternion, 'w': s.omega, 'e': s.error_bound}


class TruthOutput(Output):
    """``attitude`` (QuaternionStamped, q_NB in N) and ``angular_velocity`` (Vector3Stamped, in B).

    Always on: the run's two topics by default.
    """

    name = 'truth'
    topics = (Topic('attitude', 'geometry_msgs/msg/QuaternionStamped', 0),
              Topic('angular_velocity', VECTOR, 1))

    def encode(self, topic, stamps, cols, frames):
        """Return the CDR of ``attitude`` or ``angular_velocity`` for each row."""
        return self.encode_batch(topic, stamps, cols, frames).tolist()

    def encode_batch(self, topic, stamps, cols, frames):
        """Return the CDR of ``attitude`` or ``angular_velocity`` for each row: a Batch."""
        if topic == 'attitude':
            return cdr.attitude(stamps, cols['q'], frames[0])
        return cdr.vector(stamps, cols['w'], frames[1])

    def messages(self, topic, stamps, cols, frames):
        """Return the messages of ``attitude`` or ``angular_velocity`` for each row."""
        if topic == 'attitude':
            return [msgs.attitude(s, frames[0], q)
                    for s, q in zip(_stamps(stamps), cols['q'].tolist())]
        return [msgs.vector(s, frames[1], w) for s, w in zip(_stamps(stamps), cols['w'].tolist())]


class TransformOutput(Output):
    """``transform`` (TransformStamped, parent N, child B, zero translation, rotation q_NB)."""

    name = 'transform'
    enable = 'transform.enable'
    topics = (Topic('transform', 'geometry_msgs/msg/TransformStamped', 2),)

    def encode(self, topic, stamps, cols, frames):
        """Return the CDR of the transform for each row."""
        return self.encode_batch(topic, stamps, cols, frames).tolist()

    def encode_batch(self, topic, stamps, cols, frames):
        """Return the CDR of the transform for each row: a Batch."""
        return cdr.transform(stamps, cols['q'], frames[0], frames[1])

    def messages(self, topic, stamps, cols, frames):
        """Return the transform messages for each row."""
        return [msgs.transform(s, frames[0], frames[1], q)
                for s, q in zip(_stamps(stamps), cols['q'].tolist())]


class OdomOutput(Output):
    """``odom`` (nav_msgs/Odometry): the truth with its own error as a covariance.

    The attitude variance is the sample's bound squared (rad^2); the rate variance
    ``(32 eps |omega|)^2`` ((rad/s)^2): the rate's rounding, a few ulps of its norm.
    """

    name = 'odom'
    enable = 'odom.enable'
    topics = (Topic('odom', 'nav_msgs/msg/Odometry', 3),)

    @staticmethod
    def variances(cols):
        """Return ``(attitude variance, rate variance)`` arrays (n,) of the rows."""
        rate_sd = 32.0 * _EPS * np.array([float(np.linalg.norm(x)) for x in cols['w']])
        return np.asarray(cols['e'], dtype=float) ** 2, rate_sd ** 2

    def encode(self, topic, stamps, cols, frames):
        """Return the CDR of the odometry for each row."""
        return self.encode_batch(topic, stamps, cols, frames).tolist()

    def encode_batch(self, topic, stamps, cols, frames):
        """Return the CDR of the odometry for each row: a Batch."""
        av, rv = self.variances(cols)
        return cdr.odometry(stamps, cols['q'], cols['w'], av, rv, frames[0], frames[1])

    def messages(self, topic, stamps, cols, frames):
        """Return the odometry messages for each row."""
        av, rv = self.variances(cols)
        return [msgs.odometry(s, frames[0], frames[1], q, w, attitude_variance=a,
                              rate_variance=r)
                for s, q, w, a, r in zip(_stamps(stamps), cols['q'].tolist(),
                                         cols['w'].tolist(), av.tolist(), rv.tolist())]


class MarkersOutput(Output):
    """``markers`` (MarkerArray in N): a box of the inertia ellipsoid's proportions, 3 axes."""

    name = 'markers'
    enable = 'markers.enable'
    topics = (Topic('markers', MARKERS, 4),)

    def encode(self, topic, stamps, cols, frames):
        """Return the CDR of the markers for each row."""
        return self.encode_batch(topic, stamps, cols, frames).tolist()

    def encode_batch(self, topic, stamps, cols, frames):
        """Return the CDR of the markers for each row: a Batch."""
        return template.markers(stamps, cols['q'], frames[0], self.setup.solution.scene.inertia)

    def messages(self, topic, stamps, cols, frames):
        """Return the marker arrays for each row."""
        inertia = self.setup.solution.scene.inertia
        return [msgs.body_markers(s, frames[0], q, inertia)
                for s, q in zip(_stamps(stamps), cols['q'].tolist())]
