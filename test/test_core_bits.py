"""A sample's bits depend on t alone: any batch size, any split, scalar calls (issue 18).

The node evaluates its truth in look-ahead batches of varying size (and per tick by scalar
calls), the offline generator in blocks; both must publish the same bits for the same t.
Each case compares a fresh solution's one-array result with fresh solutions evaluated in
chunks, random splits, reversed order and one scalar call a sample: quaternion, rate and
bound equal bit for bit. Before the change, chunks of 7 and scalar calls differed from
the big array in about 1900 of 2000 quaternions.
"""

import glob
import os

import numpy as np
import pytest
import yaml

from rigidrot_ros.core import Scene, solve

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _presets():
    out = {}
    for path in sorted(glob.glob(os.path.join(ROOT, 'config', '*.yaml'))):
        with open(path, encoding='utf-8') as fh:
            p = yaml.safe_load(fh)['/**']['ros__parameters']
        if 'inertia' not in p:
            continue
        out[os.path.basename(path)[:-5]] = Scene(
            inertia=tuple(p['inertia']), torque=tuple(p['torque']),
            torque_frame=p['torque_frame'], omega0=tuple(p['omega0']),
            attitude0=tuple(p['attitude0']))
    return out


def _random_scenes():
    rng = np.random.default_rng(18)
    out = {}
    for i in range(3):
        i_t = float(rng.uniform(1.0, 3.0))
        out[f'random-axial-{i}'] = Scene(
            inertia=(i_t, i_t, float(rng.uniform(0.5, 4.0))),
            torque=(0.0, 0.0, float(rng.uniform(-0.05, 0.05))),
            omega0=tuple(float(v) for v in rng.normal(0, 0.5, 3)))
    out['random-sphere'] = Scene(
        inertia=(2.0, 2.0, 2.0), torque=tuple(float(v) for v in rng.normal(0, 0.02, 3)),
        omega0=tuple(float(v) for v in rng.normal(0, 0.5, 3)))
    out['random-virtual'] = Scene(
        inertia=(1.5, 1.5, 2.5), torque=(0.01, -0.02, 0.005), torque_frame='virtual',
        omega0=(0.2, 0.1, 0.7))
    out['spacecraft'] = Scene(inertia=(2.0, 2.0, 3.0), torque=(0.0, 0.0, 2e-4),
                              omega0=(0.3, -0.2, 0.5))
    out['fixed-axis'] = Scene(inertia=(1.0, 2.0, 3.0), torque=(0.0, 0.1, 0.0),
                              omega0=(0.0, 0.4, 0.0))
    return out


SCENES = {**{k: v for k, v in _presets().items() if 'triaxial' not in k}, **_random_scenes()}
#: 100 Hz over 20 s and a stretch around 300 s, negative times too
T = np.concatenate([np.arange(-50, 2000) / 100.0, 300.0 + np.arange(300) / 1000.0])


def _splits(n):
    rng = np.random.default_rng(7)
    out = {f'chunks of {c}': list(range(c, n, c)) for c in (1, 2, 7, 8, 9, 255, 256)}
    out['random split'] = sorted(rng.choice(np.arange(1, n), 80, replace=False).tolist())
    return out


def _same(a, b):
    return (a.quaternion.tobytes() == b.quaternion.tobytes()
            and a.omega.tobytes() == b.omega.tobytes()
            and np.asarray(a.error_bound).tobytes() == np.asarray(b.error_bound).tobytes())


def _cat(parts):
    from rigidrot_ros.core.solution import Samples
    return Samples(np.concatenate([p.t for p in parts]),
                   np.concatenate([p.quaternion for p in parts]),
                   np.concatenate([p.omega for p in parts]),
                   np.concatenate([p.error_bound for p in parts]))


