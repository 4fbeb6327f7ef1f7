"""A run that produced no score (no rclpy here): the one exception the run paths raise."""

__all__ = ['RunFailed']


class RunFailed(Exception):
    """A run that produced no score; ``reason`` one line, ``log`` the details.

    ``startup`` marks an estimator that never got going (a factory that raised, a command
    that exited or never subscribed before the first message): when no run of the
    campaign has succeeded yet, the campaign stops there with that one line (exit 2)
    instead of failing every run the same way.
    """

    def __init__(self, reason, log='', startup=False):
        super().__init__(reason)
        self.reason = reason
        self.log = log
        self.startup = startup
