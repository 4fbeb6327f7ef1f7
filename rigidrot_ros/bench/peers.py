"""The peers: numerical integrators of Euler's equations and the attitude kinematics.

All share one problem definition, the :class:`~rigidrot_ros.core.Scene`: state
``(omega_B, q_NB[, f])`` with ``I dw/dt = m_B - w x I w`` and ``dq/dt = q ⊗ (w, 0) / 2``;
for ``torque_frame='virtual'`` the torque in B turns about the symmetry axis by ``-f``,
``df/dt = ((I - I3)/I) r`` (the scene's definition). Every method returns ``q_NB`` at the
requested times; a method that exceeds its time budget raises :class:`TimeBudget`.
"""

import math
import time

import numpy as np
from scipy.integrate import solve_ivp

from rigidrot_ros.core import quaternion as quat

__all__ = ['TimeBudget', 'scipy_ivp', 'scipy_ivp_lean', 'rk4', 'rkmk4', 'magnus4', 'PEERS']


class TimeBudget(RuntimeError):
    """The method ran past its time budget."""


def _problem(scene):
    inertia = np.array(scene.inertia)
    m = np.array(scene.torque)
    k = None
    if scene.torque_frame == 'virtual':
        k = [j for j in range(3) if inertia[(j + 1) % 3] == inertia[(j + 2) % 3]][0]
    ratio = 0.0
    if k is not None:
        ip, i3 = inertia[(k + 1) % 3], inertia[k]
        ratio = (ip - i3) / ip

    def torque(f):
        if k is None:
            return m
        c, s = math.cos(f), math.sin(f)
        i1, i2 = (k + 1) % 3, (k + 2) % 3
        out = m.copy()
        out[i1] = c * m[i1] + s * m[i2]
        out[i2] = -s * m[i1] + c * m[i2]
        return out

    def dyn(w, f):
        """(dw/dt, df/dt)."""
        dw = (torque(f) - np.cross(w, inertia * w)) / inertia
        return dw, (ratio * w[k] if k is not None else 0.0)

    return dyn


def _deadline(budget):
    end = time.process_time() + budget

    def check():
        if time.process_time() > end:
            raise TimeBudget(f'over {budget:g} s of CPU time')
    return check


def _ivp_quaternions(rhs, scene, t_eval, method, rtol, atol):
    """Integrate ``rhs`` on (omega, q, f) from the scene's start; unit q at ``t_eval``."""
    y0 = np.concatenate([scene.omega0, scene.attitude0, [0.0]])
    t_eval = np.atleast_1d(np.asarray(t_eval, dtype=float))
    r = solve_ivp(rhs, (0.0, float(t_eval[-1])), y0, method=method, rtol=rtol,
                  atol=rtol if atol is None else atol, t_eval=t_eval)
    if not r.success:
        raise ArithmeticError(r.message)
    q = r.y[3:7].T
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def scipy_ivp(scene, t_eval, method='DOP853', rtol=1e-10, atol=None, budget=60.0):
    """Integrate with scipy ``solve_ivp`` on (omega, q, f); q renormalised at output only."""
    dyn = _problem(scene)
    check = _deadline(budget)

    def rhs(t, y):
        check()
        dw, df = dyn(y[:3], y[7])
        dq = 0.5 * quat.multiply(y[3:7], np.append(y[:3], 0.0))
        return np.concatenate([dw, dq, [df]])

    return _ivp_quaternions(rhs, scene, t_eval, method, rtol, atol)


def scipy_ivp_lean(scene, t_eval, method='DOP853', rtol=1e-10, atol=None, budget=60.0):
    """:func:`scipy_ivp` with the right-hand side in plain floats (no small-array numpy).

    The same equations; about 4x cheaper per step than the array form measured here, so
    the ratios against it are the honest ones for a user who writes a lean integrator.
    """
    i1, i2, i3 = (float(v) for v in scene.inertia)
    m = [float(v) for v in scene.torque]
    k = None
    if scene.torque_frame == 'virtual':
        inertia = scene.inertia
        k = [j for j in range(3) if inertia[(j + 1) % 3] == inertia[(j + 2) % 3]][0]
        ip, ik = inertia[(k + 1) % 3], inertia[k]
        ratio = (ip - ik) / ip
        a1, a2 = (k + 1) % 3, (k + 2) % 3
    check = _deadline(budget)
    n_calls = [0]

    def rhs(t, y):
        n_calls[0] += 1
        if n_calls[0] % 256 == 0:
            check()
        w1, w2, w3, x, yq, z, w, f = y
        m1, m2, m3 = m
        df = 0.0
        if k is not None:
            c, s = math.cos(f), math.sin(f)
            mb = list(m)
            mb[a1] = c * m[a1] + s * m[a2]
            mb[a2] = -s * m[a1] + c * m[a2]
            m1, m2, m3 = mb
            df = ratio * (w1, w2, w3)[k]
        return np.array([
            (m1 - (i3 - i2) * w2 * w3) / i1, (m2 - (i1 - i3) * w3 * w1) / i2,
            (m3 - (i2 - i1) * w1 * w2) / i3,
            0.5 * (w * w1 + yq * w3 - z * w2), 0.5 * (w * w2 + z * w1 - x * w3),
            0.5 * (w * w3 + x * w2 - yq * w1), -0.5 * (x * w1 + yq * w2 + z * w3), df])

    return _ivp_quaternions(rhs, scene, t_eval, method, rtol, atol)


