"""numba's compiled code loaded without numba's BLAS probe.

The first time a process compiles or loads numba code from its cache, numba imports its
array implementations, and those probe for a BLAS by importing ``scipy.linalg.cython_blas``
(0.3 to 0.9 s and 16 MB here). The package's compiled code (the core's kernels, the MEKF's
loop) calls no BLAS through numba: the MEKF calls numpy's own by address. So
:func:`no_blas_probe` refuses ``scipy.linalg`` to the loading thread while it loads them.
Its one effect elsewhere: numba code of the same process then takes its own loop for
``np.convolve`` and ``np.correlate``; numba's ``np.dot`` and ``np.linalg``, compiled later,
still find BLAS. Where ``scipy.linalg`` is loaded already nothing changes.
"""

import contextlib
import importlib.abc
import sys
import threading

__all__ = ['no_blas_probe']


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
