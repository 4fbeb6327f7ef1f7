"""Kalibr imu.yaml import: the mapping, and refusals that name the key."""

import pytest

from rigidrot_ros.sensors import ImuNoise, load_kalibr_imu

GOOD = '''#Accelerometers
accelerometer_noise_density: 1.86e-03   #Noise density (continuous-time)
accelerometer_random_walk:   4.33e-04   #Bias random walk

#Gyroscopes
gyroscope_noise_density:     1.87e-04   #Noise density (continuous-time)
gyroscope_random_walk:       2.66e-05   #Bias random walk

rostopic:                    /imu0      #the IMU ROS topic
update_rate:                 200.0      #Hz (for discretization of the values above)
'''
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
