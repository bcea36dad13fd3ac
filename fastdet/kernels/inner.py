"""Jit options of the kernels that only other kernels call.

Numba compiles every ``@njit`` function with a CPython wrapper (unboxing its
arguments, boxing its result) and a C-callable wrapper, and optimises and
emits machine code for both, even for a helper no Python code ever calls:
the helper is linked into its callers, which call it directly.  Leaving the
wrappers out of the label family's four helpers cut its first compile from
5.0-5.1 to 4.8 s of CPU, and out of all 24 such helpers a detection's
families from 17.8-17.9 to 16.2-16.9 s (AMD EPYC, Zen 3).  Such a helper
cannot be called from Python.
"""

from __future__ import annotations

#: ``@njit(cache=True, ..., **CALLED_FROM_KERNELS_ONLY)`` for a helper only
#: jitted code calls.
CALLED_FROM_KERNELS_ONLY = {"no_cpython_wrapper": True, "no_cfunc_wrapper": True}
