"""Vectorised CDR: whole batches of the node's fixed-layout messages as bytes at once.

The node's messages are a header (stamp and a frame id that is constant per stream), in
some types a second constant string (``child_frame_id``), then only float64 fields. In
XCDR1 little endian (what rmw serializes: the 4-byte encapsulation ``00 01 00 00``, then
each primitive aligned to its size counted from after those 4 bytes) such a message is a
constant template in which only the stamp (two 32-bit words) and a run of doubles change.
A batch is therefore one ``(n, size)`` byte array: the template repeated, the stamps and
the doubles written in as columns. Padding bytes are zero (rclpy's serializer leaves them
as they were in its buffer; every value byte is the same, see ``test/msgs/test_cdr.py``).

API
---
- :func:`serialize_batch`
  ``(kind, stamps_ns, values, frame_id, child_frame_id=None)``: ``values`` is
  ``(n, KINDS[kind].doubles)`` float64 in field order; returns a
  :class:`Batch` (one contiguous buffer, ``len()``, indexing and iteration give
  ``bytes`` per message, ``tolist()``).
- Builders with the semantics of :mod:`rigidrot_ros.msgs.messages` (same values, field for
  field): :func:`attitude`, :func:`vector`, :func:`imu` (with or without an
  accelerometer), :func:`star_tracker`, :func:`transform`, :func:`odometry`,
  :func:`magnetic_field`; and :func:`string`, one ``std_msgs/String`` (the run description).
"""

from dataclasses import dataclass

import numpy as np

__all__ = ['serialize_batch', 'type_name_of', 'Batch', 'Layout', 'KINDS', 'attitude',
           'vector', 'imu', 'star_tracker', 'transform', 'odometry', 'magnetic_field',
           'string', 'ENCAPSULATION']

#: XCDR1 little-endian encapsulation header (CDR_LE, options 0).
ENCAPSULATION = b'\x00\x01\x00\x00'
_SEC = 1_000_000_000
_INT32 = (-2 ** 31, 2 ** 31 - 1)


@dataclass(frozen=True)
class Layout:
    """The shape of one message type: ROS type name, doubles, a child frame id or not."""

    type_name: str
    doubles: int
    child: bool = False


#: The message kinds the node emits, by short name.
KINDS = {
    'QuaternionStamped': Layout('geometry_msgs/msg/QuaternionStamped', 4),
    'Vector3Stamped': Layout('geometry_msgs/msg/Vector3Stamped', 3),
    # orientation 4, its covariance 9, angular velocity 3 + 9, linear acceleration 3 + 9
    'Imu': Layout('sensor_msgs/msg/Imu', 37),
    # position 3, orientation 4, covariance 36
    'PoseWithCovarianceStamped': Layout('geometry_msgs/msg/PoseWithCovarianceStamped', 43),
    # translation 3, rotation 4
    'TransformStamped': Layout('geometry_msgs/msg/TransformStamped', 7, child=True),
    # pose 7 + 36, twist 6 + 36
    'Odometry': Layout('nav_msgs/msg/Odometry', 85, child=True),
    # magnetic field 3, its covariance 9
    'MagneticField': Layout('sensor_msgs/msg/MagneticField', 12),
}


def _string(buf, text):
    """Append a CDR string (aligned uint32 length with the NUL, bytes, NUL) to ``buf``."""
    data = text.encode('utf-8') + b'\x00'
    _align(buf, 4)
    buf += len(data).to_bytes(4, 'little') + data


def _align(buf, n):
    # alignment counts from after the encapsulation header
    buf += b'\x00' * (-(len(buf) - 4) % n)


_TEMPLATES = {}


def type_name_of(msg):
    """``pkg/msg/Type`` of a ROS message instance."""
    parts = type(msg).__module__.split('.')
    return f'{parts[0]}/{parts[1]}/{type(msg).__name__}'


def _template(kind, frame_id, child_frame_id):
    """``(template bytes, offset of the doubles)`` of a message kind with its frame ids."""
    key = (kind, frame_id, child_frame_id)
    got = _TEMPLATES.get(key)
    if got is not None:
        return got
    layout = KINDS[kind]
    if not isinstance(frame_id, str) or (layout.child and not isinstance(child_frame_id,
                                                                         str)):
        raise ValueError(f'{kind} needs string frame ids, got {frame_id!r}, '
                         f'{child_frame_id!r}')
    buf = bytearray(ENCAPSULATION)
    buf += b'\x00' * 8                  # stamp: sec (int32), nanosec (uint32)
    _string(buf, frame_id)
    if layout.child:
        _string(buf, child_frame_id)
    _align(buf, 8)
    offset = len(buf)
    buf += b'\x00' * (8 * layout.doubles)
    if len(_TEMPLATES) > 256:           # a bounded cache (frame ids may change at run time)
        _TEMPLATES.clear()
    _TEMPLATES[key] = got = (np.frombuffer(bytes(buf), dtype=np.uint8), offset)
    return got


