"""Kalibr imu.yaml import: the mapping, and refusals that name the key."""

import numpy as np
import pytest

from kalibr_helpers import _rows, _scale_misalignment, C_GYRO_I, GOOD, M_ACCEL, M_GYRO
from rigidrot_ros.sensors import ImuNoise, load_kalibr_imu

EXPECTED = {'accel.noise_density': 1.86e-3, 'accel.random_walk': 4.33e-4,
            'imu.gyro_noise_density': 1.87e-4, 'imu.gyro_random_walk': 2.66e-5,
            'imu.rate': 200.0}


def _write(tmp_path, text, name='imu.yaml'):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_a_kalibr_file_maps_to_our_parameters(tmp_path):
    params, topic = load_kalibr_imu(_write(tmp_path, GOOD))
    assert params == EXPECTED and topic == '/imu0'
    # they build the sensors' error models as they are
    ImuNoise(params['imu.gyro_noise_density'], params['imu.gyro_random_walk'])
    ImuNoise(params['accel.noise_density'], params['accel.random_walk'], kind='accel')
    # Kalibr's result layout: under one imuN block (with other keys beside)
    nested = 'imu0:\n  T_i_b: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n' + \
        ''.join('  ' + line + '\n' for line in GOOD.splitlines() if line.strip())
    assert load_kalibr_imu(_write(tmp_path, nested, 'n.yaml')) == (EXPECTED, '/imu0')


@pytest.mark.parametrize('text, words', [
    (GOOD.replace('gyroscope_random_walk', 'gyroscope_random_wlak'),
     'missing key gyroscope_random_walk'),
    (GOOD.replace('rostopic:', '#rostopic:'), 'missing key rostopic'),
    (GOOD + 'update_rate: 100.0\n', "key 'update_rate' appears twice"),
    (GOOD + 'imu0:\n  update_rate: 100.0\n', 'contradictory update_rate'),
    ('imu0:\n  a: 1\nimu1:\n  a: 2\n', '2 IMU blocks (imu0, imu1)'),
    (GOOD.replace('1.87e-04', '-1.87e-04'), 'gyroscope_noise_density must be a nonnegative'),
    (GOOD.replace('4.33e-04', '.nan'), 'accelerometer_random_walk must be a nonnegative'),
    (GOOD.replace('200.0', '0.0'), 'update_rate must be a positive'),
    (GOOD.replace('1.86e-03', 'high'), 'accelerometer_noise_density must be a number'),
    (GOOD.replace('/imu0', '[1, 2]'), 'rostopic must be a topic name'),
    (GOOD[:GOOD.index('rostopic')] + 'rostopic: [/imu0\n', 'is not valid YAML'),
    ('- 1\n- 2\n', 'is a mapping of keys'),
])
def test_bad_files_are_refused_naming_the_key(tmp_path, text, words):
    with pytest.raises(ValueError) as err:
        load_kalibr_imu(_write(tmp_path, text))
    assert words in str(err.value)


def test_a_missing_file_is_refused(tmp_path):
    with pytest.raises(ValueError, match='cannot read Kalibr file'):
        load_kalibr_imu(tmp_path / 'absent.yaml')


def test_scale_misalignment_is_imported_as_kalibr_defines_it(tmp_path):
    params, topic = load_kalibr_imu(_write(tmp_path, _scale_misalignment()))
    assert topic == '/imu0' and {k: params[k] for k in EXPECTED} == EXPECTED
    rng = np.random.default_rng(5)
    for kind, prefix, kalibr in (('gyro', 'imu.gyro_', np.array(M_GYRO) @ C_GYRO_I),
                                 ('accel', 'accel.', np.array(M_ACCEL))):
        noise = ImuNoise(scale_factor=params[prefix + 'scale_factor'],
                         misalignment=params[prefix + 'misalignment'], kind=kind)
        u = rng.standard_normal((50, 3))
        # the error model, noiseless, against Kalibr's measurement equation
        np.testing.assert_allclose(noise.apply(u, 0.005).value, u @ kalibr.T, rtol=0,
                                   atol=8 * np.finfo(float).eps)
    assert params['imu.gyro_misalignment'][::4] == [0.0, 0.0, 0.0]
    # through the node's settings: the sensors carry it
    from rigidrot_ros.run import params as table, settings
    values = table.defaults()
    values.update({'imu.enable': True, 'accel.enable': True,
                   'imu.kalibr_yaml': str(tmp_path / 'imu.yaml')})
    setup = settings.prepare_run(values)
    np.testing.assert_allclose(setup.gyro.noise.matrix, np.array(M_GYRO) @ C_GYRO_I,
                               rtol=0, atol=4 * np.finfo(float).eps)
    np.testing.assert_allclose(setup.accel.noise.matrix, M_ACCEL, rtol=0,
                               atol=4 * np.finfo(float).eps)
    # set both ways and different: refused naming both
    values['accel.scale_factor'] = [1e-3, 0.0, 0.0]
    with pytest.raises(ValueError, match=r'accel.scale_factor .* contradicts imu.kalibr_yaml '
                                         r'.*diag\(accelerometers.M\) - 1'):
        settings.prepare_run(values)


@pytest.mark.parametrize('text, words', [
    (_scale_misalignment(a=[[1e-4, 0, 0], [0, 0, 0], [0, 0, 0]]),
     'gyroscopes.A (g-sensitivity'),
    (_scale_misalignment(model='scale-misalignment-size-effect'),
     'lever arms are not modelled'),
    (_scale_misalignment(model='affine'), "model 'affine' cannot be imported"),
    (_scale_misalignment(model='calibrated'), 'the model is calibrated'),
    (_scale_misalignment(rot=M_GYRO), 'C_gyro_i must be a rotation'),
    (_scale_misalignment(m_gyro=[[1.6, 0, 0], [0, 1, 0], [0, 0, 1]]),
     'beyond this package'),
    (_scale_misalignment(m_gyro=[[1, 0, 0], [0.3, 1, 0], [0, 0, 1]]),
     'beyond this package'),
    (_scale_misalignment(m_gyro=[[1, 0], [0, 1]]), 'gyroscopes.M must be a 3x3 matrix'),
    (_scale_misalignment(m_gyro=[[1, 0, 0], [0, '.nan', 0], [0, 0, 1]]),
     'gyroscopes.M must be a 3x3 matrix'),
    (_scale_misalignment().replace('    C_gyro_i:', '    C_gyro:'),
     'missing key gyroscopes.C_gyro_i'),
    (_scale_misalignment().replace('  accelerometers:\n    M:\n' + _rows(M_ACCEL), ''),
     'needs accelerometers'),
])
def test_intrinsics_it_cannot_simulate_are_refused(tmp_path, text, words):
    with pytest.raises(ValueError) as err:
        load_kalibr_imu(_write(tmp_path, text))
    assert words in str(err.value) and str(tmp_path / 'imu.yaml') in str(err.value)


def test_every_refusal_names_the_file(tmp_path):
    for text in (GOOD + 'update_rate: 100.0\n', 'imu0: {a: 1, a: 2}\n', '? [1, 2]\n: 3\n',
                 GOOD.replace('200.0', '1' + '0' * 400)):
        with pytest.raises(ValueError) as err:
            load_kalibr_imu(_write(tmp_path, text))
        assert str(err.value).startswith(str(tmp_path / 'imu.yaml')), err.value
