"""Which evaluation runs: the one module that knows every spherical-body kernel.

The kernels are leaves that do not import each other: closed forms and 1F1
(:mod:`.kernel`), certified Taylor continuation (:mod:`.taylor`), the superadiabatic
series (:mod:`.adiabatic`), over the shared numerics of :mod:`.backends`. This module
chooses among them for a scene and wires the two cross-links: a 1F1 kernel that falls
back to Taylor continuation past its bit budget, and a Taylor continuation that seeds a
far checkpoint with one certified 1F1 evaluation when that is expected to be cheaper
than stepping there.
"""

import math

import mpmath

from .adiabatic import ADIABATIC_DELTA, AdiabaticKernel
from .backends import available_backends, PrecisionError
from .kernel import HyperKernel
from .taylor import STEP_COST_MS_PER_RAD, TaylorKernel

__all__ = ['spinor_kernel', 'hyper_kernel', 'taylor_kernel', 'OneF1Seeder', 'DELTA_SWITCH',
           'SEED_BITS']

#: Above this delta = (p^2 + q^2) / (4U) the flint backend continues the spinor by
#: certified Taylor series instead of 1F1: measured here, 1F1 needs about 65 + 2.3 delta
#: bits and costs 2.6 ms a sample at delta = 80 (5 ms at 160), while the Taylor
#: continuation streams at 0.3-0.5 ms a sample.
DELTA_SWITCH = 80.0
#: Ceiling on a 1F1 seed's bits by the radians of stepping it replaces: measured here,
#: delta = 3000 at t = 1e4 s takes 59 ms at 4096 bits against 216 ms of stepping;
#: delta = 1271, 2886 and 8747 at t = 2e4...8e4 s take 0.63 s (8192 bits), 2.7 s (16384)
#: and 0.19 s (8192) against 16 s, 100 s and 293 s of stepping.
SEED_BITS = ((2e5, 4096), (2e6, 16384), (math.inf, 32768))


#: A seed is first tried at this many bits: where |z| is large Arb's asymptotic series
#: needs far fewer bits than the cancellation estimate (measured here, the spacecraft
#: scene at t = 0.5 ... 1e5 s: delta = 325 predicts 803 bits; 128 bits give a 2.3e-16
#: ball in 0.06-0.3 ms through Tricomi's U).
CHEAP_BITS = 128


def _seed_cost_ms(bits):
    """Estimate the cost of one 1F1 seed (the value; its constants are made once), ms.

    Measured here (spacecraft, delta = 325, t = 1e3 s, four Tricomi U, under load):
    0.21 ms at 128 bits, 0.40 at 256, 0.85 at 512, 1.6 at 800 (the constants, once per
    precision: about 1.2 ms at 128 bits).
    """
    return 0.25 * max(1.0, bits / 128.0) ** 1.1


class OneF1Seeder:
    """Certified 1F1 evaluation of the Taylor kernel's spinor at a far time.

    Tried first at ``CHEAP_BITS`` when the stepping it would replace is expected to cost
    at least twice as much, then at the predicted bits (capped by ``SEED_BITS``) under the
    same rule; a budget that failed once is not tried again. The result is certified
    either way (an Arb ball within the tol), so a low first precision is only a guess
    about cost, never about accuracy.
    """

    def __init__(self, inputs, tol, setup_prec=256):
        self.inputs = inputs
        self.setup_prec = setup_prec
        self.tol = 0.5 * float(tol)
        p, q, _, u = (mpmath.mpf(v) for v in inputs)        # floats may under/overflow
        delta = min(float((p * p + q * q) / (4 * u)), 1e300)
        self.predicted = int(max(64, 24 - math.log2(self.tol)
                                 + 2 * math.log2(math.e) * math.pi * delta / 4))
        self.hyper = None
        self.failed_at = 0
        self.cheap_failed = False
        self.anchor_failed = 0

    def anchor(self, t):
        """Certified value at t at ``CHEAP_BITS``, or None: a dense anchor's evaluation.

        Its value and cost depend on t alone (no stepping from whatever checkpoint is
        nearest); None where that precision does not reach the tol (the caller then steps
        to this anchor). Tried at every anchor: a failure is not carried over to later
        anchors (it was: after one failure near the spacecraft's avoided crossing at
        t < 0, anchors far out stepped from whichever checkpoint was nearest, and their
        bits depended on the queries before). ``anchor_failed`` counts the failures.
        """
        if self.hyper is None:
            self.hyper = HyperKernel(*self.inputs, backend='flint', tol=self.tol,
                                     max_prec=SEED_BITS[0][1], fallback=None, check=False,
                                     setup_prec=self.setup_prec)
        try:
            q, err = self.hyper._at_prec(t, CHEAP_BITS)
            if err <= self.tol:
                return q, err
        except PrecisionError:
            pass
        self.anchor_failed += 1
        return None

    def __call__(self, t, stepping_ms):
        turn = stepping_ms / STEP_COST_MS_PER_RAD
        cap = next(b for limit, b in SEED_BITS if turn <= limit)
        if cap <= self.failed_at:
            return None
        if self.hyper is None or self.hyper.max_prec < cap:
            self.hyper = HyperKernel(*self.inputs, backend='flint', tol=self.tol,
                                     max_prec=cap, fallback=None, check=False,
                                     setup_prec=self.setup_prec)
        if not self.cheap_failed and stepping_ms >= 2.0 * _seed_cost_ms(CHEAP_BITS):
            try:
                q, err = self.hyper._at_prec(t, min(CHEAP_BITS, cap))
                if err <= self.tol:
                    return q, err
            except PrecisionError:
                pass
            self.cheap_failed = True
        if stepping_ms < 2.0 * _seed_cost_ms(min(self.predicted, cap)):
            return None
        try:
            self.hyper.prec = min(self.predicted, cap)
            return self.hyper.evaluate(t)
        except PrecisionError:
            self.hyper = None                       # not affordable at this budget: step
            self.failed_at = cap
            return None


