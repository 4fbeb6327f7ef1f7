"""The spherical-body kernel: attitude of a sphere under a constant torque along K3.

A body with spherical inertia I and a constant body-fixed torque along its third axis
turns with ``omega_KN_K(t) = (p, q, r0 + U t)``, ``U = |m| / I`` (Romano 2008; Sec. 3 and
Theorem 1 of Romano 2008b). Every one of Romano's models (:mod:`.models`: spherical and
axisymmetric bodies) reduces to this problem, starting from the identity attitude; the
torque-free triaxial body (:mod:`.triaxial`) does not (Jacobi elliptic functions).

Instead of the stereographic variables of Theorem 1 the kernel solves the same
kinematics in SU(2) (spinor) form. With ``q = (x, y, z, w)`` and

    v1 = w + i z,    v2 = -y + i x,    X(t) = r0 + U t,    Delta = p + i q,

the quaternion kinematics ``dq/dt = q ⊗ (omega, 0) / 2`` read

    dv1/dt = (i/2) (X v1 + conj(Delta) v2),   dv2/dt = (i/2) (Delta v1 - X v2),

a two-level system with a linearly swept diagonal (Landau-Zener). In ``s = X / sqrt(U)``
the first component solves Weber's equation ``v1'' + (s^2/4 + delta - i/2) v1 = 0``,
``delta = |Delta|^2 / (4 U)``, whose even and odd solutions are

    y_e(s) = e^{-i s^2/4} M(1/2 + i delta/2, 1/2, i s^2/2),
    y_o(s) = s e^{-i s^2/4} M(1 + i delta/2, 3/2, i s^2/2),

with Kummer's ``M = 1F1`` at the paper's argument ``z^2 = i (r0 + U t)^2 / (2U)``
(Eq. 10; the four 1F1 of Eq. 9 are exactly the four values used here, with the
paper's ``nu = -1 - i delta``). The Wronskian of (y_e, y_o) is 1, so the integration
constants follow from ``v(0) = (1, 0)`` in closed form, with no misprinted constants
(cf. Eq. 13) and no pole: the quaternion is unit by construction and continuous in t.

Two backends evaluate 1F1: python-flint (Arb, certified balls: the error bound is
rigorous) and mpmath (an error estimate from the condition of the fundamental matrix).
Working precision is raised until the bound meets the tolerance, up to a ceiling.
"""

import math

import mpmath
from mpmath import mp
import numpy as np

from .backends import (  # noqa: F401  (re-exported)
    _Exact, _FlintBackend, _mag, _MpmathBackend, _t_mag, ANGLE_GUARD_BITS, angle_prec,
    available_backends, make_backend, PrecisionError, reduce_angle, SETUP_PREC,
)
from .ddphase import DDPoly

__all__ = [
    'PrecisionError', 'SETUP_PREC', 'available_backends', 'ConstantKernel', 'AxisKernel',
    'HyperKernel', 'PolyAngle', 'angle_prec', 'reduce_angle',
]


