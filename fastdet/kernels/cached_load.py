"""Loading a cached kernel without first setting Numba up to compile.

Before it loads a function from its cache, Numba refreshes its CPU target
(``numba.core.caching.Cache.load_overload``): it imports some forty modules
of implementations (lists, sets, strings, random numbers, linear algebra,
dates, ...) and installs their typing and lowering registries.  That is what
a *compile* needs.  Loading machine code needs only the symbols the code
calls: Numba's C helpers and exception classes, installed when the target
context is made; its runtime (``NRT_*``), installed by
``rtsys.initialize``; and the hash secret that ``numba.cpython.hashing``
installs when it is imported.  Those are all the symbols Numba installs
(``llvmlite.binding.add_symbol``) outside a compile, in the Numba versions
of :data:`CHECKED_NUMBA`.  Measured on the development machine: loading the
14 kernels of a detection took 0.17 s instead of 0.27 s.

:func:`load_cached` does just that for fastdet's kernels.  A kernel that is
not in the cache is compiled as usual, and its compile refreshes the target.
With another Numba version, or one without the internals used here, the
usual path is taken.
"""

from __future__ import annotations

import importlib

import numba

#: Numba versions (major, minor) whose symbols were checked as above.
CHECKED_NUMBA = ((0, 68),)

_HASH_SECRET_MODULE = "numba.cpython.hashing"


def _numba_version():
    try:
        return tuple(int(part) for part in numba.__version__.split(".")[:2])
    except ValueError:
        return None


def supported(cache):
    """Whether :func:`load_cached` can load for this Numba ``cache`` object."""
    return (_numba_version() in CHECKED_NUMBA
            and hasattr(cache, "_load_overload")
            and hasattr(cache, "_guard_against_spurious_io_errors"))


def load_cached(cache, sig, target_context):
    """Numba's ``Cache.load_overload`` without the target's refresh.

    Parameters
    ----------
    cache : numba.core.caching.Cache
        The kernel's cache (:func:`supported` must hold).
    sig : tuple
        The signature asked for.
    target_context : numba.core.base.BaseContext

    Returns
    -------
    numba.core.compiler.CompileResult or None
        ``None`` when the cache has no entry for ``sig``.
    """
    from numba.core.runtime import rtsys

    rtsys.initialize(target_context)
    importlib.import_module(_HASH_SECRET_MODULE)
    with cache._guard_against_spurious_io_errors():
        return cache._load_overload(sig, target_context)
