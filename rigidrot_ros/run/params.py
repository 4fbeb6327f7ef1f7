"""The parameters of attitude_node, each defined once (no rclpy).

:data:`PARAMS` is the one table: name, type, default, description with units, range or
allowed values, whether it is read only, when a change applies, and its validator. From it
come the node's ``ParameterDescriptor`` s, the validation of every value (the node's
set-parameters callback, its start-up, the offline generator), ``config/default.yaml``,
``attitude_node --help`` and ``doc/parameters.md``; a test checks the files are up to date:

    python -m rigidrot_ros.run.params --yaml > config/default.yaml
    python -m rigidrot_ros.run.params --markdown > doc/parameters.md

A new parameter is one more :class:`Param` in :data:`PARAMS` (then regenerate both files);
rules across parameters (the inertia triangle inequality, a sensor rate of 0 meaning
``publish_rate``) stay in :mod:`rigidrot_ros.run.settings`.
"""

from dataclasses import dataclass
import math
import numbers
import sys
import textwrap
from typing import Any, Callable, Optional, Tuple

import yaml

from rigidrot_ros.core import MIN_TOL, TORQUE_FRAMES
from rigidrot_ros.core.scene import float_vector

__all__ = ['Param', 'PARAMS', 'BY_NAME', 'MAX_RATE', 'MIN_RATE', 'MAX_TOL', 'BACKENDS',
           'MAX_SEED', 'APPLIES', 'SENSOR_PARAMS',
           'defaults', 'check', 'check_values', 'yaml_text',
           'markdown_text', 'help_text', 'main']

#: Highest rate of the truth and of every sensor, Hz.
MAX_RATE = 1e4
#: Lowest nonzero rate, Hz.
MIN_RATE = 1e-3
#: Loosest attitude accuracy the node accepts, rad (the lowest is core.MIN_TOL).
MAX_TOL = 1.0
#: Special-function backends ('auto' lets the core choose).
BACKENDS = ('auto', 'flint', 'mpmath')
#: Highest seed of a noise stream.
MAX_SEED = 2 ** 63 - 1
#: When a change takes effect, and how each is said in the descriptions.
APPLIES = {'now': 'takes effect at once', 'reset': 'applied at the next ~/reset',
           'read only': 'read only (set it at start-up)'}

_TYPES = ('double', 'double[]', 'integer', 'bool', 'string', 'string[]')


# -- validators: value -> checked value, or ValueError naming the parameter -----------------
def _number(p, v):
    lo, hi = p.range
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v) or \
            not lo <= v <= hi:              # NaN fails, ints compare exactly
        raise ValueError(f'parameter {p.name} must be a number in [{lo:g}, {hi:g}]'
                         f'{_unit(p)}, got {v!r}')
    return float(v)


def _rate_or_zero(p, v):
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v) or \
            not (v == 0 or MIN_RATE <= v <= MAX_RATE):
        raise ValueError(f'parameter {p.name} must be 0 (= publish_rate) or a rate in '
                         f'[{MIN_RATE:g}, {MAX_RATE:g}] Hz, got {v!r}')
    return float(v)


def _integer(p, v):
    lo, hi = p.range
    if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not lo <= v <= hi:
        raise ValueError(f'parameter {p.name} must be an integer in {p.allowed()}, got {v!r}')
    return int(v)


def _bool(p, v):
    if not isinstance(v, bool):
        raise ValueError(f'parameter {p.name} must be true or false, got {v!r}')
    return v


def _string(p, v):
    if not isinstance(v, str):
        raise ValueError(f'parameter {p.name} must be a string, got {v!r}')
    return v


def _name(p, v):
    if not isinstance(v, str) or not v:
        raise ValueError(f'parameter {p.name} must be a non-empty string, got {v!r}')
    return v


def _choice(p, v):
    if not isinstance(v, str) or v not in p.choices:
        raise ValueError(f'parameter {p.name} must be one of {p.choices}, got {v!r}')
    return v


def _floats(p, v):
    """Return a list of ``p.size`` numbers as a tuple of floats (finiteness: the model)."""
    return float_vector(f'parameter {p.name}', v, p.size, kind='list', finite=False)


