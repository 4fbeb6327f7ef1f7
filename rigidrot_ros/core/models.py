"""Romano's models: :class:`Solution`, the exact motion of a spherical or axisymmetric body.

:func:`~.registry.solve` builds it for the models it is registered with
(:data:`ROMANO_MODELS`); the torque-free triaxial body is
:class:`~.triaxial.TriaxialSolution` (Jacobi elliptic functions, not reduced to the kernel
below). Both keep the contract of :class:`~.solution.BaseSolution`. The scene's model and
axis come from :func:`~.classify.classify`, its constants in the frames below from
:mod:`.constants`.

Frames: N inertial; B body (principal axes); B' the body axes cyclically permuted so that
the symmetry axis is the third; S the paper's virtual sphere (Romano, CMDA 2008, Sec. 4),
equal to B' at t = 0 and turning relative to it about the symmetry axis by ``-f(t)``; K
fixed in S with its third axis along the torque (Corollary 2). A matrix ``R_XY`` maps
Y-components to X-components, ``v_X = R_XY @ v_Y``; quaternions are (x, y, z, w), active,
``q_XY`` the quaternion of ``R_XY``. Every one of Romano's models (:data:`ROMANO_MODELS`)
is evaluated as

    q_NB(t) = q_NB(0) ⊗ q_BB' ⊗ q_SK ⊗ k(t) ⊗ q_KS ⊗ q_z(f(t)) ⊗ q_B'B,

with ``k(t)`` the spherical-body kernel in K (starting at the identity) and
``f(t) = A ((I3/I) r0 t + (m3/I) t^2 / 2)``, ``A = (I - I3)/I3`` (Eq. 27, 36, 50, 60).
"""

import math

import mpmath
from mpmath import mp
import numpy as np

from . import quaternion as quat
from .adiabatic import AdiabaticKernel
from .classify import classify
from .constants import (check_accel, const, constants_at_prec, cyclic, mag,
                        transverse_sq)
from .dense import DenseSpinor
from .kernel import (
    angle_prec, AxisKernel, ConstantKernel, HyperKernel, PolyAngle, PrecisionError,
    SETUP_PREC,
)
from .method import DELTA_SWITCH, spinor_kernel  # noqa: F401  (DELTA_SWITCH re-exported)
from .solution import BaseSolution, FLOAT_FLOOR, RateEnvelope, Samples
from .taylor import TaylorKernel

__all__ = ['Solution', 'Samples', 'FLOAT_FLOOR', 'ROMANO_MODELS']

#: Batches of at least this many times use dense output (:mod:`.dense`) where the kernel
#: suits it: one exact evaluation per checkpoint block, the exact solution's Taylor series
#: in each window. 1, so that a sample has the same bits in a batch of any size as alone
#: (the scalar path uses dense output too); tests raise it to compare with evaluating
#: sample by sample.
DENSE_MIN = 1
#: Batches are evaluated in chunks of this many samples: bounded temporary memory, and
#: temporaries small enough to be reused rather than mapped afresh (measured here: 1e6
#: samples in 0.74 s at 8192, 1.7 s at 32768).
CHUNK = 8192
#: A transverse kernel rate (rad/s) at most this, and below 2^-200 of the rate scale, is
#: neglected: the attitude bound then grows by rate * |t|, under 1e-14 rad to 1e16 s.
DROP_RATE = 1e-30
_SPINOR_KERNELS = (HyperKernel, TaylorKernel, AdiabaticKernel)

