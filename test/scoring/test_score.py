"""Scoring every supported message type, NEES/ANEES, and bag files, on synthetic bags.

Bags are written with the project's writer and checked with readers and maths we did not
write: rosbags (deserialisation), scipy's Rotation (the error rotation vector) and
scipy's chi-square quantiles (the ANEES bounds).
"""

import csv
import json
import os
from pathlib import Path
import shutil
import subprocess
import sys

import numpy as np
from numpy.testing import assert_allclose
import pytest
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from scipy.spatial.transform import Rotation
from scipy.stats import chi2
from std_msgs.msg import String
import yaml

from rigidrot_ros.bag import BagError, BagWriter, read_bag
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.scoring.score import (
    anees_bounds, extract_streams, score_against_runs, score_against_stream, ScoreError,
)
from rigidrot_ros.tools import compare
from score_helpers import _make, _run_msg, _truth, _write_bag, RATE, SCENE, START


AXIS = np.array([0.6, 0.0, 0.8])
OFFSET = np.array([1e-3, -2e-3, 5e-4])
KINDS = ['QuaternionStamped', 'PoseStamped', 'PoseWithCovarianceStamped', 'TransformStamped',
         'Odometry', 'Imu']


def test_every_type_scores_a_known_error(tmp_path):
    n = 200
    _, stamps, q_true, w_true = _truth(n)
    d = Rotation.from_rotvec(0.01 * AXIS)
    q_est = (Rotation.from_quat(q_true) * d).as_quat()     # q_true ⊗ exp(e/2), e = 0.01 a
    topics = {f'/est/{k.lower()}': (_type(k), lambda i, k=k: _make(
        k, stamps[i], q_est[i], w_true[i] + OFFSET, np.eye(3) * 1e-4)) for k in KINDS}
    topics['/est/rate'] = ('geometry_msgs/msg/Vector3Stamped',
                           lambda i: _make('Vector3Stamped', stamps[i], None, w_true[i] + OFFSET))
    bag = _write_bag(tmp_path, topics, n=n)
    # the independent reader sees what was written, field by field
    with AnyReader([bag]) as reader:
        seen = {c.topic: c.msgcount for c in reader.connections}
        for conn, _, raw in reader.messages():
            if conn.topic == '/est/odometry':
                m = reader.deserialize(raw, conn.msgtype)
                k = int(np.nonzero(stamps == m.header.stamp.sec * 10**9
                                   + m.header.stamp.nanosec)[0][0])
                o = m.pose.pose.orientation
                assert [o.x, o.y, o.z, o.w] == [float(v) for v in q_est[k]]
                assert list(m.pose.covariance[21:24]) == [1e-4, 0.0, 0.0]
    assert all(seen[t] == n for t in topics)
    contents = read_bag(str(bag))
    assert len(contents.runs) == 1 and contents.runs[0]['start_ns'] == START
    streams, skipped = extract_streams(contents)
    assert skipped == [{'topic': '/attitude_node/run', 'type': 'std_msgs/msg/String',
                        'reason': 'run description (used as the truth, not scored)'}]
    res = {(r['topic'], r['field']): r for r in score_against_runs(contents, streams)}
    for k in KINDS:
        r = res[(f'/est/{k.lower()}', 'orientation')]
        assert r['count'] == n
        assert_allclose([r['max'], r['rms'], r['p95']], 0.01, rtol=0, atol=1e-12)
        if 'Covariance' in k or k in ('Odometry', 'Imu'):
            # e = 0.01 AXIS exactly, P = 1e-4 I: NEES = 1 at every sample
            assert_allclose(r['anees'], 1.0, rtol=1e-8)
        else:
            assert 'anees' not in r
    for t in ('/est/rate', '/est/odometry', '/est/imu'):
        r = res[(t, 'angular_velocity')]
        assert r['count'] == n
        assert_allclose(r['max'], np.linalg.norm(OFFSET), rtol=1e-12)


def _type(kind):
    pkg = {'Odometry': 'nav_msgs', 'Imu': 'sensor_msgs'}.get(kind, 'geometry_msgs')
    return f'{pkg}/msg/{kind}'