def _strings(p, v):
    if isinstance(v, (str, bytes)) or not isinstance(v, (list, tuple)) or \
            not all(isinstance(t, str) for t in v):
        raise ValueError(f'parameter {p.name} must be a list of strings '
                         f"(['NAME:pkg/msg/Type', ...]), got {v!r}")
    return list(v)


def _unit(p):
    return f' {p.unit}' if p.unit else ''


@dataclass(frozen=True)
class Param:
    """One parameter of attitude_node.

    Attributes
    ----------
    name : str
        Dotted name, as in ``-p name:=value`` and nested in a params file.
    type : str
        One of 'double', 'double[]', 'integer', 'bool', 'string', 'string[]'.
    default : object
        The value when no override is given (in ``config/default.yaml`` too).
    description : str
        What it is, with units.
    applies : str
        'now' (a change takes effect at once), 'reset' (at the next ``~/reset``) or
        'read only' (set at start-up only).
    validate : callable
        ``validate(param, value) -> checked value``; ValueError naming the parameter.
    range : tuple or None
        ``(low, high)``, inclusive, for numbers (declared as the descriptor's range).
    choices : tuple or None
        The allowed strings.
    size : int
        Length of a 'double[]' value.
    unit : str
        Unit of a number, for the messages ('' if none).
    """

    name: str
    type: str
    default: Any
    description: str
    applies: str
    validate: Callable[['Param', Any], Any]
    range: Optional[Tuple[float, float]] = None
    choices: Optional[Tuple[str, ...]] = None
    size: int = 0
    unit: str = ''

    @property
    def read_only(self):
        """Return True where a change at run time is refused."""
        return self.applies == 'read only'

    def check(self, value):
        """Return ``value`` checked (and converted); ValueError naming the parameter."""
        return self.validate(self, value)

    def full_description(self):
        """Return the description and when a change applies (the descriptor's text)."""
        return f'{self.description}; {APPLIES[self.applies]}'

    def allowed(self):
        """Return the range or allowed values as text ('' if any value of the type)."""
        if self.choices:
            return ', '.join(repr(c) for c in self.choices)
        if self.validate is _rate_or_zero:
            return f'0 or [{MIN_RATE:g}, {MAX_RATE:g}]'
        if self.type == 'integer':
            hi = '2^63 - 1' if self.range[1] == MAX_SEED else self.range[1]
            return f'[{self.range[0]}, {hi}]'
        if self.range:
            return f'[{self.range[0]:g}, {self.range[1]:g}]'
        return ''


def _double(name, default, description, applies, lo, hi, unit, validate=_number):
    return Param(name, 'double', default, description, applies, validate, (lo, hi), unit=unit)


def _vector(name, default, description, applies='reset'):
    return Param(name, 'double[]', list(default), description, applies, _floats,
                 size=len(default))


def _switch(name, description):
    return Param(name, 'bool', False, description, 'read only', _bool)


def _seed(name, default, description):
    return Param(name, 'integer', default, description, 'reset', _integer, (0, MAX_SEED))


def _rate(name, default, what):
    return _double(name, default, f'{what} sample rate, Hz of clock time; 0 = publish_rate',
                   'reset', 0.0, MAX_RATE, 'Hz', _rate_or_zero)


def _timing(name, what):
    """Return the timing-model entries of sensor ``name`` (see run/scheduler.py)."""
    return (
        _double(f'{name}.latency', 0.0, f'transport latency of the {what}: each sample is '
                'published this long after its true sample time (its stamp unchanged), s',
                'reset', 0.0, 10.0, 's'),
        _double(f'{name}.stamp_jitter', 0.0, f'1-sigma jitter of the {what} stamps against '
                'the true sample time (seeded by its seed; the sample is taken at the true '
                'time, the message carries the jittered stamp), s', 'reset', 0.0, 1.0, 's'),
        _double(f'{name}.drop_probability', 0.0, f'probability that a {what} sample is '
                'dropped (read, not published; seeded by its seed)', 'reset', 0.0, 1.0, ''),
        _double(f'{name}.clock_offset', 0.0, f'offset of the {what} clock: its stamps are '
                'the true sample time plus this, s', 'reset', -1e3, 1e3, 's'),
    )


