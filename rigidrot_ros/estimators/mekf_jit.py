"""The compiled MEKF run of :mod:`rigidrot_ros.estimators.mekf_kernel` (imports numba).

Imported by :mod:`~rigidrot_ros.estimators.mekf_kernel`'s loader alone, where numba imports.
:func:`filter_run` is :meth:`~rigidrot_ros.estimators.mekf.MEKF.receive_arrays`'s loop,
operation for operation (the comments name the Python each part stands for). The BLAS
and LAPACK calls are intrinsics that call a function at an address given at run time
(numpy's library's, found by the loader), with the arguments numpy passes.
"""

import math

from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic
import numpy as np

__all__ = ['filter_run', 'make_jit']

_ROW = 101                              # CBLAS_ORDER
_NT, _T = 111, 112                      # CBLAS_TRANSPOSE
_I32, _I64, _DBL = ir.IntType(32), ir.IntType(64), ir.DoubleType()
_DPTR = _DBL.as_pointer()
_IPTR = _I64.as_pointer()


def _ptr(context, builder, aryty, ary, off):
    data = context.make_array(aryty)(context, builder, ary).data
    return builder.bitcast(builder.gep(data, [off]), _DPTR)


def _fn(builder, addr, ret, args):
    return builder.inttoptr(addr, ir.FunctionType(ret, args).as_pointer())


_i = types.int64


@intrinsic
def dgemm(typingctx, f, order, ta, tb, m, n, k, a, ao, lda, b, bo, ldb, c, co, ldc):
    """Call BLAS ``cblas_dgemm`` at ``f``: ``C = A B`` (alpha 1, beta 0), arrays at offsets."""
    sig = types.void(_i, _i, _i, _i, _i, _i, _i, a, _i, _i, b, _i, _i, c, _i, _i)

    def codegen(context, builder, signature, args):
        f_, order_, ta_, tb_, m_, n_, k_, a_, ao_, lda_, b_, bo_, ldb_, c_, co_, ldc_ = args
        tys = signature.args
        call = _fn(builder, f_, ir.VoidType(),
                   [_I32, _I32, _I32, _I64, _I64, _I64, _DBL, _DPTR, _I64, _DPTR, _I64, _DBL,
                    _DPTR, _I64])
        builder.call(call, [builder.trunc(x, _I32) for x in (order_, ta_, tb_)]
                     + [m_, n_, k_, ir.Constant(_DBL, 1.0),
                        _ptr(context, builder, tys[7], a_, ao_), lda_,
                        _ptr(context, builder, tys[10], b_, bo_), ldb_, ir.Constant(_DBL, 0.0),
                        _ptr(context, builder, tys[13], c_, co_), ldc_])
        return context.get_dummy_value()
    return sig, codegen


@intrinsic
def dgemv(typingctx, f, order, ta, m, n, a, ao, lda, x, xo, y, yo):
    """Call BLAS ``cblas_dgemv`` at ``f``: ``y = A x`` (alpha 1, beta 0, unit strides)."""
    sig = types.void(_i, _i, _i, _i, _i, a, _i, _i, x, _i, y, _i)

    def codegen(context, builder, signature, args):
        f_, order_, ta_, m_, n_, a_, ao_, lda_, x_, xo_, y_, yo_ = args
        tys = signature.args
        call = _fn(builder, f_, ir.VoidType(),
                   [_I32, _I32, _I64, _I64, _DBL, _DPTR, _I64, _DPTR, _I64, _DBL, _DPTR, _I64])
        one = ir.Constant(_I64, 1)
        builder.call(call, [builder.trunc(order_, _I32), builder.trunc(ta_, _I32), m_, n_,
                            ir.Constant(_DBL, 1.0), _ptr(context, builder, tys[5], a_, ao_),
                            lda_, _ptr(context, builder, tys[8], x_, xo_), one,
                            ir.Constant(_DBL, 0.0), _ptr(context, builder, tys[10], y_, yo_),
                            one])
        return context.get_dummy_value()
    return sig, codegen


