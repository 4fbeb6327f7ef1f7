"""Fuzz the core with extreme scenes: refuse with a reason, or be right within the bound.

Seeded scenes across every model, with magnitudes from 1e-300 to 1e300 in every field
(log-uniform exponents, random signs, exact zeros, both torque frames) and times up to
1e9 s. Every ``Scene`` / ``solve`` / ``Solution.at`` / ``omega_at`` call either raises
``ValueError``, ``NoExactSolution`` or ``PrecisionError`` with a reason, or returns finite
unit quaternions and finite rates; where an independent reference is cheap the attitude
is within the stated bound of it:

- fixed axis, torque-free sphere, torque-free axisymmetric body: the classical closed
  forms, written here in mpmath at enough digits for the phase (``R0 exp(t L_B0 / I)
  exp(t lambda e_k)``, Landau & Lifshitz Sec. 33), not the package's formulas;
- every scene at t = 0: ``attitude0``;
- the rest: invariants of Euler's equations (angular momentum in N without torque, the
  rate laws below), DOP853 (``conftest.reference``) where rates and horizon are moderate,
  and the scaled twin: the same motion with every field scaled exactly by powers of two
  to moderate magnitudes must give the same attitude within both bounds.

10 000 scenes run by default (about 25 s of CPU here); ``pytest -m fuzz`` runs
50 000 more.
"""

import math
import re
import signal
import time

import mpmath
import numpy as np
import pytest

from conftest import CLAIM, reference
from rigidrot_ros.core import NoExactSolution, PrecisionError, Scene, solve
from rigidrot_ros.core import quaternion as quat
from rigidrot_ros.core import taylor

#: Seconds one scene may take (solve and all its samples) before the test fails on it.
SCENE_SECONDS = 20.0
MODEL_TIMES = 4


class _Slow(Exception):
    pass


def _alarm(signum, frame):
    raise _Slow()


#: The float range's edges: denormals, the smallest normal, the largest finite.
EDGES = (5e-324, 1e-320, 2.2250738585072014e-308, 1e-300, 1e300, 1.7976931348623157e308)


def _magnitude(rng, wide):
    """A positive float, log-uniform over 1e-300..1e300 (wide) or 1e-3..1e3; or an edge."""
    if wide and rng.random() < 0.03:
        return float(rng.choice(EDGES))
    e = rng.uniform(-300, 300) if wide else rng.uniform(-3, 3)
    return float(10.0 ** e)


def _vector(rng, wide, p_zero):
    return [0.0 if rng.random() < p_zero else
            float(rng.choice([-1.0, 1.0])) * _magnitude(rng, wide) for _ in range(3)]


def _scene_kwargs(rng):
    """A random scene, built so that every model (and every refusal) is reached."""
    wide = rng.random() < 0.6
    kind = rng.choice(['sphere', 'axisym', 'axisym', 'triaxial', 'random'])
    big = _magnitude(rng, wide)
    if kind == 'sphere':
        inertia = [big] * 3
    elif kind == 'axisym':
        inertia = [big] * 3
        k = int(rng.integers(3))
        # the symmetry-axis moment anywhere in (0, 2I]; sometimes extreme
        inertia[k] = big * (float(rng.uniform(0.0, 2.0)) if rng.random() < 0.7
                            else _magnitude(rng, True))
    elif kind == 'triaxial':
        inertia = sorted(big * float(rng.uniform(0.5, 1.0)) for _ in range(3))
    else:
        inertia = [_magnitude(rng, wide) * (1.0 if rng.random() < 0.9 else -1.0)
                   for _ in range(3)]
    omega0 = _vector(rng, wide or rng.random() < 0.3, 0.3)
    torque = _vector(rng, wide or rng.random() < 0.3, 0.4)
    pattern = rng.integers(4)
    if pattern == 0:                       # no torque
        torque = [0.0, 0.0, 0.0]
    elif pattern == 1:                     # omega0 and torque along one axis
        k = int(rng.integers(3))
        omega0 = [v if i == k else 0.0 for i, v in enumerate(omega0)]
        torque = [v if i == k else 0.0 for i, v in enumerate(torque)]
    elif pattern == 2 and kind == 'axisym':    # transverse body torque with r0 = 0
        k = int(np.argmax([abs(inertia[(i + 1) % 3] - inertia[(i + 2) % 3]) == 0
                           for i in range(3)]))
        omega0[k] = 0.0
        torque[k] = 0.0
    att = [float(v) for v in rng.normal(size=4)]
    if rng.random() < 0.1:
        att = [v * _magnitude(rng, True) for v in att]
    elif rng.random() < 0.05:
        att = [float(rng.choice(EDGES)) * (v > 0) for v in att]
    return dict(inertia=inertia, torque=torque, omega0=omega0, attitude0=att,
                torque_frame=str(rng.choice(['body', 'virtual'])))


