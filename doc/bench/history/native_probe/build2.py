import numpy as np, numba, sys, time
from numba import cfunc, types, carray, njit
from rigidrot_ros.core import engine as E
kw = dict(cache=False, fastmath=False, error_model='numpy')
E._series = njit(**kw)(E._series); E._horner = njit(**kw)(E._horner); E._own = njit(**kw)(E._own)
em = njit(**kw)(E.eval_many)
f8p = types.CPointer(types.float64); i8p = types.CPointer(types.int64); bp = types.CPointer(types.boolean)
sig = types.int64(f8p, f8p, f8p, f8p, i8p, i8p, f8p, f8p, f8p, bp, f8p, types.int64, types.int64, types.int64, types.int64)
@cfunc(sig, nopython=True, error_model='numpy')
def eval_many_c(prm, a_w, tau_w, anc_w, lo_w, hi_w, t, out_q, out_err, ok_w, co, nprm, nw, nt, nco):
    return em(carray(prm, (nprm,)), carray(a_w, (nw,)), carray(tau_w, (nw,)), carray(anc_w, (nw, 5)),
              carray(lo_w, (nw,)), carray(hi_w, (nw,)), carray(t, (nt,)), carray(out_q, (nt, 4)),
              carray(out_err, (nt,)), carray(ok_w, (nw,)), carray(co, (nco, 4)))
lib = eval_many_c._library
obj = lib._codegen._tm.emit_object(lib._final_module)
open('em.o','wb').write(obj)
open('name','w').write(eval_many_c.native_name)
print(len(obj))
