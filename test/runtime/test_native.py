"""Compiled kernels loaded as object code: the loader, the Python entries, the cache.

The loader (``runtime.native.ObjectCode``) is checked on objects LLVM makes here from
small IR modules (what it maps, calls and refuses); the engine's kernels as loaded against
the interpreted functions (shared source, no shared compilation) on random windows; the
entries' argument checks; and, in fresh processes, a cache that is damaged or made on
another machine, and a generation run that never imports numba.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from rigidrot_ros.core import engine
from rigidrot_ros.runtime import native

pytestmark = pytest.mark.skipif(
    not (sys.platform == 'linux' and os.uname().machine == 'x86_64'),
    reason='object code is loaded on x86-64 Linux only')


def _object(ir):
    """Return the ELF object LLVM emits for ``ir`` with numba's JIT settings."""
    import llvmlite.binding as ll
    from numba.core.registry import cpu_target
    tm = cpu_target.target_context.codegen()._tm
    mod = ll.parse_assembly(ir)
    mod.verify()
    return bytes(tm.emit_object(mod))


ADD = '''
@k = private unnamed_addr constant [2 x double] [double 1.5, double 2.25]
define double @add(double %x, i64 %i) {
  %p = getelementptr [2 x double], ptr @k, i64 0, i64 %i
  %c = load double, ptr %p
  %s = fadd double %x, %c
  %r = call double @sqrt(double %s)
  ret double %r
}
declare double @sqrt(double)
'''


def test_an_object_is_mapped_relocated_and_called():
    import ctypes
    functions = native.load_object(_object(ADD))
    add = ctypes.CFUNCTYPE(ctypes.c_double, ctypes.c_double, ctypes.c_int64)(
        functions['add'])
    assert add(14.5, 0) == 4.0                  # a constant in read-only data, libm's sqrt
    assert add(7.75, 1) == np.sqrt(10.0)


@pytest.mark.parametrize('ir, why', [
    ('define i64 @f() {\n  %r = call i64 @rigidrot_no_such_function()\n  ret i64 %r\n}\n'
     'declare i64 @rigidrot_no_such_function()', "undefined symbol 'rigidrot_no_such_"),
    ('@g = global i64 0\ndefine i64 @f() {\n  %v = load i64, ptr @g\n  ret i64 %v\n}',
     'writable section'),
])
def test_an_object_it_cannot_serve_is_refused_by_name(ir, why):
    with pytest.raises(native.NativeError, match=why):
        native.load_object(_object(ir))


