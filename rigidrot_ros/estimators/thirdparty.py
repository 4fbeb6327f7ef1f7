"""Attitude filters people use, fed in memory with one run's sensor arrays (no rclpy).

Each filter is a :class:`Filter`: its library's defaults, a tuning grid and
``run(sensors, params) -> Estimate``. The filters, their libraries and conventions (read
from their sources and checked on static and turning data in ``test/bench/test_leaderboard.py``):

- ``madgwick``, ``mahony``, ``ekf``, ``aqua``: ``ahrs`` (Madgwick 2010/2011; Mahony et al.
  2008; ahrs' quaternion EKF; Valenti et al. 2015, *Sensors* 15(8)). ahrs orders
  quaternions (w, x, y, z). Madgwick's, Mahony's and the EKF's ``q`` rotate sensor vectors
  into their Earth frame E (``q_EB``); AQUA's is the inverse (``q_BE``, Valenti's global-to-
  local). All four take the specific force (+g up at rest) to E's +z and normalise the
  field; E's x is the field's horizontal part for Madgwick and AQUA (``q_NE = Rz(psi)``,
  ``psi`` the field's heading in N), E's y for Mahony (``Rz(psi - 90 deg)``); the EKF is
  given the field as its reference, so E = N.
- ``fusion``: x-io Fusion (``imufusion``), convention ENU: E's y is the field's horizontal
  part (``Rz(psi - 90 deg)``); gyro in deg/s, accelerometer in g. Its ``update`` takes a
  field at every sample: it gets the latest magnetometer sample (held between samples;
  ``update_no_magnetometer`` would zero its heading during its start-up, and a zero
  field would cut its magnetic gain by the rate ratio).
- ``vqf``: VQF (``vqf``, Laidig & Seel 2023), its 9-D quaternion; E's y is the field's
  horizontal part (``Rz(psi - 90 deg)``).
- ``mekf``: the shipped MEKF (:mod:`rigidrot_ros.estimators.mekf`), gyro + star tracker.

Every ``q`` is returned as ``q_NB`` (x, y, z, w). Starts: the ahrs filters from the
e-compass (TRIAD) of the first accelerometer and magnetometer samples, in their own E (ahrs'
batch mode starts from an e-compass too); Fusion and VQF as their libraries start (Fusion's
ramped-gain start-up, VQF's first-sample alignment); the MEKF at the first star tracker
sample. Covariances: the EKF's (its 4x4 quaternion covariance mapped to the body rotation
vector, ``P_e = 4 Xi^T P_q Xi``) and the MEKF's; the others state none.
"""

import math
import time

import numpy as np

from rigidrot_ros.core import quaternion as quat

__all__ = ['SensorRun', 'Estimate', 'Filter', 'FILTERS', 'filters', 'ecompass', 'GRAVITY']

GRAVITY = 9.80665


