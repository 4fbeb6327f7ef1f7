"""Accuracy of every model against references that share no formula with it.

- scipy DOP853 at rtol = atol = 2.5e-14 on Euler's equations and quaternion kinematics:
  within the claim (1e-12 rad; 32 eps |omega| for the rate) plus the reference's own error
  (its distance to the same integration at 1e-13, ``conftest.reference``);
- the other special-function backend at its tightest tolerance, to t = 1e3 s;
- invariants: unit quaternions, orthonormal R_NB, continuity, the initial state;
- residuals of the kinematics (dR/dt = R Omega(omega)) and of Euler's equations.
"""

import numpy as np
from numpy.testing import assert_allclose
import pytest

from conftest import ALL_MODELS, CLAIM, HYPER_MODELS, random_scene, rate_claim, reference
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import solve

EPS = np.finfo(float).eps
BACKENDS = ['flint', 'mpmath']


@pytest.mark.parametrize('backend', BACKENDS)
@pytest.mark.parametrize('model', ALL_MODELS)
def test_against_dop853(model, backend, rng):
    t = np.linspace(0.0, 10.0, 21)
    for _ in range(3):
        scene = random_scene(model, rng)
        sol = solve(scene, tol=1e-12, backend=backend)
        assert sol.model == model
        s = sol.at(t)
        w_ref, q_ref, q_err, w_err = reference(scene, t)
        err = quat.angle_between(s.quaternion, q_ref)
        assert np.all(err <= CLAIM + q_err), (err - q_err).max()
        w_dev = np.linalg.norm(s.omega - w_ref, axis=-1)
        assert np.all(w_dev <= rate_claim(s.omega) + w_err), (w_dev - w_err).max()
        assert np.all(s.error_bound <= CLAIM)


@pytest.mark.parametrize('model', HYPER_MODELS)
def test_backends_agree_to_long_horizons_and_bounds_hold(model, rng):
    """flint at tol = 1e-12 against mpmath at 2e-14 (a different 1F1 code), t to 1e3 s."""
    t = np.concatenate([np.linspace(0.0, 10.0, 6), [31.6, 100.0, 316.2, 1000.0]])
    scene = random_scene(model, rng)
    fast = solve(scene, tol=1e-12, backend='flint').at(t)
    ref = solve(scene, tol=2e-14, backend='mpmath', max_prec=8192).at(t)
    err = quat.angle_between(fast.quaternion, ref.quaternion)
    assert err.max() <= 1e-12
    assert np.all(err <= fast.error_bound + ref.error_bound)
    assert_allclose(fast.omega, ref.omega, rtol=1e-14, atol=1e-13)
    # and the other way round: mpmath at 1e-12 against flint's certified 2e-14
    fast_m = solve(scene, tol=1e-12, backend='mpmath').at(t)
    ref_f = solve(scene, tol=2e-14, backend='flint', max_prec=8192).at(t)
    err_m = quat.angle_between(fast_m.quaternion, ref_f.quaternion)
    assert np.all(err_m <= fast_m.error_bound + ref_f.error_bound)


@pytest.mark.parametrize('model', ALL_MODELS)
def test_initial_state_and_invariants(model, rng):
    scene = random_scene(model, rng)
    sol = solve(scene)
    s0 = sol.at(0.0)
    q0 = np.array(scene.attitude0)
    assert quat.angle_between(s0.quaternion, q0) <= 1e-15
    assert_allclose(s0.quaternion, q0, rtol=0, atol=1e-15)   # same sign, not only same attitude
    assert_allclose(s0.omega, scene.omega0, rtol=0, atol=1e-15)
    t = np.linspace(0.0, 20.0, 2001)
    s = sol.at(t)
    assert_allclose(np.linalg.norm(s.quaternion, axis=-1), 1.0, rtol=0, atol=8 * EPS)
    r = s.rotation
    assert_allclose(r @ np.swapaxes(r, -1, -2), np.broadcast_to(np.eye(3), r.shape),
                    rtol=0, atol=1e-14)
    assert_allclose(np.linalg.det(r), 1.0, rtol=0, atol=1e-14)
    # continuity: no sign flips, steps no larger than |omega| dt allows
    dots = np.einsum('ij,ij->i', s.quaternion[1:], s.quaternion[:-1])
    assert np.all(dots > 0)
    step = quat.angle_between(s.quaternion[1:], s.quaternion[:-1])
    wmax = np.linalg.norm(s.omega, axis=-1).max()
    assert np.all(step <= wmax * (t[1] - t[0]) * (1 + 1e-6) + 1e-12)


def _virtual_angle(scene, k, t):
    ip, i3 = scene.inertia[(k + 1) % 3], scene.inertia[k]
    r0, m3 = scene.omega0[k], scene.torque[k]
    return (ip - i3) / ip * (r0 * t + m3 / i3 * t ** 2 / 2)   # integral of ((I-I3)/I) r dt


