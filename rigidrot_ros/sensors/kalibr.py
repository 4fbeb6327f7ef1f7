"""Import of Kalibr's ``imu.yaml``: its noise model and intrinsics as this package's parameters.

Kalibr (ethz-asl/kalibr, wiki "IMU Noise Model") describes an IMU by continuous-time
densities, the same quantities :class:`ImuNoise` takes, so the mapping is one to one:

===============================  ==========================  ================
Kalibr key                       parameter                   unit
===============================  ==========================  ================
``gyroscope_noise_density``      ``imu.gyro_noise_density``  rad/s/sqrt(Hz)
``gyroscope_random_walk``        ``imu.gyro_random_walk``    rad/s^2/sqrt(Hz)
``accelerometer_noise_density``  ``accel.noise_density``     m/s^2/sqrt(Hz)
``accelerometer_random_walk``    ``accel.random_walk``       m/s^3/sqrt(Hz)
``update_rate``                  ``imu.rate``                Hz
``rostopic``                     (returned, not a param.)
===============================  ==========================  ================

Kalibr discretises them as ``sigma_d = sigma / sqrt(dt)`` (white) and
``sigma_bd = sigma_b sqrt(dt)`` (random walk) with ``dt = 1 / update_rate``; the
sensors here apply the same discretisation (the Markley–Crassidis form, which adds
``sigma_b^2 dt / 12`` to the white variance of a rate-integrating sensor), so no value
is scaled on import.

Intrinsics. ``model: calibrated`` (Kalibr's default; no ``model`` key means the same)
carries none. ``model: scale-misalignment`` (Kalibr's ``--imu-models``, Rehder et al.,
"Extending Kalibr", ICRA 2016) adds ``accelerometers: {M}`` and ``gyroscopes: {M, A,
C_gyro_i}``. Kalibr's measurement model (``IccScaledMisalignedImu`` in
``kalibr_imu_camera_calibration/IccSensors.py``: the residual is the measurement minus
the prediction plus the bias), with the IMU axes as the body axes (``T_i_b`` is not
read)::

    a_meas = M_a f + b_a                      (f: specific force in the IMU axes)
    w_meas = M_g C_gyro_i w + A C_gyro_i f + b_g

``M`` is the whole input-to-output matrix (Kalibr starts it at the identity and
estimates its lower triangle), ``C_gyro_i`` the rotation of the gyro triad from the IMU
axes, ``A`` the g-sensitivity, (rad/s)/(m/s^2). This package's model is
``y = C u + ...`` with ``C = I + diag(s) + M``, ``M`` off-diagonal
(:class:`ImuNoise`), so ``C_accel = M_a`` and ``C_gyro = M_g C_gyro_i``:
``*.scale_factor = diag(C) - 1`` and ``*.misalignment`` the off-diagonal of ``C``
(row-major, zero diagonal). The gyro has no g-sensitivity term here, so a file whose
``A`` is not zero is refused rather than simulated without it, and so is
``scale-misalignment-size-effect`` (per-axis accelerometer lever arms), or any other
``model``. The same bounds as the parameters apply (``|s_i| <= 0.5``,
``|M_ij| <= 0.1``), and ``C_gyro_i`` must be a rotation.

Accepted layouts: the keys at the top level (Kalibr's input ``imu.yaml``), or under one
``imuN`` mapping (Kalibr's result ``imu-*.yaml`` / ``camchain-imucam``); both at once
must agree. A missing key, a duplicated key, two ``imuN`` blocks, a top level and a
block that disagree, or a value out of range (negative, NaN, beyond the bounds) is refused with a
message naming the file and the key.
"""

import math
import numbers
import re
import reprlib

import numpy as np
import yaml

from .imu_noise import _MAX_MISALIGN, _MAX_SCALE

__all__ = ['load_kalibr_imu', 'KALIBR_KEYS', 'KALIBR_SOURCES', 'KALIBR_MODELS']

#: Kalibr key -> (our parameter name, unit, upper bound)
KALIBR_KEYS = {
    'gyroscope_noise_density': ('imu.gyro_noise_density', 'rad/s/sqrt(Hz)', 1.0),
    'gyroscope_random_walk': ('imu.gyro_random_walk', 'rad/s^2/sqrt(Hz)', 1.0),
    'accelerometer_noise_density': ('accel.noise_density', 'm/s^2/sqrt(Hz)', 10.0),
    'accelerometer_random_walk': ('accel.random_walk', 'm/s^3/sqrt(Hz)', 10.0),
    'update_rate': ('imu.rate', 'Hz', 1e4),
}
#: The ``model`` values imported (the others are refused).
KALIBR_MODELS = ('calibrated', 'scale-misalignment')
#: Our parameter -> the Kalibr key(s) its value comes from (for messages).
KALIBR_SOURCES = {name: key for key, (name, _, _) in KALIBR_KEYS.items()}
KALIBR_SOURCES.update({
    'imu.gyro_scale_factor': 'diag(gyroscopes.M C_gyro_i) - 1',
    'imu.gyro_misalignment': 'off-diagonal of gyroscopes.M C_gyro_i',
    'accel.scale_factor': 'diag(accelerometers.M) - 1',
    'accel.misalignment': 'off-diagonal of accelerometers.M',
})
_BLOCK = re.compile(r'^imu\d+$')
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxlist, _REPR.maxdict, _REPR.maxstring, _REPR.maxother = 3, 6, 4, 60, 60


