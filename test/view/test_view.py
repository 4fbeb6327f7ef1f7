"""rigidrot_view: a generated bag, a campaign and a live node, in headless Chromium and read back.

The browser is Debian's Chromium driven by Playwright (software WebGL); the assertions
are on the screenshot's pixels (the truth box and an estimate's ghost in their colours,
a line in the error plot) and on the recording read back from the saved .rrd by rerun's
own reader: entity paths, row counts, and the truth equal to the core's at the same stamps.
"""

import json
import os
import signal
import socket
import subprocess
import time

import numpy as np
from numpy.testing import assert_allclose, assert_array_equal
import pytest
import yaml

from rigidrot_ros.bag import read_bag
from rigidrot_ros.core import Scene, solve
from rigidrot_ros.scoring.decode import decode_bag
from rigidrot_ros.view.browser import green_surface, screenshot
from rigidrot_ros.view.rr_log import ESTIMATE_COLORS
from ros_helpers import check_as_typed, next_domain_id, ros_env, script, start, stop
from view_helpers import (
    colour_mask, columns_with, free_ports, generate, region,
    rrd_columns, rrd_entities, rrd_static_text, wait_line, without_run,
)

ORANGE = ESTIMATE_COLORS[0]


@pytest.fixture(scope='module')
def gen_bag(tmp_path_factory):
    """A 6 s bag of the default scene: truth 100 Hz, gyro 100 Hz, star tracker 10 Hz."""
    return generate(tmp_path_factory.mktemp('gen') / 'bag', 6.0)


def _truth_check(rrd, runs, n_expected=None):
    """The truth's float64 values in the .rrd equal the core's at its stamps."""
    t_ns, q = rrd_columns(rrd, '/body/truth', 'q_NB_xyzw')
    _, w = rrd_columns(rrd, '/body/truth', 'omega_BN_B')
    _, q32 = rrd_columns(rrd, '/body/truth', 'Transform3D:quaternion')
    assert len(t_ns) > 0
    if n_expected is not None:
        assert len(t_ns) == n_expected
    q, w, q32 = (np.array([r[0] for r in v]) for v in (q, w, q32))
    run = min(runs, key=lambda r: int(r['start_ns']))
    assert all(int(r['start_ns']) == int(run['start_ns']) for r in runs)
    stamps = t_ns + int(run['start_ns'])        # the time line counts from the run's start
    sol = solve(Scene.from_dict(run['scene']), tol=float(run.get('tol', 1e-12)),
                backend=run.get('backend'))
    ref = sol.at((stamps - int(run['start_ns'])) * 1e-9 * float(run.get('time_scale', 1.0)))
    assert_array_equal(q, ref.quaternion)
    assert_array_equal(w, ref.omega)
    assert_allclose(q32, ref.quaternion, rtol=0, atol=1.2e-7)    # drawn in float32
    return stamps


def _pixels(img):
    """Truth-box pixels, estimate-ghost pixels, and the error plot's columns with a line."""
    box = region(img, 0.0, 0.38, 0.08, 0.70)
    err = region(img, 0.60, 1.0, 0.10, 0.25)      # right of the legend
    return (int(green_surface(box).sum()), int(colour_mask(box, ORANGE, 60).sum()),
            columns_with(colour_mask(err, ORANGE, 60)))


def _ready(img):
    green, ghost, line = _pixels(img)
    return green > 1500 and ghost > 80 and line > 0.9