def _fixed_grid(t_eval, h):
    """Step count per output interval so that every output time is hit exactly."""
    t_eval = np.atleast_1d(np.asarray(t_eval, dtype=float))
    edges = np.concatenate([[0.0], t_eval])
    return t_eval, [max(1, int(round((b - a) / h))) for a, b in zip(edges[:-1], edges[1:])]


def rk4(scene, t_eval, h, budget=60.0):
    """Classic fixed-step RK4 on (omega, q, f), renormalising q after every step."""
    dyn = _problem(scene)
    check = _deadline(budget)
    t_eval, counts = _fixed_grid(t_eval, h)

    def rhs(y):
        dw, df = dyn(y[:3], y[7])
        dq = 0.5 * quat.multiply(y[3:7], np.append(y[:3], 0.0))
        return np.concatenate([dw, dq, [df]])

    y = np.concatenate([scene.omega0, scene.attitude0, [0.0]])
    out, t = [], 0.0
    for t_next, n in zip(t_eval, counts):
        hh = (t_next - t) / n
        for _ in range(n):
            k1 = rhs(y)
            k2 = rhs(y + 0.5 * hh * k1)
            k3 = rhs(y + 0.5 * hh * k2)
            k4 = rhs(y + hh * k3)
            y = y + hh / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            y[3:7] /= np.linalg.norm(y[3:7])
            check()
        t = t_next
        out.append(y[3:7].copy())
    return np.array(out)


def _dexpinv(theta, w):
    """Right-trivialised dexp^-1 to fourth order: w + theta x w / 2 + theta x (theta x w) / 12."""
    c = np.cross(theta, w)
    return w + 0.5 * c + np.cross(theta, c) / 12.0


def rkmk4(scene, t_eval, h, budget=60.0):
    """Runge-Kutta-Munthe-Kaas 4 on SO(3) x R^3: RK4 in the Lie algebra, exact exponential.

    Per step, ``q = q_n ⊗ exp(theta)`` with ``dtheta/dt = dexpinv_{-theta}(omega)``
    integrated with omega by classical RK4; q stays unit to rounding.
    """
    dyn = _problem(scene)
    check = _deadline(budget)
    t_eval, counts = _fixed_grid(t_eval, h)

    def rhs(w, th, f):
        dw, df = dyn(w, f)
        return dw, _dexpinv(th, w), df

    w = np.array(scene.omega0, dtype=float)
    q = np.array(scene.attitude0, dtype=float)
    f = 0.0
    out, t = [], 0.0
    zero = np.zeros(3)
    for t_next, n in zip(t_eval, counts):
        hh = (t_next - t) / n
        for _ in range(n):
            a1, b1, c1 = rhs(w, zero, f)
            a2, b2, c2 = rhs(w + 0.5 * hh * a1, 0.5 * hh * b1, f + 0.5 * hh * c1)
            a3, b3, c3 = rhs(w + 0.5 * hh * a2, 0.5 * hh * b2, f + 0.5 * hh * c2)
            a4, b4, c4 = rhs(w + hh * a3, hh * b3, f + hh * c3)
            w = w + hh / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)
            theta = hh / 6.0 * (b1 + 2 * b2 + 2 * b3 + b4)
            f = f + hh / 6.0 * (c1 + 2 * c2 + 2 * c3 + c4)
            q = quat.multiply(q, quat.from_rotvec(theta))
            check()
        t = t_next
        out.append(q.copy())
    return np.array(out)


def magnus4(scene, t_eval, h, omega, budget=60.0):
    """Fourth-order Magnus (two Gauss points) for the kinematics, given omega(t).

    ``q_{n+1} = q_n ⊗ exp(h (w1 + w2) / 2 + sqrt(3) h^2 (w1 x w2) / 12)``, with w1, w2 the
    body rates at the Gauss points. ``omega`` maps an array of times to rates (here the
    exact dynamics), so only the kinematics is integrated.
    """
    check = _deadline(budget)
    t_eval, counts = _fixed_grid(t_eval, h)
    q = np.array(scene.attitude0, dtype=float)
    out, t = [], 0.0
    g = math.sqrt(3.0) / 6.0
    for t_next, n in zip(t_eval, counts):
        hh = (t_next - t) / n
        starts = t + hh * np.arange(n)
        w1 = omega(starts + (0.5 - g) * hh)
        w2 = omega(starts + (0.5 + g) * hh)
        theta = 0.5 * hh * (w1 + w2) + (math.sqrt(3.0) / 12.0) * hh * hh * np.cross(w1, w2)
        steps = quat.from_rotvec(theta)
        for s in steps:
            q = quat.multiply(q, s)
            check()
        t = t_next
        out.append(q.copy())
    return np.array(out)


PEERS = ('DOP853', 'RK45', 'RK4', 'RKMK4', 'Magnus4')
