"""Decoded bag messages -> attitude and body-rate streams with their covariances (no rclpy).

One place turns every supported message type into what scoring needs. Quaternions are
(x, y, z, w), ``q_NB`` (rotates body vectors into the inertial frame N); rates are
omega of B relative to N, in B, rad/s.

===================================  ==================================================
type                                 streams
===================================  ==================================================
geometry_msgs/QuaternionStamped      orientation
geometry_msgs/Vector3Stamped         angular_velocity (not ``delta_angle`` /
                                     ``delta_rotation``: increments, not rates)
sensor_msgs/Imu                      orientation where ``orientation_covariance[0] != -1``,
                                     with that covariance; angular_velocity where
                                     ``angular_velocity_covariance[0] != -1``
nav_msgs/Odometry                    pose orientation with the rotation block of
                                     ``pose.covariance``; ``twist.angular`` (in the child
                                     frame) with the rotation block of ``twist.covariance``
geometry_msgs/PoseStamped            orientation
geometry_msgs/PoseWithCovariance...  orientation with the rotation block of the covariance
geometry_msgs/TransformStamped       orientation (``transform.rotation``)
===================================  ==================================================

Covariances follow the message definitions: element 0 = -1 means "this field carries no
estimate" (the field is not scored); all zeros means "unknown" (the field is scored, with
no NEES); a covariance with NaN or one that is not symmetric positive definite gives no
NEES for that sample (counted in ``cov_unusable``). The rotation block of a 6x6 pose
covariance is rows/columns 3..5 (rotation about x, y, z).
"""

from dataclasses import dataclass, field

from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
import numpy as np

__all__ = ['Stream', 'decode_bag', 'SUPPORTED', 'ORIENTATION', 'RATE', 'message_rows',
           'stream_of_rows']

ORIENTATION = 'orientation'
RATE = 'angular_velocity'
SUPPORTED = (
    'geometry_msgs/msg/QuaternionStamped', 'geometry_msgs/msg/Vector3Stamped',
    'sensor_msgs/msg/Imu', 'nav_msgs/msg/Odometry', 'geometry_msgs/msg/PoseStamped',
    'geometry_msgs/msg/PoseWithCovarianceStamped', 'geometry_msgs/msg/TransformStamped',
)
_INCREMENTS = ('delta_angle', 'delta_rotation')


@dataclass
class Stream:
    """One scorable field of one topic.

    ``stamps`` int64 ns (header stamps); ``values`` (N, 4) unit quaternions (x, y, z, w)
    or (N, 3) rates, NaN rows for unusable samples; ``cov`` (N, 3, 3) with NaN where a
    sample has no usable covariance, or None when the topic never carries one.
    """

    topic: str
    type: str
    field: str
    stamps: np.ndarray
    values: np.ndarray
    cov: np.ndarray = None
    frame_id: str = ''
    invalid: int = 0                  # samples with a non-finite or non-unit value
    cov_unknown: int = 0              # samples whose covariance is all zero ("unknown")
    cov_unusable: int = 0             # NaN, or not symmetric positive definite
    notes: list = field(default_factory=list)

    @property
    def label(self):
        """``topic`` or ``topic [field]`` where a topic gives two streams."""
        return self.topic if self.field in _default_field(self.type) else (
            f'{self.topic} [{self.field}]')


def _default_field(type_name):
    return {'geometry_msgs/msg/Vector3Stamped': (RATE,)}.get(type_name, (ORIENTATION,))


def _stamp(m):
    return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec


def _quat(q):
    return (q.x, q.y, q.z, q.w)


def _vec(v):
    return (v.x, v.y, v.z)


def _block(cov6):
    c = np.asarray(cov6, dtype=float).reshape(6, 6)
    return c[3:, 3:]


def _cov3(cov9):
    return np.asarray(cov9, dtype=float).reshape(3, 3)


