"""Node settings without ROS: the default YAML, and parameters -> scene + solver options.

Shared by the node (live parameters) and the recorder/compare tools (logged metadata), so
that a scene is validated by one piece of code wherever it comes from.
"""

import math
import os
import sys

import yaml

from rigidrot_ros.core import MIN_TOL, Scene
from rigidrot_ros.sensors import AttitudeNoise, GyroNoise

__all__ = ['PACKAGE', 'SCENE_KEYS', 'OUTPUT_KEYS', 'BACKENDS', 'find_config',
           'load_defaults', 'scene_from_params', 'solver_options', 'sensor_settings',
           'SensorSettings']

PACKAGE = 'rigidrot_ros'
SCENE_KEYS = ('inertia', 'torque', 'torque_frame', 'omega0', 'attitude0')
BACKENDS = ('auto', 'flint', 'mpmath')
#: Output switches (read only).
OUTPUT_KEYS = ('imu.enable', 'star_tracker.enable', 'odom.enable', 'transform.enable',
               'markers.enable')
#: Loosest attitude accuracy the node accepts, rad (the lowest is core.MIN_TOL).
MAX_TOL = 1.0
#: Highest sensor rate, Hz (the node's publish_rate has the same ceiling).
MAX_RATE = 1e4


def _share_dirs():
    """Candidate share/<pkg> directories: ament prefixes, this environment, the checkout."""
    dirs = []
    prefixes = os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) + [sys.prefix]
    for prefix in prefixes:
        if prefix:
            dirs.append(os.path.join(prefix, 'share', PACKAGE))
    # an editable (pip -e) install runs from the source checkout
    dirs.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    return dirs


def find_config(name='default.yaml'):
    """Return the path of an installed config file (share/rigidrot_ros/config/<name>)."""
    for d in _share_dirs():
        path = os.path.join(d, 'config', name)
        if os.path.isfile(path):
            return path
    raise FileNotFoundError(f'config/{name} of {PACKAGE} not found in {_share_dirs()}')


def load_defaults(path=None):
    """Read the ``ros__parameters`` of a params YAML (first node entry) as a dict."""
    path = path or find_config()
    with open(path, encoding='utf-8') as fh:
        doc = yaml.safe_load(fh)
    if not isinstance(doc, dict) or not doc:
        raise ValueError(f'{path}: not a ROS 2 params file')
    for entry in doc.values():
        if isinstance(entry, dict) and isinstance(entry.get('ros__parameters'), dict):
            return _flatten(entry['ros__parameters'])
    raise ValueError(f'{path}: no ros__parameters section')


def _flatten(tree, prefix=''):
    """Nested YAML mappings -> dotted parameter names, as ROS 2 reads a params file."""
    out = {}
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, dict):
            out.update(_flatten(value, name + '.'))
        else:
            out[name] = value
    return out


def _floats(name, value, size):
    if isinstance(value, (str, bytes)) or not hasattr(value, '__len__'):
        raise ValueError(f'parameter {name} must be a list of {size} numbers, got {value!r}')
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise ValueError(f'parameter {name}[{i}] must be a number, got {v!r}')
        try:
            out.append(float(v))
        except OverflowError:                                   # an int beyond 1.8e308
            raise ValueError(f'parameter {name}[{i}] is beyond the float64 range '
                             f'(|x| <= 1.8e308)') from None
    if len(out) != size:
        raise ValueError(f'parameter {name} must have {size} numbers, got {len(out)}')
    return tuple(out)


def scene_from_params(params):
    """Build a :class:`Scene` from parameter values; ValueError names the parameter."""
    try:
        return Scene(
            inertia=_floats('inertia', params['inertia'], 3),
            torque=_floats('torque', params['torque'], 3),
            torque_frame=params['torque_frame'],
            omega0=_floats('omega0', params['omega0'], 3),
            attitude0=_floats('attitude0', params['attitude0'], 4),
        )
    except KeyError as exc:
        raise ValueError(f'parameter {exc.args[0]} is missing') from None
    except ValueError as exc:
        msg = str(exc)
        raise ValueError(msg if msg.startswith('parameter') else f'parameter {msg}') from None


def solver_options(params):
    """Return ``(tol, backend)`` for :func:`solve`, validated, backend None for 'auto'."""
    tol = params.get('tol', 1e-12)
    # the declared range [MIN_TOL, MAX_TOL] binds rclpy only for doubles: check any number
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or \
            not (MIN_TOL <= tol <= MAX_TOL):                    # NaN fails, ints compare exactly
        raise ValueError(f'parameter tol must be a number in [{MIN_TOL:g}, {MAX_TOL:g}] rad, '
                         f'got {tol!r}')
    backend = params.get('backend', 'auto')
    if backend not in BACKENDS:
        raise ValueError(f'parameter backend must be one of {BACKENDS}, got {backend!r}')
    return float(tol), (None if backend == 'auto' else backend)


class SensorSettings:
    """Validated sensor and output settings of the node.

    Attributes
    ----------
    imu, star_tracker, odom, transform, markers : bool
        Which outputs are on.
    imu_rate, star_tracker_rate : float
        Sample rates, Hz of clock time (0 in the parameter means ``publish_rate``).
    gyro : GyroNoise
        The gyro's error model (a new, freshly seeded instance).
    attitude_noise : AttitudeNoise
        The star tracker's error model (a new, freshly seeded instance).
    """

    def __init__(self, params):
        p = params
        for name in OUTPUT_KEYS:
            if not isinstance(p.get(name), bool):
                raise ValueError(f'parameter {name} must be true or false, '
                                 f'got {p.get(name)!r}')
        self.imu, self.star_tracker = p['imu.enable'], p['star_tracker.enable']
        self.odom, self.transform = p['odom.enable'], p['transform.enable']
        self.markers = p['markers.enable']
        publish_rate = p.get('publish_rate', 100.0)
        self.imu_rate = _rate('imu.rate', p['imu.rate'], publish_rate)
        self.star_tracker_rate = _rate('star_tracker.rate', p['star_tracker.rate'],
                                       publish_rate)
        try:
            self.gyro = GyroNoise(p['imu.gyro_noise_density'], p['imu.gyro_random_walk'],
                                  p['imu.gyro_bias'], p['imu.seed'])
        except ValueError as exc:
            raise ValueError(f'parameter imu.{exc}') from None
        try:
            self.attitude_noise = AttitudeNoise(
                p['star_tracker.cross_boresight_arcsec'],
                p['star_tracker.about_boresight_arcsec'], p['star_tracker.boresight'],
                p['star_tracker.seed'])
        except ValueError as exc:
            raise ValueError(f'parameter star_tracker.{exc}') from None
        if self.imu and p.get('time_scale', 1.0) == 0.0:
            raise ValueError('parameter time_scale = 0 freezes the scene: the imu needs '
                             'scene time to pass (set time_scale > 0 or imu.enable false)')


def _rate(name, value, publish_rate):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            not math.isfinite(value) or not (value == 0 or 1e-3 <= value <= MAX_RATE):
        raise ValueError(f'parameter {name} must be 0 (= publish_rate) or a rate in '
                         f'[0.001, {MAX_RATE:g}] Hz, got {value!r}')
    return float(value) if value else float(publish_rate)


def sensor_settings(params):
    """Validate the sensor and output parameters: a :class:`SensorSettings`.

    Raises
    ------
    ValueError
        Naming the parameter and the rule it breaks.
    """
    try:
        return SensorSettings(params)
    except KeyError as exc:
        raise ValueError(f'parameter {exc.args[0]} is missing') from None