def _times(rng):
    ts = [0.0]
    for _ in range(MODEL_TIMES - 1):
        t = float(10.0 ** rng.uniform(-3, 9)) if rng.random() < 0.97 else \
            float(rng.choice([5e-324, 1e15, 1e300, 1.7976931348623157e308]))
        ts.append(-t if rng.random() < 0.2 else t)
    return ts


# ---------------------------------------------------------------------------------------
# independent references (mpmath)

def _mp_qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz]


def _mp_exp(v, t):
    """Quaternion of the rotation by the vector v t (mpf), i.e. exp(v t / 2)."""
    n = mpmath.sqrt(sum(x * x for x in v))
    if n == 0:
        return [mpmath.mpf(0)] * 3 + [mpmath.mpf(1)]
    h = n * t / 2
    s = mpmath.sin(h) / n
    return [x * s for x in v] + [mpmath.cos(h)]


def _mp_angle(q_ref, q):
    """Rotation angle (rad) between the mpmath reference and a float quaternion."""
    qr = [-q_ref[0], -q_ref[1], -q_ref[2], q_ref[3]]
    d = _mp_qmul(qr, [mpmath.mpf(float(v)) for v in q])
    return float(2 * mpmath.atan2(mpmath.sqrt(d[0] ** 2 + d[1] ** 2 + d[2] ** 2), abs(d[3])))


def _dps(*phases):
    """Digits for phases |x| (mpf): 30 beyond the integer part of the largest."""
    mags = [int(mpmath.mag(x)) for x in phases if x != 0]
    return 30 + max([0] + [int(m * 0.30103) + 1 for m in mags])


def _reference(scene, t):
    """(name, mpmath quaternion q_NB(t)) from a classical closed form, or None."""
    inertia, w, m = scene.inertia, scene.omega0, scene.torque
    with mpmath.workdps(30):
        q0 = [mpmath.mpf(v) for v in scene.attitude0]
        nq = mpmath.sqrt(sum(v * v for v in q0))
        q0 = [v / nq for v in q0]
    for k in range(3):
        o = [j for j in range(3) if j != k]
        if all(w[j] == 0.0 and m[j] == 0.0 for j in o):
            # fixed axis k: theta = w t + (m / I) t^2 / 2
            tt, wk = mpmath.mpf(t), mpmath.mpf(w[k])
            acc = mpmath.mpf(m[k]) / mpmath.mpf(inertia[k])
            with mpmath.workdps(_dps(wk * tt, acc * tt * tt) + 10):
                acc = mpmath.mpf(m[k]) / mpmath.mpf(inertia[k])
                theta = wk * tt + acc * tt * tt / 2
                axis = [mpmath.mpf(0)] * 3
                axis[k] = mpmath.mpf(1)
                return 'fixed-axis', _mp_qmul(q0, _mp_exp(axis, theta))
    if any(m):
        return None
    if inertia[0] == inertia[1] == inertia[2]:
        wv = [mpmath.mpf(v) for v in w]
        with mpmath.workdps(_dps(*(v * mpmath.mpf(t) for v in wv))):
            return 'torque-free-sphere', _mp_qmul(q0, _mp_exp(wv, mpmath.mpf(t)))
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        if inertia[i] == inertia[j]:
            # R(t) = R0 exp(t [L_B0 / I]x) exp(t lambda [e_k]x), lambda = (I - Ik) w_k / I
            mi, mk, tt = mpmath.mpf(inertia[i]), mpmath.mpf(inertia[k]), mpmath.mpf(t)
            with mpmath.workdps(_dps(*(mpmath.mpf(v) * tt for v in w)) + 10):
                mi, mk = mpmath.mpf(inertia[i]), mpmath.mpf(inertia[k])
                lv = [mpmath.mpf(v) for v in w]
                lv[k] = mk * lv[k] / mi                         # L_B0 / I
                lam = (mi - mk) * mpmath.mpf(w[k]) / mi
                ek = [mpmath.mpf(0)] * 3
                ek[k] = lam
                return 'torque-free-axisymmetric', _mp_qmul(
                    _mp_qmul(q0, _mp_exp(lv, tt)), _mp_exp(ek, tt))
    return None


