"""Dense output: many samples of the exact spinor from few exact evaluations.

For a batch of times (the node's stream, an estimator test's log), each window of width
``tau`` is anchored on the exact kernel at its first time ``a``; inside it the exact
solution's own Taylor series about ``a`` (the recurrence of :mod:`.taylor`, in float64)
gives every sample with one vectorised Horner pass. Bound per sample:

    anchor bound + majorant tail + 10 N eps M(tau) sqrt(2),
    M(tau) = exp(R tau / 2 + U tau^2 / 4),

the last term an a-priori bound on float64 rounding: each step of the linear recurrence
adds at most ~8 eps relative to the coefficient's majorant and the errors propagate
under the same majorant (8 N eps), and Horner's sum adds 2 N eps. Windows keep
``R tau <= 1``, so that term stays near 1e-13; a window whose total exceeds the kernel's
tol is evaluated sample by sample instead (certified), and every window re-anchors on the
exact solution: nothing accumulates.
"""

import math

import numpy as np

__all__ = ['dense_spinor', 'Window']

_EPS = np.finfo(float).eps


def _window(a, r0, u, dabs):
    def rate(t):
        return math.hypot(abs(r0 + u * t), dabs)
    tau = 1.0 / max(rate(a), 1e-300)
    if u > 0:
        tau = min(tau, 1.0 / math.sqrt(u))
    while tau * max(rate(a), rate(a + tau)) > 1.0:
        tau *= 0.5
    return tau, max(rate(a), rate(a + tau))


class Window:
    """The exact spinor's Taylor expansion on ``[a, a + tau]``, anchored on the kernel at a.

    ``bound`` is the component-error bound valid for every time in the window; ``ok`` is
    false when it would exceed the kernel's tol (then evaluate sample by sample).
    """

    def __init__(self, kernel, a):
        p, q, r0, u = (kernel.params[k] for k in ('p', 'q', 'r0', 'U'))
        d = complex(p, q)
        self.a = a
        self.tau, rmax = _window(a, r0, u, math.hypot(p, q))
        qa, err_a = kernel.evaluate(a)
        x, y, z, w = qa
        xa = r0 + u * a
        c1, c2 = [complex(w, z)], [complex(-y, x)]
        m = [1.0 + err_a]
        prev1, prev2, mprev = 0j, 0j, 0.0
        n = 0
        tau = self.tau
        while True:
            n1 = 0.5j * (xa * c1[-1] + d.conjugate() * c2[-1] + u * prev1) / (n + 1)
            n2 = 0.5j * (d * c1[-1] - xa * c2[-1] - u * prev2) / (n + 1)
            mn = (0.5 * rmax * m[-1] + 0.5 * u * mprev) / (n + 1)
            prev1, prev2, mprev = c1[-1], c2[-1], m[-1]
            c1.append(n1)
            c2.append(n2)
            m.append(mn)
            n += 1
            qn = (0.5 * rmax * tau + 0.5 * u * tau * tau) / (n + 1)
            term = max(m[-1] * tau ** n, m[-2] * tau ** (n - 1))
            if qn <= 0.25 and term <= 1e-18:
                break
            if not term < math.inf or n > 200:   # float range left (see models.DENSE_RATES)
                term = math.inf
                break
        big_m = math.exp(0.5 * rmax * tau + 0.25 * u * tau * tau) * (1.0 + err_a)
        self.bound = err_a + 4.0 * term + 10 * (n + 1) * _EPS * big_m * math.sqrt(2.0)
        self.ok = self.bound <= kernel.tol
        self.c1, self.c2 = c1, c2

    def contains(self, t):
        """Whether t lies in this window."""
        return self.a <= t <= self.a + self.tau

    def quaternions(self, t):
        """Quaternions (x, y, z, w) at times t (array) inside the window."""
        dt = np.asarray(t, dtype=float) - self.a
        s1 = np.full(dt.shape, self.c1[-1])
        s2 = np.full(dt.shape, self.c2[-1])
        for k in range(len(self.c1) - 2, -1, -1):
            s1 = s1 * dt + self.c1[k]
            s2 = s2 * dt + self.c2[k]
        return np.stack([s2.imag, -s2.real, s1.imag, s1.real], axis=-1)

    def quaternion(self, t):
        """Quaternion (x, y, z, w) at one time inside the window (plain complex Horner)."""
        dt = t - self.a
        s1, s2 = self.c1[-1], self.c2[-1]
        for k in range(len(self.c1) - 2, -1, -1):
            s1 = s1 * dt + self.c1[k]
            s2 = s2 * dt + self.c2[k]
        return np.array([s2.imag, -s2.real, s1.imag, s1.real])


def dense_spinor(kernel, ts):
    """Quaternions (n, 4) and component-error bounds (n,) of ``kernel`` at sorted ``ts``."""
    out = np.empty((len(ts), 4))
    errs = np.empty(len(ts))
    i = 0
    while i < len(ts):
        win = Window(kernel, float(ts[i]))
        j = int(np.searchsorted(ts, win.a + win.tau, side='right'))
        if win.ok:
            out[i:j] = win.quaternions(ts[i:j])
            errs[i:j] = win.bound
        else:
            for k in range(i, j):                     # certified, one sample at a time
                out[k], errs[k] = kernel.evaluate(float(ts[k]))
        i = j
    return out, errs
