"""numba's compiled code loaded from its cache without the compiler's set-up.

:func:`cached_load` is what the package's numba loads use (the MEKF's loop; the core's
kernels and the record placers where they do not load as object code,
:mod:`rigidrot_ros.runtime.native`): the two pieces below.

**The compiler's registries.** Before numba loads one function from its on-disk cache it
refreshes its whole compiler context: it imports and registers every implementation it
could compile (numpy's arrays, linalg, random, typed containers, cffi...), 0.3 to 0.4 s of
CPU in each process, although a cached function is machine code that needs none of them.
:func:`cache_only_refresh` makes that refresh, for loads on the calling thread, only the
part a loaded function needs: numba's runtime (``rtsys.initialize``). A function not in
the cache is compiled as ever, and numba's compiler refreshes the whole context first.

**The BLAS probe.** The first time a process compiles numba code (or loads it with the
whole refresh), numba imports its array implementations, and those probe for a BLAS by
importing ``scipy.linalg.cython_blas`` (0.3 to 0.9 s and 16 MB here). The package's
compiled code (the core's kernels, the MEKF's loop) calls no BLAS through numba: the MEKF
calls numpy's own by address. So :func:`no_blas_probe` refuses ``scipy.linalg`` to the
loading thread while it compiles or loads them (a cold cache compiles). Its one effect
elsewhere: numba code of the same process then takes its own loop for ``np.convolve`` and
``np.correlate``; numba's ``np.dot`` and ``np.linalg``, compiled later, still find BLAS.
Where ``scipy.linalg`` is loaded already nothing changes.
"""

import contextlib
import importlib.abc
import sys
import threading

__all__ = ['cached_load', 'cache_only_refresh', 'no_blas_probe']


class _RefuseScipyLinalg(importlib.abc.MetaPathFinder):
    """An import hook refusing ``scipy.linalg`` (and below) to one thread."""

    def __init__(self):
        self.thread = threading.get_ident()

    def find_spec(self, name, path, target=None):
        """Refuse ``scipy.linalg`` to the loading thread; leave every other import alone."""
        if (name == 'scipy.linalg' or name.startswith('scipy.linalg.')) \
                and threading.get_ident() == self.thread:
            raise ModuleNotFoundError(f'{name}: not imported while compiled code loads',
                                      name=name)
        return None


@contextlib.contextmanager
def no_blas_probe():
    """Refuse ``scipy.linalg`` to this thread while numba compiles or loads code within."""
    if 'scipy.linalg' in sys.modules:
        yield
        return
    hook = _RefuseScipyLinalg()
    sys.meta_path.insert(0, hook)
    try:
        yield
    finally:
        sys.meta_path.remove(hook)


_LIGHT = threading.local()
_PATCH = {'done': False}
_PATCH_LOCK = threading.Lock()


def _install():
    """Wrap numba's ``Cache.load_overload`` once: light refresh where a thread asks for it."""
    with _PATCH_LOCK:
        if _PATCH['done']:
            return
        from numba.core import caching
        from numba.core.runtime import rtsys
        full = caching.Cache.load_overload
        for name in ('_load_overload', '_guard_against_spurious_io_errors'):
            if not hasattr(caching.Cache, name):       # another numba: leave it as it is
                raise AttributeError(f'numba.core.caching.Cache has no {name}')

        def load_overload(self, sig, target_context):
            if not getattr(_LIGHT, 'depth', 0):
                return full(self, sig, target_context)
            try:
                rtsys.initialize(target_context)   # what a loaded function calls into
                with self._guard_against_spurious_io_errors():
                    return self._load_overload(sig, target_context)
            except Exception:  # noqa: B902 - numba's own way, which raises what is wrong
                return full(self, sig, target_context)
        load_overload.__doc__ = full.__doc__
        caching.Cache.load_overload = load_overload
        _PATCH['done'] = True


@contextlib.contextmanager
def cache_only_refresh():
    """Within, this thread's loads from numba's cache skip the compiler's registries.

    Compiling (a cache miss) is untouched: numba's compiler refreshes everything itself.
    Where numba's cache class has not the expected shape, nothing changes.
    """
    try:
        _install()
    except (ImportError, AttributeError):
        yield
        return
    _LIGHT.depth = getattr(_LIGHT, 'depth', 0) + 1
    try:
        yield
    finally:
        _LIGHT.depth -= 1


@contextlib.contextmanager
def cached_load():
    """Load (or compile) numba code within: no compiler registries for a load, no BLAS probe."""
    with no_blas_probe(), cache_only_refresh():
        yield
