"""Node settings without ROS: the default YAML, and parameters -> scene + solver options.

Shared by the node (live parameters) and the recorder/compare tools (logged metadata), so
that a scene is validated by one piece of code wherever it comes from.
"""

import math
import os
import sys

import yaml

from rigidrot_ros.core import MIN_TOL, Scene

__all__ = ['PACKAGE', 'SCENE_KEYS', 'BACKENDS', 'find_config', 'load_defaults',
           'scene_from_params', 'solver_options']

PACKAGE = 'rigidrot_ros'
SCENE_KEYS = ('inertia', 'torque', 'torque_frame', 'omega0', 'attitude0')
BACKENDS = ('auto', 'flint', 'mpmath')


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
            return dict(entry['ros__parameters'])
    raise ValueError(f'{path}: no ros__parameters section')


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
    if isinstance(tol, int) and not isinstance(tol, bool) and abs(tol) > 1e308:
        tol = math.inf                                          # an int beyond the float range
    if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not math.isfinite(tol) \
            or tol < MIN_TOL:
        raise ValueError(f'parameter tol must be a finite number >= {MIN_TOL} rad, got {tol!r}')
    backend = params.get('backend', 'auto')
    if backend not in BACKENDS:
        raise ValueError(f'parameter backend must be one of {BACKENDS}, got {backend!r}')
    return float(tol), (None if backend == 'auto' else backend)
