"""Torque-free motion of a body with three different moments (Euler-Poinsot), exact.

One cohesive algorithm, the exact Euler-Poinsot solution, kept in one module: the
per-scene table of sn, cn, dn and Q, its proved error bounds and the per-sample
evaluation share the cells, the constants and one error analysis (below).

Frames: N inertial; B body (principal axes); B' the body axes relabelled by a proper
rotation ``R_B'B`` (a permutation with signs) so that 2' is the intermediate axis and 3'
the axis about which the angular momentum circulates (the largest-moment axis when
``D = |h|^2 / 2T`` exceeds the middle moment, the smallest otherwise), with
``omega_3'(0) > 0``; L a frame whose third axis is the constant angular momentum h. A
matrix ``R_XY`` maps Y-components to X-components, ``v_X = R_XY @ v_Y``; quaternions are
(x, y, z, w), active, ``q_XY`` the quaternion of ``R_XY``. The motion is

    omega_B'(t) = (A1 cn u, sigma A2 sn u, A3 dn u),   u = lam t + u0,  parameter m,
    q_NB(t) = q_NL ⊗ q_z(xi(t)) ⊗ q_LB'(u) ⊗ q_B'B,

with ``q_LB'`` the smallest rotation taking ``h_B' / |h|`` to e3 (regular, since
``h_3' > 0``), and the angle about h

    xi(t) = (2T/|h|) t - c ∫_{u0}^{u} g(v) dv,   g = dn / (1 + beta dn),
    beta = I3' A3 / |h|,  c = (I1' A1)(sigma I2' A2) / |h|^2

(Euler's equations give ``omega_B'``: Landau & Lifshitz, Mechanics, Sec. 37; the angle
follows from ``h . omega = 2T`` and the connection of the smallest rotation,
``xi' = 2T/|h| - (u1 u2' - u2 u1') / (1 + u3)``, ``u = h_B' / |h|``; cf. Celledoni,
Fassò, Säfström, Zanna, SIAM J. Sci. Comput. 30 (2008), where the same integral appears
as an elliptic integral of the third kind). On the separatrix (m = 1) sn = tanh,
cn = dn = sech and ``∫ g = 2 / sqrt(1 - beta^2) atan(sqrt((1 - beta)/(1 + beta)) tanh(u/2))``.

Evaluation: per scene, at >= 128 bits (mpmath), K(m), u0 = F(am u0 | m)
and a table of Taylor expansions of sn, cn, dn and the periodic part Q of ``∫ g`` on cells
of width 1/8 covering the quarter period [0, K]: the values at the cell centres by the
addition theorem from u = h/2 and h (the series at 0), checked against the exact values at
u = K, and at each centre the Taylor series of the Jacobi system ``s' = c d, c' = -s d,
d' = -m s c`` to the degree the integral of g needs (its truncation, summed over the cells,
is in the bound): the first five degrees in fixed point, the rest in float64 for all
cells at once, every coefficient's error bounded a priori. Per sample, in float64
(vectorised): the phases ``lam t`` and ``Omega t`` reduced modulo the period exactly (the
constant split in 26-bit pieces, every partial product exact), one Horner pass per
function, three quaternion products. Every step is elementwise (the pieces a sample takes
follow from its own |t|; the body rate is a signed permutation, no matrix product) and a
scalar call repeats the same operations on floats, with numpy's sin, cos, exp and arctan:
a sample's quaternion, rate and bound depend on t alone, not on the batch.

The error bound is an a-priori float64 analysis, proved, not an estimate: the majorant
series ``1/(1 - u)`` bounds every Taylor coefficient of sn, cn, dn at a real point by 1
and ``1/(1 - 2u)`` those of g, so the table's truncation (< 1e-17) is bounded exactly, and
so are the float64 recurrences' errors (carried through every sum and product);
Horner rounding is bounded per cell from the stored coefficients; phase reduction,
folding and the quaternion formulas add bounded rounding (a few ulp allowed for libm's
sin, cos, exp, atan and sqrt). Within 1 - m < ~1e-50 of the separatrix (K > 60) the
table would be too long and :func:`solve` refuses. The per-scene
constants are computed at >= 128 bits: K(m), u0 and the mean rate of the angle about h
(closed form) by Arb on the flint backend (balls whose radius must lie below the last bit
kept), by mpmath on the mpmath backend; the rest by mpmath, and the table is checked at
u = K to 2^-83 (1e-25), far below the bound. The constants are rounded from the balls, not carried
as balls: ``method`` does not say 'flint'.
"""

from fractions import Fraction
import functools
import math
import operator

import mpmath
from mpmath import mp
import numpy as np

from . import quaternion as quat
from .kernel import PrecisionError
from .solution import BaseSolution, FLOAT_FLOOR, Samples

__all__ = ['TriaxialSolution', 'MODEL', 'REFERENCE']

MODEL = 'torque-free-triaxial'
REFERENCE = ('three different moments, no torque (Euler-Poinsot): Jacobi elliptic '
             'functions, angle about h by their integral')

_U = 2.0 ** -53                 # unit roundoff of float64
_H = 0.125                      # cell width of the table, in u
_R = _H / 2                     # largest |z| inside a cell
_DEG = 17                       # degree of the stored polynomials
_K0 = 5                         # degrees of each cell's series computed in fixed point
_DELTA = 2.0 ** -80             # the fixed-point table's error, as its check at K stands for
_TWO27 = 134217729.0            # Veltkamp splitter 2^27 + 1
_T_MAX = 1e250                  # beyond, t * 2^27 could overflow: refuse
_K_MAX = 60.0                   # largest quarter period tabulated (1 - m >~ 1e-51)
#: 4.1 |du| bounds the angle of q_LB' from the error du of the unit h in B'; |du| is
#: computed as sqrt((a^2 + b^2) + c^2) (elementwise, the same operations for one sample and
#: a batch), within 3 ulp of its exact value: the factor covers that
_D_LB = 4.1 * (1 + 4 * _U)


# ---------------------------------------------------------------------------------------
# per-scene set-up (mpmath)