class PolyAngle:
    """Angle ``c1 t + c2 t^2`` (rad) evaluated from exact inputs, reduced modulo 4 pi.

    Float64 would carry ``|angle| * 1e-16`` rad of error (1e-6 rad at 1e10 rad). Where
    it applies (|angle| up to about 1.4e16 rad) the angle is evaluated in double-double
    arithmetic with a proved bound (:mod:`.ddphase`); beyond, in ``SETUP_PREC`` bits, or
    ``log2 |angle| + ANGLE_GUARD_BITS`` where the angle is larger (a phase of 1e300 rad
    needs some 1080 bits), recomputing ``c1`` and ``c2`` at that precision, and reduced
    before rounding to float.

    Parameters
    ----------
    c1, c2 : mpf, float, or callable
        Numbers (taken as exact), or functions of no argument computing the coefficient
        from the scene's exact inputs at the current mpmath precision.
    """

    def __init__(self, c1, c2):
        self._c = _Exact(lambda: [c() if callable(c) else c for c in (c1, c2)])
        self.c1, self.c2 = self._c.at(SETUP_PREC)
        self.zero = (self.c1 == 0 and self.c2 == 0)
        self._c1f, self._c2f = float(self.c1), float(self.c2)
        # |c1| < 2^e1, |c2| < 2^e2 (+1 for the rounding at SETUP_PREC)
        self._e1, self._e2 = _mag(self.c1) + 1, _mag(self.c2) + 1
        # the double-double coefficients from the exact ones at 2 SETUP_PREC bits
        self._dd = DDPoly(*self._c.at(2 * SETUP_PREC))

    def prec_at(self, t):
        """Working precision (bits) that the multiple-precision path uses at t."""
        et = _t_mag(t)
        return angle_prec(max(self._e1 + et, self._e2 + 2 * et) + 1)

    def _angle_mp(self, t):
        prec = self.prec_at(t)
        c1, c2 = self._c.at(prec)
        with mp.workprec(prec):
            tt = mpmath.mpf(t)
            return reduce_angle((c1 + c2 * tt) * tt)

    def angle_bound(self, t):
        """Angle at one float t (reduced to about (-2 pi, 2 pi]) and its error bound, rad.

        The bound excludes the final rounding of the reduced angle to float64 (part of
        the composition floor of every sample).
        """
        if self.zero:
            return 0.0, 0.0
        out = self._dd.angle(t)
        if out is None:
            return self._angle_mp(t), 0.0
        return out

    def angle(self, t):
        """Angle at t (float, reduced to about (-2 pi, 2 pi])."""
        return self.angle_bound(t)[0]

    def angles(self, t):
        """Angles and their error bounds at the times ``t`` (float ndarray), rad."""
        t = np.asarray(t, dtype=float)
        if self.zero:
            return np.zeros_like(t), np.zeros_like(t)
        ang, bound, covered = self._dd.angles(t)
        if not covered.all():
            ang, bound = ang.reshape(-1), bound.reshape(-1)
            flat = t.reshape(-1)
            for i in np.flatnonzero(~covered.reshape(-1)):
                ang[i] = self._angle_mp(float(flat[i]))
                bound[i] = 0.0
            ang, bound = ang.reshape(t.shape), bound.reshape(t.shape)
        return ang, bound

    def rate(self, t):
        """Time derivative of the angle at t, rad/s."""
        return self._c1f + 2.0 * self._c2f * t


class ConstantKernel:
    """Constant angular velocity (no torque): ``q(t) = exp(omega t / 2)`` (Eq. 6, 62-64).

    ``omega`` is a list of numbers (exact) or a function computing it at the current
    mpmath precision; the angle ``|omega| t`` is formed in double-double or at the
    precision it needs (:class:`PolyAngle`).
    """

    method = 'closed-form'

    def __init__(self, omega):
        self._omega = _Exact(omega)
        self._norm = _Exact(lambda: mpmath.sqrt(sum(w * w for w in self._omega.at(mp.prec))))
        self.omega = self._omega.at(SETUP_PREC)
        self.norm = self._norm.at(SETUP_PREC)
        with mp.workprec(SETUP_PREC):
            self.axis = (np.array([float(w / self.norm) for w in self.omega])
                         if self.norm != 0 else np.zeros(3))
        self.phase = PolyAngle(lambda: self._norm.at(mp.prec), 0)
        self.prec = SETUP_PREC

    def evaluate(self, t):
        """Quaternion (x, y, z, w) at t and its error bound (quaternion norm)."""
        if self.norm == 0:
            return np.array([0.0, 0.0, 0.0, 1.0]), 0.0
        phi, err = self.phase.angle_bound(t)
        h = 0.5 * phi
        return np.append(math.sin(h) * self.axis, math.cos(h)), 0.5 * err

    def evaluate_many(self, t):
        """Quaternions (n, 4) and component-error bounds (n,) at the times ``t``."""
        t = np.asarray(t, dtype=float)
        if self.norm == 0:
            out = np.zeros(t.shape + (4,))
            out[..., 3] = 1.0
            return out, np.zeros(t.shape)
        phi, err = self.phase.angles(t)
        h = 0.5 * phi
        out = np.empty(t.shape + (4,))
        out[..., :3] = np.sin(h)[..., None] * self.axis
        out[..., 3] = np.cos(h)
        return out, 0.5 * err


class AxisKernel:
    """Rotation about K3 only (p = q = 0): angle ``r0 t + U t^2 / 2``.

    ``r0`` and ``U`` are numbers (exact) or functions computing them at the current
    mpmath precision. ``dropped`` (rad/s) is a transverse rate neglected by the caller;
    it moves the attitude by at most ``dropped * |t|``, which the error bound includes.
    """

    method = 'closed-form'

    def __init__(self, r0, U, dropped=0.0):
        def half_u():
            return (U() if callable(U) else mpmath.mpf(U)) / 2
        self.angle = PolyAngle(r0, half_u)
        self.dropped = float(dropped)
        self.prec = SETUP_PREC

    def evaluate(self, t):
        """Quaternion (x, y, z, w) at t and its error bound (quaternion norm)."""
        phi, err = self.angle.angle_bound(t)
        h = 0.5 * phi
        # an attitude error e moves the quaternion by 2 sin(e / 4) <= e / 2
        return (np.array([0.0, 0.0, math.sin(h), math.cos(h)]),
                0.5 * (err + self.dropped * abs(t)))

    def evaluate_many(self, t):
        """Quaternions (n, 4) and component-error bounds (n,) at the times ``t``."""
        phi, err = self.angle.angles(t)
        h = 0.5 * phi
        out = np.zeros(np.shape(phi) + (4,))
        out[..., 2] = np.sin(h)
        out[..., 3] = np.cos(h)
        return out, 0.5 * (err + self.dropped * np.abs(t))


