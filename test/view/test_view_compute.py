"""The view's pure parts: the box of the inertia, the 3σ and NEES, the raw stamp, roles."""

import numpy as np
from numpy.testing import assert_allclose
import pytest

from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.view import compute as cp
from rigidrot_ros.view.live import cdr_stamp, check_topic


@pytest.mark.parametrize('half', [(1.0, 0.5, 0.25), (0.3, 1.0, 0.7), (1.0, 1.0, 1.0)])
def test_the_box_has_the_inertia_it_is_drawn_for(half):
    # a uniform box's principal moments by a midpoint sum over its volume (no closed form)
    n = 40
    axes = [(np.arange(n) + 0.5) / n * 2 * h - h for h in half]
    x, y, z = np.meshgrid(*axes, indexing='ij')
    inertia = [np.mean(y ** 2 + z ** 2), np.mean(x ** 2 + z ** 2), np.mean(x ** 2 + y ** 2)]
    assert_allclose(cp.box_half_sizes(inertia), np.array(half) / max(half), rtol=2e-3)


def test_a_flat_body_still_gets_a_box():
    assert_allclose(cp.box_half_sizes([1.0, 2.0, 3.0]), [1.0, np.sqrt(1 / 2), 0.05], atol=1e-12)


def test_three_sigma_and_nees_against_samples():
    rng = np.random.default_rng(5)
    rot = quat.to_matrix(quat.from_rotvec(np.array([0.3, -1.1, 0.4])))
    sig = np.array([1e-3, 4e-3, 2e-3])
    cov = rot @ np.diag(sig ** 2) @ rot.T
    n = 20000
    e = rng.multivariate_normal(np.zeros(3), cov, size=n)
    q_true = quat.from_rotvec(rng.normal(size=(n, 3)))
    q_est = quat.multiply(q_true, quat.from_rotvec(e))     # q_est = q_true ⊗ exp(e/2)
    e_back, angle, bound3, nees = cp.attitude_errors(q_true, q_est, np.repeat(cov[None], n, 0))
    assert_allclose(e_back, e, rtol=0, atol=1e-12)
    assert_allclose(angle, np.linalg.norm(e, axis=1), rtol=0, atol=1e-12)
    assert_allclose(bound3, 3 * sig.max(), rtol=1e-12)      # 3σ along the longest axis
    assert abs(nees.mean() - 3.0) < 0.06                     # chi-square, 3 dof
    lo, hi = cp.NEES_BAND_1
    assert abs(np.mean((nees >= lo) & (nees <= hi)) - 0.95) < 0.006
    _, _, b, n_none = cp.attitude_errors(q_true[:3], q_est[:3], None)
    assert np.isnan(b).all() and np.isnan(n_none).all()


def test_the_stamp_is_read_from_the_raw_message():
    from geometry_msgs.msg import QuaternionStamped
    from rclpy.serialization import serialize_message
    m = QuaternionStamped()
    m.header.stamp.sec, m.header.stamp.nanosec = 1795816754, 273359577
    m.header.frame_id = 'world'
    assert cdr_stamp(serialize_message(m)) == 1795816754 * 10 ** 9 + 273359577


@pytest.mark.parametrize('text', ['odom:nav_msgs/msg/Odometry', '/odom', '/odom:'])
def test_a_topic_without_type_is_refused(text):
    with pytest.raises(ValueError, match='expected /name:pkg/msg/Type'):
        check_topic(text)
