"""The leaderboard's metrics, its in-memory runs and its filter wrappers.

Oracles: the inclination/heading split against plain vector geometry (the angle between
the true and estimated vertical seen in the body, and cos(theta/2) = cos(alpha/2)
cos(psi/2) for the heading), scipy's Rotation for the error angles and rotation vectors,
the node's own messages (iter_run) for the arrays the filters are fed, and the MEKF fed
those messages for the in-memory MEKF.
"""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidrot_ros.bench import leaderboard as lb
from rigidrot_ros.bench import leaderboard_cells as cells
from rigidrot_ros.bench.leaderboard_report import sign_test
from rigidrot_ros.campaign.metrics import split_error, time_to_converge
from rigidrot_ros.estimators import thirdparty
from rigidrot_ros.run.generate import iter_run, run_arrays

pytest.importorskip('ahrs')
pytest.importorskip('imufusion')
pytest.importorskip('vqf')


def _xyzw(r):
    return r.as_quat()                      # scipy's order is (x, y, z, w), active


def _vertical_geometry(q_true, q_est):
    """Inclination: the angle between the true and estimated vertical seen in B; heading
    from cos(theta/2) = cos(alpha/2) cos(psi/2) (swing about a horizontal axis)."""
    rt, re = Rotation.from_quat(q_true), Rotation.from_quat(q_est)
    z = np.array([0.0, 0.0, 1.0])
    a, b = rt.inv().apply(z), re.inv().apply(z)
    incl = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum('ij,ij->i', a, b))
    theta = (rt.inv() * re).magnitude()
    c = np.clip(np.cos(theta / 2) / np.cos(incl / 2), -1.0, 1.0)
    return incl, theta, 2 * np.arccos(c)


def test_split_against_vector_geometry():
    rng = np.random.default_rng(5)
    n = 400
    q_true = Rotation.random(n, random_state=6)
    err = Rotation.from_rotvec(rng.normal(size=(n, 3)) * rng.uniform(0.01, 0.8, (n, 1)))
    q_est = err * q_true                            # an error rotation in N
    incl, head = split_error(_xyzw(q_true), _xyzw(q_est))
    incl_ref, theta, head_ref = _vertical_geometry(_xyzw(q_true), _xyzw(q_est))
    np.testing.assert_allclose(incl, incl_ref, atol=1e-9)
    np.testing.assert_allclose(head, head_ref, atol=2e-7)
    # pure heading and pure tilt errors
    yaw = Rotation.from_euler('z', [[0.3], [-1.2], [2.5]])
    tilt = Rotation.from_euler('x', [[0.2], [-0.7], [1.1]])
    base = Rotation.random(3, random_state=1)
    i_y, h_y = split_error(_xyzw(base), _xyzw(yaw * base))
    np.testing.assert_allclose(i_y, 0.0, atol=1e-12)
    np.testing.assert_allclose(h_y, [0.3, 1.2, 2.5], atol=1e-12)
    i_t, h_t = split_error(_xyzw(base), _xyzw(tilt * base))
    np.testing.assert_allclose(i_t, [0.2, 0.7, 1.1], atol=1e-12)
    np.testing.assert_allclose(h_t, 0.0, atol=1e-12)


def test_time_to_converge():
    t = np.arange(10) * 0.1
    assert time_to_converge(t, [9, 5, 3, 1, 1, 1.5, 1, 1, 1, 1], 1.0) == pytest.approx(0.3)
    assert time_to_converge(t, np.ones(10), 1.0) == 0.0
    assert math.isnan(time_to_converge(t, [1] * 9 + [5], 1.0))


def _values():
    v = cells.cell_values('consumer', 'lever')
    v.update({'attitude0': [0.2, -0.4, 0.1, 0.8888194417315589], 'imu.seed': 4,
              'mag.seed': 9, 'star_tracker.seed': 2})
    return v


def test_run_arrays_are_the_messages():
    values = _values()
    arr = run_arrays(values, 1.0)
    got = {'/imu': [], '/mag': [], '/attitude': [], '/star_tracker': []}
    for topic, _, msg in iter_run(values, 1.0):
        if topic == '/imu':
            w, f = msg.angular_velocity, msg.linear_acceleration
            got[topic].append([w.x, w.y, w.z, f.x, f.y, f.z])
        elif topic == '/mag':
            m = msg.magnetic_field
            got[topic].append([m.x, m.y, m.z])
        elif topic == '/attitude':
            q = msg.quaternion
            got[topic].append([q.x, q.y, q.z, q.w])
        elif topic == '/star_tracker':
            o = msg.pose.pose.orientation
            got[topic].append([o.x, o.y, o.z, o.w])
    np.testing.assert_array_equal(np.hstack([arr['/imu']['w'], arr['/imu']['f']]),
                                  got['/imu'])
    np.testing.assert_array_equal(arr['/mag']['m'], got['/mag'])
    np.testing.assert_array_equal(arr['/attitude']['q'], got['/attitude'])
    np.testing.assert_array_equal(arr['/star_tracker']['q'], got['/star_tracker'])
    assert arr['run']['start_ns'] == 0


def test_every_filter_tracks_the_truth_in_its_own_frame():
    """A wrong Earth frame or quaternion convention shows as tens of degrees."""
    s = cells.sensor_runs(cells.cell_spec('tactical', 'slow', 'test', 3), 1, 4.0)[0]
    fl = thirdparty.filters()
    mekf = {'sigma_v': 1.2e-5, 'sigma_u': 2e-7, 'bias_sigma': 1.2e-6}
    for name, f in fl.items():
        est = f.run(s, mekf if name == 'mekf' else None)
        err = Rotation.from_quat(s.q_true[-100:]).inv() * Rotation.from_quat(est.q[-100:])
        assert np.degrees(err.magnitude()).max() < 1.5, name
        assert (est.P is not None) == f.has_cov


