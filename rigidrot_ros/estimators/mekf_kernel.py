"""The MEKF's whole run compiled (numba), calling numpy's own BLAS: the same bits, faster.

:meth:`rigidrot_ros.estimators.mekf.MEKF.receive_arrays` interpreted takes about 30 µs a
gyro sample, most of it the interpreter around a dozen small numpy calls (92 ms for the
3000 gyro and 300 star tracker samples of a 30 s campaign run); :func:`run` takes about
3 ms for the same run, in one compiled loop
(:func:`rigidrot_ros.estimators.mekf_jit.filter_run`) of the same operations on the same
values: the elementwise ones written out in float64 scalar operations (compiled with
``fastmath`` off: no fused multiply-add, no reassociation), and every product that sums
(``dot`` of vectors, ``@`` and ``dot`` of matrices, ``np.linalg.solve``) by a call to the
very BLAS or LAPACK function numpy calls for it, in the library numpy loaded, with the
arguments numpy gives it (layout, transposition, leading dimensions: a ``dgemm`` may sum
in another order when they change). So every estimate is the interpreted filter's, bit
for bit.

That holds only where numpy's BLAS is the ``scipy_openblas64_`` library its wheels bundle
(the symbols :data:`SYMBOLS`, in a library numpy has loaded): elsewhere, where numba does
not import, or with ``RIGIDROT_NO_JIT`` set, :func:`available` says no and the filter
stays interpreted. On load the compiled loop is also run against the interpreted filter
on a short synthetic run (the check :func:`available` is given, ``mekf._self_check``);
any bit apart and it is not used.

Compiled code is cached like the core's kernels (``NUMBA_CACHE_DIR``, else
``__pycache__``): the BLAS entry points are arguments (their addresses in this process),
not constants of the code.
"""

import ctypes
import os

import numpy as np

from rigidrot_ros.runtime import switches
from rigidrot_ros.runtime.jit import cached_load

__all__ = ['available', 'run', 'state', 'SYMBOLS', 'RunArrays']

#: numpy's BLAS/LAPACK entry points the filter's products go through (ILP64 OpenBLAS of
#: the numpy wheels, ``scipy_`` prefix, ``64_`` suffix).
SYMBOLS = ('scipy_cblas_dgemm64_', 'scipy_cblas_dgemv64_', 'scipy_cblas_ddot64_',
           'scipy_dgesv_64_')

_STATE = {'loaded': False, 'ok': False, 'reason': 'not loaded yet'}
_KERNEL = None
_FPS = None


def _blas_library():
    """Return the ctypes handle of the OpenBLAS numpy loaded (by its symbols), or a reason.

    Among the OpenBLAS libraries the process has loaded (scipy's may be one), numpy's own
    first: those in numpy's directory or its wheel's ``numpy.libs``.
    """
    import numpy.linalg  # noqa: F401 - its LAPACK module is loaded with the library
    paths = []
    try:
        with open('/proc/self/maps', encoding='utf-8', errors='replace') as fh:
            for line in fh:
                path = line.rstrip('\n').split(None, 5)[-1] if line.count(' ') >= 5 else ''
                if 'openblas' in path.rsplit('/', 1)[-1].lower() and path not in paths:
                    paths.append(path)
    except OSError as exc:
        return None, f'cannot list the loaded libraries: {exc}'
    own = os.path.dirname(os.path.abspath(np.__file__))       # numpy's (wheel: numpy.libs)
    paths.sort(key=lambda p: not p.startswith((own + os.sep, own + '.libs' + os.sep)))
    for path in paths:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        if all(hasattr(lib, s) for s in SYMBOLS):
            return lib, ''
    return None, (f"numpy's BLAS is not the OpenBLAS of its wheels (no library loaded has "
                  f'{", ".join(SYMBOLS)})')


def _load(check):
    """Compile or load the kernel and ``check`` it; set :data:`_STATE`."""
    global _KERNEL, _FPS
    _STATE['loaded'] = True
    if switches.no_jit():
        _STATE.update(ok=False, reason='RIGIDROT_NO_JIT is set')
        return
    lib, why = _blas_library()
    if lib is None:
        _STATE.update(ok=False, reason=why)
        return
    try:
        from rigidrot_ros.estimators import mekf_jit
    except ImportError as exc:
        _STATE.update(ok=False, reason=f'numba not importable: {exc}')
        return
    _FPS = np.array([ctypes.cast(getattr(lib, s), ctypes.c_void_p).value for s in SYMBOLS],
                    dtype=np.int64)
    try:
        with cached_load():
            _KERNEL = mekf_jit.make_jit(cache=True)
            bad = check()
    except Exception:                     # no writable cache location: compile in memory
        try:
            with cached_load():
                _KERNEL = mekf_jit.make_jit(cache=False)
                bad = check()
        except Exception as exc:  # noqa: B902 - numba's own failure: stay interpreted
            _KERNEL = None
            _STATE.update(ok=False, reason=f'the kernel does not compile: '
                                           f'{type(exc).__name__}: {exc}')
            return
    if bad:
        _KERNEL = None
        _STATE.update(ok=False, reason=f'the compiled filter differs from the interpreted '
                                       f'one ({bad})')
        return
    _STATE.update(ok=True, reason='')


def available(check):
    """Whether :func:`run` is usable here; loads the kernel on the first call.

    ``check()`` is then called with the kernel loaded: it returns what the compiled
    filter gives otherwise than the interpreted one (a word), or ``''``.
    """
    if not _STATE['loaded']:
        _load(check)
    return _STATE['ok']