@intrinsic
def ddot(typingctx, f, n, x, xo, y, yo):
    """Call BLAS ``cblas_ddot`` at ``f`` on ``n`` elements of ``x`` and ``y`` from offsets."""
    sig = types.float64(_i, _i, x, _i, y, _i)

    def codegen(context, builder, signature, args):
        f_, n_, x_, xo_, y_, yo_ = args
        tys = signature.args
        call = _fn(builder, f_, _DBL, [_I64, _DPTR, _I64, _DPTR, _I64])
        one = ir.Constant(_I64, 1)
        return builder.call(call, [n_, _ptr(context, builder, tys[2], x_, xo_), one,
                                   _ptr(context, builder, tys[4], y_, yo_), one])
    return sig, codegen


@intrinsic
def dgesv(typingctx, f, ints, a, ipiv, b):
    """Call LAPACK ``dgesv`` at ``f``; ``ints`` holds n, nrhs, lda, ldb and gets info."""
    sig = types.void(_i, ints, a, ipiv, b)

    def codegen(context, builder, signature, args):
        f_, ints_, a_, ipiv_, b_ = args
        tys = signature.args
        call = _fn(builder, f_, ir.VoidType(),
                   [_IPTR, _IPTR, _DPTR, _IPTR, _IPTR, _DPTR, _IPTR, _IPTR])
        idata = context.make_array(tys[1])(context, builder, ints_).data
        pdata = context.make_array(tys[3])(context, builder, ipiv_).data

        def at(i):
            return builder.bitcast(builder.gep(idata, [ir.Constant(_I64, i)]), _IPTR)
        zero = ir.Constant(_I64, 0)
        builder.call(call, [at(0), at(1), _ptr(context, builder, tys[2], a_, zero), at(2),
                            builder.bitcast(pdata, _IPTR),
                            _ptr(context, builder, tys[4], b_, zero), at(3), at(4)])
        return context.get_dummy_value()
    return sig, codegen


def _qmul(ax, ay, az, aw, bx, by, bz, bw, out, o):
    """Write ``a ⊗ b`` (``mekf._qmul``) into ``out[o:o + 4]``."""
    out[o] = aw * bx + ax * bw + ay * bz - az * by
    out[o + 1] = aw * by - ax * bz + ay * bw + az * bx
    out[o + 2] = aw * bz + ax * by - ay * bx + az * bw
    out[o + 3] = aw * bw - ax * bx - ay * by - az * bz