def _rate_laws(sol, scene, t, omega):
    """Check omega(t) against laws of Euler's equations that the models must obey."""
    inertia, w0, m = (np.array(v) for v in (scene.inertia, scene.omega0, scene.torque))
    scale = max(map(abs, scene.omega0)) + \
        max(abs(a / b) for a, b in zip(scene.torque, scene.inertia)) * abs(t)
    if not scale < math.inf:
        return                                   # omega(t) itself near the float limit
    if scale == 0.0:
        assert np.all(omega == 0.0)
        return
    tol = 1e-11 * scale
    if sol.model == 'fixed-axis' or sol.model in ('sphere', 'torque-free-sphere') and \
            scene.torque_frame == 'body' or sol.model == 'transverse-body':
        # no gyroscopic coupling: omega = omega0 + (m / I) t exactly
        np.testing.assert_allclose(omega, w0 + m / inertia * t, rtol=0, atol=tol)
        return
    if sol.model == 'sphere':
        # a virtual torque on a sphere is body-fixed too (S = B)
        np.testing.assert_allclose(omega, w0 + m / inertia * t, rtol=0, atol=tol)
        return
    if sol.model == 'torque-free-triaxial':
        # Euler-Poinsot: 2T = sum I w^2 and |h|^2 = sum (I w)^2 stay constant (scaled)
        a, b, c = inertia / np.max(inertia), omega / scale, w0 / scale
        for p in (1, 2):
            now, then = np.sum(a ** p * b * b), np.sum(a ** p * c * c)
            assert abs(now - then) <= 1e-11 * then, (p, now, then)
        return
    k = [i for i in range(3) if inertia[(i + 1) % 3] == inertia[(i + 2) % 3]][0]
    tr = [(k + 1) % 3, (k + 2) % 3]
    # axial rate grows linearly; the transverse rate's length follows the torque in S
    assert abs(omega[k] - (w0[k] + m[k] / inertia[k] * t)) <= tol
    if sol.model in ('torque-free-axisymmetric', 'axial-torque'):
        perp = math.hypot(*w0[tr])
    else:                                            # transverse torque fixed in S
        perp = math.hypot(*(w0[tr] + m[tr] / inertia[tr] * t))
    got = math.hypot(*omega[tr])
    if math.isfinite(perp) and math.isfinite(got):   # else |omega_perp| beyond 1.8e308
        assert abs(got - perp) <= tol


def _angular_momentum_n(scene, q, omega):
    """L_N / (max I max |omega|) from float q and omega (scaled: no overflow)."""
    inertia = np.array(scene.inertia)
    s_i, s_w = np.max(inertia), np.max(np.abs(scene.omega0))     # fixed scales
    if s_w == 0:
        return np.zeros(3)
    return quat.to_matrix(q) @ ((inertia / s_i) * (omega / s_w))