@pytest.mark.parametrize('name', sorted(SCENES))
def test_any_split_gives_the_bits_of_one_array(name):
    scene = SCENES[name]
    whole = solve(scene).at(T)
    for label, cuts in _splits(len(T)).items():
        sol = solve(scene)
        got = _cat([sol.at(p) for p in np.split(T, cuts)])
        assert _same(got, whole), f'{name}: {label}'
    # one solution serving a random order of scalar calls, then the array again
    sol = solve(scene)
    order = np.random.default_rng(3).permutation(len(T))
    scal = {int(i): sol.at(float(T[i])) for i in order}
    for i in range(len(T)):
        s = scal[i]
        assert s.quaternion.tobytes() == whole.quaternion[i].tobytes(), f'{name}: t={T[i]}'
        assert s.omega.tobytes() == whole.omega[i].tobytes(), f'{name}: t={T[i]}'
        assert float(s.error_bound) == float(whole.error_bound[i]), f'{name}: t={T[i]}'
    assert _same(sol.at(T[::-1]), _cat([whole]).__class__(
        T[::-1], whole.quaternion[::-1], whole.omega[::-1], whole.error_bound[::-1]))
    assert sol.omega_at(T).tobytes() == whole.omega.tobytes()


def test_evicted_checkpoints_come_back_with_the_same_bits(monkeypatch):
    """A block dropped from the bounded store and rebuilt gives the same bits."""
    from rigidrot_ros.core import dense
    monkeypatch.setattr(dense, 'CHECKPOINT_BYTES', 1)         # only the block in use kept
    monkeypatch.setattr(dense, 'CACHE', 2)
    scene = SCENES['default']
    t = np.random.default_rng(5).uniform(0.0, 200.0, 300)
    ref = solve(scene).at(t)
    sol = solve(scene)
    got = [sol.at(float(x)) for x in t] + [sol.at(float(x)) for x in t[::-1]]
    for i, s in enumerate(got[:300]):
        assert s.quaternion.tobytes() == ref.quaternion[i].tobytes()
    for i, s in enumerate(got[300:]):
        assert s.quaternion.tobytes() == ref.quaternion[299 - i].tobytes()
    assert sol._dense.checkpoint_bytes() <= dense.BLOCK_BYTES
    assert len(sol._dense._scache) <= 2


#: The scenes evaluated by dense output (the closed forms have none).
DENSE_SCENES = sorted(n for n in SCENES if solve(SCENES[n])._dense is not None)


@pytest.mark.parametrize('name', DENSE_SCENES)
def test_batch_series_and_stepwise_chains_give_the_same_bits(name):
    """Batch series and stepwise chains give the bits of one-window series and whole chains.

    The numpy series of many windows equals the one-window series bit for bit, and a block
    chained in steps (as queries reach it) equals the block chained in one go.
    """
    sol = solve(SCENES[name])
    dense = sol._dense
    keys = sorted({dense.key(float(x)) for x in np.linspace(-30.0, 400.0, 3000)} - {None})
    args = []
    for key in keys:
        anchor = dense.anchor(key)
        if anchor is not None:
            sign, e, j = key
            lo, _, h = dense._octave(sign, e)
            args.append((sign * (lo + j * h), sign * h) + anchor)
    assert len(args) >= 64
    one = [dense._series(*a) for a in args]
    many = dense._series_many(*zip(*args))
    for w1, w2 in zip(one, many):
        assert np.array(w1.c1).tobytes() == np.array(w2.c1).tobytes()
        assert np.array(w1.c2).tobytes() == np.array(w2.c2).tobytes()
        assert (w1.bound, w1.own, w1.ok) == (w2.bound, w2.own, w2.ok)
    # one block chained whole, and again in random steps
    whole = dense._fill(1, 0, 128)
    dense._chain(whole, len(whole.errs))
    steps = dense._fill(1, 0, 128)
    for stop in sorted(np.random.default_rng(9).choice(np.arange(1, 129), 12).tolist()):
        if stop > steps.done:
            dense._chain(steps, stop)
    if steps.done < len(steps.errs):
        dense._chain(steps, len(steps.errs))
    for x, y in ((whole.c1s, steps.c1s), (whole.c2s, steps.c2s), (whole.errs, steps.errs)):
        assert x.tobytes() == y.tobytes()
