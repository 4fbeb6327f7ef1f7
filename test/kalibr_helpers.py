"""Helpers that test_sensors_kalibr.py shares with other test modules."""

import numpy as np


GOOD = '''#Accelerometers
accelerometer_noise_density: 1.86e-03   #Noise density (continuous-time)
accelerometer_random_walk:   4.33e-04   #Bias random walk

#Gyroscopes
gyroscope_noise_density:     1.87e-04   #Noise density (continuous-time)
gyroscope_random_walk:       2.66e-05   #Bias random walk

rostopic:                    /imu0      #the IMU ROS topic
update_rate:                 200.0      #Hz (for discretization of the values above)
'''


# -- Kalibr's scale-misalignment model (its result file, imu-*.yaml) ------------------------
# Kalibr (IccSensors.py, IccScaledMisalignedImu): a_meas = M_a f + b_a and
# w_meas = M_g C_gyro_i w + A C_gyro_i f + b_g, M lower triangular about the identity.
M_ACCEL = [[1.002, 0.0, 0.0], [0.0013, 0.998, 0.0], [-0.0021, 0.0007, 1.001]]


M_GYRO = [[0.9991, 0.0, 0.0], [0.0024, 1.0012, 0.0], [0.0005, -0.0018, 1.0003]]


C_GYRO_I = [[0.9999950000058334, -0.003000992998838234, -0.0009969976701682984],
            [0.002998993001171566, 0.9999935000075835, -0.002001495331586601],
            [0.0010029976631683018, 0.0019984953350865994, 0.9999975000029168]]


def _rows(m, indent='      '):
    return ''.join(f'{indent}- [{", ".join(repr(x) for x in row)}]\n' for row in m)


def _scale_misalignment(a=((0.0,) * 3,) * 3, m_gyro=M_GYRO, rot=C_GYRO_I,
                        model='scale-misalignment'):
    return ('imu0:\n  T_i_b:\n' + _rows(np.eye(4).tolist(), '    ')
            + ''.join('  ' + line + '\n' for line in GOOD.splitlines()
                      if line.strip() and not line.startswith('#'))
            + '  accelerometers:\n    M:\n' + _rows(M_ACCEL)
            + '  gyroscopes:\n    A:\n' + _rows(a) + '    C_gyro_i:\n' + _rows(rot)
            + '    M:\n' + _rows(m_gyro) + f'  model: {model}\n  time_offset: 0.0\n')