def _moderate(scene, t):
    """Whether DOP853 from t = 0 is cheap and tight here."""
    inertia, w0, m = scene.inertia, scene.omega0, scene.torque
    if not (1e-3 <= min(inertia) and max(inertia) <= 1e3 and max(map(abs, m)) <= 1e3):
        return False
    rate = max(map(abs, w0)) + max(abs(a / b) for a, b in zip(m, inertia)) * abs(t)
    return rate * abs(t) <= 200.0 and 0 < abs(t) and max(map(abs, w0)) <= 1e2 and \
        max(inertia) / min(inertia) <= 20


def _twin(scene, t):
    """The same motion scaled by powers of two to moderate magnitudes: (scene, t), or None.

    Euler's equations and the kinematics are invariant under ``I -> mu I``,
    ``m -> mu lam^2 m``, ``omega -> lam omega``, ``t -> t / lam``; with ``mu`` and ``lam``
    powers of two every field scales exactly (checked), so the two attitudes must agree.
    """
    imax = max(scene.inertia)
    acc = max(abs(v) for v in scene.torque) / imax
    rate = max(max(abs(v) for v in scene.omega0), math.sqrt(acc))
    if rate == 0.0 or not math.isfinite(rate):
        return None
    a, b = -math.frexp(imax)[1], -math.frexp(rate)[1]
    if abs(a) + abs(b) < 20:                                  # already moderate
        return None
    shift = {'inertia': a, 'torque': a + 2 * b, 'omega0': b}
    try:
        fields = {key: [math.ldexp(v, k) for v in getattr(scene, key)]
                  for key, k in shift.items()}
        for key, vals in fields.items():
            if [math.ldexp(v, -shift[key]) for v in vals] != list(getattr(scene, key)):
                return None                                   # not exact (underflow)
        t2 = math.ldexp(t, -b)
        if math.ldexp(t2, b) != t:
            return None
    except OverflowError:
        return None
    return Scene(torque_frame=scene.torque_frame, attitude0=scene.attitude0, **fields), t2


class _Stats:
    def __init__(self):
        self.counts = {}
        self.worst = (0.0, None)             # error / bound
        self.slowest = (0.0, None)

    def add(self, key, n=1):
        self.counts[key] = self.counts.get(key, 0) + n

    def ratio(self, err, bound, what):
        if bound > 0 and err / bound > self.worst[0]:
            self.worst = (err / bound, what)


def _refused(stats, where, exc):
    text = str(exc)
    assert text.strip(), f'{where}: {type(exc).__name__} without a reason'
    name = 'NoExactSolution' if isinstance(exc, NoExactSolution) else type(exc).__name__
    stats.add(f'refused at {where}: {name}')


