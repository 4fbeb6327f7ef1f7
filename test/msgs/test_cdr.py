"""The vectorised CDR writer against rclpy's serializer, byte for byte, over random values."""

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from rosbags.typesys import get_typestore, Stores

from rigidrot_ros.msgs import cdr
from rigidrot_ros.msgs import messages as msgs

_STORE = get_typestore(Stores.ROS2_JAZZY)
#: frame ids of every length mod 8 (each shifts the alignment of what follows), non-ASCII,
#: and long
FRAMES = ['', 'b', 'ab', 'abc', 'body', 'inner', 'inertia', 'inertial', 'sat1/body_frame',
          'é', 'x' * 257, 'frame/' * 40]
#: extremes of the stamp (int32 seconds) and of float64 (no NaN)
STAMPS = [0, 1, 999_999_999, 1_000_000_000, 2 ** 31 * 1_000_000_000 - 1,
          -2 ** 31 * 1_000_000_000, -1]
EXTREMES = [0.0, -0.0, 5e-324, -5e-324, 2.2250738585072014e-308, 1.7976931348623157e308,
            -1.7976931348623157e308, np.inf, -np.inf, 1.0, -1.0, np.pi]


def _rclpy_bytes(msg):
    """rclpy's bytes of ``msg``, padding zeroed by an independent serializer (rosbags).

    Fast CDR leaves the padding after a string as its buffer held it; rosbags writes the
    same layout with zero padding, so its re-serialization keeps every value byte of
    rclpy's and fixes only those.
    """
    raw = serialize_message(msg)
    name = cdr.type_name_of(msg)
    canon = bytes(_STORE.serialize_cdr(_STORE.deserialize_cdr(raw, name), name))
    assert len(canon) == len(raw)
    return raw, canon


def _values(rng, n, width):
    v = rng.standard_normal((n, width)) * 10.0 ** rng.integers(-300, 300, (n, width))
    pick = rng.random((n, width)) < 0.3
    v[pick] = rng.choice(EXTREMES, size=int(pick.sum()))
    return v


def _stamps(rng, n):
    s = rng.integers(-2 ** 62, 2 ** 62, n) // 2 ** 31     # within int32 seconds
    s[: min(n, len(STAMPS))] = STAMPS[: min(n, len(STAMPS))]
    return s


def _check(batch, built):
    assert len(batch) == len(built)
    for i, msg in enumerate(built):
        raw, canon = _rclpy_bytes(msg)
        mine = batch[i]
        assert mine == canon, (i, msg)
        # every byte rclpy wrote as a value is ours too; ours differ only in zero padding
        diff = [j for j in range(len(raw)) if raw[j] != mine[j]]
        assert all(mine[j] == 0 for j in diff)


@pytest.mark.parametrize('frame', FRAMES)
def test_stamped_vectors_and_quaternions(frame):
    rng = np.random.default_rng(len(frame))
    n = 40
    st, q, v = _stamps(rng, n), _values(rng, n, 4), _values(rng, n, 3)
    _check(cdr.attitude(st, q, frame),
           [msgs.attitude(msgs.stamp(s), frame, qq) for s, qq in zip(st, q)])
    _check(cdr.vector(st, v, frame),
           [msgs.vector(msgs.stamp(s), frame, vv) for s, vv in zip(st, v)])


@pytest.mark.parametrize('frame', FRAMES)
def test_imu_and_star_tracker(frame):
    rng = np.random.default_rng(100 + len(frame))
    n = 30
    st, w, var = _stamps(rng, n), _values(rng, n, 3), np.abs(_values(rng, n, 1))[:, 0]
    _check(cdr.imu(st, w, var, frame),
           [msgs.imu(msgs.stamp(s), frame, ww, vv) for s, ww, vv in zip(st, w, var)])
    q = _values(rng, n, 4)
    cov = _values(rng, n, 9).reshape(n, 3, 3)
    _check(cdr.star_tracker(st, q, cov, frame),
           [msgs.star_tracker(msgs.stamp(s), frame, qq, cc) for s, qq, cc in zip(st, q, cov)])


