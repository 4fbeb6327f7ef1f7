import sys, ctypes, time
def st(tag):
    d={l.split(':')[0]:int(l.split()[1])//1024 for l in open('/proc/self/status') if l.startswith(('VmHWM','RssAnon','RssFile'))}
    print(f'{tag:20s}', d)
t0=time.perf_counter()
import numpy as np; st('numpy')
import llvmlite.binding as ll; st('llvmlite')
ll.initialize_native_target(); ll.initialize_native_asmprinter()
cpu = ll.get_host_cpu_name(); feats = ll.get_host_cpu_features().flatten()
tm = ll.Target.from_default_triple().create_target_machine(cpu=cpu, features=feats, opt=3, reloc='static', codemodel='jitdefault', jit=True)
eng = ll.create_mcjit_compiler(ll.parse_assembly(''), tm); st('engine')
trap = ll.parse_assembly('''
declare void @llvm.trap()
define void @rigidrot_trap() {
  call void @llvm.trap()
  unreachable
}''')
eng.add_module(trap); eng.finalize_object()
ta = eng.get_function_address('rigidrot_trap')
for s in ['NRT_Free','NRT_MemInfo_call_dtor','numba_do_raise','numba_gil_ensure','numba_gil_release','numba_runtime_build_excinfo_struct','numba_unpickle']:
    ll.add_symbol(s, ta)
obj = open('em.o','rb').read()
eng.add_object_file(ll.ObjectFileRef.from_data(obj)); eng.finalize_object()
name = open('name').read()
addr = eng.get_function_address(name); st('loaded')
P = ctypes.c_void_p; I = ctypes.c_int64
fn = ctypes.CFUNCTYPE(I, *([P]*11 + [I]*4))(addr)
print('load s', time.perf_counter()-t0)
rng = np.random.default_rng(1)
nw, per = 64, 16; nt = nw*per
prm = np.array([0.3, 0.1, 0.2, 0.05, 0.2, 1e-17, 1e-17, 1e-18, 1e-9, 1e-9])
a_w = np.arange(nw)*0.5; tau_w = np.full(nw, 0.5)
anc = np.zeros((nw,5)); th = rng.uniform(0,6,nw); anc[:,0]=np.cos(th); anc[:,3]=np.sin(th); anc[:,4]=1e-16
lo = np.arange(nw)*per; hi = lo+per
t = np.repeat(a_w, per) + np.tile(np.linspace(0,0.5,per,endpoint=False), nw)
out_q = np.zeros((nt,4)); out_err = np.zeros(nt); ok = np.zeros(nw, dtype=np.bool_); co = np.zeros((256,4))
r = fn(*[x.ctypes.data for x in (prm,a_w,tau_w,anc,lo,hi,t,out_q,out_err,ok,co)], 10, nw, nt, 256)
st('called')
np.savez('loaded.npz', out_q=out_q, out_err=out_err, ok=ok)
np.savez('inputs.npz', prm=prm,a_w=a_w,tau_w=tau_w,anc=anc,lo=lo,hi=hi,t=t)
print(r, ok.sum(), out_q[:2])
