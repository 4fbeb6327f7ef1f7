"""Import of Kalibr's ``imu.yaml``: its noise model mapped to this package's parameters.

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

Accepted layouts: the keys at the top level (Kalibr's input ``imu.yaml``), or under one
``imuN`` mapping (Kalibr's result ``imu-*.yaml`` / ``camchain-imucam``); both at once
must agree. A missing key, a duplicated key, two ``imuN`` blocks, a top level and a
block that disagree, or a value out of range (negative, NaN, beyond the bounds) is refused with a
message naming the key.
"""

import math
import numbers
import re

import yaml

__all__ = ['load_kalibr_imu', 'KALIBR_KEYS']

#: Kalibr key -> (our parameter name, unit, upper bound)
KALIBR_KEYS = {
    'gyroscope_noise_density': ('imu.gyro_noise_density', 'rad/s/sqrt(Hz)', 1.0),
    'gyroscope_random_walk': ('imu.gyro_random_walk', 'rad/s^2/sqrt(Hz)', 1.0),
    'accelerometer_noise_density': ('accel.noise_density', 'm/s^2/sqrt(Hz)', 10.0),
    'accelerometer_random_walk': ('accel.random_walk', 'm/s^3/sqrt(Hz)', 10.0),
    'update_rate': ('imu.rate', 'Hz', 1e4),
}
_BLOCK = re.compile(r'^imu\d+$')


class _UniqueKeyLoader(yaml.SafeLoader):
    """A SafeLoader that refuses a mapping with the same key twice."""


def _unique_mapping(loader, node, deep=False):
    seen = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise ValueError(f'Kalibr file: key {key!r} appears twice (line '
                             f'{key_node.start_mark.line + 1}); which value is meant?')
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG,
                                 _unique_mapping)


def _value(path, key, raw):
    name, unit, upper = KALIBR_KEYS[key]
    if isinstance(raw, bool) or not isinstance(raw, numbers.Real):
        raise ValueError(f'{path}: {key} must be a number ({unit}), got {raw!r}')
    v = float(raw)
    low_ok = v > 0.0 if key == 'update_rate' else v >= 0.0
    if not math.isfinite(v) or not low_ok or not v <= upper:
        kind = 'positive' if key == 'update_rate' else 'nonnegative'
        raise ValueError(f'{path}: {key} must be a {kind} finite number <= {upper:g} '
                         f'{unit} (for {name}), got {raw!r}')
    return v


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
        ``imu.rate``; floats), to merge over the node's values, and Kalibr's
        ``rostopic``.

    Raises
    ------
    ValueError
        One line naming the problem: unreadable or truncated file, missing, duplicated
        or contradictory key, a value out of range.
    """
    try:
        with open(path, encoding='utf-8') as f:
            text = f.read()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f'cannot read Kalibr file {path}: {exc}') from None
    try:
        doc = yaml.load(text, Loader=_UniqueKeyLoader)
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
    for key in list(KALIBR_KEYS) + ['rostopic']:
        found = [(where, d[key]) for where, d in sources if key in d]
        if not found:
            raise ValueError(f'{path}: missing key {key} (Kalibr imu.yaml needs '
                             f'{", ".join(list(KALIBR_KEYS) + ["rostopic"])})')
        if len(found) == 2 and found[0][1] != found[1][1]:
            raise ValueError(f'{path}: contradictory {key}: {found[0][1]!r} at the top '
                             f'level, {found[1][1]!r} in {found[1][0]}')
        merged[key] = found[0][1]
    topic = merged['rostopic']
    if not isinstance(topic, str) or not topic.strip():
        raise ValueError(f'{path}: rostopic must be a topic name, got {topic!r}')
    params = {KALIBR_KEYS[k][0]: _value(path, k, merged[k]) for k in KALIBR_KEYS}
    return params, topic
