"""``omega_dot_at`` and ``torque_body_at`` against a 35-digit integration of the motion.

The reference integrates Euler's equations together with the torque's own motion in B
(constant for ``torque_frame='body'``; for ``'virtual'`` fixed in the virtual sphere S,
which turns relative to B about the symmetry axis at ``-omega_e``, ``omega_e = ((I - I3)
/ I) r``: ``dM_B/dt = omega_e M_B x e_sym``) by mpmath's Taylor-series ODE solver at 35
digits, from the scene's initial state only: none of the closed forms (Romano's rates, the
angle f(t), Jacobi functions) is used. The angular acceleration is the central finite
difference of that integrated rate (step 1e-10 s: truncation ~1e-21, rounding ~1e-25).
"""

import mpmath
from mpmath import mp
import numpy as np
from numpy.testing import assert_allclose
import pytest

from rigidrot_ros.bench import common
from rigidrot_ros.core import Scene, solve


def _scenes():
    out = common.ratio_scenes()
    # both torque frames on the oblique and transverse cases, symmetry axis not z
    out['oblique_virtual_x'] = Scene(inertia=(1.0, 2.0, 2.0), torque=(0.05, 0.03, -0.02),
                                     torque_frame='virtual', omega0=(0.6, -0.2, 0.3))
    out['transverse_virtual_y'] = Scene(inertia=(1.5, 0.8, 1.5), torque=(0.02, 0.0, -0.04),
                                        torque_frame='virtual', omega0=(0.1, -0.9, 0.25))
    out['axial_virtual'] = Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05),
                                 torque_frame='virtual', omega0=(0.3, -0.2, 0.5))
    out['fixed_axis'] = Scene(inertia=(1.0, 2.0, 3.0), torque=(0.0, 0.1, 0.0),
                              omega0=(0.0, 0.7, 0.0))
    return out


SCENES = _scenes()
TIMES = (0.0, 0.37, 1.9, 3.25)


def _reference(scene, times, h=1e-10):
    """(omega, omega_dot, torque) in B at ``times`` from a 35-digit Taylor integration."""
    with mp.workdps(35):
        inertia = [mpmath.mpf(v) for v in scene.inertia]
        m0 = [mpmath.mpf(v) for v in scene.torque]
        sym = None
        if scene.torque_frame == 'virtual':
            sym = [k for k in range(3) if inertia[(k + 1) % 3] == inertia[(k + 2) % 3]][0]
            i_t = inertia[(sym + 1) % 3]
            ratio = (i_t - inertia[sym]) / i_t

        def rhs(_, y):
            w, m = y[:3], y[3:]
            lw = [inertia[i] * w[i] for i in range(3)]
            cross = [w[1] * lw[2] - w[2] * lw[1], w[2] * lw[0] - w[0] * lw[2],
                     w[0] * lw[1] - w[1] * lw[0]]
            dw = [(m[i] - cross[i]) / inertia[i] for i in range(3)]
            dm = [mpmath.mpf(0)] * 3
            if sym is not None:
                we = ratio * w[sym]
                e = [mpmath.mpf(int(i == sym)) for i in range(3)]
                dm = [we * (m[1] * e[2] - m[2] * e[1]), we * (m[2] * e[0] - m[0] * e[2]),
                      we * (m[0] * e[1] - m[1] * e[0])]
            return dw + dm

        y0 = [mpmath.mpf(v) for v in scene.omega0] + m0
        sol = mp.odefun(rhs, 0, y0)
        out = []
        for t in times:
            t = mpmath.mpf(t)
            y = sol(t)
            if t == 0:                     # one-sided: odefun runs forward from t = 0
                ya, yb, yc = sol(t + h), sol(t + 2 * h), y
                wd = [(-3 * yc[i] + 4 * ya[i] - yb[i]) / (2 * h) for i in range(3)]
            else:
                yp, ym = sol(t + h), sol(t - h)
                wd = [(yp[i] - ym[i]) / (2 * h) for i in range(3)]
            out.append(([float(v) for v in y[:3]], [float(v) for v in wd],
                        [float(v) for v in y[3:]]))
    return [np.array(x) for x in zip(*out)]


@pytest.mark.parametrize('name', sorted(SCENES))
def test_omega_dot_and_torque_against_integration(name):
    scene = SCENES[name]
    sol = solve(scene)
    t = np.array(TIMES)
    w_ref, wd_ref, m_ref = _reference(scene, TIMES)
    scale = 1.0 + float(np.max(np.abs(w_ref))) ** 2 + float(np.max(np.abs(m_ref)))
    # the closed-form rate itself first (a wrong reference would show here)
    assert_allclose(sol.omega_at(t), w_ref, rtol=0, atol=1e-14)
    assert_allclose(sol.torque_body_at(t), m_ref, rtol=0, atol=1e-15 * scale)
    assert_allclose(sol.omega_dot_at(t), wd_ref, rtol=0, atol=2e-14 * scale)
    if scene.torque_frame == 'body':            # constant in B, bit for bit
        assert np.array_equal(sol.torque_body_at(t), np.tile(scene.torque, (len(t), 1)))


@pytest.mark.parametrize('name', ['transverse_virtual', 'torque_free_triaxial', 'spacecraft'])
def test_scalar_and_array_agree(name):
    sol = solve(SCENES[name])
    t = np.linspace(-5.0, 40.0, 7)
    for f in (sol.omega_dot_at, sol.torque_body_at, sol.omega_at):
        many = f(t)
        assert many.shape == (7, 3)
        for i, ti in enumerate(t):
            one = f(float(ti))
            assert one.shape == (3,)
            assert_allclose(one, many[i], rtol=0, atol=1e-15 * (1 + np.max(np.abs(many))))
        assert f(np.array([])).shape == (0, 3)


def test_virtual_torque_turns_and_keeps_its_size():
    sol = solve(SCENES['transverse_virtual'])
    m = sol.torque_body_at(np.linspace(0.0, 100.0, 50))
    assert_allclose(np.linalg.norm(m, axis=-1), 0.04, rtol=1e-15)
    assert np.ptp(m[:, 0]) > 0.05                     # it does turn in B


def test_bad_times_name_the_problem():
    sol = solve(SCENES['default'])
    for f in (sol.omega_dot_at, sol.torque_body_at):
        with pytest.raises(ValueError, match='t must be finite'):
            f(np.nan)
        with pytest.raises(ValueError, match='t must be a float'):
            f('soon')