def _series(s0, c0, d0, m, beta, n, prec, with_g=True):
    """Taylor coefficients (fixed point: ints scaled by 2^prec) of sn, cn, dn and g.

    From ``s' = c d, c' = -s d, d' = -m s c`` at a point where they take s0, c0, d0
    (fixed point), and ``g = dn / (1 + beta dn)`` (unless not ``with_g``); degree n. Each
    step truncates by at most 2^-prec; Python ints make this some 20 times faster than mpf.
    """
    s, c, d = [s0], [c0], [d0]
    mul = operator.mul                      # the sums below are exact: any order
    for k in range(n):
        cd = sum(map(mul, c, reversed(d))) >> prec
        sd = sum(map(mul, s, reversed(d))) >> prec
        sc = sum(map(mul, s, reversed(c))) >> prec
        s.append(cd // (k + 1))
        c.append(-sd // (k + 1))
        d.append(-((m * sc) >> prec) // (k + 1))
    if not with_g:
        return s, c, d, None
    one = 1 << prec
    w0 = one + ((beta * d0) >> prec)
    g = [(d0 << prec) // w0]
    for k in range(1, n + 1):
        acc = sum(map(mul, d[1:k + 1], reversed(g))) >> prec
        g.append(((d[k] - ((beta * acc) >> prec)) << prec) // w0)
    return s, c, d, g


def _add_fx(a, b, m, prec):
    """sn, cn, dn at u + v from their values at u (``a``) and v (``b``), fixed point.

    The addition theorem: with ``D = 1 - m sn_u^2 sn_v^2``, ``sn = (s_u c_v d_v + s_v c_u
    d_u) / D``, ``cn = (c_u c_v - s_u s_v d_u d_v) / D``, ``dn = (d_u d_v - m s_u s_v c_u
    c_v) / D``. Every product and quotient truncates by at most 2^-prec.
    """
    sa, ca, da = a
    sb, cb, db = b
    ss = (sa * sb) >> prec
    den = (1 << prec) - ((m * ((ss * ss) >> prec)) >> prec)
    ns = (sa * ((cb * db) >> prec) + sb * ((ca * da) >> prec)) >> prec
    nc = (ca * cb - ss * ((da * db) >> prec)) >> prec
    nd = (da * db - ((m * ss) >> prec) * ((ca * cb) >> prec)) >> prec
    return [(x << prec) // den for x in (ns, nc, nd)]


def _extend_float(x, m, beta, w0, k0, deg):
    """Extend the cells' Taylor series of sn, cn, dn and g from degree k0 to deg in float64.

    ``x``: (4, deg + 1, ncell) array, rows 0..k0 filled (rounded from fixed point); rows
    k0 + 1..deg are filled in place by the recurrences of :func:`_series`, every cell at
    once. ``m``, ``beta``, ``w0 = 1 + beta dn`` (per cell): floats within one rounding.
    Their errors are bounded by :func:`_float_errors`.
    """
    s, c, d, g = x
    for k in range(k0, deg):
        cd = np.einsum('jn,jn->n', c[:k + 1], d[k::-1])
        sd = np.einsum('jn,jn->n', s[:k + 1], d[k::-1])
        sc = np.einsum('jn,jn->n', s[:k + 1], c[k::-1])
        s[k + 1] = cd / (k + 1)
        c[k + 1] = -sd / (k + 1)
        d[k + 1] = -(m * sc) / (k + 1)
    for k in range(k0 + 1, deg + 1):
        acc = np.einsum('jn,jn->n', d[1:k + 1], g[k - 1::-1])
        g[k] = (d[k] - beta * acc) / w0


@functools.lru_cache(maxsize=None)
def _float_errors(k0, deg):
    """Bounds on the errors of :func:`_extend_float`'s coefficients: (E, F), per degree.

    E[k] bounds |computed - exact| of sn's, cn's and dn's k-th coefficient, F[k] of g's,
    at every cell, from: the exact coefficients' majorants (|sn_k|, |cn_k|, |dn_k| <= 1,
    |g_k| <= 2^k at a real point), 0 <= m, beta <= 1 and w0 >= 1 (each rounded once),
    rows <= k0 rounded from fixed point (one rounding plus the table's 2^-80), and for
    each later row the inputs' errors carried through the sum of products, its rounding
    (gamma_n times the sum of the terms' magnitudes, in any order of summation) and one
    rounding per product and quotient. Computed once per (k0, deg), with 0.1 % spare for
    the bound's own rounding.
    """
    u = _U
    e = [u + _DELTA] * (k0 + 1)
    for k in range(k0, deg):
        n = k + 1
        gam = n * u / (1 - n * u)
        err = sum((1 + e[j]) * e[k - j] + e[j] for j in range(n))
        mag = sum((1 + e[j]) * (1 + e[k - j]) for j in range(n))
        e.append((err + gam * mag + 3.01 * u * mag) / n)        # d: m * sum, then / n
    f = [(u + _DELTA) * 2.0 ** k for k in range(k0 + 1)]
    for k in range(k0 + 1, deg + 1):
        gam = k * u / (1 - k * u)
        err_a = sum((1 + e[j]) * f[k - j] + e[j] * 2.0 ** (k - j) for j in range(1, k + 1))
        mag_a = sum((1 + e[j]) * (2.0 ** (k - j) + f[k - j]) for j in range(1, k + 1))
        err_a += gam * mag_a
        mag_n = (1 + e[k] + mag_a) * (1 + 3 * u)                 # |d_k - beta acc|
        err_n = e[k] + err_a + 2.01 * u * mag_a + u * mag_n
        f.append(err_n + 2.01 * u * mag_n)                        # / w0 (w0, its float >= 1)
    return np.array(e) * 1.001, np.array(f) * 1.001


def _q_tail(deg, r=_R):
    """Bound on the degree > deg part of the integral of g's series over [0, +-r].

    g's Taylor coefficients at a real point are bounded by 2^k (majorant 1/(1 - 2u)), so
    the tail is at most ``sum_{k > deg} 2^k r^(k+1) / (k+1) <= r (2r)^(deg+1) / ((deg+2)
    (1 - 2r))``.
    """
    return r * (2 * r) ** (deg + 1) / ((deg + 2) * (1 - 2 * r))


def _float_fx(v, prec):
    """Return float v in fixed point (scaled by 2^prec), exact but for bits below 2^-prec."""
    return int(math.ldexp(v, prec))


def _horner_fx(coef, shift):
    """Sum of coef[k] z^k at z = 2^-shift (fixed point)."""
    acc = 0
    for a in reversed(coef):
        acc = (acc >> shift) + a
    return acc


def _horner_fx_z(coef, z, prec):
    """Sum of coef[k] z^k at a fixed-point z."""
    acc = 0
    for a in reversed(coef):
        acc = ((acc * z) >> prec) + a
    return acc


def _integral_fx(coef, shift, sign):
    """Integral of the series from 0 to sign * 2^-shift (sign = +1) or from -2^-shift to 0."""
    out = 0
    for k, a in enumerate(coef):
        term = (a >> (shift * (k + 1))) // (k + 1)
        out += term if (sign > 0 or k % 2 == 0) else -term
    return out


def _integral_fx_z(coef, z, prec):
    """Integral of the series from 0 to a fixed-point z."""
    out = 0
    zp = z
    for k, a in enumerate(coef):
        out += ((a * zp) >> prec) // (k + 1)
        zp = (zp * z) >> prec
    return out


# ---------------------------------------------------------------------------------------
# the table over [0, K]: its pieces, in the order _build_table takes them

def _fixed_point(prec):
    """Return the conversions of mpf to fixed point at ``prec`` bits and back: (fx, mpf)."""
    def fx(x):
        return int(mpmath.nint(mpmath.ldexp(x, prec)))

    def mpf(i):
        return mpmath.ldexp(mpmath.mpf(i), -prec)

    return fx, mpf


def _table_degrees(ncell, closed_form):
    """Return (k0, deg): the degrees of each cell's series in fixed point and in all.

    deg makes the integral of g's truncation, summed over the cells, below 2^-64 (2^-90
    without a closed form for the mean rate, where all of each series is fixed point).
    """
    target = 2.0 ** -64 if closed_form else 2.0 ** -90
    deg = _DEG
    while 2 * ncell * _q_tail(deg) > target:
        deg += 1
    k0 = min(_K0, deg) if closed_form else deg
    return k0, deg


def _centre_series(ncell, mf, bf, k0, prec):
    """Return (s0, vals, lead): the series at 0, the last centre's values, each centre's series.

    s0: sn, cn, dn's series at 0 to the degree that makes it exact to 2^-prec at
    |z| <= 1/16 (coefficients <= 1: tail <= 16^-(n + 1) * 16 / 15). The centres' values
    come from u = h/2 and u = h by the addition theorem; ``lead[i]``: centre i's series
    of sn, cn, dn and g to degree k0, fixed point.
    """
    one = 1 << prec
    s0 = _series(0, one, one, mf, bf, prec // 4 + 1, prec, with_g=False)[:3]
    half = [_horner_fx(x, 4) for x in s0]                   # at u = h/2
    step = _add_fx(half, half, mf, prec)                    # at u = h
    lead = []
    vals = half
    for i in range(ncell):
        if i:
            vals = _add_fx(vals, step, mf, prec)
        lead.append(_series(vals[0], vals[1], vals[2], mf, bf, k0, prec))
    return s0, vals, lead


def _float_rows(lead, mf, bf, k0, deg, prec):
    """Return the cells' series as a (4, deg + 1, ncell) float array, rows > k0 in float64."""
    one = 1 << prec
    x = np.empty((4, deg + 1, len(lead)))
    for i, ser in enumerate(lead):
        for f in range(4):
            x[f, :k0 + 1, i] = [v / one for v in ser[f]]  # int / int rounds correctly
    w0 = np.array([(one + ((bf * ser[2][0]) >> prec)) / one for ser in lead])
    _extend_float(x, mf / one, bf / one, w0, k0, deg)
    return x


def _centre_integrals(x, lead, err_f, k0, deg, prec):
    """Return (integ, fp_err): the integral of g from 0 to each centre, fixed point.

    The integrals over each half-cell: the fixed-point rows, then the float rows (their
    errors, < 2^-67 a half-cell, bounded by fp_err each).
    """
    kf = np.arange(k0 + 1, deg + 1)
    w_plus = _R ** (kf + 1) / (kf + 1)
    up = (w_plus @ x[3, k0 + 1:]).tolist()                  # int_0^{h/2}
    down = ((w_plus * (-1.0) ** kf) @ x[3, k0 + 1:]).tolist()   # int_{-h/2}^0
    fp_err = float(np.sum((err_f[k0 + 1:] + 2 * (deg + 2) * _U * 2.0 ** kf) * w_plus))
    integ = []
    acc = 0
    for i in range(len(lead)):
        if i:
            acc += _integral_fx(lead[i - 1][3], 4, 1) + _float_fx(up[i - 1], prec)
        acc += _integral_fx(lead[i][3], 4, -1) + _float_fx(down[i], prec)
        integ.append(acc)
    return integ, fp_err


def _check_at_k(m, mf, s0, vals, x, zk, err_e, deg, prec):
    """Check the table at u = K, where sn = 1, cn = 0, dn = sqrt(1 - m); raise if it fails.

    The values stepped on from the last centre must agree to 2^-83; the last cell's own
    series, within its truncation r^(deg+1) / (1 - r) and the float rows' error bounds: a
    check of those bounds at one point.
    """
    fx, mpf = _fixed_point(prec)
    one = 1 << prec
    at_k = _add_fx(vals, [_horner_fx_z(v, zk, prec) for v in s0], mf, prec)
    exact_k = [one, 0, fx(mpmath.sqrt(1 - m))]
    series_k = [_horner_fx_z([_float_fx(v, prec) for v in x[f, :, -1]], zk, prec)
                for f in range(3)]
    allow = _R ** (deg + 1) / (1 - _R) + float(np.sum(err_e * _R ** np.arange(deg + 1)))
    if max(abs(a - b) for a, b in zip(at_k, exact_k)) > one >> 83 or \
            max(abs(a - b) for a, b in zip(series_k, exact_k)) > _float_fx(allow, prec):
        raise PrecisionError(
            f'the elliptic table failed its check at u = K (m = {float(m)!r}): '
            f'{[float(mpf(a - b)) for a, b in zip(at_k, exact_k)]}, series '
            f'{[float(mpf(a - b)) for a, b in zip(series_k, exact_k)]}')


def _stored_coefficients(x, lead, integ, gbar_fx, k0, prec):
    """Return the (_DEG + 1, ncell, 4) coefficients of sn, cn, dn and Q at the centres.

    sn, cn, dn as computed; Q = integral of (g - gbar): its constant and linear terms
    from fixed point, then g_(k-1) / k.
    """
    one = 1 << prec
    coef = np.empty((_DEG + 1, len(lead), 4))
    coef[:, :, :3] = x[:3, :_DEG + 1].transpose(1, 2, 0)
    for i, ser in enumerate(lead):
        centre_fx = (2 * i + 1) << (prec - 4)                 # (i + 1/2) / 8
        coef[0, i, 3] = (integ[i] - ((gbar_fx * centre_fx) >> prec)) / one
        coef[1, i, 3] = (ser[3][0] - gbar_fx) / one
        for k in range(1, min(k0, _DEG - 1) + 1):
            coef[k + 1, i, 3] = (ser[3][k] // (k + 1)) / one
    kq = np.arange(k0 + 1, _DEG)
    if len(kq):
        coef[kq + 1, :, 3] = x[3, kq] / (kq + 1)[:, None]
    return coef


def _cell_bounds(coef, k0, err_e, err_f, q_err):
    """Return the a-priori error bounds per cell and function, (ncell, 4).

    Truncation + the coefficients' errors (one rounding for those from fixed point, the
    proved bound for the float rows) + Horner; Q's also its constant terms' q_err.
    """
    r = _R
    tail = np.array([r ** (_DEG + 1) / (1 - r)] * 3 +
                    [r * (2 * r) ** _DEG / (_DEG + 1) / (1 - 2 * r)])
    absc = np.abs(coef)
    rk = r ** np.arange(_DEG + 1)
    exact_rows = np.zeros((_DEG + 1, 4), dtype=bool)
    exact_rows[:k0 + 1, :3] = True
    exact_rows[:k0 + 2, 3] = True
    coef_err = _U * np.einsum('k,knf->nf', rk, absc * exact_rows[:, None, :])
    ee = np.zeros((_DEG + 1, 4))
    ee[:, :3] = err_e[:_DEG + 1, None]
    kq_all = np.arange(1, _DEG + 1)
    ee[1:, 3] = (err_f[kq_all - 1] + _U * (2.0 ** (kq_all - 1) + err_f[kq_all - 1])) \
        / kq_all * 1.001
    coef_err += np.sum(np.where(exact_rows, 0.0, ee) * rk[:, None], axis=0)[None, :]
    ncell = coef.shape[1]
    y = np.zeros((ncell, 4))
    e = np.zeros((ncell, 4))
    for k in range(_DEG, -1, -1):
        y_next = y
        y = absc[k] + r * y_next
        e = r * e * (1 + 3 * _U) + _U * (2 * r * y_next + y) * (1 + 2 * _U)
    cell_err = (e + coef_err + tail) * 1.01                 # (ncell, 4)
    cell_err[:, 3] += q_err                                 # Q's constant terms
    return cell_err


# ---------------------------------------------------------------------------------------
# per-scene constants (K, u0, the mean rate: mpmath, Arb) and the phase reduction

def _pieces(x, count=8, bits=26):
    """Split mpf x into floats of <= ``bits`` significant bits; residual after each."""
    out, res = [], []
    r = +x
    for _ in range(count):
        if r == 0:
            p = 0.0
        else:
            with mp.workprec(bits):
                p = float(+r)
        out.append(p)
        r = r - p
        res.append(float(abs(r)) * (1 + 1e-12) + 1e-300)
    return out, res


def _split_offset(x):
    """Reduce an mpf number of turns to [-1/2, 1/2] as a double-double (hi, lo)."""
    x = x - mpmath.nint(x)
    hi = float(x)
    return hi, float(x - hi)


def _arb_exact(flint, x):
    """Return the mpf x as an exact arb (mantissa times a power of two)."""
    sign, man, exp, _ = x._mpf_
    v = flint.arb(int(man)) * flint.arb(2) ** int(exp)
    return -v if sign else v


def _sep_err(au, u_err):
    """Error of sech, tanh and the angle integral at |u| = au known to u_err.

    Their slopes are at most 1 and at most ``2 exp(-(|u| - u_err))``; where u_err is a
    quarter of |u| or more (or infinite) only their range (2) bounds them.
    """
    with np.errstate(over='ignore', invalid='ignore'):
        near = u_err <= 0.25 * au
        tail = u_err * np.minimum(1.0, 2.0 * np.exp(-0.75 * np.where(near, au, 0.0)))
        return np.where(near, tail, np.minimum(u_err, 2.0)) + 8 * _U


def _flint_if(use_arb):
    """Return the python-flint module where Arb is asked for and installed, else None."""
    if not use_arb:
        return None
    try:
        import flint
    except ImportError:
        return None
    return flint


def _elliptic_constants(m, phi0, use_arb):
    """Return ``(F(phi0 | m) at 2 mp.prec bits, K(m) at mp.prec bits)`` as mpf.

    With python-flint (``use_arb``), both are Arb balls computed at 64 bits more than they
    are returned with, and their radii must lie below 2^-mp.prec relative (the bits the
    set-up uses: certified); else mpmath, uncertified. F loses bits as m -> 1 and
    phi0 -> pi/2, hence its doubled precision in either.
    """
    prec = mp.prec
    flint = _flint_if(use_arb)
    if flint is None:
        with mp.workprec(2 * prec):
            u0 = +mpmath.ellipf(phi0, m)
        return u0, mpmath.ellipk(m)
    old = flint.ctx.prec
    try:
        out = []
        for bits, what in ((2 * prec, 'F(phi0 | m)'), (prec, 'K(m)')):
            flint.ctx.prec = bits + 64
            m_b = _arb_exact(flint, m)
            if what == 'K(m)':
                ball = flint.acb(m_b).elliptic_k().real
            else:
                ball = flint.acb.elliptic_f(_arb_exact(flint, phi0), m_b).real
            with mp.workprec(bits):
                val = _arb_to_mpf(ball, prec)
            if val is None:
                raise PrecisionError(f'{what} (m = {float(m)!r}) is not resolved by Arb '
                                     f'at {bits + 64} bits: {ball}')
            out.append(val)
        return tuple(out)
    finally:
        flint.ctx.prec = old


def _arb_to_mpf(ball, prec):
    """Round an Arb ball's midpoint to an mpf; None unless its radius is below 2^-prec of it.

    The mpf has the current mpmath precision.
    """
    man, exp = ball.mid().man_exp()
    rad_man, rad_exp = ball.rad().man_exp()
    val = mpmath.mpf((int(man), int(exp)))
    rad = mpmath.mpf((int(rad_man), int(rad_exp)))
    if not (mpmath.isfinite(val) and rad <= abs(val) * mpmath.ldexp(1, -prec)):
        return None
    return val


def _mean_rate(m, beta, use_arb):
    """Return the mean of g = dn / (1 + beta dn) over a quarter period, at mp.prec bits.

    In closed form (dn = d am / du, dn^2 = 1 - m sn^2):
    ``K gbar = (K - Pi(-n | m) / (1 - beta^2) + beta pi / (2 sqrt((1 - beta^2)(1 - beta^2
    + beta^2 m)))) / beta`` with ``n = beta^2 m / (1 - beta^2)``, and pi / 2 for beta = 0,
    at as many more bits as the cancellation of its terms costs. From Arb balls (radius
    below the last bit) with python-flint, else from mpmath. None where beta^2 is 1 at
    twice the bits, where the cancellation would cost more than 4 mp.prec bits, or where
    Arb cannot resolve it at up to four times the bits that should take.
    """
    prec = mp.prec
    with mp.workprec(2 * prec + 16):
        one_b2 = 1 - beta * beta                # exact: beta has at most prec bits
    if not one_b2 > 0:
        return None
    # the three terms are ~ K / (1 - beta^2), their sum ~ K / 2: work with the bits lost
    lost = max(0, int(-mpmath.log(one_b2, 2)) + 1)
    if lost > 4 * prec:
        return None
    work = prec + 64 + lost
    flint = _flint_if(use_arb)
    if flint is None:
        with mp.workprec(work):
            kk = mpmath.ellipk(m)
            if beta == 0:
                return +(mpmath.pi / (2 * kk))
            one_b2 = 1 - beta * beta
            pi3 = mpmath.ellippi(-beta * beta * m / one_b2, m)
            i2 = mpmath.pi / (2 * mpmath.sqrt(one_b2 * (one_b2 + beta * beta * m)))
            val = (kk - pi3 / one_b2 + beta * i2) / (beta * kk)
        return +val
    old = flint.ctx.prec
    try:
        for _ in range(3):                      # Arb says when its bits did not suffice
            flint.ctx.prec = work
            m_b, b_b = _arb_exact(flint, m), _arb_exact(flint, beta)
            kk = flint.acb(m_b).elliptic_k().real
            if beta == 0:
                ball = flint.arb.pi() / (2 * kk)
            else:
                one_b2 = 1 - b_b * b_b
                pi3 = flint.acb.elliptic_pi(-b_b * b_b * m_b / one_b2, m_b).real
                i2 = flint.arb.pi() / (2 * (one_b2 * (one_b2 + b_b * b_b * m_b)).sqrt())
                ball = (kk - pi3 / one_b2 + b_b * i2) / (b_b * kk)
            val = _arb_to_mpf(ball, prec)
            if val is not None:
                return val
            work *= 2
        return None
    finally:
        flint.ctx.prec = old


def _q_mp_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz]


class _Turns:
    """A phase ``rho t + offset`` in turns, reduced to [-1/2, 1/2] from exact float t.

    ``rho`` is split into 26-bit pieces, t into two 26-bit halves (Veltkamp), so every
    partial product is exact and its fractional part too; the fractions are summed in
    double-double. Error, in turns: ``2 u + |t| (residual(k pieces) + |rho| 2^(8 - prec)
    + rho_err)``, the last two terms for rho itself, computed from the exact inputs in some
    tens of operations at ``prec`` bits (the current mpmath precision), and ``rho_err``
    for any input of rho known less well than that. The number of pieces k is chosen per
    sample from its own |t| (:meth:`count`), so a sample's phase and its error depend on
    t alone, not on the batch it is evaluated in.
    """

    def __init__(self, rho, offset, rho_err=0.0):
        self.pieces, self.resid = _pieces(rho)
        self.off = _split_offset(offset)
        rel = float(abs(rho)) * 2.0 ** (8 - mp.prec) + float(rho_err)
        self.resid = [r + rel for r in self.resid]
        # the pieces any t takes at most: where one more would not halve the residual
        cap = len(self.pieces)
        for k in range(1, len(self.resid)):
            if self.resid[k] >= 0.5 * self.resid[k - 1]:
                cap = k + 1
                break
        self._cap = cap
        self._resid_arr = np.array(self.resid)

    def count(self, at):
        """Pieces for |t| = at: the fewest whose residual times |t| is <= 2^-62, at most the cap.

        The residuals fall (by half at least) up to the cap, so this is one plus the number
        of them, before the cap's, that |t| does not bring below 2^-62.
        """
        k = 1
        for r in self.resid[:self._cap - 1]:
            if r * at > 2.0 ** -62:
                k += 1
        return k

    def counts(self, at):
        """Vectorised :meth:`count` for an array ``at`` of |t| (the same comparisons)."""
        k = np.ones(at.shape, dtype=np.int64)
        for r in self.resid[:self._cap - 1]:
            k += r * at > 2.0 ** -62
        return k

    def reduce(self, t):
        """Vectorised: (tau in [-1/2, 1/2], error bound in turns) for a float array t.

        Each sample takes its own :meth:`count` of pieces (a piece it does not take leaves
        its sums untouched), so its bits are those of :meth:`reduce1`.
        """
        at = np.abs(t)
        ks = self.counts(at)
        k_lo = int(np.min(ks)) if t.size else 1
        k_hi = int(np.max(ks)) if t.size else 1
        c = _TWO27 * t
        th = c - (c - t)
        tl = t - th
        hi = np.full_like(t, self.off[0])
        lo = np.full_like(t, self.off[1])
        for n, p in enumerate(self.pieces[:k_hi]):
            hi_p, lo_p = hi, lo.copy()
            for part in (th, tl):
                x = p * part
                # a product beyond float range is an exact integer: fraction 0
                f = np.where(np.isfinite(x), x - np.rint(x), 0.0)
                s = hi_p + f
                bb = s - hi_p
                lo_p += (hi_p - (s - bb)) + (f - bb)
                hi_p = s - np.rint(s)
            if n < k_lo:
                hi, lo = hi_p, lo_p
            else:
                take = ks > n
                hi = np.where(take, hi_p, hi)
                lo = np.where(take, lo_p, lo)
        tau = hi + lo
        tau -= np.rint(tau)
        return tau, 2 * _U + at * self._resid_arr[ks - 1] + 1e-30

    def reduce1(self, t):
        """Scalar :meth:`reduce` in Python floats."""
        c = _TWO27 * t
        th = c - (c - t)
        tl = t - th
        at = abs(t)
        k = self.count(at)
        hi, lo = self.off
        for p in self.pieces[:k]:
            for part in (th, tl):
                x = p * part
                f = x - round(x) if math.isfinite(x) else 0.0
                s = hi + f
                bb = s - hi
                lo += (hi - (s - bb)) + (f - bb)
                hi = s - round(s)
        tau = hi + lo
        tau -= round(tau)
        return tau, 2 * _U + at * self.resid[k - 1] + 1e-30


def _frame(inertia, w):
    """Choose B': return (rows of R_B'B as index/sign pairs, side sign of I3' - I2')."""
    order = sorted(range(3), key=lambda i: inertia[i])       # ascending moments
    lo_i, mid, hi_i = order
    fi = [Fraction(v) for v in inertia]
    fw = [Fraction(v) for v in w]
    # 2T I2 - |h|^2 = sum I_i (I2 - I_i) w_i^2: > 0 when h circulates about the smallest
    e2 = sum(fi[i] * (fi[mid] - fi[i]) * fw[i] ** 2 for i in range(3))
    axis3, axis1 = (lo_i, hi_i) if e2 > 0 else (hi_i, lo_i)
    s3 = 1 if w[axis3] > 0 else -1
    idx = [axis1, mid, axis3]
    # sign of the permutation (rows e_axis1, e_mid, e_axis3)
    perm = np.eye(3)[idx]
    s1 = int(round(np.linalg.det(perm))) * s3                 # det = s1 * s3 * det(perm) = 1
    rows = np.stack([s1 * np.eye(3)[axis1], np.eye(3)[mid], s3 * np.eye(3)[axis3]])
    return rows, e2 == 0


class TriaxialSolution(BaseSolution):
    """The exact torque-free motion of a triaxial body; evaluate it with :meth:`at`.

    Keeps the contract of :class:`~.solution.BaseSolution` (the torque is zero).

    Attributes
    ----------
    scene : Scene
    model : str
        ``'torque-free-triaxial'``.
    method : str
        ``'jacobi-elliptic-table'`` (m < 1) or ``'separatrix-closed-form'`` (m = 1, the
        tennis-racket separatrix): float64 with an a-priori error bound; the per-scene
        constants come from mpmath (K, u0 and the mean rate from Arb balls on the flint
        backend; not carried as balls).
    backend : str
        The backend asked for ('flint' or 'mpmath'); both use the same evaluation, the
        flint backend takes K(m), u0 and the mean rate from Arb.
    tol : float
        Attitude accuracy asked, rad. :func:`solve` raises PrecisionError when the
        float64 bound of this scene cannot meet it.
    precision : int
        Bits used for the per-scene constants.
    """

    MODELS = {MODEL: REFERENCE}
    model = MODEL

    def __init__(self, scene, tol, backend, max_prec, floor=FLOAT_FLOOR):
        self.scene = scene
        self.tol = tol
        self.backend = backend
        self._floor = floor
        inertia = scene.inertia
        rows, on_separatrix = _frame(inertia, scene.omega0)
        self._rows = rows                                        # R_B'B
        # omega_B = R_B'B^T omega_B': a signed permutation, each component one product
        # (amp * sign) * f of the B' component it comes from (exact, no matrix product)
        self._w_src = tuple(int(np.argmax(np.abs(rows[:, j]))) for j in range(3))
        self._w_sign = tuple(float(rows[i, j]) for j, i in enumerate(self._w_src))
        q_b1b = quat.from_matrix(rows)
        # 1 - m, free of cancellation, sets the working precision (m itself must not round
        # to 1); K ~ log(4 / sqrt(1 - m)) sets the size of the table
        with mp.workprec(128):
            one_m = self._one_minus_m(rows)
        extra = 0 if one_m == 0 else max(0, int(-mpmath.log(one_m, 2)) + 8)
        if one_m != 0 and extra > 2 * _K_MAX * 1.45:
            raise PrecisionError(
                f'omega0 = {scene.omega0} lies within 1 - m = {mpmath.nstr(one_m, 2)} of the '
                f'separatrix without being on it: the quarter period K = '
                f'{float(mpmath.log(4 / mpmath.sqrt(one_m))):.0f} exceeds {_K_MAX} and its '
                f'table would take minutes. Put omega0 on the separatrix or move it off by '
                f'more than 1e-50 relative')
        with mp.workprec(128 + extra):
            self._setup(rows, on_separatrix, q_b1b, max_prec)
        if self._static_bound > tol:
            raise PrecisionError(
                f'the float64 evaluation of this torque-free triaxial scene is bounded by '
                f'{self._static_bound:.2e} rad, above tol = {tol!r} rad; ask tol >= '
                f'{2 * self._static_bound:.1e}')

    # -- set-up ----------------------------------------------------------------------
    def _one_minus_m(self, rows):
        wb = [mpmath.mpf(v) for v in self.scene.omega0]
        ib = [mpmath.mpf(v) for v in self.scene.inertia]
        w = [sum(rows[i][j] * wb[j] for j in range(3)) for i in range(3)]
        i1, i2, i3 = (sum(rows[i][j] ** 2 * ib[j] for j in range(3)) for i in range(3))
        e1 = i2 * (i2 - i1) * w[1] ** 2 + i3 * (i3 - i1) * w[2] ** 2
        e2 = i1 * (i1 - i2) * w[0] ** 2 + i3 * (i3 - i2) * w[2] ** 2       # h^2 - 2T I2
        return abs((i3 - i1) * e2 / ((i3 - i2) * e1))

    def _setup(self, rows, on_separatrix, q_b1b, max_prec):
        """Compute the per-scene constants at mp's precision, then the table or closed form.

        The amplitudes, lam, h and 2T in B' (Landau & Lifshitz, Sec. 37), the parameter m
        and the phase u0; then :meth:`_setup_frames`, and :meth:`_setup_separatrix` or
        :meth:`_setup_table`.
        """
        inertia = self.scene.inertia
        wb = [mpmath.mpf(v) for v in self.scene.omega0]
        ib = [mpmath.mpf(v) for v in inertia]
        w = [sum(rows[i][j] * wb[j] for j in range(3)) for i in range(3)]     # omega_B'
        i1, i2, i3 = (sum(rows[i][j] ** 2 * ib[j] for j in range(3)) for i in range(3))
        sigma = 1 if i3 > i2 else -1
        e3 = i1 * (i3 - i1) * w[0] ** 2 + i2 * (i3 - i2) * w[1] ** 2       # 2T I3 - h^2
        e1 = i2 * (i2 - i1) * w[1] ** 2 + i3 * (i3 - i1) * w[2] ** 2       # h^2 - 2T I1
        a1 = mpmath.sqrt(e3 / (i1 * (i3 - i1)))
        a2 = mpmath.sqrt(e3 / (i2 * (i3 - i2)))
        a3 = mpmath.sqrt(e1 / (i3 * (i3 - i1)))
        lam = mpmath.sqrt((i3 - i2) * e1 / (i1 * i2 * i3))
        hvec = [i1 * w[0], i2 * w[1], i3 * w[2]]
        hn = mpmath.sqrt(sum(v * v for v in hvec))
        two_t = i1 * w[0] ** 2 + i2 * w[1] ** 2 + i3 * w[2] ** 2
        beta = i3 * a3 / hn
        if on_separatrix:
            m = mpmath.mpf(1)
            s1 = 1 if w[0] > 0 else -1
            amp1, amp2 = s1 * a1, sigma * s1 * a2
            u0 = mpmath.atanh(w[1] / amp2)
        else:
            e2 = i1 * (i1 - i2) * w[0] ** 2 + i3 * (i3 - i2) * w[2] ** 2   # h^2 - 2T I2
            m = 1 - (i3 - i1) * e2 / ((i3 - i2) * e1)
            amp1, amp2 = a1, sigma * a2
            phi0 = mpmath.atan2(w[1] / amp2, w[0] / amp1)
            u0, kk = _elliptic_constants(m, phi0, self.backend == 'flint')
        self.m = m
        self._beta_mp = beta
        self._amp = np.array([float(amp1), float(amp2), float(a3)])
        self._w_amp = tuple(s * float(self._amp[i]) for s, i in zip(self._w_sign, self._w_src))
        self._ut = np.array([float(i1 * amp1 / hn), float(i2 * amp2 / hn), float(beta)])
        cq = (i1 * amp1) * (i2 * amp2) / hn ** 2
        self._cq = float(cq)
        self._lam = float(lam)
        self._setup_frames(hvec, hn, q_b1b)
        if on_separatrix:
            self._setup_separatrix(beta, u0, cq, two_t, hn)
        else:
            self._setup_table(m, beta, kk, lam, u0, cq, two_t, hn, max_prec)

    def _setup_frames(self, hvec, hn, q_b1b):
        """Store q_NL = q_NB(0) ⊗ q_BB' ⊗ conj(q_LB'(0)) and q_B'B, the outer factors."""
        # q_LB' = (u2, -u1, 0, 1 + u3) / norm
        u = [v / hn for v in hvec]
        p = [u[1], -u[0], mpmath.mpf(0), 1 + u[2]]
        pn = mpmath.sqrt(sum(v * v for v in p))
        p_conj = [-p[0] / pn, -p[1] / pn, -p[2] / pn, p[3] / pn]
        att = [mpmath.mpf(v) for v in self.scene.attitude0]
        qb = [mpmath.mpf(float(v)) for v in q_b1b]
        qb_conj = [-qb[0], -qb[1], -qb[2], qb[3]]
        left = _q_mp_mul(_q_mp_mul(att, qb_conj), p_conj)
        ln = mpmath.sqrt(sum(v * v for v in left))
        self._left = np.array([float(v / ln) for v in left])
        self._right = np.array(q_b1b, dtype=float)
        self._left_t = tuple(self._left)
        self._right_t = tuple(self._right)

    def _setup_separatrix(self, beta, u0, cq, two_t, hn):
        """Set the closed form on the separatrix (m = 1): its constants and bound."""
        self.method = 'separatrix-closed-form'
        self.precision = 128
        self._sep = True
        self._u0 = float(u0)
        self._u0_err = 2 * _U * abs(self._u0)
        rb = mpmath.sqrt((1 - beta) / (1 + beta))
        self._sep_c = (float(2 / mpmath.sqrt(1 - beta ** 2)), float(rb))
        f0 = 2 / mpmath.sqrt(1 - beta ** 2) * mpmath.atan(rb * mpmath.tanh(u0 / 2))
        self._xi_c = float(cq * f0)
        omega = two_t / hn
        self._xi_turns = _Turns(omega / (4 * mp.pi), 0)
        # rounding of xi = 4 pi tau + xi_c - c F (|F| <= c0 pi / 2), then sin, cos
        self._xi_round = 4 * _U * (2 * math.pi + abs(self._xi_c) +
                                   abs(self._cq) * self._sep_c[0] * math.pi / 2) + 4 * _U
        self._static_bound = self._floor + 40 * _U * (1 + abs(self._u0))

    def _setup_table(self, m, beta, kk, lam, u0, cq, two_t, hn, max_prec):
        """Set the table (m < 1), the phases' rates and offsets, and the bound."""
        self._sep = False
        self.method = 'jacobi-elliptic-table'
        # precision for carrying the cell centres over [0, K] (errors grow like e^u there)
        prec = max(mp.prec, 128 + int(1.5 * float(kk)))
        if prec > max(max_prec, 256) + 256:
            raise PrecisionError(f'the quarter period K = {float(kk):.3g} needs {prec} bits '
                                 f'(> max_prec = {max_prec}); raise max_prec')
        self.precision = prec
        with mp.workprec(prec):
            self._build_table(m, beta, kk)
        with mp.workprec(prec):
            gbar = self._gbar_mp
            u_turns = lam / (4 * kk)
            self._u_turns = _Turns(u_turns, u0 / (4 * kk))
            omega = two_t / hn - cq * gbar * lam
            self._xi_turns = _Turns(omega / (4 * mp.pi), 0, rho_err=float(
                abs(cq * gbar * lam) / (4 * mp.pi)) * self._gbar_rel_err)
            # Q at u0 (exact, from the high-precision table)
            q_u0 = self._q_mp(u0, kk)
            self._xi_c = float(cq * q_u0)
        self._K = float(kk)
        self._kk_mp = kk
        # rounding of xi = 4 pi tau + xi_c - c Q (|Q| <= its cells' bound), then sin, cos
        q_max = float(np.max(np.sum(np.abs(self._coef[:, :, 3]) *
                                    (_R ** np.arange(_DEG + 1))[:, None], axis=0)))
        self._xi_round = 4 * _U * (2 * math.pi + abs(self._xi_c) + abs(self._cq) * q_max) \
            + 4 * _U + abs(self._cq) * self._q_err
        self._static_bound = self._bound_constant()

    def _build_table(self, m, beta, kk):
        """Tabulate sn, cn, dn and Q over [0, K]: float cells and their error bounds.

        The values at the cell centres (i + 1/2) h come from u = h/2 and u = h by the
        addition theorem (the series at 0, exact to 2^-prec there, gives both) in fixed
        point, checked by stepping on to u = K, where sn = 1, cn = 0, dn = sqrt(1 - m).
        Each cell's Taylor series: its first ``_K0`` degrees in fixed point (they carry the
        integral of g, whose sum over the cells must not drift), the rest in float64 for
        all cells at once with a proved bound on every coefficient's error
        (:func:`_float_errors`), up to the degree the integral of g needs (its
        truncation, summed over the cells, is in Q's bound).
        """
        prec = mp.prec
        fx, mpf = _fixed_point(prec)
        mf, bf = fx(m), fx(beta)
        ncell = int(mpmath.ceil(kk / _H))
        # the mean rate sets the phase at long times: from its closed form; where that is
        # out of reach, the table's own, which then needs its integral to 2^-90, all of
        # each cell's series in fixed point
        gbar = _mean_rate(m, beta, self.backend == 'flint')
        k0, deg = _table_degrees(ncell, gbar is not None)
        self._degrees = (k0, deg)
        err_e, err_f = _float_errors(k0, deg)
        s0, vals, lead = _centre_series(ncell, mf, bf, k0, prec)
        x = _float_rows(lead, mf, bf, k0, deg, prec)
        integ, fp_err = _centre_integrals(x, lead, err_f, k0, deg, prec)
        self._fx = (fx, mpf, prec)
        self._g_lead = [ser[3] for ser in lead]
        self._g_rest = x[3, k0 + 1:]
        # Q at a centre i sums 2 i + 1 half-cell integrals of degree deg; one more piece
        # reaches any u (Q(u0) for the phase constant)
        self._q_err = (2 * ncell + 1) * (_q_tail(deg) + fp_err + (deg + 2) * 2.0 ** -prec)
        zk = fx(kk - (ncell - mpmath.mpf(0.5)) * _H)            # |zk| <= h/2
        _check_at_k(m, mf, s0, vals, x, zk, err_e, deg, prec)
        total = mpf(integ[-1] + _integral_fx_z(self._g_fx(ncell - 1), zk, prec))
        self._settle_mean_rate(gbar, total, m, kk)
        self._integ_fx = integ
        coef = _stored_coefficients(x, lead, integ, fx(self._gbar_mp), k0, prec)
        self._coef = coef
        # (degree, function * ncell + cell): what _table gathers from
        self._coef_flat = np.ascontiguousarray(coef.transpose(0, 2, 1)).reshape(_DEG + 1, -1)
        self._centres = (np.arange(ncell) + 0.5) * _H
        self._ncell = ncell
        self._cell_err = _cell_bounds(coef, k0, err_e, err_f, self._q_err)

    def _settle_mean_rate(self, gbar, total, m, kk):
        """Keep the mean rate of g, gbar (None: none in closed form), checked by the table.

        The table's mean, total / K, is known to (its integral's errors + the 2^-83 its
        check stands for, per unit u) / K: it must agree with the closed form to that;
        where there is no closed form it is the mean rate, and the phase bound says so.
        """
        total_err = self._q_err + float(kk) * 2.0 ** -83
        self._gbar_rel_err = 0.0
        if gbar is None:
            gbar = total / kk
            self._gbar_rel_err = total_err / float(abs(total))
        elif not abs(total - gbar * kk) <= abs(gbar * kk) * mpmath.ldexp(1, -80) + total_err:
            raise PrecisionError(f"the elliptic table's mean rate {mpmath.nstr(total / kk, 20)}"
                                 f' disagrees with its closed form {mpmath.nstr(gbar, 20)} '
                                 f'(m = {float(m)!r})')
        self._gbar_mp = gbar

    def _g_fx(self, i):
        """Cell i's series of g in fixed point (the float rows exactly, below 2^-prec)."""
        prec = self._fx[2]
        return self._g_lead[i] + [_float_fx(v, prec) for v in self._g_rest[:, i]]

    def _q_mp(self, u, kk):
        """Q(u) (the periodic part of the integral of g) at mpf u, from the fixed-point table."""
        fx, mpf, prec = self._fx
        four_k = 4 * kk
        x = u - four_k * mpmath.nint(u / four_k)
        sgn = -1 if x < 0 else 1
        x = abs(x)
        if x > kk:
            y, sgn = 2 * kk - x, -sgn
        else:
            y = x
        i = min(int(y / _H), self._ncell - 1)
        z = y - (i + mpmath.mpf(0.5)) * _H
        val = mpf(self._integ_fx[i] + _integral_fx_z(self._g_fx(i), fx(z), prec))
        return sgn * (val - self._gbar_mp * y)

    def _bound_constant(self):
        """Return the t-independent part of the per-sample bound (the phase at t = 0)."""
        n = self._ncell
        e0 = np.full(n, 2 * _U)
        return float(np.max(self._bound(e0, e0, np.arange(n))))

    # -- evaluation ------------------------------------------------------------------
    def _bound(self, e_u, e_xi, idx):
        """Attitude bound (rad) from the phase errors (turns) and the cells used."""
        k = self._K
        dy = 4 * k * e_u + 3 * _U * k + _U * _R
        err = self._cell_err[idx] + dy[:, None]                  # (n, 4)
        du = np.abs(self._ut) * (err[:, :3] + 2 * _U)
        a, b, c = du[:, 0], du[:, 1], du[:, 2]
        d_lb = _D_LB * np.sqrt(a * a + b * b + c * c) + 10 * _U
        d_xi = 4 * np.pi * e_xi + abs(self._cq) * err[:, 3] + self._xi_round
        return d_lb + d_xi + self._floor

    def _table(self, tau):
        """sn, cn, dn, Q at u = 4K tau (tau in [-1/2, 1/2]) and the cells used."""
        a = np.abs(4.0 * tau)
        j = a >= 1.0
        rho = np.where(j, a - 1.0, a)
        y = self._K * np.where(j, 1.0 - rho, rho)
        ncell = self._ncell
        idx = np.clip((y * (1.0 / _H)).astype(np.int64), 0, ncell - 1)
        z = y - self._centres[idx]
        # Horner, the four functions at once: one flat gather per degree from the
        # function-major rows (half the time of gathering (n, 4) rows; same operations)
        flat = self._coef_flat
        at = (np.arange(4)[:, None] * ncell + idx).ravel()
        n = len(z)
        acc = np.take(flat[_DEG], at).reshape(4, n)
        buf = np.empty(4 * n)
        row = buf.reshape(4, n)
        for kk in range(_DEG - 1, -1, -1):
            acc *= z
            np.take(flat[kk], at, out=buf)
            acc += row
        st = np.where(tau < 0, -1.0, 1.0)
        sj = np.where(j, -1.0, 1.0)
        sn = acc[0] * st
        cn = acc[1] * sj
        dn = acc[2]
        q = acc[3] * st * sj
        return sn, cn, dn, q, idx

    def _separatrix(self, t):
        u = self._lam * t + self._u0
        au = np.abs(u)
        e = np.exp(-au)
        sech = 2 * e / (1 + e * e)
        sg = np.where(u < 0, -1.0, 1.0)
        tanh = sg * (1 - e * e) / (1 + e * e)
        th2 = sg * (1 - e) / (1 + e)
        c0, rb = self._sep_c
        fint = c0 * np.arctan(rb * th2)
        u_err = 3 * _U * (np.abs(self._lam * t) + abs(self._u0)) + self._u0_err
        # |d sech/du|, |d tanh/du|, |d F/du| <= 2 exp(-(|u| - err)) (and <= 1, c0 / 2)
        f_err = _sep_err(au, u_err)
        return sech, tanh, fint, f_err

    def _compose1(self, ux, uy, uz, txi, q):
        """q_NB (float 4-tuple) from the unit h in B and the turns of xi (scalar paths).

        The operations of :meth:`_at_array`'s composition in the same order, on Python
        floats; sin and cos are numpy's (the functions the arrays use), so one sample's
        bits are the batch's.
        """
        pw = 1.0 + uz
        pn = math.sqrt(uy * uy + ux * ux + pw * pw)
        px, py, pw = uy / pn, -ux / pn, pw / pn
        xi = 4 * math.pi * txi + self._xi_c - self._cq * q
        hs, hc = float(np.sin(0.5 * xi)), float(np.cos(0.5 * xi))
        mid = (hc * px - hs * py, hc * py + hs * px, hs * pw, hc * pw)
        mul = quat.multiply_floats
        return mul(mul(self._left_t, mid), self._right_t)

    def _w_array(self, f):
        """omega_BN_B, (n, 3), from the B' functions ``f = (f1, f2, f3)`` (arrays).

        ``omega_B = R_B'B^T (amp_i f_i)``: a signed permutation, one product a component.
        """
        src, wa = self._w_src, self._w_amp
        out = np.empty(f[0].shape + (3,))
        for j in range(3):
            np.multiply(wa[j], f[src[j]], out=out[..., j])
        return out

    def _w_scalar(self, f):
        """:meth:`_w_array` for one sample (floats): the same products."""
        src, wa = self._w_src, self._w_amp
        return np.array([wa[0] * f[src[0]], wa[1] * f[src[1]], wa[2] * f[src[2]]])

    def _separatrix_scalar(self, t, txi, exi):
        """:meth:`at` on the separatrix for one time, in plain floats (as :meth:`at`)."""
        sech, tanh, fint, f_err = self._sep1(t)
        c0 = self._sep_c[0]
        ut = self._ut
        qq = self._compose1(ut[0] * sech, ut[1] * tanh, ut[2] * sech, txi, fint)
        omega = self._w_scalar((sech, tanh, sech))
        a, b, c = (abs(float(ut[f])) * (f_err + 2 * _U) for f in range(3))
        bound = (_D_LB * math.sqrt(a * a + b * b + c * c) + 10 * _U +
                 4 * math.pi * exi + abs(self._cq) * c0 * f_err + self._xi_round + self._floor)
        if bound > self.tol:
            raise PrecisionError(f'the triaxial bound at t = {t!r} s is {bound:.2e} rad, '
                                 f'above tol = {self.tol!r}')
        return Samples(np.asarray(t), np.array(qq), omega, np.float64(bound))

    def _omega(self, tt):
        """Angular velocity of B relative to N, in B, rad/s, at checked times."""
        flat = np.atleast_1d(tt)
        self._check_t(flat)
        if tt.ndim == 0:            # the scalar path of at(), bit for bit
            tf = float(tt)
            if self._sep:
                sech, tanh, _, _ = self._sep1(tf)
                return self._w_scalar((sech, tanh, sech))
            sn, cn, dn, _, _, _ = self._table1(tf)
            return self._w_scalar((cn, sn, dn))
        if self._sep:
            sech, tanh, _, _ = self._separatrix(flat)
            w = self._w_array((sech, tanh, sech))
        else:
            tau, _ = self._u_turns.reduce(flat)
            sn, cn, dn, _, _ = self._table(tau)
            w = self._w_array((cn, sn, dn))
        return w.reshape(tt.shape + (3,))

    @staticmethod
    def _check_t(tt):
        if not np.all(np.isfinite(tt)):
            raise ValueError('t must be finite')
        if tt.size and float(np.max(np.abs(tt))) > _T_MAX:
            bad = float(tt.flat[np.argmax(np.abs(tt))])
            raise PrecisionError(f't = {bad:.3g} s is beyond |t| = {_T_MAX:g} s, where the '
                                 f'phase of the triaxial model can be reduced exactly')

    def _at_array(self, tt):
        """:meth:`at` at a finite 1-D float array of times.

        Every operation is elementwise (no matrix product, no reduction across samples), so
        a sample's quaternion, rate and bound depend on its t alone: :meth:`_at_scalar`
        repeats them on floats.
        """
        self._check_t(tt)
        txi, exi = self._xi_turns.reduce(tt)
        if self._sep:
            sech, tanh, fint, f_err = self._separatrix(tt)
            fn = (sech, tanh, sech)
            q_val = fint
            ferr = np.stack([f_err] * 4, -1)
            du = np.abs(self._ut) * (ferr[:, :3] + 2 * _U)
            bound = (_D_LB * np.sqrt(du[:, 0] * du[:, 0] + du[:, 1] * du[:, 1] +
                                     du[:, 2] * du[:, 2]) + 10 * _U +
                     4 * np.pi * exi + abs(self._cq) * self._sep_c[0] * f_err +
                     self._xi_round + self._floor)
        else:
            tau, eu = self._u_turns.reduce(tt)
            sn, cn, dn, q_val, idx = self._table(tau)
            bound = self._bound(eu, exi, idx)
            fn = (cn, sn, dn)
        ux, uy, uz = (self._ut[i] * fn[i] for i in range(3))
        omega = self._w_array(fn)
        pw = 1.0 + uz
        pn = np.sqrt(uy * uy + ux * ux + pw * pw)
        px, py, pw = uy / pn, -ux / pn, pw / pn
        xi = 4 * np.pi * txi + self._xi_c - self._cq * q_val
        hs, hc = np.sin(0.5 * xi), np.cos(0.5 * xi)
        # q_z(xi) ⊗ (px, py, 0, pw)
        mid = np.stack([hc * px - hs * py, hc * py + hs * px, hs * pw, hc * pw], -1)
        q = quat.multiply(quat.multiply(self._left, mid), self._right)
        if np.any(bound > self.tol):
            bad = float(tt[np.argmax(bound)])
            raise PrecisionError(f'the triaxial bound at t = {bad!r} s is '
                                 f'{float(np.max(bound)):.2e} rad, above tol = {self.tol!r}')
        return Samples(tt, q, omega, bound)

    def _table1(self, t):
        """Scalar :meth:`_table` at time t: sn, cn, dn, Q, cell, phase error (turns)."""
        tau, eu = self._u_turns.reduce1(t)
        a = abs(4.0 * tau)
        j = a >= 1.0
        rho = a - 1.0 if j else a
        y = self._K * (1.0 - rho if j else rho)
        i = min(max(int(y * (1.0 / _H)), 0), self._ncell - 1)
        z = y - (i + 0.5) * _H
        rows = self._coef[:, i, :].tolist()
        s, c, d, q = rows[_DEG]                 # as _table: from the top coefficient
        for kk in range(_DEG - 1, -1, -1):
            r = rows[kk]
            s = s * z + r[0]
            c = c * z + r[1]
            d = d * z + r[2]
            q = q * z + r[3]
        st = -1.0 if tau < 0 else 1.0
        sj = -1.0 if j else 1.0
        return s * st, c * sj, d, q * st * sj, i, eu

    def _sep1(self, t):
        """Scalar :meth:`_separatrix` at time t: sech, tanh, the integral, their error.

        numpy's exp and arctan (those of the arrays: libm's may differ in the last bit).
        """
        u = self._lam * t + self._u0
        au = abs(u)
        e = float(np.exp(-au))
        sech = 2 * e / (1 + e * e)
        sg = -1.0 if u < 0 else 1.0
        tanh = sg * (1 - e * e) / (1 + e * e)
        th2 = sg * (1 - e) / (1 + e)
        fint = self._sep_c[0] * float(np.arctan(self._sep_c[1] * th2))
        u_err = 3 * _U * (abs(self._lam * t) + abs(self._u0)) + self._u0_err
        return sech, tanh, fint, float(_sep_err(np.float64(au), np.float64(u_err)))

    def _at_scalar(self, t):
        """:meth:`at` for one time, in plain floats: :meth:`_at_array`'s operations."""
        if not math.isfinite(t):
            raise ValueError('t must be finite')
        if abs(t) > _T_MAX:
            self._check_t(np.array([t]))
        txi, exi = self._xi_turns.reduce1(t)
        if self._sep:
            return self._separatrix_scalar(t, txi, exi)
        s, c, d, q, i, eu = self._table1(t)
        k = self._K
        ut = self._ut
        qq = self._compose1(ut[0] * c, ut[1] * s, ut[2] * d, txi, q)
        omega = self._w_scalar((c, s, d))
        # the bound, as in _bound (scalar)
        dy = 4 * k * eu + 3 * _U * k + _U * _R
        ce = self._cell_err[i]
        a, b, cc = (abs(float(ut[f])) * (float(ce[f]) + dy + 2 * _U) for f in range(3))
        d_lb = _D_LB * math.sqrt(a * a + b * b + cc * cc) + 10 * _U
        d_xi = 4 * math.pi * exi + abs(self._cq) * (float(ce[3]) + dy) + self._xi_round
        bound = d_lb + d_xi + self._floor
        if bound > self.tol:
            raise PrecisionError(f'the triaxial bound at t = {t!r} s is {bound:.2e} rad, '
                                 f'above tol = {self.tol!r}')
        return Samples(np.asarray(t), np.array(qq), omega, np.float64(bound))
