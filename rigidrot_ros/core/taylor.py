"""Certified Taylor-series continuation of the spherical-body spinor (any delta).

Where the 1F1 form cancels (``delta = |Delta|^2 / (4U)`` large: small torque against
the transverse rate), the same exact solution is continued by its Taylor series, which
converges everywhere (the spinor equation has coefficients linear in t, so the solution
is entire). About ``t_k`` with ``X_k = r0 + U t_k`` the coefficients of
``v(t_k + tau) = sum c_n tau^n`` obey

    (n + 1) c_{n+1} = (i/2) (H_k c_n + U sigma_z c_{n-1}),   H_k = [[X_k, conj D], [D, -X_k]],

and since ``H_k`` is Hermitian, ``|c_n| <= m_n`` with the majorant
``(n + 1) m_{n+1} = (R/2) m_n + (U/2) m_{n-1}``, ``R = sqrt(X_k^2 + |D|^2)``, which bounds
the truncated tail rigorously. Each step runs in Arb ball arithmetic (python-flint) from
the exact midpoint of the previous state; because the true propagator is unitary, the
error carried in keeps its norm, so the bound is the sum of the steps' radii (no wrapping
effect). States at step ends are kept as checkpoints, so a stream of increasing times
costs one short step per sample.

Reference: the rigorous route of Dunster, Gil, Ruiz-Antolin and Segura (arXiv:2412.13085)
for parabolic cylinder functions, applied to the two-level system directly.
"""

import bisect
import math

import numpy as np

from .backends import _FlintBackend, PrecisionError

__all__ = ['TaylorKernel', 'STEP_COST_MS_PER_RAD', 'MAX_STEP_TURN', 'MAX_SEED_TURN']

#: Measured cost of certified stepping, ms per radian turned (steps of R h = 20..40 rad
#: at 128 bits): a query farther than a seed would cost first tries the seeder.
STEP_COST_MS_PER_RAD = 0.045
#: Limits on a far query (rad turned from the nearest checkpoint): stepping across more
#: than MAX_STEP_TURN rad (about 0.27 ms per 10 rad: a minute or so) is refused with a
#: PrecisionError naming t, and a 1F1 seed is not even tried past MAX_SEED_TURN rad
#: (32768-bit evaluations take many seconds; its phase would need more bits).
MAX_STEP_TURN = 2e6
MAX_SEED_TURN = 1e9