def test_anees_bounds_match_chi_square():
    for m in (1, 7, 50, 100, 2000):
        lo, hi = anees_bounds(m)
        assert_allclose([lo, hi], np.array(chi2.ppf([0.025, 0.975], 3 * m)) / m, rtol=1e-9)
    assert_allclose(anees_bounds(1), [0.216, 9.348], atol=1e-3)   # ESTIMATOR-NOTES


def test_anees_bounds_of_long_runs():
    """Past about 4900 samples mpmath's lower incomplete gamma did not converge."""
    for m in (4900, 5000, 100_000, 1_000_000):
        lo, hi = anees_bounds(m)
        assert_allclose([lo, hi], np.array(chi2.ppf([0.025, 0.975], 3 * m)) / m, rtol=1e-9)


@pytest.mark.parametrize('frame', ['body', 'inertial'])
def test_nees_consistent_inside_overconfident_outside(tmp_path, frame):
    n = 400
    rng = np.random.default_rng(9)
    _, stamps, q_true, w_true = _truth(n)
    a = rng.normal(size=(3, 3))
    p = a @ a.T * 1e-6 + np.diag([4e-6, 1e-6, 9e-6])       # anisotropic, correlated
    e = rng.multivariate_normal(np.zeros(3), p, size=n)
    r_true = Rotation.from_quat(q_true)
    if frame == 'body':
        q_est = (r_true * Rotation.from_rotvec(e)).as_quat()
    else:
        q_est = (Rotation.from_rotvec(e) * r_true).as_quat()
    topics = {
        '/good': ('geometry_msgs/msg/PoseWithCovarianceStamped',
                  lambda i: _make('PoseWithCovarianceStamped', stamps[i], q_est[i], None, p)),
        '/overconfident': ('geometry_msgs/msg/PoseWithCovarianceStamped',
                           lambda i: _make('PoseWithCovarianceStamped', stamps[i], q_est[i],
                                           None, p / 4)),
    }
    bag = _write_bag(tmp_path, topics, n=n)
    out = tmp_path / 'n.json'
    csv_path = tmp_path / 'n.csv'
    assert compare.main([str(bag), '--json', str(out), '--csv', str(csv_path),
                         '--cov-frame', frame]) == 0
    res = {t['topic']: t for t in json.loads(out.read_text())['topics']}
    good, over = res['/good'], res['/overconfident']
    for r in (good, over):
        assert {'topic', 'type', 'count', 'max', 'rms', 'p95', 'anees',
                'anees_bounds_95'} <= set(r)
        assert r['count'] == r['nees_count'] == n
    lo, hi = good['anees_bounds_95']
    assert_allclose([lo, hi], chi2.ppf([0.025, 0.975], 3 * n) / n, rtol=1e-9)
    assert lo <= good['anees'] <= hi
    assert over['anees'] > hi and abs(over['anees'] - 4 * good['anees']) < 1e-6 * good['anees']
    # per-sample NEES from the CSV against scipy's rotation vectors
    rows = [row for row in csv.DictReader(csv_path.open()) if row['topic'] == '/good']
    assert len(rows) == n
    err = (r_true.inv() * Rotation.from_quat(q_est)).as_rotvec()
    if frame == 'inertial':
        err = r_true.apply(err)
    ref = np.einsum('ni,ij,nj->n', err, np.linalg.inv(p), err)
    assert_allclose([float(r['nees']) for r in rows], ref, rtol=1e-6)
    assert_allclose([float(r['error']) for r in rows], np.linalg.norm(err, axis=1),
                    rtol=1e-9, atol=1e-15)