class SensorRun:
    """One run's sensor samples as filters take them (SI units, in B), and its truth.

    Attributes
    ----------
    t : (N,) array
        Scene time of each imu sample (the end of the interval it covers), s.
    dt : float
        The imu sample interval, s.
    gyr, acc : (N, 3) arrays
        Rate (rad/s) and specific force (m/s^2).
    mag : (N, 3) array
        The latest magnetometer sample at each imu sample (zero-order hold), T.
    mag_new : (N,) bool array
        Whether a magnetometer sample was taken at the imu sample's time: the ahrs filters
        and VQF fuse each magnetometer sample once, at its own time (both grids start
        at 0); Fusion takes the held sample at every update (its API).
    start : int
        The first imu sample with a magnetometer sample at its time, where every filter
        starts (the e-compass of the ahrs filters needs both at one instant).
    var_gyr, var_acc, var_mag : float
        Per-axis variance of one sample as the messages state it.
    field_n, gravity_n : (3,) arrays
        The magnetic field and gravity in N that the scene's parameters give.
    star : tuple or None
        ``(t, q, R)`` of the star tracker: scene times, ``q_NB`` (x, y, z, w) and 3x3
        covariances of the body rotation-vector error.
    q_true : (N, 4) array
        The exact ``q_NB`` at ``t``.
    """

    def __init__(self, t, gyr, acc, mag, var_gyr, var_acc, var_mag, field_n, gravity_n,
                 star=None, q_true=None, mag_new=None):
        self.t = np.asarray(t, dtype=float)
        self.dt = float(np.median(np.diff(self.t))) if len(self.t) > 1 else 0.0
        self.gyr = np.ascontiguousarray(gyr, dtype=float)
        self.acc = np.ascontiguousarray(acc, dtype=float)
        self.mag = np.ascontiguousarray(mag, dtype=float)
        self.mag_new = np.ones(len(self.t), dtype=bool) if mag_new is None else \
            np.asarray(mag_new, dtype=bool)
        if not self.mag_new.any():
            raise ValueError('no magnetometer sample falls on an imu sample time')
        self.start = int(np.argmax(self.mag_new))
        self.mag_dt = self.dt * (float(np.median(np.diff(np.nonzero(self.mag_new)[0])))
                                 if self.mag_new.sum() > 1 else 1.0)
        self.var_gyr, self.var_acc, self.var_mag = float(var_gyr), float(var_acc), \
            float(var_mag)
        self.field_n = np.asarray(field_n, dtype=float)
        self.gravity_n = np.asarray(gravity_n, dtype=float)
        self.star = star
        self.q_true = None if q_true is None else np.asarray(q_true, dtype=float)

    @classmethod
    def from_arrays(cls, arrays, values):
        """Build from :func:`rigidrot_ros.run.generate.run_arrays` and the run's values.

        The imu must run on the truth's grid (``imu.rate`` 0 or ``publish_rate``), so each
        imu sample has its exact attitude; the magnetometer is held between its samples,
        and flagged where it has a sample at the imu sample's time.
        """
        from rigidrot_ros.run import params
        p = params.defaults()
        p.update(values)
        imu, truth, mag = arrays['/imu'], arrays['/attitude'], arrays['/mag']
        if 'f' not in imu:
            raise ValueError('the run has no accelerometer (accel.enable)')
        rows = np.searchsorted(truth['true_ns'], imu['true_ns'])
        last = len(truth['true_ns']) - 1
        if np.any(rows > last) or \
                np.any(truth['true_ns'][np.minimum(rows, last)] != imu['true_ns']):
            raise ValueError('the imu samples are not on the truth grid (set imu.rate to 0)')
        held = np.searchsorted(mag['true_ns'], imu['true_ns'], side='right') - 1
        if held[0] < 0:
            raise ValueError('no magnetometer sample before the first imu sample')
        star = None
        if '/star_tracker' in arrays:
            s = arrays['/star_tracker']
            star = (s['t'], s['q'], s['cov'])
        new = mag['true_ns'][held] == imu['true_ns']
        return cls(imu['t'], imu['w'], imu['f'], mag['m'][held], float(imu['var'][0]),
                   float(imu['avar'][0]), float(mag['cov'][0][0, 0]), p['mag.field'],
                   p['accel.gravity'], star, truth['q'][rows], new)


class Estimate:
    """A filter's output on a run.

    ``q`` (N, 4) ``q_NB`` (x, y, z, w) at ``SensorRun.t``, ``P`` (N, 3, 3) its body
    rotation-vector covariance or None, ``cpu_s`` the CPU seconds of its update calls.
    """

    def __init__(self, q, P, cpu_s):
        self.q, self.P, self.cpu_s = q, P, float(cpu_s)


def ecompass(acc_b, mag_b, gravity_n, field_n):
    """``q_NB`` (x, y, z, w) from one specific force and one field sample (TRIAD).

    The specific force at rest is ``-g`` (REP 145: +g up); the field is ``m_N``. The first
    pair is matched exactly, the field's direction about it.
    """
    def frame(a, b):
        a = a / np.linalg.norm(a)
        c = np.cross(a, b)
        c /= np.linalg.norm(c)
        return np.column_stack([a, c, np.cross(a, c)])
    r_nb = frame(-np.asarray(gravity_n, float), np.asarray(field_n, float)) @ \
        frame(np.asarray(acc_b, float), np.asarray(mag_b, float)).T
    return quat.from_matrix(r_nb)


def _wxyz(q_xyzw):
    return np.array([q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]])


def _xyzw(q_wxyz):
    q = np.asarray(q_wxyz, dtype=float)
    return np.concatenate([q[..., 1:], q[..., :1]], axis=-1)


def _psi(field_n):
    return math.atan2(float(field_n[1]), float(field_n[0]))


def _to_n(q_eb_xyzw, turn):
    """``q_NB = Rz(turn) ⊗ q_EB`` (x, y, z, w), continuous in sign."""
    q = quat.multiply(quat.about_z(turn), q_eb_xyzw)
    flip = np.concatenate([[False], np.einsum('ij,ij->i', q[1:], q[:-1]) < 0])
    return q * np.where(np.logical_xor.accumulate(flip), -1.0, 1.0)[:, None]