def _derivative(fun, t, h=1e-3):
    """Fourth-order central difference: truncation ~h^4 |w|^5 / 30, rounding ~eps / h."""
    return (8 * (fun(t + h) - fun(t - h)) - (fun(t + 2 * h) - fun(t - 2 * h))) / (12 * h)


@pytest.mark.parametrize('model', ALL_MODELS)
def test_kinematic_and_euler_residuals(model, rng):
    """Finite differences of the returned samples satisfy Eq. 3 and Eq. 4."""
    scene = random_scene(model, rng)
    sol = solve(scene)
    t = np.linspace(0.5, 9.5, 10)
    s = sol.at(t)
    # kinematics: dR/dt = R Omega(omega)
    dr = _derivative(lambda x: sol.at(x).rotation, t)
    wx, wy, wz = s.omega.T
    zero = np.zeros_like(wx)
    omega_hat = np.stack([np.stack([zero, -wz, wy], -1), np.stack([wz, zero, -wx], -1),
                          np.stack([-wy, wx, zero], -1)], -2)
    assert_allclose(dr, s.rotation @ omega_hat, rtol=0, atol=1e-8)
    # dynamics: I dw/dt + w x I w = m_B
    inertia = np.array(scene.inertia)
    dw = _derivative(lambda x: sol.at(x).omega, t)
    m_b = np.broadcast_to(np.array(scene.torque), dw.shape).copy()
    if scene.torque_frame == 'virtual':
        k = [j for j in range(3) if inertia[(j + 1) % 3] == inertia[(j + 2) % 3]][0]
        f = _virtual_angle(scene, k, t)
        i1, i2 = (k + 1) % 3, (k + 2) % 3
        m = np.array(scene.torque)
        m_b[:, i1] = np.cos(f) * m[i1] + np.sin(f) * m[i2]
        m_b[:, i2] = -np.sin(f) * m[i1] + np.cos(f) * m[i2]
    resid = inertia * dw + np.cross(s.omega, inertia * s.omega) - m_b
    assert_allclose(resid, 0.0, atol=1e-8)


def test_angular_momentum_is_conserved_without_torque(rng):
    """Torque-free: h_N = R_NB I omega_B is constant (a closed-form invariant)."""
    for model in ('torque-free-sphere', 'torque-free-axisymmetric'):
        scene = random_scene(model, rng)
        s = solve(scene).at(np.linspace(0.0, 1000.0, 101))
        h = np.einsum('nij,nj->ni', s.rotation, np.array(scene.inertia) * s.omega)
        assert_allclose(h, np.broadcast_to(h[0], h.shape), rtol=0,
                        atol=1e-12 * np.linalg.norm(h[0]))


def test_angular_momentum_grows_linearly_for_a_sphere(rng):
    """Sphere, body-fixed torque: dh_N/dt = R_NB m_B, checked by central differences."""
    scene = random_scene('sphere', rng)
    sol = solve(scene)
    t = np.linspace(1.0, 50.0, 8)
    inertia = np.array(scene.inertia)

    def h_n(x):
        s = sol.at(x)
        return np.einsum('nij,nj->ni', s.rotation, inertia * s.omega)

    dh = _derivative(h_n, t, h=1e-4)
    assert_allclose(dh, sol.at(t).rotation @ np.array(scene.torque), rtol=0, atol=1e-8)


def test_degenerate_limits_are_continuous():
    """p0, q0 -> 0 (hypergeometric -> closed form) and r0 -> 0 meet their limits."""
    from rigidrot_ros.core import Scene
    t = np.linspace(0.0, 10.0, 11)
    base = dict(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.4), attitude0=(0.1, 0.2, 0.3, 0.9))
    limit = solve(Scene(omega0=(0.0, 0.0, 0.5), **base)).at(t)
    assert solve(Scene(omega0=(0.0, 0.0, 0.5), **base)).method == 'closed-form'
    for eps in (1e-3, 1e-6, 1e-9):
        near = solve(Scene(omega0=(eps, -eps, 0.5), **base))
        assert near.method.startswith('hypergeometric')
        err = quat.angle_between(near.at(t).quaternion, limit.quaternion).max()
        assert err <= 10 * eps * t[-1]   # the motion itself moves by O(eps t)
    # r0 = 0 exactly against r0 = +-1e-12
    zero = solve(Scene(omega0=(0.3, -0.2, 0.0), **base)).at(t)
    for r0 in (1e-12, -1e-12):
        near = solve(Scene(omega0=(0.3, -0.2, r0), **base)).at(t)
        assert quat.angle_between(near.quaternion, zero.quaternion).max() < 1e-11
