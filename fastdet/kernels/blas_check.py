"""Numba's first compile without importing SciPy's linear algebra.

The first kernel a process compiles makes Numba import its NumPy
implementations (``numba.np.arraymath``; so does the first kernel it loads
from the cache where :mod:`fastdet.kernels.cached_load` does not apply),
and that module asks at import
whether a BLAS exists by importing ``scipy.linalg.cython_blas``: all of
``scipy.linalg``, about 0.14 s (a quarter of fastdet's start-up above
NumPy, OpenCV and Numba themselves on the development machine), for an
answer that only chooses how ``np.convolve``/``np.correlate`` compile.  No
fastdet kernel uses BLAS.

:func:`import_numba_arraymath` imports that module with the question
answered by whether SciPy is installed (it is a dependency of fastdet) and
puts Numba's own check back at once.  Code that really compiles a BLAS call
(``np.dot`` in a user's ``@njit`` function) still runs Numba's full check
then, in the same process.  If Numba changes the names this relies on,
nothing is patched and the import happens as before.
"""

from __future__ import annotations

import importlib.util
import sys
import threading

_ARRAYMATH = "numba.np.arraymath"
_lock = threading.Lock()


def import_numba_arraymath():
    """Import ``numba.np.arraymath`` (once) without importing ``scipy.linalg``.

    Returns
    -------
    bool
        Whether the deferred check was used (``False`` when the module was
        already imported, or Numba does not have the expected names).
    """
    if _ARRAYMATH in sys.modules:
        return False
    with _lock:
        if _ARRAYMATH in sys.modules:
            return False
        from numba.np import linalg

        full_check = getattr(linalg, "ensure_blas", None)
        if full_check is None:
            return False
        scipy_installed = short_check(full_check, threading.get_ident())
        linalg.ensure_blas = scipy_installed
        try:
            import numba.np.arraymath as arraymath
        finally:
            linalg.ensure_blas = full_check
        # The module bound the short check under its own name at import.
        if getattr(arraymath, "ensure_blas", None) is scipy_installed:
            arraymath.ensure_blas = full_check
        return True


def short_check(full_check, importing_thread):
    """The BLAS check ``numba.np.arraymath`` gets while it is imported.

    Parameters
    ----------
    full_check : callable
        Numba's ``ensure_blas``.
    importing_thread : int
        ``threading.get_ident()`` of the thread importing the module.

    Returns
    -------
    callable
        Raises ``ImportError`` without SciPy, like Numba's check; called
        from any other thread it runs ``full_check`` instead: a thread
        compiling a BLAS call meanwhile needs SciPy's BLAS imported.
    """
    def scipy_installed():
        if threading.get_ident() != importing_thread:
            return full_check()
        if importlib.util.find_spec("scipy") is None:
            raise ImportError("scipy is required for linear algebra")
        return None

    return scipy_installed