# -- sensors of issue 19: IMU error terms, accelerometer, magnetometer (branch wire) ---------
# Each term is zero or off by default, so the default streams are today's, bit for bit. The
# vectors' finiteness and bounds are checked by the sensor models (rigidrot_ros.sensors),
# which name the parameter; rigidrot_ros.run.settings builds them.
def _positive(p, v):
    lo, hi = p.range
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v) or \
            not lo < v <= hi:
        raise ValueError(f'parameter {p.name} must be a number in ({lo:g}, {hi:g}]'
                         f'{_unit(p)}, got {v!r}')
    return float(v)


def _imu_terms(prefix, unit, increment, big, lsb, what, measured):
    """Return the error terms shared by the gyro (``imu.gyro_``) and the accelerometer."""
    return (
        _double(f'{prefix}bias_stddev', 0.0, f'turn-on {what} bias spread, {unit}: '
                'N(0, sd^2) per axis drawn once from the seed and added to the given bias '
                '(Gazebo <bias_stddev>)', 'reset', 0.0, big, unit),
        _double(f'{prefix}bias_instability', 0.0, f'{what} bias instability: stationary '
                f'sigma of a first-order Gauss-Markov bias, {unit}; 0 = off', 'reset', 0.0,
                big, unit),
        _double(f'{prefix}bias_correlation_time', 3600.0, f'correlation time tau of the '
                f'{what} Gauss-Markov bias, s', 'reset', 0.0, 1e9, 's', _positive),
        _vector(f'{prefix}scale_factor', [0.0, 0.0, 0.0], f'{what} scale-factor errors '
                '[sx, sy, sz], fraction (1e-3 = 1000 ppm), |s| <= 0.5'),
        _vector(f'{prefix}misalignment', [0.0] * 9, f'{what} axis misalignment M, 3x3 '
                'row-major, rad, zero diagonal, |M_ij| <= 0.1: axis i senses M_ij of the '
                'input along axis j'),
        _double(f'{prefix}quantum', 0.0, f'LSB of the {what} output, {unit} (rounded); 0 = '
                'not quantised', 'reset', 0.0, lsb, unit),
        _double(f'{prefix}increment_quantum', 0.0, f'LSB of the {what} increment, '
                f'{increment}: above 0 the measured increments, quantised with the residual '
                f'carried to the next sample, are published on {measured}; 0 = none',
                'reset', 0.0, lsb, increment),
    )


