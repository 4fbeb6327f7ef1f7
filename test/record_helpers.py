"""What the recorder tests share: a node's published calls, its publishers, a bag reader."""

from pathlib import Path

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