def _check_samples(stats, sol, scene, ts, tol):
    """Scalar and batch samples: finite, unit, bounded, and right where checkable."""
    samples = []
    for t in ts:
        try:
            s = sol.at(t)
            w = sol.omega_at(t)
        except (ValueError, PrecisionError) as exc:
            _refused(stats, 'at(t)', exc)
            assert 't = ' in str(exc) or 't must' in str(exc), str(exc)
            continue
        q, err = s.quaternion, float(s.error_bound)
        assert np.all(np.isfinite(q)) and abs(np.linalg.norm(q) - 1.0) <= 4e-15, (q, t)
        assert np.all(np.isfinite(s.omega)) and np.all(np.isfinite(w)), (s.omega, t)
        np.testing.assert_array_equal(s.omega, w)
        assert 1e-14 <= err <= tol, (err, t)
        stats.add('samples returned')
        samples.append((t, q, err, s.omega))
        if t == 0.0:
            q_ref = mpmath.matrix(scene.attitude0)
            e0 = _mp_angle([q_ref[i] for i in range(4)], q)
            assert e0 <= err, (e0, err)
            stats.add('checked: attitude0 at t = 0')
            stats.ratio(e0, err, ('t=0', scene))
        ref = _reference(scene, t)
        if ref is not None:
            name, q_ref = ref
            e = _mp_angle(q_ref, q)
            assert e <= err, (name, t, e, err, scene)
            stats.add(f'checked: {name} closed form')
            stats.ratio(e, err, (name, t, scene))
        _rate_laws(sol, scene, t, s.omega)
        stats.add('checked: rate laws')
    if samples and not any(scene.torque):
        ln = [_angular_momentum_n(scene, q, w) for _, q, _, w in samples]
        scale = max(float(np.linalg.norm(v)) for v in ln)
        for v, (_, _, err, _) in zip(ln, samples):
            # rotating a fixed vector by an attitude error e moves it by <= e |L|
            assert np.linalg.norm(v - ln[0]) <= 2 * (err + 1e-14) * scale + 1e-12 * scale
        stats.add('checked: L_N conserved', len(ln))
    if samples and any(scene.torque) and _moderate(scene, samples[-1][0]):
        t, q, err, _ = samples[-1]
        try:
            with np.errstate(all='ignore'):    # scipy's step control divides 0 / 0 at rest
                _, q_ref, q_err, _ = reference(scene, np.array([0.0, t]))
        except AssertionError:                 # DOP853 gave up (step below spacing)
            stats.add('DOP853 gave up (not checked)')
        else:
            e = float(quat.angle_between(q_ref[-1], q))
            # the bound asked (at least the package's claim) plus the reference's own error
            assert e <= max(err, CLAIM) + q_err[-1], (t, e, err, q_err[-1], scene)
            stats.add('checked: DOP853 (torque, moderate)')
    if samples and any(scene.torque):
        t, q, err, _ = samples[-1]
        twin = _twin(scene, t)
        if twin is not None:
            # the twin may differ in what it refuses: DROP_RATE and DENSE_RATES are in rad/s
            try:
                s2 = solve(twin[0], tol=tol, backend=sol.backend).at(twin[1])
            except (ValueError, PrecisionError) as exc:
                _refused(stats, 'the scaled twin', exc)
            else:
                gap = float(quat.angle_between(q, s2.quaternion))
                assert gap <= err + float(s2.error_bound), (t, gap, err, repr(scene), twin)
                stats.add('checked: scaled twin (powers of two) agrees')
    if len(samples) >= 2:
        ts_ok = np.array([t for t, *_ in samples])
        batch = sol.at(ts_ok)
        for (t, q, err, _), qb, eb in zip(samples, batch.quaternion, batch.error_bound):
            gap = float(quat.angle_between(q, qb))
            assert gap <= err + eb, (t, gap, err, eb)
        stats.add('checked: batch = scalar within bounds', len(samples))


def _run(n, seed, monkeypatch):
    # far Taylor queries: refuse sooner instead of stepping or seeding for seconds
    monkeypatch.setattr(taylor, 'MAX_STEP_TURN', 2e4)
    monkeypatch.setattr(taylor, 'MAX_SEED_TURN', 2e5)
    rng = np.random.default_rng(seed)
    stats = _Stats()
    old = signal.signal(signal.SIGALRM, _alarm)
    try:
        for i in range(n):
            kw = _scene_kwargs(rng)
            ts = _times(rng)
            tol = float(10.0 ** rng.uniform(-13.7, -6)) if rng.random() < 0.5 else \
                float(rng.choice([1e-12, 1e-12, 1e-12, 0.1, 1e300]))
            backend = 'mpmath' if rng.random() < 0.05 else None
            start = time.process_time()
            signal.setitimer(signal.ITIMER_REAL, SCENE_SECONDS)
            try:
                try:
                    scene = Scene(**kw)
                except ValueError as exc:
                    _refused(stats, 'Scene', exc)
                    continue
                try:
                    sol = solve(scene, tol=tol, backend=backend)
                except (ValueError, PrecisionError) as exc:
                    _refused(stats, 'solve', exc)
                    continue
                stats.add(f'accepted: {sol.model}')
                _check_samples(stats, sol, scene, ts, tol)
            except _Slow:
                pytest.fail(f'scene {i} took over {SCENE_SECONDS} s: {kw}, t = {ts}')
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            spent = time.process_time() - start
            if spent > stats.slowest[0]:
                stats.slowest = (spent, (kw, ts))
    finally:
        signal.signal(signal.SIGALRM, old)
    print(f'\ncore fuzz: {n} scenes, seed {seed}')
    for key in sorted(stats.counts):
        print(f'  {key}: {stats.counts[key]}')
    print(f'  worst error / bound: {stats.worst[0]:.3g} ({stats.worst[1]})')
    print(f'  slowest scene: {stats.slowest[0]:.2f} s CPU ({stats.slowest[1]})')
    return stats


