"""Fuzz: generated malformed campaign specs and Kalibr files, refused without a traceback.

Each malformed input goes through the CLI's ``main`` in process (a spec as the spec, a
Kalibr file as the spec's ``imu.kalibr_yaml``) and must give exit status 2 and one line
on stderr naming the problem, with nothing written; each Kalibr file also goes through
:func:`load_kalibr_imu`, which must raise ValueError naming the file. Every mutation is
invalid by construction (a value of the wrong type or out of range for its key, a
missing required key, broken YAML), and 1 to 3 are applied together, from a seeded
generator: the same cases every run. Each (key, bad value) is also tried alone, so that a
check early in the spec does not hide the later ones.
"""

import copy
import os
import sys

import numpy as np
import pytest
import yaml

from rigidrot_ros.sensors import load_kalibr_imu
from rigidrot_ros.tools.campaign import main

sys.path.insert(0, os.path.dirname(__file__))
from kalibr_helpers import _scale_misalignment, GOOD  # noqa: E402,I100,I202

PY = sys.executable
BASE = {
    'name': 'fuzz', 'seed': 3, 'runs': 2, 'duration': 1.0, 'timeout': 60,
    'base': {'overrides': {'imu.enable': True, 'star_tracker.enable': True}},
    'dispersions': {'attitude0': 'uniform',
                    'omega0': {'mean': [0.3, -0.2, 0.5], 'sigma': 0.05}},
    'estimator': {'factory': 'rigidrot_ros.estimators.mekf:make',
                  'params': {'sigma_v': 1.7e-4, 'sigma_u': 2e-5, 'bias_sigma': 2e-3}},
}
NUMBER_JUNK = ['x', None, [], {}, [1, 2], {'a': 1}, True, float('nan'), float('inf')]
#: (path, values each of which is invalid there). A path ending in '-' deletes the key.
BAD = [
    (('seed',), NUMBER_JUNK + [-1, 1.5, 2 ** 63, 10 ** 400]),
    (('runs',), NUMBER_JUNK + [0, -3, 2.5, 10 ** 7]),
    (('duration',), NUMBER_JUNK + [0, -1.0, 1e7, 10 ** 400]),
    (('timeout',), NUMBER_JUNK + [0, -5, 1e9]),
    (('sensor_seeds',), ['sometimes', 3, [], {'a': 1}, True, None]),
    (('base',), [[1], 'x', 3, True]),
    (('base', 'params_file'), ['no_such_scene.yaml', 3, [], '', 'a\0b', {'a': 1}]),
    (('base', 'overrides'), [[1], 'x', 3, {'no.such.param': 1}, {'imu.rate': -5.0},
                             {'inertia': [1.0, 2.0]}, {'torque': 'big'},
                             {'imu.gyro_noise_density': float('nan')},
                             {'imu.enable': 'maybe'}, {'omega0': [0.1, 0.2, None]}]),
    (('base', 'spare'), [1, 'x']),
    (('dispersions',), [[1], 'x', 3, {'mass': 1}, {'attitude0': 'normal'},
                        {'omega0': {'mean': [0, 0]}}, {'omega0': {'sigma': -1.0}},
                        {'omega0': {'sigma': 'wide'}}, {'omega0': {'mean': 0}},
                        {'imu.gyro_bias': {'sigma': [1, 2, 3, 4]}},
                        {'inertia': {'low': [1, 1, 1]}},
                        {'inertia': {'low': [-1, 1, 1], 'high': [1, 1, 1]}},
                        {'inertia': {'low': [1, 1, 5], 'high': [1, 1, 6]}},
                        {'torque': {'low': [1, 0, 0], 'high': [0, 0, 0]}},
                        {'torque': {'low': [0.1, 0, 0], 'high': [0.2, 0, 0]}},
                        {'torque': {'low': 'a', 'high': 'b'}}]),
    (('estimator',), [[1], 'x', 3, {}, {'factory': 'nocolon'},
                      {'factory': 'no_such_module_xyz:make'},
                      {'factory': 'rigidrot_ros.estimators.mekf:no_such_factory'},
                      {'factory': 'rigidrot_ros.estimators.mekf:make', 'command': PY},
                      {'factory': 'rigidrot_ros.estimators.mekf:make', 'rate': 2.0},
                      {'factory': 'rigidrot_ros.estimators.mekf:make', 'params': [1]},
                      {'factory': 'rigidrot_ros.estimators.mekf:make',
                       'params': {'sigma_v': -1.0}},
                      {'factory': 'rigidrot_ros.estimators.mekf:make',
                       'params': {'nonsense': 1}},
                      {'command': f'{PY} -c "unbalanced'}, {'command': "it's"},
                      {'command': 5}, {'command': []}, {'command': [1, 2]},
                      {'command': 'no_such_estimator_xyz'},
                      {'command': PY, 'topics': 5}, {'command': PY, 'topics': []},
                      {'command': PY, 'topics': [3]}, {'command': PY, 'inputs': {}},
                      {'command': PY, 'inputs': [None]}, {'command': PY, 'rate': 0},
                      {'command': PY, 'rate': 'fast'}, {'command': PY, 'settle': -1},
                      {'command': PY, 'domain_base': 300},
                      {'command': PY, 'domain_base': 200, 'domain_span': 50},
                      {'command': PY, 'domain_span': 0}, {'command': PY, 'params': {}},
                      {'command': PY, 'colour': 'red'}]),
    (('spare_key',), [1, 'x', None]),
    (('seed-',), [None]), (('runs-',), [None]), (('duration-',), [None]),
    (('estimator-',), [None]),
]
#: YAML that does not load, or loads as something other than a mapping.
SYNTAX = ['seed: [1, 2\n', 'seed: {a: 1\n', 'a:\n\t- 1\n', 'seed: "open\n', 'a: *nope\n',
          '- 1\n- 2\n', '42\n', '"just a string"\n', '', '~\n', 'a: b: c\n', '? [1, 2]\n: 3\n',
          'a: ' + '[' * 600 + ']' * 600 + '\n', '%YAML 9.9\n---\na: 1\n', '!!python/none x\n',
          'a: !!binary "###"\n', 'seed: 1\nseed: 2\n' + '  x\n']
