"""A campaign with the estimator as a ROS program: rigidrot_mekf fed by rigidrot_replay.

Oracle: the same runs in process (the same filter class, no DDS), step by step; and a
command that crashes is recorded as a failed run with its reason.
"""

import json
import os
import sys

import pytest

from rigidrot_ros.campaign.engine import run_campaign
from rigidrot_ros.campaign.spec import load_spec
from ros_helpers import next_domain_id

from campaign_helpers import _write, SPEC  # noqa: I100, I201 - a helper module beside it

pytestmark = pytest.mark.ros


def test_ros_program_matches_in_process(tmp_path, monkeypatch):
    monkeypatch.setenv('PATH', os.path.dirname(sys.executable) + os.pathsep
                       + os.environ['PATH'])
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    base = next_domain_id()
    params = SPEC['estimator']['params']
    ros = dict(SPEC, runs=2, duration=3.0, estimator={
        'command': (f'rigidrot_mekf --sigma-v {params["sigma_v"]} --sigma-u '
                    f'{params["sigma_u"]} --bias-sigma {params["bias_sigma"]} '
                    f'--ros-args -p use_sim_time:=true'),
        'rate': 2.0, 'domain_base': base, 'domain_span': 1})
    rep = run_campaign(load_spec(_write(tmp_path, ros, 'ros.yaml')), str(tmp_path / 'ros'),
                       workers=1, progress=False)
    inproc = dict(SPEC, runs=2, duration=3.0)
    run_campaign(load_spec(_write(tmp_path, inproc)), str(tmp_path / 'in'), workers=1,
                 progress=False)
    assert rep['runs_ok'] == 2, rep['failed']
    for i in range(2):
        a = json.loads((tmp_path / 'ros' / 'runs' / f'{i:06d}.json').read_text())['series']
        b = json.loads((tmp_path / 'in' / 'runs' / f'{i:06d}.json').read_text())['series']
        da, db = dict(zip(a['t_ns'], a['nees'])), dict(zip(b['t_ns'], b['nees']))
        # every estimate but possibly the last (the replay may exit before DDS delivers
        # its final gyro samples)
        assert set(da) <= set(db) and len(da) >= len(db) - 1 > 20
        for k in da:
            assert abs(da[k] - db[k]) <= 1e-9 * max(1.0, db[k])
    crash = dict(ros, runs=1, estimator=dict(ros['estimator'], command=(
        f'{sys.executable} -c "import sys, time; time.sleep(0.5); sys.exit(3)"')))
    rep = run_campaign(load_spec(_write(tmp_path, crash, 'crash.yaml')),
                       str(tmp_path / 'crash'), workers=1, progress=False)
    assert rep['runs_failed'] == 1 and 'status 3' in rep['failed'][0]['reason'], rep