@pytest.mark.filterwarnings('error::RuntimeWarning')      # no numpy overflow, silently
def test_core_fuzz_5000_scenes(monkeypatch):
    """5000 scenes in the default suite; ``-m fuzz`` runs 50 000 more."""
    stats = _run(5000, 20261122, monkeypatch)
    c = stats.counts
    # the draw reaches every closed form and refusals of each kind
    for key in ('checked: fixed-axis closed form', 'checked: torque-free-sphere closed form',
                'checked: torque-free-axisymmetric closed form',
                'checked: DOP853 (torque, moderate)'):
        assert c.get(key, 0) >= 50, (key, c)
    assert sum(v for k, v in c.items() if k.startswith('accepted')) >= 1500, c
    for key in ('refused at solve: NoExactSolution', 'refused at at(t): PrecisionError',
                'refused at Scene: ValueError'):
        assert c.get(key, 0) >= 5, (key, c)


@pytest.mark.fuzz
@pytest.mark.timeout(3600)
@pytest.mark.filterwarnings('error::RuntimeWarning')
@pytest.mark.parametrize('seed', [1, 2, 3, 4, 5])
def test_core_fuzz_more_seeds(seed, monkeypatch, request):
    """50 000 more scenes (-m fuzz; several minutes)."""
    if 'fuzz' not in (request.config.getoption('markexpr') or ''):
        pytest.skip('long fuzz run: select it with -m fuzz')
    stats = _run(10000, seed, monkeypatch)
    assert sum(v for k, v in stats.counts.items() if k.startswith('accepted')) >= 3000


# ---------------------------------------------------------------------------------------
# the reproductions (issue 11), and the limits

_BASE = dict(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.1), omega0=(0.3, -0.2, 0.5))


@pytest.mark.parametrize('change', [
    dict(omega0=(1e300, -0.2, 0.5)), dict(inertia=(2e300, 2e300, 1e300)),
    dict(inertia=(2e-300, 2e-300, 1e-300)), dict(torque=(1e300, 0, 0), torque_frame='virtual'),
    dict(torque=(1e-300, 0, 0), torque_frame='virtual'), dict(torque=(0, 0, 1e300)),
    dict(omega0=(1e150, -0.2, 0.5)), dict(omega0=(3e200, -1e200, 2e200)),
    dict(torque=(1e300, 0, 0), inertia=(2e-300, 2e-300, 1e-300)),
    dict(torque=(5e-324, 0, 0), torque_frame='virtual'),
])
@pytest.mark.filterwarnings('error::RuntimeWarning')
def test_extreme_torque_scenes_refuse_or_hold_their_bound(change):
    """The issue's crashes: now a reason, or samples that obey the rate laws."""
    scene = Scene(**{**_BASE, **change})
    try:
        sol = solve(scene)
    except (ValueError, PrecisionError) as exc:
        assert 'torque' in str(exc) or 'inertia' in str(exc) or 'omega0' in str(exc)
        return
    for t in (0.0, 1.0, 1e3, 1e9):
        try:
            s = sol.at(t)
        except PrecisionError as exc:
            assert f't = {t!r} s' in str(exc) and 'limit' in str(exc), str(exc)
            continue
        assert np.all(np.isfinite(s.quaternion)) and float(s.error_bound) <= 1e-12
        _rate_laws(sol, scene, t, s.omega)


