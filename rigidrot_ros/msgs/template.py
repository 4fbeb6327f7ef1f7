"""CDR of messages whose layout is constant in a run but no fixed kind: the body markers.

A ``visualization_msgs/MarkerArray`` of the body (:func:`rigidrot_ros.msgs.messages.body_markers`)
has the same strings, sizes and colours at every tick of a run; only each marker's stamp and
orientation change. So it is serialized once, by mcap_ros2's pure-Python CDR writer from the
type's schema text (:mod:`rigidrot_ros.msgs.msgdefs`), with a distinct sentinel in every
place that changes; the sentinels' offsets in those bytes are the holes that a batch fills
in as columns, as :mod:`rigidrot_ros.msgs.cdr` fills its fixed templates. The bytes are the
canonical CDR (padding zero) of the messages ``body_markers`` builds, field for field
(``test/msgs/test_cdr.py``); no rclpy.
"""

import struct

from mcap_ros2._dynamic import serialize_dynamic
import numpy as np

from rigidrot_ros.msgs import messages as msgs
from rigidrot_ros.msgs.cdr import Batch
from rigidrot_ros.msgs.msgdefs import schema_text

__all__ = ['markers', 'MARKERS']

#: The type :func:`markers` serializes.
MARKERS = 'visualization_msgs/msg/MarkerArray'
_SEC = 1_000_000_000
_INT32 = (-2 ** 31, 2 ** 31 - 1)
_encoders = {}
_templates = {}


def _encoder(type_name):
    if type_name not in _encoders:
        _encoders[type_name] = serialize_dynamic(type_name, schema_text(type_name))[type_name]
    return _encoders[type_name]


def _sentinel_stamp(i):
    """Return ``(sec, nanosec)`` of marker i's sentinel stamp: 8 bytes found nowhere else."""
    return 0x5EADBEE0 + i, 999_999_000 + i


def _sentinel_double(i, c):
    """Return the sentinel of component c of marker i's orientation (a tiny, odd float)."""
    return float.fromhex(f'0x1.5eadbeef{i:02x}{c:02x}p-1000')


def _find_once(data, pattern, what):
    at = data.find(pattern)
    if at < 0 or data.find(pattern, at + 1) >= 0:
        raise ValueError(f'marker template: the sentinel of {what} is not found exactly once')
    return at


def _template(frame_id, inertia, namespace):
    """Return ``(bytes as uint8 array, stamp offsets, orientation offsets)`` of the markers."""
    key = (frame_id, tuple(float(v) for v in inertia), namespace)
    got = _templates.get(key)
    if got is not None:
        return got
    msg = msgs.body_markers(msgs.stamp(0), frame_id, (0.0, 0.0, 0.0, 1.0), inertia, namespace)
    for i, m in enumerate(msg.markers):
        sec, nanosec = _sentinel_stamp(i)
        m.header.stamp = type(m.header.stamp)(sec=sec, nanosec=nanosec)     # not shared
        o = m.pose.orientation
        o.x, o.y, o.z, o.w = (_sentinel_double(i, c) for c in range(4))
    data = bytes(_encoder(MARKERS)(msg))
    stamps = [_find_once(data, struct.pack('<iI', *_sentinel_stamp(i)), f'stamp {i}')
              for i in range(len(msg.markers))]
    quats = [_find_once(data, struct.pack('<4d', *(_sentinel_double(i, c) for c in range(4))),
                        f'orientation {i}') for i in range(len(msg.markers))]
    if len(_templates) > 64:            # a bounded cache (frame ids may change at run time)
        _templates.clear()
    _templates[key] = got = (np.frombuffer(data, dtype=np.uint8), stamps, quats)
    return got


def _times(q, b):
    """Return ``q ⊗ b`` row by row, in the operations and order of ``multiply_floats``."""
    ax, ay, az, aw = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    bx, by, bz, bw = b
    with np.errstate(all='ignore'):     # inf and NaN as the float operations give them
        return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                         aw * by - ax * bz + ay * bw + az * bx,
                         aw * bz + ax * by - ay * bx + az * bw,
                         aw * bw - ax * bx - ay * by - az * bz], axis=1)


def markers(stamps_ns, q, frame_id, inertia, namespace='body'):
    """Serialize the body markers of ``n`` samples at once: a :class:`Batch`.

    The bytes of :func:`rigidrot_ros.msgs.messages.body_markers` ``(stamp, frame_id, q,
    inertia, namespace)`` for each row: stamps in integer ns, ``q`` (n, 4) q_NB (x, y, z,
    w); the box takes q, each axis arrow q ⊗ (its turn from x). ValueError for a stamp
    beyond the int32 seconds of ``builtin_interfaces/Time``.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    q = np.asarray(q, dtype=float)
    n = len(stamps)
    if q.shape != (n, 4):
        raise ValueError(f'markers need q shaped ({n}, 4), got {q.shape}')
    sec, nsec = np.divmod(stamps, _SEC)
    if n and not (_INT32[0] <= sec.min() and sec.max() <= _INT32[1]):
        raise ValueError('a stamp lies beyond the int32 seconds of builtin_interfaces/Time')
    tpl, at_stamp, at_quat = _template(frame_id, inertia, namespace)
    out = np.empty((n, len(tpl)), dtype=np.uint8)
    out[:] = tpl
    sec_b = sec.astype('<i4').view(np.uint8).reshape(n, 4)
    nsec_b = nsec.astype('<u4').view(np.uint8).reshape(n, 4)
    turns = [None] + [msgs.axis_from_x(k) for k in range(len(at_quat) - 1)]
    for at, turn in zip(at_quat, turns):
        rows = q if turn is None else _times(q, turn)
        out[:, at:at + 32] = np.ascontiguousarray(rows, dtype='<f8').view(np.uint8).reshape(n, 32)
    for at in at_stamp:
        out[:, at:at + 4] = sec_b
        out[:, at + 4:at + 8] = nsec_b
    return Batch(out)
