"""The parameters of attitude_node, each defined once (no rclpy).

:data:`PARAMS` is the one table: name, type, default, description with units, range or
allowed values, whether it is read only, when a change applies, and its validator. From it
come the node's ``ParameterDescriptor`` s, the validation of every value (the node's
set-parameters callback, its start-up, the offline generator), ``config/default.yaml``,
``attitude_node --help`` and ``doc/parameters.md``; a test checks the files are up to date:

    python -m rigidrot_ros.params --yaml > config/default.yaml
    python -m rigidrot_ros.params --markdown > doc/parameters.md

A new parameter is one more :class:`Param` in :data:`PARAMS` (then regenerate both files);
rules across parameters (the inertia triangle inequality, a sensor rate of 0 meaning
``publish_rate``) stay in :mod:`rigidrot_ros.settings`.
"""

from dataclasses import dataclass
import math
import numbers
import sys
import textwrap
from typing import Any, Callable, Optional, Tuple

import yaml

from rigidrot_ros.core import MIN_TOL, TORQUE_FRAMES

__all__ = ['Param', 'PARAMS', 'BY_NAME', 'MAX_RATE', 'MIN_RATE', 'MAX_TOL', 'BACKENDS',
           'MAX_SEED', 'APPLIES', 'defaults', 'check', 'check_values', 'yaml_text',
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
    size = p.size
    if isinstance(v, (str, bytes)) or not hasattr(v, '__len__'):
        raise ValueError(f'parameter {p.name} must be a list of {size} numbers, got {v!r}')
    out = []
    for i, x in enumerate(v):
        if isinstance(x, bool) or not isinstance(x, numbers.Real):
            raise ValueError(f'parameter {p.name}[{i}] must be a number, got {x!r}')
        try:
            out.append(float(x))
        except OverflowError:                                   # an int beyond 1.8e308
            raise ValueError(f'parameter {p.name}[{i}] is beyond the float64 range '
                             f'(|x| <= 1.8e308)') from None
    if len(out) != size:
        raise ValueError(f'parameter {p.name} must have {size} numbers, got {len(out)}')
    return tuple(out)


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


#: Every parameter of attitude_node, in the order of ``config/default.yaml``.
PARAMS = (
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
    _switch('odom.enable', 'publish the truth as nav_msgs/Odometry on odom'),
    _switch('transform.enable', 'publish the truth as geometry_msgs/TransformStamped on '
            'transform'),
    _switch('markers.enable', 'publish the body as visualization_msgs/MarkerArray on markers'),
)

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
    missing one. Rules across parameters are :func:`rigidrot_ros.settings.prepare_run`'s.
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
    lines = ['# Defaults of attitude_node, generated from rigidrot_ros/params.py by',
             '#   python -m rigidrot_ros.params --yaml > config/default.yaml',
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
        'Generated from `rigidrot_ros/params.py` by '
        '`python -m rigidrot_ros.params --markdown` (edit the table, not this page); '
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
    """``python -m rigidrot_ros.params --yaml | --markdown | --help-text``: print one text."""
    args = sys.argv[1:] if argv is None else list(argv)
    texts = {'--yaml': yaml_text, '--markdown': markdown_text, '--help-text': help_text}
    if len(args) != 1 or args[0] not in texts:
        print('usage: python -m rigidrot_ros.params --yaml | --markdown | --help-text',
              file=sys.stderr)
        return 2
    sys.stdout.write(texts[args[0]]().rstrip('\n') + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
