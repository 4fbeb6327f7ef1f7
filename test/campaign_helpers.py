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


class _Misbehaving(Silent):
    """Receives everything; on the first gyro sample does what ``how`` says."""

    def __init__(self, how):
        self.how = how

    def receive(self, topic, msg):
        """Misbehave at the first gyro sample."""
        if not topic.endswith('/imu'):
            return []
        if self.how == 'wrong_type':
            from std_msgs.msg import String
            return [String(data='not an estimate')]
        if self.how == 'not_a_list':
            from nav_msgs.msg import Odometry
            return Odometry()
        if self.how == 'sleep':
            import time
            time.sleep(1e6)
        if self.how == 'busy':
            while True:
                pass
        return None


def misbehaving(params):
    """Make a :class:`_Misbehaving` (``params['how']``)."""
    return _Misbehaving(params['how'])


def no_receive(params):
    """Return an object that is not an estimator."""
    return object()


_CALLS = [0]


def fails_after_the_check(params):
    """Pass the spec check (the first call), then raise as a factory that cannot start."""
    _CALLS[0] += 1
    if _CALLS[0] > 1:
        raise OSError('no licence for this filter')
    return Silent()