def test_a_generated_bag_in_headless_chromium(gen_bag, tmp_path):
    rrd = tmp_path / 'view.rrd'
    web, grpc = free_ports(2)
    proc = start([script('rigidrot_view'), gen_bag, '--save', str(rrd), '--serve',
                  '--port', str(web), '--grpc-port', str(grpc)], dict(os.environ))
    try:
        lines = wait_line(proc, 'serving the view at')
        url = lines[-1].split('serving the view at ')[1].split(' (')[0]
        assert url.startswith(f'http://127.0.0.1:{web}/')
        img, secs, refused = screenshot(url, tmp_path / 'shot.png', _ready)
    finally:
        code, _, err = stop(proc, signal.SIGINT, timeout=90)
    assert code == 0, err
    assert 'Traceback' not in err
    green, ghost, line = _pixels(img)
    print(f'page drawn in {secs:.1f} s: {green} truth-box pixels, {ghost} ghost pixels, '
          f'a line over {100 * line:.0f} % of the error plot; refused {refused}')
    assert green > 1500, 'no truth box'
    assert ghost > 80, 'no estimate ghost'
    assert line > 0.9, 'the error plot is empty'
    # the bag: what was written and what the core says
    bag = read_bag(gen_bag)
    streams = {s.label: s for s in decode_bag(bag)[0]}
    n_truth = len(streams['/attitude'].stamps)
    stamps = _truth_check(str(rrd), bag.runs, n_truth)
    assert_array_equal(stamps, np.sort(streams['/attitude'].stamps))
    rows = rrd_entities(str(rrd))
    assert rows['/body/estimate/star_tracker'] == len(streams['/star_tracker'].stamps)
    assert rows['/nees/star_tracker'] == len(streams['/star_tracker'].stamps)
    assert rows['/residual/gyro/imu_angular_velocity'] == len(
        streams['/imu [angular_velocity]'].stamps)
    assert rows['/body/truth/omega'] == n_truth