class TaylorKernel:
    """Spinor ``(v1, v2)`` of omega_K = (p, q, r0 + U t) by certified Taylor stepping.

    Parameters
    ----------
    p, q, r0, U : mpf
        Rates (rad/s) and torque over inertia (rad/s^2, > 0), exact inputs.
    tol : float
        Bound asked on the kernel quaternion's component error (2-norm).
    max_prec : int
        Ceiling on the working precision, bits.
    seeder : callable or None
        ``seeder(t, stepping_ms) -> (quaternion, bound) or None``: an independent exact
        evaluation at a far t, tried before stepping there when it is expected to be
        cheaper (:func:`rigidrot_ros.core.method.taylor_kernel` passes certified 1F1,
        whose derived constants carry the inputs' bits).
    """

    method = 'taylor-series-flint'

    def __init__(self, p, q, r0, U, tol, max_prec=4096, seeder=None):
        import flint
        self.flint = flint
        self.tol = float(tol)
        self.max_prec = int(max_prec)
        self._inputs = (p, q, r0, U)
        self.params = {'p': float(p), 'q': float(q), 'r0': float(r0), 'U': float(U)}
        self._u = float(U)
        self._dabs = math.hypot(float(p), float(q))
        self.seeder = seeder
        self.seeded = 0                 # checkpoints seeded by the seeder
        self.prec = 128
        self._reset(self.prec)

    def _reset(self, prec):
        b = _FlintBackend()
        acb, arb = self.flint.acb, self.flint.arb
        p, q, r0, U = self._inputs
        with self.flint.ctx.workprec(prec):
            self._c = {
                'r0': b.real(r0), 'U': b.real(U), 'D': acb(b.real(p), b.real(q)),
                'Dbar': acb(b.real(p), -b.real(q)), 'i2': acb(0, arb(1) / 2),
            }
            one, zero = acb(1), acb(0)
        # checkpoints per direction: times and (v1 mid, v2 mid, error bound) there
        self._ck = {1: ([0.0], [(one, zero, 0.0)]), -1: ([0.0], [(one, zero, 0.0)])}
        self.prec = prec

    def _rate(self, t):
        return math.hypot(abs(self._u * t) + abs(self.params['r0']), self._dabs)

    def _step(self, t0, state, h):
        """Advance ``state`` at ``t0`` by ``h`` (float, exact binary); returns the state."""
        flint = self.flint
        acb, arb = flint.acb, flint.arb
        c = self._c
        xk = c['r0'] + c['U'] * arb(t0)
        r = math.hypot(abs(self.params['r0'] + self._u * t0), self._dabs) * (1 + 1e-12)
        u = self._u * (1 + 1e-12)
        ah = abs(h)
        a_prev, b_prev = acb(0), acb(0)
        a_n, b_n = state
        # majorant M_n = m_n |h|^n (scale-free: R |h| <= 40, U h^2 <= 64, no overflow)
        m_prev, m_n = 0.0, 1.0 + 1e-9                   # |state| <= 1 + error
        rh, uh2 = r * ah, u * ah * ah
        sum_a, sum_b = a_n, b_n
        hp = arb(h)
        hn = arb(1)
        n = 0
        eps_bits = 2.0 ** (-self.prec)
        while True:
            a_next = c['i2'] * (xk * a_n + c['Dbar'] * b_n + c['U'] * a_prev) / (n + 1)
            b_next = c['i2'] * (c['D'] * a_n - xk * b_n - c['U'] * b_prev) / (n + 1)
            m_next = (0.5 * rh * m_n + 0.5 * uh2 * m_prev) / (n + 1)
            a_prev, b_prev, a_n, b_n = a_n, b_n, a_next, b_next
            m_prev, m_n = m_n, m_next
            n += 1
            hn = hn * hp
            sum_a += a_n * hn
            sum_b += b_n * hn
            qn = (0.5 * rh + 0.5 * uh2) / (n + 1)
            term = max(m_n, m_prev)
            if qn <= 0.25 and term * 4 <= eps_bits:
                break
        tail = 4.0 * term                               # geometric, ratio <= 1/2
        sum_a = sum_a + acb(arb(0, tail), arb(0, tail))
        sum_b = sum_b + acb(arb(0, tail), arb(0, tail))
        return sum_a, sum_b

    def _advance(self, tk, st, h):
        """One step from a checkpoint state (mid, mid, err): the new (mid, mid, err)."""
        a, b = self._step(tk, st[:2], h)
        rad = math.hypot(float(a.real.rad()) + float(a.imag.rad()),
                         float(b.real.rad()) + float(b.imag.rad()))
        return a.mid(), b.mid(), (st[2] + rad) * (1 + 1e-15)

    def _hmax(self, tk):
        """Step length of R h = 20..40 rad at the larger end rate R (measured optimum).

        Longer steps need fewer terms per radian (about 3 at 40 rad against 5 at 10 rad);
        the terms grow to about e^{R h / 2}, some 29 of the 128 working bits at 40 rad.
        """
        h = 40.0 / max(self._rate(tk), 1e-300)
        if self._u > 0:
            h = min(h, 8.0 / math.sqrt(self._u))
        while h * max(self._rate(tk + h), self._rate(tk - h)) > 40.0:
            h *= 0.5
        return math.ldexp(1.0, math.floor(math.log2(h)))     # exact binary step

    def _seed(self, t, sign, turn):
        """Try the seeder at a far t; on success store its value as a checkpoint."""
        if self.seeder is None:
            return None
        got = self.seeder(t, turn * STEP_COST_MS_PER_RAD)
        if got is None:
            return None
        (x, y, z, w), err = got
        acb = self.flint.acb
        with self.flint.ctx.workprec(self.prec):
            st = (acb(w, z), acb(-y, x), err)
        times, states = self._ck[sign]
        key = [sign * v for v in times]
        j = bisect.bisect_right(key, sign * t)
        times.insert(j, t)
        states.insert(j, st)
        self.seeded += 1
        return st

    def _state(self, t):
        """Spinor midpoints at t and their error bound, from the nearest checkpoint."""
        sign = 1 if t >= 0 else -1
        times, states = self._ck[sign]
        key = [sign * x for x in times]                        # increasing
        i = bisect.bisect_right(key, sign * t) - 1
        tk, st = times[i], states[i]
        turn = max(self._rate(tk), self._rate(t)) * abs(t - tk)
        if 40.0 < turn <= MAX_SEED_TURN:
            seeded = self._seed(t, sign, turn)
            if seeded is not None:
                return seeded
        if not turn <= MAX_STEP_TURN:
            p = self.params
            seed = ('no seed (a certified 1F1 evaluation, up to 32768 bits) could be had '
                    'there' if turn <= MAX_SEED_TURN and self.seeder is not None else
                    'no seed is tried there' if self.seeder is None else
                    f'a 1F1 seed is not tried past {MAX_SEED_TURN:.3g} rad')
            raise PrecisionError(
                f't = {t!r} s is out of reach: the certified Taylor continuation would '
                f'step across {turn:.3g} rad from its nearest checkpoint (t = {tk!r} s), '
                f'beyond its limit of {MAX_STEP_TURN:.3g} rad (about a minute of CPU), and '
                f'{seed} (kernel p, q, r0 = {p["p"]:.4g}, {p["q"]:.4g}, {p["r0"]:.4g} rad/s, '
                f'U = {p["U"]:.4g} rad/s^2). Use a shorter horizon (a larger torque / '
                f'inertia or a smaller spin turns less per second).')
        with self.flint.ctx.workprec(self.prec):
            while tk != t:
                h = self._hmax(tk)
                if abs(t - tk) <= h:
                    st = self._advance(tk, st, t - tk)
                    if i == len(times) - 1 and abs(t - tk) >= 0.25 * h:
                        times.append(t)                        # a stream resumes from t
                        states.append(st)
                    return st
                nt = tk + sign * h              # may round when crossing 2^k:
                st = self._advance(tk, st, nt - tk)   # step to the time stored
                tk = nt
                if i == len(times) - 1:                        # extend the stored path
                    times.append(tk)
                    states.append(st)
                    i += 1
                else:
                    i = -1
        return st

    def anchor(self, t):
        """Quaternion and bound at t for a dense anchor: the seeder's, else :meth:`evaluate`.

        The seeder's certified 1F1 at t (about 0.25 ms) costs the same whatever was
        evaluated before; stepping from the nearest checkpoint may cost more or less.
        Not tried past ``MAX_SEED_TURN`` rad from t = 0 (as a seed is not).
        """
        t = float(t)
        if (self.seeder is not None and hasattr(self.seeder, 'anchor')
                and self._rate(t) * abs(t) <= MAX_SEED_TURN):
            got = self.seeder.anchor(t)
            if got is not None:
                return got
        return self.evaluate(t)

    def evaluate(self, t):
        """Quaternion (x, y, z, w) at t and a certified bound on its component error."""
        while True:
            v1, v2, err = self._state(float(t))
            w, z, _ = _FlintBackend.parts(v1)
            my, x, _ = _FlintBackend.parts(v2)
            err = err + 2.3e-16
            if err <= self.tol and np.isfinite([w, z, x, my]).all():
                return np.array([x, -my, z, w]), err
            if self.prec >= self.max_prec:
                raise PrecisionError(
                    f'Taylor continuation reached only {err:.3g} (asked {self.tol:.3g}) at '
                    f't = {t!r} s with {self.max_prec} bits; raise max_prec or tol')
            self._reset(min(self.max_prec, self.prec * 2))