SYNTAX_BYTES = [b'\xff\xfe\x00seed: 1\n', b'seed: \x80\x81\n', b'\x00' * 10]


def _mutate(doc, path, value):
    *parents, last = path
    node = doc
    for key in parents:
        if not isinstance(node.get(key), dict):
            node[key] = {}
        node = node[key]
    if last.endswith('-'):
        node.pop(last[:-1], None)
    else:
        node[last] = value


def _specs(rng, count):
    """Every (key, bad value) alone, then ``count`` specs with 2 or 3 of them, then broken YAML."""
    pairs = [(path, v) for path, values in BAD for v in values]
    chosen = [[k] for k in range(len(pairs))] + [
        rng.choice(len(pairs), size=int(rng.integers(2, 4)), replace=False)
        for _ in range(count)]
    out = []
    for ks in chosen:
        doc = copy.deepcopy(BASE)
        for k in ks:
            _mutate(doc, pairs[k][0], copy.deepcopy(pairs[k][1]))
        out.append(yaml.safe_dump(doc, allow_unicode=True).encode('utf-8'))
    text = yaml.safe_dump(BASE).encode('utf-8')
    for _ in range(count // 2):     # a valid spec cut anywhere, ending in an open sequence
        cut = int(rng.integers(1, len(text) - 1))
        out.append(text[:cut] + b'\nbad: [1, 2\n')
    return out + [s.encode('utf-8') for s in SYNTAX] + SYNTAX_BYTES


# -- Kalibr files ------------------------------------------------------------------------------
_KALIBR_VALUES = ['x', '-1.0', '.nan', '.inf', '1e400', '[]', '{}', 'true', 'null', '1.0e5',
                  '[1, 2]']


def _kalibr_files(rng, count):
    good = GOOD.splitlines(keepends=True)
    keyed = [i for i, line in enumerate(good) if ':' in line and not line.startswith('#')]
    out = []
    for n in range(count):
        kind = n % 6
        if kind == 0:                           # a required key gone
            drop = keyed[int(rng.integers(len(keyed)))]
            out.append(''.join(good[:drop] + good[drop + 1:]))
        elif kind == 1:                         # a value of the wrong type or range
            i = keyed[int(rng.integers(len(keyed)))]
            key = good[i].split(':')[0]
            bad = _KALIBR_VALUES[int(rng.integers(len(_KALIBR_VALUES)))]
            if key == 'rostopic':
                bad = ['5', '[]', '""', '{a: 1}'][int(rng.integers(4))]
            if key == 'update_rate' and bad == '1.0e5':
                bad = '0.0'
            out.append(''.join(good[:i] + [f'{key}: {bad}\n'] + good[i + 1:]))
        elif kind == 2:                         # a key twice, or two IMU blocks, or both
            i = keyed[int(rng.integers(len(keyed)))]
            extra = [good[i], 'imu0:\n  update_rate: 1.0\nimu1:\n  update_rate: 1.0\n',
                     'imu0:\n  update_rate: 7.0\n'][int(rng.integers(3))]
            out.append(GOOD + extra)
        elif kind == 3:                         # intrinsics it cannot import
            choice = int(rng.integers(7))
            m = [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]
            out.append([
                _scale_misalignment(a=[[0, 0, 1e-3], [0, 0, 0], [0, 0, 0]]),
                _scale_misalignment(model=['scale-misalignment-size-effect', 'affine', '5',
                                           '[1]'][int(rng.integers(4))]),
                _scale_misalignment(rot=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]),
                _scale_misalignment(m_gyro=[[1.0 + float(rng.uniform(0.6, 2)), 0, 0],
                                            [0, 1, 0], [0, 0, 1]]),
                _scale_misalignment(m_gyro=[[1, 0], [0, 1]]),
                _scale_misalignment(m_gyro=[row[:] for row in m[:2]] + [['a', 0, 1]]),
                _scale_misalignment(model='calibrated'),
            ][choice])
        elif kind == 4:                         # cut anywhere, ending in an open sequence
            text = _scale_misalignment()
            cut = int(rng.integers(1, len(text) - 2))
            out.append(text[:cut] + '\nbad: [1, 2\n')
        else:                                   # not a Kalibr mapping at all
            out.append(['- 1\n', '3\n', '', 'a: [1\n', '? [1]\n: 2\n', 'imu0: 5\n',
                        'imu0: &a [1, 2]\nimu1: *a\n'][int(rng.integers(7))])
    out.append('a: ' + '{a: ' * 600 + '}' * 600 + '\n')   # deeper than Python's recursion
    return out


