"""The torque-free triaxial body: a sample's bits depend on t alone (as test_core_bits).

The node evaluates its truth in look-ahead batches of varying size and per tick by scalar
calls, the offline generator in blocks: all must give the same bits for the same t. Each
case compares one array's quaternion, rate and bound with those of fresh solutions
evaluated in chunks, random splits, reversed order and one scalar call a sample, and
``omega_at`` (array and scalar) with the rate of :meth:`at`. The times mix the stream's
with far ones (1e4 ... 1e9 s) that need more pieces of the phase constants, so a batch
that holds them reduces its other samples' phases as they would be alone. Before the
change (a matrix product for the rate, the pieces chosen for a batch's largest t, libm's
exp and atan and math.hypot on the scalar path) chunks and scalar calls differed from the
array in 2351 of 2353 bounds on every scene, in up to 4 quaternions (chunks) and 96 rates
(scalar calls on the separatrix).
"""

import os

import numpy as np
import pytest
import yaml

from rigidrot_ros.core import Scene, solve
from rigidrot_ros.core.solution import Samples

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _preset():
    path = os.path.join(ROOT, 'config', 'torque_free_triaxial.yaml')
    with open(path, encoding='utf-8') as fh:
        p = yaml.safe_load(fh)['/**']['ros__parameters']
    return Scene(inertia=tuple(p['inertia']), torque=tuple(p['torque']),
                 torque_frame=p['torque_frame'], omega0=tuple(p['omega0']),
                 attitude0=tuple(p['attitude0']))


def _scenes():
    rng = np.random.default_rng(22)
    out = {'preset torque_free_triaxial': _preset()}
    for i in range(2):
        inertia = tuple(float(v) for v in rng.permutation([1.0, 1.7, 2.4]))
        out[f'random-{i}'] = Scene(inertia=inertia,
                                   omega0=tuple(float(v) for v in rng.uniform(-1, 1, 3)),
                                   attitude0=tuple(float(v) for v in rng.normal(size=4)))
    # h about the smallest axis (D below the middle moment), and on the separatrix
    out['about the smallest axis'] = Scene(inertia=(2.9, 2.1, 1.3), omega0=(0.7, 0.2, -0.1))
    out['separatrix'] = Scene(inertia=(3.0, 4.0, 6.0), omega0=(0.1, 1.0, 0.05),
                              attitude0=(0.1, 0.2, 0.3, 0.9))
    return out


SCENES = _scenes()
#: 100 Hz over 20 s, a stretch around 300 s, negative times, and far times
T = np.concatenate([np.arange(-50, 2000) / 100.0, 300.0 + np.arange(300) / 1000.0,
                    [1e4 + 0.1, -3e5 - 0.7, 1e6 + 0.3, 1e9 + 0.7]])


def _splits(n):
    rng = np.random.default_rng(7)
    out = {f'chunks of {c}': list(range(c, n, c)) for c in (1, 2, 7, 256)}
    out['random split'] = sorted(rng.choice(np.arange(1, n), 80, replace=False).tolist())
    return out


def _bytes(s):
    return (s.quaternion.tobytes(), s.omega.tobytes(),
            np.asarray(s.error_bound, dtype=float).tobytes())


def _cat(parts):
    return Samples(np.concatenate([p.t for p in parts]),
                   np.concatenate([p.quaternion for p in parts]),
                   np.concatenate([p.omega for p in parts]),
                   np.concatenate([p.error_bound for p in parts]))


def test_the_scenes_cover_both_methods():
    methods = {solve(s).method for s in SCENES.values()}
    assert methods == {'jacobi-elliptic-table', 'separatrix-closed-form'}


@pytest.mark.parametrize('name', sorted(SCENES))
def test_triaxial_any_split_gives_the_bits_of_one_array(name):
    scene = SCENES[name]
    whole = solve(scene).at(T)
    assert solve(scene).model == 'torque-free-triaxial'
    for label, cuts in _splits(len(T)).items():
        sol = solve(scene)
        got = _cat([sol.at(p) for p in np.split(T, cuts)])
        assert _bytes(got) == _bytes(whole), f'{name}: {label}'
    # one solution serving scalar calls in a random order, then arrays again
    sol = solve(scene)
    order = np.random.default_rng(3).permutation(len(T))
    for i in order:
        s = sol.at(float(T[i]))
        assert s.quaternion.tobytes() == whole.quaternion[i].tobytes(), f'{name}: t={T[i]}'
        assert s.omega.tobytes() == whole.omega[i].tobytes(), f'{name}: t={T[i]}'
        assert float(s.error_bound) == float(whole.error_bound[i]), f'{name}: t={T[i]}'
        assert sol.omega_at(float(T[i])).tobytes() == whole.omega[i].tobytes()
    rev = sol.at(T[::-1])
    assert _bytes(rev) == _bytes(Samples(T[::-1], whole.quaternion[::-1],
                                         whole.omega[::-1], whole.error_bound[::-1]))
    assert sol.omega_at(T).tobytes() == whole.omega.tobytes()
    assert sol.omega_at(T[:7]).tobytes() == whole.omega[:7].tobytes()