#: The sensor parameters of issue 19 (appended to :data:`PARAMS`).
SENSOR_PARAMS = _imu_terms('imu.gyro_', 'rad/s', 'rad', 10.0, 1.0, 'gyro',
                           'delta_angle_measured') + (
    Param('imu.kalibr_yaml', 'string', '', "a Kalibr imu.yaml ('' = none) whose noise "
          'densities, random walks and update_rate replace the defaults of '
          'imu.gyro_noise_density, imu.gyro_random_walk, accel.noise_density, '
          'accel.random_walk and imu.rate (with model: scale-misalignment, its M and '
          'C_gyro_i also those of imu.gyro_scale_factor, imu.gyro_misalignment, '
          'accel.scale_factor and accel.misalignment); a value set both ways and different '
          'is refused',
          'reset', _string),
    _switch('accel.enable', 'add the accelerometer to imu (linear_acceleration, the specific '
            'force in B, m/s^2, with its covariance) and publish delta_velocity '
            '(Vector3Stamped, the exact integral of the specific force, m/s, in B)'),
    _vector('accel.lever_arm', [0.0, 0.0, 0.0], 'the IMU position r in B from the point the '
            'body turns about, m, |r_i| <= 1e3'),
    _vector('accel.gravity', [0.0, 0.0, 0.0], 'gravity g in N, m/s^2, |g_i| <= 1e3: '
            '[0, 0, 0] a free-flying body, [0, 0, -9.80665] a body on a supported point '
            '(N z up)'),
    _double('accel.noise_density', 0.0, 'velocity random walk sigma_v, m/s^2/sqrt(Hz) '
            '(Kalibr accelerometer_noise_density)', 'reset', 0.0, 10.0, 'm/s^2/sqrt(Hz)'),
    _double('accel.random_walk', 0.0, 'accelerometer bias random walk sigma_u, '
            'm/s^3/sqrt(Hz) (Kalibr accelerometer_random_walk)', 'reset', 0.0, 10.0,
            'm/s^3/sqrt(Hz)'),
    _vector('accel.bias', [0.0, 0.0, 0.0], 'initial accelerometer bias [bx, by, bz], m/s^2, '
            'in B, |b_i| <= 100'),
) + _imu_terms('accel.', 'm/s^2', 'm/s', 100.0, 10.0, 'accelerometer',
               'delta_velocity_measured') + (
    _switch('mag.enable', 'publish a magnetometer as sensor_msgs/MagneticField on mag '
            '(tesla, in B, frame body_frame_id)'),
    _rate('mag.rate', 0.0, 'magnetometer'),
    _vector('mag.field', [0.0, 2.0e-5, -4.5e-5], 'the magnetic field m_N in N, tesla, '
            '|m_i| <= 1e-2 (default: 49.2 uT, 66 deg inclination, N as ENU)'),
    _vector('mag.soft_iron', [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], 'soft-iron '
            'matrix S, 3x3 row-major, |S_ij| <= 10, condition number <= 1e3, det > 0'),
    _vector('mag.hard_iron', [0.0, 0.0, 0.0], 'hard-iron offset in B, tesla, |b_i| <= 1e-2'),
    _double('mag.noise_density', 0.0, 'magnetometer white noise density, T/sqrt(Hz)',
            'reset', 0.0, 1e-3, 'T/sqrt(Hz)'),
    _seed('mag.seed', 0, 'seed of the magnetometer noise (its own stream even for the '
          'value of another seed)'),
    *_timing('mag', 'magnetometer'),
)