def _listing(root):
    return sorted(os.path.relpath(os.path.join(d, f), root) for d, _, fs in os.walk(root)
                  for f in fs + ['']) if os.path.isdir(root) else []


def test_malformed_specs_and_kalibr_files_give_one_line_and_write_nothing(
        tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(20261127)
    specs = _specs(rng, 40)
    kalibr = _kalibr_files(rng, 107)
    paths = []
    for i, data in enumerate(specs):
        p = tmp_path / f'spec{i:03d}.yaml'
        p.write_bytes(data)
        paths.append(str(p))
    for i, text in enumerate(kalibr):
        k = tmp_path / f'imu{i:03d}.yaml'
        k.write_text(text)
        with pytest.raises(ValueError) as err:
            load_kalibr_imu(k)
        msg = str(err.value)
        assert str(k) in msg and '\n' not in msg, (text, msg)
        doc = copy.deepcopy(BASE)
        doc['base']['overrides']['imu.kalibr_yaml'] = str(k)
        p = tmp_path / f'kspec{i:03d}.yaml'
        p.write_text(yaml.safe_dump(doc))
        paths.append(str(p))
    assert len(specs) >= 200 and len(kalibr) >= 100
    before = _listing(tmp_path)
    out = tmp_path / 'out'
    for path in paths:
        status = main([path, '-o', str(out), '--quiet'])
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert status == 2 and len(lines) == 1 and lines[0].startswith('rigidrot_campaign: ') \
            and 'Traceback' not in err, (open(path, 'rb').read()[:300], err)
        assert not out.exists()
    assert _listing(tmp_path) == before
