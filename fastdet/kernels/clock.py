"""A chain of dependent integer operations: the clock a core actually runs at.

``fastdet bench`` sets a frame's arithmetic against one core's cycles
(:mod:`fastdet.bench.floor`).  The clock ``/proc/cpuinfo`` names is the
nominal one, and cores boost above it: an AMD EPYC (Zen 3) listed at 2.45 GHz
ran this chain at 3.2 GHz, so a floor counted at the nominal clock was a
third too high.  Each step of :func:`integer_chain` is a shift, an exclusive
or and an add, each needing the one before: one cycle each on every x86-64
and ARM64 core, so :data:`CYCLES_PER_STEP` cycles a step, whatever else the
core could do alongside.
"""

from __future__ import annotations

from numba import njit, uint64

#: Cycles one step of :func:`integer_chain` takes (three dependent one-cycle operations).
CYCLES_PER_STEP = 3


@njit(cache=True, nogil=True)
def integer_chain(steps, seed):
    """``seed`` put through ``steps`` steps of ``x = (x ^ (x >> 7)) + 1`` (uint64, wrapping)."""
    x = uint64(seed)
    for _ in range(steps):
        x = (x ^ (x >> uint64(7))) + uint64(1)
    return x