class Batch:
    """Serialized messages of one kind, all of one size, in one buffer.

    ``batch[i]`` and iteration give each message's ``bytes``; :attr:`data` is the
    ``(n, size)`` uint8 array. The builders make it from its plan, written out on first
    use: :attr:`row` (one message's bytes, uint8 (size,), the constant fields in place),
    the stamps' ``sec``, ``nsec`` (int64 (n,)) and :attr:`columns` (``[(byte, float64
    (n, k)), ...]``: k doubles of each message from that byte on); a writer that places
    the messages elsewhere (:func:`rigidrot_ros.bag.chunks.place_batch`) reads the plan
    (:meth:`plan`) and never builds :attr:`data`.
    """

    __slots__ = ('_data', 'row', 'sec', 'nsec', 'columns')

    def __init__(self, data=None, row=None, sec=None, nsec=None, columns=None):
        self._data = data
        self.row, self.sec, self.nsec, self.columns = row, sec, nsec, columns

    @property
    def data(self):
        """The ``(n, size)`` uint8 array of the messages (built from the plan once)."""
        if self._data is None:
            n = len(self.sec)
            out = np.empty((n, len(self.row)), dtype=np.uint8)
            out[:] = self.row
            out[:, 4:8] = self.sec.astype('<i4').view(np.uint8).reshape(n, 4)
            out[:, 8:12] = self.nsec.astype('<u4').view(np.uint8).reshape(n, 4)
            for at, v in self.columns:
                out[:, at:at + 8 * v.shape[1]] = v.view(np.uint8)
            self._data = out
        return self._data

    @property
    def planned(self):
        """Whether the batch has its plan (:attr:`row`, ...) and not only :attr:`data`."""
        return self.row is not None

    def plan(self):
        """Return ``(values, slots)``: the columns' doubles side by side, and their bytes.

        ``values`` float64 (n, m), ``slots`` int64 (m,): value j of a message goes at its
        byte ``slots[j]``.
        """
        n = len(self.sec)
        values = np.empty((n, sum(v.shape[1] for _, v in self.columns)), dtype='<f8')
        slots, j = [], 0
        for at, v in self.columns:
            k = v.shape[1]
            values[:, j:j + k] = v
            slots += [at + 8 * i for i in range(k)]
            j += k
        return values, np.array(slots, dtype=np.int64)

    def __len__(self):
        return len(self.sec) if self._data is None else self._data.shape[0]

    @property
    def size(self):
        """Bytes per message."""
        return len(self.row) if self._data is None else self._data.shape[1]

    def __getitem__(self, i):
        return self.data[i].tobytes()

    def __iter__(self):
        return iter(self.tolist())

    def tolist(self):
        """Each message as ``bytes``, in order."""
        blob = self.data.tobytes()
        m = self.data.shape[1]
        return [blob[i:i + m] for i in range(0, len(blob), m)]


def serialize_batch(kind, stamps_ns, values, frame_id, child_frame_id=None):
    """Serialize ``n`` messages of ``kind`` at once: a :class:`Batch`.

    Parameters
    ----------
    kind : str
        A key of :data:`KINDS`.
    stamps_ns : array_like of int, (n,)
        ``header.stamp`` of each message, integer nanoseconds (sec = ns // 1e9, nanosec =
        ns % 1e9, as :func:`rigidrot_ros.msgs.messages.stamp`).
    values : array_like of float, (n, KINDS[kind].doubles)
        Every float64 field of the message in declaration order.
    frame_id, child_frame_id : str
        ``header.frame_id`` (and ``child_frame_id`` where the type has one): constants.

    Raises
    ------
    ValueError
        A shape that does not fit the kind, or a stamp beyond the int32 seconds of
        ``builtin_interfaces/Time``.
    """
    layout = KINDS[kind]
    stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    vals = np.ascontiguousarray(values, dtype='<f8')
    n = len(stamps)
    if vals.shape != (n, layout.doubles):
        raise ValueError(f'{kind} needs values shaped ({n}, {layout.doubles}), '
                         f'got {vals.shape}')
    sec, nsec = np.divmod(stamps, _SEC)
    if n and not (_INT32[0] <= sec.min() and sec.max() <= _INT32[1]):
        raise ValueError('a stamp lies beyond the int32 seconds of builtin_interfaces/Time')
    tpl, offset = _template(kind, frame_id, child_frame_id)
    return Batch(row=tpl, sec=sec, nsec=nsec, columns=[(offset, vals)])