def test_bytes_that_are_no_loadable_object_are_refused():
    obj = _object(ADD)
    with pytest.raises(native.NativeError, match='not an ELF object'):
        native.load_object(b'\x89PNG\r\n\x1a\n' + bytes(100))
    with pytest.raises(native.NativeError, match='truncated'):
        native.load_object(obj[:len(obj) // 2])
    rng = np.random.default_rng(5)
    for _ in range(200):                        # damaged anywhere: refused, never a crash
        bad = bytearray(obj)
        at = rng.integers(0, len(bad), 4)
        bad[at[0]:at[0] + 8] = rng.integers(0, 256, 8, dtype=np.uint8).tobytes()
        try:
            native.ObjectCode(bytes(bad))
        except native.NativeError:
            pass
    other = bytearray(obj)
    other[18:20] = (183).to_bytes(2, 'little')  # e_machine: AArch64
    with pytest.raises(native.NativeError, match='not x86-64'):
        native.load_object(bytes(other))


def test_the_engine_kernels_are_the_native_ones_here():
    state = engine.jit_state()
    assert state['how'] == 'native', state


def _window(rng):
    prm = np.array([rng.uniform(-2, 2), rng.uniform(-0.5, 0.5), rng.uniform(-1, 1),
                    rng.uniform(-1, 1), 0.0, 1e-17, 1e-17, 1e-18, 10 ** rng.uniform(-14, -6),
                    10 ** rng.uniform(-14, -6)])
    prm[4] = np.hypot(prm[2], prm[3])
    th = rng.uniform(0, 6.3)
    anc = np.array([np.cos(th), 0.1 * np.sin(th), np.sin(th), 0.0, 1e-16])
    anc[:4] /= np.linalg.norm(anc[:4])
    return prm, anc, rng.uniform(-50, 50), 10 ** rng.uniform(-3, 0.5)


def test_native_kernels_give_the_interpreted_bits_on_random_windows():
    k = engine.kernels()
    rng = np.random.default_rng(2026)
    for _ in range(60):
        prm, anc, a, tau = _window(rng)
        dt = rng.uniform(-tau, tau)
        got = k['eval_one'](prm, a, tau, dt, anc, np.empty((engine.MAX_TERMS, 4)))
        want = engine.eval_one(prm, a, tau, dt, anc, np.empty((engine.MAX_TERMS, 4)))
        assert np.array(got, dtype=float).tobytes() == np.array(want, dtype=float).tobytes()
        nb = 5
        ab, hs = a + tau * np.arange(nb), np.full(nb, tau)
        for name, k0, stop in (('chain', 0, nb), ('chain_back', nb - 1, 0)):
            runs = []
            for fn in (k[name], getattr(engine, name)):
                state, anc_b = anc.copy(), np.zeros((nb, 5))
                out = fn(prm, ab, hs, k0, stop, state, True, anc_b,
                         np.empty((engine.MAX_TERMS, 4)))
                runs.append((out, state.tobytes(), anc_b.tobytes()))
            assert runs[0] == runs[1], name
        anc_b = np.repeat(anc[None, :], nb, axis=0)
        t = np.sort(np.repeat(ab, 4) + rng.uniform(0, tau, 4 * nb))
        lo = np.arange(nb, dtype=np.int64) * 4
        runs = []
        for fn in (k['eval_many'], engine.eval_many):
            q, e, ok = np.zeros((4 * nb, 4)), np.zeros(4 * nb), np.zeros(nb, dtype=bool)
            fn(prm, ab, hs, anc_b, lo, lo + 4, t, q, e, ok, np.empty((engine.MAX_TERMS, 4)))
            runs.append((q.tobytes(), e.tobytes(), ok.tobytes()))
        assert runs[0] == runs[1]


def test_an_entry_checks_its_arguments_and_names_the_wrong_one():
    one = engine.kernels()['eval_one']
    prm = np.array([0.5, 0.05, 0.3, -0.2, 0.36, 0.0, 0.0, 0.0, 1e-12, 0.9e-12])
    anc, co = np.array([1.0, 0.0, 0.0, 0.0, 0.0]), np.empty((engine.MAX_TERMS, 4))
    assert one(prm, 0.0, 0.5, 0.25, anc, co) == engine.eval_one(prm, 0.0, 0.5, 0.25, anc, co)
    with pytest.raises(TypeError, match=r'eval_one\(\) takes 6 arguments'):
        one(prm, 0.0, 0.5, 0.25, anc)
    with pytest.raises(TypeError, match='argument 1: expected a C-contiguous 1-d float64'):
        one(prm.astype(np.float32), 0.0, 0.5, 0.25, anc, co)
    with pytest.raises(TypeError, match='argument 6: .* of 4 columns'):
        one(prm, 0.0, 0.5, 0.25, anc, np.empty((engine.MAX_TERMS, 5)))
    with pytest.raises(TypeError):
        one(prm, 'x', 0.5, 0.25, anc, co)
    with pytest.raises((TypeError, ValueError)):
        one(prm, 0.0, 0.5, 0.25, np.zeros((5, 2))[:, 0], co)           # strided
    with pytest.raises((TypeError, ValueError)):                         # read-only output
        one(prm, 0.0, 0.5, 0.25, anc, np.frombuffer(bytes(co.nbytes)).reshape(co.shape))
    assert one(prm, 0.0, 0.5, 0.25, anc, co) == engine.eval_one(prm, 0.0, 0.5, 0.25, anc, co)


def test_a_cache_file_is_whole_or_refused(tmp_path):
    path = str(tmp_path / 'k.native')
    native.write_cache(path, {'b': ('sym_b', b'\x7fELF-two'), 'a': ('sym_a', b'one')})
    assert native.read_cache(path) == {'a': ('sym_a', b'one'), 'b': ('sym_b', b'\x7fELF-two')}
    data = open(path, 'rb').read()
    open(path, 'wb').write(data[:-3])
    with pytest.raises(native.NativeError, match='truncated'):
        native.read_cache(path)
    open(path, 'wb').write(b'PK\x03\x04' + data)
    with pytest.raises(native.NativeError, match='not a kernel cache file'):
        native.read_cache(path)
    flipped = bytearray(data)
    flipped[-2] ^= 1                            # one bit of the code: never run
    open(path, 'wb').write(bytes(flipped))
    with pytest.raises(native.NativeError, match='does not match its checksum'):
        native.read_cache(path)


CHILD = r'''
import json, sys
sys.argv = ['x']
MACHINE
from rigidrot_ros.core import engine
from rigidrot_ros.bag import chunks
k = engine.kernels()
import numpy as np
prm = np.array([0.5, 0.05, 0.3, -0.2, 0.36, 0.0, 0.0, 0.0, 1e-12, 0.9e-12])
got = k['eval_one'](prm, 0.0, 0.5, 0.25, np.array([1.0, 0, 0, 0, 0]), np.empty((203, 4)))
print(json.dumps({'state': engine.jit_state(), 'got': [float(x) for x in got],
                  'numba': 'numba' in sys.modules, 'place': chunks.can_place()}))
'''


def _child(tmp_path, machine=None):
    code = CHILD.replace('MACHINE', '' if machine is None else
                         f'import platform\nplatform.machine = lambda: {machine!r}')
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / 'cache'), RIGIDROT_NO_JIT='',
               RIGIDROT_NO_NATIVE='')
    out = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_damaged_cache_is_built_anew_and_another_machine_takes_numba(tmp_path):
    first = _child(tmp_path)
    assert first['state']['how'] == 'native' and not first['state']['cached']
    files = sorted((tmp_path / 'cache').glob('*.native'))
    assert [f.name.split('.')[0] for f in files] == ['chunks', 'engine']
    again = _child(tmp_path)
    assert again['state']['cached'] and not again['numba'] and again['place']
    assert again['got'] == first['got']
    for f in files:                             # cut short, as by a full disk
        f.write_bytes(f.read_bytes()[:1000])
    rebuilt = _child(tmp_path)
    assert rebuilt['state']['how'] == 'native' and not rebuilt['state']['cached']
    assert rebuilt['got'] == first['got'] and rebuilt['place']
    assert _child(tmp_path)['state']['cached']
    other = _child(tmp_path, machine='aarch64')
    assert other['state']['how'] == 'numba' and 'x86-64 Linux only' in \
        other['state']['reason']
    assert other['got'] == first['got'] and other['place']


GENERATE = r'''
import sys
from rigidrot_ros.tools.generate import main
code = main(sys.argv[1:])
print('NUMBA', 'numba' in sys.modules, 'llvmlite' in sys.modules)
sys.exit(code)
'''


def test_generation_runs_without_numba_once_the_kernels_are_built(tmp_path):
    env = dict(os.environ, RIGIDROT_NO_JIT='', RIGIDROT_NO_NATIVE='')
    runs = []
    for i in range(2):              # the first may build the kernels; the second loads them
        out = subprocess.run(
            [sys.executable, '-c', GENERATE, '-o', str(tmp_path / f'bag{i}'), '--duration',
             '2', '--quiet', '-p', 'imu.enable:=true', '-p', 'star_tracker.enable:=true'],
            env=env, capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        runs.append(out.stdout.split('NUMBA')[-1].split())
    assert runs[1] == ['False', 'False'], runs
    bags = [sorted((tmp_path / f'bag{i}').glob('*.mcap')) for i in range(2)]
    assert bags[0][0].read_bytes() == bags[1][0].read_bytes()