def test_a_bag_without_run_description_says_so_and_shows_the_rest(gen_bag, tmp_path):
    bag = without_run(gen_bag, tmp_path / 'norun')
    rrd = tmp_path / 'norun.rrd'
    out = subprocess.run([script('rigidrot_view'), bag, '--save', str(rrd)],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert 'Traceback' not in out.stderr
    said = [ln for ln in out.stderr.splitlines() if 'no run description' in ln]
    assert len(said) == 1 and said[0].startswith('rigidrot_view: '), out.stderr
    rows = rrd_entities(str(rrd))
    assert '/body/truth' not in rows
    assert rows['/body/estimate/star_tracker'] == 60
    assert 'no run description' in rrd_static_text(str(rrd), '/notes')


def test_a_port_in_use_is_named_exit_2(gen_bag, tmp_path):
    web, grpc = free_ports(2)
    with socket.socket() as s:
        s.bind(('', web))
        s.listen()
        out = subprocess.run([script('rigidrot_view'), gen_bag, '--port', str(web),
                              '--grpc-port', str(grpc)], capture_output=True, text=True,
                             timeout=60)
    check_as_typed(out, 'rigidrot_view', 2, [f'port {web}', 'in use', '--port'])


SPEC = {
    'name': 'view test', 'seed': 7, 'runs': 3, 'duration': 3.0,
    'base': {'overrides': {'imu.enable': True, 'star_tracker.enable': True,
                           'imu.gyro_noise_density': 1.7e-4, 'imu.gyro_random_walk': 2e-5}},
    'dispersions': {'attitude0': 'uniform', 'imu.gyro_bias': {'mean': [0, 0, 0],
                                                              'sigma': 2e-3}},
    'estimator': {'factory': 'rigidrot_ros.estimators.mekf:make',
                  'params': {'sigma_v': 1.7e-4, 'sigma_u': 2e-5, 'bias_sigma': 2e-3}},
}


def test_a_campaign_with_a_failed_run_and_a_run_opened(tmp_path):
    spec = tmp_path / 'spec.yaml'
    spec.write_text(yaml.safe_dump(SPEC))
    camp = tmp_path / 'camp'
    subprocess.run([script('rigidrot_campaign'), str(spec), '-o', str(camp), '--quiet'],
                   check=True, capture_output=True, timeout=300)
    # a failed run, as the engine writes one
    failed = camp / 'runs' / '000002.json'
    res = json.loads(failed.read_text())
    res['row'].update(status='failed', reason='the estimator crashed (test)')
    res['series'] = None
    failed.write_text(json.dumps(res))
    rrd = tmp_path / 'camp.rrd'
    out = subprocess.run([script('rigidrot_view'), str(camp), '--run', '1', '--save', str(rrd)],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert 'Traceback' not in out.stderr
    said = [ln for ln in out.stderr.splitlines() if 'left out' in ln]
    assert len(said) == 1 and 'the estimator crashed (test)' in said[0], out.stderr
    rows = rrd_entities(str(rrd))
    series = [json.loads((camp / 'runs' / f'{i:06d}.json').read_text())['series']
              for i in (0, 1)]
    common = sorted(set(series[0]['t_ns']) & set(series[1]['t_ns']))
    assert rows['/campaign/nees/mc'] == len(common)
    t_mc, mc = rrd_columns(str(rrd), '/campaign/nees/mc', 'Scalars:scalars')
    by_t = [dict(zip(s['t_ns'], s['nees'])) for s in series]
    assert_allclose([v[0] for v in mc], [(by_t[0][t] + by_t[1][t]) / 2 for t in common],
                    rtol=1e-12)
    # run 1 opened: its NEES is the campaign's, sample for sample; its truth the core's
    t_run, nees = rrd_columns(str(rrd), '/nees/estimator_odom', 'Scalars:scalars')
    assert_array_equal(t_run, series[1]['t_ns'])
    assert_allclose([v[0] for v in nees], series[1]['nees'], rtol=1e-9)
    runs = json.loads(rrd_static_text(str(rrd), '/runs'))
    _truth_check(str(rrd), runs)
    assert rows['/body/estimate/estimator_odom'] == len(series[1]['t_ns'])


@pytest.mark.ros
def test_live_node_with_the_shipped_mekf(tmp_path):
    env = ros_env(next_domain_id())
    rrd = tmp_path / 'live.rrd'
    node = start([script('attitude_node'), '--ros-args', '-p', 'imu.enable:=true',
                  '-p', 'star_tracker.enable:=true', '-p', 'imu.rate:=200.0'], env)
    mekf = start([script('rigidrot_mekf'), '--sigma-v', '1.7e-4', '--sigma-u', '2e-5',
                  '--bias-sigma', '2e-3'], env)
    view = start([script('rigidrot_view'), '--live', '--save', str(rrd), '--max-rate', '50',
                  '--topic', '/estimator/odom:nav_msgs/msg/Odometry',
                  '--topic', '/chatter:std_msgs/msg/String'], env)
    early = []
    try:
        early = wait_line(view, 'live: ', timeout=120)
        time.sleep(6.0)
    finally:
        code, _, err = stop(view, signal.SIGINT, timeout=90)
        err = ''.join(early) + err
        stop(mekf, signal.SIGINT)
        stop(node, signal.SIGINT)
    assert code == 0, err
    assert 'Traceback' not in err
    said = [ln for ln in err.splitlines() if '/chatter' in ln and 'not shown' in ln]
    assert len(said) == 1, err
    summary = json.loads(err.split('live summary: ', 1)[1].splitlines()[0])
    assert summary['topics']['/imu']['received'] > 3 * summary['topics']['/imu']['shown'] > 0
    rows = rrd_entities(str(rrd))
    assert rows['/body/estimate/estimator_odom'] > 20, rows
    assert rows['/nees/estimator_odom'] > 20, rows
    assert rows['/residual/gyro/imu_angular_velocity'] > 20, rows
    assert rows['/residual/star_tracker/star_tracker'] > 10, rows
    runs = json.loads(rrd_static_text(str(rrd), '/runs'))
    stamps = _truth_check(str(rrd), runs)
    assert np.all(np.diff(stamps) >= int(1e9 / 50)), 'the truth is shown at most 50 Hz'
