"""Compiled kernels kept as machine code and loaded without numba or LLVM.

numba compiles a function for this processor, and its cache holds the machine code. But
loading that code back takes numba and LLVM into the process: ``import numba`` is about
70 MB and 0.3 s, and loading the core's kernels another 40 MB. Before this module, 136 MB
of the generation benchmark's 186 MB peak was there before the first sample. A kernel
that is plain arithmetic on arrays needs none of it to run. So:

- **Built once** (:func:`load_kernels` on a cache miss; numba imported there). Each kernel
  is compiled as a C function (``numba.cfunc``: pointers and integers in, an int64 out).
  A Python entry for it (:func:`trampoline_ir`, a ``METH_FASTCALL`` function in LLVM IR)
  is linked into the same module, and numba's own code generator emits the object: an
  ELF relocatable object, the machine code numba would run itself.
- **Loaded** (:class:`ObjectCode`). The object is mapped into executable memory: its
  sections copied, its relocations applied (x86-64: the large code model of numba's JIT
  settings, absolute 64-bit addresses), its symbols resolved in this process. Each entry
  becomes a Python builtin (:func:`python_function`). A call costs less than numba's
  dispatcher: 0.43 µs against 0.60 µs for one sample (2026-11-28).

What the object may call is checked, not assumed. Functions of this process (libm, the
Python C API) are resolved by name. Some numba helpers are called only on a C function's
error path, to raise a Python exception from compiled code; a kernel compiled with
``error_model='numpy'`` and without ``raise`` never reaches them. Those
(:data:`TRAPPED`) point at an instruction that stops the process (``ud2``), so that a
path believed dead can never run on garbage. Any other undefined symbol, relocation type
or writable section, or a machine other than x86-64 Linux, raises :class:`NativeError`
with the reason, and the caller takes numba's own load.

The cache (:func:`cache_path`) is one file per kernel set, beside numba's. Its key covers
the kernels' source and this module's, numba's and llvmlite's versions and settings,
Python's version, and this processor (``/proc/cpuinfo``'s model and flags: numba
compiles for the host). A change of any of them builds anew, and so does a damaged file.
"""

import contextlib
import ctypes
import fcntl
import hashlib
import json
import mmap
import os
import platform
import struct
import sys

__all__ = ['NativeError', 'ObjectCode', 'load_object', 'load_kernels', 'load_ir', 'c_signature',
           'trampoline_ir', 'python_function', 'cache_path', 'cache_key', 'read_cache',
           'write_cache', 'TRAPPED']

#: numba helpers referenced only by a C function's error path (building and raising a
#: Python exception, releasing arrays that a C function's views never own): resolved to a
#: trap, since a kernel without ``raise`` compiled with ``error_model='numpy'`` cannot
#: reach them.
TRAPPED = frozenset({
    'NRT_Free', 'NRT_MemInfo_call_dtor', 'numba_do_raise', 'numba_gil_ensure',
    'numba_gil_release', 'numba_runtime_build_excinfo_struct', 'numba_unpickle'})

_MAGIC = b'RIGIDROT-NATIVE-1\n'
_EHDR = struct.Struct('<16sHHIQQQIHHHHHH')
_SHDR = struct.Struct('<IIQQQQIIQQ')
_SYM = struct.Struct('<IBBHQQ')
_RELA = struct.Struct('<QQq')
_SHT_PROGBITS, _SHT_SYMTAB, _SHT_RELA, _SHT_NOBITS = 1, 2, 4, 8
_SHF_WRITE, _SHF_ALLOC = 1, 2
_SHN_UNDEF, _SHN_ABS = 0, 0xfff1
_EM_X86_64 = 62
_R_X86_64_64, _R_X86_64_PC32, _R_X86_64_PLT32 = 1, 2, 4
_UD2 = b'\x0f\x0b'
#: The largest object mapped (bytes of its sections): the kernels take tens of kB.
_MAX_MAP = 1 << 26


class NativeError(RuntimeError):
    """The object code cannot be loaded here; the message says why."""


def _cstr(table, offset):
    end = table.index(b'\0', offset)
    return table[offset:end].decode('ascii', 'replace')