def _fields(type_name, m):
    """``[(field, value, covariance or None, frame), ...]`` of one decoded message."""
    if type_name == 'geometry_msgs/msg/QuaternionStamped':
        return [(ORIENTATION, _quat(m.quaternion), None, m.header.frame_id)]
    if type_name == 'geometry_msgs/msg/Vector3Stamped':
        return [(RATE, _vec(m.vector), None, m.header.frame_id)]
    if type_name == 'sensor_msgs/msg/Imu':
        out = []
        if m.orientation_covariance[0] != -1:
            out.append((ORIENTATION, _quat(m.orientation), _cov3(m.orientation_covariance),
                        m.header.frame_id))
        if m.angular_velocity_covariance[0] != -1:
            out.append((RATE, _vec(m.angular_velocity),
                        _cov3(m.angular_velocity_covariance), m.header.frame_id))
        return out
    if type_name == 'nav_msgs/msg/Odometry':
        return [(ORIENTATION, _quat(m.pose.pose.orientation), _block(m.pose.covariance),
                 m.header.frame_id),
                (RATE, _vec(m.twist.twist.angular), _block(m.twist.covariance),
                 m.child_frame_id)]
    if type_name == 'geometry_msgs/msg/PoseStamped':
        return [(ORIENTATION, _quat(m.pose.orientation), None, m.header.frame_id)]
    if type_name == 'geometry_msgs/msg/PoseWithCovarianceStamped':
        return [(ORIENTATION, _quat(m.pose.pose.orientation), _block(m.pose.covariance),
                 m.header.frame_id)]
    if type_name == 'geometry_msgs/msg/TransformStamped':
        return [(ORIENTATION, _quat(m.transform.rotation), None, m.header.frame_id)]
    raise KeyError(type_name)


def unscorable_reason(topic, type_name):
    """Why ``topic`` of ``type_name`` cannot be scored, or None if it can."""
    if type_name == 'std_msgs/msg/String' and topic.endswith('/run'):
        return 'run description (used as the truth, not scored)'
    if type_name not in SUPPORTED:
        return f'{type_name} carries no attitude or body rate this tool reads'
    if (type_name == 'geometry_msgs/msg/Vector3Stamped'
            and topic.rstrip('/').split('/')[-1] in _INCREMENTS):
        return 'an increment over the IMU interval, not a rate: not scored against omega'
    return None


def _check_cov(c):
    """(covariance or None, status) with status 'ok', 'unknown' or 'unusable'."""
    if not np.all(np.isfinite(c)):
        return None, 'unusable'
    if not np.any(c):
        return None, 'unknown'
    if not np.allclose(c, c.T, rtol=1e-9, atol=0.0):
        return None, 'unusable'
    try:
        np.linalg.cholesky(c)
    except np.linalg.LinAlgError:
        return None, 'unusable'
    return c, 'ok'


def decode_bag(bag, topics=None):
    """Decode a :class:`~rigidrot_ros.bag.BagContents` into scorable streams.

    Parameters
    ----------
    bag : BagContents
        The log.
    topics : list of str, optional
        Only these topics (each must exist and be scorable; ValueError otherwise).

    Returns
    -------
    streams : list of Stream
        One per (topic, field), in the bag's topic order.
    skipped : list of dict
        ``{'topic', 'type', 'reason'}`` for each topic that cannot be scored.
    """
    names = list(bag.topics) if not topics else list(topics)
    skipped = []
    wanted = []
    for t in names:
        if t not in bag.topics:
            raise ValueError(f'{bag.path}: no topic {t!r} in the log (it has '
                             f'{sorted(bag.topics)})')
        type_name = bag.topics[t][0]
        why = unscorable_reason(t, type_name)
        if why is not None:
            if topics:
                raise ValueError(f'{bag.path}: topic {t!r} is {type_name}: {why}; '
                                 f'scorable types: {", ".join(SUPPORTED)}')
            skipped.append({'topic': t, 'type': type_name, 'reason': why})
            continue
        wanted.append(t)
    factory = DecoderFactory()
    by_topic = {t: [] for t in wanted}
    for topic, _, _, _, data in bag.messages:
        if topic in by_topic:
            by_topic[topic].append(data)
    streams = []
    for n, t in enumerate(wanted):
        type_name, _, text = bag.topics[t]
        # the factory caches decoders by schema id: one id per topic
        decode = factory.decoder_for('cdr', Schema(id=n + 1, name=type_name,
                                                   encoding='ros2msg',
                                                   data=text.encode('utf-8')))
        rows = {}
        for data in by_topic[t]:
            try:
                m = decode(data)
                fields = _fields(type_name, m)
            except Exception as exc:  # noqa: B902 - a malformed message, named below
                skipped.append({'topic': t, 'type': type_name,
                                'reason': f'a message does not decode as {type_name}: '
                                          f'{type(exc).__name__}: {exc}'})
                rows = None
                break
            for fld, value, cov, frame in fields:
                rows.setdefault(fld, []).append((_stamp(m), value, cov, frame))
        if rows is None:
            continue
        if not by_topic[t]:
            skipped.append({'topic': t, 'type': type_name, 'reason': 'no messages'})
            continue
        if not rows:
            skipped.append({'topic': t, 'type': type_name,
                            'reason': 'every field is marked "no estimate" (covariance[0] '
                                      '= -1)'})
            continue
        for fld, items in rows.items():
            streams.append(_stream(t, type_name, fld, items))
    return streams, skipped


