"""Compiled kernels kept as machine code and loaded without numba or LLVM.

numba compiles a function for this processor, and its cache holds the machine code; but
loading that code back takes numba and LLVM into the process: ``import numba`` alone is
70 MB of memory and 0.3 s, and the load another 40 MB (the generation benchmark's peak,
186 MB, was 136 MB of that before its first sample). A kernel that is plain arithmetic on
arrays needs none of it to run. So:

- :func:`build` (numba imported, once per machine and kernel source) compiles each kernel
  as a C function (``numba.cfunc``: pointers and integers in, an integer out) and keeps
  the object code LLVM emitted for it: an ELF relocatable object, the same machine code
  numba runs itself;
- :func:`load` maps that object into executable memory: its sections copied, its
  relocations applied (x86-64: the large code model that numba's JIT settings give,
  absolute 64-bit addresses), the symbols it calls resolved in this process; the
  kernels are then called through :mod:`ctypes`.

What the object may call is checked, not assumed: functions of this process (libm, the
Python C API) by name, and the few numba helpers that only a C function's error path
calls (raising a Python exception from compiled code), which a kernel compiled with
``error_model='numpy'`` and no ``raise`` never reaches: those point at an instruction
that stops the process (``ud2``), so that a path believed dead can never run on
garbage. Any other undefined symbol, relocation type, writable section or a machine
other than x86-64 is refused with the reason, and the caller takes numba as before.

The cache (:func:`cache_path`) is one file per kernel set, keyed by the kernels' source,
numba's and llvmlite's versions, Python's, and this processor (``/proc/cpuinfo``'s model
and flags: numba compiles for the host): a change of any of them builds anew.
"""

import ctypes
import hashlib
import json
import mmap
import os
import platform
import struct
import sys

__all__ = ['NativeError', 'ObjectCode', 'load_object', 'emit', 'cache_path', 'cache_key',
           'read_cache', 'write_cache', 'TRAPPED']

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
_SHT_PROGBITS, _SHT_SYMTAB, _SHT_STRTAB, _SHT_RELA, _SHT_NOBITS = 1, 2, 3, 4, 8
_SHF_WRITE, _SHF_ALLOC = 1, 2
_SHN_UNDEF, _SHN_ABS = 0, 0xfff1
_EM_X86_64 = 62
_R_X86_64_64, _R_X86_64_PC32, _R_X86_64_PLT32 = 1, 2, 4
_UD2 = b'\x0f\x0b'


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
        self._place()
        self.functions = self._relocate()

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
        size = -(-(self._trap + len(_UD2)) // mmap.PAGESIZE) * mmap.PAGESIZE
        self._map = mmap.mmap(-1, size, prot=mmap.PROT_READ | mmap.PROT_WRITE)
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
_MAPPED = []
_mprotect = _PROCESS.mprotect
_mprotect.argtypes = (ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int)
_mprotect.restype = ctypes.c_int


def load_object(data):
    """Map ``data`` (an ELF object) and return its functions' addresses by name."""
    if sys.platform != 'linux' or platform.machine() not in ('x86_64', 'AMD64'):
        raise NativeError(f'loading object code is done on x86-64 Linux only, not '
                          f'{sys.platform} {platform.machine()}')
    code = ObjectCode(data)
    _MAPPED.append(code)            # mapped for the life of the process: addresses are out
    return code.functions


# -- the cache -------------------------------------------------------------------------------
def _cpu():
    """This processor as numba compiles for it: model name and flags (``/proc/cpuinfo``)."""
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
    for part in (*sources, _version('numba'), _version('llvmlite'), sys.version, _cpu()):
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


def emit(cfunc):
    """Return ``(symbol, object bytes)`` of a ``numba.cfunc``: the code numba runs itself.

    The object is what numba's own code generator emits for the function's final (linked,
    optimised) module, with numba's JIT settings for this processor. Raises
    :class:`NativeError` where this numba does not have the parts used.
    """
    try:
        lib = cfunc._library
        return cfunc.native_name, bytes(lib._codegen._tm.emit_object(lib._final_module))
    except AttributeError as exc:
        raise NativeError(f'this numba does not expose its object code ({exc})') from None


def write_cache(path, kernels):
    """Write ``kernels`` (name: ``(symbol, object bytes)``) to ``path``, whole or not at all."""
    head, blobs, at = {}, [], 0
    for name, (symbol, obj) in sorted(kernels.items()):
        head[name] = [symbol, at, len(obj)]
        blobs.append(obj)
        at += len(obj)
    head = json.dumps(head, sort_keys=True).encode()
    tmp = f'{path}.{os.getpid()}.tmp'
    with open(tmp, 'wb') as f:
        f.write(_MAGIC + struct.pack('<QQ', len(head), at) + head + b''.join(blobs))
    os.replace(tmp, path)           # readers see the whole file or none


def read_cache(path):
    """Return ``{name: (symbol, object bytes)}`` from ``path``; :class:`NativeError` if unusable."""
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
        return {name: (symbol, body[at:at + size])
                for name, (symbol, at, size) in head.items()}
    except (ValueError, TypeError):
        raise NativeError(f'{path}: unreadable header') from None