_ROWS = {}


def _serialize_columns(kind, stamps_ns, n, fixed, columns, frame_id, child_frame_id=None):
    """Serialize ``n`` messages whose doubles are ``fixed`` but for ``columns``: a Batch.

    The bytes :func:`serialize_batch` gives for the ``(n, doubles)`` values that repeat the
    row ``fixed`` (a tuple of floats) with ``columns`` (``[(first double, (n, k) or (n,)
    array), ...]``) written over it; the constant doubles are in the row template once,
    so a batch writes its stamps and those columns only. ``n``: the rows the columns
    hold (a count other than the stamps' raises as :func:`serialize_batch` does).
    """
    layout = KINDS[kind]
    stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    m = len(stamps)
    if n != m:
        raise ValueError(f'{kind} needs values shaped ({m}, {layout.doubles}), '
                         f'got ({n}, {layout.doubles})')
    sec, nsec = np.divmod(stamps, _SEC)
    if m and not (_INT32[0] <= sec.min() and sec.max() <= _INT32[1]):
        raise ValueError('a stamp lies beyond the int32 seconds of builtin_interfaces/Time')
    key = (kind, frame_id, child_frame_id, fixed)
    got = _ROWS.get(key)
    if got is None:
        tpl, offset = _template(kind, frame_id, child_frame_id)
        row = tpl.copy()
        row[offset:] = np.array(fixed, dtype='<f8').view(np.uint8)
        if len(_ROWS) > 256:            # a bounded cache (frame ids may change at run time)
            _ROWS.clear()
        _ROWS[key] = got = (row, offset)
    row, offset = got
    cols = [(offset + 8 * first,
             np.ascontiguousarray(np.broadcast_to(values, (m,) + np.shape(values)[1:]),
                                  dtype='<f8').reshape(m, -1))
            for first, values in columns]
    return Batch(row=row, sec=sec, nsec=nsec, columns=cols)


#: The Imu doubles without an accelerometer: orientation (0, 0, 0, 1) and
#: ``orientation_covariance[0] = -1`` (not provided), ``linear_acceleration_covariance[0]
#: = -1``, the rest 0 until written.
_IMU_GYRO = tuple(1.0 if i == 3 else -1.0 if i in (4, 28) else 0.0 for i in range(37))
#: The same with an accelerometer (its covariance written).
_IMU_ACCEL = tuple(1.0 if i == 3 else -1.0 if i == 4 else 0.0 for i in range(37))


# -- builders: the values of rigidrot_ros.msgs.messages, a batch at a time --------------------
def _rows(a, width, name):
    a = np.asarray(a, dtype=float)
    if a.ndim != 2 or a.shape[1] != width:
        raise ValueError(f'{name} must be shaped (n, {width}), got {a.shape}')
    return a


def attitude(stamps_ns, q, frame_id):
    """``QuaternionStamped`` of q_NB rows (x, y, z, w), as :func:`messages.attitude`."""
    return serialize_batch('QuaternionStamped', stamps_ns, _rows(q, 4, 'q'), frame_id)


def vector(stamps_ns, v, frame_id):
    """``Vector3Stamped`` of 3-vector rows, as :func:`messages.vector`."""
    return serialize_batch('Vector3Stamped', stamps_ns, _rows(v, 3, 'v'), frame_id)