@pytest.mark.parametrize('change', [
    dict(omega0=(0, 0, 1e300), torque=(0, 0, 0)),
    dict(inertia=(1, 1, 1), torque=(0, 0, 0), omega0=(1e300, 0, 0)),
    dict(omega0=(0, 0, 1e150), torque=(0, 0, 0)),
    dict(omega0=(3e200, -1e200, 2e200), torque=(0, 0, 0)),
    dict(omega0=(3e-200, -1e-300, 5e-324), torque=(0, 0, 0)),
    dict(inertia=(1e-300, 1e-300, 1e-300), torque=(0, 0, 1e-10), omega0=(0, 0, 1e5)),
])
@pytest.mark.parametrize('t', [1.0, 1e-3, 12345.678, 1e9, -7e8, 1.7e308])
@pytest.mark.filterwarnings('error::RuntimeWarning')
def test_huge_phases_are_exact(change, t):
    """The issue's silent wrong answers: phases of 1e300 rad, reduced at enough bits."""
    scene = Scene(**{**_BASE, **change})
    sol = solve(scene)
    try:
        s = sol.at(t)
    except ValueError as exc:                 # omega(t) itself beyond the float range
        assert 'float64 range' in str(exc) and f't = {t!r} s' in str(exc)
        return
    name, q_ref = _reference(scene, t)
    assert _mp_angle(q_ref, s.quaternion) <= float(s.error_bound) == 1e-14


def test_phase_precision_grows_with_the_angle():
    sol = solve(Scene(omega0=(0.0, 0.0, 1e300)))
    assert sol._kernel.angle.prec_at(1.0) >= 1000 + 80
    assert solve(Scene(omega0=(0.0, 0.0, 1.0)))._kernel.angle.prec_at(1e9) == 256


def test_taylor_continuation_refuses_far_times_at_once(monkeypatch):
    """Past MAX_STEP_TURN rad of stepping (and no 1F1 seed) a far t is refused, fast."""
    monkeypatch.setattr(taylor, 'MAX_SEED_TURN', 0.0)
    sol = solve(Scene(inertia=(1, 1, 1), omega0=(2.0, 0.0, 0.0), torque=(0.0, 0.0, 1e-3)))
    assert sol.method.startswith('taylor')
    start = time.process_time()
    with pytest.raises(PrecisionError, match=r't = 1000000\.0 s is out of reach.*limit of 2e\+06'):
        sol.at(1e6)
    assert time.process_time() - start < 1.0
    assert np.isfinite(sol.at(10.0).quaternion).all()      # nearer times still work


def test_mpmath_1f1_beyond_max_prec_says_so_at_once():
    from rigidrot_ros.core.kernel import HyperKernel
    start = time.process_time()
    with pytest.raises(PrecisionError, match=r'would need about \d+ bits \(ceiling 256\).*delta'):
        HyperKernel(2.0, 0.0, 0.5, 1e-2, 'mpmath', tol=1e-12, max_prec=256)
    assert time.process_time() - start < 1.0