def filter_run(fp, imu_t, imu_w, imu_var, star_t, star_q, star_r6, star_ok, kinds, rows,
               sv2, su2, bs2, bias0, every, out_t, out_q, out_p, out_w, out_gv, counts,
               fstate, istate):
    """Run the MEKF over the samples in arrival order; the estimates into ``out_*``.

    ``fp``: the addresses of dgemm, dgemv, ddot, dgesv. ``imu_w`` (n*3), ``star_q``
    (m*4), ``star_r6`` (m*36: each sample's 6x6 covariance, the rotation block filled),
    ``out_q`` (k*4), ``out_p`` (k*36), ``out_w`` (k*3), ``out_gv`` (k*9) flat. ``kinds``
    (0 imu, 1 star tracker, else ignored) and ``rows`` the arrival order. ``counts``
    gets (estimates, updates, rejected, status: 0, or 1 for a singular ``S``).
    """
    P, q, beta, omega, gvar = np.zeros(36), np.empty(4), bias0.copy(), np.zeros(3), np.zeros(9)
    pb, ub = _propagate_buffers(), _update_buffers()
    pend = np.empty(len(star_t), dtype=np.int64)    # waiting star samples, sorted
    npend = t_ns = due_t = gyro_count = n_out = updates = rejected = status = 0
    started = omega_set = due = False
    for j in range(len(kinds)):
        kind = kinds[j]
        if kind != 0 and kind != 1:
            continue
        k = rows[j]
        t = imu_t[k] if kind == 0 else star_t[k]
        if due and t > due_t:                   # _flush(t)
            due = False
            _emit(n_out, due_t, q, P, omega, beta, gvar, out_t, out_q, out_p, out_w, out_gv)
            n_out += 1
        if kind == 1:                           # _on_star
            if not _star_valid(fp[2], star_q, k * 4, star_ok[k]):
                rejected += 1
            elif not started:
                _start(fp[2], P, q, star_q, k * 4, star_r6, k * 36, bs2)
                t_ns = t
                started = True
            elif t == t_ns:
                status = _update(fp, P, q, beta, star_q, k * 4, star_r6, k * 36, ub)
                if status:
                    break
                updates += 1
            elif t > t_ns:
                npend = _queue(pend, npend, star_t, k, t)
            else:
                rejected += 1
            continue
        # _on_imu
        if not started or t <= t_ns:
            continue
        wx, wy, wz = imu_w[k * 3], imu_w[k * 3 + 1], imu_w[k * 3 + 2]
        if not (math.isfinite(wx) and math.isfinite(wy) and math.isfinite(wz)):
            rejected += 1
            continue
        omega[0], omega[1], omega[2] = wx, wy, wz
        omega_set = True
        for i in range(9):
            gvar[i] = 0.0
        gvar[0] = gvar[4] = gvar[8] = imu_var[k]
        npend, t_ns, done, status = _advance(fp, t, t_ns, pend, npend, star_t, star_q,
                                             star_r6, P, q, omega, beta, sv2, su2, pb, ub)
        updates += done
        if status:
            break
        _propagate(fp, (t - t_ns) * 1e-9, P, q, omega, beta, sv2, su2, pb)
        t_ns = t
        gyro_count += 1
        if gyro_count % every == 0:
            due = True
            due_t = t
    if status == 0 and due:                     # _flush(None)
        _emit(n_out, due_t, q, P, omega, beta, gvar, out_t, out_q, out_p, out_w, out_gv)
        n_out += 1
    counts[0], counts[1], counts[2], counts[3] = n_out, updates, rejected, status
    _save(fstate, istate, q, P, beta, omega, gvar, started, t_ns, gyro_count, omega_set,
          pend, npend)


def _propagate_buffers():
    """Return the buffers of :func:`_propagate`: tmp, phi (the identity), W, WW, w, v, qn."""
    phi = np.zeros(36)
    for i in range(6):
        phi[i * 6 + i] = 1.0
    return (np.empty(36), phi, np.empty(9), np.empty(9), np.empty(3), np.empty(3),
            np.empty(4))


def _update_buffers():
    """Return the buffers of :func:`_update`, in the order it unpacks them."""
    return (np.empty(4), np.empty(4), np.empty(9), np.empty(18), np.empty(18),
            np.empty(3, dtype=np.int64), np.empty(5, dtype=np.int64), np.empty(6),
            np.empty(36), np.empty(36), np.empty(36), np.empty(18), np.empty(36),
            np.empty(4))


def _star_valid(f_dot, star_q, qo, ok):
    """Whether a star tracker sample is taken (``_on_star``'s check): finite, unit, valid."""
    q0, q1, q2, q3 = star_q[qo], star_q[qo + 1], star_q[qo + 2], star_q[qo + 3]
    return (math.isfinite(q0) and math.isfinite(q1) and math.isfinite(q2)
            and math.isfinite(q3)
            and abs(math.sqrt(ddot(f_dot, 4, star_q, qo, star_q, qo)) - 1) < 1e-6
            and ok)


def _start(f_dot, P, q, star_q, qo, star_r6, ro, bs2):
    """Start the filter at the first star tracker sample (``_on_star`` before ``started``)."""
    nrm = math.sqrt(ddot(f_dot, 4, star_q, qo, star_q, qo))     # np.linalg.norm
    q[0], q[1], q[2], q[3] = (star_q[qo] / nrm, star_q[qo + 1] / nrm, star_q[qo + 2] / nrm,
                              star_q[qo + 3] / nrm)
    for i in range(36):
        P[i] = 0.0
    for r in range(3):
        for c in range(3):
            P[r * 6 + c] = star_r6[ro + (3 + r) * 6 + 3 + c]
            P[(3 + r) * 6 + 3 + c] = bs2 * (1.0 if r == c else 0.0)