@pytest.mark.parametrize('frame', FRAMES)
def test_imu_with_accelerometer_and_magnetic_field(frame):
    rng = np.random.default_rng(200 + len(frame))
    n = 30
    st, w, f = _stamps(rng, n), _values(rng, n, 3), _values(rng, n, 3)
    var, avar = np.abs(_values(rng, n, 2)).T
    _check(cdr.imu(st, w, var, frame, f, avar),
           [msgs.imu(msgs.stamp(s), frame, ww, vv, ff, aa)
            for s, ww, vv, ff, aa in zip(st, w, var, f, avar)])
    m, cov = _values(rng, n, 3), _values(rng, n, 9).reshape(n, 3, 3)
    _check(cdr.magnetic_field(st, m, cov, frame),
           [msgs.magnetic_field(msgs.stamp(s), frame, mm, cc) for s, mm, cc in zip(st, m, cov)])
    with pytest.raises(ValueError, match='accel_variance'):
        cdr.imu(st, w, var, frame, f)


@pytest.mark.parametrize('frame, child', [(a, b) for a in FRAMES[:9] for b in
                                          ('', 'b', 'body', 'inertial', 'x' * 13)]
                         + [(FRAMES[-1], FRAMES[-2])])
def test_transform_and_odometry(frame, child):
    rng = np.random.default_rng(len(frame) * 31 + len(child))
    n = 12
    st, q, w = _stamps(rng, n), _values(rng, n, 4), _values(rng, n, 3)
    # variances as the node makes them (squares: finite, or inf, never NaN in the eye)
    av, rv = np.abs(rng.standard_normal(n)) ** 2, np.abs(rng.standard_normal(n)) * 1e-30
    _check(cdr.transform(st, q, frame, child),
           [msgs.transform(msgs.stamp(s), frame, child, qq) for s, qq in zip(st, q)])
    _check(cdr.odometry(st, q, w, av, rv, frame, child),
           [msgs.odometry(msgs.stamp(s), frame, child, qq, ww, attitude_variance=a,
                          rate_variance=r) for s, qq, ww, a, r in zip(st, q, w, av, rv)])


def test_batch_shapes_and_errors():
    b = cdr.vector([1, 2, 3], np.zeros((3, 3)), 'body')
    assert len(b) == 3 and b.size == len(b[0]) and b.tolist() == list(b)
    assert len(cdr.vector([], np.zeros((0, 3)), 'body')) == 0
    with pytest.raises(ValueError, match=r'\(n, 3\), got \(2, 4\)'):
        cdr.vector([1, 2], np.zeros((2, 4)), 'body')
    with pytest.raises(ValueError, match=r'\(2, 3\), got \(3, 3\)'):
        cdr.serialize_batch('Vector3Stamped', [1, 2], np.zeros((3, 3)), 'body')
    with pytest.raises(ValueError, match='int32'):
        cdr.vector([2 ** 31 * 1_000_000_000], np.zeros((1, 3)), 'body')
    with pytest.raises(ValueError, match='frame ids'):
        cdr.transform([1], np.zeros((1, 4)), 'n', None)


@pytest.mark.parametrize('frame', FRAMES)
def test_body_markers_from_their_template(frame):
    """msgs.template.markers against rclpy's bytes of messages.body_markers, row by row."""
    from rigidrot_ros.msgs import template
    rng = np.random.default_rng(len(frame) + 7)
    n = 12
    st, q = _stamps(rng, n), _values(rng, n, 4)
    for inertia in ((2.0, 2.0, 1.0), (1.0, 2.0, 3.0)):
        _check(template.markers(st, q, frame, inertia),
               [msgs.body_markers(msgs.stamp(s), frame, qq, inertia) for s, qq in zip(st, q)])
    with pytest.raises(ValueError, match=r'\(2, 4\)'):
        template.markers([1, 2], np.zeros((3, 4)), frame, (1.0, 1.0, 1.0))


@pytest.mark.parametrize('text', ['', 'a', 'abcd', 'é', '{"rigidrot_run": 1}' * 50])
def test_a_string_message(text):
    from std_msgs.msg import String
    raw = cdr.string(text)
    assert raw == serialize_message(String(data=text))
    assert _STORE.deserialize_cdr(raw, 'std_msgs/msg/String').data == text
