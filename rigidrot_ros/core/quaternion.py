"""Unit-quaternion helpers on numpy arrays.

Convention, used everywhere in rigidrot_ros: quaternions are stored ``(x, y, z, w)``
(ROS and scipy order), Hamilton product, active. ``q_NB`` rotates body vectors into the
inertial frame, and the matching matrix ``R_NB`` means ``v_N = R_NB @ v_B``.
All functions broadcast over leading axes.
"""

import math

import numpy as np

__all__ = [
    'multiply', 'conjugate', 'about_z', 'from_rotvec', 'to_matrix', 'from_matrix',
    'angle_between', 'multiply_floats', 'axis_floats',
]


def multiply(a, b):
    """Hamilton product ``a ⊗ b`` of quaternions in (x, y, z, w) order."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ], axis=-1)


def multiply_floats(a, b):
    """Hamilton product ``a ⊗ b`` of two quaternions given as float 4-tuples (x, y, z, w).

    The per-sample paths use this instead of :func:`multiply`: no array overhead.
    """
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def axis_floats(k, angle):
    """Quaternion (x, y, z, w) tuple of a rotation by ``angle`` rad about axis k (0, 1, 2)."""
    h = 0.5 * angle
    v = [0.0, 0.0, 0.0, math.cos(h)]
    v[k] = math.sin(h)
    return tuple(v)


def conjugate(q):
    """Inverse of a unit quaternion (x, y, z, w)."""
    q = np.asarray(q, dtype=float)
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def about_z(angle):
    """Quaternion (x, y, z, w) of a rotation by ``angle`` rad about the third axis."""
    angle = np.asarray(angle, dtype=float)
    zero = np.zeros_like(angle)
    return np.stack([zero, zero, np.sin(0.5 * angle), np.cos(0.5 * angle)], axis=-1)


def from_rotvec(v):
    """Quaternion (x, y, z, w) of the rotation vector ``v`` (axis times angle, rad)."""
    v = np.asarray(v, dtype=float)
    angle = np.linalg.norm(v, axis=-1)
    half = 0.5 * angle
    # sin(half)/angle, with its limit 1/2 at angle -> 0
    scale = np.where(angle > 1e-8, np.sin(half) / np.where(angle > 0, angle, 1.0),
                     0.5 - angle ** 2 / 48.0)
    return np.concatenate([v * scale[..., None], np.cos(half)[..., None]], axis=-1)


def to_matrix(q):
    """Rotation matrix of unit quaternions (x, y, z, w): ``R_NB`` from ``q_NB``."""
    q = np.asarray(q, dtype=float)
    x, y, z, w = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)


def from_matrix(r):
    """Return the unit quaternion (x, y, z, w), w >= 0, of rotation matrices (Shepperd)."""
    r = np.asarray(r, dtype=float)
    out = np.empty(r.shape[:-2] + (4,))
    flat_r = r.reshape(-1, 3, 3)
    flat_o = out.reshape(-1, 4)
    for n, m in enumerate(flat_r):
        tr = m[0, 0] + m[1, 1] + m[2, 2]
        k = int(np.argmax([m[0, 0], m[1, 1], m[2, 2], tr]))
        if k == 3:
            s = 2.0 * np.sqrt(1.0 + tr)
            q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s,
                 0.25 * s]
        else:
            i, j, n3 = k, (k + 1) % 3, (k + 2) % 3
            s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[n3, n3])
            q = [0.0, 0.0, 0.0, (m[n3, j] - m[j, n3]) / s]
            q[i] = 0.25 * s
            q[j] = (m[j, i] + m[i, j]) / s
            q[n3] = (m[n3, i] + m[i, n3]) / s
        q = np.asarray(q)
        flat_o[n] = q if q[3] >= 0 else -q
    return out


def angle_between(q1, q2):
    """Rotation angle (rad, in [0, pi]) of ``conj(q1) ⊗ q2``: the attitude error between two.

    Uses ``2 atan2(|vec|, |w|)``, accurate for tiny angles (unlike ``acos``).
    """
    d = multiply(conjugate(q1), q2)
    vec = np.linalg.norm(d[..., :3], axis=-1)
    return 2.0 * np.arctan2(vec, np.abs(d[..., 3]))