def _queue(pend, npend, star_t, k, t):
    """Append star sample ``k``, then ``_advance``'s stable sort by stamp; the new count."""
    pos = npend
    while pos > 0 and star_t[pend[pos - 1]] > t:
        pos -= 1
    for i in range(npend, pos, -1):
        pend[i] = pend[i - 1]
    pend[pos] = k
    return npend + 1


def _advance(fp, t, t_ns, pend, npend, star_t, star_q, star_r6, P, q, omega, beta, sv2, su2,
             pb, ub):
    """Take the waiting star samples stamped up to ``t`` (the filter's ``_advance``).

    Returns the samples left waiting, the filter's time, the updates made, the status.
    """
    head = done = status = 0
    while head < npend and star_t[pend[head]] <= t:
        s = pend[head]
        head += 1
        _propagate(fp, (star_t[s] - t_ns) * 1e-9, P, q, omega, beta, sv2, su2, pb)
        t_ns = star_t[s]
        status = _update(fp, P, q, beta, star_q, s * 4, star_r6, s * 36, ub)
        if status:
            return npend, t_ns, done, status
        done += 1
    if head:
        for i in range(npend - head):
            pend[i] = pend[i + head]
        npend -= head
    return npend, t_ns, done, status


def _save(fstate, istate, q, P, beta, omega, gvar, started, t_ns, gyro_count, omega_set,
          pend, npend):
    """Write the filter's state at the end of the run into ``fstate`` and ``istate``."""
    for i in range(4):
        fstate[i] = q[i]
    for i in range(36):
        fstate[4 + i] = P[i]
    for i in range(3):
        fstate[40 + i] = beta[i]
        fstate[43 + i] = omega[i]
    for i in range(9):
        fstate[46 + i] = gvar[i]
    istate[0] = 1 if started else 0
    istate[1] = t_ns
    istate[2] = gyro_count
    istate[3] = 1 if omega_set else 0
    istate[4] = npend
    for i in range(npend):
        istate[5 + i] = pend[i]


def _emit(n, t, q, P, omega, beta, gvar, out_t, out_q, out_p, out_w, out_gv):
    """Write estimate ``n`` (``_flush``): its stamp, q, P, the rate less the bias, gyro var."""
    out_t[n] = t
    for i in range(4):
        out_q[n * 4 + i] = q[i]
    for i in range(36):
        out_p[n * 36 + i] = P[i]
    for i in range(3):
        out_w[n * 3 + i] = omega[i] - beta[i]
    for i in range(9):
        out_gv[n * 9 + i] = gvar[i]