def _start_e(s, turn):
    """Return the e-compass start ``q_EB`` (w, x, y, z) in E, where ``q_NE = Rz(turn)``."""
    k = s.start
    q_nb = ecompass(s.acc[k], s.mag[k], s.gravity_n, s.field_n)
    return _wxyz(quat.multiply(quat.about_z(-turn), q_nb))


def _nan_before_start(s, q):
    q[:s.start] = np.nan
    return q


# -- the ahrs filters ----------------------------------------------------------------------
def _ahrs_loop(s, marg, imu, q0_wxyz):
    """Run from ``s.start`` (``q0`` there): ``marg`` at magnetometer samples, else ``imu``."""
    out = np.full((len(s.t), 4), np.nan)
    q = out[s.start] = q0_wxyz
    gyr, acc, mag, new, dt = s.gyr, s.acc, s.mag, s.mag_new, s.dt
    c = time.process_time()
    for k in range(s.start + 1, len(s.t)):
        q = marg(q, gyr[k], acc[k], mag[k], dt) if new[k] else imu(q, gyr[k], acc[k], dt)
        out[k] = q
    return out, time.process_time() - c


def _madgwick(s, p):
    import ahrs.filters as af
    turn = _psi(s.field_n)
    f = af.Madgwick(frequency=1.0 / s.dt, gain=float(p['gain']))
    q, cpu = _ahrs_loop(s, lambda q, g, a, m, dt: f.updateMARG(q, g, a, m, dt=dt),
                        lambda q, g, a, dt: f.updateIMU(q, g, a, dt=dt), _start_e(s, turn))
    return Estimate(_to_n(_xyzw(q), turn), None, cpu)


def _mahony(s, p):
    import ahrs.filters as af
    turn = _psi(s.field_n) - math.pi / 2
    f = af.Mahony(k_P=float(p['k_P']), k_I=float(p['k_I']), frequency=1.0 / s.dt)
    q, cpu = _ahrs_loop(s, lambda q, g, a, m, dt: f.updateMARG(q, g, a, m, dt=dt),
                        lambda q, g, a, dt: f.updateIMU(q, g, a, dt=dt), _start_e(s, turn))
    return Estimate(_to_n(_xyzw(q), turn), None, cpu)


def _aqua(s, p):
    import ahrs.filters as af
    turn = _psi(s.field_n)
    f = af.AQUA(frequency=1.0 / s.dt, alpha=float(p['alpha']), beta=float(p['beta']),
                adaptive=bool(p['adaptive']))
    q0 = _start_e(s, turn) * np.array([1.0, -1.0, -1.0, -1.0])        # AQUA's q is q_BE
    q, cpu = _ahrs_loop(s, lambda q, g, a, m, dt: f.updateMARG(q, g, a, m, dt=dt),
                        lambda q, g, a, dt: f.updateIMU(q, g, a, dt=dt), q0)
    return Estimate(_to_n(quat.conjugate(_xyzw(q)), turn), None, cpu)


def _ekf_noises(s, p):
    """Return the EKF's ``[var_gyr, var_acc, var_mag]``: ahrs' defaults, or matched.

    ``noise: matched`` gives the gyro's per-sample variance and the unit vectors'
    variances (the accelerometer's and magnetometer's per-axis variance over their
    squared norms), the last two times ``meas_scale``: the factor that covers what the
    noise model leaves out (lever-arm acceleration, a disturbed field).
    """
    if p['noise'] == 'default':
        return [0.3 ** 2, 0.5 ** 2, 0.8 ** 2]
    g2 = float(s.gravity_n @ s.gravity_n)
    m2 = float(s.field_n @ s.field_n)
    c = float(p['meas_scale'])
    return [s.var_gyr, c * s.var_acc / g2, c * s.var_mag / m2]