class HyperKernel:
    """Torque along K3 with a transverse rate (U > 0, p + i q != 0): 1F1 spinor solution.

    Parameters
    ----------
    p, q, r0 : mpf
        ``omega_KN_K(0)``, rad/s.
    U : mpf
        Torque over inertia, rad/s^2, > 0.
    backend : str
        'flint' or 'mpmath'.
    tol : float
        Error asked of the kernel quaternion (Euclidean norm of the component error).
    max_prec : int
        Ceiling on the working precision, bits.
    fallback : callable or None
        With flint, a factory of the kernel that continues a sample when 1F1 would need
        more than ``FALLBACK_BITS`` (:func:`rigidrot_ros.core.method.hyper_kernel` passes
        the certified Taylor continuation); None: try up to ``max_prec`` and raise
        PrecisionError.
    check : bool
        Evaluate at t = 0 on construction, so that an impossible scene fails at once.
    setup_prec : int
        Bits for the derived constants (sqrt U, ...): at least those of the inputs.
    """

    #: With flint, a sample whose 1F1 would need more bits than this is continued by
    #: certified Taylor series instead (see :mod:`rigidrot_ros.core.taylor`).
    FALLBACK_BITS = 1024
    #: With flint, Kummer's functions at ``|z| = s^2 / 2`` from this up are formed from
    #: Tricomi's U (:meth:`_kummer_far`); None: always 1F1.
    FAR_Z = 100.0
    #: With flint, the far route's Tricomi U are summed at this many bits plus those of
    #: their phase (:meth:`_u_prec`), not at the working precision (whose bits go to the
    #: phase s^2 / 4 and the constants).
    U_BITS = 64
    #: ... with their asymptotic series cut where its terms fall below 2^-U_TERM_BITS
    #: (:meth:`_u_terms`; Arb's remainder bound is some 2^6 above the first term left out)
    U_TERM_BITS = 56
    #: ... and again at the working precision where their bound passes this share of tol
    #: (1/64: a dense anchor's bound stays at its floor, ``dense.ANCHOR_TOL`` tol).
    FAR_RETRY = 1.0 / 64
    #: Bits added to the starting precision of a dense anchor away from t = 0
    #: (:meth:`prec_at`).
    PREC_MARGIN = 8

    def __init__(self, p, q, r0, U, backend, tol, max_prec=4096, fallback=None, check=True,
                 setup_prec=SETUP_PREC):
        self.backend = make_backend(backend)
        self.fallback = fallback if callable(fallback) else None
        self.method = f'hypergeometric-{self.backend.name}'
        self.tol = float(tol)
        self.max_prec = int(max_prec)
        self._fallback = None
        self._inputs = (p, q, r0, U)
        # sqrt(U), s0 and conj(Delta)/sqrt(U) are rounded here: at least as finely as the
        # inputs, whose rounding the caller accounts for (the phase s^2 / 4 can be 1e100 rad)
        self.setup_prec = max(SETUP_PREC, int(setup_prec))
        with mp.workprec(self.setup_prec):
            p, q, r0, U = (mpmath.mpf(v) for v in (p, q, r0, U))
            self.sqrtU = mpmath.sqrt(U)
            self.delta = (p * p + q * q) / (4 * U)
            self.r0, self.U = r0, U
            self.s0 = r0 / self.sqrtU
            self.half_delta = self.delta / 2
            self.dbar_re, self.dbar_im = p / self.sqrtU, -q / self.sqrtU  # conj(Delta)/sqrt U
        self.params = {'p': float(p), 'q': float(q), 'r0': float(r0), 'U': float(U),
                       'delta': float(self.delta)}
        self._consts = {}
        # Start where the magnitudes of the even/odd solutions (about e^{pi delta/4}
        # each) would leave the tolerance's bits plus guard bits.
        need = -math.log2(self.tol) + 2 * math.log2(math.e) * math.pi * float(self.delta) / 4
        # ... plus the bits of the phase s0^2 / 4, formed at the working precision, and
        # (mpmath's estimate) of |s0| and of the v2 gain (2 + |s0|) / |conj(Delta) / sqrt U|
        ms0 = max(0, _mag(self.s0))
        need += 2 * ms0
        if not self.backend.certified:
            dbar = mpmath.hypot(self.dbar_re, self.dbar_im)
            need += ms0 + max(0, max(ms0, 2) - _mag(dbar))
        self.predicted = int(max(64, 24 + min(need, 1e9)))
        self.prec = min(self.predicted, self.max_prec)
        self.start_prec = self.prec              # dense anchors start here (determinism)
        self._need0, self._ms0 = need - 2 * ms0, ms0
        self._s_float = (float(self.r0), float(self.U), float(self.sqrtU))
        self._alpha_abs = math.hypot(0.5, float(self.half_delta))
        self._nterms = {}                        # |z| to 5 bits -> terms of the far U
        self._ubits = {}                         # exponent of |z| -> bits of the far U
        if not self.backend.certified and self.predicted > self.max_prec:
            # mpmath would grind through hopeless precisions: say so at once
            raise PrecisionError(
                f'the mpmath 1F1 evaluation would need about {self.predicted} bits '
                f'(ceiling {self.max_prec}): delta = (p^2 + q^2) / (4U) = '
                f'{float(self.delta):.4g} is large (small torque against the transverse '
                f"rate). Use backend='flint' (certified Taylor continuation) or raise "
                f'max_prec.')
        if check:
            self.evaluate(0.0)                   # fail now, not at the first sample

    def prec_at(self, t):
        """Working precision to start from at t: a function of t alone (dense anchors).

        As the starting precision, with the phase bits of ``s(t) = (r0 + U t) / sqrt U``
        in place of those of ``s0`` (the phase ``s^2 / 4`` is formed at the working
        precision), plus ``PREC_MARGIN``: far anchors then need one evaluation, not a
        failed one at the start precision first. None past the float range.
        """
        r0, u, su = self._s_float
        s = abs((r0 + u * t) / su) * (1 + 1e-9)
        if not math.isfinite(s):
            return None
        ms = max(self._ms0, math.frexp(s)[1] if s else 0)
        need = self._need0 + 2 * ms + (0 if ms == self._ms0 else self.PREC_MARGIN)
        prec = -(-int(max(64, 24 + min(need, 1e9))) // 16) * 16      # few distinct precisions
        return min(self.max_prec, max(self.start_prec, prec))

    # -- per-precision constants ----------------------------------------------------------
    def _constants(self, prec):
        c = self._consts.get(prec)
        if c is not None:
            return c
        b = self.backend
        with b.workprec(prec):
            c = {
                'half': b.real(0.5), 'one': b.real(1), 'two': b.real(2),
                'i': b.cplx(0, 1),
                'alpha': b.cplx(0.5, self.half_delta),
                'beta': b.cplx(1, self.half_delta),
                'sqrtU': b.real(self.sqrtU), 'r0': b.real(self.r0), 'U': b.real(self.U),
                'dbar': b.cplx(self.dbar_re, self.dbar_im),
                'b12': b.real(0.5), 'b32': b.real(1.5), 'b52': b.real(2.5),
            }
            c['alpha1'] = c['alpha'] + 1
            c['beta1'] = c['beta'] + 1
            s0 = c['r0'] / c['sqrtU']
            ye, yep, yo, yop = self._fundamental(c, s0)
            u1, u1s = c['one'], c['i'] * s0 / 2          # v1(0) = 1, dv1/ds(0) = i s0 / 2
            c['C1'] = yop * u1 - yo * u1s                # Y(s0)^{-1} u0, det Y = 1
            c['C2'] = ye * u1s - yep * u1
            c['cond0'] = max(b.abs(ye), b.abs(yep), b.abs(yo), b.abs(yop))
        self._consts[prec] = c
        return c

    def _kummer_far(self, c, z):
        """Return the four Kummer functions of :meth:`_fundamental` at large |z|.

        For Im z > 0 (principal branches; DLMF 13.2.41 and 13.7.2 with ``arg z = pi/2``):

            M(a, b, z) = G1 U(a, b, z) + G2 e^z U(b - a, b, -z),
            G1 = Gamma(b) e^{i pi a} / Gamma(b - a),  G2 = Gamma(b) e^{i pi (a - b)} / Gamma(a),

        with Tricomi's U, whose asymptotic series Arb sums fast at large |z| (about a third
        of a 1F1 there, which recomputes the gamma factors at every call; here they are
        constants of the scene). ``U(a, b, z) = z^{1-b} U(a - b + 1, 2 - b, z)`` (DLMF
        13.2.40) gives the pair of M(beta, 3/2) from that of M(alpha, 1/2): six U, not
        eight. Ball arithmetic throughout: the result is certified as the 1F1 route's is.
        """
        b = self.backend
        g = c.get('far')
        if g is None:
            g = c['far'] = {}
            pi_i = b.pi_i()
            for key, ak, bk in (('m1', 'alpha', 'b12'), ('m2', 'alpha1', 'b32'),
                                ('m3', 'beta', 'b32'), ('m4', 'beta1', 'b52')):
                a_, b_ = c[ak], c[bk]
                gb = b.gamma(b_)
                g[key] = (gb * b.exp(pi_i * a_) / b.gamma(b_ - a_),
                          gb * b.exp(pi_i * (a_ - b_)) / b.gamma(a_))
            g['a_m1'], g['a_m2'], g['a_m4'] = c['alpha'], c['alpha1'], c['beta1']
            g['c12'] = c['b12'] - c['alpha']                  # 1/2 - alpha
            g['c1'] = c['b32'] - c['beta']                    # 1 - alpha
        mz = -z
        ez = b.exp(z)
        u1 = b.hypu(g['a_m1'], c['b12'], z)
        v1 = b.hypu(g['c12'], c['b12'], mz)
        u3 = u1 / b.sqrt(z)                                   # U(beta, 3/2, z)
        v3 = v1 / b.sqrt(mz)                                  # U(1 - alpha, 3/2, -z)
        u2 = b.hypu(g['a_m2'], c['b32'], z)
        v2 = b.hypu(g['c12'], c['b32'], mz)
        u4 = b.hypu(g['a_m4'], c['b52'], z)
        v4 = b.hypu(g['c1'], c['b52'], mz)
        out = []
        for key, u, v in (('m1', u1, v1), ('m2', u2, v2), ('m3', u3, v3), ('m4', u4, v4)):
            g1, g2 = g[key]
            out.append(g1 * u + g2 * ez * v)
        return out

    def _far_constants(self, c, sign):
        """Per-precision constants of :meth:`_spinor_far` for one sign of s (cached in c).

        ``A``, ``Bp = sgn(s) B e^{-i pi/4} / sqrt 2``, ``Bq = sgn(s) B c sqrt 2 e^{i pi/4}``
        (see there) and ``2 / conj(Delta)`` (in units of sqrt U).
        """
        b = self.backend
        key = ('spinor_far', sign)
        k = c.get(key)
        if k is None:
            self._kummer_far(c, c['i'] * b.real(4 * self.FAR_Z) / 2)   # the G constants
            g = c['far']
            pi_i = b.pi_i()
            sqrt2 = b.sqrt(c['two'])
            kk = sqrt2 * b.exp(-pi_i / 4)                            # sqrt 2 e^{-i pi/4}
            kc = sqrt2 * b.exp(pi_i / 4)
            bb = c['C1'] * g['m1'][1] + c['C2'] * sign * kc * g['m3'][1]
            k = c[key] = {
                'A': c['C1'] * g['m1'][0] + c['C2'] * sign * kk * g['m3'][0],
                'Bp': sign * bb * kk / 2,
                'Bq': sign * bb * g['c12'] * kc,
                'two_dbar': c['two'] / c['dbar'],
            }
        return k

    def _u_prec(self, s2, prec):
        """Bits at which :meth:`_spinor_far` sums its Tricomi U: a function of s^2 and prec.

        ``U_BITS`` plus the bits of the phase ``|alpha| log |z|`` of ``z^{-alpha}``,
        rounded up to 16; at most ``prec``. Only a cost choice: the balls say what came
        out, and :meth:`_at_prec` repeats the U at ``prec`` where the bound missed tol.
        """
        z = 0.5 * s2
        if not 1.0 < z < math.inf:
            return prec
        e = math.frexp(z)[1]
        bits = self._ubits.get(e)
        if bits is None:                        # |z| < 2^e: log |z| < e log 2
            bits = self._ubits[e] = self.U_BITS + math.frexp(
                self._alpha_abs * (e * math.log(2.0) + 4.0) + 1.0)[1]
        return min(prec, max(16, -(-bits // 16) * 16))

    def _u_terms(self, s2):
        """Terms of the asymptotic series of the far route's U at ``|z| = s2 / 2`` (or -1).

        The terms of ``U(a, b, z) ~ z^{-a} sum (a)_k (a - b + 1)_k / (k! (-z)^k)`` (DLMF
        13.7.3) have ratios at most ``(|alpha| + 1.5 + k)^2 / ((k + 1) |z|)`` for the two
        U of :meth:`_spinor_far`; n is the first k where their product falls below
        ``2^-U_TERM_BITS`` (cached by |z| rounded down to 5 bits). -1 where the terms stop
        falling first, or grow at first (``(|alpha| + 1.5)^2 > |z| / 2``: there Arb's
        remainder bound is far above the first term left out), and Arb then chooses: only
        a cost choice, since Arb bounds the remainder rigorously whatever n.
        """
        m, e = math.frexp(0.5 * s2)
        key = (e, int(16.0 * m))
        n = self._nterms.get(key)
        if n is None:
            z = math.ldexp(key[1], e - 4)                  # <= |z|, within 1/8 of it
            a = self._alpha_abs + 1.5
            target = math.ldexp(1.0, -self.U_TERM_BITS)
            term, n = 1.0, -1
            for k in range(400 if a * a <= 0.5 * z else 0):
                ratio = (a + k) ** 2 / ((k + 1) * z)
                term *= ratio
                if term <= target:
                    n = k + 1
                    break
                if ratio >= 1.0 and k > a:                # diverging before the target
                    break
            self._nterms[key] = n
        return n

    def _spinor_far(self, c, s, uprec=None, s2f=None, sign=None):
        """``(v1, v2)`` at s from two Tricomi U, or None where |z| < FAR_Z.

        In the basis ``F1 = U(alpha, 1/2, z)``, ``e^z F2``, ``F2 = U(c, 1/2, -z)`` (``c =
        1/2 - alpha``) of Kummer's equation, :meth:`_kummer_far` and DLMF 13.2.40 give
        ``v1 = e^{-z/2} (A F1 + B e^z F2)`` with constants for each sign of s:

            A = C1 G1(m1) + C2 sgn(s) k G1(m3),   B = C1 G2(m1) + C2 sgn(s) conj(k) G2(m3),

        ``k = sqrt 2 e^{-i pi/4}`` (``s z^{-1/2}``; ``s (-z)^{-1/2} = sgn(s) conj(k)``).
        With ``dz/ds = i s`` and ``U'(a, b, z) = -a U(a + 1, b + 1, z)`` (DLMF 13.3.22),
        ``v2 = -(2 i dv1/ds + s v1) / conj(Delta)`` (in units of sqrt U) is

            v2 = (2 s / conj(Delta)) [B e^{z/2} c F2d - A e^{-z/2} G],
            G = F1 + alpha F1d,   F1d = U(alpha + 1, 3/2, z),   F2d = U(c + 1, 3/2, -z).

        Here z = i s^2 / 2 is imaginary, so ``-z = conj(z)``, and ``conj(alpha) = c + 1/2``:
        with ``conj U(a, b, z) = U(conj a, b, conj z)`` (b real), Kummer's transformation
        ``U(a, b, z) = z^{1-b} U(a - b + 1, 2 - b, z)`` (DLMF 13.2.40) and the contiguous
        relation ``U(a, b, z) = a U(a + 1, b, z) + U(a, b - 1, z)`` (DLMF 13.3.10),

            F2 = (-z)^{1/2} conj(G),   F2d = (-z)^{-1/2} conj(F1),

        ``(-z)^{1/2} = |s| e^{-i pi/4} / sqrt 2``. So

            v1 = e^{-z/2} A F1 + e^{z/2} Bp s conj(G),
            v2 = (2 / conj(Delta)) [e^{z/2} Bq conj(F1) - s e^{-z/2} A G]

        (:meth:`_far_constants`): two U (and one exponential, its conjugate the other).
        The U are summed at ``uprec`` bits (:meth:`_u_prec`) with :meth:`_u_terms` terms
        of their asymptotic series (None or the working precision: Arb's own choice of
        method and terms), the rest at the working precision, all in Arb balls: certified
        as the 1F1 route is.
        """
        b = self.backend
        s2 = s * s
        if sign is None:
            if not b.far_ok(s2, self.FAR_Z):
                return None
            sign = 1 if s > 0 else -1 if s < 0 else 0
            if not sign:
                return None
        k = self._far_constants(c, sign)
        z = c['i'] * s2 / 2
        e_half = (z / 2).exp()
        e_mhalf = e_half.conjugate()                # z / 2 is imaginary (real part exactly 0)
        ctx = b.flint.ctx
        prec = ctx.prec
        uprec = uprec or prec
        n = self._u_terms(s2f or float(s2.real.mid())) if uprec < prec else -1
        ctx.prec = uprec                            # as workprec(uprec), without its cost
        try:
            if n < 0:
                f1 = z.hypgeom_u(c['alpha'], c['b12'])
                f1d = z.hypgeom_u(c['alpha1'], c['b32'])          # U(alpha + 1, 3/2, z)
            else:
                f1 = z.hypgeom_u(c['alpha'], c['b12'], n=n, asymp=True)
                f1d = z.hypgeom_u(c['alpha1'], c['b32'], n=n, asymp=True)
        finally:
            ctx.prec = prec
        g = f1 + c['alpha'] * f1d
        a_ = k['A']
        v1 = e_mhalf * (a_ * f1) + e_half * ((k['Bp'] * s) * g.conjugate())
        v2 = k['two_dbar'] * (e_half * (k['Bq'] * f1.conjugate()) - (s * e_mhalf) * (a_ * g))
        return v1, v2

    def _fundamental(self, c, s):
        """(y_e, y_e', y_o, y_o') at s, derivatives in s."""
        b = self.backend
        i = c['i']
        s2 = s * s
        phi = i * s2 / 2
        e = b.exp(-phi / 2)
        if b.certified and self.FAR_Z is not None and b.far_ok(s2, self.FAR_Z):
            m1, m2, m3, m4 = self._kummer_far(c, phi)
        else:
            m1 = b.hyp1f1(c['alpha'], c['b12'], phi)
            m2 = b.hyp1f1(c['alpha1'], c['b32'], phi)
            m3 = b.hyp1f1(c['beta'], c['b32'], phi)
            m4 = b.hyp1f1(c['beta1'], c['b52'], phi)
        ye = e * m1
        yep = e * (i * s * (2 * c['alpha'] * m2 - m1 / 2))
        yo = s * e * m3
        yop = e * (m3 - phi * m3 + (2 * c['beta'] / 3) * i * s2 * m4)
        return ye, yep, yo, yop

    # -- evaluation -----------------------------------------------------------------------
    def _at_prec(self, t, prec, uprec=None):
        """Quaternion and bound at t with ``prec`` working bits (the far route's U at uprec).

        ``uprec`` None: :meth:`_u_prec`; where the far route's bound then passes
        ``FAR_RETRY`` of tol, the U are summed again at ``prec`` (a function of t and
        prec alone, as the first try is).
        """
        b = self.backend
        if b.certified and self.FAR_Z is not None:
            r0, u, su = self._s_float
            sf = (r0 + u * t) / su
            s2f = sf * sf                           # inf, not OverflowError, past the range
            if 2.000002 * self.FAR_Z < s2f < math.inf:
                # surely |z| >= FAR_Z (the ball test of _spinor_far would pass): the far
                # route with plain floats in between (no workprec, no np.array)
                return self._at_prec_far(t, prec, uprec, s2f, 1 if sf > 0.0 else -1)
        far = None
        with b.workprec(prec):
            c = self._constants(prec)
            s = (c['r0'] + c['U'] * b.real(t)) / c['sqrtU']
            if b.certified and self.FAR_Z is not None:
                r0, u, su = self._s_float
                s2f = (r0 + u * t) / su
                s2f *= s2f                          # inf, not OverflowError, past the range
                if uprec is None:
                    uprec = self._u_prec(s2f, prec)
                far = self._spinor_far(c, s, uprec, s2f)
            if far is not None:
                v1, v2 = far
            else:
                ye, yep, yo, yop = self._fundamental(c, s)
                v1 = c['C1'] * ye + c['C2'] * yo
                v1s = c['C1'] * yep + c['C2'] * yop
                v2 = -(2 * c['i'] * v1s + s * v1) / c['dbar']
            if far is not None:
                # Arb balls: midpoints (nearest doubles) and radii (bounds in the plane);
                # a non-finite value is caught below
                c1, c2 = complex(v1), complex(v2)
                w, z, my, x = c1.real, c1.imag, c2.real, c2.imag
                err = math.hypot(float(v1.rad()), float(v2.rad()))
            else:
                w, z, r1 = b.parts(v1)
                my, x, r2 = b.parts(v2)
            q = np.array([x, -my, z, w])
            if far is None and b.certified:
                err = math.hypot(r1, r2)
            elif far is None:
                # running-error estimate: eps * ||Y(s)|| * ||Y(s0)^-1|| * |u0| * v2 gain,
                # times the phases s^2 / 4 and s0^2 / 4 (rounding s moves them by eps s^2 / 2)
                ns = max(b.abs(ye), b.abs(yep), b.abs(yo), b.abs(yop))
                su = b.abs(s)
                s0 = abs(float(self.s0))
                gain = 1.0 + (2.0 + su) / b.abs(c['dbar'])
                phase = 1.0 + 0.5 * (su * su + s0 * s0)
                err = 64.0 * 2.0 ** -prec * ns * c['cond0'] * (1.0 + s0) * gain * phase
        if not (math.isfinite(x) and math.isfinite(my) and math.isfinite(z)
                and math.isfinite(w)):
            err = math.inf
        if far is not None and uprec < prec and not err <= self.FAR_RETRY * self.tol:
            return self._at_prec(t, prec, prec)
        # float64 rounding of the four components
        return q, err + 2.3e-16

    def _at_prec_far(self, t, prec, uprec, s2f, sign):
        """:meth:`_at_prec` on the far route, where ``s2f`` (a float) puts |z| past FAR_Z.

        The very Arb operations of :meth:`_at_prec` there (so the same balls and bits),
        with the precision set on flint's context directly.
        """
        ctx = self.backend.flint.ctx
        old = ctx.prec
        ctx.prec = prec
        try:
            c = self._consts.get(prec) or self._constants(prec)
            s = (c['r0'] + c['U'] * self.backend.real(t)) / c['sqrtU']
            if uprec is None:
                uprec = self._u_prec(s2f, prec)
            v1, v2 = self._spinor_far(c, s, uprec, s2f, sign)
            c1, c2 = complex(v1), complex(v2)
            err = math.hypot(float(v1.rad()), float(v2.rad()))
        finally:
            ctx.prec = old
        w, z, my, x = c1.real, c1.imag, c2.real, c2.imag
        if not (math.isfinite(x) and math.isfinite(my) and math.isfinite(z)
                and math.isfinite(w)):
            err = math.inf
        if uprec < prec and not err <= self.FAR_RETRY * self.tol:
            return self._at_prec_far(t, prec, prec, s2f, sign)
        return np.array([x, -my, z, w]), err + 2.3e-16

    def evaluate(self, t):
        """Quaternion (x, y, z, w) at t and a bound on its component error (2-norm).

        The precision starts at the last one that worked and rises until the bound
        meets ``tol``; past ``max_prec`` bits a :class:`PrecisionError` names the cause.
        """
        prec = self.prec
        last_err = math.inf
        ceiling = self.max_prec
        if self.backend.certified and self.fallback is not None:
            ceiling = min(ceiling, self.FALLBACK_BITS)
            prec = min(prec, ceiling)
            if self.predicted > 2 * self.FALLBACK_BITS:
                prec = ceiling + 1                   # hopeless for 1F1: straight to Taylor
        uprec = None                             # the cheap U first, full ones once raised
        while prec <= ceiling:
            try:
                q, err = self._at_prec(t, prec, uprec)
            except PrecisionError:
                q, err = None, math.inf
            if err <= self.tol:
                self.prec = prec
                return q, err
            last_err = err
            if prec >= ceiling:
                break
            step = 32 if not math.isfinite(err) else \
                max(32, int(math.log2(err) - math.log2(self.tol)) + 16)
            prec = min(ceiling, max(prec + step, int(prec * 1.25)))
            uprec = prec
        if self.backend.certified and self.fallback is not None:
            if self._fallback is None:
                self._fallback = self.fallback()
                self.method = f'hypergeometric-flint+{self._fallback.method}'
            return self._fallback.evaluate(t)
        pr = self.params
        with mp.workprec(64):                    # |z^2| in floats can overflow or divide by 0
            z2 = float(abs(self.r0 + self.U * mpmath.mpf(t)) ** 2 / (2 * self.U))
        raise PrecisionError(
            f'the {self.backend.name} 1F1 evaluation reached only {last_err:.3g} '
            f'(asked {self.tol:.3g}) at t = {t!r} s with {self.max_prec} bits: the sphere '
            f'problem has delta = (p^2 + q^2) / (4U) = {pr["delta"]:.4g} and |z^2| = '
            f'(r0 + U t)^2 / (2U) = {z2:.4g} '
            f'(p, q, r0 = {pr["p"]:.6g}, {pr["q"]:.6g}, {pr["r0"]:.6g} rad/s, '
            f'U = {pr["U"]:.6g} rad/s^2). Large delta (small torque against the transverse '
            f'rate) or large |z^2| (long horizons) need more bits: raise max_prec, use a '
            f'larger tol, or shorten the horizon.')
