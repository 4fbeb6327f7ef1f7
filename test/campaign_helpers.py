"""Estimators for the campaign tests: one that crashes on some runs, one that is silent."""

from rigidrot_ros.estimators.mekf import MEKF


class Flaky(MEKF):
    """The MEKF, except that it raises on a run whose first star tracker w is below 0.5."""

    def receive(self, topic, msg):
        """Raise on the chosen runs, else filter."""
        if topic.endswith('star_tracker') and self.q is None and \
                abs(msg.pose.pose.orientation.w) < 0.5:
            raise RuntimeError('flaky estimator: this run is not for me')
        return super().receive(topic, msg)


class Silent:
    """Receives everything, publishes nothing."""

    def receive(self, topic, msg):
        """Nothing."""
        return []

    def finish(self):
        """Nothing."""
        return []


def flaky(params):
    """Make a :class:`Flaky`."""
    return Flaky(params)


def silent(params):
    """Make a :class:`Silent`."""
    return Silent()
