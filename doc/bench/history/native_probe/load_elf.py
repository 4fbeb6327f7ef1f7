import sys, ctypes, time
def st(tag):
    d={l.split(':')[0]:int(l.split()[1])//1024 for l in open('/proc/self/status') if l.startswith(('VmHWM','RssAnon','RssFile'))}
    print(f'{tag:20s}', d)
t0=time.perf_counter()
import numpy as np; st('numpy')
from rigidrot_ros.runtime import native
fns = native.load_object(open('em.o','rb').read()); st('loaded')
name = open('name').read()
P = ctypes.c_void_p; I = ctypes.c_int64
fn = ctypes.CFUNCTYPE(I, *([P]*11 + [I]*4))(fns[name])
print('load s', time.perf_counter()-t0, 'llvmlite' in sys.modules, 'numba' in sys.modules)
d = np.load('inputs.npz'); L = np.load('loaded.npz')
nt = len(d['t']); nw=len(d['a_w'])
out_q = np.zeros((nt,4)); out_err = np.zeros(nt); ok = np.zeros(nw, dtype=np.bool_); co = np.zeros((256,4))
args=[d['prm'], d['a_w'], d['tau_w'], d['anc'], d['lo'], d['hi'], d['t'], out_q, out_err, ok, co]
r = fn(*[x.ctypes.data for x in args], 10, nw, nt, 256); st('called')
print(r, 'bit-identical', np.array_equal(out_q.view(np.int64), L['out_q'].view(np.int64)), np.array_equal(out_err, L['out_err']), (ok==L['ok']).all())
try:
    native.load_object(b'not elf')
except native.NativeError as e: print('refused:', e)
try:
    native.load_object(open('em.o','rb').read()[:3000])
except native.NativeError as e: print('refused:', e)
