"""The node's run description on ``~/run`` and its own recorder (``record:=true``).

:class:`RunLog` announces each run (start-up, every ``~/reset``) with its first
publication, and hands what the node published to the recorder
(:class:`rigidrot_ros.ros.recorder.Recorder`, which writes the same bytes); the recorder is
opened by :func:`open_recorder` from the parameters. It packs the records on the
publishing thread; the chunks' compression and writes run in the node's look-ahead worker
(``BagWriter(offload=...)``; ``RIGIDROT_RECORD_OFFLOAD=0``: on the publishing thread).
"""

import functools
import sys

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

from rigidrot_ros.bag import BagWriter
from rigidrot_ros.ros.cli import SceneError
from rigidrot_ros.ros.recorder import Recorder, type_name_of
from rigidrot_ros.run import outputs
from rigidrot_ros.runtime import switches

__all__ = ['RunLog', 'open_recorder', 'publish_all', 'RECORD_FLUSH_S']

#: Seconds between the recorder's chunk flushes: a flush's cost grows with the chunk, and
#: a flush of 0.4 s of kHz streams took 1.5 ms (p99 3.7 ms, under load), past a period.
RECORD_FLUSH_S = 0.1


def publish_all(node, items):
    """Publish ``node``'s ``(publisher, message or its bytes)`` items in order; how many went out.

    Fewer than all when the context shut down (SIGINT/SIGTERM) meanwhile: the node records
    those that went out and counts as published no truth tick none of whose messages did,
    so its bag holds every tick it says it published. Any other error is raised.
    """
    sent = 0
    try:
        for pub, payload in items:
            pub.publish(payload)
            sent += 1
    except _rclpy.RCLError:
        if node.context.ok():
            raise
    return sent


def open_recorder(node, values, worker=None):
    """Return a :class:`Recorder` of ``node`` into a new bag (``record_path``, ``record_topics``).

    ``worker``: the node's :class:`rigidrot_ros.runtime.worker.BatchWorker`, if it has one;
    the writer then closes its chunks there (``BagWriter(offload=worker.call)``, outside the
    worker's evaluation lock; its gate opened where the node waits for a chunk write),
    unless ``RIGIDROT_RECORD_OFFLOAD=0``. Raises :class:`SceneError` naming the path or the
    parameter when it cannot.
    """
    path = values['record_path'] or 'runs'
    topics = [t for t in (values['record_topics'] or []) if t]
    offload = {}
    if worker is not None and switches.record_offload():
        offload = dict(offload=functools.partial(worker.call, evaluates=False),
                       on_wait=worker.gate.open)
    try:
        writer = BagWriter(path, node.get_name(), flush_period=RECORD_FLUSH_S, **offload)
    except OSError as exc:
        raise SceneError(f'cannot record to {path!r}: {exc}') from None
    try:
        recorder = Recorder(node, writer, topics=topics, exclude_own=True)
    except Exception as exc:  # noqa: B902 - ValueError, or rclpy's invalid-name errors
        writer.close()
        raise SceneError(f'parameter record_topics: {exc}') from None
    node.get_logger().info(f'recording to {writer.path}')
    return recorder


class RunLog:
    """Announce each run on ``~/run``; record what the node published (if recording).

    ``pub_run``: the ``~/run`` publisher (std_msgs/String, transient-local, depth 1, so any
    recorder keeps it); ``recorder``: a :class:`Recorder` or None. Set ``pending`` to
    announce a new run with the next publication.
    """

    def __init__(self, pub_run, recorder=None):
        self.pub_run, self.recorder = pub_run, recorder
        self.index = 0
        self.pending = True

    def tick(self, node, setup, start_ns, now_ns, published):
        """After each publication: announce a new run if one is pending, record what went out.

        ``published`` lists ``(publisher, msg, raw)`` for every message of this call that
        went out (all of them, unless ROS shut down during the call), in order (``raw``: the
        serialized bytes if made already, else None); their topic names are looked up only
        when there is a recorder. A pending run is announced with the first call that
        published anything. The run description
        (:func:`outputs.run_description`: ``setup``, ``start_ns``, the node's publishers)
        is JSON in std_msgs/String.
        """
        published = self._announce(node, setup, start_ns, published)
        if self.recorder is not None:
            self.recorder.record_published(
                now_ns, [(pub.topic_name, m, raw) for pub, m, raw in published])

    def tick_many(self, node, setup, start_ns, calls):
        """:meth:`tick` for several calls at once: ``calls`` lists ``(now_ns, published)``.

        The pacer's calls (:mod:`rigidrot_ros.ros.pacing`), each published at its own time:
        announced as :meth:`tick` would, recorded in one batch per announcement.
        """
        batch = []
        for now_ns, published in calls:
            if self.pending and published and batch:
                self._record(batch)     # the run's record after the messages before it
                batch = []
            published = self._announce(node, setup, start_ns, published)
            if self.recorder is not None:
                batch += [(pub.topic_name, m, raw, now_ns) for pub, m, raw in published]
        self._record(batch)

    def _record(self, batch):
        if self.recorder is not None and batch:
            self.recorder.record_many(batch)

    def _announce(self, node, setup, start_ns, published):
        """Announce a pending run with the first call that published; ``published`` + ``~/run``."""
        if self.pending and published:
            self.pending = False
            self.index += 1
            info = outputs.run_description(
                setup, start_ns, self.index, node.get_fully_qualified_name(),
                {p.topic_name: type_name_of(p.msg_type) for p in node.publishers})
            msg = outputs.run_message(info)
            if publish_all(node, [(self.pub_run, msg)]):
                published = list(published) + [(self.pub_run, msg, None)]
            if self.recorder is not None:
                self.recorder.add_run(info)
        return published

    def close(self, ticks):
        """Finish the bag (summary, index, metadata.yaml), if recording; ``ticks`` published."""
        if self.recorder is None:
            return
        try:
            path, counts = self.recorder.close()
            # the context may be shut down already: no rosout logging here
            print(f'attitude_node: bag finished: {path} {counts}, '
                  f'published {ticks} ticks', file=sys.stderr)
        except (OSError, ValueError) as exc:
            print(f'attitude_node: could not finish the bag: {exc}', file=sys.stderr)
        self.recorder = None