#: Romano's models (Solution evaluates these) and the paper's results they evaluate.
ROMANO_MODELS = {
    'fixed-axis': 'rotation about one principal axis (omega0 and torque along it)',
    'torque-free-sphere': 'spherical body, no torque: constant rotation (Eq. 6, 62-64)',
    'torque-free-axisymmetric': 'axisymmetric body, no torque (Theorem 5, Eq. 58-64)',
    'sphere': 'spherical body, constant body-fixed torque (Theorem 1, Corollaries 1-2)',
    'axial-torque': 'axisymmetric body, torque along the symmetry axis (Theorem 2)',
    'transverse-virtual': 'axisymmetric body, transverse torque fixed in the virtual '
                          'sphere, turning at -omega_e in the body (Theorem 3)',
    'transverse-body': 'axisymmetric body, body-fixed transverse torque, r0 = 0 (Theorem 4)',
    'oblique-virtual': 'axisymmetric body, oblique torque fixed in the virtual sphere '
                       '(Theorems 2 and 3 combined by the reduction theorem, Eq. 22-25)',
}

#: Dense output runs its Taylor recurrence in float64: it is used only where the kernel's
#: rates (and sqrt U) stay within [DENSE_RATES[0], DENSE_RATES[1]] rad/s, so that its
#: coefficients and majorants (about rate^n / n!, n up to ~40) neither overflow nor
#: underflow; elsewhere samples are evaluated one by one.
DENSE_RATES = (1e-6, 1e7)


def _dense_tmax(kernel):
    """Largest |t| to which dense output suits the kernel's rates (-1: never)."""
    if not isinstance(kernel, _SPINOR_KERNELS):
        return -1.0
    p, q, r0, u = (kernel.params[k] for k in ('p', 'q', 'r0', 'U'))
    if not all(math.isfinite(v) for v in (p, q, r0, u)):
        return -1.0
    d, top = math.hypot(p, q), DENSE_RATES[1]
    if max(d, math.sqrt(u)) < DENSE_RATES[0] or max(math.hypot(r0, d), math.sqrt(u)) > top:
        return -1.0
    # |r0| + U t <= sqrt(top^2 - d^2): the rate at t stays below the top
    return (math.sqrt(top * top - d * d) - abs(r0)) / u * (1 - 1e-12) if u > 0 else math.inf