def imu(stamps_ns, omega, variance, frame_id, linear_acceleration=None,
        accel_variance=None):
    """``Imu`` of gyro (and accelerometer) samples, as :func:`messages.imu`: no orientation.

    Without ``linear_acceleration`` the field stays zero with
    ``linear_acceleration_covariance[0] = -1`` (not provided); with it (``(n, 3)``, m/s^2)
    ``accel_variance`` ``(n,)`` goes on that covariance's diagonal.
    """
    w = _rows(omega, 3, 'omega')
    n = len(w)
    var = np.broadcast_to(np.asarray(variance, dtype=float).reshape(-1), (n,))
    # orientation (0, 0, 0, 1): the type's default; orientation_covariance[0] = -1
    columns = [(13, w), (16, var), (20, var), (24, var)]
    if linear_acceleration is None:     # linear_acceleration_covariance[0] = -1 too
        return _serialize_columns('Imu', stamps_ns, n, _IMU_GYRO, columns, frame_id)
    if accel_variance is None:
        raise ValueError('imu: linear_acceleration needs accel_variance (its covariance)')
    f = _rows(linear_acceleration, 3, 'linear_acceleration')
    avar = np.broadcast_to(np.asarray(accel_variance, dtype=float).reshape(-1), (n,))
    if len(f) != n:
        raise ValueError(f'imu: linear_acceleration has {len(f)} rows, omega {n}')
    columns += [(25, f), (28, avar), (32, avar), (36, avar)]
    return _serialize_columns('Imu', stamps_ns, n, _IMU_ACCEL, columns, frame_id)


def magnetic_field(stamps_ns, field, covariance, frame_id):
    """``MagneticField`` of magnetometer samples, as :func:`messages.magnetic_field`.

    ``field``: ``(n, 3)`` tesla; ``covariance``: ``(n, 3, 3)`` (or one ``(3, 3)`` for
    every sample), T^2, row-major into ``magnetic_field_covariance``.
    """
    f = _rows(field, 3, 'field')
    cov = np.broadcast_to(np.asarray(covariance, dtype=float), (len(f), 3, 3))
    vals = np.empty((len(f), 12))
    vals[:, :3] = f
    vals[:, 3:] = cov.reshape(len(f), 9)
    return serialize_batch('MagneticField', stamps_ns, vals, frame_id)


def _cov6(rot_blocks):
    """Row-major 6x6 covariances: -1 on the unused first block's diagonal, ``rot`` second."""
    n = len(rot_blocks)
    c = np.zeros((n, 6, 6))
    c[:, 0, 0] = c[:, 1, 1] = c[:, 2, 2] = -1.0
    c[:, 3:, 3:] = rot_blocks
    return c.reshape(n, 36)


def star_tracker(stamps_ns, q, covariance_b, frame_id):
    """``PoseWithCovarianceStamped`` of star tracker samples, as :func:`messages.star_tracker`.

    ``covariance_b``: ``(n, 3, 3)`` (or one ``(3, 3)`` for every sample), rad^2.
    """
    q = _rows(q, 4, 'q')
    cov = np.broadcast_to(np.asarray(covariance_b, dtype=float), (len(q), 3, 3))
    vals = np.zeros((len(q), 43))
    vals[:, 3:7] = q
    vals[:, 7:] = _cov6(cov)
    return serialize_batch('PoseWithCovarianceStamped', stamps_ns, vals, frame_id)


def transform(stamps_ns, q, parent_frame_id, child_frame_id):
    """``TransformStamped`` N -> B, zero translation, as :func:`messages.transform`."""
    q = _rows(q, 4, 'q')
    vals = np.zeros((len(q), 7))
    vals[:, 3:] = q
    return serialize_batch('TransformStamped', stamps_ns, vals, parent_frame_id,
                           child_frame_id)


def odometry(stamps_ns, q, omega, attitude_variance, rate_variance, frame_id,
             child_frame_id):
    """``Odometry`` of the truth, as :func:`messages.odometry` (variances per sample)."""
    q = _rows(q, 4, 'q')
    w = _rows(omega, 3, 'omega')
    n = len(q)
    eye = np.eye(3)
    av = np.broadcast_to(np.asarray(attitude_variance, dtype=float), (n,))
    rv = np.broadcast_to(np.asarray(rate_variance, dtype=float), (n,))
    vals = np.zeros((n, 85))
    vals[:, 3:7] = q
    vals[:, 7:43] = _cov6(av[:, None, None] * eye)
    vals[:, 46:49] = w
    vals[:, 49:85] = _cov6(rv[:, None, None] * eye)
    return serialize_batch('Odometry', stamps_ns, vals, frame_id, child_frame_id)


def string(text):
    """Return the CDR bytes of one ``std_msgs/String`` of ``text`` (as rclpy writes them)."""
    data = text.encode('utf-8') + b'\x00'
    return ENCAPSULATION + len(data).to_bytes(4, 'little') + data