def _short(v):
    """Return ``repr(v)``, bounded however big or nested ``v`` is (YAML aliases)."""
    return _REPR.repr(v)


_INTRINSICS = ('model', 'gyroscopes', 'accelerometers')


class _DuplicateKey(Exception):
    """A mapping with the same key twice (the loader does not know the file's path)."""


class _UniqueKeyLoader(yaml.SafeLoader):
    """A SafeLoader that refuses a mapping with the same key twice."""


def _unique_mapping(loader, node, deep=False):
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        try:
            twice = key in seen
        except TypeError:
            raise yaml.constructor.ConstructorError(
                None, None, f'found an unhashable key ({type(key).__name__})',
                key_node.start_mark) from None
        if twice:
            raise _DuplicateKey(f'key {key!r} appears twice (line '
                                f'{key_node.start_mark.line + 1}); which value is meant?')
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG,
                                 _unique_mapping)


def _value(path, key, raw):
    name, unit, upper = KALIBR_KEYS[key]
    if isinstance(raw, bool) or not isinstance(raw, numbers.Real):
        raise ValueError(f'{path}: {key} must be a number ({unit}), got {_short(raw)}')
    try:
        v = float(raw)
    except OverflowError:
        v = math.inf
    low_ok = v > 0.0 if key == 'update_rate' else v >= 0.0
    if not math.isfinite(v) or not low_ok or not v <= upper:
        kind = 'positive' if key == 'update_rate' else 'nonnegative'
        raise ValueError(f'{path}: {key} must be a {kind} finite number <= {upper:g} '
                         f'{unit} (for {name}), got {_short(raw)}')
    return v


def _matrix(path, key, raw):
    """Return the 3x3 float matrix of ``raw`` (three rows of three finite numbers)."""
    ok = isinstance(raw, list) and len(raw) == 3 and all(
        isinstance(row, list) and len(row) == 3 and all(
            isinstance(x, numbers.Real) and not isinstance(x, bool) for x in row)
        for row in raw)
    if ok:
        try:
            m = np.array(raw, dtype=float)
        except OverflowError:
            ok = False
        else:
            ok = bool(np.all(np.isfinite(m)))
    if not ok:
        raise ValueError(f'{path}: {key} must be a 3x3 matrix of finite numbers (three rows '
                         f'of three), got {_short(raw)}')
    return m


def _block(path, doc, key, fields):
    block = doc.get(key)
    if not isinstance(block, dict):
        raise ValueError(f'{path}: model scale-misalignment needs {key}: '
                         f'{{{", ".join(fields)}}} (Kalibr\'s intrinsics), got {_short(block)}')
    missing = [f for f in fields if f not in block]
    if missing:
        raise ValueError(f'{path}: missing key {key}.{missing[0]} (model scale-misalignment '
                         f'needs {", ".join(key + "." + f for f in fields)})')
    return {f: _matrix(path, f'{key}.{f}', block[f]) for f in fields}


def _error_terms(path, prefix, c, what):
    """Scale factor and misalignment of the input-to-output matrix ``c``, checked."""
    scale = np.diag(c) - 1.0
    mis = c - np.diag(np.diag(c))
    if np.any(np.abs(scale) > _MAX_SCALE) or np.any(np.abs(mis) > _MAX_MISALIGN):
        raise ValueError(f'{path}: {what} = {np.round(c, 6).tolist()} is beyond this '
                         f"package's error model ({prefix}scale_factor = diagonal - 1 "
                         f'within +-{_MAX_SCALE:g}, {prefix}misalignment = off-diagonal '
                         f'within +-{_MAX_MISALIGN:g} rad)')
    return {f'{prefix}scale_factor': [float(x) for x in scale],
            f'{prefix}misalignment': [float(x) for x in mis.ravel()]}