@pytest.mark.parametrize('call, match', [
    (lambda: Scene(inertia=(10 ** 400, 1, 1)), r'inertia\[0\] = .* beyond the float64 range'),
    (lambda: Scene(omega0=None), 'omega0 must be a sequence'),
    (lambda: Scene(torque={'x': 1, 'y': 2, 'z': 3}), 'torque must be a sequence'),
    (lambda: Scene(torque_frame=['body']), 'torque_frame must be one of'),
    (lambda: solve(Scene(), tol=10 ** 400), 'tol must be a finite'),
    (lambda: solve(Scene(), max_prec=10 ** 9), 'max_prec must be an integer from 64 to 65536'),
    (lambda: solve(Scene(omega0=(0, 0, 1))).at(10 ** 400), 't must be a float'),
    (lambda: solve(Scene(omega0=(0, 0, 1))).at('soon'), 't must be a float'),
    (lambda: solve(Scene(omega0=(0, 0, 1))).omega_at(None), 't must be'),
    (lambda: solve(Scene(inertia=(1e-300,) * 3, torque=(0, 0, 1e300))),
     r'torque / inertia reaches 1\.0e\+600 rad/s\^2: beyond the float64 range'),
    (lambda: solve(Scene(inertia=(1,) * 3, torque=(0, 0, 1e300))).at(1e10),
     r'at t = 10000000000\.0 s the body rate .* exceeds the float64 range'),
])
def test_bad_or_out_of_range_input_names_the_problem(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_1f1_constants_carry_the_inputs_precision():
    """Found by the scaled twin: sqrt(U) rounded at 256 bits put a 1e137 rad phase 1.3 rad off.

    Transverse rate 1e-13 rad/s against a spin of 1e46 rad/s and U = 2.7e136 rad/s^2: the
    motion is a rotation about K3 to 1e-80 rad, by r0 t + U t^2 / 2 (mpmath, 1200 bits).
    """
    scene = Scene(inertia=(2.64664376756607e-100,) * 3, torque_frame='virtual',
                  torque=(-7.851002516315222e-23, 0.0, -7.136590266206839e+36),
                  omega0=(8.164025352037806e-91, 0.0, -1.0359937547287274e+46))
    t = 2.224241735462357
    sol = solve(scene, tol=1e-9)
    assert sol.method == 'hypergeometric-flint'
    s = sol.at(t)
    with mpmath.workprec(1200):
        inertia, m, w = (mpmath.mpf(v)
                         for v in (scene.inertia[0], scene.torque[2], scene.omega0[2]))
        mx, wx = mpmath.mpf(scene.torque[0]), mpmath.mpf(scene.omega0[0])
        mn = mpmath.sqrt(m * m + mx * mx)
        axis = [mx / mn, mpmath.mpf(0), m / mn]
        # omega along the torque, spun up at |m| / I: q(t) = exp(theta(t) axis / 2)
        r0 = (wx * mx + w * m) / mn
        theta = r0 * t + mn / inertia * mpmath.mpf(t) ** 2 / 2
        q_ref = _mp_exp(axis, theta)
    # + 1e-15: the reference neglects the transverse rate's effect, about 1e-80 rad
    assert _mp_angle(q_ref, s.quaternion) <= float(s.error_bound) + 1e-15


def test_dense_output_stays_out_of_float_overflow():
    """sqrt(U) = 2.5e11 rad/s: the float64 window recurrence would overflow (it hung)."""
    scene = Scene(inertia=(30.09823907985878,) * 3, omega0=(0.0, -3.3070049477882004, 0.0),
                  torque=(-1.916788479126416e+24, 0.0, 7.049395374642068e-80))
    sol = solve(scene)
    start = time.process_time()
    s = sol.at(np.linspace(0.0, 2.0, 20))
    assert time.process_time() - start < 5.0 and np.all(s.error_bound <= 1e-12)


@pytest.mark.parametrize('r0', [1e160, 1e250])
def test_mpmath_backend_refuses_huge_spin_with_a_reason(r0):
    """The mpmath 1F1 path's refusal reports |z^2| without overflowing a float.

    Under a low ceiling it refuses at once, naming the bits it would need; given just
    those (not the default 4096, whose climb costs some 10 s of mpmath gamma functions
    and ends the same way) it tries, reaches no bound, and reports |z^2| = inf.
    """
    scene = Scene(inertia=(2.0, 2.0, 1.0), torque=(0.0, 0.0, 0.05), omega0=(0.3, -0.2, r0))
    with pytest.raises(PrecisionError, match=r'mpmath 1F1 evaluation would need about '
                                             r'(\d+) bits \(ceiling 128\)') as early:
        solve(scene, backend='mpmath', max_prec=128)
    need = int(re.search(r'about (\d+) bits', str(early.value)).group(1))
    assert 128 < need <= 4096
    with pytest.raises(PrecisionError, match=r'mpmath 1F1 evaluation reached only .* '
                                             r'with %d bits: .* \|z\^2\| = '
                                             r'\(r0 \+ U t\)\^2 / \(2U\) = inf ' % need):
        solve(scene, backend='mpmath', max_prec=need)
