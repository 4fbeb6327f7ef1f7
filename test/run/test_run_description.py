"""A bag says which error model produced it: the run description's ``sensors``.

The node and the generator write one description (``run.outputs.run_description``; the
node-against-generator identity of ``test_generate.py`` compares it field for field); here
the generator's bag is read back with rosbags, and the scorer, ``rigidrot_compare`` and a
campaign's report are checked to read it.
"""

import contextlib
import io
import json
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores

from rigidrot_ros.run import params
from rigidrot_ros.run.generate import generate_bag, RUN_TOPIC

KALIBR = '''accelerometer_noise_density: 1.86e-03
accelerometer_random_walk: 4.33e-04
gyroscope_noise_density: 1.87e-04
gyroscope_random_walk: 2.66e-05
rostopic: /imu0
update_rate: 200.0
'''
#: The error terms set away from their defaults (besides those the Kalibr file supplies).
TERMS = {
    'imu.gyro_bias': [1e-3, -5e-4, 1.5e-3], 'imu.gyro_bias_stddev': 1e-3,
    'imu.gyro_bias_instability': 2e-4, 'imu.gyro_bias_correlation_time': 100.0,
    'imu.gyro_scale_factor': [1e-3, -2e-3, 5e-4],
    'imu.gyro_misalignment': [0.0, 1e-3, 0.0, -1e-3, 0.0, 2e-3, 0.0, 0.0, 0.0],
    'imu.gyro_quantum': 1e-5, 'imu.gyro_increment_quantum': 1e-7, 'imu.seed': 4,
    'accel.bias': [0.01, 0.0, -0.02], 'accel.bias_stddev': 0.005,
    'accel.bias_instability': 1e-3, 'accel.bias_correlation_time': 50.0,
    'accel.scale_factor': [2e-3, 0.0, 0.0], 'accel.quantum': 1e-4,
    'accel.increment_quantum': 1e-6, 'accel.lever_arm': [0.1, 0.0, 0.2],
    'accel.gravity': [0.0, 0.0, -9.80665],
    'mag.soft_iron': [1.1, 0.01, 0.0, 0.01, 0.9, 0.0, 0.0, 0.0, 1.0],
    'mag.hard_iron': [1e-6, 0.0, -2e-6], 'mag.noise_density': 1e-8, 'mag.seed': 9,
    'star_tracker.cross_boresight_arcsec': 7.0, 'star_tracker.boresight': [1.0, 0.0, 0.0],
    'imu.latency': 0.002,
}
ON = {'imu.enable': True, 'accel.enable': True, 'mag.enable': True,
      'star_tracker.enable': True}
SUPPLIED = {'accel.noise_density': 1.86e-3, 'accel.random_walk': 4.33e-4,
            'imu.gyro_noise_density': 1.87e-4, 'imu.gyro_random_walk': 2.66e-5,
            'imu.rate': 200.0}


def _bag(tmp_path):
    kalibr = tmp_path / 'imu.yaml'
    kalibr.write_text(KALIBR)
    values = dict(ON, **TERMS, **{'imu.kalibr_yaml': str(kalibr)})
    return generate_bag(values, 1.0, tmp_path / 'bag'), values


def _description(path):
    """The run description as rosbags reads it from the ~/run message."""
    store = get_typestore(Stores.ROS2_JAZZY)
    with AnyReader([Path(path)], default_typestore=store) as reader:
        conns = [c for c in reader.connections if c.topic == RUN_TOPIC]
        (_, _, raw), = list(reader.messages(connections=conns))
        return json.loads(reader.deserialize(raw, conns[0].msgtype).data)


