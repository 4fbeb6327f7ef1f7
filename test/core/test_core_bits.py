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

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


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


def test_taylor_anchors_do_not_depend_on_what_was_stepped_before():
    """Spacecraft (Taylor kernel): an anchor is the seeder's 1F1 at t, not a stepped state.

    Before, a far anchor stepped from whichever checkpoint was nearest, so its cost (and
    the rounding of its value) depended on the queries before it.
    """
    scene = SCENES['spacecraft']
    t = np.random.default_rng(7).uniform(0.0, 1e3, 40)
    cold = [solve(scene).at(float(x)) for x in t]              # every query in a fresh solve
    sol = solve(scene)
    kern = sol._kernel
    assert kern.method == 'taylor-series-flint'
    got = [sol.at(float(x)) for x in t]
    for i, s in enumerate(got):
        assert s.quaternion.tobytes() == cold[i].quaternion.tobytes(), f't={t[i]}'
        assert float(s.error_bound) == float(cold[i].error_bound)
    assert sol._dense.exact_anchors >= 4              # blocks of ~100 windows of 2 s
    assert all(len(times) == 1 for times, _ in kern._ck.values())      # nothing stepped


#: The scenes evaluated by dense output (the closed forms have none).
DENSE_SCENES = sorted(n for n in SCENES if solve(SCENES[n])._dense is not None)


@pytest.mark.parametrize('name', DENSE_SCENES)
def test_compiled_engine_gives_the_bits_of_the_interpreted_one(name):
    """numba's code makes the very float64 operations Python makes (no FMA, no reordering).

    Every window of a stretch, negative times too: samples (:func:`engine.eval_one`),
    batches (:func:`engine.eval_many`), chained anchors both ways (:func:`engine.chain`,
    :func:`engine.chain_back`) from the compiled kernels and from the same functions
    interpreted by Python, bit for bit.
    """
    from rigidrot_ros.core import engine
    # numba is an install requirement: the compiled engine must be in use here
    assert engine.jit_state()['compiled'], engine.jit_state()['reason']
    comp = engine.kernels()
    py = {'eval_one': engine.eval_one, 'eval_many': engine.eval_many,
          'chain': engine.chain, 'chain_back': engine.chain_back}
    # the module's Python functions call its _series/_horner, compiled where numba loaded
    # the kernels: swap those too
    glob = vars(engine)
    dense = solve(SCENES[name])._dense
    t = np.concatenate([np.linspace(-30.0, 400.0, 1500), [0.0, 1.0, 2.0, 1e-300]])
    blocks = {}
    for x in t.tolist():
        key = dense.key(x)
        if key is None:
            continue
        n = dense._index(key)
        b0, g = dense.block_of(n)
        blocks.setdefault((key[0], b0), (key[0], b0, g))
    co = np.empty((engine.MAX_TERMS, 4))
    saved = glob['_series'], glob['_horner'], glob['_own']
    try:
        for sign, b0, g in list(blocks.values())[:6]:
            runs = {}
            for mode in ('compiled', 'python'):
                fns = comp if mode == 'compiled' else py
                if mode == 'python':
                    glob['_series'], glob['_horner'], glob['_own'] = (
                        getattr(f, 'py_func', f) for f in saved)
                blk = dense._fill(sign, b0, g)
                a, hs = blk.a.copy(), blk.hs.copy()
                st = blk.fwd.copy()
                k, _ = fns['chain'](dense._prm, a, hs, blk.m, len(a), st, True, blk.anc, co)
                back = blk.anc[blk.m].copy()
                k2, _ = fns['chain_back'](dense._prm, a, hs, blk.m, 0, back, False, blk.anc,
                                          co)
                lo, hi = k2, k
                samples = [fns['eval_one'](dense._prm, float(a[i]), abs(float(hs[i])),
                                           0.37 * float(hs[i]), blk.anc[i], co)
                           for i in range(lo, hi)]
                tt = a[lo:hi] + 0.61 * hs[lo:hi]
                order = np.arange(hi - lo)
                out_q, out_e = np.empty((hi - lo, 4)), np.empty(hi - lo)
                ok = np.empty(hi - lo, dtype=np.bool_)
                fns['eval_many'](dense._prm, a[lo:hi], np.abs(hs[lo:hi]), blk.anc[lo:hi],
                                 order, order + 1, tt, out_q, out_e, ok, co)
                runs[mode] = (blk.anc[lo:hi].tobytes(), np.array(samples).tobytes(),
                              out_q.tobytes(), out_e.tobytes(), ok.tobytes(), st.tobytes())
                glob['_series'], glob['_horner'], glob['_own'] = saved
            assert runs['compiled'] == runs['python'], f'{name}: block {sign} {b0}'
    finally:
        glob['_series'], glob['_horner'], glob['_own'] = saved


@pytest.mark.parametrize('name', DENSE_SCENES)
def test_stepwise_chains_give_the_bits_of_whole_chains(name):
    """A block chained in steps (as queries reach it, both ways) equals one chained whole."""
    dense = solve(SCENES[name])._dense
    b0 = 3 * dense._blen
    g = dense._blen
    whole = dense._fill(1, b0, g)
    dense._chain(whole, g)
    dense._chain_back(whole, 0)
    steps = dense._fill(1, b0, g)
    for stop in np.random.default_rng(9).choice(np.arange(0, g), 12).tolist():
        if stop >= steps.hi:
            dense._chain(steps, stop + 1, whole=False)       # stops at the query's window
        if stop < steps.lo:
            dense._chain_back(steps, stop, whole=False)
    dense._chain(steps, g)
    dense._chain_back(steps, 0)
    assert (whole.lo, whole.hi, steps.lo, steps.hi) == (0, g, 0, g)
    assert whole.anc.tobytes() == steps.anc.tobytes()
