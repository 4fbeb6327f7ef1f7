"""ahrs' Madgwick, Mahony and EKF on the node's imu and mag, as separate processes, scored.

attitude_node runs the air-bearing scene (config/air_bearing.yaml: gravity, accelerometer,
magnetometer) and records; six rigidrot_demo_estimator processes (three filters, with and
without the magnetometer) start 10 deg off the first fix; rigidrot_compare scores the bag.
Oracles: the exact truth from the run description (core, scipy rotations for the errors).
What a broken input would break: the tilt converges only if the accelerometer is the
specific force in B with N's z up (a sign or frame error leaves it tens of degrees off);
the heading converges only with the field in the right frame and the filter's Earth frame
mapped to N (a 90 deg slip shows as 90 deg).
"""

import json
import signal
import subprocess
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigidrot_ros.bag import read_bag
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.run.settings import find_config
from rigidrot_ros.scoring.score import extract_streams
from ros_helpers import next_domain_id, ros_env, script, start, stop

pytestmark = pytest.mark.ros

RUNS = [('madgwick', False), ('madgwick', True), ('mahony', False), ('mahony', True),
        ('ekf', False), ('ekf', True)]
#: After convergence (the last 40 % of the run), bounds on the error, deg: (tilt, total).
#: Measured offline on the same scene (doc/sensors.md): tilt <= 0.36, total with mag <= 1.2;
#: without mag the heading keeps the start's yaw part (10 / sqrt(3) = 5.8 deg, less what
#: the filter's tilt correction turns into it).
TILT_MAX = 1.0
MAG_TOTAL_MAX = 2.0


def _topic(kind, mag):
    return f'/{kind}{"_mag" if mag else ""}/odom'


def test_ahrs_filters_converge_where_they_can_and_are_scored(tmp_path):
    env = ros_env(next_domain_id())
    root = tmp_path / 'node'
    ests = []
    for kind, mag in RUNS:
        name = _topic(kind, mag)[:-5]
        ests.append(start([script('rigidrot_demo_estimator'), '--filter', kind,
                           '--initial-error-deg', '10'] + (['--mag'] if mag else []) +
                          ['--ros-args', '-r', f'estimator/odom:={name}/odom',
                           '-r', f'estimator/pose:={name}/pose',
                           '-r', f'estimator/attitude:={name}/attitude',
                           '-r', f'__node:={name[1:]}'], env))
    topics = [f'{_topic(k, m)}:nav_msgs/msg/Odometry' for k, m in RUNS]
    time.sleep(3.0)                             # the estimators hear the first fix
    node = start([script('attitude_node'), '--ros-args', '--params-file',
                  find_config('air_bearing.yaml'), '-p', 'record:=true',
                  '-p', f'record_path:={root}', '-p', f'record_topics:={topics}'], env)
    try:
        time.sleep(14.0)
    finally:
        errs = [stop(e, signal.SIGINT) for e in ests]
        time.sleep(0.5)
        code, _, err = stop(node, signal.SIGINT)
    assert code == 0, err
    for (kind, mag), (c, _, e) in zip(RUNS, errs):
        assert c == 0 and 'Traceback' not in e and 'initialised' in e, (kind, mag, e[-2000:])
    bag = next(root.iterdir())
    res = subprocess.run([script('rigidrot_compare'), str(bag), '--json',
                          str(tmp_path / 's.json')], env=env, capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    scores = {(t['topic'], t['field']): t
              for t in json.loads((tmp_path / 's.json').read_text())['topics']}
    contents = read_bag(str(bag))
    run = contents.runs[0]
    sol = solve(Scene.from_dict(run['scene']), tol=1e-12)
    report = {}
    for kind, mag in RUNS:
        topic = _topic(kind, mag)
        score = scores[(topic, 'orientation')]
        stream = [s for s in extract_streams(contents, [topic])[0]
                  if s.field == 'orientation'][0]
        t = (stream.stamps - int(run['start_ns'])) * 1e-9
        assert score['count'] == len(t) > 500, (topic, score['count'], len(t))
        truth = Rotation.from_quat(sol.at(t).quaternion)
        est = Rotation.from_quat(stream.values)
        total = np.degrees(np.linalg.norm((truth.inv() * est).as_rotvec(), axis=1))
        up_t, up_e = truth.inv().apply([0, 0, 1]), est.inv().apply([0, 0, 1])
        tilt = np.degrees(np.arccos(np.clip(np.sum(up_t * up_e, axis=1), -1, 1)))
        late = slice(int(0.6 * len(t)), None)
        report[topic] = (float(total[0]), float(tilt[late].max()), float(total[late].max()),
                         score.get('anees'))
        if kind != 'ekf':       # the EKF (P0 = I) corrects most of it in its first update
            assert total[0] > 5.0, (topic, total[0])        # it did start off the truth
        assert tilt[late].max() < TILT_MAX, (topic, report[topic])
        if mag:
            assert total[late].max() < MAG_TOTAL_MAX, (topic, report[topic])
        else:                                   # heading unobservable: the yaw error stays
            assert total[late].min() > 2.0, (topic, report[topic])
        if kind == 'ekf':
            assert score['nees_count'] == score['count'] and score['anees'] > 0
        else:
            assert 'anees' not in score or score['anees'] is None
    print('ahrs filters (start error, late tilt max, late total max deg, ANEES):', report)