def test_the_bag_records_the_effective_sensor_configuration(tmp_path):
    from rigidrot_ros.sensors import ImuNoise
    path, values = _bag(tmp_path)
    sensors = _description(path)['sensors']
    assert set(sensors) == {'imu', 'star_tracker', 'mag'}
    effective = dict(params.defaults(), **values, **SUPPLIED)
    groups = {'imu': ('imu.', 'accel.'), 'star_tracker': ('star_tracker.',), 'mag': ('mag.',)}
    for name, prefixes in groups.items():
        got = sensors[name]['parameters']
        want = {p.name for p in params.PARAMS
                if p.name.startswith(prefixes) and not p.name.endswith('.enable')}
        assert set(got) == want, name                 # every parameter of the sensor
        for n in want:
            assert got[n] == effective[n], (n, got[n], effective[n])
    assert sensors['imu']['rate_hz'] == 200.0           # from the Kalibr file
    assert sensors['imu']['kalibr'] == SUPPLIED
    assert sensors['mag']['rate_hz'] == sensors['star_tracker']['rate_hz'] * 10 == 100.0
    # the turn-on biases drawn from the seed, as the error models draw them
    gyro = ImuNoise(seed=4, kind='gyro', bias_stddev=1e-3)
    accel = ImuNoise(seed=4, kind='accel', bias_stddev=0.005)
    assert sensors['imu']['turn_on_bias'] == {'gyro': gyro.turn_on_bias.tolist(),
                                              'accel': accel.turn_on_bias.tolist()}
    assert np.all(np.abs(gyro.turn_on_bias) > 0)


def test_a_sensor_that_is_off_is_not_described(tmp_path):
    path = generate_bag({'star_tracker.enable': True}, 0.5, tmp_path / 'bag')
    assert set(_description(path)['sensors']) == {'star_tracker'}


def test_the_scorer_and_compare_show_the_error_model(tmp_path):
    from rigidrot_ros.bag import read_bag
    from rigidrot_ros.scoring.score import extract_streams, score_against_runs
    from rigidrot_ros.tools.compare import main
    path, _ = _bag(tmp_path)
    bag = read_bag(path)
    results = score_against_runs(bag, extract_streams(bag)[0])
    by_topic = {r['label']: r for r in results}
    imu = by_topic['/imu [angular_velocity]']['sensor']
    assert imu['name'] == 'imu' and imu['parameters']['imu.gyro_noise_density'] == 1.87e-4
    assert by_topic['/star_tracker']['sensor']['parameters']['star_tracker.seed'] == 1
    assert 'sensor' not in by_topic['/attitude']
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main([str(path), '--json', str(tmp_path / 's.json')]) == 0
    text = out.getvalue()
    assert 'sensor error models (from the run description):' in text
    line = next(ln for ln in text.splitlines() if ln.strip().startswith('imu at 200 Hz'))
    for words in ('imu.gyro_noise_density 0.000187', 'imu.gyro_bias_stddev 0.001',
                  'accel.lever_arm [0.1, 0, 0.2]', 'gyro turn-on bias'):
        assert words in line, (words, line)
    saved = json.loads((tmp_path / 's.json').read_text())
    assert any(t.get('sensor', {}).get('name') == 'imu' for t in saved['topics'])


def test_a_campaign_report_shows_the_runs_sensor_model(tmp_path):
    from rigidrot_ros.campaign.aggregate import aggregate, VARIES
    from rigidrot_ros.campaign.run import run_one
    from rigidrot_ros.campaign.spec import check_spec
    spec = check_spec({
        'seed': 3, 'runs': 2, 'duration': 2.0,
        'base': {'overrides': {'imu.enable': True, 'star_tracker.enable': True,
                               'imu.gyro_noise_density': 2e-4}},
        'dispersions': {'imu.gyro_bias': {'mean': [0, 0, 0], 'sigma': 1e-3}},
        'estimator': {'factory': 'rigidrot_ros.estimators.mekf:make',
                      'params': {'sigma_v': 2e-4, 'sigma_u': 2e-5, 'bias_sigma': 1e-3}}})
    results = [run_one(spec, i) for i in range(2)]
    rows = [r['row'] for r in results]
    assert all(r['status'] == 'ok' for r in rows), rows
    assert rows[0]['sensors']['imu']['parameters']['imu.gyro_bias'] == rows[0]['imu.gyro_bias']
    report = aggregate(results, spec)
    imu = report['sensors']['imu']['parameters']
    assert imu['imu.gyro_noise_density'] == 2e-4
    assert imu['imu.gyro_bias'] == imu['imu.seed'] == VARIES      # drawn per run
    assert report['sensors']['star_tracker']['parameters']['star_tracker.seed'] == VARIES
    assert report['sensors']['imu']['rate_hz'] == 100.0