#: Every parameter of attitude_node, in the order of ``config/default.yaml``.
_BASE_PARAMS = (
    _vector('inertia', [2.0, 2.0, 1.0], 'principal moments of inertia [I1, I2, I3], kg m^2 '
            '(positive, triangle inequality)'),
    _vector('torque', [0.0, 0.0, 0.05], 'constant torque [m1, m2, m3], N m, components in '
            'torque_frame'),
    Param('torque_frame', 'string', 'body', "'body' (torque fixed in B) or 'virtual' (fixed "
          'in the virtual-sphere frame S, Theorem 3)', 'reset', _choice,
          choices=TORQUE_FRAMES),
    _vector('omega0', [0.3, -0.2, 0.5], 'initial angular velocity [p0, q0, r0] of B '
            'relative to N, in B, rad/s'),
    _vector('attitude0', [0.0, 0.0, 0.0, 1.0], 'initial attitude q_NB [x, y, z, w] '
            '(rotates body vectors into N), normalised'),
    _double('tol', 1e-12, 'attitude accuracy asked of the exact solution, rad', 'reset',
            MIN_TOL, MAX_TOL, 'rad'),
    Param('backend', 'string', 'auto', "special functions: 'auto', 'flint' (Arb, "
          "certified) or 'mpmath'", 'reset', _choice, choices=BACKENDS),
    _double('publish_rate', 100.0, 'truth rate, Hz; a change anchors a new tick grid at the '
            'next tick (the scene clock runs on)', 'now', MIN_RATE, MAX_RATE, 'Hz'),
    _double('time_scale', 1.0, 'scene seconds per clock second', 'reset', 0.0, 1e9, ''),
    Param('frame_id', 'string', 'inertial', 'header.frame_id of attitude: the inertial '
          'frame N', 'now', _name),
    Param('body_frame_id', 'string', 'body', 'header.frame_id of angular_velocity: the body '
          'frame B', 'now', _name),
    Param('qos_depth', 'integer', 10, 'history depth of the publishers', 'read only',
          _integer, (1, 10000)),
    Param('record', 'bool', False, 'write every published message to an MCAP bag',
          'read only', _bool),
    Param('record_path', 'string', 'runs', 'directory under which each run gets a new bag '
          "directory ('' = runs)", 'read only', _string),
    Param('record_topics', 'string[]', [''], 'further topics to record raw as they arrive, '
          'e.g. an estimator output; NAME:pkg/msg/Type subscribes at once, so the first '
          'message is kept; empty names are ignored', 'read only', _strings),
    _switch('imu.enable', 'publish a gyro as sensor_msgs/Imu on imu, and the exact '
            'delta_angle and delta_rotation (Vector3Stamped, rad, in B) over each sample '
            'interval'),
    _rate('imu.rate', 0.0, 'gyro'),
    _double('imu.gyro_noise_density', 1.7e-4, 'angle random walk sigma_v, rad/s/sqrt(Hz) '
            '(Kalibr gyroscope_noise_density; Gazebo <stddev> = sigma_v / sqrt(dt))', 'reset',
            0.0, 1.0, 'rad/s/sqrt(Hz)'),
    _double('imu.gyro_random_walk', 2e-5, 'rate random walk sigma_u of the bias, '
            'rad/s^2/sqrt(Hz) (Kalibr gyroscope_random_walk)', 'reset', 0.0, 1.0,
            'rad/s^2/sqrt(Hz)'),
    _vector('imu.gyro_bias', [0.0, 0.0, 0.0], 'initial gyro bias [bx, by, bz], rad/s, in B'),
    _seed('imu.seed', 0, 'seed of the gyro noise: the same seed gives the same stream'),
    *_timing('imu', 'imu'),
    _switch('star_tracker.enable', 'publish a star tracker as '
            'geometry_msgs/PoseWithCovarianceStamped on star_tracker'),
    _rate('star_tracker.rate', 10.0, 'star tracker'),
    _double('star_tracker.cross_boresight_arcsec', 5.0, '1-sigma error across the '
            'boresight, arc seconds', 'reset', 0.0, 3600.0, 'arcsec'),
    _double('star_tracker.about_boresight_arcsec', 35.0, '1-sigma error about the boresight '
            '(roll), arc seconds', 'reset', 0.0, 3600.0, 'arcsec'),
    _vector('star_tracker.boresight', [0.0, 0.0, 1.0], 'boresight axis [x, y, z] in B '
            '(normalised)'),
    _seed('star_tracker.seed', 1, 'seed of the star tracker noise'),
    *_timing('star_tracker', 'star tracker'),
    _switch('odom.enable', 'publish the truth as nav_msgs/Odometry on odom'),
    _switch('transform.enable', 'publish the truth as geometry_msgs/TransformStamped on '
            'transform'),
    _switch('markers.enable', 'publish the body as visualization_msgs/MarkerArray on markers'),
)


def _grouped(base, extra):
    """Return ``base`` with each of ``extra`` after the last entry of its group (or at the end).

    A params file nests by group, so a group must stay in one piece (``imu:`` twice would be a
    duplicated YAML key).
    """
    out = list(base)
    for p in extra:
        head = p.name.rpartition('.')[0]
        where = [i for i, q in enumerate(out) if q.name.rpartition('.')[0] == head]
        out.insert(where[-1] + 1 if where else len(out), p)
    return tuple(out)


PARAMS = _grouped(_BASE_PARAMS, SENSOR_PARAMS)

#: The entries of :data:`PARAMS` by name.
BY_NAME = {p.name: p for p in PARAMS}


def defaults():
    """Return every parameter's default value, by name (fresh lists)."""
    return {p.name: (list(p.default) if isinstance(p.default, list) else p.default)
            for p in PARAMS}


def check(name, value):
    """Return ``value`` checked by the table's validator for ``name``; ValueError else."""
    if name not in BY_NAME:
        raise ValueError(f'unknown parameter {name!r}: attitude_node declares '
                         f'{", ".join(sorted(BY_NAME))}')
    return BY_NAME[name].check(value)


def check_values(values):
    """Check every value of ``values`` (all of :data:`PARAMS`) with its own validator.

    Returns the checked values by name; ValueError names the first bad parameter, or a
    missing one. Rules across parameters are :func:`rigidrot_ros.run.settings.prepare_run`'s.
    """
    out = {}
    for p in PARAMS:
        if p.name not in values:
            raise ValueError(f'parameter {p.name} is missing')
        out[p.name] = p.check(values[p.name])
    return out