def taylor_kernel(p, q, r0, U, tol, max_prec=4096, seed=True, setup_prec=256):
    """Certified Taylor continuation, seeded by 1F1 at far queries unless ``seed`` is off.

    ``setup_prec``: bits of the inputs, for the seeds' derived constants.
    """
    seeder = OneF1Seeder((p, q, r0, U), tol, setup_prec) if seed else None
    return TaylorKernel(p, q, r0, U, tol=tol, max_prec=max_prec, seeder=seeder)


def hyper_kernel(p, q, r0, U, backend, tol, max_prec=4096, fallback=True, setup_prec=256):
    """1F1 kernel; with flint and ``fallback``, samples past its budget continue by Taylor.

    ``setup_prec``: bits of the inputs, for the derived constants (sqrt U, ...).
    """
    def factory():
        return taylor_kernel(p, q, r0, U, tol=tol, max_prec=max_prec, setup_prec=setup_prec)
    return HyperKernel(p, q, r0, U, backend, tol=tol, max_prec=max_prec,
                       fallback=factory if fallback else None, setup_prec=setup_prec)


def spinor_kernel(p, q, r0, U, ktol, backend, max_prec, inputs=None, setup_prec=256):
    """Choose the kernel of omega_K = (p, q, r0 + U t) for a transverse rate p + i q != 0.

    Parameters are the exact (mpf) inputs, ``ktol`` the bound asked of the kernel
    quaternion; ``inputs`` (optional) computes ``[p, q, r0, U]`` at the current mpmath
    precision for the adiabatic series' long phases. The regimes (README, "How it is
    computed"): the superadiabatic series where delta >= ADIABATIC_DELTA and its estimate
    meets ktol; certified Taylor continuation above DELTA_SWITCH (flint), or where
    mpmath's 1F1 would exceed ``max_prec``; 1F1 otherwise. ``setup_prec`` is the bits the
    inputs carry (more than 256 for huge phases); derived constants keep at least as many.
    """
    delta_mp = (p ** 2 + q ** 2) / (4 * U)
    delta = float(delta_mp)
    # bits mpmath's 1F1 would need (HyperKernel's own predictor)
    mp_bits = 24 - math.log2(ktol) + 2 * math.log2(math.e) * math.pi * delta / 4
    mp_hopeless = backend == 'mpmath' and mp_bits > max_prec and \
        'flint' in available_backends()
    # the adiabatic series only where its estimate 10 eps^3 meets the tol
    adiabatic_ok = 10 / (4 * delta_mp) ** 3 + mpmath.mpf(1e-15) <= ktol
    if delta >= ADIABATIC_DELTA and adiabatic_ok:
        return AdiabaticKernel(p, q, r0, U, tol=ktol, inputs=inputs)
    if (backend == 'flint' and delta > DELTA_SWITCH) or mp_hopeless:
        return taylor_kernel(p, q, r0, U, tol=ktol, max_prec=max_prec, setup_prec=setup_prec)
    return hyper_kernel(p, q, r0, U, backend, tol=ktol, max_prec=max_prec,
                        setup_prec=setup_prec)