def _intrinsics(path, merged):
    """Parameters of Kalibr's ``model`` and its intrinsics (``{}`` for calibrated)."""
    model = merged.get('model', 'calibrated')
    given = [k for k in ('gyroscopes', 'accelerometers') if k in merged]
    if model == 'calibrated':
        if given:
            raise ValueError(f'{path}: {given[0]} (intrinsics) given, but the model is '
                             f'calibrated (none); say model: scale-misalignment to import '
                             f'them, or remove them')
        return {}
    if model != 'scale-misalignment':
        why = (' (its per-axis accelerometer lever arms are not modelled here)'
               if model == 'scale-misalignment-size-effect' else '')
        raise ValueError(f'{path}: model {_short(model)} cannot be imported{why}; this package '
                         f'reads {" or ".join(KALIBR_MODELS)}')
    acc = _block(path, merged, 'accelerometers', ('M',))
    gyro = _block(path, merged, 'gyroscopes', ('M', 'A', 'C_gyro_i'))
    rot = gyro['C_gyro_i']
    if not (np.allclose(rot @ rot.T, np.eye(3), rtol=0.0, atol=1e-6)
            and np.linalg.det(rot) > 0.0):
        raise ValueError(f'{path}: gyroscopes.C_gyro_i must be a rotation matrix '
                         f'(orthonormal, det +1, to 1e-6), got {rot.tolist()}')
    if np.any(gyro['A'] != 0.0):
        raise ValueError(f'{path}: gyroscopes.A (g-sensitivity, (rad/s)/(m/s^2)) is '
                         f'{gyro["A"].tolist()}, but the gyro modelled here has no '
                         f'g-sensitivity term: set A to zeros to import M and C_gyro_i '
                         f'without it')
    params = _error_terms(path, 'imu.gyro_', gyro['M'] @ rot, 'gyroscopes.M C_gyro_i')
    params.update(_error_terms(path, 'accel.', acc['M'], 'accelerometers.M'))
    return params


def load_kalibr_imu(path):
    """Read a Kalibr ``imu.yaml`` and map it to this package's parameter names.

    Parameters
    ----------
    path : str or os.PathLike
        The file.

    Returns
    -------
    (dict, str)
        The parameters by their dotted node names (``imu.gyro_noise_density``,
        ``imu.gyro_random_walk``, ``accel.noise_density``, ``accel.random_walk``,
        ``imu.rate``: floats; with ``model: scale-misalignment`` also
        ``imu.gyro_scale_factor``, ``imu.gyro_misalignment``, ``accel.scale_factor``,
        ``accel.misalignment``: lists of 3 and 9 floats), to merge over the node's
        values, and Kalibr's ``rostopic``.

    Raises
    ------
    ValueError
        One line naming the file and the problem: unreadable or truncated file, missing,
        duplicated or contradictory key, a value out of range, intrinsics this package
        cannot simulate.
    """
    try:
        with open(path, encoding='utf-8') as f:
            text = f.read()
    except (OSError, ValueError) as exc:        # ValueError: not UTF-8, a NUL in the path
        raise ValueError(f'cannot read Kalibr file {path}: {exc}') from None
    try:
        doc = yaml.load(text, Loader=_UniqueKeyLoader)
    except _DuplicateKey as exc:
        raise ValueError(f'{path}: {exc}') from None
    except RecursionError:
        raise ValueError(f'{path} is not valid YAML: nested too deeply to read') from None
    except yaml.YAMLError as exc:
        where = getattr(exc, 'problem_mark', None)
        line = f' at line {where.line + 1}' if where is not None else ''
        raise ValueError(f'{path} is not valid YAML{line}: '
                         f'{getattr(exc, "problem", None) or exc}') from None
    if not isinstance(doc, dict):
        raise ValueError(f'{path}: a Kalibr imu.yaml is a mapping of keys '
                         f'({", ".join(KALIBR_KEYS)}, rostopic), got {type(doc).__name__}')
    blocks = sorted(k for k, v in doc.items() if isinstance(k, str) and _BLOCK.match(k)
                    and isinstance(v, dict))
    if len(blocks) > 1:
        raise ValueError(f'{path}: {len(blocks)} IMU blocks ({", ".join(blocks)}); keep '
                         f'the one to simulate')
    sources = [('top level', {k: v for k, v in doc.items() if k not in blocks})]
    if blocks:
        sources.append((blocks[0], doc[blocks[0]]))
    merged = {}
    for key in list(KALIBR_KEYS) + ['rostopic'] + list(_INTRINSICS):
        found = [(where, d[key]) for where, d in sources if key in d]
        if not found:
            if key in _INTRINSICS:
                continue
            raise ValueError(f'{path}: missing key {key} (Kalibr imu.yaml needs '
                             f'{", ".join(list(KALIBR_KEYS) + ["rostopic"])})')
        if len(found) == 2 and found[0][1] != found[1][1]:
            raise ValueError(f'{path}: contradictory {key}: {_short(found[0][1])} at the '
                             f'top level, {_short(found[1][1])} in {found[1][0]}')
        merged[key] = found[0][1]
    topic = merged['rostopic']
    if not isinstance(topic, str) or not topic.strip():
        raise ValueError(f'{path}: rostopic must be a topic name, got {_short(topic)}')
    params = {KALIBR_KEYS[k][0]: _value(path, k, merged[k]) for k in KALIBR_KEYS}
    params.update(_intrinsics(path, merged))
    return params, topic