# -- generated texts --------------------------------------------------------------------------
def _yaml_scalar(v):
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, float):
        text = repr(v)
        if 'e' in text and '.' not in text.split('e')[0]:
            text = text.replace('e', '.0e')        # YAML 1.1 (PyYAML) reads 1e-12 as a string
        return text
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        plain = v and v.replace('_', '').replace('/', '').isalnum() and \
            yaml.safe_load(v) == v
        return v if plain else "'" + v.replace("'", "''") + "'"
    if isinstance(v, (list, tuple)):
        return '[' + ', '.join(_yaml_scalar(x) for x in v) + ']'
    raise TypeError(f'no YAML form for {v!r}')


def yaml_text():
    """Return ``config/default.yaml``: every parameter's default, described, nested by dot."""
    lines = ['# Defaults of attitude_node, generated from rigidrot_ros/run/params.py by',
             '#   python -m rigidrot_ros.run.params --yaml > config/default.yaml',
             '# (edit the table, not this file). The default scene: an axially symmetric body',
             '# (I3 < I) spun up by a constant torque along its symmetry axis while it nutates',
             '# (Theorem 2 of Romano 2008). Units: kg m^2, N m, rad/s, rad, Hz.',
             '/**:', '  ros__parameters:']
    group = None
    for p in PARAMS:
        head, _, leaf = p.name.rpartition('.')
        if head != group:
            if head:
                lines.append(f'    {head}:')
            group = head
        indent = ' ' * (6 if head else 4)
        lines += textwrap.wrap(p.full_description(), 99, initial_indent=indent + '# ',
                               subsequent_indent=indent + '# ', break_on_hyphens=False)
        lines.append(f'{indent}{leaf}: {_yaml_scalar(p.default)}')
    return '\n'.join(lines) + '\n'


def _md_cell(text):
    return str(text).replace('|', '\\|')


def markdown_text():
    """Return ``doc/parameters.md``: the table as a MyST page (one ``#`` title)."""
    lines = [
        '# Parameters of attitude_node', '',
        'Generated from `rigidrot_ros/run/params.py` by '
        '`python -m rigidrot_ros.run.params --markdown` (edit the table, not this page); '
        '`config/default.yaml` holds the same defaults. Set them with '
        '`-p NAME:=VALUE` or `--params-file FILE`. *Applies*: `now` takes effect at once, '
        '`reset` at the next `~/reset` (the running scene is validated against it at once), '
        '`read only` only at start-up.', '',
        '| name | type | default | range / allowed | applies | description |',
        '|---|---|---|---|---|---|',
    ]
    for p in PARAMS:
        lines.append(f'| `{p.name}` | {p.type} | `{_yaml_scalar(p.default)}` | '
                     f'{_md_cell(p.allowed())} | {p.applies} | {_md_cell(p.description)} |')
    return '\n'.join(lines) + '\n'


def help_text(width=92):
    """Return the parameter part of ``attitude_node --help``: name, default, range, text."""
    lines = []
    for p in PARAMS:
        allowed = p.allowed()
        bounds = f', {"one of" if p.choices else "range"} {allowed}' if allowed else ''
        lines.append(f'  {p.name} [{p.default!r}{bounds}]')
        lines += textwrap.wrap(p.full_description(), width, initial_indent=' ' * 6,
                               subsequent_indent=' ' * 6)
    return '\n'.join(lines)


def main(argv=None):
    """``python -m rigidrot_ros.run.params --yaml | --markdown | --help-text``: print one text."""
    args = sys.argv[1:] if argv is None else list(argv)
    texts = {'--yaml': yaml_text, '--markdown': markdown_text, '--help-text': help_text}
    if len(args) != 1 or args[0] not in texts:
        print('usage: python -m rigidrot_ros.run.params --yaml | --markdown | --help-text',
              file=sys.stderr)
        return 2
    sys.stdout.write(texts[args[0]]().rstrip('\n') + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