def _propagate(fp, dt, P, q, omega, beta, sv2, su2, pb):
    """Propagate the state over ``dt`` (``MEKF._propagate``); ``pb``: its buffers."""
    if dt <= 0:
        return
    tmp, phi, W, WW, w, v, qn = pb
    f_gemm, f_dot = fp[0], fp[2]
    for i in range(3):
        w[i] = omega[i] - beta[i]
    x = math.sqrt(ddot(f_dot, 3, w, 0, w, 0))
    w0, w1, w2 = w[0], w[1], w[2]
    n0, n1, n2 = -w0, -w1, -w2
    W[0], W[1], W[2] = 0.0, n2, w1
    W[3], W[4], W[5] = w2, 0.0, n0
    W[6], W[7], W[8] = n1, w0, 0.0
    dgemm(f_gemm, _ROW, _NT, _NT, 3, 3, 3, W, 0, 3, W, 0, 3, WW, 0, 3)
    a0, a1, a2, b0, b1, b2, c0, c1, c2 = (WW[0], WW[1], WW[2], WW[3], WW[4], WW[5], WW[6],
                                          WW[7], WW[8])
    if x * dt < 1e-5:
        s1, s2, s3 = dt, dt * dt / 2, dt ** 3.0 / 6
    else:
        s1 = math.sin(x * dt) / x
        s2 = (1 - math.cos(x * dt)) / (x * x)
        s3 = (x * dt - math.sin(x * dt)) / x ** 3.0
    phi[0] = 1.0 - 0.0 * s1 + a0 * s2
    phi[1] = 0.0 - n2 * s1 + a1 * s2
    phi[2] = 0.0 - w1 * s1 + a2 * s2
    phi[3] = 0.0 * s2 - 1.0 * dt - a0 * s3
    phi[4] = n2 * s2 - 0.0 * dt - a1 * s3
    phi[5] = w1 * s2 - 0.0 * dt - a2 * s3
    phi[6] = 0.0 - w2 * s1 + b0 * s2
    phi[7] = 1.0 - 0.0 * s1 + b1 * s2
    phi[8] = 0.0 - n0 * s1 + b2 * s2
    phi[9] = w2 * s2 - 0.0 * dt - b0 * s3
    phi[10] = 0.0 * s2 - 1.0 * dt - b1 * s3
    phi[11] = n0 * s2 - 0.0 * dt - b2 * s3
    phi[12] = 0.0 - n1 * s1 + c0 * s2
    phi[13] = 0.0 - w0 * s1 + c1 * s2
    phi[14] = 1.0 - 0.0 * s1 + c2 * s2
    phi[15] = n1 * s2 - 0.0 * dt - c0 * s3
    phi[16] = w0 * s2 - 0.0 * dt - c1 * s3
    phi[17] = 0.0 * s2 - 1.0 * dt - c2 * s3
    dgemm(f_gemm, _ROW, _NT, _NT, 6, 6, 6, phi, 0, 6, P, 0, 6, tmp, 0, 6)
    dgemm(f_gemm, _ROW, _NT, _T, 6, 6, 6, tmp, 0, 6, phi, 0, 6, P, 0, 6)
    # P += Q(dt): (sv2 dt + su2 dt^3 / 3) I, -(su2 dt^2 / 2) I, su2 dt I, signed zeros kept
    qa = sv2 * dt + su2 * dt ** 3.0 / 3
    qb = -(su2 * dt * dt / 2)
    qc = su2 * dt
    for r in range(3):
        for c in range(3):
            e = 1.0 if r == c else 0.0
            P[r * 6 + c] += qa * e
            P[r * 6 + 3 + c] += qb * e
            P[(3 + r) * 6 + c] += qb * e
            P[(3 + r) * 6 + 3 + c] += qc * e
    # P = P + P.T; P *= 0.5
    for r in range(6):
        for c in range(r, 6):
            s = P[r * 6 + c] + P[c * 6 + r]
            P[r * 6 + c] = s * 0.5
            P[c * 6 + r] = s * 0.5
    # q <- q ⊗ exp(w dt / 2), normalised
    for i in range(3):
        v[i] = w[i] * dt
    a = math.sqrt(ddot(f_dot, 3, v, 0, v, 0))
    s = 0.5 - a * a / 48.0 if a < 1e-6 else math.sin(0.5 * a) / a
    _qmul(q[0], q[1], q[2], q[3], v[0] * s, v[1] * s, v[2] * s, math.cos(0.5 * a), qn, 0)
    nrm = math.sqrt(ddot(f_dot, 4, qn, 0, qn, 0))
    for i in range(4):
        q[i] = qn[i] / nrm