class ObjectCode:
    """An ELF relocatable object mapped into executable memory: its functions by name.

    ``data``: the object file's bytes (``ET_REL``, x86-64). Raises :class:`NativeError`
    naming what it cannot load. The memory stays mapped for the life of the process (the
    functions' addresses are handed out); :attr:`functions` maps each global function
    defined to its address.
    """

    def __init__(self, data):
        data = bytes(data)
        if len(data) < _EHDR.size or data[:4] != b'\x7fELF':
            raise NativeError('not an ELF object')
        ident, e_type, machine, _, _, _, shoff, _, _, _, _, shentsize, shnum, shstrndx = \
            _EHDR.unpack_from(data)
        if ident[4] != 2 or ident[5] != 1:
            raise NativeError('not a 64-bit little-endian ELF object')
        if e_type != 1:
            raise NativeError(f'ELF type {e_type}, not a relocatable object')
        if machine != _EM_X86_64:
            raise NativeError(f'ELF machine {machine}, not x86-64')
        if shentsize != _SHDR.size or shoff + shnum * shentsize > len(data):
            raise NativeError('truncated or malformed section headers')
        self._data = data
        self._sec = [_SHDR.unpack_from(data, shoff + i * shentsize) for i in range(shnum)]
        for s in self._sec:
            if s[1] != _SHT_NOBITS and s[4] + s[5] > len(data):
                raise NativeError('truncated object: a section runs past the end')
        self._names = self._sec[shstrndx][4] if shstrndx < shnum else 0
        try:
            self._place()
            self.functions = self._relocate()
        except (ValueError, IndexError, struct.error) as exc:    # a name, an index, a size
            raise NativeError(f'malformed ELF object ({exc})') from None

    def _name(self, i):
        return _cstr(self._data, self._names + self._sec[i][0])

    def _place(self):
        """Lay the loaded sections out in one anonymous mapping (read-write for now)."""
        self._base = {}
        offset = 0
        for i, (_, typ, flags, _, _, size, _, _, align, _) in enumerate(self._sec):
            if not flags & _SHF_ALLOC or size == 0 or self._name(i) == '.eh_frame':
                continue                    # nothing unwinds through a kernel
            if flags & _SHF_WRITE:
                raise NativeError(f'writable section {self._name(i)!r}: a kernel keeps '
                                  'no state')
            if typ not in (_SHT_PROGBITS, _SHT_NOBITS):
                raise NativeError(f'section {self._name(i)!r} of type {typ:#x}')
            align = max(int(align), 1)
            offset = -(-offset // align) * align
            self._base[i] = offset
            offset += size
        self._trap = -(-offset // 16) * 16
        if self._trap > _MAX_MAP:
            raise NativeError(f'sections of {self._trap} bytes: too large for a kernel')
        size = -(-(self._trap + len(_UD2)) // mmap.PAGESIZE) * mmap.PAGESIZE
        try:
            self._map = mmap.mmap(-1, size, prot=mmap.PROT_READ | mmap.PROT_WRITE)
        except OSError as exc:
            raise NativeError(f'cannot map {size} bytes: {exc.strerror}') from None
        for i, off in self._base.items():
            _, typ, _, _, src, n, *_ = self._sec[i]
            if typ == _SHT_PROGBITS:
                self._map[off:off + n] = self._data[src:src + n]
        self._map[self._trap:self._trap + len(_UD2)] = _UD2
        self._view = ctypes.c_char.from_buffer(self._map)     # held: the map stays open
        self._addr = ctypes.addressof(self._view)
        self._size = size

    def _symbols(self):
        tabs = [i for i, s in enumerate(self._sec) if s[1] == _SHT_SYMTAB]
        if len(tabs) != 1:
            raise NativeError(f'{len(tabs)} symbol tables, not one')
        _, _, _, _, off, size, link, *_ = self._sec[tabs[0]]
        strtab = self._data[self._sec[link][4]:self._sec[link][4] + self._sec[link][5]]
        out = []
        for k in range(size // _SYM.size):
            name, info, _, shndx, value, _ = _SYM.unpack_from(self._data, off + k * _SYM.size)
            out.append((_cstr(strtab, name), info, shndx, value))
        return out

    def _resolve(self, sym):
        """Return the address of symbol ``sym`` (name, info, shndx, value)."""
        name, _, shndx, value = sym
        if shndx == _SHN_UNDEF:
            if name in TRAPPED:
                return self._addr + self._trap
            try:
                return ctypes.cast(getattr(_PROCESS, name), ctypes.c_void_p).value
            except AttributeError:
                raise NativeError(f'undefined symbol {name!r}: not in this process') \
                    from None
        if shndx == _SHN_ABS:
            return value
        if shndx not in self._base:
            raise NativeError(f'symbol {name!r} in section {self._name(shndx)!r}, '
                              'which is not loaded')
        return self._addr + self._base[shndx] + value

    def _relocate(self):
        """Apply the relocations of the loaded sections; make the mapping read + execute."""
        syms = self._symbols()
        buf = (ctypes.c_char * self._size).from_address(self._addr)
        for s in self._sec:
            if s[1] != _SHT_RELA or s[7] not in self._base:
                continue                    # the relocations of a section not loaded
            target = self._base[s[7]]
            for k in range(s[5] // _RELA.size):
                r_off, info, addend = _RELA.unpack_from(self._data, s[4] + k * _RELA.size)
                kind, index = info & 0xffffffff, info >> 32
                if r_off + (8 if kind == _R_X86_64_64 else 4) > self._sec[s[7]][5]:
                    raise NativeError('a relocation outside its section')
                where = target + r_off
                value = self._resolve(syms[index]) + addend
                if kind == _R_X86_64_64:
                    struct.pack_into('<Q', buf, where, value & 0xffffffffffffffff)
                elif kind in (_R_X86_64_PC32, _R_X86_64_PLT32):
                    rel = value - (self._addr + where)
                    if not -2 ** 31 <= rel < 2 ** 31:
                        raise NativeError(f'a 32-bit relative relocation to '
                                          f'{syms[index][0]!r} is out of range')
                    struct.pack_into('<i', buf, where, rel)
                else:
                    raise NativeError(f'relocation type {kind} is not supported')
        if _mprotect(self._addr, self._size, mmap.PROT_READ | mmap.PROT_EXEC) != 0:
            raise NativeError(f'mprotect: {os.strerror(ctypes.get_errno())}')
        return {name: self._resolve((name, info, shndx, value))
                for name, info, shndx, value in syms
                if info >> 4 == 1 and info & 15 == 2 and shndx not in (_SHN_UNDEF, _SHN_ABS)}


_PROCESS = ctypes.CDLL(None, use_errno=True)
#: The mapped objects and the method definitions of their entries: never freed, not even
#: as the interpreter finalizes (each list holds an extra reference). An entry can outlive
#: its module's globals (a kernel table, a solution's tuple of kernels), and both its code
#: and its definition (which a builtin reads as it is freed) must outlive the entry.
_MAPPED = []
_DEFS = []
ctypes.pythonapi.Py_IncRef(ctypes.py_object(_MAPPED))
ctypes.pythonapi.Py_IncRef(ctypes.py_object(_DEFS))
_mprotect = _PROCESS.mprotect
_mprotect.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
_mprotect.restype = ctypes.c_int


def _check_platform():
    """Raise :class:`NativeError` unless this is x86-64 Linux (what the loader maps)."""
    if sys.platform != 'linux' or platform.machine() not in ('x86_64', 'AMD64'):
        raise NativeError(f'object code is loaded on x86-64 Linux only, not '
                          f'{sys.platform} {platform.machine()}')


def load_object(data):
    """Map ``data`` (an ELF object) and return its functions' addresses by name."""
    _check_platform()
    code = ObjectCode(data)
    _MAPPED.append(code)            # mapped for the life of the process: addresses are out
    return code.functions


# -- the cache -------------------------------------------------------------------------------
def _cpu():
    """Return this processor as numba compiles for it: model and flags (``/proc/cpuinfo``)."""
    try:
        with open('/proc/cpuinfo', encoding='ascii', errors='replace') as f:
            lines = f.read().split('\n\n')[0].splitlines()
    except OSError:
        return platform.machine()
    keep = ('vendor_id', 'cpu family', 'model', 'model name', 'flags')
    return '\n'.join(ln for ln in lines if ln.split(':')[0].strip() in keep)


def _version(dist):
    from importlib import metadata
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return ''


def cache_key(*sources):
    """Return the cache key of kernels built from ``sources`` (str or bytes) here."""
    h = hashlib.sha256()
    # numba's own settings of the code it makes (its target and optimisation level)
    names = ('NUMBA_CPU_NAME', 'NUMBA_CPU_FEATURES', 'NUMBA_OPT')
    tuning = [os.environ.get(v, '') for v in names]
    for part in (*sources, _version('numba'), _version('llvmlite'), sys.version, _cpu(),
                 *tuning):
        h.update(part if isinstance(part, bytes) else str(part).encode())
        h.update(b'\0')
    return h.hexdigest()[:32]


def cache_path(module_file, name, key):
    """Where the kernel set ``name`` with ``key`` is kept: a writable directory's file.

    ``NUMBA_CACHE_DIR`` when set (as numba's own cache), else ``__pycache__`` beside
    ``module_file``, else the user's cache directory; None where none is writable.
    """
    user = os.path.join(os.environ.get('XDG_CACHE_HOME') or
                        os.path.join(os.path.expanduser('~'), '.cache'), 'rigidrot_ros')
    dirs = [os.environ['NUMBA_CACHE_DIR']] if os.environ.get('NUMBA_CACHE_DIR') else \
        [os.path.join(os.path.dirname(os.path.abspath(module_file)), '__pycache__'), user]
    for d in dirs:
        try:
            os.makedirs(d, exist_ok=True)
        except OSError:
            continue
        if os.access(d, os.W_OK):
            return os.path.join(d, f'{name}.{key}.native')
    return None


def _object(cfunc, name, spec, result, nogil=False):
    """Return the object code of ``cfunc`` with its Python entry ``rr_<name>`` linked in.

    The C function's module is numba's final (linked, optimised) one; the entry
    (:func:`trampoline_ir`) is linked into a copy of it, and the object emitted by numba's
    own code generator, with numba's JIT settings for this processor. Raises
    :class:`NativeError` where this numba does not have the parts used.
    """
    import llvmlite.binding as ll
    try:
        lib = cfunc._library
        final = lib._final_module.clone()
        tm = lib._codegen._tm
    except AttributeError as exc:
        raise NativeError(f'this numba does not expose its object code ({exc})') from None
    entry = ll.parse_assembly(trampoline_ir(name, cfunc.native_name, spec, result, nogil))
    entry.verify()
    final.link_in(entry)
    return bytes(tm.emit_object(final))


def c_signature(spec, result):
    """Return the numba signature of the C function behind a call ``spec``.

    ``'f'``: float64; ``'i'`` and ``'b'``: int64; an array ``(kind, ndim, width, out)``:
    a pointer to its items and its length, and its second dimension too where ``width`` is
    None; a ``'sample'`` result adds a pointer to 5 float64 (x, y, z, w, bound). The
    function returns an int64.
    """
    from numba import types
    item = {'f8': types.float64, 'i8': types.int64, 'b1': types.boolean, 'u1': types.uint8}
    args = []
    for a in spec:
        if isinstance(a, str):
            args.append(types.float64 if a == 'f' else types.int64)
        else:
            args += [types.CPointer(item[a[0]]), types.int64] + \
                ([types.int64] if a[1] == 2 and a[2] is None else [])
    if result == 'sample':
        args.append(types.CPointer(types.float64))
    return types.int64(*args)


def load_kernels(module_file, name, build):
    """Return ``(functions, cached)``: the kernel set ``name``, built once, then loaded.

    ``functions``: each kernel as a Python builtin; ``cached``: whether they came from the
    cache file. ``module_file``: the module the kernels are made from (its source and this
    module's are in the cache key); ``build()``, called on a cache miss (numba imported
    there), returns ``{kernel: (cfunc, spec, result[, nogil])}`` (:func:`trampoline_ir`).
    A cache file that cannot be read or loaded is built anew once. Raises
    :class:`NativeError` with the reason where the kernels cannot be had this way (the
    caller then takes numba's own load).
    """
    _check_platform()
    sources = []
    for source in (__file__, module_file):
        with open(source, 'rb') as f:
            sources.append(f.read())

    def build_entries(why):
        try:
            return {k: (f'rr_{k}', _object(cf, k, *how)) for k, (cf, *how) in build().items()}
        except NativeError:
            raise
        except Exception as exc:  # noqa: B902 - numba's and LLVM's errors alike
            raise NativeError(f'building the kernels failed: {type(exc).__name__}: {exc}'
                              + (f' (the cache: {why})' if why else '')) from None
    return _load_or_build(cache_path(module_file, name, cache_key(*sources)),
                          build_entries, _functions)


#: LLVM IR of two helpers for loops written in IR (:func:`load_ir`) that keep time on
#: ``CLOCK_REALTIME`` (the ROS system clock): ``i64 @now(ptr %ts)``, the clock in ns,
#: and ``void @sleep_until(ptr %ts, i64 %t)``, an absolute ``clock_nanosleep``; ``%ts``
#: is the caller's ``[2 x i64]`` (a ``timespec``).
CLOCK_IR = r'''
declare i32 @clock_gettime(i32, ptr)
declare i32 @clock_nanosleep(i32, i32, ptr, ptr)

define internal i64 @now(ptr %ts) {
  %r = call i32 @clock_gettime(i32 0, ptr %ts)
  %ps = getelementptr i64, ptr %ts, i64 0
  %pn = getelementptr i64, ptr %ts, i64 1
  %s = load i64, ptr %ps
  %n = load i64, ptr %pn
  %sn = mul i64 %s, 1000000000
  %t = add i64 %sn, %n
  ret i64 %t
}

define internal void @sleep_until(ptr %ts, i64 %t) {
  %ps = getelementptr i64, ptr %ts, i64 0
  %pn = getelementptr i64, ptr %ts, i64 1
  %s = sdiv i64 %t, 1000000000
  %n = srem i64 %t, 1000000000
  store i64 %s, ptr %ps
  store i64 %n, ptr %pn
  %r = call i32 @clock_nanosleep(i32 0, i32 1, ptr %ts, ptr null)
  ret void
}

'''


def load_ir(module_file, name, ir, symbol):
    """Return the address of ``symbol``, a C function written in LLVM IR (``ir``), built once.

    The IR is compiled for this processor with LLVM's large code model (absolute addresses,
    what :class:`ObjectCode` relocates), kept in the cache beside ``module_file`` (its key:
    the IR, this module, LLVM's version, the processor) and mapped by :func:`load_object`.
    LLVM (llvmlite) is imported only to build. Raises :class:`NativeError` with the reason.
    """
    _check_platform()
    with open(__file__, 'rb') as f:
        own = f.read()

    def build_entries(why):
        try:
            return {name: (symbol, _compile_ir(ir))}
        except Exception as exc:  # noqa: B902 - llvmlite's errors, a missing llvmlite
            raise NativeError(f'building {name} failed: {type(exc).__name__}: {exc}') \
                from None

    def address(entries):
        functions = load_object(entries[name][1]) if name in entries else {}
        if symbol not in functions:
            raise NativeError(f'{symbol!r} is not in its object')
        return functions[symbol]
    return _load_or_build(cache_path(module_file, name, cache_key(own, ir)),
                          build_entries, address)[0]


def _load_or_build(path, build, load):
    """Return ``(load(entries), cached)``: the cache file at ``path`` loaded, else built.

    Under the build lock (one process builds, the others then load its file): a cache
    file that cannot be read or loaded is built anew once, ``build(why)`` returning the
    entries (``{name: (symbol, object bytes)}``), which are loaded and then written.
    """
    with _build_lock(path):
        why = None
        if path is not None and os.path.exists(path):
            try:
                return load(read_cache(path)), True
            except NativeError as exc:
                why = str(exc)          # built anew below
        entries = build(why)
        out = load(entries)
        if path is not None:
            try:
                write_cache(path, entries)
            except OSError:
                pass                    # built again next time
        return out, False


def _compile_ir(ir):
    """Return the object code of the LLVM IR ``ir`` for this processor (large code model)."""
    import llvmlite.binding as ll
    ll.initialize_native_target()
    ll.initialize_native_asmprinter()
    module = ll.parse_assembly(ir)
    module.verify()
    target = ll.Target.from_default_triple()
    tm = target.create_target_machine(cpu=ll.get_host_cpu_name(),
                                      features=ll.get_host_cpu_features().flatten(),
                                      opt=2, reloc='static', codemodel='large')
    module.triple = tm.triple
    module.data_layout = str(tm.target_data)
    return bytes(tm.emit_object(module))


@contextlib.contextmanager
def _build_lock(path):
    """Hold an exclusive lock on ``path + '.lock'`` (none where it cannot be had).

    Processes started together on a cold cache (a test suite's workers) then build the
    kernels once: the first builds and writes the file, the others wait and load it.
    """
    if path is None:
        yield
        return
    try:
        fd = os.open(path + '.lock', os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        yield
        return
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:
            pass                        # a file system without locks: build alike
        yield
    finally:
        os.close(fd)                    # releases the lock


def _functions(entries):
    out = {}
    for kernel, (symbol, obj) in entries.items():
        functions = load_object(obj)
        if symbol not in functions:
            raise NativeError(f'{symbol!r} is not in its object')
        out[kernel] = python_function(functions[symbol], kernel)
    return out


def write_cache(path, kernels):
    """Write ``kernels`` (name: ``(symbol, object bytes)``) to ``path``, whole or not at all."""
    head, blobs, at = {}, [], 0
    for name, (symbol, obj) in sorted(kernels.items()):
        head[name] = [symbol, at, len(obj)]
        blobs.append(obj)
        at += len(obj)
    body = b''.join(blobs)
    head = json.dumps({'kernels': head, 'sha256': hashlib.sha256(body).hexdigest()},
                      sort_keys=True).encode()
    tmp = f'{path}.{os.getpid()}.tmp'
    with open(tmp, 'wb') as f:
        f.write(_MAGIC + struct.pack('<QQ', len(head), at) + head + body)
    os.replace(tmp, path)           # readers see the whole file or none


def read_cache(path):
    """Return ``{name: (symbol, object bytes)}`` read from ``path``, or raise NativeError."""
    try:
        with open(path, 'rb') as f:
            data = f.read()
    except OSError as exc:
        raise NativeError(f'cannot read {path}: {exc.strerror}') from None
    n = len(_MAGIC)
    if data[:n] != _MAGIC or len(data) < n + 16:
        raise NativeError(f'{path} is not a kernel cache file')
    nh, no = struct.unpack_from('<QQ', data, n)
    if len(data) != n + 16 + nh + no:
        raise NativeError(f'{path} is truncated')
    try:
        head = json.loads(data[n + 16:n + 16 + nh])
        body = data[n + 16 + nh:]
        if hashlib.sha256(body).hexdigest() != head['sha256']:
            raise NativeError(f'{path}: its object code does not match its checksum')
        return {name: (symbol, body[at:at + size])
                for name, (symbol, at, size) in head['kernels'].items()}
    except (ValueError, TypeError, KeyError):
        raise NativeError(f'{path}: unreadable header') from None


# -- calling from Python -----------------------------------------------------------------
#: numpy's buffer: C-contiguous with its format (and writable, for an output).
_GETBUF_IN, _GETBUF_OUT = 0x38 | 0x4, 0x38 | 0x4 | 0x1
#: array kinds: itemsize and the accepted format characters (``struct`` codes).
_KINDS = {'f8': (8, 'd', 'float64'), 'i8': (8, 'lq', 'int64'), 'b1': (1, '?', 'bool'),
          'u1': (1, 'B', 'uint8')}
_METH_FASTCALL = 0x80


def trampoline_ir(name, symbol, spec, result, nogil=False):
    """LLVM IR of ``rr_<name>``, a ``METH_FASTCALL`` Python function calling ``symbol``.

    ``spec`` lists the Python arguments (:func:`c_signature`); each array is taken
    through the buffer protocol, C-contiguous, of its kind (format and item size) and
    number of dimensions (a 2-d array's second dimension ``width``), writable if ``out``;
    anything else raises TypeError naming the argument (numpy raises its own ValueError
    for a strided array, or a read-only one where one is written). ``result``: ``'int'``
    the C function's int64, ``'pair'`` ``(r >> 1, bool(r & 1))``, ``'sample'`` the 5
    doubles written and ``bool(r)``. ``nogil``: the interpreter is released during the C
    function's call (the arrays stay held through their buffers).
    """
    n = len(spec)
    arrays = [i for i, a in enumerate(spec) if not isinstance(a, str)]
    lines, consts = [], []

    def const(text):
        data = text.encode() + b'\0'
        body = ''.join(chr(c) if 32 <= c < 127 and c not in (34, 92) else f'\\{c:02X}'
                       for c in data)
        consts.append(f'@.s{len(consts)} = private unnamed_addr constant '
                      f'[{len(data)} x i8] c"{body}"')
        return f'@.s{len(consts) - 1}'

    def fail(text, acquired):
        """Jump to a block raising TypeError(text) after releasing ``acquired`` buffers."""
        label = f'fail{len(lines)}'
        msg = const(text)
        lines.extend([f'{label}:', '  %exc.' + label + ' = load ptr, ptr @PyExc_TypeError',
                      f'  call void @PyErr_SetString(ptr %exc.{label}, ptr {msg})',
                      f'  br label %release{len(acquired)}'])
        return label

    body = [f'  %bufs = alloca [{max(len(arrays), 1)} x [80 x i8]], align 8',
            '  %out = alloca [5 x double], align 8',
            f'  %nok = icmp eq i64 %nargs, {n}',
            '  br i1 %nok, label %arg0, label %' +
            fail(f'{name}() takes {n} arguments', [])]
    c_args, acquired = [], []
    for i, a in enumerate(spec):
        body += [f'arg{i}:', f'  %po{i} = getelementptr ptr, ptr %args, i64 {i}',
                 f'  %o{i} = load ptr, ptr %po{i}']
        nxt = f'arg{i + 1}'
        if a in ('f', 'i', 'b'):
            call = {'f': f'  %v{i} = call double @PyFloat_AsDouble(ptr %o{i})',
                    'i': f'  %v{i} = call i64 @PyLong_AsLongLong(ptr %o{i})',
                    'b': f'  %t{i} = call i32 @PyObject_IsTrue(ptr %o{i})'}[a]
            body.append(call)
            if a == 'b':
                body += [f'  %e{i} = icmp slt i32 %t{i}, 0',
                         f'  %v{i} = sext i32 %t{i} to i64',
                         f'  br i1 %e{i}, label %release{len(acquired)}, label %{nxt}']
            else:
                minus = '-1.0' if a == 'f' else '-1'
                cmp = 'fcmp oeq double' if a == 'f' else 'icmp eq i64'
                body += [f'  %e{i} = {cmp} %v{i}, {minus}',
                         f'  br i1 %e{i}, label %chk{i}, label %{nxt}',
                         f'chk{i}:', f'  %err{i} = call ptr @PyErr_Occurred()',
                         f'  %none{i} = icmp eq ptr %err{i}, null',
                         f'  br i1 %none{i}, label %{nxt}, label %release{len(acquired)}']
            c_args.append(('double' if a == 'f' else 'i64', f'%v{i}'))
            continue
        kind, ndim, width, out = a
        size, chars, dtype = _KINDS[kind]
        j = len(acquired)
        what = (f'{name}() argument {i + 1}: expected a C-contiguous {ndim}-d {dtype} array' +
                (f' of {width} columns' if ndim == 2 and width is not None else ''))
        body += [f'  %b{i} = getelementptr [80 x i8], ptr %bufs, i64 {j}',
                 f'  %g{i} = call i32 @PyObject_GetBuffer(ptr %o{i}, ptr %b{i}, i32 '
                 f'{_GETBUF_OUT if out else _GETBUF_IN})',
                 f'  %ge{i} = icmp ne i32 %g{i}, 0',
                 f'  br i1 %ge{i}, label %release{j}, label %got{i}', f'got{i}:']
        acquired.append(i)
        bad = fail(what, acquired)
        body += [f'  %pnd{i} = getelementptr i8, ptr %b{i}, i64 36',
                 f'  %nd{i} = load i32, ptr %pnd{i}',
                 f'  %pis{i} = getelementptr i8, ptr %b{i}, i64 24',
                 f'  %is{i} = load i64, ptr %pis{i}',
                 f'  %pfm{i} = getelementptr i8, ptr %b{i}, i64 40',
                 f'  %fm{i} = load ptr, ptr %pfm{i}',
                 f'  %c0{i} = load i8, ptr %fm{i}',
                 # one byte-order prefix of native order ('@', '=', '<') may lead
                 f'  %x1{i} = icmp eq i8 %c0{i}, 64', f'  %x2{i} = icmp eq i8 %c0{i}, 61',
                 f'  %x3{i} = icmp eq i8 %c0{i}, 60',
                 f'  %x12{i} = or i1 %x1{i}, %x2{i}', f'  %px{i} = or i1 %x12{i}, %x3{i}',
                 f'  %skip{i} = zext i1 %px{i} to i64',
                 f'  %pc{i} = getelementptr i8, ptr %fm{i}, i64 %skip{i}',
                 f'  %c{i} = load i8, ptr %pc{i}',
                 f'  %pz{i} = getelementptr i8, ptr %pc{i}, i64 1',
                 f'  %z{i} = load i8, ptr %pz{i}',
                 f'  %zok{i} = icmp eq i8 %z{i}, 0',
                 f'  %ndok{i} = icmp eq i32 %nd{i}, {ndim}',
                 f'  %isok{i} = icmp eq i64 %is{i}, {size}']
        conds = [f'%zok{i}', f'%ndok{i}', f'%isok{i}']
        ors = []
        for k, ch in enumerate(chars):
            body.append(f'  %ch{i}_{k} = icmp eq i8 %c{i}, {ord(ch)}')
            ors.append(f'%ch{i}_{k}')
        while len(ors) > 1:
            body.append(f'  %chor{i}_{len(ors)} = or i1 {ors[0]}, {ors[1]}')
            ors = [f'%chor{i}_{len(ors)}'] + ors[2:]
        conds.append(ors[0])
        acc = conds[0]
        for k, cnd in enumerate(conds[1:]):
            body.append(f'  %all{i}_{k} = and i1 {acc}, {cnd}')
            acc = f'%all{i}_{k}'
        body += [f'  br i1 {acc}, label %shape{i}, label %{bad}', f'shape{i}:',
                 f'  %psh{i} = getelementptr i8, ptr %b{i}, i64 48',
                 f'  %sh{i} = load ptr, ptr %psh{i}',
                 f'  %len{i} = load i64, ptr %sh{i}',
                 f'  %data{i} = load ptr, ptr %b{i}']
        c_args += [('ptr', f'%data{i}'), ('i64', f'%len{i}')]
        if ndim == 2:
            body += [f'  %pw{i} = getelementptr i64, ptr %sh{i}, i64 1',
                     f'  %w{i} = load i64, ptr %pw{i}']
        if ndim == 2 and width is not None:
            body += [f'  %wok{i} = icmp eq i64 %w{i}, {width}',
                     f'  br i1 %wok{i}, label %{nxt}, label %{bad}']
        else:
            body.append(f'  br label %{nxt}')
            if ndim == 2:
                c_args.append(('i64', f'%w{i}'))
    if result == 'sample':
        c_args.append(('ptr', '%out'))
    body += [f'arg{n}:'] + (['  %ts = call ptr @PyEval_SaveThread()'] if nogil else []) + \
        [f'  %r = call i64 @"{symbol}"({", ".join(f"{t} {v}" for t, v in c_args)})'] + \
        (['  call void @PyEval_RestoreThread(ptr %ts)'] if nogil else [])
    for j in reversed(range(len(acquired))):
        body.append(f'  call void @PyBuffer_Release(ptr %b{acquired[j]})')
    if result == 'int':
        body.append('  %res = call ptr @PyLong_FromLongLong(i64 %r)')
    elif result == 'pair':
        body += ['  %k = ashr i64 %r, 1', '  %flag = and i64 %r, 1',
                 '  %fb = call ptr @PyBool_FromLong(i64 %flag)',
                 f'  %res = call ptr (ptr, ...) @Py_BuildValue(ptr {const("(LN)")}, '
                 'i64 %k, ptr %fb)']
    else:
        body.append('  %fb = call ptr @PyBool_FromLong(i64 %r)')
        vals = []
        for k in range(5):
            body += [f'  %pq{k} = getelementptr double, ptr %out, i64 {k}',
                     f'  %q{k} = load double, ptr %pq{k}']
            vals.append(f'double %q{k}')
        body.append(f'  %res = call ptr (ptr, ...) @Py_BuildValue(ptr {const("(dddddN)")}, '
                    f'{", ".join(vals)}, ptr %fb)')
    body.append('  ret ptr %res')
    # release blocks: releaseJ frees the first J buffers, then returns NULL
    for j in reversed(range(len(acquired) + 1)):
        body.append(f'release{j}:')
        if j:
            body += [f'  call void @PyBuffer_Release(ptr %b{acquired[j - 1]})',
                     f'  br label %release{j - 1}']
        else:
            body.append('  ret ptr null')
    decl = ', '.join(t for t, _ in c_args)
    head = ['declare double @PyFloat_AsDouble(ptr)', 'declare i64 @PyLong_AsLongLong(ptr)',
            'declare i32 @PyObject_IsTrue(ptr)', 'declare ptr @PyErr_Occurred()',
            'declare i32 @PyObject_GetBuffer(ptr, ptr, i32)',
            'declare void @PyBuffer_Release(ptr)', 'declare void @PyErr_SetString(ptr, ptr)',
            'declare ptr @PyLong_FromLongLong(i64)', 'declare ptr @PyBool_FromLong(i64)',
            'declare ptr @Py_BuildValue(ptr, ...)', '@PyExc_TypeError = external global ptr',
            'declare ptr @PyEval_SaveThread()', 'declare void @PyEval_RestoreThread(ptr)',
            f'declare i64 @"{symbol}"({decl})']
    entry = [f'define ptr @rr_{name}(ptr %self, ptr %args, i64 %nargs) {{', 'entry:']
    return '\n'.join(head + consts + entry + body[:4] + lines + body[4:] + ['}']) + '\n'


class _MethodDef(ctypes.Structure):
    _fields_ = [('ml_name', ctypes.c_char_p), ('ml_meth', ctypes.c_void_p),
                ('ml_flags', ctypes.c_int), ('ml_doc', ctypes.c_char_p)]


_new_function = ctypes.pythonapi.PyCFunction_NewEx
_new_function.argtypes = (ctypes.POINTER(_MethodDef), ctypes.c_void_p, ctypes.py_object)
_new_function.restype = ctypes.py_object


def python_function(address, name, module=__name__):
    """Return a Python builtin calling the ``METH_FASTCALL`` function at ``address``."""
    d = _MethodDef(name.encode(), address, _METH_FASTCALL, None)
    _DEFS.append(d)                 # the definition outlives the function (see _DEFS)
    return _new_function(ctypes.byref(d), None, module)
