import numpy as np
from rigidrot_ros.core import engine
K = engine._load()
d = np.load('inputs.npz'); L = np.load('loaded.npz')
nt = len(d['t']); nw=len(d['a_w'])
out_q = np.zeros((nt,4)); out_err = np.zeros(nt); ok = np.zeros(nw, dtype=np.bool_); co = np.zeros((256,4))
K['eval_many'](d['prm'], d['a_w'], d['tau_w'], d['anc'], d['lo'], d['hi'], d['t'], out_q, out_err, ok, co)
print('ok same', (ok==L['ok']).all(), ok.sum(), 'q bit-identical', np.array_equal(out_q.view(np.int64), L['out_q'].view(np.int64)), 'err', np.array_equal(out_err, L['out_err']))