def _stream(topic, type_name, fld, items):
    n = len(items)
    width = 4 if fld == ORIENTATION else 3
    stamps = np.array([i[0] for i in items], dtype=np.int64)
    values = np.array([i[1] for i in items], dtype=float).reshape(n, width)
    s = Stream(topic=topic, type=type_name, field=fld, stamps=stamps, values=values,
               frame_id=items[0][3] if items else '')
    bad = ~np.all(np.isfinite(values), axis=1)
    if fld == ORIENTATION:
        norm = np.linalg.norm(values, axis=1)
        bad |= ~((norm > 0.5) & (norm < 2.0))
        with np.errstate(invalid='ignore', divide='ignore'):
            s.values = values / norm[:, None]
    s.values[bad] = np.nan
    s.invalid = int(bad.sum())
    if any(i[2] is not None for i in items):
        cov = np.full((n, 3, 3), np.nan)
        given = [k for k, i in enumerate(items) if i[2] is not None]
        for k, status in zip(given, _check_covs([items[k][2] for k in given])):
            if status == 'ok':
                cov[k] = items[k][2]
            elif status == 'unknown':
                s.cov_unknown += 1
            else:
                s.cov_unusable += 1
        s.cov = cov if s.cov_unknown < n else None
    return s


def _check_covs(covs):
    """:func:`_check_cov`'s status of each 3x3 of ``covs``, the checks made on all at once.

    The same tests, element by element as ``np.allclose`` makes them (``|c - c^T| <=
    rtol |c^T|``, or equal) and a Cholesky factorisation of each (LAPACK's, one matrix at
    a time either way); a stack one matrix of which fails it is checked one by one.
    """
    if not covs:
        return []
    c = np.array(covs, dtype=float).reshape(len(covs), 3, 3)
    status = np.full(len(c), 'unusable', dtype=object)
    finite = np.all(np.isfinite(c), axis=(1, 2))
    nonzero = np.any(c, axis=(1, 2))
    status[finite & ~nonzero] = 'unknown'
    cand = np.nonzero(finite & nonzero)[0]
    ct = np.swapaxes(c[cand], 1, 2)
    close = (np.abs(c[cand] - ct) <= 0.0 + 1e-9 * np.abs(ct)) | (c[cand] == ct)
    cand = cand[np.all(close, axis=(1, 2))]
    try:
        np.linalg.cholesky(c[cand])
        status[cand] = 'ok'
    except np.linalg.LinAlgError:
        for k in cand:
            status[k] = _check_cov(c[k])[1]
    return status.tolist()


def message_rows(type_name, msg):
    """Return ``(stamp_ns, [(field, value, covariance or None, frame), ...])`` of a message.

    What :func:`decode_bag` reads of one message of a supported type, taken from a
    message object in memory (an rclpy message, or one decoded from a bag) and copied, so
    a message changed after this call does not change what is scored. KeyError for a type
    that is not supported.
    """
    fields = [(fld, tuple(float(x) for x in value),
               None if cov is None else np.array(cov, dtype=float), frame)
              for fld, value, cov, frame in _fields(type_name, msg)]
    return _stamp(msg), fields


def stream_of_rows(topic, type_name, fld, rows):
    """Return the :class:`Stream` of field ``fld`` of ``rows`` (:func:`message_rows`), or None.

    The stream :func:`decode_bag` makes of the same messages in a bag, which reads them in
    log-time order (the campaign logs an estimate at its stamp): the rows are taken in
    stamp order, rows of one stamp in the order given. None when no row has the field.
    """
    order = sorted(range(len(rows)), key=lambda k: rows[k][0])
    items = [(rows[k][0], value, cov, frame) for k in order
             for f, value, cov, frame in rows[k][1] if f == fld]
    return _stream(topic, type_name, fld, items) if items else None