class Solution(BaseSolution):
    """The exact motion of a spherical or axisymmetric body (Romano's models).

    Evaluate it with :meth:`at` (see :class:`~.solution.BaseSolution` for the contract).

    Attributes
    ----------
    scene : Scene
    model : str
        Which exact model covers the scene (a key of :data:`ROMANO_MODELS`).
    method : str
        How the kernel is evaluated: 'closed-form', 'hypergeometric-flint',
        'hypergeometric-mpmath', 'taylor-series-flint' (certified Taylor continuation,
        for large delta), 'hypergeometric-flint+taylor-series-flint' once single
        samples fell back from 1F1 to Taylor, or 'adiabatic-series' (delta >= 1e4; its
        error bound is an estimate, not certified).
    backend : str
        The special-function backend ('flint' or 'mpmath'), also for closed forms.
    tol : float
        Attitude accuracy asked, rad.
    """

    MODELS = ROMANO_MODELS

    def __init__(self, scene, tol, backend, max_prec):
        self.scene = scene
        self.tol = tol
        self.backend = backend
        self.model, k = classify(scene)
        self._axis = k                                         # symmetry (or fixed) axis
        perm = cyclic(k)                                      # R_B'B
        self._perm_T = perm.T
        q_b1b = quat.from_matrix(perm)                         # q_B'B
        inertia = scene.inertia
        w0 = perm @ np.array(scene.omega0)                     # omega0 in B'
        m = perm @ np.array(scene.torque)                      # torque in B' (= S at t=0)
        i_t, i_3 = inertia[(k + 1) % 3], inertia[k]        # transverse and axial moments
        if self.model == 'fixed-axis':
            i_t = i_3
        w0f = tuple(float(v) for v in w0)                 # exact: perm only permutes
        mf = tuple(float(v) for v in m)
        constants = constants_at_prec(i_t, i_3, w0f, mf)
        with mp.workprec(SETUP_PREC):
            c = constants()
            check_accel(c, scene)
            self._f = PolyAngle(const(constants, 'c1'), const(constants, 'c2'))
            q_sk, kernel = self._kernel_for(constants, w0f, mf, i_t, i_3, max_prec)
            q_sk = np.array([float(v) for v in q_sk])
            ms, mI, mI3 = c['ms'], c['mI'], c['mI3']
            self._w_s0 = np.array([float(v) for v in c['w_s']])
            self._m_over_I = np.array([float(v / mI) for v in ms])
            self._rdot = float(ms[2] / mI3)                    # d r / dt = m3 / I3
        self._compose(kernel, q_sk, q_b1b, w0, m)

    def _kernel_for(self, constants, w0f, mf, i_t, i_3, max_prec):
        """Return (q_SK, kernel) as mpf and a kernel; set ``_kin`` (see _input_error).

        A fixed axis and a torque-free scene take closed forms with K = S; under a
        torque, :meth:`_torqued_kernel`.
        """
        c = constants()
        kin = 0.0                        # rate of setup-rounding error, see _input_error
        if self.model == 'fixed-axis':
            q_sk = [mpmath.mpf(0)] * 3 + [mpmath.mpf(1)]
            kernel = AxisKernel(const(constants, 'r0'), const(constants, 'rdot'))
        elif c['mnorm'] == 0:
            q_sk = [mpmath.mpf(0)] * 3 + [mpmath.mpf(1)]
            kernel = ConstantKernel(const(constants, 'w_s'))
        else:
            q_sk = c['q_sk']
            kernel, kin = self._torqued_kernel(constants, w0f, mf, i_t, i_3, max_prec)
        self._kin = kin
        return q_sk, kernel

    def _torqued_kernel(self, constants, w0f, mf, i_t, i_3, max_prec):
        """Return (kernel, kin) for the motion in K under a torque.

        The inputs (p, q, r0, U) in K take as many bits as the transverse rate needs;
        a negligible transverse rate is dropped (AxisKernel), otherwise a spinor kernel.
        kin: the rate of the attitude error from rounding the inputs (0 if none).
        """
        c = constants()
        wk, U = c['wk'], c['U']
        wnorm = mpmath.sqrt(sum(v * v for v in wk))
        # the transverse rate |omega_S x m| / |m| in K, exactly (rationals): at
        # SETUP_PREC a tiny one would drown in the rounding of the K frame
        d2 = transverse_sq(w0f, mf, i_t, i_3)
        dk = mpmath.sqrt(mpmath.mpf(d2.numerator) / d2.denominator)
        prec_in = SETUP_PREC
        if d2 and dk < wnorm * mpmath.mpf(2) ** (64 - SETUP_PREC):
            prec_in = angle_prec(mag(wnorm) - mag(dk) + SETUP_PREC - 16)
            with mp.workprec(prec_in):
                wk, U = constants()['wk'], constants()['U']

        def inputs():
            """(p, q, r0, U) in K with at least prec_in bits."""
            with mp.workprec(max(mp.prec, prec_in)):
                c = constants()
                return c['wk'] + [c['U']]
        # a transverse rate below 2^-200 of the motion's rate scale and below
        # DROP_RATE is dropped; the kernel's bound grows by dk |t| (AxisKernel's
        # 'dropped'), checked against tol at every sample
        tiny = mpmath.mpf(2) ** (-200) * max(wnorm, mpmath.sqrt(U))
        if d2 == 0 or (dk <= tiny and dk <= DROP_RATE):
            kernel = AxisKernel(const(constants, 'wk', 2), const(constants, 'U'),
                                dropped=float(dk))
            return kernel, 0.0
        # the kernel quaternion may take 2/5 of the attitude budget
        ktol = 0.4 * (self.tol - FLOAT_FLOOR)
        kernel = spinor_kernel(wk[0], wk[1], wk[2], U, ktol, self.backend, max_prec,
                               inputs=inputs, setup_prec=prec_in)
        if isinstance(kernel, AdiabaticKernel):
            return kernel, 0.0
        # inputs (and the kernels' derived constants) rounded at prec_in bits: relative
        # error < 2^-(prec_in - 8) of the rate, so the attitude drifts by at most that
        # times the turn int |omega_K| dt <= |omega_K(0)| |t| + U t^2 / 2
        self._kin_rates = (float(wnorm), float(U))
        return kernel, 2.0 ** -(prec_in - 8)

    def _compose(self, kernel, q_sk, q_b1b, w0, m):
        """Store the kernel and the fixed quaternion factors around it (q_SK: floats)."""
        self._dense_tmax = _dense_tmax(kernel)
        # spinor kernels return |k| = 1 only to within their error: normalise them
        self._unit_fix = isinstance(kernel, _SPINOR_KERNELS)
        self._kernel = kernel
        self._dense = DenseSpinor(kernel) if self._dense_tmax >= 0 else None
        self._left = quat.multiply(
            quat.multiply(np.array(self.scene.attitude0), quat.conjugate(q_b1b)), q_sk)
        self._mid = quat.conjugate(q_sk)
        self._right = q_b1b
        # q = left ⊗ k ⊗ (cos(f/2) P0 + sin(f/2) P1): q_z(f) is linear in (cos, sin)
        eye = np.eye(4)
        self._lmat = np.stack([quat.multiply(self._left, e) for e in eye], axis=-1)
        self._p0 = quat.multiply(self._mid, self._right)
        self._p1 = quat.multiply(quat.multiply(self._mid, eye[2]), self._right)
        self._left_t, self._p0_t, self._p1_t = (
            tuple(float(v) for v in x) for x in (self._left, self._p0, self._p1))
        self._r0 = float(w0[2])
        self._m_b1 = tuple(float(v) for v in m)               # torque in B' (= S) at t = 0
        self._perm_idx = [int(np.argmax(np.abs(row))) for row in self._perm_T]
        self._floats = (float(self._w_s0[0]), float(self._w_s0[1]), float(self._m_over_I[0]),
                        float(self._m_over_I[1]))

    def _dense_at(self, tmax):
        """Whether dense output is safe up to |t| = tmax (see DENSE_RATES)."""
        return tmax <= self._dense_tmax

    def _input_error(self, t):
        """Kernel component error from rounding its inputs (prec_in bits), at |t| (array).

        The rate is off by at most ``kin`` of itself, so the attitude by at most
        ``kin * int |omega_K| dt``; a quaternion moves by half the attitude angle.
        """
        if not self._kin:
            return 0.0
        w, u = self._kin_rates
        at = np.abs(t)
        with np.errstate(over='ignore', invalid='ignore'):
            return 0.5 * self._kin * (w * at + 0.5 * u * at * at)

    def _check(self, tt, err, omega):
        """Raise where the bound exceeds tol or omega leaves the float range."""
        bad = ~(err <= self.tol)
        if np.any(bad):
            i = int(np.argmax(bad))
            raise PrecisionError(
                f'at t = {float(tt.flat[i])!r} s the attitude error bound '
                f'{float(err.flat[i]):.3g} rad exceeds tol = {self.tol:.3g} rad: {self.model} '
                f'evaluated by {self.method} ({self._why_bound()}). Use a shorter horizon or '
                f'a larger tol.')
        if not np.all(np.isfinite(omega)):
            raise ValueError(self._omega_overflow(tt, omega))

    def _why_bound(self):
        if isinstance(self._kernel, AxisKernel) and self._kernel.dropped:
            return (f'a transverse rate of {self._kernel.dropped:.3g} rad/s, below 2^-200 of '
                    f'the rate, is neglected: the bound grows by that times |t|, to the limit '
                    f'tol at |t| = {self.tol / self._kernel.dropped:.3g} s')
        if self._kin:
            return (f'its inputs carry {round(8 - math.log2(self._kin))} bits, so the bound '
                    f'grows with the turn |omega_K| |t| + U t^2 / 2, whose limit at this tol '
                    f'is about {self.tol / self._kin:.2g} rad')
        return 'the kernel bound'

    def _omega_overflow(self, tt, omega):
        bad = ~np.all(np.isfinite(np.reshape(omega, (-1, 3))), axis=-1)
        i = int(np.argmax(bad))
        return (f'at t = {float(np.reshape(tt, -1)[i])!r} s the body rate |omega0| + '
                f'|torque / inertia| |t| exceeds the float64 range (1.8e308 rad/s): '
                f'omega0 = {self.scene.omega0} rad/s, torque / inertia up to '
                f'{float(np.max(np.abs(self._m_over_I))):.3g} rad/s^2. Use a shorter horizon.')

    def _omega_b1(self, tt, f, cs=None):
        """Omega in B at times tt, f(tt) given (overflow gives inf, without a warning).

        omega_S(t) = omega_S(0) + (m/I) t; omega_B' = (Rz(-f) omega_S_perp, r(t)).
        ``cs``: (cos f, sin f) if already at hand.
        """
        with np.errstate(over='ignore', invalid='ignore'):
            a = self._w_s0[0] + self._m_over_I[0] * tt
            b = self._w_s0[1] + self._m_over_I[1] * tt
            c, s = (np.cos(f), np.sin(f)) if cs is None else cs
            w_b1 = np.stack([a * c + b * s, b * c - a * s, self._r0 + self._rdot * tt],
                            axis=-1)
            return w_b1[..., self._perm_idx]

    def rate_envelope(self):
        """Return the :class:`~.solution.RateEnvelope` of the closed-form rate.

        'linear' for a sphere or a fixed axis (omega linear in t); otherwise the
        constants of ``omega_B' = (a cos f + b sin f, b cos f - a sin f, r)`` (Eq. 39, 47,
        56, 58), ``f' = c1 + c2 t``, ``a, b, r`` linear in t.
        """
        scene = self.scene
        inertia = np.array(scene.inertia, dtype=float)
        m = np.array(scene.torque, dtype=float)
        w0 = np.array(scene.omega0, dtype=float)
        if self.model in ('fixed-axis', 'torque-free-sphere', 'sphere'):
            return RateEnvelope('linear', accel=float(np.linalg.norm(m / inertia)))
        k = self._axis
        tr = [(k + 1) % 3, (k + 2) % 3]
        i_t, i_3 = inertia[tr[0]], inertia[k]
        a = (i_t - i_3) / i_3
        # f(t) = A ((I3/I) r0 t + (m3/I) t^2 / 2): f'(x) = c1 + c2 x
        return RateEnvelope(
            'closed-form', c1=float(abs(a * i_3 / i_t * w0[k])), c2=float(abs(a * m[k] / i_t)),
            w_t=float(np.sum(np.abs(w0[tr]))), m_t=float(np.sum(np.abs(m[tr]))) / i_t,
            r0=float(abs(w0[k])), rdot=float(abs(m[k] / i_3)))

    @property
    def method(self):
        """How the kernel is evaluated ('closed-form', 'hypergeometric-flint', ...)."""
        return self._kernel.method

    @property
    def precision(self):
        """Return the bits of working precision used by the last kernel evaluation."""
        return self._kernel.prec

    def _at_array(self, tt):
        """:meth:`at` at a finite 1-D float array of times (sorted or not)."""
        n = len(tt)
        if self._kin:                                          # refuse before the work
            self._check(tt, 2.0 * self._input_error(tt) + FLOAT_FLOOR, np.zeros(3))
        q = np.empty((n, 4))
        omega = np.empty((n, 3))
        err = np.empty(n)
        if n == 0:
            return Samples(tt, q, omega, err)
        order = None
        if n > 1 and not np.all(tt[1:] >= tt[:-1]):
            order = np.argsort(tt, kind='stable')
        ts = tt if order is None else tt[order]
        # chunks from t = 0 outwards, so windows chain in their own direction
        neg = int(np.searchsorted(ts, 0.0, side='left'))
        chunks = [(max(0, e - CHUNK), e) for e in range(neg, 0, -CHUNK)]
        chunks += [(s, min(n, s + CHUNK)) for s in range(neg, n, CHUNK)]
        dense = self._dense is not None and n >= DENSE_MIN
        for a, b in chunks:
            tc = ts[a:b]
            qc, wc, ec = self._chunk(tc, dense)
            self._check(tc, ec, wc)
            if order is None:
                q[a:b], omega[a:b], err[a:b] = qc, wc, ec
            else:
                idx = order[a:b]
                q[idx], omega[idx], err[idx] = qc, wc, ec
        return Samples(tt, q, omega, err)

    def _chunk(self, tc, dense):
        """Quaternions, rates and bounds at the sorted times ``tc`` (one chunk).

        Every sample gets the bits :meth:`_at_scalar` gives it alone: the same kernel
        path (chosen per sample), and the same float operations in the same order
        (numpy's elementwise products, sums, sqrt, sin, cos and arcsin round as Python's
        do; no matrix product or reduction, whose order could depend on the batch).
        """
        m = len(tc)
        kernel = self._kernel
        k = np.empty((m, 4))
        kerr = np.empty(m)
        use = np.abs(tc) <= self._dense_tmax if dense else np.zeros(m, dtype=bool)
        if use.all():
            self._dense.many(tc, k, kerr)
        else:
            if use.any():
                kd, ed = np.empty((int(use.sum()), 4)), np.empty(int(use.sum()))
                self._dense.many(tc[use], kd, ed)
                k[use], kerr[use] = kd, ed
            rest = ~use
            if hasattr(kernel, 'evaluate_many'):
                k[rest], kerr[rest] = kernel.evaluate_many(tc[rest])
            else:
                for i in np.flatnonzero(rest):
                    k[i], kerr[i] = kernel.evaluate(float(tc[i]))
        kerr = kerr + self._input_error(tc)
        if self._unit_fix:
            # return unit quaternions at any tol: |k/|k| - k*| <= |k - k*| + ||k| - 1|
            # (as _at_scalar: only where the norm is off by more than 1e-15)
            x, y, z, w = k.T
            n2 = x * x + y * y + z * z + w * w
            off = ~(np.abs(n2 - 1.0) <= 1e-15)
            if off.any():
                norm = np.sqrt(n2[off])
                good = (norm > 0.0) & (norm < math.inf)
                ko = k[off]
                ko[good] = ko[good] / norm[good][:, None]
                ko[~good] = (0.0, 0.0, 0.0, 1.0)              # only at a meaningless tol
                k[off] = ko
                eo = kerr[off] + np.abs(norm - 1.0)
                eo[~good] = math.inf
                kerr[off] = eo
        f, ferr = self._f.angles(tc)
        h = 0.5 * f
        c, s = np.cos(h), np.sin(h)
        p0, p1 = self._p0_t, self._p1_t
        q2 = (c * p0[0] + s * p1[0], c * p0[1] + s * p1[1], c * p0[2] + s * p1[2],
              c * p0[3] + s * p1[3])
        mul = quat.multiply_floats
        q = np.stack(mul(mul(self._left_t, tuple(k.T)), q2), axis=-1)
        omega = self._omega_b1(tc, f)
        # a component error e of a unit quaternion moves the attitude by <= 2 asin(e)
        err = 2.0 * np.arcsin(np.minimum(kerr, 1.0)) + ferr + FLOAT_FLOOR
        return q, omega, err

    def _omega(self, tt):
        """Omega in B at checked times: the dynamics alone, in closed form.

        Eq. 39, 47, 56, 58: no special function is evaluated, so this is cheap.
        """
        f = self._f.angles(tt)[0]
        omega = self._omega_b1(tt, f)
        if not np.all(np.isfinite(omega)):
            raise ValueError(self._omega_overflow(tt, omega))
        return omega

    def _torque_body(self, tt):
        """Torque in B (N m) at checked times.

        'body': constant. 'virtual': constant in S, which turns relative to B' about the
        symmetry axis by ``-f(t)``, so ``M_B' = (m1 cos f + m2 sin f, m2 cos f - m1 sin f,
        m3)`` (the rotation that takes omega_S to omega_B').
        """
        shape = np.shape(tt) + (3,)
        if self.scene.torque_frame == 'body' or self._f.zero:
            return np.broadcast_to(np.array(self.scene.torque, dtype=float), shape).copy()
        f = self._f.angles(tt)[0]
        m = self._m_b1
        c, s = np.cos(f), np.sin(f)
        m_b1 = np.stack([m[0] * c + m[1] * s, m[1] * c - m[0] * s,
                         np.full(np.shape(tt), m[2])], axis=-1)
        return m_b1[..., self._perm_idx]

    def _kernel_scalar(self, t):
        """Kernel at one time as a float 4-tuple; the node's stream reuses dense windows."""
        if self._dense is not None and self._dense_at(abs(t)):
            return self._dense.at(t)
        k, kerr = self._kernel.evaluate(t)
        return tuple(k.tolist()), kerr

    def _at_scalar(self, t):
        """:meth:`at` for one time, in plain floats (the node's per-tick path)."""
        if not math.isfinite(t):
            raise ValueError('t must be finite')
        kin = 0.0
        if self._kin:                                          # python floats: fast, no warning
            w, u = self._kin_rates
            kin = 0.5 * self._kin * (w * abs(t) + 0.5 * u * t * t)
            if not 2.0 * kin + FLOAT_FLOOR <= self.tol:       # refuse before the work
                self._check(np.asarray(t), np.float64(2.0 * kin + FLOAT_FLOOR), np.zeros(3))
        k, kerr = self._kernel_scalar(t)
        kerr = kerr + kin
        if self._unit_fix:
            x, y, z, w = k
            n2 = x * x + y * y + z * z + w * w
            if not abs(n2 - 1.0) <= 1e-15:                     # off unit (coarse tol)
                norm = math.sqrt(n2)
                if 0.0 < norm < math.inf:
                    k = (x / norm, y / norm, z / norm, w / norm)
                    kerr += abs(norm - 1.0)
                else:                                          # only at a meaningless tol
                    k, kerr = (0.0, 0.0, 0.0, 1.0), math.inf
        f, ferr = self._f.angle_bound(t)
        h = 0.5 * f
        c, s = math.cos(h), math.sin(h)
        p0, p1 = self._p0_t, self._p1_t
        q2 = (c * p0[0] + s * p1[0], c * p0[1] + s * p1[1], c * p0[2] + s * p1[2],
              c * p0[3] + s * p1[3])
        mul = quat.multiply_floats
        q = mul(mul(self._left_t, k), q2)
        cf, sf = math.cos(f), math.sin(f)
        w0x, w0y, mx, my = self._floats
        a, b = w0x + mx * t, w0y + my * t                    # python floats: inf, no warning
        w_b1 = (a * cf + b * sf, b * cf - a * sf, self._r0 + self._rdot * t)
        err = 2.0 * math.asin(min(kerr, 1.0)) + ferr + FLOAT_FLOOR
        if not (err <= self.tol and math.isfinite(w_b1[0] + w_b1[1] + w_b1[2])):
            with np.errstate(over='ignore', invalid='ignore'):
                self._check(np.asarray(t), np.float64(err), np.array(w_b1) @ self._perm_T.T)
        pi = self._perm_idx
        return Samples(np.asarray(t), np.array(q),
                       np.array((w_b1[pi[0]], w_b1[pi[1]], w_b1[pi[2]])), np.float64(err))