def _update(fp, P, q, beta, star_q, qo, star_r6, ro, ub):
    """Update with a star tracker sample (``MEKF._update``); 1 if ``S`` is singular.

    ``q_m = star_q[qo:qo + 4]``, ``R`` the rotation block of ``star_r6[ro:ro + 36]``,
    ``ub`` its buffers. Returns 1 where ``np.linalg.solve`` raises (a singular ``S``), else 0.
    """
    qe, zq, a_s, b_s, X, ipiv, ints, dx, IKH, t1, t2, KR, KRK, ex = ub
    f_gemm, f_gemv, f_dot, f_gesv = fp[0], fp[1], fp[2], fp[3]
    # z = _qlog(_qmul(q^-1, q_m))
    _qmul(-q[0], -q[1], -q[2], q[3], star_q[qo], star_q[qo + 1], star_q[qo + 2],
          star_q[qo + 3], qe, 0)
    if qe[3] < 0:
        for i in range(4):
            zq[i] = -qe[i]
    else:
        for i in range(4):
            zq[i] = qe[i]
    n = math.sqrt(ddot(f_dot, 3, zq, 0, zq, 0))
    ang = 2.0 * math.atan2(n, zq[3])
    f = ang / n if n > 1e-12 else 2.0
    z0, z1, z2 = zq[0] * f, zq[1] * f, zq[2] * f
    zq[0], zq[1], zq[2] = z0, z1, z2
    # K = solve(P[:3, :3] + R, P[:3, :]).T: dgesv on Fortran-ordered copies
    for c in range(3):
        for r in range(3):
            a_s[r + 3 * c] = P[r * 6 + c] + star_r6[ro + (3 + r) * 6 + 3 + c]
    for c in range(6):
        for r in range(3):
            b_s[r + 3 * c] = P[r * 6 + c]
    ints[0], ints[1], ints[2], ints[3], ints[4] = 3, 6, 3, 3, 0
    dgesv(f_gesv, ints, a_s, ipiv, b_s)
    if ints[4] > 0:
        return 1
    for r in range(3):                  # X = solve(...) (3, 6), C order; K = X.T
        for c in range(6):
            X[r * 6 + c] = b_s[r + 3 * c]
    dgemv(f_gemv, _ROW, _T, 3, 6, X, 0, 6, zq, 0, dx, 0)            # dx = K @ z
    # IKH = eye(6); IKH[:, :3] -= K
    for r in range(6):
        for c in range(6):
            e = 1.0 if r == c else 0.0
            IKH[r * 6 + c] = e - X[c * 6 + r] if c < 3 else e
    dgemm(f_gemm, _ROW, _NT, _NT, 6, 6, 6, IKH, 0, 6, P, 0, 6, t1, 0, 6)     # IKH @ P
    dgemm(f_gemm, _ROW, _NT, _T, 6, 6, 6, t1, 0, 6, IKH, 0, 6, t2, 0, 6)     # @ IKH.T
    dgemm(f_gemm, _ROW, _T, _NT, 6, 3, 3, X, 0, 6, star_r6, ro + 21, 6, KR, 0, 3)  # K @ R
    dgemm(f_gemm, _ROW, _NT, _NT, 6, 6, 3, KR, 0, 3, X, 0, 6, KRK, 0, 6)     # @ K.T
    for i in range(36):
        t2[i] = t2[i] + KRK[i]
    for r in range(6):                  # P = 0.5 * (P + P.T)
        for c in range(6):
            P[r * 6 + c] = 0.5 * (t2[r * 6 + c] + t2[c * 6 + r])
    # q = _qmul(q, _qexp(dx[:3])); q /= np.linalg.norm(q)
    a = math.sqrt(ddot(f_dot, 3, dx, 0, dx, 0))
    s = 0.5 - a * a / 48.0 if a < 1e-6 else math.sin(0.5 * a) / a
    _qmul(q[0], q[1], q[2], q[3], dx[0] * s, dx[1] * s, dx[2] * s, math.cos(0.5 * a), ex, 0)
    nrm = math.sqrt(ddot(f_dot, 4, ex, 0, ex, 0))
    for i in range(4):
        q[i] = ex[i] / nrm
    for i in range(3):
        beta[i] = beta[i] + dx[3 + i]
    return 0


def make_jit(cache):
    """Return :func:`filter_run` compiled (``cache``: on disk), its helpers compiled first."""
    g = globals()
    for name in ('_qmul', '_emit', '_propagate', '_update', '_propagate_buffers',
                 '_update_buffers', '_star_valid', '_start', '_queue', '_advance', '_save'):
        fn = g[name]
        g[name] = njit(cache=cache, fastmath=False)(getattr(fn, 'py_func', fn))
    return njit(cache=cache, fastmath=False)(filter_run)
