"""Compiled code loads from numba's cache without numba's compiler registries.

``runtime.jit.cached_load`` makes a cache load refresh only numba's runtime; the whole
compiler (numpy's array implementations, linalg, typed containers...) is imported only
when something is compiled. Checked in fresh processes: after the core's kernels load
from a warm cache none of those modules is in the process, the kernels give the
interpreted functions' bits, and a function compiled afterwards in the same process gets
numba's whole compiler; a light load that fails is left to numba's own load. The
kernels load through numba here (``RIGIDROT_NO_NATIVE=1``): that is the way where the
object-code loader of ``runtime.native`` is not (another machine), and the MEKF's way.
"""

import json
import os
import subprocess
import sys

#: numba's own load of the kernels, not the object-code loader's
ENV = dict(os.environ, RIGIDROT_NO_NATIVE='1')

PROBE = r'''
import json, sys
import numpy as np
from rigidrot_ros.core import engine
k = engine.kernels()
state = engine.jit_state()
heavy = sorted(m for m in ('numba.np.linalg', 'numba.np.arraymath', 'numba.typed.typeddict',
                           'numba.np.npyimpl', 'scipy.linalg') if m in sys.modules)
prm = np.array([0.5, 0.05, 0.3, -0.2, 0.36, 0.0, 0.0, 0.0, 1e-12, 0.9e-12])
co = np.empty((engine.MAX_TERMS, 4))
anc = np.array([1.0, 0.0, 0.0, 0.0, 0.0])
got = [float(x) for x in np.ravel(k['eval_one'](prm, 0.0, 0.5, 0.25, anc, co))]
want = [float(x) for x in np.ravel(engine.eval_one(prm, 0.0, 0.5, 0.25, anc, co))]
import numba
@numba.njit(cache=False)
def fresh(a):
    return np.linalg.norm(a) + np.sum(np.sort(a))
print(json.dumps({'state': state, 'heavy': heavy, 'same': got == want,
                  'fresh': fresh(np.array([3.0, 4.0])),
                  'compiler_after': 'numba.np.arraymath' in sys.modules}))
'''


def _probe():
    proc = subprocess.run([sys.executable, '-c', PROBE], capture_output=True, text=True,
                          timeout=180, env=ENV)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_a_cache_load_skips_the_compiler_and_a_later_compile_gets_it():
    first = _probe()                      # compiles the kernels if the cache is cold
    assert first['state']['compiled'], first['state']['reason']     # numba is a dependency
    got = _probe() if first['state']['cached'] else first
    assert got['same'], 'a kernel loaded from the cache differs from the interpreted one'
    assert got['fresh'] == 12.0
    assert got['compiler_after'], "the later compile did not load numba's compiler"
    if first['state']['cached']:
        assert got['heavy'] == [], f'the cache load imported {got["heavy"]}'


FLAKY = r'''
import json, sys
from numba.core import caching
orig = caching.Cache._load_overload
failed = []
def flaky(self, sig, ctx):
    if not failed:
        failed.append(str(sig))
        raise RuntimeError('a load that fails once')
    return orig(self, sig, ctx)
caching.Cache._load_overload = flaky
from rigidrot_ros.core import engine
engine.kernels()
print(json.dumps({'state': engine.jit_state(), 'failed': len(failed),
                  'whole_refresh': 'numba.np.arraymath' in sys.modules}))
'''


def test_a_light_load_that_fails_is_left_to_numbas_own_load():
    proc = subprocess.run([sys.executable, '-c', FLAKY], capture_output=True, text=True,
                          timeout=180, env=ENV)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert got['state']['compiled'] and got['state']['how'] == 'numba', got
    assert got['failed'] == 1 and got['whole_refresh'], got
