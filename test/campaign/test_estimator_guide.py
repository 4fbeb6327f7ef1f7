"""The guide "Your own estimator": its quoted files, its skeletons as campaigns, the helps.

The page quotes each file of doc/estimator/ whole, after a ``<!-- file: PATH -->`` line;
the Python skeleton and the ROS 2 skeleton (long-lived, reset between runs) each run a
small campaign from their shipped specs, and, being the same filter on the same runs,
agree step by step (oracle: each other, through two different transports: function calls
and DDS); every shipped filter's ``--help`` names the topics it takes and publishes.
"""

import os
from pathlib import Path
import re
import subprocess
import sys

import pytest
import yaml

from rigidrot_ros.campaign.engine import run_campaign
from rigidrot_ros.campaign.spec import load_spec
from ros_helpers import next_domain_id, script

ROOT = Path(__file__).resolve().parents[2]
GUIDE = ROOT / 'doc' / 'estimator.md'
FILES = ROOT / 'doc' / 'estimator'
_QUOTE = re.compile(r'^<!-- file: (\S+) -->\n```[a-z]*\n(.*?)^```$', re.M | re.S)


def test_the_page_quotes_every_skeleton_file_exactly():
    quoted = dict(_QUOTE.findall(GUIDE.read_text(encoding='utf-8')))
    shipped = sorted(f'doc/estimator/{p.name}' for p in FILES.iterdir() if p.is_file())
    assert sorted(quoted) == shipped
    for path, text in quoted.items():
        assert text == (ROOT / path).read_text(encoding='utf-8'), f'{path} differs from the page'


def _small(name, tmp_path, **estimator):
    doc = yaml.safe_load((FILES / name).read_text(encoding='utf-8'))
    doc.update(runs=2, duration=3.0, timeout=120)
    doc['estimator'].update(estimator)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc), encoding='utf-8')
    out = tmp_path / name.replace('.yaml', '')
    report = run_campaign(load_spec(str(path)), str(out), workers=1, progress=False)
    return report, out


@pytest.mark.ros
def test_both_skeletons_run_as_campaigns_and_agree_step_by_step(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(FILES))            # skeleton:make, in the pool too
    monkeypatch.setenv('PYTHONPATH', os.pathsep.join([str(FILES)] + sys.path))
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    py, py_out = _small('skeleton.yaml', tmp_path)
    node = yaml.safe_load((FILES / 'skeleton_node.yaml').read_text())['estimator']['command']
    command = node.replace('python3 doc/estimator/skeleton_node.py',
                           f'{sys.executable} {FILES / "skeleton_node.py"}')
    ros, ros_out = _small('skeleton_node.yaml', tmp_path, command=command,
                          domain_base=next_domain_id(), domain_span=1)
    assert py['runs_ok'] == ros['runs_ok'] == 2, (py['failed'], ros['failed'])
    for i in range(2):
        a = yaml.safe_load((py_out / 'runs' / f'{i:06d}.json').read_text())['series']
        b = yaml.safe_load((ros_out / 'runs' / f'{i:06d}.json').read_text())['series']
        assert a['t_ns'] == b['t_ns'] and len(a['t_ns']) == 299      # every gyro stamp
        for x, y in zip(a['nees'], b['nees']):
            assert abs(x - y) <= 1e-9 * max(1.0, y)


@pytest.mark.parametrize('prog, names', [
    ('rigidrot_mekf', ['imu', 'sensor_msgs/msg/Imu', 'star_tracker',
                       'geometry_msgs/msg/PoseWithCovarianceStamped', 'estimator/odom',
                       'nav_msgs/msg/Odometry', '~/reset', 'std_srvs/srv/Trigger']),
    ('rigidrot_demo_estimator', ['attitude', 'geometry_msgs/msg/QuaternionStamped', 'imu',
                                 'sensor_msgs/msg/Imu', 'mag',
                                 'sensor_msgs/msg/MagneticField', 'estimator/odom',
                                 'nav_msgs/msg/Odometry', 'estimator/pose',
                                 'geometry_msgs/msg/PoseWithCovarianceStamped',
                                 'estimator/attitude']),
])
def test_every_shipped_filter_help_lists_its_topics(prog, names):
    out = subprocess.run([script(prog), '--help'], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    subscribes = out.stdout[out.stdout.index('subscribes'):]
    for name in names:
        assert re.search(rf'(^|\s){re.escape(name)}(\s|:|$)', subscribes, re.M), \
            f'{prog} --help does not name {name}'


def test_the_api_reference_documents_campaigns_and_estimators():
    sys.path.insert(0, str(ROOT / 'doc'))
    try:
        import conf
    finally:
        sys.path.remove(str(ROOT / 'doc'))
    names = conf.api_modules()
    for mod in ('rigidrot_ros.campaign.spec', 'rigidrot_ros.campaign.session',
                'rigidrot_ros.campaign.inproc', 'rigidrot_ros.estimators.mekf',
                'rigidrot_ros.estimators.mekf_node'):
        assert mod in names