def test_in_memory_mekf_is_the_mekf_fed_messages():
    from rigidrot_ros.estimators.mekf import make
    values = _values()
    s = thirdparty.SensorRun.from_arrays(run_arrays(values, 1.5), values)
    params = {'sigma_v': 2.4e-4, 'sigma_u': 1e-6, 'bias_sigma': 1e-5}
    est = thirdparty.filters()['mekf'].run(s, params)
    f = make(dict(params, output_every=1))
    out = []
    for topic, _, msg in iter_run(values, 1.5):
        out += f.receive(topic, msg)
    out += f.finish()
    t = np.array([o.header.stamp.sec + 1e-9 * o.header.stamp.nanosec for o in out])
    q = np.array([[o.pose.pose.orientation.x, o.pose.pose.orientation.y,
                   o.pose.pose.orientation.z, o.pose.pose.orientation.w] for o in out])
    cov = np.array([np.reshape(o.pose.covariance, (6, 6))[3:, 3:] for o in out])
    rows = np.searchsorted(np.round(s.t * 1e9), np.round(t * 1e9))
    assert len(out) > 100 and np.array_equal(np.round(s.t[rows] * 1e9), np.round(t * 1e9))
    sign = np.sign(np.einsum('ij,ij->i', q, est.q[rows]))
    np.testing.assert_array_equal(est.q[rows] * sign[:, None], q)
    np.testing.assert_array_equal(est.P[rows], cov)


def test_tiny_cell_metrics_recomputed():
    """A cell of 2 training and 3 held-out runs; its metrics recomputed another way."""
    size = {'duration': 3.0, 'window': 1.0, 'train': 2, 'test': 3, 'default': 2, 'seed': 5}
    names = ['vqf', 'fusion', 'mekf']
    cell = cells.run_cell('consumer', 'lever', size, names=names)
    assert list(cell['filters']) == names
    assert cells.cell_spec('consumer', 'lever', 'train', 5)['seed'] != \
        cells.cell_spec('consumer', 'lever', 'test', 5)['seed']
    test = cells.sensor_runs(cells.cell_spec('consumer', 'lever', 'test', 5), 3, 3.0)
    fl = thirdparty.filters()
    for name in names:
        res = cell['filters'][name]
        best = min(res['tuning'], key=lambda r: r['train_rmse_deg'])
        assert res['tuned_params'] == dict(res['default_params'], **best['params'])
        tot, inc, hed, nees = [], [], [], []
        for s in test:
            est = fl[name].run(s, res['tuned_params'])
            win = s.t >= 1.0
            qt, qe = s.q_true[win], est.q[win]
            i_ref, theta, h_ref = _vertical_geometry(qt, qe)
            tot.append(theta)
            inc.append(i_ref)
            hed.append(h_ref)
            if est.P is not None:
                e = (Rotation.from_quat(qt).inv() * Rotation.from_quat(qe)).as_rotvec()
                sol = np.linalg.solve(est.P[win], e[..., None])[..., 0]
                nees.append(np.einsum('ni,ni->n', e, sol))
        summ = res['tuned']

        def rms(x):
            return math.degrees(math.sqrt(np.mean(np.concatenate(x) ** 2)))
        assert summ['rmse_deg']['total'] == pytest.approx(rms(tot), rel=1e-9)
        assert summ['rmse_deg']['incl'] == pytest.approx(rms(inc), rel=1e-7)
        assert summ['rmse_deg']['head'] == pytest.approx(rms(hed), rel=1e-5)
        assert summ['p95_deg'] == pytest.approx(
            math.degrees(np.percentile(np.concatenate(tot), 95)), rel=1e-9)
        if name == 'mekf':
            assert summ['anees'] == pytest.approx(np.mean(np.concatenate(nees)), rel=1e-7)
        else:
            assert summ['anees'] is None
        assert summ['runs'] == 3 and res['default']['runs'] == 2
        defaults = []                   # the defaults, on the first 2 held-out runs
        for s in test[:2]:
            est = fl[name].run(s, res['default_params'])
            defaults.append(_vertical_geometry(s.q_true[s.t >= 1.0], est.q[s.t >= 1.0])[1])
        assert res['default']['rmse_deg']['total'] == pytest.approx(rms(defaults), rel=1e-9)
        assert summ['us_per_sample'] > 0
    md = lb.render_md({'leaderboard': {'cells': [cell], 'wall_s': 1.0, 'cpu_s': 1.0,
                                       'processes': 1, 'load_average': [0.1, 0.2],
                                       'grades': cells.GRADES, 'motions': cells.MOTIONS,
                                       'bias_tau_s': cells.BIAS_TAU_S},
                       'footer': {}})
    # three held-out runs cannot make a leader significant (sign test p >= 0.25)
    assert 'no covariance' in md and 'no clear leader' in md and '**(leads)**' not in md


def test_sign_test_is_the_binomial_test():
    from scipy import stats
    for k, n in ((37, 50), (30, 50), (25, 50), (0, 7), (7, 7), (3, 4)):
        assert sign_test(k, n) == pytest.approx(stats.binomtest(k, n).pvalue, rel=1e-12)
