"""What the recorder tests share: a node's published calls, its publishers, a bag reader."""

import errno
import os
from pathlib import Path
import queue
import threading
import time

from geometry_msgs.msg import Vector3Stamped
import rclpy
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from std_msgs.msg import String

from rigidrot_ros.msgs import messages as msgs


def published_calls(n, pad=0):
    """``n`` calls of published messages: a raw vector and a String object (serialized later)."""
    out = []
    for i in range(n):
        vec = msgs.vector(msgs.stamp(10**9 + i * 10**6), 'body', (i, -i, 0.5 * i))
        out.append((10**9 + i * 10**6 + 7,
                    [('/rate', Vector3Stamped, serialize_message(vec)),
                     ('/note', String(data=f'call {i} ' + 'x' * (pad + i % 97)), None)]))
    return out


def publishing_node(name):
    """Make a node with the publishers of :func:`published_calls` (``/rate``, ``/note``)."""
    node = rclpy.create_node(name)
    node.create_publisher(Vector3Stamped, '/rate', 10)
    node.create_publisher(String, '/note', 10)
    return node


def rosbags_rows(path):
    """``[(topic, log time ns, CDR bytes)]`` of a bag, read by rosbags (needs its summary)."""
    with AnyReader([Path(path)]) as reader:
        return [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]


class _Thread:
    """A real offload thread: runs the calls in order, each after ``delay`` s."""

    def __init__(self, delay=0.0):
        self.delay, self.calls, self.most = delay, queue.SimpleQueue(), 0
        self.writer = None
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def __call__(self, fn):
        if self.writer is not None:
            self.most = max(self.most, len(self.writer._pending))
        self.calls.put(fn)

    def _loop(self):
        while True:
            fn = self.calls.get()
            if fn is None:
                return
            time.sleep(self.delay)
            fn()

    def stop(self):
        self.calls.put(None)
        self.thread.join(10)


class _Disk:
    """The file's stream, which can be made full (ENOSPC) while the writer runs."""

    def __init__(self, fh):
        self.fh, self.full = fh, False

    @classmethod
    def under(cls, writer):
        """Put a disk under ``writer``'s open file (its mcap stream); return it."""
        disk = cls(writer._fh)
        writer._writer._Writer__stream = disk
        return disk

    def write(self, data):
        if self.full and data:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self.fh.write(data)

    def __getattr__(self, name):
        return getattr(self.fh, name)