def _ekf(s, p):
    import ahrs.filters as af
    field = s.field_n / np.linalg.norm(s.field_n)
    f = af.EKF(frame='NED', magnetic_ref=field, frequency=1.0 / s.dt,
               noises=_ekf_noises(s, p))
    n = len(s.t)
    out, cov = np.full((n, 4), np.nan), np.full((n, 4, 4), np.nan)
    q = out[s.start] = _start_e(s, 0.0)
    cov[s.start] = f.P
    gyr, acc, mag, new, dt = s.gyr, s.acc, s.mag, s.mag_new, s.dt
    c = time.process_time()
    for k in range(s.start + 1, n):
        f.mag = True if new[k] else None       # its measurement model asks self.mag
        q = f.update(q, gyr[k], acc[k], mag[k] if new[k] else None, dt=dt)
        out[k] = q
        cov[k] = f.P
    cpu = time.process_time() - c
    w, x, y, z = out.T                         # body rotation vector e: dq = q ⊗ (0, e/2)
    xi = np.stack([np.stack([-x, -y, -z], -1), np.stack([w, -z, y], -1),
                   np.stack([z, w, -x], -1), np.stack([-y, x, w], -1)], axis=1)
    P = 4.0 * np.einsum('nki,nkl,nlj->nij', xi, cov, xi)
    return Estimate(_nan_before_start(s, _to_n(_xyzw(out), 0.0)),
                    0.5 * (P + np.swapaxes(P, 1, 2)), cpu)


# -- Fusion and VQF -------------------------------------------------------------------------
def _fusion(s, p):
    import imufusion
    turn = _psi(s.field_n) - math.pi / 2
    st = imufusion.AhrsSettings()
    st.convention = imufusion.CONVENTION_ENU
    st.sample_rate = 1.0 / s.dt
    st.gain = float(p['gain'])
    st.acceleration_rejection = float(p['acceleration_rejection'])
    st.magnetic_rejection = float(p['magnetic_rejection'])
    st.rejection_timeout = int(round(float(p['rejection_timeout_s']) / s.dt))
    st.gyroscope_range = float(p['gyroscope_range'])
    f = imufusion.Ahrs()
    f.set_settings(st)
    gyr = np.ascontiguousarray(np.degrees(s.gyr))
    acc = np.ascontiguousarray(s.acc / GRAVITY)
    mag = np.ascontiguousarray(s.mag * 1e6)
    n = len(s.t)
    out = np.full((n, 4), np.nan)
    c = time.process_time()
    for k in range(s.start, n):
        f.update(gyr[k], acc[k], mag[k])
        out[k] = f.get_quaternion()
    cpu = time.process_time() - c
    return Estimate(_nan_before_start(s, _to_n(_xyzw(out), turn)), None, cpu)


def _vqf(s, p):
    import vqf
    turn = _psi(s.field_n) - math.pi / 2
    f = vqf.VQF(s.dt, s.dt, s.mag_dt, tauAcc=float(p['tauAcc']), tauMag=float(p['tauMag']),
                motionBiasEstEnabled=bool(p['motionBiasEstEnabled']),
                magDistRejectionEnabled=bool(p['magDistRejectionEnabled']))
    k = s.start
    mag = np.where(s.mag_new[k:, None], s.mag[k:] * 1e6, 0.0)   # VQF skips a zero sample
    gyr, acc, mag = (np.ascontiguousarray(a) for a in (s.gyr[k:], s.acc[k:], mag))
    out = np.full((len(s.t), 4), np.nan)
    c = time.process_time()
    out[k:] = f.updateBatch(gyr, acc, mag)['quat9D']
    cpu = time.process_time() - c
    return Estimate(_nan_before_start(s, _to_n(_xyzw(out), turn)), None, cpu)


# -- the shipped MEKF -----------------------------------------------------------------------
def _mekf(s, p):
    from types import SimpleNamespace as NS

    from rigidrot_ros.estimators.mekf import MEKF
    if s.star is None:
        raise ValueError('the MEKF needs the star tracker (star_tracker.enable)')
    f = MEKF({'sigma_v': float(p['sigma_v']), 'sigma_u': float(p['sigma_u']),
              'bias_sigma': float(p['bias_sigma']), 'output_every': 1_000_000})
    t_s, q_s, r_s = s.star
    stars = []
    for t, q, r in zip(t_s, q_s, r_s):
        cov = np.zeros((6, 6))
        cov[3:, 3:] = r
        stars.append(NS(header=NS(stamp=_stamp(t)), pose=NS(pose=NS(orientation=NS(
            x=q[0], y=q[1], z=q[2], w=q[3])), covariance=cov.ravel())))
    gyro_cov = (s.var_gyr * np.eye(3)).ravel()
    imus = [NS(header=NS(stamp=_stamp(t)), angular_velocity=NS(x=w[0], y=w[1], z=w[2]),
               angular_velocity_covariance=gyro_cov) for t, w in zip(s.t, s.gyr.tolist())]
    n = len(s.t)
    out, cov = np.full((n, 4), np.nan), np.full((n, 3, 3), np.nan)
    ns_imu = np.rint(s.t * 1e9).astype(np.int64)
    ns_star = np.rint(np.asarray(t_s) * 1e9).astype(np.int64)
    j = 0
    c = time.process_time()
    for k in range(n):
        while j < len(stars) and ns_star[j] < ns_imu[k]:
            f.receive('star_tracker', stars[j])
            j += 1
        f.receive('imu', imus[k])
        while j < len(stars) and ns_star[j] == ns_imu[k]:
            f.receive('star_tracker', stars[j])
            j += 1
        if f.q is not None and f.t_ns == ns_imu[k]:
            out[k] = f.q
            cov[k] = f.P[:3, :3]
    cpu = time.process_time() - c
    ok = np.all(np.isfinite(out), axis=1)
    out[ok] = _to_n(out[ok], 0.0)
    return Estimate(out, cov, cpu)