def test_covariance_markers_follow_the_message_definitions(tmp_path):
    n = 50
    _, stamps, q_true, w_true = _truth(n)
    nan = np.full((3, 3), np.nan)
    not_pd = np.diag([1e-4, -1e-4, 1e-4])
    none = np.zeros((3, 3))
    none[0, 0] = -1.0

    def imu(cov):
        return lambda i: _make('Imu', stamps[i], q_true[i], w_true[i], cov)
    bag = _write_bag(tmp_path, {
        '/imu_gyro_only': ('sensor_msgs/msg/Imu', imu(none)),
        '/imu_unknown': ('sensor_msgs/msg/Imu', imu(np.zeros((3, 3)))),
        '/imu_nan': ('sensor_msgs/msg/Imu', imu(nan)),
        '/imu_not_pd': ('sensor_msgs/msg/Imu', imu(not_pd)),
        '/estimator/delta_angle': ('geometry_msgs/msg/Vector3Stamped',
                                   lambda i: _make('Vector3Stamped', stamps[i], None, OFFSET)),
        '/chatter': ('std_msgs/msg/String', None),
    }, n=0)
    # n=0 wrote no messages; add them by hand (String has no header)
    w = BagWriter(None, '', path=str(tmp_path / 'markers'))
    c = read_bag(str(bag))
    for t, (ty, _, text) in c.topics.items():
        w.add_topic(t, ty, schema=text)
    w.write('/attitude_node/run', serialize_message(_run_msg()), START)
    w.write('/chatter', serialize_message(String(data='hello')), START)
    for k in range(n):
        for t, cov in (('/imu_gyro_only', none), ('/imu_unknown', np.zeros((3, 3))),
                       ('/imu_nan', nan), ('/imu_not_pd', not_pd)):
            w.write(t, serialize_message(_make('Imu', stamps[k], q_true[k], w_true[k], cov)),
                    stamps[k])
        w.write('/estimator/delta_angle',
                serialize_message(_make('Vector3Stamped', stamps[k], None, OFFSET)), stamps[k])
    w.close()
    contents = read_bag(w.path)
    streams, skipped = extract_streams(contents)
    by = {(s.topic, s.field): s for s in streams}
    assert ('/imu_gyro_only', 'orientation') not in by          # -1: no estimate
    assert ('/imu_gyro_only', 'angular_velocity') in by
    assert by[('/imu_unknown', 'orientation')].cov is None       # all zero: unknown
    assert by[('/imu_unknown', 'orientation')].cov_unknown == n
    assert by[('/imu_nan', 'orientation')].cov_unusable == n
    assert by[('/imu_not_pd', 'orientation')].cov_unusable == n
    reasons = {s['topic']: s['reason'] for s in skipped}
    assert 'not a rate' in reasons['/estimator/delta_angle']
    assert 'carries no attitude' in reasons['/chatter']
    res = {(r['topic'], r['field']): r for r in score_against_runs(contents, streams)}
    assert res[('/imu_unknown', 'orientation')]['max'] <= 1e-15
    assert 'anees' not in res[('/imu_unknown', 'orientation')]
    assert res[('/imu_nan', 'orientation')]['nees_count'] == 0
    # the table lists what it did not score, with the reason
    out = subprocess.run([sys.executable, '-m', 'rigidrot_ros.tools.compare', w.path],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert 'not scored: an increment' in out.stdout and 'no usable covariance' in out.stdout


def test_plot_shows_estimators_with_their_band(tmp_path):
    n = 300
    rng = np.random.default_rng(3)
    _, stamps, q_true, w_true = _truth(n)
    p = np.diag([1e-6, 4e-6, 2e-6])
    e = rng.multivariate_normal(np.zeros(3), p, size=n)
    q_est = (Rotation.from_quat(q_true) * Rotation.from_rotvec(e)).as_quat()
    bag = _write_bag(tmp_path, {
        '/attitude': ('geometry_msgs/msg/QuaternionStamped',
                      lambda i: _make('QuaternionStamped', stamps[i], q_true[i], None)),
        '/estimator/odom': ('nav_msgs/msg/Odometry',
                            lambda i: _make('Odometry', stamps[i], q_est[i], w_true[i], p)),
    }, n=n)
    for scale in ('log', 'linear'):
        png = tmp_path / f'p_{scale}.png'
        assert compare.main([str(bag), '--plot', str(png), '--yscale', scale]) == 0
        assert png.stat().st_size > 20000
    # the truth alone is plotted only when asked
    only = _write_bag(tmp_path, {'/attitude': ('geometry_msgs/msg/QuaternionStamped',
                                               lambda i: _make('QuaternionStamped', stamps[i],
                                                               q_true[i], None))}, n=20,
                      name='truth')
    assert compare.main([str(only), '--plot', str(tmp_path / 't.png')]) == 2
    assert compare.main([str(only), '--plot', str(tmp_path / 't.png'), '--plot-truth']) == 0


def test_plot_without_matplotlib_names_the_install(tmp_path):
    code = ('import sys; sys.modules["matplotlib"] = None\n'
            'from rigidrot_ros.tools.compare import main\n'
            f'sys.exit(main([{str(tmp_path)!r}, "--plot", "x.png"]))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and 'pip install matplotlib' in lines[0]


# -- bag files ------------------------------------------------------------------------------
def _simple_bag(tmp_path, name, start, n):
    w = BagWriter(str(tmp_path / 'parts'), name)
    w.add_topic('/attitude_node/run', 'std_msgs/msg/String')
    w.add_topic('/attitude', 'geometry_msgs/msg/QuaternionStamped')
    if start == START:
        w.write('/attitude_node/run', serialize_message(_run_msg()), START)
    _, stamps, q, _ = _truth(start // 10**7 - START // 10**7 + n)
    for k in range(len(stamps) - n, len(stamps)):
        w.write('/attitude', serialize_message(_make('QuaternionStamped', stamps[k], q[k],
                                                     None)), stamps[k])
    w.close()
    return Path(w.path)


def test_split_bag_is_read_whole_and_bad_metadata_is_refused(tmp_path):
    a = _simple_bag(tmp_path, 'a', START, 100)
    b = _simple_bag(tmp_path, 'b', START + 10**9, 100)
    split = tmp_path / 'split'
    split.mkdir()
    files = ['split_0.mcap', 'split_1.mcap']
    os.replace(next(a.glob('*.mcap')), split / files[0])
    os.replace(next(b.glob('*.mcap')), split / files[1])
    meta = yaml.safe_load((a / 'metadata.yaml').read_text())
    meta['rosbag2_bagfile_information']['relative_file_paths'] = files
    (split / 'metadata.yaml').write_text(yaml.safe_dump(meta))
    c = read_bag(str(split))
    assert c.files == [str(split / f) for f in files]
    stamps = [m[2] for m in c.messages if m[0] == '/attitude']
    assert len(stamps) == 200 and stamps == sorted(stamps)
    res = score_against_runs(c, extract_streams(c)[0])
    assert res[0]['count'] == 200 and res[0]['max'] < 1e-12
    # metadata.yaml listing a file that is not there; a file it does not list; garbage
    meta['rosbag2_bagfile_information']['relative_file_paths'] = files + ['split_2.mcap']
    (split / 'metadata.yaml').write_text(yaml.safe_dump(meta))
    with pytest.raises(BagError, match='split_2.mcap'):
        read_bag(str(split))
    meta['rosbag2_bagfile_information']['relative_file_paths'] = files[:1]
    (split / 'metadata.yaml').write_text(yaml.safe_dump(meta))
    with pytest.raises(BagError, match='does not list'):
        read_bag(str(split))
    for garbage in ('{{{ not yaml', 'just a string', 'rosbag2_bagfile_information: 3'):
        (split / 'metadata.yaml').write_text(garbage)
        with pytest.raises(BagError, match='not a valid rosbag2 metadata file'):
            read_bag(str(split))
    # without metadata.yaml the files are read in their index order
    os.remove(split / 'metadata.yaml')
    assert len(read_bag(str(split)).messages) == 201


def test_writer_memory_is_bounded_and_split_bags_read_whole(tmp_path):
    """Chunk indexes are kept packed, and a long recording splits into files."""
    import tracemalloc
    w = BagWriter(str(tmp_path), 'mem', flush_period=1e9, split_seconds=0)
    topics = [f'/t{i}' for i in range(10)]
    for t in topics:
        w.add_topic(t, 'std_msgs/msg/String')
    data = serialize_message(String(data='hello'))

    def chunks(n, k0):
        for k in range(k0, k0 + n):
            for t in topics:
                w.write(t, data, START + k)
            w.flush()
    chunks(200, 0)
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    chunks(2000, 200)
    grown = sum(s.size_diff for s in tracemalloc.take_snapshot().compare_to(before,
                                                                            'filename'))
    tracemalloc.stop()
    assert grown / 2000 < 300, grown / 2000           # bytes per chunk, 10 channels
    w.close()
    with AnyReader([Path(w.path)]) as reader:
        assert sum(c.msgcount for c in reader.connections) == 22000
    # split: a new file at each flush; rosbags and read_bag read them all, in order
    w = BagWriter(str(tmp_path), 'split', flush_period=1e9, split_seconds=1e-9)
    w.add_topic('/a', 'std_msgs/msg/String')
    w.add_topic('/attitude_node/run', 'std_msgs/msg/String')
    w.write('/attitude_node/run', serialize_message(_run_msg()), START)
    for k in range(6):
        w.write('/a', serialize_message(String(data=f'{k}')), START + k + 1)
        w.flush()
    w.close()
    files = sorted(Path(w.path).glob('*.mcap'))
    assert len(files) == 6
    meta = yaml.safe_load((Path(w.path) / 'metadata.yaml').read_text())
    info = meta['rosbag2_bagfile_information']
    assert info['message_count'] == 7 and len(info['relative_file_paths']) == 6
    assert sum(f['message_count'] for f in info['files']) == 7
    with AnyReader([Path(w.path)]) as reader:
        got = [reader.deserialize(d, c.msgtype).data for c, _, d in reader.messages()
               if c.topic == '/a']
    assert got == [f'{k}' for k in range(6)]
    c = read_bag(w.path)
    assert [m[2] for m in c.messages] == sorted(m[2] for m in c.messages)
    assert len(c.messages) == 7 and len(c.runs) == 1


def test_two_nodes_in_one_bag_each_topic_scored_against_its_own(tmp_path):
    """Namespaced nodes: a topic goes with the node that publishes it or owns its namespace."""
    other = Scene(inertia=(3.0, 3.0, 3.0), torque=(0.1, 0.0, 0.0), omega0=(0.0, 1.0, 0.0),
                  attitude0=(0.0, 0.0, 0.0, 1.0))
    n = 100
    t = np.arange(n) / RATE
    stamps = START + np.round(t * 1e9).astype(np.int64)
    q1 = solve(SCENE, tol=1e-12).at(t).quaternion
    q2 = solve(other, tol=1e-12).at(t).quaternion
    q1_est = (Rotation.from_quat(q1) * Rotation.from_rotvec(0.01 * AXIS)).as_quat()
    w = BagWriter(str(tmp_path), 'two')
    for ns, scene in (('/sat1', SCENE), ('/sat2', other)):
        info = json.loads(_run_msg().data)
        info.update(node=f'{ns}/attitude_node', scene=scene.as_dict(),
                    topics={f'{ns}/attitude': 'geometry_msgs/msg/QuaternionStamped'})
        w.add_topic(f'{ns}/attitude_node/run', 'std_msgs/msg/String')
        w.write(f'{ns}/attitude_node/run', serialize_message(String(data=json.dumps(info))),
                START)
    for topic in ('/sat1/attitude', '/sat2/attitude', '/sat1/estimator/attitude',
                  '/estimator/attitude'):
        w.add_topic(topic, 'geometry_msgs/msg/QuaternionStamped')
    for k in range(n):
        for topic, q in (('/sat1/attitude', q1), ('/sat2/attitude', q2),
                         ('/sat1/estimator/attitude', q1_est), ('/estimator/attitude', q1_est)):
            w.write(topic, serialize_message(_make('QuaternionStamped', stamps[k], q[k], None)),
                    stamps[k])
    w.close()
    c = read_bag(w.path)
    res = {r['topic']: r for r in score_against_runs(c, extract_streams(c)[0])}
    assert res['/sat1/attitude']['max'] < 1e-12 and res['/sat2/attitude']['max'] < 1e-12
    assert abs(res['/sat1/estimator/attitude']['max'] - 0.01) < 1e-12
    assert res['/estimator/attitude']['count'] == 0
    assert 'cannot tell which one is the truth' in res['/estimator/attitude']['reason']


@pytest.mark.parametrize('frame', ['body', 'inertial'])
def test_truth_from_a_second_log_gives_the_same_nees(tmp_path, frame):
    """--truth OTHER_BAG: the node's logged attitude as truth, NEES as against the exact."""
    n = 300
    rng = np.random.default_rng(5)
    _, stamps, q_true, _ = _truth(n)
    p = np.diag([2e-6, 1e-6, 3e-6])
    e = rng.multivariate_normal(np.zeros(3), p, size=n)
    r_true = Rotation.from_quat(q_true)
    r_err = Rotation.from_rotvec(e)
    q_est = (r_true * r_err if frame == 'body' else r_err * r_true).as_quat()
    est = _write_bag(tmp_path, {'/est': ('geometry_msgs/msg/PoseWithCovarianceStamped',
                                         lambda i: _make('PoseWithCovarianceStamped',
                                                         stamps[i], q_est[i], None, p))},
                     n=n, name='est')
    truth = _write_bag(tmp_path, {'/attitude': ('geometry_msgs/msg/QuaternionStamped',
                                                lambda i: _make('QuaternionStamped', stamps[i],
                                                                q_true[i], None))},
                       n=n, name='truth')
    a, b = tmp_path / 'a.json', tmp_path / 'b.json'
    assert compare.main([str(est), '--json', str(a), '--cov-frame', frame]) == 0
    assert compare.main([str(est), '--truth', str(truth), '--json', str(b),
                         '--cov-frame', frame]) == 0
    exact = json.loads(a.read_text())['topics'][0]
    logged = json.loads(b.read_text())['topics'][0]
    assert logged['count'] == exact['count'] == n
    assert_allclose(logged['anees'], exact['anees'], rtol=1e-9)
    assert_allclose(logged['max'], exact['max'], rtol=1e-9)
    # the same NEES as scipy's rotation vectors in the frame asked for
    ref = np.einsum('ni,ij,nj->n', e, np.linalg.inv(p), e).mean()
    assert_allclose(logged['anees'], ref, rtol=1e-6)


def test_truth_log_reference_is_a_truth_topic_and_gaps_are_skipped(tmp_path):
    """--truth: never a noisy sensor topic as the reference; no slerp across a gap."""
    n = 300
    _, stamps, q_true, _ = _truth(n)
    noisy = (Rotation.from_quat(q_true) * Rotation.from_rotvec(
        np.random.default_rng(2).normal(scale=1e-3, size=(n, 3)))).as_quat()
    q_est = (Rotation.from_quat(q_true) * Rotation.from_rotvec(0.01 * AXIS)).as_quat()

    def pose(q):
        return ('geometry_msgs/msg/PoseWithCovarianceStamped',
                lambda i: _make('PoseWithCovarianceStamped', stamps[i], q[i], None,
                                np.eye(3) * 1e-4))
    # the estimator bag carries a star_tracker topic too, as a node with sensors records it
    est = _write_bag(tmp_path, {'/star_tracker': pose(q_est)}, n=n, name='est')
    truth = _write_bag(tmp_path, {
        '/attitude': ('geometry_msgs/msg/QuaternionStamped',
                      lambda i: _make('QuaternionStamped', stamps[i], q_true[i], None)),
        '/star_tracker': pose(noisy), '/estimator/odom': pose(noisy)}, n=n, name='truth')
    out = tmp_path / 'r.json'
    assert compare.main([str(est), '--truth', str(truth), '--json', str(out)]) == 0
    r = json.loads(out.read_text())['topics'][0]
    assert r['truth_topic'] == '/attitude' and r['count'] == n
    assert_allclose(r['max'], 0.01, rtol=0, atol=1e-9)
    # nor another estimator's odom of the same name, when the runs name the node's topics
    est2 = _write_bag(tmp_path, {'/estimator/odom': pose(q_est)}, n=n, name='est2')
    c, t = read_bag(str(est2)), read_bag(str(truth))
    r = score_against_stream(c, extract_streams(c)[0], t, extract_streams(t)[0])[0]
    assert r['truth_topic'] == '/attitude'
    assert_allclose(r['max'], 0.01, rtol=0, atol=1e-9)
    # only sensor topics in the truth log: refused, with the reason
    sensors = _write_bag(tmp_path, {'/star_tracker': pose(noisy)}, n=n, name='sensors')
    with pytest.raises(ScoreError, match='not used as the truth'):
        c, t = read_bag(str(est)), read_bag(str(sensors))
        score_against_stream(c, extract_streams(c)[0], t, extract_streams(t)[0])
    # a truth log that misses 0.5 s (samples 100..149): the messages inside are skipped
    kept = np.r_[0:100, 150:n]
    gap = _write_bag(tmp_path, {'/attitude': (
        'geometry_msgs/msg/QuaternionStamped',
        lambda i: _make('QuaternionStamped', stamps[kept[i]], q_true[kept[i]], None))},
        n=len(kept), name='gap')
    c, t = read_bag(str(est)), read_bag(str(gap))
    r = score_against_stream(c, extract_streams(c)[0], t, extract_streams(t)[0])[0]
    assert r['truth_gaps'] == 50 and r['count'] == n - 50
    assert_allclose(r['max'], 0.01, rtol=0, atol=1e-9)
    lines = compare._table([r], [])
    assert '50 message(s) inside gaps of the truth log (/attitude) not scored' in lines


def test_reindex_a_torn_split_bag(tmp_path):
    """A split bag whose last file was cut off (the writer killed) is finished whole."""
    from rigidrot_ros.bag import reindex
    w = BagWriter(str(tmp_path), 'torn', flush_period=1e9, split_seconds=1e-9)
    w.add_topic('/attitude_node/run', 'std_msgs/msg/String')
    w.add_topic('/a', 'std_msgs/msg/String')
    w.write('/attitude_node/run', serialize_message(_run_msg()), START)
    for k in range(5):
        w.write('/a', serialize_message(String(data=f'{k}')), START + k + 1)
        w.flush()
    torn = tmp_path / 'copy'
    shutil.copytree(w.path, torn)                 # as a SIGKILL would leave it
    w.close()
    files = sorted(torn.glob('*.mcap'))
    assert len(files) == 5
    with pytest.raises(Exception):
        with AnyReader([torn]) as reader:
            list(reader.messages())
    out = reindex(str(torn))
    assert [os.path.basename(f) for f in out['rewritten']] == [files[-1].name]
    with AnyReader([torn]) as reader:
        got = [reader.deserialize(d, c.msgtype).data for c, _, d in reader.messages()
               if c.topic == '/a']
    assert got == [f'{k}' for k in range(5)]
    info = yaml.safe_load((torn / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['message_count'] == 6 and len(info['files']) == 5


def test_a_channel_without_schema_is_skipped_with_a_note(tmp_path):
    """Schema id 0 is legal MCAP: read, compare and reindex skip that channel and say so."""
    from mcap.writer import Writer
    from rigidrot_ros.bag import reindex
    from rigidrot_ros.msgs.msgdefs import schema_text
    n = 50
    _, stamps, q, _ = _truth(n)
    path = tmp_path / 'mixed.mcap'
    with open(path, 'wb') as fh:
        w = Writer(fh, use_chunking=False)
        w.start(profile='ros2', library='test')
        ids = {}
        for topic, ty in (('/attitude_node/run', 'std_msgs/msg/String'),
                          ('/attitude', 'geometry_msgs/msg/QuaternionStamped')):
            sid = w.register_schema(name=ty, encoding='ros2msg',
                                    data=schema_text(ty).encode())
            ids[topic] = w.register_channel(topic=topic, message_encoding='cdr',
                                            schema_id=sid)
        raw = w.register_channel(topic='/j', message_encoding='json', schema_id=0)
        w.add_message(ids['/attitude_node/run'], START, serialize_message(_run_msg()), START)
        for k in range(n):
            w.add_message(ids['/attitude'], int(stamps[k]), serialize_message(
                _make('QuaternionStamped', stamps[k], q[k], None)), int(stamps[k]))
            w.add_message(raw, int(stamps[k]), b'{"k": 1}', int(stamps[k]))
        w.finish()
    torn = tmp_path / 'torn.mcap'
    torn.write_bytes(path.read_bytes()[:-40])          # the footer cut off
    for p in (path, torn):
        c = read_bag(str(p))
        assert c.schemaless == ['/j'] and '/j' not in c.topics
        assert "channel(s) ['/j'] have no schema" in c.note
        assert sum(m[0] == '/attitude' for m in c.messages) == n
        out = subprocess.run([sys.executable, '-m', 'rigidrot_ros.tools.compare', str(p)],
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0 and 'Traceback' not in out.stderr, out.stderr
        assert 'have no schema' in out.stderr
    assert 'unfinished file' in read_bag(str(torn)).note
    assert reindex(str(path))['rewritten'] == []
    done = reindex(str(torn))
    assert done['rewritten'] == [str(torn)] and done['counts']['/attitude'] == n
    assert any('have no schema' in note for note in done['notes'])


def test_reindex_never_merges_a_foreign_mcap(tmp_path):
    """An unlisted .mcap in a bag directory is another bag's, not part of this one."""
    from rigidrot_ros.bag import reindex
    bag = _simple_bag(tmp_path, 'own', START, 30)
    other = _simple_bag(tmp_path, 'other', START, 20)
    shutil.copy(next(other.glob('*.mcap')), bag / 'other.mcap')
    meta = (bag / 'metadata.yaml').read_text()
    with pytest.raises(BagError, match=r"\['other.mcap'\], which metadata.yaml does not"):
        reindex(str(bag))
    assert (bag / 'metadata.yaml').read_text() == meta
    # metadata.yaml unreadable: only <dir>_<n>.mcap is the bag; the stranger is left alone
    (bag / 'metadata.yaml').write_text('{{{ not yaml')
    out = reindex(str(bag))
    assert [os.path.basename(f) for f in out['files']] == [f'{bag.name}_0.mcap']
    assert out['counts'] == {'/attitude_node/run': 1, '/attitude': 30}
    assert any("['other.mcap']: not named" in n for n in out['notes'])
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['relative_file_paths'] == [f'{bag.name}_0.mcap']
    assert (bag / 'metadata.yaml.orig').read_text() == '{{{ not yaml'
    # no file of the bag's own name: refused, nothing renamed or rebuilt
    os.rename(bag / f'{bag.name}_0.mcap', bag / 'renamed.mcap')
    os.remove(bag / 'metadata.yaml')
    with pytest.raises(BagError, match='no file named'):
        reindex(str(bag))
    assert not (bag / 'metadata.yaml').exists()


def _timed_score(tmp_path, name, timing):
    """Score a generated run of ideal sensors with the given timing parameters."""
    from rigidrot_ros.run.generate import generate_bag
    values = {'imu.enable': True, 'imu.rate': 100.0, 'imu.gyro_noise_density': 0.0,
              'imu.gyro_random_walk': 0.0, 'star_tracker.enable': True,
              'star_tracker.cross_boresight_arcsec': 0.0,
              'star_tracker.about_boresight_arcsec': 0.0, 'omega0': [0.3, -0.2, 0.5]}
    values.update(timing)
    c = read_bag(generate_bag(values, 4.0, tmp_path / name, start_ns=START))
    return {r['topic']: r for r in score_against_runs(c, extract_streams(c)[0])}


def test_sensor_clock_offset_is_removed_and_jitter_is_named(tmp_path):
    """sensor_timing of ~/run: an offset stamp is scored at its true time (the errors of
    the run without the offset, sample for sample, also for a sample stamped before the
    run's start); jittered stamps are scored at the stamp, and the result says so."""
    plain = _timed_score(tmp_path, 'plain', {})
    offset = _timed_score(tmp_path, 'offset', {'imu.clock_offset': 0.5,
                                               'star_tracker.clock_offset': -0.3})
    for topic in ('/star_tracker', '/imu'):
        assert 'timing' not in plain[topic]
        assert offset[topic]['count'] == plain[topic]['count'] > 30
        assert_allclose(offset[topic]['t'], plain[topic]['t'], rtol=0, atol=1e-9)
        assert_allclose(offset[topic]['error'], plain[topic]['error'], rtol=0, atol=1e-12)
        assert offset[topic]['timing']['scored_at'].endswith('(the true sample time)')
    assert offset['/star_tracker']['timing']['clock_offset_s'] == -0.3
    # an ideal star tracker against the truth of the same exact solution at the same time:
    # nothing but the rounding of the published quaternion (measured 1.7e-16 rad)
    ideal = 8 * np.finfo(float).eps
    assert plain['/star_tracker']['max'] <= ideal
    # scored at the stamp, the offset would have cost |omega| * 0.3 s of attitude
    assert offset['/star_tracker']['max'] <= ideal
    jitter = _timed_score(tmp_path, 'jitter', {'star_tracker.stamp_jitter': 1e-3,
                                               'star_tracker.clock_offset': 0.1})
    star = jitter['/star_tracker']
    assert 'not recoverable' in star['timing']['scored_at']
    w = float(np.linalg.norm([0.3, -0.2, 0.5]))
    # jitter shows up as error: about sigma |omega| rad (rms of |e| of a 1-D jitter)
    assert 0.3 * 1e-3 * w < star['rms'] < 3 * 1e-3 * w
    # a sample jittered to before the run's start belongs to no run: skipped, counted
    assert star['count'] + star.get('skipped', 0) == plain['/star_tracker']['count']
    assert star['count'] >= plain['/star_tracker']['count'] - 1