def state():
    """Return whether the compiled filter is used, and if not why (a dict), as loaded."""
    return dict(_STATE)


class RunArrays:
    """A run's samples as the kernel takes them (see :func:`run`)."""

    def __init__(self, imu, star, order):
        imu_name, imu_cols = imu if imu is not None else (None, None)
        star_name, star_cols = star if star is not None else (None, None)
        if imu_cols is not None:
            self.imu_t = np.ascontiguousarray(imu_cols['stamps_ns'], dtype=np.int64)
            self.imu_w = np.ascontiguousarray(imu_cols['w'], dtype=float).reshape(-1)
            self.imu_var = np.ascontiguousarray(imu_cols['var'], dtype=float).reshape(-1)
        else:
            self.imu_t = np.zeros(0, dtype=np.int64)
            self.imu_w = self.imu_var = np.zeros(0)
        if star_cols is not None:
            self.star_t = np.ascontiguousarray(star_cols['stamps_ns'], dtype=np.int64)
            m = len(self.star_t)
            self.star_q = np.ascontiguousarray(star_cols['q'], dtype=float).reshape(-1)
            cov6 = np.zeros((m, 6, 6))
            cov6[:, 3:, 3:] = star_cols['cov']
            self.star_r6 = cov6.reshape(-1)
            self.cov6 = cov6
        else:
            self.star_t = np.zeros(0, dtype=np.int64)
            self.star_q = self.star_r6 = np.zeros(0)
            self.cov6 = np.zeros((0, 6, 6))
        code = {imu_name: 0, star_name: 1}
        code.pop(None, None)
        self.kinds = np.array([code.get(t, 2) for t, _ in order], dtype=np.int64)
        self.rows = np.array([r for _, r in order], dtype=np.int64)
        for kind, n in ((0, len(self.imu_t)), (1, len(self.star_t))):
            mine = self.kinds == kind           # rows as Python indexes them: -1 the last
            rows = self.rows[mine]
            if len(rows) and (rows.min() < -n or rows.max() >= n):
                raise IndexError('list index out of range')
            self.rows[mine] = np.where(rows < 0, rows + n, rows)


def run(filt, data):
    """Run ``filt`` (an :class:`~rigidrot_ros.estimators.mekf.MEKF`, fresh) over ``data``.

    ``data`` a :class:`RunArrays`. Returns ``(stamps_ns, q, P, w, gyro_var)`` of the
    estimates ((n,), (n, 4), (n, 6, 6), (n, 3), (n, 3, 3)), as
    :meth:`~rigidrot_ros.estimators.mekf.MEKF.receive_arrays` snapshots them; the
    filter's ``updates`` and ``rejected`` counts are set. ``np.linalg.LinAlgError`` where
    the interpreted filter raises it (a singular innovation covariance).
    """
    if _KERNEL is None:
        raise RuntimeError(f'the compiled MEKF is not available: {_STATE["reason"]}')
    p = filt.p
    m = len(data.star_t)
    ok = np.array([filt._takes_star(data.star_q[4 * k:4 * k + 4], data.cov6[k, 3:, 3:])
                   for k in range(m)], dtype=np.bool_)     # R checked only where q is usable
    cap = len(data.imu_t) // p.output_every + 1
    out_t = np.zeros(cap, dtype=np.int64)
    out_q, out_p = np.zeros(cap * 4), np.zeros(cap * 36)
    out_w, out_gv = np.zeros(cap * 3), np.zeros(cap * 9)
    counts = np.zeros(4, dtype=np.int64)
    fstate, istate = np.zeros(55), np.zeros(5 + m, dtype=np.int64)
    _KERNEL(_FPS, data.imu_t, data.imu_w, data.imu_var, data.star_t, data.star_q,
            data.star_r6, ok, data.kinds, data.rows, p.sigma_v ** 2, p.sigma_u ** 2,
            p.bias_sigma ** 2, np.ascontiguousarray(p.bias0, dtype=float), p.output_every,
            out_t, out_q, out_p, out_w, out_gv, counts, fstate, istate)
    n, filt.updates, filt.rejected, status = (int(c) for c in counts)
    _set_state(filt, data, fstate, istate)
    if status:
        raise np.linalg.LinAlgError('Singular matrix')
    return (out_t[:n], out_q[:n * 4].reshape(n, 4), out_p[:n * 36].reshape(n, 6, 6),
            out_w[:n * 3].reshape(n, 3), out_gv[:n * 9].reshape(n, 3, 3))


def _set_state(filt, data, fstate, istate):
    """Leave ``filt`` in the state the interpreted run would (its last estimate taken)."""
    started, t_ns, gyro_count, omega_set, npend = (int(v) for v in istate[:5])
    if started:
        filt.q = fstate[:4].copy()
        filt.P = fstate[4:40].reshape(6, 6).copy()
        filt.t_ns = t_ns
    filt.beta = fstate[40:43].copy()
    if omega_set:
        filt.omega = fstate[43:46].copy()
        filt.gyro_var = fstate[46:55].reshape(3, 3).copy()
    filt._gyro_count = gyro_count
    filt.pending_star = [(int(data.star_t[k]), data.star_q[4 * k:4 * k + 4].copy(),
                          data.cov6[k, 3:, 3:]) for k in istate[5:5 + npend].tolist()]
    filt._due = None