def _stamp(t):
    from types import SimpleNamespace as NS
    sec, nsec = divmod(int(round(float(t) * 1e9)), 1_000_000_000)
    return NS(sec=sec, nanosec=nsec)


class Filter:
    """One filter: ``name``, ``label``, ``library``, ``defaults``, ``grid``, ``has_cov``.

    ``grid`` is a list of parameter overrides (dicts) tried when tuning; ``defaults`` the
    library's own (the MEKF's: matched to the gyro's datasheet, given by the caller).
    ``sensors`` says what it fuses.
    """

    def __init__(self, name, label, library, fn, defaults, grid, has_cov, sensors):
        self.name, self.label, self.library = name, label, library
        self._fn, self.defaults, self.grid = fn, dict(defaults), list(grid)
        self.has_cov, self.sensors = has_cov, sensors

    def params(self, override=None):
        """Return the defaults updated by ``override``."""
        p = dict(self.defaults)
        p.update(override or {})
        return p

    def run(self, sensors, override=None):
        """Run on a :class:`SensorRun` with the defaults updated by ``override``."""
        return self._fn(sensors, self.params(override))


def _log_grid(lo, hi, n):
    return [float(f'{v:.3g}') for v in np.geomspace(lo, hi, n)]


def filters():
    """Return the filters, by name, in the leaderboard's order (:class:`Filter`)."""
    fl = [
        Filter('madgwick', 'Madgwick (ahrs)', 'ahrs', _madgwick, {'gain': 0.041},
               [{'gain': g} for g in _log_grid(1e-4, 3.0, 6)], False, 'gyro + acc + mag'),
        Filter('mahony', 'Mahony (ahrs)', 'ahrs', _mahony, {'k_P': 1.0, 'k_I': 0.3},
               [{'k_P': k, 'k_I': float(f'{0.3 * k:.3g}')} for k in _log_grid(1e-3, 30.0, 6)],
               False, 'gyro + acc + mag'),
        Filter('ekf', 'EKF (ahrs)', 'ahrs', _ekf, {'noise': 'default', 'meas_scale': 1.0},
               [{'noise': 'matched', 'meas_scale': c} for c in _log_grid(1.0, 1e6, 4)],
               True, 'gyro + acc + mag'),
        Filter('aqua', 'AQUA (ahrs)', 'ahrs', _aqua,
               {'alpha': 0.01, 'beta': 0.01, 'adaptive': False},
               [{'alpha': a, 'beta': a} for a in _log_grid(1e-5, 0.5, 6)], False,
               'gyro + acc + mag'),
        Filter('fusion', 'Fusion (imufusion)', 'imufusion', _fusion,
               {'gain': 0.5, 'acceleration_rejection': 0.0, 'magnetic_rejection': 0.0,
                'rejection_timeout_s': 0.0, 'gyroscope_range': 0.0},
               [{'gain': g} for g in _log_grid(1e-3, 10.0, 9)], False, 'gyro + acc + mag'),
        Filter('vqf', 'VQF (vqf)', 'vqf', _vqf,
               {'tauAcc': 3.0, 'tauMag': 9.0, 'motionBiasEstEnabled': True,
                'magDistRejectionEnabled': True},
               [{'tauAcc': a, 'tauMag': m} for a in (0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0)
                for m in (0.3, 1.0, 3.0, 9.0, 30.0, 100.0)], False, 'gyro + acc + mag'),
        Filter('mekf', 'MEKF (rigidrot_ros)', 'rigidrot_ros', _mekf,
               {'sigma_v': None, 'sigma_u': 0.0, 'bias_sigma': 0.0},
               [], True, 'gyro + star tracker'),
    ]
    return {f.name: f for f in fl}


#: The filters' names, in the leaderboard's order.
FILTERS = tuple(filters())
